"""Smoke training: a short real ``ns-train`` run plus ``ns-eval`` on a small scene, on the CPU.

Reference methods are shrunk with the presets in ``runtime/smoke_presets.yaml`` (ns-train
arguments, applied exactly as a user would type them).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Dict, List, Optional

import yaml

from nerfify_ns.errors import NerfifyError
from nerfify_ns.runtime.launch import ENV_GENERATED, GENERATED_METHOD, ProgressHook, TrainRun, ns_eval, ns_train


class SmokeTrainError(NerfifyError):
    """A smoke run did not reach its iterations with finite losses."""

    def __init__(self, method: str, reason: str, log_path: Path) -> None:
        super().__init__(f"smoke training of {method} failed ({reason}); see the log {log_path}")
        self.method, self.reason, self.log_path = method, reason, log_path

    def with_log(self, log_path: Path) -> "SmokeTrainError":
        """The same failure, pointing at a copy of its log kept elsewhere."""
        return SmokeTrainError(self.method, self.reason, log_path)


@lru_cache(maxsize=1)
def smoke_presets() -> Dict[str, dict]:
    text = resources.files("nerfify_ns.runtime").joinpath("smoke_presets.yaml").read_text()
    return yaml.safe_load(text)


def preset_args(method: str) -> List[str]:
    """The ns-train arguments that shrink ``method`` for a small CPU scene (none if unknown)."""
    return [str(a) for a in smoke_presets().get(method, {}).get("args", [])]


GENERATED = GENERATED_METHOD
"""The generated method (re-exported from :mod:`nerfify_ns.runtime.launch`, its one home)."""


def generated_smoke_args(base: str) -> List[str]:
    """ns-train arguments for a generated plugin derived from ``base`` on a small CPU scene: the pipeline
    and ray-batch arguments of the base's preset and no mixed precision. Model arguments are left out:
    the plugin's sizes come from its plan, already pruned for the scene."""
    args, out, i = preset_args(base), [], 0
    while i < len(args):
        flag, values = args[i], []
        i += 1
        while i < len(args) and not args[i].startswith("--"):
            values.append(args[i])
            i += 1
        if flag.startswith("--pipeline.") and not flag.startswith("--pipeline.model."):
            out += [flag, *values]
    return [*out, "--mixed-precision", "False"]


def generated_env(plugin_dir: Path) -> dict:
    """The environment under which ``GENERATED_METHOD`` is the plugin in ``plugin_dir``."""
    return {**os.environ, ENV_GENERATED: str(Path(plugin_dir).absolute())}


@dataclass
class SmokeResult:
    run: TrainRun
    metrics: Optional[dict]

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
    data: Path,
    out_dir: Path,
    *,
    iterations: int = 100,
    extra_args: List[str] | None = None,
    evaluate: bool = True,
    timeout: float = 900,
    env: Optional[dict] = None,
    on_progress: Optional[ProgressHook] = None,
) -> SmokeResult:
    """Train ``method`` for ``iterations`` on ``data`` and evaluate it; raises when it failed.
    ``on_progress(step, total)`` is called while it trains."""
    run = ns_train(method, data, out_dir, iterations=iterations,
                   method_args=[*preset_args(method), *(extra_args or [])], timeout=timeout, env=env,
                   on_progress=on_progress)
    if not run.ok or run.last_step + 1 < iterations:
        reason = "timed out" if run.timed_out else f"exit code {run.returncode}, reached step {run.last_step}"
        raise SmokeTrainError(method, reason, run.log_path)
    metrics = ns_eval(run.config_path, out_dir / "eval.json", timeout=timeout, env=env) if evaluate else None
    return SmokeResult(run=run, metrics=metrics)
