"""Markdown and plain-text ingestion, cleaned markdown, key-term report and topic check on small documents."""

from __future__ import annotations

import pytest

from nerfify_ns.paper import NotANerfPaperError, clean_markdown, ingest, key_terms_report, require_nerf_paper

MD = """# TinyNeRF: Radiance Fields for Tests

We present TinyNeRF, a neural radiance field that uses a hash encoding and volume rendering for novel view synthesis. It is small, fast and renders camera rays through a density field with a tiny MLP, and we evaluate it on synthetic scenes.

## 1 Introduction

Neural radiance fields [1] changed view synthesis. This narrative paragraph motivates the work.

## 2 Related Work

Many works [2, 3] study radiance fields.

## 3 Method

The volume rendering equation is

$$
C(\\mathbf{r}) = \\sum_i T_i \\alpha_i \\mathbf{c}_i
$$
(1)

\\[ T_i = \\exp(-\\sum_{j<i} \\sigma_j \\delta_j) \\tag{2} \\]

Figure 1: Overview of the TinyNeRF pipeline.

### 3.1 Implementation details

We use a batch size of 4096 rays, a hash encoding with 16 levels and a hash table size of $T=2^{19}$, and train for 30k iterations with a learning rate of 1e-2 [2].

```
Algorithm 1: Training
1: sample rays
2: render and step
```

| Method | PSNR | SSIM |
|---|---|---|
| NeRF | 31.0 | 0.95 |
| Ours | 32.1 | 0.96 |

## Acknowledgements

We thank the funding agency.

## References

[1] B. Mildenhall, P. P. Srinivasan, M. Tancik. NeRF: Representing scenes as neural radiance fields for view synthesis. In ECCV, 2020. arXiv:2003.08934.
[2] T. Muller, A. Evans, C. Schied, A. Keller. Instant neural graphics primitives. ACM TOG, 2022.
[3] J. T. Barron, B. Mildenhall. Mip-NeRF 360: Unbounded anti-aliased neural radiance fields. In CVPR, 2022.
"""  # noqa: E501

TXT = """TinyNeRF: Radiance Fields for Tests

Abstract
We present TinyNeRF, a neural radiance field for novel view synthesis with volume rendering.

1 Introduction
Radiance fields [1] render camera rays.

2 Method
The color of a ray is a weighted sum of sample colors:
C(r) = sum_i w_i c_i    (1)
where the weights come from the density. We use 64 coarse samples and 128 fine samples.

References
[1] B. Mildenhall, P. P. Srinivasan, M. Tancik. NeRF: Representing scenes as neural radiance fields. In ECCV, 2020.
[2] T. Muller, A. Evans. Instant neural graphics primitives. ACM TOG, 2022. doi:10.1145/3528223.3530127
"""


@pytest.fixture(scope="module")
def md_doc(tmp_path_factory):
    path = tmp_path_factory.mktemp("md") / "tiny.md"
    path.write_text(MD)
    return ingest(path)


def test_markdown_structure(md_doc):
    assert md_doc.kind == "markdown" and md_doc.title == "TinyNeRF: Radiance Fields for Tests"
    assert md_doc.abstract.startswith("We present TinyNeRF")
    assert [(s.number, s.title, s.level) for s in md_doc.sections] == [
        ("1", "Introduction", 1), ("2", "Related Work", 1), ("3", "Method", 1), ("3.1", "Implementation details", 2),
        ("", "Acknowledgements", 1)]
    assert md_doc.sections[2].loc.line == 13
    assert md_doc.sections[2].paragraphs[0].loc.line == 15


def test_markdown_math_captions_tables_algorithms(md_doc):
    assert [(e.number, e.latex) for e in md_doc.equations] == [
        ("1", "C(\\mathbf{r}) = \\sum_i T_i \\alpha_i \\mathbf{c}_i"),
        ("2", "T_i = \\exp(-\\sum_{j<i} \\sigma_j \\delta_j)")]
    assert md_doc.equations[0].section == "3 Method"
    assert [(c.kind, c.number) for c in md_doc.captions] == [("figure", "1")]
    assert md_doc.result_tables[0].rows == [["Method", "PSNR", "SSIM"], ["NeRF", "31.0", "0.95"],
                                            ["Ours", "32.1", "0.96"]]
    assert md_doc.algorithms[0].number == "1" and md_doc.algorithms[0].lines[1] == "1: sample rays"


def test_markdown_references_and_hyperparameters(md_doc):
    assert [r.key for r in md_doc.references] == ["1", "2", "3"]
    assert md_doc.references[0].arxiv == "2003.08934" and md_doc.references[2].year == 2022
    hp = {h.name: h.value for h in md_doc.hyperparameters}
    assert hp["batch_size"] == 4096 and hp["num_levels"] == 16 and hp["log2_hashmap_size"] == 19
    assert hp["num_iterations"] == 30000 and hp["learning_rate"] == pytest.approx(1e-2)


def test_clean_markdown_drops_narrative_keeps_content(md_doc):
    cleaned = clean_markdown(md_doc)
    assert "narrative paragraph motivates" not in cleaned and "Many works" not in cleaned
    assert "funding agency" not in cleaned
    for kept in ("\\sum_i T_i \\alpha_i", "\\tag{1}", "\\tag{2}", "Figure 1: Overview", "1: sample rays",
                 "batch size of 4096 rays", "[1]", "[2]", "[3]", "arXiv:2003.08934", "Implementation details"):
        assert kept in cleaned, kept
    assert "_Cites: [1]_" in cleaned  # the citations of the dropped introduction survive


def test_key_terms_report(md_doc):
    report = key_terms_report(md_doc, clean_markdown(md_doc))
    assert "TinyNeRF" in report["terms"] and "hash encoding" in report["terms"]
    assert "TinyNeRF" in report["kept"] and report["coverage"] > 0.5
    # the abstract itself does not count: a cleaned text with only the abstract loses the terms
    bare = f"# T\n\n## Abstract\n\n{md_doc.abstract}\n"
    assert key_terms_report(md_doc, bare)["kept"] == []


def test_plain_text(tmp_path):
    path = tmp_path / "tiny.txt"
    path.write_text(TXT)
    doc = ingest(path)
    assert doc.kind == "text" and doc.title == "TinyNeRF: Radiance Fields for Tests"
    assert doc.abstract.startswith("We present TinyNeRF")
    assert [(s.number, s.title) for s in doc.sections] == [("1", "Introduction"), ("2", "Method")]
    assert [(e.number, e.text, e.loc.line) for e in doc.equations] == [("1", "C(r) = sum_i w_i c_i", 11)]
    assert len(doc.references) == 2 and doc.references[1].doi == "10.1145/3528223.3530127"
    hp = {h.name: h.value for h in doc.hyperparameters}
    assert hp == {"num_coarse_samples": 64, "num_fine_samples": 128}
    assert doc.find("where the weights come from the density").line == 12


def test_topic(md_doc, tmp_path):
    assert require_nerf_paper(md_doc) > 6
    path = tmp_path / "db.md"
    path.write_text("# Adaptive Indexing for Column Stores\n\nWe study B-tree and LSM indexes for analytical "
                    "SQL workloads and show that adaptive indexing cuts query latency on TPC-H.\n\n## 1 Method\n\n"
                    "Our cost model estimates join cardinalities.\n")
    with pytest.raises(NotANerfPaperError, match="Adaptive Indexing"):
        require_nerf_paper(ingest(path))


def test_a_converters_arxiv_stamp_and_equation_headings_are_neither_title_nor_sections(tmp_path):
    """A markdown conversion that set the arXiv stamp as the first heading, the title one level down, and two
    display equations as headings (one with its "=" lost)."""
    text = "\n\n".join(["# arXiv:2401.01234v1 [cs.CV] 3 Jan 2024", "## PyramidField: Scale-Aware Radiance Fields",
                        "Ann Author, Lab", "### Abstract", "We render each pixel at its own scale. " * 3,
                        "### 1 Introduction", "Aliasing is a problem for grid-based radiance fields. " * 3,
                        "### 3 Method", "Each level is a separate head:",
                        "#### σ,c = f_l(x,d), [Gauss] (3)", "and the levels are blended:",
                        "#### f_i(x,d). [Laplacian] (4)", "We train for 20k iterations with these heads. " * 3])
    path = tmp_path / "paper.md"
    path.write_text(text)
    doc = ingest(path)
    assert doc.title == "PyramidField: Scale-Aware Radiance Fields"
    assert [s.title for s in doc.sections] == ["Introduction", "Method"]
    assert [e.number for e in doc.equations] == ["3", "4"]


def test_a_converters_anchors_links_and_inline_tags_are_not_the_papers_text(tmp_path):
    """A PDF-to-markdown converter's empty anchors before headings, in-document links around citations and
    equation references, and inline tags: the headings, citations and words are the paper's own."""
    text = "\n\n".join([
        "# LightSplit: Split-Sum Radiance Fields", "Ann Author, Lab", "## Abstract",
        "We estimate lighting with a small network. " * 3,
        '## <span id="page-1-0"></span>1 Introduction',
        "Inverse rendering is hard [\\[11\\]](#page-9-7). We follow NeRF [\\[20,](#page-9-1) [21\\]](#page-9-2). " * 2,
        '## <span id="page-3-1"></span>3 Method',
        "The term in Equation [\\(4\\)](#page-4-0) depends on ω<sup>i</sup> and the <b>albedo</b>. " * 3])
    path = tmp_path / "paper.md"
    path.write_text(text)
    doc = ingest(path)
    assert [(s.number, s.title) for s in doc.sections] == [("1", "Introduction"), ("3", "Method")]
    intro = " ".join(p.text for p in doc.sections[0].paragraphs)
    assert "hard [11]." in intro and "NeRF [20, 21]." in intro and "#page" not in intro
    method = " ".join(p.text for p in doc.sections[1].paragraphs)
    assert "Equation (4) depends on ω^i and the albedo." in method and "<" not in method
