"""The builder's finishing pass over a Document's equations: each gets its source, its canonical LaTeX
(``equations.normalize.normalize_latex``; the source's own spelling kept in ``latex_raw``), a confidence with
the notes behind it (``equations.confidence``), and the sentence it belongs to."""

from __future__ import annotations

import bisect
import re

from nerfify_ns.equations.confidence import source_confidence
from nerfify_ns.equations.normalize import has_lost_backslashes, normalize_latex
from nerfify_ns.paper.hyperparams import split_sentences

SOURCE_OF_KIND = {"latex": "tex", "markdown": "markdown", "pdf": "pdf", "text": "text"}


def equation_sentence(before: str, after: str, number: str = "") -> str:
    """The sentence an equation belongs to: the text before it back to its sentence's start, the equation
    as ``⟨Eq. n⟩`` (``⟨equation⟩`` unnumbered), and the text after it when it continues the sentence
    (``where ...``, ``with ...``) up to that sentence's end."""
    head = ""
    before = re.sub(r"\s+", " ", before or "").strip()
    if before:
        sents = split_sentences(before)
        head = sents[-1] if sents else before
        if re.search(r"[.!?]$", head) and not head.endswith(":"):
            head = ""  # the equation starts a new sentence
    tail = ""
    after = re.sub(r"\s+", " ", after or "").strip()
    if after and re.match(r"[a-z(,;]|where\b|with\b|and\b|in which\b", after):
        sents = split_sentences(after)
        tail = sents[0] if sents else after
        if not re.match(r"[a-z(,;]", tail) and head:
            tail = ""
    marker = f"⟨Eq. {number}⟩" if number else "⟨equation⟩"
    return " ".join(p for p in (head, marker, tail) if p).strip()


def annotate_equations(doc) -> None:
    """Give every equation of ``doc`` its source, normalised LaTeX (the original kept in ``latex_raw`` when
    it changed), confidence with its notes, and its sentence (from the paragraphs around it). A reader
    with better knowledge (the PDF's geometry) may overwrite these afterwards."""
    source = SOURCE_OF_KIND.get(doc.kind, doc.kind)
    lost = any(has_lost_backslashes(e.latex) for e in doc.equations)
    paragraphs = sorted(doc.paragraphs(), key=lambda p: p.loc.order)
    orders = [p.loc.order for p in paragraphs]
    for e in doc.equations:
        e.source = e.source or source
        failed = ""
        if e.latex and not e.latex_raw:
            try:
                norm = normalize_latex(e.latex, lost_backslashes=lost)
            except Exception as err:  # noqa: BLE001 - the per-equation boundary: kept as written, said why
                norm = e.latex
                failed = f"not normalised ({type(err).__name__}: {' '.join(str(err).split())[:120]})"
            if norm != e.latex:
                e.latex_raw, e.latex = e.latex, norm
        if failed:
            e.notes = list(e.notes or []) + [failed]
        if e.confidence is None:
            if e.latex:
                e.confidence, notes = source_confidence(e.latex, e.source)
                e.notes = notes + ([failed] if failed else [])
                e.method = e.method or "source"
            else:
                e.confidence, e.method = 0.0, e.method or "none"
                e.notes = ["no LaTeX: only the text layer" if e.text else "empty equation"]
        if not e.sentence and e.loc.order:
            i = bisect.bisect_left(orders, e.loc.order)
            prev = paragraphs[i - 1] if i > 0 and paragraphs[i - 1].section == e.section else None
            nxt = paragraphs[i] if i < len(paragraphs) and paragraphs[i].section == e.section else None
            e.sentence = equation_sentence(prev.text if prev else "", nxt.text if nxt else "", e.number)
