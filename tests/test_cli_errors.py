"""Hostile command lines get one ``error:`` line, exit 2 and nothing written: output paths
that cannot be written (a read-only folder, a parent that is a file, a symbolic link with --overwrite),
numbers out of their range, and plans whose method name is not a valid, unshadowed name."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
CLI = Path(sys.executable).with_name("ns-nerfify")
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"


def run_cli(*args: str, cwd: Path, prefix=()) -> subprocess.CompletedProcess:
    return subprocess.run([*prefix, str(CLI), *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def snapshot(folder: Path) -> dict:
    return {str(p.relative_to(folder)): (p.is_symlink(), p.is_file() and p.read_bytes())
            for p in sorted(folder.rglob("*"))}


def assert_one_error(done: subprocess.CompletedProcess, needle: str) -> None:
    lines = [line for line in (done.stdout + done.stderr).splitlines() if line.strip()]
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Traceback" not in done.stdout + done.stderr
    assert len([line for line in lines if line.startswith("error:")]) == 1 and lines[-1].startswith("error:"), lines
    assert needle in lines[-1], lines[-1]


def read_only_prefix(folder: Path) -> list:
    """A command prefix under which ``folder`` is read-only (a read-only bind mount: root ignores mode bits)."""
    if os.geteuid() != 0:
        folder.chmod(0o555)
        return []
    unshare = shutil.which("unshare")
    probe = subprocess.run([unshare, "-m", "true"], capture_output=True) if unshare else None
    if probe is None or probe.returncode != 0:
        pytest.skip("root without mount namespaces: no way to make a folder read-only for root")
    return [unshare, "-m", "sh", "-c", 'mount --bind "$0" "$0" && mount -o remount,bind,ro "$0" "$0" && '
            'exec "$@"', str(folder)]


@pytest.mark.parametrize("command", [
    ["compose", "--method", "nerfacto", "--until", "plan"],
    ["scene", "default"],
    ["demo"],
])
def test_out_under_a_read_only_folder(command, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    out = locked / "out"
    args = [*command, str(out)] if command[0] == "scene" else [*command, "--out", str(out)]
    done = run_cli(*args, cwd=tmp_path, prefix=read_only_prefix(locked))
    assert_one_error(done, "not writable (a read-only file system)" if os.geteuid() == 0 else "not writable")
    assert list(locked.iterdir()) == [] and sorted(p.name for p in tmp_path.iterdir()) == ["locked"]


def test_report_into_a_read_only_run_folder(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text("{}")
    done = run_cli("report", str(run), cwd=tmp_path, prefix=read_only_prefix(run))
    assert_one_error(done, f"cannot write into {run}")
    assert [p.name for p in run.iterdir()] == ["run.json"]


@pytest.mark.parametrize("command", [
    ["compose", "--method", "nerfacto", "--until", "plan", "--out"],
    [str(EXAMPLE), "--until", "plan", "--out"],
    ["scene", "default"],
    ["grammar"],
    ["verify", str(ROOT / "method_configs"), "--out"],
])
def test_out_under_a_regular_file(command, tmp_path):
    (tmp_path / "a-file").write_text("mine")
    done = run_cli(*command, str(tmp_path / "a-file" / "sub" / "out"), cwd=tmp_path)
    assert_one_error(done, f"{tmp_path / 'a-file'} is not a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"] and (tmp_path / "a-file").read_text() == "mine"


def test_symlinked_out_with_overwrite_is_refused_and_touches_nothing(tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    (real / "notes.txt").write_text("keep me")
    (tmp_path / "link").symlink_to(real)
    before = snapshot(tmp_path)
    done = run_cli("compose", "--method", "nerfacto", "--until", "plan", "--out", str(tmp_path / "link"),
                   "--overwrite", cwd=tmp_path)
    assert_one_error(done, "is a symbolic link")
    assert snapshot(tmp_path) == before  # no .link.old-*, no .link.partial-*, the target untouched


@pytest.mark.parametrize("args, needle", [
    (["--resolution", "0"], "resolution must be between 1 and 1024 pixels, got 0"),
    (["--resolution", "100000"], "resolution must be between 1 and 1024 pixels, got 100000"),
    (["--n-train", "-1"], "n_train (training views) must be between 1 and 1000, got -1"),
    (["--n-train", "0"], "n_train (training views) must be between 1 and 1000, got 0"),
    (["--n-test", "-3"], "n_test (test views) must be between 0 and 1000, got -3"),
    (["--seed", "-1"], "seed must be between 0 and 4294967295, got -1"),
])
def test_scene_numbers_out_of_range(args, needle, tmp_path):
    done = run_cli("scene", "default", str(tmp_path / "s"), *args, cwd=tmp_path)
    assert_one_error(done, needle)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, needle", [
    (["compose", "--method", "nerfacto", "--resolution", "0", "--until", "plan"], "resolution must be between"),
    (["compose", "--method", "nerfacto", "--iterations", "0"], "--iterations must be at least 1, got 0"),
    (["compose", "--method", "nerfacto", "--every", "-5"], "--every must be at least 1, got -5"),
    (["compose", "--method", "nerfacto", "--smoke-iterations", "0"], "--smoke-iterations must be at least 1"),
    (["compose", "--method", "nerfacto", "--patch-rounds", "-1"], "--patch-rounds must be at least 0, got -1"),
    ([str(EXAMPLE), "--iterations", "-1"], "--iterations must be at least 1, got -1"),
    (["demo", "--iterations", "0"], "--iterations must be at least 1, got 0"),
    (["verify", "PLUGIN", "--timeout", "0"], "--timeout must be a positive number of seconds"),
    (["verify", "PLUGIN", "--max-rounds", "0"], "--max-rounds must be at least 1, got 0"),
    (["verify", "PLUGIN", "--iterations", "-2"], "--iterations must be at least 1, got -2"),
])
def test_numeric_options_out_of_range(args, needle, tmp_path):
    if "PLUGIN" in args:
        (tmp_path / "plugin").mkdir()
    done = run_cli(*[str(tmp_path / "plugin") if a == "PLUGIN" else a for a in args], cwd=tmp_path)
    assert_one_error(done, needle)
    assert [p.name for p in tmp_path.iterdir()] == (["plugin"] if "PLUGIN" in args else [])
    assert "PLUGIN" not in args or list((tmp_path / "plugin").iterdir()) == []


@pytest.mark.parametrize("method, needle", [
    ("nerfacto", "shadows Nerfstudio's built-in method"),
    ("splatfacto", "shadows Nerfstudio's built-in method"),
    ("import", "a Python keyword"),
    ("class", "a Python keyword"),
    ("torch", "would shadow an installed module"),
    ("nerfify-generated", "shadows the installed Nerfstudio plugin 'nerfify-generated'"),
])
def test_plan_method_names_that_cannot_name_a_plugin(method, needle, tmp_path):
    plan = yaml.safe_load((ROOT / "method_configs" / "nerfacto.yaml").read_text())
    plan["method"] = method
    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(plan))
    done = run_cli("compose", "plan.yaml", "--until", "plan", cwd=tmp_path)
    assert_one_error(done, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.yaml"]


def test_the_novel_parts_line_counts_a_part_once_however_many_sections_name_it(monkeypatch):
    """Two holes at one slot (two sections of the paper about the renderer) are one part, as the equations stage and
    the report count them: 3 found, 1 built, not 4."""
    from types import SimpleNamespace

    from rich.console import Console

    from nerfify_ns import cli

    console = Console(record=True, width=200)
    monkeypatch.setattr(cli, "CONSOLE", console)
    holes = [{"slot": "model.renderer", "status": "not implemented"},
             {"slot": "model.renderer", "status": "not implemented"},
             {"slot": "model.schedule_hooks", "status": "implemented"},
             {"slot": "model.field.MLPField.backbone", "status": "not implemented"}]
    cli._novel_line(SimpleNamespace(plan={"holes": holes}, derived=None))
    text = console.export_text()
    assert "3 novel part(s) found, 1 built from the paper; 2 stand(s) on the base's part" in text
