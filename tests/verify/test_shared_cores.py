"""The checks and the smoke rung run at once: half the cores' threads each, never more than the user allowed."""

import os

from nerfify_ns.verify.ladder import shared_cores


def test_two_processes_at_once_get_half_the_cores_each(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    cores = len(os.sched_getaffinity(0))
    env = shared_cores()
    assert env["OMP_NUM_THREADS"] == env["MKL_NUM_THREADS"] == str(max(1, cores // 2))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert shared_cores()["OMP_NUM_THREADS"] == "1"
    monkeypatch.setenv("OMP_NUM_THREADS", "not a number")
    assert shared_cores()["OMP_NUM_THREADS"] == str(max(1, cores // 2))
    # the smoke rung's recorder times a step with the threads training will have
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert shared_cores()["NERFIFY_TIMING_THREADS"] == str(cores)


def test_the_budget_reads_the_step_at_trainings_threads_from_the_rungs_timing(monkeypatch):
    """A rung run beside the checks (1 thread) timed a step with training's 2 threads: its steps are scaled by the
    speedup it measured, not by the ratio of threads, and the rays' share of a step comes from the same timing;
    without a timing the ratio of threads stands (an upper bound on the speedup)."""
    import pytest

    from nerfify_ns.pipeline import _smoke_timing
    from nerfify_ns.verify.verdicts import LadderReport, RungResult

    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    cost = {"rays": [128, 512], "seconds": [0.3, 0.6], "seconds_per_ray": 0.3 / 384, "threads": 2,
            "rung_threads": 1, "speedup": 1.25}
    smoke = RungResult("smoke", details={"seconds_per_iteration": 0.5, "startup_seconds": 15.0, "threads": 1,
                                         "ray_cost": cost})
    timing = _smoke_timing(LadderReport(plugin="p", rungs=[smoke]))
    assert timing["seconds_per_iteration"] == pytest.approx(0.4)
    assert timing["ray_share"] == pytest.approx(0.3 / 384 * timing["rays"] / 0.4)
    smoke.details.pop("ray_cost")
    timing = _smoke_timing(LadderReport(plugin="p", rungs=[smoke]))
    assert timing["seconds_per_iteration"] == pytest.approx(0.25) and timing["ray_share"] is None


def test_a_smoke_rung_that_held_a_batch_of_samples_is_measured_in_samples_without_a_ray_share(monkeypatch):
    """A pipeline that sizes a step by its samples (the proxy gave the rung 8,192 a step): the budget's batch is that
    count, and the recorder's seconds per ray say nothing of such a step's share."""
    from nerfify_ns.pipeline import _smoke_timing
    from nerfify_ns.verify.verdicts import LadderReport, RungResult

    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    cost = {"rays": [128, 512], "seconds": [0.3, 0.6], "seconds_per_ray": 0.3 / 384, "threads": 2}
    smoke = RungResult("smoke", details={"seconds_per_iteration": 0.5, "startup_seconds": 15.0, "threads": 2,
                                         "ray_cost": cost})
    samples = {"pipeline.target_num_samples": 8192, "model.sampler.occupancy_grid.render_steps": 128}
    timing = _smoke_timing(LadderReport(plugin="p", rungs=[smoke]), samples)
    assert timing["rays"] == 8192 and timing["ray_share"] is None and timing["samples"] == samples
    rays = _smoke_timing(LadderReport(plugin="p", rungs=[smoke]), {"model.sampler.occupancy_grid.render_steps": 128})
    assert rays["rays"] == 128 and rays["ray_share"] is not None
