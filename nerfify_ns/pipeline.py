"""The whole nerfify flow on one screen.

    1 read -> 2 equations -> 3 plan -> 4 plugin -> 5 verify -> 6 train -> 7 patches -> 8 report

1. ``read``: the paper ingested into one ``Document``, its techniques detected with evidence, its citations
   followed, its family, base and plan derived (``paper/``, ``knowledge/``, ``synthesis/plan_from_paper.py``; the
   planner agent with ``--llm``).
2. ``equations``: the paper's novel parts compiled from its equations (``equations/``, ``synthesis/novel/``; the
   coder agent with ``--llm``), written to ``equations.yaml`` for a person to correct.
3. ``plan``: the plan validated and fitted to the scene (``grammar/``, ``synthesis/prune.py``).
4. ``plugin``: the plan rendered into a pip-installable Nerfstudio plugin (``synthesis/compose.py``, ``templates/``).
5. ``verify``: the sandboxed verification ladder: static, contract, stability, smoke (``verify/``).
6. ``train``: training within the budget, then checkpoint evaluation, only after the ladder passed (``evaluate/``).
7. ``patches``: the patch loop, ``--patch-rounds N`` (``evaluate/patch_loop.py``).
8. report: ``run.json``, ``report.html`` and ``report.json``, always written (``evaluate/report.py``).

``run_paper`` runs them all from a paper; ``run_compose`` starts at stage 3 from a plan (a file or a reference plan).
Both take one options object (:class:`RunOptions`, :class:`PaperOptions`: the command line's flags) and run stages 3
to 8 through :func:`_build`, in the same order. ``until`` stops after a stage. A stage that fails (verification,
training, evaluation) is recorded and the later ones are not run; the output folder (its layout:
``nerfify_ns.runfolder``) is still written, with ``run.json`` (which stages ran, failed or were not run, and why),
``nerfify.log`` (warnings and other packages' output) and the report. ``run_demo`` smoke-trains a built-in method.
Every run writes its output folder atomically.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from nerfify_ns import runfolder
from nerfify_ns.ablations import FULL, Ablations
from nerfify_ns.atomic import OutputExistsError, atomic_dir, check_target  # noqa: F401  (re-exported)
from nerfify_ns.budget import COMPOSE_BUDGET, PAPER_BUDGET, Budget, Limit, check_count, check_limit, smoke_limit
from nerfify_ns.dataset import Dataset, read_dataset
from nerfify_ns.errors import NerfifyError
from nerfify_ns.evaluate.smoke_train import SmokeResult, SmokeTrainError, smoke_train
from nerfify_ns.grammar import validate
from nerfify_ns.knowledge.citations import CitationGraph, build_citation_graph
from nerfify_ns.knowledge.detect import detect_techniques
from nerfify_ns.knowledge.kb import KnowledgeBase
from nerfify_ns.outcome import Outcome, Progress, Stage
from nerfify_ns.paper import Document, clean_markdown, ingest, key_terms_report, require_nerf_paper
from nerfify_ns.plan import Plan
from nerfify_ns.runlog import run_log
from nerfify_ns.runtime.presets import for_method, generated_smoke_args, smoke_iterations
from nerfify_ns.scenes import write_scene
from nerfify_ns.synthesis.compose import plugin_sources, write_plugin
from nerfify_ns.synthesis.novel import Implementation, implement_holes
from nerfify_ns.synthesis.novel.implement import revert
from nerfify_ns.synthesis.novel.records import read_corrections, write_records
from nerfify_ns.synthesis.plan_from_paper import DerivedPlan, derive_plan
from nerfify_ns.synthesis.proxy import measured_batch, smoke_samples
from nerfify_ns.synthesis.prune import adopt_scene, prune_plan
from nerfify_ns.synthesis.scene_probe import probe_scene


class FamilyError(NerfifyError):
    """A paper whose family the grammar cannot build (Gaussian splatting, surfaces, methods that do not train a
    view-synthesis model): one line saying what was read and what cannot be built."""

    def __init__(self, family: Any, parts: int):
        method = f"; {family.method_line()}" if getattr(family, "method", "") else ""
        super().__init__(f"a {family.headline()} paper: {family.why}{method}; read {parts} novel part(s) of it "
                         f"({runfolder.PLAN}, {runfolder.REPORT_HTML}), built none")


LOG_FILE = runfolder.LOG
"""The run's log in its output folder: warnings and other packages' output, stage by stage."""


@dataclass(frozen=True)
class RunOptions:
    """How a run goes, from a paper or from a plan: the command line's flags."""

    data: Path | None = None
    """A dataset to train on (any format ``nerfify_ns.dataset`` reads, read once); None: the procedural ``scene`` is
    rendered into the output folder."""
    scene: str = "default"
    """The procedural scene rendered when no dataset is given (``ns-nerfify scene --list``)."""
    budget: Budget | None = None
    """The CPU budget (iterations, checkpoint cadence, wall-clock seconds, presets); None: the command's default
    (``PAPER_BUDGET``, ``COMPOSE_BUDGET``). Its ``seconds`` bound the whole run, from its first stage."""
    until: str | None = None
    """Stop after this stage (plan, plugin, verify, train); the folder and its report are still written."""
    keep_all: bool = False
    """Keep every part of the plan (fitted to the scene, nothing pruned for it)."""
    patch_rounds: int = 0
    """Rounds of the patch loop after training (0: no patch loop)."""
    overwrite: bool = False
    """Replace an output folder nerfify-ns wrote earlier (anything else is refused)."""
    progress: Progress = field(default_factory=Progress)
    """What the user sees of the run (the CLI's bars); the default shows nothing."""
    ablations: Ablations = FULL
    """Stages switched off (``nerfify_ns.ablations``), recorded in run.json."""
    agents: Any | None = None
    """The model-backed agents (``nerfify_ns.agents.Agents``, built by the CLI for ``--llm``), or None: the
    deterministic path only. The planner's plan is merged with the derived one, the coder works on the holes the
    compiler left (not in a dry run), the critic in the patch loop, ``agents.json`` before the report; every model
    failure is a warning and the deterministic result stands. The ablation no-agents sets them aside."""


@dataclass(frozen=True)
class PaperOptions(RunOptions):
    """How a paper's run goes: :class:`RunOptions` and what only a paper has."""

    dry_run: bool = False
    """Stop after the equations stage and write nothing (the CLI prints the plan with its evidence and holes)."""
    kb: KnowledgeBase | None = None
    """The knowledge base every stage reads (None: the package's), one object for the whole run."""
    equations: Path | None = None
    """A person's corrected equations.yaml: its edited holes are recompiled, the others reused."""


@dataclass
class PaperResult:
    out: Path | None
    document: Document
    derived: DerivedPlan
    graph: CitationGraph
    plan: dict
    outcome: Outcome
    summary: dict | None = None
    """The evaluation's summary (eval/summary.json) when training ran."""
    implementation: Implementation | None = None
    """What the equation compiler made of the paper's novel parts (equations.yaml)."""


@dataclass
class ComposeResult:
    out: Path
    plan: dict
    outcome: Outcome
    files: list
    summary: dict | None = None


def run_paper(paper: Path, out: Path | None = None, options: PaperOptions | None = None) -> PaperResult:
    """Stages 1 to 8 from a paper (a dry run: 1 and 2, nothing written), up to ``options.until``; ``out``: the output
    folder (default ``nerfify-out/METHOD``)."""
    options = options or PaperOptions()
    options = replace(options, budget=options.budget or PAPER_BUDGET,
                      agents=options.agents if options.ablations.agents else None)
    outcome = Outcome("paper", options.until, options.progress, ablations=list(options.ablations.names))
    deadline = time.perf_counter() + options.budget.seconds if options.budget.seconds else None
    data = options.data
    dataset = None if options.dry_run else _read_data(data)  # a bad dataset is refused before the paper is read
    check_count("--patch-rounds", options.patch_rounds, 0)
    corrections = read_corrections(options.equations) if options.equations is not None else ({}, {})
    if out is not None and not options.dry_run:  # before the paper is read: a bad --out costs nothing
        check_target(Path(out), options.overwrite, inputs=(paper, data))
    kb = KnowledgeBase.of(options.kb)
    doc, derived, graph = _read(paper, options, outcome, kb)
    implementation = _compile_equations(doc, derived, options, outcome, kb, corrections)
    if options.dry_run:
        return PaperResult(None, doc, derived, graph, derived.plan, outcome, implementation=implementation)
    final = Path(out or Path("nerfify-out") / derived.plan["method"]).absolute()
    if not _buildable(derived):  # the plan and what was read are written; nothing is built that would pretend
        with atomic_dir(final, options.overwrite, inputs=(paper, data)) as staging, run_log(staging / LOG_FILE):
            _write_paper_artefacts(staging, doc, derived, graph)
            (staging / runfolder.PLAN).write_text(Plan.of(derived.plan).dump())
            with outcome.stage("plan", "checking that the grammar can build the paper's method",
                               failures=(NerfifyError,)):
                raise FamilyError(derived.family, len(derived.holes))
            _report(staging, outcome)
            _rewrite_saved_paths(staging, final)
        return PaperResult(final, doc, derived, graph, derived.plan, outcome, implementation=implementation)
    options = replace(options, scene=_scene_for_family(options.scene, dataset, derived))
    with atomic_dir(final, options.overwrite, inputs=(paper, data)) as staging, run_log(staging / LOG_FILE):
        _write_paper_artefacts(staging, doc, derived, graph)
        write_records(staging, implementation, doc, images=True)
        plan, summary = _build(derived.plan, staging, dataset, options, outcome, deadline, implementation.sources,
                               _fallback(implementation, staging, doc))
        _rewrite_saved_paths(staging, final)
    return PaperResult(final, doc, derived, graph, plan, outcome, summary, implementation)


def run_compose(plan: dict, out: Path, options: RunOptions | None = None, *,
                sources: dict[str, str] | None = None) -> ComposeResult:
    """Stages 3 to 8 from a plan (validated first), up to ``options.until``. ``sources``: the code of the plan's
    custom components (``components.<name>`` -> source)."""
    options = options or RunOptions()
    options = replace(options, budget=options.budget or COMPOSE_BUDGET)
    outcome = Outcome("compose", options.until, options.progress)
    deadline = time.perf_counter() + options.budget.seconds if options.budget.seconds else None
    dataset = _read_data(options.data)  # a bad dataset is bad input: nothing is written
    check_count("--patch-rounds", options.patch_rounds, 0)
    validate(plan)  # a plan the grammar rejects is bad input: nothing is written
    final = Path(out).absolute()
    with atomic_dir(final, options.overwrite, inputs=(options.data,)) as staging, run_log(staging / LOG_FILE):
        plan, summary = _build(plan, staging, dataset, options, outcome, deadline, sources)
        files = _plugin_files(staging)
        _rewrite_saved_paths(staging, final)
    return ComposeResult(final, plan, outcome, files, summary)


def _build(plan: dict, folder: Path, data: Dataset | None, options: RunOptions, outcome: Outcome,
           deadline: float | None, sources: dict[str, str] | None = None,
           fallback: Callable | None = None) -> tuple[dict, dict | None]:
    """Stages 3 to 8: plan for the scene -> plugin -> verification ladder -> training and evaluation (only after the
    ladder passed) -> patch loop -> run.json and the report. Returns the plan and the evaluation's summary.
    ``data``: the dataset, read once and shared by every stage (None: the procedural ``options.scene`` is
    rendered). ``deadline``: the ``time.perf_counter()`` by which the whole run ends (``budget.seconds``): training
    gets the iterations that fit the time left after the ladder (:func:`_fit_training`). ``fallback``: see
    :func:`_verify`."""
    budget, proxy_scene = _proxy_budget(plan, options.budget, data)  # a budgeted run's smaller procedural scene
    with outcome.stage("plan", "fitting the plan to the scene") as stage:
        plan, data = _plan_for_scene(plan, folder, data, options.scene, options.keep_all, budget, stage)
    if outcome.wants("plugin"):
        with outcome.stage("plugin", f"generating the plugin '{plan['method']}'") as stage:
            written = write_plugin(plan, folder, sources=sources, one_shot=not options.ablations.dag)
            stage.summary = f"{len(written.files)} files" + (
                "" if options.ablations.dag else " (one shot, no file DAG)")
    plan, timing = _verify(plan, folder, data, options, budget, outcome, deadline, sources, fallback)
    summary, run = _train(plan, folder, data, budget, outcome, deadline, timing, proxy_scene)
    _patches(plan, folder, data, options, budget, outcome, run)
    if options.agents is not None:
        options.agents.write(folder)
    _report(folder, outcome)
    return plan, summary


def _read(paper: Path, options: PaperOptions, outcome: Outcome,
          kb: KnowledgeBase) -> tuple[Document, DerivedPlan, CitationGraph]:
    """Stage 1: the paper read, its techniques detected, its citations followed, its plan derived (and, with the
    agents, the planner's plan merged with it)."""
    with outcome.stage("read", f"reading {Path(paper).name}, detecting techniques, following citations") as stage:
        doc = ingest(paper)
        require_nerf_paper(doc)
        detections = detect_techniques(doc, kb)
        graph = build_citation_graph(doc, detections, kb=kb, follow=options.ablations.citations)
        derived = derive_plan(doc, detections, graph, kb=kb, reference_plans=options.ablations.reference_plans)
        if options.agents is not None:
            stage.note("asking the model for a plan (planner agent)")
            derived.plan = options.agents.plan(doc, derived)
        stage.summary = (f"base {derived.base}, {sum(d.used for d in derived.detections)} techniques used, "
                         f"{len(derived.holes)} hole(s)")
    return doc, derived, graph


def _buildable(derived: DerivedPlan) -> bool:
    return derived.family is None or derived.family.buildable


def _compile_equations(doc: Document, derived: DerivedPlan, options: PaperOptions, outcome: Outcome,
                       kb: KnowledgeBase, corrections: tuple[dict, dict]) -> Implementation:
    """Stage 2: the paper's novel parts (the plan's holes) compiled from its equations, ``corrections``: a person's
    equations.yaml (edited holes, reusable ones); with the agents (not in a dry run) the coder on the parts the
    equations left open. The derived plan takes the compiled parts."""
    implementation = Implementation(Plan.of(derived.plan), sources={}, records=[])
    if not options.ablations.equations:
        outcome.skip("equations", "switched off (ablation no-equations)")
    elif not _buildable(derived):
        outcome.skip("equations", f"a {derived.family.headline()} paper: nothing is built")
    else:
        with outcome.stage("equations", "compiling the paper's novel parts from its equations") as stage:
            implementation = implement_holes(doc, derived.plan, corrections=corrections[0], reuse=corrections[1],
                                             kb=kb)
            if options.agents is not None and not options.dry_run:
                stage.note("asking the model for the parts the equations left open (coder agent, sandboxed ladder)")
                options.agents.code(implementation)
            stage.summary = implementation.headline() + (
                f"; {options.agents.summary()}" if options.agents is not None else "")
    implementation.plan = Plan.of(derived.host_cards(implementation.plan))
    derived.plan, derived.holes = implementation.plan, implementation.plan["holes"]
    return implementation


def _verify(plan: dict, folder: Path, data: Dataset, options: RunOptions, budget: Budget, outcome: Outcome,
            deadline: float | None, sources: dict[str, str] | None,
            fallback: Callable | None) -> tuple[dict, dict]:
    """Stage 5: the verification ladder on the plugin, ``verify.json``. Returns the plan (the fallback's when it
    stood in) and what the smoke rung measured of the plugin's speed (empty when the ladder did not run). When the
    ladder fails, ``fallback(ladder)`` may give a plan without the compiled components to blame (and their sources):
    the plugin is regenerated from it and the ladder run again, once."""
    from nerfify_ns.verify import run_ladder

    if not outcome.wants("verify"):
        return plan, {}
    if not options.ablations.verify:
        outcome.skip("verify", "switched off (ablation no-verify)")
        return plan, {}
    with outcome.stage("verify", "verification ladder: static, contract and stability checks (sandboxed)",
                       total=smoke_iterations(plan["base"], budget.smoke_iterations),
                       failures=(NerfifyError,)) as stage:
        smoke_args, smoke_values = smoke_samples(plan) if budget.proxy and deadline is not None else ([], {})

        def ladder_run():
            left = deadline - time.perf_counter() if deadline is not None else None
            return run_ladder(folder, scene=data, out_dir=folder / "verify", repair="apply",
                              smoke_iterations=budget.smoke_iterations,
                              timeout=check_limit(budget, left).timeout, smoke_limit=smoke_limit(budget, left),
                              smoke_args=smoke_args,
                              on_progress=_step_progress(stage, "verification ladder: smoke-training rung",
                                                         "verification ladder: judging the smoke run"))
        ladder = ladder_run()
        # a smoke rung that ran out of time is no fault of the compiled parts: nothing is reverted
        retry = fallback(ladder) if fallback is not None and not ladder.ok and not _smoke_timed_out(ladder) else None
        if retry is not None:  # the compiled parts failed: the base's parts stand in, the ladder runs again
            stage.note("verification ladder: again, the base's parts standing in for the compiled ones")
            plan, sources = _plan_for_scene(retry[0], folder, data, options.scene, options.keep_all, budget,
                                            stage)[0], retry[1]
            _regenerate(plan, folder, sources)
            ladder = ladder_run()
        if _smoke_timed_out(ladder):  # not verified for want of time: kept as it is, training goes on
            _note_unverified(plan, folder, ladder, budget)
        (folder / runfolder.VERIFY).write_text(json.dumps(ladder.to_dict(), indent=2, default=str))
        timing = _smoke_timing(ladder, smoke_values)
        _judge_ladder(ladder, stage)
    return plan, timing


def _train(plan: dict, folder: Path, data: Dataset, budget: Budget, outcome: Outcome, deadline: float | None,
           timing: dict, proxy_scene: dict | None) -> tuple[dict | None, TrainingRun | None]:
    """Stage 6: training for the iterations that fit (:func:`_fit_training`), then the checkpoints evaluated
    (``eval/``). Returns the evaluation's summary and the run (None, None when the stage did not run)."""
    from nerfify_ns.evaluate.run_eval import evaluate_run

    summary, run = None, None
    if not outcome.wants("train"):
        return summary, run
    label = "training within the budget" if deadline is not None else f"training for {budget.iterations} iterations"
    with outcome.stage("train", f"{label}, evaluating its checkpoints", total=budget.iterations,
                       failures=(NerfifyError,)) as stage:
        run = _fit_training(plan, folder, budget, data, timing, deadline, proxy_scene)
        stage.advance(0, run.iterations)
        if run.proxy:
            stage.note(run.proxy["headline"])
        stage.note(f"training {plan['method']} for {run.iterations} iterations" if run.ceiling is None else
                   f"training {plan['method']} until the budget's deadline (about {run.iterations} iterations, "
                   f"at most {run.ceiling})")
        summary = evaluate_run(folder, data, folder / runfolder.EVAL_DIR, iterations=run.ceiling or run.iterations,
                               every=run.every, label=plan["method"],
                               method_args=for_method(plan["base"], [*_train_args(plan, budget), *run.args]),
                               env=run.env,
                               timeout=run.limit.timeout, limit=run.limit, estimated=run.iterations,
                               on_progress=_step_progress(stage, f"training {plan['method']}",
                                                          "rendering and scoring the checkpoints"))
        summary = _record_run(folder, summary, run)
        _judge_evaluation(summary, stage, run)
    return summary, run


def _patches(plan: dict, folder: Path, data: Dataset, options: RunOptions, budget: Budget, outcome: Outcome,
             run: TrainingRun | None) -> None:
    """Stage 7: the patch loop (``options.patch_rounds`` rounds; the critic agent's diagnoses with the agents)."""
    if not options.ablations.visual_feedback:
        outcome.skip("patches", "switched off (ablation no-visual-feedback)")
    elif not options.patch_rounds:
        outcome.skip("patches", "not requested (--patch-rounds 0)")
    elif outcome.wants("patches"):
        from nerfify_ns.evaluate.patch_loop import run_patch_loop

        with outcome.stage("patches", f"patch loop ({options.patch_rounds} rounds)",
                           failures=(NerfifyError,)) as stage:
            loop = run_patch_loop(plan, data, folder / "patches", rounds=options.patch_rounds,
                                  iterations=run.iterations if run is not None else budget.iterations,
                                  sources=plugin_sources(folder, plan),
                                  **({"critic": options.agents.critic()} if options.agents is not None else {}))
            stage.summary = (f"{len(loop.kept())} patch(es) kept, best PSNR {loop.best_psnr} dB; stopped: "
                             f"{loop.history.get('stopped')}")


def _scene_for_family(scene: str, dataset: Dataset | None, derived: DerivedPlan) -> str:
    """The procedural scene a paper trains on when the user named none: a dynamic paper gets the first catalogued
    scene with timestamps (its time parts are kept, not pruned for a static scene); otherwise ``scene``."""
    family = derived.family
    if dataset is not None or scene != "default" or family is None or not family.scene.get("timestamps"):
        return scene
    from nerfify_ns.scenes.catalog import list_scenes, scene_spec

    timed = next((name for name in list_scenes() if (scene_spec(name).get("flags") or {}).get("dynamic")), None)
    if timed is None:
        return scene
    derived.plan.setdefault("notes", []).append(
        f"a {family.name} paper: trained on the procedural scene '{timed}' (it has timestamps); --scene or --data "
        "chooses another")
    return timed


def _fallback(implementation: Implementation, folder: Path, doc: Document) -> Callable:
    """When the ladder fails on compiled components, the plan without them (the base's parts stand in, the
    records say which rung and why) and their sources; None when no compiled component is to blame."""
    def fallback(ladder) -> tuple[dict, dict[str, str]] | None:
        compiled = [r for r in implementation.records  # compiled code, or typed parts built from the paper's prose
                    if (r.source or getattr(r, "placed", None)) and r.status != "not implemented"]
        if not compiled or _smoke_timed_out(ladder):  # out of time is no failure of the compiled parts
            return None
        failures = ladder.failures or []
        named = [r.id for r in compiled if any(name and name in f"{f.message} {f.where()}" for f in failures
                                               for name in (r.component.get("class", ""),
                                                            *r.component.get("terminals", ())))]
        first = failures[0] if failures else None
        why = f"the ladder's {first.rung} rung failed ({first.rule}: {first.message[:300]})" if first else \
            "the ladder failed"
        blamed = named or [r.id for r in compiled]  # a plugin-level failure (smoke): every compiled part
        plan = revert(implementation, blamed, why)
        write_records(folder, implementation, doc)
        return plan, implementation.sources
    return fallback


@dataclass
class TrainingRun:
    """What the evaluation run trains: iterations, checkpoint cadence, the schedule fitted to it, why."""

    iterations: int
    every: int
    args: list
    """ns-train arguments of the fitted schedule (``nerfify_ns.synthesis.schedule``)."""
    limit: Limit
    """The training's and the rendering's time limit and where it comes from (none without a budget)."""
    budget: dict | None = None
    """How the wall-clock budget became iterations (None without a budget)."""
    schedule: dict | None = None
    """The plan's ``schedule`` record when the schedule was scaled."""
    proxy: dict | None = None
    """The CPU proxy the run trains (``schedule.proxy``), or None: the paper's settings."""
    ceiling: int | None = None
    """``ns-train``'s iterations when the training keeps the budget's deadline itself (``env``), None: exactly
    ``iterations``."""
    env: dict = field(default_factory=dict)
    """The training process's environment: its deadline (:data:`nerfify_ns.runtime.pace.ENV_PACE`)."""


UNMEASURED_ITERATIONS = 200
"""Iterations of a budgeted run when nothing measured the plugin's speed (the ladder switched off)."""


def _smoke_timing(ladder, samples: dict | None = None) -> dict:
    """What the ladder's smoke rung measured of the plugin's speed (``verify.smoke.step_timing``), with its ray
    batch and the sample counts it trained with (``samples``, by plan path; none: the plan's); empty when the rung
    did not run or measured nothing. A rung stopped by its time limit measured its first steps."""
    from nerfify_ns.verify.ladder import process_threads
    from nerfify_ns.verify.smoke_rung import SMOKE_ARGS

    smoke = next((r for r in ladder.rungs if r.name == "smoke" and (r.status == "pass" or _timed_out(r))), None)
    if smoke is None or not smoke.details.get("seconds_per_iteration"):
        return {}
    # a rung run beside the checks had fewer threads than training will have: its steps are faster with training's
    # threads by the speedup the recorder measured (else by the ratio of threads, an upper bound)
    threads, training = smoke.details.get("threads"), process_threads()
    cost = smoke.details.get("ray_cost") or {}
    scale = (1.0 / cost["speedup"] if cost.get("speedup") and cost.get("threads") == training
             else threads / training if isinstance(threads, int) and 0 < threads < training else 1.0)
    # the batch it trained: its rays, or for a pipeline that counts a step's samples those (the proxy's floor)
    samples_batch = measured_batch(samples or {})
    step, rays = smoke.details["seconds_per_iteration"] * scale, samples_batch or _rays(SMOKE_ARGS)
    # the part of a step its rays cost: the recorder's timing at two batches, against the step at those threads
    share = (min(1.0, cost["seconds_per_ray"] * rays / step)
             if cost.get("seconds_per_ray") is not None and cost.get("threads") in (None, training)
             and samples_batch is None else None)
    return {"seconds_per_iteration": step,
            "startup_seconds": smoke.details["startup_seconds"], "rays": rays,
            "samples": dict(samples or {}), "ray_share": share}


def _timed_out(rung) -> bool:
    return rung.status == "fail" and bool(rung.failures) and all(d.rule == "timeout" for d in rung.failures)


def _smoke_timed_out(ladder) -> bool:
    """The ladder failed only because its smoke rung ran out of time (every other rung passed)."""
    rung = getattr(ladder, "rung", None)
    smoke = rung("smoke") if callable(rung) else None
    return smoke is not None and _timed_out(smoke) and all(r.ok for r in ladder.rungs if r is not smoke)


def _note_unverified(plan: Plan, folder: Path, ladder, budget: Budget) -> None:
    """A smoke rung stopped by its time limit: the plugin is kept as it is, "not verified: time" with the figures
    in the plan's notes and in the ladder's report, and how to finish it."""
    smoke = ladder.rung("smoke")
    done, wanted = smoke.details.get("iterations", 0), smoke.details.get("iterations_wanted")
    figures = (f"{smoke.failures[0].message}; the plugin is kept as it is; finish the rung with a longer --budget"
               f"{f' or --smoke-iterations {done}' if done >= 3 else ''}")
    smoke.notes.append(figures)
    plan.notes.append(f"smoke rung not verified: time ({figures})")
    (folder / runfolder.PLAN).write_text(Plan.of(plan).dump())
    smoke.details["verdict"] = "not verified: time"
    if wanted is None:
        smoke.details["iterations_wanted"] = smoke_iterations(plan["base"], budget.smoke_iterations)


def _rays(args) -> int:
    """The training ray batch the last ``--pipeline.datamanager.train-num-rays-per-batch`` of ``args`` sets."""
    args = list(args)
    flag = "--pipeline.datamanager.train-num-rays-per-batch"
    found = [int(args[i + 1]) for i, a in enumerate(args[:-1]) if a == flag]
    return found[-1] if found else 4096


def _fit_training(plan: Plan, folder: Path, budget: Budget, data: Dataset, timing: dict,
                  deadline: float | None, proxy_scene: dict | None = None) -> TrainingRun:
    """The evaluation run: ``budget.iterations`` without a deadline, and no time limit; with one, as many
    iterations as fit the time left (the smoke rung's measured speed, scaled to the evaluation's ray batch), at most
    the plan's own ``trainer.max_num_iterations``, and the budget's limit. With ``budget.proxy`` a run that cannot fit
    the paper's settings trains a CPU proxy (``nerfify_ns.synthesis.proxy``; ``proxy_scene``: the smaller scene it
    rendered). With ``budget.scale_schedule`` a run shorter than the paper's schedule gets it scaled. Both are
    recorded as the plan's ``schedule`` (plan.yaml rewritten). Raises ``BudgetError`` when the budget leaves too
    little. Without the smoke rung's measurement (ladder switched off) a budgeted run trains
    :data:`UNMEASURED_ITERATIONS`."""
    from nerfify_ns.budget import (
        PACE_CEILING,
        POST_SECONDS,
        RENDER_COST,
        fit_iterations,
        pace_margin,
        scaled_step,
        training_limit,
    )
    from nerfify_ns.runtime.pace import ENV_PACE, Pace
    from nerfify_ns.runtime.presets import render_cost, step_time_exponent
    from nerfify_ns.synthesis.proxy import Measured, fit_proxy
    from nerfify_ns.synthesis.schedule import scale_schedule

    iterations, every, record, proxy = budget.iterations, budget.cadence(budget.iterations), None, None
    ceiling, env = None, {}
    width = 1.0  # the proxy's MLP width over the paper's (the learning rates follow it)
    limit = training_limit(budget, None)
    rays = _rays(_train_args(plan, budget))
    paper_rays = int((plan.get("datamanager") or {}).get("train_num_rays_per_batch") or 0) or None
    args: list = []
    most = min(budget.iterations, int((plan.get("trainer") or {}).get("max_num_iterations") or budget.iterations))
    if deadline is not None and not timing:  # nothing measured (the ladder was switched off): a fixed length
        iterations = min(UNMEASURED_ITERATIONS, most)
        every = budget.cadence(iterations)
        limit = training_limit(budget, deadline - time.perf_counter())
        record = {"seconds": budget.seconds, "iterations": iterations, "every": every,
                  "reason": f"the smoke rung did not run, so nothing measured the plugin's speed: {iterations} "
                            "iterations, not fitted to the budget"}
    elif deadline is not None:
        left = deadline - time.perf_counter()
        h, w = data.image_size
        rendered = h * w * len(data.eval_frames)
        exponent = step_time_exponent(plan["base"])
        if budget.proxy:
            measured = Measured(timing["seconds_per_iteration"], timing["startup_seconds"], timing["rays"],
                                timing.get("samples") or {}, timing.get("ray_share"))
            fitted_proxy = fit_proxy(plan, measured, seconds_left=left, rays=rays, exponent=exponent,
                                     rays_per_checkpoint=rendered, train_pixels=h * w * len(data.train_frames),
                                     budget=budget, most=most, scene=proxy_scene,
                                     render_cost=render_cost(plan["base"], RENDER_COST))
            fit, step = fitted_proxy.time, fitted_proxy.seconds_per_iteration
            if fitted_proxy.active:
                proxy, args, rays = fitted_proxy.record(paper_rays), fitted_proxy.args(), fitted_proxy.rays
                width = fitted_proxy.width_ratio
        else:
            step = scaled_step(timing["seconds_per_iteration"], timing["rays"], rays,
                               ray_share=timing.get("ray_share"), exponent=exponent)
            fit = fit_iterations(left, step, timing["startup_seconds"], rendered, rays, budget, most=most,
                                 render_cost=render_cost(plan["base"], RENDER_COST))
        iterations, every = fit.iterations, fit.every
        limit = training_limit(budget, left)
        ceiling = max(iterations, min(most, math.ceil(iterations * PACE_CEILING)))
        pace = Pace(end=time.time() + left - POST_SECONDS, step_seconds=step, render_seconds=fit.render_one_seconds,
                    startup_seconds=timing["startup_seconds"], margin_seconds=pace_margin(left),
                    iterations=iterations if budget.scale_schedule else 0.0)
        env = {ENV_PACE: pace.to_env()}
        record = {"seconds": budget.seconds, "seconds_left": round(left, 1), "iterations": iterations,
                  "ceiling": ceiling, "every": every, "seconds_per_iteration": round(step, 4),
                  "smoke_seconds_per_iteration": round(timing["seconds_per_iteration"], 4),
                  "startup_seconds": round(timing["startup_seconds"], 1),
                  "render_seconds": round(fit.render_seconds, 1), "limit_seconds": round(limit.seconds or 0, 1),
                  "reason": f"{fit.describe()}; the training keeps the budget's deadline itself, up to "
                            f"{ceiling} iterations"}
    schedule = None
    if budget.scale_schedule or proxy:
        fitted = scale_schedule(plan, iterations, rays=rays, width=width) if budget.scale_schedule else None
        if proxy or (fitted is not None and fitted.scaled):
            schedule = {**(fitted.record() if fitted is not None else {}), **({"proxy": proxy} if proxy else {})}
            args = [*args, *(fitted.args if fitted is not None else [])]
            plan["schedule"] = schedule
            (folder / runfolder.PLAN).write_text(Plan.of(plan).dump())
    return TrainingRun(iterations, every, args, limit, record, schedule, proxy, ceiling, env)


def _proxy_budget(plan: dict, budget: Budget, data: Dataset | None) -> tuple[Budget, dict | None]:
    """``budget`` with the CPU proxy's smaller procedural scene for the plan's base (``proxy.yaml``), and that
    scene's record; unchanged for a given dataset or a budget that fits the base's full scene."""
    from nerfify_ns.synthesis.proxy import proxy_scene, with_scene

    scene = None if data is not None else proxy_scene(plan.get("base"), budget)
    return with_scene(budget, scene), scene


def _paced(summary: dict, run: TrainingRun) -> dict | None:
    """How a training that kept the budget's deadline itself went against its estimate: iterations and seconds per
    step, both measured outside it (its events, the curve's clock), and a line saying so when it trained fewer than
    estimated (None: not paced, or not evaluated)."""
    if run.ceiling is None or not run.budget or summary.get("status") != "ok":
        return None
    done, estimated = int(summary.get("iterations_done") or 0), int(run.budget["iterations"])
    step = float(summary.get("seconds") or 0.0) / max(int(summary.get("evaluated_iterations") or done), 1)
    planned = float(run.budget["seconds_per_iteration"])
    line = (f"trained {done} of the {estimated} iterations estimated to fit: a step took {step:.2f} s where "
            f"{planned:.2f} s was estimated, and the training stopped itself at the budget's deadline"
            if done < estimated and not summary.get("stopped") else "")  # a limit's stop says so itself
    return {"iterations": done, "estimated": estimated, "seconds_per_iteration": round(step, 4),
            "estimated_seconds_per_iteration": planned, "short": line}


def _record_run(folder: Path, summary: dict, run: TrainingRun) -> dict:
    """The evaluation summary with how its length was chosen (budget, schedule), written back."""
    from nerfify_ns.budget import within_budget
    from nerfify_ns.evaluate.run_eval import write_json

    summary = {**summary, "budget": run.budget, "schedule": run.schedule,
               "within_budget": within_budget(run.budget, summary), "paced": _paced(summary, run)}
    write_json(folder / "eval" / runfolder.SUMMARY, summary)
    return summary


def _plan_for_scene(plan: dict, folder: Path, data: Dataset | None, scene: str, keep_all: bool,
                    budget: Budget, stage: Stage) -> tuple[dict, Dataset]:
    """Render (or take) the scene, prune the plan for it unless ``keep_all``, write ``plan.yaml``."""
    if data is None:
        stage.note(f"rendering scene '{scene}'")
        data = read_dataset(write_scene(scene, folder / "scene", **budget.scene))
    facts = probe_scene(data)
    plan = Plan.of(adopt_scene(plan, facts) if keep_all else prune_plan(plan, facts))
    (folder / runfolder.PLAN).write_text(plan.dump())
    stage.summary = (f"{plan['method']} (base {plan['base']}), {data.format} dataset, "
                     f"{len(plan.get('pruned') or [])} pruning(s), {len(plan.get('holes') or [])} hole(s)")
    return plan, data


def _regenerate(plan: dict, folder: Path, sources: dict[str, str] | None) -> None:
    """The plugin written again from ``plan`` into ``folder`` (its earlier files removed first)."""
    meta = folder / runfolder.PLUGIN_META
    if meta.is_file():
        for name in json.loads(meta.read_text()).get("files", []):
            (folder / name).unlink(missing_ok=True)
    write_plugin(plan, folder, sources=sources)


def _read_data(data: Path | None) -> Dataset | None:
    """The dataset at ``data`` read and checked once (None when no --data was given: a scene is rendered)."""
    return None if data is None else read_dataset(data)


def _judge_ladder(ladder, stage: Stage) -> None:
    """The ladder's verdict on the stage: its first broken rule (rung, rule, where, why), else the rungs. A smoke
    rung stopped by its time limit is "not verified: time" with its figures, not a failure."""
    if ladder.ok or _smoke_timed_out(ladder):
        stage.summary = ", ".join(f"{r.name} {'not verified: time' if _timed_out(r) else r.status}"
                                  for r in ladder.rungs) + (
            f"; {len(ladder.patches)} repair(s)" if ladder.patches else "")
        smoke = ladder.rung("smoke")
        if smoke is not None and _timed_out(smoke):
            stage.summary += f" ({smoke.notes[-1] if smoke.notes else smoke.failures[0].message})"
        elif smoke is not None and smoke.details.get("paced"):  # judged on the steps its time allowed
            stage.summary += f" (smoke {smoke.details['paced']})"
        return
    first = ladder.failures[0] if ladder.failures else None
    where = f" ({first.where()})" if first and first.where() != "-" else ""
    stage.fail(f"{first.rung} rung, {first.rule}{where}: {first.message}" if first else "no rung passed")


def _train_args(plan: dict, budget: Budget) -> list:
    """ns-train arguments of the evaluation run: CPU settings, the base's CPU preset when budgeted, the budget's
    own arguments (a later argument wins)."""
    from nerfify_ns.evaluate.run_eval import CPU_ARGS

    return [*CPU_ARGS, *(generated_smoke_args(plan["base"]) if budget.cpu_presets else []), *budget.train_args]


def _step_progress(stage: Stage, during: str, after: str) -> Callable[[int, int], None]:
    """``on_progress(step, total)`` of a training process: the stage's bar, and what it does (``during`` the
    training, ``after`` it)."""
    def hook(step: int, total: int) -> None:
        stage.advance(step, total)
        stage.note(after if step >= total else during)
    return hook


def _judge_evaluation(summary: dict, stage: Stage, run: TrainingRun | None = None) -> None:
    """The evaluation's verdict on the stage: its reason when training or evaluation failed, else PSNR (and the
    CPU proxy the run trained, when it did); a run its limit stopped (evaluated at its last checkpoint) or whose
    renders are grey says so first."""
    from nerfify_ns.evaluate.report import grey_ratio

    if summary.get("status") != "ok":
        stage.fail(summary.get("reason") or "training failed")
        return
    lpips = summary.get("lpips")
    diagnostics = summary.get("diagnostics") or {}
    colour = (f", foreground colour spread {diagnostics['colour_spread']:.3f} (ground truth "
              f"{diagnostics['colour_spread_gt']:.3f})" if diagnostics.get("colour_spread") is not None
              and diagnostics.get("colour_spread_gt") is not None else "")
    grey = grey_ratio(diagnostics)
    short = (summary.get("paced") or {}).get("short")
    stage.summary = ((f"{summary['stopped']}; " if summary.get("stopped") else "")
                     + (f"{short}; " if short else "")
                     + (f"renders grey (foreground colour spread {grey:.2f}x the ground truth's); "
                        if grey is not None else "")
                     + f"{summary.get('evaluated_iterations') or summary['iterations_done']} iterations in "
                     f"{summary['seconds']:.1f} s; held-out PSNR "
                     f"{summary['psnr']:.2f} dB, SSIM {summary['ssim']:.3f}, LPIPS "
                     f"{'unavailable' if lpips is None else f'{lpips:.3f}'}{colour}"
                     + (f"; {run.proxy['headline']}" if run is not None and run.proxy else ""))


def _report(folder: Path, outcome: Outcome) -> None:
    """``run.json`` (the outcome) and the report that states it at its top."""
    from nerfify_ns.evaluate.report import write_report

    start = time.perf_counter()
    outcome.write(folder / runfolder.OUTCOME)
    outcome.progress.start("report", "writing the report")
    write_report(folder)
    outcome.progress.finish("report", "report.html, report.json", time.perf_counter() - start)


def _plugin_files(folder: Path) -> list:
    """The files of the plugin generated into ``folder`` (none when the plugin stage did not run)."""
    meta = folder / runfolder.PLUGIN_META
    return json.loads(meta.read_text())["files"] if meta.is_file() else []


def _write_paper_artefacts(folder: Path, doc: Document, derived: DerivedPlan, graph: CitationGraph) -> None:
    cleaned = clean_markdown(doc)
    (folder / runfolder.PAPER).write_text(cleaned)
    (folder / runfolder.EVIDENCE).write_text(json.dumps({
        "paper": {"title": doc.title, "source": str(doc.source), "kind": doc.kind},
        "key_terms": key_terms_report(doc, cleaned), **derived.to_dict()}, indent=2, default=str))
    (folder / runfolder.CITATIONS).write_text(graph.to_json())
    graph.draw(folder / runfolder.CITATIONS_FIGURE)


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
    data: Path | None = None,
    iterations: int = 100,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> DemoResult:
    """Make (or take) a scene, smoke-train ``method`` on it on the CPU, evaluate, write ``out``."""
    outcome = Outcome("demo", progress=progress or Progress())
    dataset = _read_data(data)
    check_count("--iterations", iterations)
    final = Path(out).absolute()
    with atomic_dir(out, overwrite, inputs=(data,)) as staging, run_log(staging / LOG_FILE):
        if dataset is None:
            with outcome.stage("scene", f"rendering scene '{scene}'"):
                data = write_scene(scene, staging / "scene")
                dataset = read_dataset(data)
        with outcome.stage("train", f"training {method} for {iterations} iterations with Nerfstudio's trainer, "
                           "then ns-eval", total=iterations) as stage:
            try:
                result = smoke_train(method, dataset, staging / "train", iterations=iterations,
                                     on_progress=stage.advance)
            except SmokeTrainError as exc:
                raise exc.with_log(_keep_log(exc.log_path, method)) from None
            metrics = result.summary()
            stage.summary = f"{metrics['iterations']} iterations, PSNR {metrics['psnr']}, SSIM {metrics['ssim']}"
        scene_path = final / "scene" if dataset.root.is_relative_to(staging) else dataset.root
        (staging / runfolder.SUMMARY).write_text(json.dumps(result.summary(), indent=2))
        _rewrite_saved_paths(staging, final)
        _rebase(result, staging, final)
    return DemoResult(out=final, scene=scene_path, smoke=result)


def _keep_log(log_path: Path, name: str) -> Path:
    """A copy of a failed run's log outside the staging folder, which is about to go."""
    kept = Path(tempfile.gettempdir()) / f"nerfify-{name}-failed.log"
    shutil.copy(log_path, kept)
    return kept


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
