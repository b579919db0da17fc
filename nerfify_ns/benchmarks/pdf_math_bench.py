"""PDF equation reading benchmark: the time ``pdf_math.find_equations`` takes per paper, with what it found.

Run: ``.venv/bin/python -m nerfify_ns.benchmarks.pdf_math_bench [PDF ...] [--runs 3] [--pages 15] [--per-page 2]``
With no PDF it reads a synthetic 15-page two-column paper made here (TeX math fonts, numbered equations with
scripts, limits and fraction bars) and the PDFs of ``../shared/papers`` when that folder exists.
Target: well under 1 s for 15 pages with 20+ numbered equations (the equation compiler's whole budget is 5 s).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

TTF_FONTS = {"cmmi": "cmmi10.ttf", "cmr": "cmr10.ttf", "cmex": "cmex10.ttf", "cmsy": "cmsy10.ttf",
             "stixi": "STIXGeneralItalic.ttf"}
PROSE = ("Neural radiance fields render each ray by volume rendering of densities and colours sampled along it, "
         "and the network is optimised with a photometric loss against the training images.")


def _ttf(name: str) -> str:
    import matplotlib

    return os.path.join(os.path.dirname(matplotlib.__file__), "mpl-data", "fonts", "ttf", TTF_FONTS[name])


class MathWriter:
    """Writes glyphs of TeX's math fonts (matplotlib's BaKoMa TrueType copies: ``X`` in cmex10 is the display
    sum, as a raw TeX code) at chosen baselines and sizes on a pymupdf page; ``x`` advances as it writes."""

    def __init__(self, page) -> None:
        import pymupdf

        self.page = page
        self.fonts = {k: pymupdf.Font(fontfile=_ttf(k)) for k in TTF_FONTS}

    def put(self, x: float, y: float, text: str, font: str, size: float = 10.0) -> float:
        """Write ``text`` with its baseline at ``y``; returns the x after it."""
        if font == "times":
            import pymupdf

            self.page.insert_text((x, y), text, fontsize=size, fontname="tiro")
            return x + pymupdf.get_text_length(text, fontname="tiro", fontsize=size)
        self.page.insert_text((x, y), text, fontsize=size, fontname=font, fontfile=_ttf(font))
        return x + self.fonts[font].text_length(text, fontsize=size)

    def transmittance(self, x: float, b: float, number: str) -> None:
        """``T_i = exp(-sum_{j=1}^{i-1} sigma_j delta_j)  (number)``: scripts, a big operator with limits."""
        put = self.put
        x = put(x, b, "T", "cmmi")
        x = put(x, b + 1.5, "i", "cmmi", 7) + 2
        x = put(x, b, "=", "cmr") + 2
        x = put(x, b, "exp(", "cmr")
        x = put(x, b, "-", "cmr")
        sx = x
        x = put(x, b - 9.2, "X", "cmex")  # CMEX's display sum hangs below its origin
        put(sx + 1, b + 10.5, "j", "cmmi", 7)
        put(sx + 4.5, b + 10.5, "=1", "cmr", 7)
        put(sx + 0.5, b - 12.5, "i", "cmmi", 7)
        put(sx + 3.5, b - 12.5, "-1", "cmr", 7)
        x += 2
        x = put(x, b, "σ", "stixi")
        x = put(x, b + 1.5, "j", "cmmi", 7)
        x = put(x, b, "δ", "stixi")
        x = put(x, b + 1.5, "j", "cmmi", 7)
        put(x, b, ")", "cmr")
        self.number(b, number)

    def fraction(self, x: float, b: float, number: str) -> None:
        """``w = a / (b + c) + x^2  (number)``: a drawn fraction bar and a superscript."""
        put = self.put
        x = put(x, b, "w", "cmmi") + 2
        x = put(x, b, "=", "cmr") + 3
        fx = x
        put(fx + 6, b - 6.5, "a", "cmmi")
        dx = put(fx, b + 8.5, "b", "cmmi")
        dx = put(dx, b + 8.5, "+", "cmr")
        dx = put(dx, b + 8.5, "c", "cmmi")
        self.page.draw_line((fx, b - 3.3), (dx, b - 3.3), width=0.4)
        x = dx + 3
        x = put(x, b, "+", "cmr") + 2
        x = put(x, b, "x", "cmmi")
        put(x, b - 4, "2", "cmr", 7)
        self.number(b, number)

    def number(self, b: float, number: str) -> None:
        self.put(self.right - 18, b, f"({number})", "times")

    right = 296.0


def make_math_pdf(path: Path, pages: int = 15, per_page: int = 2, columns: int = 2) -> Path:
    """A synthetic paper in TeX's math fonts: per column prose, then ``per_page`` numbered display equations
    spread over the columns (alternately the transmittance and the fraction), each introduced by a sentence."""
    import pymupdf

    doc = pymupdf.open()
    n = 0
    width = 612
    col_w = 246 if columns == 2 else 468
    starts = (50, 316) if columns == 2 else (72,)
    for _ in range(pages):
        page = doc.new_page(width=width, height=792)
        w = MathWriter(page)
        eqs_here = per_page
        for ci, x0 in enumerate(starts):
            w.right = x0 + col_w
            y = 80
            k = eqs_here // len(starts) + (1 if ci < eqs_here % len(starts) else 0)
            for _ in range(k):
                for _ in range(2):
                    rc = page.insert_textbox(pymupdf.Rect(x0, y - 9, x0 + col_w, y + 60), PROSE, fontsize=10,
                                             fontname="tiro", align=pymupdf.TEXT_ALIGN_JUSTIFY)
                    if rc < 0:
                        raise RuntimeError("benchmark prose does not fit its box")
                    y += 60 - rc + 6
                w.put(x0, y, "The transmittance is computed as follows:" if n % 2 == 0 else
                      "The weights are normalised as follows:", "times")
                y += 30
                n += 1
                (w.transmittance if n % 2 else w.fraction)(x0 + col_w / 2 - 45, y, str(n))
                y += 30
                w.put(x0, y, "where each symbol is defined in the text above.", "times")
                y += 24
    doc.save(str(path))
    doc.close()
    return path


def bench(path: Path, runs: int = 3) -> dict:
    """Median wall and CPU seconds of ``find_equations`` on ``path`` and what it found."""
    import pymupdf

    from nerfify_ns.paper.pdf_math import find_equations

    walls, cpus, found = [], [], []
    for _ in range(runs):
        pdf = pymupdf.open(str(path))
        try:
            t, c = time.perf_counter(), time.process_time()
            found = find_equations(pdf)
            walls.append(time.perf_counter() - t)
            cpus.append(time.process_time() - c)
            pages = pdf.page_count
        finally:
            pdf.close()
    conf = [e.confidence for e in found]
    return {"pdf": str(path), "pages": pages, "equations": len(found), "numbered": sum(1 for e in found if e.number),
            "actualtext": sum(1 for e in found if e.method == "actualtext"),
            "mean_confidence": round(statistics.mean(conf), 3) if conf else None,
            "min_confidence": round(min(conf), 3) if conf else None,
            "wall_s": round(statistics.median(walls), 3), "cpu_s": round(statistics.median(cpus), 3)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pdfs", nargs="*", type=Path)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--pages", type=int, default=15)
    ap.add_argument("--per-page", type=int, default=2)
    args = ap.parse_args(argv)
    pdfs = list(args.pdfs)
    with tempfile.TemporaryDirectory(prefix="nerfify-mathbench-") as tmp:
        if not pdfs:
            pdfs.append(make_math_pdf(Path(tmp) / "synthetic.pdf", args.pages, args.per_page))
            shared = Path(__file__).resolve().parents[2].parent / "shared" / "papers"
            pdfs.extend(sorted(shared.glob("*/*.pdf")) if shared.is_dir() else [])
        for pdf in pdfs:
            r = bench(pdf, args.runs)
            print(f"{Path(r['pdf']).name}: {r['pages']} pages, {r['equations']} equations ({r['numbered']} numbered, "
                  f"{r['actualtext']} from embedded LaTeX), confidence mean {r['mean_confidence']} min "
                  f"{r['min_confidence']}; find_equations {r['wall_s']} s wall, {r['cpu_s']} s CPU "
                  f"(median of {args.runs})")
    return 0


if __name__ == "__main__":  # pragma: no cover
    from nerfify_ns.interrupts import run_interruptible

    raise SystemExit(run_interruptible(main))
