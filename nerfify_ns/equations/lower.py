"""Lower equations (IR) to the readable source of a torch ``nn.Module``.

``lower(equations, inputs, outputs, sizes, class_name)`` -> source text; ``lower_module(...)`` -> ``Lowered``
(the source plus the map from generated identifiers to the paper's symbols).

* One line (or block, for a finite-range loop) per equation, its number and reading in a comment above it.
* Inputs: ``{key: layout}`` in forward's argument order (``{"sigma": ("R", "S"), "c": ("R", "S", 3)}``);
  outputs: keys, returned in that order (one tensor, or a tuple).
* Learned parameters (keys of ``sizes`` with a shape or ``ParamSpec``) are ``nn.Parameter`` attributes
  named after their symbols (``W_gamma`` -> ``self.p_w_gamma``); fixed ones are buffers.
* ``W x``: a 2-D parameter times a vector is ``torch.nn.functional.linear(x, W)``; ``\\odot``, ``\\otimes``,
  ``\\circ`` and every other product are element-wise; sums over samples are ``torch.sum(..., dim=1)``;
  ``\\sum_{j<i}`` is an exclusive cumulative sum; ``\\prod_{j<i} \\exp(x_j)`` is ``exp`` of an exclusive
  cumulative sum (log space: no underflow), any other ``\\prod_{j<i}`` an exclusive cumulative product;
  a reduction whose body depends on both indices uses a triangular mask.
* Safety: a paper is untrusted input. Nothing of its text reaches the source except through the IR:
  identifiers are generated (``naming.py``), numbers are ``repr(float)`` literals, and the paper's
  notation appears only in comments made safe by ``render.safe_comment`` (one line, a fixed ASCII set,
  truncated). The module's docstrings are fixed text.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .emit import assemble
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
from .naming import Names, class_name_ok
from .shapes import (
    MAX_RANGE,
    RAY,
    SAMPLE,
    CompileError,
    ParamSpec,
    ShapeError,
    check_cost,
    check_layout,
    component_base,
    is_bound_variable,
    named_sizes,
    param_specs,
    resolve_dims,
    schedule,
)
from .show import safe_comment, show

_IMPLICIT = "@S"
MAX_LIMIT = 1 << 40
"""The largest magnitude of a range limit: no paper's range comes near it, and its arithmetic stays exact."""
_ATOM, _POW, _UNARY, _MUL, _ADD, _CMP = 100, 8, 7, 6, 5, 3


class LoweringError(CompileError):
    """An equation that cannot be lowered (the message names the equation)."""


@dataclass
class _T:
    axes: tuple[str, ...]
    feat: tuple[int, ...]


@dataclass
class _C:
    code: str
    prec: int
    t: _T
    tensor: bool = True


@dataclass
class Lowered:
    """The generated module and how its names map to the paper's symbols."""

    source: str
    class_name: str
    inputs: list[tuple[str, str, tuple]]        # (key, argument name, layout)
    outputs: list[tuple[str, str]]              # (key, identifier)
    params: dict[str, tuple[str, ParamSpec]]    # key -> (attribute, spec)
    names: dict[str, str] = field(default_factory=dict)  # identifier -> key
    equations: list[str] = field(default_factory=list)   # numbers of the equations compiled, in order
    layouts: dict[str, tuple] = field(default_factory=dict)  # output key -> its layout ('R', 'S' or both)


_TORCH_UNARY = {"exp": "torch.exp", "log": "torch.log", "sin": "torch.sin", "cos": "torch.cos", "tan": "torch.tan",
                "tanh": "torch.tanh", "sigmoid": "torch.sigmoid", "relu": "torch.relu",
                "softplus": "torch.nn.functional.softplus", "abs": "torch.abs", "sqrt": "torch.sqrt",
                "ceil": "torch.ceil", "floor": "torch.floor"}
_MATH_UNARY = {"exp": "math.exp", "log": "math.log", "sin": "math.sin", "cos": "math.cos", "tan": "math.tan",
               "tanh": "math.tanh", "abs": "abs", "sqrt": "math.sqrt", "ceil": "math.ceil", "floor": "math.floor"}


def _paren(c: _C, prec: int) -> str:
    return c.code if c.prec >= prec else f"({c.code})"


def _broadcast(a: tuple[int, ...], b: tuple[int, ...], where: str) -> tuple[int, ...]:
    n = max(len(a), len(b))
    a, b = (1,) * (n - len(a)) + a, (1,) * (n - len(b)) + b
    out = []
    for x, y in zip(a, b, strict=False):
        if x != y and 1 not in (x, y):
            raise ShapeError(f"{where}: feature shapes {a} and {b} do not combine")
        out.append(max(x, y))
    return tuple(out)


class _Lower:
    def __init__(self, names: Names, env: dict[str, tuple[str, _T, bool]], sizes: dict, ref: str | None,
                 sample_ref: str | None, ray_ref: str | None):
        self.names, self.env, self.sizes = names, env, sizes
        self.ref, self.sample_ref, self.ray_ref = ref, sample_ref, ray_ref
        self.order: list[str] = [RAY]
        self.sample_vars: list[str] = []
        self.loop_vars: dict[str, str] = {}
        self.loop_lo: dict[str, str] = {}
        self.pre: list[str] = []
        self.indent = 0
        self.uses_n_samples = self.uses_n_rays = False
        self.where = ""

    # --- helpers -------------------------------------------------------------------------------------------
    def _rank(self, axis: str) -> int:
        return self.order.index(axis) if axis in self.order else len(self.order)

    def _sorted(self, axes) -> tuple[str, ...]:
        return tuple(sorted(set(axes), key=self._rank))

    def aligned(self, c: _C, axes: tuple[str, ...], fr: int) -> _C:
        """c indexed so that it broadcasts against the target batch axes and feature rank."""
        if not c.tensor:
            return c
        idx = [":" if a in c.t.axes else "None" for a in axes] + ["None"] * (fr - len(c.t.feat)) \
            + [":"] * len(c.t.feat)
        while idx and idx[-1] == ":":
            idx.pop()
        while idx and idx[0] == "None":
            idx.pop(0)  # leading new axes: broadcasting adds them
        if not idx:
            return c
        return _C(f"{_paren(c, _ATOM)}[{', '.join(idx)}]", _ATOM, c.t, True)

    def align(self, c: _C, axes: tuple[str, ...], fr: int, prec: int = 0) -> str:
        """The aligned code, parenthesised to bind at least as tightly as ``prec`` (an argument: none)."""
        return _paren(self.aligned(c, axes, fr), prec)

    def _joint(self, *cs: _C) -> tuple[tuple[str, ...], int, tuple[int, ...]]:
        axes = self._sorted(a for c in cs for a in c.t.axes)
        feat: tuple[int, ...] = ()
        for c in cs:
            feat = _broadcast(feat, c.t.feat, self.where)
        return axes, len(feat), feat

    def _n_samples(self) -> str:
        if self.sample_ref is None:
            raise LoweringError(f"{self.where}: a reduction over samples without any per-sample input")
        self.uses_n_samples = True
        return "n_samples"

    def _dtype_ref(self) -> str:
        if self.ref is None:
            raise LoweringError(f"{self.where}: no input to take a dtype from")
        return self.ref

    def _emit(self, line: str) -> None:
        self.pre.append("    " * self.indent + line)

    # --- nodes ---------------------------------------------------------------------------------------------
    def lo(self, e: Expr) -> _C:
        if isinstance(e, Number):
            if not math.isfinite(e.value):
                raise LoweringError(f"{self.where}: a non-finite number")
            text = repr(float(e.value))
            return _C(text, _ATOM if e.value >= 0 else _UNARY, _T((), ()), False)
        if isinstance(e, Symbol):
            return self.symbol(e)
        if isinstance(e, Neg):
            c = self.lo(e.arg)
            return _C(f"-{_paren(c, _POW)}", _UNARY, c.t, c.tensor)
        if isinstance(e, BinOp):
            return self.binop(e)
        if isinstance(e, Apply):
            return self.apply(e)
        if isinstance(e, Compare):
            op = {"<": "<", "<=": "<=", ">": ">", ">=": ">=", "==": "==", "!=": "!="}.get(e.op)
            if op is None:
                raise LoweringError(f"{self.where}: the condition '{e.op}' is not lowered")
            a, b = self.lo(e.left), self.lo(e.right)
            axes, fr, feat = self._joint(a, b)
            return _C(f"{self.align(a, axes, fr, _ADD)} {op} {self.align(b, axes, fr, _ADD)}", _CMP, _T(axes, feat),
                      a.tensor or b.tensor)
        if isinstance(e, Norm):
            return self.norm(e)
        if isinstance(e, Concat):
            return self.concat(e)
        if isinstance(e, Cases):
            return self.cases(e)
        if isinstance(e, Expectation):
            c = self.lo(e.body)
            if RAY not in c.t.axes:
                return c
            dim = c.t.axes.index(RAY)
            return _C(f"torch.mean({c.code}, dim={dim})", _ATOM, _T(tuple(a for a in c.t.axes if a != RAY), c.t.feat))
        if isinstance(e, Reduce):
            return self.reduce(e)
        if isinstance(e, Integral):
            if e.quadrature is None:
                raise LoweringError(f"{self.where}: an integral without its quadrature (not resolved)")
            return self.lo(e.quadrature)
        raise LoweringError(f"{self.where}: cannot lower {type(e).__name__}")

    def symbol(self, s: Symbol) -> _C:
        if is_bound_variable(s) and s.name in self.loop_vars:
            return _C(f"float({self.loop_vars[s.name]})", _ATOM, _T((), ()), False)
        key = s.key
        looped = [lab for lab in s.subscripts + ((s.superscript,) if s.superscript else ()) if lab in self.loop_vars]
        base = component_base(s, set(self.loop_vars)) if looped else s
        if base is not s and base.key in self.env:  # a_k in a sum over k: the k-th component of a's features
            c = self.symbol(base)
            (var,) = [lab for lab in s.subscripts if lab in self.loop_vars]
            if c.t.feat:
                return _C(f"{_paren(c, _ATOM)}.select({-len(c.t.feat)}, {self.loop_vars[var]} - "
                          f"({self.loop_lo[var]}))", _ATOM, _T(c.t.axes, c.t.feat[1:]), c.tensor)
        if looped:
            raise LoweringError(f"{self.where}: '{safe_comment(key, 40)}' is indexed by the range variable "
                                f"'{safe_comment(looped[0], 20)}': not lowered (bind the sum, e.g. a spherical-"
                                "harmonics basis, instead)")
        if key not in self.env:
            named = named_sizes(self.sizes)
            if key in named and s.index is None:
                return _C(repr(float(named[key])), _ATOM, _T((), ()), False)
            raise LoweringError(f"{self.where}: '{safe_comment(key, 60)}' is neither an input, a parameter nor "
                                "defined earlier")
        ident, t, tensor = self.env[key]
        if SAMPLE not in t.axes:
            if s.index is not None and not is_bound_variable(s):
                raise ShapeError(f"{self.where}: '{safe_comment(key, 60)}' is used with a sample index but has no "
                                 "sample axis")
            return _C(ident, _ATOM, t, tensor)
        if s.index is not None and s.index.offset:
            raise LoweringError(f"{self.where}: a shifted sample index ({safe_comment(key, 40)}) is not lowered")
        var = s.index.var if s.index is not None else (self.sample_vars[-1] if self.sample_vars else _IMPLICIT)
        if var not in self.order:
            self.order.append(var)
        return _C(ident, _ATOM, _T(tuple(var if a == SAMPLE else a for a in t.axes), t.feat), tensor)

    def binop(self, e: BinOp) -> _C:
        if (e.op == "^" and isinstance(e.left, Norm) and e.left.order == 2 and isinstance(e.right, Number)
                and e.right.value == 2.0):
            x = self.lo(e.left.arg)  # ||x||^2: the sum of squares (no square root)
            if not x.t.feat:
                return _C(f"{_paren(x, _POW + 1)} ** 2", _POW, x.t, x.tensor)
            return _C(f"torch.sum({x.code} ** 2, dim=-1)" if x.prec > _POW else f"torch.sum(({x.code}) ** 2, dim=-1)",
                      _ATOM, _T(x.t.axes, x.t.feat[:-1]))
        a, b = self.lo(e.left), self.lo(e.right)
        if e.op == "*" and a.tensor and not a.t.axes and len(a.t.feat) == 2:
            if not b.t.feat or b.t.feat[-1] != a.t.feat[1]:
                raise ShapeError(f"{self.where}: a matrix {a.t.feat} times a value with features {b.t.feat}")
            return _C(f"torch.nn.functional.linear({b.code}, {a.code})", _ATOM,
                      _T(b.t.axes, b.t.feat[:-1] + (a.t.feat[0],)))
        if e.op == "*" and b.tensor and not b.t.axes and len(b.t.feat) == 2 and a.t.feat:
            raise ShapeError(f"{self.where}: a matrix on the right of a product (x W) is not read")
        axes, fr, feat = self._joint(a, b)
        op, prec = {"+": ("+", _ADD), "-": ("-", _ADD), "*": ("*", _MUL), "odot": ("*", _MUL), "/": ("/", _MUL),
                    "^": ("**", _POW)}[e.op]
        left_prec = prec + 1 if e.op == "^" else prec
        right_prec = prec + 1 if e.op in ("-", "/") else (prec if e.op != "^" else _UNARY)
        la, rb = self.align(a, axes, fr, left_prec), self.align(b, axes, fr, right_prec)
        return _C(f"{la} {op} {rb}", prec, _T(axes, feat), a.tensor or b.tensor)

    def apply(self, e: Apply) -> _C:
        args = [self.lo(a) for a in e.args]
        f = e.func
        if f in _TORCH_UNARY or f in ("sigmoid", "relu", "softplus", "stopgrad"):
            x = args[0]
            if not x.tensor:
                scalar = {"sigmoid": f"1.0 / (1.0 + math.exp(-{_paren(x, _POW)}))",
                          "relu": f"max({x.code}, 0.0)", "softplus": f"math.log1p(math.exp({x.code}))",
                          "stopgrad": x.code}
                if f in scalar:
                    return _C(scalar[f], _MUL if f == "sigmoid" else _ATOM, x.t, False)
                return _C(f"{_MATH_UNARY[f]}({x.code})", _ATOM, x.t, False)
            if f == "stopgrad":
                return _C(f"{_paren(x, _ATOM)}.detach()", _ATOM, x.t)
            return _C(f"{_TORCH_UNARY[f]}({x.code})", _ATOM, x.t)
        if f == "softmax":  # over the features (a temperature is the paper's division of the argument)
            x = args[0]
            if not x.t.feat:
                raise LoweringError(f"{self.where}: a softmax over a quantity without features (one number per "
                                    "element)")
            return _C(f"torch.softmax({x.code}, dim=-1)", _ATOM, x.t)
        if f in ("min", "max"):
            a, b = args
            if not a.tensor and not b.tensor:
                return _C(f"{f}({a.code}, {b.code})", _ATOM, a.t, False)
            if not a.tensor or not b.tensor:
                tensor, number = (a, b) if a.tensor else (b, a)
                bound = "max" if f == "min" else "min"
                return _C(f"torch.clamp({tensor.code}, {bound}={number.code})", _ATOM, tensor.t)
            axes, fr, feat = self._joint(a, b)
            fn = "torch.minimum" if f == "min" else "torch.maximum"
            return _C(f"{fn}({self.align(a, axes, fr)}, {self.align(b, axes, fr)})", _ATOM, _T(axes, feat))
        if f == "clamp":
            x, lo, hi = args
            if not lo.tensor and not hi.tensor:
                if not x.tensor:
                    return _C(f"min(max({x.code}, {lo.code}), {hi.code})", _ATOM, x.t, False)
                return _C(f"torch.clamp({x.code}, {lo.code}, {hi.code})", _ATOM, x.t)
            axes, fr, feat = self._joint(x, lo, hi)
            inner = f"torch.maximum({self.align(x, axes, fr)}, {self.align(lo, axes, fr)})"
            return _C(f"torch.minimum({inner}, {self.align(hi, axes, fr)})", _ATOM, _T(axes, feat))
        if f == "mse":
            a, b = args
            axes, fr, _ = self._joint(a, b)
            return _C(f"torch.mean(({self.align(a, axes, fr, _ADD)} - {self.align(b, axes, fr, _ADD + 1)}) ** 2)",
                      _ATOM, _T((), ()))
        raise LoweringError(f"{self.where}: the function {f} is not lowered")

    def norm(self, e: Norm) -> _C:
        x = self.lo(e.arg)
        if not x.t.feat:
            return _C(f"torch.abs({x.code})", _ATOM, x.t, x.tensor) if x.tensor else _C(f"abs({x.code})", _ATOM,
                                                                                         x.t, False)
        t = _T(x.t.axes, x.t.feat[:-1])
        if e.order == 2:
            return _C(f"torch.linalg.vector_norm({x.code}, dim=-1)", _ATOM, t)
        if e.order == 1:
            return _C(f"torch.sum(torch.abs({x.code}), dim=-1)", _ATOM, t)
        return _C(f"torch.amax(torch.abs({x.code}), dim=-1)", _ATOM, t)

    def concat(self, e: Concat) -> _C:
        items = [self.lo(item) for item in e.items]
        if not any(c.tensor for c in items):
            if self.ref is None:
                raise LoweringError(f"{self.where}: a concatenation of numbers without any input")
            values = ", ".join(c.code for c in items)
            return _C(f"torch.tensor([{values}], dtype={self.ref}.dtype, device={self.ref}.device)", _ATOM,
                      _T((), (len(items),)))
        for c in items:
            if len(c.t.feat) > 1:
                raise ShapeError(f"{self.where}: concatenating a value with features {c.t.feat}")
        axes = self._sorted(a for c in items for a in c.t.axes)
        parts, width = [], 0
        for c in items:
            if not c.tensor:
                parts.append(c.code)
                width += 1
                continue
            aligned = self.aligned(c, axes, len(c.t.feat))
            parts.append(aligned.code if c.t.feat else f"{_paren(aligned, _ATOM)}[..., None]")
            width += c.t.feat[0] if c.t.feat else 1
        return _C(f"_cat_features({', '.join(parts)})", _ATOM, _T(axes, (width,)))

    def cases(self, e: Cases) -> _C:
        values = [self.lo(v) for v, _ in e.branches]
        conds = [self.lo(c) for _, c in e.branches[:-1]]  # the last case is the fallback
        axes, fr, feat = self._joint(*values, *conds)
        result = values[-1]
        for value, cond in zip(reversed(values[:-1]), reversed(conds), strict=False):
            if not cond.tensor:  # a condition on numbers only (0.5 > k): a 0-d tensor, so shapes stay known
                ref = self._dtype_ref()
                cond = _C(f"torch.as_tensor({cond.code}, device={ref}.device)", _ATOM, _T((), ()))
            a, b = self.align(value, axes, fr), self.align(result, axes, fr)
            if not value.tensor and not result.tensor:
                a = f"torch.full_like({self.align(cond, axes, fr, _ATOM)}, {a}, dtype={self._dtype_ref()}.dtype)"
            result = _C(f"torch.where({self.align(cond, axes, fr)}, {a}, {b})", _ATOM, _T(axes, feat))
        return result

    def reduce(self, r: Reduce) -> _C:
        fn = _REDUCE_FN[r.kind]
        extreme = r.kind in ("min", "max")
        if extreme and r.mode != "full":
            raise LoweringError(f"{self.where}: a running {r.kind} over earlier samples is not read")
        if r.axis == "range":
            return self._range(r)
        if r.axis == "rays":
            c = self.lo(r.body)
            if RAY not in c.t.axes:
                if extreme:
                    return c  # the min (max) over the rays of what does not depend on the ray
                if self.ray_ref is None:
                    raise LoweringError(f"{self.where}: a sum over rays without any per-ray input")
                self.uses_n_rays = True
                op = "*" if r.kind == "sum" else "**"
                return _C(f"{_paren(c, _POW + 1)} {op} n_rays", _MUL if op == "*" else _POW, c.t, c.tensor)
            dim = c.t.axes.index(RAY)
            return _C(f"{fn}({c.code}, dim={dim})", _ATOM, _T(tuple(a for a in c.t.axes if a != RAY), c.t.feat))
        v = r.index
        if v not in self.order:
            self.order.append(v)
        self.sample_vars.append(v)
        try:
            body = self.lo(r.body)
        finally:
            self.sample_vars.pop()
        expanded = v not in body.t.axes and r.mode != "full"
        if expanded:
            ones = _C(f"_sample_ones({self._n_samples()}, {self.ref})", _ATOM, _T((v,), ()))
            axes = self._sorted(body.t.axes + (v,))
            fr = len(body.t.feat)
            body = _C(f"{self.align(body, axes, fr, _MUL)} * {self.align(ones, axes, fr, _MUL + 1)}", _MUL,
                      _T(axes, body.t.feat))
        if v not in body.t.axes and extreme:
            return body  # the min (max) over the samples of what does not depend on the sample
        if v not in body.t.axes:
            n = self._n_samples()
            op = "*" if r.kind == "sum" else "**"
            return _C(f"{_paren(body, _POW + 1)} {op} {n}", _MUL if op == "*" else _POW, body.t, body.tensor)
        dim = body.t.axes.index(v)
        rest = tuple(a for a in body.t.axes if a != v)
        if r.mode == "full":
            return _C(f"{fn}({body.code}, dim={dim})", _ATOM, _T(rest, body.t.feat))
        u = r.outer
        if u not in self.order:
            self.order.append(u)
        inclusive = r.mode == "inclusive"
        if u not in body.t.axes:
            if r.kind == "sum":
                code = f"torch.cumsum({body.code}, dim={dim})" if inclusive else \
                    f"_exclusive_cumsum({body.code}, dim={dim})"
            elif isinstance(r.body, Apply) and r.body.func == "exp" and not expanded:
                inner = self.lo_in_scope(r.body.args[0], v)
                code = f"torch.exp(torch.cumsum({inner.code}, dim={dim}))" if inclusive else \
                    f"torch.exp(_exclusive_cumsum({inner.code}, dim={dim}))"
            else:
                code = f"torch.cumprod({body.code}, dim={dim})" if inclusive else \
                    f"_exclusive_cumprod({body.code}, dim={dim})"
            renamed = tuple(u if a == v else a for a in body.t.axes)
            target = self._sorted(renamed)
            if renamed != target:
                perm = [renamed.index(a) for a in target] + [len(renamed) + k for k in range(len(body.t.feat))]
                code = f"{code}.permute({', '.join(str(p) for p in perm)})"
            return _C(code, _ATOM, _T(target, body.t.feat))
        n = self._n_samples()
        mask = _C(f"_before_mask({n}, {inclusive}, {self.ref})", _ATOM, _T(self._sorted((u, v)), ()))
        axes = self._sorted(body.t.axes + (u,))
        fr = len(body.t.feat)
        b, m = self.align(body, axes, fr), self.align(mask, axes, fr, _MUL + 1)
        dim = axes.index(v)
        rest = tuple(a for a in axes if a != v)
        if r.kind == "sum":
            return _C(f"torch.sum({self.align(body, axes, fr, _MUL)} * {m}, dim={dim})", _ATOM, _T(rest, body.t.feat))
        return _C(f"torch.prod(torch.where({m}, {b}, 1.0), dim={dim})", _ATOM, _T(rest, body.t.feat))

    def lo_in_scope(self, e: Expr, var: str) -> _C:
        self.sample_vars.append(var)
        try:
            return self.lo(e)
        finally:
            self.sample_vars.pop()

    def _int_bound(self, e: Expr) -> tuple[str, int | None]:
        """A range limit as Python int code, and its value when it does not depend on an outer range."""
        if isinstance(e, Number):
            if not math.isfinite(e.value) or abs(e.value) > MAX_LIMIT:
                raise LoweringError(f"{self.where}: a range limit that is not a finite number of at most "
                                    f"{MAX_LIMIT:,}")
            if e.value != int(e.value):
                raise LoweringError(f"{self.where}: a range limit that is not an integer")
            return str(int(e.value)), int(e.value)
        if isinstance(e, Symbol) and e.key in named_sizes(self.sizes):
            value = named_sizes(self.sizes)[e.key]
            return str(value), value
        if isinstance(e, Symbol) and not e.subscripts and e.name in self.loop_vars:
            return self.loop_vars[e.name], None  # the number of an enclosing range
        if isinstance(e, Neg):
            code, value = self._int_bound(e.arg)
            return f"-{code}" if value is None else str(-value), None if value is None else -value
        if isinstance(e, BinOp) and e.op in ("+", "-", "*"):
            (a, va), (b, vb) = self._int_bound(e.left), self._int_bound(e.right)
            if va is not None and vb is not None:
                value = va + vb if e.op == "+" else (va - vb if e.op == "-" else va * vb)
                if abs(value) > MAX_LIMIT:
                    raise LoweringError(f"{self.where}: a range limit larger than {MAX_LIMIT:,}")
                return str(value), value
            return f"({a} {e.op} {b})", None
        raise LoweringError(f"{self.where}: a range limit that is not a number or a size "
                            f"({safe_comment(show(e), 40)})")

    def _range(self, r: Reduce) -> _C:
        (lo, lo_value), (hi, hi_value) = self._int_bound(r.lower), self._int_bound(r.upper)
        if lo_value is not None and hi_value is not None and hi_value - lo_value + 1 > MAX_RANGE:
            raise LoweringError(f"{self.where}: a range of more than {MAX_RANGE} terms")
        stop = str(hi_value + 1) if hi_value is not None else f"{hi} + 1"
        acc = self.names.fresh("acc", r.kind)
        loop = self.names.fresh("k", r.index)
        extreme = r.kind in ("min", "max")
        if extreme and lo_value is not None and hi_value is not None and hi_value < lo_value:
            raise LoweringError(f"{self.where}: a {r.kind} over an empty range")
        self._emit(f"{acc} = {'None' if extreme else (0.0 if r.kind == 'sum' else 1.0)}")
        self._emit(f"for {loop} in range({lo}, {stop}):")
        self.loop_vars[r.index] = loop
        self.loop_lo[r.index] = lo
        self.indent += 1
        try:
            body = self.lo(r.body)
            if extreme:  # the first term, then the elementwise min (max) of the terms so far
                pick = ("torch.minimum" if r.kind == "min" else "torch.maximum") if body.tensor else r.kind
                self._emit(f"{acc} = {body.code} if {acc} is None else {pick}({acc}, {body.code})")
            else:
                op = "+" if r.kind == "sum" else "*"
                self._emit(f"{acc} = {acc} {op} {_paren(body, _MUL + 1)}")
        finally:
            self.indent -= 1
            self.loop_vars.pop(r.index, None)
            self.loop_lo.pop(r.index, None)
        return _C(acc, _ATOM, body.t, body.tensor)


_REDUCE_FN = {"sum": "torch.sum", "prod": "torch.prod", "min": "torch.amin", "max": "torch.amax"}


def _as_equations(ir) -> list[Equation]:
    items = ir if isinstance(ir, list | tuple) else [ir]
    for item in items:
        if isinstance(item, ParseFailure):
            raise LoweringError(f"an equation that was not read: {item}")
        if not isinstance(item, Equation):
            raise LoweringError(f"not an equation: {type(item).__name__}")
    return list(items)


def lower_module(equations, inputs: dict, outputs: list[str], sizes: dict | None = None,
                 class_name: str = "CompiledEquations") -> Lowered:
    """Lower equations to an nn.Module's source (see the module docstring); raises LoweringError/ShapeError."""
    equations = _as_equations(equations)
    sizes = dict(sizes or {})
    if not class_name_ok(class_name):
        raise LoweringError("the class name must be a CamelCase identifier of letters and digits")
    inputs = dict(inputs.items() if isinstance(inputs, dict) else inputs)
    params = param_specs(sizes)
    names = Names()
    env: dict[str, tuple[str, _T, bool]] = {}
    input_rows = []
    for key, dims in inputs.items():
        dims = tuple(dims)
        check_layout(key, dims)
        feat = resolve_dims(tuple(d for d in dims if d not in (RAY, SAMPLE)), sizes)
        ident = names.get("v", key)
        env[key] = (ident, _T(tuple(d for d in dims if d in (RAY, SAMPLE)), feat), True)
        input_rows.append((key, ident, dims))
    param_rows = {}
    for key, spec in params.items():
        if not math.isfinite(spec.std) or spec.init not in ("default", "normal", "zeros", "ones") or not all(
                isinstance(n, int) and 0 < n <= 1 << 20 for n in spec.shape) or (spec.clamp is not None and not (
                len(spec.clamp) == 2 and all(v is None or (isinstance(v, int | float) and math.isfinite(v))
                                             for v in spec.clamp))):
            raise LoweringError(f"parameter '{safe_comment(key, 40)}': a shape of positive ints, a known init, "
                                "a finite std and finite bounds")
        if key in env:
            raise LoweringError(f"'{safe_comment(key, 40)}' is both an input and a parameter")
        attr = names.get("p", key)
        env[key] = (f"self.{attr}", _T((), tuple(spec.shape)), True)
        param_rows[key] = (attr, spec)
    order = schedule(equations, list(outputs), set(env) | set(named_sizes(sizes)))
    check_cost(order, sizes)  # nested finite ranges, operations: refused before anything is emitted
    first = input_rows[0][1] if input_rows else None
    sample_ref = next((ident for key, ident, dims in input_rows if SAMPLE in dims), None)
    ray_ref = next((ident for key, ident, dims in input_rows if RAY in dims), None)
    lw = _Lower(names, env, sizes, first, sample_ref, ray_ref)
    body: list[str] = []
    for eq in order:
        lw.where = f"equation {safe_comment(eq.number, 12)}" if eq.number else \
            f"the equation of '{safe_comment(eq.defines, 40)}'"
        lw.order = [RAY] + ([eq.free_index] if eq.free_index else [])
        lw.sample_vars = [eq.free_index] if eq.free_index else []
        lw.pre = []
        result = lw.lo(eq.rhs)
        keep = {RAY, eq.free_index, _IMPLICIT} if eq.free_index else {RAY, _IMPLICIT}
        samples = [a for a in result.t.axes if a != RAY]
        if any(a not in keep for a in result.t.axes) or len(samples) > 1:
            raise ShapeError(f"{lw.where}: a sample index is left free on the right side")
        ident = names.fresh("v", eq.defines)
        label = f"({safe_comment(eq.number, 12)}) " if eq.number else ""
        body.append(f"# {label}{safe_comment(show(eq))}")
        body.extend(lw.pre)
        body.append(f"{ident} = {result.code}")
        env[eq.defines] = (ident, _T(tuple(SAMPLE if a != RAY else RAY for a in result.t.axes), result.t.feat),
                           result.tensor)
    output_rows = []
    returns = []
    layouts = {}
    for key in outputs:
        ident, t, tensor = env[key]
        output_rows.append((key, ident))
        layouts[key] = tuple(t.axes)
        returns.append(ident if tensor else f"torch.as_tensor({ident})")
    head = []
    if lw.uses_n_samples:
        head.append(f"n_samples = {sample_ref}.shape[1]")
    if lw.uses_n_rays:
        head.append(f"n_rays = {ray_ref}.shape[0]")
    source = assemble(class_name, input_rows, output_rows, param_rows, head + body, returns,
                      [eq.number or "" for eq in order])
    return Lowered(source, class_name, input_rows, output_rows, param_rows, dict(names.mapping),
                   [eq.number or "" for eq in order], layouts)


def lower(equations, inputs: dict, outputs: list[str], sizes: dict | None = None,
          class_name: str = "CompiledEquations") -> str:
    """The source of an nn.Module computing ``outputs`` from ``inputs`` (see ``lower_module``)."""
    return lower_module(equations, inputs, outputs, sizes, class_name).source
