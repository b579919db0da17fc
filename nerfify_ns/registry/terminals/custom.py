"""The ``custom`` alternative: a component of the plugin that implements a production's interface.

A paper's novel part lives here: ``custom: {module, class, params, implements, source, evidence}``
names a class inside the generated plugin (``<package>.<module>``). The composer builds it where the
production's terminal would be; the ladder builds it the same way and checks it against the
production's contract (``INTERFACES``), like any terminal.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Literal

from nerfify_ns.registry.contract import Contract, T
from nerfify_ns.registry.examples import (
    COMPOSITE_CASES,
    DENSITY_CASES,
    DIRECTION_CASES,
    POINT_CASES,
    RAY_CASES,
    VALUE_CASES,
)
from nerfify_ns.registry.params import param
from nerfify_ns.registry.terminal import Call, TerminalDef

CUSTOM = "custom"
CUSTOM_MEMBER = re.compile(r"^custom(_[a-z0-9_]+)?$")
"""Keys that hold custom components: a production's ``custom`` alternative, a set's ``custom_memory``, ..."""


@dataclass
class Custom:
    module: str = param("components.custom")
    """Dotted module inside the plugin package that defines the class (e.g. ``components.sh_head``)."""
    class_: str = param("Component")
    """The class implementing the production's interface."""
    params: dict[str, Any] = param({})
    """Constructor arguments of the class (beyond those the interface passes)."""
    implements: list[str] = param([])
    """The paper's equations the component implements (e.g. ``Eq. 7``)."""
    source: Literal["compiler", "model", "hand"] = param("hand")
    """Who wrote the component: the equation compiler, a language model, or a person."""
    evidence: str = param("")
    """Where in the paper the part is described (quote, section, page)."""
    input_domain: Literal["raw", "unit", "signed_unit"] = param("signed_unit")
    """Position encodings only: the domain the component expects its positions in."""
    weight: float = param(1.0, range=(0.0, 100.0))
    """Regularisers only: weight of the term in the total loss."""
    wrapper: Literal["condition", "blend"] = param("condition")
    """Field wrappers only: a conditioner of the field's inputs, or a blend of several copies of the field (its
    ``params.num_fields``, default 2)."""


@dataclass(frozen=True)
class Interface:
    """What a component of one production takes and returns: constructor arguments the composer passes
    (beyond ``params``), the contract, how the ladder calls it, and the stiff cases that apply."""

    production: str
    doc: str
    ctor: tuple[str, ...]
    contract: Contract
    call: Call
    cases: tuple[str, ...] = ()
    out_dim: bool = False
    """The component reports its output width through ``get_out_dim()``."""
    duties: tuple[dict[str, Any], ...] = ()
    """Duties of a custom component in this production (as a terminal's)."""

    def contract_for(self, params: dict[str, Any]) -> Contract:
        """The contract, with the position range of the component's input domain where it has one (a field
        wrapper's: a conditioner's or, ``wrapper: blend``, a blend's of ``params.num_fields`` fields)."""
        if self.production == "FieldWrapper" and params.get("wrapper") == "blend":
            return blend_contract(int((params.get("params") or {}).get("num_fields", 2)))
        if self.production != "PosEncoding":
            return self.contract
        rng = DOMAIN_RANGES[params.get("input_domain", "signed_unit")]
        positions = T("[N, 3]", range=rng, grad=True, role="positions", doc="sample positions")
        return Contract({"positions": positions}, self.contract.outputs)

    def to_data(self) -> dict:
        data = {"doc": self.doc, "ctor": list(self.ctor), "contract": self.contract.to_data(),
                "cases": list(self.cases)}
        if self.duties:
            data["duties"] = [dict(d) for d in self.duties]
        return data


DOMAIN_RANGES = {"raw": (None, None), "unit": (0.0, 1.0), "signed_unit": (-1.0, 1.0)}


def _one(inp: str, out: str) -> Call:
    def call(module, inputs, env):
        x = inputs[inp]
        return {out: module.to(x.dtype)(x) if hasattr(module, "to") else module(x)}

    return call


def _density_head(module, inputs, env):
    density, geo = module(inputs["hidden"])
    return {"density": density, "geo_features": geo}


def _renderer(module, inputs, env):
    ray_samples, densities = inputs["ray_samples"]
    inputs["densities"] = densities
    if hasattr(module, "bind_samples"):  # a renderer that reads the samples (the equation compiler's)
        module.bind_samples(ray_samples, densities)
    return {"rgb": module(rgb=inputs["rgb"], weights=ray_samples.get_weights(densities))}


def _loss(module, inputs, env):
    return {"loss": module(inputs["pred"], inputs["target"])}


def _regularizer(module, inputs, env):
    return {"loss": module(densities=inputs["densities"], deltas=inputs["deltas"], weights=inputs["weights"])}


def _sampler(module, inputs, env):
    import torch
    from nerfstudio.model_components.ray_samplers import UniformSampler

    bundle = inputs["ray_bundle"]
    coarse = UniformSampler(num_samples=int(env["S"]))(bundle)
    weights = torch.rand(bundle.origins.shape[0], int(env["S"]), 1).requires_grad_(True)
    samples = module(bundle, coarse, weights)
    return {"ray_samples": torch.cat([samples.frustums.starts, samples.frustums.ends], -1)}


def _field(module, inputs, env):
    import torch
    from nerfstudio.field_components.field_heads import FieldHeadNames
    from nerfstudio.model_components.ray_samplers import UniformSampler

    samples = UniformSampler(num_samples=int(env["S"]))(inputs["ray_bundle"])
    samples.camera_indices = torch.zeros(*samples.shape, 1, dtype=torch.long)
    out = module(samples)
    return {"density": out[FieldHeadNames.DENSITY], "rgb": out[FieldHeadNames.RGB]}


def _field_wrapper(module, inputs, env):
    from nerfify_ns.registry.terminals.wrappers import _blend_call, _conditioner_call

    if env.get("wrapper") == "blend":
        return _blend_call(module, inputs, env)
    return _conditioner_call("positions", "times", "features")(module, inputs, env)


def blend_contract(num_fields: int) -> Contract:
    """The contract of a blend of ``num_fields`` fields (the field_blend terminal's, at that count)."""
    from nerfify_ns.registry.terminals.wrappers import blend_contract as terminal_contract

    return terminal_contract(str(num_fields))


def _pixel_map(module, inputs, env):
    from nerfify_ns.registry.terminals.training import map_call

    return map_call(module, inputs, env)


def _hook(module, inputs, env):
    from nerfify_ns.registry.terminals.training import hook_call

    return hook_call(module, inputs, env)


FEATURES = {"features": T("[N, out_dim]", doc="encoded features (width: the component's get_out_dim())")}
LOSS = {"loss": T("[]", range=(0.0, None), doc="a non-negative scalar")}
RAYS = {"ray_bundle": T("[R]", "rays", role="rays")}

SAMPLED = {"requires_terminal": {"slot": "model.sampler", "any_of": ["hierarchical", "proposal", "occupancy_grid",
                                                                    "custom"]}}
"""Duty of a component that reads the field's samples along rays or draws the training rays: a model with a ray
sampler (a model of Gaussians rasterises whole images)."""

INTERFACES: dict[str, Interface] = {i.production: i for i in [
    Interface("PosEncoding", "forward(positions [N, 3]) -> [N, get_out_dim()]", (),
              Contract({"positions": T("[N, 3]", range=(-1.0, 1.0), grad=True, role="positions")}, FEATURES),
              _one("positions", "features"), POINT_CASES, out_dim=True),
    Interface("DirEncoding", "forward(directions [N, 3]) -> [N, get_out_dim()]", (),
              Contract({"directions": T("[N, 3]", grad=True, role="directions")}, FEATURES),
              _one("directions", "features"), DIRECTION_CASES, out_dim=True),
    Interface("Backbone", "__init__(in_dim, out_dim=None, ...); forward(features [N, in_dim]) -> [N, get_out_dim()]",
              ("in_dim", "out_dim"),
              Contract({"features": T("[N, in_dim]", grad=True)}, {"hidden": T("[N, out_dim]")}),
              _one("features", "hidden"), ("values_1e8", "empty_batch"), out_dim=True),
    Interface("DensityHead", "__init__(in_dim, ...); forward(hidden [N, in_dim]) -> (density [N, 1] >= 0, "
              "geometry features [N, get_out_dim()])", ("in_dim",),
              Contract({"hidden": T("[N, in_dim]", grad=True, role="pre_density")},
                       {"density": T("[N, 1]", range=(0.0, None)), "geo_features": T("[N, out_dim]")}),
              _density_head, DENSITY_CASES, out_dim=True),
    Interface("RGBHead", "__init__(in_dim, ...); forward(features [N, in_dim]) -> rgb [N, 3] in [0, 1]", ("in_dim",),
              Contract({"features": T("[N, in_dim]", grad=True)}, {"rgb": T("[N, 3]", range=(0.0, 1.0))}),
              _one("features", "rgb"), ("values_1e8", "empty_batch")),
    Interface("SpatialDistortion", "forward(positions [N, 3]) -> positions [N, 3] with norm < 2", (),
              Contract({"positions": T("[N, 3]", grad=True, role="positions")},
                       {"positions": T("[N, 3]", range=(-2.0, 2.0))}),
              _one("positions", "positions"), POINT_CASES),
    Interface("TensorDecomposition", "__init__(resolution, num_components, ...); forward(positions [N, 3] in [-1, 1]) "
              "-> [N, get_out_dim()]; upsample_grid(resolution)", ("resolution", "num_components"),
              Contract({"positions": T("[N, 3]", range=(-1.0, 1.0), grad=True, role="positions")}, FEATURES),
              _one("positions", "features"), POINT_CASES, out_dim=True),
    Interface("Sampler", "__init__(num_samples, ...); forward(ray_bundle, coarse ray_samples, weights [R, S, 1]) -> "
              "RaySamples [R, K] (the base's importance sampler)", ("num_samples",),
              Contract(RAYS, {"ray_samples": T("[R, K, 2]")}, free=("K",)), _sampler, RAY_CASES,
              duties=({"requires_base": ["vanilla-nerf", "mipnerf", "tensorf"]},)),
    Interface("Renderer", "a subclass of nerfstudio's RGBRenderer (background blending): __init__(background_color, "
              "...); forward(rgb=[R, S, 3], weights=[R, S, 1]) -> rgb [R, 3]; optionally bind_samples(ray_samples, "
              "densities [R, S, 1]), called with the field's samples before forward",
              ("background_color",),
              Contract({"ray_samples": T("[R, S]", "samples", role="samples"),
                        "rgb": T("[R, S, 3]", range=(0.0, 1.0), grad=True)},
                       {"rgb": T("[R, 3]", range=(0.0, 1.0))}), _renderer, COMPOSITE_CASES),
    Interface("RGBLoss", "forward(pred [R, 3], target [R, 3]) -> scalar >= 0", (),
              Contract({"pred": T("[R, 3]", range=(0.0, 1.0), grad=True), "target": T("[R, 3]", range=(0.0, 1.0))},
                       LOSS), _loss, VALUE_CASES),
    Interface("Regularizers", "forward(densities=[R, S, 1], sigma at the field's samples, deltas=[R, S, 1], the "
              "steps between them, weights=[R, S, K] or None, each field's share of every sample where the field "
              "blends K fields (None otherwise)) -> scalar >= 0, added to the loss times `weight`", (),
              Contract({"densities": T("[R, S, 1]", range=(0.0, 5.0), grad=True, role="densities"),
                        "deltas": T("[R, S, 1]", range=(0.01, 0.2), role="steps", doc="step between samples"),
                        "weights": T("[R, S, num_fields]", range=(0.0, 1.0),
                                     doc="each blended field's share of a sample")},
                       LOSS, sizes={"num_fields": 3}),
              _regularizer, VALUE_CASES, duties=(SAMPLED,)),
    Interface("Field", "a nerfstudio Field: __init__(aabb, num_images, ...); forward(ray_samples [R, S]) -> "
              "{DENSITY: [R, S, 1] >= 0, RGB: [R, S, 3] in [0, 1]}", ("aabb", "num_images"),
              Contract(RAYS, {"density": T("[R, S, 1]", range=(0.0, None)),
                              "rgb": T("[R, S, 3]", range=(0.0, 1.0))}), _field, RAY_CASES),
    Interface("FieldWrapper", "a conditioner of the neural field: __init__(num_images, ...); forward(positions "
              "[N, 3] (world), times [N, 1], camera_indices [N] long) -> (positions [N, 3], times [N, 1], features "
              "[N, get_out_dim()]): the position and time the field is queried at (return the inputs to keep "
              "them) and features appended to the backbone's input (width 0 for none); applied in the plan's "
              "order, before the field's own encoding. With `wrapper: blend`, a blend of K = params.num_fields "
              "(default 2) copies of the field: __init__(num_images, ...); forward(densities [N, K, 1], rgbs "
              "[N, K, 3], positions [N, 3], times [N, 1]) -> (density [N, 1] >= 0, rgb [N, 3] in [0, 1])",
              ("num_images",),
              Contract({"positions": T("[N, 3]", grad=True, role="positions", doc="sample positions (world)"),
                        "times": T("[N, 1]", range=(0.0, 1.0), grad=True, doc="sample times"),
                        "camera_indices": T("[N]", "long", role="camera_indices", doc="training image index")},
                       {"positions": T("[N, 3]", doc="the position the field is queried at"),
                        "times": T("[N, 1]", doc="the time the field is queried at"),
                        "features": T("[N, out_dim]", doc="features appended to the backbone's input")},
                       doc="reads positions, times, camera indices; writes positions, times, backbone features"),
              _field_wrapper, ("empty_batch", "points_outside_contraction", "half"), out_dim=True,
              duties=({"requires_terminal": {"slot": "model.field", "any_of": ["MLPField"]}},)),
    Interface("PixelSampler", "a per-image pixel map: forward(images [N, H, W, 3] in [0, 1], image_indices [N] long) "
              "-> weights [N, H, W] >= 0; the plugin's MapPixelSampler draws each batch's pixels in proportion "
              "(an image whose weights are all 0 is never drawn); computed once per image batch", (),
              Contract({"images": T("[N, H, W, 3]", range=(0.0, 1.0), doc="the batch's training images"),
                        "image_indices": T("[N]", "long", role="camera_indices", doc="their training-set indices")},
                       {"weights": T("[N, H, W]", range=(0.0, None), doc="unnormalised pixel probabilities")},
                       sizes={"H": 6, "W": 5}, doc="reads the batch's images and indices; writes the pixel map"),
              _pixel_map, ("zeros", "empty_batch"), duties=(SAMPLED,)),
    Interface("ScheduleHook", "a subclass of components.schedule_hooks.ScheduleHook (the plugin has it): "
              "forward(steps [N] long) -> values [N] (the value written at each step); write(value, model, "
              "datamanager) applies one value; check(model) raises when the model lacks what it changes; "
              "`every` (default 1) iterations between calls, before the training iteration", (),
              Contract({"steps": T("[N]", "long", role="steps", doc="training steps")},
                       {"values": T("[N]", doc="the value at each step")},
                       doc="reads the step; writes what its write() names (a part of the model or the datamanager)"),
              _hook, ("empty_batch",)),
]}
"""The interface of every production that accepts ``custom``."""

TERMINALS = [
    TerminalDef("custom", "*", Custom,
                "A component of the plugin implementing the production's interface (a paper's novel part).",
                "<the plugin's own module>"),
]
