"""The grammar as a GBNF grammar of plans (llama.cpp constrained decoding), duties included.

A plan is emitted as canonical compact JSON (``canonical_json``: keys in grammar order, no
whitespace). Duties tie distant parts of a plan together (a proposal sampler needs an interlevel
loss and a ``proposal_networks`` optimiser group, contraction needs an unbounded scene), which a
context-free grammar expresses by enumerating the *decision slots* (choices whose alternatives
carry duties or that duties refer to) and specialising the rules under each consistent context.
Identical specialised rules are shared (hash-consing), so the grammar stays small.

Integer ranges are exact (digit-range rules). Float ranges are enforced for their sign only: a
float outside its range but of the right sign is accepted here and rejected by ``validate``,
which constrained decoding runs afterwards.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from nerfify_ns.grammar.spec import CUSTOM, CUSTOM_MEMBER, Grammar, GrammarSpecError, Param, load_grammar
from nerfify_ns.grammar.validate import ANNOTATIONS, duties_at

ABSENT = None
_IDENT = '[A-Za-z_] [A-Za-z0-9_]*'
CUSTOM_NAMES = {"module": f'"\\"components." {_IDENT} "\\""', "class": f'"\\"" {_IDENT} "\\""'}
"""GBNF of a custom component's module (inside the plugin's components package) and class name."""
ROOT_HEAD = ("method", "description", "paper")
ROOT_TAIL = ("evidence", "pruned", "holes", "notes")

_PRELUDE = (r'string ::= "\"" ( [^"\\] | "\\" ( ["\\/bfnrt] | "u" [0-9a-fA-F] [0-9a-fA-F] [0-9a-fA-F] [0-9a-fA-F] ) )* '
            r'"\""' "\n" r'''number ::= "-"? unumber
unumber ::= ( "0" | [1-9] [0-9]* ) ( "." [0-9]+ )? ( [eE] [-+]? [0-9]+ )?
boolean ::= "true" | "false"
value ::= object | array | string | number | boolean | "null"
object ::= "{" ( string ":" value ( "," string ":" value )* )? "}"
array ::= "[" ( value ( "," value )* )? "]"
identkey ::= "\"" [A-Za-z_] [A-Za-z0-9_]* "\""
mapping ::= "{" ( identkey ":" value ( "," identkey ":" value )* )? "}"
methodname ::= "\"" [a-z] [a-z0-9-]{RANGE} "\""''')


def _lit(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


# ------------------------------------------------------------------------- canonical JSON
def _ordered(value: dict, order: Sequence[str]) -> list[str]:
    known = [k for k in order if k in value]
    return known + [k for k in value if k not in order]


def _param_value(param: Param | None, value: Any) -> Any:
    if param is not None and param.type in ("int", "int_list"):
        fix = lambda v: int(v) if isinstance(v, float) and v.is_integer() else v  # noqa: E731
        return [fix(v) for v in value] if isinstance(value, list) else fix(value)
    return value


def _canonical(g: Grammar, symbol: str | None, value: Any) -> Any:
    """``value`` re-ordered as the grammar orders ``symbol`` (unknown keys kept, at the end)."""
    if not isinstance(value, dict) or symbol is None:
        return value
    if symbol in g.terminals:
        params = g.terminals[symbol].params
        return {k: _param_value(params.get(k), value[k]) for k in _ordered(value, list(params))}
    nt = g.nonterminals[symbol]
    if nt.kind == "sequence":
        slots = {s.name: s.symbol for s in nt.slots}
        return {k: _canonical(g, slots.get(k), value[k]) for k in _ordered(value, list(slots))}
    if nt.kind in ("choice", "set"):
        def member(k: str) -> str | None:
            return k if k in nt.alternatives else (CUSTOM if nt.custom and CUSTOM_MEMBER.match(str(k)) else None)
        return {k: _canonical(g, member(k), value[k]) for k in _ordered(value, nt.alternatives)}
    if nt.kind == "open":
        if set(value) == {CUSTOM}:
            return {CUSTOM: _canonical(g, CUSTOM, value[CUSTOM])}
        return _canonical(g, nt.terminal, value)
    if nt.kind == "map":
        return {k: _canonical(g, nt.value if k in nt.keys else None, value[k]) for k in _ordered(value, nt.keys)}
    return value


def canonical_json(plan: dict, grammar: Grammar | None = None) -> str:
    """The compact JSON of ``plan`` in grammar order: what the GBNF grammar derives."""
    g = grammar or load_grammar()
    slots = [s.name for s in g.nonterminals[g.start].slots]
    order = [*ROOT_HEAD, *slots, *ROOT_TAIL]
    body = _canonical(g, g.start, {k: v for k, v in plan.items() if k not in ANNOTATIONS})
    ordered = {k: (body[k] if k in body else plan[k]) for k in _ordered(plan, order)}
    return json.dumps(ordered, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


# ------------------------------------------------------------------------- numbers
def _digit_range(lo: str, hi: str) -> str:
    """GBNF for the decimal strings of equal length between ``lo`` and ``hi``."""
    if lo == hi:
        return _lit(lo)
    if set(lo) == {"0"} and set(hi) == {"9"}:
        return " ".join(["[0-9]"] * len(lo))
    if len(lo) == 1:
        return f"[{lo}-{hi}]"
    rest = len(lo) - 1
    a, b = int(lo[0]), int(hi[0])
    if a == b:
        return f"{_lit(lo[0])} ( {_digit_range(lo[1:], hi[1:])} )"
    options = [f"{_lit(lo[0])} ( {_digit_range(lo[1:], '9' * rest)} )"]
    if b - a > 1:
        options.append(f"[{a + 1}-{b - 1}]" + " [0-9]" * rest)
    options.append(f"{_lit(hi[0])} ( {_digit_range('0' * rest, hi[1:])} )")
    return " | ".join(options)


def int_range(lo: int, hi: int) -> str:
    """GBNF matching exactly the canonical integers in [lo, hi] (0 <= lo <= hi)."""
    options = []
    for length in range(len(str(lo)), len(str(hi)) + 1):
        first = max(lo, 10 ** (length - 1) if length > 1 else 0)
        last = min(hi, 10 ** length - 1)
        if first <= last:
            options.append(f"( {_digit_range(str(first), str(last))} )")
    return " | ".join(options)


def _scalar(param: Param, kind: str) -> str:
    lo, hi = param.range or (None, None)
    if kind == "int":
        if lo is not None and hi is not None and lo >= 0:
            return f"( {int_range(math.ceil(lo), math.floor(hi))} )"
        return "unumber" if lo is not None and lo >= 0 else "number"
    return "unumber" if lo is not None and lo >= 0 else "number"


def _list(item: str, length: tuple[int, int] | None) -> str:
    lo, hi = length or (0, 16)
    optional = ""
    for _ in range(hi - max(lo, 1)):
        optional = f"( \",\" {item} {optional} )?"
    if lo == 0:
        return f"\"[\" ( {item} {optional} )? \"]\"" if hi > 0 else "\"[]\""
    required = " ".join([item] + [f"\",\" {item}"] * (lo - 1))
    return f"\"[\" {required} {optional} \"]\""


def param_rule(param: Param, item_rule: str | None = None) -> str:
    """GBNF of a parameter value; lists refer to ``item_rule`` (the rule of one item) when given."""
    if param.type == "bool":
        return "boolean"
    if param.type == "str":
        return "string"
    if param.type == "enum":
        return "( " + " | ".join(_lit(json.dumps(v)) for v in param.values) + " )"
    if param.type in ("int_list", "float_list"):
        return _list(item_rule or f"( {_scalar(param, param.type.split('_')[0])} )", param.length)
    if param.type == "str_list":
        return _list("string", param.length)
    if param.type == "mapping":
        return "mapping"
    return _scalar(param, param.type)


# ------------------------------------------------------------------------- contexts
@dataclass(frozen=True)
class _Effects:
    """What a context fixes: chosen alternatives, required/forbidden items, scene constants, groups."""

    ctx: tuple[tuple[str, Any], ...]
    required: frozenset
    forbidden: frozenset
    scene: tuple[tuple[str, Any], ...]
    groups: frozenset

    def choice(self, path: str) -> Any:
        return dict(self.ctx).get(path, "*")


def _slot_paths(g: Grammar) -> dict[str, tuple[str, bool]]:
    """Every choice/enum/optional-terminal slot path -> (symbol, optional)."""
    out: dict[str, tuple[str, bool]] = {}

    def walk(symbol: str, path: str) -> None:
        if symbol in g.terminals:
            return
        nt = g.nonterminals[symbol]
        def join(key):
            return f'{path}.{key}' if path else key
        if nt.kind == "sequence":
            for slot in nt.slots:
                out[join(slot.name)] = (slot.symbol, slot.optional)
                walk(slot.symbol, join(slot.name))
        elif nt.kind == "choice":
            for alt in nt.alternatives:
                walk(alt, join(alt))
    walk(g.start, "")
    return out


def _options(g: Grammar, symbol: str, optional: bool) -> list[Any]:
    if symbol in g.terminals:
        return [symbol, ABSENT] if optional else [symbol]
    alts = list(g.nonterminals[symbol].alternatives)
    return alts + ([ABSENT] if optional else [])


def _decision_paths(g: Grammar) -> list[str]:
    slots = _slot_paths(g)
    referenced = {"base"} | {d["requires_terminal"]["slot"] for t in g.terminals.values()
                             for d in t.duties if "requires_terminal" in d}
    decisions = set()
    for path, (symbol, optional) in slots.items():
        if symbol in g.nonterminals and g.nonterminals[symbol].kind not in ("choice", "enum"):
            continue
        alts = [a for a in _options(g, symbol, optional) if a in g.terminals]
        if path in referenced or any(g.terminals[a].duties or g.terminals[a].param_groups for a in alts):
            if symbol in g.terminals and not g.terminals[symbol].param_groups and not any(
                    "requires_loss" in d or "requires_scene" in d for d in g.terminals[symbol].duties):
                continue  # an optional terminal with only base/terminal duties is a dependent item
            decisions.add(path)
    for path in list(decisions):  # the choices a decision lies under are decisions too
        parts = path.split(".")
        for i in range(1, len(parts)):
            prefix = ".".join(parts[:i])
            if (prefix in slots and slots[prefix][0] in g.nonterminals
                    and g.nonterminals[slots[prefix][0]].kind == "choice"):
                decisions.add(prefix)
    return sorted(decisions, key=lambda p: (p.count("."), p))


def _active(path: str, ctx: dict[str, Any], decisions: list[str]) -> bool:
    parts = path.split(".")
    for i in range(1, len(parts)):
        prefix = ".".join(parts[:i])
        if prefix in decisions and ctx.get(prefix) != parts[i]:
            return False
    return True


def _holds(g: Grammar, duty: dict, ctx: dict[str, Any], scene: dict[str, Any] | None = None) -> bool | None:
    """Whether a base/terminal duty holds under ``ctx`` (None for duties that become effects); a scene duty holds
    when ``scene`` (the flags a context pins) gives every flag it names the value it needs."""
    (rule, arg), = duty.items()
    if rule == "requires_scene" and scene is not None and all(flag in scene for flag in arg):
        return all(scene[flag] == value for flag, value in arg.items())
    if rule == "requires_base":
        return ctx.get("base") in arg
    if rule == "requires_terminal":
        if arg["slot"] not in ctx:
            raise GrammarSpecError(f"GBNF export: requires_terminal on {arg['slot']}, which is not a decision slot")
        return ctx[arg["slot"]] in arg["any_of"]
    return None


def _contexts(g: Grammar) -> list[_Effects]:
    slots = _slot_paths(g)
    decisions = _decision_paths(g)
    contexts: list[dict[str, Any]] = [{}]
    for path in decisions:
        symbol, optional = slots[path]
        contexts = [{**ctx, path: option} for ctx in contexts
                    for option in (_options(g, symbol, optional) if _active(path, ctx, decisions) else [ABSENT])]
    pins: list[dict[str, Any]] = [{}]
    for flag, values in _scene_splits(g, slots, decisions).items():
        pins = [{**pin, flag: value} for pin in pins for value in values]
    return [e for e in (_effects(g, ctx, slots, decisions, pin) for ctx in contexts for pin in pins)
            if e is not None]


def _scene_splits(g: Grammar, slots: dict[str, tuple[str, bool]], decisions: list[str]) -> dict[str, list[Any]]:
    """Scene flags that dependent items (set members) need: each context is split over their values, so a member
    that needs a flag is allowed exactly where the context pins the flag to that value."""
    flags: dict[str, list[Any]] = {}
    for _, terminal in _dependent_items(g, slots, decisions):
        for duty in g.terminals[terminal].duties:
            for flag in duty.get("requires_scene") or {}:
                param = g.terminals["scene"].params[flag]
                flags[flag] = [True, False] if param.type == "bool" else list(param.values)
    return flags


def _dependent_items(g: Grammar, slots: dict[str, tuple[str, bool]], decisions: list[str]) -> list[tuple[str, str]]:
    """(path, terminal) of optional terminal slots and set members that are not decisions but have duties."""
    items = [(p, s) for p, (s, opt) in slots.items()
             if opt and s in g.terminals and p not in decisions and g.terminals[s].duties]
    for path, (symbol, _) in slots.items():
        if symbol in g.nonterminals and g.nonterminals[symbol].kind == "set":
            items += [(f"{path}.{m}", m) for m in g.nonterminals[symbol].members if g.terminals[m].duties]
    return items


def _effects(g: Grammar, ctx: dict[str, Any], slots, decisions,
             pinned: dict[str, Any] | None = None) -> _Effects | None:
    required, forbidden, scene, groups = set(), set(), dict(pinned or {}), set()
    for path, choice in ctx.items():
        if choice is ABSENT or choice not in g.terminals:
            continue
        term = g.terminals[choice]
        groups |= set(term.param_groups)
        for duty in duties_at(g, f"{path}.{choice}" if choice == CUSTOM else path, choice):
            held = _holds(g, duty, ctx)
            if held is False:
                return None
            if "requires_loss" in duty:
                required.add(f"model.losses.{duty['requires_loss']}")
            for flag, value in (duty.get("requires_scene") or {}).items():
                if scene.get(flag, value) != value:
                    return None
                scene[flag] = value
    for path, terminal in _dependent_items(g, slots, decisions):
        if not _active(path, ctx, decisions):
            continue
        term = g.terminals[terminal]
        if term.param_groups or any(_holds(g, d, ctx, scene) is None for d in term.duties):
            raise GrammarSpecError(f"GBNF export: {terminal} at {path} has duties a grammar cannot express here")
        if not all(_holds(g, d, ctx, scene) for d in term.duties):
            if path in required:
                return None
            forbidden.add(path)
    return _Effects(tuple(sorted(ctx.items(), key=str)), frozenset(required), frozenset(forbidden),
                    tuple(sorted(scene.items())), frozenset(groups))


# ------------------------------------------------------------------------- emission
class _Emitter:
    def __init__(self, g: Grammar, structure_only: bool = False) -> None:
        self.g = g
        self.structure_only = structure_only
        """A model's plan: terminals without parameters (their defaults; a scene's duty flags stay), no custom
        components (a planner chooses among known techniques)."""
        self.rules: dict[str, str] = {}
        self.by_body: dict[str, str] = {}

    def rule(self, hint: str, body: str) -> str:
        if body in self.by_body:
            return self.by_body[body]
        base = "".join(c if c.isalnum() else "-" for c in hint.lower()).strip("-") or "r"
        name = base
        for i in itertools.count(2):
            if name not in self.rules:
                break
            name = f"{base}-{i}"
        self.rules[name] = body
        self.by_body[body] = name
        return name

    def obj(self, hint: str, members: list[tuple[str, str, bool]]) -> str:
        """An object with members in order; (key, rule, required); commas placed exactly."""
        members = [(f"{_lit(json.dumps(k) + ':')} {r}", req) for k, r, req in members]
        if not members:
            return self.rule(hint, '"{}"')
        options, all_optional = [], True
        for first, (text, req) in enumerate(members):
            tail = " ".join(f"\",\" {t}" if r else f"( \",\" {t} )?" for t, r in members[first + 1:])
            options.append(f"( {text} {tail} )")
            if req:
                all_optional = False
                break
        inner = f"( {' | '.join(options)} ){'?' if all_optional else ''}"
        return self.rule(hint, f'"{{" {inner} "}}"')

    def custom_set(self, symbol: str, members: list[tuple[str, str, bool]], fx: _Effects) -> str:
        """A set's object: its optional members in order, then any number of custom members
        (``"custom"`` or ``"custom_<name>"``)."""
        key = self.rule("custom-key", '"\\"custom" ( "_" [a-z0-9_]+ )? "\\":"')
        member = self.rule("custom-member", f"{key} {self.terminal(CUSTOM, fx)}")
        items = [f"{_lit(json.dumps(k) + ':')} {r}" for k, r, _ in members]
        options = []
        for first, text in enumerate(items):
            tail = " ".join(f"( \",\" {t} )?" for t in items[first + 1:])
            options.append(f"( {text} {tail} ( \",\" {member} )* )")
        options.append(f"( {member} ( \",\" {member} )* )")
        return self.rule(symbol, f'"{{" ( {" | ".join(options)} )? "}}"')

    def terminal(self, name: str, fx: _Effects) -> str:
        term = self.g.terminals[name]
        consts = dict(fx.scene) if name == "scene" else {}
        members = []
        for pname, param in term.params.items():
            if name == CUSTOM and pname in CUSTOM_NAMES:
                members.append((pname, self.rule(f"custom-{pname}", CUSTOM_NAMES[pname]), True))
            elif pname in consts:
                value = json.dumps(consts[pname])
                rule = self.rule(f"{name}-{pname}-{value}", _lit(value))
                members.append((pname, rule, consts[pname] != param.default))
            elif self.structure_only:
                continue
            else:
                item = None
                if param.type in ("int_list", "float_list"):
                    item = self.rule(f"{name}-{pname}-item", _scalar(param, param.type.split("_")[0]))
                members.append((pname, self.rule(f"{name}-{pname}", param_rule(param, item)), False))
        return self.obj(name, members)

    def symbol(self, symbol: str, path: str, fx: _Effects) -> str:
        if symbol in self.g.terminals:
            return self.terminal(symbol, fx)
        nt = self.g.nonterminals[symbol]
        def join(key):
            return f'{path}.{key}' if path else key
        chosen = fx.choice(path)
        if nt.kind == "enum":
            alts = nt.alternatives if chosen == "*" else [chosen]
            return self.rule(symbol, " | ".join(_lit(json.dumps(a)) for a in alts))
        if nt.kind == "choice":
            alts = nt.alternatives if chosen == "*" else [chosen]
            alts = [a for a in alts if not (self.structure_only and a == CUSTOM)] or alts
            options = [self.obj(f"{symbol}-{a}", [(a, self.symbol(a, join(a), fx), True)]) for a in alts]
            return self.rule(symbol, " | ".join(options))
        if nt.kind == "sequence":
            members = []
            for slot in nt.slots:
                sub = join(slot.name)
                decided = fx.choice(sub)
                if decided is ABSENT or sub in fx.forbidden:
                    continue
                required = not slot.optional or sub in fx.required or decided != "*"
                members.append((slot.name, self.symbol(slot.symbol, sub, fx), required))
            return self.obj(symbol, members)
        if nt.kind == "set":
            members = [(m, self.terminal(m, fx), False) for m in nt.members if join(m) not in fx.forbidden]
            custom = nt.custom and not self.structure_only and all(
                _holds(self.g, d, dict(fx.ctx), dict(fx.scene)) is not False
                for d in duties_at(self.g, join(CUSTOM), CUSTOM))  # a set's custom members: their interface's duties
            return self.custom_set(symbol, members, fx) if custom else self.obj(symbol, members)
        if nt.kind == "open" and self.structure_only:
            return self.terminal(nt.terminal, fx)
        if nt.kind == "open":
            custom = self.obj(f"{symbol}-custom", [(CUSTOM, self.terminal(CUSTOM, fx), True)])
            return self.rule(symbol, f"{custom} | {self.terminal(nt.terminal, fx)}")
        value = nt.value
        return self.obj(symbol, [(k, self.symbol(value, join(k), fx), True) for k in nt.keys if k in fx.groups])

    def root(self, fx: _Effects, annotations: bool = True) -> str:
        start = self.g.nonterminals[self.g.start]
        members = [("method", "methodname", True)]
        members += [("description", "string", False), ("paper", "object", False)] if annotations else []
        for slot in start.slots:
            decided = fx.choice(slot.name)
            if decided is ABSENT or slot.name in fx.forbidden:
                continue
            required = not slot.optional or slot.name in fx.required or decided != "*"
            members.append((slot.name, self.symbol(slot.symbol, slot.name, fx), required))
        if not annotations:  # a model's plan: its evidence (path -> quote), at most EVIDENCE_ITEMS of them
            return self.obj("plan", members + [("evidence", "evidence-map", False)])
        members += [("evidence", "object", False), ("pruned", "array", False), ("holes", "array", False),
                    ("notes", "array", False)]
        return self.obj("plan", members)


EVIDENCE_ITEMS = 8
"""The most evidence entries a model's plan may carry (``to_gbnf(annotations=False)``)."""


def to_gbnf(grammar: Grammar | None = None, *, annotations: bool = True, max_string: int | None = None,
            structure_only: bool = False) -> str:
    """The GBNF grammar of canonical plan JSON (root rule ``root``). For a model's decoding
    (``nerfify_ns.agents.planner``): ``annotations=False`` keeps only ``method``, the derivation and an
    ``evidence`` map of at most :data:`EVIDENCE_ITEMS` path -> quote entries; ``max_string`` bounds every string
    (and a number's digits), so a small model cannot ramble past ``max_tokens`` inside one; ``structure_only``:
    the derivation's choices only (every terminal at its defaults, no custom components), a short answer."""
    g = grammar or load_grammar()
    emitter = _Emitter(g, structure_only)
    variants = sorted({emitter.root(fx, annotations) for fx in _contexts(g)})
    lines = [f"# nerfify plan grammar (grammar_spec.yaml version {g.version}); {len(variants)} duty contexts",
             "root ::= " + " | ".join(variants)]
    lines += [f"{name} ::= {body}" for name, body in emitter.rules.items()]
    prelude = _PRELUDE.replace("{RANGE}", "{1,62}")
    if max_string is not None:
        prelude = prelude.replace(' )* "\\""\n', f' ){{0,{max_string}}} "\\""\n', 1)
        prelude = prelude.replace('[1-9] [0-9]*', '[1-9] [0-9]{0,11}').replace('"." [0-9]+', '"." [0-9]{1,12}')
        prelude = prelude.replace('[eE] [-+]? [0-9]+', '[eE] [-+]? [0-9]{1,3}')
    if not annotations:
        prelude += ('\nevidence-map ::= "{" ( string ":" string '
                    f'( "," string ":" string ){{0,{EVIDENCE_ITEMS - 1}}} )? '
                    '"}"')
    lines.append(prelude)
    return "\n".join(lines) + "\n"
