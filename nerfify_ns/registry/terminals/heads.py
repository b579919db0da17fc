"""The backbone MLP, density heads and colour heads of a field."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from nerfify_ns.registry.contract import Contract, T
from nerfify_ns.registry.examples import DENSITY_CASES, DENSITY_OFFSETS
from nerfify_ns.registry.params import param
from nerfify_ns.registry.terminal import Code, Constraint, Harness, TerminalDef

SMALL = {"layer_width": 32, "num_layers": 3, "density_width": 16, "color_width": 16, "density_layers": 2,
         "color_layers": 2}

ACTIVATIONS: dict[str, Code] = {
    "softplus": Code(expr="nn.functional.softplus({{ x }})"),
    "relu": Code(expr="nn.functional.relu({{ x }})"),
    # Nerfstudio's trunc_exp is a plain exp forward: its argument is clamped so densities stay finite
    "trunc_exp": Code(("from nerfstudio.field_components.activations import trunc_exp",),
                      expr="trunc_exp(({{ x }}).clamp(max=20.0))"),
}
"""Density activations: the expression a density head renders, and the harness evaluates, for each."""


def activation(name: str):
    """The activation ``name`` as a function, evaluated from the expression it renders into plugins."""
    from nerfify_ns.registry.snippets import compile_expression

    return compile_expression(ACTIVATIONS[name], "x")


@dataclass
class Backbone:
    num_layers: int = param(8, range=(1, 16))
    """Hidden layers of the MLP (NeRF: 8)."""
    layer_width: int = param(256, range=(8, 1024))
    """Units per hidden layer (NeRF: 256)."""
    skip_connections: list[int] = param([4], range=(1, 14), length=(0, 8))
    """Layers that receive the encoded input again (NeRF: a skip at layer 4)."""
    skip_every_layer: bool = param(False)
    """The encoded input is fed again to every hidden layer after the first (replaces skip_connections)."""
    branches: bool = param(False)
    """Separate density and colour branches after the shared layers: the density head reads one, the colour head
    the other (each with its own depth and width below)."""
    density_layers: int = param(1, range=(1, 8))
    """Layers of the density branch (with branches)."""
    density_width: int = param(128, range=(8, 1024))
    """Units per layer of the density branch (with branches)."""
    color_layers: int = param(1, range=(1, 8))
    """Layers of the colour branch, whose output are the geometry features of the colour head (with branches)."""
    color_width: int = param(128, range=(8, 1024))
    """Units per layer of the colour branch (with branches)."""
    hidden_norm: Literal["none", "layer"] = param("none")
    """Normalisation after each hidden layer's linear map, before its activation: none, or layer (LayerNorm over
    the units with a learned gain and bias, Ba et al. 2016, arXiv 1607.06450)."""


@dataclass
class DensityLinear:
    activation: Literal["softplus", "relu", "trunc_exp"] = param("softplus")
    """Activation turning the raw density into sigma >= 0."""


@dataclass
class DensitySplit:
    geo_feat_dim: int = param(15, range=(1, 256))
    """Geometry features after the density channel (Instant-NGP: 15)."""
    activation: Literal["trunc_exp", "softplus", "relu"] = param("trunc_exp")
    """Activation turning the raw density into sigma >= 0."""
    init_density: float = param(1.0, range=(1.0e-6, 1.0e6))
    """Scale of the activated density at initialisation."""


@dataclass
class RGBMLP:
    num_layers: int = param(3, range=(1, 8))
    """Hidden layers of the colour head."""
    layer_width: int = param(128, range=(8, 1024))
    """Units per hidden layer of the colour head."""


@dataclass
class TensorialAppearance:
    appearance_dim: int = param(27, range=(1, 256))
    """Width of the appearance features after the basis matrix B."""
    num_layers: int = param(2, range=(1, 8))
    """Hidden layers of the appearance MLP."""
    layer_width: int = param(128, range=(8, 1024))
    """Units per hidden layer."""
    feature_frequencies: int = param(2, range=(1, 16))
    """Frequencies of the encoding of the appearance features."""
    direction_frequencies: int = param(2, range=(1, 16))
    """Frequencies of the encoding of the view direction."""


def backbone_skips(p) -> tuple:
    """The layers that receive the encoded input again: every hidden layer after the first
    (``skip_every_layer``), else ``skip_connections`` (those below the last layer, e.g. at small sizes)."""
    layers = range(1, p["num_layers"] - 1) if p.get("skip_every_layer") else (p["skip_connections"] or [])
    return tuple(s for s in layers if s < p["num_layers"] - 1)


def _build_backbone(p, env):
    from nerfstudio.field_components.mlp import MLP
    from torch import nn

    if p["branches"]:
        from nerfify_ns.components.mlp_branches import BranchedMLP

        return BranchedMLP(in_dim=int(env["in_dim"]), num_layers=p["num_layers"], layer_width=p["layer_width"],
                           skip_connections=backbone_skips(p), density_layers=p["density_layers"],
                           density_width=p["density_width"], color_layers=p["color_layers"],
                           color_width=p["color_width"])
    if p.get("hidden_norm", "none") == "layer":
        from nerfify_ns.components.mlp_normed import NormedMLP

        return NormedMLP(in_dim=int(env["in_dim"]), num_layers=p["num_layers"], layer_width=p["layer_width"],
                         skip_connections=backbone_skips(p) or None)
    return MLP(in_dim=int(env["in_dim"]), num_layers=p["num_layers"], layer_width=p["layer_width"],
               skip_connections=backbone_skips(p) or None, activation=nn.ReLU(), implementation="torch")


def _build_colour_head(p, env):
    from nerfstudio.field_components.mlp import MLP
    from torch import nn

    return MLP(in_dim=int(env["in_dim"]), num_layers=p["num_layers"], layer_width=p["layer_width"], out_dim=3,
               activation=nn.ReLU(), out_activation=nn.Sigmoid(), implementation="torch")


def _raw_density(raw, env):
    offset = DENSITY_OFFSETS.get(env.get("case", ""))
    return raw if offset is None else raw * 0 + offset


def _build_density_linear(p, env):
    from torch import nn

    return nn.Linear(int(env["in_dim"]), 1)


def _call_density_linear(module, inputs, env):
    hidden = inputs["hidden"]
    raw = _raw_density(module.to(hidden.dtype)(hidden), env)
    return {"density": activation(env["activation"])(raw), "geo_features": hidden}


def _call_density_split(module, inputs, env):
    import torch

    hidden = inputs["hidden"]
    raw, geo = torch.split(hidden, [1, env["geo_feat_dim"]], dim=-1)
    return {"density": env["init_density"] * activation(env["activation"])(_raw_density(raw, env).to(hidden)),
            "geo_features": geo}


def _call(key: str):
    def call(module, inputs, env):
        x = inputs["features"]
        return {key: module.to(x.dtype)(x)}

    return call


SKIPS_BEFORE_LAST_LAYER = Constraint(
    "skip connections feed hidden layers: every entry of skip_connections is below num_layers - 1 (unless "
    "skip_every_layer, which replaces them)",
    lambda p, plan: p.get("skip_every_layer") or all(s < p["num_layers"] - 1 for s in p["skip_connections"] or []))
"""Nerfstudio's MLP concatenates the input before layer i; its last layer (num_layers - 1) takes no skip."""

BRANCHES_NEED_A_LINEAR_DENSITY_HEAD = Constraint(
    "separate density and colour branches feed the linear density head (density_linear): density_split reads "
    "the density from the backbone's first channel and a custom head reads all of it",
    lambda p, plan: not p["branches"] or "density_linear" in (
        (((plan.get("model") or {}).get("field") or {}).get("MLPField") or {}).get("density_head") or {}))

HIDDEN_NORM_WITHOUT_BRANCHES = Constraint(
    "a normalisation after each hidden layer (hidden_norm) is built for the single backbone MLP: not with "
    "separate density and colour branches",
    lambda p, plan: p.get("hidden_norm", "none") == "none" or not p["branches"])

FEATURES_IN = {"features": T("[N, in_dim]", grad=True, doc="encoded positions (a width the harness chooses)")}
DENSITY_OUT = {"density": T("[N, 1]", range=(0.0, None), doc="sigma >= 0")}
HIDDEN_IN = T("[N, in_dim]", grad=True, role="pre_density", doc="backbone output")

TERMINALS = [
    TerminalDef(
        "mlp", "Backbone", Backbone, "The backbone MLP over encoded positions (NeRF: 8 x 256 with a skip at layer 4).",
        "nerfstudio.field_components.mlp.MLP", card="mlp_backbone",
        contract=Contract(FEATURES_IN, {"hidden": T("[N, (1 - branches) * layer_width + branches * (density_width "
                                                     "+ color_width)]",
                                                     doc="hidden features (with branches: the density branch's, "
                                                         "then the colour branch's)")}),
        harness=Harness(build=_build_backbone, call=_call("hidden"), cases=("values_1e8", "empty_batch", "half"),
                        small=SMALL),
        constraints=(SKIPS_BEFORE_LAST_LAYER, BRANCHES_NEED_A_LINEAR_DENSITY_HEAD, HIDDEN_NORM_WITHOUT_BRANCHES)),
    TerminalDef(
        "density_linear", "DensityHead", DensityLinear,
        "A linear density head on the backbone features, then an activation (NeRF).",
        "torch.nn.Linear", card="density_activation",
        contract=Contract({"hidden": HIDDEN_IN},
                          {**DENSITY_OUT, "geo_features": T("[N, in_dim]", doc="features for the colour head")}),
        harness=Harness(build=_build_density_linear, call=_call_density_linear, cases=DENSITY_CASES)),
    TerminalDef(
        "density_split", "DensityHead", DensitySplit,
        "Density is the first backbone output through an activation; the rest are geometry features (Instant-NGP).",
        "nerfstudio.field_components.activations.trunc_exp", card="density_activation",
        contract=Contract({"hidden": T("[N, 1 + geo_feat_dim]", grad=True, role="pre_density",
                                       doc="density channel and geometry features")},
                          {**DENSITY_OUT, "geo_features": T("[N, geo_feat_dim]", doc="features for the colour head")}),
        harness=Harness(build=lambda p, env: None, call=_call_density_split, cases=DENSITY_CASES)),
    TerminalDef(
        "rgb_mlp", "RGBHead", RGBMLP,
        "Colour head over geometry features, encoded direction and appearance code, sigmoid output.",
        "nerfstudio.field_components.mlp.MLP", card="mlp_backbone",
        contract=Contract(FEATURES_IN, {"rgb": T("[N, 3]", range=(0.0, 1.0), doc="colour")}),
        harness=Harness(build=_build_colour_head, call=_call("rgb"), cases=("values_1e8", "empty_batch", "half"),
                        small=SMALL)),
    TerminalDef(
        "tensorial_appearance", "TensorialField", TensorialAppearance,
        "TensoRF appearance head: basis matrix B, then a small MLP over features and view direction.",
        "torch.nn.Linear", card="tensorf_vm",
        contract=Contract(FEATURES_IN, {"rgb": T("[N, 3]", range=(0.0, 1.0), doc="colour")}, sizes={"in_dim": 15}),
        harness=Harness(build=_build_colour_head, call=_call("rgb"), cases=("values_1e8", "empty_batch", "half"),
                        small=SMALL),
        config={"tensorf": {"appearance_dim": "appearance_dim"}}),
]
