"""A bound hole lowered into a component: the sizes at the check's small scale and at the paper's, the equations
module through the one compile path (``equations.compile_equations``, checked against the interpreter), the wiring
of networks, state, bases and inputs around it (``adapters.py``) and the component's own contract check on its
interface's example inputs."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from nerfify_ns.equations import (
    BinOp,
    compile_equations,
    show,
)
from nerfify_ns.equations.ir import walk
from nerfify_ns.equations.naming import Names
from nerfify_ns.equations.shapes import CompileError, ParamSpec, sample_indexed_keys
from nerfify_ns.equations.show import safe_comment
from nerfify_ns.synthesis.novel.adapters import (
    Adapter,
    Feed,
    NetSpec,
    StateSpec,
    Wiring,
)
from nerfify_ns.synthesis.novel.binding import _Attempt, _Hole, _short

SMALL_RUNTIME = 5          # the width of a runtime input (the interface's in_dim) in the checks


FULL_RUNTIME = 999_983     # ... in the component's source: a sentinel the constructor's in_dim replaces


SMALL_SENTINEL = 999_979   # ... in the self-check's small component


@dataclass
class _Sized:
    params: dict          # key -> ParamSpec
    widths: dict          # key -> int or None (inputs, networks, state, basis, outputs)
    evidence: dict
    solver: Any
    runtime: int = 0


def _sizes(work: _Hole, att: _Attempt, bindings: dict, runtime: int, small: bool) -> _Sized:
    solver, evidence = work.solve(att, bindings, runtime, small=small)
    params, widths = {}, {}
    for key, b in bindings.items():
        value = solver.value(key)
        if b["as"] == "parameter":
            clamp = tuple(b["clamp"]) if b.get("clamp") else None
            params[key] = ParamSpec(tuple(int(v) for v in value), clamp=clamp)
        else:
            widths[key] = value[0] if value else None
    for key in att.outputs:
        value = solver.value(key)
        widths[key] = value[0] if value else None
    return _Sized(params, widths, evidence, solver, runtime)


def _inputs(att: _Attempt, bindings: dict, sized: _Sized) -> dict:
    """The equations module's inputs (every bound symbol but the parameters), with their layouts."""
    seq = sample_indexed_keys(att.equations)
    out = {}
    for key, b in bindings.items():
        if b["as"] in ("parameter", "constant"):
            continue
        per_sample = bool(b.get("per_sample")) or (key in seq and b["as"] == "network")
        width = sized.widths.get(key)
        out[key] = (("R", "S") if per_sample else ("R",)) + ((int(width),) if width else ())
    return out


def _outputs(att: _Attempt, bindings: dict) -> list[str]:
    return list(att.outputs) + [k for k, b in bindings.items() if b["as"] == "state"]


def _domains(work: _Hole, bindings: dict) -> dict:
    """The value range of each input in the check, from its role's range (a density is non-negative, a weight lies
    in [0, 1]): the check's default range (0.1, 0.9) clipped to it."""
    out = {}
    for key, b in bindings.items():
        role = work.notation.roles.get(b.get("role") or "")
        if b["as"] in ("parameter", "constant") or role is None or role.range == (None, None):
            continue
        lo, hi = role.range
        low = 0.1 if lo is None else max(0.1, float(lo) + 0.05)
        high = 0.9 if hi is None else min(0.9, float(hi) - 0.05)
        if low < high:
            out[key] = (low, high)
    return out


def _lower(work: _Hole, att: _Attempt, bindings: dict, sized: _Sized, class_name: str, check: bool):
    """Lower (and check) the equations through the one compile path (``equations.compile_equations``)."""
    return compile_equations(att.equations, _inputs(att, bindings, sized), _outputs(att, bindings), sized.params,
                             class_name, check=check, domains=_domains(work, bindings))


def _runtime_width(source: str, sentinel: int, wiring: Wiring, adapter: Adapter) -> str:
    """A learned matrix that multiplies the interface's input has that input's width, known when the plugin is
    built (``in_dim``): the sentinel width it was lowered with becomes the constructor's ``in_dim``."""
    pattern = re.compile(rf"(?<![\d.]){sentinel}(?![\d.])")
    if not pattern.search(source):
        return source
    if not adapter.runtime_width:
        raise CompileError(f"a learned matrix multiplies an input of the {adapter.production} interface whose width "
                           "is known only when the plugin is built")
    source = pattern.sub("in_dim", source)
    source = source.replace("    def __init__(self):\n        super().__init__()",
                            "    def __init__(self, in_dim):\n        super().__init__()", 1)
    wiring.equations_args = adapter.runtime_width
    return source


def _operator_discrepancies(work: _Hole, att: _Attempt, sized: _Sized) -> list[str]:
    """Where the paper's words for an operator disagree with the shapes ("⊗ represents the dot product" between two
    vectors of one width, which the equations can only use element-wise): the shapes are followed, and said."""
    element_wise = [n for eq in att.equations for n in walk(eq.rhs) if isinstance(n, BinOp) and n.op == "odot"]
    notes = []
    for op, called, quote, where in work.words.operators:
        if called in ("dot", "inner", "scalar", "matrix", "outer", "kronecker") and element_wise:
            example = element_wise[0]
            try:
                width = sized.solver.shape(example.left)
            except Exception:  # noqa: BLE001 - a note only
                width = ()
            w = sized.solver.resolve(width[0]) if width else None
            notes.append(f"the paper calls {op} a {called} product ({where}: \"{_short(quote, 120)}\"), but the "
                         f"shapes ({show(example.left)} and {show(example.right)}, {w or 'one'} feature(s) each, whose "
                         "result is combined element-wise with vectors of that width) allow only an element-wise "
                         "product: compiled element-wise, following the shapes")
            break
    return notes


def _selfcheck(source: str, cls: str, production: str, params: dict) -> str:
    """The component built and run once on its interface's example inputs (the registry's, nominal case), as the
    contract rung will: outputs against the contract, a backward pass with finite gradients. '' when it holds,
    else the problems. Our own generated code, run in this process (the ladder runs the plugin sandboxed)."""
    import torch

    from nerfify_ns.registry import default_registry
    from nerfify_ns.registry.contract import check_outputs
    from nerfify_ns.registry.examples import example_inputs

    interface = default_registry().interfaces[production]
    namespace: dict = {"__name__": "nerfify_compiled_component"}
    try:
        exec(compile(source, f"<compiled {cls}>", "exec"), namespace)  # noqa: S102 - our generated source
        torch.manual_seed(0)
        contract = interface.contract_for(params or {})
        env = contract.environment(params or {}, {}, {"case": "nominal"})
        known = {"in_dim": int(env["in_dim"]), "out_dim": None, "background_color": "white"}
        module = namespace[cls](**{k: known[k] for k in interface.ctor if k in known}, **(params or {}))
        if hasattr(module, "get_out_dim"):
            env["out_dim"] = int(module.get_out_dim())
        inputs = example_inputs(contract, env, "nominal")
        outputs = interface.call(module, inputs, env)
        problems = list(check_outputs(contract, outputs, env))
        total = sum(v.float().sum() for v in outputs.values() if isinstance(v, torch.Tensor) and v.requires_grad)
        if isinstance(total, torch.Tensor):
            total.backward()
            problems += [f"gradient of {n} not finite" for n, p in module.named_parameters()
                         if p.grad is not None and not torch.isfinite(p.grad).all()]
    except Exception as err:  # noqa: BLE001 - a compiler bug, reported with the component
        return f"raised {type(err).__name__}: {str(err).splitlines()[0][:200] if str(err) else ''}"
    return "; ".join(problems)[:400]


def _plain_binding(b: dict) -> dict:
    return {k: v for k, v in b.items() if k not in ("code", "per_sample", "width", "scalar") and v not in (None, "")}


def _class_name(hid: str) -> str:
    return "".join(part.capitalize() for part in re.split(r"[^a-zA-Z0-9]+", hid) if part) + "FromEquations"


def _wiring(work: _Hole, att: _Attempt, bindings: dict, lowered, sized: _Sized, cls: str,
            small: bool = False) -> Wiring:
    names = Names()
    w = Wiring(cls=cls, eq_cls=f"{cls}Equations")
    layers = work.words.layers[0] if work.words.layers else None
    width = work.words.widths[0] if work.words.widths else None
    depth_text = (f"{layers[0]} layers ({layers[2]}: \"{_short(layers[1], 100)}\")" if layers
                  else "2 layers (the paper states no depth)")
    width_text = (f"{width[0]} wide ({width[2]}: \"{_short(width[1], 100)}\")" if width
                  else "64 wide (the paper states no width)")
    for key, _ident, dims in lowered.inputs:
        b = bindings[key]
        local = names.get("a", key)
        if b["as"] == "network":
            net = NetSpec(key, names.get("net", key), None if b.get("scalar") else sized.widths.get(key),
                          layers[0] if layers else 2, width[0] if width else 64, b.get("activation"),
                          per_sample=("S" in dims), evidence=f"{depth_text}, {width_text}")
            w.networks.append(net)
            b["network"] = {"reads": work.adapter.network_input, "layers": net.layers, "width": net.width,
                            "out": net.out_width or 1, "activation": net.activation or "none",
                            "evidence": net.evidence,
                            "sentences": list(dict.fromkeys(s[1] for s in (layers, width) if s))}
            w.feeds.append(Feed(key, local, ""))
        elif b["as"] == "state":
            st = StateSpec(key, names.get("state", key), int(b.get("rows", 1)), int(sized.widths.get(key) or 1))
            w.states.append((st, ""))
            w.feeds.append(Feed(key, local, f"_read_state(self.{st.attr}, x)"))
        elif b["as"] == "basis":
            if work.context.get("dir_encoding") != "sh" or not work.context.get("dir_dim"):
                raise CompileError(f"'{safe_comment(b['basis'], 20)}' is the spherical-harmonics basis of the viewing "
                                   "direction: the plan's direction encoding must be `sh` for the colour head to "
                                   f"receive it (it is `{safe_comment(str(work.context.get('dir_encoding')), 20)}`)")
            channels, size = int(sized.widths.get(key) or 1), int(work.context["dir_dim"])
            net = NetSpec(b["coefficient"], names.get("net", b["coefficient"]), channels * size,
                          1, width[0] if width else 64, None,
                          evidence=f"a linear map of the geometry features to {channels} x {size} coefficients "
                                   f"(channels x the basis' size: levels {work.context.get('sh_levels')} of the "
                                   "plan's direction encoding)")
            w.networks.append(net)
            w.feeds.append(Feed(key, local, f"_basis_sum(self.{net.attr}(geometry), x[:, : self.dir_dim], {channels})"))
            b["network"] = {"reads": work.adapter.network_input, "layers": 1, "out": channels * size,
                            "evidence": net.evidence}
            b["size"] = size
            b["degree"] = (f"l_max = {int(work.context.get('sh_levels') or 1) - 1}: the plan's direction encoding "
                           f"(sh, levels {work.context.get('sh_levels')}; "
                           f"{_short(work.plan.evidence_for(work.context.get('dir_path', '')), 160)})")
        elif b["as"] == "constant":
            w.feeds.append(Feed(key, local, f"{float(b['value'])!r}"))
        else:
            w.feeds.append(Feed(key, local, b["code"]))
    if small:  # the self-check's variant: small networks and state
        for net in w.networks:
            net.width, net.layers = min(net.width, 8), min(net.layers, 2)
        w.states = [(StateSpec(st.key, st.attr, min(st.rows, 16), st.width), o) for st, o in w.states]
    for key, _ident in lowered.outputs:
        w.outputs.append((key, names.get("o", key), sized.widths.get(key)))
    w.states = [(st, next(o for k, o, _ in w.outputs if k == st.key)) for st, _ in w.states]
    production = work.adapter.production
    if production == "Backbone":
        widths_now = [sized.widths.get(k) or 1 for k in att.outputs]
        runtime = sized.runtime
        other = _sizes(work, att, bindings, runtime + 1, small=small)
        widths_next = [other.widths.get(k) or 1 for k in att.outputs]
        per_in = sum(widths_next) - sum(widths_now)
        fixed = sum(widths_now) - per_in * runtime
        w.out_dim = f"{fixed} + {per_in} * self.in_dim" if per_in else f"{fixed}"
    if len(w.networks) > 1 and not small:
        w.notes.append(f"one network per symbol ({', '.join(n.key for n in w.networks)}), each of the paper's depth "
                       "and width: a trunk the paper's architecture may share between them is not read from its text")
    if production == "Backbone" and len(att.outputs) > 1:
        w.notes.append(f"the Backbone interface has one output: the part's outputs ({', '.join(att.outputs)}) are "
                       "concatenated into it; the field's density head reads all of it, and its colour head reads it "
                       "with the encoded direction")
    if production == "Renderer":
        out_key = att.outputs[0] if att.outputs else ""
        if "S" in (lowered.layouts.get(out_key) or ()):
            w.composite_output = True
            w.notes.append(f"the part's output '{safe_comment(out_key, 30)}' is per sample where the Renderer's "
                           "contract is per ray: it is composited with the renderer's volume-rendering weights "
                           "(sum_i w_i x_i)")
        if any(b.get("role") == "ray_colour" and b["as"] == "input" for b in bindings.values()):
            w.notes.append("the ray's colour the part reads is the base's rendering (its weights, blended with the "
                           "background as Nerfstudio's RGBRenderer does)")
        else:
            w.notes.append("the base's background blending is not applied: the paper's rendering equation has no "
                           "background term (its own terms explain the whole ray)")
    if production == "RGBHead":
        w.params = {"dir_dim": int(work.context.get("dir_dim") or 0)}
    counts = {int(b["count"]) for b in bindings.values() if b.get("count")}
    if production == "Regularizers" and counts:
        if len(counts) > 1:
            raise CompileError(f"the part reads the shares of blends of {sorted(counts)} fields (one blend per field)")
        w.params = {"num_fields": counts.pop()}
    if production == "RGBLoss":
        (key,) = att.outputs
        w.loss_mean = True
        w.notes.append("the loss is reduced to a scalar by its mean over the batch (rays and channels), as "
                       "Nerfstudio's losses are")
    return w
