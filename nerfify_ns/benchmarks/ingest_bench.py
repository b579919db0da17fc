"""Paper-ingestion benchmark: median ``ingest()`` time of a 15-page two-column PDF (made here) or a given one.

Run: ``.venv/bin/python -m nerfify_ns.benchmarks.ingest_bench [PDF] [--runs 7] [--pages 15]``
Target: ingestion well under 2 s for 15 pages (the whole ``--dry-run`` must stay under 10 s).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from nerfify_ns.interrupts import run_interruptible

SENTENCE = ("We render each camera ray with volume rendering of a neural radiance field and optimize the MLP with a "
            "photometric loss, using a batch size of 4096 rays and a learning rate of 5e-4 [{n}]. ")


def _box(page, rect, text: str, size: float, font: str = "helv") -> None:
    if page.insert_textbox(rect, text, fontsize=size, fontname=font) < 0:
        raise RuntimeError(f"benchmark text does not fit its box: {text[:40]}")


def make_two_column_pdf(path: Path, pages: int = 15) -> Path:
    """A synthetic paper: title, per page two columns of headed paragraphs, an equation and a caption."""
    import pymupdf

    doc = pymupdf.open()
    for p in range(pages - 1):  # the last page holds the references
        page = doc.new_page(width=612, height=792)
        top = 72
        if p == 0:
            _box(page, pymupdf.Rect(50, 60, 562, 120), "BenchNeRF: A Synthetic Paper for Timing Ingestion", 16, "hebo")
            top = 130
        for col, x0 in enumerate((50, 316)):
            y = top
            _box(page, pymupdf.Rect(x0, y, x0 + 246, y + 20), f"{p + 1}.{col + 1} Section on page {p + 1}", 11, "hebo")
            y += 22
            for k in range(3):
                text = "".join(SENTENCE.format(n=(p * 7 + k + i) % 30 + 1) for i in range(3))
                _box(page, pymupdf.Rect(x0, y, x0 + 246, y + 150), text, 8.5)
                y += 150
            number = p * 2 + col + 1
            _box(page, pymupdf.Rect(x0 + 20, y, x0 + 246, y + 20), f"C(r) = sum_i T_i alpha_i c_i      ({number})", 9.5)
            _box(page, pymupdf.Rect(x0, y + 24, x0 + 246, y + 60), f"Figure {number}: Renderings of scene {col}.", 9)
    page = doc.new_page(width=612, height=792)
    _box(page, pymupdf.Rect(50, 60, 296, 80), "References", 11, "hebo")
    for half, x0 in enumerate((50, 316)):
        refs = "\n".join(f"[{i}] A. Author and B. Author. Radiance field paper {i}. In CVPR, 2021. "
                         f"arXiv:2003.{8900 + i}." for i in range(1 + 15 * half, 16 + 15 * half))
        _box(page, pymupdf.Rect(x0, 84, x0 + 246, 760), refs, 7)
    doc.save(path)
    doc.close()
    return path


def time_ingest(pdf: Path, runs: int):
    """Ingest ``pdf`` ``runs`` times in this process: (the last Document, the seconds of each run)."""
    from nerfify_ns.paper import ingest

    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        doc = ingest(pdf)
        times.append(time.perf_counter() - t0)
    return doc, times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pdf", nargs="?", type=Path, help="a PDF to time (default: a generated 15-page one)")
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--pages", type=int, default=15)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        pdf = args.pdf or make_two_column_pdf(Path(tmp) / "bench.pdf", args.pages)
        doc, times = time_ingest(pdf, args.runs)
    med = statistics.median(times)
    print(f"ingest {pdf.name}: {doc.page_count} pages, {len(doc.sections)} sections, {len(doc.equations)} equations, "
          f"{len(doc.references)} references, {len(doc.hyperparameters)} hyperparameters")
    print(f"median {med:.3f} s over {args.runs} runs (min {min(times):.3f} s, max {max(times):.3f} s); "
          f"{'OK' if med < 2.0 else 'SLOW'} against the 2 s target")


if __name__ == "__main__":
    run_interruptible(main)
