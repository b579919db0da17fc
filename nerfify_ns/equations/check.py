"""Check a lowering as any component is checked: the emitted module against the numpy interpreter.

``check_lowering(ir, bindings_spec, sizes)`` lowers the equations, runs the module in float64 on random
inputs and parameters, runs the interpreter on the same values, compares every output (relative tolerance
1e-6), and runs ``torch.autograd.gradcheck`` over the inputs and parameters. It never raises for a
failure of the equations: the report says what failed and why (``CheckReport.ok``, ``.reason``).

Bounded before it runs (a paper must not hang or exhaust our process): the equations' cost
(``shapes.check_cost``: nested finite ranges, operations) is checked by the lowering, the values the check
allocates by ``MAX_CHECK_VALUES``, and the gradcheck's work (two evaluations per perturbed value) by
``GRADCHECK_WORK``: past it the gradcheck runs in torch's fast mode (random projections: two evaluations per
input tensor), and past that too it is skipped, saying so.

``bindings_spec`` is the inputs' layouts (``{"sigma": ("R", "S"), "c": ("R", "S", 3)}``); ``domains``
gives an input's value range (default (0.1, 0.9): inside the domain of log, sqrt and division, and of
``1 - alpha`` products); parameters are drawn from N(0, 0.5^2 / fan_in).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .interpret import interpret
from .ir import Apply, Equation, walk
from .lower import _as_equations, lower_module
from .shapes import CompileError, evaluation_cost, resolve_dims

DEFAULT_DOMAIN = (0.1, 0.9)
MAX_CHECK_VALUES = 1_000_000
"""Values (inputs and parameters at the check's sizes) the check may allocate; the binder checks at small
sizes (a few thousand values)."""
GRADCHECK_WORK = 500_000
"""Operations the gradcheck may run (evaluations it needs times the equations' operations per evaluation)."""


def _describe(err: BaseException) -> str:
    message = " ".join(str(err).split())[:200]
    return f"{type(err).__name__}: {message}" if message else type(err).__name__


@dataclass
class OutputCheck:
    key: str
    shape: tuple
    max_abs: float
    max_rel: float
    ok: bool


@dataclass
class CheckReport:
    ok: bool
    reason: str = ""
    outputs: list[OutputCheck] = field(default_factory=list)
    gradcheck: str = "not run"
    source: str = ""

    def __str__(self) -> str:
        parts = [("passed" if self.ok else f"failed: {self.reason}")]
        parts += [f"{o.key}: max rel {o.max_rel:.1e}" for o in self.outputs]
        parts.append(f"gradcheck {self.gradcheck}")
        return "; ".join(parts)


def _uses_stopgrad(equations: list[Equation]) -> bool:
    return any(isinstance(n, Apply) and n.func == "stopgrad" for eq in equations for n in walk(eq.rhs))


def check_lowering(ir, bindings_spec: dict, sizes: dict | None = None, outputs: list[str] | None = None, *,
                   n_rays: int = 3, n_samples: int = 5, seed: int = 0, rtol: float = 1e-6,
                   domains: dict | None = None, gradcheck: bool = True,
                   class_name: str = "CheckedEquations") -> CheckReport:
    """Lower, run, compare with the interpreter, gradcheck (see the module docstring)."""
    import torch

    sizes = dict(sizes or {})
    domains = dict(domains or {})
    try:
        equations = _as_equations(ir)
        outputs = list(outputs) if outputs is not None else [eq.defines for eq in equations]
        lowered = lower_module(equations, bindings_spec, outputs, sizes, class_name)
    except CompileError as err:
        return CheckReport(False, f"lowering: {err}")
    except Exception as err:  # noqa: BLE001 - a lowering bug on what a paper wrote: the part's reason
        return CheckReport(False, f"lowering: {_describe(err)}")
    report = CheckReport(False, source=lowered.source)
    try:
        shapes = {key: resolve_dims(tuple(dims), sizes, n_rays, n_samples) for key, _, dims in lowered.inputs}
    except CompileError as err:
        report.reason = f"inputs: {err}"
        return report
    n_values = sum(int(np.prod(shape, dtype=np.float64)) for shape in shapes.values()) + sum(
        int(np.prod(spec.shape, dtype=np.float64)) for _, spec in lowered.params.values())
    if n_values > MAX_CHECK_VALUES:
        report.reason = (f"not checked: the inputs and parameters at the check's sizes hold {n_values:,} values "
                         f"(at most {MAX_CHECK_VALUES:,})")
        return report
    namespace: dict = {}
    try:
        exec(compile(lowered.source, f"<nerfify-equations {class_name}>", "exec"), namespace)  # our own source
        module = namespace[class_name]().double()
    except Exception as err:  # noqa: BLE001 - a lowering bug: report it with the source
        report.reason = f"the module does not build: {type(err).__name__}: {err}"
        return report
    rng = np.random.default_rng(seed)
    values: dict[str, np.ndarray] = {}
    layout: dict[str, tuple] = {}
    for key, _, dims in lowered.inputs:
        shape = shapes[key]
        lo, hi = domains.get(key, DEFAULT_DOMAIN)
        values[key] = rng.uniform(lo, hi, size=shape)
        layout[key] = tuple(dims)
    with torch.no_grad():
        for key, (attr, spec) in lowered.params.items():
            fan_in = spec.shape[-1] if spec.shape else 1
            arr = rng.normal(0.0, 0.5 / np.sqrt(max(fan_in, 1)), size=spec.shape)
            if spec.clamp:  # values inside the paper's constraint (the module projects onto it when training)
                low, high = (v if v is not None else d for v, d in zip(spec.clamp, (-1.0, 1.0), strict=True))
                arr = rng.uniform(low + 0.1 * (high - low), high - 0.1 * (high - low), size=spec.shape)
            getattr(module, attr).copy_(torch.from_numpy(arr))
            values[key] = arr
            layout[key] = tuple(range(len(spec.shape)))
    inputs = [torch.from_numpy(values[key]).clone() for key, _, _ in lowered.inputs]
    try:
        with torch.no_grad():
            got = module(*inputs)
    except Exception as err:  # noqa: BLE001 - the generated module failed: report it
        report.reason = f"the module failed: {type(err).__name__}: {err}"
        return report
    got = got if isinstance(got, tuple) else (got,)
    try:
        want = interpret(equations, values, layout, sizes, outputs)
    except CompileError as err:
        report.reason = f"interpreter: {err}"
        return report
    except Exception as err:  # noqa: BLE001 - the interpreter on what a paper wrote: the part's reason
        report.reason = f"interpreter: {_describe(err)}"
        return report
    ok = True
    for key, tensor in zip(outputs, got, strict=False):
        a, b = tensor.detach().numpy(), np.asarray(want[key], dtype=np.float64)
        if a.shape != b.shape:
            report.outputs.append(OutputCheck(key, a.shape, float("inf"), float("inf"), False))
            report.reason = f"'{key}': shape {a.shape} from the module, {b.shape} from the interpreter"
            ok = False
            continue
        same = (a == b) | (np.isnan(a) & np.isnan(b))  # equal infinities and NaNs from both agree
        finite = np.isfinite(a) & np.isfinite(b)
        diff = np.where(finite, np.abs(np.where(finite, a, 0.0) - np.where(finite, b, 0.0)), 0.0)
        scale = np.where(finite, np.abs(b), 0.0)
        atol = 1e-12 * max(1.0, float(scale.max(initial=0.0)))
        good = bool(np.all(same | (finite & (diff <= rtol * scale + atol))))
        rel = float(np.max(diff / np.maximum(scale, atol), initial=0.0)) if diff.size else 0.0
        report.outputs.append(OutputCheck(key, a.shape, float(diff.max(initial=0.0)), rel, good))
        if not good:
            ok = False
            report.reason = report.reason or f"'{key}' differs from the interpreter (max relative error {rel:.2e})"
    if ok and gradcheck:
        operations = evaluation_cost(equations, sizes).operations
        full, fast = 2 * n_values * operations, 2 * (len(inputs) + len(lowered.params) + 1) * operations
        if full <= GRADCHECK_WORK or fast <= GRADCHECK_WORK:
            report.gradcheck = _gradcheck(module, lowered, inputs, equations, fast=full > GRADCHECK_WORK)
        else:
            report.gradcheck = (f"skipped: a numerical gradient of {operations:,} operations per evaluation over "
                                f"{n_values:,} values is past the check's budget ({GRADCHECK_WORK:,} operations)")
        if report.gradcheck.startswith("failed"):
            ok = False
            report.reason = f"gradcheck {report.gradcheck}"
    elif not gradcheck:
        report.gradcheck = "skipped: not requested"
    report.ok = ok
    return report


def _gradcheck(module, lowered, inputs, equations, fast: bool = False) -> str:
    import torch
    from torch.func import functional_call

    if _uses_stopgrad(equations):
        return "skipped: a stop-gradient (sg) makes the numerical gradient differ by design"
    names = [attr for attr, spec in lowered.params.values() if spec.learned]
    params = [getattr(module, n).detach().clone().requires_grad_(True) for n in names]
    xs = [x.detach().clone().requires_grad_(True) for x in inputs]
    n_in = len(xs)

    def fn(*tensors):
        state = dict(zip(names, tensors[n_in:], strict=False))
        out = functional_call(module, state, tuple(tensors[:n_in]))
        out = out if isinstance(out, tuple) else (out,)
        return torch.cat([o.reshape(-1) for o in out])

    with torch.no_grad():
        scale = float(fn(*xs, *params).abs().max()) if n_in + len(params) else 0.0
    # central differences with step 1e-6 carry an absolute error of about 1e-16 * |y| / 1e-6
    atol = 1e-6 + 1e-9 * scale
    try:
        torch.autograd.gradcheck(fn, tuple(xs + params), eps=1e-6, atol=atol, rtol=1e-4, fast_mode=fast)
    except Exception as err:  # noqa: BLE001 - torch raises GradcheckError (and RuntimeError for bad graphs)
        return "failed: " + (str(err).strip().splitlines() or [type(err).__name__])[0][:200]
    return "passed (fast mode: random projections, the full Jacobian would cost too much)" if fast else "passed"

