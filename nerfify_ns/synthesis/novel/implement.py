"""A paper's novel parts as compiled components: each hole of the derived plan, from its equations.

    result = implement_holes(doc, derived.plan)                     # or with corrections (equations.yaml)
    result.plan                                  # the plan, holes filled through `custom` where compiled
    result.sources                               # {"components.<name>": source} for the composer
    result.records                               # per hole: equations as read, bindings, sizes, status, reason

For one hole (the production its part fills, at its slot):

1. **Equations.** The hole's own equations and those of the sections that continue it (the paper's later,
   final form of the same part), each read by the equation reader; those it refuses keep their reason.
2. **Outputs.** The production's adapter (``adapters.py``) says what the component returns: the quantity of a
   role (the colour head a colour, the renderer a ray's colour, the loss a loss) or, for a backbone, what the
   hole's equations define and nothing else reads. The latest definition in the paper is tried first; a part
   stated as per-sample contributions is their sum over the samples (NeRF's C(r) = sum_i C_i(r)).
3. **Bindings.** Every symbol the outputs need is, in this order: a person's correction; defined by an equation
   of the part; given by the interface (the adapter, by its role: from the paper's own definitions, the cards'
   notation, then the shared table); a learned parameter (W, b); a standard basis bound to Nerfstudio's
   implementation (spherical harmonics); persistent state (defined in terms of itself); a network the paper
   names (its width and depth from the paper's hyperparameters, with the sentence); else the part is not
   implemented and the reason names the symbol and the equation.
4. **Sizes** (``widths.py``): the equations' own constraints, the roles' widths, the paper's stated shapes
   (``Psi in R^{z x h}``) and hyperparameters; an open width is never guessed.
5. **Compile and check** (``equations.compile_equations``) at small sizes (module vs interpreter, gradcheck),
   then lower at the paper's sizes and write the component around it (``adapters.py``). The composer places
   it through the plan's ``custom`` alternative; the ladder checks it like any component.

Nothing here knows a paper: everything paper-specific comes from the paper (or a person's correction).
"""

from __future__ import annotations

import copy
import hashlib
import json
import re
import time
from dataclasses import dataclass, field
from typing import Any

from nerfify_ns import runfolder
from nerfify_ns.equations import (
    Apply,
    BinOp,
    Concat,
    Equation,
    Index,
    Number,
    ParseFailure,
    Reduce,
    Symbol,
    compile_equations,
    parse_equations,
    show,
)
from nerfify_ns.equations.ir import walk
from nerfify_ns.equations.naming import Names
from nerfify_ns.equations.shapes import CompileError, ParamSpec, is_bound_variable, sample_indexed_keys, uses
from nerfify_ns.equations.show import safe_comment
from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.novel.adapters import (
    ADAPTERS,
    RUNTIME,
    Adapter,
    Feed,
    NetSpec,
    Provision,
    StateSpec,
    Wiring,
    component_source,
)
from nerfify_ns.synthesis.novel.causes import cause_of
from nerfify_ns.synthesis.novel.notation import Definition, Notation, PaperWords
from nerfify_ns.synthesis.novel.widths import WidthError, Widths

IMPLEMENTED, PARTLY, NOT_IMPLEMENTED = "implemented", "partly implemented", "not implemented"
SMALL_RUNTIME = 5          # the width of a runtime input (the interface's in_dim) in the checks
FULL_RUNTIME = 999_983     # ... in the component's source: a sentinel the constructor's in_dim replaces
SMALL_SENTINEL = 999_979   # ... in the self-check's small component
MAX_ROOTS = 8


# ------------------------------------------------------------------------------------------ equations
@dataclass
class Item:
    """One displayed equation (a block may hold several) and what the reader made of it."""

    number: str
    latex: str
    section: str
    order: int
    where: str
    in_hole: bool
    page: int | None = None
    bbox: list | None = None
    corrected: bool = False
    parsed: list = field(default_factory=list)
    position: int = 0

    def equations(self) -> list[Equation]:
        return [p for p in self.parsed if isinstance(p, Equation)]

    def failures(self) -> list[ParseFailure]:
        return [p for p in self.parsed if isinstance(p, ParseFailure)]


def _norm(latex: str) -> str:
    return re.sub(r"\s+", "", latex or "")


def doc_items(doc: Any) -> list[Item]:
    """Every displayed equation of the paper, in reading order."""
    items = []
    sections = [s.heading for s in getattr(doc, "sections", []) or []]
    for i, e in enumerate(getattr(doc, "equations", []) or []):
        latex = (e.latex or "").strip()
        if not latex:
            continue
        loc = e.loc
        where = ", ".join(x for x in (f"p.{e.page or loc.page}" if (e.page or getattr(loc, "page", None)) else
                                      (f"l.{loc.line}" if getattr(loc, "line", None) else ""),
                                      f"Sec. {e.section}" if e.section else "") if x)
        items.append(Item(number=str(e.number or ""), latex=latex, section=e.section or "",
                          order=getattr(loc, "order", 0) or 0, where=where, in_hole=False,
                          page=e.page or getattr(loc, "page", None), bbox=e.bbox, position=i))
    rank = {s: k for k, s in enumerate(sections)}
    items.sort(key=lambda it: (rank.get(it.section, len(rank)), it.order, it.position))
    for k, it in enumerate(items):
        it.position = k
    return items


def describe(err: BaseException) -> str:
    """An exception as part of a recorded reason: its type and the first 200 characters of its message."""
    message = " ".join(str(err).split())[:200]
    return f"{type(err).__name__}: {message}" if message else type(err).__name__


def _parse(item: Item) -> None:
    """Read an item's equations once; whatever goes wrong is the item's recorded failure, never the run's."""
    if not item.parsed:
        try:
            item.parsed = parse_equations(item.latex, number=item.number or None)
        except Exception as err:  # noqa: BLE001 - the per-equation boundary (parse_equations itself never raises)
            item.parsed = [ParseFailure(f"could not read Eq. {item.number or '?'}: {describe(err)}", None, "",
                                        item.latex[:200], item.number or None)]


# ------------------------------------------------------------------------------------------ records
@dataclass
class HoleResult:
    """What became of one hole: the record written to equations.yaml and shown by the report."""

    id: str
    slot: str
    production: str
    section: str
    status: str = NOT_IMPLEMENTED
    reason: str = ""
    cause: str = ""
    equations: list = field(default_factory=list)
    bindings: dict = field(default_factory=dict)
    sizes: dict = field(default_factory=dict)
    state: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    component: dict = field(default_factory=dict)
    checks: dict = field(default_factory=dict)
    hash: str = ""
    source: str = ""
    seconds: float = 0.0
    replaced: Any = None

    def to_dict(self) -> dict:
        out = {"id": self.id, "slot": self.slot, "production": self.production, "section": self.section,
               "status": self.status, "reason": self.reason, **({"cause": self.cause} if self.cause else {}),
               "equations": self.equations,
               "bindings": self.bindings, "sizes": self.sizes, "state": self.state, "notes": self.notes,
               "component": self.component, "checks": self.checks, "hash": self.hash}
        return out


@dataclass
class Implementation:
    plan: Plan
    sources: dict
    records: list
    seconds: float = 0.0
    counts: dict = field(default_factory=dict)

    def headline(self) -> str:
        n = len(self.records)
        done = sum(r.status == IMPLEMENTED for r in self.records)
        partly = sum(r.status == PARTLY for r in self.records)
        if not n:
            return "the paper has no novel part left as a hole"
        return (f"{done} of {n} novel part(s) of the paper implemented from its equations or sentences"
                + (f", {partly} partly" if partly else "") + f", {n - done - partly} not implemented")


# ------------------------------------------------------------------------------------------ the work
class _Unbound(CompileError):
    pass


@dataclass
class _Attempt:
    equations: list                 # Equation, in schedule order later
    outputs: list                   # keys returned by the module
    items: list                     # Item of each equation
    composite: Equation | None = None
    dropped: list = field(default_factory=list)     # notes on rewrites
    roots: list = field(default_factory=list)


class _Hole:
    def __init__(self, hole: dict, items: list[Item], words: PaperWords, notation: Notation, plan: Plan,
                 context: dict, corrections: dict | None, cards: list[str]):
        self.hole, self.items, self.words, self.notation, self.plan = hole, items, words, notation, plan
        self.context, self.cards = context, cards
        self.corr = corrections or {}
        self.adapter: Adapter | None = ADAPTERS.get(hole["production"])
        self.result = HoleResult(id=hole_id(hole), slot=hole["slot"], production=hole["production"],
                                 section=hole.get("section", ""))
        self.provisions = _with_derived(self.adapter.provisions(context), notation) if self.adapter else {}

    # -------------------------------------------------------------- roles
    def role_of(self, sym: Symbol) -> Definition | None:
        binding = (self.corr.get("bindings") or {}).get(sym.key)
        if isinstance(binding, dict) and binding.get("role"):
            return Definition(binding["role"], "correction", runfolder.EQUATIONS, "", "")
        d = self.words.definition(sym)
        if d is not None:
            return d
        for card in self.cards:
            role = (self.notation.cards.get(card) or {}).get(sym.name)
            if role:
                return Definition(role, "card", card)
        role = self.notation.table_role(sym)
        if role:
            return Definition(role, "table", f"{sym.name} -> {role}")
        return None

    # -------------------------------------------------------------- selection
    def hole_items(self) -> list[Item]:
        """The hole's own equations (by number or text) and those of the sections that continue it."""
        wanted_numbers = {str(e.get("number")) for e in self.hole.get("equations", []) if e.get("number")}
        wanted_text = {_norm(e.get("latex", "")) for e in self.hole.get("equations", []) if e.get("latex")}
        own = [it for it in self.items if (it.number and it.number in wanted_numbers) or _norm(it.latex) in wanted_text]
        sections = []
        for it in own:
            if it.section not in sections:
                sections.append(it.section)
        if not own and self.hole.get("section"):
            own = [it for it in self.items if it.section == self.hole["section"]]
            sections = [self.hole["section"]]
        for it in own:
            it.in_hole = True
        return own

    def following(self, own: list[Item]) -> list[Item]:
        """Equations of the section right after the hole's last one (a paper's final form of the part)."""
        if not own:
            return []
        last = max(it.position for it in own)
        section = next((it.section for it in self.items if it.position > last and it.section != own[-1].section), None)
        return [it for it in self.items if it.section == section and it.position > last] if section else []

    def definitions(self, pool: list[Item]) -> dict[str, list[tuple[Equation, Item]]]:
        out: dict[str, list] = {}
        for it in pool:
            for eq in it.equations():
                if eq.defines and eq.relation in ("=", ":="):
                    if eq.also:  # a chain a = b = c: its last form (a derivation's result) first
                        last = Equation(eq.lhs, eq.also[-1], eq.number, eq.relation, eq.source, (), eq.free_index)
                        out.setdefault(eq.defines, []).append((last, it))
                    out.setdefault(eq.defines, []).append((eq, it))
        return out

    def roots(self, own: list[Item], later: list[Item]) -> list[tuple[list[Equation], list[Item], Equation | None]]:
        """Candidate outputs, the paper's latest form first: (equations defining the outputs, their items,
        a composite equation summing per-sample contributions or None)."""
        adapter = self.adapter
        if adapter.output_mode == "sinks":
            eqs = [(eq, it) for it in own for eq in it.equations() if eq.defines and eq.relation in ("=", ":=")]
            defined = {eq.defines for eq, _ in eqs}
            used = set()
            for eq, _ in eqs:
                used |= {k for k in uses(eq) if k != eq.defines}
            sinks = [(eq, it) for eq, it in eqs if eq.defines not in used and not isinstance(eq.rhs, Number)]
            return [([eq for eq, _ in sinks], [it for _, it in sinks], None)] if sinks and defined else []
        found = []
        for it in sorted(later + own, key=lambda x: -x.position):
            for eq in reversed(it.equations()):
                if not eq.defines or eq.relation not in ("=", ":=") or not isinstance(eq.lhs, Symbol):
                    continue
                d = self.role_of(eq.lhs)
                if d is None or d.role not in adapter.output_roles:
                    continue
                found.append((eq, it))
        candidates = []
        seen = set()
        for eq, it in found:
            contribution = adapter.production == "Renderer" and eq.free_index is not None
            if contribution:  # per-sample contributions of one block: their sum over the samples is the output
                group = [(e, it) for e in it.equations() if e.free_index is not None and e.defines
                         and (self.role_of(e.lhs) or Definition("", "")).role in adapter.output_roles]
                key = tuple(e.defines for e, _ in group)
                if key in seen:
                    continue
                seen.add(key)
                weighted = not any(self._weighs(e) for e, _ in group)
                candidates.append(([e for e, _ in group], [it for _ in group],
                                   _composite([e for e, _ in group], weighted)))
            else:
                if eq.defines in seen:
                    continue
                seen.add(eq.defines)
                candidates.append(([eq], [it], None))
        return candidates[:MAX_ROOTS]

    # -------------------------------------------------------------- closure and bindings
    def attempt(self, roots: list[Equation], root_items: list[Item], composite: Equation | None, own: list[Item],
                pool: list[Item]) -> tuple[_Attempt, dict]:
        """The equations the roots need (each symbol's definition nearest the roots) and every free symbol's
        binding; raises _Unbound naming what is missing."""
        self._basis, self._concat_used, self._provision_used = {}, set(), {}
        defs = self.definitions(pool)
        first = _first_seen(pool)
        chosen: dict[str, tuple[Equation, Item]] = {}
        rewritten: dict[str, Equation] = {}
        notes: list[str] = []
        for eq, it in zip(roots, root_items, strict=False):
            chosen[eq.defines] = (eq, it)
        root_sections = {it.section for it in root_items}
        corrections = self.corr.get("bindings") or {}
        free: dict[str, tuple[Symbol, Equation]] = {}
        pending = list(roots) + ([composite] if composite else [])
        while pending:
            eq = self._rewrite(pending.pop(0), notes)
            if eq.defines:
                rewritten[eq.defines] = eq
            for key in sorted(uses(eq), key=lambda k: (first.get(k, (1 << 30,)), k)):
                if key in chosen or key in free or key == eq.defines:
                    continue
                sym = _find_symbol(eq, key)
                corrected = corrections.get(key)
                if isinstance(corrected, dict) and corrected.get("as") in ("input", "network", "parameter", "constant"):
                    free[key] = (sym, eq)
                    continue
                definition = self._pick_definition(key, defs, root_items, sym)
                providable = sym is not None and self._providable(sym)
                near = definition is not None and (definition[1] in own or definition[1].section in root_sections)
                if definition is not None and (near or not providable):
                    chosen[key] = definition
                    pending.append(definition[0])
                else:
                    free[key] = (sym, eq)
        equations = [rewritten.get(key, eq) for key, (eq, _) in chosen.items()]
        items = [it for _, it in chosen.values()]
        if composite is not None:
            equations.append(rewritten.get(composite.defines, composite))
            items.append(None)
        bindings: dict[str, dict] = {}
        unbound: list[str] = []
        for key in sorted(free, key=lambda k: (first.get(k, (1 << 30,)), k)):
            sym, eq = free[key]
            try:
                bindings[key] = self._bind(key, sym, eq, corrections.get(key))
            except _Unbound as err:
                unbound.append(str(err))
            except Exception as err:  # noqa: BLE001 - the per-symbol boundary: this symbol's reason
                unbound.append(f"'{key}' could not be bound: {describe(err)}")
        if unbound:
            raise _Unbound(" | ".join(unbound))
        for eq in equations:  # persistent state: a symbol its own definition reads
            if eq.defines in uses(eq):
                bindings[eq.defines] = self._state(eq)
        for key, b in bindings.items():  # a constant the text states: an equation of the part (key = value)
            if b["as"] == "constant":
                sym = free[key][0]
                lhs = Symbol(sym.name, sym.subscripts, sym.superscript, sym.decorations)
                equations.insert(0, Equation(lhs, Number(float(b["value"])), None, "=", "", (), None))
                items.insert(0, None)
        outputs = [composite.defines] if composite is not None else [eq.defines for eq in roots]
        return _Attempt(equations, outputs, items, composite, notes, list(roots)), bindings

    def _pick_definition(self, key, defs, root_items, sym: Symbol | None = None):
        """The definition of ``key`` the part uses: one that defines it per sample when it is read with a sample
        index (and per ray otherwise), in the roots' block, then their section, then the hole's; the paper's
        latest form first (a derivation ends with the form it uses)."""
        options = defs.get(key) or []
        if not options:
            return None
        sections = {it.section for it in root_items}
        indexed = sym is not None and sym.index is not None

        def rank(option):
            eq, it = option
            same_block = any(it is r for r in root_items)
            return ((eq.free_index is not None) != indexed, not same_block, it.section not in sections,
                    not it.in_hole, -it.position)
        return sorted(options, key=rank)[0]

    def _rewrite(self, eq: Equation, notes: list[str]) -> Equation:
        """Rewrites a production needs, each reported: a trailing concatenation with the viewing direction in a
        backbone's output (the field concatenates the encoded direction before the colour head), and a sum over
        a standard basis (spherical harmonics) bound to Nerfstudio's implementation."""
        rhs = eq.rhs
        if self.adapter.production == "Backbone" and isinstance(rhs, Concat):
            kept = []
            for item in rhs.items:
                d = self.role_of(item) if isinstance(item, Symbol) else None
                if d is not None and d.role in ("direction", "direction_encoding") and \
                        d.role not in self.provisions:
                    notes.append(f"({eq.number or '?'}) {safe_comment(item.key, 30)}: the viewing direction is "
                                 "concatenated by the field (its colour head receives the encoded direction with the "
                                 "backbone's output), not by the backbone")
                    continue
                kept.append(item)
            if len(kept) != len(rhs.items) and kept:
                rhs = Concat(tuple(kept)) if len(kept) > 1 else kept[0]
        rhs = self._bind_bases(rhs, eq, notes)
        if rhs is eq.rhs:
            return eq
        return Equation(eq.lhs, rhs, eq.number, eq.relation, eq.source, eq.also, eq.free_index)

    def _bind_bases(self, expr, eq, notes):
        """sum_l sum_m X_l^m Y_l^m(d), Y a standard basis -> one symbol the component computes with Nerfstudio's
        implementation of Y (the oracle of the basis)."""
        if isinstance(expr, Reduce) and expr.axis == "range" and isinstance(expr.body, Reduce) and \
                expr.body.axis == "range" and isinstance(expr.body.body, BinOp) and expr.body.body.op in ("*", "odot"):
            a, b = expr.body.body.left, expr.body.body.right
            for basis, coef in ((a, b), (b, a)):
                if not (isinstance(basis, Symbol) and isinstance(coef, Symbol)):
                    continue
                d = self.role_of(basis)
                role = self.notation.roles.get(d.role) if d else None
                if role is None or role.kind != "basis":
                    continue
                indices = {expr.index, expr.body.index}
                for part in (coef, basis):  # a basis expansion: both factors carry both indices of the sums
                    missing = sorted(indices - (set(part.subscripts) | {part.superscript}))
                    if missing:
                        raise _Unbound(f"({eq.number or '?'}) in the sum over {', '.join(sorted(indices))} of "
                                       f"{safe_comment(coef.key, 30)} times {safe_comment(basis.key, 30)} "
                                       f"({role.doc}), '{safe_comment(part.key, 30)}' does not carry the sum's index "
                                       f"'{safe_comment(missing[0], 10)}' (a wrong subscript or superscript?)")
                c = self.role_of(coef)
                if not (self.words.names(coef) or (c is not None and c.source in ("paper", "card", "correction"))):
                    raise _Unbound(f"({eq.number or '?'}) the coefficients '{safe_comment(coef.key, 30)}' of the "
                                   f"{role.doc} are neither named by the paper nor by a card's notation")
                sym = Symbol("basis", (coef.name, basis.name))
                self._basis[sym.key] = (basis, coef, d)
                notes.append(f"({eq.number or '?'}) the sum over l and m of {safe_comment(coef.key, 20)} times "
                             f"{safe_comment(basis.key, 20)}: {role.doc}, bound to Nerfstudio's implementation "
                             f"({safe_comment(d.evidence(), 80)})")
                return sym
            return expr
        if isinstance(expr, Apply):
            args = tuple(self._bind_bases(a, eq, notes) for a in expr.args)
            return expr if args == expr.args else Apply(expr.func, args)
        if isinstance(expr, BinOp):
            left, right = self._bind_bases(expr.left, eq, notes), self._bind_bases(expr.right, eq, notes)
            return expr if (left is expr.left and right is expr.right) else BinOp(expr.op, left, right)
        return expr

    def _weighs(self, eq: Equation) -> bool:
        """Whether a per-sample equation is a contribution already weighted along its ray (it reads a weight, a
        transmittance, an opacity, or accumulates over the samples), rather than a per-sample value."""
        for node in walk(eq.rhs):
            if isinstance(node, Reduce):
                return True
            d = self.role_of(node) if isinstance(node, Symbol) else None
            if d is not None and d.role in ("weight", "transmittance", "opacity"):
                return True
        return False

    def _providable(self, sym: Symbol) -> bool:
        d = self.role_of(sym)
        return d is not None and d.role in self.provisions

    def _input(self, role: str, source: str, evidence: str, **extra) -> dict:
        prov = self.provisions[role]
        return {"as": "input", "role": role, "source": source, "evidence": evidence, "reads": prov.doc,
                "code": prov.code, "per_sample": prov.per_sample, "width": prov.width, **extra}

    def _bind(self, key: str, sym: Symbol | None, eq: Equation, corrected: dict | None) -> dict:
        where = f"equation ({eq.number})" if eq.number else f"the equation of '{safe_comment(eq.defines or '?', 30)}'"
        name = safe_comment(key, 40)
        if key in self._basis:
            basis, coef, d = self._basis[key]
            return {"as": "basis", "role": d.role, "source": d.source, "evidence": d.evidence(),
                    "basis": basis.key, "coefficient": coef.key}
        if sym is None:
            raise _Unbound(f"'{name}' in {where}: not found")
        corrected = corrected if isinstance(corrected, dict) else None
        how = corrected.get("as") if corrected else None
        if how == "constant":
            if not isinstance(corrected.get("value"), int | float) or isinstance(corrected.get("value"), bool):
                raise _Unbound(f"'{name}': a constant in equations.yaml needs a numeric value")
            return {"as": "constant", "role": str(corrected.get("role", "constant")), "source": "correction",
                    "evidence": runfolder.EQUATIONS, "value": float(corrected["value"])}
        if how == "input":
            role = str(corrected.get("role", ""))
            if role not in self.provisions:
                raise _Unbound(f"'{name}': equations.yaml binds it to '{safe_comment(role, 30)}', which the "
                               f"{self.adapter.production} interface does not give (it gives: "
                               f"{', '.join(sorted(self.provisions)) or 'nothing'})")
            self._provision_used[role] = key
            return self._input(role, "correction", runfolder.EQUATIONS)
        d = self.role_of(sym)
        role = d.role if d else None
        kind = self.notation.roles[role].kind if role in self.notation.roles else None
        if how == "parameter" or (how is None and role in ("weight_matrix", "bias")):
            matrix = role != "bias" and (role == "weight_matrix" or sym.name[:1].isupper())
            return {"as": "parameter", "role": role or "weight_matrix", "source": d.source if d else "correction",
                    "evidence": d.evidence() if d else runfolder.EQUATIONS, "matrix": matrix}
        if how == "network":
            return self._network(key, sym, d, corrected)
        stated = self.words.constants.get(_loose(sym))
        if stated is not None and role not in self.provisions:
            value, quote, where2 = stated
            return {"as": "constant", "role": role if kind == "constant" else "constant", "source": "paper",
                    "evidence": f"{where2}: \"{_short(quote)}\"", "value": value}
        if role in self.provisions and role not in self._provision_used and not self._read_per_ray(sym, role):
            self._provision_used[role] = key
            return self._input(role, d.source, d.evidence())
        composited = self._composited(sym, role, d)
        if composited is not None:
            return composited
        learned = self.words.is_learned(sym)
        if learned is not None and role not in self.provisions:
            matrix = role == "weight_matrix" or (sym.name[:1].isupper() and sym.name.isalpha() and len(sym.name) == 1)
            # a lower-case Greek letter (beta, tau) is a scalar by convention; other letters are sized by the equations
            greek = len(sym.name) > 1 and sym.name.isalpha() and sym.name.islower() and not sym.subscripts
            return {"as": "parameter", "role": "learned", "source": "paper",
                    "evidence": f"{learned[1]}: \"{_short(learned[0])}\"", "matrix": matrix, "learned": True,
                    **({"scalar": True} if greek and not matrix else {})}
        # a concatenation partner the paper's "concatenated with the ..." sentence names
        if isinstance(eq.rhs, Concat) and any(isinstance(i, Symbol) and i.key == key for i in eq.rhs.items):
            for role2, quote, where2 in self.words.concat_roles:
                if role2 in self.provisions and role2 not in self._provision_used and role2 not in self._concat_used:
                    self._concat_used.add(role2)
                    self._provision_used[role2] = key
                    return self._input(role2, "paper", f"{where2}: \"{_short(quote)}\"",
                                       note="the paper does not define the symbol; its sentence says what is "
                                            "concatenated")
        named = self.words.names(sym)
        networkish = role is None or kind in ("network", "per_point", "per_ray", "per_sample")
        if self.adapter.network_input and networkish and (named or (d is not None and d.source in ("paper", "card"))):
            return self._network(key, sym, d, corrected)
        if role in self.provisions:
            what = (f"a second {role} ('{safe_comment(self._provision_used[role], 30)}' already reads the interface's "
                    f"{role}) that the paper's text does not name")
        elif d is not None and networkish and self.adapter.network_input:
            what = (f"a {role} ({d.source} notation) that the paper's text never names (a symbol becomes a network's "
                    "output only when the paper names it)")
        elif d is not None:
            what = f"a {role} ({'the paper' if d.source == 'paper' else 'the ' + d.source + ' notation'}) that the " \
                   f"{self.adapter.production} interface does not give"
        else:
            what = "a symbol the paper neither defines nor names"
        said = self.words.first_sentence(sym)
        paper = f"; the paper: \"{_short(said[0], 140)}\" ({said[1]})" if said else ""
        raise _Unbound(f"'{name}' ({where}): {what}{paper}")

    def _read_per_ray(self, sym: Symbol, role: str | None) -> bool:
        """A per-sample quantity read at a ray (``l(r)``, no sample index) in a production that renders rays."""
        r = self.notation.roles.get(role or "")
        if r is None or r.kind != "per_sample" or sym.index is not None or "weight" not in self.provisions:
            return False
        return any(isinstance(a, Symbol) and (self.role_of(a) or Definition("", "")).role == "ray" for a in sym.args)

    def _composited(self, sym: Symbol, role: str | None, d: Definition | None) -> dict | None:
        """A per-ray quantity whose per-sample counterpart the interface gives (a ray's colour, the mean luminance
        along a ray): the volume-rendering composite sum_i w_i x_i with the renderer's weights, said in the record."""
        r = self.notation.roles.get(role or "")
        if r is None:
            return None
        source = r.composite_of if r.kind == "per_ray" else (role if self._read_per_ray(sym, role) else "")
        prov, weight = self.provisions.get(source), self.provisions.get("weight")
        if not source or prov is None or weight is None or not prov.per_sample or not weight.per_sample:
            return None
        weights = "weights" if prov.width is not None else "weights[..., 0]"
        return {"as": "input", "role": role, "source": d.source if d else "table",
                "evidence": d.evidence() if d else "", "code": f"torch.sum({weights} * {prov.code}, dim=1)",
                "reads": f"{prov.doc}, composited per ray with the renderer's volume-rendering weights "
                         "(sum_i w_i x_i, the base's weights)",
                "composited": f"sum over the samples of the weights times {source}", "per_sample": False,
                "width": prov.width}

    def _network(self, key, sym, d, corrected) -> dict:
        if not self.adapter.network_input:
            raise _Unbound(f"'{safe_comment(key, 40)}' would be a network's output, but the "
                           f"{self.adapter.production} interface has no input a network could read")
        act = self.words.activations.get(_loose(sym))
        role = d.role if d else "network"
        rng = self.notation.roles[role].range if role in self.notation.roles else (None, None)
        activation, act_source = None, "none: the paper states none and the role has no range"
        if corrected and corrected.get("activation"):
            activation, act_source = str(corrected["activation"]), runfolder.EQUATIONS
        elif act:
            activation, act_source = act[0], f"{act[2]}: \"{_short(act[1])}\""
        elif role == "hidden":
            activation, act_source = "relu", "hidden features of dense ReLU layers"
        elif tuple(rng) == (0, 1):
            activation, act_source = "sigmoid", f"a {role} lies in [0, 1]"
        elif rng[0] == 0:
            activation, act_source = "softplus", f"a {role} is non-negative"
        if activation not in (None, "sigmoid", "softplus", "relu", "tanh"):
            raise _Unbound(f"'{safe_comment(key, 40)}': the activation '{safe_comment(activation, 20)}' is not one of "
                           "sigmoid, softplus, relu, tanh")
        return {"as": "network", "role": role, "source": d.source if d else "paper",
                "evidence": d.evidence() if d else "named in the paper's text", "activation": activation,
                "activation_evidence": act_source, "reads": self.adapter.network_input}

    def _state(self, eq: Equation) -> dict:
        return {"as": "state", "role": "state", "source": "equation",
                "evidence": f"({eq.number or '?'}) defines {safe_comment(eq.defines, 30)} in terms of itself",
                "initial": 0.0,
                "note": "the paper does not say when it is updated: it is kept across training steps (each step "
                        "reads the last value and stores the new one, detached from the graph), saved in "
                        "checkpoints (a buffer), and used unchanged at evaluation; it starts at zero"}

    # -------------------------------------------------------------- sizes
    def solve(self, att: _Attempt, bindings: dict, runtime: int, small: bool = False) -> tuple[Widths, dict]:
        """Widths of everything (raises WidthError / _Unbound for a contradiction or an open width). ``small``:
        the widths the paper states are replaced by small ones (the checks run at small sizes)."""
        w = Widths()
        evidence: dict[str, dict] = {}
        runtime_var = w.var("runtime")
        w.set(runtime_var, runtime)

        def stated(value: int) -> int:
            return min(int(value), 4) if small else int(value)

        for key, b in bindings.items():
            kind = b["as"]
            if kind == "input":
                width = b.get("width")
                w.known(key, () if width is None else ((runtime_var,) if width == RUNTIME else (int(width),)))
            elif kind == "parameter" and b.get("scalar"):
                w.known(key, ())
            elif kind == "parameter":
                w.matrix(key) if b.get("matrix") else w.vector(key)
            elif kind == "constant":
                w.known(key, ())
            else:
                w.vector(key)
        corrected = {}
        for key, shape in (self.corr.get("sizes") or {}).items():  # sizes a person set
            value = shape.get("shape") if isinstance(shape, dict) else shape
            if key in w.shapes and isinstance(value, list) and len(value) == len(w.shapes[key]) and \
                    all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= 1 << 16 for v in value):
                corrected[key] = value
                evidence[key] = {"source": "correction", "evidence": runfolder.EQUATIONS}
        for key, value in corrected.items():
            # at the check's small sizes a learned matrix's corrected size only fills what the rest leaves open
            # (scaled sizes would not add up), applied after the first pass below
            if not (small and bindings.get(key, {}).get("as") == "parameter"):
                for var, v in zip(w.shapes[key], value, strict=False):
                    w.set(var, stated(v))
        for key in att.outputs:  # an output's role fixes its width (a colour has 3 channels)
            sym = next((eq.lhs for eq in att.equations if eq.defines == key), None)
            d = self.role_of(sym) if isinstance(sym, Symbol) else None
            role = self.notation.roles.get(d.role) if d else None
            if role is not None and role.features and isinstance(role.features[0], int):
                if key in w.shapes and w.shapes[key]:
                    w.set(w.shapes[key][0], role.features[0])
                else:
                    w.known(key, (role.features[0],))
        for key, b in bindings.items():  # the paper's stated shapes (state: rows x width)
            if b["as"] == "state":
                sym = next(eq.lhs for eq in att.equations if eq.defines == key)
                shape = self.words.shape_of(sym)
                if shape:
                    (rows, rq, rw), (width, wq, ww) = shape
                    w.set(w.shapes[key][0], stated(width))
                    b["rows"], b["rows_evidence"] = rows, f"{rw}: \"{_short(rq)}\""
                    evidence[key] = {"source": "paper", "evidence": f"{ww}: \"{_short(wq)}\""}
        w.run(att.equations)
        if small:
            for key, value in corrected.items():
                if bindings.get(key, {}).get("as") == "parameter":
                    for i in w.open(key):
                        w.set(w.shapes[key][i], stated(value[i]))
                    w.run(att.equations)
        paper_width = self.words.widths[0] if self.words.widths else None
        for key, b in bindings.items():  # a hidden embedding: the paper's width
            if b["as"] == "network" and b["role"] == "hidden" and w.open(key) and paper_width:
                w.set(w.shapes[key][0], stated(paper_width[0]))
                evidence[key] = {"source": "paper", "evidence": f"{paper_width[2]}: \"{_short(paper_width[1])}\""}
        w.run(att.equations)
        for key, b in bindings.items():  # a matrix whose output width nothing fixes: the paper's width
            if b["as"] == "parameter" and b.get("matrix") and w.open(key) == [0] and paper_width:
                w.set(w.shapes[key][0], stated(paper_width[0]))
                evidence[key] = {"source": "paper", "evidence": f"{paper_width[2]}: \"{_short(paper_width[1])}\""}
                w.run(att.equations)
        for key, b in bindings.items():
            if b["as"] == "network" and w.open(key):
                b["scalar"] = True  # nothing makes it a vector: one number per element
                w.shapes[key] = ()
            elif b["as"] == "parameter" and b.get("learned") and not b.get("matrix") and w.open(key) == [0]:
                w.shapes[key] = ()  # a learned quantity nothing makes a vector: one learned number
                evidence[key] = {"source": "paper", "evidence": b["evidence"] + " (one number: nothing in the "
                                                                                "equations makes it a vector)"}
        w.run(att.equations)
        for key, b in bindings.items():
            if b["as"] in ("parameter", "state", "basis") and w.open(key):
                raise _Unbound(f"the size of '{safe_comment(key, 40)}' is not fixed by the equations, the "
                               f"{self.adapter.production} contract or the paper's hyperparameters (set it in "
                               "equations.yaml: sizes)")
        return w, evidence


def _with_derived(provisions: dict, notation: Notation) -> dict:
    """The interface's quantities and those a standard formula derives from them (``notation.yaml``: derived; a
    colour's luminance is the weighted sum of its channels)."""
    out = dict(provisions)
    for name, role in notation.roles.items():
        if not role.derived or name in out or role.derived[0] not in provisions:
            continue
        src = provisions[role.derived[0]]
        weights = ", ".join(repr(float(v)) for v in role.derived[1])
        out[name] = Provision(name, src.per_sample, None,
                              f"torch.sum({src.code} * {src.code}.new_tensor([{weights}]), dim=-1)",
                              f"{role.doc}, from {src.doc}")
    return out


def _first_seen(pool: list[Item]) -> dict[str, tuple]:
    """Where each symbol first appears in the paper's equations, left to right (the order in which symbols of
    the same role claim the interface's inputs)."""
    first: dict[str, tuple] = {}
    for it in pool:
        for k, eq in enumerate(it.equations()):
            for n, node in enumerate(walk(eq.rhs)):
                if isinstance(node, Symbol):
                    first.setdefault(node.key, (it.position, k, n))
    return first


def _short(text: str, limit: int = 200) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _loose(sym: Symbol) -> str:
    from nerfify_ns.synthesis.novel.notation import symbol_loose_key

    return symbol_loose_key(sym)


def _find_symbol(eq: Equation, key: str) -> Symbol | None:
    for side in (eq.rhs,):
        for node in walk(side):
            if isinstance(node, Symbol) and node.key == key and not is_bound_variable(node):
                return node
    return None


def _composite(parts: list[Equation], weighted: bool = False) -> Equation:
    """hat C(r) = sum_i (C_i^a(r) + C_i^b(r) ...): the per-sample contributions summed over the samples; per-sample
    values that are no contributions (``weighted``) are composited with the renderer's weights, sum_i w_i c_i."""
    body = None
    for eq in parts:
        lhs = eq.lhs
        term = Symbol(lhs.name, lhs.subscripts, lhs.superscript, lhs.decorations, Index("i"), ())
        body = term if body is None else BinOp("+", body, term)
    if weighted:
        body = BinOp("*", Symbol("w", ("composite",), None, (), Index("i"), ()), body)
    rhs = Reduce("sum", "i", None, None, None, body, axis="samples", mode="full")
    return Equation(Symbol("C", ("composite",), None, ("hat",)), rhs, None, "=", "", (), None)


def hole_id(hole: dict) -> str:
    slot = hole.get("slot", "")
    name = slot.rsplit(".", 1)[-1] or hole.get("production", "part")
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_") or "part"


# ------------------------------------------------------------------------------------------ the entry point
def plan_context(plan: Plan) -> dict:
    """Facts of the plan the adapters need: the direction encoding and its width."""
    ctx: dict = {}
    for root in ("model.field.MLPField",):
        de = plan.get(f"{root}.dir_encoding") or {}
        if isinstance(de, dict) and de:
            name = next(iter(de))
            params = de[name] or {}
            ctx["dir_encoding"] = name
            ctx["dir_path"] = f"{root}.dir_encoding"
            ctx["dir_dim"] = _encoding_width(name, params)
            if name == "sh":
                ctx["sh_levels"] = params.get("levels")
    return ctx


def _encoding_width(terminal: str, params: dict) -> int | None:
    """The width of a direction encoding from its contract's output shape (``[N, levels ** 2]``)."""
    try:
        from nerfify_ns.registry import default_registry
        from nerfify_ns.registry.contract import dims, eval_dim

        defn = default_registry()[terminal]
        full = {name: spec.default for name, spec in defn.param_specs.items()}
        full.update(params or {})
        (spec,) = defn.contract.outputs.values()
        return int(eval_dim(dims(spec.shape)[-1], full))
    except Exception:  # noqa: BLE001 - a terminal without a computable width: the adapter says so
        return None


def implement_holes(doc: Any, plan: dict, *, corrections: dict | None = None, reuse: dict | None = None,
                    cache: dict | None = None, kb: Any = None) -> Implementation:
    """Compile every hole of ``plan`` from ``doc``'s equations (see the module docstring). ``corrections``: the
    holes a person edited in equations.yaml, ``reuse``: hole id -> the earlier result of a hole not edited (both
    from ``records.read_corrections``; a reused hole is not recompiled); ``cache``: content digest -> result,
    kept by the caller across calls (a benchmark, a test)."""
    start = time.perf_counter()
    plan = Plan.of(copy.deepcopy(dict(plan)))
    notation = Notation.load()
    words = PaperWords.read(doc, notation)
    items = doc_items(doc)
    context = plan_context(plan)
    cards = _cards_in(plan)
    by_id = {h.get("id"): h for h in ((corrections or {}).get("holes") or []) if isinstance(h, dict)}
    records: list[HoleResult] = []
    sources: dict[str, str] = {}
    taken_slots: set[str] = set()
    holes = list(plan.get("holes") or [])
    groups: dict[str, list[dict]] = {}
    for h in holes:
        groups.setdefault(h["slot"], []).append(h)
    new_holes = []
    for slot, group in groups.items():
        merged = _merge(group)
        hid = hole_id(merged)
        corr = by_id.get(hid) or {}
        for it in items:
            it.in_hole = False
        local_items = _apply_corrections(items, corr)
        for it in local_items:
            _parse(it)
            it.in_hole = False
        t0 = time.perf_counter()
        try:
            work = _Hole(merged, local_items, words, notation, plan, context, corr, cards)
            work._basis = {}
            work._concat_used = set()
            digest = _digest(merged, local_items, corr, context)
            if reuse and hid in reuse and reuse[hid].production == merged["production"]:
                result = copy.deepcopy(reuse[hid])
                result.notes = [n for n in result.notes if not n.startswith("not recompiled")] + [
                    "not recompiled: equations.yaml leaves this part as it was (its hash matches)"]
            elif cache is not None and digest in cache:
                result = copy.deepcopy(cache[digest])
                result.notes = list(result.notes) + ["not recompiled: its equations, bindings and sizes did not "
                                                     "change"]
            else:
                result = _implement_one(work)
                result = _try_alternative(result, merged, local_items, words, notation, plan, context, corr, cards)
                result.hash = digest
                if cache is not None:
                    cache[digest] = copy.deepcopy(result)
            from nerfify_ns.synthesis.novel import prose  # a part stated in words: its typed terminals

            result = prose.build(merged, words.sentences, plan, corr, result)
        except Exception as err:  # noqa: BLE001 - the per-part boundary: this part's reason, the run goes on
            result = _failed_part(merged, hid, local_items, err)
        result.seconds = time.perf_counter() - t0
        result.cause = cause_of(result.reason) if result.status == NOT_IMPLEMENTED else ""
        if corr.get("recompiled_because"):  # its generated code was edited since: said, not reused
            result.notes = list(result.notes) + [str(corr["recompiled_because"])]
        records.append(result)
        if result.status in (IMPLEMENTED, PARTLY) and result.source:
            module = result.component["module"]
            sources[module] = result.source
            entry = {k: result.component[k] for k in ("module", "class", "params", "implements", "source",
                                                      "evidence")}
            result.replaced = copy.deepcopy(plan.get(result.slot))
            _place(plan, result.slot, entry, result.production, hid)
            taken_slots.add(slot)
        for h in group:
            h = dict(h)
            h["stands_in_base"] = h.get("stands_in", "")
            h["status"] = result.status
            h["reason"] = result.reason
            if result.cause:
                h["cause"] = result.cause
            h["compiled"] = result.component.get("module", "") if result.status != NOT_IMPLEMENTED else ""
            if result.status != NOT_IMPLEMENTED:
                h["stands_in"] = result.component.get("stands_in") or (
                    f"{result.component['module']}.{result.component['class']} compiled from "
                    f"{', '.join(result.component['implements'])}")
            new_holes.append(h)
    plan["holes"] = new_holes
    if words.unread:
        where, reason, _ = words.unread[0]
        plan.setdefault("notes", []).append(
            f"notation: {len(words.unread)} sentence(s) or value(s) not read ({where + ': ' if where else ''}"
            f"{reason}); the rest of the paper was read")
    if records:
        done = sum(r.status == IMPLEMENTED for r in records)
        worded = sum(r.status == IMPLEMENTED and r.component.get("source") == "prose" for r in records)
        plan.setdefault("notes", []).append(
            f"equation compiler: {done - worded} of {len(records)} novel part(s) implemented from the paper's "
            "equations" + (f", {worded} from its sentences (typed terminals)" if worded else ""))
    for it in items:
        _parse(it)
    result = Implementation(plan, sources, records, time.perf_counter() - start)
    result.counts = equation_counts(items)
    return result


def _failed_part(hole: dict, hid: str, items: list[Item], err: BaseException) -> HoleResult:
    """The record of a part whose reading, binding or compiling raised: not implemented, the exception (type and
    message) its reason, the equations it names with what the reader made of them."""
    result = HoleResult(id=hid, slot=str(hole.get("slot", "")), production=str(hole.get("production", "")),
                        section=str(hole.get("section", "")))
    result.reason = f"could not compile the part: {describe(err)}"
    try:
        wanted = {str(e.get("number")) for e in hole.get("equations", []) or [] if isinstance(e, dict)}
        result.equations = [_record_equation(it, []) for it in items if it.number and it.number in wanted]
    except Exception:  # noqa: BLE001 - the reason above stands alone
        result.equations = []
    return result


def equation_counts(items: list[Item]) -> dict:
    numbered = [it for it in items if it.number]
    read = [it for it in numbered if it.parsed and all(isinstance(p, Equation) for p in it.parsed)]
    return {"numbered": len(numbered), "read": len(read), "displayed": len(items)}


def _cards_in(plan: Plan) -> list[str]:
    text = json.dumps(plan.get("evidence") or {}) + json.dumps(plan.get("holes") or [])
    return [name for name in Notation.load().cards if name in text or name.replace("_", " ") in text.lower()]


def _merge(group: list[dict]) -> dict:
    if len(group) == 1:
        return dict(group[0])
    merged = dict(group[0])
    merged["equations"] = [e for h in group for e in h.get("equations", [])]
    merged["section"] = group[0].get("section", "")
    merged["sections"] = [h.get("section", "") for h in group]
    merged["text"] = " ".join(h.get("text", "") for h in group)
    return merged


def _apply_corrections(items: list[Item], corr: dict) -> list[Item]:
    """The paper's equations with a person's corrected LaTeX (equations.yaml: equations[].latex)."""
    fixes = {}
    for e in corr.get("equations") or []:
        if isinstance(e, dict) and isinstance(e.get("latex"), str) and (e.get("number") or e.get("key")):
            fixes[str(e.get("number") or e.get("key"))] = e["latex"]
    out = []
    for it in items:
        key = it.number or f"@{it.position}"
        if key in fixes and _norm(fixes[key]) != _norm(it.latex):
            clone = copy.copy(it)
            clone.latex, clone.corrected, clone.parsed = fixes[key], True, []
            out.append(clone)
        else:
            out.append(it)
    return out


def _digest(hole: dict, items: list[Item], corr: dict, context: dict) -> str:
    data = json.dumps({"hole": {k: hole.get(k) for k in ("slot", "production", "equations", "section")},
                       "items": [(it.number, it.latex, it.section) for it in items],
                       "bindings": corr.get("bindings"), "sizes": corr.get("sizes"), "context": context,
                       "version": 1}, sort_keys=True, default=str)
    return hashlib.sha256(data.encode()).hexdigest()[:16]


ALTERNATIVES = {"RGBLoss": ("Regularizers",), "Regularizers": ("RGBLoss",)}
"""Productions that return the same kind of thing (a loss): a part the derivation filed under one whose interface
does not give what its equations read is tried in the other (a loss on the field's densities is a regulariser)."""


def _slot_of(production: str) -> str | None:
    from nerfify_ns.grammar import load_grammar

    return next((path for path, symbol in load_grammar().symbol_paths() if symbol == production), None)


def _try_alternative(result: HoleResult, hole: dict, items, words, notation, plan, context, corr, cards) -> HoleResult:
    if result.status != NOT_IMPLEMENTED or hole["production"] not in ALTERNATIVES or result.component:
        return result
    for production in ALTERNATIVES[hole["production"]]:
        slot = _slot_of(production)
        if slot is None or production not in ADAPTERS:
            continue
        other = dict(hole, production=production, slot=slot)
        work = _Hole(other, items, words, notation, plan, context, corr, cards)
        work._basis, work._concat_used = {}, set()
        alt = _implement_one(work)
        if alt.status != NOT_IMPLEMENTED:
            alt.id, alt.notes = result.id, alt.notes + [
                f"placed as {production} at {slot}: the derivation filed the part under {hole['production']}, whose "
                f"interface does not give what its equations read ({_short(result.reason, 200)})"]
            return alt
    return result


SET_PRODUCTIONS = ("Regularizers", "FieldWrapper", "ScheduleHook")
"""Productions whose slot is a set: the component joins it as a member (``custom_<hole>``)."""


def _member(slot: str, production: str, hid: str) -> str:
    return f"{slot}.custom_{hid}" if production in SET_PRODUCTIONS else slot


def _place(plan: Plan, slot: str, entry: dict, production: str = "", hid: str = "") -> None:
    """The compiled component at the hole's slot, through the production's `custom` alternative (a set's member)."""
    if production in SET_PRODUCTIONS:
        plan.set(_member(slot, production, hid), entry)
    else:
        plan.set(slot, {"custom": entry})


def revert(implementation: Implementation, hole_ids: list[str], reason: str) -> Plan:
    """The plan with the compiled components of ``hole_ids`` taken out again (the base's parts stand in), their
    records and holes saying why (a ladder rung failed on them)."""
    from nerfify_ns.synthesis.novel import prose

    plan = implementation.plan
    for r in implementation.records:
        if r.id not in hole_ids or r.status == NOT_IMPLEMENTED:
            continue
        if prose.revert(plan, r):  # typed terminals built from the paper's sentences
            pass
        elif r.production in SET_PRODUCTIONS:
            plan.delete(_member(r.slot, r.production, r.id))
        else:
            plan.set(r.slot, copy.deepcopy(r.replaced))
        implementation.sources.pop(r.component.get("module", ""), None)
        r.status = NOT_IMPLEMENTED
        r.reason = f"compiled, but {reason}; the base's part stands in"
        r.cause = cause_of(r.reason)
        r.checks["ladder"] = reason
        for h in plan.get("holes") or []:
            if h.get("slot") == r.slot:
                h["status"], h["reason"], h["compiled"], h["cause"] = NOT_IMPLEMENTED, r.reason, "", r.cause
                h["stands_in"] = h.get("stands_in_base", h.get("stands_in", ""))
    return plan


@dataclass
class _Sized:
    params: dict          # key -> ParamSpec
    widths: dict          # key -> int or None (inputs, networks, state, basis, outputs)
    evidence: dict
    solver: Any
    runtime: int = 0


def _sizes(work: _Hole, att: _Attempt, bindings: dict, runtime: int, small: bool) -> _Sized:
    solver, evidence = work.solve(att, bindings, runtime, small=small)
    params, widths = {}, {}
    for key, b in bindings.items():
        value = solver.value(key)
        if b["as"] == "parameter":
            params[key] = ParamSpec(tuple(int(v) for v in value))
        else:
            widths[key] = value[0] if value else None
    for key in att.outputs:
        value = solver.value(key)
        widths[key] = value[0] if value else None
    return _Sized(params, widths, evidence, solver, runtime)


def _inputs(att: _Attempt, bindings: dict, sized: _Sized) -> dict:
    """The equations module's inputs (every bound symbol but the parameters), with their layouts."""
    seq = sample_indexed_keys(att.equations)
    out = {}
    for key, b in bindings.items():
        if b["as"] in ("parameter", "constant"):
            continue
        per_sample = bool(b.get("per_sample")) or (key in seq and b["as"] == "network")
        width = sized.widths.get(key)
        out[key] = (("R", "S") if per_sample else ("R",)) + ((int(width),) if width else ())
    return out


def _outputs(att: _Attempt, bindings: dict) -> list[str]:
    return list(att.outputs) + [k for k, b in bindings.items() if b["as"] == "state"]


def _domains(work: _Hole, bindings: dict) -> dict:
    """The value range of each input in the check, from its role's range (a density is non-negative, a weight lies
    in [0, 1]): the check's default range (0.1, 0.9) clipped to it."""
    out = {}
    for key, b in bindings.items():
        role = work.notation.roles.get(b.get("role") or "")
        if b["as"] in ("parameter", "constant") or role is None or role.range == (None, None):
            continue
        lo, hi = role.range
        low = 0.1 if lo is None else max(0.1, float(lo) + 0.05)
        high = 0.9 if hi is None else min(0.9, float(hi) - 0.05)
        if low < high:
            out[key] = (low, high)
    return out


def _lower(work: _Hole, att: _Attempt, bindings: dict, sized: _Sized, class_name: str, check: bool):
    """Lower (and check) the equations through the one compile path (``equations.compile_equations``)."""
    return compile_equations(att.equations, _inputs(att, bindings, sized), _outputs(att, bindings), sized.params,
                             class_name, check=check, domains=_domains(work, bindings))


def _implement_one(work: _Hole) -> HoleResult:
    res = work.result
    own = work.hole_items()
    for it in own:
        _parse(it)
    if work.adapter is None:
        res.equations = [_record_equation(it, []) for it in own]
        res.reason = (f"the compiler has no adapter for the {res.production} production yet (it places components "
                      f"in: {', '.join(sorted(ADAPTERS))}); the base's part stands in")
        return res
    later = work.following(own)
    if not own and not later:
        res.reason = "no equation of the paper belongs to this part (the hole names none the reader found)"
        return res
    roots = work.roots(own, later)
    if not roots:
        res.equations = [_record_equation(it, []) for it in own + later]
        unread = [f"({it.number or '?'}) {f}" for it in own for f in it.failures()]
        res.reason = (f"no equation of the part defines what the {res.production} returns "
                      f"({', '.join(work.adapter.output_roles)})"
                      + (f"; equations not read: {'; '.join(unread)}" if unread else ""))
        return res
    failures: list[str] = []
    chosen = None
    for root_eqs, root_items, composite in roots:
        label = ", ".join(f"({e.number})" if e.number else f"'{safe_comment(e.defines or '?', 20)}'" for e in root_eqs)
        try:
            att, bindings = work.attempt(root_eqs, root_items, composite, own, work.items)
            small = _sizes(work, att, bindings, SMALL_RUNTIME, small=True)
            trial = _lower(work, att, bindings, small, "CheckedPart", check=False)
            if trial.lowered is None:
                raise CompileError(trial.reason)
            chosen = (att, bindings, small)
            break
        except (CompileError, WidthError) as err:
            failures.append(f"{label}: {err}")
        except Exception as err:  # noqa: BLE001 - the per-form boundary: this form's reason, the next is tried
            failures.append(f"{label}: could not compile: {describe(err)}")
    considered = list(own)
    if chosen is None:
        res.equations = [_record_equation(it, []) for it in considered]
        gives = ", ".join(sorted(work.provisions)) or "nothing"
        unread = [f"({it.number or '@' + str(it.position)}) {f}" for it in own for f in it.failures()]
        res.reason = (("equations not read: " + "; ".join(unread) + "; so " if unread else "") +
                      "no form of the part compiled: " + " || ".join(_dedupe(failures)[:4]) +
                      f" [the {res.production} interface gives: {gives}; bind a symbol or fix an equation in "
                      "equations.yaml]")
        return res
    att, bindings, small = chosen
    res.notes += att.dropped
    checked = _lower(work, att, bindings, small, "CheckedPart", check=True)
    res.checks = {"lowering": str(checked.report) if checked.report else checked.reason,
                  "check_sizes": {k: list(v.shape) for k, v in small.params.items()}}
    extra = [it for it in att.items if it is not None and not any(it is c for c in considered)]
    res.equations = [_record_equation(it, att.items) for it in considered + extra]
    if not checked.ok:
        res.reason = f"the compiled module failed its check against the interpreter: {checked.reason}"
        return res
    try:
        full = _sizes(work, att, bindings, FULL_RUNTIME, small=False)
        cls = _class_name(res.id)
        full_lowered = _lower(work, att, bindings, full, f"{cls}Equations", check=False)
        if full_lowered.lowered is None:
            raise CompileError(f"lowering at the paper's sizes: {full_lowered.reason}")
        wiring = _wiring(work, att, bindings, full_lowered.lowered, full, cls)
        equations_source = _runtime_width(full_lowered.lowered.source, FULL_RUNTIME, wiring, work.adapter)
    except (CompileError, WidthError) as err:
        res.reason = str(err)
        return res
    from nerfify_ns.synthesis.compose import CompositionError, _format_python

    module = f"components.{res.id}_equations"
    try:
        source = _format_python(component_source(work.adapter, wiring, equations_source, work.context),
                                module.replace(".", "/") + ".py")
    except CompositionError as err:
        res.reason = f"the generated component does not parse (a compiler bug): {err}"
        return res
    try:  # the component itself, built at the check's small sizes, on its interface's example inputs
        small_rt = _sizes(work, att, bindings, SMALL_SENTINEL, small=True)
        small_lowered = _lower(work, att, bindings, small_rt, f"{cls}Equations", check=False).lowered
        small_wiring = _wiring(work, att, copy.deepcopy(bindings), small_lowered, small_rt, cls, small=True)
        small_source = _runtime_width(small_lowered.source, SMALL_SENTINEL, small_wiring, work.adapter)
        problem = _selfcheck(component_source(work.adapter, small_wiring, small_source, work.context), cls,
                             res.production, small_wiring.params)
    except (CompileError, WidthError, AttributeError) as err:
        problem = f"{type(err).__name__}: {err}"
    if problem:
        res.reason = f"the generated component failed its own contract check (a compiler bug): {problem}"
        res.checks["component"] = problem
        return res
    res.checks["component"] = "passed: built and run on the interface's example inputs (nominal case), outputs " \
                              "against the contract, gradients finite"
    res.source = source
    numbers = sorted((f"Eq. {e.number}" for e in att.equations if e.number), key=_number_key)
    unnumbered: dict[str, int] = {}
    for e, it in zip(att.equations, att.items, strict=False):
        if not e.number and e is not att.composite and it is not None:
            unnumbered[it.section] = unnumbered.get(it.section, 0) + 1
    implements = numbers + [f"{n} unnumbered equation(s) of {section}" for section, n in unnumbered.items()]
    res.component = {"module": module, "class": cls, "params": wiring.params, "implements": implements,
                     "source": "compiler",
                     "evidence": _short(f"{', '.join(dict.fromkeys(it.section for it in att.items if it))}: "
                                        + "; ".join(show(e) for e in att.equations if e is not att.composite), 300)}
    res.bindings = {k: _plain_binding(b) for k, b in bindings.items()}
    res.sizes = {k: {"shape": list(v.shape), **full.evidence.get(k, {"source": "equations",
                                                                       "evidence": "fixed by the equations, the "
                                                                                   "roles' widths and the contract"})}
                 for k, v in full.params.items()}
    for key, b in bindings.items():
        if b["as"] in ("network", "state") and full.widths.get(key):
            res.sizes[key] = {"shape": [int(full.widths[key])],
                              **full.evidence.get(key, {"source": "equations", "evidence": "fixed by the equations"})}
    res.state = {k: {"rows": int(b.get("rows", 1)), "initial": b.get("initial", 0.0), "note": b.get("note", ""),
                     **({"rows_evidence": b["rows_evidence"]} if b.get("rows_evidence") else {})}
                 for k, b in bindings.items() if b["as"] == "state"}
    if att.composite is not None and "w_composite" in bindings:
        res.notes.append("the paper's colour is per sample where the Renderer's contract is per ray: the rendered "
                         f"colour is {', '.join(safe_comment(e.defines, 30) for e in att.roots)} composited with the "
                         "renderer's volume-rendering weights, sum_i w_i c_i")
    elif att.composite is not None:
        res.notes.append("the rendered colour is the sum over the samples of the per-sample contributions "
                         f"({', '.join(safe_comment(e.defines, 30) for e in att.roots)}), as NeRF's "
                         "C(r) = sum_i C_i(r)")
    res.notes += wiring.notes + _operator_discrepancies(work, att, full)
    res.notes += [f"'{safe_comment(k, 30)}' is per ray where the interface gives it per sample: the "
                  f"{safe_comment(str(b.get('role')), 30)} composited with the renderer's volume-rendering weights "
                  "(sum_i w_i x_i), as the production's contract is per ray" for k, b in bindings.items()
                  if b.get("composited")]
    unread = [e for e in res.equations if e["status"].startswith("not read")]
    not_needed = [e for e in res.equations if e["status"] == "not needed by the component's outputs"]
    touched = set(bindings) | {eq.defines for eq in att.equations}
    missed = [e for e in unread if _defines_text(e["latex"]) in touched]  # an unread definition the part uses
    res.status = PARTLY if (failures or missed) else IMPLEMENTED
    reasons = []
    if failures:
        reasons.append("later forms not compiled: " + " | ".join(failures[:3]))
    if unread:
        reasons.append(("equations not read: " if missed else "equations not read (the outputs compiled without "
                        "them): ") + "; ".join(
            f"({e['number'] or e.get('key')}) {e['status'][len('not read: '):]}" for e in unread[:4]))
    head = f"compiled from {', '.join(implements) or 'the composite output'}"
    if not_needed:
        head += "; not needed by its outputs: " + ", ".join(f"({e['number'] or e.get('key')})" for e in not_needed)
    res.reason = head + ("; " + "; ".join(reasons) if reasons else "")
    return res


def _runtime_width(source: str, sentinel: int, wiring: Wiring, adapter: Adapter) -> str:
    """A learned matrix that multiplies the interface's input has that input's width, known when the plugin is
    built (``in_dim``): the sentinel width it was lowered with becomes the constructor's ``in_dim``."""
    pattern = re.compile(rf"(?<![\d.]){sentinel}(?![\d.])")
    if not pattern.search(source):
        return source
    if not adapter.runtime_width:
        raise CompileError(f"a learned matrix multiplies an input of the {adapter.production} interface whose width "
                           "is known only when the plugin is built")
    source = pattern.sub("in_dim", source)
    source = source.replace("    def __init__(self):\n        super().__init__()",
                            "    def __init__(self, in_dim):\n        super().__init__()", 1)
    wiring.equations_args = adapter.runtime_width
    return source


def _operator_discrepancies(work: _Hole, att: _Attempt, sized: _Sized) -> list[str]:
    """Where the paper's words for an operator disagree with the shapes ("⊗ represents the dot product" between two
    vectors of one width, which the equations can only use element-wise): the shapes are followed, and said."""
    element_wise = [n for eq in att.equations for n in walk(eq.rhs) if isinstance(n, BinOp) and n.op == "odot"]
    notes = []
    for op, called, quote, where in work.words.operators:
        if called in ("dot", "inner", "scalar", "matrix", "outer", "kronecker") and element_wise:
            example = element_wise[0]
            try:
                width = sized.solver.shape(example.left)
            except Exception:  # noqa: BLE001 - a note only
                width = ()
            w = sized.solver.resolve(width[0]) if width else None
            notes.append(f"the paper calls {op} a {called} product ({where}: \"{_short(quote, 120)}\"), but the "
                         f"shapes ({show(example.left)} and {show(example.right)}, {w or 'one'} feature(s) each, whose "
                         "result is combined element-wise with vectors of that width) allow only an element-wise "
                         "product: compiled element-wise, following the shapes")
            break
    return notes


def _defines_text(latex: str) -> str | None:
    """The key of the symbol an equation's left side names, read from its LaTeX alone (for an equation the reader
    refused: a derivation step whose left side is an integral names none)."""
    from nerfify_ns.equations import parse_expression

    lhs = re.split(r"(?<![<>!\\])=", latex, maxsplit=1)[0] if "=" in latex else ""
    expr = parse_expression(lhs) if lhs.strip() else None
    return expr.key if isinstance(expr, Symbol) else None


def _dedupe(failures: list[str]) -> list[str]:
    """Failures of alternative forms, each symbol's reason once (later forms repeat earlier ones)."""
    seen, out = set(), []
    for f in failures:
        label, _, rest = f.partition(": ")
        parts = [p for p in rest.split(" | ") if p not in seen]
        seen.update(parts)
        if parts:
            out.append(f"{label}: " + " | ".join(parts))
    return out


def _number_key(text: str) -> tuple:
    digits = re.findall(r"\d+", text)
    return (int(digits[0]) if digits else 1 << 30, text)


def _selfcheck(source: str, cls: str, production: str, params: dict) -> str:
    """The component built and run once on its interface's example inputs (the registry's, nominal case), as the
    contract rung will: outputs against the contract, a backward pass with finite gradients. '' when it holds,
    else the problems. Our own generated code, run in this process (the ladder runs the plugin sandboxed)."""
    import torch

    from nerfify_ns.registry import default_registry
    from nerfify_ns.registry.contract import check_outputs
    from nerfify_ns.registry.examples import example_inputs

    interface = default_registry().interfaces[production]
    namespace: dict = {"__name__": "nerfify_compiled_component"}
    try:
        exec(compile(source, f"<compiled {cls}>", "exec"), namespace)  # noqa: S102 - our generated source
        torch.manual_seed(0)
        contract = interface.contract_for(params or {})
        env = contract.environment(params or {}, {}, {"case": "nominal"})
        known = {"in_dim": int(env["in_dim"]), "out_dim": None, "background_color": "white"}
        module = namespace[cls](**{k: known[k] for k in interface.ctor if k in known}, **(params or {}))
        if hasattr(module, "get_out_dim"):
            env["out_dim"] = int(module.get_out_dim())
        inputs = example_inputs(contract, env, "nominal")
        outputs = interface.call(module, inputs, env)
        problems = list(check_outputs(contract, outputs, env))
        total = sum(v.float().sum() for v in outputs.values() if isinstance(v, torch.Tensor) and v.requires_grad)
        if isinstance(total, torch.Tensor):
            total.backward()
            problems += [f"gradient of {n} not finite" for n, p in module.named_parameters()
                         if p.grad is not None and not torch.isfinite(p.grad).all()]
    except Exception as err:  # noqa: BLE001 - a compiler bug, reported with the component
        return f"raised {type(err).__name__}: {str(err).splitlines()[0][:200] if str(err) else ''}"
    return "; ".join(problems)[:400]


def _record_equation(it: Item, attempt_items: list) -> dict:
    reading = "; ".join(show(p) if isinstance(p, Equation) else f"not read: {p}" for p in it.parsed)
    if any(it is a for a in attempt_items if a is not None):
        status = "compiled"
    elif it.failures() and not it.equations():
        status = "not read: " + "; ".join(str(f) for f in it.failures())
    else:
        status = "not needed by the component's outputs"
    out = {"number": it.number, "latex": it.latex, "reading": reading, "status": status, "where": it.where}
    if not it.number:
        out["key"] = f"@{it.position}"
    if it.page:
        out["page"] = it.page
    if it.bbox:
        out["bbox"] = [round(float(v), 2) for v in it.bbox]
    if it.corrected:
        out["corrected"] = True
    return out


def _plain_binding(b: dict) -> dict:
    return {k: v for k, v in b.items() if k not in ("code", "per_sample", "width", "scalar") and v not in (None, "")}


def _class_name(hid: str) -> str:
    return "".join(part.capitalize() for part in re.split(r"[^a-zA-Z0-9]+", hid) if part) + "FromEquations"


def _wiring(work: _Hole, att: _Attempt, bindings: dict, lowered, sized: _Sized, cls: str,
            small: bool = False) -> Wiring:
    names = Names()
    w = Wiring(cls=cls, eq_cls=f"{cls}Equations")
    layers = work.words.layers[0] if work.words.layers else None
    width = work.words.widths[0] if work.words.widths else None
    depth_text = (f"{layers[0]} layers ({layers[2]}: \"{_short(layers[1], 100)}\")" if layers
                  else "2 layers (the paper states no depth)")
    width_text = (f"{width[0]} wide ({width[2]}: \"{_short(width[1], 100)}\")" if width
                  else "64 wide (the paper states no width)")
    for key, _ident, dims in lowered.inputs:
        b = bindings[key]
        local = names.get("a", key)
        if b["as"] == "network":
            net = NetSpec(key, names.get("net", key), None if b.get("scalar") else sized.widths.get(key),
                          layers[0] if layers else 2, width[0] if width else 64, b.get("activation"),
                          per_sample=("S" in dims), evidence=f"{depth_text}, {width_text}")
            w.networks.append(net)
            b["network"] = {"reads": work.adapter.network_input, "layers": net.layers, "width": net.width,
                            "out": net.out_width or 1, "activation": net.activation or "none",
                            "evidence": net.evidence}
            w.feeds.append(Feed(key, local, ""))
        elif b["as"] == "state":
            st = StateSpec(key, names.get("state", key), int(b.get("rows", 1)), int(sized.widths.get(key) or 1))
            w.states.append((st, ""))
            w.feeds.append(Feed(key, local, f"_read_state(self.{st.attr}, x)"))
        elif b["as"] == "basis":
            if work.context.get("dir_encoding") != "sh" or not work.context.get("dir_dim"):
                raise CompileError(f"'{safe_comment(b['basis'], 20)}' is the spherical-harmonics basis of the viewing "
                                   "direction: the plan's direction encoding must be `sh` for the colour head to "
                                   f"receive it (it is `{safe_comment(str(work.context.get('dir_encoding')), 20)}`)")
            channels, size = int(sized.widths.get(key) or 1), int(work.context["dir_dim"])
            net = NetSpec(b["coefficient"], names.get("net", b["coefficient"]), channels * size,
                          1, width[0] if width else 64, None,
                          evidence=f"a linear map of the geometry features to {channels} x {size} coefficients "
                                   f"(channels x the basis' size: levels {work.context.get('sh_levels')} of the "
                                   "plan's direction encoding)")
            w.networks.append(net)
            w.feeds.append(Feed(key, local, f"_basis_sum(self.{net.attr}(geometry), x[:, : self.dir_dim], {channels})"))
            b["network"] = {"reads": work.adapter.network_input, "layers": 1, "out": channels * size,
                            "evidence": net.evidence}
            b["size"] = size
            b["degree"] = (f"l_max = {int(work.context.get('sh_levels') or 1) - 1}: the plan's direction encoding "
                           f"(sh, levels {work.context.get('sh_levels')}; "
                           f"{_short(work.plan.evidence_for(work.context.get('dir_path', '')), 160)})")
        elif b["as"] == "constant":
            w.feeds.append(Feed(key, local, f"{float(b['value'])!r}"))
        else:
            w.feeds.append(Feed(key, local, b["code"]))
    if small:  # the self-check's variant: small networks and state
        for net in w.networks:
            net.width, net.layers = min(net.width, 8), min(net.layers, 2)
        w.states = [(StateSpec(st.key, st.attr, min(st.rows, 16), st.width), o) for st, o in w.states]
    for key, _ident in lowered.outputs:
        w.outputs.append((key, names.get("o", key), sized.widths.get(key)))
    w.states = [(st, next(o for k, o, _ in w.outputs if k == st.key)) for st, _ in w.states]
    production = work.adapter.production
    if production == "Backbone":
        widths_now = [sized.widths.get(k) or 1 for k in att.outputs]
        runtime = sized.runtime
        other = _sizes(work, att, bindings, runtime + 1, small=small)
        widths_next = [other.widths.get(k) or 1 for k in att.outputs]
        per_in = sum(widths_next) - sum(widths_now)
        fixed = sum(widths_now) - per_in * runtime
        w.out_dim = f"{fixed} + {per_in} * self.in_dim" if per_in else f"{fixed}"
    if len(w.networks) > 1 and not small:
        w.notes.append(f"one network per symbol ({', '.join(n.key for n in w.networks)}), each of the paper's depth "
                       "and width: a trunk the paper's architecture may share between them is not read from its text")
    if production == "Backbone" and len(att.outputs) > 1:
        w.notes.append(f"the Backbone interface has one output: the part's outputs ({', '.join(att.outputs)}) are "
                       "concatenated into it; the field's density head reads all of it, and its colour head reads it "
                       "with the encoded direction")
    if production == "Renderer":
        out_key = att.outputs[0] if att.outputs else ""
        if "S" in (lowered.layouts.get(out_key) or ()):
            w.composite_output = True
            w.notes.append(f"the part's output '{safe_comment(out_key, 30)}' is per sample where the Renderer's "
                           "contract is per ray: it is composited with the renderer's volume-rendering weights "
                           "(sum_i w_i x_i)")
        if any(b.get("role") == "ray_colour" and b["as"] == "input" for b in bindings.values()):
            w.notes.append("the ray's colour the part reads is the base's rendering (its weights, blended with the "
                           "background as Nerfstudio's RGBRenderer does)")
        else:
            w.notes.append("the base's background blending is not applied: the paper's rendering equation has no "
                           "background term (its own terms explain the whole ray)")
    if production == "RGBHead":
        w.params = {"dir_dim": int(work.context.get("dir_dim") or 0)}
    if production == "RGBLoss":
        (key,) = att.outputs
        w.loss_mean = True
        w.notes.append("the loss is reduced to a scalar by its mean over the batch (rays and channels), as "
                       "Nerfstudio's losses are")
    return w
