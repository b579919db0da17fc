"""The survey's labels in the suite format: a paper's family, and per novelty item the production it changes, the card
of a borrowed part (or where a part without a card is known from) and phrases from the paper. The repository's
labelled suites load, their phrases are really in the papers, and a malformed label is one line naming the key."""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

import pytest

from nerfify_ns.nerfifybench import SuiteError, load_suite
from nerfify_ns.nerfifybench.suite import FAMILIES, NEW_PRODUCTIONS, card_names, productions

ROOT = Path(__file__).resolve().parents[2]
SUITES = ROOT / "examples" / "bench"
FAMILY_PAPERS = ROOT / "tests" / "data" / "papers"

GOOD = """
papers:
  - id: p1
    input: paper.md
    family: dynamic
    scenes: [dynamic]
    reference: dnerf
    novelty:
      - id: codes
        kind: architecture
        weight: 1.0
        where: Sec. 3.1, Eq. 2
        production: FieldWrapper
        phrases: ["time-dependent latent codes", "per-frame code"]
      - id: pe
        kind: architecture
        weight: 0.3
        where: Sec. 3.1
        production: PosEncoding
        card: positional_encoding
        phrases: ["positional encoding", "higher dimensional space"]
      - id: gaussians
        kind: architecture
        weight: 0.3
        where: Sec. 3
        production: Primitive
        known_from: 3D Gaussian splatting
        phrases: ["anisotropic 3D Gaussians", "tile-based rasterizer"]
      - id: size
        kind: hyperparameter
        weight: 0.2
        where: Sec. 4
        production: FieldWrapper
        phrases: ["1024-dimensional latent codes", "latent code dimension"]
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "suite.yaml"
    path.write_text(text)
    return path


def test_the_new_fields_are_typed(tmp_path):
    (paper,) = load_suite(write(tmp_path, GOOD)).papers
    assert paper.family == "dynamic"
    codes, pe, gaussians, size = paper.novelty
    assert (codes.production, codes.card, codes.phrases) == ("FieldWrapper", None, ("time-dependent latent codes",
                                                                                      "per-frame code"))
    assert pe.card == "positional_encoding" and gaussians.known_from == "3D Gaussian splatting"
    # novel: no card, not known from elsewhere, a part rather than a setting
    assert [i.novel for i in paper.novelty] == [True, False, False, False]
    assert size.equations == () and codes.equations == ("2",)


def test_old_suites_need_no_labels(tmp_path):
    old = "papers:\n  - {id: p, input: p.md, scenes: [default], reference: nerfacto, novelty: [{id: a, kind: loss, " \
          "weight: 1, where: Sec. 3}]}\n"
    (paper,) = load_suite(write(tmp_path, old)).papers
    assert paper.family == "" and paper.novelty[0].production == "" and paper.novelty[0].phrases == ()


@pytest.mark.parametrize("old,new,message", [
    ("family: dynamic", "family: video", "papers[0].family: 'video' is not one of static, dynamic, splatting"),
    ("production: FieldWrapper\n        phrases: [\"time", "production: Deformer\n        phrases: [\"time",
     "papers[0].novelty[0].production: 'Deformer' is not a production (one of "),
    ("card: positional_encoding", "card: nerf_pe", "papers[0].novelty[1].card: 'nerf_pe' is not a knowledge card"),
    ("known_from: 3D Gaussian splatting", "known_from: 3D Gaussian splatting\n        card: rgb_l1",
     "papers[0].novelty[2]: give at most one of 'card'"),
    ('phrases: ["positional encoding", "higher dimensional space"]', 'phrases: ["positional encoding"]',
     "papers[0].novelty[1].phrases: expected a list of 2-4 phrases"),
    ('phrases: ["positional encoding", "higher dimensional space"]', 'phrases: [a, b, c, d, e]',
     "papers[0].novelty[1].phrases: expected a list of 2-4 phrases"),
    ('phrases: ["positional encoding", "higher dimensional space"]', f'phrases: [a, "{"x" * 200}"]',
     "papers[0].novelty[1].phrases: phrase 'xxxx"),
    ('phrases: ["positional encoding", "higher dimensional space"]', 'phrases: [a, ""]',
     "papers[0].novelty[1].phrases[1]: expected non-empty text"),
    ("        production: Primitive\n", "", "papers[0].novelty[2]: missing required key 'production' (the paper has a"),
    ('        phrases: ["anisotropic 3D Gaussians", "tile-based rasterizer"]\n', "",
     "papers[0].novelty[2]: missing required key 'phrases'"),
    ("known_from: 3D Gaussian splatting", "source: 3D-GS", "papers[0].novelty[2]: unknown key 'source'"),
])
def test_malformed_labels_are_one_line(tmp_path, old, new, message):
    assert old in GOOD
    with pytest.raises(SuiteError) as info:
        load_suite(write(tmp_path, GOOD.replace(old, new, 1)))
    text = str(info.value)
    assert message in text and "\n" not in text and text.startswith("suite.yaml: ")


def test_a_not_training_paper_needs_no_production(tmp_path):
    text = GOOD.replace("family: dynamic", "family: not-training").replace("        production: FieldWrapper\n", "")
    (paper,) = load_suite(write(tmp_path, text)).papers
    assert paper.novelty[0].production == "" and paper.novelty[0].novel


def test_productions_and_cards_are_the_projects():
    """Every grammar nonterminal the survey's items name is one (the new ones besides), and the card names are the
    knowledge base's files."""
    import yaml

    grammar = yaml.safe_load((ROOT / "nerfify_ns" / "registry" / "productions.yaml").read_text())["nonterminals"]
    assert set(productions()) == set(grammar) | set(NEW_PRODUCTIONS)
    for name in ("Field", "PosEncoding", "DirEncoding", "Backbone", "DensityHead", "RGBHead", "SpatialDistortion",
                 "TensorDecomposition", "Sampler", "Renderer", "RGBLoss", "Regularizers", "CameraOptimizer",
                 "Optimizers", "Scheduler"):
        assert name in grammar
    assert set(card_names()) == {p.stem for p in (ROOT / "nerfify_ns" / "knowledge" / "cards").glob("*.yaml")}
    assert {"hash_grid", "positional_encoding", "rgb_l2"} <= set(card_names())


# ------------------------------------------------------------------------------------------ the labelled suites
def labelled(name: str):
    return load_suite(SUITES / name) if name != "families.yaml" else load_suite(FAMILY_PAPERS / name)


@pytest.mark.parametrize("name", ["dev.yaml", "examples.yaml", "families.yaml"])
def test_every_labelled_paper_has_a_family_and_labelled_items(name):
    suite = labelled(name)
    for paper in suite.papers:
        assert paper.family in FAMILIES, paper.id
        assert paper.novelty, paper.id
        for item in paper.novelty:
            assert 2 <= len(item.phrases) <= 4, (paper.id, item.id)
            assert item.production or paper.family == "not-training", (paper.id, item.id)


def test_the_dev_corpus_labels():
    """What the papers say, as labelled: NeRF is all cards; the dynamic papers have a time part of their own; the
    Gaussian-splatting papers' own parts include primitives of their own (anchors, their Gaussians)."""
    dev = labelled("dev.yaml")
    assert {p.id for p in dev.papers} == {"nerf", "bionerf", "gh_nerf", "seathru_nerf", "nerfplayer", "hexplane",
                                          "dynerf", "deformable_3dgs", "scaffold_gs", "4dgs"}
    family = {p.id: p.family for p in dev.papers}
    assert {k for k, v in family.items() if v == "dynamic"} == {"nerfplayer", "hexplane", "dynerf"}
    assert {k for k, v in family.items() if v == "splatting"} == {"deformable_3dgs", "scaffold_gs", "4dgs"}
    novel = {p.id: {i.id for i in p.novelty if i.novel} for p in dev.papers}
    assert novel["nerf"] == set()
    assert all(novel[p] for p in family if p != "nerf")
    assert all(any(i.production == "Primitive" for i in dev.paper(p).novelty) for p in family
               if family[p] == "splatting")
    time_parts = {"FieldWrapper", "PosEncoding", "PixelSampler", "ScheduleHook"}
    assert all(any(i.novel and i.production in time_parts for i in dev.paper(p).novelty) for p in family
               if family[p] == "dynamic")
    # the items with checks keep them
    assert all(i.check for p in dev.papers for i in p.novelty if i.kind == "equation" and p.id in
               ("nerf", "bionerf", "gh_nerf", "seathru_nerf"))


def test_the_example_and_family_labels():
    examples = labelled("examples.yaml")
    novel = {p.id: [i.id for i in p.novelty if i.novel] for p in examples.papers}
    assert novel == {"gridlite": ["luminance-prior"], "fourierfield": [], "glintfield": ["glint-term"]}
    gridlite = examples.paper("gridlite")
    assert next(i for i in gridlite.novelty if i.novel).equations == ("2",)
    assert next(i for i in gridlite.novelty if i.id == "sh-directions").card == "spherical_harmonics"
    families = labelled("families.yaml")
    assert {p.id: p.family for p in families.papers} == {
        "family_static": "static", "family_dynamic": "dynamic", "family_splatting": "splatting",
        "family_not_training": "not-training"}
    assert {p.id: [(i.id, i.production) for i in p.novelty if i.novel] for p in families.papers} == {
        "family_static": [("tone-response", "Renderer")],
        "family_dynamic": [("deformation-network", "FieldWrapper")],
        "family_splatting": [("anisotropy-regulariser", "Regularizers")],
        "family_not_training": [("density-matching", ""), ("coarse-alignment", "")]}


# ------------------------------------------------------------------------------------------ phrases are the papers'
def _normal(text: str) -> str:
    """Lower case, ligatures and compatibility forms folded, line-break hyphens joined, only letters and digits."""
    text = unicodedata.normalize("NFKC", text).lower()
    text = re.sub(r"-\s*\n\s*", "", text)
    return "".join(ch for ch in text if ch.isalnum())


def _paper_text(path: Path) -> str:
    if path.suffix == ".pdf":
        from nerfify_ns.paper.pdf import open_pdf

        with open_pdf(path) as doc:
            return "\n".join(page.get_text() for page in doc)
    return path.read_text(encoding="utf-8", errors="replace")


def _entries():
    for name in ("dev.yaml", "examples.yaml", "families.yaml"):
        for paper in labelled(name).papers:
            yield pytest.param(paper, id=f"{name}:{paper.id}")


@pytest.mark.parametrize("paper", list(_entries()))
def test_phrases_are_copied_from_the_paper(paper):
    """A label's phrases are the paper's own words (so they were written from reading it)."""
    if not paper.input.is_file():
        pytest.skip(f"paper {paper.input} not present (the shared papers folder is outside the project)")
    text = _normal(_paper_text(paper.input))
    assert all(len(_normal(p)) >= 4 for i in paper.novelty for p in i.phrases), \
        "a phrase without words matches anything"
    assert _normal("a phrase no paper of ours contains") not in text
    missing = [(i.id, p) for i in paper.novelty for p in i.phrases if _normal(p) not in text]
    assert not missing, missing


def test_the_family_papers_say_they_were_written_for_the_tests():
    for path in sorted(FAMILY_PAPERS.glob("family_*.md")):
        first = path.read_text().splitlines()[0]
        assert first.startswith("<!--") and "nerfify-ns tests" in first, path.name
        lines = len(path.read_text().splitlines())
        assert 60 <= lines <= 120, (path.name, lines)
