"""Pure-torch replacements for nerfacc 0.5.2's CUDA extension (``nerfacc.cuda._C``).

Why
---
nerfacc's Python API reaches its CUDA kernels through ``nerfacc/cuda/__init__.py``, whose lazy
functions run ``from ._backend import _C`` on every call.  On a machine without CUDA, importing
``nerfacc.cuda._backend`` spends minutes on a JIT build (``torch.utils.cpp_extension.load``)
and then fails, so Nerfstudio's ``instant-ngp`` / ``instant-ngp-bounded`` cannot train on a CPU.

What
----
:func:`install` registers a module named ``nerfacc.cuda._backend`` in ``sys.modules`` whose
``_C`` attribute is :data:`backend`: a module object with the same attribute names as the
compiled extension, implemented with vectorised torch ops (no Python loop over rays).  Because
the real ``_backend`` is never imported, no JIT build is ever attempted.  It also patches two
nerfacc *Python* functions whose CPU path is broken (see :func:`install`).

Only the ops Nerfstudio 1.1.5 reaches (``instant-ngp``, ``instant-ngp-bounded``, training and
evaluation) are served (:data:`OPS`): ``ray_aabb_intersect``, ``traverse_grids``
(``OccGridEstimator.sampling``), ``exclusive_sum`` forward and backward
(``render_visibility_from_density`` / ``render_weight_from_density``) and the Python ``pack_info``
(patched).  ``accumulate_along_rays`` and ``OccGridEstimator.update_every_n_steps`` are plain torch
already.  Any other ``_C`` op (products, ``searchsorted``, ``importance_sampling``, the lens
undistortions) raises an ``AttributeError`` that says so.

``traverse_grids`` (the hot op) is served three ways, all vectorised over rays:

* constant step (``cone_angle == 0``, e.g. ``instant-ngp-bounded``): every position the kernel
  visits lies on the lattice ``near + k * step``, so all candidate steps inside the ray's AABB
  segments are enumerated at once (dense ``[segments, steps]`` blocks, chunked to bound memory),
  their midpoint cells looked up in the binary grid, and the occupied ones compacted;
* ``cone_angle > 0`` (``instant-ngp``): the lattice is exact while ``t * cone_angle <= step``; from
  there on the kernel's state machine (emit, or skip an empty cell with a fixed ``dt``) is run as
  one event per ray and iteration, single-threaded (many tiny ops);
* ``step_size <= 0``: one sample per occupied cell, cells delimited by plane crossings.

Semantics follow ``nerfacc/cuda/csrc/*.cu`` of nerfacc 0.5.2 (whose ``traverse_grids`` takes
``t_mins, t_maxs, hits`` and has no ``traverse_steps_limit`` / ``over_allocate`` arguments; those
belong to later nerfacc versions).  Known, documented differences are listed in
:data:`KNOWN_DIFFERENCES`.

All functions accept CPU (or CUDA, when force-installed) tensors of any floating dtype; the
CUDA kernels accept float32 only.
"""

from __future__ import annotations

import sys
import threading
import types
from collections.abc import Sequence

import torch
from torch import Tensor

__all__ = [
    "install",
    "uninstall",
    "is_installed",
    "backend",
    "KNOWN_DIFFERENCES",
    "RaySegmentsSpec",
    "OPS",
]

#: Differences from the CUDA kernels that are deliberate or unavoidable.
KNOWN_DIFFERENCES = (
    "traverse_grids: sample positions are computed in closed form (t_k = near + k*dt) instead of by "
    "repeated float32 additions, and cells are found by point lookup at the sample midpoint instead of "
    "a 3D-DDA, so results agree up to float rounding (a sample whose midpoint lies within ~1e-6 of a "
    "cell face may fall on the other side).",
    "traverse_grids: a run of adjacent samples is split into two intervals (a duplicated edge) by the "
    "CUDA kernel when its DDA crosses an empty cell that contains no sample midpoint (a corner cell); "
    "here such runs stay one interval.  The (start, end) pairs of all samples are identical.",
    "traverse_grids: levels are assigned per segment exactly like the kernel (sorted AABB hits); for "
    "non-nested AABBs the kernel may march through the gap between two boxes without re-marching, "
    "here samples whose midpoint is in a gap are never produced.  Segments with non-finite ends "
    "(e.g. rays with a zero direction and an infinite far plane) are dropped instead of looping.",
    "traverse_grids with step_size <= 0: zero-length DDA cells (ties between two axes) are dropped; "
    "like the kernel (whose DDA starts at tmin + 1e-6 and ends at tmax - 1e-6) plane crossings within "
    "1e-6 of a segment end open no cell.",
)

# Upper bound on the number of candidate samples materialised at once in traverse_grids.
_CANDIDATE_CHUNK = 1 << 22


# --------------------------------------------------------------------------------------------
# Data specs (mirror the pybind classes of nerfacc.cpp)
# --------------------------------------------------------------------------------------------
class RaySegmentsSpec:
    """Replacement for ``_C.RaySegmentsSpec``: batched ``vals`` [..., n_edges] or flattened ``vals``
    [n_edges] with ``chunk_starts``/``chunk_cnts`` [n_rays], ``ray_indices`` [n_edges] and the
    ``is_left``/``is_right`` edge masks.  Undefined fields are ``None`` (as pybind returns them)."""

    __slots__ = ("vals", "chunk_starts", "chunk_cnts", "ray_indices", "is_left", "is_right")

    def __init__(self) -> None:
        self.vals: Tensor | None = None
        self.chunk_starts: Tensor | None = None
        self.chunk_cnts: Tensor | None = None
        self.ray_indices: Tensor | None = None
        self.is_left: Tensor | None = None
        self.is_right: Tensor | None = None

    def __repr__(self) -> str:  # pragma: no cover - debugging aid
        fields = {
            k: (None if getattr(self, k) is None else tuple(getattr(self, k).shape)) for k in self.__slots__
        }
        return f"RaySegmentsSpec({fields})"


def is_cub_available() -> bool:
    """Replaces ``_C.is_cub_available``: there is no CUB on the CPU, so this is always ``False``."""
    return False


# --------------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------------
class _single_thread:
    """Run a loop of many small torch ops on one intra-op thread (restored afterwards).

    The sequential cone march issues thousands of ops on a few thousand elements; splitting them
    over OpenMP threads gains nothing, and when the other cores are busy (or have to be woken up,
    as on small VMs) each op's barrier can stall for milliseconds.
    """

    def __enter__(self):
        self.prev = torch.get_num_threads()
        if self.prev != 1:
            torch.set_num_threads(1)
        return self

    def __exit__(self, *exc):
        if self.prev != 1:
            torch.set_num_threads(self.prev)
        return False


def _arange(n: int, device: torch.device) -> Tensor:
    """``torch.arange(n)`` as int64 on ``device``."""
    return torch.arange(n, device=device, dtype=torch.long)


def _starts_from_cnts(cnts: Tensor) -> Tensor:
    """Exclusive prefix sum of counts (``chunk_starts`` of a packed layout)."""
    return torch.cumsum(cnts, 0) - cnts


def _segment_of_items(cnts: Tensor, total: int) -> Tensor:
    """Segment id of every item of a packed layout with per-segment counts ``cnts``."""
    return torch.repeat_interleave(_arange(cnts.numel(), cnts.device), cnts, output_size=total)


class _Layout:
    """Gather plan for scanning chunks ``[start, start + cnt)`` of a flattened tensor.

    ``idx`` maps positions of the packed (gathered) layout back to the input; it is ``None`` when the
    chunks already tile the input contiguously in order (the usual ``pack_info`` layout).  ``offs``
    and ``cnts`` describe the chunks in the packed layout; ``seg`` (chunk id per packed item),
    ``first`` and ``last`` (packed position of the item's chunk's first / last item) are computed
    on demand.
    """

    def __init__(self, chunk_starts: Tensor, chunk_cnts: Tensor, n_items: int) -> None:
        device = chunk_cnts.device
        self.cnts = chunk_cnts.long().clamp_min(0)
        starts = chunk_starts.long()
        self.total = int(self.cnts.sum().item()) if self.cnts.numel() else 0
        self.offs = _starts_from_cnts(self.cnts)
        if self.total == n_items and bool(torch.equal(starts, self.offs)):
            self.idx: Tensor | None = None
        else:
            shift = torch.repeat_interleave(starts - self.offs, self.cnts, output_size=self.total)
            self.idx = shift + _arange(self.total, device)
        self._seg: Tensor | None = None

    @property
    def seg(self) -> Tensor:
        if self._seg is None:
            self._seg = _segment_of_items(self.cnts, self.total)
        return self._seg

    def expand(self, per_chunk: Tensor) -> Tensor:
        """Per-chunk values repeated for every item of the chunk."""
        return per_chunk.index_select(0, self.seg)

    @property
    def first(self) -> Tensor:
        return self.expand(self.offs)

    @property
    def last(self) -> Tensor:
        return self.expand(self.offs + self.cnts - 1)

    def gather(self, x: Tensor) -> Tensor:
        return x if self.idx is None else x[self.idx]

    def scatter(self, packed: Tensor, like: Tensor) -> Tensor:
        if self.idx is None:
            return packed
        out = torch.zeros_like(like)
        out[self.idx] = packed
        return out


def _doubling_scan(x: Tensor, first: Tensor, op) -> Tensor:
    """Segmented inclusive scan by recursive doubling (Hillis-Steele).

    ``y_i = x_first(i) (op) ... (op) x_i``: after round r every item holds the combination of the
    last 2^r items of its segment.  log2(max segment length) rounds; keeps infinities and NaNs
    inside their own segment.
    """
    n = x.numel()
    y = x.clone()
    if n == 0:
        return y
    pos = _arange(n, x.device)
    d = 1
    max_len = int((pos - first).max().item()) + 1
    while d < max_len:
        src = pos - d
        ok = src >= first
        shifted = y[src.clamp_min(0)]
        y = torch.where(ok, op(y, shifted), y)
        d *= 2
    return y


class _Lazy:
    """A tensor computed on first use (``.get()``)."""

    def __init__(self, fn, dtype=None) -> None:
        self.fn, self.dtype, self.value = fn, dtype, None

    def get(self) -> Tensor:
        if self.value is None:
            v = self.fn() if callable(self.fn) else self.fn
            self.value = v if self.dtype is None else v.to(self.dtype)
        return self.value


def _segmented_sum(x: Tensor, lay: _Layout, reverse: bool) -> tuple[Tensor, Tensor]:
    """Exclusive segmented sum of packed ``x``, forward or reverse.

    Returns ``(scan, total)`` where ``total`` (a :class:`_Lazy`, computed only when asked for) is
    the per-item chunk total used by ``normalize``.
    Fast path: with ``P_i = sum_{j<i} x_j`` (one global cumsum in float64) and a chunk ``[s, e)``:
    forward ``P_i - P_s``, reverse ``P_e - P_{i+1}`` (exact to float32 rounding for finite inputs).  When the input
    holds inf/NaN the global prefix would leak across chunks (detected from the last prefix), so
    the per-chunk doubling scan is used instead.
    """
    n = x.numel()
    if n == 0:
        return x.clone(), _Lazy(x.clone())
    acc = x.double() if x.dtype != torch.float64 else x
    P = torch.zeros(n + 1, dtype=torch.float64, device=x.device)
    torch.cumsum(acc, 0, out=P[1:])
    if bool(torch.isfinite(P[-1])):
        if not reverse:
            base = lay.expand(P.index_select(0, lay.offs))
            out = P[:-1] - base
            total = lambda: lay.expand(P.index_select(0, lay.offs + lay.cnts)) - base  # noqa: E731
        else:
            end = lay.expand(P.index_select(0, lay.offs + lay.cnts))
            out = end - P[1:]
            total = lambda: end - lay.expand(P.index_select(0, lay.offs))  # noqa: E731
        return out.to(x.dtype), _Lazy(total, x.dtype)
    # robust path (non-finite values present)
    if not reverse:
        first = lay.first
        incl = _doubling_scan(x, first, torch.add)
        total = _Lazy(incl[lay.last])
        pos = _arange(n, x.device)
        excl = torch.where(pos > first, incl[(pos - 1).clamp_min(0)], torch.zeros_like(x))
        return excl, total
    # reverse scan = forward scan of the reversed array, whose segments start at the old ends
    pos = _arange(n, x.device)
    rfirst = (n - 1 - lay.last).flip(0)
    rx = x.flip(0)
    rincl = _doubling_scan(rx, rfirst, torch.add)
    total = _Lazy(rincl[(n - 1 - lay.first).flip(0)].flip(0))
    rexcl = torch.where(pos > rfirst, rincl[(pos - 1).clamp_min(0)], torch.zeros_like(x))
    return rexcl.flip(0), total


# --------------------------------------------------------------------------------------------
# Scans (scan.cu)
# --------------------------------------------------------------------------------------------
@torch.no_grad()
def exclusive_sum(
    chunk_starts: Tensor, chunk_cnts: Tensor, inputs: Tensor, normalize: bool = False, backward: bool = False
) -> Tensor:
    """Replaces ``_C.exclusive_sum``.

    Forward: ``y_i = sum_{j=s..i-1} x_j`` (0 at the chunk start).  Backward:
    ``g_i = sum_{j=i+1..e} dy_j`` (reverse exclusive scan).  ``normalize`` divides by
    ``max(chunk total, 1e-10)`` where the total includes the last item, as in the kernel.
    """
    lay = _Layout(chunk_starts, chunk_cnts, inputs.numel())
    x = lay.gather(inputs.reshape(-1))
    out, total = _segmented_sum(x, lay, reverse=bool(backward))
    if normalize:
        out = out / total.get().clamp_min(1e-10)
    return lay.scatter(out, inputs.reshape(-1)).view_as(inputs)


# --------------------------------------------------------------------------------------------
# Ray / AABB (grid.cu, utils_grid.cuh)
# --------------------------------------------------------------------------------------------
@torch.no_grad()
def ray_aabb_intersect(
    rays_o: Tensor,
    rays_d: Tensor,
    aabbs: Tensor,
    near_plane: float = -float("inf"),
    far_plane: float = float("inf"),
    miss_value: float = float("inf"),
) -> list[Tensor]:
    """Replaces ``_C.ray_aabb_intersect``: slab test for every (ray, box) pair.

    Per axis ``t0 = (min - o) / d``, ``t1 = (max - o) / d`` (swapped when ``1/d < 0``).  The axes are
    folded in order x, y, z exactly like ``device::ray_aabb_intersect``: the pair misses when
    ``tmin > tmax_axis or tmin_axis > tmax``; otherwise ``tmin = max``, ``tmax = min``.  A hit also
    needs ``tmax > 0``; hits are then clamped, ``tmin = fmax(tmin, near)``, ``tmax = fmin(tmax, far)``
    (no re-check that ``tmin < tmax``, like the kernel).  Misses get ``miss_value``.

    Returns ``[t_mins, t_maxs, hits]`` of shape ``[n_rays, n_aabbs]``.
    """
    o = rays_o[:, None, :]
    inv = 1.0 / rays_d[:, None, :]
    lo = aabbs[None, :, :3].to(rays_o.dtype)
    hi = aabbs[None, :, 3:].to(rays_o.dtype)
    ta = (lo - o) * inv
    tb = (hi - o) * inv
    pos = inv >= 0
    t0 = torch.where(pos, ta, tb)
    t1 = torch.where(pos, tb, ta)
    tmin = t0[..., 0]
    tmax = t1[..., 0]
    miss = torch.zeros_like(tmin, dtype=torch.bool)
    for ax in (1, 2):
        tmin_a = t0[..., ax]
        tmax_a = t1[..., ax]
        miss = miss | (tmin > tmax_a) | (tmin_a > tmax)
        tmin = torch.where(tmin_a > tmin, tmin_a, tmin)  # comparisons with NaN are False, as in C
        tmax = torch.where(tmax_a < tmax, tmax_a, tmax)
    hits = ~(miss | (tmax <= 0))
    tmin = torch.fmax(tmin, torch.full_like(tmin, near_plane))
    tmax = torch.fmin(tmax, torch.full_like(tmax, far_plane))
    miss_t = torch.full_like(tmin, miss_value)
    return [torch.where(hits, tmin, miss_t), torch.where(hits, tmax, miss_t), hits]


# --------------------------------------------------------------------------------------------
# traverse_grids (grid.cu)
# --------------------------------------------------------------------------------------------
def _segments(t_mins, t_maxs, hits, near_planes, far_planes, n_grids):
    """Per-ray traversal segments exactly as the kernel forms them.

    The ``2 * n_grids`` hit times are sorted (only when ``n_grids > 1``, like the kernel); segment
    ``i`` is ``[t_sorted[i], t_sorted[i+1]]``.  Its level is the grid entered at ``i``, or, when ``i``
    leaves a grid, the grid left next (skipped when the next event enters a grid).  The grid must
    be hit, and the segment is clipped to ``[near, far]`` and dropped when empty.

    Returns ``(a, b, level, valid)``, each ``[n_rays, 2 * n_grids - 1]``.
    """
    n_rays = t_mins.shape[0]
    cat = torch.cat([t_mins, t_maxs], -1)
    if n_grids > 1:
        t_sorted, t_indices = torch.sort(cat, dim=-1, stable=True)
    else:
        t_sorted = cat
        t_indices = _arange(2 * n_grids, cat.device).expand(n_rays, 2 * n_grids)
    idx_i = t_indices[:, :-1]
    idx_n = t_indices[:, 1:]
    entering = idx_i < n_grids
    next_entering = idx_n < n_grids
    lvl_i = idx_i % n_grids
    lvl_n = idx_n % n_grids
    hit_i = hits.gather(1, lvl_i)
    hit_n = hits.gather(1, lvl_n)
    valid = hit_i & (entering | (~next_entering & hit_n))
    level = torch.where(entering, lvl_i, lvl_n)
    a = torch.fmax(t_sorted[:, :-1], near_planes[:, None].expand(-1, 2 * n_grids - 1))
    b = torch.fmin(t_sorted[:, 1:], far_planes[:, None].expand(-1, 2 * n_grids - 1))
    valid = valid & (a < b) & torch.isfinite(a) & torch.isfinite(b)
    return a, b, level, valid


class _Emitted:
    """Emitted samples of one traversal: ray id, start, end, and whether the sample continues the
    previous one of its ray (``continuous`` in the kernel: the two share an interval edge)."""

    def __init__(self, ray: Tensor, t0: Tensor, t1: Tensor, cont: Tensor) -> None:
        self.ray, self.t0, self.t1, self.cont = ray, t0, t1, cont

    @staticmethod
    def cat(parts: Sequence[_Emitted], device, dtype) -> _Emitted:
        if not parts:
            e = torch.empty(0, dtype=dtype, device=device)
            return _Emitted(torch.empty(0, dtype=torch.long, device=device), e, e.clone(),
                            torch.empty(0, dtype=torch.bool, device=device))
        if len(parts) == 1:
            return parts[0]
        return _Emitted(
            torch.cat([p.ray for p in parts]),
            torch.cat([p.t0 for p in parts]),
            torch.cat([p.t1 for p in parts]),
            torch.cat([p.cont for p in parts]),
        )


def _cell_index(points_unit: Tensor, res: Tensor) -> Tensor:
    """``int(u * res)`` clamped to ``[0, res - 1]`` per axis (``make_int3`` truncates)."""
    return torch.minimum(points_unit.long().clamp_min(0), res - 1)


def _march_lattice(
    o, d, near, a, b, level, valid, step, binaries_flat, aabbs, res, cells_per_lvl, k_stop=None
) -> _Emitted:
    """Marching with a constant step ``dt`` (``cone_angle == 0`` or ``t * cone_angle <= dt``).

    With a constant ``dt`` every ``t_last`` the kernel visits lies on the lattice
    ``t_k = near + k * dt`` (the skip loops and the initial march use the same ``dt``).  Sample ``k``
    is emitted iff its midpoint ``m_k = t_k + dt / 2`` lies in a segment ``[a, b)`` and the cell of
    that segment's grid containing ``o + m_k d`` is occupied.  For each segment the candidate ``k``
    are ``[K(a), K(b))`` with ``K(x) = max(0, ceil((x - near) / dt - 1/2))``: all candidates are
    enumerated in chunks, tested against the grid, and compacted.  The cell coordinate is affine in
    ``k`` per segment, ``u = U0 + V k``, so a candidate costs a few float ops.  ``k_stop`` (per ray,
    optional) keeps only ``k < k_stop``.  The result also carries ``kk`` (the lattice index).
    """
    device, dtype = o.device, o.dtype
    n_rays = o.shape[0]
    S = a.shape[1]
    seg_ray = _arange(n_rays, device)[:, None].expand(-1, S)[valid]
    sa = a[valid].double()
    sb = b[valid].double()
    slvl = level[valid]
    snear = near.double()[seg_ray]
    k_lo = torch.ceil((sa - snear) / step - 0.5).clamp_min(0)
    k_hi = torch.ceil((sb - snear) / step - 0.5).clamp_min(0)
    if k_stop is not None:
        k_hi = torch.minimum(k_hi, k_stop.double()[seg_ray])
    cnt = (k_hi - k_lo).clamp_min(0).long()
    if cnt.numel() == 0 or int(cnt.sum().item()) == 0:
        em = _Emitted.cat([], device, dtype)
        em.kk = torch.empty(0, dtype=torch.float64, device=device)
        return em
    # per-segment affine map from the candidate's rank j to the cell coordinate, u = U0 + V * j
    lo = aabbs[slvl, :3].double()
    hi = aabbs[slvl, 3:].double()
    resd = res.double()
    scale = resd / (hi - lo)
    so = o.double()[seg_ray]
    sd = d.double()[seg_ray]
    V = sd * (step * scale)
    U0 = (so - lo + sd * (snear + 0.5 * step)[:, None]) * scale + V * k_lo[:, None]
    # the kernel truncates u to int and clamps to [0, res-1]; clamping first then flooring is the
    # same and stays in float32, where cell ids (< 2^24) are exact
    fdt = torch.float64 if binaries_flat.numel() >= (1 << 24) else torch.float32
    strides = torch.tensor([float(res[1] * res[2]), float(res[2]), 1.0], dtype=fdt, device=device)
    res_list = [int(r) for r in res.tolist()]
    cubic = res_list[0] == res_list[1] == res_list[2]
    U0 = U0.to(fdt)
    V = V.to(fdt)
    lvl_base = (slvl * cells_per_lvl).to(fdt)
    occupancy = binaries_flat.view(torch.uint8)  # index_select on bytes beats bool indexing

    # Candidates are laid out densely, [segments, max count], on groups of segments sorted by
    # count (little padding, no per-candidate gathers, in-place float ops); kept samples are then
    # scattered back in (segment, k) order, which is the (ray, t) order.
    n_seg = cnt.numel()
    order = torch.sort(cnt).indices
    cnt_sorted = cnt[order]
    cnt_list = cnt_sorted.tolist()
    kept_seg, kept_j = [], []
    group = max(1, -(-n_seg // 8))  # >= 8 groups keep the padding small
    g0 = 0
    while g0 < n_seg:
        g1 = min(n_seg, g0 + group)
        cmax = cnt_list[g1 - 1]
        if (g1 - g0) * cmax > _CANDIDATE_CHUNK:
            g1 = g0 + max(1, _CANDIDATE_CHUNK // max(cmax, 1))
            cmax = cnt_list[g1 - 1]
        if cmax > 0:
            segs = order[g0:g1]
            j = torch.arange(cmax, dtype=fdt, device=device)
            u = torch.addcmul(U0[segs][:, None, :], V[segs][:, None, :], j[None, :, None])
            if cubic:
                u.clamp_(0, res_list[0] - 1)
            else:
                for ax in range(3):
                    u[..., ax].clamp_(0, res_list[ax] - 1)
            u.floor_()
            lin = torch.matmul(u, strides)
            lin.add_(lvl_base[segs][:, None])
            occ = occupancy.index_select(0, lin.view(-1).long()).view(lin.shape)
            gi, jj = torch.nonzero(occ, as_tuple=True)
            inside = jj < cnt_sorted[g0:g1][gi]  # drop the padding
            kept_seg.append(segs[gi[inside]])
            kept_j.append(jj[inside])
        g0 = g1
    seg_k = torch.cat(kept_seg)
    jj = torch.cat(kept_j)
    n_out = seg_k.numel()
    if n_out == 0:
        em = _Emitted.cat([], device, dtype)
        em.kk = torch.empty(0, dtype=torch.float64, device=device)
        return em
    # counting sort by segment; within a segment the candidates are already in k order
    per_seg = torch.bincount(seg_k, minlength=n_seg)
    out_start = torch.cumsum(per_seg, 0) - per_seg
    first_in_run = torch.ones(n_out, dtype=torch.bool, device=device)
    first_in_run[1:] = seg_k[1:] != seg_k[:-1]
    run_start = torch.where(first_in_run, _arange(n_out, device), torch.zeros_like(seg_k))
    run_start = torch.cummax(run_start, 0).values
    pos = out_start[seg_k] + (_arange(n_out, device) - run_start)
    seg_sorted = torch.empty_like(seg_k)
    seg_sorted[pos] = seg_k
    j_sorted = torch.empty_like(jj)
    j_sorted[pos] = jj
    kk = k_lo[seg_sorted] + j_sorted.double()
    ray = seg_ray[seg_sorted]
    nr = near.double()[ray]
    t0 = (nr + kk * step).to(dtype)
    t1 = (nr + (kk + 1.0) * step).to(dtype)
    cont = torch.zeros_like(ray, dtype=torch.bool)
    if n_out > 1:
        cont[1:] = (ray[1:] == ray[:-1]) & (kk[1:] == kk[:-1] + 1)
    em = _Emitted(ray, t0, t1, cont)
    em.kk = kk
    return em


def _march_cone(
    o, d, t_start, last_emit, a, b, level, valid, step, cone, binaries_flat, aabbs, res, cells_per_lvl
) -> _Emitted:
    """Marching with ``dt = clamp(t * cone_angle, step, 1e10)`` (sequential in t, vectorised over rays).

    Reproduces the kernel's state machine from ``t = t_start`` with one event per ray and iteration:
    ``dt = calc_dt(t)``, ``m = t + dt / 2``; if ``m`` lies in a segment and its cell is occupied the
    sample ``[t, t + dt]`` is emitted and ``t += dt``; otherwise (an empty cell, or the gap before
    the next segment) the kernel's skip loop ``while (t + dt/2 < exit) t += dt`` with that fixed
    ``dt`` is done in closed form, ``t += max(1, ceil((exit - m) / dt)) * dt``, where ``exit`` is the
    time the ray leaves the cell (slab test against the cell, clipped to the segment end) or the
    start of the next segment.  A ray stops once ``m`` is past its last segment.  ``last_emit`` says
    whether the sample just before ``t_start`` was emitted (then the next sample is continuous).
    """
    device, dtype = o.device, o.dtype
    n_rays, S = a.shape
    nseg = valid.sum(1)
    rows = torch.nonzero(nseg > 0).squeeze(1)
    if rows.numel() == 0:
        return _Emitted.cat([], device, dtype)
    # per (ray, segment) table row: a, b, cell-id base, unit-space origin (3) and direction (3),
    # then (3 + 3) for the cell exit time t_ax = cell * inv + c0 with inv = 1 / direction and
    # c0 = ((dir > 0) - origin) * inv (c0 = +inf, inv = 0 where the direction is 0).  Valid
    # segments are moved to the front of each ray (they are in t order) and one +inf row ends it.
    order = torch.sort((~valid).to(torch.int8), dim=1, stable=True).indices
    va = valid.gather(1, order)[rows]
    sa = a.gather(1, order)[rows]
    sb = b.gather(1, order)[rows]
    sl = level.gather(1, order)[rows]
    inf = float("inf")
    sa = torch.where(va, sa, torch.full_like(sa, inf))
    sb = torch.where(va, sb, torch.full_like(sb, inf))
    lo = aabbs[:, :3].to(dtype)[sl]
    hi = aabbs[:, 3:].to(dtype)[sl]
    resf = res.to(dtype)
    scale = resf / (hi - lo)
    ro, rd = o[rows], d[rows]
    ou = (ro[:, None, :] - lo) * scale
    du = rd[:, None, :] * scale
    zero_dir = du == 0
    inv = torch.where(zero_dir, torch.zeros_like(du), 1.0 / torch.where(zero_dir, torch.ones_like(du), du))
    c0 = torch.where(zero_dir, torch.full_like(du, inf), ((du > 0).to(dtype) - ou) * inv)
    base = (sl * cells_per_lvl).to(dtype)
    table = torch.cat([sa[..., None], sb[..., None], base[..., None], ou, du, inv, c0], -1)
    pad = torch.zeros_like(table[:, :1])
    pad[..., 0:2] = inf
    n_rows = table.shape[1] + 1
    table = torch.cat([table, pad], 1).reshape(-1, table.shape[2])  # [n * (S + 1), 15]
    sb = torch.cat([sb, torch.full_like(sb[:, :1], inf)], 1)
    fdt = dtype if (binaries_flat.numel() < (1 << 24) or dtype == torch.float64) else torch.float64
    strides = torch.tensor([float(res[1] * res[2]), float(res[2]), 1.0], dtype=fdt, device=device)
    zero3 = torch.zeros(3, dtype=dtype, device=device)
    umax = resf - 1

    ids = rows
    row_base = _arange(rows.numel(), device) * n_rows
    nseg_a = nseg[rows]
    t = t_start[rows].to(dtype)
    last = last_emit[rows]
    rec_ids, rec_t, rec_dt, rec_occ, rec_last = [], [], [], [], []
    it = 0
    while True:
        dt = torch.clamp(t * cone, step, 1e10)
        m = torch.add(t, dt, alpha=0.5)
        j = (sb <= m[:, None]).sum(1)
        if it % 4 == 0:
            alive = j < nseg_a
            n_alive = int(alive.sum().item())
            if n_alive == 0:
                break
            if n_alive < 0.75 * ids.numel():
                keep = torch.nonzero(alive).squeeze(1)
                ids, t, last, sb, row_base = ids[keep], t[keep], last[keep], sb[keep], row_base[keep]
                nseg_a, dt, m, j = nseg_a[keep], dt[keep], m[keep], j[keep]
        it += 1
        row = table.index_select(0, row_base + j)
        # past its last segment a ray reads a row with a = +inf: never in a segment, never emits
        in_seg = row[:, 0] <= m
        u = torch.addcmul(row[:, 3:6], row[:, 6:9], m[:, None])
        cell = torch.clamp(u, zero3, umax).floor_()
        lin = torch.addmv(row[:, 2].to(fdt), cell.to(fdt), strides)
        occ = binaries_flat[lin.long()] & in_seg
        rec_ids.append(ids)
        rec_t.append(t)
        rec_dt.append(dt)
        rec_occ.append(occ)
        rec_last.append(last)
        # time the ray leaves this (empty) cell, or the start of the next segment when in a gap
        t_exit = torch.addcmul(row[:, 12:15], cell, row[:, 9:12]).amin(1)
        t_exit = torch.where(in_seg, torch.minimum(t_exit, row[:, 1]), row[:, 0])
        n_skip = torch.ceil((t_exit - m) / dt).clamp_(1, 1e30)
        t = torch.where(occ, t + dt, torch.where(in_seg | (j < nseg_a), torch.addcmul(t, n_skip, dt), t))
        last = occ
    if not rec_ids:
        return _Emitted.cat([], device, dtype)
    occ = torch.cat(rec_occ)
    k = torch.nonzero(occ).squeeze(1)
    ray = torch.cat(rec_ids)[k]
    t0 = torch.cat(rec_t)[k]
    t1 = t0 + torch.cat(rec_dt)[k]
    cont = torch.cat(rec_last)[k]
    order = torch.sort(ray, stable=True).indices  # iteration order is t order within a ray
    return _Emitted(ray[order], t0[order], t1[order], cont[order])


def _march_cells(o, d, a, b, level, valid, binaries_flat, aabbs, res, cells_per_lvl) -> _Emitted:
    """Marching with ``step_size <= 0``: one interval per occupied DDA cell.

    The cells along a segment are delimited by the segment ends and the times the ray crosses the
    grid planes ``x = min + i * voxel`` (per axis, ignoring crossings within the kernel's ``eps =
    1e-6`` of the segment ends); each occupied cell ``[t_i, t_{i+1}]`` is a sample.
    """
    device, dtype = o.device, o.dtype
    n_rays, S = a.shape
    seg_ray = _arange(n_rays, device)[:, None].expand(-1, S)[valid]
    if seg_ray.numel() == 0:
        return _Emitted.cat([], device, dtype)
    sa, sb, sl = a[valid], b[valid], level[valid]
    n_seg = sa.numel()
    so, sd = o[seg_ray], d[seg_ray]
    lo = aabbs[sl, :3].to(dtype)
    hi = aabbs[sl, 3:].to(dtype)
    vox = (hi - lo) / res.to(dtype)
    # plane indices strictly inside (a, b) per axis
    ua = (so + sd * sa[:, None] - lo) / vox
    ub = (so + sd * sb[:, None] - lo) / vox
    umin = torch.minimum(ua, ub)
    umax = torch.maximum(ua, ub)
    i_lo = (torch.floor(umin) + 1).clamp(0, None).long()
    i_hi = (torch.ceil(umax) - 1).long()
    i_hi = torch.minimum(i_hi, res[None, :].expand_as(i_hi))
    cnt = (i_hi - i_lo + 1).clamp_min(0)
    cnt = torch.where(sd == 0, torch.zeros_like(cnt), cnt)
    cnt_flat = cnt.reshape(-1)  # [n_seg * 3]
    total = int(cnt_flat.sum().item())
    pair = torch.repeat_interleave(_arange(n_seg * 3, device), cnt_flat, output_size=total)
    first_of_pair = torch.repeat_interleave(_starts_from_cnts(cnt_flat), cnt_flat, output_size=total)
    j = _arange(total, device) - first_of_pair
    ps, ax = pair // 3, pair % 3
    plane = lo[ps, ax] + (i_lo.reshape(-1)[pair] + j).to(dtype) * vox[ps, ax]
    t_cross = (plane - so[ps, ax]) / sd[ps, ax]
    # like the kernel, whose DDA starts in the cell at a + 1e-6 and ends in the cell at b - 1e-6,
    # plane crossings within 1e-6 of a segment end do not open a new cell
    inside = (t_cross > sa[ps] + 1e-6) & (t_cross < sb[ps] - 1e-6)
    ps, t_cross = ps[inside], t_cross[inside]
    seg_all = torch.cat([_arange(n_seg, device), _arange(n_seg, device), ps])
    t_all = torch.cat([sa, sb, t_cross])
    order = torch.sort(t_all, stable=True).indices
    order = order[torch.sort(seg_all[order], stable=True).indices]
    seg_all, t_all = seg_all[order], t_all[order]
    same = seg_all[1:] == seg_all[:-1]
    c0, c1, cseg = t_all[:-1][same], t_all[1:][same], seg_all[:-1][same]
    nonzero = c1 > c0
    c0, c1, cseg = c0[nonzero], c1[nonzero], cseg[nonzero]
    mid = (c0 + c1) * 0.5
    lvl = sl[cseg]
    p = so[cseg] + sd[cseg] * mid[:, None]
    u = (p - lo[cseg]) / (hi[cseg] - lo[cseg]) * res.to(dtype)
    cell = _cell_index(u, res)
    strides = torch.tensor([res[1] * res[2], res[2], 1], device=device, dtype=torch.long)
    occ = binaries_flat[(cell * strides).sum(1) + lvl * cells_per_lvl]
    ray_all = seg_ray[cseg]
    prev_occ = torch.zeros_like(occ)
    if occ.numel() > 1:
        prev_occ[1:] = occ[:-1] & (ray_all[1:] == ray_all[:-1])
    k = torch.nonzero(occ).squeeze(1)
    return _Emitted(ray_all[k], c0[k], c1[k], prev_occ[k])


def _pack_outputs(em: _Emitted, n_rays: int, compute_intervals: bool, compute_samples: bool, device, dtype):
    """Write the emitted samples as the kernel's two RaySegmentsSpec (intervals, samples).

    A sample that does not continue the previous one opens a run: it contributes its left edge
    (``is_left``) and its right edge; a continuing sample contributes only its right edge, and the
    right edge before it is then also a left edge.  So sample ``i`` gives the edges
    ``[t0_i (if it opens a run), t1_i]`` with ``is_left(t1_i) = cont_{i+1}``.
    """
    intervals, samples = RaySegmentsSpec(), RaySegmentsSpec()
    n = em.ray.numel()
    ray = em.ray.long()
    if n:
        n_per_ray = torch.bincount(ray, minlength=n_rays)
    else:
        n_per_ray = torch.zeros(n_rays, dtype=torch.long, device=device)
    if compute_samples:
        samples.chunk_cnts = n_per_ray
        samples.chunk_starts = _starts_from_cnts(n_per_ray)
        samples.vals = ((em.t1 + em.t0) * 0.5).to(dtype)
        samples.ray_indices = ray
    if compute_intervals:
        opens = ~em.cont
        next_cont = torch.zeros_like(em.cont)
        next_cont[:-1] = em.cont[1:]
        yes, no = torch.ones_like(opens), torch.zeros_like(opens)
        idx = torch.nonzero(torch.stack([opens, yes], 1).reshape(-1)).squeeze(1)

        def pick(first: Tensor, second: Tensor) -> Tensor:
            return torch.stack([first, second], 1).reshape(-1).index_select(0, idx)

        intervals.vals = pick(em.t0.to(dtype), em.t1.to(dtype))
        intervals.is_left = pick(yes, next_cont)
        intervals.is_right = pick(no, yes)
        intervals.ray_indices = idx // 2 if n == 0 else ray.index_select(0, idx // 2)
        runs = torch.bincount(ray[opens], minlength=n_rays) if n else torch.zeros_like(n_per_ray)
        intervals.chunk_cnts = n_per_ray + runs
        intervals.chunk_starts = _starts_from_cnts(intervals.chunk_cnts)
    return [intervals, samples]


@torch.no_grad()
def traverse_grids(
    rays_o: Tensor,
    rays_d: Tensor,
    binaries: Tensor,
    aabbs: Tensor,
    t_mins: Tensor,
    t_maxs: Tensor,
    hits: Tensor,
    near_planes: Tensor,
    far_planes: Tensor,
    step_size: float,
    cone_angle: float,
    compute_intervals: bool = True,
    compute_samples: bool = True,
) -> list[RaySegmentsSpec]:
    """Replaces ``_C.traverse_grids`` (nerfacc 0.5.2 signature): ray marching through multi-level
    binary occupancy grids.

    Each ray is split into segments by its sorted AABB hits (see :func:`_segments`); inside a
    segment the finest hit grid applies.  With ``step_size > 0`` the ray is marched from its near
    plane with ``dt = clamp(t * cone_angle, step_size, 1e10)``; a step ``[t, t + dt]`` becomes a
    sample iff its midpoint ``t + dt/2`` lies in a segment and in an occupied cell, and empty cells
    are skipped with the kernel's fixed-``dt`` skip loop.  With ``step_size <= 0`` every occupied
    cell crossed is one sample.  Adjacent samples share interval edges.

    Returns ``[intervals, samples]``: ``intervals`` holds the edges (``vals``, ``is_left``,
    ``is_right``, ``ray_indices``, ``chunk_starts``/``chunk_cnts``), ``samples`` the midpoints.
    """
    device = rays_o.device
    dtype = rays_o.dtype if rays_o.is_floating_point() else torch.float32
    n_rays = rays_o.shape[0]
    n_grids = binaries.shape[0]
    res = torch.tensor(list(binaries.shape[1:]), device=device, dtype=torch.long)
    cells_per_lvl = int(res.prod().item())
    binaries_flat = binaries.reshape(-1).bool()
    o, d = rays_o.to(dtype), rays_d.to(dtype)
    near = near_planes.to(dtype).reshape(-1)
    far = far_planes.to(dtype).reshape(-1)
    aabbs = aabbs.to(device)
    if n_rays == 0 or n_grids == 0:
        empty = _Emitted.cat([], device, dtype)
        return _pack_outputs(empty, n_rays, compute_intervals, compute_samples, device, dtype)
    a, b, level, valid = _segments(t_mins.to(dtype), t_maxs.to(dtype), hits.bool(), near, far, n_grids)
    step = float(step_size)
    cone = float(cone_angle)
    if step <= 0.0:
        em = _march_cells(o, d, a, b, level, valid, binaries_flat, aabbs, res, cells_per_lvl)
    else:
        if cone <= 0.0:
            em = _march_lattice(
                o, d, near, a, b, level, valid, step, binaries_flat, aabbs, res, cells_per_lvl
            )
        else:
            # dt == step_size while t * cone <= step_size, so every t visited up to k_h, the last
            # lattice index with near + k * step <= step / cone, lies on the lattice near + k * step
            # (a skip started there keeps dt == step).  The lattice march is exact for k < k_h and
            # the sequential march takes over at t_{k_h}, where calc_dt is still == step.
            t_star = step / cone
            near64 = near.double()
            k_h = torch.floor((t_star - near64) / step)
            k_h = torch.where(near64 <= t_star, k_h, torch.zeros_like(near64))
            t_end = torch.where(valid, b, torch.full_like(b, -float("inf"))).max(1).values
            k_end = torch.ceil((t_end.double() - near64) / step - 0.5).clamp_min(0)
            all_lattice = k_end <= k_h + 1  # dt never exceeds step along the ray
            k_stop = torch.where(all_lattice, torch.full_like(k_h, float("inf")), k_h)
            em_lat = _march_lattice(
                o, d, near, a, b, level, valid, step, binaries_flat, aabbs, res, cells_per_lvl, k_stop=k_stop
            )
            # rays needing the sequential march: did the lattice emit the sample right before k_star?
            seq = ~all_lattice
            last_emit = torch.zeros(n_rays, dtype=torch.bool, device=device)
            if em_lat.ray.numel():
                is_last = torch.ones_like(em_lat.ray, dtype=torch.bool)
                is_last[:-1] = em_lat.ray[1:] != em_lat.ray[:-1]
                lr, lk = em_lat.ray[is_last], em_lat.kk[is_last]
                last_emit[lr] = lk == (k_h[lr] - 1)
            t_start = (near64 + k_h * step).to(dtype)
            parts = [em_lat]
            if bool(seq.any()):
                v = valid & seq[:, None]
                with _single_thread():
                    parts.append(
                        _march_cone(o, d, t_start, last_emit & seq, a, b, level, v, step, cone,
                                    binaries_flat, aabbs, res, cells_per_lvl)
                    )
            em = _Emitted.cat(parts, device, dtype)
            if len(parts) > 1 and em.ray.numel():
                order = torch.sort(em.ray, stable=True).indices
                em = _Emitted(em.ray[order], em.t0[order], em.t1[order], em.cont[order])
    return _pack_outputs(em, n_rays, compute_intervals, compute_samples, device, dtype)


# --------------------------------------------------------------------------------------------
# The backend object and its installation
# --------------------------------------------------------------------------------------------
#: The ``_C`` attributes Nerfstudio 1.1.5 reaches (``instant-ngp`` and ``instant-ngp-bounded``, training
#: and evaluation; ``tests/runtime/test_nerfacc_cpu.py`` traces the calls), the only ones served.
OPS = ("is_cub_available", "RaySegmentsSpec", "ray_aabb_intersect", "traverse_grids", "exclusive_sum")


def _make_backend() -> types.ModuleType:
    """Build the ``_C`` stand-in module from the functions and classes above."""
    mod = types.ModuleType("nerfify_ns.runtime.nerfacc_cpu._C")
    mod.__doc__ = "Pure-torch stand-in for nerfacc's compiled extension (same attribute names as _C)."
    for name in OPS:
        setattr(mod, name, globals()[name])

    def __getattr__(name: str):  # PEP 562: only for names the module lacks
        if name.startswith("__"):
            raise AttributeError(name)
        raise AttributeError(f"nerfacc's CUDA op {name!r} has no CPU stand-in: Nerfstudio 1.1.5 never calls it "
                             f"(the CPU backend serves {', '.join(OPS)})")

    mod.__getattr__ = __getattr__
    return mod


#: The ``_C`` stand-in: a module with the compiled extension's attribute names.
backend = _make_backend()

_BACKEND_MODULE = "nerfacc.cuda._backend"
_lock = threading.RLock()
_state: dict = {"installed": False, "saved": {}}


@torch.no_grad()
def _pack_info_any_device(ray_indices: Tensor, n_rays: int | None = None) -> Tensor:
    """Replaces ``nerfacc.pack_info``, which raises ``NotImplementedError`` for CPU tensors.

    ``chunk_cnts[r] = #{i : ray_indices[i] == r}``, ``chunk_starts = cumsum(chunk_cnts) - chunk_cnts``;
    returns ``[n_rays, 2]`` of ``ray_indices``' dtype.  CUDA tensors go to the original function.
    """
    assert ray_indices.dim() == 1, "ray_indices must be a 1D tensor with shape (n_samples)."
    original = _state["saved"].get("pack_info")
    if ray_indices.is_cuda and original is not None:
        return original(ray_indices, n_rays)
    if n_rays is None:
        n_rays = int(ray_indices.max().item()) + 1 if ray_indices.numel() else 0
    cnts = torch.bincount(ray_indices.long(), minlength=n_rays)[:n_rays].to(ray_indices.dtype)
    starts = torch.cumsum(cnts, 0, dtype=ray_indices.dtype) - cnts
    return torch.stack([starts, cnts], -1)


def _ray_samples_to_cpp(self):
    """Replaces ``nerfacc.data_specs.RaySamples._to_cpp``, which reads a non-existent
    ``self.chunk_cnts`` attribute (AttributeError for every RaySamples, on any device)."""
    spec = backend.RaySegmentsSpec()
    spec.vals = self.vals.contiguous()
    if self.packed_info is not None:
        spec.chunk_starts = self.packed_info[:, 0].contiguous()
        spec.chunk_cnts = self.packed_info[:, 1].contiguous()
    if self.ray_indices is not None:
        spec.ray_indices = self.ray_indices.contiguous()
    return spec


def is_installed() -> bool:
    """Whether :func:`install` has put the torch backend in place of nerfacc's CUDA extension."""
    return bool(_state["installed"]) and getattr(sys.modules.get(_BACKEND_MODULE), "_C", None) is backend


def install(force: bool = False) -> bool:
    """Serve nerfacc's ``_C`` ops with the pure-torch :data:`backend`; never JIT-build nerfacc.

    Does nothing and returns ``False`` when ``torch.cuda.is_available()`` and not ``force`` (a GPU
    machine keeps the real CUDA backend).  Otherwise it

    * registers ``sys.modules["nerfacc.cuda._backend"]`` as a module whose ``_C`` is :data:`backend`
      (replacing a real one if it was imported already), so ``nerfacc.cuda``'s lazy functions never
      import the real ``_backend`` and no ``torch.utils.cpp_extension.load`` happens;
    * patches ``nerfacc.pack_info`` (also the names bound in ``nerfacc.pack`` and
      ``nerfacc.volrend``): it raises ``NotImplementedError`` for CPU tensors, and Nerfstudio's
      ``NGPModel.get_outputs`` and every ``ray_indices``-based volrend call use it;
    * patches ``RaySamples._to_cpp``, which is broken on every device (reads ``self.chunk_cnts``).

    Idempotent and thread-safe; returns ``True`` when installed.
    """
    with _lock:
        if _state["installed"] and is_installed():
            return True
        if torch.cuda.is_available() and not force:
            return False
        import nerfacc  # noqa: F401  (cheap: nerfacc imports its CUDA backend lazily)
        import nerfacc.cuda as nacc_cuda
        import nerfacc.data_specs as nacc_specs
        import nerfacc.pack as nacc_pack
        import nerfacc.volrend as nacc_volrend

        saved = _state["saved"]
        if not saved:
            saved["backend_module"] = sys.modules.get(_BACKEND_MODULE)
            saved["backend_attr"] = nacc_cuda.__dict__.get("_backend")
            saved["pack_info"] = nacc_pack.pack_info
            saved["nerfacc.pack_info"] = nerfacc.pack_info
            saved["volrend.pack_info"] = nacc_volrend.pack_info
            saved["RaySamples._to_cpp"] = nacc_specs.RaySamples.__dict__["_to_cpp"]

        fake = types.ModuleType(_BACKEND_MODULE)
        fake.__doc__ = "nerfify_ns.runtime.nerfacc_cpu: pure-torch stand-in for nerfacc's CUDA backend."
        fake.__file__ = __file__
        fake._C = backend
        fake.__all__ = ["_C"]
        sys.modules[_BACKEND_MODULE] = fake
        nacc_cuda._backend = fake

        nacc_pack.pack_info = _pack_info_any_device
        nerfacc.pack_info = _pack_info_any_device
        nacc_volrend.pack_info = _pack_info_any_device
        nacc_specs.RaySamples._to_cpp = _ray_samples_to_cpp
        _state["installed"] = True
        return True


def uninstall() -> bool:
    """Undo :func:`install` (restores the saved modules and functions).  Returns whether anything
    was undone.  Mainly for tests."""
    with _lock:
        if not _state["installed"]:
            return False
        import nerfacc
        import nerfacc.cuda as nacc_cuda
        import nerfacc.data_specs as nacc_specs
        import nerfacc.pack as nacc_pack
        import nerfacc.volrend as nacc_volrend

        saved = _state["saved"]
        if saved.get("backend_module") is None:
            sys.modules.pop(_BACKEND_MODULE, None)
        else:
            sys.modules[_BACKEND_MODULE] = saved["backend_module"]
        if saved.get("backend_attr") is None:
            nacc_cuda.__dict__.pop("_backend", None)
        else:
            nacc_cuda._backend = saved["backend_attr"]
        nacc_pack.pack_info = saved["pack_info"]
        nerfacc.pack_info = saved["nerfacc.pack_info"]
        nacc_volrend.pack_info = saved["volrend.pack_info"]
        nacc_specs.RaySamples._to_cpp = saved["RaySamples._to_cpp"]
        _state["installed"] = False
        _state["saved"] = {}
        return True
