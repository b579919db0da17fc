"""The demo flow's output handling: atomic folders and one-line errors, nothing half-written."""

import subprocess
import sys

import pytest

from nerfify_ns.atomic import MARKER, OutputExistsError, OverwriteRefused, atomic_dir
from nerfify_ns.evaluate.smoke_train import SmokeTrainError
from nerfify_ns.pipeline import run_demo


def test_atomic_dir_appears_only_on_success(tmp_path):
    out = tmp_path / "out"
    with atomic_dir(out) as staging:
        (staging / "a.txt").write_text("x")
        assert not out.exists()
    assert (out / "a.txt").read_text() == "x"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_atomic_dir_leaves_nothing_on_failure(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with atomic_dir(out) as staging:
            (staging / "half.txt").write_text("x")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_non_empty_output_is_refused_unless_overwrite(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    with pytest.raises(OutputExistsError, match="--overwrite"):
        with atomic_dir(out):
            pass
    assert (out / "keep.txt").read_text() == "precious"
    with pytest.raises(OverwriteRefused, match="replaces only an output folder of nerfify-ns"):
        with atomic_dir(out, overwrite=True):  # not ours: even --overwrite leaves it alone
            pass
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    (out / "keep.txt").unlink()
    with atomic_dir(out) as staging:
        (staging / "old.txt").write_text("x")
    with atomic_dir(out, overwrite=True) as staging:  # ours (its marker): replaced
        (staging / "new.txt").write_text("y")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "new.txt"]


def test_failed_training_keeps_the_log_and_writes_no_output(tiny_scene, tmp_path):
    out = tmp_path / "demo"
    with pytest.raises(SmokeTrainError) as err:
        run_demo(out, method="no-such-method", data=tiny_scene, iterations=2)
    assert not out.exists() and list(tmp_path.iterdir()) == []
    assert err.value.log_path.exists() and "no-such-method" in err.value.log_path.read_text()


def test_cli_reports_one_line_and_exit_code(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "x").write_text("x")
    proc = subprocess.run([sys.executable, "-m", "nerfify_ns.cli", "demo", "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "--overwrite" in lines[0]


def test_cli_unknown_scene_is_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "nerfify_ns.cli", "scene", "no-such-scene", str(tmp_path / "s")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    assert len(lines) == 1 and "unknown scene 'no-such-scene'" in lines[0] and "default" in lines[0]
    assert not (tmp_path / "s").exists()


@pytest.mark.slow
def test_an_evaluation_failure_is_a_failed_stage_with_the_folder_written(tiny_scene, tmp_path, monkeypatch):
    """The ladder passes (real, sandboxed); the evaluation then fails (a stand-in raising the error a failed
    evaluation raises: since the dataset reader refuses a scene without a test split up front, no real input
    reaches this stage broken): the train stage fails with that reason, the report is written, nothing is
    raised."""
    import json

    from nerfify_ns.budget import Budget
    from nerfify_ns.errors import NerfifyError
    from nerfify_ns.evaluate import run_eval
    from nerfify_ns.pipeline import RunOptions, run_compose
    from nerfify_ns.synthesis.resources import load_reference_plan

    def failing_evaluation(*args, **kwargs):
        raise NerfifyError("ns-eval found no frame to score (stand-in)")

    monkeypatch.setattr(run_eval, "evaluate_run", failing_evaluation)
    result = run_compose(load_reference_plan("kplanes-static"), tmp_path / "out",
                         options=RunOptions(data=tiny_scene,
                                            budget=Budget(iterations=10, every=10, smoke_iterations=20)))
    outcome = result.outcome
    assert [r.status for r in outcome.records] == ["ran", "ran", "ran", "failed", "not run"]
    assert "no frame to score" in outcome.failed.reason and result.summary is None
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["outcome"]["failed"]["name"] == "train" and report["sections"]["verification"]["status"] == "pass"
    assert (tmp_path / "out" / "nerfify.log").is_file() and (tmp_path / "out" / "plan.yaml").is_file()


def test_a_budget_spent_before_training_fails_the_train_stage_in_one_line(tiny_scene, tmp_path, monkeypatch, capsys):
    """Training that does not happen (the budget is gone once the ladder has passed) is a failed stage: one red
    line naming the stage and the reason on the console, exit code 1, the folder and its report saying the same.
    The ladder is a stand-in (a pass with the smoke rung's measured speed), so nothing trains here."""
    import json

    from nerfify_ns import verify
    from nerfify_ns.cli import CONSOLE, Compose
    from nerfify_ns.verify.verdicts import LadderReport, RungResult

    def passing_ladder(plugin_dir, **kwargs):
        smoke = RungResult("smoke", details={"seconds_per_iteration": 0.5, "startup_seconds": 15.0})
        return LadderReport(plugin=str(plugin_dir), rungs=[RungResult("static"), smoke])

    monkeypatch.setattr(verify, "run_ladder", passing_ladder)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_:
        with CONSOLE.capture() as captured:
            Compose(method="kplanes-static", data=tiny_scene, out=out, budget="1s").main()
    assert exit_.value.code == 1
    lines = captured.get().splitlines()
    failed = [line for line in lines if line.startswith("failed")]
    assert len(failed) == 1 and failed[0].startswith("failed train: the budget leaves"), lines
    assert "give a longer --budget" in failed[0]
    run = json.loads((out / "run.json").read_text())
    assert run["failed"]["name"] == "train" and "budget" in run["failed"]["reason"]
    html = (out / "report.html").read_text()
    top = html[:html.index('<section id="paper">')]
    assert "train failed: the budget leaves" in top and 'class="headline fail"' in top
    assert not (out / "eval").exists()
