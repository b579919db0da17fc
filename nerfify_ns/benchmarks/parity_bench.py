"""Parity and pruning benchmark: generated plugins against Nerfstudio's built-in methods, side by side.

    python -m nerfify_ns.benchmarks.parity_bench [--methods vanilla-nerf nerfacto instant-ngp tensorf]
                                            [--out bench-results/parity] [--repeats 2] [--skip-pruning] [--timing-only]

Parity: for each method, the reference plan's plugin (pruning off) and the built-in method train in
the same run on the same scene with the same settings and seeds; the benchmark prints held-out PSNR
(final checkpoint, mean over the test views, mean over the seeds) and the median training throughput
of both, their difference and ratio against the parity bounds (0.5 dB, 10%), and writes PSNR
against wall-clock seconds for every run as CSV and a PNG plot. Throughput is judged on an
interleaved training-step timing of both models in one process (:mod:`.step_timing`): the rays/s of
two ns-train processes, also printed, move by up to ~10% with the machine's load alone.
``--timing-only`` runs just that timing (a few minutes).

Pruning: the nerfacto reference plan generated as is (--keep-all) and pruned for the bounded
synthetic scene, same budget; prints the speed-up (seconds per iteration) and the PSNR of both at
equal wall-clock time (the shorter run's end).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

from nerfify_ns.evaluate.curve import Curve, plot_curves, record_curve, train_for_curve, write_curve_csv
from nerfify_ns.evaluate.smoke_train import generated_env
from nerfify_ns.interrupts import run_interruptible
from nerfify_ns.runtime.launch import GENERATED_METHOD, offline_prefix, run_logged
from nerfify_ns.scenes import write_scene
from nerfify_ns.synthesis.compose import compose
from nerfify_ns.synthesis.prune import prune_plan
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.synthesis.scene_probe import probe_scene

# Per method: iterations and ray batch that fit a CPU budget (the MLP-only NeRF is ~10 ms per ray), and
# arguments both sides get (instant-ngp's dynamic batch would otherwise grow to 262,144 samples).
BUDGET = {"vanilla-nerf": (50, 64), "nerfacto": (150, 1024), "instant-ngp": (150, 1024), "tensorf": (150, 1024)}
EVERY = {"vanilla-nerf": 50}  # checkpoints evaluated per run: rendering is the NeRF's bottleneck
QUICK = {"vanilla-nerf": (30, 64), "nerfacto": (60, 512), "instant-ngp": (60, 512), "tensorf": (60, 512)}
REPEATS = {"vanilla-nerf": 1}  # its rendering is the slowest; runs are reproducible, so one seed suffices
EXTRA = {"instant-ngp": ["--pipeline.target-num-samples", "32768"]}


def _args(method: str, rays: int, seed: int) -> list[str]:
    return ["--machine.seed", str(seed), "--mixed-precision", "False",
            "--pipeline.datamanager.train-num-rays-per-batch", str(rays),
            "--pipeline.datamanager.eval-num-rays-per-batch", str(rays), *EXTRA.get(method, [])]


def _run(method: str, label: str, scene: Path, out: Path, iterations: int, every: int, args: list[str],
         env=None) -> dict:
    run = train_for_curve(method, scene, out, iterations=iterations, every=every, method_args=args, env=env,
                          timeout=3600)
    if not run.ok:
        raise SystemExit(f"{label}: training failed (exit {run.returncode}); see {run.log_path}")
    curve = record_curve(run, out, label=label, timeout=1800, env=env)
    return {"label": label, "curve": curve, "psnr": curve.points[-1].psnr,
            "rays_per_sec": run.median_rays_per_sec,
            "sec_per_iter": curve.points[-1].train_seconds / curve.points[-1].step}


def _psnr_at(curve: Curve, seconds: float) -> float:
    """PSNR at ``seconds`` of training, linearly interpolated between checkpoints."""
    pts = curve.points
    for a, b in zip(pts, pts[1:], strict=False):
        if a.train_seconds <= seconds <= b.train_seconds:
            w = (seconds - a.train_seconds) / max(b.train_seconds - a.train_seconds, 1e-9)
            return a.psnr + w * (b.psnr - a.psnr)
    return pts[-1].psnr if seconds >= pts[-1].train_seconds else pts[0].psnr


def step_timing(method: str, plugin_dir: Path, repeats: int = 15) -> dict:
    """The interleaved training-step timing of :mod:`nerfify_ns.benchmarks.step_timing`, in a subprocess
    without network (it imports the generated plugin); its result is the last JSON line of its log."""
    cmd = [*offline_prefix(), sys.executable, "-m", "nerfify_ns.benchmarks.step_timing", str(plugin_dir), method,
           "--rays", str(BUDGET[method][1]), "--repeats", str(repeats)]
    log = Path(plugin_dir).parent / "step_timing.log"
    result = run_logged(cmd, log, Path(plugin_dir).parent, timeout=1800, env={"PYTHONWARNINGS": "ignore"})
    lines = [line for line in result.tail(200).splitlines() if line.startswith("{")]
    if result.returncode != 0 or result.timed_out or not lines:
        raise SystemExit(f"{method}: step timing failed (exit {result.returncode}); see {log}")
    return json.loads(lines[-1])


def _side(runs: list[dict]) -> dict:
    """Mean held-out PSNR, its spread over the seeds, median throughput of one side's runs."""
    psnrs = [r["psnr"] for r in runs]
    return {"psnr": statistics.mean(psnrs), "psnr_runs": psnrs, "psnr_spread": max(psnrs) - min(psnrs),
            "rays_per_sec": statistics.median(r["rays_per_sec"] for r in runs)}


def parity(method: str, scene: Path, out: Path, every: int, seed: int, repeats: int, train: bool = True) -> dict:
    """Built-in and generated, ``repeats`` seeds each, interleaved (built-in, generated, built-in, ...)
    so that a drift in machine load hits both sides alike; PSNR is the mean over the seeds, next to
    the built-in's own spread. With the runtime's seeded workers a seed fixes a run of either side,
    so equal PSNR per seed is what equivalence looks like. ``train=False``: the step timing only."""
    iterations, rays = BUDGET[method]
    every = EVERY.get(method, every)
    plugin = compose(load_reference_plan(method), out / "plugin", overwrite=True, record=False)
    timing = step_timing(method, plugin.out)
    if not train:
        return {"method": method, "rays_per_batch": rays, "step_timing": timing}
    sides: dict[str, list[dict]] = {"builtin": [], "generated": []}
    for k in range(REPEATS.get(method, repeats)):
        args = _args(method, rays, seed + k)
        sides["builtin"].append(_run(method, f"{method} (Nerfstudio) seed {seed + k}", scene,
                                     out / f"builtin-{k}", iterations, every, args))
        sides["generated"].append(_run(GENERATED_METHOD, f"{method} (generated) seed {seed + k}", scene,
                                       out / f"generated-{k}", iterations, every, args,
                                       env=generated_env(plugin.out)))
    curves = [r["curve"] for runs in sides.values() for r in runs]
    write_curve_csv([p for c in curves for p in c.points], out / "curves.csv")
    plot_curves(curves, out / "curves.png", title=f"{method}: held-out PSNR against training time")
    builtin, generated = _side(sides["builtin"]), _side(sides["generated"])
    return {"method": method, "iterations": iterations, "rays_per_batch": rays, "seeds": REPEATS.get(method, repeats),
            "psnr_builtin": builtin["psnr"], "psnr_generated": generated["psnr"],
            "psnr_builtin_runs": builtin["psnr_runs"], "psnr_generated_runs": generated["psnr_runs"],
            "psnr_builtin_spread": builtin["psnr_spread"],
            "psnr_delta": generated["psnr"] - builtin["psnr"],
            "rays_per_sec_builtin": builtin["rays_per_sec"], "rays_per_sec_generated": generated["rays_per_sec"],
            "throughput_ratio": generated["rays_per_sec"] / builtin["rays_per_sec"],
            "step_timing": timing, "step_throughput_ratio": timing["throughput_ratio"]}


def pruning(scene: Path, out: Path, every: int, seed: int) -> dict:
    iterations, rays = BUDGET["nerfacto"]
    every = EVERY.get("nerfacto", every)
    plan = load_reference_plan("nerfacto")
    runs = {}
    for label, variant in (("kept", plan), ("pruned", prune_plan(plan, probe_scene(scene)))):
        plugin = compose(variant, out / label / "plugin", overwrite=True, record=False)
        runs[label] = _run(GENERATED_METHOD, f"nerfacto {label}", scene, out / label, iterations, every,
                           _args("nerfacto", rays, seed), env=generated_env(plugin.out))
    horizon = min(r["curve"].points[-1].train_seconds for r in runs.values())
    plot_curves([r["curve"] for r in runs.values()], out / "curves.png")
    return {"iterations": iterations,
            "speedup_sec_per_iter": runs["kept"]["sec_per_iter"] / runs["pruned"]["sec_per_iter"],
            "equal_time_seconds": horizon,
            "psnr_at_equal_time_kept": _psnr_at(runs["kept"]["curve"], horizon),
            "psnr_at_equal_time_pruned": _psnr_at(runs["pruned"]["curve"], horizon),
            "psnr_final_kept": runs["kept"]["psnr"], "psnr_final_pruned": runs["pruned"]["psnr"]}


def _parity_line(r: dict) -> str:
    """One method's verdict against the parity bounds: PSNR within 0.5 dB, throughput within 10%
    (judged on the interleaved step timing; the ns-train rays/s of two processes is shown beside it)."""
    t = r["step_timing"]
    timing = (f"step {t['median_step_seconds_builtin']:.3f} s vs {t['median_step_seconds_generated']:.3f} s "
              f"(throughput ratio {t['throughput_ratio']:.3f})")
    if "psnr_delta" not in r:
        return f"{r['method']:>13}: {timing}"
    ok = abs(r["psnr_delta"]) <= 0.5 and abs(t["throughput_ratio"] - 1) <= 0.1
    return (f"{r['method']:>13}: PSNR built-in {r['psnr_builtin']:.2f} dB (spread {r['psnr_builtin_spread']:.2f}), "
            f"generated {r['psnr_generated']:.2f} dB (delta {r['psnr_delta']:+.2f}); {timing}; ns-train rays/s "
            f"{r['rays_per_sec_builtin']:.0f} vs {r['rays_per_sec_generated']:.0f} (ratio {r['throughput_ratio']:.3f})"
            f" -> {'within' if ok else 'OUTSIDE'} 0.5 dB / 10%")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="*", default=list(BUDGET))
    parser.add_argument("--out", type=Path, default=Path("bench-results/parity"))
    parser.add_argument("--every", type=int, default=25)
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=2, help="seeds per side (seed, seed+1, ...)")
    parser.add_argument("--skip-pruning", action="store_true")
    parser.add_argument("--timing-only", action="store_true",
                        help="only the interleaved training-step timing (no ns-train runs, no pruning)")
    parser.add_argument("--quick", action="store_true", help="a short budget (QUICK) for a first look")
    ns = parser.parse_args()
    if ns.quick:
        BUDGET.update(QUICK)
        EVERY.update({m: n // 2 for m, (n, _) in QUICK.items()})
    # Few test views: every checkpoint renders all of them, and the MLP-only NeRF renders ~100 rays/s.
    scene = write_scene("default", ns.out / "scene", resolution=ns.resolution, n_test=3, overwrite=True)
    results = {"parity": [parity(m, scene, ns.out / m, ns.every, ns.seed, ns.repeats, train=not ns.timing_only)
                          for m in ns.methods]}
    for r in results["parity"]:
        print(_parity_line(r))
    if not (ns.skip_pruning or ns.timing_only):
        p = results["pruning"] = pruning(scene, ns.out / "pruning", ns.every, ns.seed)
        print(f"pruning (nerfacto, bounded scene): {p['speedup_sec_per_iter']:.2f}x faster per iteration; PSNR at "
              f"{p['equal_time_seconds']:.0f} s: pruned {p['psnr_at_equal_time_pruned']:.2f} dB vs kept "
              f"{p['psnr_at_equal_time_kept']:.2f} dB")
    (ns.out / "summary.json").write_text(json.dumps(results, indent=2))
    print(f"wrote {ns.out / 'summary.json'}")


if __name__ == "__main__":
    run_interruptible(main)
