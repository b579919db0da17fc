"""The assembled plugin: its model built from its own config with a tiny scene box, run on a small
RayBundle, losses backpropagated; nominal and stiff cases. Runs only inside a probe subprocess."""

from __future__ import annotations

import copy
import inspect
import math

import torch
from torch import nn

from nerfify_ns.registry.contract import finite_problem
from nerfify_ns.registry.examples import AABB, RAY_CASES, collide, ray_bundle

MODEL_CASES = (*RAY_CASES, "density_0", "density_1e8", "density_raw_1e8", "half")
"""The ray cases of the harness plus densities forced through the assembled field and half precision."""
DENSITY_MODULES = ("backbone", "density_head", "mlp_base", "mlp_base_mlp", "linear")
"""Field submodules whose output is (or starts with) the pre-activation density."""


PROBE_CAPS = {"grid_resolution": 32, "grid_levels": 2, "num_random": 5000}
"""Model config values capped in the probe's model (an occupancy grid update runs the field on every cell; a
splatting model's random initial Gaussians are rasterised in every pass)."""


def build_model(spec, scale: float = 1.0):
    """The plugin's model from its own config, on a [-1.5, 1.5]^3 scene box (times ``scale``)."""
    from nerfstudio.data.scene_box import SceneBox

    cfg = copy.deepcopy(spec.config.pipeline.model)
    for name in ("near_plane", "far_plane"):
        if isinstance(getattr(cfg, name, None), int | float):
            setattr(cfg, name, getattr(cfg, name) * scale)
    if isinstance(getattr(cfg, "collider_params", None), dict):
        cfg.collider_params = {k: v * scale for k, v in cfg.collider_params.items()}
    for name, cap in PROBE_CAPS.items():  # wiring is checked at small sizes: the grid update visits every cell
        if isinstance(getattr(cfg, name, None), int):
            setattr(cfg, name, min(getattr(cfg, name), cap))
    model = cfg.setup(scene_box=SceneBox(aabb=torch.tensor(AABB) * scale), num_train_data=4, metadata={})
    return model.to("cpu")


def plugin_fields(model, package: str) -> list[tuple[str, nn.Module]]:
    from nerfstudio.fields.base_field import Field

    return [
        (name, m)
        for name, m in model.named_modules()
        if isinstance(m, Field) and name and type(m).__module__.split(".")[0] == package
    ]


def field_forward(field, case: str = "nominal") -> dict[str, torch.Tensor]:
    """The field's outputs on uniform samples of a small ray bundle."""
    from nerfstudio.field_components.field_heads import FieldHeadNames
    from nerfstudio.model_components.ray_samplers import UniformSampler

    bundle = collide(ray_bundle(case, times=True), case)  # times: a space-time field reads them, others not
    samples = UniformSampler(num_samples=8)(bundle)
    samples.camera_indices = torch.zeros(*samples.shape, 1, dtype=torch.long)
    out = field(samples)
    return {
        ("density" if k == FieldHeadNames.DENSITY else getattr(k, "value", str(k))): v
        for k, v in out.items()
        if isinstance(v, torch.Tensor)
    }


class _NoOptimizers:
    """What a model's callbacks read of the trainer's optimisers in the harness (splatfacto keeps them for its
    densification, which runs after an iteration, never in the harness): none."""

    optimizers: dict = {}


def before_iteration(model, step: int = 0) -> None:
    """Run the model's own BEFORE_TRAIN_ITERATION callbacks (occupancy grid update, proposal annealing, a splatting
    model's step counter)."""
    from nerfstudio.engine.callbacks import TrainingCallbackAttributes, TrainingCallbackLocation

    callbacks = model.get_training_callbacks(TrainingCallbackAttributes(_NoOptimizers(), None, None, None))
    for cb in callbacks:
        cb.run_callback_at_location(step, TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)


def renders_cameras(model) -> bool:
    """A model that renders whole cameras (splatting: ``get_outputs(camera)``), not ray bundles."""
    try:
        return "camera" in inspect.signature(type(model).get_outputs).parameters
    except (TypeError, ValueError):
        return False


CAMERA_CASES = {"grazing_rays": "a camera facing away from the scene (it sees no Gaussian)",
                "scene_scale_1e-3": "the scene and the camera 1e-3 times as large",
                "scene_scale_1e3": "the scene and the camera 1e3 times as large"}
"""The model cases a model of cameras meets, and what each is for it; the others (near and far planes, rays that
miss, an empty ray batch) have no meaning where whole images are rasterised (:func:`camera_case_not_applicable`)."""


def camera_case_not_applicable(model, case: str) -> str | None:
    """Why ``case`` does not apply to a model that renders cameras, or None."""
    if not renders_cameras(model) or case == "nominal" or case in CAMERA_CASES or case.startswith("density") \
            or case == "half":
        return None
    return f"a model that rasterises whole cameras has no {case.replace('_', ' ')} (rays, near and far planes)"


def small_camera(model, case: str = "nominal", size: int = 24, time: float = 0.5):
    """A ``size`` x ``size`` pinhole camera looking at the centre of the model's scene box from 8/3 of its half
    extent (4 for the [-1.5, 1.5]^3 box), at time ``time``, camera index 0; ``grazing_rays``: facing away."""
    from nerfstudio.cameras.cameras import Cameras, CameraType

    aabb = model.scene_box.aabb.float()
    centre, half = aabb.mean(0), (aabb[1] - aabb[0]).abs().max() / 2
    eye = centre + torch.tensor([0.0, -1.0, 0.25]) / math.sqrt(1.0625) * half * (8.0 / 3.0)
    back = torch.nn.functional.normalize(eye - centre, dim=0)
    if case == "grazing_rays":
        back = -back
    right = torch.nn.functional.normalize(torch.linalg.cross(torch.tensor([0.0, 0.0, 1.0]), back), dim=0)
    up = torch.linalg.cross(back, right)
    c2w = torch.stack([right, up, back, eye], dim=1)[None]
    focal = float(size)
    camera = Cameras(camera_to_worlds=c2w, fx=focal, fy=focal, cx=size / 2, cy=size / 2, width=size, height=size,
                     camera_type=CameraType.PERSPECTIVE, times=torch.tensor([[time]]))
    camera.metadata = {"cam_idx": 0}
    return camera


def train_step(model, case: str = "nominal", rays: int = 16):
    """outputs, loss dict and total loss of one training forward on a small ray bundle (backward done); a model that
    renders cameras: on a small camera (:func:`small_camera`)."""
    from nerfify_ns.registry.examples import RUN_SEED

    model.train()
    before_iteration(model)
    generator = torch.Generator().manual_seed(5 + RUN_SEED)
    if renders_cameras(model):
        camera = small_camera(model, case)
        batch = {"image": torch.rand(int(camera.height), int(camera.width), 3, generator=generator)}
        outputs = model.get_outputs(camera)
    else:
        bundle = ray_bundle(case, rays, times=True)
        if case in ("grazing_rays", "missing_rays"):
            bundle.nears = bundle.fars = None  # the model's own collider decides
        batch = {"image": torch.rand(bundle.origins.shape[0], 3, generator=generator)}
        outputs = model(bundle)
    metrics = model.get_metrics_dict(outputs, batch)
    losses = model.get_loss_dict(outputs, batch, metrics)
    total = sum(v for v in losses.values() if isinstance(v, torch.Tensor))
    if isinstance(total, torch.Tensor) and total.requires_grad:
        total.backward()
    return outputs, losses, total


def output_problems(outputs: dict, losses: dict) -> list[str]:
    problems = []
    for key in ("rgb", "accumulation", "depth", "expected_depth", "rgb_fine", "rgb_coarse"):
        value = outputs.get(key)
        if isinstance(value, torch.Tensor):
            problems += [p for p in [finite_problem(f"outputs[{key!r}]", value)] if p]
    for key, value in losses.items():
        if isinstance(value, torch.Tensor):
            problems += [p for p in [finite_problem(f"loss {key!r}", value)] if p]
    return problems


def grad_problems(model, require: bool) -> tuple[list[str], list[str]]:
    """(non-finite gradient problems, names of trainable parameters without a gradient)."""
    groups = model.get_param_groups()
    ids = {id(p) for params in groups.values() for p in params}
    bad, missing = [], []
    for name, p in model.named_parameters():
        if id(p) not in ids or not p.requires_grad:
            continue
        if p.grad is None:
            missing.append(name)
        elif not torch.isfinite(p.grad).all():
            bad.append(f"gradient of {name} not finite")
    return bad, (missing if require else [])


def patch_density(model, package: str, case: str):
    """Force the stiff density of ``case`` on every plugin field: (why not, or None; a function undoing it)."""
    fields = plugin_fields(model, package)
    undo = []
    if case in ("density_0", "density_1e8"):
        value = 0.0 if case == "density_0" else 1e8
        for _, f in fields:

            def forced(ray_samples, _orig=f.get_density):
                result = _orig(ray_samples)
                if isinstance(result, tuple):
                    return (result[0] * 0.0 + value, *result[1:])
                return result * 0.0 + value

            f.get_density = forced
            undo.append(lambda f=f: f.__dict__.pop("get_density", None))
    else:
        for _, f in fields:
            module = next(
                (getattr(f, n) for n in DENSITY_MODULES if isinstance(getattr(f, n, None), nn.Module)), None
            )
            if module is not None:
                handle = module.register_forward_hook(
                    lambda m, i, o: o + 1e8 if isinstance(o, torch.Tensor) else o
                )
                undo.append(handle.remove)
        if not undo:
            return "no field submodule producing the pre-activation density " + str(DENSITY_MODULES), None

    def restore() -> None:
        for fn in undo:
            fn()

    return None, restore
