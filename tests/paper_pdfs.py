"""Small PDFs made with pymupdf for the paper-ingestion tests (no real paper copied)."""

from __future__ import annotations

from pathlib import Path

import pymupdf

W, H = 612, 792
LEFT = pymupdf.Rect(50, 150, 296, 700)
RIGHT = pymupdf.Rect(316, 150, 562, 700)

LEFT_TEXT = ("LEFTSTART Neural radiance fields represent a scene as a continuous volumetric function queried along "
             "camera rays. We render each ray with volume rendering and optimize the network with a photometric "
             "loss. This paragraph is the first one of the left column and ends here LEFTEND.")
RIGHT_TEXT = ("RIGHTSTART In our experiments we use a batch size of 4096 rays and a learning rate of 5e-4 that "
              "decays exponentially to 5e-5. We use 64 coarse samples and 128 fine samples per ray and train for "
              "300k iterations on one GPU, as in [1] and [2]. RIGHTEND")
REFS = ["[1] B. Mildenhall, P. P. Srinivasan, and M. Tancik. NeRF: Representing scenes as neural radiance fields "
        "for view synthesis. In ECCV, 2020. arXiv:2003.08934.",
        "[2] T. Muller, A. Evans, C. Schied, and A. Keller. Instant neural graphics primitives with a multiresolution "
        "hash encoding. ACM Transactions on Graphics, 2022. doi:10.1145/3528223.3530127.",
        "[3] J. T. Barron, B. Mildenhall, and D. Verbin. Mip-NeRF 360: Unbounded anti-aliased neural radiance "
        "fields. In CVPR, 2022. arXiv:2111.12077."]


def _box(page, rect, text, size=9.5, bold=False):
    rect = pymupdf.Rect(rect.x0, rect.y0, rect.x1, rect.y0 + 300)  # only the text's own extent is extracted
    rc = page.insert_textbox(rect, text, fontsize=size, fontname="hebo" if bold else "helv")
    assert rc >= 0, f"text did not fit: {text[:40]}"


def two_column_pdf(path: Path, title: str = "TinyNeRF: A Test Radiance Field for View Synthesis") -> Path:
    """Page 1: title, abstract (full width), two columns (right column top-aligned with the left)."""
    doc = pymupdf.open()
    p = doc.new_page(width=W, height=H)
    _box(p, pymupdf.Rect(50, 60, 562, 100), title, size=16, bold=True)
    _box(p, pymupdf.Rect(50, 105, 562, 120), "Ada Lovelace, Alan Turing", size=10)
    _box(p, pymupdf.Rect(50, 122, 296, 136), "Abstract", size=11, bold=True)
    _box(p, pymupdf.Rect(50, 150, 296, 210), "We present TinyNeRF, a neural radiance field for novel view synthesis "
         "with a hash encoding and volume rendering of camera rays.")
    _box(p, pymupdf.Rect(50, 220, 296, 236), "1 Method", size=11, bold=True)
    _box(p, pymupdf.Rect(50, 240, 296, 330), LEFT_TEXT)
    _box(p, pymupdf.Rect(60, 340, 296, 356), "C(r) = sum_i T_i (1 - exp(-sigma_i delta_i)) c_i        (1)")
    _box(p, pymupdf.Rect(50, 365, 296, 420), "where T_i is the transmittance along the ray and delta_i the "
         "distance between adjacent samples.")
    _box(p, pymupdf.Rect(316, 150, 562, 166), "2 Implementation details", size=11, bold=True)
    _box(p, pymupdf.Rect(316, 170, 562, 260), RIGHT_TEXT)
    _box(p, pymupdf.Rect(316, 270, 562, 300), "Figure 1: Overview of the TinyNeRF pipeline.")
    p2 = doc.new_page(width=W, height=H)
    _box(p2, pymupdf.Rect(50, 60, 296, 76), "References", size=11, bold=True)
    y = 80
    for ref in REFS:
        _box(p2, pymupdf.Rect(50, y, 296, y + 60), ref, size=8)
        y += 62
    _box(p2, pymupdf.Rect(316, 60, 562, 76), "A Additional details", size=11, bold=True)
    _box(p2, pymupdf.Rect(316, 80, 562, 200), "Appendix text in the right column of page two. It repeats the "
         "radiance field and the rendering of rays to fill the column with enough text for the layout.")
    doc.save(path)
    doc.close()
    return path


def text_pdf(path: Path, paragraphs: list[str], title: str) -> Path:
    """A one-column PDF with a title and paragraphs."""
    doc = pymupdf.open()
    p = doc.new_page(width=W, height=H)
    _box(p, pymupdf.Rect(50, 60, 562, 100), title, size=16, bold=True)
    y = 110
    for para in paragraphs:
        _box(p, pymupdf.Rect(50, y, 562, y + 80), para, size=10)
        y += 85
    doc.save(path)
    doc.close()
    return path
