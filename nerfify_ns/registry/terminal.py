"""One grammar terminal, defined once: production, typed parameters, card, implementation, the code it
renders into a plugin, its contract as data, and how the ladder builds and runs it at small sizes.

The grammar's terminal *is* this class (``grammar.spec.Terminal``): the grammar built from the registry holds
the definitions themselves, and a grammar read back from its export (``grammar_spec.yaml``) holds definitions
rebuilt from the data (:meth:`TerminalDef.from_data`: parameters, contract, duties; no code or harness)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from nerfify_ns.registry.contract import Contract
from nerfify_ns.registry.params import ParamSpec, param_defaults, param_specs, params_class_from_data

Build = Callable[[dict[str, Any], dict[str, Any]], Any]
"""(small parameters, contract environment) -> the component (a module or a callable)."""
Call = Callable[[Any, dict[str, Any], dict[str, Any]], dict[str, Any]]
"""(component, example inputs by contract name, environment: sizes, parameters and ``case``) -> outputs by
contract name."""


@dataclass(frozen=True)
class Code:
    """What the terminal renders into a generated plugin.

    ``ctor`` is a Jinja2 expression over the parameters ``p`` building the component; ``expr`` is a
    Jinja2 expression evaluated in the plugin (``{{ x }}`` is its input where it has one; a
    regulariser's may use ``self``, ``outputs``, ``batch`` and ``{{ field }}``, the model's field); ``imports``
    are added to the file that uses it; ``component`` names a module of ``nerfify_ns/components`` copied into the
    plugin; ``traits`` are facts the templates read (``domain``, ``normalized_input``, ``times``, ...)."""

    imports: tuple[str, ...] = ()
    ctor: str | None = None
    expr: str | None = None
    component: str | None = None
    traits: dict[str, Any] = field(default_factory=dict)

    def to_data(self) -> dict:
        data = {k: v for k, v in (("imports", list(self.imports)), ("ctor", self.ctor), ("expr", self.expr),
                                  ("component", self.component)) if v}
        data.update(self.traits)
        return data


@dataclass(frozen=True)
class Constraint:
    """A rule across a terminal's parameters that types and ranges cannot say (``validate`` checks it;
    the JSON Schema and GBNF exports cannot express it, so constrained decoding relies on ``validate``)."""

    doc: str
    holds: Callable[[dict[str, Any], Mapping[str, Any]], bool]
    """(the terminal's parameters with defaults, the whole plan) -> whether the rule holds."""


def samples_rays(plan: Mapping[str, Any]) -> bool:
    """Whether the plan's model samples rays (it has a ``model.sampler``; a model of Gaussians rasterises whole
    images): the rule of the parts that read a field's samples or draw the training rays."""
    return bool((plan.get("model") or {}).get("sampler"))


@dataclass(frozen=True)
class Harness:
    """How the contract and stability rungs run the terminal at small sizes.

    ``build`` makes the component (default: evaluate ``code.ctor`` with its imports); ``call`` runs it on
    the example inputs (default: the component called with the inputs in contract order, its result
    named as the contract's single output); ``cases`` are the stiff cases that apply; ``small`` caps
    parameters for a quick run. ``in_model``: the terminal lives inside a Nerfstudio model and is
    checked through the assembled model only."""

    build: Build | None = None
    call: Call | None = None
    cases: tuple[str, ...] = ()
    small: dict[str, int] = field(default_factory=dict)
    in_model: bool = False


@dataclass(frozen=True)
class TerminalDef:
    """A grammar terminal and everything the stages need to know about it."""

    name: str
    production: str
    """The nonterminal this terminal is an alternative or member of (or whose slot it fills)."""
    params_class: type | None
    """The dataclass of the terminal's parameters (None: no parameters); ``params`` are its typed specs."""
    doc: str
    implementation: str
    """The Nerfstudio class or function, or the component of ours, that implements the technique."""
    card: str | None = None
    """The knowledge-base card of the technique."""
    contract: Contract = field(default_factory=Contract)
    code: Code = field(default_factory=Code)
    harness: Harness = field(default_factory=Harness)
    duties: tuple[dict[str, Any], ...] = ()
    param_groups: tuple[str, ...] = ()
    config: dict[str, dict[str, str]] = field(default_factory=dict)
    """Per base model: parameter -> field of the base's Nerfstudio model config."""
    config_class: str | None = None
    input_domain: str | None = None
    constraints: tuple[Constraint, ...] = ()
    """Rules across parameters (checked by ``validate`` on the parameters with defaults filled in)."""

    @property
    def params(self) -> dict[str, ParamSpec]:
        """The typed parameters, by name (read from ``params_class``; a fresh copy: callers may edit it)."""
        return param_specs(self.params_class) if self.params_class is not None else {}

    @property
    def param_specs(self) -> dict[str, ParamSpec]:
        return self.params

    def defaults(self) -> dict[str, Any]:
        """The parameters' defaults (a fresh copy: callers may edit it)."""
        return param_defaults(self.params_class) if self.params_class is not None else {}

    def with_defaults(self, given: Mapping[str, Any] | None) -> dict[str, Any]:
        """The terminal's parameters: the plan's values over the defaults."""
        return {**self.defaults(), **dict(given or {})}

    def small(self, given: Mapping[str, Any] | None) -> dict[str, Any]:
        """The parameters shrunk for a quick contract/stability run (the structure kept)."""
        p = self.with_defaults(given)
        for key, cap in self.harness.small.items():
            value = p.get(key)
            if isinstance(value, list):
                p[key] = [min(int(v), cap) for v in value]
            elif isinstance(value, int | float) and not isinstance(value, bool):
                p[key] = type(value)(min(value, cap))
        return p

    def to_grammar_data(self) -> dict:
        """The terminal as ``grammar_spec.yaml`` writes it (an export of this definition)."""
        data: dict[str, Any] = {"doc": self.doc, "production": self.production,
                                "implementation": self.implementation}
        for key in ("config_class", "card", "input_domain"):
            if getattr(self, key):
                data[key] = getattr(self, key)
        if self.param_groups:
            data["param_groups"] = list(self.param_groups)
        if self.params_class is not None:
            data["params"] = {name: spec.to_data() for name, spec in self.params.items()}
        if self.config:
            data["config"] = {k: dict(v) for k, v in self.config.items()}
        if not self.contract.empty:
            data["contract"] = self.contract.to_data()
        if self.duties:
            data["duties"] = [dict(d) for d in self.duties]
        if self.constraints:
            data["constraints"] = [c.doc for c in self.constraints]
        code = self.code.to_data()
        if code:
            data["code"] = code
        if self.harness.cases:
            data["cases"] = list(self.harness.cases)
        return data


    @classmethod
    def from_data(cls, name: str, raw: Mapping[str, Any]) -> TerminalDef:
        """A terminal from its export (``to_grammar_data``'s form): parameters, contract, duties, card; the code
        it renders and the ladder's harness are not exported (constraints come back as their docs only)."""
        code = dict(raw.get("code") or {})
        plain = {k: code.pop(k) for k in ("imports", "ctor", "expr", "component") if k in code}
        return cls(name=name, production=raw.get("production", ""), doc=raw.get("doc", ""),
                   params_class=params_class_from_data(name, raw["params"]) if "params" in raw else None,
                   implementation=raw["implementation"], card=raw.get("card"),
                   contract=Contract.from_data(raw.get("contract") or {}),
                   code=Code(imports=tuple(plain.get("imports") or ()), ctor=plain.get("ctor"), expr=plain.get("expr"),
                             component=plain.get("component"), traits=code),
                   harness=Harness(cases=tuple(raw.get("cases") or ())), duties=tuple(raw.get("duties") or ()),
                   param_groups=tuple(raw.get("param_groups") or ()), config=dict(raw.get("config") or {}),
                   config_class=raw.get("config_class"), input_domain=raw.get("input_domain"))


def replace(defn: TerminalDef, **changes: Any) -> TerminalDef:
    """A copy of ``defn`` with some fields changed (tests corrupt contracts with it)."""
    return dataclasses.replace(defn, **changes)
