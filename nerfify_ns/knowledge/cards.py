"""Technique cards: one YAML file per technique in ``cards/`` (the file stem is the card name)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns.knowledge.errors import CardFormatError, UnknownCardError
from nerfify_ns.knowledge.text import alias_pattern, longest_non_overlapping

CARDS_DIR = Path(__file__).resolve().parent / "cards"

REQUIRED_FIELDS = ("name", "title", "aliases", "paper", "production", "parameters", "equation",
                   "signals", "requires")
TERMINAL_FIELDS = ("implementation", "defaults", "params", "contract", "code")
"""What a card must not say: how a technique is implemented, its defaults and contract live in its terminal
(``nerfify_ns/registry/terminals/``), the one home; a card states paper knowledge only."""
PAPER_FIELDS = ("title", "authors", "year", "venue", "arxiv")
"""A card's ``paper`` may also give ``key``: its key among the known papers where ``papers.yaml`` lacks it."""
EQUATION_FIELDS = ("ref", "latex", "text")
SIGNAL_FIELDS = ("hyperparameters", "equations", "phrases")


@dataclass(frozen=True)
class PaperRef:
    """The paper that introduced a technique."""

    title: str
    authors: tuple[str, ...]
    year: int | None
    venue: str | None
    arxiv: str | None
    key: str | None = None


@dataclass(frozen=True)
class Equation:
    """The technique's key equation: where it is in the paper, LaTeX and a plain-text form."""

    ref: str | None
    latex: str
    text: str
    canonical: tuple[str, ...] = ()
    """Further forms of the equation, written so the equation compiler's parser reads them (a sum written out
    for one band, the integral's quadrature): what a paper's equation is matched against, by structure."""


@dataclass(frozen=True)
class Signals:
    """What reveals the technique in a paper's text."""

    hyperparameters: tuple[str, ...]
    equations: tuple[str, ...]
    phrases: tuple[str, ...]


@dataclass(frozen=True)
class HyperparameterMap:
    """How a hyperparameter the paper states (a name of ``nerfify_ns/paper/hyperparams.yaml``) sets a
    parameter of the card's terminal.

    ``value`` is an expression of ``value`` (the paper's number) and the terminal's current parameters
    (``plan_from_paper.evaluate`` reads it; None = skip); ``also`` derives further parameters the same
    way; ``qualifiers`` are the statement qualifiers accepted, in order of preference ("" = none);
    ``sentence`` a regular expression the statement must match; ``together`` hyperparameters that must
    be stated in the same sentence (the entries are then applied as one); ``card_used`` only when the
    paper itself is found to use the card (a bare "8 layers" may be any network of the paper)."""

    name: str
    param: str
    value: str = "value"
    also: tuple[tuple[str, str], ...] = ()
    qualifiers: tuple[str, ...] = ()
    sentence: str = ""
    together: tuple[str, ...] = ()
    card_used: bool = False

    @property
    def grouped(self) -> bool:
        """Whether it changes several parameters at once (applied to the terminal as a whole)."""
        return bool(self.also or self.together)


@dataclass(frozen=True)
class Card:
    """A NeRF technique as papers state it: what it is called, who introduced it, its equation, what reveals it
    in a paper, where it goes in the grammar. How it is implemented (class, defaults, contract) is its terminal's.

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
    signals: Signals
    requires: tuple[str, ...]
    notes: str = ""
    related_papers: tuple[str, ...] = ()
    path: Path | None = field(default=None, compare=False)
    hyperparameters: Mapping[str, tuple[HyperparameterMap, ...]] = field(default_factory=dict, compare=False)
    implements_equation: bool = True
    equation_slot: str | None = None
    hyperparameter_patterns: Mapping[str, Mapping[str, Any]] = field(default_factory=dict, compare=False)
    """How papers state the hyperparameters this technique introduces: name -> ``patterns`` (regular expressions
    with ``{num}`` / ``{int}``), ``unit``, ``self_qualified`` (the name says which part it sets: no coarse/fine
    qualifier is read after it), ``signals`` (a paper stating it signals the card, as ``detect.yaml``'s
    ``hyperparameter_cards``). ``paper/hyperparams.py`` reads them beside the generic ``hyperparams.yaml``."""
    notation: Mapping[str, str] = field(default_factory=dict, compare=False)
    """The notation of the card's equation: symbol name -> role of ``synthesis/novel/notation.yaml``."""
    hosted_in: Mapping[str, Mapping[str, Any]] = field(default_factory=dict, compare=False)
    """Where the technique also lives inside another part, as that part's parameters: terminal -> {param: value}
    (K-Planes as the encoding of a deformation of Gaussians). A plan without the card's own slot that holds such a
    part gets the technique there."""

    @property
    def terminal(self) -> str:
        """The primary grammar terminal (the first of ``terminals``)."""
        return self.terminals[0]

    def params_for(self, terminal: str | None = None) -> dict[str, Any]:
        """The paper's parameter values for ``terminal`` (default: the primary one); {} if none."""
        terminal = terminal or self.terminal
        if terminal not in self.terminals:
            raise UnknownCardError(f"card {self.name!r} does not cover terminal {terminal!r}; "
                                   f"it covers {list(self.terminals)}")
        if len(self.terminals) == 1:
            return dict(self.parameters)
        return dict(self.parameters.get(terminal) or {})

    def hyperparameters_for(self, terminal: str | None = None) -> tuple[HyperparameterMap, ...]:
        """How the paper's hyperparameters set ``terminal``'s parameters (in order of priority)."""
        return tuple(self.hyperparameters.get(terminal or self.terminal, ()))


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


HYPERPARAMETER_FIELDS = ("param", "value", "also", "qualifiers", "sentence", "together", "card_used")


def _hyperparameter(path: Path, name: str, raw: Any, terminal: str) -> HyperparameterMap:
    """One entry of a card's ``hyperparameters``: ``name: param`` or ``name: {param: ..., value: ...}``."""
    if isinstance(raw, str):
        raw = {"param": raw}
    if not isinstance(raw, dict) or not isinstance(raw.get("param"), str):
        raise _fail(path, f"hyperparameters.{terminal}.{name} must be a parameter name or a mapping with 'param'")
    unknown = [k for k in raw if k not in HYPERPARAMETER_FIELDS]
    if unknown:
        raise _fail(path, f"hyperparameters.{terminal}.{name}: unknown field(s) {', '.join(unknown)} "
                          f"(known: {', '.join(HYPERPARAMETER_FIELDS)})")
    also = raw.get("also") or {}
    if not isinstance(also, dict) or not all(isinstance(v, str) for v in also.values()):
        raise _fail(path, f"hyperparameters.{terminal}.{name}.also must map parameters to expressions")
    qualifiers = raw.get("qualifiers") or []
    if not isinstance(qualifiers, list):
        raise _fail(path, f"hyperparameters.{terminal}.{name}.qualifiers must be a list")
    return HyperparameterMap(name=name, param=raw["param"], value=str(raw.get("value") or "value"),
                             also=tuple((str(k), v) for k, v in also.items()),
                             qualifiers=tuple(str(q or "") for q in qualifiers),
                             sentence=str(raw.get("sentence") or ""),
                             together=_strings(path, raw.get("together"), f"hyperparameters.{name}.together"),
                             card_used=bool(raw.get("card_used", False)))


def _hyperparameters(path: Path, raw: Any, terminals: tuple[str, ...]) -> dict[str, tuple[HyperparameterMap, ...]]:
    """A card's ``hyperparameters``, keyed by terminal (a one-terminal card may leave the terminal out)."""
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise _fail(path, "hyperparameters must be a mapping")
    by_terminal = raw if len(terminals) > 1 or set(raw) <= set(terminals) else {terminals[0]: raw}
    extra = [k for k in by_terminal if k not in terminals]
    if extra:
        raise _fail(path, f"hyperparameters of a card with several terminals are keyed by terminal "
                          f"({list(terminals)}); got {extra}")
    out = {}
    for terminal, entries in by_terminal.items():
        if not isinstance(entries, dict):
            raise _fail(path, f"hyperparameters.{terminal} must map hyperparameter names to parameters")
        out[terminal] = tuple(_hyperparameter(path, str(n), v, terminal) for n, v in entries.items())
    return out


def parse_card(data: Any, path: Path) -> Card:
    """A ``Card`` from the YAML mapping of ``path``; raises ``CardFormatError``."""
    if not isinstance(data, dict):
        raise _fail(path, "a card must be a YAML mapping")
    misplaced = [k for k in TERMINAL_FIELDS if k in data]
    if misplaced:
        raise _fail(path, f"{', '.join(misplaced)} belong(s) to the terminal (nerfify_ns/registry/terminals/), "
                          "not to the card")
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
    for key in ("title", "production"):
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
                       arxiv=None if arxiv is None else str(arxiv),
                       key=None if paper.get("key") is None else str(paper["key"])),
        production=data["production"],
        terminals=terminals,
        parameters=parameters,
        equation=Equation(ref=None if equation["ref"] is None else str(equation["ref"]),
                          latex=equation["latex"], text=equation["text"],
                          canonical=_strings(path, equation.get("canonical") or [], "equation.canonical")),
        signals=Signals(hyperparameters=_strings(path, signals["hyperparameters"], "signals.hyperparameters"),
                        equations=_strings(path, signals["equations"], "signals.equations"),
                        phrases=_strings(path, signals["phrases"], "signals.phrases")),
        requires=_strings(path, data["requires"], "requires"),
        notes=str(data.get("notes") or ""),
        related_papers=_strings(path, data.get("related_papers"), "related_papers"),
        path=path,
        hyperparameters=_hyperparameters(path, data.get("hyperparameters"), terminals),
        implements_equation=bool(data.get("implements_equation", True)),
        equation_slot=None if data.get("equation_slot") is None else str(data["equation_slot"]),
        hyperparameter_patterns=_patterns(path, data.get("hyperparameter_patterns")),
        notation=_notation(path, data.get("notation")),
        hosted_in=_hosted_in(path, data.get("hosted_in")),
    )


def _hosted_in(path: Path, raw: Any) -> dict[str, dict]:
    if raw is None:
        return {}
    if not isinstance(raw, dict) or not all(isinstance(k, str) and isinstance(v, dict) for k, v in raw.items()):
        raise _fail(path, "hosted_in must map a terminal to the parameters that make it host the technique")
    return {k: dict(v) for k, v in raw.items()}


def _patterns(path: Path, raw: Any) -> dict[str, dict]:
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise _fail(path, "hyperparameter_patterns must map a hyperparameter name to its patterns")
    out = {}
    for name, entry in raw.items():
        if not isinstance(entry, dict) or not _strings(path, entry.get("patterns"), f"{name}.patterns"):
            raise _fail(path, f"hyperparameter_patterns.{name} needs a list of patterns")
        out[str(name)] = {"patterns": list(entry["patterns"]), "unit": str(entry.get("unit") or ""),
                          "self_qualified": bool(entry.get("self_qualified", False)),
                          "signals": bool(entry.get("signals", False))}
    return out


def _notation(path: Path, raw: Any) -> dict[str, str]:
    if raw is None:
        return {}
    if not isinstance(raw, dict) or not all(isinstance(v, str) for v in raw.values()):
        raise _fail(path, "notation must map a symbol name to a role")
    return {str(k): v for k, v in raw.items()}


def load_card_file(path: Path) -> Card:
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise _fail(Path(path), f"invalid YAML ({exc})") from exc
    return parse_card(data, Path(path))


def read_cards(directory: Path | str = CARDS_DIR) -> dict[str, Card]:
    """Every card of the folder ``directory``, by name (read now: no cache; a ``KnowledgeBase`` keeps them)."""
    folder = Path(directory)
    if not folder.is_dir():
        raise CardFormatError(f"no cards folder at {folder}; reinstall nerfify-ns (or give a folder with cards/)")
    return {c.name: c for c in (load_card_file(p) for p in sorted(folder.glob("*.yaml")))}


def _default_cards() -> dict[str, Card]:
    from nerfify_ns.knowledge.kb import KnowledgeBase

    return KnowledgeBase.default().cards


def load_cards(directory: Path | None = None) -> dict[str, Card]:
    """Every card, by name: the default knowledge base's (a copy), or those of ``directory`` (read now)."""
    return read_cards(directory) if directory is not None else dict(_default_cards())


def card(name: str, cards: Mapping[str, Card] | None = None) -> Card:
    """The card called ``name`` (of ``cards``, default: the default knowledge base); raises ``UnknownCardError``."""
    cards = _default_cards() if cards is None else cards
    try:
        return cards[name]
    except KeyError:
        known = ", ".join(sorted(cards))
        raise UnknownCardError(f"no knowledge card named {name!r}; known cards: {known}") from None


def card_notation(directory: Path | str = CARDS_DIR) -> dict[str, dict[str, str]]:
    """The notation of every card's equation that states one (card name -> symbol name -> role)."""
    return {c.name: dict(c.notation) for c in read_cards(directory).values() if c.notation}


def cards_for_terminal(terminal: str, cards: Mapping[str, Card] | None = None) -> list[Card]:
    """Cards covering grammar terminal ``terminal`` (primary terminal first)."""
    cards = _default_cards() if cards is None else cards
    found = [c for c in cards.values() if terminal in c.terminals]
    return sorted(found, key=lambda c: (c.terminal != terminal, c.name))


@dataclass(frozen=True)
class AliasMatch:
    """One alias found in a text: the card, the alias, and the span in the text."""

    card: Card
    alias: str
    start: int
    end: int


def match_aliases(text: str, cards: Iterable[Card] | None = None) -> list[AliasMatch]:
    """Every card alias occurring in ``text`` (whole words, case-insensitive, hyphen/space tolerant,
    optional plural), ordered by position; overlapping hits are all kept."""
    hits: list[AliasMatch] = []
    for c in (_default_cards().values() if cards is None else cards):
        for alias in c.aliases:
            for m in alias_pattern(alias).finditer(text):
                hits.append(AliasMatch(card=c, alias=alias, start=m.start(), end=m.end()))
    hits.sort(key=lambda h: (h.start, -(h.end - h.start), h.card.name))
    return hits


def find_by_alias(text: str, cards: Iterable[Card] | None = None) -> list[Card]:
    """The cards whose aliases occur in ``text``, each once, in order of first occurrence.

    Where aliases overlap the longest wins ("integrated positional encoding" is not also
    "positional encoding")."""
    spans = [(h.start, h.end, h.card) for h in match_aliases(text, cards)]
    seen: dict[str, Card] = {}
    for _, _, c in longest_non_overlapping(spans):
        seen.setdefault(c.name, c)
    return list(seen.values())
