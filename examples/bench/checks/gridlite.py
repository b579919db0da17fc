"""Checks of GridLite (examples/gridlite_paper.md, written for the project) items."""

import numpy as np
import torch


def distortion_loss(target):
    """Eq. 1: L_dist(s, w) = sum_{i,j} w_i w_j |(s_i + s_{i+1})/2 - (s_j + s_{j+1})/2|
    + 1/3 sum_i w_i^2 (s_{i+1} - s_i),
    against the distortion loss the plan uses (Nerfstudio's, on its normalised spacing)."""
    from nerfstudio.cameras.rays import Frustums, RaySamples
    from nerfstudio.model_components.losses import distortion_loss as ns_distortion

    g = torch.Generator().manual_seed(0)
    edges = torch.sort(torch.rand(3, 17, generator=g, dtype=torch.float64), dim=1).values
    w = torch.rand(3, 16, generator=g, dtype=torch.float64)
    w = w / w.sum(-1, keepdim=True)
    starts, ends = edges[:, :-1, None], edges[:, 1:, None]
    frustums = Frustums(origins=torch.zeros(3, 16, 3, dtype=torch.float64),
                        directions=torch.ones(3, 16, 3, dtype=torch.float64), starts=starts, ends=ends,
                        pixel_area=torch.ones(3, 16, 1, dtype=torch.float64))
    samples = RaySamples(frustums=frustums, spacing_starts=starts, spacing_ends=ends)
    got = float(ns_distortion([w[..., None]], [samples]))  # the mean over the rays
    s, wn = edges.numpy(), w.numpy()
    mid = (s[:, 1:] + s[:, :-1]) / 2
    want = (wn[:, :, None] * wn[:, None, :] * np.abs(mid[:, :, None] - mid[:, None, :])).sum((1, 2)) \
        + (wn ** 2 * (s[:, 1:] - s[:, :-1])).sum(1) / 3
    np.testing.assert_allclose(got, want.mean(), rtol=1e-6)


def exposure(target):
    """Eq. 2: C_hat(r) = exp(beta * mean luminance) C(r), beta learned: a compiled renderer must scale its colour so."""
    assert target.cls is not None, "no compiled component implements Eq. 2"
