"""Known or new by meaning: a paper's equation matches a card's by structure in the compiler's IR (renamed
symbols, other operand order, constant factors), never because a card's name is nearby; the ledger of claims."""

from pathlib import Path

import pytest

from nerfify_ns.knowledge.kb import KnowledgeBase
from nerfify_ns.paper import ingest
from nerfify_ns.synthesis.known import CardEquations, canonical, operators
from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

KB = KnowledgeBase.default()
INDEX = CardEquations.of(KB)


def test_a_cards_equation_with_other_symbols_and_order_matches():
    # hierarchical sampling's weights, w_i = T_i (1 - exp(-sigma_i delta_i)), written with other names and order
    match = INDEX.match(r"\omega_k = \left(1 - \exp\left(-\delta_k \rho_k\right)\right) A_k")
    assert match is not None and match.card == "hierarchical_sampling", match


def test_a_constant_factor_does_not_make_an_equation_new():
    match = INDEX.match(r"\mathcal{E} = \frac{1}{2} \operatorname{MSE}(\hat{I}, I)")
    assert match is not None and match.card == "rgb_l2", match


def test_a_new_equation_is_not_known_even_beside_a_cards_name():
    # the luminance prior multiplies the pixel colour by exp(beta * mean luminance): no card has it
    assert INDEX.match(r"\hat{C}(\mathbf{r}) = \exp(\beta \, \bar{\ell}(\mathbf{r})) \, C(\mathbf{r})") is None


def test_renaming_is_consistent_not_anonymous():
    # x * x is not x * y: the renaming keeps which symbols are the same
    from nerfify_ns.equations import parse_equation

    same = canonical(parse_equation(r"a = b c").rhs)
    other = canonical(parse_equation(r"a = b b").rhs)
    assert same != other
    assert canonical(parse_equation(r"a = u v").rhs) == same


def test_unreadable_equations_compare_by_their_operators_only_when_long_enough():
    assert operators(r"\sum_i \exp(-x) + \sin(y)") == ("sum", "exp", "-", "+", "sin")
    assert INDEX.match("", text="a + b") is None


OWN_PAPER = """# LearnPE: A Learnable Positional Encoding for Radiance Fields

## Abstract

We present LearnPE, a radiance field for object scenes. We propose a novel learnable positional encoding whose
frequencies are trained with the field.

## 1 Introduction

Neural radiance fields [1] encode positions with a fixed positional encoding. Unlike [1], we learn the frequencies.

## 3 Method

### 3.1 Learnable positional encoding

We propose a novel learnable positional encoding: every frequency is a parameter.

$$\\gamma(\\mathbf{x}) = \\sin(\\mathbf{B} \\mathbf{x} + \\mathbf{b}) \\tag{1}$$

where $\\mathbf{B}$ and $\\mathbf{b}$ are learned with the field.

### 3.2 Rendering

We use volume rendering as in NeRF [1]. We train with a learning rate of 5e-4 for 200k iterations.

## References

[1] B. Mildenhall, P. P. Srinivasan, M. Tancik, J. T. Barron, R. Ramamoorthi, R. Ng. NeRF: Representing Scenes as
Neural Radiance Fields for View Synthesis. In ECCV, 2020. arXiv:2003.08934.
"""


def test_a_sentence_describing_a_new_part_is_never_a_cards_evidence(tmp_path: Path):
    paper = tmp_path / "learnpe.md"
    paper.write_text(OWN_PAPER)
    derived = plan_from_paper(ingest(paper), KB)
    claims = derived.ledger.claim_sentences()
    new = [p for p in derived.ledger.parts if p.status == "new"]
    assert [p.heading for p in new] == ["Learnable positional encoding"], derived.ledger.to_dict()["parts"]
    assert new[0].production == "PosEncoding"
    quotes = [e.get("quote", "") for e in derived.evidence.values()]
    assert not any(q and any(q in c or c in q for c in claims) for q in quotes), quotes
    assert [h["production"] for h in derived.holes] == ["PosEncoding"]
    assert derived.holes[0]["claim"].startswith("We propose a novel learnable positional encoding")


SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "papers"
needs_shared = pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/papers is absent (CI always has it)")


@needs_shared
def test_the_nerf_paper_gives_no_hole():
    derived = plan_from_paper(ingest(SHARED / "nerf" / "nerf.md"), KB)
    assert derived.holes == [], [h["contribution"] for h in derived.holes]
    known = {c for p in derived.ledger.parts if p.status == "known" for c in p.covered_by}
    assert {"positional_encoding", "hierarchical_sampling", "background_model"} <= known


def test_gridlite_gives_the_luminance_prior_as_its_only_hole():
    paper = Path(__file__).resolve().parents[2] / "examples" / "gridlite_paper.md"
    derived = plan_from_paper(ingest(paper), KB)
    assert [(h["production"], h["contribution"].split(": ", 1)[1]) for h in derived.holes] == \
        [("Renderer", "Luminance prior")]
    assert derived.holes[0]["equations"][0]["number"] == "2"


def test_a_weight_a_mean_and_a_scale_do_not_make_an_equation_new():
    # the Cauchy sparsity penalty written with the scale folded into a constant and a plain weight (no 1/N)
    match = INDEX.match(r"\mathcal{L}_{c} = \gamma \sum_{j,n} \log\left(1 + 3 \tau(\mathbf{x}_j(s_n))^2\right)")
    assert match is not None and match.card == "density_sparsity", match


def test_a_functions_name_read_as_a_product_is_not_dropped_as_a_scale():
    # BCE(a, b) is parsed as B * C * E(a, b): its letters are kept, so a sum of it is not spherical harmonics'
    # sum of coefficients times basis functions
    assert INDEX.match(r"\mathcal{L}_{m} = \sum_{i,j} BCE(M_{p}(i, j), M_{g}(i, j))") is None


def test_a_known_papers_garbled_part_is_its_own_card_and_its_techniques_choose_the_base(tmp_path: Path):
    # Mip-NeRF 360's text as a PDF extraction loses the contraction's name and its equation's symbols: the part
    # lands at SpatialDistortion, where the paper's own card (scene_contraction) does, so it is that card, not a
    # hole; and the paper's own cards count for the base although the text names few of them
    paper = tmp_path / "paper.md"
    paper.write_text("""# Mip-NeRF 360: Unbounded Anti-Aliased Neural Radiance Fields

## Abstract

We present an extension of mip-NeRF for unbounded scenes that uses a non-linear scene parameterization, online
distillation, and a novel regularizer.

## 1 Introduction

Unbounded scenes are hard for neural radiance fields.

## 2 Scene and Ray Parameterization

We propose a parameterization of unbounded scenes: every point outside the unit ball is contracted into a ball of
radius two, with the mean and covariance of every Gaussian contracted by the same function, so that distant content
takes less of the bounded domain.

## 3 Experiments

We evaluate on nine scenes.
""")
    derived = plan_from_paper(ingest(paper), KB)
    assert not [h for h in derived.holes if h.get("production") == "SpatialDistortion"], derived.holes
    part = next(p for p in derived.ledger.parts if p.heading == "Scene and Ray Parameterization")
    assert part.status == "known" and part.covered_by == ["scene_contraction"], (part.status, part.why)
    assert derived.base == "nerfacto", derived.base_reason
