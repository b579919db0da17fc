"""SIGTERM to ``ns-nerfify bench --ray`` while its tasks wait on the local cluster it started: one
``interrupted:`` line, exit 143, and the cluster's processes (raylet, GCS, workers) gone; no native stack dump."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

CLI = Path(sys.executable).with_name("ns-nerfify")
SUITE = """
budget: {iterations: 2, every: 1, resolution: 16, n_train: 4, n_test: 1, cpus: 64}
papers:
  - id: waits
    input: paper.md
    scenes: [default]
    reference: {method: nerfacto}
    novelty:
      - {id: a, kind: equation, weight: 1.0, where: "Eq. 1"}
"""


def _descendants(pid: int) -> dict:
    """pid -> command line of every process below ``pid``."""
    children: dict = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
            cmd = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        children.setdefault(int(stat.rsplit(")", 1)[1].split()[1]), []).append((int(entry), cmd))
    found, todo = {}, [pid]
    while todo:
        for child, cmd in children.get(todo.pop(), []):
            found[child] = cmd
            todo.append(child)
    return found


@pytest.mark.slow
def test_sigterm_stops_the_cluster_it_started_and_exits_143(tmp_path):
    pytest.importorskip("ray")
    (tmp_path / "suite.yaml").write_text(SUITE)  # 64 CPUs per task: it waits on this machine's cluster
    (tmp_path / "paper.md").write_text("# A paper\n")
    ray_tmp = tempfile.mkdtemp(prefix="r", dir="/tmp")  # Ray's socket paths must stay under 108 bytes
    env = {**os.environ, "RAY_TMPDIR": ray_tmp, "RAY_USAGE_STATS_ENABLED": "0"}
    try:
        _interrupt(tmp_path, env)
    finally:
        shutil.rmtree(ray_tmp, ignore_errors=True)


def _interrupt(tmp_path: Path, env: dict) -> None:
    proc = subprocess.Popen([str(CLI), "bench", "suite.yaml", "--ray", "--out", "out"], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline, ray_procs = time.monotonic() + 120, {}
    while time.monotonic() < deadline and proc.poll() is None:
        ray_procs = {p: c for p, c in _descendants(proc.pid).items() if "raylet" in c or "gcs_server" in c}
        if any("raylet" in c for c in ray_procs.values()) and (tmp_path / "out").is_dir():
            break
        time.sleep(0.5)
    if proc.poll() is not None:
        out, err = proc.communicate()
        if "cannot start or reach the Ray cluster" in out + err:  # a loaded machine: Ray's own 30-s start limit
            pytest.skip(f"Ray could not start a local cluster here: {(out + err).strip()[:200]}")
    assert ray_procs and proc.poll() is None, proc.communicate()
    time.sleep(3)  # the task submitted and waiting
    ray_procs = _descendants(proc.pid)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=90)
    lines = [line for line in (out + err).splitlines() if line.strip()]
    assert proc.returncode == 143, out + err
    assert lines == ["interrupted: SIGTERM; stopped the Ray cluster it started"], lines
    for _ in range(100):
        alive = [p for p in ray_procs if Path(f"/proc/{p}").exists()
                 and "Z" not in Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0]]
        if not alive:
            break
        time.sleep(0.2)
    assert not alive, {p: ray_procs[p] for p in alive}
