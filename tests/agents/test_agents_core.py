"""The agents' core with a scripted model (deterministic replay): the client (finish reason, json-repair salvage,
validation and re-asking with the problems, bounded retries with backoff, budgets that stop cleanly), the
response cache, the planner's merge (disagreements with both sides' evidence; the model wins only with a quote
found in the paper), and that nothing of this is imported on the default path."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

from nerfify_ns.agents.cache import ResponseCache
from nerfify_ns.agents.client import Client
from nerfify_ns.agents.config import LLMConfig
from nerfify_ns.agents.errors import BudgetExceeded, InvalidAnswer, ProviderError
from nerfify_ns.agents.providers import ScriptedProvider
from nerfify_ns.agents.usage import Ledger

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"


def client(answers, tmp_path=None, **settings):
    config = LLMConfig(backend="scripted", model="m", **{"retries": 2, "backoff": 0.5, **settings})
    provider = ScriptedProvider(answers)
    sleeps = []
    cache = ResponseCache(tmp_path / "cache.sqlite" if tmp_path else None)
    c = Client(config, provider, cache, Ledger("m", True, config.run_tokens, config.stage_tokens), sleeps.append)
    return c, provider, sleeps


def test_default_path_imports_no_agent_and_no_sdk():
    """`import nerfify_ns.pipeline` / `.cli` (what `ns-nerfify PAPER` without --llm runs) imports neither the
    agents nor openai, anthropic, json_repair or llama_cpp."""
    code = ("import sys, nerfify_ns.pipeline, nerfify_ns.cli, nerfify_ns.evaluate.report; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'openai', 'anthropic', 'json_repair', "
            "'llama_cpp'}), 'nerfify_ns.agents' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["[]", "False"], done.stdout


def test_salvage_validate_and_reask(tmp_path):
    c, provider, _ = client({"planner": [
        '```json\n{"a": 1,}\n```',          # a fence and a trailing comma: salvaged, but `a` must be 2
        '{"a": 2',                           # cut JSON, salvaged by json-repair, accepted
    ]})
    answer = c.ask("planner", [{"role": "user", "content": "q"}],
                   check=lambda v: [] if v.get("a") == 2 else [f"a must be 2, got {v.get('a')}"])
    assert answer.value == {"a": 2} and answer.attempts == 2
    assert any("json-repair" in n for n in answer.notes)
    reask = provider.requests[1].messages[-1]["content"]
    assert "a must be 2, got 1" in reask  # the problems went back to the model


def test_invalid_after_the_retries_and_not_json():
    c, _, _ = client({"planner": ["no json here at all", "still none", "nope"]})
    with pytest.raises(InvalidAnswer, match="rejected after 3 tries: not JSON"):
        c.ask("planner", [{"role": "user", "content": "q"}])


def test_cut_answer_is_not_an_answer_and_is_not_retried():
    c, provider, _ = client({"planner": [{"text": '{"a": ', "finish": "length"}, '{"a": 1}']}, max_tokens=8)
    with pytest.raises(ProviderError, match=r"cut at max_tokens=8 .*raise --llm-max-tokens"):
        c.ask("planner", [{"role": "user", "content": "q"}])
    assert len(provider.requests) == 1


def test_transient_failures_are_retried_with_doubling_backoff():
    c, provider, sleeps = client({"coder": [{"error": "http", "message": "HTTP 503", "retry": True},
                                            {"error": "timeout", "message": "slow", "retry": True}, '{"ok": true}']})
    assert c.ask("coder:x", [{"role": "user", "content": "q"}]).value == {"ok": True}
    assert sleeps == [0.5, 1.0] and c.ledger.total().failures == 2 and c.ledger.total().calls == 1


def test_budget_stops_cleanly_per_run_and_per_stage():
    c, provider, _ = client({"*": ['{"x": "' + "y" * 400 + '"}'] * 5}, run_tokens=150)
    c.ask("planner", [{"role": "user", "content": "q"}])  # about 100 tokens: under the budget
    c.ask("planner", [{"role": "user", "content": "q2"}])
    with pytest.raises(BudgetExceeded, match=r"run's token budget \(150\) is spent"):
        c.ask("coder:a", [{"role": "user", "content": "q3"}])
    assert len(provider.requests) == 2
    c2, _, _ = client({"*": ['{"x": "' + "y" * 400 + '"}'] * 5}, stage_tokens=50, run_tokens=None)
    c2.ask("coder:a", [{"role": "user", "content": "q"}])
    with pytest.raises(BudgetExceeded, match="coder stage's token budget"):
        c2.ask("coder:b", [{"role": "user", "content": "q"}])
    c2.ask("critic", [{"role": "user", "content": "q"}])  # another stage still has its budget


def test_money_where_the_price_is_known():
    ledger = Ledger("gpt-4o-mini", local=False, run_usd=0.001)
    ledger.charge("planner", 2000, 1000)  # 2000 * 0.15e-6 + 1000 * 0.6e-6
    assert ledger.total().cost_usd == pytest.approx(0.0009)
    ledger.charge("planner", 2000, 1000)
    with pytest.raises(BudgetExceeded, match="0.001 USD is spent"):
        ledger.before_call("coder:x")
    unknown = Ledger("some-model", local=False)
    unknown.charge("planner", 10, 10)
    assert unknown.to_dict()["total"]["cost_usd"] is None and unknown.to_dict()["price_known"] is False


def test_cache_replays_and_keys_by_content(tmp_path):
    c, provider, _ = client({"planner": ['{"v": 1}', '{"v": 2}']}, tmp_path)
    msgs = [{"role": "user", "content": "q"}]
    assert c.ask("planner", msgs).value == {"v": 1}
    c2, provider2, _ = client({"planner": []}, tmp_path)  # a new process: no answers at all
    assert c2.ask("planner", msgs).value == {"v": 1} and provider2.requests == []
    assert c2.ledger.total().cache_hits == 1 and c2.ledger.total().calls == 0
    with pytest.raises(ProviderError, match="no answer left"):  # other messages: another key, a real call
        c2.ask("planner", [{"role": "user", "content": "other"}])


# ------------------------------------------------------------------------------------------ the planner
@pytest.fixture(scope="module")
def paper_run():
    from nerfify_ns.pipeline import PaperOptions, run_paper

    return run_paper(EXAMPLE, options=PaperOptions(dry_run=True))


def test_planner_merge_quotes_decide(paper_run):
    """Two disagreements: the RGB loss (the model quotes a sentence of the paper: taken) and the direction
    encoding (a made-up quote: the deterministic choice stays). Both are listed with both sides' evidence."""
    from nerfify_ns.agents.planner import merge_plans

    model = copy.deepcopy(dict(paper_run.plan))
    model["model"]["losses"]["rgb"] = {"l1": {}}
    model["model"]["field"]["MLPField"]["dir_encoding"] = {"frequency": {"num_frequencies": 4}}
    model["evidence"] = {
        "model.losses.rgb": "a colour MLP with two hidden layers of 64 units predicts RGB with a sigmoid",
        "model.field.MLPField.dir_encoding": "we encode directions with Fourier features of four frequencies"}
    merged, found = merge_plans(paper_run.plan, model, paper_run.document)
    by_path = {d.path: d for d in found}
    assert set(by_path) == {"model.losses.rgb", "model.field.MLPField.dir_encoding"}
    rgb, dirs = by_path["model.losses.rgb"], by_path["model.field.MLPField.dir_encoding"]
    assert (rgb.deterministic, rgb.model, rgb.quote_found, rgb.winner) == ("l2", "l1", True, "model")
    assert (dirs.deterministic, dirs.model, dirs.quote_found, dirs.winner) == ("sh", "frequency", False,
                                                                              "deterministic")
    assert "spherical harmonics" in dirs.deterministic_evidence.lower() and dirs.model_evidence
    assert merged.get("model.losses.rgb") == {"l1": {}} and "sh" in merged.get("model.field.MLPField.dir_encoding")
    assert merged.get("evidence")["model.losses.rgb"].startswith("model (quote found in the paper)")


def test_planner_invalid_model_plan_falls_back_with_one_warning(paper_run):
    """A model plan our grammar rejects (three times, re-asked with the violations) -> one warning line and the
    deterministic plan, unchanged."""
    from nerfify_ns.agents import Agents
    from nerfify_ns.pipeline import PaperOptions, run_paper

    bad = copy.deepcopy(dict(paper_run.plan))
    bad["model"]["sampler"] = {"proposal": {"nerf_samples": -3}}
    provider = ScriptedProvider({"planner": [json.dumps(bad)] * 3})
    agents = Agents(LLMConfig(backend="scripted", model="m"), provider, ResponseCache(None))
    result = run_paper(EXAMPLE, options=PaperOptions(dry_run=True, agents=agents))
    assert result.plan == paper_run.plan
    assert len(agents.warnings) == 1 and agents.warnings[0].startswith("llm planner: the model's answer was rejected "
                                                                       "after 3 tries: ")
    assert "nerf_samples" in provider.requests[1].messages[-1]["content"]  # the violation went back


SMOLLM2_PLAN = (  # decoded by SmolLM2-135M under the planner's GBNF (seed 1, 2026-11-24); validate accepts it
    '{"method":"nerfacto-ref","scene":{"bounded":false,"timestamps":true},"base":"nerfacto","trainer":{},'
    '"datamanager":{},"model":{"field":{"MLPField":{"pos_encoding":{"kplanes_time":{}},"dir_encoding":{"sh":{}},'
    '"backbone":{},"density_head":{"density_split":{}},"rgb_head":{},"spatial_distortion":{"scene_contraction":{}},'
    '"appearance_embedding":{}}},"sampler":{"proposal":{}},"renderer":{},"losses":{"rgb":{"l2":{}},"interlevel":{},'
    '"distortion":{}},"camera_optimizer":{"so3xr3":{}},"bounds":{}},"optimizers":{"fields":{"optimizer":{"adam":{}},'
    '"scheduler":{"exponential_decay":{}}},"proposal_networks":{"optimizer":{"adam":{}},"scheduler":{"multistep":{}}},'
    '"camera_opt":{"optimizer":{"adam":{}},"scheduler":{"exponential_decay":{}}}},'
    '"evidence":{"model.field.MLPField.pos_encoding":"Nerfstudio defaults"}}')


def test_planner_gbnf_is_structure_only():
    """The planner's GBNF accepts a plan of choices at their defaults with an evidence map, and refuses
    parameters, custom components, other annotations and strings past the bound; what it accepts validates."""
    from nerfify_ns.agents.planner import MAX_STRING, plan_problems, planner_constraint
    from nerfify_ns.grammar.gbnf_match import GbnfGrammar

    schema, gbnf = planner_constraint("llamacpp_gbnf")
    assert schema is None
    g = GbnfGrammar(gbnf)
    assert g.accepts(SMOLLM2_PLAN) and plan_problems(json.loads(SMOLLM2_PLAN)) == []
    with_param = SMOLLM2_PLAN.replace('"backbone":{}', '"backbone":{"num_layers":2}')
    custom = SMOLLM2_PLAN.replace('"rgb_head":{}', '"rgb_head":{"custom":{"module":"components.x","class":"X"}}')
    notes = SMOLLM2_PLAN[:-1] + ',"notes":[]}'
    long = SMOLLM2_PLAN.replace("Nerfstudio defaults", "x" * (MAX_STRING + 1))
    for text in (with_param, custom, notes, long):
        assert not g.accepts(text)


def test_scripted_answers_file(tmp_path):
    """``--llm scripted:ANSWERS.yaml``: a replayed model from a file (stage -> answers); a bad file is one line."""
    from nerfify_ns.agents import Agents
    from nerfify_ns.agents.errors import LLMSetupError

    answers = tmp_path / "answers.yaml"
    answers.write_text("planner:\n  - '{\"a\": 1}'\n")
    agents = Agents(LLMConfig.parse(f"scripted:{answers}", cache=tmp_path / "c.sqlite"))
    assert agents.client.ask("planner", [{"role": "user", "content": "q"}]).value == {"a": 1}
    (tmp_path / "bad.yaml").write_text("{unclosed")
    with pytest.raises(LLMSetupError, match="cannot read it"):
        Agents(LLMConfig.parse(f"scripted:{tmp_path / 'bad.yaml'}", cache=tmp_path / "c.sqlite"))
