"""Grammar fuzzing: every plan the grammar accepts composes and passes the static and contract rungs.

    .venv/bin/python -m nerfify_ns.benchmarks.grammar_fuzz --plans 300 --seed 0      # ~1 h, the benchmark lane
    .venv/bin/python -m nerfify_ns.benchmarks.grammar_fuzz --plans 300 --seed 0 --start 150  # plans 150..299 only
    .venv/bin/python -m nerfify_ns.benchmarks.grammar_fuzz --seed 0 --only 17                  # replay plan 17

Plans are random derivations with parameters at their edges (``nerfify_ns.grammar.fuzz``), pruned for a
tiny scene with the plan's own scene flags (the sizes every run on a 32 px scene gets), composed, and
verified in the sandbox (static, contract). Each failure is printed with its seed and index and its
plan is kept under ``bench-results/grammar-fuzz/``; the coverage of the sampled plans (terminals, both
edges of every parameter) is printed at the end and written to ``summary.json``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from nerfify_ns.grammar import load_grammar
from nerfify_ns.grammar.fuzz import PlanSampler
from nerfify_ns.interrupts import run_interruptible
from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.compose import write_plugin
from nerfify_ns.synthesis.prune import prune_plan
from nerfify_ns.synthesis.scene_probe import SceneFacts

RESULTS = Path("bench-results/grammar-fuzz")
TINY = {"image_size": (32, 32), "num_images": 12}


def tiny_scene_facts(plan: Plan) -> SceneFacts:
    """Facts of a 32 px, 12-image scene with the plan's own scene flags."""
    g = load_grammar()
    flags = {name: plan.get(f"scene.{name}", p.default) for name, p in g.terminals["scene"].params.items()}
    return SceneFacts(**flags, **TINY, evidence={k: "the plan's scene flags (fuzzing)" for k in flags})


def check_plan(plan: Plan, work: Path, timeout: float = 300) -> list[str]:
    """Compose ``plan`` (pruned for the tiny scene) and run the static and contract rungs; the failures."""
    from nerfify_ns.verify import run_ladder

    pruned = prune_plan(plan, tiny_scene_facts(plan))
    folder = work / "plugin"
    folder.mkdir(parents=True)
    write_plugin(pruned, folder)
    report = run_ladder(folder, out_dir=work / "verify", rungs=["static", "contract"], repair="off", timeout=timeout)
    return [str(d) for d in report.failures]


def run(plans: int, seed: int, only: int | None = None, keep: Path = RESULTS, start: int = 0) -> dict:
    """Sample ``plans`` plans of ``seed`` and check those from ``start`` on (or the one ``only``)."""
    sampler = PlanSampler(load_grammar(), seed=seed)
    failures, seconds = [], []
    keep.mkdir(parents=True, exist_ok=True)
    for index in range(plans if only is None else only + 1):
        plan = sampler.sample(method=f"fuzz-{seed}-{index}")
        if (only is not None and index != only) or index < start:
            continue
        began = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix="nerfify-fuzz-") as tmp:
            try:
                found = check_plan(plan, Path(tmp))
            except Exception as exc:  # noqa: BLE001 - composing an accepted plan must not fail at all
                found = [f"composition failed: {type(exc).__name__}: {exc}"]
        seconds.append(time.perf_counter() - began)
        status = "ok" if not found else "FAIL"
        print(f"seed {seed} plan {index}: {status} ({seconds[-1]:.1f} s)" + (f": {found[0][:300]}" if found else ""),
              flush=True)
        if found:
            (keep / f"seed{seed}-plan{index}.yaml").write_text(plan.dump())
            failures.append({"seed": seed, "index": index, "failures": found})
    coverage = sampler.coverage.report(load_grammar())
    summary = {"seed": seed, "first": start if only is None else only, "plans": len(seconds),
               "failed": len(failures), "failures": failures,
               "median_seconds": sorted(seconds)[len(seconds) // 2] if seconds else None, "coverage": coverage}
    (keep / f"summary-seed{seed}-from{summary['first']}.json").write_text(json.dumps(summary, indent=2))
    print(f"{len(seconds) - len(failures)} of {len(seconds)} plans compose and pass static + contract; coverage: "
          f"{coverage['terminals_sampled']}/{coverage['terminals_total']} terminals, "
          f"{coverage['parameters_at_both_edges']}/{coverage['parameters']} parameters at both edges")
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plans", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", type=int, default=None, help="replay one plan index of the seed")
    parser.add_argument("--start", type=int, default=0, help="check the plans from this index on (the sample "
                        "sequence is the same: two processes can split a seed's plans)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    summary = run(args.plans, args.seed, args.only, args.out, args.start)
    return 1 if summary["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(run_interruptible(main))
