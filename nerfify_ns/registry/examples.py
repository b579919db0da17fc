"""Example inputs at small sizes, generated from a contract, and the stiff and extreme cases.

``example_inputs(contract, env, case)`` makes one input per contract entry from its role, shape,
dtype and range; a case (``CASES``) changes sizes (``empty_batch``), precision (``half``) or values
(positions at 1e5, densities of 1e8, zero step sizes, ...). Torch and Nerfstudio are imported on use:
this runs inside the sandboxed probe.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from nerfify_ns.registry.contract import Contract, TensorSpec

AABB = ((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5))
"""The scene box of every example (and of the assembled model)."""

CASES: dict[str, str] = {
    "nominal": "small random inputs of the contract's shapes",
    "empty_batch": "zero rays / points",
    "points_outside_contraction": "positions at 1e5, far outside the scene box and the contraction",
    "scene_scale_1e-3": "positions and scene box scaled by 1e-3",
    "scene_scale_1e3": "positions and scene box scaled by 1e3",
    "half": "float16 inputs and parameters",
    "near_eq_far": "near plane = far plane (zero-length rays)",
    "far_1e5": "far plane at 1e5",
    "grazing_rays": "rays tangent to a face of the scene box (box collider)",
    "missing_rays": "rays pointing away from the scene box (box collider)",
    "density_raw_0": "pre-activation density 0",
    "density_raw_1e8": "pre-activation density 1e8",
    "density_raw_-1e8": "pre-activation density -1e8",
    "density_0": "densities 0 everywhere",
    "density_1e8": "densities 1e8 everywhere",
    "step_zero": "zero step sizes (deltas)",
    "step_tiny": "step sizes 1e-10",
    "step_huge": "step sizes 1e10",
    "density_1e8_step_huge": "densities 1e8 with step sizes 1e10",
    "zeros": "all-zero inputs",
    "values_1e8": "inputs of magnitude 1e8",
}

POINT_CASES = ("empty_batch", "points_outside_contraction", "scene_scale_1e-3", "scene_scale_1e3", "half")
DIRECTION_CASES = ("zeros", "values_1e8", "empty_batch", "half")
RAY_CASES = ("near_eq_far", "far_1e5", "grazing_rays", "missing_rays", "scene_scale_1e-3", "scene_scale_1e3",
             "empty_batch")
DENSITY_CASES = ("density_raw_0", "density_raw_1e8", "density_raw_-1e8", "empty_batch", "half")
COMPOSITE_CASES = ("density_0", "density_1e8", "step_zero", "step_tiny", "step_huge", "near_eq_far", "far_1e5",
                   "density_1e8_step_huge", "empty_batch", "half")
VALUE_CASES = ("zeros", "values_1e8", "empty_batch", "half")
SAMPLER_LOSS_CASES = ("density_0", "density_1e8", "step_zero", "step_huge", "near_eq_far", "far_1e5",
                      "density_1e8_step_huge", "empty_batch")

SCALES = {"scene_scale_1e-3": 1e-3, "scene_scale_1e3": 1e3}
DENSITY_OFFSETS = {"density_raw_0": 0.0, "density_raw_1e8": 1e8, "density_raw_-1e8": -1e8}


class NotApplicable(Exception):
    """The case does not apply to this component (e.g. a marcher that needs at least one ray)."""


def case_sizes(case: str) -> dict[str, int]:
    """Size overrides of a case: an empty batch has no points and no rays."""
    return {"N": 0, "R": 0} if case == "empty_batch" else {}


def case_dtype(case: str):
    import torch

    return torch.float16 if case == "half" else torch.float32


RUN_SEED = 0
"""Added to every example's seed: the ladder draws one per run (``os.urandom``), so a component cannot know
the inputs it will be checked on in advance; 0 reproduces the fixed examples."""


def set_run_seed(seed: int) -> None:
    global RUN_SEED
    RUN_SEED = int(seed) % (1 << 62)


def _generator(seed: int):
    import torch

    return torch.Generator().manual_seed(seed + RUN_SEED)


def _positions(shape: tuple[int, ...], spec: TensorSpec, case: str):
    import torch

    x = torch.rand(*shape, generator=_generator(0))
    low, high = spec.range
    x = low + (high - low) * x if low is not None and high is not None else x * 3 - 1.5
    if case == "points_outside_contraction":
        x = torch.sign(x) * 1e5
    return x * SCALES.get(case, 1.0)


def _directions(shape: tuple[int, ...], case: str):
    import torch

    d = torch.nn.functional.normalize(torch.randn(*shape, generator=_generator(1)), dim=-1)
    return _value_case(d, case)


def _value_case(x, case: str):
    import torch

    if case == "zeros":
        return torch.zeros_like(x)
    if case == "values_1e8":
        return x * 1e8
    return x


def _values(shape: tuple[int, ...], spec: TensorSpec, case: str, seed: int):
    import torch

    low, high = spec.range
    low = -1.0 if low is None else low
    high = low + 2.0 if high is None else high
    x = low + (high - low) * torch.rand(*shape, generator=_generator(seed))
    return _value_case(x, case)


def _tensor(name: str, spec: TensorSpec, shape: tuple[int, ...], case: str, env: Mapping[str, Any], seed: int):
    import torch

    if spec.dtype == "long":
        return torch.randint(0, max(int(env.get("cameras", 4)), 1), shape, generator=_generator(seed))
    if spec.role == "positions":
        x = _positions(shape, spec, case)
    elif spec.role == "directions":
        x = _directions(shape, case)
    elif spec.role == "covariances":
        x = (torch.eye(3) * 1e-3).expand(*shape).clone()
    elif spec.role == "pre_density":
        x = _values(shape, spec, "nominal", seed)
    else:
        x = _values(shape, spec, case, seed)
    x = x.to(case_dtype(case))
    return x.requires_grad_(True) if spec.grad else x


def example_inputs(contract: Contract, env: Mapping[str, Any], case: str = "nominal") -> dict[str, Any]:
    """One example per contract input, at the sizes of ``env`` and changed by ``case``."""
    inputs: dict[str, Any] = {}
    for seed, (name, spec) in enumerate(contract.inputs.items(), start=2):
        if spec.dtype == "rays":
            inputs[name] = collide(ray_bundle(case, int(env["R"])), case)
        elif spec.dtype == "samples":
            inputs[name] = composite_samples(case, int(env["S"]), int(env["R"]))
        elif spec.dtype == "list" and spec.role == "planes":
            inputs[name] = planes(case)
        elif spec.dtype in ("list", "function"):
            inputs[name] = None  # the terminal's harness supplies these
        else:
            inputs[name] = _tensor(name, spec, contract.shape(spec, env), case, env, seed)
    return inputs


def planes(case: str):
    """Two small feature planes (a list of [1, C, H, W]), the input of plane regularisers."""
    if case == "empty_batch":
        return []
    spec = TensorSpec("[1, 4, 8, 8]")
    return [_values((1, 4, 8, 8), spec, case, 7).to(case_dtype(case)).requires_grad_(True),
            _values((1, 4, 6, 8), spec, case, 8).to(case_dtype(case)).requires_grad_(True)]


def ray_bundle(case: str, rays: int = 16, times: bool = False):
    """Rays from a sphere of radius 4 towards the box centre; nears/fars per case (None: a collider decides);
    ``times``: each ray carries a time in [0, 1], as a dynamic (D-NeRF) dataset's rays do."""
    import torch
    from nerfstudio.cameras.rays import RayBundle

    rays = 0 if case == "empty_batch" else rays
    scale = SCALES.get(case, 1.0)
    gen = _generator(3)
    origins = torch.nn.functional.normalize(torch.randn(rays, 3, generator=gen), dim=-1) * 4.0
    directions = torch.nn.functional.normalize(-origins + 0.3 * torch.randn(rays, 3, generator=gen), dim=-1)
    if case == "grazing_rays":
        origins = torch.tensor([[4.0, 1.5, 0.0]]).repeat(rays, 1)
        origins[:, 2] = torch.linspace(-1.5, 1.5, rays)
        directions = torch.tensor([[-1.0, 0.0, 0.0]]).repeat(rays, 1)
    elif case == "missing_rays":
        directions = -directions
    bundle = RayBundle(origins=origins * scale, directions=directions,
                       pixel_area=torch.full((rays, 1), 1e-4 * scale * scale),
                       camera_indices=torch.zeros(rays, 1, dtype=torch.long),
                       times=torch.rand(rays, 1, generator=gen) if times else None)
    if case in ("grazing_rays", "missing_rays"):
        return bundle
    near, far = (4.0, 4.0) if case == "near_eq_far" else (2.0, 1e5 if case == "far_1e5" else 6.0)
    bundle.nears = torch.full((rays, 1), near * scale)
    bundle.fars = torch.full((rays, 1), far * scale)
    return bundle


def collide(bundle, case: str = "nominal"):
    """Nears/fars from Nerfstudio's box collider for rays that have none (grazing/missing cases)."""
    if bundle.nears is not None:
        return bundle
    import torch
    from nerfstudio.data.scene_box import SceneBox
    from nerfstudio.model_components.scene_colliders import AABBBoxCollider

    return AABBBoxCollider(SceneBox(aabb=torch.tensor(AABB)), near_plane=0.05)(bundle)


STEPS = {"step_zero": 0.0, "step_tiny": 1e-10, "step_huge": 1e10, "density_1e8_step_huge": 1e10, "near_eq_far": 0.0}
DENSITIES = {"density_0": 0.0, "density_1e8": 1e8, "density_1e8_step_huge": 1e8}


def composite_samples(case: str, samples: int = 8, rays: int = 16):
    """(RaySamples with per-case step sizes, densities [R, S, 1] requiring gradients) for compositing."""
    import torch
    from nerfstudio.cameras.rays import Frustums, RaySamples

    rays = 0 if case == "empty_batch" else rays
    spacing = (1e5 - 2.0) / samples if case == "far_1e5" else STEPS.get(case, 0.5)
    starts = 2.0 + spacing * torch.arange(samples, dtype=torch.float32)
    starts = starts.view(1, samples, 1).expand(rays, samples, 1).contiguous()
    ends = starts + spacing
    frustums = Frustums(origins=torch.zeros(rays, samples, 3),
                        directions=torch.tensor([0.0, 0.0, 1.0]).expand(rays, samples, 3),
                        starts=starts, ends=ends, pixel_area=torch.ones(rays, samples, 1))
    top = max(float(ends.max()) if ends.numel() else 1.0, 1e-12)
    ray_samples = RaySamples(frustums=frustums, spacing_starts=starts / top, spacing_ends=ends / top,
                             spacing_to_euclidean_fn=lambda x: x, deltas=ends - starts)
    value = DENSITIES.get(case)
    densities = (torch.rand(rays, samples, 1, generator=_generator(4)) * 5 if value is None
                 else torch.full((rays, samples, 1), value))
    return ray_samples, densities.requires_grad_(True)
