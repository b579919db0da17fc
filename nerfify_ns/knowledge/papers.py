"""The registry of known papers (``papers.yaml``) and matching of references against it."""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns.knowledge.errors import PaperRegistryError
from nerfify_ns.knowledge.text import (
    alias_pattern,
    longest_non_overlapping,
    normalize_arxiv_id,
    normalize_title,
    strip_latex,
)

PAPERS_FILE = Path(__file__).resolve().parent / "papers.yaml"
PAPER_FIELDS = ("key", "title", "authors", "year", "venue", "arxiv", "aliases", "provides")
FUZZY_TITLE_RATIO = 0.93   # near-identical titles only (OCR slips, a dropped word)
FUZZY_MIN_LENGTH = 24


@dataclass(frozen=True)
class KnownPaper:
    """A paper the knowledge base knows, and the cards (techniques) it is the source of."""

    key: str
    title: str
    authors: tuple[str, ...]
    year: int | None
    venue: str | None
    arxiv: str | None
    aliases: tuple[str, ...] = ()
    provides: tuple[str, ...] = ()
    notes: str = field(default="", compare=False)
    builds_on: tuple[str, ...] = field(default=(), compare=False)

    @property
    def normalized_title(self) -> str:
        return normalize_title(self.title)


def _parse(entry: object, index: int, path: Path) -> KnownPaper:
    if not isinstance(entry, dict):
        raise PaperRegistryError(f"{path}: entry {index} is not a mapping; fix papers.yaml")
    missing = [k for k in PAPER_FIELDS if k not in entry]
    if missing:
        raise PaperRegistryError(f"{path}: entry {entry.get('key', index)!r} lacks {', '.join(missing)}; "
                                 "fix papers.yaml")
    arxiv = entry["arxiv"]
    if arxiv is not None and normalize_arxiv_id(str(arxiv)) != str(arxiv):
        raise PaperRegistryError(f"{path}: {entry['key']!r} has a non-canonical arXiv id {arxiv!r} "
                                 "(write e.g. 2111.12077, no version); fix papers.yaml")
    for key in ("authors", "aliases", "provides"):
        value = entry[key] or []
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise PaperRegistryError(f"{path}: {entry['key']!r}.{key} must be a list of strings; "
                                     "fix papers.yaml")
    return KnownPaper(key=str(entry["key"]), title=str(entry["title"]), authors=tuple(entry["authors"] or ()),
                      year=None if entry["year"] is None else int(entry["year"]),
                      venue=None if entry["venue"] is None else str(entry["venue"]),
                      arxiv=None if arxiv is None else str(arxiv), aliases=tuple(entry["aliases"] or ()),
                      provides=tuple(entry["provides"] or ()), notes=str(entry.get("notes") or ""),
                      builds_on=_builds_on(entry, path))


def _builds_on(entry: dict, path: Path) -> tuple[str, ...]:
    deps = entry.get("builds_on") or []
    if not isinstance(deps, list) or not all(isinstance(d, str) for d in deps):
        raise PaperRegistryError(f"{path}: {entry['key']!r}.builds_on must be a list of paper keys, got {deps!r}; "
                                 "fix papers.yaml")
    return tuple(deps)


def read_papers(path: Path | str = PAPERS_FILE) -> dict[str, KnownPaper]:
    """Every paper of the registry file ``path``, by key (read now: no cache; a ``KnowledgeBase`` keeps them).

    Raises ``PaperRegistryError`` for a malformed file, a repeated key, arXiv id or title, or a
    ``builds_on`` naming a paper the registry does not know."""
    file = Path(path)
    try:
        data = yaml.safe_load(file.read_text(encoding="utf-8"))
    except OSError as exc:
        raise PaperRegistryError(f"cannot read {file} ({exc}); reinstall nerfify-ns") from exc
    except yaml.YAMLError as exc:
        raise PaperRegistryError(f"{file}: invalid YAML ({exc}); fix papers.yaml") from exc
    entries = data.get("papers") if isinstance(data, dict) else None
    if not isinstance(entries, list):
        raise PaperRegistryError(f"{file}: expected a top-level 'papers:' list; fix papers.yaml")
    papers = tuple(_parse(e, i, file) for i, e in enumerate(entries))
    seen: dict[str, str] = {}
    for p in papers:
        for kind, value in (("key", p.key), ("arxiv", p.arxiv), ("title", p.normalized_title)):
            if value is None:
                continue
            tag = f"{kind}:{value}"
            if tag in seen:
                raise PaperRegistryError(f"{file}: {p.key!r} repeats the {kind} of {seen[tag]!r}; "
                                         "fix papers.yaml")
            seen[tag] = p.key
    for p in papers:
        if any(f"key:{d}" not in seen for d in p.builds_on):
            raise PaperRegistryError(f"{file}: {p.key!r}.builds_on must list known paper keys, got "
                                     f"{list(p.builds_on)!r}; fix papers.yaml")
    return {p.key: p for p in papers}


def with_card_sources(papers: dict[str, KnownPaper], cards: Mapping[str, Any]) -> dict[str, KnownPaper]:
    """The known papers with each card's own paper (``card.paper``) providing it: the paper of the same arXiv id or
    title gains the card in ``provides``; a card whose paper is not known adds it (key: ``paper.key``, else the
    card's name). ``papers.yaml`` then lists what a paper provides besides the techniques it introduced."""
    out = dict(papers)
    for c in sorted(cards.values(), key=lambda c: c.name):
        ref = c.paper
        arxiv = normalize_arxiv_id(ref.arxiv) if ref.arxiv else None
        source = next((p for p in out.values() if (arxiv and p.arxiv == arxiv)
                       or p.normalized_title == normalize_title(ref.title)), None)
        if source is None:
            key = ref.key or c.name
            out[key] = KnownPaper(key=key, title=ref.title, authors=ref.authors, year=ref.year, venue=ref.venue,
                                  arxiv=arxiv, provides=(c.name,))
        elif c.name not in source.provides:
            out[source.key] = dataclasses.replace(source, provides=(*source.provides, c.name))
    return out


def load_papers(path: Path | None = None) -> dict[str, KnownPaper]:
    """Every known paper, by key: the default knowledge base's (``path`` given: that file, read now)."""
    if path is not None:
        return read_papers(path)
    from nerfify_ns.knowledge.kb import KnowledgeBase

    return dict(KnowledgeBase.default().papers)


def match_paper(title: str | None = None, arxiv: str | None = None,
                papers: dict[str, KnownPaper] | None = None) -> KnownPaper | None:
    """The known paper a reference points to, or ``None``.

    Tried in order: the arXiv id (any form: "arXiv:2111.12077v2", a URL, old-style "cs.CV/0502076");
    the normalised title (case, punctuation, LaTeX commands and braces, accents ignored); a paper
    alias equal to the title ("Mip-NeRF 360"); a near-identical title (ratio >= 0.93).
    """
    papers = load_papers() if papers is None else papers
    return _match_paper(title, arxiv, papers)


def _match_paper(title: str | None, arxiv: str | None, papers: dict[str, KnownPaper]) -> KnownPaper | None:
    wanted = normalize_arxiv_id(arxiv) if arxiv else None
    if wanted:
        for p in papers.values():
            if p.arxiv and normalize_arxiv_id(p.arxiv) == wanted:
                return p
    if not title:
        return None
    key = normalize_title(title)
    if not key:
        return None
    for p in papers.values():
        if p.normalized_title == key:
            return p
    bare = strip_latex(title).strip(" .,;:")
    for p in papers.values():
        if any(alias_pattern(a).fullmatch(bare) for a in p.aliases):
            return p
    if len(key) >= FUZZY_MIN_LENGTH:
        best, best_ratio = None, 0.0
        for p in papers.values():
            ratio = difflib.SequenceMatcher(None, key, p.normalized_title).ratio()
            if ratio > best_ratio:
                best, best_ratio = p, ratio
        if best is not None and best_ratio >= FUZZY_TITLE_RATIO:
            return best
    return None


def find_papers_by_alias(text: str, papers: dict[str, KnownPaper] | None = None) -> list[KnownPaper]:
    """Known papers named in running text by an alias ("as in Mip-NeRF 360"), in order of first
    mention; overlapping aliases resolve to the longest ("Mip-NeRF 360" is not also "Mip-NeRF")."""
    papers = load_papers() if papers is None else papers
    spans = [(m.start(), m.end(), p) for p in papers.values() for a in p.aliases
             for m in alias_pattern(a).finditer(text)]
    seen: dict[str, KnownPaper] = {}
    for _, _, p in longest_non_overlapping(spans):
        seen.setdefault(p.key, p)
    return list(seen.values())
