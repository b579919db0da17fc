"""Run one component (a registry terminal, or a custom component of a plugin) on one case and check it
against its contract. Runs only inside a sandboxed probe (it builds and calls component code).

    problems = run_terminal(registry["hash"], plan_params, "nominal")      # [] when the contract holds
    problems = run_custom(interface, custom_entry, "mypkg", "nominal")

Shapes, dtypes, ranges and finiteness come from the contract (``registry.contract.check_outputs``);
then the outputs are back-propagated: every trainable parameter must receive a gradient (nominal case)
and every gradient that arrives, at parameters and inputs, must be finite.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any

from nerfify_ns.registry.contract import Contract, check_outputs
from nerfify_ns.registry.examples import NotApplicable, case_sizes, example_inputs
from nerfify_ns.registry.snippets import build_from_code
from nerfify_ns.registry.terminal import TerminalDef


@dataclass
class CaseResult:
    """One component on one case: pass, fail (with problems) or n/a (why)."""

    case: str
    status: str
    problems: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"case": self.case, "status": self.status, "problems": self.problems}


def _tensors(value: Any) -> list[Any]:
    import torch

    if isinstance(value, torch.Tensor):
        return [value]
    if isinstance(value, list | tuple):
        return [t for v in value for t in _tensors(v)]
    return []


def gradient_problems(module: Any, inputs: dict[str, Any], outputs: dict[str, Any], required: bool) -> list[str]:
    """Back-propagate the sum of the finite outputs; parameters without gradient (when ``required``) and
    non-finite gradients at parameters and inputs are problems."""
    import torch

    differentiable = [v for v in outputs.values() if isinstance(v, torch.Tensor) and v.requires_grad]
    if not differentiable:
        return []
    total = sum(torch.where(torch.isfinite(v), v, torch.zeros_like(v)).float().sum() for v in differentiable)
    try:
        total.backward()
    except RuntimeError as exc:
        return [f"backward failed: {str(exc).splitlines()[0]}"]
    problems = []
    params = module.named_parameters() if isinstance(module, torch.nn.Module) else []
    for name, param in params:
        if not param.requires_grad:
            continue
        if param.grad is None:
            if required:
                problems.append(f"parameter {name} receives no gradient")
        elif not torch.isfinite(param.grad).all():
            problems.append(f"gradient of parameter {name} not finite")
    for name, value in inputs.items():
        for tensor in _tensors(value):
            if tensor.grad is not None and not torch.isfinite(tensor.grad).all():
                problems.append(f"gradient of input {name} not finite")
    return problems


def _default_call(contract: Contract):
    (output,) = contract.outputs

    def call(module, inputs, env):
        return {output: module(*inputs.values())}

    return call


def check_component(contract: Contract, build, call, params: dict[str, Any], case: str,
                    extra: dict[str, Any] | None = None) -> CaseResult:
    """Build, run on the case's example inputs, check outputs against ``contract``, back-propagate."""
    import torch

    torch.manual_seed(0)
    env = contract.environment(params, case_sizes(case), {**(extra or {}), "case": case})
    try:
        module = build(params, env)
        if hasattr(module, "get_out_dim"):
            env["out_dim"] = int(module.get_out_dim())
        if case == "half" and isinstance(module, torch.nn.Module):
            module = module.half()
        inputs = example_inputs(contract, env, case)
        outputs = call(module, inputs, env)
        problems = check_outputs(contract, outputs, env, float_inputs=case != "half")
        problems += gradient_problems(module, inputs, outputs, required=case == "nominal")
    except NotApplicable as exc:
        return CaseResult(case, "n/a", [str(exc)])
    except Exception as exc:  # noqa: BLE001 - component code may fail in any way: that is the finding
        first = str(exc).splitlines()[0][:200] if str(exc) else ""
        return CaseResult(case, "fail", [f"raised {type(exc).__name__}: {first}"])
    return CaseResult(case, "fail" if problems else "pass", problems)


def gradient_record(cap, module: Any, inputs: dict[str, Any], outputs: dict[str, Any]) -> tuple:
    """Back-propagate the sum of the finite outputs (with the functions ``cap`` bound before plugin code ran);
    (parameter name -> summed absolute gradient or None, input name -> summed absolute gradient). The judging
    happens in the checker (:mod:`nerfify_ns.verify.checker`)."""
    torch = cap.torch
    differentiable = [v for v in outputs.values() if isinstance(v, torch.Tensor) and v.requires_grad]
    if not differentiable:
        return {}, {}
    total = sum(cap.sum(cap.to(cap.where(cap.isfinite(v), v, cap.zeros_like(v)), torch.float32))
                for v in differentiable)
    cap.backward(total)
    params = module.named_parameters() if isinstance(module, torch.nn.Module) else []
    grads = {name: cap.abs_sum(p.grad) for name, p in params if p.requires_grad}
    input_grads = {}
    for name, value in inputs.items():
        for i, tensor in enumerate(_tensors(value)):
            if tensor.grad is not None:
                input_grads[f"{name}[{i}]" if i else name] = cap.abs_sum(tensor.grad)
    return grads, input_grads


def record_case(cap, contract: Contract, build, call, params: dict[str, Any], case: str) -> tuple:
    """Build, run on the case's example inputs and back-propagate, judging nothing: (header, arrays) for the
    checker, which holds the contract. Status ``ran``, ``n/a`` (why) or ``raised`` (what)."""
    torch = cap.torch
    from nerfify_ns.registry.examples import RUN_SEED

    torch.manual_seed(RUN_SEED)
    env = contract.environment(params, case_sizes(case), {"case": case})
    try:
        module = build(params, env)
        out_dim = int(module.get_out_dim()) if hasattr(module, "get_out_dim") else None
        if out_dim is not None:
            env["out_dim"] = out_dim
        if case == "half" and isinstance(module, torch.nn.Module):
            module = module.half()
        inputs = example_inputs(contract, env, case)
        outputs = call(module, inputs, env)
        if not isinstance(outputs, dict):
            raise TypeError(f"the component returned a {type(outputs).__name__}, not its named outputs")
        arrays, dtypes, others = {}, {}, {}
        for name, value in outputs.items():
            if isinstance(value, torch.Tensor):
                arrays[str(name)], dtypes[str(name)] = cap.array(value)
            else:
                others[str(name)] = type(value).__name__
        grads, input_grads = gradient_record(cap, module, inputs, outputs)
    except NotApplicable as exc:
        return {"status": "n/a", "message": str(exc)}, {}
    except Exception as exc:  # noqa: BLE001 - component code may fail in any way: that is the finding
        text = str(exc).splitlines()[0][:200] if str(exc) else ""
        return {"status": "raised", "message": f"raised {type(exc).__name__}: {text}"}, {}
    return {"status": "ran", "out_dim": out_dim, "dtypes": dtypes, "others": others, "grads": grads,
            "input_grads": input_grads}, arrays


def record_spec(cap, spec: dict[str, Any], package: str, case: str) -> tuple:
    """:func:`record_case` of one component of :func:`nerfify_ns.verify.checker.component_specs`."""
    if spec["terminal"] == "custom":
        interface, entry = spec["interface"], spec["entry"]

        def build(params, env):
            return custom_class(package, entry)(**interface_arguments(interface, env), **(entry.get("params") or {}))

        return record_case(cap, spec["contract"], build, interface.call, spec["params"], case)
    defn = spec["defn"]
    return record_case(cap, spec["contract"], _terminal_build(defn),
                       defn.harness.call or _default_call(spec["contract"]), spec["params"], case)


def _terminal_build(defn: TerminalDef):
    if defn.harness.build is not None:
        return defn.harness.build
    return lambda params, env: build_from_code(defn.code, params)


def run_terminal(defn: TerminalDef, params: dict[str, Any] | None, case: str = "nominal",
                 contract: Contract | None = None) -> CaseResult:
    """A registry terminal with the plan's ``params`` (shrunk to small sizes) on ``case``."""
    contract = contract or defn.contract
    call = defn.harness.call or _default_call(contract)
    return check_component(contract, _terminal_build(defn), call, defn.small(params), case)


def custom_class(package: str, entry: dict[str, Any]):
    """The class a custom entry names, imported from the plugin package (on ``sys.path``)."""
    module = importlib.import_module(f"{package}.{entry['module']}")
    return getattr(module, entry["class"])


def interface_arguments(interface, env: dict[str, Any]) -> dict[str, Any]:
    """The constructor arguments an interface passes besides ``params`` (the example sizes)."""
    import torch

    from nerfify_ns.registry.examples import AABB

    known = {"in_dim": int(env["in_dim"]), "out_dim": None, "num_images": int(env["cameras"]),
             "aabb": torch.tensor(AABB), "resolution": 16, "num_components": 8, "num_samples": int(env["S"]),
             "background_color": "white"}
    return {name: known[name] for name in interface.ctor}


def run_custom(interface, entry: dict[str, Any], package: str, case: str = "nominal",
               contract: Contract | None = None) -> CaseResult:
    """A custom component of the plugin against its production's interface."""
    contract = contract or interface.contract_for(entry)

    def build(params, env):
        return custom_class(package, entry)(**interface_arguments(interface, env), **(entry.get("params") or {}))

    return check_component(contract, build, interface.call, dict(entry), case)


# ----------------------------------------------------------------------------- the component suite
def _kplanes_density_build(params, env):
    import torch

    from nerfify_ns.components.kplanes import KPlanesDensityField
    from nerfify_ns.registry.examples import AABB, DENSITY_OFFSETS

    module = KPlanesDensityField(torch.tensor(AABB), resolution=8, num_components=4)
    offset = DENSITY_OFFSETS.get(env["case"])
    if offset is not None:
        module.linear.register_forward_hook(lambda m, i, o: o * 0 + offset)
    return module


def _kplanes_density_call(module, inputs, env):
    x = inputs["positions"]
    return {"density": module.density_fn(x.float() if env["case"] == "half" else x)}


def _extra_components() -> list[TerminalDef]:
    """Components of ours that fill a terminal indirectly (the k-planes proposal density field)."""
    from nerfify_ns.registry.contract import T
    from nerfify_ns.registry.terminal import Harness

    return [TerminalDef(
        "KPlanesDensityField", "Sampler", None, "A k-planes proposal density field.",
        "nerfify_ns.components.kplanes.KPlanesDensityField",
        contract=Contract({"positions": T("[N, 3]", grad=True, role="positions")},
                          {"density": T("[N, 1]", range=(0.0, None))}),
        harness=Harness(build=_kplanes_density_build, call=_kplanes_density_call,
                        cases=("density_raw_0", "density_raw_1e8", "density_raw_-1e8", "empty_batch",
                               "points_outside_contraction", "scene_scale_1e3")))]


def suite_components() -> list[tuple]:
    """(name, cases, run, (implementation, owner)) of every terminal with a contract, at default
    parameters, and of our indirect components: the stability suite of the whole knowledge base."""
    from nerfify_ns.registry import default_registry

    found = []
    for defn in [*default_registry(), *_extra_components()]:
        if defn.harness.in_model or defn.contract.empty:
            continue
        owner = "ours" if defn.implementation.startswith("nerfify_ns.") else "nerfstudio"
        found.append((defn.name, defn.harness.cases, lambda case, d=defn: run_terminal(d, None, case),
                      (defn.implementation, owner)))
    return found
