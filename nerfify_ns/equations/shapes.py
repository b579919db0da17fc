"""Layouts and sizes shared by the interpreter, the lowering and the checks.

Convention: a per-ray tensor is ``[R, ...features]``; a per-sample tensor is ``[R, S, ...features]`` (R
rays, S samples along each ray); a learned parameter has its own shape (``W [out, in]``, ``b [out]``);
a scalar has shape ``()``. A layout names a binding's dimensions: ``("R", "S", 3)`` or ``("R", "F")``
with ``F`` looked up in the sizes table. Within an equation each sample index (``i``, ``j``, ``t``)
is its own axis, ordered outer to inner after ``R``; a result keeps at most one, which becomes ``S``.

Sizes table (the caller's): named dimensions -> int (``{"F": 32, "L": 8}``) and learned parameters ->
shape or ``ParamSpec`` (``{"W_gamma": (64, 32), "b_gamma": (64,), "B": ParamSpec((16, 3), learned=False,
init="normal", std=10.0)}``).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import NerfifyError
from .ir import Equation, Reduce, Symbol, children, walk

RAY, SAMPLE = "R", "S"


class CompileError(NerfifyError):
    """An equation that was read but cannot be evaluated or lowered (the message says which and why)."""


class ShapeError(CompileError):
    """Shapes that do not fit (the message names the equation and the operands)."""


@dataclass(frozen=True)
class ParamSpec:
    """A learned (or fixed random) matrix/vector named by the paper: shape, whether trained, initialiser
    ('default': kaiming-uniform for matrices as nn.Linear, zeros for vectors; 'normal' with ``std``;
    'zeros'; 'ones')."""

    shape: tuple[int, ...]
    learned: bool = True
    init: str = "default"
    std: float = 1.0
    clamp: tuple | None = None
    """(low, high), either None: the paper's constraint on the learned values ("clamped to [0, 1]"), applied at
    every training step (the values are projected before each forward pass) and by the initialiser."""


def param_specs(sizes: dict) -> dict[str, ParamSpec]:
    """The parameters of a sizes table (entries whose value is a shape or a ParamSpec)."""
    out = {}
    for key, value in (sizes or {}).items():
        if isinstance(value, ParamSpec):
            out[key] = value
        elif isinstance(value, tuple | list):
            out[key] = ParamSpec(tuple(int(v) for v in value))
    return out


def named_sizes(sizes: dict) -> dict[str, int]:
    return {k: int(v) for k, v in (sizes or {}).items() if isinstance(v, int) and not isinstance(v, bool)}


def resolve_dims(dims: tuple, sizes: dict, n_rays: int | None = None, n_samples: int | None = None) -> tuple:
    """A layout's dimensions as ints (R and S from the arguments, names from the sizes table)."""
    named = named_sizes(sizes)
    out = []
    for d in dims:
        if d == RAY:
            out.append(n_rays)
        elif d == SAMPLE:
            out.append(n_samples)
        elif isinstance(d, int):
            out.append(d)
        elif d in named:
            out.append(named[d])
        else:
            raise ShapeError(f"size '{d}' is not in the sizes table")
    return tuple(out)


def check_layout(key: str, dims: tuple) -> None:
    dims = tuple(dims)
    if SAMPLE in dims and dims[:2] != (RAY, SAMPLE):
        raise ShapeError(f"layout of '{key}': per-sample tensors are [R, S, ...features], got {list(dims)}")
    if RAY in dims and dims[0] != RAY:
        raise ShapeError(f"layout of '{key}': the ray dimension R comes first, got {list(dims)}")


def sample_indexed_keys(equations: list[Equation]) -> set[str]:
    """Keys used with a sample index anywhere (their bindings are per-sample by default)."""
    keys = set()
    for eq in equations:
        for side in (eq.lhs, eq.rhs):
            for node in walk(side):
                if isinstance(node, Symbol) and node.index is not None and node.name != node.index.var:
                    keys.add(node.key)
    return keys


def is_bound_variable(sym: Symbol) -> bool:
    """``t`` inside an integral over t, ``k`` inside a sum over a range: a variable, not a quantity."""
    return sym.index is not None and sym.name == sym.index.var and not sym.subscripts and not sym.superscript \
        and not sym.decorations and not sym.args


def uses(eq: Equation) -> set[str]:
    """The keys the right-hand side reads (a field's evaluation point is not read; ``a_k`` inside a sum over the
    range of ``k`` reads ``a``, whose component k it is)."""
    out, stack = set(), [(eq.rhs, frozenset())]
    while stack:
        node, ranges = stack.pop()
        if isinstance(node, Symbol):
            if not is_bound_variable(node):
                out.add(component_base(node, ranges).key)
            continue  # not its args
        if isinstance(node, Reduce) and node.axis != "range":
            stack.append((node.body, ranges))  # limits over samples or rays are read, not evaluated
            continue
        inner = ranges | {node.index} if isinstance(node, Reduce) else ranges
        stack.extend((c, inner if c is getattr(node, "body", None) else ranges) for c in children(node))
    return out


def component_base(sym: Symbol, ranges) -> Symbol:
    """``a_k`` read inside a sum over the range of ``k``: the symbol ``a`` whose k-th component it is (one range
    subscript); any other symbol is itself."""
    looped = [lab for lab in sym.subscripts if lab in ranges]
    if len(looped) != 1 or (sym.superscript and sym.superscript in ranges):
        return sym
    return Symbol(sym.name, tuple(lab for lab in sym.subscripts if lab != looped[0]), sym.superscript,
                  sym.decorations, sym.index, sym.args)


def schedule(equations: list[Equation], outputs: list[str], available: set[str]) -> list[Equation]:
    """The equations the outputs need, each after the ones it reads (``available``: inputs, parameters,
    sizes). A symbol both available and defined is state: its definition reads the given (previous)
    value and later equations read the new one."""
    by_key: dict[str, Equation] = {}
    for eq in equations:
        key = eq.defines
        if key is None:
            raise CompileError(f"equation {eq.number or '?'}: the left side is not a symbol")
        if key in by_key:
            raise CompileError(f"'{key}' is defined twice (equations {by_key[key].number or '?'} and "
                               f"{eq.number or '?'})")
        by_key[key] = eq
    order: list[Equation] = []
    state: dict[str, str] = {}

    def visit(key: str, chain: tuple[str, ...]) -> None:
        if state.get(key) == "done":
            return
        if key not in by_key:
            if key in available:
                state[key] = "done"
                return
            raise CompileError(f"'{key}' is neither an input, a parameter nor defined by an equation"
                               + (f" (needed by '{chain[-1]}')" if chain else ""))
        if state.get(key) == "visiting":
            raise CompileError("equations define each other in a cycle: " + " -> ".join(chain + (key,)))
        state[key] = "visiting"
        eq = by_key[key]
        for dep in sorted(uses(eq)):
            if dep == key:
                if key not in available:
                    raise CompileError(f"'{key}' is defined in terms of itself (equation {eq.number or '?'}): "
                                       "pass its previous value as an input (persistent state)")
                continue
            visit(dep, chain + (key,))
        state[key] = "done"
        order.append(eq)

    for key in outputs:
        visit(key, ())
    # the paper's order wherever the dependencies allow it
    needed, done, stable = {id(eq) for eq in order}, set(), []
    pending = [eq for eq in equations if id(eq) in needed]
    while pending:
        for eq in pending:
            deps = {d for d in uses(eq) if d in by_key and d != eq.defines and id(by_key[d]) in needed}
            if deps <= done:
                stable.append(eq)
                done.add(eq.defines)
                pending.remove(eq)
                break
        else:  # pragma: no cover - the walk above already rejected cycles
            raise CompileError("equations define each other in a cycle")
    return stable


# --- the cost of evaluating equations, known before anything runs ---------------------------------------

MAX_RANGE = 4096
"""Terms of one finite range (``\\sum_{k=0}^{L-1}``)."""

MAX_RANGE_ITERATIONS = 4096
"""Iterations of finite ranges in one evaluation of the equations, nested ranges multiplied and ranges side by
side added (a spherical-harmonics basis of degree 4 takes 16-25, a positional encoding 10-20). Three nested
``\\sum_{k=1}^{4096}`` ask for 7e10 and are refused before the lowering, the interpreter or the check runs."""

MAX_OPERATIONS = 20_000
"""Operations (IR nodes, a range's body counted once per iteration) in one evaluation of the equations: a
part's equations have tens to a few hundred (a spherical-harmonics colour head of degree 4 about 300). The
check runs the module and the interpreter once and the gradcheck twice per perturbed value, so this bounds
the time one part's check takes (``check.py``)."""


@dataclass(frozen=True)
class Cost:
    """What one evaluation of some equations asks for: ``iterations`` of finite ranges (nested multiplied),
    ``operations`` (IR nodes, a range's body once per iteration)."""

    iterations: int
    operations: int


def _interval(e, env: dict, named: dict):
    """The (low, high) a range limit can take, with the enclosing ranges' variables at any of their values;
    None when it is not a number, a size or arithmetic of them (the lowering refuses those)."""
    import math

    from .ir import BinOp, Neg, Number

    if isinstance(e, Number):
        return (float(e.value), float(e.value)) if math.isfinite(e.value) else None
    if isinstance(e, Symbol) and not e.subscripts and not e.args:
        if e.name in env:
            return env[e.name]
        if e.key in named:
            return (float(named[e.key]), float(named[e.key]))
        return None
    if isinstance(e, Neg):
        inner = _interval(e.arg, env, named)
        return None if inner is None else (-inner[1], -inner[0])
    if isinstance(e, BinOp) and e.op in ("+", "-", "*"):
        a, b = _interval(e.left, env, named), _interval(e.right, env, named)
        if a is None or b is None:
            return None
        if e.op == "+":
            return (a[0] + b[0], a[1] + b[1])
        if e.op == "-":
            return (a[0] - b[1], a[1] - b[0])
        products = [x * y for x in a for y in b]
        return (min(products), max(products))
    return None


def _cost(e, env: dict, named: dict) -> tuple[int, int]:
    if isinstance(e, Reduce) and e.axis == "range":
        lo = _interval(e.lower, env, named) if e.lower is not None else None
        hi = _interval(e.upper, env, named) if e.upper is not None else None
        if lo is None or hi is None:
            # limits that are not numbers or sizes: the lowering refuses them, the interpreter counts its
            # iterations as it runs them (MAX_RANGE_ITERATIONS); here the body is counted once
            count, inner_env = 1, {k: v for k, v in env.items() if k != e.index}
        else:
            span = min(hi[1], 1e15) - max(lo[0], -1e15) + 1
            count = max(0, int(span))
            inner_env = {**env, e.index: (lo[0], hi[1])}
        body_iterations, body_operations = _cost(e.body, inner_env, named)
        return count * (1 + body_iterations), 1 + count * body_operations
    iterations, operations = 0, 1
    for child in children(e):
        i, o = _cost(child, env, named)
        iterations, operations = iterations + i, operations + o
    return iterations, operations


def evaluation_cost(equations, sizes: dict | None = None) -> Cost:
    """The cost of one evaluation of ``equations`` (see ``Cost``), from the IR and the sizes alone."""
    named = named_sizes(sizes or {})
    iterations = operations = 0
    for eq in equations:
        if not isinstance(eq, Equation):
            continue
        for side in (eq.rhs, *eq.also):
            i, o = _cost(side, {}, named)
            iterations, operations = iterations + i, operations + o
    return Cost(iterations, operations)


def check_cost(equations, sizes: dict | None = None) -> Cost:
    """``evaluation_cost``, or a CompileError when it is past ``MAX_RANGE_ITERATIONS`` or ``MAX_OPERATIONS``:
    checked before anything is lowered, interpreted or run."""
    cost = evaluation_cost(equations, sizes)
    if cost.iterations > MAX_RANGE_ITERATIONS:
        raise CompileError(f"the equations ask for {_count(cost.iterations)} iterations of finite ranges in one "
                           f"evaluation (nested ranges multiply); at most {MAX_RANGE_ITERATIONS:,} are run")
    if cost.operations > MAX_OPERATIONS:
        raise CompileError(f"the equations ask for {_count(cost.operations)} operations in one evaluation; at most "
                           f"{MAX_OPERATIONS:,} are run")
    return cost


def _count(n: int) -> str:
    return f"{n:,}" if n < 10**9 else f"{float(n):.1e}"
