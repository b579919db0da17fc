"""The one representation of an ingested paper: plain dataclasses, each with a JSON-able ``to_dict()``."""

from __future__ import annotations

import dataclasses
import re
import unicodedata
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

Number = int | float


def _plain(obj: Any) -> Any:
    """Recursively turn dataclasses / tuples into JSON-able dicts and lists."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, list | tuple):
        return [_plain(x) for x in obj]
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    return obj


class _Dictable:
    def to_dict(self) -> dict:
        """A JSON-able dict of this object."""
        return _plain(self)


@dataclass
class Location(_Dictable):
    """Where something is: page (PDF, 1-based) or line (text sources, 1-based), file, and reading order."""

    page: int | None = None
    line: int | None = None
    file: str | None = None
    order: int = 0

    def __str__(self) -> str:
        parts = []
        if self.file:
            parts.append(self.file)
        if self.page is not None:
            parts.append(f"p.{self.page}")
        if self.line is not None:
            parts.append(f"l.{self.line}")
        return ", ".join(parts) or f"#{self.order}"


@dataclass
class Paragraph(_Dictable):
    """A paragraph of running text."""

    text: str
    loc: Location = field(default_factory=Location)
    section: str = ""


@dataclass
class Section(_Dictable):
    """A (sub)section: number ("3.1", may be empty), title, level (1 = section) and its paragraphs."""

    title: str
    number: str = ""
    level: int = 1
    loc: Location = field(default_factory=Location)
    paragraphs: list[Paragraph] = field(default_factory=list)

    @property
    def heading(self) -> str:
        return f"{self.number} {self.title}".strip()


@dataclass
class Equation(_Dictable):
    """A display equation: its LaTeX from every input, number as printed ("3"), and how far to trust it.

    ``latex`` is normalised (``equations/normalize.py``; the source's own spelling in ``latex_raw`` when that
    differs); for a PDF it is reconstructed from the text layer (``paper/pdf_math/``). ``source`` is
    tex | markdown | pdf | text; ``method`` how the LaTeX was obtained: source (written in the input),
    actualtext (a PDF's embedded LaTeX, e.g. axessibility), layout (rebuilt from glyphs and rules), none.
    ``page`` (1-based) and ``bbox`` (x0, y0, x1, y1 in PDF points) locate a PDF equation; ``confidence`` is
    0..1 with ``notes`` saying what lowered it; ``sentence`` is the sentence the equation belongs to, the
    equation shown as ``⟨Eq. n⟩``.
    """

    latex: str = ""
    text: str = ""
    number: str = ""
    label: str = ""
    loc: Location = field(default_factory=Location)
    section: str = ""
    source: str = ""
    method: str = ""
    page: int | None = None
    bbox: list[float] | None = None
    confidence: float | None = None
    sentence: str = ""
    notes: list[str] = field(default_factory=list)
    latex_raw: str = ""


@dataclass
class Algorithm(_Dictable):
    """An algorithm block ("Algorithm 1: ...") with its lines."""

    number: str = ""
    title: str = ""
    lines: list[str] = field(default_factory=list)
    loc: Location = field(default_factory=Location)
    section: str = ""


@dataclass
class Caption(_Dictable):
    """A figure or table caption."""

    kind: str  # "figure" | "table"
    number: str
    text: str
    loc: Location = field(default_factory=Location)
    label: str = ""


@dataclass
class ResultTable(_Dictable):
    """A table of results: its caption (if found) and rows of cells where parseable."""

    caption: str = ""
    number: str = ""
    rows: list[list[str]] = field(default_factory=list)
    loc: Location = field(default_factory=Location)


@dataclass
class Reference(_Dictable):
    """A bibliography entry; ``key`` is the printed index ("7") or the BibTeX key."""

    key: str
    raw: str = ""
    title: str = ""
    authors: list[str] = field(default_factory=list)
    year: int | None = None
    venue: str = ""
    arxiv: str = ""
    doi: str = ""
    index: int = 0


@dataclass
class Citation(_Dictable):
    """An in-text citation: the keys cited and the sentence citing them."""

    keys: list[str]
    sentence: str
    loc: Location = field(default_factory=Location)
    section: str = ""


@dataclass
class Hyperparameter(_Dictable):
    """A hyperparameter found in the text, with the sentence it came from."""

    name: str
    value: Number | list
    unit: str = ""
    sentence: str = ""
    raw: str = ""
    qualifier: str = ""
    loc: Location = field(default_factory=Location)
    section: str = ""


@dataclass
class Document(_Dictable):
    """An ingested paper."""

    source: str
    kind: str  # pdf | latex | markdown | text
    title: str = ""
    abstract: str = ""
    authors: list[str] = field(default_factory=list)
    sections: list[Section] = field(default_factory=list)
    equations: list[Equation] = field(default_factory=list)
    algorithms: list[Algorithm] = field(default_factory=list)
    captions: list[Caption] = field(default_factory=list)
    result_tables: list[ResultTable] = field(default_factory=list)
    references: list[Reference] = field(default_factory=list)
    citations: list[Citation] = field(default_factory=list)
    hyperparameters: list[Hyperparameter] = field(default_factory=list)
    page_count: int = 0
    warnings: list[str] = field(default_factory=list)

    # ----- navigation -------------------------------------------------------------------------------
    def paragraphs(self) -> Iterator[Paragraph]:
        for s in self.sections:
            yield from s.paragraphs

    def _items(self) -> Iterator[tuple[str, Location, str]]:
        """(text, location, section) of every text-bearing element, in reading order."""
        if self.title:
            pdf = self.kind == "pdf"
            yield self.title, Location(page=1 if pdf else None, line=None if pdf else 1), ""
        if self.abstract:
            yield self.abstract, Location(), "Abstract"
        for s in self.sections:
            yield s.heading, s.loc, s.heading
            for p in s.paragraphs:
                yield p.text, p.loc, p.section
        for e in self.equations:
            yield f"{e.latex} {e.text}", e.loc, e.section
        for a in self.algorithms:
            yield "\n".join([a.title, *a.lines]), a.loc, a.section
        for c in self.captions:
            yield c.text, c.loc, ""
        for r in self.references:
            yield r.raw, Location(), "References"

    def text(self) -> str:
        """The full text: title, abstract, then each section's heading and paragraphs."""
        parts = [self.title, self.abstract]
        for s in self.sections:
            parts.append(s.heading)
            parts.extend(p.text for p in s.paragraphs)
        return "\n\n".join(p for p in parts if p)

    def find(self, quote: str) -> Location | None:
        """The location of ``quote`` (whitespace, case, dash and math-markup insensitive), or None."""
        for norm in (normalize_text, alnum_key):
            q = norm(quote)
            if not q:
                return None
            for text, loc, _ in self._items():
                if q in norm(text):
                    return loc
        return None

    def section_of(self, location: Location) -> Section | None:
        """The section that holds ``location`` (the last one starting at or before it)."""
        best = None
        for s in self.sections:
            if _key(s.loc) <= _key(location):
                best = s
        return best


def _key(loc: Location) -> tuple:
    if loc.order:
        return (loc.order,)
    return (loc.page or 0, loc.line or 0)


_DASHES = dict.fromkeys(map(ord, "\u2212\u2013\u2014\u2010\u2011"), "-")
_QUOTES = {ord("\u2019"): "'", ord("\u2018"): "'", ord("\u201c"): '"', ord("\u201d"): '"'}


def normalize_text(s: str) -> str:
    """Lower-case, NFKC, unified dashes/quotes, no ``$``, single spaces."""
    s = unicodedata.normalize("NFKC", s).translate(_DASHES).translate(_QUOTES).replace("$", "")
    return re.sub(r"\s+", " ", s).strip().lower()


def alnum_key(s: str) -> str:
    """Only letters and digits, lower-cased: the loosest comparison."""
    return re.sub(r"[^0-9a-z]+", "", normalize_text(s))
