"""Checks of SeaThru-NeRF items named by the item (the suite's own checks of the paper are in seathru.py)."""


import _refs  # checks/_refs.py: the check's folder is on sys.path in the check process


def proposal_sampling(target):
    """Sec. 4 (mip-NeRF 360's proposal sampling, which SeaThru-NeRF trains with): at least one proposal round
    before the NeRF samples, each round resampling by inverse transform of the previous round's weights."""
    v = _refs.as_derived(target)
    assert len(v["samples_per_ray"]) >= 1 and v["nerf_samples"] > 0, v
    _refs.inverse_transform_sampling(int(v["nerf_samples"]))


def transmittance_prior(target):
    """Losses (the accumulation prior): P(x) proportional to e^{-|x|/0.1} + e^{-|1-x|/0.1}, L_acc = -log P(T_i^obj)
    with T_i^obj = exp(-sum_{j<i} sigma_j delta_j), a mean over the samples (the constant factor of P changes no
    gradient and is taken as 1): the compiled regulariser against it in float64, on densities and steps."""
    import numpy as np
    import torch

    assert target.cls is not None, "no compiled regulariser implements the prior"
    prior = target.cls().double()
    g = torch.Generator().manual_seed(0)
    sigma = torch.rand(4, 12, 1, generator=g, dtype=torch.float64) * 3
    delta = torch.rand(4, 12, 1, generator=g, dtype=torch.float64) * 0.2 + 0.01
    got = float(prior(densities=sigma, deltas=delta))
    s, d = sigma[..., 0].numpy(), delta[..., 0].numpy()
    t = np.exp(-np.concatenate([np.zeros((4, 1)), np.cumsum(s * d, 1)[:, :-1]], 1))
    want = float(np.mean(-np.log(np.exp(-np.abs(t) / 0.1) + np.exp(-np.abs(1 - t) / 0.1))))
    assert abs(got - want) < 1e-9 * max(1.0, abs(want)), f"the regulariser gives {got}, the prior {want}"
