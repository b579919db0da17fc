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

CONSOLE = Console(width=120)

# What "stock" leaves on: without these two Nerfstudio cannot start training offline on the CPU.
STOCK_SKIP = {"nerfacto": "hashgrid,cpu_default", "vanilla-nerf": "hashgrid,cpu_default", "instant-ngp": None}
E2E_ARGS = {
    "nerfacto": ["--pipeline.datamanager.train-num-rays-per-batch", "1024"],
    "instant-ngp": ["--pipeline.datamanager.train-num-rays-per-batch", "1024"],
    "vanilla-nerf": ["--pipeline.datamanager.train-num-rays-per-batch", "256"],
}


def time_hash_encoding(points: int, repeats: int, position_grad: bool) -> Dict[str, float]:
    """Median seconds for forward+backward, stock vs ours, on the same encoding and inputs."""
    from nerfstudio.field_components.encodings import HashEncoding

    from nerfify_ns.runtime.hashgrid import fast_pytorch_fwd

    stock = HashEncoding.__dict__["pytorch_fwd"]
    if stock is fast_pytorch_fwd:
        raise RuntimeError("the runtime patched HashEncoding before the benchmark captured the stock path")
    torch.manual_seed(0)
    enc = HashEncoding(num_levels=16, log2_hashmap_size=19, max_res=2048, implementation="torch")
    x = torch.rand(points, 3)
    seconds: Dict[str, List[float]] = {"stock": [], "ours": []}
    for _ in range(repeats):  # interleaved so drifts in machine load hit both alike
        for name, fn in (("stock", stock), ("ours", fast_pytorch_fwd)):
            enc.hash_table.grad = None
            xx = x.clone().requires_grad_(position_grad)
            start = time.perf_counter()
            out = fn(enc, xx)
            out.backward(torch.ones_like(out))
            seconds[name].append(time.perf_counter() - start)
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
    rays = run.rays_per_sec[2:] or run.rays_per_sec  # Nerfstudio already skips steps 0-1
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
    iterations: int = 12
    """Training iterations per end-to-end run."""
    methods: List[str] = field(default_factory=lambda: ["nerfacto", "instant-ngp", "vanilla-nerf"])
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
        stock_pps, ours_pps = args.points / t["stock"], args.points / t["ours"]
        results["hash_encoding"][key] = {"stock_points_per_s": stock_pps, "ours_points_per_s": ours_pps,
                                         "ratio": ours_pps / stock_pps}
        table.add_row(f"hash enc fwd+bwd, points/s ({key})", f"{stock_pps:,.0f}", f"{ours_pps:,.0f}",
                      f"{ours_pps / stock_pps:.2f}x")
    if not args.skip_e2e:
        from nerfify_ns.scenes import write_scene

        with tempfile.TemporaryDirectory() as tmp:
            data = write_scene("default", Path(tmp) / "scene")
            for method in args.methods:
                skip = STOCK_SKIP[method]
                stock = e2e_rays_per_sec(method, data, Path(tmp) / f"{method}-stock", args.iterations, skip) \
                    if skip is not None else None
                ours = e2e_rays_per_sec(method, data, Path(tmp) / f"{method}-ours", args.iterations, "")
                ratio = ours / stock if ours and stock else None
                results["training"][method] = {"stock_rays_per_s": stock, "ours_rays_per_s": ours, "ratio": ratio,
                                               "args": E2E_ARGS[method]}
                table.add_row(f"{method} training, rays/s",
                              f"{stock:,.0f}" if stock else "cannot run" if skip is None else "failed",
                              f"{ours:,.0f}" if ours else "failed", f"{ratio:.2f}x" if ratio else "-")
    CONSOLE.print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "runtime.json").write_text(json.dumps(results, indent=2))
    CONSOLE.print(f"wrote {args.out / 'runtime.json'}")
    return results


if __name__ == "__main__":
    main(tyro.cli(Args))
