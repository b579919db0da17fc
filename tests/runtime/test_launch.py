"""The one Nerfstudio-run layer: command lines, run layout, the events reader, the process runner (timeouts
kill the whole process group), the progress hook, and the one name of the generated method."""

from __future__ import annotations

import ast
import os
import sys
import textwrap
import time
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest

import nerfify_ns
from nerfify_ns.runtime import events as ev
from nerfify_ns.runtime.launch import GENERATED_METHOD, RunLayout, eval_command, progress_poll, train_command
from nerfify_ns.runtime.process import TIMEOUT_CODE, run_process

# A stand-in for a training: logs one Train Loss per step to tensorboard events in RUN_DIR, then exits.
FAKE_TRAINING = textwrap.dedent("""
    import sys, time
    from torch.utils.tensorboard import SummaryWriter
    writer = SummaryWriter(sys.argv[1])
    for step in range(int(sys.argv[2])):
        writer.add_scalar("Train Loss", 1.0 / (step + 1), step)
        writer.add_scalar("Train Rays / Sec", 100.0 + step, step)
        writer.flush()
        time.sleep(float(sys.argv[3]))
    writer.close()
""")


def _alive(pid: int) -> bool:
    """Running (a killed orphan may stay a zombie until PID 1 reaps it: that is not alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return not (stat.exists() and stat.read_text().rsplit(")", 1)[1].split()[0] in ("Z", "X"))


def test_train_command_and_layout(tmp_path):
    layout = RunLayout(tmp_path / "out", "nerfacto")
    cmd = train_command("nerfacto", tmp_path / "scene", layout, iterations=7, method_args=["--machine.seed", "3"],
                        dataparser="blender-data", dataparser_args=["--scale-factor", "1.0"], prefix=["unshare", "-n"])
    assert cmd[:2] == ["unshare", "-n"] and Path(cmd[2]).name == "ns-train" and cmd[3] == "nerfacto"
    pairs = dict(zip(cmd[4::2], cmd[5::2], strict=False))
    assert pairs["--data"] == str((tmp_path / "scene").resolve()) and pairs["--max-num-iterations"] == "7"
    assert pairs["--output-dir"] == str(tmp_path / "out") and pairs["--vis"] == "tensorboard"
    assert cmd[-3:] == ["blender-data", "--scale-factor", "1.0"]
    assert cmd.index("--machine.seed") > cmd.index("--viewer.quit-on-train-completion")  # presets after ours
    assert layout.run_dir == tmp_path / "out" / "run" / "nerfacto" / "run"
    assert layout.config == layout.run_dir / "config.yml" and layout.checkpoints.name == "nerfstudio_models"
    assert layout.log == tmp_path / "out" / "nerfacto.train.log"
    assert RunLayout(tmp_path, GENERATED_METHOD, log_name="train.log").log == tmp_path / "train.log"
    ecmd = eval_command(layout.config, tmp_path / "eval.json")
    assert Path(ecmd[0]).name == "ns-eval" and ecmd[1:] == ["--load-config", str(layout.config),
                                                            "--output-path", str(tmp_path / "eval.json")]


def test_events_reader_is_incremental(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(tmp_path))
    writer.add_text("config", "{'_target': ...}", 0)  # Nerfstudio logs its config as text: not a scalar
    for step in range(3):
        writer.add_scalar("Train Loss", 1.0 / (step + 1), step)
    writer.add_histogram("weights", np.array([0.1, 0.2, 0.3]), 0)
    writer.flush()
    reader = ev.EventReader(tmp_path)
    assert ev.losses(reader.poll()) == {0: 1.0, 1: 0.5, 2: pytest.approx(1 / 3)}
    assert set(reader.scalars) == {"Train Loss"}
    assert reader.last_step() == 2
    for step in range(3, 5):
        writer.add_scalar("Train Loss", 1.0 / (step + 1), step)
        writer.add_scalar("Train Rays / Sec", 10.0 * step, step)
    writer.close()
    scalars = reader.poll()
    assert sorted(ev.losses(scalars)) == [0, 1, 2, 3, 4] and ev.rays_per_sec(scalars) == [30.0, 40.0]
    assert ev.read_scalars(tmp_path) == scalars and ev.read_scalars(tmp_path / "absent") == {}


def test_timeout_kills_the_whole_process_group(tmp_path):
    pid_file = tmp_path / "grandchild.pid"
    code = (f"import subprocess, sys, time\n"
            f"p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(120)'])\n"
            f"open({str(pid_file)!r}, 'w').write(str(p.pid))\nprint('started', flush=True)\ntime.sleep(120)\n")
    result = run_process([sys.executable, "-c", code], tmp_path / "log.txt", cwd=tmp_path, timeout=5)
    assert result.timed_out and result.returncode == TIMEOUT_CODE and result.seconds < 30
    assert "started" in result.tail()
    time.sleep(0.5)
    assert not _alive(int(pid_file.read_text())), "the grandchild outlived the timeout"


def test_failing_poll_hook_kills_the_run_and_propagates(tmp_path):
    pid_file = tmp_path / "child.pid"
    code = f"import os, time\nopen({str(pid_file)!r}, 'w').write(str(os.getpid()))\ntime.sleep(120)\n"

    def poll():
        if pid_file.exists():
            raise KeyboardInterrupt  # what Ctrl-C in a progress bar looks like

    with pytest.raises(KeyboardInterrupt):
        run_process([sys.executable, "-c", code], tmp_path / "log.txt", cwd=tmp_path, timeout=60, poll=poll,
                    poll_seconds=0.2)
    assert not _alive(int(pid_file.read_text()))


def test_progress_hook_follows_the_events(tmp_path):
    run_dir = tmp_path / "run" / "m" / "run"
    seen = []
    poll = progress_poll(run_dir, 6, lambda step, total: seen.append((step, total)))
    result = run_process([sys.executable, "-c", FAKE_TRAINING, str(run_dir), "6", "0.4"], tmp_path / "log.txt",
                         cwd=tmp_path, timeout=120, poll=poll, poll_seconds=0.2)
    poll()
    assert result.returncode == 0, result.tail()
    steps = [s for s, _ in seen]
    assert steps == sorted(set(steps)) and steps[-1] == 6 and {t for _, t in seen} == {6}
    assert len(steps) >= 3, f"progress was reported only at {steps}"
    assert progress_poll(run_dir, 6, None) is None


def test_one_name_for_the_generated_method():
    """The entry point is named by the constant, and no module of the package spells the name again."""
    (ep,) = [e for e in entry_points(group="nerfstudio.method_configs") if e.value.startswith("nerfify_ns.")]
    assert ep.name == GENERATED_METHOD
    root = Path(nerfify_ns.__file__).parent
    spelled = [str(p.relative_to(root)) for p in root.rglob("*.py")
               if p.name != "launch.py" and any(isinstance(n, ast.Constant) and n.value == GENERATED_METHOD
                                               for n in ast.walk(ast.parse(p.read_text())))]
    assert spelled == []
