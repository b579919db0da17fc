"""One hole's equations bound to a production's interface (``_Hole``): which equations define what the production
returns (the paper's latest form first), the closure of equations they need, what every free symbol is (a
person's correction, the interface by role, a composite per ray of a per-sample quantity, a learned parameter, a
standard basis, persistent state, a constant the text states, a network the paper names) and the sizes of it all
(``solve``). Raises ``_Unbound`` naming what is missing; ``component.py`` lowers what is bound."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from nerfify_ns import runfolder
from nerfify_ns.equations import (
    Apply,
    BinOp,
    Concat,
    Equation,
    Index,
    Number,
    Reduce,
    Symbol,
)
from nerfify_ns.equations.ir import inline_functions, walk
from nerfify_ns.equations.shapes import CompileError, is_bound_variable, uses
from nerfify_ns.equations.show import safe_comment, show
from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.novel.adapters import (
    ADAPTERS,
    RUNTIME,
    Adapter,
    Provision,
)
from nerfify_ns.synthesis.novel.items import Item, _norm, describe
from nerfify_ns.synthesis.novel.items import _parse as _parse_item  # noqa: PLC2701
from nerfify_ns.synthesis.novel.notation import Definition, Notation, PaperWords, _short
from nerfify_ns.synthesis.novel.objective import sums_over
from nerfify_ns.synthesis.novel.results import HoleResult
from nerfify_ns.synthesis.novel.widths import Widths

MAX_ROOTS = 8
_DEFINING = ("=", ":=", "propto")  # relations that define their left side (propto: up to a constant factor)


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
    own_weights: list = field(default_factory=list)  # Symbol: a loss term's own weight, taken out of its equation


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
        own += self._unnumbered_after(own)
        for it in own:
            it.in_hole = True
        return own

    def _unnumbered_after(self, own: list[Item]) -> list[Item]:
        """Unnumbered blocks right after one of the part's equations in its section (the "where the terms are:"
        block that defines what the numbered equation adds up)."""
        claimed = {_norm(e.get("latex", "")) for h in self.plan.get("holes") or [] if isinstance(h, dict)
                   and h is not self.hole for e in h.get("equations") or [] if isinstance(e, dict) and e.get("latex")}
        out = []
        for it in own:
            _parse_item(it)
            read = set().union(*(uses(e) for e in it.equations()))
            after = sorted((x for x in self.items if x.section == it.section and x.position > it.position),
                           key=lambda x: x.position)
            for nxt in after:  # up to the next numbered equation or one of the part's own
                if nxt.number or nxt in own or nxt in out:
                    break
                _parse_item(nxt)
                if _norm(nxt.latex) not in claimed and any(e.defines in read for e in nxt.equations()):
                    out.append(nxt)
        return out

    def following(self, own: list[Item]) -> list[Item]:
        """Equations of the section right after the hole's last one (a paper's final form of the part)."""
        if not own:
            return []
        last = max(it.position for it in own)
        section = next((it.section for it in self.items if it.position > last and it.section != own[-1].section), None)
        if section in self._other_parts_sections():  # another part's own equations, built there
            return []
        return [it for it in self.items if it.section == section and it.position > last] if section else []

    def _other_parts_sections(self) -> set[str]:
        """The sections another novel part of the plan stands on (its own equations are that part's)."""
        mine = {self.hole.get("section"), *(self.hole.get("sections") or [])}
        out = set()
        for h in self.plan.get("holes") or []:
            if isinstance(h, dict):
                out |= {h.get("section"), *(h.get("sections") or [])}
        return {s for s in out - mine if s}

    def definitions(self, pool: list[Item]) -> dict[str, list[tuple[Equation, Item]]]:
        out: dict[str, list] = {}
        for it in pool:
            for eq in it.equations():
                if eq.defines and eq.relation in _DEFINING:
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
            eqs = [(eq, it) for it in own for eq in it.equations() if eq.defines and eq.relation in _DEFINING]
            defined = {eq.defines for eq, _ in eqs}
            used = set()
            for eq, _ in eqs:
                used |= {k for k in uses(eq) if k != eq.defines}
            sinks = [(eq, it) for eq, it in eqs if eq.defines not in used and not isinstance(eq.rhs, Number)]
            return [([eq for eq, _ in sinks], [it for _, it in sinks], None)] if sinks and defined else []
        found = []
        for it in sorted(later + own, key=lambda x: -x.position):
            for eq in reversed(it.equations()):
                if not eq.defines or eq.relation not in _DEFINING or not isinstance(eq.lhs, Symbol):
                    continue
                d = self.role_of(eq.lhs)
                if d is None or d.role not in adapter.output_roles:
                    continue
                found.append((eq, it))
        defined = {eq.defines for eq, _ in found}
        found = [(eq, it) for eq, it in found if not sums_over(eq, defined)]  # an objective adding up parts
        candidates = []
        seen = set()
        for eq, it in found:
            contribution = adapter.production == "Renderer" and eq.free_index is not None
            if contribution:  # per-sample contributions of one block or section: their sum over the samples
                group = [(e, other) for other in sorted(later + own, key=lambda x: x.position)
                         if other is it or (other.section and other.section == it.section)
                         for e in other.equations() if e.free_index is not None and e.defines
                         and isinstance(e.lhs, Symbol)
                         and (self.role_of(e.lhs) or Definition("", "")).role in adapter.output_roles]
                key = tuple(e.defines for e, _ in group)
                if key in seen:
                    continue
                seen.add(key)
                weighted = not any(self._weighs(e) for e, _ in group)
                candidates.append(([e for e, _ in group], [other for _, other in group],
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
        self._own_weights, self._observed = [], None
        defs = self.definitions(pool)
        self._defs = defs
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
        self._observed = self._observation(free)
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
        return _Attempt(equations, outputs, items, composite, notes, list(roots), list(self._own_weights)), bindings

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
        rhs = self._own_weight(rhs, eq, notes)
        rhs = self._batch_mean(rhs, eq, notes)
        rhs = self._bind_bases(rhs, eq, notes)
        rhs = self._inline_functions(rhs, eq, notes)
        if eq.relation == "propto":  # a definition up to a constant factor: the factor is 1, said in the record
            notes.append(f"({eq.number or '?'}) {safe_comment(eq.defines or '?', 30)} is defined up to a constant "
                         "factor (\\propto) the paper does not give: taken as 1 (under a logarithm, as in a "
                         "negative log-likelihood, the factor only shifts the loss by a constant)")
            return Equation(eq.lhs, rhs, eq.number, "=", eq.source, eq.also, eq.free_index)
        if rhs is eq.rhs:
            return eq
        return Equation(eq.lhs, rhs, eq.number, eq.relation, eq.source, eq.also, eq.free_index)

    def _own_weight(self, rhs, eq: Equation, notes: list[str]):
        """A regulariser written with its own weight (``L_s = lambda_s sum_{i,k} ...``): the weight is the term's
        weight in the total loss (the plugin adds the component times it), not a quantity the component computes;
        the factor is taken out and said, and its value is resolved where the paper states it."""
        if self.adapter.production != "Regularizers" or not (isinstance(rhs, BinOp) and rhs.op == "*"):
            return rhs
        for weight, rest in ((rhs.left, rhs.right), (rhs.right, rhs.left)):
            d = self.role_of(weight) if isinstance(weight, Symbol) else None
            if d is not None and d.role == "loss_weight" and \
                    not any(isinstance(n, Symbol) and n.key == weight.key for n in walk(rest)):
                self._own_weights.append(weight)
                notes.append(f"({eq.number or '?'}) {safe_comment(weight.key, 30)}: the term's own weight in the "
                             "paper's equation, applied as the regulariser's weight in the loss (the component "
                             "computes the term without it)")
                return rest
        return rhs

    def _batch_mean(self, rhs, eq: Equation, notes: list[str]):
        """A loss written as the mean over the batch's rays (``\\frac{1}{|\\mathcal{R}|} \\sum_{\\mathbf{r} \\in
        \\mathcal{R}} ...``): the per-ray term, which the loss's interface averages over the batch."""
        if self.adapter.production not in ("RGBLoss", "Regularizers"):
            return rhs
        pairs = []
        if isinstance(rhs, BinOp) and rhs.op == "*":
            pairs = [(rhs.left, rhs.right), (rhs.right, rhs.left)]
        elif isinstance(rhs, BinOp) and rhs.op == "/":
            pairs = [(BinOp("/", Number(1.0), rhs.right), rhs.left)]
        for scale, total in pairs:
            if not (isinstance(total, Reduce) and total.kind == "sum" and total.axis == "rays"
                    and total.condition is not None and isinstance(scale, BinOp) and scale.op == "/"
                    and isinstance(scale.left, Number) and scale.left.value == 1.0):
                continue
            size = scale.right
            counted = size.args[0] if isinstance(size, Apply) and size.func == "abs" and len(size.args) == 1 else None
            if isinstance(counted, Symbol) and getattr(total.condition.right, "key", None) == counted.key:
                notes.append(f"({eq.number or '?'}) the sum over the rays divided by their number "
                             f"|{safe_comment(counted.key, 20)}| is the mean over the batch: the per-ray term, "
                             "averaged by the loss")
                return total.body
        return rhs

    def _inline_functions(self, expr, eq, notes):
        """A function the paper defines with a dummy argument (``P(x) \\propto e^{-|x|/0.1} + ...``) and applies to
        a quantity (``-\\log P(T_i)``): its definition with the argument put in, said in the record."""
        defs = {key: [d for d, _ in options] for key, options in (getattr(self, "_defs", None) or {}).items()}
        out, applied = inline_functions(expr, defs)
        for call, definition, params in applied:
            notes.append(f"({eq.number or '?'}) {safe_comment(call.key, 30)}: the function the paper defines in "
                         f"({definition.number or '?'}) with its argument "
                         f"{', '.join(safe_comment(p.key, 20) for p in params)} replaced by "
                         f"{', '.join(safe_comment(show(a), 30) for a in call.args)}")
            if definition.relation == "propto":
                notes.append(f"({definition.number or '?'}) {safe_comment(call.key, 30)} is defined up to a constant "
                             "factor (\\propto) the paper does not give: taken as 1 (under a logarithm, as in a "
                             "negative log-likelihood, the factor only shifts the loss by a constant)")
        return out

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
        if key == self._observed:
            self._provision_used["target_colour"] = key
            return self._input("target_colour", "convention", "the plain symbol of an estimate and its observation "
                               "(C and its hat): the observed colour")
        if role in self.provisions and self.provisions[role].columns:
            return self._column(key, sym, role, where)
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
            out = {"as": "parameter", "role": "learned", "source": "paper",
                   "evidence": f"{learned[1]}: \"{_short(learned[0])}\"", "matrix": matrix, "learned": True,
                   **({"scalar": True} if greek and not matrix else {})}
            constraint = self.words.constraint(sym)
            if constraint is not None:  # the paper's range, applied to the learned values at every step
                out["clamp"] = [constraint[0], constraint[1]]
                out["clamp_evidence"] = f"{constraint[3]}: \"{_short(constraint[2], 400)}\""
            shape = self.words.shape_of(sym) if matrix else None
            if shape:
                out["stated_shape"] = [int(v) for v, _, _ in shape]
                out["shape_evidence"] = f"{shape[0][2]}: \"{_short(shape[0][1])}\""
            return out
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

    def _observation(self, free: dict) -> str | None:
        """Of two rendered colours a loss compares, ``C`` and ``\\hat{C}`` (both a ray's colour in the notation, no
        ground truth named), the plain one is the observation: a hat marks the estimate (the render)."""
        if "target_colour" not in self.provisions:
            return None
        colours = {key: sym for key, (sym, _) in free.items() if sym is not None
                   and (self.role_of(sym) or Definition("", "")).role == "ray_colour"}
        hatted = [sym for sym in colours.values() if "hat" in sym.decorations]
        plain = [key for key, sym in colours.items() if not sym.decorations]
        if len(colours) == 2 and len(hatted) == 1 and len(plain) == 1 and \
                hatted[0].name == colours[plain[0]].name:
            return plain[0]
        return None

    def _column(self, key: str, sym: Symbol, role: str, where: str) -> dict:
        """A quantity the interface gives one column per output of a decomposition (the blended fields' shares of a
        sample): the column is the symbol's place in the tuple the paper writes the decomposition's outputs as."""
        prov = self.provisions[role]
        place = self.words.outputs.get(_loose(sym))
        if place is None:
            raise _Unbound(f"'{safe_comment(key, 40)}' ({where}): a {role} the {self.adapter.production} interface "
                           "gives one per blended field, but the paper writes no tuple of outputs (f: x -> (P_1, ..., "
                           "P_K)) that places it among them")
        column, count, quote, where2 = place
        return {**self._input(role, "paper", f"{where2}: \"{_short(quote)}\""),
                "code": prov.code.format(column=column), "count": count,
                "note": f"output {column + 1} of the {count} the paper's decomposition gives: the share of the "
                        f"blend's field {column + 1} (the fields in the decomposition's order)"}

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
        for key, b in bindings.items():  # a learned matrix's stated shape fills what the equations leave open
            if b["as"] == "parameter" and b.get("stated_shape") and len(b["stated_shape"]) == len(w.shapes[key]):
                for i in w.open(key):
                    w.set(w.shapes[key][i], stated(b["stated_shape"][i]))
                evidence[key] = {"source": "paper", "evidence": b["shape_evidence"]}
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
