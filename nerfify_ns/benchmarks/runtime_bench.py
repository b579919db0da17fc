"""CPU runtime benchmark: stock Nerfstudio, our runtime before its fused paths, and ours now, side by side.

1. Hash encoding forward+backward (Nerfacto's main field: 16 levels, 2^19 table, 2 features),
   points per second, stock ``HashEncoding.pytorch_fwd`` vs ours, with and without gradients
   to the positions (camera optimisation needs them).
2. The machine's FLOP bound: fp32 (and bf16) GEMM throughput at the torch thread count.
3. End-to-end training rays per second through real ``ns-train`` processes on a bundled scene,
   read from Nerfstudio's own ``Train Rays / Sec`` events: ``nerfacto`` (default config at 1024
   rays per batch), ``instant-ngp`` and ``instant-ngp-bounded`` (1024 rays asked; Nerfstudio's
   dynamic batch then resizes it towards its sample target), ``vanilla-nerf`` and the main job's
   plugin (``examples/gridlite_paper.md``'s plan, built with ``--until plugin``), in three variants
   run interleaved (round-robin, ``--rounds`` times, medians reported):

   * ``stock``: Nerfstudio with only what it needs to start offline (LPIPS, and nerfacc's backend,
     without which instant-ngp cannot run on the CPU at all);
   * ``before``: our runtime without its fused paths (``NERFIFY_RUNTIME_SKIP`` = :data:`FUSED_PATCHES`);
   * ``after``: our runtime as shipped.

   Each method's FLOPs per ray (one training step counted by ``torch.utils.flop_counter``, in a
   subprocess) times its rays/s, over the GEMM peak, gives the fraction of the FLOP bound achieved.

Run: ``.venv/bin/python -m nerfify_ns.benchmarks.runtime_bench [--rounds 1] [--out bench-results]``
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
import tyro
from rich.console import Console
from rich.table import Table

from nerfify_ns.interrupts import run_interruptible

CONSOLE = Console(width=120)

#: The runtime's fused paths (nerfify_ns.runtime.fused); "before" leaves them out.
FUSED_PATCHES = "denormals,fused_optimizer,contraction,occupancy_chunks,freed_memory,density_reuse"
#: What each variant leaves out of the runtime. "stock" keeps LPIPS (offline start), nerfacc (instant-ngp
#: cannot run on the CPU without it; nerfacto and vanilla-nerf never reach it) and the seeded workers.
VARIANT_SKIP = {"stock": f"hashgrid,cpu_default,{FUSED_PATCHES}", "before": FUSED_PATCHES, "after": ""}
#: The variants of ``steps`` mode (``nerfify_ns.benchmarks.step_timing.VARIANTS``).
STEP_VARIANTS = ("stock", "before", "fused", "after")
PLUGIN = "gridlite"
"""The main job's plugin (examples/gridlite_paper.md), trained as nerfify's generated method."""
PLUGIN_PAPER = Path(__file__).resolve().parents[2] / "examples" / "gridlite_paper.md"
E2E_ARGS = {
    "nerfacto": ["--pipeline.datamanager.train-num-rays-per-batch", "1024"],
    "instant-ngp": ["--pipeline.datamanager.train-num-rays-per-batch", "1024"],
    "instant-ngp-bounded": ["--pipeline.datamanager.train-num-rays-per-batch", "1024"],
    "vanilla-nerf": ["--pipeline.datamanager.train-num-rays-per-batch", "256"],
    PLUGIN: ["--pipeline.datamanager.train-num-rays-per-batch", "512"],  # the main job's CPU batch
}
# Iterations per run; rays/s is the median over the second half of each run (instant-ngp's time
# includes its occupancy-grid updates, every 16 steps, as Nerfstudio's own rays/s does).
E2E_ITERATIONS = {"nerfacto": 16, "vanilla-nerf": 8, "instant-ngp": 32, "instant-ngp-bounded": 32, PLUGIN: 16}


def gemm_gflops(dtype: torch.dtype = torch.float32, n: int = 2048, repeats: int = 7) -> float:
    """Best-of-``repeats`` GFLOP/s of an n x n x n matrix product (2 n^3 FLOPs) at torch's thread count:
    the FLOP bound of the machine (best, not median: the bound is what the cores can do unshared)."""
    a, b = torch.randn(n, n, dtype=dtype), torch.randn(n, n, dtype=dtype)
    torch.mm(a, b)
    best = min(_timed(lambda: torch.mm(a, b)) for _ in range(repeats))
    return 2 * n ** 3 / best / 1e9


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def flops_per_ray(method: str, plugin: Path | None) -> float | None:
    """FLOPs per ray of one training step (:func:`nerfify_ns.benchmarks.step_timing.step_flops`) at the
    method's benchmark batch, in a subprocess (a plugin is generated code; Nerfstudio's models keep state)."""
    rays = int(E2E_ARGS[method][-1])
    cmd = [sys.executable, "-m", "nerfify_ns.benchmarks.step_timing", "--flops",
           "nerfacto" if method == PLUGIN else method, "--rays", str(rays)]
    if method == PLUGIN:
        cmd += ["--plugin", str(plugin)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        CONSOLE.print(f"[red]{method}: FLOP count failed: {proc.stderr[-500:]}")
        return None
    return float(json.loads(lines[-1])["flops_per_ray"])


def step_variants(method: str, plugin: Path | None, repeats: int, threads: int,
                  variants: tuple[str, ...] = STEP_VARIANTS, grid_updates: int = 1) -> dict | None:
    """:func:`nerfify_ns.benchmarks.step_timing.time_variants` in a fresh subprocess pinned to ``threads``, at
    each method's real batch (Instant-NGP: Nerfstudio's dynamic batch, about 262,144 samples a step)."""
    rays = int(E2E_ARGS[method][-1])
    cmd = [sys.executable, "-m", "nerfify_ns.benchmarks.step_timing", "--variants",
           "nerfacto" if method == PLUGIN else method, "--rays", str(rays), "--repeats", str(repeats),
           "--which", ",".join(variants), "--real-batch", "--grid-updates", str(grid_updates)]
    if method == PLUGIN:
        cmd += ["--plugin", str(plugin)]
    env = {**os.environ, "PYTHONWARNINGS": "ignore", "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=7200, env=env)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        CONSOLE.print(f"[red]{method}: step timing failed: {proc.stderr[-800:]}")
        return None
    return json.loads(lines[-1])


def _save(out: Path, results: dict) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "runtime.json").write_text(json.dumps(results, indent=2))


def steps(args: Args, peak_gflops: float, table: Table, out: dict | None = None, save=None) -> dict:
    """In-process training steps under the :data:`STEP_VARIANTS`, interleaved, per method (see
    :func:`step_variants`), with each variant's fraction of the fp32 FLOP bound. A method with an occupancy
    grid is rated with its grid updates amortised (one every 16 steps, as the trainer runs them). Each method's
    entry goes into ``out`` and ``save()`` is called after it."""
    out = {} if out is None else out
    variants = tuple(args.step_variants)
    with tempfile.TemporaryDirectory() as tmp:
        plugin = args.plugin
        if PLUGIN in args.methods and plugin is None:
            plugin = build_plugin(Path(tmp) / "plugin")
        for method in args.methods:
            load = os.getloadavg()
            entry = step_variants(method, plugin, args.step_repeats, args.threads, variants, args.grid_updates)
            if entry is None:
                continue
            entry["load_before"], entry["load_after"] = load, os.getloadavg()
            fpr = flops_per_ray(method, plugin)
            entry["flops_per_ray"] = fpr
            key = "rays_per_s_with_grid_updates" if "grid_update_seconds" in entry else "rays_per_s"
            rps = {v: entry[f"{v}_{key}"] for v in variants}
            for v, value in rps.items():
                entry[f"{v}_fraction_of_fp32_peak"] = value * fpr / (peak_gflops * 1e9) if fpr else None
            for v in variants:
                if v != "after" and "after" in rps:
                    entry[f"after_over_{v}"] = rps["after"] / rps[v]
            out[method] = entry
            frac = entry.get("after_fraction_of_fp32_peak")
            batch = "real batch" if entry.get("real_batch") else f"{entry['rays']} rays"
            ratios = [f"{entry[f'after_over_{v}']:.2f}x {v}" for v in variants if f"after_over_{v}" in entry]
            table.add_row(f"{method} rays/s ({batch}{', grid updates' if key != 'rays_per_s' else ''}): "
                          + " / ".join(variants), "", " / ".join(f"{rps[v]:,.0f}" for v in variants),
                          ", ".join(ratios) + (f", {100 * frac:.2f}% of fp32 peak" if frac else "")
                          + f" (load {load[0]:.1f}-{entry['load_after'][0]:.1f})")
            CONSOLE.print(f"{method}: {json.dumps({k: entry[k] for k in entry if 'rays_per_s' in k})}")
            sys.stdout.flush()
            if save is not None:
                save()
    return out


def build_plugin(out: Path) -> Path:
    """The main job's plugin folder: ``ns-nerfify examples/gridlite_paper.md --until plugin``."""
    proc = subprocess.run([str(Path(sys.executable).parent / "ns-nerfify"), str(PLUGIN_PAPER), "--until", "plugin",
                           "--out", str(out)], capture_output=True, text=True, timeout=1800)
    if not (out / "pyproject.toml").is_file():
        raise SystemExit(f"building the main job's plugin failed (exit {proc.returncode}): {proc.stderr[-500:]}")
    return out


def time_hash_encoding(points: int, repeats: int, position_grad: bool) -> dict[str, float]:
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
    seconds: dict[str, list[float]] = {name: [] for name, _, _ in variants}
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


def e2e_rays_per_sec(method: str, data: Path, work: Path, iterations: int, variant: str,
                     plugin: Path | None = None) -> float | None:
    """Median of Nerfstudio's per-step Train Rays / Sec for one ns-train run (None if it failed)."""
    from nerfify_ns.runtime.launch import ENV_GENERATED, GENERATED_METHOD, ns_train

    env = {"NERFIFY_RUNTIME_SKIP": VARIANT_SKIP[variant]} if VARIANT_SKIP[variant] else {}
    kwargs: dict = {}
    if method == PLUGIN:  # generated code: trained in the sandbox, as the main job trains it
        env[ENV_GENERATED] = str(plugin)
        kwargs["sandbox"] = [plugin]
    run = ns_train(GENERATED_METHOD if method == PLUGIN else method, data, work, iterations=iterations, env=env,
                   timeout=3600, method_args=[*E2E_ARGS[method], "--machine.device-type", "cpu"], **kwargs)
    if not run.ok:
        CONSOLE.print(f"[red]{method} ({variant}) failed: {run.log_path}")
        return None
    rays = run.rays_per_sec[len(run.rays_per_sec) // 2:]  # second half: past start-up and warm-up
    return statistics.median(rays) if rays else None


def e2e(args: Args, peak_gflops: float, table: Table) -> dict:
    """The interleaved end-to-end runs: per method and variant, the median rays/s over the rounds, the
    ratios to stock and before, and the fraction of the fp32 FLOP bound achieved."""
    from nerfify_ns.scenes import write_scene

    training: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        data = write_scene("default", Path(tmp) / "scene")
        plugin = args.plugin
        if PLUGIN in args.methods and plugin is None:
            plugin = build_plugin(Path(tmp) / "plugin")
        runs: dict[str, dict[str, list[float]]] = {m: {v: [] for v in args.variants} for m in args.methods}
        for r in range(args.rounds):
            for method in args.methods:
                iterations = args.iterations or E2E_ITERATIONS[method]
                order = args.variants[r % len(args.variants):] + args.variants[:r % len(args.variants)]
                for variant in order:
                    rays = e2e_rays_per_sec(method, data, Path(tmp) / f"{method}-{variant}-{r}", iterations,
                                            variant, plugin)
                    if rays:
                        runs[method][variant].append(rays)
                    CONSOLE.print(f"round {r}: {method} {variant}: {rays or 0:,.0f} rays/s "
                                  f"(load {os.getloadavg()[0]:.1f})")
        for method in args.methods:
            fpr = flops_per_ray(method, plugin)
            med = {v: statistics.median(x) if x else None for v, x in runs[method].items()}
            entry: dict = {"args": E2E_ARGS[method], "iterations": args.iterations or E2E_ITERATIONS[method],
                           "runs_rays_per_s": runs[method], "flops_per_ray": fpr}
            for v, value in med.items():
                entry[f"{v}_rays_per_s"] = value
                entry[f"{v}_fraction_of_fp32_peak"] = value * fpr / (peak_gflops * 1e9) if value and fpr else None
            for a, b in (("after", "stock"), ("after", "before"), ("before", "stock")):
                if med.get(a) and med.get(b):
                    entry[f"{a}_over_{b}"] = med[a] / med[b]
            training[method] = entry
            cells = [f"{med[v]:,.0f}" if med.get(v) else "-" for v in ("stock", "before", "after")]
            frac = entry.get("after_fraction_of_fp32_peak")
            notes = [f"{entry[k]:.2f}x {k.split('_')[-1]}" for k in ("after_over_stock", "after_over_before")
                     if k in entry]
            table.add_row(f"{method} rays/s: stock / before / after", cells[0], f"{cells[1]} / {cells[2]}",
                          ", ".join(notes + ([f"{100 * frac:.1f}% of fp32 peak"] if frac else [])))
    return training


@dataclass
class Args:
    """CPU runtime benchmark (stock Nerfstudio fallbacks vs nerfify's runtime)."""

    out: Path = Path("bench-results")
    """Folder for runtime.json."""
    points: int = 65536
    """Points per hash-encoding call (about 1024 rays x 64 samples)."""
    repeats: int = 7
    """Repeats per hash-encoding measurement (median reported)."""
    iterations: int | None = None
    """Training iterations per end-to-end run (default: per method, see E2E_ITERATIONS)."""
    methods: list[str] = field(default_factory=lambda: ["nerfacto", "instant-ngp", "instant-ngp-bounded",
                                                        "vanilla-nerf", PLUGIN])
    """Methods for the end-to-end runs (``gridlite``: the main job's plugin)."""
    variants: list[str] = field(default_factory=lambda: ["stock", "before", "after"])
    """Runtime variants, run interleaved (see the module docstring)."""
    rounds: int = 1
    """Round-robin rounds over methods and variants (medians over rounds are reported)."""
    plugin: Path | None = None
    """The main job's plugin folder (default: built from examples/gridlite_paper.md into a temporary folder)."""
    skip_e2e: bool = False
    """Skip the end-to-end ns-train runs."""
    mode: str = "steps"
    """``steps``: in-process training steps, the three variants interleaved in one process per method (robust
    to a shared machine's load); ``e2e``: real ns-train processes (start-up and data loading included); ``both``."""
    step_repeats: int = 5
    """Timed steps per variant in ``steps`` mode (after 2 warm-up steps; medians reported)."""
    step_variants: list[str] = field(default_factory=lambda: list(STEP_VARIANTS))
    """Runtime variants of ``steps`` mode (``stock``, ``before``, ``fused``, ``after``: see
    ``nerfify_ns.benchmarks.step_timing.VARIANTS``)."""
    grid_updates: int = 1
    """Warm-up occupancy-grid updates timed per variant in ``steps`` mode (methods with a grid; 0: none)."""
    threads: int = 1
    """Torch threads of the ``steps`` subprocesses (pinned; 1 keeps a loaded machine's stragglers out of every
    parallel op)."""


def main(args: Args) -> dict:
    results: dict = {"torch_threads": torch.get_num_threads(), "hash_encoding": {}, "training": {}}
    results["load_before"] = os.getloadavg()
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
    peak = {"fp32": gemm_gflops(torch.float32), "bf16": gemm_gflops(torch.bfloat16)}
    results["gemm_gflops"] = peak
    table.add_row("GEMM peak GFLOP/s (2048^3), fp32 / bf16", "", f"{peak['fp32']:,.0f} / {peak['bf16']:,.0f}", "")
    if args.mode in ("steps", "both"):
        if args.threads != torch.get_num_threads():
            torch.set_num_threads(args.threads)
            peak["fp32_at_step_threads"] = gemm_gflops(torch.float32)
        results["steps"] = {}
        save = lambda: _save(args.out, results)  # noqa: E731 - after each method: a stopped run keeps what it measured
        steps(args, peak.get("fp32_at_step_threads", peak["fp32"]), table, results["steps"], save)
    if args.mode in ("e2e", "both") and not args.skip_e2e:
        results["training"] = e2e(args, peak["fp32"], table)
    CONSOLE.print(table)
    results["load_after"] = os.getloadavg()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "runtime.json").write_text(json.dumps(results, indent=2))
    CONSOLE.print(f"wrote {args.out / 'runtime.json'}")
    return results


if __name__ == "__main__":
    run_interruptible(lambda: main(tyro.cli(Args)))
