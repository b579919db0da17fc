"""BibTeX (.bib) and .bbl parsing into References, linear in the size of the files.

Every scan continues from where the previous one stopped (patterns matched at a position, never on a copy of
the rest of the text), a value that is never closed ends the parse, and the entries and bytes read are bounded
by :mod:`nerfify_ns.paper.limits` (``max_bib_entries``, ``max_bib_bytes``).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

from nerfify_ns.paper.document import Reference
from nerfify_ns.paper.errors import PaperLimitError
from nerfify_ns.paper.latex_source import SourceTree, read_group
from nerfify_ns.paper.limits import Limits, size_text
from nerfify_ns.paper.references import ARXIV, DOI, parse_reference

_ENTRY = re.compile(r"@\s*([A-Za-z]{1,40})\s*\{\s*([^,\s@{}]{1,500})\s*,")
"""An entry's start; its key stops at the next ``@`` or brace (scans never overlap)."""
_FIELD = re.compile(r"\s*([A-Za-z_\-]+)\s*=\s*")
_COMMA = re.compile(r"\s*,")
_BARE = re.compile(r"[\w.\-]+")
_QUOTED = re.compile(r'[{}"]')
_BIBITEM = re.compile(r"\\bibitem\s*(?:\[[^\[\]]{0,2000}\])?\s*\{([^{}]{1,2000})\}")


def _value(text: str, i: int) -> tuple[str, int]:
    while i < len(text) and text[i] in " \t\n":
        i += 1
    if i < len(text) and text[i] == "{":
        return read_group(text, i)
    if i < len(text) and text[i] == '"':
        depth = 0
        for m in _QUOTED.finditer(text, i + 1):
            c = m.group()
            if c == '"' and depth == 0:
                return text[i + 1:m.start()], m.end()
            depth += {"{": 1, "}": -1}.get(c, 0)
        return text[i + 1:], len(text) + 1
    m = _BARE.match(text, i)
    return (m.group(0), m.end()) if m else ("", i)


def strip_tex(s: str) -> str:
    """BibTeX value to plain text: no braces, accents flattened, single spaces."""
    s = re.sub(r"\\[`'^\"~=.uvHtcdb]\s*\{?([A-Za-z])\}?", r"\1", s)
    s = re.sub(r"\\(?:textit|textbf|emph|mathrm|text)\s*", "", s)
    s = s.replace("{", "").replace("}", "").replace("~", " ").replace("\\&", "&")
    return re.sub(r"\s+", " ", s).strip()


def bib_entries(text: str, max_entries: int | None = None, source: str = "") -> Iterator[tuple[str, dict]]:
    """(key, fields) of every @entry of a .bib text (@string/@comment/@preamble skipped), in one linear scan;
    more than ``max_entries`` entries raise PaperLimitError naming ``source``."""
    pos, n = 0, 0
    for m in _ENTRY.finditer(text):
        if m.start() < pos:
            continue  # inside the previous entry's values
        if m.group(1).lower() in ("string", "comment", "preamble"):
            continue
        n += 1
        if max_entries is not None and n > max_entries:
            raise PaperLimitError(f"{source or 'the bibliography'}: more than {max_entries:,} bibliography entries "
                                  "(the limit); pass the paper's own .bib or .bbl")
        fields, i = {}, m.end()
        while True:
            f = _FIELD.match(text, i)
            if not f:
                break
            val, i = _value(text, f.end())
            fields[f.group(1).lower()] = val
            c = _COMMA.match(text, i)
            if not c:
                break
            i = c.end()
        pos = i
        yield m.group(2), fields


def _reference(key: str, fields: dict) -> Reference:
    authors = [strip_tex(a) for a in re.split(r"\s+and\s+", fields.get("author", "")) if a.strip()]
    year = re.search(r"\d{4}", fields.get("year", ""))
    venue = strip_tex(fields.get("journal") or fields.get("booktitle") or fields.get("publisher") or "")
    arxiv = ""
    eprint = fields.get("eprint", "")
    if re.fullmatch(r"\s*\d{4}\.\d{4,5}(v\d+)?\s*|\s*[a-z\-]+/\d{7}\s*", eprint):
        arxiv = re.sub(r"v\d+$", "", eprint.strip())
    else:
        for f in ("journal", "url", "note", "volume", "howpublished"):
            if (m := ARXIV.search(fields.get(f, ""))):
                arxiv = m.group(1)
                break
    doi = fields.get("doi", "").strip()
    if not doi and (m := DOI.search(fields.get("url", ""))):
        doi = m.group(1)
    raw = ", ".join(x for x in [", ".join(authors), strip_tex(fields.get("title", "")), venue,
                                fields.get("year", "")] if x)
    return Reference(key=key, raw=raw, title=strip_tex(fields.get("title", "")), authors=authors,
                     year=int(year.group(0)) if year else None, venue=venue, arxiv=arxiv, doi=doi)


def parse_bbl(text: str, max_entries: int | None = None, source: str = "") -> list[Reference]:
    """The \\bibitem entries of a .bbl (or a thebibliography environment)."""
    refs = []
    items = []
    for m in _BIBITEM.finditer(text):
        items.append(m)
        if max_entries is not None and len(items) > max_entries:
            raise PaperLimitError(f"{source or 'the bibliography'}: more than {max_entries:,} references (the "
                                  "limit); pass the paper's own .bbl")
    for n, (m, nxt) in enumerate(zip(items, [*items[1:], None], strict=False), start=1):
        body = text[m.end(): nxt.start() if nxt else len(text)]
        body = body.split("\\end{thebibliography}", 1)[0]
        body = re.sub(r"\\newblock\s*", " ", body)
        body = re.sub(r"\\(?:url|href)\s*\{([^}]{0,2000})\}", r" \1 ", body)
        ref = parse_reference(strip_tex(body), key=m.group(1).strip(), index=n)
        refs.append(ref)
    return refs


def load_references(tree: SourceTree, main: Path, bib_names: list[str], cited: list[str]) -> list[Reference]:
    """References of a LaTeX project: the .bbl entries (enriched from .bib), else the cited .bib entries.

    ``\\bibliography{names}`` resolve inside the paper's folder only (``tree``; outside is OutsidePaperError);
    without names, the folder's .bib files are read. At most ``max_bib_bytes`` and ``max_bib_entries`` in all."""
    limits = tree.limits
    budget = _BibBudget(limits)
    bib: dict[str, dict] = {}
    if bib_names:
        files = []
        for n in bib_names:
            shown = f"\\bibliography{{{n}}}"
            found = tree.locate(n if n.endswith(".bib") else n + ".bib", [tree.root, main.parent], shown,
                                suffixes=("",))
            if found is not None:
                files.append((found, shown))
    else:
        files = [(f, tree.rel(f)) for f in tree.with_suffix(".bib", strict=False)]
    for f, shown in files:
        text = budget.read(tree, f, shown)
        for key, fields in bib_entries(text, budget.entries_left(), shown):
            budget.entries += 1
            bib[key] = fields
    bbl = main.with_suffix(".bbl")
    bbls = [bbl] if os.path.lexists(bbl) else tree.with_suffix(".bbl", strict=False)
    if bbls:
        shown = tree.rel(bbls[0])
        refs = parse_bbl(budget.read(tree, bbls[0], shown), limits.max_references, shown)
        for r in refs:
            if r.key in bib:  # the .bib has cleaner fields
                b = _reference(r.key, bib[r.key])
                r.title, r.authors = b.title or r.title, b.authors or r.authors
                r.year, r.venue = b.year or r.year, b.venue or r.venue
                r.arxiv, r.doi = b.arxiv or r.arxiv, b.doi or r.doi
        return refs
    keys = ([k for k in dict.fromkeys(cited) if k in bib] or list(bib))[:limits.max_references]
    refs = [_reference(k, bib[k]) for k in keys]
    for n, r in enumerate(refs, start=1):
        r.index = n
    return refs


class _BibBudget:
    """Bytes and entries of a paper's bibliography files, all files together."""

    def __init__(self, limits: Limits):
        self.limits, self.bytes, self.entries = limits, 0, 0

    def read(self, tree: SourceTree, path: Path, shown: str) -> str:
        left = self.limits.max_bib_bytes - self.bytes
        try:
            text = tree.read(path, shown, max(0, left), what="bibliography")
        except PaperLimitError as e:
            raise PaperLimitError(f"{shown}: the bibliography files are larger than "
                                  f"{size_text(self.limits.max_bib_bytes)} (the limit); pass the paper's own .bib "
                                  "or .bbl") from e
        self.bytes += len(text)
        return text

    def entries_left(self) -> int:
        return self.limits.max_bib_entries - self.entries
