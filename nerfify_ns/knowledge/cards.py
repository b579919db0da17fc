"""Technique cards: one YAML file per technique in ``cards/`` (the file stem is the card name)."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Optional

import yaml

from nerfify_ns.knowledge.errors import CardFormatError, UnknownCardError
from nerfify_ns.knowledge.text import alias_pattern, longest_non_overlapping

CARDS_DIR = Path(__file__).resolve().parent / "cards"

REQUIRED_FIELDS = ("name", "title", "aliases", "paper", "production", "parameters", "equation",
                   "implementation", "signals", "requires")
PAPER_FIELDS = ("title", "authors", "year", "venue", "arxiv")
EQUATION_FIELDS = ("ref", "latex", "text")
SIGNAL_FIELDS = ("hyperparameters", "equations", "phrases")


@dataclass(frozen=True)
class PaperRef:
    """The paper that introduced a technique."""

    title: str
    authors: tuple[str, ...]
    year: Optional[int]
    venue: Optional[str]
    arxiv: Optional[str]


@dataclass(frozen=True)
class Equation:
    """The technique's key equation: where it is in the paper, LaTeX and a plain-text form."""

    ref: Optional[str]
    latex: str
    text: str


@dataclass(frozen=True)
class Signals:
    """What reveals the technique in a paper's text."""

    hyperparameters: tuple[str, ...]
    equations: tuple[str, ...]
    phrases: tuple[str, ...]


@dataclass(frozen=True)
class Card:
    """A NeRF technique: what it is called, who introduced it, where it goes in the grammar.

    ``parameters`` holds the paper's values keyed by the terminal's parameter names; a card covering
    several terminals keys them by terminal first (``{terminal: {param: value}}``): use
    ``params_for(terminal)``.
    """

    name: str
    title: str
    aliases: tuple[str, ...]
    paper: PaperRef
    production: str
    terminals: tuple[str, ...]
    parameters: dict[str, Any]
    equation: Equation
    implementation: str
    signals: Signals
    requires: tuple[str, ...]
    notes: str = ""
    related_papers: tuple[str, ...] = ()
    path: Optional[Path] = field(default=None, compare=False)

    @property
    def terminal(self) -> str:
        """The primary grammar terminal (the first of ``terminals``)."""
        return self.terminals[0]

    def params_for(self, terminal: Optional[str] = None) -> dict[str, Any]:
        """The paper's parameter values for ``terminal`` (default: the primary one); {} if none."""
        terminal = terminal or self.terminal
        if terminal not in self.terminals:
            raise UnknownCardError(f"card {self.name!r} does not cover terminal {terminal!r}; "
                                   f"it covers {list(self.terminals)}")
        if len(self.terminals) == 1:
            return dict(self.parameters)
        return dict(self.parameters.get(terminal) or {})


def _fail(path: Path, message: str) -> CardFormatError:
    return CardFormatError(f"{path}: {message}; fix the card (fields: see nerfify_ns/knowledge/cards.py)")


def _strings(path: Path, value: Any, what: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise _fail(path, f"{what} must be a list of strings")
    return tuple(value)


def _mapping(path: Path, value: Any, what: str, required: tuple[str, ...]) -> dict:
    if not isinstance(value, dict):
        raise _fail(path, f"{what} must be a mapping with {', '.join(required)}")
    missing = [k for k in required if k not in value]
    if missing:
        raise _fail(path, f"{what} lacks {', '.join(missing)}")
    return value


def parse_card(data: Any, path: Path) -> Card:
    """A ``Card`` from the YAML mapping of ``path``; raises ``CardFormatError``."""
    if not isinstance(data, dict):
        raise _fail(path, "a card must be a YAML mapping")
    missing = [k for k in REQUIRED_FIELDS if k not in data]
    if "terminal" not in data and "terminals" not in data:
        missing.append("terminal (or terminals)")
    if missing:
        raise _fail(path, f"missing field(s) {', '.join(missing)}")
    name = data["name"]
    if name != path.stem:
        raise _fail(path, f"name {name!r} differs from the file stem {path.stem!r}")
    if "terminal" in data and "terminals" in data:
        raise _fail(path, "give either terminal or terminals, not both")
    terminals = (data["terminal"],) if "terminal" in data else _strings(path, data["terminals"], "terminals")
    if not terminals or not all(isinstance(t, str) and t for t in terminals):
        raise _fail(path, "terminal(s) must be non-empty strings")
    aliases = _strings(path, data["aliases"], "aliases")
    if any(a != a.lower() for a in aliases):
        raise _fail(path, "aliases must be lower-case")
    for a in aliases:
        try:
            alias_pattern(a)
        except ValueError as exc:
            raise _fail(path, str(exc)) from exc
    paper = _mapping(path, data["paper"], "paper", PAPER_FIELDS)
    equation = _mapping(path, data["equation"], "equation", EQUATION_FIELDS)
    signals = _mapping(path, data["signals"], "signals", SIGNAL_FIELDS)
    parameters = data["parameters"] if data["parameters"] is not None else {}
    if not isinstance(parameters, dict):
        raise _fail(path, "parameters must be a mapping")
    if len(terminals) > 1:
        extra = [k for k in parameters if k not in terminals]
        if extra or not all(isinstance(v, dict) or v is None for v in parameters.values()):
            raise _fail(path, "a card with several terminals keys parameters by terminal "
                              f"({list(terminals)}); "
                              f"got {extra or list(parameters)}")
    for key in ("title", "production", "implementation"):
        if not isinstance(data[key], str) or not data[key]:
            raise _fail(path, f"{key} must be a non-empty string")
    if not isinstance(equation["latex"], str) or not isinstance(equation["text"], str):
        raise _fail(path, "equation.latex and equation.text must be strings")
    year = paper["year"]
    arxiv = paper["arxiv"]
    return Card(
        name=name,
        title=data["title"],
        aliases=aliases,
        paper=PaperRef(title=str(paper["title"]), authors=_strings(path, paper["authors"], "paper.authors"),
                       year=int(year) if year is not None else None,
                       venue=None if paper["venue"] is None else str(paper["venue"]),
                       arxiv=None if arxiv is None else str(arxiv)),
        production=data["production"],
        terminals=terminals,
        parameters=parameters,
        equation=Equation(ref=None if equation["ref"] is None else str(equation["ref"]),
                          latex=equation["latex"], text=equation["text"]),
        implementation=data["implementation"],
        signals=Signals(hyperparameters=_strings(path, signals["hyperparameters"], "signals.hyperparameters"),
                        equations=_strings(path, signals["equations"], "signals.equations"),
                        phrases=_strings(path, signals["phrases"], "signals.phrases")),
        requires=_strings(path, data["requires"], "requires"),
        notes=str(data.get("notes") or ""),
        related_papers=_strings(path, data.get("related_papers"), "related_papers"),
        path=path,
    )


def load_card_file(path: Path) -> Card:
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise _fail(Path(path), f"invalid YAML ({exc})") from exc
    return parse_card(data, Path(path))


@lru_cache(maxsize=8)
def _load_cards_cached(directory: str) -> tuple[tuple[str, Card], ...]:
    folder = Path(directory)
    if not folder.is_dir():
        raise CardFormatError(f"no cards folder at {folder}; reinstall nerfify-ns")
    cards = [load_card_file(p) for p in sorted(folder.glob("*.yaml"))]
    return tuple((c.name, c) for c in cards)


def load_cards(directory: Optional[Path] = None) -> dict[str, Card]:
    """Every card, by name (loaded once per folder, then cached)."""
    return dict(_load_cards_cached(str(Path(directory or CARDS_DIR).resolve())))


def card(name: str) -> Card:
    """The card called ``name``; raises ``UnknownCardError``."""
    cards = load_cards()
    try:
        return cards[name]
    except KeyError:
        known = ", ".join(sorted(cards))
        raise UnknownCardError(f"no knowledge card named {name!r}; known cards: {known}") from None


def cards_for_terminal(terminal: str) -> list[Card]:
    """Cards covering grammar terminal ``terminal`` (primary terminal first)."""
    found = [c for c in load_cards().values() if terminal in c.terminals]
    return sorted(found, key=lambda c: (c.terminal != terminal, c.name))


@dataclass(frozen=True)
class AliasMatch:
    """One alias found in a text: the card, the alias, and the span in the text."""

    card: Card
    alias: str
    start: int
    end: int


def match_aliases(text: str) -> list[AliasMatch]:
    """Every card alias occurring in ``text`` (whole words, case-insensitive, hyphen/space tolerant,
    optional plural), ordered by position; overlapping hits are all kept."""
    hits: list[AliasMatch] = []
    for c in load_cards().values():
        for alias in c.aliases:
            for m in alias_pattern(alias).finditer(text):
                hits.append(AliasMatch(card=c, alias=alias, start=m.start(), end=m.end()))
    hits.sort(key=lambda h: (h.start, -(h.end - h.start), h.card.name))
    return hits


def find_by_alias(text: str) -> list[Card]:
    """The cards whose aliases occur in ``text``, each once, in order of first occurrence.

    Where aliases overlap the longest wins ("integrated positional encoding" is not also
    "positional encoding")."""
    spans = [(h.start, h.end, h.card) for h in match_aliases(text)]
    seen: dict[str, Card] = {}
    for _, _, c in longest_non_overlapping(spans):
        seen.setdefault(c.name, c)
    return list(seen.values())
