"""Checks of Scaffold-GS (Lu et al. 2024) items: reference functions written from the paper."""

import torch


def l1_loss(target):
    """Eq. 11: the L1 loss between rendered and true pixel colours, |C_hat - C|, as a mean."""
    from nerfstudio.model_components.losses import L1Loss

    assert target.path.endswith(".l1"), f"colour loss at {target.path}, not L1"
    g = torch.Generator().manual_seed(0)
    pred, gt = torch.rand(32, 3, generator=g), torch.rand(32, 3, generator=g)
    torch.testing.assert_close(L1Loss()(pred, gt), (pred - gt).abs().mean())
