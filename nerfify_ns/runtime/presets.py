"""CPU presets of Nerfstudio's built-in methods (each base's in ``registry/bases.yaml``, other variants in
``runtime/smoke_presets.yaml``): the ns-train arguments that
shrink a method for a small CPU scene, exactly as a user would type them, and how long a smoke run of each
must be for its loss to move."""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from importlib import resources

import yaml

DEFAULT_SMOKE_ITERATIONS = 20
"""Smoke-training iterations of a base whose preset names none."""


@lru_cache(maxsize=1)
def smoke_presets() -> dict[str, dict]:
    """Every CPU preset by method name: each base model's (``smoke`` of its one definition,
    ``nerfify_ns/registry/bases.yaml``), then the variants of ``smoke_presets.yaml`` that are no base."""
    from nerfify_ns.registry.bases import smoke_presets as base_presets

    text = resources.files("nerfify_ns.runtime").joinpath("smoke_presets.yaml").read_text()
    return {**base_presets(), **(yaml.safe_load(text) or {})}


def preset_args(method: str) -> list[str]:
    """The ns-train arguments that shrink ``method`` for a small CPU scene (none if unknown)."""
    return [str(a) for a in smoke_presets().get(method, {}).get("args", [])]


RAY_BATCH_FLAGS = ("--pipeline.datamanager.train-num-rays-per-batch", "--pipeline.datamanager.eval-num-rays-per-batch")
"""The ns-train options of a data manager that samples rays; one that loads whole images has neither."""


def options(args: Sequence[str]) -> list[tuple[str, list[str]]]:
    """ns-train arguments as (option, its values) in order: the values are what follows an option up to the next."""
    out: list[tuple[str, list[str]]] = []
    for a in args:
        if a.startswith("--") or not out:
            out.append((a, []))
        else:
            out[-1][1].append(a)
    return out


def for_method(method: str, args: Sequence[str]) -> list[str]:
    """``args`` as ``method`` (a built-in method, or the base of a generated plugin) takes them: without the
    ray-batch options when its data manager loads whole images (``whole_images`` in its preset: splatfacto), where
    tyro would refuse them."""
    if not smoke_presets().get(method, {}).get("whole_images"):
        return list(args)
    return [a for flag, values in options(args) if flag not in RAY_BATCH_FLAGS for a in (flag, *values)]


def smoke_iterations(base: str | None, given: int | None = None) -> int:
    """Iterations of the smoke rung for a plugin derived from ``base``: ``given`` when set, else the base's
    preset (``smoke_iterations``: bases whose loss leaves its first plateau late need more)."""
    if given is not None:
        return given
    return int(smoke_presets().get(base or "", {}).get("smoke_iterations", DEFAULT_SMOKE_ITERATIONS))


DEFAULT_STEP_TIME_EXPONENT = 1.0
"""A base whose preset states none: a training step's time grows in proportion to the ray batch (an upper bound:
per-step costs that do not grow with the batch, such as the optimiser's update, make it grow less)."""


def step_time_exponent(base: str | None) -> float:
    """How a training step's time grows with the ray batch for a plugin derived from ``base``: time ~ rays ** e
    (``step_time_exponent`` in the preset, measured; :data:`DEFAULT_STEP_TIME_EXPONENT` otherwise). A budgeted run
    scales the smoke rung's measured step time to the evaluation's batch with it."""
    return float(smoke_presets().get(base or "", {}).get("step_time_exponent", DEFAULT_STEP_TIME_EXPONENT))


def render_cost(base: str | None, default: float) -> float:
    """Rendering a ray against training one for a plugin derived from ``base`` (``render_cost`` in the preset,
    measured; ``default`` otherwise): a budgeted run reserves the checkpoints' rendering with it."""
    return float(smoke_presets().get(base or "", {}).get("render_cost", default))


def generated_smoke_args(base: str) -> list[str]:
    """ns-train arguments for a generated plugin derived from ``base`` on a small CPU scene: the pipeline
    and ray-batch arguments of the base's preset, its ``plugin_args`` (a size of the scene, not of the paper's
    method: splatfacto's random initial Gaussians) and no mixed precision. Model arguments are otherwise left out:
    the plugin's sizes come from its plan, already pruned for the scene."""
    out = [a for flag, values in options(preset_args(base))
           if flag.startswith("--pipeline.") and not flag.startswith("--pipeline.model.") for a in (flag, *values)]
    return [*out, *plugin_args(base), "--mixed-precision", "False"]


def plugin_args(base: str) -> list[str]:
    """ns-train arguments every CPU run of a plugin derived from ``base`` takes, the smoke rung's included: a size of
    the small scene, not of the paper's method (``plugin_args`` of the base's preset: splatfacto's random initial
    Gaussians)."""
    return [str(a) for a in smoke_presets().get(base, {}).get("plugin_args", [])]
