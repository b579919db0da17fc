"""No hidden time limits: every limit comes from the budget or the user and is named, with the progress made, when
it is reached; --iterations alone has none; a smoke rung that runs out of time is "not verified: time", never a
failure that reverts the paper's compiled parts."""

import math
from pathlib import Path

import pytest

from nerfify_ns.budget import CHECK_SECONDS, SMOKE_SHARE, Budget, Limit, check_limit, smoke_limit, training_limit
from nerfify_ns.cli import paper_budget
from nerfify_ns.verify.verdicts import Diagnosis, LadderReport, RungResult


def test_iterations_alone_have_no_time_limit():
    budget = paper_budget(None, 600, None, None)
    assert budget.seconds is None
    for limit in (training_limit(budget, None), smoke_limit(budget, None)):
        assert limit.seconds is None and limit.timeout == math.inf and limit.describe() == "no time limit"
    assert check_limit(budget, None).seconds == CHECK_SECONDS  # a check process: seconds of work, named


def test_a_budget_derives_each_limit_and_names_it():
    budget = paper_budget(None, None, None, None)  # the default 4 minutes
    smoke = smoke_limit(budget, 200.0)
    assert smoke.seconds == pytest.approx(SMOKE_SHARE * 200.0)
    assert smoke.describe() == (f"the {SMOKE_SHARE * 200:.0f} s limit of the smoke rung's share of the 4-minute "
                                f"budget ({SMOKE_SHARE:.0%} of the 200 s left when the ladder started)")
    train = training_limit(budget, 150.0)
    assert train.seconds == 150.0 and "4-minute budget" in train.describe()
    assert check_limit(budget, 100.0).seconds == 100.0  # never more than the budget has left
    given = Budget(timeout=42.0)
    assert smoke_limit(given, None).seconds == 42.0 and check_limit(given, None).seconds == 42.0
    assert training_limit(given, None).describe() == "the 42 s limit of each process (the budget's timeout)"
    assert smoke_limit(given, None).describe().startswith("the 42 s limit of ")


def test_the_evaluation_names_the_limit_and_the_iterations_done(tmp_path, monkeypatch):
    """A training stopped by its limit says how far it got and whose limit it was (not a bare "timed out")."""
    from nerfify_ns.evaluate import run_eval
    from nerfify_ns.runtime.launch import TrainRun
    from nerfify_ns.scenes import write_scene

    scene = write_scene("default", tmp_path / "scene", resolution=16, n_train=4, n_val=1, n_test=1)
    plugin = tmp_path / "plugin"
    plugin.mkdir()
    (plugin / "nerfify.json").write_text("{}")
    seen = {}

    def stopped(method, data, out_dir, *, iterations, timeout, **kw):
        seen["timeout"] = timeout
        run = TrainRun(method=method, returncode=-9, wall_seconds=12.0, log_path=tmp_path / "train.log",
                       timed_out=True)
        run.losses = {s: 0.1 for s in range(241)}
        (tmp_path / "train.log").write_text("")
        return run

    monkeypatch.setattr(run_eval, "train_for_curve", stopped)
    limit = Limit(900.0, "the 15-minute budget (the time it had left when training started)")
    summary = run_eval.evaluate_run(plugin, scene, tmp_path / "eval", iterations=600, every=200, limit=limit)
    assert seen["timeout"] == 900.0 and summary["status"] == "failed"
    assert summary["reason"] == ("stopped at 241 of 600 iterations: the 900 s limit of the 15-minute budget (the "
                                 "time it had left when training started)")
    unlimited = run_eval.evaluate_run(plugin, scene, tmp_path / "eval2", iterations=600, every=200)
    assert seen["timeout"] == math.inf and "no time limit" in unlimited["reason"]
    paced = run_eval.evaluate_run(plugin, scene, tmp_path / "eval3", iterations=600, every=200, limit=limit,
                                  estimated=300)
    assert paced["reason"].startswith("stopped at 241 of the 300 iterations estimated to fit (at most 600): the 900 s")


class _Stage:
    """What the pipeline's verdict functions write to: the stage's line, or why it failed."""

    summary, failed = "", None

    def fail(self, why):
        self.failed = why


def _ladder(smoke: RungResult) -> LadderReport:
    rungs = [RungResult("static"), RungResult("contract"), RungResult("stability"), smoke]
    return LadderReport(plugin="/x", rungs=rungs, rounds=[rungs])


def _timed_out_smoke() -> RungResult:
    smoke = RungResult("smoke", details={"iterations": 41, "iterations_wanted": 80})
    smoke.fail(Diagnosis("smoke", "timeout", "stopped at 41 of 80 iterations after 74 s: the 74 s limit of the "
                                             "smoke rung's share of the 4-minute budget"))
    return smoke


def test_a_smoke_rung_out_of_time_is_not_verified_and_nothing_is_reverted(tmp_path):
    from nerfify_ns.pipeline import _fallback, _judge_ladder, _note_unverified, _smoke_timed_out
    from nerfify_ns.plan import Plan
    from nerfify_ns.synthesis.novel import Implementation
    from nerfify_ns.synthesis.resources import load_reference_plan

    ladder = _ladder(_timed_out_smoke())
    assert not ladder.ok and _smoke_timed_out(ladder)

    class Record:  # a compiled part, as the equation compiler records it
        id, source, status, component = "hole-0", "compiler", "implemented", {"class": "Memory"}

    implementation = Implementation(Plan.of(load_reference_plan("vanilla-nerf")), sources={}, records=[Record()])
    assert _fallback(implementation, tmp_path, None)(ladder) is None  # kept: a timeout blames no part

    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    _note_unverified(plan, tmp_path, ladder, Budget())
    assert "smoke rung not verified: time (stopped at 41 of 80 iterations" in plan.notes[-1]
    assert "--budget" in plan.notes[-1] and "--smoke-iterations 41" in plan.notes[-1]
    assert "not verified: time" in Path(tmp_path / "plan.yaml").read_text()

    stage = _Stage()
    _judge_ladder(ladder, stage)
    assert stage.failed is None and "smoke not verified: time" in stage.summary


def test_a_real_failure_still_fails_and_a_timeout_beside_it_does_not_excuse_it():
    from nerfify_ns.pipeline import _judge_ladder, _smoke_timed_out

    smoke = _timed_out_smoke()
    broken = _ladder(smoke)
    broken.rungs[1].fail(Diagnosis("contract", "shape", "density is [R, 2], expected [R, 1]"))
    assert not _smoke_timed_out(broken)
    crashed = RungResult("smoke")
    crashed.fail(Diagnosis("smoke", "exit-code", "ns-train exited with 1"))
    assert not _smoke_timed_out(_ladder(crashed))

    stage = _Stage()
    _judge_ladder(_ladder(crashed), stage)
    assert stage.failed and "exit-code" in stage.failed


@pytest.mark.slow
def test_a_training_its_limit_stops_after_a_checkpoint_is_evaluated_there_and_says_so(tiny_scene, tmp_path,
                                                                                      monkeypatch):
    """A real 10-iteration run of a composed nerfacto plan (checkpoints at 5 and 10), reported as if its limit had
    stopped it after them (the run's own record: timed out, killed): its checkpoints are rendered and evaluated, the
    summary is ok with where it stopped, and the report's headline says it first, in the partial colour. Without a
    checkpoint the same stop is a failure (test above)."""
    import json

    import yaml

    from nerfify_ns import runfolder
    from nerfify_ns.evaluate import run_eval
    from nerfify_ns.evaluate.report import read_outcome
    from nerfify_ns.synthesis.compose import compose
    from nerfify_ns.synthesis.prune import prune_plan
    from nerfify_ns.synthesis.resources import load_reference_plan
    from nerfify_ns.synthesis.scene_probe import probe_scene

    plan = prune_plan(load_reference_plan("nerfacto"), probe_scene(tiny_scene))
    plan["trainer"]["mixed_precision"] = False
    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(plan, sort_keys=False))
    plugin = compose(plan, tmp_path / "plugin", record=False)
    real = run_eval.train_for_curve

    def stopped_by_its_limit(*args, **kwargs):
        run = real(*args, **kwargs)
        assert run.ok, run.log_tail(15)
        run.timed_out, run.returncode = True, -9  # as the process runner records a run its limit killed
        return run

    monkeypatch.setattr(run_eval, "train_for_curve", stopped_by_its_limit)
    limit = Limit(600.0, "the 10-minute budget (the time it had left when training started)")
    summary = run_eval.evaluate_run(plugin.out, tiny_scene, tmp_path / "eval", iterations=10, every=5, seed=0,
                                    limit=limit, env={"NERFIFY_LPIPS_WEIGHTS": "none"})
    assert summary["status"] == "ok" and summary["psnr"] is not None, summary
    assert summary["stopped"] == ("stopped at 10 of 10 iterations: the 600 s limit of the 10-minute budget (the time "
                                  "it had left when training started); evaluated at its last checkpoint, iteration 10")
    (tmp_path / runfolder.OUTCOME).write_text(json.dumps({"ok": True, "headline": "ran train", "stages": []}))
    outcome = read_outcome(tmp_path, {})
    assert outcome["partial"] and outcome["headline"].startswith("Training stopped at 10 of 10 iterations")


def test_a_training_that_kept_its_deadline_with_fewer_iterations_than_estimated_says_so(tmp_path):
    """The budget estimated 487 iterations from the smoke rung's pace; the machine ran slower and the training
    stopped itself at its deadline after 180: within the budget, and the train stage's line says what it trained,
    of what, and why. The headline's colour is the outcome's (grey renders, a limit's stop), not the estimate's
    miss. A run that reached its estimate says nothing of the kind."""
    import json

    from nerfify_ns import runfolder
    from nerfify_ns.evaluate.report import read_outcome
    from nerfify_ns.pipeline import TrainingRun, _judge_evaluation, _paced

    run = TrainingRun(487, 244, [], Limit(215.0, "the 4-minute budget"),
                      {"seconds": 240.0, "iterations": 487, "seconds_per_iteration": 0.4}, ceiling=974)
    summary = {"status": "ok", "iterations_done": 180, "evaluated_iterations": 180, "seconds": 126.0, "psnr": 20.0,
               "ssim": 0.8, "lpips": None}
    short = _paced(summary, run)
    assert short["short"] == ("trained 180 of the 487 iterations estimated to fit: a step took 0.70 s where 0.40 s "
                              "was estimated, and the training stopped itself at the budget's deadline")
    stage = _Stage()
    _judge_evaluation({**summary, "paced": short}, stage, run)
    assert stage.failed is None and stage.summary.startswith(f"{short['short']}; 180 iterations in 126.0 s")
    longer = _paced({"status": "ok", "iterations_done": 700, "evaluated_iterations": 700, "seconds": 140.0}, run)
    assert longer["short"] == "" and longer["iterations"] == 700 and longer["estimated"] == 487
    assert _paced({"status": "failed"}, run) is None
    killed = _paced({"status": "ok", "iterations_done": 180, "evaluated_iterations": 120, "seconds": 90.0,
                     "stopped": "stopped at 180 of 974 iterations: the 215 s limit"}, run)
    assert killed["short"] == "" and killed["iterations"] == 180  # the limit's own line says where it stopped
    assert _paced({"status": "ok", "iterations_done": 10}, TrainingRun(10, 5, [], Limit(None, "none"))) is None

    (tmp_path / runfolder.OUTCOME).write_text(json.dumps({"ok": True, "headline": "ran train", "stages": []}))
    (tmp_path / runfolder.EVAL_DIR).mkdir()
    (tmp_path / runfolder.EVAL_DIR / runfolder.SUMMARY).write_text(json.dumps({"status": "ok", "paced": short}))
    outcome = read_outcome(tmp_path, {})
    assert not outcome["partial"] and outcome["headline"] == "ran train"


def test_a_smoke_rung_judged_on_the_steps_its_time_allowed_says_how_many():
    from nerfify_ns.pipeline import _judge_ladder

    smoke = RungResult("smoke", details={"iterations": 44, "iterations_wanted": 80,
                                         "paced": "trained 44 of 80 iterations: the 60 s limit of the smoke rung's "
                                                  "share left no time for more at 0.90 s a step"})

    stage = _Stage()
    _judge_ladder(_ladder(smoke), stage)
    assert stage.failed is None
    assert stage.summary.endswith("smoke pass (smoke trained 44 of 80 iterations: the 60 s limit of the smoke rung's "
                                  "share left no time for more at 0.90 s a step)")
