"""A budgeted training keeps its deadline itself: it stops, with a checkpoint at the step it reached, when one more
step would leave too little time to render its checkpoints, and trains on while there is time."""

from __future__ import annotations

import json
import time

import pytest

from nerfify_ns.runtime.pace import MEASURED_STEPS, STOP_LINE, Pace, PaceKeeper, _checkpoints_before


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _keeper(end: float, step: float = 1.0, render: float = 5.0, startup: float = 10.0, margin: float = 2.0):
    clock = Clock()
    pace = Pace(end=clock.now + end, step_seconds=step, render_seconds=render, startup_seconds=startup,
                margin_seconds=margin)
    return PaceKeeper(pace, clock), clock


def _run(keeper: PaceKeeper, clock: Clock, seconds_per_step: float, checkpoints: int = 2, most: int = 10_000) -> int:
    """Steps taken until the keeper stops the run (``most`` when it never does)."""
    for step in range(most):
        clock.now += seconds_per_step
        if keeper.after_step(checkpoints):
            return step
    return most


def test_it_trains_on_while_the_time_left_covers_a_step_the_start_and_the_renders():
    keeper, clock = _keeper(end=100.0)
    stopped = _run(keeper, clock, 1.0)
    # 100 s: steps of 1 s, then 1 s (one more step) + 10 s start + 2 x 5 s renders + 2 s margin = 23 s after it
    assert 75 <= stopped <= 78
    assert clock.now + 1.0 + 10.0 + 10.0 + 2.0 > keeper.pace.end >= clock.now + 10.0 + 10.0 + 2.0


def test_a_slower_machine_stops_it_sooner_and_its_renders_are_charged_at_the_slower_pace():
    keeper, clock = _keeper(end=100.0)
    stopped = _run(keeper, clock, 2.0)
    # 2 s a step: the renders (a forward pass on the same machine) take twice the planned 5 s each
    assert 31 <= stopped <= 33
    assert clock.now + 2.0 + 10.0 + 2 * 10.0 + 2.0 > keeper.pace.end


def test_more_checkpoints_to_render_stop_it_sooner():
    few, clock_few = _keeper(end=100.0)
    many, clock_many = _keeper(end=100.0)
    assert _run(many, clock_many, 1.0, checkpoints=6) < _run(few, clock_few, 1.0, checkpoints=2)


def test_nothing_is_decided_before_the_pace_is_measured():
    keeper, clock = _keeper(end=1.0)  # already too late: still, the first steps are not judged on no pace
    clock.now += 5.0
    assert keeper.after_step(1) is False  # first step: no duration yet
    for _ in range(MEASURED_STEPS - 1):
        clock.now += 5.0
        assert keeper.after_step(1) is False
    clock.now += 5.0
    assert keeper.after_step(1) is True
    assert keeper.step_seconds() == 5.0


def test_a_burst_of_slow_steps_costs_the_next_step_not_the_renders():
    """The last steps' pace prices one more step; the checkpoints' rendering, minutes later, is priced at the whole
    run's pace (a burst of load during training need not last into the rendering)."""
    keeper, clock = _keeper(end=10_000.0, step=1.0, render=50.0)
    for _ in range(101):
        clock.now += 1.0
        keeper.after_step(2)
    for _ in range(16):
        clock.now += 4.0
        keeper.after_step(2)
    assert keeper.step_seconds() == 4.0
    assert keeper.finish(2) == pytest.approx(clock.now + 4.0 + 10.0 + 2 * 50.0 * 1.0 + 2.0)


def test_the_pace_is_the_median_of_recent_steps_so_one_slow_step_does_not_stop_a_run():
    keeper, clock = _keeper(end=60.0)
    for _ in range(10):
        clock.now += 1.0
        assert not keeper.after_step(1)
    clock.now += 20.0  # one step held up (a checkpoint saved, a burst of load)
    assert not keeper.after_step(1)
    assert keeper.step_seconds() == 1.0


@pytest.mark.parametrize("text", [None, "", "not json", "[]", '{"end": 1}', '{"end": "x", "step_seconds": 1, '
                                  '"render_seconds": 1, "startup_seconds": 1, "margin_seconds": 1}',
                                  '{"end": 1, "step_seconds": 0, "render_seconds": 1, "startup_seconds": 1, '
                                  '"margin_seconds": 1}'])
def test_no_pace_or_a_malformed_one_keeps_nothing(text):
    assert Pace.from_env(text) is None


def test_a_pace_survives_the_environment():
    pace = Pace(end=time.time() + 60, step_seconds=0.25, render_seconds=3.0, startup_seconds=12.0,
                margin_seconds=3.0)
    assert Pace.from_env(pace.to_env()) == pace


def test_checkpoints_before_a_step_are_counted_from_the_folder(tmp_path):
    for step in (100, 200, 250):
        (tmp_path / f"step-{step:09d}.ckpt").write_bytes(b"")
    (tmp_path / "step-latest.ckpt").write_bytes(b"")  # not a step: not counted
    assert _checkpoints_before(tmp_path, 250) == 2
    assert _checkpoints_before(tmp_path, 251) == 3
    assert _checkpoints_before(tmp_path / "missing", 10) == 0


@pytest.mark.slow  # about a minute: a real training that stops itself
def test_a_real_training_stops_itself_at_its_deadline_with_a_checkpoint_and_is_evaluated(tiny_scene, tmp_path):
    """ns-train asked for 5,000 iterations with a deadline 25 s after its start: it stops itself (no limit
    reached), its last checkpoint is the last step it trained, and the evaluation is an ordinary one."""
    import yaml

    from nerfify_ns.budget import Limit
    from nerfify_ns.evaluate import run_eval
    from nerfify_ns.runtime.pace import ENV_PACE
    from nerfify_ns.synthesis.compose import compose
    from nerfify_ns.synthesis.prune import prune_plan
    from nerfify_ns.synthesis.resources import load_reference_plan
    from nerfify_ns.synthesis.scene_probe import probe_scene

    plan = prune_plan(load_reference_plan("nerfacto"), probe_scene(tiny_scene))
    plan["trainer"]["mixed_precision"] = False
    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(plan, sort_keys=False))
    plugin = compose(plan, tmp_path / "plugin", record=False)
    startup = 20.0  # a Nerfstudio process's start on a loaded two-core machine, about
    pace = Pace(end=time.time() + startup + 25.0 + startup + 5.0, step_seconds=0.1, render_seconds=2.0,
                startup_seconds=startup, margin_seconds=3.0)
    summary = run_eval.evaluate_run(plugin.out, tiny_scene, tmp_path / "eval", iterations=5000, every=2500, seed=0,
                                    limit=Limit(600.0, "the test's limit"),
                                    env={"NERFIFY_LPIPS_WEIGHTS": "none", ENV_PACE: pace.to_env()})
    assert summary["status"] == "ok" and summary["psnr"] is not None, summary
    assert not summary["stopped"]  # no limit reached: the training ended itself
    done = summary["iterations_done"]
    assert 3 < done < 5000
    assert summary["evaluated_iterations"] == done  # evaluated at the checkpoint of the last step trained
    saved = sorted((tmp_path / "eval" / "train").rglob("step-*.ckpt"))
    assert saved and saved[-1].name == f"step-{done - 1:09d}.ckpt"  # steps count from 0
    log = (tmp_path / "eval" / "train").glob("*.train.log")
    assert any(STOP_LINE in p.read_text() for p in log)
    assert summary["train_wall_seconds"] < 600


class _Config:
    schedule_step_scale = 0.01  # the run's 100 planned iterations of a paper's 10,000


class _Model:
    config = _Config()


def test_a_run_slower_than_planned_compresses_its_schedule_so_its_stages_still_end():
    """The schedule was scaled for the planned iterations; when the steps take twice the planned time, the run
    will train about half of them, and the model config's schedule scale follows (never raised again), so a stage
    the paper ends at three fifths of its training ends within the run."""
    from nerfify_ns.runtime.pace import _follow_deadline

    clock = Clock()
    pace = Pace(end=clock.now + 100.0 + 10 + 2 * 5 + 2, step_seconds=1.0, render_seconds=5.0, startup_seconds=10.0,
                margin_seconds=2.0, iterations=100)
    keeper, model = PaceKeeper(pace, clock), _Model()
    model.config = _Config()
    scales = []
    for step in range(200):
        clock.now += 2.0  # twice the planned step
        if keeper.after_step(2):
            break
        _follow_deadline(model, keeper, step, 2)
        scales.append(model.config.schedule_step_scale)
    done = step + 1
    assert 45 <= done <= 55  # about half the planned 100
    assert scales[0] == 0.01 and scales[-1] == pytest.approx(0.01 * done / 100, rel=0.1)
    assert all(b <= a for a, b in zip(scales, scales[1:], strict=False))
    stage_end = 0.6 * 10_000  # the paper's step where a stage ends
    assert stage_end * scales[-1] < done  # the stage ends within the run


def test_a_faster_run_keeps_its_planned_schedule_and_no_pace_changes_nothing():
    from nerfify_ns.runtime.pace import _follow_deadline

    clock = Clock()
    pace = Pace(end=clock.now + 200.0, step_seconds=1.0, render_seconds=5.0, startup_seconds=10.0,
                margin_seconds=2.0, iterations=100)
    keeper, model = PaceKeeper(pace, clock), _Model()
    model.config = _Config()
    for step in range(40):
        clock.now += 0.5
        keeper.after_step(2)
        _follow_deadline(model, keeper, step, 2)
    assert model.config.schedule_step_scale == 0.01
    unplanned = PaceKeeper(Pace(end=clock.now + 200.0, step_seconds=1.0, render_seconds=5.0, startup_seconds=10.0,
                                margin_seconds=2.0), clock)
    model.config.schedule_step_scale = 0.5
    for step in range(20):
        clock.now += 3.0
        unplanned.after_step(2)
        _follow_deadline(model, unplanned, step, 2)
    assert model.config.schedule_step_scale == 0.5
    assert Pace.from_env(pace.to_env()) == pace
    legacy = {k: v for k, v in json.loads(pace.to_env()).items() if k != "iterations"}
    assert Pace.from_env(json.dumps(legacy)).iterations == 0.0
