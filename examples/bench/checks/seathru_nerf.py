"""Checks of SeaThru-NeRF items named by the item (the suite's own checks of the paper are in seathru.py)."""


def _refs():
    """The shared reference functions (checks/_refs.py; check files are loaded by path)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("nerfify_bench_refs", Path(__file__).with_name("_refs.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def proposal_sampling(target):
    """Sec. 4 (mip-NeRF 360's proposal sampling, which SeaThru-NeRF trains with): at least one proposal round
    before the NeRF samples, each round resampling by inverse transform of the previous round's weights."""
    v = _refs().as_derived(target)
    assert len(v["samples_per_ray"]) >= 1 and v["nerf_samples"] > 0, v
    _refs().inverse_transform_sampling(int(v["nerf_samples"]))
