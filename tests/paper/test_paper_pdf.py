"""PDF ingestion on PDFs generated here: reading order, headings, equations, captions, references, errors."""

from __future__ import annotations

import pymupdf
import pytest
from paper_pdfs import text_pdf, two_column_pdf

from nerfify_ns.errors import NerfifyError
from nerfify_ns.paper import (
    CorruptPdfError,
    EmptyDocumentError,
    EncryptedPdfError,
    InputTooLargeError,
    Limits,
    NotANerfPaperError,
    ScannedPdfError,
    UnsupportedInputError,
    ingest,
    require_nerf_paper,
)


@pytest.fixture(scope="module")
def two_col(tmp_path_factory):
    path = two_column_pdf(tmp_path_factory.mktemp("pdf") / "tiny.pdf")
    return ingest(path)


def test_title_abstract_and_page_count(two_col):
    assert two_col.kind == "pdf" and two_col.page_count == 2
    assert two_col.title == "TinyNeRF: A Test Radiance Field for View Synthesis"
    assert two_col.abstract.startswith("We present TinyNeRF")
    assert two_col.authors == ["Ada Lovelace", "Alan Turing"]


def test_two_column_reading_order(two_col):
    text = two_col.text()
    # the right column starts higher on the page than the left column's paragraph, yet comes after it
    assert text.index("LEFTSTART") < text.index("LEFTEND") < text.index("RIGHTSTART") < text.index("RIGHTEND")
    assert "Appendix text in the right column" in text


def test_sections_and_paragraph_locations(two_col):
    heads = [(s.number, s.title) for s in two_col.sections]
    assert heads[:2] == [("1", "Method"), ("2", "Implementation details")]
    method = two_col.sections[0]
    assert method.loc.page == 1 and method.paragraphs[0].text.startswith("LEFTSTART")
    assert method.paragraphs[0].section == "1 Method"
    loc = two_col.find("decays exponentially to 5e-5")
    assert loc is not None and loc.page == 1
    assert two_col.section_of(loc).title == "Implementation details"
    assert two_col.find("a sentence that is not in the paper") is None


def test_equation_caption_and_hyperparameters(two_col):
    assert [e.number for e in two_col.equations] == ["1"]
    assert "T_i" in two_col.equations[0].text and two_col.equations[0].loc.page == 1
    assert [(c.kind, c.number) for c in two_col.captions] == [("figure", "1")]
    hp = {(h.name, str(h.value)) for h in two_col.hyperparameters}
    assert {("batch_size", "4096"), ("learning_rate", "0.0005"), ("learning_rate_final", "5e-05"),
            ("num_coarse_samples", "64"), ("num_fine_samples", "128"), ("num_iterations", "300000")} <= hp


def test_references_parsed(two_col):
    refs = two_col.references
    assert [r.key for r in refs] == ["1", "2", "3"]
    assert refs[0].arxiv == "2003.08934" and refs[0].year == 2020
    assert refs[0].title.startswith("NeRF: Representing scenes")
    assert refs[0].authors[0] == "B. Mildenhall"
    assert refs[1].doi == "10.1145/3528223.3530127" and refs[2].arxiv == "2111.12077"
    cited = {k for c in two_col.citations for k in c.keys}
    assert cited == {"1", "2"}


def test_to_dict_is_json(two_col):
    import json

    data = json.loads(json.dumps(two_col.to_dict()))
    assert data["kind"] == "pdf" and data["references"][0]["arxiv"] == "2003.08934"


def test_encrypted_pdf(tmp_path):
    path = two_column_pdf(tmp_path / "plain.pdf")
    doc = pymupdf.open(path)
    doc.save(tmp_path / "enc.pdf", encryption=pymupdf.PDF_ENCRYPT_AES_256, user_pw="user", owner_pw="owner")
    with pytest.raises(EncryptedPdfError, match="password"):
        ingest(tmp_path / "enc.pdf")


@pytest.mark.parametrize("data", [b"this is not a pdf at all" * 10, b"%PDF-1.7\n%garbage\n" + b"\x00\xff" * 50])
def test_corrupt_pdf(tmp_path, data):
    (tmp_path / "bad.pdf").write_bytes(data)
    with pytest.raises(CorruptPdfError):
        ingest(tmp_path / "bad.pdf")


def test_image_only_pdf_is_scanned(tmp_path):
    doc = pymupdf.open()
    page = doc.new_page()
    pix = pymupdf.Pixmap(pymupdf.csRGB, pymupdf.IRect(0, 0, 64, 64), False)
    pix.clear_with(200)
    page.insert_image(pymupdf.Rect(50, 50, 500, 500), pixmap=pix)
    doc.save(tmp_path / "scan.pdf")
    with pytest.raises(ScannedPdfError, match="OCR"):
        ingest(tmp_path / "scan.pdf")


def test_blank_and_zero_byte(tmp_path):
    doc = pymupdf.open()
    doc.new_page()
    doc.save(tmp_path / "blank.pdf")
    with pytest.raises(EmptyDocumentError):
        ingest(tmp_path / "blank.pdf")
    (tmp_path / "zero.pdf").write_bytes(b"")
    with pytest.raises(EmptyDocumentError, match="0 bytes"):
        ingest(tmp_path / "zero.pdf")


def test_limits(tmp_path):
    path = two_column_pdf(tmp_path / "p.pdf")
    with pytest.raises(InputTooLargeError, match="MB"):
        ingest(path, Limits(max_bytes=100))
    with pytest.raises(InputTooLargeError, match="2 pages"):
        ingest(path, Limits(max_pages=1))


def test_unsupported_inputs(tmp_path):
    (tmp_path / "paper.docx").write_bytes(b"x")
    with pytest.raises(UnsupportedInputError, match="unsupported"):
        ingest(tmp_path / "paper.docx")
    with pytest.raises(UnsupportedInputError, match="no such"):
        ingest(tmp_path / "missing.pdf")


def test_errors_are_one_line_nerfify_errors(tmp_path):
    (tmp_path / "zero.pdf").write_bytes(b"")
    with pytest.raises(NerfifyError) as info:
        ingest(tmp_path / "zero.pdf")
    assert "\n" not in str(info.value)


def test_non_nerf_pdf_is_rejected(tmp_path):
    path = text_pdf(tmp_path / "db.pdf", [
        "We study query optimization in relational databases. Our cost model estimates the cardinality of joins "
        "and chooses index structures for transactional workloads.",
        "Experiments on TPC-H show that the optimizer reduces latency of SQL queries by a third compared with a "
        "rule-based planner, while B-tree indexes keep write amplification low."], "Cost-Based Join Ordering")
    doc = ingest(path)
    with pytest.raises(NotANerfPaperError, match="does not look like a NeRF"):
        require_nerf_paper(doc)


def test_nerf_pdf_is_accepted(two_col):
    assert require_nerf_paper(two_col) > 0
