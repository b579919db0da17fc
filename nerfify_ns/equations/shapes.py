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


def param_specs(sizes: dict) -> dict[str, ParamSpec]:
    """The parameters of a sizes table (entries whose value is a shape or a ParamSpec)."""
    out = {}
    for key, value in (sizes or {}).items():
        if isinstance(value, ParamSpec):
            out[key] = value
        elif isinstance(value, (tuple, list)):
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


def batch_axes(dims: tuple) -> tuple[str, ...]:
    return tuple(d for d in dims[:2] if d in (RAY, SAMPLE))


def is_bound_variable(sym: Symbol) -> bool:
    """``t`` inside an integral over t, ``k`` inside a sum over a range: a variable, not a quantity."""
    return sym.index is not None and sym.name == sym.index.var and not sym.subscripts and not sym.superscript \
        and not sym.decorations and not sym.args


def uses(eq: Equation) -> set[str]:
    """The keys the right-hand side reads (a field's evaluation point is not read)."""
    out, stack = set(), [eq.rhs]
    while stack:
        node = stack.pop()
        if isinstance(node, Symbol):
            if not is_bound_variable(node):
                out.add(node.key)
            continue  # not its args
        if isinstance(node, Reduce) and node.axis != "range":
            stack.append(node.body)  # limits over samples or rays are read, not evaluated
            continue
        stack.extend(children(node))
    return out


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
