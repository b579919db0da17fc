"""The knowledge base as one object: loaded from a folder, passed to the stages, no module-level caches."""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

import pytest
from synthetic_papers import write_paper

from nerfify_ns.errors import NerfifyError
from nerfify_ns.knowledge import CARDS_DIR, KnowledgeBase, UnknownCardError, load_cards
from nerfify_ns.knowledge.citations import build_citation_graph, find_citation_uses
from nerfify_ns.knowledge.detect import detect_techniques, used_cards
from nerfify_ns.knowledge.errors import KnowledgeError

PACKAGE = Path(__file__).resolve().parents[2] / "nerfify_ns"
KEEP = ("rgb_l2", "positional_encoding", "hierarchical_sampling", "mlp_backbone", "density_activation",
        "background_model")


def reduced_kb(tmp_path: Path, keep=KEEP) -> KnowledgeBase:
    """A knowledge-base folder holding only ``keep`` cards (everything else from the package)."""
    cards = tmp_path / "kb" / "cards"
    cards.mkdir(parents=True)
    for name in keep:
        shutil.copy(CARDS_DIR / f"{name}.yaml", cards / f"{name}.yaml")
    return KnowledgeBase.load(tmp_path / "kb")


def test_default_is_one_object_with_every_part():
    kb = KnowledgeBase.default()
    assert KnowledgeBase.default() is kb and KnowledgeBase.of(None) is kb
    assert {"hash_grid", "proposal_networks", "kplanes"} <= set(kb.cards)
    assert {"nerf", "mipnerf360", "instant-ngp"} <= set(kb.papers)
    assert kb.rules.used_threshold > 0 and kb.patterns.patterns and kb.bases.statements
    assert kb.card_aliases is kb.card_aliases  # derived tables cached on the object
    fresh = KnowledgeBase.load()
    assert fresh is not kb and set(fresh.cards) == set(kb.cards) and fresh.cards["hash_grid"] == kb.cards["hash_grid"]
    assert load_cards() == kb.cards and load_cards() is not kb.cards  # the convenience default hands out copies


def test_a_folder_with_a_reduced_card_set_is_a_consistent_knowledge_base(tmp_path):
    kb = reduced_kb(tmp_path)
    assert set(kb.cards) == set(KEEP)
    assert kb.sources["cards"] == tmp_path / "kb" / "cards" and kb.sources["papers"].name == "papers.yaml"
    # references to cards the base lacks are dropped: a known paper provides only cards it has
    assert kb.papers["mipnerf360"].provides == ()
    assert "hash_grid" not in {c for names in kb.rules.hyperparameter_cards.values() for c in names}
    with pytest.raises(UnknownCardError, match="rgb_l2"):
        kb.card("hash_grid")
    assert [c.name for c in kb.find_by_alias("a multiresolution hash encoding and positional encoding")] == [
        "positional_encoding"]


def test_the_stages_read_the_knowledge_base_they_are_given(tmp_path):
    doc = write_paper(tmp_path, {"3 Method": (
        "We use the proposal network of [3] and a multiresolution hash encoding following Instant-NGP [4]. "
        "Positions are also encoded with positional encoding.")})
    full, reduced = KnowledgeBase.default(), reduced_kb(tmp_path)
    assert {"proposal_networks", "hash_grid"} <= set(used_cards(detect_techniques(doc, full)))
    found = detect_techniques(doc, reduced)
    assert {d.card for d in found} <= set(KEEP) and "positional_encoding" in used_cards(found)
    assert [u.components for u in find_citation_uses(doc, full)][0] == ["proposal_networks"]
    assert all(not u.components for u in find_citation_uses(doc, reduced))
    graph = build_citation_graph(doc, found, kb=reduced)
    assert graph.kb is reduced and {c.card for c in graph.resolution.taken} <= set(KEEP)


def test_bad_folders_raise_typed_errors(tmp_path):
    with pytest.raises(KnowledgeError, match="no knowledge-base folder"):
        KnowledgeBase.load(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(KnowledgeError, match="none of the knowledge-base files"):
        KnowledgeBase.load(tmp_path / "empty")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "bases.yaml").write_text("models: [not, a, mapping]\n")
    with pytest.raises(KnowledgeError, match="bases.yaml"):
        KnowledgeBase.load(tmp_path / "bad")
    assert issubclass(KnowledgeError, NerfifyError)


def _cached_functions(path: Path) -> list[str]:
    """Functions of ``path`` decorated with functools' lru_cache or cache."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            for dec in node.decorator_list:
                target = dec.func if isinstance(dec, ast.Call) else dec
                name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
                if name in ("lru_cache", "cache"):
                    found.append(f"{path.name}:{node.name}")
    return found


def test_no_module_level_caches_of_knowledge():
    files = sorted((PACKAGE / "knowledge").glob("*.py")) + [PACKAGE / "synthesis" / "plan_from_paper.py",
                                                             PACKAGE / "synthesis" / "base_choice.py"]
    assert [f for path in files for f in _cached_functions(path)] == []
