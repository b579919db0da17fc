"""The grammar as a JSON Schema (draft 2020-12) of plans, duties included.

Structure: one ``$defs`` entry per nonterminal and terminal. Duties and the optimiser-group
rule become ``if``/``then``/``else`` clauses over "terminal T is used" predicates, so the schema
accepts exactly the plans ``validate`` accepts (see tests/test_grammar_exports.py).
"""

from __future__ import annotations

from typing import Any

from nerfify_ns.grammar.spec import CUSTOM, CUSTOM_MEMBER, Grammar, Param, Terminal, load_grammar
from nerfify_ns.grammar.validate import ANNOTATIONS, IDENTIFIER, METHOD_NAME, MODULE, duties_at

_JSON_TYPES = {str: "string", dict: "object", list: "array"}


def _number(param: Param, kind: str) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": kind}
    lo, hi = param.range or (None, None)
    if lo is not None:
        schema["minimum"] = lo
    if hi is not None:
        schema["maximum"] = hi
    return schema


def param_schema(param: Param) -> dict[str, Any]:
    if param.type == "int":
        return _number(param, "integer")
    if param.type == "float":
        return _number(param, "number")
    if param.type == "bool":
        return {"type": "boolean"}
    if param.type == "str":
        return {"type": "string"}
    if param.type == "enum":
        return {"enum": list(param.values)}
    if param.type == "str_list":
        schema = {"type": "array", "items": {"type": "string"}}
        if param.length:
            schema["minItems"], schema["maxItems"] = param.length
        return schema
    if param.type == "mapping":
        return {"type": "object", "propertyNames": {"pattern": IDENTIFIER.pattern}}
    item = _number(param, "integer" if param.type == "int_list" else "number")
    schema: dict[str, Any] = {"type": "array", "items": item}
    if param.length:
        schema["minItems"], schema["maxItems"] = param.length
    return schema


def _terminal_schema(term: Terminal) -> dict[str, Any]:
    schema = {"type": "object", "description": term.doc, "additionalProperties": False,
              "properties": {name: param_schema(p) for name, p in term.params.items()}}
    if term.name == CUSTOM:  # a module inside the plugin and a class name (validate checks the same)
        schema["properties"]["module"] = {"type": "string", "pattern": MODULE.pattern}
        schema["properties"]["class"] = {"type": "string", "pattern": IDENTIFIER.pattern}
        schema["required"] = ["module", "class"]
    return schema


def _ref(symbol: str) -> dict[str, str]:
    return {"$ref": f"#/$defs/{symbol}"}


def _nonterminal_schema(g: Grammar, name: str) -> dict[str, Any]:
    nt = g.nonterminals[name]
    if nt.kind == "enum":
        return {"enum": list(nt.alternatives), "description": nt.doc}
    if nt.kind == "choice":
        return {"description": nt.doc, "oneOf": [
            {"type": "object", "properties": {alt: _ref(alt)}, "required": [alt], "additionalProperties": False}
            for alt in nt.alternatives]}
    if nt.kind == "sequence":
        return {"type": "object", "description": nt.doc, "additionalProperties": False,
                "properties": {s.name: _ref(s.symbol) for s in nt.slots},
                "required": [s.name for s in nt.slots if not s.optional]}
    if nt.kind == "open":
        custom = {"type": "object", "properties": {CUSTOM: _ref(CUSTOM)}, "required": [CUSTOM],
                  "additionalProperties": False}
        return {"description": nt.doc, "oneOf": [custom, _ref(nt.terminal)]}
    keys = nt.keys if nt.kind == "map" else nt.members
    schema = {"type": "object", "description": nt.doc, "additionalProperties": False,
              "properties": {k: _ref(nt.value if nt.kind == "map" else k) for k in keys}}
    if nt.custom:
        schema["patternProperties"] = {CUSTOM_MEMBER.pattern: _ref(CUSTOM)}
    return schema


def _at(path: str, leaf: dict[str, Any]) -> dict[str, Any]:
    """A schema requiring ``path`` to exist and satisfy ``leaf`` at its end."""
    schema = leaf
    for key in reversed(path.split(".")):
        schema = {"type": "object", "required": [key], "properties": {key: schema}}
    return schema


def _used(g: Grammar, terminal: str) -> dict[str, Any]:
    """Predicate: ``terminal`` appears somewhere in the plan (as a slot, alternative or enum value)."""
    options = [_at(path, {}) for path in g.terminal_paths(terminal)]
    options += [_at(path, {"const": terminal}) for path in _enum_paths(g, terminal)]
    return {"anyOf": options} if options else {"not": {}}


def _enum_paths(g: Grammar, terminal: str) -> list[str]:
    return [path for path, symbol in g.symbol_paths()
            if symbol in g.nonterminals and g.nonterminals[symbol].kind == "enum"
            and terminal in g.nonterminals[symbol].alternatives]


def _choice_in(g: Grammar, slot: str, any_of: list[str]) -> dict[str, Any]:
    symbol = g.slot_symbol(slot)
    if symbol in g.nonterminals and g.nonterminals[symbol].kind == "enum":
        return _at(slot, {"enum": any_of})
    options = [_at(f"{slot}.{alt}", {}) for alt in any_of if alt is not None]
    if None in any_of:  # the slot may be absent
        options.append({"not": _at(slot, {})})
    return {"anyOf": options}


def _duty_schema(g: Grammar, duty: dict) -> dict[str, Any]:
    (rule, arg), = duty.items()
    if rule == "requires_base":
        return _choice_in(g, "base", list(arg))
    if rule == "requires_loss":
        return _at(f"model.losses.{arg}", {})
    if rule == "requires_terminal":
        return _choice_in(g, arg["slot"], list(arg["any_of"]))
    if rule == "requires_scene":
        clauses = []
        for flag, value in arg.items():
            default = g.terminals["scene"].params[flag].default
            leaf = {"type": "object", "properties": {flag: {"const": value}}}
            if value != default:
                leaf["required"] = [flag]
            clauses.append(_at("scene", leaf))
        return {"allOf": clauses}
    raise ValueError(f"unknown duty {rule}")


def _custom_duties(g: Grammar) -> list[dict[str, Any]]:
    """Duties of custom components, per production (e.g. a custom sampler only under some bases); in a set, any
    member named ``custom`` or ``custom_<name>`` carries them."""
    clauses = []
    for path, symbol in g.symbol_paths():
        if symbol != CUSTOM:
            continue
        parent = path.rsplit(".", 1)[0] if "." in path else ""
        kind = g.nonterminals.get(g.slot_symbol(parent) or "")
        if kind is not None and kind.kind == "set":
            some_custom = {"type": "object", "not": {"propertyNames": {"not": {"pattern": CUSTOM_MEMBER.pattern}}}}
            present = _at(parent, some_custom)
        else:
            present = _at(path, {})
        for duty in duties_at(g, path, CUSTOM):
            clauses.append({"if": present, "then": _duty_schema(g, duty)})
    return clauses


def _duties(g: Grammar) -> list[dict[str, Any]]:
    clauses = [{"if": _used(g, name), "then": _duty_schema(g, duty)}
               for name, term in g.terminals.items() for duty in term.duties]
    clauses += _custom_duties(g)
    for key in g.nonterminals["Optimizers"].keys:
        providers = [name for name, term in g.terminals.items() if key in term.param_groups]
        clauses.append({"if": {"anyOf": [_used(g, p) for p in providers]},
                        "then": _at(f"optimizers.{key}", {}),
                        "else": {"properties": {"optimizers": {"not": {"required": [key]}}}}})
    return clauses


def to_json_schema(grammar: Grammar | None = None) -> dict[str, Any]:
    """The JSON Schema of plans the grammar derives."""
    g = grammar or load_grammar()
    defs: dict[str, Any] = {name: _terminal_schema(t) for name, t in g.terminals.items()}
    defs.update({name: _nonterminal_schema(g, name) for name in g.nonterminals})
    start = g.nonterminals[g.start]
    properties = {s.name: _ref(s.symbol) for s in start.slots}
    properties.update({k: {"type": _JSON_TYPES[t]} for k, t in ANNOTATIONS.items()})
    properties["method"] = {"type": "string", "pattern": METHOD_NAME.pattern}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "nerfify plan",
        "description": f"A derivation of the nerfify grammar of Nerfstudio methods (version {g.version}).",
        "type": "object",
        "additionalProperties": False,
        "properties": properties,
        "required": ["method"] + [s.name for s in start.slots if not s.optional],
        "allOf": _duties(g),
        "$defs": defs,
    }
