"""Ingestion of the real papers in ../shared/papers (skipped, saying why, when the folder is absent)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from nerfify_ns.paper import clean_markdown, ingest, key_terms_report, require_nerf_paper
from nerfify_ns.paper.document import normalize_text

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
PAPERS = SHARED / "papers"


def paper(rel: str) -> Path:
    path = PAPERS / rel
    if not path.is_file():
        pytest.skip(f"real paper {path} not present (the shared papers folder is outside the project)")
    return path


@pytest.fixture(scope="module")
def nerf_md():
    return ingest(paper("nerf/nerf.md"))


@pytest.fixture(scope="module")
def bionerf():
    return ingest(paper("bionerf/bionerf.pdf"))


@pytest.fixture(scope="module")
def gh_nerf():
    return ingest(paper("gh_nerf/gh_nerf.pdf"))


def test_nerf_md_structure(nerf_md):
    assert nerf_md.title == "NeRF: Representing Scenes as Neural Radiance Fields for View Synthesis"
    assert nerf_md.abstract.startswith("We present a method that achieves state-of-the-art results")
    numbers = [s.number for s in nerf_md.sections]
    assert numbers[:8] == ["1", "2", "3", "4", "5", "5.1", "5.2", "5.3"]
    assert [e.number for e in nerf_md.equations[:6]] == ["1", "2", "3", "4", "5", "6"]
    # the duplicated unicode+LaTeX math is collapsed to LaTeX
    assert nerf_md.equations[0].latex.startswith("C(\\mathbf{r})=\\int_{t_{n}}^{t_{f}}")
    assert "(x,y,z)(x,y,z)" not in nerf_md.text() and "$\\mathbf{x}=(x,y,z)$" in nerf_md.text()
    assert len(nerf_md.result_tables) >= 5
    cited = {k for c in nerf_md.citations for k in c.keys}
    assert {"16", "26", "18"} <= cited  # no reference list in this conversion, but the citations are found


def test_nerf_md_hyperparameters_with_real_sentences(nerf_md):
    hp: dict = {}
    for h in nerf_md.hyperparameters:
        hp.setdefault(h.name, []).append(h)
    values = {name: [h.value for h in hs] for name, hs in hp.items()}
    assert 64 in values["num_coarse_samples"] and 128 in values["num_fine_samples"]
    assert values["batch_size"] == [4096] and hp["batch_size"][0].unit == "rays"
    assert values["learning_rate"] == [pytest.approx(5e-4)]
    assert values["learning_rate_final"] == [pytest.approx(5e-5)]
    assert [100000, 300000] in values["num_iterations"]
    freqs = {(h.qualifier, h.value) for h in hp["num_frequencies"]}
    assert {("position", 10), ("direction", 4)} <= freqs
    text = normalize_text(nerf_md.text())
    for h in nerf_md.hyperparameters:
        assert normalize_text(h.sentence) in text, h.sentence  # the evidence is really in the paper
        assert nerf_md.find(h.sentence) is not None
    assert hp["batch_size"][0].section == "5.3 Implementation details"


def test_nerf_md_clean(nerf_md):
    cleaned = clean_markdown(nerf_md)
    assert "In this work, we address the long-standing problem" not in cleaned  # introduction dropped
    assert "A promising recent direction in computer vision" not in cleaned  # related work dropped
    assert "We thank Kevin Cao" not in cleaned  # acknowledgements dropped
    assert cleaned.count("\\tag{") == len([e for e in nerf_md.equations if e.number])
    assert "batch size of 4096 rays" in cleaned and "Hierarchical volume sampling" in cleaned
    report = key_terms_report(nerf_md, cleaned)
    assert report["coverage"] >= 0.7 and "radiance fields" in report["kept"]


def test_bionerf_pdf(bionerf):
    assert bionerf.title == "BioNeRF: Biologically Plausible Neural Radiance Fields for View Synthesis"
    assert bionerf.page_count == 10 and bionerf.authors[0] == "Leandro A. Passos"
    assert bionerf.abstract.startswith("This paper presents BioNeRF")
    titles = [s.title for s in bionerf.sections]
    assert titles.index("Introduction") < titles.index("Related Works") < titles.index("Experiments")
    # two-column reading order: page 1 left column (introduction start) comes before its right column
    text = bionerf.text()
    assert text.index("Neural Radiance Fields (NeRF) [16] provide") < text.index("One of NeRF’s fundamental concepts")
    assert [e.number for e in bionerf.equations[:10]] == [str(i) for i in range(1, 11)]
    assert len(bionerf.references) > 20
    assert any(r.arxiv == "2207.07338" for r in bionerf.references)
    assert all(r.title and r.year for r in bionerf.references[:10])
    hp = {h.name: h.value for h in bionerf.hyperparameters}
    assert hp["learning_rate"] == pytest.approx(5e-4) and hp["num_iterations"] == 400000
    assert {t.number for t in bionerf.result_tables} >= {"1", "2", "3"}


def test_gh_nerf_pdf(gh_nerf):
    assert gh_nerf.title.startswith("GH-NeRF: Neural Radiance Fields with Gaussian")
    assert [s.number for s in gh_nerf.sections[:5]] == ["1", "2", "2.1", "2.2", "3"]
    assert len(gh_nerf.references) >= 7 and gh_nerf.references[0].title.startswith("Mip-nerf")
    assert {e.number for e in gh_nerf.equations} >= {"1", "2", "3", "7"}


def test_seathru_appendix_is_ingested():
    doc = ingest(paper("seathru_nerf/seathru_nerf_appendix.pdf"))
    assert doc.page_count == 1 and doc.title.startswith("SeaThru-NeRF")
    assert any("Derivation" in s.title for s in doc.sections)
    assert doc.references == [] and not re.search(r"\b0\d\d\b \b0\d\d\b", doc.text())  # margin line numbers gone
    assert require_nerf_paper(doc) > 0


@pytest.mark.parametrize("rel", ["nerf/nerf.md", "bionerf/bionerf.pdf", "gh_nerf/gh_nerf.pdf"])
def test_real_papers_are_nerf_papers(rel):
    assert require_nerf_paper(ingest(paper(rel))) > 20
