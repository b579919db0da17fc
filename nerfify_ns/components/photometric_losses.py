"""Photometric losses missing from Nerfstudio.

``charbonnier_loss``: the Charbonnier penalty sqrt((x - y)^2 + eps^2) (Charbonnier et al., "Two
deterministic half-quadratic regularization algorithms for computed imaging", ICIP 1994), the data
term of Mip-NeRF 360 (Barron et al. 2022, arXiv 2111.12077, Sec. 5, eps = 1e-3); a smooth L1 that
is robust to outliers and has a finite gradient at 0.

Imports only torch: generated plugins import this module.
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor, nn

__all__ = ["charbonnier_loss", "CharbonnierLoss"]


def charbonnier_loss(pred: Tensor, target: Tensor, eps: float = 1e-3,
                     reduction: Literal["mean", "sum", "none"] = "mean") -> Tensor:
    """mean(sqrt((pred - target)^2 + eps^2)); computed in float32 at least (half inputs stay finite).

    An empty batch gives 0 (not NaN) with ``reduction="mean"``.
    """
    if eps <= 0:
        raise ValueError(f"eps must be > 0, got {eps}")
    if pred.dtype not in (torch.float32, torch.float64):
        pred = pred.float()
    if target.dtype not in (torch.float32, torch.float64):
        target = target.float()
    diff = pred - target
    value = torch.sqrt(diff.square() + eps * eps)
    if reduction == "none":
        return value
    if reduction == "sum":
        return value.sum()
    if reduction != "mean":
        raise ValueError(f"reduction must be 'mean', 'sum' or 'none', got {reduction!r}")
    return value.mean() if value.numel() > 0 else value.sum()


class CharbonnierLoss(nn.Module):
    """Module form of ``charbonnier_loss`` (drop-in for ``MSELoss`` / ``L1Loss`` in a model)."""

    def __init__(self, eps: float = 1e-3, reduction: Literal["mean", "sum", "none"] = "mean") -> None:
        super().__init__()
        self.eps = eps
        self.reduction = reduction

    def forward(self, pred: Tensor, target: Tensor) -> Tensor:
        return charbonnier_loss(pred, target, eps=self.eps, reduction=self.reduction)

    def extra_repr(self) -> str:
        return f"eps={self.eps}, reduction={self.reduction}"
