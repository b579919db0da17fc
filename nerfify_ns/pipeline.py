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
from typing import Callable, Optional, Tuple

from nerfify_ns.atomic import OutputExistsError, atomic_dir  # noqa: F401  (OutputExistsError re-exported)
from nerfify_ns.evaluate.smoke import (GENERATED, SmokeResult, SmokeTrainError, generated_env, generated_smoke_args,
                                       smoke_train)
from nerfify_ns.grammar import validate
from nerfify_ns.knowledge.citations import CitationGraph, build_citation_graph
from nerfify_ns.knowledge.detect import detect_techniques
from nerfify_ns.paper import Document, clean_markdown, ingest, key_terms_report, require_nerf_paper
from nerfify_ns.scenes import write_scene
from nerfify_ns.synthesis.compose import ComposedPlugin, write_plugin
from nerfify_ns.synthesis.plan_from_paper import DerivedPlan, derive_plan
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
class PaperResult:
    out: Optional[Path]
    document: Document
    derived: DerivedPlan
    graph: CitationGraph
    plan: dict
    stages: dict


def run_paper(
    paper: Path,
    out: Optional[Path] = None,
    *,
    data: Optional[Path] = None,
    scene: str = "default",
    iterations: int = 200,
    every: int = 50,
    dry_run: bool = False,
    keep_all: bool = False,
    patch_rounds: int = 0,
    overwrite: bool = False,
    progress: Progress = lambda stage: None,
) -> PaperResult:
    """Paper -> plan with evidence -> (unless dry_run) plugin, verification, training, evaluation, report."""
    progress(f"reading {Path(paper).name}")
    doc = ingest(paper)
    require_nerf_paper(doc)
    progress("detecting techniques and recovering what the paper borrows from its citations")
    detections = detect_techniques(doc)
    graph = build_citation_graph(doc, detections)
    derived = derive_plan(doc, detections, graph)
    if dry_run:
        return PaperResult(out=None, document=doc, derived=derived, graph=graph, plan=derived.plan, stages={})
    final = Path(out or Path("nerfify-out") / derived.plan["method"]).absolute()
    with atomic_dir(final, overwrite) as staging:
        _write_paper_artefacts(staging, doc, derived, graph)
        plan, data, _ = _plugin_for_scene(derived.plan, staging, data, scene, keep_all, progress)
        stages = _verify_train_report(staging, data, plan, iterations, every, patch_rounds, progress)
        _rewrite_saved_paths(staging, final)
    record_generated(final)
    return PaperResult(out=final, document=doc, derived=derived, graph=graph, plan=plan, stages=stages)


def _write_paper_artefacts(folder: Path, doc: Document, derived: DerivedPlan, graph: CitationGraph) -> None:
    cleaned = clean_markdown(doc)
    (folder / "paper.md").write_text(cleaned)
    (folder / "evidence.json").write_text(json.dumps({
        "paper": {"title": doc.title, "source": str(doc.source), "kind": doc.kind},
        "key_terms": key_terms_report(doc, cleaned), **derived.to_dict()}, indent=2, default=str))
    (folder / "citations.json").write_text(graph.to_json())
    graph.draw(folder / "citations.png")


def _verify_train_report(folder: Path, data: Path, plan: dict, iterations: int, every: int, patch_rounds: int,
                         progress: Progress) -> dict:
    """The verification ladder, training with error against time, evaluation maps, patches, the report."""
    from nerfify_ns.evaluate.report import write_report
    from nerfify_ns.evaluate.run_eval import evaluate_run
    from nerfify_ns.verify import run_ladder

    progress("verifying the plugin (static, contracts, stability, smoke training)")
    ladder = run_ladder(folder, scene=data, out_dir=folder / "verify")
    (folder / "verify.json").write_text(json.dumps(ladder.to_dict(), indent=2, default=str))
    stages = {"verify": ladder.ok}
    if ladder.ok:
        progress(f"training {plan['method']} for {iterations} iterations (error against time) and evaluating")
        stages["eval"] = evaluate_run(folder, data, folder / "eval", iterations=iterations, every=every,
                                      label=plan["method"])
        if patch_rounds:
            from nerfify_ns.evaluate.patch_loop import run_patch_loop

            progress(f"patch loop ({patch_rounds} rounds)")
            stages["patches"] = run_patch_loop(plan, data, folder / "patches", rounds=patch_rounds,
                                               iterations=iterations)
    progress("writing the report")
    write_report(folder)
    return stages


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
        plan, data, plugin = _plugin_for_scene(plan, staging, data, scene, keep_all, progress)
        smoke = None
        if train:
            progress(f"smoke-training {plan['method']} for {iterations} iterations with Nerfstudio's trainer")
            smoke = _smoke(plan, staging, data, iterations)
            (staging / "smoke" / "summary.json").write_text(json.dumps(smoke.summary(), indent=2))
            _rewrite_saved_paths(staging, final)
            _rebase(smoke, staging, final)
    record_generated(final)
    plugin.out = final
    return ComposeResult(out=final, plugin=plugin, plan=plan, smoke=smoke)


def _plugin_for_scene(plan: dict, folder: Path, data: Optional[Path], scene: str, keep_all: bool,
                      progress: Progress) -> Tuple[dict, Path, ComposedPlugin]:
    """Render (or take) the scene, prune the plan for it unless ``keep_all``, write the plugin into ``folder``."""
    if data is None:
        progress(f"rendering scene '{scene}'")
        data = write_scene(scene, folder / "scene")
    facts = probe_scene(data)
    plan = adopt_scene(plan, facts) if keep_all else prune_plan(plan, facts)
    progress(f"generating the plugin '{plan['method']}'")
    return plan, Path(data), write_plugin(plan, folder)


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
        scene_path = final / "scene" if data.is_relative_to(staging) else data
        (staging / "summary.json").write_text(json.dumps(result.summary(), indent=2))
        _rewrite_saved_paths(staging, final)
        _rebase(result, staging, final)
    return DemoResult(out=final, scene=scene_path, smoke=result)


def _rewrite_saved_paths(staging: Path, final: Path) -> None:
    """Point saved Nerfstudio configs, JSON files and the report at the folder they will have after the rename."""
    for path in [*staging.rglob("*.yml"), *staging.rglob("*.json"), *staging.glob("*.html")]:
        text = path.read_text(errors="replace")
        if str(staging) not in text and f"- {staging.name}\n" not in text:
            continue
        # Nerfstudio stores paths as lists of parts; staging and final differ in one part (same parent).
        path.write_text(text.replace(str(staging), str(final)).replace(f"- {staging.name}\n", f"- {final.name}\n"))


def _rebase(result: SmokeResult, staging: Path, final: Path) -> None:
    """Point the result's paths at the renamed output folder."""
    run = result.run
    for attr in ("log_path", "run_dir", "config_path"):
        value = getattr(run, attr)
        if value is not None and Path(value).is_relative_to(staging):
            setattr(run, attr, final / Path(value).relative_to(staging))
