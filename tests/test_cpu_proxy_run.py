"""A budgeted run on a vanilla-NeRF base (NeRF's 8 x 256 MLP, 64 + 128 samples per ray: about a GFLOP per ray, far
beyond a CPU's budget) trains a CPU proxy of the method, fits its budget, states the proxy, and renders colour."""

from __future__ import annotations

import json
import time
from dataclasses import replace

import pytest

BUDGET_SECONDS = 240.0
"""The default budget of ``ns-nerfify PAPER``."""
OVERRUN = 1.15
"""What a run may exceed its budget by: the estimate of the time left is made from the smoke rung's pace, and a
shared machine's pace changes while it trains (the report is written after the budget's evaluation)."""


@pytest.mark.slow
def test_a_budgeted_vanilla_nerf_run_fits_its_budget_and_renders_colour(tmp_path):
    from nerfify_ns.budget import PAPER_BUDGET
    from nerfify_ns.pipeline import run_compose
    from nerfify_ns.plan import Plan
    from nerfify_ns.synthesis.resources import load_reference_plan

    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    budget = replace(PAPER_BUDGET, seconds=BUDGET_SECONDS)  # the paper command's budget: the proxy allowed
    start = time.perf_counter()
    result = run_compose(plan, tmp_path / "out", budget=budget)
    wall = time.perf_counter() - start
    summary = result.summary
    assert result.outcome.ok, result.outcome.failed
    assert wall <= OVERRUN * BUDGET_SECONDS, f"{wall:.0f} s for a {BUDGET_SECONDS:.0f} s budget"

    proxy = summary["schedule"]["proxy"]  # recorded in the plan and the summary, named in the report's headline
    assert proxy["headline"].startswith("trained a CPU proxy: ") and "samples per ray" in proxy["headline"]
    assert any(s["path"].endswith("num_importance_samples") and s["proxy"] < s["paper"] for s in proxy["settings"])
    assert all(a in summary["method_args"] for a in proxy["ns_train_args"])
    saved = Plan.load(tmp_path / "out" / "plan.yaml")
    assert saved["schedule"]["proxy"]["headline"] == proxy["headline"]
    assert saved["model"]["sampler"]["hierarchical"]["num_importance_samples"] == 128  # the paper's, in the code
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert proxy["headline"] in report["outcome"]["result"]

    diagnostics = summary["diagnostics"]
    assert diagnostics["colour_spread_gt"] > 0 and diagnostics["colour_spread"] is not None
    assert diagnostics["colour_spread_ratio"] >= 0.5, (
        f"grey renders: colour spread {diagnostics['colour_spread']:.4f} against the ground truth's "
        f"{diagnostics['colour_spread_gt']:.4f} after {summary['iterations_done']} iterations ({proxy['headline']})")
