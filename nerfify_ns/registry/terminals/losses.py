"""Photometric losses, sampler losses and regularisers."""

from __future__ import annotations

from dataclasses import dataclass

from nerfify_ns.registry.contract import Contract, T
from nerfify_ns.registry.examples import SAMPLER_LOSS_CASES, VALUE_CASES, composite_samples
from nerfify_ns.registry.params import param
from nerfify_ns.registry.terminal import Code, Constraint, Harness, TerminalDef, samples_rays

LOSS = {"loss": T("[]", range=(0.0, None), doc="a non-negative scalar")}
PHOTOMETRIC_IN = {"pred": T("[R, 3]", range=(0.0, 1.0), grad=True, doc="rendered colours"),
                  "target": T("[R, 3]", range=(0.0, 1.0), doc="observed colours")}


@dataclass
class Charbonnier:
    eps: float = param(0.001, range=(1.0e-8, 1.0))
    """The smoothing epsilon of sqrt((x - y)^2 + eps^2)."""


@dataclass
class Weighted:
    weight: float = param(1.0, range=(0.0, 100.0))
    """Weight of the term in the total loss."""


@dataclass
class Distortion(Weighted):
    weight: float = param(0.002, range=(0.0, 100.0))
    """Weight lambda of the distortion loss (Nerfacto: 0.002)."""


@dataclass
class PlaneTV:
    weight: float = param(0.0002, range=(0.0, 10.0))
    """Weight of the total variation term."""


@dataclass
class TimeSmoothness:
    weight: float = param(0.001, range=(0.0, 10.0))
    """Weight of the time-smoothness term."""


@dataclass
class PlaneL1:
    weight: float = param(0.0001, range=(0.0, 10.0))
    """Weight of the L1 term pulling space-time planes towards 1."""


@dataclass
class RayEntropy:
    weight: float = param(0.001, range=(0.0, 10.0))
    """Weight of the entropy term."""
    threshold: float = param(0.1, range=(0.0, 1.0))
    """Rays whose opacity is below this are left out (InfoNeRF)."""


@dataclass
class DensitySparsity:
    weight: float = param(0.0001, range=(0.0, 10.0))
    """Weight of the sparsity term."""
    scale: float = param(0.5, range=(1.0e-6, 1.0e6))
    """Scale c of log(1 + sigma^2 / c)."""


@dataclass
class TensorL1:
    weight: float = param(0.0005, range=(0.0, 10.0))
    """Weight of the L1 norm of the density factors."""


@dataclass
class TensorTV:
    density_weight: float = param(0.001, range=(0.0, 10.0))
    """Weight of the total variation of the density planes."""
    color_weight: float = param(0.0001, range=(0.0, 10.0))
    """Weight of the total variation of the colour planes."""


def _photometric(name: str):
    def call(module, inputs, env):
        import torch
        from torch import nn

        pred, target = inputs["pred"], inputs["target"]
        if name == "charbonnier":
            from nerfify_ns.components.photometric_losses import charbonnier_loss

            return {"loss": charbonnier_loss(pred, target, eps=env["eps"])}
        if name == "l1":
            return {"loss": nn.L1Loss()(pred, target)}
        from nerfstudio.model_components.losses import MSELoss

        del torch
        return {"loss": MSELoss()(pred, target)}

    return call


def _sampler_loss(name: str):
    def call(module, inputs, env):
        from nerfstudio.model_components import losses

        case = env.get("case", "nominal")
        fine, fine_density = composite_samples(case, 8)
        coarse, coarse_density = composite_samples(case, 4)
        inputs["densities"] = [fine_density, coarse_density]
        w_fine, w_coarse = fine.get_weights(fine_density), coarse.get_weights(coarse_density)
        if name == "interlevel":
            return {"loss": env["weight"] * losses.interlevel_loss([w_coarse, w_fine], [coarse, fine])}
        return {"loss": env["weight"] * losses.distortion_loss([w_fine], [fine]).mean()}

    return call


def _regularizer(function: str, *names: str):
    def call(module, inputs, env):
        from nerfify_ns.components import regularizers

        extra = {k: env[k] for k in names}
        return {"loss": env["weight"] * getattr(regularizers, function)(*inputs.values(), **extra)}

    return call


def _none(p, env):
    return None


PLANES = {"planes": T("[2]", "list", role="planes", grad=True, doc="feature planes, each [1, C, H, W]")}
SAMPLER_LOSS_IN = {"ray_samples": T("[R, S]", "samples", role="samples", doc="samples of two levels")}
PLANE_ENCODINGS = {"spatial": ("kplanes", "kplanes_time"), "time": ("kplanes_time",)}
"""The field encodings whose ``position_encoding`` has the planes the regularisers read (``spatial_planes``;
``time_planes``): a triplane encoding has one coefficient tensor and no such planes."""
PLANES_WRAPPER = ("gaussian_deformation", "encoding", "planes")
"""A field wrapper whose ``position_encoding`` is a K-Planes module over (x, y, z, t) when its parameter says so
(4D-GS's structure encoder in a deformation of Gaussians)."""


def plane_owner(plan: dict, kind: str = "spatial") -> str | None:
    """The plan path of the part whose ``position_encoding`` holds the feature planes a plane regulariser of
    ``kind`` ("spatial" or "time") reads: the field's k-planes encoding, or a deformation of Gaussians over planes;
    None when the plan has no such planes."""
    model = plan.get("model") if isinstance(plan.get("model"), dict) else {}
    field = model.get("field") if isinstance(model.get("field"), dict) else {}
    mlp = field.get("MLPField") if isinstance(field.get("MLPField"), dict) else {}
    encoding = mlp.get("pos_encoding") if isinstance(mlp.get("pos_encoding"), dict) else {}
    for name in PLANE_ENCODINGS[kind]:
        if name in encoding:
            return f"model.field.MLPField.pos_encoding.{name}"
    wrappers = model.get("field_wrappers") if isinstance(model.get("field_wrappers"), dict) else {}
    name, param_name, value = PLANES_WRAPPER
    given = wrappers.get(name)
    if isinstance(given, dict) and given.get(param_name) == value:
        return f"model.field_wrappers.{name}"
    return None


PLANES_IN_FIELD = {"requires_terminal": {"slot": "model.field.MLPField.pos_encoding",
                                        "any_of": list(PLANE_ENCODINGS["spatial"]) + [None]}}
"""The part of the plane rules the exports check too: a neural field's encoding has the planes (absent: a model
without such a field, where :data:`READS_PLANES` decides)."""
TIME_PLANES_IN_FIELD = {"requires_terminal": {"slot": "model.field.MLPField.pos_encoding",
                                             "any_of": list(PLANE_ENCODINGS["time"]) + [None]}}
READS_PLANES = Constraint(
    "it reads feature planes: the field's k-planes encoding (kplanes, kplanes_time) or a deformation of Gaussians "
    "over planes (gaussian_deformation with encoding planes)", lambda p, plan: plane_owner(plan) is not None)
READS_TIME_PLANES = Constraint(
    "it reads space-time planes: the field's kplanes_time encoding or a deformation of Gaussians over planes "
    "(gaussian_deformation with encoding planes)", lambda p, plan: plane_owner(plan, "time") is not None)


def regularizer(name, params, doc, implementation, card, function, expr, inputs, *, extra=(), duties=(),
                traits=None, constraints=()) -> TerminalDef:
    """A regulariser of ``nerfify_ns.components.regularizers``, added to the base model's loss dictionary."""
    return TerminalDef(
        name, "Regularizers", params, doc, implementation, card=card, contract=Contract(inputs, LOSS),
        code=Code((f"from .components.regularizers import {function}",), expr=expr, component="regularizers",
                  traits=traits or {}),
        harness=Harness(build=_none, call=_regularizer(function, *extra), cases=VALUE_CASES), duties=duties,
        constraints=tuple(constraints))


SAMPLED_DENSITIES = Constraint(
    "it reads the densities of the field's samples along rays: a model with a ray sampler (a model of Gaussians "
    "has none)", lambda p, plan: samples_rays(plan))

TERMINALS = [
    TerminalDef("l2", "RGBLoss", None, "Mean squared error between rendered and observed colour (NeRF Eq. 6).",
                "nerfstudio.model_components.losses.MSELoss", card="rgb_l2",
                contract=Contract(PHOTOMETRIC_IN, LOSS),
                harness=Harness(build=_none, call=_photometric("l2"), cases=VALUE_CASES)),
    TerminalDef("l1", "RGBLoss", None, "Mean absolute error between rendered and observed colour.",
                "torch.nn.L1Loss", card="rgb_l1", contract=Contract(PHOTOMETRIC_IN, LOSS),
                code=Code(("from torch import nn",), ctor="nn.L1Loss()"),
                harness=Harness(build=_none, call=_photometric("l1"), cases=VALUE_CASES)),
    TerminalDef("charbonnier", "RGBLoss", Charbonnier,
                "Charbonnier loss sqrt((x - y)^2 + eps^2) (Mip-NeRF 360 Sec. 5).",
                "nerfify_ns.components.photometric_losses.charbonnier_loss", card="charbonnier",
                contract=Contract(PHOTOMETRIC_IN, LOSS),
                code=Code(("from .components.photometric_losses import CharbonnierLoss",),
                          ctor="CharbonnierLoss(eps={{ p.eps }})", component="photometric_losses"),
                harness=Harness(build=_none, call=_photometric("charbonnier"), cases=VALUE_CASES)),
    TerminalDef("interlevel", "Losses", Weighted,
                "Proposal supervision: proposal weights must bound the NeRF weights (Mip-NeRF 360 Eq. 13).",
                "nerfstudio.model_components.losses.interlevel_loss", card="interlevel_loss",
                contract=Contract(SAMPLER_LOSS_IN, LOSS),
                harness=Harness(build=_none, call=_sampler_loss("interlevel"), cases=SAMPLER_LOSS_CASES),
                config={"nerfacto": {"weight": "interlevel_loss_mult"}},
                duties=({"requires_terminal": {"slot": "model.sampler", "any_of": ["proposal"]}},)),
    TerminalDef("distortion", "Losses", Distortion,
                "Distortion loss pulling each ray's weights to a compact interval (Mip-NeRF 360 Eq. 15).",
                "nerfstudio.model_components.losses.distortion_loss", card="distortion_loss",
                contract=Contract(SAMPLER_LOSS_IN, LOSS),
                harness=Harness(build=_none, call=_sampler_loss("distortion"), cases=SAMPLER_LOSS_CASES),
                config={"nerfacto": {"weight": "distortion_loss_mult"}},
                duties=({"requires_terminal": {"slot": "model.sampler", "any_of": ["proposal"]}},)),
    regularizer("plane_tv", PlaneTV, "Total variation of every spatial plane (K-Planes Eq. 4).",
                "nerfify_ns.components.regularizers.plane_tv", "plane_tv", "plane_tv",
                "plane_tv({{ field }}.position_encoding.spatial_planes)", PLANES, duties=(PLANES_IN_FIELD,),
                constraints=(READS_PLANES,)),
    regularizer("time_smoothness", TimeSmoothness,
                "Smoothness of the time axis of space-time planes, a 1D Laplacian (K-Planes Eq. 5).",
                "nerfify_ns.components.regularizers.time_smoothness", "time_smoothness", "time_smoothness",
                "time_smoothness({{ field }}.position_encoding.time_planes)", PLANES, duties=(TIME_PLANES_IN_FIELD,),
                constraints=(READS_TIME_PLANES,)),
    regularizer("plane_l1", PlaneL1,
                "L1 sparsity of the space-time planes towards 1 (static by default; K-Planes Eq. 6).",
                "nerfify_ns.components.regularizers.plane_l1_to_one", "time_smoothness", "plane_l1_to_one",
                "plane_l1_to_one({{ field }}.position_encoding.time_planes)", PLANES, duties=(TIME_PLANES_IN_FIELD,),
                constraints=(READS_TIME_PLANES,)),
    regularizer("ray_entropy", RayEntropy,
                "Entropy of each ray's normalised weights, minimised for sparse rays (InfoNeRF Eq. 7).",
                "nerfify_ns.components.regularizers.ray_entropy", "ray_entropy", "ray_entropy",
                "ray_entropy(outputs[\"weights_list\"][-1], threshold={{ p.threshold }})",
                {"weights": T("[R, S, 1]", range=(0.0, 1.0), grad=True, role="weights", doc="weights of each ray")},
                extra=("threshold",), traits={"requires_output": "weights_list"},
                duties=({"requires_base": ["nerfacto"]},)),
    regularizer("density_sparsity", DensitySparsity,
                "Cauchy sparsity of densities at the samples, log(1 + sigma^2 / c) (SNeRG / Plenoxels).",
                "nerfify_ns.components.regularizers.density_sparsity", "density_sparsity", "density_sparsity",
                "density_sparsity({{ field }}.last_density, scale={{ p.scale }})",
                {"densities": T("[R, S, 1]", range=(0.0, 5.0), grad=True, role="densities",
                                doc="sigma of each sample")},
                extra=("scale",), traits={"keeps_density": True}, constraints=(SAMPLED_DENSITIES,)),
    TerminalDef("tensor_l1", "Regularizers", TensorL1,
                "L1 norm of the density factors (TensoRF Sec. 4, sparsity).",
                "nerfstudio.models.tensorf.TensoRFModel", card="tensorf_vm", harness=Harness(in_model=True),
                duties=({"requires_base": ["tensorf"]},)),
    TerminalDef("tensor_tv", "Regularizers", TensorTV,
                "Total variation of the VM plane factors (TensoRF, real scenes).",
                "nerfstudio.models.tensorf.TensoRFModel", card="tensorf_vm", harness=Harness(in_model=True),
                duties=({"requires_base": ["tensorf"]},
                        {"requires_terminal": {"slot": "model.field.TensorialField.decomposition",
                                               "any_of": ["tensor_vm"]}})),
]
