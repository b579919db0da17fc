"""The tiny suite end to end (bench lane: real pipeline runs and trainings, several minutes).

* Killed mid-way (SIGTERM to ``ns-nerfify bench``) and rerun: the finished task is not run again, the rest is.
* The same suite on a two-node local Ray cluster started here gives identical numbers (seeded: PSNR, SSIM, LPIPS
  per checkpoint and the novelty scores; wall-clock seconds aside).
* A suite with a missing paper file, an unknown reference method, a check that raises and a reference that fails to
  train: each a row failure with its reason, the rest of the suite runs.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nerfify_ns.nerfifybench import load_suite
from nerfify_ns.nerfifybench.run import run_bench

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "examples" / "bench" / "tiny.yaml"
pytestmark = [pytest.mark.slow, pytest.mark.bench]


def _numbers(results: dict) -> dict:
    """What must not depend on the executor: per task its status, metrics, curve values and novelty scores."""
    out = {}
    for key, r in results["tasks"].items():
        curve = r.get("curve") or {}
        out[key] = {"status": r["status"], **{m: (r.get("metrics") or {}).get(m) for m in ("psnr", "ssim", "lpips")},
                    "curve": [curve.get(k) for k in ("step", "psnr", "ssim", "loss")],
                    "novelty": (r.get("novelty") or {}).get("coverage")}
    return out


def _two_node_cluster(ray_cluster, attempts: int = 3):
    """A local Ray cluster of two nodes with one CPU each. Ray gives a node 30 s to register, which a loaded 2-core
    machine can miss: a failed start is shut down and tried again."""
    for attempt in range(attempts):
        cluster = ray_cluster.Cluster()
        try:
            cluster.add_node(num_cpus=1)  # the first node is the head
            cluster.add_node(num_cpus=1)
            return cluster
        except Exception:  # noqa: BLE001 - Ray's start-up timeout
            cluster.shutdown()
            if attempt == attempts - 1:
                raise


def test_tiny_killed_and_resumed_then_identical_on_ray(tmp_path):
    ray_cluster = pytest.importorskip("ray.cluster_utils")
    out = tmp_path / "local"
    cmd = [str(Path(sys.executable).with_name("ns-nerfify")), "bench", str(TINY), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    first = None
    deadline = time.time() + 1500
    while first is None and time.time() < deadline and proc.poll() is None:
        time.sleep(2)
        first = next(iter(out.glob("tasks/*/*/*/*/result.json")), None)
    assert first is not None, proc.stdout.read().decode()[-3000:] if proc.poll() is not None else "no task finished"
    os.kill(proc.pid, signal.SIGTERM)
    assert proc.wait(timeout=120) == 143
    finished_at = first.stat().st_mtime
    killed = [p for p in out.glob("tasks/*/*/*/*") if p.is_dir() and not (p / "result.json").is_file()]
    suite = load_suite(TINY)
    resumed = run_bench(suite, out)
    assert resumed.skipped == 1 and resumed.ran == 3 and first.stat().st_mtime == finished_at
    assert all((p / "result.json").is_file() for p in killed)  # the task cut short ran again from the start
    local = json.loads((out / "results.json").read_text())
    assert not local["failures"], local["failures"]

    from nerfify_ns.nerfifybench.executor import RayExecutor

    cluster = _two_node_cluster(ray_cluster)
    try:
        on_ray = run_bench(suite, tmp_path / "ray", executor=RayExecutor(cluster.address))
    finally:
        cluster.shutdown()
    assert on_ray.ran == 4
    remote = json.loads((tmp_path / "ray" / "results.json").read_text())
    assert remote["executor"] == "ray" and _numbers(remote) == _numbers(local)
    assert (tmp_path / "ray" / "tasks" / "gridlite" / "default" / "full" / "seed0" / "run" / "plan.yaml").is_file()
    assert (tmp_path / "ray" / "plots" / "gridlite-default-seed0.png").is_file()


FAILURES = """
budget: {iterations: 4, every: 2, rays: 64, resolution: 32, n_train: 6, n_test: 1}
papers:
  - id: missing
    input: missing.pdf
    scenes: [default]
    reference: kplanes
    novelty: []
  - id: raises
    input: gridlite_paper.md
    scenes: [default]
    reference: {method: depth-nerfacto, note: needs depth images the scene does not have}
    novelty:
      - {id: distortion, kind: loss, weight: 1.0, where: "Eq. 1", plan: model.losses.distortion, check: "checks.py:boom"}
"""  # noqa: E501


def test_every_kind_of_row_failure_and_the_rest_runs(tmp_path):
    tmp_path.chmod(0o755)  # the suite's folder is read by the sandbox's user (pytest makes it 700)
    shutil.copy(ROOT / "examples" / "gridlite_paper.md", tmp_path / "gridlite_paper.md")
    (tmp_path / "checks.py").write_text("def boom(target):\n    return {}['no such key']\n")
    (tmp_path / "suite.yaml").write_text(FAILURES)
    result = run_bench(load_suite(tmp_path / "suite.yaml"), tmp_path / "out")
    tables = (tmp_path / "out" / "tables.md").read_text()
    tasks = json.loads((tmp_path / "out" / "results.json").read_text())["tasks"]
    assert "missing.pdf" in tasks["missing/default/full/seed0"]["reason"]
    assert "ns-train kplanes" in tasks["missing/default/reference/seed0"]["reason"]
    assert "ns-train depth-nerfacto" in tasks["raises/default/reference/seed0"]["reason"]
    full = tasks["raises/default/full/seed0"]
    assert full["status"] == "ok" and full["executability"]["trains"]  # the rest of the suite ran
    assert "novelty check distortion raised: KeyError" in tables and len(result.failed) == 3
