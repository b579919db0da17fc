"""The data and schedule side of training: the datamanager's pixel sampler (which pixels of which training
images a batch draws) and schedule hooks (training callbacks at given steps).

Pixel samplers are per-image probability maps (``components/pixel_samplers.py``): the plugin's
``MapPixelSampler`` draws each batch's pixels in proportion to the map. Schedule hooks
(``components/schedule_hooks.py``) give a value per step (their contract) and write it to one named part: the
model's scalars and parameters (anneal, freeze) or the training pixel sampler's active images (curriculum).
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Literal

from nerfify_ns.registry.contract import Contract, T
from nerfify_ns.registry.params import param
from nerfify_ns.registry.terminal import Code, Constraint, Harness, TerminalDef, samples_rays
from nerfify_ns.registry.terminals.custom import CUSTOM_MEMBER

MAP_SIZES = {"H": 6, "W": 5}
"""Example image size (rows, columns) for the pixel maps' contract (N images)."""
IMAGES = {"images": T("[N, H, W, 3]", range=(0.0, 1.0), doc="the training images of the batch (RGB in [0, 1])"),
          "image_indices": T("[N]", "long", role="camera_indices", doc="their indices in the training set")}
WEIGHTS = {"weights": T("[N, H, W]", range=(0.0, None), doc="unnormalised probability of each pixel")}
MAP_CASES = ("zeros", "empty_batch")
STEPS = {"steps": T("[N]", "long", role="steps", doc="training steps")}
HOOK_CASES = ("empty_batch",)
RAY_BATCHES = Constraint(
    "it draws or restricts the training rays: a model trained on ray batches (a model of Gaussians has no ray "
    "sampler; its data manager loads whole images)",
    lambda p, plan: samples_rays(plan))
"""Rule of a part that draws or restricts the training pixels (a rule, not a duty: the plan's ray sampler is there)."""


@dataclass
class GradientImportance:
    uniform_fraction: float = param(0.5, range=(0.0, 1.0))
    """Share of the probability spread uniformly over the pixels (the rest follows the image gradient)."""


@dataclass
class ViewSelection:
    rule: Literal["every_nth", "first_n"] = param("every_nth")
    """every_nth: views whose index is a multiple of n; first_n: views 0..n-1."""
    n: int = param(8, range=(1, 100000))
    """The n of the rule."""


@dataclass
class Anneal:
    target: str = param("deformation.window")
    """The annealed scalar, ``<part>.<attribute>``: an attribute of every part of the model whose name ends with
    ``<part>`` (``deformation.window``: the coarse-to-fine window of the deformation's encoding of x;
    ``encoding_window.window``: the share from coarse to fine, 0 to 1, of the bands of the field's position
    encoding, its frequencies or grid levels, switched on in turn)."""
    start_value: float = param(0.0, range=(-1.0e6, 1.0e6))
    """Value up to start_step."""
    end_value: float = param(10.0, range=(-1.0e6, 1.0e6))
    """Value from end_step on."""
    start_step: int = param(0, range=(0, 10000000))
    """Step at which annealing starts."""
    end_step: int = param(2000, range=(0, 10000000))
    """Step at which annealing ends."""
    curve: Literal["linear", "cosine"] = param("linear")
    """Interpolation between the two values (cosine: eased at both ends)."""


@dataclass
class Freeze:
    module: str = param("deformation")
    """The part whose parameters stop learning: a name, or the end of a dotted name, of a part of the model."""
    start_step: int = param(0, range=(0, 10000000))
    """First frozen step."""
    end_step: int = param(1000, range=(0, 10000000))
    """First step that learns again."""


@dataclass
class ImageCurriculum:
    rule: Literal["prefix", "keyframes"] = param("prefix")
    """prefix: the first fraction of the training images (in dataset order: a video's frames in time), growing;
    keyframes: every keyframe_stride-th image until end_step, then all (DyNeRF's hierarchical training)."""
    start_fraction: float = param(0.25, range=(0.0, 1.0))
    """Fraction of the images at step 0 (prefix)."""
    keyframe_stride: int = param(4, range=(1, 100000))
    """Every k-th image is a key frame (keyframes)."""
    end_step: int = param(2000, range=(0, 10000000))
    """Step from which every image is used."""


# ----------------------------------------------------------------------------- what hooks may write
_PART = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


def _terminals_in(plan: Any) -> Iterator[str]:
    """Every mapping key of the plan (terminal names among them)."""
    if isinstance(plan, Mapping):
        for key, value in plan.items():
            yield str(key)
            yield from _terminals_in(value)


def schedulable_parts(plan: Mapping[str, Any]) -> set[str]:
    """The parts a schedule hook of ``plan`` may change: what the plan's terminals declare (``schedulable``)."""
    from nerfify_ns.registry.core import default_registry

    registry = default_registry()
    names: set[str] = set()
    for key in _terminals_in(plan.get("model") if isinstance(plan, Mapping) else None):
        if key in registry.terminals:
            names.update(registry[key].code.traits.get("schedulable", ()))
    return names


def _writes_a_part_of_the_plan(key: str, attribute: bool) -> Constraint:
    def holds(p: Mapping[str, Any], plan: Mapping[str, Any]) -> bool:
        name = str(p.get(key, ""))
        if not _PART.match(name) or (attribute and "." not in name):
            return False
        if any(CUSTOM_MEMBER.match(k) for k in _terminals_in(plan.get("model"))):
            return True  # a component of the plugin may expose any part: checked when the model is built
        return name in schedulable_parts(plan)

    what = "<part>.<attribute>" if attribute else "a part"
    return Constraint(f"{key} names {what} the plan's terminals expose to schedule hooks (their `schedulable` "
                      "trait, e.g. deformation, deformation.window), or the plan has a custom component", holds)


def _build(cls: str, *names: str):
    def build(p, env):
        from nerfify_ns.components import pixel_samplers, schedule_hooks

        module = pixel_samplers if hasattr(pixel_samplers, cls) else schedule_hooks
        return getattr(module, cls)(**{n: p[n] for n in names})

    return build


def map_call(module, inputs, env):
    return {"weights": module(inputs["images"], inputs["image_indices"])}


def hook_call(module, inputs, env):
    """The hook's schedule over N steps from 0 to 20,000."""
    import torch

    count = int(env["N"])
    steps = torch.linspace(0, 20000, count).long() if count else torch.zeros(0, dtype=torch.long)
    return {"values": module(steps)}


MAP_IMPORT = "from .components.pixel_samplers import {}"
HOOK_IMPORT = "from .components.schedule_hooks import {}"

TERMINALS = [
    TerminalDef(
        "gradient_importance", "PixelSampler", GradientImportance,
        "Training pixels drawn by importance: probability from the image gradient plus a uniform share (ray "
        "importance sampling, as DyNeRF's).",
        "nerfify_ns.components.pixel_samplers.GradientImportance",
        contract=Contract(IMAGES, WEIGHTS, sizes=MAP_SIZES, doc="reads the batch's images; writes the pixel map"),
        code=Code((MAP_IMPORT.format("GradientImportance"),),
                  ctor="GradientImportance(uniform_fraction={{ p.uniform_fraction }})", component="pixel_samplers"),
        harness=Harness(build=_build("GradientImportance", "uniform_fraction"), call=map_call, cases=MAP_CASES),
        constraints=(RAY_BATCHES,)),
    TerminalDef(
        "view_selection", "PixelSampler", ViewSelection,
        "Training views chosen by a rule (every n-th view, or the first n): the others are never sampled.",
        "nerfify_ns.components.pixel_samplers.ViewSelection",
        contract=Contract(IMAGES, WEIGHTS, sizes=MAP_SIZES, doc="reads the image indices; writes the pixel map"),
        code=Code((MAP_IMPORT.format("ViewSelection"),),
                  ctor="ViewSelection(rule={{ p.rule | tojson }}, n={{ p.n }})", component="pixel_samplers"),
        harness=Harness(build=_build("ViewSelection", "rule", "n"), call=map_call, cases=MAP_CASES),
        constraints=(RAY_BATCHES,)),
    TerminalDef(
        "anneal", "ScheduleHook", Anneal,
        "A scalar of the model annealed between two values over a range of steps (e.g. Nerfies' coarse-to-fine "
        "window).",
        "nerfify_ns.components.schedule_hooks.Anneal",
        contract=Contract(STEPS, {"values": T("[N]", doc="the value written at each step")},
                          doc="reads the step; writes model.<target> (an attribute of the named part)"),
        code=Code((HOOK_IMPORT.format("Anneal"),),
                  ctor="Anneal(target={{ p.target | tojson }}, start_value={{ p.start_value }}, "
                       "end_value={{ p.end_value }}, start_step={{ p.start_step }}, end_step={{ p.end_step }}, "
                       "curve={{ p.curve | tojson }})",
                  component="schedule_hooks", traits={"writes": "model"}),
        harness=Harness(build=_build("Anneal", "target", "start_value", "end_value", "start_step", "end_step",
                                     "curve"), call=hook_call, cases=HOOK_CASES),
        constraints=(_writes_a_part_of_the_plan("target", attribute=True),)),
    TerminalDef(
        "freeze", "ScheduleHook", Freeze,
        "A part of the model stops learning between two steps (a training stage, e.g. the canonical field "
        "before the deformation).",
        "nerfify_ns.components.schedule_hooks.Freeze",
        contract=Contract(STEPS, {"values": T("[N]", range=(0.0, 1.0), doc="1 where the part is frozen")},
                          doc="reads the step; writes requires_grad of model.<module>'s parameters"),
        code=Code((HOOK_IMPORT.format("Freeze"),),
                  ctor="Freeze(module={{ p.module | tojson }}, start_step={{ p.start_step }}, "
                       "end_step={{ p.end_step }})",
                  component="schedule_hooks", traits={"writes": "model"}),
        harness=Harness(build=_build("Freeze", "module", "start_step", "end_step"), call=hook_call,
                        cases=HOOK_CASES),
        constraints=(_writes_a_part_of_the_plan("module", attribute=False),)),
    TerminalDef(
        "image_curriculum", "ScheduleHook", ImageCurriculum,
        "A curriculum over the training images: a growing prefix (frames added in time) or key frames first "
        "(DyNeRF's hierarchical training).",
        "nerfify_ns.components.schedule_hooks.ImageCurriculum",
        contract=Contract(STEPS, {"values": T("[N]", range=(0.0, 1.0), doc="fraction of the images in use")},
                          doc="reads the step; writes the training pixel sampler's active images"),
        code=Code((HOOK_IMPORT.format("ImageCurriculum"),),
                  ctor="ImageCurriculum(rule={{ p.rule | tojson }}, start_fraction={{ p.start_fraction }}, "
                       "keyframe_stride={{ p.keyframe_stride }}, end_step={{ p.end_step }})",
                  component="schedule_hooks", traits={"writes": "datamanager", "needs_map_sampler": True}),
        harness=Harness(build=_build("ImageCurriculum", "rule", "start_fraction", "keyframe_stride", "end_step"),
                        call=hook_call, cases=HOOK_CASES),
        constraints=(RAY_BATCHES,)),
]
