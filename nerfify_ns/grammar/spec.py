"""The grammar of Nerfstudio methods, loaded from ``grammar_spec.yaml`` into typed objects.

Nonterminal kinds: sequence (named slots), choice (one alternative, ``{alt: value}``), enum
(a parameterless terminal written as its name), set (a subset of member terminals) and map
(a subset of keys holding the same nonterminal). Terminals carry their implementation, typed
parameters, interface contract, duties and the optimiser groups they create.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Dict, Iterator, List, Optional, Tuple

import yaml

from nerfify_ns.data import grammar_spec_path
from nerfify_ns.errors import NerfifyError

KINDS = ("sequence", "choice", "enum", "set", "map")
PARAM_TYPES = ("int", "float", "bool", "str", "enum", "int_list", "float_list")


class GrammarSpecError(NerfifyError):
    """grammar_spec.yaml itself is inconsistent (a bug in the grammar, not in a plan)."""


@dataclass(frozen=True)
class Param:
    """A typed terminal parameter: type, inclusive range, allowed values, list length, default."""

    name: str
    type: str
    default: Any = None
    range: Optional[Tuple[Optional[float], Optional[float]]] = None
    values: Tuple[Any, ...] = ()
    length: Optional[Tuple[int, int]] = None
    doc: str = ""


@dataclass(frozen=True)
class Terminal:
    """A leaf of the grammar: one implementable technique or configuration block."""

    name: str
    doc: str
    implementation: str
    params: Dict[str, Param]
    card: Optional[str] = None
    contract: Dict[str, Any] = field(default_factory=dict)
    duties: Tuple[Dict[str, Any], ...] = ()
    param_groups: Tuple[str, ...] = ()
    config: Dict[str, Dict[str, str]] = field(default_factory=dict)
    config_class: Optional[str] = None
    input_domain: Optional[str] = None

    def defaults(self) -> Dict[str, Any]:
        return {name: p.default for name, p in self.params.items()}


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
    slots: Tuple[Slot, ...] = ()
    alternatives: Tuple[str, ...] = ()
    keys: Tuple[str, ...] = ()
    value: Optional[str] = None

    @property
    def members(self) -> Tuple[str, ...]:
        """The terminals a set may hold (stored as its alternatives)."""
        return self.alternatives


@dataclass(frozen=True)
class Grammar:
    start: str
    version: int
    nonterminals: Dict[str, Nonterminal]
    terminals: Dict[str, Terminal]
    source: str = ""

    def is_terminal(self, symbol: str) -> bool:
        return symbol in self.terminals

    def symbol_paths(self) -> Iterator[Tuple[str, str]]:
        """Every (plan path, symbol) the grammar can derive, e.g. ("model.sampler.proposal", "proposal")."""
        yield from _walk(self, self.start, "")

    def terminal_paths(self, terminal: str) -> List[str]:
        return [path for path, symbol in self.symbol_paths() if symbol == terminal]

    def slot_symbol(self, path: str) -> Optional[str]:
        """The symbol a plan path holds (None for unknown paths)."""
        return next((symbol for p, symbol in self.symbol_paths() if p == path), None)


def _walk(grammar: Grammar, symbol: str, path: str) -> Iterator[Tuple[str, str]]:
    yield path, symbol
    if grammar.is_terminal(symbol):
        return
    nt = grammar.nonterminals[symbol]
    join = (lambda key: f"{path}.{key}" if path else key)
    if nt.kind == "sequence":
        for slot in nt.slots:
            yield from _walk(grammar, slot.symbol, join(slot.name))
    elif nt.kind in ("choice", "set"):
        for alt in nt.alternatives:
            yield from _walk(grammar, alt, join(alt))
    elif nt.kind == "map":
        for key in nt.keys:
            yield from _walk(grammar, nt.value, join(key))


def _param(name: str, raw: dict, owner: str) -> Param:
    kind = raw.get("type")
    if kind not in PARAM_TYPES:
        raise GrammarSpecError(f"terminal {owner}: parameter {name} has unknown type {kind!r}")
    rng = raw.get("range")
    return Param(name=name, type=kind, default=raw.get("default"), doc=raw.get("doc", ""),
                 range=tuple(rng) if rng is not None else None,
                 values=tuple(raw.get("values", ())), length=tuple(raw["length"]) if "length" in raw else None)


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
        keys=tuple(raw.get("keys") or ()), value=raw.get("value"),
    )


def _terminal(name: str, raw: dict) -> Terminal:
    return Terminal(
        name=name, doc=raw.get("doc", ""), implementation=raw["implementation"],
        params={k: _param(k, v, name) for k, v in (raw.get("params") or {}).items()},
        card=raw.get("card"), contract=raw.get("contract") or {}, duties=tuple(raw.get("duties") or ()),
        param_groups=tuple(raw.get("param_groups") or ()), config=raw.get("config") or {},
        config_class=raw.get("config_class"), input_domain=raw.get("input_domain"),
    )


def _check_references(grammar: Grammar) -> None:
    known = set(grammar.nonterminals) | set(grammar.terminals)
    for nt in grammar.nonterminals.values():
        refs = [s.symbol for s in nt.slots] + list(nt.alternatives) + ([nt.value] if nt.value else [])
        for ref in refs:
            if ref not in known:
                raise GrammarSpecError(f"nonterminal {nt.name} refers to unknown symbol {ref!r}")
        if nt.kind in ("enum", "set") and any(r not in grammar.terminals for r in nt.alternatives):
            raise GrammarSpecError(f"{nt.kind} {nt.name} may only list terminals")


def parse_grammar(text: str, source: str = "") -> Grammar:
    raw = yaml.safe_load(text)
    grammar = Grammar(
        start=raw["start"], version=raw.get("version", 0), source=source,
        nonterminals={k: _nonterminal(k, v) for k, v in raw["nonterminals"].items()},
        terminals={k: _terminal(k, v) for k, v in raw["terminals"].items()},
    )
    _check_references(grammar)
    return grammar


@lru_cache(maxsize=4)
def load_grammar(path: Optional[str] = None) -> Grammar:
    """The grammar in ``path`` (default: the project's ``grammar_spec.yaml``)."""
    if path is None:
        return parse_grammar(grammar_spec_path().read_text(), "grammar_spec.yaml")
    return parse_grammar(Path(path).read_text(), str(path))
