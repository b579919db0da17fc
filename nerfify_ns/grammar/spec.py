"""The grammar of Nerfstudio methods as typed objects, built from the terminal registry.

Nonterminal kinds: sequence (named slots), choice (one alternative, ``{alt: value}``), enum
(a parameterless terminal written as its name), set (a subset of member terminals; with ``custom``
also components of the plugin), map (a subset of keys holding the same nonterminal) and open (one
terminal's parameters, or ``{custom: {...}}``). A terminal is the registry's ``TerminalDef``: implementation,
typed parameters, contract, duties, the optimiser groups it creates, and (built from the registry) the code it
renders and the ladder's harness.
``grammar_spec.yaml`` is the registry's export; ``parse_grammar`` reads such an export back.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns.registry import Registry, RegistryError, TerminalDef, default_registry
from nerfify_ns.registry.core import check_references
from nerfify_ns.registry.params import ParamSpec, ParamTypeError
from nerfify_ns.registry.terminals.custom import CUSTOM, CUSTOM_MEMBER  # noqa: F401 - the grammar's names for them

KINDS = ("sequence", "choice", "enum", "set", "map", "open")

Param = ParamSpec
"""A typed terminal parameter (the registry's ParamSpec)."""


GrammarSpecError = RegistryError
"""The grammar itself is inconsistent (a bug in the grammar, not in a plan): the registry's error, since one
reference check (``registry.core.check_references``) serves the registry and the grammar read from its export."""

Terminal = TerminalDef
"""A leaf of the grammar, one implementable technique or configuration block: the registry's definition itself."""


@dataclass(frozen=True)
class Slot:
    """A named position in a sequence: the symbol it holds and whether it may be left out."""

    name: str
    symbol: str
    optional: bool


@dataclass(frozen=True)
class Nonterminal:
    name: str
    kind: str
    doc: str
    slots: tuple[Slot, ...] = ()
    alternatives: tuple[str, ...] = ()
    keys: tuple[str, ...] = ()
    value: str | None = None
    terminal: str | None = None
    """The terminal of an ``open`` nonterminal."""
    custom: bool = False
    """A set that also holds custom components."""

    @property
    def members(self) -> tuple[str, ...]:
        """The terminals a set may hold (stored as its alternatives)."""
        return self.alternatives

    @property
    def accepts_custom(self) -> bool:
        return self.kind == "open" or self.custom or CUSTOM in self.alternatives


@dataclass(frozen=True)
class Grammar:
    start: str
    version: int
    nonterminals: dict[str, Nonterminal]
    terminals: dict[str, Terminal]
    source: str = ""
    interfaces: dict[str, Any] = field(default_factory=dict, compare=False)

    def is_terminal(self, symbol: str) -> bool:
        return symbol in self.terminals

    def symbol_paths(self) -> Iterator[tuple[str, str]]:
        """Every (plan path, symbol) the grammar can derive, e.g. ("model.sampler.proposal", "proposal")."""
        yield from _walk(self, self.start, "")

    def terminal_paths(self, terminal: str) -> list[str]:
        return [path for path, symbol in self.symbol_paths() if symbol == terminal]

    def slot_symbol(self, path: str) -> str | None:
        """The symbol a plan path holds (None for unknown paths)."""
        return next((symbol for p, symbol in self.symbol_paths() if p == path), None)

    def production_at(self, path: str) -> str | None:
        """The production a terminal (or ``custom``) at ``path`` fills: the nonterminal whose alternative,
        member or open terminal it is (``model.sampler.custom`` -> ``Sampler``)."""
        parent = path.rsplit(".", 1)[0] if "." in path else ""
        for candidate in (parent, path):
            symbol = self.slot_symbol(candidate)
            if symbol in self.nonterminals and self.nonterminals[symbol].kind in ("choice", "set", "open"):
                return symbol
        return None

    def slot_of(self, path: str) -> str:
        """The slot a terminal path fills: the path of the choice or set around an alternative or member
        (``model.sampler.proposal`` -> ``model.sampler``), or the path itself for a sequence slot."""
        parent = path.rsplit(".", 1)[0] if "." in path else ""
        symbol = self.slot_symbol(parent) if parent else None
        if symbol in self.nonterminals and self.nonterminals[symbol].kind in ("choice", "open"):
            return parent
        return path


def _walk(grammar: Grammar, symbol: str, path: str) -> Iterator[tuple[str, str]]:
    yield path, symbol
    if grammar.is_terminal(symbol):
        return
    nt = grammar.nonterminals[symbol]
    def join(key):
        return f"{path}.{key}" if path else key
    if nt.kind == "sequence":
        for slot in nt.slots:
            yield from _walk(grammar, slot.symbol, join(slot.name))
    elif nt.kind in ("choice", "set"):
        for alt in nt.alternatives:
            yield from _walk(grammar, alt, join(alt))
        if nt.custom:
            yield join(CUSTOM), CUSTOM
    elif nt.kind == "map":
        for key in nt.keys:
            yield from _walk(grammar, nt.value, join(key))
    elif nt.kind == "open":
        yield path, nt.terminal
        yield join(CUSTOM), CUSTOM


def _slot(name: str, ref: str) -> Slot:
    return Slot(name=name, symbol=ref.rstrip("?"), optional=ref.endswith("?"))


def _nonterminal(name: str, raw: dict) -> Nonterminal:
    kind = raw.get("kind")
    if kind not in KINDS:
        raise GrammarSpecError(f"nonterminal {name}: unknown kind {kind!r}")
    return Nonterminal(
        name=name, kind=kind, doc=raw.get("doc", ""),
        slots=tuple(_slot(k, v) for k, v in (raw.get("slots") or {}).items()),
        alternatives=tuple(raw.get("alternatives") or raw.get("members") or ()),
        keys=tuple(raw.get("keys") or ()), value=raw.get("value"), terminal=raw.get("terminal"),
        custom=bool(raw.get("custom")),
    )


def _terminal(name: str, raw: dict) -> Terminal:
    try:
        return TerminalDef.from_data(name, raw)
    except ParamTypeError as exc:
        raise GrammarSpecError(str(exc)) from exc


def grammar_from_data(raw: dict, source: str = "", interfaces: dict | None = None) -> Grammar:
    grammar = Grammar(
        start=raw["start"], version=raw.get("version", 0), source=source,
        nonterminals={k: _nonterminal(k, v) for k, v in raw["nonterminals"].items()},
        terminals={k: _terminal(k, v) for k, v in raw["terminals"].items()},
        interfaces=dict(interfaces if interfaces is not None else raw.get("interfaces") or {}),
    )
    check_references(raw["nonterminals"], grammar.terminals, grammar.interfaces)
    return grammar


def parse_grammar(text: str, source: str = "") -> Grammar:
    """A grammar from YAML text (an export such as ``grammar_spec.yaml``)."""
    return grammar_from_data(yaml.safe_load(text), source)


def grammar_from_registry(registry: Registry) -> Grammar:
    """The grammar of a registry: its productions and the grammar view of every terminal definition."""
    grammar = Grammar(
        start=registry.productions["start"], version=registry.productions["version"], source="registry",
        nonterminals={k: _nonterminal(k, v) for k, v in registry.nonterminals.items()},
        terminals=dict(registry.terminals), interfaces=dict(registry.interfaces),
    )
    return grammar  # the registry checked its references when it was built


@lru_cache(maxsize=4)
def load_grammar(path: str | None = None) -> Grammar:
    """The project's grammar, built from the terminal registry; or the exported grammar in ``path``."""
    if path is None:
        return grammar_from_registry(default_registry())
    return parse_grammar(Path(path).read_text(), str(path))
