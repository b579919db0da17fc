"""The registry: the productions (data) and the terminal definitions (code), checked for consistency."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

import yaml

from nerfify_ns.errors import NerfifyError
from nerfify_ns.registry.terminal import TerminalDef

SPEC_HEADER = """\
# The grammar of Nerfstudio methods. A nerfify plan is a derivation in it.
#
# GENERATED from the terminal registry (nerfify_ns/registry/: productions.yaml and terminals/*.py);
# do not edit by hand: `python -m nerfify_ns.registry` rewrites it, and a test fails when this file is
# stale. The grammar, the composer and the verification ladder read the registry itself.
#
# Terminals: production, implementation (a Nerfstudio class or one of nerfify_ns/components), card (the
# knowledge-base card of its technique), params (type, range, default = Nerfstudio's default, doc),
# contract (named tensors: symbolic shape, dtype, range, gradient, role; checked by the contract rung),
# code (what it renders into a plugin), cases (the stiff cases of the stability rung), duties and
# param_groups (the optimiser groups it creates). `config` maps params onto the base model's Nerfstudio
# config fields, per base. `interfaces`: what a `custom` component (a component of the plugin) of each
# production must implement.
#
# Duties (checked by validate, exported to JSON Schema and GBNF):
#   requires_base: [bases]                    only with these base models
#   requires_loss: name                       model.losses.<name> must be present
#   requires_scene: {flag: value}             plan.scene.<flag> must equal value
#   requires_terminal: {slot: path, any_of}   the choice at path must be one of these
# Global rule param_groups: the optimiser groups equal the union of the param_groups of the terminals
# used (no group missing, none extra). Parameter types: int, float, bool, str, enum (values), int_list /
# float_list / str_list (length, item range), mapping. A range of null means open.
"""


class RegistryError(NerfifyError):
    """The registry is inconsistent (a bug in a terminal definition or in productions.yaml)."""


@dataclass
class Registry:
    """Productions and terminals; ``registry[name]`` is a terminal's definition."""

    productions: dict[str, Any]
    terminals: dict[str, TerminalDef]
    interfaces: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, name: str) -> TerminalDef:
        return self.terminals[name]

    def __contains__(self, name: object) -> bool:
        return name in self.terminals

    def __iter__(self) -> Iterator[TerminalDef]:
        return iter(self.terminals.values())

    @property
    def nonterminals(self) -> dict[str, dict]:
        return self.productions["nonterminals"]

    def of_production(self, production: str) -> list[TerminalDef]:
        return [t for t in self.terminals.values() if t.production == production]

    def grammar_data(self) -> dict[str, Any]:
        """The grammar as data: what ``grammar_spec.yaml`` holds."""
        return {"version": self.productions["version"], "start": self.productions["start"],
                "nonterminals": self.nonterminals,
                "terminals": {name: t.to_grammar_data() for name, t in self.terminals.items()},
                "interfaces": {name: i.to_data() for name, i in self.interfaces.items()}}

    def export_yaml(self) -> str:
        """``grammar_spec.yaml``: the header, then the grammar data."""
        body = yaml.safe_dump(self.grammar_data(), sort_keys=False, width=110, allow_unicode=True,
                              default_flow_style=None)
        return SPEC_HEADER + body

    def check(self) -> None:
        """Raise RegistryError when the productions and the terminals do not fit (see :func:`check_references`)."""
        check_references(self.nonterminals, self.terminals, self.interfaces)


def check_references(nonterminals: dict[str, dict], terminals: dict[str, TerminalDef],
                     interfaces: dict[str, Any]) -> None:
    """The one reference check of a grammar, built from the registry or read back from its export: raise
    RegistryError when a symbol is unknown, an enum, set or open production lists a nonterminal, a terminal sits
    under the wrong production, or a production that accepts ``custom`` has no interface or no ``custom`` terminal."""
    known = set(nonterminals) | set(terminals)
    for name, nt in nonterminals.items():
        listed = list(nt.get("alternatives") or nt.get("members") or [])
        refs = [s.rstrip("?") for s in (nt.get("slots") or {}).values()]
        refs += listed + [r for r in (nt.get("value"), nt.get("terminal")) if r]
        for ref in refs:
            if ref not in known:
                raise RegistryError(f"production {name} refers to unknown symbol {ref!r}")
        if nt.get("kind") in ("enum", "set", "open") and any(r not in terminals for r in listed):
            raise RegistryError(f"{nt.get('kind')} {name} may only list terminals")
        custom = "custom" in listed or nt.get("custom") or nt.get("kind") == "open"
        if custom and name not in interfaces:
            raise RegistryError(f"production {name} accepts custom components but has no interface")
        if custom and "custom" not in terminals:
            raise RegistryError(f"{name} accepts custom components but the grammar has no 'custom' terminal")
    for name, t in terminals.items():
        if t.production != "*" and t.production not in nonterminals:
            raise RegistryError(f"terminal {name}: unknown production {t.production!r}")
        if t.production != "*" and not _listed(nonterminals[t.production], name):
            raise RegistryError(f"terminal {name} says production {t.production} but is not in it")


def _listed(nt: dict, name: str) -> bool:
    slots = [s.rstrip("?") for s in (nt.get("slots") or {}).values()]
    return name in (nt.get("alternatives") or []) or name in (nt.get("members") or []) \
        or name == nt.get("terminal") or name in slots


def build_registry(productions_text: str | None = None) -> Registry:
    """A registry from the productions (default: ``productions.yaml``) and every terminal module."""
    from nerfify_ns.registry.terminals import MODULES
    from nerfify_ns.registry.terminals.custom import INTERFACES

    text = productions_text or resources.files("nerfify_ns.registry").joinpath("productions.yaml").read_text()
    terminals: dict[str, TerminalDef] = {}
    for module in MODULES:
        for t in module.TERMINALS:
            if t.name in terminals:
                raise RegistryError(f"terminal {t.name} is defined twice")
            terminals[t.name] = t
    registry = Registry(productions=_with_declared(yaml.safe_load(text), terminals), terminals=terminals,
                        interfaces=dict(INTERFACES))
    registry.check()
    return registry


def _with_declared(productions: dict[str, Any], terminals: dict[str, TerminalDef]) -> dict[str, Any]:
    """The productions with every terminal that names a choice, enum or set production among its alternatives or
    members (after those ``productions.yaml`` lists, before ``custom``): a technique added as one terminal module
    declares its production and needs no edit of ``productions.yaml``."""
    for t in terminals.values():
        nt = productions["nonterminals"].get(t.production)
        if nt is None or nt.get("kind") not in ("choice", "enum", "set") or _listed(nt, t.name):
            continue
        key = "members" if "members" in nt else "alternatives"
        listed = list(nt.get(key) or [])
        at = listed.index("custom") if "custom" in listed else len(listed)
        nt[key] = [*listed[:at], t.name, *listed[at:]]
    return productions


_DEFAULT: list[Registry] = []


def default_registry() -> Registry:
    """The project's registry (built once: its definitions are code, fixed for the process)."""
    if not _DEFAULT:
        _DEFAULT.append(build_registry())
    return _DEFAULT[0]
