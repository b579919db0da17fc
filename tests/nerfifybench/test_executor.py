"""The local executor: every task a process of its own; a failed row does not stop the suite; a rerun skips the
finished tasks and runs again the one whose process was cut short (its folder has no result.json)."""

from __future__ import annotations

import json

from nerfify_ns.nerfifybench import load_suite
from nerfify_ns.nerfifybench.run import run_bench

SUITE = """
budget: {iterations: 2, every: 1, resolution: 16, n_train: 4, n_test: 1}
papers:
  - id: gone
    input: missing_paper.pdf
    scenes: [default]
    reference: {plan: bad_plan.yaml, note: a plan the grammar refuses}
    novelty:
      - {id: a, kind: equation, weight: 1.0, where: "Eq. 1"}
"""


def test_row_failures_and_resume(tmp_path):
    (tmp_path / "suite.yaml").write_text(SUITE)
    (tmp_path / "bad_plan.yaml").write_text("method: bad\nbase: nerfacto\nmodel: {sampler: {warp_drive: {}}}\n")
    suite = load_suite(tmp_path / "suite.yaml")
    out = tmp_path / "out"
    first = run_bench(suite, out)
    assert (first.ran, first.skipped) == (2, 0)
    results = json.loads((out / "results.json").read_text())
    reasons = {k: r["reason"] for k, r in results["tasks"].items()}
    assert "missing_paper.pdf" in reasons["gone/default/full/seed0"]
    assert reasons["gone/default/reference/seed0"].startswith("reference plan bad_plan.yaml: ")
    tables = (out / "tables.md").read_text()
    assert "## Row failures" in tables and "gone/default/full/seed0: " in tables
    assert results["summaries"]["gone"]["configs"]["full"]["M"] == 1.0  # no plan: the item is missing
    again = run_bench(suite, out)
    assert (again.ran, again.skipped) == (0, 2)
    (out / "tasks" / "gone" / "default" / "full" / "seed0" / "result.json").unlink()  # as if killed mid-task
    resumed = run_bench(suite, out)
    assert (resumed.ran, resumed.skipped) == (1, 1)
