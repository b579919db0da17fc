"""Run Nerfstudio's own ``ns-train`` and ``ns-eval`` in a separate process and read what they logged.

Training never runs in our process: a subprocess with a time limit, no network (``unshare -n``
where available) and its working directory inside the output folder. Results (iterations reached,
losses, rays per second) are read back from the run's own tensorboard events and files, never
from text printed by a generator.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

from nerfify_ns.runtime.errors import RuntimeLayerError


class TrainLaunchError(RuntimeLayerError):
    """ns-train or ns-eval could not be run, or produced nothing usable."""


@dataclass
class TrainRun:
    """What one ``ns-train`` process did, read from its own outputs."""

    method: str
    returncode: int
    wall_seconds: float
    log_path: Path
    run_dir: Optional[Path] = None
    config_path: Optional[Path] = None
    timed_out: bool = False
    losses: Dict[int, float] = field(default_factory=dict)
    """Train loss per logged step."""
    rays_per_sec: List[float] = field(default_factory=list)
    """Nerfstudio's per-step ``Train Rays / Sec`` (steps after the first two)."""

    @property
    def last_step(self) -> int:
        return max(self.losses) if self.losses else -1

    @property
    def finite(self) -> bool:
        return bool(self.losses) and all(math.isfinite(v) for v in self.losses.values())

    @property
    def median_rays_per_sec(self) -> Optional[float]:
        if not self.rays_per_sec:
            return None
        values = sorted(self.rays_per_sec)
        return values[len(values) // 2]

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and not self.timed_out and self.finite

    def log_tail(self, lines: int = 25) -> str:
        text = self.log_path.read_text(errors="replace") if self.log_path.exists() else ""
        return "\n".join(text.splitlines()[-lines:])


def _bin(name: str) -> str:
    """The console script ``name`` of the interpreter we run under."""
    candidate = Path(sys.executable).with_name(name)
    return str(candidate) if candidate.exists() else (shutil.which(name) or name)


def offline_prefix() -> List[str]:
    """``unshare -n`` (a process with no network) when we may use it, else nothing."""
    unshare = shutil.which("unshare")
    if unshare and hasattr(os, "geteuid") and os.geteuid() == 0:
        return [unshare, "-n"]
    return []


def _run(cmd: Sequence[str], log_path: Path, cwd: Path, timeout: float, env: Optional[dict]) -> tuple[int, float, bool]:
    start = time.perf_counter()
    full_env = dict(os.environ, **(env or {}))
    full_env.setdefault("PYTHONWARNINGS", "ignore::FutureWarning,ignore::UserWarning")
    with open(log_path, "w") as log:
        proc = subprocess.Popen(list(cmd), stdout=log, stderr=subprocess.STDOUT, cwd=cwd, env=full_env,
                                start_new_session=True)
        try:
            code = proc.wait(timeout=timeout)
            return code, time.perf_counter() - start, False
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, 9)
            proc.wait()
            return -9, time.perf_counter() - start, True


def read_events(run_dir: Path) -> tuple[Dict[int, float], List[float]]:
    """Train loss per step and per-step rays/s from the run's tensorboard event files."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    losses: Dict[int, float] = {}
    rays: List[float] = []
    for events in sorted(run_dir.glob("events.out.tfevents.*")):
        acc = EventAccumulator(str(events), size_guidance={"scalars": 0})
        acc.Reload()
        tags = acc.Tags().get("scalars", [])
        if "Train Loss" in tags:
            losses.update({e.step: e.value for e in acc.Scalars("Train Loss")})
        if "Train Rays / Sec" in tags:
            rays.extend(e.value for e in acc.Scalars("Train Rays / Sec"))
    return losses, rays


def ns_train(
    method: str,
    data: Path,
    out_dir: Path,
    *,
    iterations: int,
    method_args: Sequence[str] = (),
    dataparser: str = "blender-data",
    dataparser_args: Sequence[str] = (),
    timeout: float = 900,
    env: Optional[dict] = None,
    offline: bool = True,
) -> TrainRun:
    """Train ``method`` on ``data`` with Nerfstudio's trainer in a subprocess."""
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    cmd = [
        *(offline_prefix() if offline else []),
        _bin("ns-train"), method,
        "--data", str(Path(data).resolve()),
        "--output-dir", str(out_dir),
        "--experiment-name", "run",
        "--timestamp", "run",
        "--max-num-iterations", str(iterations),
        "--vis", "tensorboard",
        "--logging.steps-per-log", "1",
        "--viewer.quit-on-train-completion", "True",
        *method_args,
        dataparser, *dataparser_args,
    ]
    log_path = out_dir / f"{method}.train.log"
    code, seconds, timed_out = _run(cmd, log_path, out_dir, timeout, env)
    run = TrainRun(method=method, returncode=code, wall_seconds=seconds, log_path=log_path, timed_out=timed_out)
    run_dir = out_dir / "run" / method / "run"
    if run_dir.is_dir():
        run.run_dir = run_dir
        config = run_dir / "config.yml"
        run.config_path = config if config.exists() else None
        run.losses, run.rays_per_sec = read_events(run_dir)
    return run


def headline_metrics(results: dict) -> Dict[str, Optional[float]]:
    """PSNR, SSIM and LPIPS of an ``ns-eval`` result; coarse-to-fine models report the fine ones."""
    def pick(name: str) -> Optional[float]:
        return results.get(f"fine_{name}", results.get(name))

    return {"psnr": pick("psnr"), "ssim": pick("ssim"), "lpips": pick("lpips")}


def ns_eval(config_path: Path, output_path: Path, *, timeout: float = 900, env: Optional[dict] = None) -> dict:
    """Evaluate a trained run with ``ns-eval``; returns its headline metrics (LPIPS ``None`` when unavailable)
    merged over all of ``results``."""
    output_path = Path(output_path).resolve()
    cmd = [*offline_prefix(), _bin("ns-eval"), "--load-config", str(config_path), "--output-path", str(output_path)]
    log_path = output_path.with_suffix(".log")
    code, _, timed_out = _run(cmd, log_path, output_path.parent, timeout, env)
    if code != 0 or timed_out or not output_path.exists():
        tail = "\n".join(log_path.read_text(errors="replace").splitlines()[-15:])
        raise TrainLaunchError(f"ns-eval failed for {config_path} (exit {code}, timed out: {timed_out}):\n{tail}")
    results = json.loads(output_path.read_text())["results"]
    return {**results, **headline_metrics(results)}
