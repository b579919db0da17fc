"""Fast torch multi-resolution hash encoding (Instant-NGP, Müller et al. 2022, Sec. 3, Eq. 3-4).

Replaces the body of Nerfstudio's ``HashEncoding.pytorch_fwd`` (the fallback used when
tiny-cuda-nn is missing). On the CPU the stock path is bound by memory traffic: eight separate
gathers, eight dense ``index_put`` table gradients, a ``[N, L, 8, F]`` layout that jumps between
levels, and element-wise products broadcast over tiny trailing dimensions. This version:

* works level-major and planar (``[L, 8, N]``: level, corner, point), so each level's slice of
  the table stays in cache and every element-wise op runs over long contiguous rows;
* builds the 8 corner indices from per-axis hash terms
  (``x * 1 ^ y * 2654435761 ^ z * 805459861`` wrapped to the table size; only the low
  ``log2_hashmap_size`` bits matter, so the products are computed in int32 with wrap-around);
* gathers once (``index_select``) and scatters once (``scatter_add_``), treating a 2-feature row
  as one complex number so both move scalars (complex addition is component-wise);
* computes the gradient with respect to positions analytically (camera optimisation needs it).

The parameter layout is Nerfstudio's (one ``hash_table`` of shape ``[levels * T, F]``, the same
hash and level offsets), so checkpoints are interchangeable with the stock torch path; outputs and
gradients match it to float rounding (``tests/test_hashgrid.py``). One documented difference: at
a position lying exactly on a grid plane the stock path (``ceil == floor``) reports a zero
derivative across that plane; this one reports the right-sided derivative.

On the CPU a fused C++ kernel (``csrc/hashgrid_cpu.cpp``, :mod:`nerfify_ns.runtime.hashgrid_ext`)
does the same in one pass per direction (hash, gather and interpolate; recomputed rows, race-free
scatter and the analytic position gradient in backward). It is compiled at setup time only
(``python -m nerfify_ns.runtime.hashgrid_ext build``); :func:`hash_encode` uses it for float32/float64
CPU tensors whenever it is built, else this torch path. ``NERFIFY_HASHGRID_IMPL`` = ``auto`` (default),
``torch`` or ``cpp`` forces a choice; ``cpp`` raises a RuntimeError when the kernel cannot be used.
"""

from __future__ import annotations

import contextlib
import os
import threading

import torch
from torch import Tensor

from nerfify_ns.runtime import hashgrid_ext

# Instant-NGP's spatial hash primes, as Nerfstudio's torch fallback uses them.
PRIMES = (1, 2654435761, 805459861)


def _wrap_int32(value: int) -> int:
    """Two's-complement int32 view of ``value`` (the hash keeps only the low bits)."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value >= 1 << 31 else value


_PRIMES_I32 = tuple(_wrap_int32(p) for p in PRIMES)


def _corner_stack(a: tuple[Tensor, Tensor], b: tuple[Tensor, Tensor], c: tuple[Tensor, Tensor], op) -> Tensor:
    """``op(op(a_i, b_j), c_k)`` for corners ``4 i + 2 j + k``, stacked on a new last axis (``[L, N, 8]``).

    Corners of one point stay adjacent so a gather or scatter touches the same cache lines for them.
    """
    pairs = [op(a[i], b[j]) for i in (0, 1) for j in (0, 1)]
    return torch.stack([op(p, c[k]) for p in pairs for k in (0, 1)], dim=-1)


def corner_indices(positions: Tensor, scalings: Tensor, table_size: int) -> tuple[Tensor, Tensor]:
    """Flat table indices ``[L, N, 8]`` (level offsets included, int32) and fractions ``[3, L, N]``.

    Corner ``c = 4 * bx + 2 * by + bz`` takes ``floor + b`` along each axis. Masking each axis term
    before the XOR equals masking the XOR, and since every masked value is below ``table_size`` (a
    power of two), adding the level offset to one term equals adding it to the result.
    """
    scaled = positions.t()[:, None, :] * scalings[None, :, None]  # [3, L, N]
    floor = torch.floor(scaled)
    frac = scaled - floor
    base = floor.to(torch.int32)
    mask = table_size - 1
    terms: list[tuple[Tensor, Tensor]] = []
    for axis, prime in enumerate(_PRIMES_I32):
        lo = base[axis] * prime if prime != 1 else base[axis]
        terms.append((lo & mask, (lo + prime) & mask))
    levels = scalings.shape[0]
    offsets = (torch.arange(levels, device=positions.device, dtype=torch.int32) * table_size)[:, None]
    terms[2] = (terms[2][0] + offsets, terms[2][1] + offsets)
    return _corner_stack(*terms, op=torch.bitwise_xor), frac


def _axis_weights(frac: Tensor) -> list[tuple[Tensor, Tensor]]:
    """Per-axis linear weights ``(1 - t, t)`` for the floor and floor + 1 corners."""
    return [(1.0 - frac[a], frac[a]) for a in range(3)]


def corner_weights(frac: Tensor) -> Tensor:
    """Trilinear weights ``[L, N, 8]`` of the corners, from fractions ``[3, L, N]``."""
    return _corner_stack(*_axis_weights(frac), op=torch.mul)


def _position_gradient(dots: Tensor, frac: Tensor, scalings: Tensor) -> Tensor:
    """Gradient w.r.t. positions ``[N, 3]`` from per-corner ``<f_c, dL/d out>`` products ``[L, N, 8]``.

    Along an axis the trilinear weight's derivative is ``+-1`` times the other two axes' weights,
    so each component is a difference of corner products contracted with two weight pairs.
    """
    (ox, fx), (oy, fy), (oz, fz) = _axis_weights(frac)
    d = dots.transpose(1, 2).contiguous().unbind(1)  # d[4 bx + 2 by + bz], each contiguous [L, N]

    def contract(diff: list[Tensor], u: tuple[Tensor, Tensor], v: tuple[Tensor, Tensor]) -> Tensor:
        return (diff[0] * v[0] + diff[1] * v[1]) * u[0] + (diff[2] * v[0] + diff[3] * v[1]) * u[1]

    gx = contract([d[4] - d[0], d[5] - d[1], d[6] - d[2], d[7] - d[3]], (oy, fy), (oz, fz))
    gy = contract([d[2] - d[0], d[3] - d[1], d[6] - d[4], d[7] - d[5]], (ox, fx), (oz, fz))
    gz = contract([d[1] - d[0], d[3] - d[2], d[5] - d[4], d[7] - d[6]], (ox, fx), (oy, fy))
    per_level = torch.stack([gx, gy, gz], dim=-1)  # [L, N, 3]
    return (per_level * scalings[:, None, None]).sum(dim=0)


def _rows(table: Tensor) -> Tensor:
    """One element per 2-feature row (complex view, so gathers and scatters move scalars)."""
    return torch.view_as_complex(table) if table.shape[-1] == 2 else table


class HashGridFunction(torch.autograd.Function):
    """Differentiable multi-resolution hash-grid lookup: one gather, one scatter."""

    @staticmethod
    def forward(ctx, positions: Tensor, table: Tensor, scalings: Tensor, table_size: int):  # type: ignore[override]
        idx, frac = corner_indices(positions, scalings, table_size)
        levels, n, _ = idx.shape
        features = table.shape[1]
        flat_idx = idx.view(-1)
        gathered = _rows(table.detach()).index_select(0, flat_idx)
        feats = (torch.view_as_real(gathered) if features == 2 else gathered).view(levels * n, 8, features)
        weights = corner_weights(frac).to(table.dtype)
        out = torch.bmm(weights.view(levels * n, 1, 8), feats).view(levels, n, features)
        ctx.table_shape = table.shape
        ctx.save_for_backward(flat_idx, weights, frac, scalings, feats if ctx.needs_input_grad[0] else None)
        return out.transpose(0, 1).reshape(n, levels * features)

    @staticmethod
    def backward(ctx, grad_out: Tensor):  # type: ignore[override]
        flat_idx, weights, frac, scalings, feats = ctx.saved_tensors
        levels, n, _ = weights.shape
        features = ctx.table_shape[1]
        grad_levels = grad_out.reshape(n, levels, features).transpose(0, 1).contiguous()  # [L, N, F]
        grad_table: Tensor | None = None
        if ctx.needs_input_grad[1]:
            grad_table = grad_out.new_zeros(ctx.table_shape)
            if features == 2:  # complex product: a real weight times a 2-feature gradient
                per_corner = weights * torch.view_as_complex(grad_levels)[:, :, None]
                _rows(grad_table).scatter_add_(0, flat_idx, per_corner.view(-1))
            else:
                per_corner = weights[..., None] * grad_levels[:, :, None, :]
                grad_table.index_add_(0, flat_idx, per_corner.view(-1, features))
        grad_pos: Tensor | None = None
        if ctx.needs_input_grad[0]:
            dots = torch.bmm(feats, grad_levels.view(levels * n, features, 1)).view(levels, n, 8)
            grad_pos = _position_gradient(dots, frac, scalings)
        return grad_pos, grad_table, None, None


ENV_IMPL = "NERFIFY_HASHGRID_IMPL"
IMPLS = ("auto", "torch", "cpp")


def _use_cpp(positions: Tensor, table: Tensor) -> bool:
    """Whether :func:`hash_encode` runs the C++ kernel, per ``NERFIFY_HASHGRID_IMPL`` and the tensors."""
    impl = os.environ.get(ENV_IMPL, "auto").strip().lower() or "auto"
    if impl not in IMPLS:
        raise ValueError(f"{ENV_IMPL}={impl!r}: expected one of {', '.join(IMPLS)}")
    if impl == "torch":
        return False
    eligible = (positions.device.type == "cpu" and table.device.type == "cpu"
                and positions.dtype == table.dtype and positions.dtype in (torch.float32, torch.float64))
    if impl == "auto":
        return eligible and hashgrid_ext.load() is not None
    if not eligible:
        raise RuntimeError(f"{ENV_IMPL}=cpp: the C++ hash-grid kernel takes CPU float32/float64 tensors "
                           f"of one dtype, got positions {positions.dtype} on {positions.device}, "
                           f"table {table.dtype} on {table.device}")
    hashgrid_ext.require()  # RuntimeError saying how to build when it is not available
    return True


class _Recorded:
    """One no-gradient encoding inside :func:`recording_encodings`: its positions, its output, the table
    (and the table's version: an in-place update invalidates it) and, once the alpha test has run, the
    rows the field will evaluate."""

    __slots__ = ("positions", "out", "table", "version", "rows")

    def __init__(self, positions: Tensor, out: Tensor, table: Tensor) -> None:
        self.positions, self.out, self.table, self.version = positions, out, table, table._version
        self.rows: Tensor | None = None


_recording = threading.local()


def _records() -> dict[int, _Recorded]:
    if not hasattr(_recording, "records"):
        _recording.records, _recording.active = {}, False
    return _recording.records


@contextlib.contextmanager
def recording_encodings():
    """Within this context each no-gradient C++ encoding is recorded (the latest per table; earlier
    records are dropped on entry), so the next differentiable encoding of a subset of those positions
    with the same, unchanged table takes the recorded values instead of recomputing them (Instant-NGP:
    nerfacc's alpha test evaluates every marched sample's density, then the field evaluates the
    surviving ones again with gradients)."""
    _records().clear()
    _recording.active = True
    try:
        yield
    finally:
        _recording.active = False


def keep_recorded_rows(mask: Tensor) -> None:
    """The alpha test's boolean mask over the recorded positions: the rows a later pass will ask for."""
    for record in _records().values():
        if record.rows is None and mask.dim() == 1 and mask.shape[0] == record.positions.shape[0]:
            record.rows = mask.nonzero().squeeze(1)


def _reusable(flat: Tensor, table: Tensor) -> _Recorded | None:
    """The record (removed from the cache) whose kept rows are bitwise ``flat`` with ``table`` unchanged."""
    records = _records()
    record = records.pop(id(table), None) if records else None
    if record is None or record.table is not table or record.version != table._version or record.rows is None:
        return None
    if record.rows.shape[0] != flat.shape[0] or flat.dtype != record.positions.dtype:
        return None
    return record if torch.equal(record.positions.index_select(0, record.rows), flat) else None


def hash_encode(positions: Tensor, table: Tensor, scalings: Tensor, table_size: int) -> Tensor:
    """Encode ``positions`` ``[..., 3]`` with the hash ``table`` ``[L * T, F]`` -> ``[..., L * F]``.

    Inside :func:`recording_encodings` a no-gradient C++ encoding is recorded; a differentiable one whose
    positions are bitwise the kept rows of a record (same table, not updated since) returns those rows'
    recorded values, with the same backward (:class:`~nerfify_ns.runtime.hashgrid_ext.HashGridReusedFunction`).
    """
    levels = scalings.shape[0]
    flat = positions.reshape(-1, 3)
    if _use_cpp(flat, table):
        flat = flat.contiguous()
        scalings = scalings.to(positions)
        record = _reusable(flat, table) if torch.is_grad_enabled() else None
        if record is not None:
            out = hashgrid_ext.HashGridReusedFunction.apply(flat, table, scalings, table_size, record.out, record.rows)
        else:
            out = hashgrid_ext.HashGridCppFunction.apply(flat, table, scalings, table_size)
            if getattr(_recording, "active", False) and not torch.is_grad_enabled():
                _records()[id(table)] = _Recorded(flat, out, table)
    else:
        out = HashGridFunction.apply(flat, table, scalings.to(positions), table_size)
    return out.reshape(*positions.shape[:-1], levels * table.shape[1])


def fast_pytorch_fwd(self, in_tensor: Tensor) -> Tensor:
    """Drop-in body for ``nerfstudio.field_components.encodings.HashEncoding.pytorch_fwd``."""
    assert in_tensor.shape[-1] == 3
    return hash_encode(in_tensor, self.hash_table, self.scalings.to(in_tensor.device), self.hash_table_size)
