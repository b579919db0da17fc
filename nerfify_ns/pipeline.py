"""The whole nerfify flow on one screen.

Today (foundation): scene -> smoke-train a reference method through Nerfstudio's trainer on the
CPU -> evaluate. The paper -> knowledge -> grammar -> synthesis -> verify stages plug in ahead of
the training step as they land.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

from nerfify_ns.atomic import OutputExistsError, atomic_dir  # noqa: F401  (OutputExistsError re-exported)
from nerfify_ns.evaluate.smoke import SmokeResult, SmokeTrainError, smoke_train
from nerfify_ns.scenes import write_scene

Progress = Callable[[str], None]


@dataclass
class DemoResult:
    out: Path
    scene: Path
    smoke: SmokeResult


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
            kept = Path(tempfile.gettempdir()) / f"nerfify-{method}-failed.log"
            shutil.copy(exc.log_path, kept)  # the staging folder and its log are about to go
            raise exc.with_log(kept) from None
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
