"""Two-column pages as a layout-keeping PDF-to-text tool writes them (``pdftotext -layout``): each line holds a line
of the left column, a run of spaces, then a line of the right column, so read line by line every sentence is cut
by the other column's. :func:`one_column` puts each page's left column before its right one.

    left = "We present a method that                  the density is predicted by"
    one_column(text)  # -> ("<!-- page 1 -->\\nWe present a method that\\n...\\n\\nthe density is ...", origin)

The gutter of a page is the column where the right-hand lines start: the position most lines resume at after a
gap of :data:`GAP` spaces or more, or start at when the left column is empty there. A line whose text runs across
the gutter without a gap (a title, a caption set over both columns) stays whole, in the left column's place. A text
is taken as two-column only when at least :data:`LEAST_LINES` lines, and :data:`LEAST_SHARE` of its lines, hold
text on both sides of their page's gutter, and its pages can be told apart (form feeds, page markers, or running
headers and footers that repeat on :data:`RUNNING` pages or more); anything else is returned unchanged.
"""

from __future__ import annotations

import re
from collections import Counter

from nerfify_ns.paper.pagesplit import PAGE_MARK

GAP = 3
"""Spaces between a left-column line and a right-column line (fewer are spaces inside a line)."""
LEAST_LINES = 40
LEAST_SHARE = 0.25
RUNNING = 3
SLACK = 4
"""How far a right-column line may start from its page's gutter (a paragraph's indent, a ragged layout)."""

_GAP = re.compile(r"\S( {" + str(GAP) + r",})(?=\S)")
_DIGITS = re.compile(r"\d+")


def _gutter(lines: list[str]) -> int | None:
    """The column where a page's right-hand lines start, or None when it has no second column."""
    starts: list[int] = []
    indents = sorted(len(line) - len(line.lstrip()) for line in lines if len(line.strip()) >= 20)
    margin = indents[len(indents) // 10] if indents else 0  # the page's left margin (a stamp in it aside)
    for line in lines:
        text = line.lstrip()
        if not text:
            continue
        indent = len(line) - len(text)
        for m in _GAP.finditer(line):
            if m.start(1) - indent >= 15 and len(line) - m.end(1) >= 10:
                starts.append(m.end(1))
        if indent - margin >= 30 and len(text) >= 10:
            starts.append(indent)
    if not starts:
        return None
    counts = Counter(starts)
    best = max(sorted(counts), key=lambda p: sum(counts[q] for q in range(p - 2, p + 3)))
    near = sum(counts[q] for q in range(best - 2, best + 3))
    return best if near >= 5 else None


def _split(line: str, gutter: int) -> tuple[str, str, bool]:
    """(left text, right text, whether the line held both) of one line at ``gutter``."""
    text = line.lstrip()
    indent = len(line) - len(text)
    if not text:
        return "", "", False
    if indent >= gutter - SLACK:
        return "", text.rstrip(), False
    for m in _GAP.finditer(line):
        if gutter - SLACK <= m.end(1) <= gutter + SLACK + 2:
            return line[:m.start(1)].strip(), line[m.end(1):].strip(), True
    return line.strip(), "", False  # the left column alone, or a line across both columns


def _pages(lines: list[str]) -> list[tuple[int, list[str]]]:
    """(first line's index, lines) per page: split at form feeds, page markers, else at running headers/footers."""
    if any("\f" in line for line in lines) or any(PAGE_MARK.match(line) for line in lines):
        pages: list[tuple[int, list[str]]] = [(0, [])]
        for i, line in enumerate(lines):
            if PAGE_MARK.match(line):
                pages.append((i + 1, []))
                continue
            pieces = line.split("\f")
            for k, piece in enumerate(pieces):
                if k:
                    pages.append((i, []))
                pages[-1][1].append(piece)
        return [p for p in pages if any(s.strip() for s in p[1])]
    keys = [_DIGITS.sub("#", " ".join(line.split())) for line in lines]
    counts = Counter(k for k in keys if len(k) >= 15)
    running = {k for k, n in counts.items() if n >= RUNNING}
    if not running:
        return [(0, lines)]
    pages, content = [(0, [])], 0
    for i, (line, key) in enumerate(zip(lines, keys, strict=True)):
        if key in running and content >= 5:
            pages.append((i, []))
            content = 0
        pages[-1][1].append(line)
        content += bool(line.strip()) and key not in running
    return pages


def one_column(text: str) -> tuple[str, list[int] | None]:
    """``text`` with every two-column page's left column before its right one, each page opened by a page marker;
    and per line of the result, the line of ``text`` it comes from (1-based). ``(text, None)`` when ``text`` is not
    a two-column layout."""
    lines = text.splitlines()
    pages = _pages(lines)
    if len(pages) < 2:
        return text, None
    both = total = 0
    split_pages = []
    for first, page in pages:
        gutter = _gutter(page)
        rows = []
        for k, line in enumerate(page):
            left, right, two = (_split(line, gutter) if gutter is not None else (line.strip(), "", False))
            rows.append((first + k + 1, " ".join(left.split()), " ".join(right.split())))
            both += two
            total += bool(line.strip())
        split_pages.append(rows)
    if both < LEAST_LINES or both < LEAST_SHARE * total:
        return text, None
    out: list[str] = []
    origin: list[int] = []
    for number, rows in enumerate(split_pages, 1):  # every page holds a line (_pages)
        out.append(f"<!-- page {number} -->")
        origin.append(rows[0][0])
        for side in (1, 2):
            for line_no, *texts in rows:
                out.append(texts[side - 1])
                origin.append(line_no)
            out.append("")
            origin.append(rows[-1][0])
    return "\n".join(out), origin
