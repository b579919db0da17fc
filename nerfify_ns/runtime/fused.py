"""CPU fast paths for where a Nerfstudio training step spends its time, each keeping stock results.

Profiles of ``nerfacto``, ``instant-ngp`` and ``vanilla-nerf`` steps on the CPU (see
``docs/performance.md``) put the time in: the optimiser (Adam's for-loop implementation over the
16.7M-entry hash tables), the L-inf norm of the scene contraction (``torch.linalg.norm(ord=inf)``
is ~100x slower than ``abs().amax()`` on ``[N, 3]``), the occupancy grid's updates over all
cells during its warm-up (8.4M points through the field at once, so every intermediate of the MLP
streams through memory), and denormal floats (which slow every op of a small field by up to 10x).
Each function below is one patch of :mod:`nerfify_ns.runtime` (applied only without CUDA) and is
tested against the stock implementation on random inputs, values and gradients:

* :func:`flush_denormals`       FTZ/DAZ in the calling thread and every ATen pool thread;
* :func:`fused_optimizer_setup` Nerfstudio's ``OptimizerConfig.setup`` with ``fused=True`` for the
                                optimisers that have a fused CPU kernel (Adam, AdamW: Kingma & Ba 2015,
                                Algorithm 1; Loshchilov & Hutter 2019 for the decoupled decay);
* :func:`contract`              Mip-NeRF 360's contraction (Barron et al. 2022, Eq. 10) with the L-inf
                                norm as ``abs().amax()``;
* :func:`make_chunked_occupancy_update` nerfacc's ``OccGridEstimator`` EMA update (Instant-NGP,
                                Mueller et al. 2022, Sec. 4: "occupancy grids") evaluating the density in
                                chunks of :data:`OCC_CHUNK` points: the density of a point depends on that
                                point only, so chunking changes no value, only how much memory each
                                intermediate takes;
* :func:`reuse_freed_memory`    glibc keeps freed blocks for the next allocation instead of unmapping
                                them (a step's large activations no longer fault in fresh pages);
* :func:`make_recording_sigma_fn` / :func:`make_visibility_recorder` the hash encodings of nerfacc's
                                alpha test (no gradients) are kept, and the field's differentiable pass
                                over the surviving samples reuses them when its positions are bitwise
                                those samples' (:func:`nerfify_ns.runtime.hashgrid.hash_encode`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable

import torch
from torch import Tensor

#: Points per density evaluation in the occupancy grid's update (a field's [chunk, 64] activations
#: stay in the L2 cache instead of streaming 2.1M x 64 floats through memory per level).
OCC_CHUNK = int(os.environ.get("NERFIFY_OCC_CHUNK", "65536"))

#: torch optimisers with a fused CPU kernel that computes the same update as their default
#: implementation (checked by tests/runtime/test_fused.py against the default on random gradients).
FUSED_CPU_OPTIMIZERS = (torch.optim.Adam, torch.optim.AdamW)


# ----------------------------------------------------------------------------- denormal floats
def flush_denormals() -> int:
    """Treat denormal floats as zero (FTZ and DAZ) in this thread and ATen's intra-op pool.

    A small field's activations and gradients decay into the denormal range (below 1.2e-38) early in
    training, where x86 takes microcode assists on every operation. ``torch.set_flush_denormal``
    alone sets only the calling thread; the pool's threads are set by the C++ extension when it is
    built. Returns the number of threads set (1 without the extension, 0 where unsupported).
    """
    if not torch.set_flush_denormal(True):
        return 0
    from nerfify_ns.runtime import hashgrid_ext

    module = hashgrid_ext.load()
    setter = getattr(module, "set_flush_denormal_all_threads", None)
    return int(setter(True)) if setter is not None else 1


# ----------------------------------------------------------------------------- fused optimiser
def _cpu_float_params(params: list) -> bool:
    """All tensors (plain or in param-group dicts) are floating-point CPU tensors."""
    tensors: list[Tensor] = []
    for item in params:
        if isinstance(item, dict):
            tensors.extend(item.get("params", []))
        else:
            tensors.append(item)
    return bool(tensors) and all(
        isinstance(t, Tensor) and t.device.type == "cpu" and t.is_floating_point() for t in tensors)


def fused_optimizer_setup(self, params) -> torch.optim.Optimizer:
    """``OptimizerConfig.setup`` (same keyword arguments) adding ``fused=True`` where it is exact.

    Only for :data:`FUSED_CPU_OPTIMIZERS`, CPU floating-point parameters, and a config that sets
    neither ``fused`` nor ``foreach`` itself; anything else is built exactly as Nerfstudio does.
    """
    kwargs = vars(self).copy()
    kwargs.pop("_target")
    kwargs.pop("max_norm", None)
    target = self._target
    params = list(params)
    if target in FUSED_CPU_OPTIMIZERS and "fused" not in kwargs and "foreach" not in kwargs \
            and _cpu_float_params(params):
        return target(params, fused=True, **kwargs)
    return target(params, **kwargs)


# ----------------------------------------------------------------------------- scene contraction
def contract(x: Tensor, order) -> Tensor:
    """Mip-NeRF 360's contraction, Eq. 10: ``x`` inside the unit ball, ``(2 - 1/|x|) x/|x|`` outside.

    Same expression as Nerfstudio's ``SceneContraction`` (values and gradients, ties of the L-inf norm
    included: both split the gradient evenly between equal maxima); the L-inf norm is computed as
    ``abs().amax()``, other norms with ``torch.linalg.vector_norm``.
    """
    if order is not None and math.isinf(order) and order > 0:
        mag = x.abs().amax(dim=-1, keepdim=True)
    else:
        mag = torch.linalg.norm(x, ord=order, dim=-1)[..., None]
    return torch.where(mag < 1, x, (2 - (1 / mag)) * (x / mag))


def make_contraction_forward(stock_forward: Callable) -> Callable:
    """A ``SceneContraction.forward`` that uses :func:`contract` for point tensors and the stock
    method for Gaussians (whose covariance needs the Jacobian path)."""

    def forward(self, positions):
        if isinstance(positions, Tensor):
            return contract(positions, self.order)
        return stock_forward(self, positions)

    forward._nerfify_stock = stock_forward  # type: ignore[attr-defined]
    return forward


# ----------------------------------------------------------------------------- occupancy grid
def chunked(fn: Callable[[Tensor], Tensor], chunk: int) -> Callable[[Tensor], Tensor]:
    """``fn`` applied to ``x`` in row chunks of ``chunk`` and concatenated (``fn`` must be pointwise)."""

    def apply(x: Tensor) -> Tensor:
        if x.shape[0] <= chunk:
            return fn(x)
        return torch.cat([fn(part) for part in x.split(chunk)], dim=0)

    return apply


def make_chunked_occupancy_update(stock_update: Callable) -> Callable:
    """An ``OccGridEstimator._update`` whose ``occ_eval_fn`` runs in chunks of :data:`OCC_CHUNK`."""

    def _update(self, step: int, occ_eval_fn: Callable, *args, **kwargs):
        return stock_update(self, step, chunked(occ_eval_fn, OCC_CHUNK), *args, **kwargs)

    _update._nerfify_stock = stock_update  # type: ignore[attr-defined]
    return _update



# ----------------------------------------------------------------------------- freed memory reuse
#: glibc ``mallopt`` parameters (malloc.h).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, M_MMAP_MAX = -1, -3, -4
#: Free memory glibc keeps at the top of the heap before returning it to the kernel.
KEEP_FREED_BYTES = 1 << 30


def _libc_mallopt() -> Callable[[int, int], int] | None:
    """glibc's ``mallopt`` (``None`` on other C libraries, where this patch does nothing)."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        fn = libc.mallopt
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return fn


def reuse_freed_memory(on: bool = True) -> bool:
    """Serve every allocation from the process heap and keep freed memory for the next one (glibc).

    glibc serves each block above 32 MB (its largest dynamic mmap threshold) with a fresh ``mmap``
    and returns it with ``munmap`` when freed, so every ``[262144, 64]`` activation of an
    Instant-NGP step (67 MB), and every temporary of that size in the backward, is first touched as
    new pages: the kernel zeroes each page at a page fault, and element-wise ops on it run at a
    fraction of memory bandwidth (measured: ``relu`` + ``mul`` over 262,144 x 64 floats 2.7x faster,
    a ``[262144, 32] x [32, 64]`` product 2.5x, with freed memory reused). ``on`` turns ``mmap`` off
    (``M_MMAP_MAX = 0``) and keeps up to :data:`KEEP_FREED_BYTES` of free memory at the heap's top;
    ``False`` restores glibc's steady-state defaults (mmap above 32 MB, trim above 64 MB). Values are
    untouched: only where the memory comes from changes. Returns whether glibc accepted it.
    """
    mallopt = _libc_mallopt()
    if mallopt is None:
        return False
    if on:
        settings = ((M_MMAP_MAX, 0), (M_TRIM_THRESHOLD, KEEP_FREED_BYTES))
    else:
        settings = ((M_MMAP_MAX, 65536), (M_MMAP_THRESHOLD, 32 << 20), (M_TRIM_THRESHOLD, 64 << 20))
    return all(mallopt(param, value) == 1 for param, value in settings)


# ----------------------------------------------------------------------------- alpha-test densities
def make_recording_sigma_fn(stock_get_sigma_fn: Callable) -> Callable:
    """A ``VolumetricSampler.get_sigma_fn`` whose ``sigma_fn`` (nerfacc's alpha test, Instant-NGP's
    occupancy-grid sampling) records the hash encodings it computes (:mod:`nerfify_ns.runtime.hashgrid`),
    so the field's differentiable pass over the samples that survive the test reuses them."""
    from nerfify_ns.runtime import hashgrid

    def get_sigma_fn(self, origins, directions, times=None):
        sigma_fn = stock_get_sigma_fn(self, origins, directions, times)
        if sigma_fn is None:
            return None

        def recording_sigma_fn(t_starts, t_ends, ray_indices):
            with hashgrid.recording_encodings():
                return sigma_fn(t_starts, t_ends, ray_indices)

        return recording_sigma_fn

    get_sigma_fn._nerfify_stock = stock_get_sigma_fn  # type: ignore[attr-defined]
    return get_sigma_fn


def make_visibility_recorder(stock_visibility: Callable) -> Callable:
    """nerfacc's ``render_visibility_from_density`` that hands the alpha test's mask (which samples the
    field will see) to the hash encodings recorded for it."""
    from nerfify_ns.runtime import hashgrid

    def render_visibility_from_density(*args, **kwargs):
        masks = stock_visibility(*args, **kwargs)
        hashgrid.keep_recorded_rows(masks)
        return masks

    render_visibility_from_density._nerfify_stock = stock_visibility  # type: ignore[attr-defined]
    return render_visibility_from_density
