"""Markdown reader: headings, paragraphs with line numbers, math blocks, pipe tables, captions."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

from nerfify_ns.equations.mathdup import Budget, fix_inline, has_duplicated_math, split_display
from nerfify_ns.paper.builder import CAPTION, Block, build, heading_level, split_heading
from nerfify_ns.paper.document import Document, Location
from nerfify_ns.paper.language import prose, require_english
from nerfify_ns.paper.limits import DEFAULT_LIMITS, Limits, check_elements, read_text_file
from nerfify_ns.paper.pagesplit import NUMBERED_LINE, flat_blocks

_EQ_NUM = re.compile(r"^\(\s*(\d+[a-z]?|[A-Z]\.?\d+)\s*\)$")
_TRAILING_NUM = re.compile(r"\s*\(\s*(\d+[a-z]?)\s*\)\s*$")
_END_NUM = re.compile(r"\(\s*(\d+[a-z]?)\s*\)\s*$")
"""A trailing ``(n)``, searched in the last characters only (no leading ``\\s*``: linear)."""
_TAG = re.compile(r"\\tag\{([^{}]{0,200})\}")
_NUMERIC_CELL = re.compile(r"^[-−+]?\d+(?:\.\d+)?%?$")
_LIST = re.compile(r"^\s*(?:[-*+]\s+(?:[–—]\s+)?|\d+[.)]\s+)")


def read_markdown(path: Path, limits: Limits = DEFAULT_LIMITS) -> Document:
    """Ingest a ``.md`` file (at most ``limits.max_text_chars`` characters; English prose only)."""
    text = without_converter_markup(read_text_file(path, limits))
    blocks = flat_blocks(text) or markdown_blocks(text)
    check_elements(blocks, path.name, limits)
    require_english(prose(blocks), path.name)
    return build(blocks, source=str(path), kind="markdown")


_ANCHOR = re.compile(r"<(span|a)\b[^<>\n]{0,200}>\s*</\1>", re.IGNORECASE)
_INTERNAL_LINK = re.compile(r"\[((?:\\.|[^\[\]\n]){1,80})\]\(#[^()\s]{1,80}\)")
_INLINE_TAG = re.compile(r"<(sup|sub|b|i|em|strong)>([^<>\n]{0,200})</\1>", re.IGNORECASE)
_ESCAPED = re.compile(r"\\([\[\]()*_#])")


def without_converter_markup(text: str) -> str:
    """``text`` without the HTML and links a PDF-to-markdown converter leaves around the paper's own text: empty
    anchors (``<span id="page-3-1"></span>3.2 Rendering``), in-document links around citations and references
    (``[\\[11\\]](#page-9-7)`` is ``[11]``, ``Equation [\\(4\\)](#page-4-0)`` is ``Equation (4)``), and inline
    tags (``ω<sup>i</sup>`` is ``ω^i``, ``<b>LPIPS</b>`` is ``LPIPS``). Lines stay where they are."""
    if "<" not in text and "](#" not in text:
        return text
    text = _ANCHOR.sub("", text)
    text = _INTERNAL_LINK.sub(lambda m: _ESCAPED.sub(r"\1", m.group(1)), text)
    return _INLINE_TAG.sub(lambda m: ("^" if m.group(1).lower() == "sup" else "_" if m.group(1).lower() == "sub"
                                      else "") + m.group(2), text)


def markdown_blocks(text: str) -> list[Block]:
    """The blocks of a markdown text, in order."""
    lines = text.splitlines()
    budget = Budget()  # the whole document's de-duplication work
    fix = (lambda s: fix_inline(s, budget)) if has_duplicated_math(text) else (lambda s: s)
    reader = _Reader(lines, fix, budget)
    return list(reader.blocks())


_STAMP = re.compile(r"^arXiv:\s*\d{4}\.\d{4,5}", re.IGNORECASE)
"""An arXiv identifier stamp ("arXiv:2312.00252v1 [cs.CV] 30 Nov 2023")."""
_MATH = re.compile(r"=|\w\([^)]*\)|[∑∫∏σαβγδλθμτφψωΣΦΨΩ^_\\]")
"""Math in a heading that ends with an equation number (``NUMBERED_LINE``): an ``=``, a function applied, a Greek
letter or a script; such a heading is a display equation a converter set as a heading."""
_SECTION_NAME = re.compile(r"^(?:abstract|introduction|related work|background|method|references|appendix|overview|"
                           r"preliminar|motivation|approach|our |experiment|results?\b|conclusion|implementation|"
                           r"contribution|summary|limitation|discussion|acknowledg)", re.IGNORECASE)
"""Headings that open a paper's sections: never its title."""


class _Reader:
    def __init__(self, lines: list[str], fix, budget: Budget | None = None):
        self.lines, self.fix, self.i = lines, fix, 0
        self.budget = budget or Budget()
        self.seen_title = False
        self.seen_heading = False
        self.last_para = ""

    def blocks(self) -> Iterator[Block]:
        n = len(self.lines)
        while self.i < n:
            line = self.lines[self.i]
            s = line.strip()
            if not s:
                self.i += 1
            elif s.startswith("#"):
                yield from self._heading(s)
            elif s.startswith("```"):
                yield from self._fence()
            elif s.startswith("$$") or s.startswith("\\["):
                yield from self._math()
            elif s.startswith("|"):
                yield from self._table()
            else:
                yield from self._paragraph()

    def _loc(self, i: int) -> Location:
        return Location(line=i + 1)

    def _heading(self, s: str) -> Iterator[Block]:
        hashes = len(s) - len(s.lstrip("#"))
        text = re.sub(r"[*_`]", "", s[hashes:]).strip()
        loc = self._loc(self.i)
        self.i += 1
        if _STAMP.match(text):
            return  # an arXiv stamp a converter set as a heading: neither the title nor a section
        eq = NUMBERED_LINE.match(s[hashes:].strip()) if len(s) < 300 else None  # a heading's length
        if eq and _MATH.search(eq.group("body")):  # a display equation set as a heading ("#### σ,c = f(x,d), (3)")
            yield Block("equation", eq.group("body").rstrip(",. "), loc, number=eq.group("num"))
            return
        number, title = split_heading(text)
        if not self.seen_title and (hashes == 1 or not self.seen_heading) and not number \
                and not _SECTION_NAME.match(title):
            self.seen_title = self.seen_heading = True
            yield Block("title", text, loc)
            return
        self.seen_heading = True
        yield Block("heading", title, loc, level=heading_level(number, max(1, hashes - 1)), number=number)

    def _fence(self) -> Iterator[Block]:
        start = self.i
        self.i += 1
        body = []
        while self.i < len(self.lines) and not self.lines[self.i].strip().startswith("```"):
            body.append(self.lines[self.i])
            self.i += 1
        self.i += 1
        text = "\n".join(body)
        m = re.match(r"\s*Algorithm\s+(\d+)", text)
        if m or re.search(r"^[^\S\n]*\d+:\s", text, re.MULTILINE):
            yield Block("algorithm", text, self._loc(start), number=m.group(1) if m else "")

    def _math(self) -> Iterator[Block]:
        start = self.i
        first = self.lines[self.i].strip()
        closer = "$$" if first.startswith("$$") else "\\]"
        parts = [first[2:]]
        ends = parts[0].rstrip().endswith(closer)  # does the body so far end with the closer (blanks aside)?
        while not ends:
            self.i += 1
            if self.i >= len(self.lines):
                break
            parts.append(self.lines[self.i])
            if parts[-1].strip():
                ends = parts[-1].rstrip().endswith(closer)
        body = "\n".join(parts)
        self.i += 1
        latex, _, after = body.rpartition(closer) if closer in body else (body, "", "")
        number = ""
        if (m := _TAG.search(latex)):
            number, latex = m.group(1), _TAG.sub("", latex)
        elif (m := _TRAILING_NUM.match(after)) or (m := _END_NUM.search(latex, max(0, len(latex) - 200))):
            number = m.group(1)
            latex = latex[:m.start()] if m.string == latex else latex
        if not number and self.i < len(self.lines) and _EQ_NUM.match(self.lines[self.i].strip()):
            number = _EQ_NUM.match(self.lines[self.i].strip()).group(1)
            self.i += 1
        yield Block("equation", "", self._loc(start), number=number, latex=latex.strip())

    def _table(self) -> Iterator[Block]:
        start = self.i
        rows = []
        while self.i < len(self.lines) and self.lines[self.i].strip().startswith("|"):
            row = self.lines[self.i].strip().strip("|")
            if not re.fullmatch(r"[\s|:\-]+", row):
                rows.append([c.strip() for c in row.split("|")])
            self.i += 1
        if any(_EQ_NUM.match(r[-1] if r else "") or _EQ_NUM.match(r[-2] if len(r) > 1 else "") for r in rows):
            yield from self._equation_rows(rows, start)
            return
        cells = [[self._cell(c) for c in r] for r in rows]
        if sum(1 for r in cells for c in r if _NUMERIC_CELL.match(c)) >= 3:
            yield Block("table", "", self._loc(start), rows=cells)

    def _cell(self, c: str) -> str:
        c = re.sub(r"\{?\\mathbf\{([^{}]*)\}\}?|\{([^{}]*)\}", lambda m: m.group(1) or m.group(2) or "", c)
        c = self.fix(c)
        return c.strip("$ ")

    def _equation_rows(self, rows: list[list[str]], start: int) -> Iterator[Block]:
        """LaTeXML equation tables: ``|  | <math> |  | (n) |``, one or more rows per equation."""
        pending_u, pending_l = [], []
        for r in rows:
            nums = [c for c in r if _EQ_NUM.match(c)]
            body = [c for c in r if c and not _EQ_NUM.match(c)]
            for cell in body:
                u, lx = split_display(cell, self.budget)
                pending_u.append(u)
                pending_l.append(lx)
            if nums:
                yield Block("equation", " ".join(x for x in pending_u if x), self._loc(start),
                            number=_EQ_NUM.match(nums[0]).group(1), latex=" ".join(x for x in pending_l if x))
                pending_u, pending_l = [], []
        if pending_l or pending_u:
            yield Block("equation", " ".join(pending_u), self._loc(start), latex=" ".join(pending_l))

    def _paragraph(self) -> Iterator[Block]:
        start = self.i
        parts = []
        while self.i < len(self.lines):
            s = self.lines[self.i].strip()
            if not s or s.startswith(("#", "|", "```", "$$", "\\[")) or (parts and _LIST.match(s)):
                break
            parts.append(_LIST.sub("", s) if not parts else s)
            self.i += 1
            if s.endswith("$$"):
                break
        text = self.fix(" ".join(parts))
        if text == self.last_para:  # converters repeat list items
            return
        self.last_para = text
        kind = "caption" if CAPTION.match(text) else "para"
        alg = re.match(r"\**Algorithm\s+(\d+)\**[:.]?\s*(.*)", text)
        if alg:
            yield Block("algorithm", text, self._loc(start), number=alg.group(1), title=alg.group(2)[:120])
        else:
            yield Block(kind, text, self._loc(start))
