"""A technique added as a card, one terminal module and this test (RawNeRF's relative L2 loss, which SeaThru-NeRF
borrows): the registry, the grammar, the knowledge base, citation recovery and hyperparameter reading all find it
without any other file."""

from __future__ import annotations

import copy

import pytest
import torch

from nerfify_ns.grammar import load_grammar, validate
from nerfify_ns.knowledge import find_by_alias, load_cards, load_papers
from nerfify_ns.paper.hyperparams import extract_from_sentence
from nerfify_ns.registry import default_registry
from nerfify_ns.registry.snippets import build_from_code
from nerfify_ns.synthesis.resources import load_reference_plan


@pytest.fixture(scope="module", autouse=True)
def cpu_runtime():
    from nerfify_ns.runtime import activate

    activate(force=True)


def test_the_terminal_joins_its_production_with_its_card():
    term = default_registry()["relative_l2"]
    assert term.card == "relative_l2" and term.production == "RGBLoss"
    assert "relative_l2" in load_grammar().nonterminals["RGBLoss"].alternatives
    assert load_cards()["relative_l2"].params_for() == {"eps": 0.001}


def test_the_rendered_loss_is_rawnerfs_relative_error_with_its_gradient():
    term = default_registry()["relative_l2"]
    loss = build_from_code(term.code, {"eps": 0.01})
    assert isinstance(loss, torch.nn.Module)
    target = torch.tensor([[0.5, 0.1, 0.9], [0.02, 0.3, 0.0]])
    pred = torch.tensor([[0.4, 0.2, 0.8], [0.05, 0.3, 0.1]], requires_grad=True)
    value = loss(target, pred)
    expected = (((pred.detach() - target) / (pred.detach() + 0.01)) ** 2).mean()
    assert torch.allclose(value, expected)
    value.backward()
    grad = 2 * (pred.detach() - target) / (pred.detach() + 0.01) ** 2 / pred.numel()
    assert torch.allclose(pred.grad, grad)  # the weight sg(pred) + eps carries no gradient
    plain = torch.nn.MSELoss()(target, pred.detach())
    assert value > plain  # dark values weigh more than in the plain L2 loss


def test_a_plan_with_it_validates():
    plan = copy.deepcopy(load_reference_plan("nerfacto"))
    plan["model"]["losses"]["rgb"] = {"relative_l2": {"eps": 0.001}}
    assert validate(plan).used["model.losses.rgb.relative_l2"] == "relative_l2"


def test_the_knowledge_base_finds_it_in_a_paper_and_its_source_paper():
    assert [c.name for c in find_by_alias("Reconstruction (linear domain; RawNeRF-style) on raw images.")] \
        == ["relative_l2"]
    source = load_papers()["rawnerf"]
    assert source.arxiv == "2111.13679" and source.provides == ("relative_l2",)


def test_seathru_nerfs_reconstruction_loss_is_found_with_its_quote():
    """SeaThru-NeRF states its reconstruction loss as RawNeRF's: the derived plan takes the technique, quoting it."""
    from pathlib import Path

    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    paper = Path(__file__).resolve().parents[3] / "shared" / "papers" / "seathru_nerf" / "seathru_condensed.md"
    if not paper.is_file():
        pytest.skip(f"the SeaThru-NeRF paper is not at {paper} (../shared is absent)")
    plan = plan_from_paper(ingest(paper)).plan
    assert plan.get("model.losses.rgb") == {"relative_l2": {"eps": 0.001}}
    assert "RawNeRF-style" in plan.evidence_for("model.losses.rgb")


def test_its_hyperparameter_is_read_from_its_own_pattern():
    found = extract_from_sentence(r"We divide by $\mathrm{sg}(\hat{C}) + \epsilon$ with $\epsilon = 10^{-3}$.")
    assert [(h.name, h.value) for h in found if h.name == "relative_loss_eps"] == [("relative_loss_eps", 0.001)]
