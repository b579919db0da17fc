"""A part a paper states only in prose that the deterministic path cannot build, written by a scripted model: a
paper of our own (TintNeRF, below) whose one contribution is a small "tint network" appended to the field's input,
described in sentences with its sizes in words and no equation. The equation compiler has nothing to bind and no
typed terminal states it, so the hole is left to the coder, which is told the contribution, the claim, the
sentences and the reason; its first answer breaks the Backbone contract (a width that is not its get_out_dim), the
contract rung's diagnosis goes back, the second answer passes every rung (static, contract, stability, smoke) in
the sandbox and is installed as the plan's custom backbone with its sources."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

TINTNERF = Path(__file__).resolve().parents[1] / "data" / "papers" / "prose_coder.md"

TINT = '''"""TintNeRF's tint network (Sec. 3.1): two layers of 32 units, a ReLU between them and a tanh at the output,
four tint values appended to the field's input; then the field's MLP. Written for the coder test."""

import torch
from torch import nn


class BackboneModelPart(nn.Module):
    def __init__(self, in_dim: int, out_dim=None, width: int = 64, **kwargs):
        super().__init__()
        self.in_dim, self.width = in_dim, width
        self.tint = nn.Sequential(nn.Linear(in_dim, 32), nn.ReLU(), nn.Linear(32, 4), nn.Tanh())
        self.mlp = nn.Sequential(nn.Linear(in_dim + 4, width), nn.ReLU(), nn.Linear(width, width), nn.ReLU())

    def get_out_dim(self) -> int:
        return self.width

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.mlp(torch.cat([features, self.tint(features)], dim=-1))
'''
TINT_WRONG_WIDTH = TINT.replace("return self.width\n", "return self.width + 4\n")


def _answer(code: str) -> str:
    return json.dumps({"code": code, "implements": ["Sec. 3.1"],
                       "sentences": ["A small tint network reads the position of each sample and returns a tint "
                                     "feature of four values in [-1, 1] that is appended to the input of the field."]})


@pytest.fixture()
def tint_paper():
    return TINTNERF


def _tint_hole(paper):
    from nerfify_ns.pipeline import PaperOptions, run_paper
    from nerfify_ns.synthesis.novel import NOT_IMPLEMENTED

    impl = run_paper(paper, options=PaperOptions(dry_run=True)).implementation
    tint = [r for r in impl.records if "tint network" in " ".join(
        str(h.get("text", "")) for h in impl.plan["holes"] if h.get("slot") == r.slot)]
    assert len(tint) == 1, [(r.id, r.production) for r in impl.records]
    (record,) = tint
    assert record.status == NOT_IMPLEMENTED  # no equation to compile, no typed terminal states it
    impl.records = [record]  # the coder is scripted for this hole alone
    return impl, record


def test_the_coder_is_told_the_prose_parts_contribution_claim_and_sentences(tint_paper):
    from nerfify_ns.agents.coder import coder_messages, frozen_interface

    impl, record = _tint_hole(tint_paper)
    hole = next(h for h in impl.plan["holes"] if h.get("slot") == record.slot)
    user = coder_messages(record, hole, frozen_interface(record))[1]["content"]
    assert "two layers of thirty-two units" in " ".join(user.split())
    assert hole["contribution"] and hole["contribution"] in user
    assert hole["claim"] and hole["claim"] in user
    assert record.reason and record.reason in user  # why the deterministic path left it


@pytest.mark.slow
def test_a_prose_only_part_is_written_repaired_from_the_diagnosis_and_installed(tint_paper, tmp_path):
    from test_agents_coder import scripted

    impl, record = _tint_hole(tint_paper)
    agents, provider = scripted([_answer(TINT_WRONG_WIDTH), _answer(TINT)], rounds=2)
    (result,) = agents.code(impl, work=tmp_path / "work", smoke=True)
    assert result["status"] == "accepted", result
    first, second = result["rounds"]
    assert first["status"] == "fail" and first["rungs"]["contract"] == "fail"
    assert "rung contract" in first["diagnosis"] and "68" in first["diagnosis"]  # the claimed width, 64 + 4
    assert first["diagnosis"].splitlines()[0] in provider.requests[1].messages[-1]["content"]  # repaired from it
    assert second["rungs"] == {"static": "pass", "contract": "pass", "stability": "pass", "smoke": "pass"}
    entry = impl.plan.get(f"{record.slot}.custom")
    assert entry["source"] == "model" and entry["module"] == f"components.{record.id}_model"
    assert "tint network" in entry["evidence"]
    assert impl.sources[entry["module"]] == TINT and record.status == "implemented"
    assert "written by the model" in record.reason
