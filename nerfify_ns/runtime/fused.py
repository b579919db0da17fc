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
                                intermediate takes.
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

