"""The grammar of Nerfstudio methods as typed objects, built from the terminal registry.

Nonterminal kinds: sequence (named slots), choice (one alternative, ``{alt: value}``), enum
(a parameterless terminal written as its name), set (a subset of member terminals; with ``custom``
also components of the plugin), map (a subset of keys holding the same nonterminal) and open (one
terminal's parameters, or ``{custom: {...}}``). Terminals carry their implementation, typed
parameters, contract, duties and the optimiser groups they create; ``Terminal.definition`` is the
registry's definition (code, harness) where the grammar was built from the registry.
``grammar_spec.yaml`` is the registry's export; ``parse_grammar`` reads such an export back.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns.errors import NerfifyError
from nerfify_ns.registry import Registry, TerminalDef, default_registry
from nerfify_ns.registry.params import PARAM_TYPES, ParamSpec

KINDS = ("sequence", "choice", "enum", "set", "map", "open")
CUSTOM = "custom"
CUSTOM_MEMBER = re.compile(r"^custom(_[a-z0-9_]+)?$")
"""Keys of a set that hold custom components (``custom``, ``custom_memory``, ...)."""

Param = ParamSpec
"""A typed terminal parameter (the registry's ParamSpec)."""


class GrammarSpecError(NerfifyError):
    """The grammar itself is inconsistent (a bug in the grammar, not in a plan)."""


@dataclass(frozen=True)
class Terminal:
    """A leaf of the grammar: one implementable technique or configuration block."""

    name: str
    doc: str
    implementation: str
    params: dict[str, Param]
    card: str | None = None
    contract: dict[str, Any] = field(default_factory=dict)
    duties: tuple[dict[str, Any], ...] = ()
    param_groups: tuple[str, ...] = ()
    config: dict[str, dict[str, str]] = field(default_factory=dict)
    config_class: str | None = None
    input_domain: str | None = None
    production: str = ""
    definition: TerminalDef | None = field(default=None, compare=False, repr=False)

    def defaults(self) -> dict[str, Any]:
        return {name: p.default for name, p in self.params.items()}

    @classmethod
    def from_definition(cls, d: TerminalDef) -> Terminal:
        return cls(name=d.name, doc=d.doc, implementation=d.implementation, params=d.param_specs, card=d.card,
                   contract=d.contract.to_data() if not d.contract.empty else {}, duties=tuple(d.duties),
                   param_groups=tuple(d.param_groups), config={k: dict(v) for k, v in d.config.items()},
                   config_class=d.config_class, input_domain=d.input_domain, production=d.production, definition=d)


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


def _param(name: str, raw: dict, owner: str) -> Param:
    kind = raw.get("type")
    if kind not in PARAM_TYPES:
        raise GrammarSpecError(f"terminal {owner}: parameter {name} has unknown type {kind!r}")
    rng = raw.get("range")
    return Param(name=name, type=kind, default=raw.get("default"), doc=raw.get("doc", ""),
                 range=tuple(rng) if rng is not None else None,
                 values=tuple(raw.get("values", ())), length=tuple(raw["length"]) if "length" in raw else None)


def _terminal(name: str, raw: dict) -> Terminal:
    return Terminal(
        name=name, doc=raw.get("doc", ""), implementation=raw["implementation"],
        params={k: _param(k, v, name) for k, v in (raw.get("params") or {}).items()},
        card=raw.get("card"), contract=raw.get("contract") or {}, duties=tuple(raw.get("duties") or ()),
        param_groups=tuple(raw.get("param_groups") or ()), config=raw.get("config") or {},
        config_class=raw.get("config_class"), input_domain=raw.get("input_domain"),
        production=raw.get("production", ""),
    )


def _check_references(grammar: Grammar) -> None:
    known = set(grammar.nonterminals) | set(grammar.terminals)
    for nt in grammar.nonterminals.values():
        refs = [s.symbol for s in nt.slots] + list(nt.alternatives) + [r for r in (nt.value, nt.terminal) if r]
        for ref in refs:
            if ref not in known:
                raise GrammarSpecError(f"nonterminal {nt.name} refers to unknown symbol {ref!r}")
        if nt.kind in ("enum", "set", "open") and any(r not in grammar.terminals for r in nt.alternatives):
            raise GrammarSpecError(f"{nt.kind} {nt.name} may only list terminals")
        if nt.accepts_custom and CUSTOM not in grammar.terminals:
            raise GrammarSpecError(f"{nt.name} accepts custom components but the grammar has no 'custom' terminal")


def grammar_from_data(raw: dict, source: str = "", interfaces: dict | None = None) -> Grammar:
    grammar = Grammar(
        start=raw["start"], version=raw.get("version", 0), source=source,
        nonterminals={k: _nonterminal(k, v) for k, v in raw["nonterminals"].items()},
        terminals={k: _terminal(k, v) for k, v in raw["terminals"].items()},
        interfaces=dict(interfaces if interfaces is not None else raw.get("interfaces") or {}),
    )
    _check_references(grammar)
    return grammar


def parse_grammar(text: str, source: str = "") -> Grammar:
    """A grammar from YAML text (an export such as ``grammar_spec.yaml``)."""
    return grammar_from_data(yaml.safe_load(text), source)


def grammar_from_registry(registry: Registry) -> Grammar:
    """The grammar of a registry: its productions and the grammar view of every terminal definition."""
    grammar = Grammar(
        start=registry.productions["start"], version=registry.productions["version"], source="registry",
        nonterminals={k: _nonterminal(k, v) for k, v in registry.nonterminals.items()},
        terminals={name: Terminal.from_definition(d) for name, d in registry.terminals.items()},
        interfaces=dict(registry.interfaces),
    )
    _check_references(grammar)
    return grammar


@lru_cache(maxsize=4)
def load_grammar(path: str | None = None) -> Grammar:
    """The project's grammar, built from the terminal registry; or the exported grammar in ``path``."""
    if path is None:
        return grammar_from_registry(default_registry())
    return parse_grammar(Path(path).read_text(), str(path))
