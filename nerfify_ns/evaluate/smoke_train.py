"""Smoke training: a short real ``ns-train`` run plus ``ns-eval`` on a small scene, on the CPU.

Reference methods are shrunk with their CPU presets (:mod:`nerfify_ns.runtime.presets`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from nerfify_ns.budget import Limit
from nerfify_ns.dataset import DataLike
from nerfify_ns.errors import NerfifyError
from nerfify_ns.runtime.launch import ENV_GENERATED, GENERATED_METHOD, ProgressHook, TrainRun, ns_eval, ns_train
from nerfify_ns.runtime.presets import preset_args


class SmokeTrainError(NerfifyError):
    """A smoke run did not reach its iterations with finite losses."""

    def __init__(self, method: str, reason: str, log_path: Path) -> None:
        super().__init__(f"smoke training of {method} failed ({reason}); see the log {log_path}")
        self.method, self.reason, self.log_path = method, reason, log_path

    def with_log(self, log_path: Path) -> SmokeTrainError:
        """The same failure, pointing at a copy of its log kept elsewhere."""
        return SmokeTrainError(self.method, self.reason, log_path)


GENERATED = GENERATED_METHOD
"""The generated method (re-exported from :mod:`nerfify_ns.runtime.launch`, its one home)."""


def generated_env(plugin_dir: Path) -> dict:
    """The environment under which ``GENERATED_METHOD`` is the plugin in ``plugin_dir``."""
    return {**os.environ, ENV_GENERATED: str(Path(plugin_dir).absolute())}


@dataclass
class SmokeResult:
    run: TrainRun
    metrics: dict | None

    def summary(self) -> dict:
        metrics = self.metrics or {}
        return {
            "method": self.run.method,
            "iterations": self.run.last_step + 1,
            "final_loss": self.run.losses.get(self.run.last_step),
            "train_seconds": round(self.run.wall_seconds, 1),
            "rays_per_sec": self.run.median_rays_per_sec,
            "psnr": metrics.get("psnr"),
            "ssim": metrics.get("ssim"),
            "lpips": metrics.get("lpips"),
            "config": str(self.run.config_path) if self.run.config_path else None,
        }


def smoke_train(
    method: str,
    data: DataLike,
    out_dir: Path,
    *,
    iterations: int = 100,
    extra_args: list[str] | None = None,
    evaluate: bool = True,
    timeout: float | None = None,
    env: dict | None = None,
    on_progress: ProgressHook | None = None,
) -> SmokeResult:
    """Train ``method`` for ``iterations`` on ``data`` and evaluate it; raises when it failed.
    ``on_progress(step, total)`` is called while it trains. ``timeout``: the caller's limit on the training and on
    the evaluation, seconds (None: none), named with the progress made when it is reached."""
    limit = Limit(timeout, "the caller's timeout" if timeout is not None else "none")
    run = ns_train(method, data, out_dir, iterations=iterations,
                   method_args=[*preset_args(method), *(extra_args or [])], timeout=limit.timeout, env=env,
                   on_progress=on_progress)
    if not run.ok or run.last_step + 1 < iterations:
        reason = (f"stopped at {run.last_step + 1} of {iterations} iterations: {limit.describe()}" if run.timed_out
                  else f"exit code {run.returncode}, reached step {run.last_step}")
        raise SmokeTrainError(method, reason, run.log_path)
    metrics = ns_eval(run.config_path, out_dir / "eval.json", timeout=limit.timeout, env=env) if evaluate else None
    return SmokeResult(run=run, metrics=metrics)
