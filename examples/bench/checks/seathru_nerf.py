"""Checks of SeaThru-NeRF items named by the item (the suite's own checks of the paper are in seathru.py)."""


import _refs  # checks/_refs.py: the check's folder is on sys.path in the check process


def proposal_sampling(target):
    """Sec. 4 (mip-NeRF 360's proposal sampling, which SeaThru-NeRF trains with): at least one proposal round
    before the NeRF samples, each round resampling by inverse transform of the previous round's weights."""
    v = _refs.as_derived(target)
    assert len(v["samples_per_ray"]) >= 1 and v["nerf_samples"] > 0, v
    _refs.inverse_transform_sampling(int(v["nerf_samples"]))
