"""Assemble a Document from the typed blocks every reader emits, in reading order."""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field

from nerfify_ns.paper.annotate import annotate_equations
from nerfify_ns.paper.document import (
    Algorithm,
    Caption,
    Citation,
    Document,
    Equation,
    Location,
    Paragraph,
    Reference,
    ResultTable,
    Section,
)
from nerfify_ns.paper.hyperparams import extract_hyperparameters, split_sentences
from nerfify_ns.paper.references import is_references_heading, parse_reference_text

KINDS = ("title", "authors", "abstract", "heading", "para", "equation", "caption", "algorithm", "table",
         "references")


@dataclass
class Block:
    """One unit a reader found: its kind (see KINDS), text and where it is."""

    kind: str
    text: str
    loc: Location = field(default_factory=Location)
    level: int = 1
    number: str = ""
    latex: str = ""
    label: str = ""
    rows: list = field(default_factory=list)
    title: str = ""


_HEADING = re.compile(r"^(?:(?:Appendix|Section)\s+)?((?:\d+|[A-Z])(?:\.(?:\d+|[A-Z]))*)\.?\s+(\S.*)$")
_ABSTRACT = re.compile(r"^\s*abstract\.?\s*$", re.IGNORECASE)
CAPTION = re.compile(r"^\s*(Figure|Fig\.|Table|Tab\.)\s*([A-Z]?\d+[a-z]?)\s*[.:|]\s*(.*)", re.IGNORECASE | re.DOTALL)
_RUN_IN_ACK = re.compile(r"^(Acknowledge?ments?)[.:]?\s+(.*)", re.DOTALL)
NUM_CITE = re.compile(r"\[(\d{1,4}(?:\s*[,–\-]\s*\d{1,4})*)\]")


def split_heading(text: str) -> tuple[str, str]:
    """("3.1", "Title") from "3.1 Title" / "Appendix A Title"; ("", text) when unnumbered."""
    text = re.sub(r"\s+", " ", text).strip()
    m = _HEADING.match(text)
    if m and not re.fullmatch(r"[A-Z]", m.group(1) or "") or (m and text.lower().startswith("appendix")):
        return m.group(1), m.group(2).strip()
    return "", text


def heading_level(number: str, default: int = 1) -> int:
    return number.count(".") + 1 if number else default


def build(blocks: Iterable[Block], source: str, kind: str, page_count: int = 0,
          references: list[Reference] | None = None, title: str = "", authors: list[str] | None = None,
          cite_keys: set | None = None) -> Document:
    """The Document of ``blocks``; ``references`` (e.g. from BibTeX) replaces a parsed reference section."""
    doc = Document(source=source, kind=kind, title=title, authors=list(authors or []), page_count=page_count)
    state = _State(doc)
    for order, b in enumerate(blocks, start=1):
        b.loc.order = order
        state.add(b)
    state.finish()
    if references is not None:
        doc.references = references
    elif state.ref_text:
        doc.references = parse_reference_text("\n".join(state.ref_text))
    if not doc.abstract:
        _abstract_from_front(doc, state.front)
    doc.sections = [s for s in doc.sections if s.paragraphs or s.title]
    items = [(p.text, p.loc, p.section) for p in doc.paragraphs()]
    doc.hyperparameters = extract_hyperparameters(items + [(line, a.loc, a.section)
                                                           for a in doc.algorithms for line in a.lines],
                                                  doc.warnings)
    keys = cite_keys if cite_keys is not None else {r.key for r in doc.references}
    doc.citations = extract_citations(items, keys)
    annotate_equations(doc)
    return doc


class _State:
    """The builder's cursor: current section, whether we are in the references or the abstract."""

    def __init__(self, doc: Document):
        self.doc = doc
        self.section: Section | None = None
        self.in_refs = False
        self.in_abstract = False
        self.ref_text: list[str] = []
        self.front: list[Block] = []

    @property
    def section_name(self) -> str:
        return self.section.heading if self.section else ""

    def add(self, b: Block) -> None:
        getattr(self, f"_on_{b.kind}")(b)

    def _on_title(self, b: Block) -> None:
        if not self.doc.title:
            self.doc.title = b.text.strip()

    def _on_authors(self, b: Block) -> None:
        self.doc.authors.extend(a for a in re.split(r",\s*|\s+and\s+", b.text) if a.strip())

    def _on_abstract(self, b: Block) -> None:
        self.doc.abstract = (self.doc.abstract + "\n\n" + b.text).strip()

    def _on_heading(self, b: Block) -> None:
        number, title = (b.number, b.text) if b.number else split_heading(b.text)
        self.in_abstract = bool(_ABSTRACT.match(title))
        if self.in_abstract:
            return
        self.in_refs = is_references_heading(title)
        if self.in_refs:
            return
        self.section = Section(title=title, number=number, level=b.level or heading_level(number), loc=b.loc)
        self.doc.sections.append(self.section)

    def _on_para(self, b: Block) -> None:
        text = b.text.strip()
        if not text:
            return
        ack = _RUN_IN_ACK.match(text)
        if ack and not self.in_refs and not (self.section and _RUN_IN_ACK.match(self.section.title)):
            self._on_heading(Block("heading", ack.group(1), b.loc, level=1))
            text = ack.group(2)
        if self.in_refs:
            self.ref_text.append(b.text)
        elif self.in_abstract:
            self.doc.abstract = (self.doc.abstract + "\n\n" + text).strip()
        elif self.section is None:
            self.front.append(b)
        else:
            self.section.paragraphs.append(Paragraph(text=text, loc=b.loc, section=self.section_name))

    def _on_references(self, b: Block) -> None:
        self.ref_text.append(b.text)

    def _on_equation(self, b: Block) -> None:
        self.in_abstract = False
        self.doc.equations.append(Equation(latex=b.latex, text=b.text, number=b.number, label=b.label,
                                           loc=b.loc, section=self.section_name))

    def _on_caption(self, b: Block) -> None:
        m = CAPTION.match(b.text)
        kind = ("table" if m.group(1).lower().startswith("tab") else "figure") if m else (b.title or "figure")
        number = b.number or (m.group(2) if m else "")
        self.doc.captions.append(Caption(kind=kind, number=number, text=b.text.strip(), loc=b.loc, label=b.label))

    def _on_algorithm(self, b: Block) -> None:
        lines = [ln.strip() for ln in b.text.splitlines() if ln.strip()]
        self.doc.algorithms.append(Algorithm(number=b.number, title=b.title or (lines[0] if lines else ""),
                                             lines=lines, loc=b.loc, section=self.section_name))

    def _on_table(self, b: Block) -> None:
        self.doc.result_tables.append(ResultTable(caption=b.title, number=b.number, rows=b.rows, loc=b.loc))

    def finish(self) -> None:
        """Attach captions to tables that have none (same number)."""
        by_num = {c.number: c.text for c in self.doc.captions if c.kind == "table"}
        for t in self.doc.result_tables:
            if not t.caption and t.number in by_num:
                t.caption = by_num[t.number]


def _abstract_from_front(doc: Document, front: list[Block]) -> None:
    """No explicit abstract: take the first long paragraph before the first section."""
    for b in front:
        if len(b.text.split()) >= 40:
            doc.abstract = b.text.strip()
            return


def expand_keys(spec: str) -> list[str]:
    """"3, 5–7" -> ["3", "5", "6", "7"]."""
    keys: list[str] = []
    for part in re.split(r"\s*,\s*", spec):
        m = re.fullmatch(r"(\d+)\s*[–\-]\s*(\d+)", part)
        if m and int(m.group(2)) - int(m.group(1)) < 50:
            keys.extend(str(i) for i in range(int(m.group(1)), int(m.group(2)) + 1))
        elif part.strip():
            keys.append(part.strip())
    return keys


def extract_citations(items: list[tuple[str, Location, str]], keys: set) -> list[Citation]:
    """In-text citations: numeric ``[7]``, ``[3, 5–7]`` and bracketed BibTeX keys known in ``keys``."""
    out: list[Citation] = []
    for text, loc, section in items:
        for sentence in split_sentences(text):
            found: list[str] = []
            for m in re.finditer(r"\[([^\[\]]{1,200})\]", sentence):
                if NUM_CITE.fullmatch(m.group(0)):
                    found.extend(expand_keys(m.group(1)))
                elif keys:
                    found.extend(k for k in (x.strip() for x in m.group(1).split(",")) if k in keys)
            if found:
                out.append(Citation(keys=list(dict.fromkeys(found)), sentence=sentence, loc=loc, section=section))
    return out
