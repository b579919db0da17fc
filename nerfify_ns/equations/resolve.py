"""The meaning that depends on the whole equation: sample indices, what reductions run over, quadratures.

Run by ``parse_equation`` after the reading; everything here follows ``Conventions`` (notation NeRF
papers share), nothing paper-specific:

* **Sample indices.** A subscript is a sample index (``Symbol.index``) when a sum/product/integral binds
  it, or when it is a free index of the left-hand side (``T_i = ...``: ``i`` is in
  ``index_letters``; ``T(t) = ...``: ``t`` is a ray parameter). ``t_{i+1}`` is the index ``i`` shifted
  by one. A field at a point takes the point's index: ``T(s_i)``, ``\\sigma(\\mathbf{r}(t))``.
* **Reductions.** ``\\sum_{i=1}^{N}``, ``\\sum_i`` (N a sample count): over every sample of the ray;
  ``\\sum_{j<i}``, ``\\sum_{j=1}^{i-1}``: exclusive, over the samples before ``i``; ``\\sum_{j\\le i}``,
  ``\\sum_{j=1}^{i}``: inclusive; ``\\sum_{\\mathbf{r}\\in\\mathcal{R}}``: over the batch of rays;
  ``\\sum_{k=0}^{L-1}`` (a number or a size as the upper limit): a finite range, ``k`` a number.
* **Integrals along the ray** become their quadrature over the samples (``Integral.quadrature``):
  ``\\int_{t_n}^{t} f(s) ds`` (upper limit the outer position) -> ``\\sum_{j<i} f_j \\delta_j``;
  ``\\int T \\sigma X dt`` (the volume-rendering integral: one density factor and a transmittance
  factor) -> ``\\sum_i T_i (1 - \\exp(-\\sigma_i \\delta_i)) X_i`` (Max 1995, exact for piecewise-constant
  density); any other -> the Riemann sum ``\\sum_i f_i \\delta_i``.
* **Expectations** ``\\mathbb{E}_{\\mathbf{r}}`` are over rays.
"""

from __future__ import annotations

import re
from dataclasses import replace

from .ir import (
    Apply,
    BinOp,
    Cases,
    Compare,
    Concat,
    Conventions,
    Equation,
    Expectation,
    Expr,
    Index,
    Integral,
    Neg,
    Norm,
    Number,
    Reduce,
    Symbol,
    walk,
)

_INDEX_LABEL = re.compile(r"([A-Za-z]'*)([+-][0-9]{1,2})?")


class ResolveError(Exception):
    def __init__(self, reason: str, fragment: str = ""):
        super().__init__(reason)
        self.reason, self.fragment = reason, fragment


def _plain(sym: Expr) -> bool:
    return isinstance(sym, Symbol) and not (sym.subscripts or sym.superscript or sym.args or sym.index)


class _Resolver:
    def __init__(self, conventions: Conventions, free: str | None):
        self.c = conventions
        self.free = free               # the left side's sample index
        self.found_free: set[str] = set()

    # scope: dict var -> 'sample' | 'ray' | 'range'
    def expr(self, e: Expr, scope: dict[str, str]) -> Expr:
        if isinstance(e, Symbol):
            return self.symbol(e, scope)
        if isinstance(e, Number):
            return e
        if isinstance(e, BinOp):
            return BinOp(e.op, self.expr(e.left, scope), self.expr(e.right, scope))
        if isinstance(e, Neg):
            return Neg(self.expr(e.arg, scope))
        if isinstance(e, Apply):
            return Apply(e.func, tuple(self.expr(a, scope) for a in e.args))
        if isinstance(e, Compare):
            return Compare(e.op, self.expr(e.left, scope), self.expr(e.right, scope))
        if isinstance(e, Norm):
            return Norm(self.expr(e.arg, scope), e.order)
        if isinstance(e, Concat):
            return Concat(tuple(self.expr(a, scope) for a in e.items))
        if isinstance(e, Cases):
            return Cases(tuple((self.expr(v, scope), None if c is None else self.expr(c, scope))
                               for v, c in e.branches))
        if isinstance(e, Expectation):
            if e.index not in self.c.ray_indices:
                raise ResolveError(f"an expectation over '{e.index}': only expectations over rays are read",
                                   e.index)
            return Expectation(e.index, self.expr(e.body, {**scope, e.index: "ray"}))
        if isinstance(e, Reduce):
            return self.reduce(e, scope)
        if isinstance(e, Integral):
            return self.integral(e, scope)
        raise ResolveError("unknown node", type(e).__name__)  # pragma: no cover

    # --- symbols -------------------------------------------------------------------------------------------
    def symbol(self, s: Symbol, scope: dict[str, str]) -> Symbol:
        if _plain(s) and scope.get(s.name) in ("sample", "range"):
            return replace(s, index=Index(s.name))  # the position t itself, or the number k of a range
        labels, index = [], s.index
        for label in s.subscripts:
            m = _INDEX_LABEL.fullmatch(label)
            var = m.group(1) if m else None
            kind = scope.get(var) if var else None
            if var and index is None and kind == "sample":
                index = Index(var, int(m.group(2) or 0))
            elif var and index is None and kind == "ray":
                continue  # C_r: per ray anyway
            elif var and kind == "range":
                labels.append(label)  # k_l^m: read; evaluating it is refused (a basis the binder supplies)
            elif var and index is None and var in self.c.index_letters and var not in scope:
                self.found_free.add(var)
                index = Index(var, int(m.group(2) or 0))
            else:
                labels.append(label)
        args = tuple(self.expr(a, scope) for a in s.args)
        if index is None:
            index = self._index_of_args(args, scope)
        return Symbol(s.name, tuple(labels), s.superscript, s.decorations, index, args)

    def _index_of_args(self, args, scope) -> Index | None:
        for a in args:
            if isinstance(a, Symbol):
                if a.index is not None and scope.get(a.index.var, "sample") == "sample":
                    return a.index
                if _plain(a) and a.name in self.c.ray_params and a.name not in scope:
                    self.found_free.add(a.name)
                    return Index(a.name)
                inner = self._index_of_args(a.args, scope)
                if inner is not None:
                    return inner
        return None

    # --- reductions ----------------------------------------------------------------------------------------
    def reduce(self, r: Reduce, scope: dict[str, str]) -> Reduce:
        index = r.index or self._infer_index(r.body, scope)
        axis, mode, outer = self._classify(r, index, scope)
        inner = {**scope, index: {"samples": "sample", "rays": "ray", "range": "range"}[axis]}
        lower, upper = r.lower, r.upper
        if axis == "range":
            lower, upper = self.expr(lower, scope), self.expr(upper, scope)
        condition = r.condition
        return Reduce(r.kind, index, lower, upper, condition, self.expr(r.body, inner), axis, mode, outer)

    def _infer_index(self, body: Expr, scope) -> str:
        seen = []
        for node in walk(body):
            if isinstance(node, Symbol):
                for label in node.subscripts:
                    if label in self.c.index_letters and label not in scope and label not in seen:
                        seen.append(label)
        if len(seen) != 1:
            raise ResolveError("a sum or product without an index (and none to infer)", "\\sum")
        return seen[0]

    def _classify(self, r: Reduce, index: str, scope) -> tuple[str, str, str | None]:
        cond, lower, upper = r.condition, r.lower, r.upper
        if cond is not None and cond.op == "in":
            target = cond.right
            if isinstance(target, Symbol) and target.name in self.c.ray_sets and not target.subscripts \
                    and not target.args:
                return "rays", "full", None
            raise ResolveError("a sum over a set other than the batch of rays", getattr(target, "key", "in"))
        if cond is not None:
            if not (isinstance(cond.right, Symbol) and _plain(cond.right) and scope.get(cond.right.name) == "sample"):
                raise ResolveError(f"a range condition on '{index}' not relative to a sample index", index)
            if cond.op == "<":
                return "samples", "exclusive", cond.right.name
            if cond.op == "<=":
                return "samples", "inclusive", cond.right.name
            raise ResolveError(f"a range '{index} {cond.op} {cond.right.name}' is not read", index)
        if lower is not None and not (isinstance(lower, Number) and lower.value in (0.0, 1.0)):
            if upper is None or self._is_sample_upper(upper, scope):
                raise ResolveError("a sum over samples that does not start at the first sample", index)
        if upper is None and lower is None and self._indexes_rays(r.body, index):
            return "rays", "full", None  # sum_{i,k} f(r_i(t_k)): i numbers the rays, k their samples
        if upper is None:
            if index in self.c.ray_indices and lower is None:
                return "rays", "full", None
            return "samples", "full", None
        if isinstance(upper, Symbol) and _plain(upper) and scope.get(upper.name) == "sample":
            return "samples", "inclusive", upper.name
        if (isinstance(upper, BinOp) and upper.op == "-" and isinstance(upper.left, Symbol) and _plain(upper.left)
                and scope.get(upper.left.name) == "sample" and isinstance(upper.right, Number)
                and upper.right.value == 1.0):
            return "samples", "exclusive", upper.left.name
        if self._is_sample_upper(upper, scope):
            return "samples", "full", None
        if (isinstance(upper, Symbol) and _plain(upper) and upper.name in self.c.index_letters) or any(
                isinstance(n, Symbol) and _plain(n) and n.name in self.c.index_letters and n.name not in scope
                for n in walk(upper)):
            raise ResolveError(f"the limit of '{index}' names an index that nothing binds", index)
        if lower is None:
            raise ResolveError(f"a finite range over '{index}' without a lower limit", index)
        return "range", "full", None

    def _indexes_rays(self, body: Expr, index: str) -> bool:
        """Whether ``index`` numbers the rays in ``body``: it subscripts a ray (``\\mathbf{r}_i``)."""
        return any(isinstance(n, Symbol) and n.name in self.c.ray_indices and index in n.subscripts
                   for n in walk(body))

    def _is_sample_upper(self, upper: Expr, scope) -> bool:
        return isinstance(upper, Symbol) and not upper.args and upper.key in self.c.sample_counts

    # --- integrals -----------------------------------------------------------------------------------------
    def integral(self, g: Integral, scope: dict[str, str]) -> Integral:
        v = g.var
        if v in scope:
            raise ResolveError(f"the integration variable '{v}' is already bound", v)
        body = self.expr(g.body, {**scope, v: "sample"})
        step = Symbol(self.c.step, index=Index(v))
        up = g.upper
        if isinstance(up, Symbol) and _plain(up) and scope.get(up.name) == "sample":
            quad = Reduce("sum", v, None, None, Compare("<", Symbol(v), Symbol(up.name)), BinOp("*", body, step),
                          "samples", "exclusive", up.name)
            return Integral(v, g.lower, g.upper, body, quad, "left Riemann sum over the earlier samples")
        factors = _factors(body)
        dens = [k for k, f in enumerate(factors) if isinstance(f, Symbol) and f.name in self.c.density
                and f.index == Index(v)]
        trans = [f for f in factors if (isinstance(f, Symbol) and f.name in self.c.transmittance
                                        and f.index == Index(v)) or _is_exp_of_cumulative(f)]
        if len(dens) == 1 and trans:
            sigma = factors[dens[0]]
            alpha = BinOp("-", Number(1.0, "1"), Apply("exp", (Neg(BinOp("*", sigma, step)),)))
            new = factors[:dens[0]] + [alpha] + factors[dens[0] + 1:]
            quad = Reduce("sum", v, None, None, None, _product(new), "samples", "full", None)
            return Integral(v, g.lower, g.upper, body, quad,
                            "volume-rendering quadrature: sigma dt -> 1 - exp(-sigma_i delta_i)")
        quad = Reduce("sum", v, None, None, None, BinOp("*", body, step), "samples", "full", None)
        return Integral(v, g.lower, g.upper, body, quad, "Riemann sum over the samples")


def _factors(e: Expr) -> list[Expr]:
    out = []
    while isinstance(e, BinOp) and e.op == "*":
        out.insert(0, e.right)
        e = e.left
    out.insert(0, e)
    return out


def _product(factors: list[Expr]) -> Expr:
    result = factors[0]
    for f in factors[1:]:
        result = BinOp("*", result, f)
    return result


def _is_exp_of_cumulative(e: Expr) -> bool:
    """``\\exp(-\\int_{t_n}^{t} \\sigma)`` or ``\\exp(-\\sum_{j<i} ...)``: a transmittance written out."""
    if not (isinstance(e, Apply) and e.func == "exp"):
        return False
    return any(isinstance(n, Reduce) and n.mode == "exclusive" for n in walk(e.args[0]))


def _lhs_free(lhs: Symbol, rhs: Expr, c: Conventions) -> str | None:
    for label in lhs.subscripts:
        m = _INDEX_LABEL.fullmatch(label)
        if m and m.group(1) in c.index_letters and not m.group(2):
            return m.group(1)
    limits = set()
    for node in walk(rhs):
        for bound in ((node.upper,) if isinstance(node, Integral | Reduce) else ()):
            if isinstance(bound, Symbol) and _plain(bound):
                limits.add(bound.name)
        if isinstance(node, Reduce) and node.condition is not None and isinstance(node.condition.right, Symbol):
            limits.add(node.condition.right.name)
    for arg in lhs.args:
        if _plain(arg) and (arg.name in c.ray_params or arg.name in limits):
            return arg.name
        if isinstance(arg, Symbol) and len(arg.subscripts) == 1 and arg.subscripts[0] in c.index_letters:
            return arg.subscripts[0]  # T(s_i)
    return None


def resolve(equation: Equation, conventions: Conventions) -> Equation:
    """Fill sample indices, reduction axes and integral quadratures (see the module docstring)."""
    lhs = equation.lhs
    if not isinstance(lhs, Symbol):
        from .show import show

        raise ResolveError("the left side is not a symbol", show(lhs)[:40])
    free = _lhs_free(lhs, equation.rhs, conventions)
    resolver = _Resolver(conventions, free)
    scope = {free: "sample"} if free else {}
    rhs = resolver.expr(equation.rhs, scope)
    also = tuple(resolver.expr(e, scope) for e in equation.also)
    stray = resolver.found_free - ({free} if free else set())
    if free is None and len(stray) == 1:
        free = stray.pop()  # L = -log P(T_i): a per-sample result
    elif stray:
        raise ResolveError(f"free index '{sorted(stray)[0]}' on the right side only", sorted(stray)[0])
    lhs_resolved = resolver.symbol(Symbol(lhs.name, lhs.subscripts, lhs.superscript, lhs.decorations),
                                   {free: "sample"} if free else {})
    lhs_args = tuple(lhs.args)
    if free and lhs_resolved.index is None:
        lhs_resolved = replace(lhs_resolved, index=Index(free))
    if lhs_resolved.index is not None and lhs_resolved.index.offset:
        raise ResolveError("a shifted index on the left side", lhs.key)
    lhs_resolved = replace(lhs_resolved, args=lhs_args)
    return replace(equation, lhs=lhs_resolved, rhs=rhs, also=also, free_index=free)
