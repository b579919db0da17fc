"""Random derivations of the grammar, parameters at their edges: the grammar fuzzer.

    sampler = PlanSampler(load_grammar(), seed=7)
    plan = sampler.sample()            # a Plan that validate() accepts
    sampler.coverage.report()          # terminals sampled, parameters seen at both edges

Every plan the grammar accepts must compose and pass the static and contract rungs (the benchmark
``nerfify_ns.benchmarks.grammar_fuzz`` checks that over hundreds of plans; a failure is a bug in the grammar
or in the composer). A sample starts as a random walk (each choice and optional slot at random, each
parameter at its low edge, its high edge, its default or a random value), then the grammar's own
violations are settled one at a time: a scene flag set as a duty needs it, a required loss added, the
optimiser groups made those of the model, an optional part whose duty fails dropped, a choice whose
duty fails drawn again. Custom components are never sampled (a fuzzer has no component code to give);
their composition is tested with hand-written components.
"""

from __future__ import annotations

import copy
import random
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

from nerfify_ns.errors import NerfifyError
from nerfify_ns.grammar.spec import CUSTOM, Grammar, Param
from nerfify_ns.grammar.validate import Derivation, Violation, derive, expected_param_groups
from nerfify_ns.plan import Plan

EDGE_WEIGHTS = (("low", 0.3), ("high", 0.3), ("default", 0.2), ("random", 0.2))
MAX_SETTLE_STEPS = 60
MAX_ATTEMPTS = 200


class FuzzError(NerfifyError):
    """No valid plan could be sampled (a grammar whose duties cannot all be met)."""


@dataclass
class Coverage:
    """What the samples covered: terminals used, and each parameter's edges (low/high) or values."""

    terminals: set[str] = field(default_factory=set)
    edges: dict[tuple[str, str], set[str]] = field(default_factory=lambda: defaultdict(set))

    def add(self, plan: Plan, grammar: Grammar) -> None:
        for path, name in derive(plan, grammar).used.items():
            self.terminals.add(name)
            term = grammar.terminals[name]
            given = plan.get(path) if isinstance(plan.get(path), dict) else {}
            for pname, param in term.params.items():
                if pname in given:
                    self.edges[(name, pname)].add(edge_of(param, given[pname]))

    def missing(self, grammar: Grammar) -> dict[str, list[str]]:
        """Terminals never sampled, and parameters not seen at both edges (or every value of an enum)."""
        missing_terminals = sorted(set(grammar.terminals) - self.terminals - {CUSTOM})
        missing_edges = []
        for name, term in grammar.terminals.items():
            if name == CUSTOM:
                continue
            for pname, param in term.params.items():
                wanted = required_edges(param)
                seen = self.edges.get((name, pname), set())
                if wanted - seen:
                    missing_edges.append(f"{name}.{pname}: {sorted(wanted - seen)}")
        return {"terminals": missing_terminals, "edges": missing_edges}

    def report(self, grammar: Grammar) -> dict:
        missing = self.missing(grammar)
        total = sum(len(t.params) for n, t in grammar.terminals.items() if n != CUSTOM)
        return {"terminals_sampled": len(self.terminals), "terminals_total": len(grammar.terminals) - 1,
                "parameters": total, "parameters_at_both_edges": total - len(missing["edges"]),
                "missing_terminals": missing["terminals"], "missing_edges": missing["edges"]}


def required_edges(param: Param) -> set[str]:
    if param.type in ("int", "float", "int_list", "float_list"):
        return {"low", "high"}
    if param.type == "bool":
        return {"True", "False"}
    if param.type == "enum":
        return {str(v) for v in param.values}
    return set()


def edge_of(param: Param, value: Any) -> str:
    """Which edge (or value) ``value`` shows of ``param``."""
    if param.type in ("bool", "enum"):
        return str(value)
    low, high = _bounds(param)
    items = value if isinstance(value, list) else [value]
    if not items:
        return "low"
    if any(v == low for v in items) and (not isinstance(value, list) or len(value) == (param.length or (0, 0))[0]):
        return "low"
    if any(v == high for v in items):
        return "high"
    return "inside"


def _bounds(param: Param) -> tuple[float, float]:
    """Finite bounds of a number parameter: its range, or the default times 1e-3 and 1e3 where open."""
    default = param.default if not isinstance(param.default, list) else (param.default or [1])[0]
    low, high = param.range or (None, None)
    default = default if isinstance(default, int | float) and not isinstance(default, bool) else 1
    low = low if low is not None else (default / 1e3 if default > 0 else -1e3)
    high = high if high is not None else (default * 1e3 if default > 0 else 1e3)
    return low, high


class PlanSampler:
    """Samples valid plans of ``grammar``; ``seed`` fixes the sequence (print it to replay a failure)."""

    def __init__(self, grammar: Grammar, seed: int = 0) -> None:
        self.g = grammar
        self.seed = seed
        self.rng = random.Random(seed)
        self.coverage = Coverage()

    # ------------------------------------------------------------------ random walk
    def value(self, param: Param, terminal: str = "") -> Any:
        kind = self.rng.choices([e for e, _ in EDGE_WEIGHTS], [w for _, w in EDGE_WEIGHTS])[0]
        unseen = sorted(required_edges(param) - self.coverage.edges.get((terminal, param.name), set()))
        if unseen and param.type in ("int", "float", "int_list", "float_list") and self.rng.random() < 0.5:
            kind = self.rng.choice(unseen)  # coverage-guided: an edge not seen yet
        if param.type == "bool":
            if unseen and self.rng.random() < 0.5:  # coverage-guided: a value not seen yet
                return self.rng.choice(unseen) == "True"
            return self.rng.random() < 0.5
        if param.type == "enum":
            return self.rng.choice(list(param.values))
        if param.type in ("str", "str_list", "mapping"):
            return copy.deepcopy(param.default)
        if kind == "default":
            return copy.deepcopy(param.default)
        if param.type in ("int_list", "float_list"):
            return self._list(param, kind)
        return self._number(param, kind, param.type)

    def _number(self, param: Param, kind: str, number: str) -> Any:
        low, high = _bounds(param)
        if number in ("int", "int_list"):
            low, high = int(low), int(high)
            return {"low": low, "high": high}.get(kind, self.rng.randint(low, min(high, max(low, 4 * low + 64))))
        value = {"low": low, "high": high}.get(kind)
        return float(value) if value is not None else float(self.rng.uniform(low, min(high, max(low * 10, 1.0))))

    def _list(self, param: Param, kind: str) -> list[Any]:
        lo_len, hi_len = param.length or (1, 4)
        length = {"low": lo_len, "high": min(hi_len, 6)}.get(kind, self.rng.randint(lo_len, min(hi_len, 4)))
        item = param.type.split("_")[0]
        return [self._number(param, kind if kind in ("low", "high") else "random", item) for _ in range(length)]

    def terminal(self, name: str) -> dict[str, Any]:
        term = self.g.terminals[name]
        return {pname: self.value(param, name) for pname, param in term.params.items() if self.rng.random() < 0.7}

    def symbol(self, symbol: str) -> Any:
        if symbol in self.g.terminals:
            return self.terminal(symbol)
        nt = self.g.nonterminals[symbol]
        if nt.kind == "enum":
            return self.rng.choice(list(nt.alternatives))
        if nt.kind == "choice":
            alt = self.rng.choice([a for a in nt.alternatives if a != CUSTOM])
            return {alt: self.symbol(alt)}
        if nt.kind == "open":
            return self.terminal(nt.terminal)
        if nt.kind == "set":
            return {m: self.terminal(m) for m in nt.members if self.rng.random() < 0.3}
        if nt.kind == "map":
            return {}  # optimiser groups follow from the model (settled below)
        return {slot.name: self.symbol(slot.symbol) for slot in nt.slots
                if not slot.optional or self.rng.random() < 0.5}

    # ------------------------------------------------------------------ settling the duties
    def settle(self, plan: Plan) -> bool:
        """Fix the violations one at a time; True when the plan validates (the method name, which settling
        never edits, is checked against the installed modules once, at the end)."""
        for _ in range(MAX_SETTLE_STEPS):
            derivation = derive(plan, self.g, installed=False)
            if self._groups(plan, derivation):
                derivation = derive(plan, self.g, installed=False)
            if not derivation.violations:
                return not derive(plan, self.g).violations
            if not self._fix(plan, derivation.violations[0]):
                return False
        return False

    def _groups(self, plan: Plan, derivation: Derivation) -> bool:
        """Make the plan's optimiser groups the ones its model expects; True when they changed."""
        if derivation.violations and any(v.rule not in ("param_groups",) and v.path.startswith("optimizers")
                                         for v in derivation.violations):
            return False
        expected = expected_param_groups(self.g, derivation)
        groups = plan.setdefault("optimizers", {})
        stale = [k for k in groups if k not in expected]
        for name in stale:
            groups.pop(name)
        new = [name for name in expected if name not in groups]
        for name in new:
            groups[name] = self.symbol("OptimizerGroup")
        return bool(stale or new)

    def _fix(self, plan: Plan, v: Violation) -> bool:
        if v.rule == "requires_scene":
            term = self.g.terminals[v.production]
            for duty in term.duties:
                for flag, value in (duty.get("requires_scene") or {}).items():
                    plan.set(f"scene.{flag}", value)
            return True
        if v.rule == "requires_loss":
            loss = v.message.split("model.losses.")[-1].split()[0].rstrip(")")
            plan.set(f"model.losses.{loss}", self.terminal(loss))
            return True
        if v.rule == "requires_terminal" and self.rng.random() < 0.5 and self._settle_slot(plan, v):
            return True
        if v.rule in ("requires_base", "requires_terminal"):
            return self._drop_or_redraw(plan, v.path)
        if v.rule == "param_constraint":
            parent = v.path.rpartition(".")[0]
            nt = self.g.nonterminals.get(self.g.slot_symbol(parent) or "") if parent else None
            if nt is not None and nt.kind == "set" and self.rng.random() < 0.5:
                plan.delete(v.path)  # a member whose rule needs another part of the plan (a hook's target)
                return True
            plan.set(v.path, self.terminal(v.production))
            return True
        return False

    def _settle_slot(self, plan: Plan, v: Violation) -> bool:
        """A duty on another slot settled at that slot: an alternative it allows drawn there, or the slot emptied
        when it must be absent (a base without a sampler); False when the duty names no optional or choice slot."""
        term = self.g.terminals.get(v.production)
        for duty in term.duties if term is not None else ():
            arg = duty.get("requires_terminal")
            if not arg:
                continue
            slot, allowed = arg["slot"], list(arg["any_of"])
            current = plan.get(slot)
            held = next(iter(current), None) if isinstance(current, dict) else current
            if held in allowed:
                continue
            symbol = self.g.slot_symbol(slot)
            nt = self.g.nonterminals.get(symbol or "")
            options = [a for a in allowed if a is not None and a != CUSTOM]
            if options and nt is not None and nt.kind == "choice":
                alt = self.rng.choice(options)
                plan.set(slot, {alt: self.symbol(alt)})
                return True
            if None in allowed and current is not None and self._optional(slot):
                plan.delete(slot)
                return True
        return False

    def _drop_or_redraw(self, plan: Plan, path: str) -> bool:
        """An optional part whose duty fails is dropped; a choice's alternative is drawn again."""
        parent, _, key = path.rpartition(".")
        symbol = self.g.slot_symbol(parent) if parent else None
        nt = self.g.nonterminals.get(symbol or "")
        if nt is not None and nt.kind == "choice":
            plan.set(parent, self.symbol(symbol))
            return True
        if path == "base":
            plan["base"] = self.rng.choice(list(self.g.nonterminals["Base"].alternatives))
            return True
        if nt is not None and nt.kind == "set" or self._optional(path):
            plan.delete(path)
            return True
        return False

    def _optional(self, path: str) -> bool:
        parent, _, key = path.rpartition(".")
        symbol = self.g.slot_symbol(parent) if parent else self.g.start
        nt = self.g.nonterminals.get(symbol or "")
        return nt is not None and nt.kind == "sequence" and any(s.name == key and s.optional for s in nt.slots)

    # ------------------------------------------------------------------ samples
    def sample(self, method: str | None = None) -> Plan:
        """One valid plan (its method name says which sample of which seed it is)."""
        for _attempt in range(MAX_ATTEMPTS):
            plan = Plan(self.symbol(self.g.start))
            plan["method"] = method or f"fuzz-{self.seed}"
            if self.settle(plan):
                self.coverage.add(plan, self.g)
                return plan
        raise FuzzError(f"no valid plan after {MAX_ATTEMPTS} attempts (seed {self.seed})")
