"""CPU runtime benchmark: stock Nerfstudio fallbacks vs our runtime layer, side by side.

1. Hash encoding forward+backward (Nerfacto's main field: 16 levels, 2^19 table, 2 features),
   points per second, stock ``HashEncoding.pytorch_fwd`` vs ours, with and without gradients
   to the positions (camera optimisation needs them).
2. End-to-end training rays per second through real ``ns-train`` processes on a bundled scene,
   read from Nerfstudio's own ``Train Rays / Sec`` events: ``nerfacto`` (default config at 1024
   rays per batch, the setting of the design card's measurement), ``instant-ngp`` and
   ``vanilla-nerf``. "stock" is Nerfstudio with only what it needs to start at all offline
   (LPIPS, and nerfacc for instant-ngp, which otherwise cannot run on the CPU).

Run: ``.venv/bin/python -m nerfify_ns.bench.runtime_bench [--iterations 12] [--out bench-results]``
"""

from __future__ import annotations

import json
import statistics
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional

import torch
import tyro
from rich.console import Console
from rich.table import Table

from nerfify_ns.interrupts import run_interruptible

CONSOLE = Console(width=120)

# What "stock" leaves on: without these two Nerfstudio cannot start training offline on the CPU.
STOCK_SKIP = {"nerfacto": "hashgrid,cpu_default", "vanilla-nerf": "hashgrid,cpu_default", "instant-ngp": None,
              "instant-ngp-bounded": None}
E2E_ARGS = {
    "nerfacto": ["--pipeline.datamanager.train-num-rays-per-batch", "1024"],
    "instant-ngp": ["--pipeline.datamanager.train-num-rays-per-batch", "1024"],
    "instant-ngp-bounded": ["--pipeline.datamanager.train-num-rays-per-batch", "1024"],
    "vanilla-nerf": ["--pipeline.datamanager.train-num-rays-per-batch", "256"],
}
# Iterations per run; rays/s is the median over the second half of each run (instant-ngp's time
# includes its occupancy-grid updates, every 16 steps, as Nerfstudio's own rays/s does).
E2E_ITERATIONS = {"nerfacto": 16, "vanilla-nerf": 12, "instant-ngp": 48, "instant-ngp-bounded": 48}


def time_hash_encoding(points: int, repeats: int, position_grad: bool) -> Dict[str, float]:
    """Median seconds for forward+backward: stock, our torch path, our C++ kernel (same encoding, inputs)."""
    import os

    from nerfstudio.field_components.encodings import HashEncoding

    from nerfify_ns.runtime import hashgrid_ext
    from nerfify_ns.runtime.hashgrid import ENV_IMPL, fast_pytorch_fwd

    stock = HashEncoding.__dict__["pytorch_fwd"]
    if stock is fast_pytorch_fwd:
        raise RuntimeError("the runtime patched HashEncoding before the benchmark captured the stock path")
    torch.manual_seed(0)
    enc = HashEncoding(num_levels=16, log2_hashmap_size=19, max_res=2048, implementation="torch")
    x = torch.rand(points, 3)
    variants = [("stock", stock, None), ("torch", fast_pytorch_fwd, "torch")]
    if hashgrid_ext.load() is not None:
        variants.append(("cpp", fast_pytorch_fwd, "cpp"))
    seconds: Dict[str, List[float]] = {name: [] for name, _, _ in variants}
    for _ in range(repeats):  # interleaved so drifts in machine load hit all alike
        for name, fn, impl in variants:
            os.environ[ENV_IMPL] = impl or "auto"
            enc.hash_table.grad = None
            xx = x.clone().requires_grad_(position_grad)
            start = time.perf_counter()
            out = fn(enc, xx)
            out.backward(torch.ones_like(out))
            seconds[name].append(time.perf_counter() - start)
    os.environ.pop(ENV_IMPL, None)
    return {name: statistics.median(values) for name, values in seconds.items()}


def e2e_rays_per_sec(method: str, data: Path, work: Path, iterations: int, skip: Optional[str]) -> Optional[float]:
    """Median of Nerfstudio's per-step Train Rays / Sec for one ns-train run (None if it failed)."""
    from nerfify_ns.runtime.launch import ns_train

    env = {"NERFIFY_RUNTIME_SKIP": skip} if skip else {}
    run = ns_train(method, data, work, iterations=iterations, env=env, timeout=3600,
                   method_args=[*E2E_ARGS[method], "--machine.device-type", "cpu"])
    if not run.ok:
        CONSOLE.print(f"[red]{method} ({'stock' if skip is not None else 'ours'}) failed: {run.log_path}")
        return None
    rays = run.rays_per_sec[len(run.rays_per_sec) // 2:]  # second half: past start-up and warm-up
    return statistics.median(rays) if rays else None


@dataclass
class Args:
    """CPU runtime benchmark (stock Nerfstudio fallbacks vs nerfify's runtime)."""

    out: Path = Path("bench-results")
    """Folder for runtime.json."""
    points: int = 65536
    """Points per hash-encoding call (about 1024 rays x 64 samples)."""
    repeats: int = 7
    """Repeats per hash-encoding measurement (median reported)."""
    iterations: Optional[int] = None
    """Training iterations per end-to-end run (default: per method, see E2E_ITERATIONS)."""
    methods: List[str] = field(default_factory=lambda: ["nerfacto", "instant-ngp", "instant-ngp-bounded",
                                                        "vanilla-nerf"])
    """Methods for the end-to-end runs."""
    skip_e2e: bool = False
    """Only run the hash-encoding part."""


def main(args: Args) -> dict:
    results: dict = {"torch_threads": torch.get_num_threads(), "hash_encoding": {}, "training": {}}
    table = Table(title="nerfify CPU runtime vs stock Nerfstudio 1.1.5 (medians)")
    for col in ("measurement", "stock", "ours", "ratio"):
        table.add_column(col)
    for position_grad in (False, True):
        t = time_hash_encoding(args.points, args.repeats, position_grad)
        key = "with_position_grad" if position_grad else "table_grad_only"
        pps = {name: args.points / seconds for name, seconds in t.items()}
        results["hash_encoding"][key] = {f"{name}_points_per_s": v for name, v in pps.items()}
        for name in ("torch", "cpp"):
            if name in pps:
                ratio = pps[name] / pps["stock"]
                results["hash_encoding"][key][f"{name}_ratio"] = ratio
                table.add_row(f"hash enc fwd+bwd points/s, {key}, ours={name}", f"{pps['stock']:,.0f}",
                              f"{pps[name]:,.0f}", f"{ratio:.2f}x")
    if not args.skip_e2e:
        from nerfify_ns.scenes import write_scene

        with tempfile.TemporaryDirectory() as tmp:
            data = write_scene("default", Path(tmp) / "scene")
            for method in args.methods:
                skip, iterations = STOCK_SKIP[method], args.iterations or E2E_ITERATIONS[method]
                stock = e2e_rays_per_sec(method, data, Path(tmp) / f"{method}-stock", iterations, skip) \
                    if skip is not None else None
                ours = e2e_rays_per_sec(method, data, Path(tmp) / f"{method}-ours", iterations, "")
                ratio = ours / stock if ours and stock else None
                results["training"][method] = {"stock_rays_per_s": stock, "ours_rays_per_s": ours, "ratio": ratio,
                                               "args": E2E_ARGS[method], "iterations": iterations}
                table.add_row(f"{method} training, rays/s",
                              f"{stock:,.0f}" if stock else "cannot run" if skip is None else "failed",
                              f"{ours:,.0f}" if ours else "failed", f"{ratio:.2f}x" if ratio else "-")
    CONSOLE.print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "runtime.json").write_text(json.dumps(results, indent=2))
    CONSOLE.print(f"wrote {args.out / 'runtime.json'}")
    return results


if __name__ == "__main__":
    run_interruptible(lambda: main(tyro.cli(Args)))
