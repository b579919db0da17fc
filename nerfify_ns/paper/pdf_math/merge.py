"""Into the Document: the equations found in the PDF merged with what its text layer gave (``enrich_document``)."""

from __future__ import annotations

import time

from .find import find_equations
from .layout import PdfEquation


def enrich_document(doc, pdf) -> dict:
    """Merge the PDF's display equations into ``doc.equations``: an equation the reader found by its
    number gets the LaTeX, box, confidence and sentence; one it missed (unnumbered, or not recognised)
    is added in reading order; one the layout reader cannot confirm keeps its text and says so.
    Returns timing and counts."""
    from nerfify_ns.paper.document import Equation, Location

    t0 = time.perf_counter()
    try:
        found = find_equations(pdf)
    except Exception as e:  # never let equation reading break ingestion
        for eq in doc.equations:
            eq.notes = eq.notes + [f"PDF equation reading failed: {e}"]
        return {"seconds": round(time.perf_counter() - t0, 3), "found": 0, "error": str(e)}
    by_key = {}
    for f in found:
        if f.number:
            by_key.setdefault((f.page, f.number), f)
    rank = {id(f): i for i, f in enumerate(found)}
    used = set()
    keys: dict[int, float] = {}
    last = -1.0
    for eq in doc.equations:
        f = by_key.get((eq.loc.page, eq.number)) if eq.number else None
        if f is not None and id(f) in used:
            f = None
        if f is None:
            keys[id(eq)] = last + 0.001
            last = keys[id(eq)]
            eq.source = "pdf"
            if not eq.latex:
                eq.method, eq.confidence = "none", 0.0
                eq.notes = ["no display math found at this equation's place by the layout reader; text only"]
            continue
        used.add(id(f))
        _apply(eq, f)
        keys[id(eq)] = last = float(rank[id(f)])
    added = 0
    for f in found:
        if id(f) in used:
            continue
        loc = Location(page=f.page)
        section = ""
        before = f.sentence.split("⟨")[0].strip() if f.sentence else ""
        anchor = doc.find(before[-60:]) if len(before) >= 12 else None
        if anchor is not None:
            sec = doc.section_of(anchor)
            section = sec.heading if sec else ""
            loc.order = anchor.order + 0.5  # just after the paragraph that introduces it
        else:  # the last section starting on this page or before
            on = [sec for sec in doc.sections if sec.loc.page is not None and sec.loc.page <= f.page]
            section = on[-1].heading if on else ""
        eq = Equation(text=f.text, number=f.number, loc=loc, section=section)
        _apply(eq, f)
        keys[id(eq)] = rank[id(f)] + 0.0005
        doc.equations.append(eq)
        added += 1
    doc.equations.sort(key=lambda e: keys[id(e)])
    return {"seconds": round(time.perf_counter() - t0, 3), "found": len(found), "added": added,
            "numbered": sum(1 for f in found if f.number)}


def _apply(eq, f: PdfEquation) -> None:
    eq.source = "pdf"
    eq.method = f.method
    eq.page = f.page
    eq.bbox = list(f.bbox)
    if eq.latex and eq.latex != f.latex and not eq.latex_raw:
        eq.latex_raw = eq.latex
    eq.latex = f.latex
    eq.confidence = f.confidence
    eq.notes = list(f.notes)
    eq.sentence = f.sentence or eq.sentence
    if f.label and not eq.label:
        eq.label = f.label
    if not eq.text:
        eq.text = f.text
