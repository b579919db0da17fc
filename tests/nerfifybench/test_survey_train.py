"""The survey's ``--train`` rows: what a run folder of ``ns-nerfify PAPER`` states (trained, iterations, within the
budget, PSNR, colour ratio, CPU proxy, found parts built and verified), read from a folder made by hand; the bounded
child process and its process group; the child entry point's usage line."""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import yaml

from nerfify_ns import runfolder
from nerfify_ns.nerfifybench import survey as sv


def _run_folder(tmp: Path, *, within: bool, ladder: str = "static pass, contract pass, stability pass, smoke pass",
                proxy: bool = True) -> Path:
    out = tmp / "run"
    (out / runfolder.EVAL_DIR).mkdir(parents=True)
    plan = {"base": "vanilla-nerf", "family": {"name": "static"},
            "holes": [{"production": "RGBHead", "contribution": "p1: colour head", "status": "implemented"},
                      {"production": "Backbone", "contribution": "p2: layer norm", "status": "not implemented",
                       "reason": "no equation of the part defines what the Backbone returns"}],
            "model": {"field": {"custom": {"production": "FieldWrapper", "contribution": "p3: memory",
                                           "status": "partly implemented", "implements": ["4"]}}}}
    if proxy:
        plan["schedule"] = {"proxy": {"headline": "trained a CPU proxy: 64 instead of 192 samples per ray"}}
    (out / runfolder.PLAN).write_text(yaml.safe_dump(plan))
    stages = [{"name": "verify", "status": "ran", "summary": ladder}, {"name": "train", "status": "ran", "summary": ""}]
    (out / runfolder.OUTCOME).write_text(json.dumps({"stages": stages}))
    summary = {"status": "ok", "iterations_done": 120 if within else 80, "iterations": 120, "psnr": 21.5,
               "seconds": 150.0, "diagnostics": {"colour_spread_ratio": 0.74},
               "budget": {"seconds": 240.0, "iterations": 120}, "schedule": plan.get("schedule"),
               "within_budget": within}
    (out / runfolder.EVAL_DIR / runfolder.SUMMARY).write_text(json.dumps(summary))
    return out


def _row(out: Path, seconds: float = 231.0, exit_code: int = 0) -> sv.PaperRow:
    row = sv.PaperRow("paper", "paper.md", exit_code=exit_code, seconds=seconds)
    sv.read_plan(row, out)
    sv.read_training(row, out)
    return row


def test_a_trained_run_folder_gives_its_row(tmp_path):
    row = _row(_run_folder(tmp_path, within=True))
    t = row.train
    assert (t["trained"], t["iterations"], t["planned"], t["within_budget"]) == (True, 120, 120, True)
    assert (t["wall_seconds"], t["budget_seconds"], t["psnr"], t["colour_ratio"]) == (231.0, 240.0, 21.5, 0.74)
    assert t["proxy"].startswith("trained a CPU proxy: 64 instead of 192")
    assert (t["found"], t["built"], t["verified"]) == (3, 2, 2)  # the compiled custom part counts as found and built
    line = sv.train_table([row]).splitlines()[-1]
    assert "| yes (120; 120 estimated) | yes (231 s / 240 s) | 21.50 | 0.74 | yes: trained a CPU proxy" in line
    assert "| 2 / 2 of 3 |" in line


def test_a_run_past_its_budget_and_a_ladder_out_of_time_say_so(tmp_path):
    out = _run_folder(tmp_path, within=False, proxy=False,
                      ladder="static pass, contract pass, stability pass, smoke not verified: time")
    t = _row(out, seconds=402.0).train
    assert (t["within_budget"], t["iterations"], t["proxy"]) == (False, 80, None)
    assert (t["built"], t["verified"]) == (2, 0)
    line = sv.train_table([_row(out, seconds=402.0)]).splitlines()[-1]
    assert "| no (402 s / 240 s) |" in line and "| no | 2 / 0 of 3 |" in line


def test_a_family_the_tool_cannot_build_is_not_trained_and_says_why(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    family = {"name": "splatting", "buildable": False, "why": "Gaussian splatting: the grammar builds fields"}
    (out / runfolder.PLAN).write_text(yaml.safe_dump({"base": "kplanes", "family": family, "holes": []}))
    (out / runfolder.OUTCOME).write_text(json.dumps({"stages": [
        {"name": "plan", "status": "failed", "reason": "a splatting paper"},
        {"name": "train", "status": "not run"}]}))
    row = sv.PaperRow("paper", "paper.md", exit_code=1, seconds=20.0)
    sv.read_plan(row, out)
    sv.read_training(row, out, budget_seconds=240.0)
    assert row.train["trained"] is False and row.train["iterations"] is None
    assert row.train["why"] == "not built: a splatting paper: Gaussian splatting: the grammar builds fields"
    assert sv.train_table([row]).splitlines()[-1].startswith("| paper | 1 | no | - (20 s / - s) |")


def test_a_buildable_paper_whose_train_stage_failed_did_not_fit_its_budget(tmp_path):
    out = _run_folder(tmp_path, within=True)
    (out / runfolder.EVAL_DIR / runfolder.SUMMARY).unlink()
    reason = "the budget leaves 143 s for training and evaluation, and 10 iterations need about 171 s"
    (out / runfolder.OUTCOME).write_text(json.dumps({"stages": [
        {"name": "verify", "status": "ran", "summary": "static pass, contract pass, stability pass, smoke pass"},
        {"name": "train", "status": "failed", "reason": reason}]}))
    row = sv.PaperRow("paper", "paper.md", exit_code=1, seconds=111.0)
    sv.read_plan(row, out)
    sv.read_training(row, out, budget_seconds=240.0)
    t = row.train
    assert (t["trained"], t["within_budget"], t["budget_seconds"]) == (False, False, 240.0)
    assert t["why"] == f"train failed: {reason}"
    assert "| no | no (111 s / 240 s) |" in sv.train_table([row]).splitlines()[-1]


def test_a_bounded_child_past_its_limit_is_stopped_with_its_process_group(tmp_path):
    pid_file = tmp_path / "pid"
    start = time.perf_counter()
    done = sv._run_bounded(["sh", "-c", f"sleep 60 & echo $! > {pid_file}; wait"], timeout=1, memory=2**30)
    assert done is None and time.perf_counter() - start < 20
    pid = int(pid_file.read_text())
    status = Path(f"/proc/{pid}/status")
    time.sleep(0.2)
    assert not status.exists() or "zombie" in status.read_text()  # the grandchild went with the group
    assert sv._run_bounded(["sh", "-c", "echo hi; exit 3"], timeout=10, memory=2**30) == (3, "hi\n")


def test_the_child_entry_point_without_arguments_is_one_usage_line():
    done = subprocess.run([sys.executable, "-m", "nerfify_ns.nerfifybench.survey"], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stdout == "" and done.stderr.strip().startswith("usage: ") and len(done.stderr.splitlines()) == 1
