"""Schedule hooks: training callbacks that change a part of the model or the data at given steps.

A hook is a module with ``forward(steps [K] long) -> values [K]`` (its schedule: the value it writes at each
step; the ScheduleHook contract of the grammar), ``write(value, model, datamanager)`` (what it changes;
``run(step, model, pipeline)`` writes the value of a step) and
``check(model)`` (called when the model is built: the part it changes exists). :func:`training_callbacks` turns
the model's hooks into Nerfstudio ``TrainingCallback``s run before every training iteration with the trainer's
``TrainingCallbackAttributes`` (the pipeline, hence the datamanager).

- :class:`Anneal`: a scalar of the model annealed from ``start_value`` to ``end_value`` between two steps
  (linear or cosine), e.g. the coarse-to-fine window over encoding frequencies of Nerfies (Park et
  al. 2021, arXiv 2011.12948, Eq. 9: alpha(step) = m step / N) or a deformation's window.
- :class:`Freeze`: the parameters of a part of the model stop learning between two steps (a stage that trains
  the canonical field before the deformation: the warm-up of Deformable 3D Gaussians, Yang et al. 2024,
  arXiv 2309.13101, "the first 3k iterations without optimizing the deformation field").
- :class:`ImageCurriculum`: the training images a batch may draw from grow over the steps (``prefix``: the first
  fraction of the images in dataset order, a video's frames growing in time) or are the key frames first
  (``keyframes``: every k-th frame until ``end_step``, then all: DyNeRF's hierarchical training, Li et al. 2022,
  arXiv 2103.02597). It sets the ``active`` images of the plugin's :class:`MapPixelSampler`.

Imports only torch and nerfstudio: generated plugins import this module.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import torch
from torch import Tensor, nn

__all__ = ["ScheduleHook", "Anneal", "Freeze", "ImageCurriculum", "training_callbacks", "named_parts"]


def _progress(steps: Tensor, start: int, end: int) -> Tensor:
    """(step - start) / (end - start) clamped to [0, 1] (a step function at ``start`` when end <= start)."""
    s = steps.double()
    if end <= start:
        return (s >= start).double()
    return ((s - start) / float(end - start)).clamp(0.0, 1.0)


def named_parts(model: nn.Module, name: str) -> list[tuple[str, nn.Module]]:
    """The outermost modules of ``model`` whose qualified name is ``name`` or ends with ``.<name>``, or that call
    themselves ``name`` (their ``part_name``: a wrapper found wherever the model holds it, e.g. the window of every
    field's position encoding, coarse and fine)."""
    found: list[tuple[str, nn.Module]] = []
    for qualified, module in model.named_modules():
        if qualified == name or qualified.endswith("." + name) or getattr(module, "part_name", None) == name:
            if not any(qualified.startswith(outer + ".") for outer, _ in found):
                found.append((qualified, module))
    return found


class ScheduleHook(nn.Module):
    """A training callback at given steps: ``forward(steps)`` is its schedule, ``write`` applies one value."""

    every: int = 1
    """Iterations between calls (1: before every training iteration)."""

    def forward(self, steps: Tensor) -> Tensor:  # pragma: no cover - every hook defines its schedule
        raise NotImplementedError

    def value(self, step: int) -> float:
        return float(self(torch.tensor([int(step)]))[0])

    def check(self, model: nn.Module) -> None:
        """Raise ValueError when the model lacks what the hook changes (called when the model is built)."""

    def write(self, value: float, model: nn.Module, datamanager: Any) -> None:  # pragma: no cover
        raise NotImplementedError

    def run(self, step: int, model: nn.Module, pipeline: Any = None, scale: float = 1.0) -> None:
        """Write the value of training step ``step``: the schedule read at ``step / scale`` (``scale``: run steps
        per paper step, below 1 when a budgeted run is shorter than the paper's, so that its phases end within it)."""
        paper_step = int(step / scale) if 0 < scale < 1 else int(step)
        self.write(self.value(paper_step), model, getattr(pipeline, "datamanager", None))


class Anneal(ScheduleHook):
    """Write ``start_value`` -> ``end_value`` between ``start_step`` and ``end_step`` to ``target``: an attribute
    (a float, or a tensor buffer/parameter filled in place) named ``<part>.<attribute>``, of every part of the
    model whose name ends with ``<part>`` (``deformation.window``: the deformation field's window)."""

    def __init__(self, target: str = "deformation.window", start_value: float = 0.0, end_value: float = 10.0,
                 start_step: int = 0, end_step: int = 2000, curve: str = "linear") -> None:
        super().__init__()
        if curve not in ("linear", "cosine"):
            raise ValueError(f"curve must be linear or cosine, got {curve!r}")
        self.part, _, self.attribute = target.rpartition(".")
        self.target = target
        self.start_value, self.end_value = float(start_value), float(end_value)
        self.start_step, self.end_step, self.curve = int(start_step), int(end_step), curve

    def forward(self, steps: Tensor) -> Tensor:
        s = _progress(steps, self.start_step, self.end_step)
        a, b = self.start_value, self.end_value
        if self.curve == "cosine":
            s = (1 - torch.cos(math.pi * s)) / 2
        return (a + (b - a) * s).float()

    def _targets(self, model: nn.Module) -> list[tuple[str, nn.Module]]:
        parts = named_parts(model, self.part) if self.part else [("", model)]
        return [(name, m) for name, m in parts if hasattr(m, self.attribute)]

    def check(self, model: nn.Module) -> None:
        if not self._targets(model):
            raise ValueError(f"anneal: the model has no {self.target!r} (a part named {self.part!r} with an attribute "
                             f"{self.attribute!r})")

    def write(self, value: float, model: nn.Module, datamanager: Any) -> None:
        targets = self._targets(model)
        if not targets:
            self.check(model)
        for _, module in targets:
            current = getattr(module, self.attribute)
            if isinstance(current, Tensor):
                with torch.no_grad():
                    current.fill_(value)
            else:
                setattr(module, self.attribute, type(current)(value) if isinstance(current, int | float) else value)


class Freeze(ScheduleHook):
    """The parameters of every part named ``module`` (a name or the end of a dotted name) stop learning from
    ``start_step`` until ``end_step`` (``requires_grad`` off, so the optimiser leaves them as they are)."""

    def __init__(self, module: str = "deformation", start_step: int = 0, end_step: int = 1000) -> None:
        super().__init__()
        self.module, self.start_step, self.end_step = module, int(start_step), int(end_step)

    def forward(self, steps: Tensor) -> Tensor:
        return ((steps >= self.start_step) & (steps < self.end_step)).float()

    def _params_of(self, model: nn.Module) -> list[nn.Parameter]:
        return [p for _, part in named_parts(model, self.module) for p in part.parameters()]

    def check(self, model: nn.Module) -> None:
        if not named_parts(model, self.module):
            raise ValueError(f"freeze: the model has no part named {self.module!r}")
        if len({id(p) for p in self._params_of(model)}) >= len(list(model.parameters())):
            raise ValueError(f"freeze: {self.module!r} holds every parameter of the model; nothing would learn")

    def write(self, value: float, model: nn.Module, datamanager: Any) -> None:
        params = self._params_of(model)
        if not params:
            self.check(model)
        for p in params:
            p.requires_grad_(value < 0.5)
            if value >= 0.5:
                p.grad = None


class ImageCurriculum(ScheduleHook):
    """The images training may draw from, by step: ``rule="prefix"``, the first ``ceil(f n)`` of the n training
    images, f growing linearly from ``start_fraction`` to 1 at ``end_step``; ``rule="keyframes"``, the images
    whose index is a multiple of ``keyframe_stride`` until ``end_step``, then all. ``forward`` gives the active
    fraction (keyframes: 1 / stride before ``end_step``). Needs the plugin's MapPixelSampler."""

    def __init__(self, rule: str = "prefix", start_fraction: float = 0.25, keyframe_stride: int = 4,
                 end_step: int = 2000) -> None:
        super().__init__()
        if rule not in ("prefix", "keyframes"):
            raise ValueError(f"rule must be prefix or keyframes, got {rule!r}")
        self.rule, self.start_fraction = rule, float(start_fraction)
        self.keyframe_stride, self.end_step = max(int(keyframe_stride), 1), int(end_step)

    def forward(self, steps: Tensor) -> Tensor:
        if self.rule == "keyframes":
            return torch.where(steps >= self.end_step, torch.ones_like(steps, dtype=torch.float32),
                               torch.full_like(steps, 1.0 / self.keyframe_stride, dtype=torch.float32))
        f = self.start_fraction + (1 - self.start_fraction) * _progress(steps, 0, self.end_step)
        return f.float()

    def write(self, value: float, model: nn.Module, datamanager: Any) -> None:
        if datamanager is None:  # the model alone (no trainer): nothing to restrict
            return
        sampler = getattr(datamanager, "train_pixel_sampler", None)
        if sampler is None or not hasattr(sampler, "active"):
            raise ValueError("image_curriculum needs the plugin's MapPixelSampler as the training pixel sampler, "
                             f"found {type(sampler).__name__}")
        if value >= 1.0:
            sampler.active = None
        elif self.rule == "keyframes":
            stride = self.keyframe_stride
            sampler.active = lambda index: index % stride == 0
        else:
            count = max(1, math.ceil(value * len(datamanager.train_dataset)))
            sampler.active = lambda index: index < count


STEP_SCALE_FIELD = "schedule_step_scale"
"""The generated model config's field of run steps per paper step, read by every hook (1.0: the paper's schedule)."""


def training_callbacks(hooks: Iterable[ScheduleHook], model: nn.Module, attributes: Any | None) -> list:
    """Nerfstudio TrainingCallbacks running each hook before every ``hook.every``-th training iteration, on the
    paper's schedule compressed by the model config's ``schedule_step_scale`` (absent: 1.0), read at every call: a
    budgeted run that turns out slower than planned lowers it as it goes, so the schedule's stages still end within
    the steps the run gets."""
    from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackLocation

    pipeline = getattr(attributes, "pipeline", None)
    config = getattr(model, "config", None)

    def runner(hook: ScheduleHook):
        def run(step: int) -> None:
            hook.run(step, model=model, pipeline=pipeline, scale=float(getattr(config, STEP_SCALE_FIELD, 1.0) or 1.0))
        return run

    return [TrainingCallback(where_to_run=[TrainingCallbackLocation.BEFORE_TRAIN_ITERATION],
                             update_every_num_iters=max(int(hook.every), 1), func=runner(hook)) for hook in hooks]
