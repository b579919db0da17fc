"""The knowledge base as one object: cards, known papers, detection rules, citation patterns, base models.

    kb = KnowledgeBase.load()                 # the package's own data
    kb = KnowledgeBase.load("my-kb/")         # a folder: cards/, papers.yaml, detect.yaml,
                                              # citation_patterns.yaml, bases.yaml (each optional)
    detections = detect_techniques(doc, kb)
    graph = build_citation_graph(doc, detections, kb=kb)
    derived = derive_plan(doc, detections, graph, kb=kb)

Every stage that reads knowledge takes the object it is given, so a run, a test or a benchmark ablation
can hand the stages a different knowledge base. A folder may hold only some of the files; the others
come from the package (a folder with a reduced ``cards/`` is a knowledge base without those
techniques). References to cards the base does not have (a paper's ``provides``, a hyperparameter's
card in ``detect.yaml``) are dropped, so a reduced card set is consistent.

Tables derived from the data (compiled alias patterns, matched references) are cached on the object;
``KnowledgeBase.default()`` is the package's knowledge base, loaded once, which the convenience
defaults of the stage functions use.
"""

from __future__ import annotations

import dataclasses
import re
from functools import cached_property
from pathlib import Path
from typing import Any, ClassVar

from nerfify_ns.knowledge.cards import (
    CARDS_DIR,
    AliasMatch,
    Card,
    card,
    cards_for_terminal,
    find_by_alias,
    match_aliases,
    read_cards,
)
from nerfify_ns.knowledge.errors import KnowledgeError
from nerfify_ns.knowledge.papers import (
    PAPERS_FILE,
    KnownPaper,
    _match_paper,
    find_papers_by_alias,
    read_papers,
    with_card_sources,
)
from nerfify_ns.knowledge.patterns import BASES_FILE, PATTERNS_FILE, BaseRules, PatternSet, read_bases, read_patterns
from nerfify_ns.knowledge.sentences import DETECT_FILE, Rules, read_rules
from nerfify_ns.knowledge.text import alias_pattern, normalize_arxiv_id, normalize_title

PACKAGE_DIR = Path(__file__).resolve().parent
# what a knowledge-base folder may hold: attribute -> (file or folder name, the package's own)
LAYOUT = {"cards": ("cards", CARDS_DIR), "papers": ("papers.yaml", PAPERS_FILE),
          "rules": ("detect.yaml", DETECT_FILE), "patterns": ("citation_patterns.yaml", PATTERNS_FILE),
          "bases": ("bases.yaml", BASES_FILE)}
_WORD = re.compile(r"[0-9a-z]+")

AliasTable = tuple[tuple[str, re.Pattern, Any], ...]


def first_word(alias: str) -> str:
    """The longest word of ``alias`` (a cheap prefilter: a text without it cannot contain the alias)."""
    words = _WORD.findall(alias.lower())
    return max(words, key=len) if words else ""


class KnowledgeBase:
    """Cards, known papers, detection rules, citation patterns and base models, read once (see module doc)."""

    _default: ClassVar[KnowledgeBase | None] = None

    def __init__(self, cards: dict[str, Card], papers: dict[str, KnownPaper], rules: Rules, patterns: PatternSet,
                 bases: BaseRules, sources: dict[str, Path] | None = None):
        self.cards = cards
        self.papers = {k: _known_cards_only(p, cards) for k, p in with_card_sources(papers, cards).items()}
        signalled = {name: list(names) for name, names in rules.hyperparameter_cards.items()}
        for c in cards.values():  # a card's own hyperparameters signal it (its `hyperparameter_patterns`)
            for name, entry in c.hyperparameter_patterns.items():
                if entry.get("signals") and c.name not in signalled.setdefault(name, []):
                    signalled[name].append(c.name)
        self.rules = dataclasses.replace(rules, hyperparameter_cards={
            name: [c for c in names if c in cards] for name, names in signalled.items()
            if any(c in cards for c in names)})
        self.patterns = patterns
        self.bases = bases
        self.sources = dict(sources or {})
        self._references: dict[tuple[str, str, str], str | None] = {}
        self._sources_of_cards: dict[str, str | None] = {}

    # ------------------------------------------------------------------ construction
    @classmethod
    def load(cls, folder: Path | str | None = None) -> KnowledgeBase:
        """The knowledge base in ``folder`` (default: the package's own); files it lacks come from the package.

        Raises ``KnowledgeError`` for a missing folder or one holding none of the knowledge-base files,
        and the typed error of a malformed file (``CardFormatError``, ``PaperRegistryError``, ...)."""
        sources = {attr: default for attr, (_name, default) in LAYOUT.items()}
        if folder is not None:
            root = Path(folder)
            if not root.is_dir():
                raise KnowledgeError(f"no knowledge-base folder at {root}")
            found = {attr: root / name for attr, (name, _default) in LAYOUT.items() if (root / name).exists()}
            if not found:
                names = ", ".join(name for name, _ in LAYOUT.values())
                raise KnowledgeError(f"{root} holds none of the knowledge-base files ({names})")
            sources.update(found)
        return cls(cards=read_cards(sources["cards"]), papers=read_papers(sources["papers"]),
                   rules=read_rules(sources["rules"]), patterns=read_patterns(sources["patterns"]),
                   bases=read_bases(sources["bases"]), sources=sources)

    @classmethod
    def default(cls) -> KnowledgeBase:
        """The package's knowledge base, loaded on first use and kept (the stage functions' default)."""
        if cls._default is None:
            cls._default = cls.load()
        return cls._default

    @classmethod
    def of(cls, kb: KnowledgeBase | None) -> KnowledgeBase:
        """``kb`` itself, or the default knowledge base when None."""
        return kb if kb is not None else cls.default()

    def __repr__(self) -> str:
        where = self.sources.get("cards", CARDS_DIR)
        return f"KnowledgeBase({len(self.cards)} cards, {len(self.papers)} papers, cards from {where})"

    # ------------------------------------------------------------------ cards
    def card(self, name: str) -> Card:
        """The card called ``name``; raises ``UnknownCardError`` naming the known ones."""
        return card(name, self.cards)

    def cards_for_terminal(self, terminal: str) -> list[Card]:
        return cards_for_terminal(terminal, self.cards)

    def match_aliases(self, text: str) -> list[AliasMatch]:
        return match_aliases(text, self.cards.values())

    def find_by_alias(self, text: str) -> list[Card]:
        return find_by_alias(text, self.cards.values())

    def productions_of(self, c: Card) -> list[str]:
        """The card productions ``c`` fills (its own, plus those of its extra terminals)."""
        extra = self.patterns.terminal_productions
        out = [c.production]
        for t in c.terminals:
            if t in extra and extra[t] not in out:
                out.append(extra[t])
        return out

    @cached_property
    def card_aliases(self) -> AliasTable:
        """(prefilter word, pattern, (card, alias)) for every card alias."""
        return tuple((first_word(a), alias_pattern(a), (c.name, a)) for c in self.cards.values() for a in c.aliases)

    @cached_property
    def phrase_patterns(self) -> tuple[tuple[str, str, str, re.Pattern], ...]:
        """(prefilter word, card, phrase, pattern) for every card's signal phrase."""
        out = []
        for c in self.cards.values():
            for ph in c.signals.phrases:
                try:
                    out.append((first_word(ph), c.name, ph, alias_pattern(ph)))
                except ValueError:
                    continue
        return tuple(out)

    # ------------------------------------------------------------------ papers
    @property
    def builds_on(self) -> dict[str, tuple[str, ...]]:
        """Known paper -> the known papers its method derives from (papers.yaml ``builds_on``)."""
        return {k: p.builds_on for k, p in self.papers.items()}

    @cached_property
    def paper_aliases(self) -> AliasTable:
        """(prefilter word, pattern, paper key) for every known paper's alias."""
        return tuple((first_word(a), alias_pattern(a), p.key) for p in self.papers.values() for a in p.aliases)

    @cached_property
    def titles(self) -> tuple[tuple[str, str], ...]:
        return tuple((p.key, p.normalized_title) for p in self.papers.values())

    def match_paper(self, title: str | None = None, arxiv: str | None = None) -> KnownPaper | None:
        """The known paper with this arXiv id or title (see ``papers.match_paper``)."""
        return _match_paper(title, arxiv, self.papers)

    def find_papers_by_alias(self, text: str) -> list[KnownPaper]:
        return find_papers_by_alias(text, self.papers)

    def match_reference(self, ref: Any) -> KnownPaper | None:
        """The known paper a ``Reference`` points to: arXiv id, title, then a known title inside the raw entry
        (memoised on this object)."""
        args = (getattr(ref, "title", "") or "", getattr(ref, "arxiv", "") or "", getattr(ref, "raw", "") or "")
        if args not in self._references:
            found = self._match_reference(*args)
            self._references[args] = found.key if found else None
        key = self._references[args]
        return self.papers[key] if key else None

    def _match_reference(self, title: str, arxiv: str, raw: str) -> KnownPaper | None:
        found = self.match_paper(title=title or None, arxiv=arxiv or None)
        if found is not None:
            return found
        if re.search(r"arxiv|\d{4}\.\d{4,5}", raw, re.IGNORECASE):
            found = self.match_paper(arxiv=normalize_arxiv_id(raw))
            if found is not None:
                return found
        key = f" {normalize_title(raw)} "
        best: tuple[str, str] | None = None
        for pkey, ptitle in self.titles:
            if len(ptitle) >= 20 and f" {ptitle} " in key and (best is None or len(ptitle) > len(best[1])):
                best = (pkey, ptitle)
        return self.papers.get(best[0]) if best else None

    def card_source(self, c: Card) -> str | None:
        """The known paper that introduced card ``c`` (memoised on this object)."""
        if c.name not in self._sources_of_cards:
            p = self.match_paper(title=c.paper.title, arxiv=c.paper.arxiv or None)
            self._sources_of_cards[c.name] = p.key if p else None
        return self._sources_of_cards[c.name]

    # ------------------------------------------------------------------ base models
    def base_for_paper(self, key: str) -> str | None:
        """The base model whose code a known paper is (bases.yaml ``papers``), or None."""
        return next((m.name for m in self.bases.models if key in m.papers), None)

    @cached_property
    def base_names(self) -> AliasTable:
        """(prefilter word, pattern, base model) for every name of a base model."""
        return tuple((first_word(n), alias_pattern(n), m.name) for m in self.bases.models for n in m.names)


def _known_cards_only(p: KnownPaper, cards: dict[str, Card]) -> KnownPaper:
    """``p`` providing only cards the knowledge base has."""
    if all(c in cards for c in p.provides):
        return p
    return dataclasses.replace(p, provides=tuple(c for c in p.provides if c in cards))


