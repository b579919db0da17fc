"""Contracts as data: the named tensors a component takes and returns, checked by the ladder.

A ``TensorSpec`` gives a symbolic shape (``"[R, S, 3]"``, ``"[N, num_levels * features_per_level]"``,
``"[]"`` for a scalar), a dtype, a value range, whether gradients must flow (inputs: finite gradients
reach them; outputs: they are differentiable) and a role that the example-input generator and the
stiff cases use (``positions``, ``directions``, ``values``, ``weights``, ``densities``, ``rays``,
``samples``, ...). Dimensions are integers, sizes (``N`` points, ``R`` rays, ``S`` samples per ray,
``in_dim`` the input width a harness chose), the component's parameters, or arithmetic over them
(``+ - * // **``, ``len(...)``, ``int(...)``, ``min``/``max``); ``out_dim`` is the component's own
``get_out_dim()`` where it has one.
"""

from __future__ import annotations

import ast
import math
import operator
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

SIZES = {"N": 64, "R": 16, "S": 8, "in_dim": 16, "cameras": 4}
"""Example sizes of the contract symbols (the contract and stability rungs run at these)."""

DTYPES = ("float", "long", "bool", "rays", "samples", "list", "function")


class ContractSpecError(ValueError):
    """A contract that cannot be read (a bad shape expression, an unknown dtype): a registry bug."""


@dataclass(frozen=True)
class TensorSpec:
    """One named tensor of a contract."""

    shape: str
    dtype: str = "float"
    range: tuple[float | None, float | None] = (None, None)
    grad: bool = False
    role: str = "values"
    doc: str = ""

    def __post_init__(self) -> None:
        if self.dtype not in DTYPES:
            raise ContractSpecError(f"unknown dtype {self.dtype!r} (one of {', '.join(DTYPES)})")
        dims(self.shape)  # fails early on a malformed shape

    def to_data(self) -> dict:
        data: dict[str, Any] = {"shape": self.shape, "dtype": self.dtype}
        if self.range != (None, None):
            data["range"] = list(self.range)
        if self.grad:
            data["grad"] = True
        data["role"] = self.role
        if self.doc:
            data["doc"] = self.doc
        return data


def T(shape: str, dtype: str = "float", *, range: tuple[float | None, float | None] = (None, None),
      grad: bool = False, role: str = "values", doc: str = "") -> TensorSpec:
    """Shorthand for a TensorSpec in terminal definitions."""
    return TensorSpec(shape=shape, dtype=dtype, range=range, grad=grad, role=role, doc=doc)


@dataclass(frozen=True)
class Contract:
    """Named inputs and outputs with symbolic shapes; ``sizes`` overrides example sizes of symbols."""

    inputs: dict[str, TensorSpec] = field(default_factory=dict)
    outputs: dict[str, TensorSpec] = field(default_factory=dict)
    sizes: dict[str, int] = field(default_factory=dict)
    free: tuple[str, ...] = ()
    """Symbols bound by the outputs themselves (``M`` packed samples): the first output using one sets it."""
    doc: str = ""

    def environment(self, params: Mapping[str, Any], case_sizes: Mapping[str, int] | None = None,
                    extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The symbols a shape may use: example sizes (per case), parameters, extra bindings."""
        return {**SIZES, **self.sizes, **(case_sizes or {}), **dict(params), **(extra or {})}

    def shape(self, spec: TensorSpec, env: Mapping[str, Any]) -> tuple[int, ...]:
        return tuple(eval_dim(d, env) for d in dims(spec.shape))

    def to_data(self) -> dict:
        data: dict[str, Any] = {"inputs": {k: v.to_data() for k, v in self.inputs.items()},
                                "outputs": {k: v.to_data() for k, v in self.outputs.items()}}
        if self.sizes:
            data["sizes"] = dict(self.sizes)
        if self.free:
            data["free"] = list(self.free)
        if self.doc:
            data["doc"] = self.doc
        return data

    @property
    def empty(self) -> bool:
        return not self.inputs and not self.outputs

    @classmethod
    def from_data(cls, raw: Mapping[str, Any]) -> Contract:
        """A contract from its data form (``to_data``; an empty mapping is the empty contract)."""
        def specs(group: Mapping[str, Any] | None) -> dict[str, TensorSpec]:
            return {k: TensorSpec(shape=v["shape"], dtype=v.get("dtype", "float"),
                                  range=tuple(v.get("range") or (None, None)), grad=bool(v.get("grad")),
                                  role=v.get("role", "values"), doc=v.get("doc", "")) for k, v in (group or {}).items()}
        return cls(inputs=specs(raw.get("inputs")), outputs=specs(raw.get("outputs")),
                   sizes=dict(raw.get("sizes") or {}), free=tuple(raw.get("free") or ()), doc=raw.get("doc", ""))

    # Read as a mapping, a contract is its data form (empty for the empty contract), as the grammar export has it.
    def keys(self):
        return ({} if self.empty else self.to_data()).keys()

    def __getitem__(self, key: str) -> Any:
        return ({} if self.empty else self.to_data())[key]

    def __bool__(self) -> bool:
        return not self.empty


# ------------------------------------------------------------------------------- shapes
_SHAPE = re.compile(r"^\s*\[(.*)\]\s*$")


def dims(shape: str) -> list[str]:
    """``"[R, S, 3]"`` -> ``["R", "S", "3"]``; ``"[]"`` -> ``[]`` (commas inside parentheses kept)."""
    match = _SHAPE.match(shape)
    if not match:
        raise ContractSpecError(f"a shape is written [d1, d2, ...], got {shape!r}")
    inner, parts, depth, current = match.group(1), [], 0, ""
    for ch in inner:
        depth += (ch == "(") - (ch == ")")
        if ch == "," and depth == 0:
            parts.append(current.strip())
            current = ""
        else:
            current += ch
    if current.strip():
        parts.append(current.strip())
    for part in parts:
        _parse(part)
    return parts


_BINARY: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.FloorDiv: operator.floordiv,
    ast.Pow: operator.pow, ast.Mod: operator.mod,
}
_CALLS: dict[str, Callable[..., Any]] = {"len": len, "int": int, "min": min, "max": max, "sum": sum,
                                         "ceil": math.ceil, "prod": math.prod}


def _parse(expr: str) -> ast.AST:
    try:
        return ast.parse(expr, mode="eval").body
    except SyntaxError:
        raise ContractSpecError(f"cannot read the dimension {expr!r}") from None


def eval_dim(expr: str, env: Mapping[str, Any]) -> int:
    """The integer a dimension expression takes under ``env`` (names, numbers, + - * // ** %, calls)."""
    value = _eval(_parse(expr), env, expr)
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise ContractSpecError(f"dimension {expr!r} is {value!r}, not an integer")
    return value


def _eval(node: ast.AST, env: Mapping[str, Any], expr: str) -> Any:
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float):
        return node.value
    if isinstance(node, ast.Name):
        if node.id not in env:
            raise ContractSpecError(f"dimension {expr!r}: unknown symbol {node.id!r}")
        value = env[node.id]
        return int(value) if isinstance(value, bool) else value
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        return _BINARY[type(node.op)](_eval(node.left, env, expr), _eval(node.right, env, expr))
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        return -_eval(node.operand, env, expr)
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _CALLS:
        return _CALLS[node.func.id](*[_eval(a, env, expr) for a in node.args])
    if isinstance(node, ast.List):
        return [_eval(e, env, expr) for e in node.elts]
    raise ContractSpecError(f"dimension {expr!r}: unsupported expression {ast.dump(node)[:60]}")


def symbols(shape: str) -> list[str]:
    """The names a shape refers to."""
    return sorted({n.id for d in dims(shape) for n in ast.walk(_parse(d)) if isinstance(n, ast.Name)}
                  - set(_CALLS))


# ------------------------------------------------------------------------------- checking
def check_outputs(contract: Contract, outputs: Mapping[str, Any], env: Mapping[str, Any], *,
                  float_inputs: bool = True) -> list[str]:
    """Problems of ``outputs`` against the contract: missing names, shapes, dtypes, device, value
    ranges, non-finite values. Each problem names the tensor, what the contract says and what came."""
    import torch

    problems: list[str] = []
    env = dict(env)
    for name, spec in contract.outputs.items():
        if name not in outputs:
            problems.append(f"{name}: missing (the contract declares outputs {sorted(contract.outputs)})")
            continue
        value = outputs[name]
        if spec.dtype in ("rays", "samples", "list", "function"):
            continue
        if not isinstance(value, torch.Tensor):
            problems.append(f"{name}: not a tensor ({type(value).__name__})")
            continue
        _bind_free(contract, spec, value, env)
        if len(dims(spec.shape)) != value.dim():
            problems.append(f"{name}: shape {tuple(value.shape)}, contract {spec.shape} "
                            f"({len(dims(spec.shape))} dimensions)")
        elif tuple(value.shape) != (expected := contract.shape(spec, env)):
            problems.append(f"{name}: shape {tuple(value.shape)}, contract {spec.shape} = {expected}")
        problems += _dtype_problems(name, spec, value, float_inputs)
        problems += _value_problems(name, spec, value)
    return problems


def _bind_free(contract: Contract, spec: TensorSpec, value: Any, env: dict[str, Any]) -> None:
    parts = dims(spec.shape)
    if len(parts) != value.dim():
        return
    for part, size in zip(parts, value.shape, strict=False):
        if part in contract.free and part not in env:
            env[part] = int(size)


def _dtype_problems(name: str, spec: TensorSpec, value: Any, float_inputs: bool) -> list[str]:
    import torch

    if value.device.type != "cpu":
        return [f"{name}: on {value.device}, inputs on cpu"]
    if spec.dtype == "float":
        if not value.is_floating_point():
            return [f"{name}: dtype {value.dtype}, contract float"]
        if float_inputs and value.dtype not in (torch.float32, torch.float64):
            return [f"{name}: dtype {value.dtype} from float32 inputs"]
    if spec.dtype == "long" and value.dtype not in (torch.int64, torch.int32):
        return [f"{name}: dtype {value.dtype}, contract long"]
    return []


def finite_problem(name: str, value: Any) -> str | None:
    import torch

    if isinstance(value, torch.Tensor) and value.is_floating_point() and value.numel() \
            and not torch.isfinite(value).all():
        bad = (~torch.isfinite(value)).sum().item()
        return f"{name}: {bad} of {value.numel()} values not finite"
    return None


def _value_problems(name: str, spec: TensorSpec, value: Any) -> list[str]:
    import torch

    problems = [p for p in [finite_problem(name, value)] if p]
    if not value.is_floating_point() or not value.numel():
        return problems
    finite = value[torch.isfinite(value)]
    low, high = spec.range
    if finite.numel() and low is not None and float(finite.min()) < low - 1e-4:
        problems.append(f"{name}: min {float(finite.min()):.3g} below the contract's {low}")
    if finite.numel() and high is not None and float(finite.max()) > high + 1e-4:
        problems.append(f"{name}: max {float(finite.max()):.3g} above the contract's {high}")
    return problems
