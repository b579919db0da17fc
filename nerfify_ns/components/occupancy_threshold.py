"""The pruning threshold of an occupancy grid as a value a schedule hook writes.

Instant-NGP (Müller et al. 2022, Sec. 5.1) marks a grid cell empty when the density the field gives it, times the
marching step, falls below a threshold (nerfacc's ``OccGridEstimator.update_every_n_steps(..., occ_thre=0.01)``),
and samples in empty cells are never evaluated. Papers anneal that threshold over training (VR-NeRF, Xu et al. 2023:
"we prune grid voxels ... below the current pruning threshold (which we anneal linearly from zero to 0.2)") so that
little is pruned while the field is still forming. :func:`scheduled_threshold` gives the grid an attribute
``threshold`` that every later update uses; an ``Anneal`` of ``occupancy_grid.threshold`` writes it.

Imports nothing but the standard library: generated plugins import this module.
"""

from __future__ import annotations

from typing import Any

__all__ = ["scheduled_threshold"]

DEFAULT_THRESHOLD = 0.01
"""nerfacc's own default (``occ_thre``): the grid's updates are unchanged until a hook writes another value."""


def scheduled_threshold(grid: Any, threshold: float = DEFAULT_THRESHOLD) -> Any:
    """``grid`` (a nerfacc ``OccGridEstimator``) whose updates prune below ``grid.threshold`` (set to ``threshold``;
    a schedule hook changes it between steps) whatever threshold its caller passes."""
    grid.threshold = float(threshold)
    update = grid.update_every_n_steps

    def update_every_n_steps(step: int, occ_eval_fn: Any, occ_thre: float | None = None, **kwargs: Any) -> None:
        return update(step=step, occ_eval_fn=occ_eval_fn, occ_thre=float(grid.threshold), **kwargs)

    grid.update_every_n_steps = update_every_n_steps
    return grid
