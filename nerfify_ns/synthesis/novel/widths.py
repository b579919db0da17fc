"""Feature widths of a hole's equations: which sizes the equations fix and which they leave open.

Every quantity has a feature shape: ``()`` (one number per ray, sample or point), ``(w,)`` (a vector) or, for a
learned matrix, ``(out, in)``. Known widths come from the bindings (a colour has 3 channels, a network's output
the paper's width); unknowns are variables, unified by the equations: an element-wise operation makes its
operands' widths equal, ``W x`` makes W's input width x's, a concatenation adds widths, the left side of an
equation has the width of its right side. What stays open is reported (and a default with its evidence, or a
person's correction in ``equations.yaml``, fills it).

    solver = Widths()
    solver.known("h_Delta", 256); solver.matrix("W_gamma"); solver.vector("b_gamma")
    solver.run(equations)                     # raises WidthError naming the equation on a contradiction
    solver.value("W_gamma")                    # (out, in) with ints or None for what is still open
"""

from __future__ import annotations

from dataclasses import dataclass

from nerfify_ns.equations.ir import (
    Apply,
    BinOp,
    Cases,
    Compare,
    Concat,
    Equation,
    Expectation,
    Integral,
    Neg,
    Norm,
    Number,
    Reduce,
    Symbol,
)
from nerfify_ns.equations.shapes import is_bound_variable
from nerfify_ns.errors import NerfifyError


def _in_dependency_order(equations: list[Equation]) -> list[Equation]:
    """Each equation after those defining what it reads (the paper's order otherwise; a cycle keeps its order)."""
    from nerfify_ns.equations.shapes import uses

    defined = {eq.defines for eq in equations}
    done: set = set()
    pending, out = list(equations), []
    while pending:
        for eq in pending:
            if {k for k in uses(eq) if k in defined and k != eq.defines} <= done:
                break
        else:
            eq = pending[0]
        pending.remove(eq)
        out.append(eq)
        done.add(eq.defines)
    return out


class WidthError(NerfifyError):
    """Widths that contradict each other (the message names the equation and the two widths)."""


@dataclass(frozen=True)
class Var:
    id: int


@dataclass(frozen=True)
class Sum:
    parts: tuple


SCALAR = ()


class Widths:
    def __init__(self) -> None:
        self.parent: dict[int, int] = {}
        self.fixed: dict[int, int] = {}
        self.shapes: dict[str, tuple] = {}
        self.matrices: set[str] = set()
        self.sums: list[tuple] = []     # (Sum, target)
        self.where = ""
        self._n = 0
        self.origin: dict[int, str] = {}

    # --------------------------------------------------------------- variables
    def var(self, origin: str = "") -> Var:
        self._n += 1
        self.parent[self._n] = self._n
        self.origin[self._n] = origin
        return Var(self._n)

    def find(self, v: Var) -> int:
        i = v.id
        while self.parent[i] != i:
            self.parent[i] = self.parent[self.parent[i]]
            i = self.parent[i]
        return i

    def resolve(self, w) -> int | None:
        if isinstance(w, int):
            return w
        if isinstance(w, Var):
            return self.fixed.get(self.find(w))
        if isinstance(w, Sum):
            parts = [self.resolve(p) for p in w.parts]
            return None if any(p is None for p in parts) else sum(parts)
        return None

    def unify(self, a, b) -> None:
        if a is None or b is None:
            return
        ra, rb = self.resolve(a), self.resolve(b)
        if ra is not None and rb is not None:
            if ra != rb and 1 not in (ra, rb):
                raise WidthError(f"{self.where}: widths {ra} and {rb} do not combine")
            return
        if isinstance(a, Sum) or isinstance(b, Sum):
            self.sums.append((a, b))
            return
        if isinstance(a, Var) and isinstance(b, Var):
            ia, ib = self.find(a), self.find(b)
            if ia != ib:
                self.parent[ia] = ib
                if ia in self.fixed:
                    self.fixed[ib] = self.fixed.pop(ia)
            return
        var, value = (a, rb) if isinstance(a, Var) else (b, ra)
        self.fixed[self.find(var)] = int(value)

    def set(self, v, value: int) -> None:
        self.unify(v, int(value))

    # --------------------------------------------------------------- declarations
    def known(self, key: str, shape: tuple) -> None:
        self.shapes[key] = tuple(shape)

    def matrix(self, key: str) -> tuple:
        shape = (self.var(f"{key} rows"), self.var(f"{key} columns"))
        self.shapes[key] = shape
        self.matrices.add(key)
        return shape

    def vector(self, key: str) -> tuple:
        shape = (self.var(key),)
        self.shapes[key] = shape
        return shape

    def value(self, key: str) -> tuple:
        return tuple(self.resolve(w) for w in self.shapes.get(key, ()))

    def open(self, key: str) -> list[int]:
        """Positions of ``key``'s shape that are still unknown."""
        return [i for i, w in enumerate(self.shapes.get(key, ())) if self.resolve(w) is None]

    # --------------------------------------------------------------- the walk
    def run(self, equations: list[Equation], rounds: int | None = None) -> None:
        """Propagate widths through ``equations`` until nothing changes (each round may settle one more link of a
        chain, whatever order the equations come in)."""
        equations = _in_dependency_order(equations)
        for _ in range(rounds or len(equations) + 2):
            before = (dict(self.fixed), {k: self.find(Var(k)) for k in self.parent})
            for eq in equations:
                self.where = f"equation {eq.number}" if eq.number else f"the equation of '{eq.defines}'"
                rhs = self.shape(eq.rhs)
                key = eq.defines
                if key is None:
                    continue
                if key in self.shapes and (self.shapes[key] or not rhs):
                    self._same(self.shapes[key], rhs)
                else:
                    self.shapes[key] = rhs
            self._settle_sums()
            after = (dict(self.fixed), {k: self.find(Var(k)) for k in self.parent})
            if after == before:
                break

    def _settle_sums(self) -> None:
        for a, b in list(self.sums):
            total, target = (a, b) if isinstance(a, Sum) else (b, a)
            want = self.resolve(target)
            if not isinstance(total, Sum):
                continue
            parts = [self.resolve(p) for p in total.parts]
            if want is None and all(p is not None for p in parts):
                self.unify(target, sum(parts))
            elif want is not None and sum(p is None for p in parts) == 1:
                missing = next(p for p, r in zip(total.parts, parts, strict=False) if r is None)
                rest = sum(r for r in parts if r is not None)
                if want - rest <= 0:
                    raise WidthError(f"{self.where}: a concatenation of width {want} cannot hold {rest} + more")
                self.unify(missing, want - rest)

    def _same(self, a: tuple, b: tuple) -> None:
        if len(a) != len(b):
            if not a or not b:
                return  # a scalar broadcasts
            raise WidthError(f"{self.where}: a value with {len(a)} feature dimension(s) and one with {len(b)}")
        for x, y in zip(a, b, strict=False):
            self.unify(x, y)

    def _broadcast(self, a: tuple, b: tuple) -> tuple:
        if not a:
            return b
        if not b:
            return a
        if len(a) == len(b):
            for x, y in zip(a, b, strict=False):
                if self.resolve(x) == 1:
                    continue
                if self.resolve(y) == 1:
                    continue
                self.unify(x, y)
            return tuple(y if self.resolve(x) == 1 else x for x, y in zip(a, b, strict=False))
        return a if len(a) > len(b) else b

    def shape(self, e) -> tuple:
        if isinstance(e, Number):
            return SCALAR
        if isinstance(e, Symbol):
            if is_bound_variable(e):
                return SCALAR
            return self.shapes.get(e.key, SCALAR)
        if isinstance(e, Neg):
            return self.shape(e.arg)
        if isinstance(e, BinOp):
            if e.op == "*" and isinstance(e.left, Symbol) and e.left.key in self.matrices:
                out, inp = self.shapes[e.left.key]
                right = self.shape(e.right)
                if right:
                    self.unify(inp, right[-1])
                return (out,)
            a, b = self.shape(e.left), self.shape(e.right)
            if e.op == "^":
                return a
            return self._broadcast(a, b)
        if isinstance(e, Apply):
            shapes = [self.shape(a) for a in e.args]
            if e.func == "mse":
                return SCALAR
            out = SCALAR
            for s in shapes:
                out = self._broadcast(out, s)
            return out
        if isinstance(e, Compare):
            return self._broadcast(self.shape(e.left), self.shape(e.right))
        if isinstance(e, Concat):
            parts = []
            for item in e.items:
                s = self.shape(item)
                parts.append(s[-1] if s else 1)
            values = [self.resolve(p) for p in parts]
            if all(v is not None for v in values):
                return (sum(values),)
            return (Sum(tuple(parts)),)
        if isinstance(e, Norm):
            s = self.shape(e.arg)
            return s[:-1]
        if isinstance(e, Reduce):
            return self.shape(e.body)
        if isinstance(e, Integral):
            return self.shape(e.quadrature if e.quadrature is not None else e.body)
        if isinstance(e, Cases):
            out = SCALAR
            for value, cond in e.branches:
                out = self._broadcast(out, self.shape(value))
                if cond is not None:
                    self.shape(cond)
            return out
        if isinstance(e, Expectation):
            return self.shape(e.body)
        return SCALAR
