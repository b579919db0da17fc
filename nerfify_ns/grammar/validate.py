"""``validate(plan)``: accept exactly the derivations of the grammar, name the rule that breaks.

A plan is a derivation of ``Method`` plus annotations (method name, paper, evidence, pruned parts,
holes, notes). Checking runs in two passes: the structure (slots, alternatives, parameter types
and ranges) and then the duties of every terminal used and the optimiser-group rule.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nerfify_ns.errors import NerfifyError
from nerfify_ns.grammar.spec import CUSTOM, CUSTOM_MEMBER, Grammar, Nonterminal, Param, Terminal, load_grammar
from nerfify_ns.plan import method_name_problems

METHOD_NAME = re.compile(r"^[a-z][a-z0-9-]{1,62}\Z")  # \Z: "$" would also match before a final newline
ANNOTATIONS: dict[str, type] = {
    "method": str, "description": str, "paper": dict, "evidence": dict, "pruned": list, "holes": list,
    "notes": list, "repairs": list, "schedule": dict, "family": dict, "contributions": list,
}
IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*\Z")
MODULE = re.compile(r"^components\.[A-Za-z_][A-Za-z0-9_]*\Z")
"""A custom component's module: inside the plugin's ``components`` package."""
RESERVED_MODULES = frozenset(p.stem for p in (Path(__file__).resolve().parents[1] / "components").glob("*.py"))
"""Module names of nerfify's own components (copied into plugins): a custom module may not take one."""


@dataclass(frozen=True)
class Violation:
    """One broken rule: where in the plan, which production, which rule, and what to do."""

    path: str
    production: str
    rule: str
    message: str

    def __str__(self) -> str:
        return f"{self.path or '<plan>'}: {self.production}: {self.rule}: {self.message}"


class PlanError(NerfifyError):
    """The plan is not a derivation of the grammar."""

    def __init__(self, violations: list[Violation]) -> None:
        self.violations = violations
        more = f" (and {len(violations) - 1} more)" if len(violations) > 1 else ""
        super().__init__(f"invalid plan: {violations[0]}{more}")


@dataclass
class Derivation:
    """What a plan derives: the alternative chosen at each choice and the terminals used."""

    choices: dict[str, str] = field(default_factory=dict)
    used: dict[str, str] = field(default_factory=dict)
    violations: list[Violation] = field(default_factory=list)

    def fail(self, path: str, production: str, rule: str, message: str) -> None:
        self.violations.append(Violation(path, production, rule, message))


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _is_int(value: Any) -> bool:
    return (isinstance(value, int) and not isinstance(value, bool)) or (
        isinstance(value, float) and math.isfinite(value) and value.is_integer())


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _scalar_ok(param: Param, kind: str, value: Any) -> str | None:
    """None if ``value`` has ``kind``; otherwise what it should be."""
    checks = {"int": _is_int, "float": _is_number, "bool": lambda v: isinstance(v, bool),
              "str": lambda v: isinstance(v, str), "enum": lambda v: v in param.values}
    if not checks[kind](value):
        return f"one of {list(param.values)}" if kind == "enum" else f"a {kind}"
    return None


def _in_range(param: Param, value: Any) -> bool:
    lo, hi = param.range or (None, None)
    return (lo is None or value >= lo) and (hi is None or value <= hi)


def _json_like(value: Any, depth: int = 0) -> bool:
    """A value a plan may carry in a mapping parameter: numbers, strings, booleans, lists and mappings."""
    if depth > 8:
        return False
    if value is None or isinstance(value, bool | str) or _is_number(value):
        return True
    if isinstance(value, list):
        return all(_json_like(v, depth + 1) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and IDENTIFIER.match(k) and _json_like(v, depth + 1) for k, v in value.items())
    return False


def _check_param(d: Derivation, path: str, production: str, param: Param, value: Any) -> None:
    if param.type == "mapping":
        if not isinstance(value, dict) or not _json_like(value):
            d.fail(path, production, "param_type", f"{param.name} must be a mapping of identifiers to numbers, "
                   f"strings, booleans or lists, got {value!r}")
        return
    if param.type == "str_list":
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            d.fail(path, production, "param_type", f"{param.name} must be a list of strings, got {value!r}")
        elif param.length and not param.length[0] <= len(value) <= param.length[1]:
            d.fail(path, production, "param_length",
                   f"{param.name} must have {param.length[0]}..{param.length[1]} items")
        return
    if param.type in ("int_list", "float_list"):
        item_kind = param.type.split("_")[0]
        if not isinstance(value, list):
            d.fail(path, production, "param_type", f"{param.name} must be a list of {item_kind}s, got {value!r}")
            return
        lo, hi = param.length or (0, math.inf)
        if not lo <= len(value) <= hi:
            d.fail(path, production, "param_length", f"{param.name} must have {lo}..{hi} items, got {len(value)}")
        for item in value:
            if _scalar_ok(param, item_kind, item) is not None:
                d.fail(path, production, "param_type", f"{param.name} items must be {item_kind}s, got {item!r}")
            elif not _in_range(param, item):
                d.fail(path, production, "param_range", f"{param.name} item {item} outside {list(param.range)}")
        return
    expected = _scalar_ok(param, param.type, value)
    if expected is not None:
        d.fail(path, production, "param_type", f"{param.name} must be {expected}, got {value!r}")
    elif param.type in ("int", "float") and not _in_range(param, value):
        d.fail(path, production, "param_range", f"{param.name}={value} outside {list(param.range)}")


def _check_terminal(g: Grammar, d: Derivation, term: Terminal, value: Any, path: str) -> None:
    d.used[path] = term.name
    if not isinstance(value, dict):
        d.fail(path, term.name, "terminal_params", f"expected a mapping of {term.name}'s parameters, got {value!r}")
        return
    for name, item in value.items():
        param = term.params.get(name)
        if param is None:
            d.fail(path, term.name, "unknown_param",
                   f"{term.name} has no parameter {name!r} (it has: {', '.join(term.params) or 'none'})")
        else:
            _check_param(d, path, term.name, param, item)
    if term.name == CUSTOM:
        _check_custom(d, value, path)


def _check_custom(d: Derivation, value: dict, path: str) -> None:
    """A custom component names a module inside the plugin and a class: both must be identifiers."""
    module, cls = value.get("module"), value.get("class")
    if not isinstance(module, str) or not MODULE.match(module):
        d.fail(path, CUSTOM, "custom_component",
               f"module must be a module of the plugin's components package (e.g. components.my_head), got {module!r}")
    elif module.split(".")[1] in RESERVED_MODULES:
        d.fail(path, CUSTOM, "custom_component", f"module {module} would replace nerfify's own component "
               f"module of that name (reserved: {', '.join(sorted(RESERVED_MODULES))}); choose another name")
    if not isinstance(cls, str) or not IDENTIFIER.match(cls):
        d.fail(path, CUSTOM, "custom_component", f"class must be a Python class name, got {cls!r}")


def _check_mapping(d: Derivation, nt: Nonterminal, value: Any, path: str) -> bool:
    if isinstance(value, dict):
        return True
    d.fail(path, nt.name, "structure", f"{nt.name} must be a mapping, got {value!r}")
    return False


def _check_sequence(g: Grammar, d: Derivation, nt: Nonterminal, value: dict, path: str) -> None:
    names = {slot.name for slot in nt.slots}
    for key in value:
        if key not in names:
            d.fail(_join(path, key), nt.name, "unknown_slot",
                   f"{nt.name} has no slot {key!r} (slots: {', '.join(sorted(names))})")
    for slot in nt.slots:
        if slot.name in value:
            _check_symbol(g, d, slot.symbol, value[slot.name], _join(path, slot.name))
        elif not slot.optional:
            d.fail(_join(path, slot.name), nt.name, "missing_slot", f"{nt.name} requires slot {slot.name!r}")


def _check_choice(g: Grammar, d: Derivation, nt: Nonterminal, value: dict, path: str) -> None:
    if len(value) != 1:
        d.fail(path, nt.name, "choice_arity",
               f"{nt.name} takes exactly one of {list(nt.alternatives)}, got {list(value) or 'none'}")
        return
    (alt, inner), = value.items()
    if alt not in nt.alternatives:
        d.fail(path, nt.name, "unknown_alternative", f"{alt!r} is not an alternative of {nt.name} "
               f"(alternatives: {', '.join(nt.alternatives)})")
        return
    d.choices[path] = alt
    _check_symbol(g, d, alt, inner, _join(path, alt))


def _check_set(g: Grammar, d: Derivation, nt: Nonterminal, value: dict, path: str) -> None:
    allowed = nt.keys if nt.kind == "map" else nt.members
    for key, inner in value.items():
        if nt.custom and isinstance(key, str) and CUSTOM_MEMBER.match(key):
            _check_terminal(g, d, g.terminals[CUSTOM], inner, _join(path, key))
        elif key not in allowed:
            d.fail(_join(path, key), nt.name, "unknown_member",
                   f"{key!r} is not allowed in {nt.name} (allowed: {', '.join(allowed)})")
        else:
            _check_symbol(g, d, nt.value if nt.kind == "map" else key, inner, _join(path, key))


def _check_symbol(g: Grammar, d: Derivation, symbol: str, value: Any, path: str) -> None:
    if g.is_terminal(symbol):
        _check_terminal(g, d, g.terminals[symbol], value, path)
        return
    nt = g.nonterminals[symbol]
    if nt.kind == "enum":
        if value in nt.alternatives:
            d.choices[path] = value
            d.used[path] = value
        else:
            d.fail(path, nt.name, "unknown_alternative",
                   f"{value!r} is not an alternative of {nt.name} (alternatives: {', '.join(nt.alternatives)})")
        return
    if not _check_mapping(d, nt, value, path):
        return
    {"sequence": _check_sequence, "choice": _check_choice, "set": _check_set, "map": _check_set,
     "open": _check_open}[nt.kind](g, d, nt, value, path)


def _check_open(g: Grammar, d: Derivation, nt: Nonterminal, value: dict, path: str) -> None:
    """An open slot: its terminal's parameters, or ``{custom: {...}}`` (a component of the plugin)."""
    if set(value) == {CUSTOM}:
        d.choices[path] = CUSTOM
        _check_terminal(g, d, g.terminals[CUSTOM], value[CUSTOM], _join(path, CUSTOM))
    else:
        d.choices[path] = nt.terminal
        _check_terminal(g, d, g.terminals[nt.terminal], value, path)


# ---------------------------------------------------------------------------------- duties
def scene_flag(g: Grammar, plan: dict, flag: str) -> Any:
    """The value of a scene flag in ``plan``, its default when the plan leaves it out."""
    scene = plan.get("scene") if isinstance(plan.get("scene"), dict) else {}
    return scene.get(flag, g.terminals["scene"].params[flag].default)


def _duty_holds(g: Grammar, d: Derivation, plan: dict, duty: dict) -> str | None:
    """None if ``duty`` holds; else (rule, message)."""
    (rule, arg), = duty.items()
    if rule == "requires_base":
        base = d.choices.get("base")
        return None if base in arg else f"requires base in {arg}, the plan's base is {base!r}"
    if rule == "requires_loss":
        return None if f"model.losses.{arg}" in d.used else f"requires loss {arg!r}: add model.losses.{arg}"
    if rule == "requires_scene":
        bad = {flag: value for flag, value in arg.items() if scene_flag(g, plan, flag) != value}
        return None if not bad else f"requires a scene with {bad} (plan.scene says otherwise)"
    if rule == "requires_terminal":
        chosen = d.choices.get(arg["slot"])
        if chosen in arg["any_of"]:
            return None
        allowed = [a for a in arg["any_of"] if a is not None]
        if not allowed:
            return f"requires no {arg['slot']}, got {chosen!r}"
        return (f"requires {arg['slot']} to be one of {allowed}{' or absent' if None in arg['any_of'] else ''}, "
                f"got {chosen!r}")
    raise ValueError(f"unknown duty {rule}")


def expected_param_groups(g: Grammar, d: Derivation) -> list[str]:
    """The optimiser groups the model will have: the union of its terminals' param_groups."""
    groups = [grp for term in d.used.values() for grp in g.terminals[term].param_groups]
    return list(dict.fromkeys(groups))


def duties_at(g: Grammar, path: str, term: str) -> tuple:
    """The duties of the terminal used at ``path``: its own, and for a custom component its production's."""
    if term != CUSTOM:
        return g.terminals[term].duties
    interface = g.interfaces.get(g.production_at(path) or "")
    duties = getattr(interface, "duties", None) if interface is not None and not isinstance(interface, dict) \
        else (interface or {}).get("duties")
    return tuple(duties or ())


def _check_constraints(g: Grammar, d: Derivation, plan: dict) -> None:
    """Rules across a terminal's parameters (and the plan around it) that types and ranges cannot say."""
    for path, name in d.used.items():
        definition = g.terminals[name]
        if not definition.constraints:
            continue
        given = _at_path(plan, path)
        params = definition.with_defaults(given if isinstance(given, dict) else {})
        for constraint in definition.constraints:
            if not constraint.holds(params, plan):
                d.fail(path, name, "param_constraint", f"{name}: {constraint.doc}")


def _at_path(plan: dict, path: str) -> Any:
    node: Any = plan
    for key in path.split("."):
        node = node.get(key) if isinstance(node, dict) else None
    return node


def _check_duties(g: Grammar, d: Derivation, plan: dict) -> None:
    _check_constraints(g, d, plan)
    for path, term in d.used.items():
        for duty in duties_at(g, path, term):
            problem = _duty_holds(g, d, plan, duty)
            if problem:
                d.fail(path, term, next(iter(duty)), f"{term} {problem}")
    if isinstance(plan.get("optimizers"), dict):
        expected, actual = set(expected_param_groups(g, d)), set(plan["optimizers"])
        for group in sorted(expected - actual):
            d.fail(f"optimizers.{group}", "Optimizers", "param_groups",
                   f"the model has parameter group {group!r} but no optimiser for it")
        for group in sorted(actual - expected):
            d.fail(f"optimizers.{group}", "Optimizers", "param_groups",
                   f"optimiser for {group!r}, a parameter group the model does not have")


def _check_annotations(d: Derivation, plan: dict, installed: bool = True) -> dict:
    derivation = {}
    for key, value in plan.items():
        kind = ANNOTATIONS.get(key)
        if kind is None:
            derivation[key] = value
        elif not isinstance(value, kind):
            d.fail(key, "Plan", "annotation", f"{key} must be a {kind.__name__}, got {type(value).__name__}")
    name = plan.get("method")
    if not isinstance(name, str) or not METHOD_NAME.match(name):
        d.fail("method", "Plan", "method_name",
               f"method must be a lower-case name like 'kplanes-static' (a-z, 0-9, '-'), got {name!r}")
    elif installed:  # a valid project and import name that shadows nothing installed (validate only; not the exports)
        for rule, message in method_name_problems(name):
            d.fail("method", "Plan", rule, message)
    return derivation


def derive(plan: Any, grammar: Grammar | None = None, *, installed: bool = True) -> Derivation:
    """Check ``plan`` against the grammar and return what it derives with every violation found.
    ``installed=False`` leaves out the one check that looks at the Python environment (that the method's
    name shadows no installed module), for callers that check many edits of one plan and that name once."""
    g = grammar or load_grammar()
    d = Derivation()
    if not isinstance(plan, dict):
        d.fail("", "Plan", "structure", f"a plan is a mapping, got {type(plan).__name__}")
        return d
    _check_symbol(g, d, g.start, _check_annotations(d, plan, installed), "")
    if not d.violations:
        _check_duties(g, d, plan)
    return d


def check(plan: Any, grammar: Grammar | None = None) -> list[Violation]:
    return derive(plan, grammar).violations


def validate(plan: Any, grammar: Grammar | None = None) -> Derivation:
    """Accept a derivation of the grammar (returned) or raise PlanError naming the broken rules."""
    d = derive(plan, grammar)
    if d.violations:
        raise PlanError(d.violations)
    return d
