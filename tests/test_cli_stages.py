"""`ns-nerfify PAPER --until STAGE` as a user runs it (a real process): a quiet console (other packages'
warnings go to the run's log), one line per finished stage, and a complete, honest output folder whose
report says at its top which stages ran and which did not; boolean flags that read naturally."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
CLI = Path(sys.executable).with_name("ns-nerfify")
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"
WARNING_LINE = re.compile(r"Warning\b|warnings\.warn|deprecated", re.I)


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(CLI), *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def stage_statuses(out: Path) -> dict:
    return {s["name"]: s["status"] for s in json.loads((out / "run.json").read_text())["stages"]}


@pytest.mark.parametrize("until, ran, not_run", [
    ("plan", ["read", "equations", "plan"], ["plugin", "verify", "train", "patches"]),
    ("plugin", ["read", "equations", "plan", "plugin"], ["verify", "train", "patches"]),
])
def test_until_writes_an_honest_folder_and_keeps_the_console_quiet(until, ran, not_run, tmp_path):
    out = tmp_path / "out"
    done = run_cli(str(EXAMPLE), "--until", until, "--out", str(out), cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    terminal = done.stdout + done.stderr
    assert not [line for line in terminal.splitlines() if WARNING_LINE.search(line)], terminal
    assert done.stderr == ""
    assert [line.split()[1].rstrip(":") for line in done.stdout.splitlines() if line.startswith("done ")] == \
        [*ran, "report"]
    assert f"stopped after {until} (--until {until}); not run: {', '.join(not_run[:-1])}" in done.stdout

    statuses = stage_statuses(out)
    assert [statuses[s] for s in ran] == ["ran"] * len(ran) and [statuses[s] for s in not_run] == ["not run"] * len(
        not_run)
    plan = yaml.safe_load((out / "plan.yaml").read_text())
    assert plan["method"] == "gridlite" and plan["pruned"]
    for name in ("paper.md", "evidence.json", "citations.json", "report.html", "report.json", "nerfify.log"):
        assert (out / name).is_file(), name
    assert (out / "gridlite" / "model.py").is_file() == (until == "plugin")
    assert not (out / "verify.json").exists() and not (out / "eval").exists()
    assert not list(tmp_path.glob(".out.partial-*"))

    report = json.loads((out / "report.json").read_text())
    assert report["outcome"]["ok"] is True and report["outcome"]["until"] == until
    assert [s["status"] for s in report["outcome"]["stages"] if s["name"] in not_run] == ["not run"] * len(not_run)
    html = (out / "report.html").read_text()
    top = html[:html.index('<section id="paper">')]
    assert f"stopped after {until} (--until {until})" in top and "not run" in top
    if until == "plugin":  # generating the plugin imports Nerfstudio, whose warnings went to the log
        assert "FutureWarning" in (out / "nerfify.log").read_text()


def test_until_names_a_stage(tmp_path):
    done = run_cli(str(EXAMPLE), "--until", "report", cwd=tmp_path)
    assert done.returncode == 2 and "report" in done.stdout + done.stderr
    assert list(tmp_path.iterdir()) == []


SUBCOMMANDS = ("paper", "compose", "verify", "report", "grammar", "demo", "scene", "lpips-weights", "runtime")


@pytest.mark.parametrize("sub", SUBCOMMANDS)
def test_help_has_no_double_negatives(sub, capsys):
    import tyro

    from nerfify_ns.cli import Commands

    with pytest.raises(SystemExit) as exit_:
        tyro.cli(Commands, args=[sub, "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert "--" in text and not re.search(r"--no-no-|--no-[a-z-]*not", text), text
    flags = set(re.findall(r"--([a-z][a-z0-9-]*)", text))
    assert not {f for f in flags if f.startswith("no-") and f[3:].startswith(("no", "not", "skip", "without"))}
    if sub == "compose":
        assert {"train", "no-train", "until", "iterations"} <= flags


def test_no_train_stops_after_the_ladder():
    from nerfify_ns.cli import Compose

    assert Compose(method="nerfacto", train=False)._until() == "verify"
    assert Compose(method="nerfacto", train=False, until="plugin")._until() == "plugin"
    assert Compose(method="nerfacto", until="train")._until() == "train"
    assert Compose(method="nerfacto")._until() is None


@pytest.mark.slow
def test_a_failed_verification_exits_1_and_still_writes_the_folder(tmp_path):
    """The smoke rung cannot see a 1-iteration run learn: the ladder fails, training does not run, one red line
    names the stage, the rung and the reason, exit code 1, and the folder and its report say the same."""
    import os

    out = tmp_path / "kp"
    env = {**os.environ, "NERFIFY_CACHE": str(tmp_path / "cache")}
    done = subprocess.run([str(CLI), "compose", "--method", "kplanes-static", "--smoke-iterations", "1", "--out",
                           str(out)], capture_output=True, text=True, cwd=tmp_path, timeout=600, env=env)
    assert done.returncode == 1, done.stdout + done.stderr
    assert done.stderr == "" and "Traceback" not in done.stdout
    failed = [line for line in done.stdout.splitlines() if line.startswith("failed")]
    assert len(failed) == 1 and failed[0].startswith("failed verify: smoke rung"), done.stdout
    assert "ns-train nerfify-generated" not in done.stdout  # no invitation to train what failed
    assert not [line for line in done.stdout.splitlines() if line.startswith("done verify")]

    assert stage_statuses(out) == {"plan": "ran", "plugin": "ran", "verify": "failed", "train": "not run",
                                   "patches": "not run"}
    run = json.loads((out / "run.json").read_text())
    assert run["ok"] is False and run["failed"]["name"] == "verify" and "smoke rung" in run["failed"]["reason"]
    assert [s["reason"] for s in run["stages"] if s["name"] == "train"] == ["verify failed"]
    assert json.loads((out / "verify.json").read_text())["ok"] is False and not (out / "eval").exists()
    html = (out / "report.html").read_text()
    top = html[:html.index('<section id="paper">')]
    assert "verify failed: smoke rung" in top and 'class="headline fail"' in top
    assert json.loads((out / "report.json").read_text())["outcome"]["failed"]["name"] == "verify"
    assert not (tmp_path / "cache" / "generated" / "last.json").exists()  # a failed plugin is not made the default
