"""An independent numpy float64 interpreter of the IR: the oracle the torch lowering is checked against.

``interpret(equations, bindings, layout=None, sizes=None, outputs=None)`` -> {key: array}.

Written for clarity, not speed, and on purpose unlike the lowering: every value carries the names of its
batch axes (``R`` and one axis per sample index in scope, e.g. ``("R", "i", "j")``) and operands are
aligned by name; cumulative reductions over earlier samples (``\\sum_{j<i}``, ``\\prod_{j=1}^{i-1}``) are
the masked sum/product over the pair of axes (i, j) straight from their definition, where the lowering
uses cumulative sums in log space; a finite range is a Python loop.

Bounded before it evaluates anything: ``shapes.check_cost`` refuses equations whose finite ranges (nested
ranges multiplied) or operations are past ``MAX_RANGE_ITERATIONS`` / ``MAX_OPERATIONS``, and the iterations run
are counted as they run (a range limit read from a binding is known only then).

Bindings follow ``shapes.py`` (``[R, S, ...]`` per sample, ``[R, ...]`` per ray, parameters as shaped);
without a layout, a symbol used with a sample index is per-sample, a parameter of ``sizes`` is as given,
a 0-d value is a scalar, and anything else is per ray.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .ir import (
    Apply,
    BinOp,
    Cases,
    Compare,
    Concat,
    Equation,
    Expectation,
    Expr,
    Integral,
    Neg,
    Norm,
    Number,
    ParseFailure,
    Reduce,
    Symbol,
)
from .shapes import (
    MAX_RANGE,
    MAX_RANGE_ITERATIONS,
    RAY,
    SAMPLE,
    CompileError,
    ShapeError,
    check_cost,
    check_layout,
    component_base,
    is_bound_variable,
    named_sizes,
    param_specs,
    sample_indexed_keys,
    schedule,
)

_IMPLICIT = "@S"


@dataclass
class Val:
    """An array whose leading dimensions are the named batch axes, the rest features."""

    a: np.ndarray
    axes: tuple[str, ...]

    @property
    def feat(self) -> tuple[int, ...]:
        return self.a.shape[len(self.axes):]


class _Eval:
    def __init__(self, values: dict[str, Val], sizes: dict, n_rays: int | None, n_samples: int | None):
        self.values, self.sizes = values, sizes
        self.n_rays, self.n_samples = n_rays, n_samples
        self.order: list[str] = [RAY]
        self.sample_vars: list[str] = []
        self.ranges: dict[str, float] = {}
        self.range_lo: dict[str, int] = {}
        self.where = ""
        self.iterations = 0  # of finite ranges, all together: the static check's bound, kept while running

    # --- alignment -----------------------------------------------------------------------------------------
    def _rank(self, axis: str) -> int:
        return self.order.index(axis) if axis in self.order else len(self.order)

    def align(self, *vals: Val, features: bool = True) -> tuple[list[np.ndarray], tuple[str, ...]]:
        axes = tuple(sorted({a for v in vals for a in v.axes}, key=self._rank))
        fr = max(len(v.feat) for v in vals) if features else 0
        out = []
        for v in vals:
            present = [a for a in axes if a in v.axes]
            perm = [v.axes.index(a) for a in present] + list(range(len(v.axes), v.a.ndim))
            arr = np.transpose(v.a, perm)
            shape = []
            k = 0
            for a in axes:
                if a in v.axes:
                    shape.append(arr.shape[k])
                    k += 1
                else:
                    shape.append(1)
            feat = arr.shape[len(present):]
            pad = (fr - len(feat)) if features else 0
            out.append(arr.reshape(tuple(shape) + (1,) * pad + tuple(feat)))
        return out, axes

    def binary(self, fn, x: Val, y: Val) -> Val:
        (a, b), axes = self.align(x, y)
        try:
            return Val(fn(a, b), axes)
        except ValueError as err:
            raise ShapeError(f"{self.where}: shapes {x.feat} and {y.feat} do not combine ({err})") from None

    # --- nodes ---------------------------------------------------------------------------------------------
    def ev(self, e: Expr) -> Val:
        if isinstance(e, Number):
            return Val(np.asarray(e.value, dtype=np.float64), ())
        if isinstance(e, Symbol):
            return self.symbol(e)
        if isinstance(e, Neg):
            v = self.ev(e.arg)
            return Val(-v.a, v.axes)
        if isinstance(e, BinOp):
            return self.binop(e)
        if isinstance(e, Apply):
            return self.apply(e)
        if isinstance(e, Compare):
            fn = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal, "==": np.equal,
                  "!=": np.not_equal}.get(e.op)
            if fn is None:
                raise CompileError(f"{self.where}: the condition '{e.op}' is not evaluated")
            return self.binary(fn, self.ev(e.left), self.ev(e.right))
        if isinstance(e, Norm):
            return self.norm(e)
        if isinstance(e, Concat):
            return self.concat(e)
        if isinstance(e, Cases):
            return self.cases(e)
        if isinstance(e, Expectation):
            v = self.ev(e.body)
            if RAY not in v.axes:
                return v
            return Val(v.a.mean(axis=v.axes.index(RAY)), tuple(a for a in v.axes if a != RAY))
        if isinstance(e, Reduce):
            return self.reduce(e)
        if isinstance(e, Integral):
            if e.quadrature is None:
                raise CompileError(f"{self.where}: an integral without its quadrature (not resolved)")
            return self.ev(e.quadrature)
        raise CompileError(f"{self.where}: cannot evaluate {type(e).__name__}")

    def symbol(self, s: Symbol) -> Val:
        if is_bound_variable(s):
            if s.name in self.ranges:
                return Val(np.asarray(self.ranges[s.name], dtype=np.float64), ())
        key = s.key
        looped = [lab for lab in s.subscripts + ((s.superscript,) if s.superscript else ()) if lab in self.ranges]
        base = component_base(s, set(self.ranges)) if looped else s
        if base is not s and base.key in self.values:  # a_k in a sum over k: the k-th component of a's features
            v = self.symbol(base)
            (var,) = [lab for lab in s.subscripts if lab in self.ranges]
            if v.a.ndim > len(v.axes):
                k = int(self.ranges[var]) - self.range_lo[var]
                if not 0 <= k < v.a.shape[len(v.axes)]:
                    raise CompileError(f"{self.where}: component {k} of '{base.key}' is past its "
                                       f"{v.a.shape[len(v.axes)]} features")
                return Val(np.take(v.a, k, axis=len(v.axes)), v.axes)
        if looped:
            raise CompileError(f"{self.where}: '{key}' is indexed by the range variable '{looped[0]}': not "
                               "evaluated (bind the sum, e.g. a spherical-harmonics basis, instead)")
        if key not in self.values:
            named = named_sizes(self.sizes)
            if key in named and s.index is None:
                return Val(np.asarray(float(named[key])), ())
            raise CompileError(f"{self.where}: '{key}' has no binding")
        v = self.values[key]
        if SAMPLE not in v.axes:
            if s.index is not None and not is_bound_variable(s):
                raise ShapeError(f"{self.where}: '{key}' is used with the sample index {s.index.var} but is bound "
                                 "without a sample axis")
            return v
        if s.index is not None and s.index.offset:
            raise CompileError(f"{self.where}: the shifted index in '{key}_{{{s.index.var}{s.index.offset:+d}}}' "
                               "is not evaluated (bind the quantity it defines instead)")
        var = s.index.var if s.index is not None else (self.sample_vars[-1] if self.sample_vars else _IMPLICIT)
        if var not in self.order:
            self.order.append(var)
        return Val(v.a, tuple(var if a == SAMPLE else a for a in v.axes))

    def binop(self, e: BinOp) -> Val:
        x, y = self.ev(e.left), self.ev(e.right)
        if e.op == "*" and not x.axes and len(x.feat) == 2:
            if len(y.feat) < 1:
                raise ShapeError(f"{self.where}: a matrix {x.feat} times a value without features")
            if y.feat[-1] != x.feat[1]:
                raise ShapeError(f"{self.where}: a matrix {x.feat} times a vector of size {y.feat[-1]}")
            return Val(np.einsum("on,...n->...o", x.a, y.a), y.axes)
        if e.op == "*" and not y.axes and len(y.feat) == 2 and len(x.feat) >= 1:
            raise ShapeError(f"{self.where}: a matrix on the right of a product (x W) is not read")
        fn = {"+": np.add, "-": np.subtract, "*": np.multiply, "odot": np.multiply, "/": np.divide,
              "^": np.power}[e.op]
        return self.binary(fn, x, y)

    def apply(self, e: Apply) -> Val:
        args = [self.ev(a) for a in e.args]
        f = e.func
        unary = {
            "exp": np.exp, "log": np.log, "sin": np.sin, "cos": np.cos, "tan": np.tan, "tanh": np.tanh,
            "sigmoid": lambda x: 0.5 * (1.0 + np.tanh(0.5 * x)), "relu": lambda x: np.where(x > 0, x, 0.0),
            "softplus": lambda x: np.logaddexp(0.0, x), "abs": np.abs, "sqrt": np.sqrt, "ceil": np.ceil,
            "floor": np.floor, "stopgrad": lambda x: x,
        }
        if f in unary:
            return Val(unary[f](args[0].a), args[0].axes)
        if f == "softmax":  # over the features (a temperature is the paper's division of the argument)
            x = args[0]
            if x.a.ndim <= len(x.axes):
                raise CompileError(f"{self.where}: a softmax over a quantity without features (one number per "
                                   "element)")
            z = np.exp(x.a - np.max(x.a, axis=-1, keepdims=True))
            return Val(z / np.sum(z, axis=-1, keepdims=True), x.axes)
        if f in ("min", "max"):
            return self.binary(np.minimum if f == "min" else np.maximum, args[0], args[1])
        if f == "clamp":
            (x, lo, hi), axes = self.align(*args)
            return Val(np.minimum(np.maximum(x, lo), hi), axes)
        if f == "mse":
            d = self.binary(np.subtract, args[0], args[1])
            return Val(np.asarray(np.mean(d.a ** 2)), ())
        raise CompileError(f"{self.where}: unknown function {f}")

    def norm(self, e: Norm) -> Val:
        v = self.ev(e.arg)
        if not v.feat:
            return Val(np.abs(v.a), v.axes)
        if e.order == 2:
            a = np.sqrt(np.sum(v.a ** 2, axis=-1))
        elif e.order == 1:
            a = np.sum(np.abs(v.a), axis=-1)
        else:
            a = np.max(np.abs(v.a), axis=-1)
        return Val(a, v.axes)

    def concat(self, e: Concat) -> Val:
        vals = [self.ev(item) for item in e.items]
        for v in vals:
            if len(v.feat) > 1:
                raise ShapeError(f"{self.where}: concatenating a value with features {v.feat}")
        vals = [Val(v.a[..., None], v.axes) if not v.feat else v for v in vals]
        arrays, axes = self.align(*vals)
        batch = np.broadcast_shapes(*[a.shape[:-1] for a in arrays])
        return Val(np.concatenate([np.broadcast_to(a, batch + a.shape[-1:]) for a in arrays], axis=-1), axes)

    def cases(self, e: Cases) -> Val:
        values = [self.ev(v) for v, _ in e.branches]
        conds = [self.ev(c) if c is not None else None for _, c in e.branches]
        conds[-1] = None  # the last case is the fallback (its condition, if any, is the complement)
        items = values + [c for c in conds if c is not None]
        arrays, axes = self.align(*items)
        vals, cs = arrays[:len(values)], arrays[len(values):]
        result = vals[-1]
        for val, cond in zip(reversed(vals[:-1]), reversed(cs), strict=False):
            result = np.where(cond, val, result)
        shape = np.broadcast_shapes(*[a.shape for a in arrays])
        return Val(np.broadcast_to(result, shape).copy(), axes)

    def reduce(self, r: Reduce) -> Val:
        op = {"sum": np.sum, "prod": np.prod, "min": np.min, "max": np.max}[r.kind]
        extreme = r.kind in ("min", "max")
        if extreme and r.mode != "full":
            raise CompileError(f"{self.where}: a running {r.kind} over earlier samples is not read")
        if r.axis == "range":
            return self._range(r)
        if r.axis == "rays":
            body = self.ev(r.body)
            if RAY not in body.axes and extreme:
                return body
            if RAY not in body.axes:
                factor = self.n_rays
                return Val(body.a * factor if r.kind == "sum" else body.a ** factor, body.axes)
            return Val(op(body.a, axis=body.axes.index(RAY)), tuple(a for a in body.axes if a != RAY))
        v = r.index
        if v not in self.order:
            self.order.append(v)
        self.sample_vars.append(v)
        try:
            body = self.ev(r.body)
        finally:
            self.sample_vars.pop()
        if self.n_samples is None:
            raise CompileError(f"{self.where}: a reduction over samples without any per-sample binding")
        if v not in body.axes:
            body = Val(np.broadcast_to(body.a[None], (self.n_samples,) + body.a.shape), (v,) + body.axes)
            arrays, axes = self.align(body)
            body = Val(arrays[0], axes)
        if r.mode == "full":
            return Val(op(body.a, axis=body.axes.index(v)), tuple(a for a in body.axes if a != v))
        u = r.outer
        if u not in self.order:
            self.order.append(u)
        n = self.n_samples
        rows, cols = np.arange(n)[:, None], np.arange(n)[None, :]
        mask = Val(cols < rows if r.mode == "exclusive" else cols <= rows, (u, v))
        (b, m), axes = self.align(body, mask)
        b = np.broadcast_to(b, np.broadcast_shapes(b.shape, m.shape))
        masked = b * m if r.kind == "sum" else np.where(m, b, 1.0)
        return Val(op(masked, axis=axes.index(v)), tuple(a for a in axes if a != v))

    def _range(self, r: Reduce) -> Val:
        lo, hi = self.ev(r.lower), self.ev(r.upper)
        if lo.a.ndim or hi.a.ndim or not (np.isfinite(lo.a) and np.isfinite(hi.a)) or lo.a != np.round(lo.a) \
                or hi.a != np.round(hi.a):
            raise CompileError(f"{self.where}: the range of '{r.index}' is not a pair of integers")
        if float(hi.a) - float(lo.a) + 1 > MAX_RANGE:
            raise CompileError(f"{self.where}: a range of more than {MAX_RANGE} terms")
        lo_i, hi_i = int(lo.a), int(hi.a)
        extreme = r.kind in ("min", "max")
        if extreme and hi_i < lo_i:
            raise CompileError(f"{self.where}: a {r.kind} over an empty range")
        combine = {"sum": np.add, "prod": np.multiply, "min": np.minimum, "max": np.maximum}[r.kind]
        acc = None if extreme else Val(np.asarray(0.0 if r.kind == "sum" else 1.0), ())
        for k in range(lo_i, hi_i + 1):
            self.iterations += 1
            if self.iterations > MAX_RANGE_ITERATIONS:
                raise CompileError(f"{self.where}: more than {MAX_RANGE_ITERATIONS:,} iterations of finite ranges")
            self.ranges[r.index] = float(k)
            self.range_lo[r.index] = lo_i
            term = self.ev(r.body)
            acc = term if acc is None else self.binary(combine, acc, term)
        self.ranges.pop(r.index, None)
        return acc


def _as_equations(ir) -> list[Equation]:
    items = ir if isinstance(ir, list | tuple) else [ir]
    for item in items:
        if isinstance(item, ParseFailure):
            raise CompileError(f"an equation that was not read: {item}")
        if not isinstance(item, Equation):
            raise CompileError(f"not an equation: {type(item).__name__}")
    return list(items)


def _bind(key: str, array, dims: tuple | None, per_sample: bool, is_param: bool) -> Val:
    a = np.asarray(array, dtype=np.float64)
    if dims is None:
        if is_param or a.ndim == 0:
            dims = tuple(range(a.ndim))
        elif per_sample:
            if a.ndim < 2:
                raise ShapeError(f"'{key}' is used per sample: bind it as [R, S, ...], got shape {a.shape}")
            dims = (RAY, SAMPLE) + tuple(range(a.ndim - 2))
        else:
            dims = (RAY,) + tuple(range(a.ndim - 1))
    dims = tuple(dims)
    check_layout(key, dims)
    if len(dims) != a.ndim:
        raise ShapeError(f"'{key}': layout {list(dims)} does not fit shape {a.shape}")
    return Val(a, tuple(d for d in dims if d in (RAY, SAMPLE)))


def interpret(ir, bindings: dict, layout: dict | None = None, sizes: dict | None = None,
              outputs: list[str] | None = None) -> dict[str, np.ndarray]:
    """Evaluate equations in float64 (see the module docstring); returns each output in its layout
    ([R, S, ...], [R, ...] or a scalar)."""
    equations = _as_equations(ir)
    layout, sizes = dict(layout or {}), dict(sizes or {})
    per_sample = sample_indexed_keys(equations)
    params = param_specs(sizes)
    values = {key: _bind(key, arr, layout.get(key), key in per_sample, key in params)
              for key, arr in bindings.items()}
    n_rays = {v.a.shape[0] for v in values.values() if RAY in v.axes}
    n_samples = {v.a.shape[v.axes.index(SAMPLE)] for v in values.values() if SAMPLE in v.axes}
    if len(n_rays) > 1 or len(n_samples) > 1:
        raise ShapeError(f"bindings disagree on the number of rays {sorted(n_rays)} or samples {sorted(n_samples)}")
    outputs = list(outputs) if outputs is not None else [eq.defines for eq in equations]
    order = schedule(equations, outputs, set(values) | set(named_sizes(sizes)))
    check_cost(order, sizes)  # nested finite ranges, operations: refused before anything is evaluated
    ev = _Eval(values, sizes, next(iter(n_rays), None), next(iter(n_samples), None))
    for eq in order:
        ev.where = f"equation {eq.number}" if eq.number else f"the equation of '{eq.defines}'"
        ev.order = [RAY] + ([eq.free_index] if eq.free_index else [])
        ev.sample_vars = [eq.free_index] if eq.free_index else []
        result = ev.ev(eq.rhs)
        keep = {RAY, eq.free_index, _IMPLICIT} if eq.free_index else {RAY, _IMPLICIT}
        extra = [a for a in result.axes if a not in keep]
        samples = [a for a in result.axes if a != RAY]
        if extra or len(samples) > 1:
            raise ShapeError(f"{ev.where}: the sample index {(extra or samples)[0]} is left free on the right side")
        values[eq.defines] = Val(result.a, tuple(SAMPLE if a != RAY else RAY for a in result.axes))
    return {key: values[key].a for key in outputs}
