"""Regularisers missing from Nerfstudio, written to stay finite at the extremes.

- ``plane_tv``: K-Planes (Fridovich-Keil et al. 2023, arXiv 2301.10241) Eq. 4, total variation of
  spatial planes.
- ``time_smoothness``: K-Planes Eq. 5, squared 1D Laplacian along the time axis of space-time planes.
- ``plane_l1_to_one``: K-Planes Eq. 6, L1 distance of the space-time planes to 1 (static by default).
- ``ray_entropy``: InfoNeRF (Kim et al. 2022, arXiv 2112.15399) Eq. 6-7, Shannon entropy of each
  ray's normalised weights, masked for rays that see (almost) nothing.
- ``density_sparsity``: Cauchy sparsity log(1 + sigma^2 / c) (SNeRG, Hedman et al. 2021,
  arXiv 2103.14645, Eq. 4; also used by Plenoxels, arXiv 2112.05131).

Planes are [1, C, H, W] (or [C, H, W]) tensors; a space-time plane has time on dim -2 ([1, C, T, S]),
the layout of ``MultiScaleKPlanes.time_planes``. Every function returns a 0-dim tensor that is 0 for
empty input and keeps the graph of its inputs (so ``backward`` works even then).

Imports only torch: generated plugins import this module.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence

import torch
from torch import Tensor

__all__ = ["plane_tv", "time_smoothness", "plane_l1_to_one", "ray_entropy", "density_sparsity"]


def _upcast(x: Tensor) -> Tensor:
    """float16/bfloat16 (and integer) tensors to float32; float32/float64 unchanged."""
    return x if x.dtype in (torch.float32, torch.float64) else x.float()


def _as_list(planes: Iterable[Tensor] | Tensor) -> list[Tensor]:
    if isinstance(planes, Tensor):
        return [planes]
    return list(planes)


def _zero(planes: Sequence[Tensor]) -> Tensor:
    """A 0 that still depends on the inputs (finite gradient of 0)."""
    if not planes:
        return torch.zeros(())
    zero = _upcast(planes[0]).sum() * 0.0
    for p in planes[1:]:
        zero = zero + _upcast(p).sum() * 0.0
    return zero


def _mean_or_zero(x: Tensor) -> Tensor:
    return x.mean() if x.numel() > 0 else x.sum()


def _mean_over_planes(planes: Iterable[Tensor] | Tensor, per_plane: Callable[[Tensor], Tensor]) -> Tensor:
    """Mean of ``per_plane`` over the planes (each upcast to float32 at least); 0 for no planes."""
    planes = _as_list(planes)
    if not planes:
        return _zero(planes)
    total = _zero(planes)
    for plane in planes:
        total = total + per_plane(_upcast(plane))
    return total / len(planes)


def plane_tv(planes: Iterable[Tensor] | Tensor) -> Tensor:
    """Total variation of planes (K-Planes Eq. 4), averaged over planes.

    For each plane P [1, C, H, W]:
        TV(P) = mean_{c,i,j} (P[c,i,j] - P[c,i-1,j])^2 + mean_{c,i,j} (P[c,i,j] - P[c,i,j-1])^2
    i.e. the paper's 1 / (|C| n^2) sum over squared neighbour differences, each direction averaged over
    its own count of neighbour pairs. The result is the mean of TV(P) over the planes given (pass
    ``MultiScaleKPlanes.spatial_planes``). Computed in float32 at least.
    """
    def tv(p: Tensor) -> Tensor:
        dh = p[..., 1:, :] - p[..., :-1, :]
        dw = p[..., :, 1:] - p[..., :, :-1]
        return _mean_or_zero(dh.square()) + _mean_or_zero(dw.square())

    return _mean_over_planes(planes, tv)


def time_smoothness(planes: Iterable[Tensor] | Tensor) -> Tensor:
    """Smoothness along time of space-time planes (K-Planes Eq. 5), averaged over planes.

    For each plane P [1, C, T, S] (time on dim -2):
        L(P) = mean_{c,t,i} (P[c,t-1,i] - 2 P[c,t,i] + P[c,t+1,i])^2
    Planes with fewer than 3 time steps contribute 0. Computed in float32 at least.
    """
    def smoothness(p: Tensor) -> Tensor:
        return _mean_or_zero((p[..., :-2, :] - 2.0 * p[..., 1:-1, :] + p[..., 2:, :]).square())

    return _mean_over_planes(planes, smoothness)


def plane_l1_to_one(planes: Iterable[Tensor] | Tensor) -> Tensor:
    """L1 separation of space-time planes from 1 (K-Planes Eq. 6), averaged over planes.

    For each plane P: L(P) = mean_{c,t,i} |1 - P[c,t,i]|; a plane equal to 1 makes the Hadamard
    product ignore time there, so this favours static content. Computed in float32 at least.
    """
    return _mean_over_planes(planes, lambda p: _mean_or_zero((1.0 - p).abs()))


def ray_entropy(weights: Tensor, threshold: float = 0.1, eps: float = 1e-10) -> Tensor:
    """Ray entropy loss (InfoNeRF, Kim et al. 2022, Eq. 6-7).

    For every ray r with weights w_i (``weights`` [R, S, 1] or [R, S]; the paper uses opacities alpha_i,
    rendering weights work alike):
        p_i = w_i / sum_j w_j,   H(r) = -sum_i p_i log p_i,
        M(r) = 1 if Q(r) = sum_i w_i > threshold else 0      (rays that see nothing are not penalised)
        L = sum_r M(r) H(r) / sum_r M(r)
    Returns 0 when no ray passes the mask. ``eps`` keeps log and the normalisation finite for zero
    weights; computed in float32 at least.
    """
    w = _upcast(weights)
    if w.dim() == 3 and w.shape[-1] == 1:
        w = w[..., 0]
    if w.dim() == 1:
        w = w.unsqueeze(0)
    if w.numel() == 0:
        return w.sum()
    acc = w.sum(dim=-1)  # [R]
    p = w / (acc.unsqueeze(-1) + eps)
    entropy = -(p * torch.log(p.clamp_min(0.0) + eps)).sum(dim=-1)  # [R]; clamp: finite if w < 0
    mask = (acc > threshold).to(entropy.dtype)
    return (entropy * mask).sum() / mask.sum().clamp_min(1.0)


def density_sparsity(densities: Tensor, scale: float = 0.5) -> Tensor:
    """Cauchy sparsity loss mean log(1 + sigma^2 / c) (SNeRG Eq. 4, Hedman et al. 2021; Plenoxels).

    ``densities`` [R, S, 1] (>= 0; any shape works), ``scale`` is c. Evaluated stably for huge
    densities (1e8 and beyond): for x = sigma / sqrt(c) with |x| > 1, log(1 + x^2) =
    2 log|x| + log1p(1 / x^2). Computed in float32 at least; 0 for an empty tensor.
    """
    if scale <= 0:
        raise ValueError(f"scale must be > 0, got {scale}")
    sigma = _upcast(densities)
    if sigma.numel() == 0:
        return sigma.sum()
    x = sigma.abs() / math.sqrt(scale)
    big = x > 1.0
    x_small = torch.where(big, torch.zeros_like(x), x)
    x_big = torch.where(big, x, torch.ones_like(x))
    large = 2.0 * torch.log(x_big) + torch.log1p(1.0 / x_big.square())
    value = torch.where(big, large, torch.log1p(x_small.square()))
    return value.mean()
