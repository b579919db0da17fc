"""BibTeX (.bib) and .bbl parsing into References."""

from __future__ import annotations

import re
from pathlib import Path

from nerfify_ns.paper.document import Reference
from nerfify_ns.paper.latex_source import read_group
from nerfify_ns.paper.references import ARXIV, DOI, parse_reference

_ENTRY = re.compile(r"@\s*([A-Za-z]+)\s*\{\s*([^,\s]+)\s*,")


def _value(text: str, i: int) -> tuple[str, int]:
    while i < len(text) and text[i] in " \t\n":
        i += 1
    if i < len(text) and text[i] == "{":
        return read_group(text, i)
    if i < len(text) and text[i] == '"':
        j = i + 1
        depth = 0
        while j < len(text) and not (text[j] == '"' and depth == 0):
            depth += {"{": 1, "}": -1}.get(text[j], 0)
            j += 1
        return text[i + 1:j], j + 1
    m = re.match(r"[\w.\-]+", text[i:])
    return (m.group(0), i + m.end()) if m else ("", i)


def strip_tex(s: str) -> str:
    """BibTeX value to plain text: no braces, accents flattened, single spaces."""
    s = re.sub(r"\\[`'^\"~=.uvHtcdb]\s*\{?([A-Za-z])\}?", r"\1", s)
    s = re.sub(r"\\(?:textit|textbf|emph|mathrm|text)\s*", "", s)
    s = s.replace("{", "").replace("}", "").replace("~", " ").replace("\\&", "&")
    return re.sub(r"\s+", " ", s).strip()


def parse_bib(text: str) -> dict[str, Reference]:
    """Every @entry of a .bib text, by key (@string/@comment/@preamble skipped)."""
    refs: dict[str, Reference] = {}
    for m in _ENTRY.finditer(text):
        if m.group(1).lower() in ("string", "comment", "preamble"):
            continue
        fields, i = {}, m.end()
        while True:
            f = re.match(r"\s*([A-Za-z_\-]+)\s*=\s*", text[i:])
            if not f:
                break
            val, i = _value(text, i + f.end())
            fields[f.group(1).lower()] = val
            c = re.match(r"\s*,", text[i:])
            if not c:
                break
            i += c.end()
        refs[m.group(2)] = _reference(m.group(2), fields)
    return refs


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


def parse_bbl(text: str) -> list[Reference]:
    """The \\bibitem entries of a .bbl (or a thebibliography environment)."""
    refs = []
    items = list(re.finditer(r"\\bibitem\s*(?:\[[^\]]*\])?\s*\{([^}]+)\}", text))
    for n, (m, nxt) in enumerate(zip(items, [*items[1:], None]), start=1):
        body = text[m.end(): nxt.start() if nxt else len(text)]
        body = body.split("\\end{thebibliography}")[0]
        body = re.sub(r"\\newblock\s*", " ", body)
        body = re.sub(r"\\(?:url|href)\s*\{([^}]*)\}", r" \1 ", body)
        ref = parse_reference(strip_tex(body), key=m.group(1).strip(), index=n)
        refs.append(ref)
    return refs


def load_references(folder: Path, main: Path, bib_names: list[str], cited: list[str]) -> list[Reference]:
    """References of a LaTeX project: the .bbl entries (enriched from .bib), else the cited .bib entries."""
    bib: dict[str, Reference] = {}
    files = [folder / (n if n.endswith(".bib") else n + ".bib") for n in bib_names] or sorted(folder.rglob("*.bib"))
    for f in files:
        if f.is_file():
            bib.update(parse_bib(f.read_text(encoding="utf-8", errors="replace")))
    bbl = main.with_suffix(".bbl")
    bbls = [bbl] if bbl.is_file() else sorted(folder.rglob("*.bbl"))
    if bbls:
        refs = parse_bbl(bbls[0].read_text(encoding="utf-8", errors="replace"))
        for r in refs:
            if r.key in bib:  # the .bib has cleaner fields
                b = bib[r.key]
                r.title, r.authors = b.title or r.title, b.authors or r.authors
                r.year, r.venue = b.year or r.year, b.venue or r.venue
                r.arxiv, r.doi = b.arxiv or r.arxiv, b.doi or r.doi
        return refs
    keys = [k for k in dict.fromkeys(cited) if k in bib] or list(bib)
    refs = [bib[k] for k in keys]
    for n, r in enumerate(refs, start=1):
        r.index = n
    return refs
