"""The occupancy grid's pruning threshold as a value a schedule hook writes: a real nerfacc grid prunes below
whatever the hook last wrote, and the anneal the paper's sentence states builds, generates and runs."""

from __future__ import annotations

import torch

from nerfify_ns.components.occupancy_threshold import DEFAULT_THRESHOLD, scheduled_threshold
from nerfify_ns.components.schedule_hooks import Anneal
from nerfify_ns.runtime import nerfacc_cpu

nerfacc_cpu.install(force=True)

import nerfacc  # noqa: E402


def _occupied(threshold: float) -> float:
    """The share of a grid's cells left occupied after one warm-up update over a density ramp (0 to 0.04 along x,
    the marching step folded in): every cell is evaluated, and a cell is kept when its value exceeds the threshold."""
    grid = nerfacc.OccGridEstimator(roi_aabb=[-1, -1, -1, 1, 1, 1], resolution=16, levels=1)
    grid = scheduled_threshold(grid)
    assert grid.threshold == DEFAULT_THRESHOLD
    torch.nn.Module.__setattr__(grid, "threshold", threshold)  # what the hook's write does
    grid.train()
    grid.update_every_n_steps(step=0, occ_eval_fn=lambda x: 0.02 * (x[:, :1] + 1.0))  # its caller's default 0.01
    return grid.binaries.float().mean().item()


def test_the_grid_prunes_below_the_threshold_last_written():
    low, default, high = _occupied(0.005), _occupied(DEFAULT_THRESHOLD), _occupied(0.015)
    assert 0.8 < low < 0.9 and 0.7 < default < 0.8 and 0.55 < high < 0.65, (low, default, high)


def test_an_anneal_writes_the_threshold_of_the_models_grid():
    model = torch.nn.Module()
    model.occupancy_grid = scheduled_threshold(
        nerfacc.OccGridEstimator(roi_aabb=[-1, -1, -1, 1, 1, 1], resolution=8, levels=1))
    hook = Anneal(target="occupancy_grid.threshold", start_value=0.0, end_value=0.2, start_step=0, end_step=100)
    hook.check(model)
    for step, expected in ((0, 0.0), (50, 0.1), (100, 0.2), (400, 0.2)):
        hook.write(float(hook(torch.tensor([step]))[0]), model, None)
        assert abs(model.occupancy_grid.threshold - expected) < 1e-6
