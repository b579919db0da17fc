"""SIGINT and SIGTERM end any command cleanly: every child process group we started is
stopped (training, its data workers, the sandboxed smoke rung), the staging folder is removed, one
``interrupted:`` line is printed (no traceback), the exit code is 130 or 143, and a rerun works.

The real CLI runs in a subprocess; the tests wait until the work they interrupt has started (a training
process in the test's folder, or the staging folder), send the signal, and then look for survivors by walking
/proc for processes whose working directory or command line points into the test's folder. Two of them train
for real (the smoke rung of compose, the training stage of the main job); the others are quick.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CLI = Path(sys.executable).with_name("ns-nerfify")
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"


def processes_in(folder: Path) -> list[tuple[int, str]]:
    """Live processes (zombies aside) whose working directory or command line points into ``folder``."""
    found, root = [], str(folder)
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            try:
                cwd = os.readlink(entry / "cwd")
            except OSError:
                cwd = ""
        except (OSError, IndexError):
            continue
        if state != "Z" and (root in cmdline or cwd == root or cwd.startswith(root + "/")):
            found.append((int(entry.name), cmdline.strip()))
    return found


def wait_for(condition: Callable[[], object], timeout: float, what: str, proc: subprocess.Popen = None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        if proc is not None and proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"the command ended (exit {proc.returncode}) before {what}:\n{out[-3000:]}\n{err[-3000:]}")
        time.sleep(0.2)
    pytest.fail(f"timed out after {timeout} s waiting for {what}")


def start(args: list[str], cwd: Path) -> subprocess.Popen:
    """The CLI in a session of its own (the signal goes to it alone, as ``kill PID`` sends it)."""
    return subprocess.Popen([str(CLI), *args], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def training_in(folder: Path, marker: str) -> Callable[[], list[tuple[int, str]]]:
    return lambda: [p for p in processes_in(folder) if "ns-train" in p[1] and marker in p[1]]


def assert_interrupted_cleanly(proc: subprocess.Popen, signum: int, folder: Path) -> str:
    """Exit 128 + signum, one ``interrupted:`` line and no traceback, no staging or trash folder, no survivor."""
    out, err = proc.communicate(timeout=120)
    text = out + err
    assert proc.returncode == 128 + signum, text[-3000:]
    assert "Traceback" not in text and "KeyboardInterrupt" not in text, text[-3000:]
    name = signal.Signals(signum).name
    interrupted = [line for line in text.splitlines() if line.startswith("interrupted:")]
    assert len(interrupted) == 1 and interrupted[0].startswith(f"interrupted: {name}"), text[-3000:]
    assert text.strip().splitlines()[-1] == interrupted[0]
    debris = [p for p in folder.rglob(".*") if ".partial-" in p.name or ".old-" in p.name]
    assert debris == []
    deadline = time.monotonic() + 10
    while processes_in(folder) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert processes_in(folder) == []
    return interrupted[0]


@pytest.mark.slow
@pytest.mark.bench  # the same interrupt path as the main job's SIGTERM test, which CI keeps
def test_sigint_during_the_sandboxed_smoke_rung_of_compose(tmp_path):
    """Ctrl-C while the verification ladder smoke-trains the plugin in its sandbox (a child in a session of its
    own, which the terminal's SIGINT does not reach): the sandboxed training is stopped, nothing is written."""
    out = tmp_path / "nerfacto"
    proc = start(["compose", "--method", "nerfacto", "--out", str(out)], tmp_path)
    try:
        wait_for(training_in(tmp_path, "nerfify-generated"), 300, "the smoke rung's training", proc)
        time.sleep(3)  # well into it: the trainer and its data loading are running
        proc.send_signal(signal.SIGINT)
        line = assert_interrupted_cleanly(proc, signal.SIGINT, tmp_path)
    finally:
        proc.kill()
    assert "stopped 1 child process group" in line and "removed 1 unfinished output folder" in line
    assert not out.exists() and not (tmp_path / "nerfify-out").exists()

    again = subprocess.run([str(CLI), "compose", "--method", "nerfacto", "--out", str(out), "--until", "plugin"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stdout + again.stderr
    assert (out / "nerfacto_ref" / "model.py").is_file()


@pytest.mark.slow
def test_sigterm_during_training_of_the_main_job(tmp_path):
    """``kill PID`` while ``ns-nerfify PAPER`` trains the plugin (ns-train and its data workers): all of them
    stop, the staging folder goes, exit 143; a rerun works."""
    out = tmp_path / "nerfify-out" / "gridlite"
    proc = start([str(EXAMPLE)], tmp_path)
    try:
        wait_for(training_in(tmp_path, "/eval/train"), 480, "the training stage", proc)
        tree = wait_for(lambda: (lambda t: t if any("ns-train" not in cmd for _, cmd in t) else None)(
            [p for p in processes_in(tmp_path) if p[0] != proc.pid]), 120, "ns-train's data worker", proc)
        proc.send_signal(signal.SIGTERM)
        line = assert_interrupted_cleanly(proc, signal.SIGTERM, tmp_path)
    finally:
        proc.kill()
    assert any("ns-train" in cmd for _, cmd in tree) and any("ns-train" not in cmd for _, cmd in tree), tree
    assert "stopped 1 child process group" in line
    assert not out.exists()

    again = subprocess.run([str(CLI), str(EXAMPLE), "--until", "plan"], cwd=tmp_path, capture_output=True,
                           text=True, timeout=300)
    assert again.returncode == 0, again.stdout + again.stderr
    assert (out / "plan.yaml").is_file()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_interrupting_a_scene_being_rendered_leaves_nothing(signum, tmp_path):
    """No child processes here: the staging folder alone, removed; exit 130/143; a rerun works."""
    proc = start(["scene", "default", str(tmp_path / "scene"), "--resolution", "256", "--n-train", "100"], tmp_path)
    try:
        wait_for(lambda: list(tmp_path.glob(".scene.partial-*/train/r_0.png")), 120, "the first view", proc)
        proc.send_signal(signum)
        line = assert_interrupted_cleanly(proc, signum, tmp_path)
    finally:
        proc.kill()
    assert line == f"interrupted: {signal.Signals(signum).name}; removed 1 unfinished output folder"
    assert list(tmp_path.iterdir()) == []
    again = subprocess.run([str(CLI), "scene", "default", str(tmp_path / "scene"), "--resolution", "8",
                            "--n-train", "2", "--n-val", "1", "--n-test", "1"], capture_output=True, text=True,
                           timeout=120)
    assert again.returncode == 0 and (tmp_path / "scene" / "scene.json").is_file(), again.stdout + again.stderr


RUNNER = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from nerfify_ns import interrupts
    from nerfify_ns.atomic import atomic_dir
    from nerfify_ns.runtime.process import run_process

    def main():
        here = Path(sys.argv[1])
        with atomic_dir(here / "out") as staging:
            # a leader with two workers in its group, and a second group alongside
            (staging / "started").write_text("yes")
            run_process(["sh", "-c", "sleep 300 & sleep 300 & sh -c 'sleep 300' & wait"], staging / "a.log",
                        cwd=here, timeout=600, poll=lambda: run_process(
                            ["sh", "-c", "sleep 301"], staging / "b.log", cwd=here, timeout=600))

    interrupts.run_interruptible(main)
""")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_every_child_process_group_is_stopped(signum, tmp_path):
    """The process registry: two live groups (a leader with workers, and one started while the first runs),
    both stopped on the signal, the staging folder removed, one line on stderr, exit 130/143."""
    script = tmp_path / "runner.py"
    script.write_text(RUNNER)
    proc = subprocess.Popen([sys.executable, str(script), str(tmp_path)], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        wait_for(lambda: any("sleep 301" in c for _, c in processes_in(tmp_path)), 60, "both groups", proc)
        assert len([c for _, c in processes_in(tmp_path) if c.startswith("sleep 300")]) >= 2
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signum, err
    name = signal.Signals(signum).name
    assert err.strip() == f"interrupted: {name}; stopped 2 child process groups, removed 1 unfinished output folder"
    assert "Traceback" not in out + err
    deadline = time.monotonic() + 10
    while processes_in(tmp_path) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert processes_in(tmp_path) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runner.py"]


def test_a_signal_inside_a_held_block_waits_for_its_end():
    """What must not be cut in the middle (registering a child, renaming a finished folder) runs under held():
    the interrupt comes when the block ends; a second signal during the clean-up is ignored."""
    from nerfify_ns import interrupts

    interrupts.install()
    try:
        steps = []
        with pytest.raises(interrupts.Interrupted) as info:
            with interrupts.held():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.05)
                steps.append("after the signal")
            steps.append("not reached")
        assert steps == ["after the signal"] and info.value.exit_code == 143
        os.kill(os.getpid(), signal.SIGINT)  # already unwinding: ignored
        time.sleep(0.05)
        assert interrupts.received() == signal.SIGTERM
    finally:
        interrupts.reset()
