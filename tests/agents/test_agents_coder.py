"""The coder agent with a scripted model: the ladder's diagnosis goes back, the node is installed through the
plugin's file DAG (the plan's custom alternative), checked in the sandbox, and carries its equations and
sentences; the report says a model wrote it. CI: GridLite's colour head, wrong (4 channels) then right. Bench:
BioNeRF's backbone, wrong three ways (shape mismatch, NaN for large inputs, a missing module) then right, with
every rung (smoke included) and training, and a cached rerun without any call."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from coder_answers import (
    MISSING_MODULE,
    NAN_FOR_LARGE,
    RGB_HEAD,
    RGB_HEAD_FOUR,
    RIGHT,
    SHAPE_MISMATCH,
    answer,
    rgb_answer,
    rgb_head_hole,
)

from nerfify_ns.agents import Agents, LLMConfig
from nerfify_ns.agents.cache import ResponseCache
from nerfify_ns.agents.providers import ScriptedProvider

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"
PAPERS = ROOT.parent / "shared" / "papers"


def scripted(answers, cache=None, rounds=3):
    provider = ScriptedProvider({"coder": answers})
    config = LLMConfig(backend="scripted", model="replay", coder_rounds=rounds)
    return Agents(config, provider, cache if cache is not None else ResponseCache(None)), provider


@pytest.mark.slow
def test_coder_stops_within_its_rounds_with_the_diagnosis(tmp_path):
    """CI's case (cheap checks): a syntax error (the composer refuses it), then an import of a missing module (the
    sandboxed static rung), with a bound of two rounds: each diagnosis goes back, then the loop stops, the compiler's
    result stands and the record, the warning and agents.json carry the last diagnosis."""
    from nerfify_ns.pipeline import PaperOptions, run_paper

    impl = run_paper(EXAMPLE, options=PaperOptions(dry_run=True)).implementation
    rgb_head_hole(impl)
    broken = RGB_HEAD.replace("def forward(self, features):", "def forward(self, features)")
    missing = RGB_HEAD.replace("import torch\n", "import torch\nimport gridlite_colour_tables  # noqa\n", 1)
    agents, provider = scripted([rgb_answer(broken), rgb_answer(missing)], rounds=2)
    (result,) = agents.code(impl, work=tmp_path / "work")
    first, second = result["rounds"]
    assert result["status"] == "rejected" and first["rungs"] == {}  # the composer refused it before any rung
    assert "does not parse (line 12: expected ':')" in first["diagnosis"]
    assert first["diagnosis"] in provider.requests[1].messages[-1]["content"]
    assert second["rungs"] == {"static": "fail", "contract": "skip", "stability": "skip"}
    assert "rung static, rule import, at gridlite/components/rgb_head_model.py:2" in second["diagnosis"]
    assert "gridlite_colour_tables" in second["diagnosis"] and str(tmp_path) not in second["diagnosis"]
    (record,) = impl.records
    assert record.status == "not implemented" and "components.rgb_head_model" not in impl.sources
    assert "gridlite_colour_tables" in record.notes[-1] and len(record.checks["coder"]) == 2
    assert len(agents.warnings) == 1 and "no passing node within 2 round(s)" in agents.warnings[0]
    assert len(provider.requests) == 2


@pytest.mark.bench
@pytest.mark.slow
def test_coder_feeds_back_the_diagnosis_and_installs_the_node(tmp_path):
    from nerfify_ns.evaluate.report import write_report
    from nerfify_ns.pipeline import PaperOptions, run_paper
    from nerfify_ns.synthesis.novel.records import write_records

    run = run_paper(EXAMPLE, options=PaperOptions(dry_run=True))
    impl = run.implementation
    record = rgb_head_hole(impl)
    agents, provider = scripted([rgb_answer(RGB_HEAD_FOUR), rgb_answer(RGB_HEAD)])
    (result,) = agents.code(impl, work=tmp_path / "work")
    assert result["status"] == "accepted" and [r["status"] for r in result["rounds"]] == ["fail", "pass"]
    first = result["rounds"][0]
    assert first["rungs"] == {"static": "pass", "contract": "fail", "stability": "skip"}
    feedback = provider.requests[1].messages[-1]["content"]
    assert "rung contract, rule component-contract" in feedback and "rgb: shape (64, 4), contract [N, 3]" in feedback
    # the interface is frozen: the prompt names the module, class, constructor and contract
    assert '"class": "RgbHeadModelPart"' in provider.requests[0].messages[1]["content"]
    entry = impl.plan.get("model.field.MLPField.rgb_head.custom")
    assert entry["source"] == "model" and entry["module"] == "components.rgb_head_model"
    assert "two hidden layers of 64 units" in entry["evidence"] and entry["implements"] == ["Sec. 3.1"]
    assert impl.sources["components.rgb_head_model"] == RGB_HEAD and record.status == "implemented"
    assert not (tmp_path / "work" / "rgb_head" / "round-1" / "plugin").exists()  # verdicts kept, copies not
    # the report: the hole was written by a model, with its calls and tokens
    folder = tmp_path / "run"
    folder.mkdir()
    write_records(folder, impl, run.document)
    agents.write(folder)
    write_report(folder)
    html = (folder / "report.html").read_text()
    assert "written by" in html and "coder: rgb_head (RGBHead): accepted" in html
    data = json.loads((folder / "agents.json").read_text())
    assert data["usage"]["scopes"]["coder:rgb_head"]["calls"] == 2
    assert ">model<" in html.replace(" ", "") and "2 calls (0 cached)" in html


# ------------------------------------------------------------------------------------------ bench lane
def _bionerf(tmp_path):
    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.novel import implement_holes
    from nerfify_ns.synthesis.novel.implement import revert
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    path = PAPERS / "bionerf" / "bionerf.pdf"
    if not path.is_file():
        pytest.skip(f"real paper {path} not present (../shared/papers is outside the project and never committed)")
    doc = ingest(path)
    impl = implement_holes(doc, plan_from_paper(doc).plan)
    revert(impl, ["backbone"], "set aside for the coder test")  # as if the equations had not compiled
    return doc, impl


@pytest.mark.bench
@pytest.mark.slow
def test_bionerf_three_wrong_answers_stop_with_the_diagnosis(tmp_path):
    _, impl = _bionerf(tmp_path)
    agents, provider = scripted([answer(SHAPE_MISMATCH), answer(NAN_FOR_LARGE), answer(MISSING_MODULE)], rounds=3)
    (result,) = agents.code(impl, work=tmp_path / "work")
    rounds = result["rounds"]
    assert result["status"] == "rejected" and len(rounds) == 3
    assert rounds[0]["rungs"]["contract"] == "fail" and "hidden" in rounds[0]["diagnosis"]  # width != get_out_dim
    assert rounds[1]["rungs"]["stability"] == "fail" and "values_1e8" in rounds[1]["diagnosis"]
    assert "bionerf_memory" in rounds[2]["diagnosis"]
    for k in (1, 2):  # each diagnosis went back to the model
        assert rounds[k - 1]["diagnosis"].splitlines()[0] in provider.requests[k].messages[-1]["content"]
    record = next(r for r in impl.records if r.id == "backbone")
    assert record.status == "not implemented" and "bionerf_memory" in record.notes[-1]
    assert agents.warnings and "no passing node within 3 round(s)" in agents.warnings[0]


@pytest.mark.bench
@pytest.mark.slow
def test_bionerf_right_in_the_fourth_round_passes_every_rung_trains_and_replays(tmp_path):
    from nerfify_ns.budget import Budget
    from nerfify_ns.pipeline import RunOptions, run_compose

    _, impl = _bionerf(tmp_path)
    cache = ResponseCache(tmp_path / "cache.sqlite")
    answers = [answer(SHAPE_MISMATCH), answer(NAN_FOR_LARGE), answer(MISSING_MODULE), answer(RIGHT)]
    agents, provider = scripted(answers, cache, rounds=4)
    (result,) = agents.code(impl, work=tmp_path / "work", smoke=True)
    assert result["status"] == "accepted" and [r["status"] for r in result["rounds"]] == ["fail"] * 3 + ["pass"]
    assert result["rounds"][-1]["rungs"] == {"static": "pass", "contract": "pass", "stability": "pass",
                                             "smoke": "pass"}
    budget = Budget(iterations=80, every=80, cpu_presets=True, timeout=3600,
                    train_args=("--pipeline.datamanager.train-num-rays-per-batch", "256"),
                    scene={"resolution": 32, "n_train": 12, "n_val": 2, "n_test": 2})
    run = run_compose(impl.plan, tmp_path / "run", options=RunOptions(budget=budget), sources=impl.sources)
    assert run.outcome.failed is None, run.outcome.failed
    assert run.summary["status"] == "ok" and math.isfinite(run.summary["psnr"])
    # a rerun with the cache: the same four rounds, no call
    _, again_impl = _bionerf(tmp_path)
    again, silent = scripted([], ResponseCache(tmp_path / "cache.sqlite"), rounds=4)
    (replayed,) = again.code(again_impl, work=tmp_path / "work2")
    assert silent.requests == [] and again.ledger.total().calls == 0 and again.ledger.total().cache_hits == 4
    assert replayed["status"] == "accepted" and again_impl.sources["components.backbone_model"] == RIGHT


def test_the_coder_is_told_the_parts_claim_sentences_and_hyperparameters():
    """The model coder receives what the paper says of the part (its claim, its sentences, its hyperparameters from
    the ledger), not only the equations the compiler read."""
    from types import SimpleNamespace

    from nerfify_ns.agents.coder import coder_messages

    record = SimpleNamespace(equations=[], status="not implemented", reason="no equation", source="")
    hole = {"claim": "We propose a small network that blends the two fields per sample.",
            "text": "The mixer is an MLP with two layers of 32 units.",
            "hyperparameters": [{"name": "hidden_dim", "value": 32, "sentence": "two layers of 32 units"}]}
    frozen = {"class": "Mixer", "constructor_arguments": [], "get_out_dim": False}
    user = coder_messages(record, hole, frozen)[1]["content"]
    assert "blends the two fields per sample" in user
    assert "two layers of 32 units" in user and '"hidden_dim"' in user
