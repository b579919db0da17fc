"""A paper's own statement of the Nerfstudio model it builds on (patterns in bases.yaml)."""

from __future__ import annotations

import pytest
from synthetic_papers import write_paper

from nerfify_ns.knowledge import KnowledgeBase
from nerfify_ns.knowledge.bases import find_base_statements


def statements(tmp_path, text: str, heading: str = "3 Method"):
    return find_base_statements(write_paper(tmp_path, {heading: text}))


@pytest.mark.parametrize("sentence, bases", [
    ("We build on Nerfstudio's nerfacto and replace its colour head.", ["nerfacto"]),
    ("Our implementation is based on Instant-NGP.", ["instant-ngp"]),
    ("Our method is built on top of TensoRF.", ["tensorf"]),
    ("We build on [3] and change only the field.", ["nerfacto"]),          # [3] is Mip-NeRF 360: nerfacto's model
    ("Our implementation builds upon the official implementation of Mip-NeRF [2].", ["mipnerf"]),
    ("We adopt K-Planes as our backbone.", ["kplanes-static"]),
    ("Backbones: **InstantNGP** [4] and **TensoRF**.", ["instant-ngp", "tensorf"]),
    ("Base code: Mip-NeRF-360 (forward-facing, NDC).", ["nerfacto"]),
    ("Unlike nerfacto, we build on TensoRF.", ["tensorf"]),                 # the contrast clause names nothing
    ("Our FooNeRF builds on TensoRF for fast training.", ["tensorf"]),      # the method by its name
])
def test_statements_name_their_base(tmp_path, sentence, bases):
    found = statements(tmp_path, sentence)
    assert found and found[0].bases == bases
    assert found[0].quote == sentence and found[0].section.startswith("3")


@pytest.mark.parametrize("sentence, heading", [
    ("We build on NeRF [1].", "3 Method"),                                  # the idea, not an implementation
    ("We use the hash encoding of Instant-NGP.", "3 Method"),               # a component, not a base
    ("We build on Instant-NGP's hash encoding.", "3 Method"),
    ("Chen et al. [5] built on top of TensoRF.", "2 Related Work"),
    ("Our implementation is based on PyTorch.", "3 Method"),
    ("We compare against nerfacto, which we outperform.", "5 Experiments"),
])
def test_other_sentences_are_not_statements(tmp_path, sentence, heading):
    assert statements(tmp_path, sentence, heading) == []


def test_method_statements_come_first(tmp_path):
    doc = write_paper(tmp_path, {"3 Method": "Our implementation is based on TensoRF.",
                                 "4 Experiments": "We use Instant-NGP as our backbone for the ablation."},
                      abstract="We present FooNeRF; our method is built on top of nerfacto.")
    assert [s.bases for s in find_base_statements(doc)] == [["tensorf"], ["nerfacto"], ["instant-ngp"]]


def test_patterns_are_data(tmp_path):
    """A knowledge base without statement patterns finds none (the patterns live in bases.yaml)."""
    kb = tmp_path / "kb"
    kb.mkdir()
    text = (KnowledgeBase.default().sources["bases"]).read_text(encoding="utf-8")
    head, _, rest = text.partition("statements:")
    (kb / "bases.yaml").write_text(head + "statements: []\n" + rest[rest.index("\nchoice:"):], encoding="utf-8")
    doc = write_paper(tmp_path, {"3 Method": "Our implementation is based on Instant-NGP."})
    assert find_base_statements(doc) and find_base_statements(doc, KnowledgeBase.load(kb)) == []


def test_the_method_named_building_on_a_base_in_related_work_is_a_statement(tmp_path):
    """ "Our FooNeRF builds on TensoRF" closing the related work is the paper's own statement; another paper's
    building on it there is not."""
    found = statements(tmp_path, "ZeroRF [5] adapts TensoRF. Our FooNeRF builds on TensoRF for fast training.",
                       heading="2 Related Work")
    assert [f.bases for f in found] == [["tensorf"]] and found[0].quote.startswith("Our FooNeRF")
