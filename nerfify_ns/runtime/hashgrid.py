"""Fast torch multi-resolution hash encoding (Instant-NGP, Müller et al. 2022, Sec. 3, Eq. 3-4).

Replaces the body of Nerfstudio's ``HashEncoding.pytorch_fwd`` (the fallback used when
tiny-cuda-nn is missing). On the CPU the stock path is bound by memory traffic: eight separate
gathers, eight dense ``index_put`` table gradients and a ``[N, L, 8, F]`` layout that jumps between
levels. This version:

* works level-major (``[L, N, 8]``), so each level's slice of the table stays in cache while it
  is read and written;
* builds all 8 corner indices at once by broadcasting the per-axis hash terms
  (``x * 1 ^ y * 2654435761 ^ z * 805459861`` wrapped to the table size; only the low
  ``log2_hashmap_size`` bits matter, so the products are computed in int32 with wrap-around);
* treats a 2-feature row as one complex number, so the gather is one ``index_select`` of scalars
  and the backward one ``scatter_add_`` of scalars (complex addition is component-wise);
* computes the gradient with respect to positions analytically (camera optimisation needs it).

The parameter layout is Nerfstudio's (one ``hash_table`` of shape ``[levels * T, F]``, the same
hash and level offsets), so checkpoints are interchangeable with the stock torch path; outputs and
gradients match it to float rounding (``tests/test_hashgrid.py``). One documented difference: at
a position lying exactly on a grid plane the stock path (``ceil == floor``) reports a zero
derivative across that plane; this one reports the right-sided derivative.
"""

from __future__ import annotations

from typing import Optional, Tuple

import torch
from torch import Tensor

# Instant-NGP's spatial hash primes, as Nerfstudio's torch fallback uses them.
PRIMES = (1, 2654435761, 805459861)


def _wrap_int32(value: int) -> int:
    """Two's-complement int32 view of ``value`` (the hash keeps only the low bits)."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value >= 1 << 31 else value


_PRIMES_I32 = tuple(_wrap_int32(p) for p in PRIMES)


def _axis_weights(frac: Tensor) -> Tuple[Tensor, Tensor, Tensor]:
    """Per-axis linear weights ``[..., 2]`` for the floor and floor + 1 corners."""
    one_minus = 1.0 - frac
    return tuple(torch.stack([one_minus[..., a], frac[..., a]], dim=-1) for a in range(3))  # type: ignore


def corner_indices_and_weights(
    positions: Tensor, scalings: Tensor, table_size: int
) -> Tuple[Tensor, Tensor, Tensor]:
    """Level-major hash indices ``[L, N, 8]``, trilinear weights ``[L, N, 8]``, fractions ``[L, N, 3]``.

    Corner ``c = 4 * bx + 2 * by + bz`` takes ``floor + b`` along each axis. Indices are within a
    level (add ``level * table_size`` to address the flat table).
    """
    scaled = scalings[:, None, None] * positions[None, :, :]  # [L, N, 3]
    floor = torch.floor(scaled)
    frac = scaled - floor
    base = floor.to(torch.int32)
    hx, hy, hz = (
        torch.stack([base[..., a] * p, base[..., a] * p + p], dim=-1) for a, p in enumerate(_PRIMES_I32)
    )
    idx = (hx[..., :, None, None] ^ hy[..., None, :, None] ^ hz[..., None, None, :]) & (table_size - 1)
    wx, wy, wz = _axis_weights(frac)
    weights = wx[..., :, None, None] * wy[..., None, :, None] * wz[..., None, None, :]
    levels, n = scaled.shape[:2]
    return idx.reshape(levels, n, 8), weights.reshape(levels, n, 8), frac


def _rows_as_scalars(table: Tensor) -> Tensor:
    """A 1-D view with one element per table row: complex for 2 features, the table itself for 1."""
    if table.shape[1] == 2:
        return torch.view_as_complex(table)
    if table.shape[1] == 1:
        return table.view(-1)
    return table


def _scalars_as_rows(values: Tensor, features: int) -> Tensor:
    """Inverse of :func:`_rows_as_scalars` for gathered values: ``[..., F]``."""
    if features == 2:
        return torch.view_as_real(values)
    if features == 1:
        return values[..., None]
    return values


def _position_gradient(dots: Tensor, frac: Tensor, scalings: Tensor) -> Tensor:
    """Gradient w.r.t. positions ``[N, 3]`` from per-corner ``<f_c, dL/d out>`` products ``[L, N, 8]``."""
    levels, n = frac.shape[:2]
    d = dots.reshape(levels, n, 2, 2, 2)
    wx, wy, wz = _axis_weights(frac)
    sign = frac.new_tensor([-1.0, 1.0])
    gx = torch.einsum("lnabc,a,lnb,lnc->ln", d, sign, wy, wz)
    gy = torch.einsum("lnabc,lna,b,lnc->ln", d, wx, sign, wz)
    gz = torch.einsum("lnabc,lna,lnb,c->ln", d, wx, wy, sign)
    return (torch.stack([gx, gy, gz], dim=-1) * scalings[:, None, None]).sum(dim=0)


class HashGridFunction(torch.autograd.Function):
    """Differentiable multi-resolution hash-grid lookup: one gather, one scatter."""

    @staticmethod
    def forward(ctx, positions: Tensor, table: Tensor, scalings: Tensor, table_size: int):  # type: ignore[override]
        idx, weights, frac = corner_indices_and_weights(positions, scalings, table_size)
        levels, n = idx.shape[:2]
        features = table.shape[1]
        offsets = torch.arange(levels, device=idx.device, dtype=torch.int64)[:, None, None] * table_size
        flat_idx = (idx.to(torch.int64) + offsets).reshape(-1)
        gathered = _rows_as_scalars(table.detach()).index_select(0, flat_idx)
        feats = _scalars_as_rows(gathered, features).reshape(levels, n, 8, features)
        out = torch.einsum("lnc,lncf->nlf", weights.to(table.dtype), feats).reshape(n, levels * features)
        ctx.table_shape = table.shape
        keep_feats = feats if ctx.needs_input_grad[0] else None
        ctx.save_for_backward(flat_idx, weights, frac, scalings, keep_feats)
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor):  # type: ignore[override]
        flat_idx, weights, frac, scalings, feats = ctx.saved_tensors
        levels, n = weights.shape[:2]
        features = ctx.table_shape[1]
        grad_levels = grad_out.reshape(n, levels, features).transpose(0, 1)  # [L, N, F]
        grad_table: Optional[Tensor] = None
        if ctx.needs_input_grad[1]:
            per_corner = (weights[..., None] * grad_levels[:, :, None, :]).reshape(-1, features).contiguous()
            grad_table = grad_out.new_zeros(ctx.table_shape)
            target = _rows_as_scalars(grad_table)
            if target.dim() == 1:
                target.scatter_add_(0, flat_idx, _rows_as_scalars(per_corner))
            else:
                target.index_add_(0, flat_idx, per_corner)
        grad_pos: Optional[Tensor] = None
        if ctx.needs_input_grad[0]:
            dots = torch.einsum("lncf,lnf->lnc", feats, grad_levels)
            grad_pos = _position_gradient(dots, frac, scalings)
        return grad_pos, grad_table, None, None


def hash_encode(positions: Tensor, table: Tensor, scalings: Tensor, table_size: int) -> Tensor:
    """Encode ``positions`` ``[..., 3]`` with the hash ``table`` ``[L * T, F]`` -> ``[..., L * F]``."""
    levels = scalings.shape[0]
    flat = positions.reshape(-1, 3)
    out = HashGridFunction.apply(flat, table, scalings.to(positions), table_size)
    return out.reshape(*positions.shape[:-1], levels * table.shape[1])


def fast_pytorch_fwd(self, in_tensor: Tensor) -> Tensor:
    """Drop-in body for ``nerfstudio.field_components.encodings.HashEncoding.pytorch_fwd``."""
    assert in_tensor.shape[-1] == 3
    return hash_encode(in_tensor, self.hash_table, self.scalings.to(in_tensor.device), self.hash_table_size)
