"""One paper, two renderings, one component: the markdown rendering the pipeline writes of a paper (the run
folder's paper.md, ``paper.clean.clean_markdown``) keeps each display equation where the paper shows it, beside the
sentences that say which part it defines; a rendering that moved every equation to the end of its section made the
equation compiler read the loss (BioNeRF's Eq. 10) as one of the backbone's equations, and the backbone compiled
from the PDF failed from the markdown. Unit: the placement on a document of our own; real paper (skips without
../shared): BioNeRF's filters and memory compile to the same code from its PDF and from its markdown."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from nerfify_ns.paper.clean import clean_markdown
from nerfify_ns.paper.document import Document, Equation, Paragraph, Section

PAPERS = Path(__file__).resolve().parents[3] / "shared" / "papers"
BIONERF = PAPERS / "bionerf" / "bionerf.pdf"


def _doc() -> Document:
    sec = "3 Method"
    paragraphs = ["Filtering. The gate is computed from the feature as follows:",
                  "where W is a weight matrix. The memory keeps what the gate lets through.",
                  "Loss. The loss compares the rendered colour with the ground truth:",
                  "where MSE is the mean squared error."]
    equations = [("g = \\sigma(W h + b)", "1", "The gate is computed from the feature as follows: ⟨Eq. 1⟩ where W is "
                  "a weight matrix."),
                 ("m = g \\odot h", "2", "and ⟨Eq. 2⟩"),
                 ("\\mathcal{L} = \\mathrm{MSE}(C, C^*)", "3", "The loss compares the rendered colour with the ground "
                  "truth: ⟨Eq. 3⟩ where MSE is the mean squared error.")]
    doc = Document(title="GateNeRF", source="test.pdf", kind="pdf")
    doc.sections = [Section(title="Method", number="3", level=1,
                            paragraphs=[Paragraph(p, section=sec) for p in paragraphs])]
    doc.equations = [Equation(latex=tex, number=n, section=sec, sentence=sentence) for tex, n, sentence in equations]
    return doc


def test_each_equation_stays_beside_the_sentences_that_introduce_it():
    doc = _doc()
    assert doc.sections[0].heading == "3 Method" and all(e.section == doc.sections[0].heading for e in doc.equations)
    text = clean_markdown(doc)
    order = [m.group(0) for m in re.finditer(r"\\tag\{\d\}|Filtering\.|where W|Loss\.|where MSE", text)]
    assert order == ["Filtering.", "\\tag{1}", "\\tag{2}", "where W", "Loss.", "\\tag{3}", "where MSE"], order


def _code(source: str) -> str:
    """The generated module without its comments (they quote where each size was read: a page in the PDF, a line
    in the markdown)."""
    return "\n".join(line.split("#", 1)[0].rstrip() for line in source.splitlines() if line.split("#", 1)[0].strip())


@pytest.mark.slow
def test_bionerfs_filters_and_memory_from_its_pdf_and_from_its_markdown(tmp_path):
    if not BIONERF.is_file():
        pytest.skip(f"real paper {BIONERF} not present (../shared/papers is outside the project and never committed)")
    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.novel import IMPLEMENTED, implement_holes
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    pdf = ingest(BIONERF)
    rendering = tmp_path / "bionerf.md"
    rendering.write_text(clean_markdown(pdf))
    built = {}
    for name, doc in (("pdf", pdf), ("md", ingest(rendering))):
        impl = implement_holes(doc, plan_from_paper(doc).plan)
        backbone = next(r for r in impl.records if r.production == "Backbone")
        assert backbone.status == IMPLEMENTED, (name, backbone.reason)
        built[name] = (backbone.component["implements"], _code(impl.sources[backbone.component["module"]]))
    assert built["pdf"][0] == built["md"][0] == [f"Eq. {k}" for k in range(1, 10)]
    assert built["pdf"][1] == built["md"][1]
