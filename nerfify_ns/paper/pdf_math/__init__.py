"""Display equations of a PDF as LaTeX, rebuilt from its text layer (pymupdf), each with a confidence.

Two ways, the better one first:

1. **Embedded LaTeX.** Papers made with ``axessibility`` (loaded by the CVPR/ICCV author kits) carry each
   formula's LaTeX source as the ``/ActualText`` of a marked-content span. We read those strings from the
   page's content stream and give each to the display equation whose glyphs it renders (``method="actualtext"``).
2. **Layout.** Otherwise the glyphs themselves (``method="layout"``): pymupdf's ``rawdict`` gives every
   glyph's font, size and baseline, so math-italic, symbol and extension fonts (CMMI/CMSY/CMEX/CMR/MSBM and
   their Type 1/TrueType cousins, Unicode math fonts) map to LaTeX tokens (raw TeX font codes included);
   sub- and superscripts are smaller glyphs on raised or lowered baselines; big operators take the small
   glyphs centred above and below them as limits; horizontal rules from ``page.get_drawings()`` are
   fraction bars (numerator above, denominator below) or radical overbars; tall delimiters assembled from
   pieces span rows of cases and matrices.

Display equations are found per column: lines dominated by math glyphs, grouped while they stay close,
split at equation numbers ("(n)" set apart at the column's edge). The confidence is the share of glyphs
mapped times what the structure checks leave (``notes`` says what lowered it). Nothing here guesses a
symbol it cannot read: it is written ``?`` and counted.

Entry points: ``find_equations(pdf)`` -> ``list[PdfEquation]``; ``enrich_document(doc, pdf)`` merges them
into a ``Document`` read by ``pdf.py``.

Modules, in the order a page is read: ``glyphs`` (a character and its font -> a LaTeX token), ``layout`` (a
page's spans -> lines, columns, equation numbers), ``structure`` (one equation's glyphs and rules -> LaTeX),
``actualtext`` (the embedded LaTeX), ``find`` (the display equations of a PDF), ``merge`` (into the Document).
"""

from .actualtext import actual_texts
from .find import MAX_EQUATION_GLYPHS, MAX_EQUATIONS, MAX_RULES, TIME_BUDGET_S, find_equations
from .glyphs import Glyph, make_glyph
from .layout import EQ_NUMBER, PdfEquation, glyph_text
from .merge import enrich_document
from .structure import reconstruct

__all__ = ["EQ_NUMBER", "MAX_EQUATIONS", "MAX_EQUATION_GLYPHS", "MAX_RULES", "TIME_BUDGET_S", "Glyph", "PdfEquation",
           "actual_texts", "enrich_document", "find_equations", "glyph_text", "make_glyph", "reconstruct"]
