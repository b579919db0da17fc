"""``--overwrite`` replaces only our own output: a folder carrying our marker (or a run folder written before the
marker existed), never ``/``, the home or current folder or one that holds them, nor a folder holding the run's
input. Everything else is one ``error:`` line, exit 2, nothing touched. A run removes the staging folders that a
killed run of the same output left (ours by name and marker), and nothing else."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from hostile_cli import assert_one_error, run_cli, snapshot

from nerfify_ns.atomic import MARKER, STAGING_MARKER, OverwriteRefused, atomic_dir, clean_leftovers, is_ours

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"
PLAN = ["compose", "--method", "nerfacto", "--until", "plan"]


def ours(folder: Path) -> Path:
    """A folder as a finished run leaves it (written through atomic_dir: it carries the marker)."""
    with atomic_dir(folder) as staging:
        (staging / "plan.yaml").write_text("method: old\n")
    return folder


def test_cwd_home_root_parent_and_foreign_folders_are_never_replaced(tmp_path):
    home = ours(tmp_path / "home")
    work = ours(home / "work")  # even carrying our marker: it is the current folder
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("years of work")
    before = snapshot(tmp_path)
    env = {"HOME": str(home)}
    for out, needle in ((".", "it is the current folder"), ("..", "it is your home folder"),
                        ("/", "the root folder is never an output folder"), (str(home), "it is your home folder"),
                        (str(tmp_path), "it holds your home folder"),
                        (str(foreign), "replaces only an output folder of nerfify-ns")):
        done = run_cli("scene", "default", out, "--overwrite", cwd=work, env=env)  # the lightest writer
        assert_one_error(done, needle, seconds=60)
        assert snapshot(tmp_path) == before, out


def test_a_folder_holding_the_input_paper_is_not_replaced(tmp_path):
    out = ours(tmp_path / "out")
    paper = out / "papers" / "gridlite.md"
    paper.parent.mkdir()
    shutil.copy(EXAMPLE, paper)
    before = snapshot(tmp_path)
    done = run_cli(str(paper), "--until", "plan", "--out", str(out), "--overwrite", cwd=tmp_path)
    assert_one_error(done, f"it holds this run's input {paper}")
    assert snapshot(tmp_path) == before


def test_our_own_output_is_replaced_and_a_killed_runs_staging_is_cleaned(tmp_path):
    out = ours(tmp_path / "out")
    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = tmp_path / f".out.partial-{dead.pid}-0123abcd"  # a SIGKILLed run's staging folder of this output
    stale.mkdir()
    (stale / STAGING_MARKER).write_text(json.dumps({"tool": "nerfify-ns", "pid": dead.pid, "start": "1"}))
    (stale / "half.txt").write_text("x")
    unmarked = tmp_path / f".out.partial-{dead.pid}-89abcdef"  # the same name pattern, no marker: not ours
    unmarked.mkdir()
    live = tmp_path / f".out.partial-{os.getpid()}-00000000"  # a live process's staging folder: in use
    live.mkdir()
    (live / STAGING_MARKER).write_text(json.dumps({"tool": "nerfify-ns", "pid": os.getpid()}))
    other = tmp_path / f".other.partial-{dead.pid}-11111111"  # another output's: not this run's business
    shutil.copytree(stale, other)
    done = run_cli(*PLAN, "--out", str(out), "--overwrite", cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (out / MARKER).is_file() and "method: nerfacto" in (out / "plan.yaml").read_text()
    assert not stale.exists() and unmarked.is_dir() and live.is_dir() and other.is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f".other.partial-{dead.pid}-11111111",
                                                                   unmarked.name, live.name, "out"])


def test_a_run_folder_from_before_the_marker_counts_as_ours(tmp_path):
    legacy = tmp_path / "legacy"
    legacy.mkdir()
    (legacy / "run.json").write_text(json.dumps({"ok": True, "stages": []}))
    (legacy / "plan.yaml").write_text("method: x\n")
    assert is_ours(legacy)
    (legacy / "plan.yaml").unlink()  # run.json alone is anyone's file name
    assert not is_ours(legacy)
    with pytest.raises(OverwriteRefused):
        with atomic_dir(legacy, overwrite=True):
            pass
    assert sorted(p.name for p in legacy.iterdir()) == ["run.json"]


def test_a_swap_cut_by_a_kill_is_put_back(tmp_path):
    dead = subprocess.Popen(["true"])
    dead.wait()
    moved = ours(tmp_path / "out").rename(tmp_path / f".out.old-{dead.pid}-0badf00d")  # killed mid-swap
    assert clean_leftovers(tmp_path / "out") == ["put back out (a killed run had moved it aside)"]
    assert not moved.exists() and (tmp_path / "out" / "plan.yaml").read_text() == "method: old\n"
