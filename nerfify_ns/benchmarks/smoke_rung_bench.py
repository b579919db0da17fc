"""Benchmark of the smoke-train rung: a reference plugin (composed after pruning for the 32x32 CI scene)
trained through Nerfstudio's trainer in the sandbox, 3 runs, median wall time printed.

    .venv/bin/python -m nerfify_ns.benchmarks.smoke_rung_bench [--method kplanes-static] [--runs 3] [--iterations 20]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from pathlib import Path

from nerfify_ns.interrupts import run_interruptible


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", default="kplanes-static")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--iterations", type=int, default=20)
    args = parser.parse_args()

    from nerfify_ns.scenes import write_scene
    from nerfify_ns.synthesis.compose import compose
    from nerfify_ns.synthesis.prune import prune_plan
    from nerfify_ns.synthesis.resources import load_reference_plan
    from nerfify_ns.synthesis.scene_probe import probe_scene
    from nerfify_ns.verify.plugin import load_plugin
    from nerfify_ns.verify.smoke_rung import smoke_rung

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        scene = write_scene("default", root / "scene", resolution=32, n_train=12, n_val=2, n_test=2)
        plugin = compose(
            prune_plan(load_reference_plan(args.method), probe_scene(scene)), root / "plugin", record=False
        ).out
        info = load_plugin(plugin)
        times, runs = [], []
        for i in range(args.runs):
            result = smoke_rung(info, scene, root / f"smoke-{i}", iterations=args.iterations, timeout=600)
            times.append(result.seconds)
            runs.append(
                {
                    "status": result.status,
                    "seconds": round(result.seconds, 1),
                    **{
                        k: result.details.get(k)
                        for k in ("iterations", "photometric_first", "photometric_last")
                    },
                }
            )
            print(json.dumps(runs[-1]), flush=True)
        print(
            f"smoke rung ({args.method}, {args.iterations} iterations, sandboxed ns-train): "
            f"median {statistics.median(times):.1f} s over {args.runs} runs"
        )


if __name__ == "__main__":
    run_interruptible(main)
