"""The smoke rung's length follows the time it has: with a time limit, it trains as many of its iterations as fit
(measured by its own first steps), then renders its probe and times its rays, and is judged on the steps it
trained; a run that stops early of its own accord is not excused by it."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from nerfify_ns.budget import Limit
from nerfify_ns.verify.smoke_rung import (
    SMOKE_FEWEST,
    SMOKE_TAIL_SECONDS,
    SMOKE_TAIL_STEPS,
    smoke_pace,
    stopped_at_deadline,
)

WANTED = 5000
"""The paced smoke rung's iterations in the real run below: more than its 90 s can hold."""


def _result(seconds: float, returncode: int = 0, timed_out: bool = False):
    return SimpleNamespace(seconds=seconds, returncode=returncode, timed_out=timed_out)


def test_a_short_run_is_excused_only_when_it_ended_itself_at_its_deadline():
    limit = Limit(80.0, "the smoke rung's share")
    pace = smoke_pace(limit)
    assert pace is not None and pace.render_seconds == SMOKE_TAIL_STEPS and pace.startup_seconds == SMOKE_TAIL_SECONDS
    # the pace stops training when one step, the tail and the margin would pass the limit: ending within that of it
    assert stopped_at_deadline(_result(78.0), limit, pace, step=0.5)
    assert stopped_at_deadline(_result(80.0 - pace.margin_seconds - SMOKE_TAIL_SECONDS - 17 * 0.5), limit, pace,
                               step=0.5)
    # ended long before its deadline (an early exit of its own accord), crashed, or killed by the limit: not excused
    assert not stopped_at_deadline(_result(30.0), limit, pace, step=0.5)
    assert not stopped_at_deadline(_result(78.0, returncode=1), limit, pace, step=0.5)
    assert not stopped_at_deadline(_result(80.0, timed_out=True), limit, pace, step=0.5)
    assert not stopped_at_deadline(_result(78.0), limit, pace, step=None)  # no steps measured


def test_no_limit_no_pace():
    assert smoke_pace(Limit(None, "none")) is None
    assert not stopped_at_deadline(_result(10.0), Limit(None, "none"), None, step=0.1)


@pytest.mark.slow  # about 90 s: a real smoke rung cut by its time limit
def test_a_smoke_rung_with_less_time_than_its_iterations_trains_what_fits_and_is_judged_on_it(tiny_scene, tmp_path):
    """5,000 smoke iterations (more than fit: a quiet machine trains nerfacto's tiny scene at about 0.02 s a step,
    and a run of 1,000 once finished inside the limit) with a 90 s limit: the rung stops itself before the limit, its
    recorder still renders the probe and times the rays (what a budget plans from), and it passes on the steps it
    trained, saying how many of how many."""
    import yaml

    from nerfify_ns.synthesis.compose import compose
    from nerfify_ns.synthesis.prune import prune_plan
    from nerfify_ns.synthesis.resources import load_reference_plan
    from nerfify_ns.synthesis.scene_probe import probe_scene
    from nerfify_ns.verify.ladder import run_ladder

    plan = prune_plan(load_reference_plan("nerfacto"), probe_scene(tiny_scene))
    plan["trainer"]["mixed_precision"] = False
    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(plan, sort_keys=False))
    plugin = compose(plan, tmp_path / "plugin", record=False)
    report = run_ladder(plugin.out, scene=tiny_scene, out_dir=tmp_path / "verify", repair="off", rungs=["smoke"],
                        smoke_iterations=WANTED, smoke_limit=Limit(90.0, "the test's share"))
    smoke = report.rung("smoke")
    assert smoke is not None
    details = smoke.details
    assert details["wall_s"] < 90.0, details  # it ended itself: the limit did not kill it
    assert 0 < details["iterations"] < WANTED
    assert details["ray_cost"] is not None  # the recorder's tail ran after the stop
    if details["iterations"] >= SMOKE_FEWEST * WANTED:  # the usual case: judged on the steps it trained, and passed
        assert smoke.status == "pass", [str(d) for d in smoke.failures]
        assert details["paced"].startswith(f"trained {details['iterations']} of {WANTED} iterations: the 90 s limit")
    else:  # a very loaded machine: too few steps to judge, for want of time (never a failure of the plugin)
        assert [d.rule for d in smoke.failures] == ["timeout"]
        assert "stopped itself" in smoke.failures[0].message


def test_what_the_process_did_after_its_last_step_is_kept_apart_from_its_start(monkeypatch):
    """The smoke rung's start-up (what a later Nerfstudio process pays again) is the wall time before its last
    step less the steps; the recorder's probe and ray timing after it are its tail, seen on our clock."""
    from nerfify_ns.verify import smoke_rung

    now = [100.0]
    monkeypatch.setattr(smoke_rung.time, "perf_counter", lambda: now[0])
    seen = []
    clock = smoke_rung.LastStepClock(lambda step, total: seen.append(step))
    assert clock.tail(90.0, 30.0) == 0.0  # no step seen: no tail
    for at, step in ((105.0, 1), (108.0, 5), (111.0, 5), (112.0, 20)):
        now[0] = at
        clock(step, 20)
    assert seen == [1, 5, 5, 20] and clock.at == 112.0
    assert clock.tail(90.0, 30.0) == 8.0  # launched at 90, ended at 120, last step seen at 112
    scalars = {smoke_rung.ITER_TIME_TAG: {0: 3.0, 1: 1.0, 2: 1.0, 3: 1.0}}
    timing = smoke_rung.step_timing(scalars, 30.0, 8.0)
    assert timing == {"seconds_per_iteration": 1.0, "startup_seconds": 19.0, "tail_seconds": 8.0}
