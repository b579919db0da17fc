"""The whole nerfify flow on one screen.

    paper -> knowledge -> plan (grammar) -> prune for the scene -> compose plugin -> verify -> train/evaluate -> report

``run_compose`` starts from a plan (a file or a reference plan); ``run_demo`` smoke-trains a
built-in method. Every run writes its output folder atomically.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

from nerfify_ns.atomic import OutputExistsError, atomic_dir  # noqa: F401  (OutputExistsError re-exported)
from nerfify_ns.evaluate.smoke import (GENERATED, SmokeResult, SmokeTrainError, generated_env, generated_smoke_args,
                                       smoke_train)
from nerfify_ns.grammar import validate
from nerfify_ns.scenes import write_scene
from nerfify_ns.synthesis.compose import ComposedPlugin, write_plugin
from nerfify_ns.synthesis.prune import adopt_scene, prune_plan
from nerfify_ns.synthesis.registry import record_generated
from nerfify_ns.synthesis.scene_probe import probe_scene

Progress = Callable[[str], None]


@dataclass
class DemoResult:
    out: Path
    scene: Path
    smoke: SmokeResult


@dataclass
class ComposeResult:
    out: Path
    plugin: ComposedPlugin
    plan: dict
    smoke: Optional[SmokeResult]


def run_compose(
    plan: dict,
    out: Path,
    *,
    data: Optional[Path] = None,
    scene: str = "default",
    iterations: int = 100,
    keep_all: bool = False,
    train: bool = True,
    overwrite: bool = False,
    progress: Progress = lambda stage: None,
) -> ComposeResult:
    """Plan -> validate -> prune for the scene -> generate the plugin into ``out`` -> smoke-train it."""
    final = Path(out).absolute()
    with atomic_dir(out, overwrite) as staging:
        progress("validating the plan against the grammar")
        validate(plan)
        if data is None:
            progress(f"rendering scene '{scene}'")
            data = write_scene(scene, staging / "smoke" / "scene")
        facts = probe_scene(data)
        plan = adopt_scene(plan, facts) if keep_all else prune_plan(plan, facts)
        progress(f"generating the plugin '{plan['method']}'")
        plugin = write_plugin(plan, staging)
        smoke = None
        if train:
            progress(f"smoke-training {plan['method']} for {iterations} iterations with Nerfstudio's trainer")
            smoke = _smoke(plan, staging, data, iterations)
            _point_config_at(smoke, staging, final)
            _rebase(smoke, staging, final)
            (staging / "smoke" / "summary.json").write_text(json.dumps(smoke.summary(), indent=2))
    record_generated(final)
    plugin.out = final
    return ComposeResult(out=final, plugin=plugin, plan=plan, smoke=smoke)


def _smoke(plan: dict, plugin_dir: Path, data: Path, iterations: int) -> SmokeResult:
    try:
        return smoke_train(GENERATED, data, plugin_dir / "smoke", iterations=iterations,
                           extra_args=generated_smoke_args(plan["base"]), env=generated_env(plugin_dir))
    except SmokeTrainError as exc:
        raise exc.with_log(_keep_log(exc.log_path, plan["method"])) from None


def _keep_log(log_path: Path, name: str) -> Path:
    """A copy of a failed run's log outside the staging folder, which is about to go."""
    kept = Path(tempfile.gettempdir()) / f"nerfify-{name}-failed.log"
    shutil.copy(log_path, kept)
    return kept


def run_demo(
    out: Path,
    *,
    method: str = "nerfacto",
    scene: str = "default",
    data: Optional[Path] = None,
    iterations: int = 100,
    overwrite: bool = False,
    progress: Progress = lambda stage: None,
) -> DemoResult:
    """Make (or take) a scene, smoke-train ``method`` on it on the CPU, evaluate, write ``out``."""
    final = Path(out).absolute()
    with atomic_dir(out, overwrite) as staging:
        if data is None:
            progress(f"rendering scene '{scene}'")
            data = write_scene(scene, staging / "scene")
        progress(f"training {method} for {iterations} iterations with Nerfstudio's trainer")
        try:
            result = smoke_train(method, data, staging / "train", iterations=iterations)
        except SmokeTrainError as exc:
            raise exc.with_log(_keep_log(exc.log_path, method)) from None
        _point_config_at(result, staging, final)
        scene_path = final / "scene" if data.is_relative_to(staging) else data
        _rebase(result, staging, final)
        (staging / "summary.json").write_text(json.dumps(result.summary(), indent=2))
    return DemoResult(out=final, scene=scene_path, smoke=result)


def _point_config_at(result: SmokeResult, staging: Path, final: Path) -> None:
    """Rewrite the run's saved Nerfstudio config for the folder it will have after the rename."""
    config = result.run.config_path
    if config is not None and config.exists():
        # Nerfstudio stores paths as lists of parts; staging and final differ in one part (same parent).
        text = config.read_text().replace(str(staging), str(final))
        config.write_text(text.replace(f"- {staging.name}\n", f"- {final.name}\n"))


def _rebase(result: SmokeResult, staging: Path, final: Path) -> None:
    """Point the result's paths at the renamed output folder."""
    run = result.run
    for attr in ("log_path", "run_dir", "config_path"):
        value = getattr(run, attr)
        if value is not None and Path(value).is_relative_to(staging):
            setattr(run, attr, final / Path(value).relative_to(staging))
