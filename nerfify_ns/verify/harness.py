"""Small-size harnesses for every grammar terminal with a torch implementation.

A harness builds its terminal's component from plan parameters (shrunk to small sizes) and runs it
on one case (``nominal`` or a stiff/extreme case from ``CASES``), returning the outputs named as in
the terminal's contract, the expected shapes, value bounds and the tensors whose gradients must be
finite. Runs only inside a probe subprocess (it imports Nerfstudio and may import plugin code).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Tuple

import torch
from torch import Tensor, nn

N = 64  # points per batch
R = 16  # rays per batch
AABB = ((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5))

POINT_CASES = ("empty_batch", "points_outside_contraction", "scene_scale_1e-3", "scene_scale_1e3", "half")
RAY_CASES = (
    "near_eq_far",
    "far_1e5",
    "grazing_rays",
    "missing_rays",
    "scene_scale_1e-3",
    "scene_scale_1e3",
    "empty_batch",
)
DENSITY_CASES = ("density_raw_0", "density_raw_1e8", "density_raw_-1e8", "empty_batch", "half")
COMPOSITE_CASES = (
    "density_0",
    "density_1e8",
    "step_zero",
    "step_tiny",
    "step_huge",
    "near_eq_far",
    "far_1e5",
    "density_1e8_step_huge",
    "empty_batch",
    "half",
)
VALUE_CASES = ("zeros", "values_1e8", "empty_batch", "half")
CASES = {
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


class NotApplicable(Exception):
    """The case does not apply to this component (e.g. half precision on an op the CPU lacks)."""


@dataclass
class Run:
    """What one harness run produced."""

    outputs: Dict[str, Tensor]
    shapes: Dict[str, Tuple[int, ...]] = field(default_factory=dict)
    bounds: Dict[str, Tuple[Optional[float], Optional[float]]] = field(default_factory=dict)
    module: Optional[nn.Module] = None
    inputs: List[Tensor] = field(default_factory=list)
    dtype: torch.dtype = torch.float32


@dataclass
class Harness:
    terminal: str
    run: Callable[[dict, str], Run]
    cases: Tuple[str, ...]


# ----------------------------------------------------------------------------- inputs
def _dtype(case: str) -> torch.dtype:
    return torch.float16 if case == "half" else torch.float32


def _n(case: str) -> int:
    return 0 if case == "empty_batch" else N


def _points(case: str, domain: str = "signed_unit") -> Tensor:
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(_n(case), 3, generator=gen)
    x = x * 2 - 1 if domain == "signed_unit" else (x * 3 - 1.5 if domain == "raw" else x)
    if case == "points_outside_contraction":
        x = torch.sign(x) * 1e5
    elif case == "scene_scale_1e-3":
        x = x * 1e-3
    elif case == "scene_scale_1e3":
        x = x * 1e3
    return x.to(_dtype(case)).requires_grad_(True)


def _directions(case: str) -> Tensor:
    d = torch.nn.functional.normalize(
        torch.randn(_n(case), 3, generator=torch.Generator().manual_seed(1)), dim=-1
    )
    if case == "zeros":
        d = torch.zeros_like(d)
    elif case == "values_1e8":
        d = d * 1e8
    return d.to(_dtype(case)).requires_grad_(True)


def _values(case: str, shape: Tuple[int, ...], low: float = 0.0, high: float = 1.0) -> Tensor:
    x = low + (high - low) * torch.rand(*shape, generator=torch.Generator().manual_seed(2))
    if case == "zeros":
        x = torch.zeros_like(x)
    elif case == "values_1e8":
        x = x * 1e8
    return x.to(_dtype(case)).requires_grad_(True)


def ray_bundle(case: str, rays: int = R):
    """Rays from a sphere of radius 4 towards the box centre; nears/fars per case (None: a collider decides)."""
    from nerfstudio.cameras.rays import RayBundle

    rays = 0 if case == "empty_batch" else rays
    scale = {"scene_scale_1e-3": 1e-3, "scene_scale_1e3": 1e3}.get(case, 1.0)
    gen = torch.Generator().manual_seed(3)
    origins = torch.nn.functional.normalize(torch.randn(rays, 3, generator=gen), dim=-1) * 4.0
    directions = torch.nn.functional.normalize(-origins + 0.3 * torch.randn(rays, 3, generator=gen), dim=-1)
    near, far = 2.0, 6.0
    if case == "grazing_rays":
        origins = torch.tensor([[4.0, 1.5, 0.0]]).repeat(rays, 1)
        origins[:, 2] = torch.linspace(-1.5, 1.5, rays)
        directions = torch.tensor([[-1.0, 0.0, 0.0]]).repeat(rays, 1)
    elif case == "missing_rays":
        directions = -directions
    bundle = RayBundle(
        origins=origins * scale,
        directions=directions,
        pixel_area=torch.full((rays, 1), 1e-4 * scale * scale),
        camera_indices=torch.zeros(rays, 1, dtype=torch.long),
    )
    if case in ("grazing_rays", "missing_rays"):
        return bundle
    if case == "near_eq_far":
        near, far = 4.0, 4.0
    elif case == "far_1e5":
        far = 1e5
    bundle.nears = torch.full((rays, 1), near * scale)
    bundle.fars = torch.full((rays, 1), far * scale)
    return bundle


def collide(bundle, case: str):
    """Nears/fars from Nerfstudio's box collider for rays that have none (grazing/missing cases)."""
    if bundle.nears is not None:
        return bundle
    from nerfstudio.data.scene_box import SceneBox
    from nerfstudio.model_components.scene_colliders import AABBBoxCollider

    return AABBBoxCollider(SceneBox(aabb=torch.tensor(AABB)), near_plane=0.05)(bundle)


def composite_samples(case: str, samples: int = 8):
    """RaySamples with per-case step sizes and densities (requires_grad) for compositing harnesses."""
    from nerfstudio.cameras.rays import Frustums, RaySamples

    rays = 0 if case == "empty_batch" else R
    step = {
        "step_zero": 0.0,
        "step_tiny": 1e-10,
        "step_huge": 1e10,
        "density_1e8_step_huge": 1e10,
        "near_eq_far": 0.0,
    }.get(case, 0.5)
    t0 = 1e5 if case == "far_1e5" else 2.0
    spacing = (1e5 - 2.0) / samples if case == "far_1e5" else step
    starts = (2.0 if case == "far_1e5" else t0) + spacing * torch.arange(samples, dtype=torch.float32)
    starts = starts.view(1, samples, 1).expand(rays, samples, 1).contiguous()
    ends = starts + spacing
    frustums = Frustums(
        origins=torch.zeros(rays, samples, 3),
        directions=torch.tensor([0.0, 0.0, 1.0]).expand(rays, samples, 3),
        starts=starts,
        ends=ends,
        pixel_area=torch.ones(rays, samples, 1),
    )
    ray_samples = RaySamples(
        frustums=frustums,
        spacing_starts=starts / max(float(ends.max()) if ends.numel() else 1.0, 1e-12),
        spacing_ends=ends / max(float(ends.max()) if ends.numel() else 1.0, 1e-12),
        spacing_to_euclidean_fn=lambda x: x,
        deltas=ends - starts,
    )
    value = {"density_0": 0.0, "density_1e8": 1e8, "density_1e8_step_huge": 1e8}.get(case)
    gen = torch.Generator().manual_seed(4)
    densities = (
        torch.rand(rays, samples, 1, generator=gen) * 5
        if value is None
        else torch.full((rays, samples, 1), value)
    )
    return ray_samples, densities.requires_grad_(True)


# ----------------------------------------------------------------------------- small sizes
def small(terminal: str, params: dict) -> dict:
    """The terminal's parameters shrunk for a quick test (the structure kept)."""
    p = dict(params)
    caps = {
        "num_levels": 4,
        "log2_hashmap_size": 12,
        "max_res": 64,
        "num_components": 8,
        "resolution": 16,
        "init_resolution": 16,
        "final_resolution": 16,
        "layer_width": 32,
        "num_layers": 3,
        "density_components": 4,
        "color_components": 6,
        "num_coarse_samples": 8,
        "num_importance_samples": 8,
        "nerf_samples": 8,
        "grid_resolution": 16,
        "grid_levels": 1,
        "network_max_res": 32,
        "network_num_levels": 2,
        "network_log2_hashmap_size": 10,
        "num_frequencies": 6,
        "resolutions": 16,
        "samples_per_ray": 8,
        "time_resolution": 4,
        "dim": 8,
    }
    for key, cap in caps.items():
        if key in p and p[key] is not None:
            value = p[key]
            p[key] = (
                [min(int(v), cap) for v in value] if isinstance(value, list) else type(value)(min(value, cap))
            )
    if "skip_connections" in p:
        p["skip_connections"] = [s for s in p["skip_connections"] or [] if s < p.get("num_layers", 3)]
    if "min_res" in p:
        p["min_res"] = min(p["min_res"], p.get("max_res", 64))
    return p


# ----------------------------------------------------------------------------- harnesses
def _encoding(terminal: str):
    def run(p: dict, case: str) -> Run:
        from nerfstudio.field_components import encodings as enc

        dt, n = _dtype(case), _n(case)
        inputs: List[Tensor] = []
        if terminal in ("positional", "integrated_positional"):
            module = enc.NeRFEncoding(
                in_dim=3,
                num_frequencies=p["num_frequencies"],
                min_freq_exp=p["min_freq_exp"],
                max_freq_exp=p["max_freq_exp"],
                include_input=p["include_input"],
            )
            x = _points(case, "raw")
            covs = None
            if terminal == "integrated_positional":
                covs = (torch.eye(3) * 1e-3).expand(n, 3, 3).to(dt).clone().requires_grad_(True)
                inputs.append(covs)
            out = module(x, covs=covs)
            dim = 3 * 2 * p["num_frequencies"] + (3 if p["include_input"] else 0)
        elif terminal == "hash":
            module = enc.HashEncoding(
                num_levels=p["num_levels"],
                min_res=p["min_res"],
                max_res=p["max_res"],
                log2_hashmap_size=p["log2_hashmap_size"],
                features_per_level=p["features_per_level"],
                implementation="torch",
            )
            x = _points(case, "unit")
            out = module(x)
            dim = p["num_levels"] * p["features_per_level"]
        elif terminal in ("kplanes", "kplanes_time"):
            from nerfify_ns.components.kplanes import MultiScaleKPlanes

            module = MultiScaleKPlanes(
                resolutions=p["resolutions"],
                num_components=p["num_components"],
                reduce=p["reduce"],
                time_resolution=p.get("time_resolution"),
            )
            x = _points(case)
            times = None
            if terminal == "kplanes_time":
                times = torch.rand(n, 1).to(dt).requires_grad_(True)
                inputs.append(times)
            out = module.to(dt)(x, times)
            dim = len(p["resolutions"]) * p["num_components"]
        elif terminal == "triplane":
            module = enc.TriplaneEncoding(
                resolution=p["resolution"], num_components=p["num_components"], reduce=p["reduce"]
            )
            x = _points(case)
            out = module.to(dt)(x)
            dim = p["num_components"]
        elif terminal in ("tensor_vm", "tensor_cp"):
            cls = enc.TensorVMEncoding if terminal == "tensor_vm" else enc.TensorCPEncoding
            comps = p["density_components"]
            module = cls(resolution=p["init_resolution"], num_components=comps)
            x = _points(case)
            out = module.to(dt)(x)
            dim = (3 if terminal == "tensor_vm" else 1) * comps
        elif terminal == "sh":
            module = enc.SHEncoding(levels=p["levels"], implementation="torch")
            x = _directions(case)
            out = module(x)
            dim = p["levels"] ** 2
        else:  # frequency
            module = enc.NeRFEncoding(
                in_dim=3,
                num_frequencies=p["num_frequencies"],
                min_freq_exp=p["min_freq_exp"],
                max_freq_exp=p["max_freq_exp"],
                include_input=p["include_input"],
            )
            x = _directions(case)
            out = module(x)
            dim = 3 * 2 * p["num_frequencies"] + (3 if p["include_input"] else 0)
        return Run({"features": out}, {"features": (n, dim)}, module=module, inputs=[x, *inputs], dtype=dt)

    return run


def _mlp(terminal: str):
    def run(p: dict, case: str) -> Run:
        from nerfstudio.field_components.mlp import MLP

        dt, n = _dtype(case), _n(case)
        in_dim = 12 + 3 if terminal == "tensorial_appearance" else 16
        if terminal in ("tensorial_appearance", "rgb_mlp"):
            module = MLP(
                in_dim=in_dim,
                num_layers=p["num_layers"],
                layer_width=p["layer_width"],
                out_dim=3,
                activation=nn.ReLU(),
                out_activation=nn.Sigmoid(),
                implementation="torch",
            )
            key, dim, bounds = "rgb", 3, (0.0, 1.0)
        else:
            module = MLP(
                in_dim=in_dim,
                num_layers=p["num_layers"],
                layer_width=p["layer_width"],
                skip_connections=tuple(p["skip_connections"]) or None,
                activation=nn.ReLU(),
                implementation="torch",
            )
            key, dim, bounds = "hidden", p["layer_width"], (None, None)
        x = _values(case if case != "empty_batch" else "nominal", (n, in_dim), -1.0, 1.0)
        out = module.to(dt)(x)
        return Run({key: out}, {key: (n, dim)}, {key: bounds}, module=module, inputs=[x], dtype=dt)

    return run


def _activation(name: str) -> Callable[[Tensor], Tensor]:
    from nerfstudio.field_components.activations import trunc_exp

    return {"softplus": nn.functional.softplus, "relu": torch.relu, "trunc_exp": trunc_exp}[name]


def _density(terminal: str):
    def run(p: dict, case: str) -> Run:
        dt, n = _dtype(case), _n(case)
        width = 1 + p["geo_feat_dim"] if terminal == "density_split" else 16
        hidden = _values("nominal", (n, width), -1.0, 1.0).to(dt).detach().requires_grad_(True)
        offset = {"density_raw_0": 0.0, "density_raw_1e8": 1e8, "density_raw_-1e8": -1e8}.get(case, 0.0)
        act = _activation(p["activation"])
        if terminal == "density_split":
            module = None
            raw, geo = torch.split(hidden, [1, p["geo_feat_dim"]], dim=-1)
            raw = raw * 0 + offset if case.startswith("density_raw") else raw
            density = p["init_density"] * act(raw.to(hidden))
            geo_dim = p["geo_feat_dim"]
        else:
            module = nn.Linear(width, 1).to(dt)
            raw = module(hidden)
            raw = raw * 0 + offset if case.startswith("density_raw") else raw
            density, geo = act(raw), hidden
            geo_dim = width
        return Run(
            {"density": density, "geo_features": geo},
            {"density": (n, 1), "geo_features": (n, geo_dim)},
            {"density": (0.0, None)},
            module=module,
            inputs=[hidden],
            dtype=dt,
        )

    return run


def _contraction(p: dict, case: str) -> Run:
    from nerfstudio.field_components.spatial_distortions import SceneContraction

    x = _points(case, "raw")
    out = SceneContraction(order=float("inf") if p["order"] == "inf" else None)(x)
    return Run(
        {"positions": out},
        {"positions": (_n(case), 3)},
        {"positions": (-2.0, 2.0)},
        inputs=[x],
        dtype=_dtype(case),
    )


def _embedding(p: dict, case: str) -> Run:
    from nerfstudio.field_components.embedding import Embedding

    n = _n(case)
    module = Embedding(4, p["dim"])
    out = module(torch.randint(0, 4, (n,)))
    return Run({"embedding": out}, {"embedding": (n, p["dim"])}, module=module)


def _renderer(p: dict, case: str) -> Run:
    from nerfstudio.model_components.renderers import AccumulationRenderer, DepthRenderer, RGBRenderer

    ray_samples, densities = composite_samples(case)
    rays, samples = densities.shape[:2]
    dt = _dtype(case)
    densities_in = densities.to(dt) if case == "half" else densities
    weights = ray_samples.get_weights(densities_in)
    rgb = torch.rand(rays, samples, 3).to(dt).requires_grad_(True)
    background = p["background"] if p["background"] != "random" else "white"
    out = {
        "rgb": RGBRenderer(background_color=background)(rgb=rgb, weights=weights),
        "accumulation": AccumulationRenderer()(weights=weights),
        "depth": DepthRenderer(method="median")(weights=weights, ray_samples=ray_samples),
        "expected_depth": DepthRenderer(method="expected")(weights=weights, ray_samples=ray_samples),
    }
    shapes = {k: (rays, 3 if k == "rgb" else 1) for k in out}
    bounds = {"rgb": (0.0, 1.0), "accumulation": (0.0, 1.0 + 1e-3)}
    return Run(out, shapes, bounds, inputs=[densities, rgb], dtype=dt)


def _sampler(terminal: str):
    def run(p: dict, case: str) -> Run:
        from nerfstudio.model_components import ray_samplers as rs

        bundle = collide(ray_bundle(case), case)
        rays = bundle.origins.shape[0]
        module = None
        out: Dict[str, Tensor] = {}
        if terminal == "near_far":
            from nerfstudio.model_components.scene_colliders import NearFarCollider

            bundle.nears = bundle.fars = None
            scale = {"scene_scale_1e-3": 1e-3, "scene_scale_1e3": 1e3}.get(case, 1.0)
            far = 1e5 if case == "far_1e5" else p["far_plane"] * scale
            near = far if case == "near_eq_far" else p["near_plane"] * scale
            b = NearFarCollider(near_plane=near, far_plane=far)(bundle)
            return Run(
                {"nears": b.nears, "fars": b.fars},
                {"nears": (rays, 1), "fars": (rays, 1)},
                {"nears": (0.0, None)},
            )
        if terminal == "hierarchical":
            coarse = rs.UniformSampler(num_samples=p["num_coarse_samples"])(bundle)
            weights = torch.rand(rays, p["num_coarse_samples"], 1).requires_grad_(True)
            samples = rs.PDFSampler(num_samples=p["num_importance_samples"])(bundle, coarse, weights)
            expected = (
                p["num_importance_samples"] + p["num_coarse_samples"] + 1
            )  # include_original: bin edges
            inputs = [weights]
        elif terminal == "proposal":
            from nerfstudio.data.scene_box import SceneBox

            aabb = torch.tensor(AABB)
            if p["network"] == "kplanes":
                from nerfify_ns.components.kplanes import KPlanesDensityField

                nets = [
                    KPlanesDensityField(aabb, resolution=r, num_components=4) for r in p["network_max_res"]
                ]
            else:
                from nerfstudio.fields.density_fields import HashMLPDensityField

                nets = [
                    HashMLPDensityField(
                        aabb,
                        num_levels=p["network_num_levels"],
                        max_res=r,
                        log2_hashmap_size=p["network_log2_hashmap_size"],
                        implementation="torch",
                    )
                    for r in p["network_max_res"]
                ]
            module = nn.ModuleList(nets)
            sampler = rs.ProposalNetworkSampler(
                num_proposal_samples_per_ray=tuple(p["samples_per_ray"]),
                num_nerf_samples_per_ray=p["nerf_samples"],
                num_proposal_network_iterations=len(p["samples_per_ray"]),
                single_jitter=p["single_jitter"],
                initial_sampler=rs.UniformSampler(single_jitter=p["single_jitter"])
                if p["initial_sampler"] == "uniform"
                else None,
            )
            samples, weights_list, _ = sampler(bundle, density_fns=[n.density_fn for n in nets])
            expected = p["nerf_samples"]
            out["weights_list"] = torch.cat([w.reshape(rays, -1) for w in weights_list], dim=-1)
            inputs = []
            del SceneBox
        else:  # occupancy_grid
            import nerfacc

            grid = nerfacc.OccGridEstimator(
                roi_aabb=torch.tensor(AABB).flatten(),
                resolution=p["grid_resolution"],
                levels=p["grid_levels"],
            )
            module = nn.Linear(3, 1)
            sampler = rs.VolumetricSampler(
                occupancy_grid=grid, density_fn=lambda x: torch.nn.functional.softplus(module(x))
            )
            if case == "empty_batch":
                raise NotApplicable("nerfacc's marcher takes at least one ray")
            samples, ray_indices = sampler(
                bundle,
                render_step_size=0.05,
                near_plane=float(bundle.nears.min()),
                far_plane=float(bundle.fars.max()),
                alpha_thre=p["alpha_thre"],
                cone_angle=p["cone_angle"],
            )
            m = samples.frustums.starts.shape[0]
            starts, ends = samples.frustums.starts, samples.frustums.ends
            return Run(
                {"ray_samples": torch.cat([starts, ends], -1), "ray_indices": ray_indices.float()},
                {"ray_samples": (m, 2), "ray_indices": (m,)},
                module=None,
            )
        starts, ends = samples.frustums.starts, samples.frustums.ends
        out["ray_samples"] = torch.cat([starts, ends], -1)
        out["positions"] = samples.frustums.get_positions()
        shapes = {"ray_samples": (rays, expected, 2), "positions": (rays, expected, 3)}
        return Run(out, shapes, module=module, inputs=inputs)

    return run


def _photometric(terminal: str):
    def run(p: dict, case: str) -> Run:
        dt = _dtype(case)
        rays = 0 if case == "empty_batch" else R
        pred = _values(case, (rays, 3))
        target = torch.rand(rays, 3).to(dt)
        if terminal == "charbonnier":
            from nerfify_ns.components.losses import charbonnier_loss

            loss = charbonnier_loss(pred, target, eps=p["eps"])
        elif terminal == "l1":
            loss = nn.L1Loss()(pred, target)
        else:
            from nerfstudio.model_components.losses import MSELoss

            loss = MSELoss()(pred, target)
        return Run({"loss": loss}, {"loss": ()}, {"loss": (0.0, None)}, inputs=[pred], dtype=dt)

    return run


def _sampler_loss(terminal: str):
    def run(p: dict, case: str) -> Run:
        from nerfstudio.model_components import losses

        rs1, d1 = composite_samples(case, 8)
        rs2, d2 = composite_samples(case, 4)
        w1, w2 = rs1.get_weights(d1), rs2.get_weights(d2)
        if terminal == "interlevel":
            loss = p["weight"] * losses.interlevel_loss([w2, w1], [rs2, rs1])
        else:
            loss = p["weight"] * losses.distortion_loss([w1], [rs1]).mean()
        return Run({"loss": loss}, {"loss": ()}, {"loss": (0.0, None)}, inputs=[d1, d2])

    return run


def _regularizer(terminal: str):
    def run(p: dict, case: str) -> Run:
        from nerfify_ns.components import regularizers as reg

        dt = _dtype(case)
        if terminal in ("plane_tv", "time_smoothness", "plane_l1"):
            planes = (
                [] if case == "empty_batch" else [_values(case, (1, 4, 8, 8)), _values(case, (1, 4, 6, 8))]
            )
            fn = {
                "plane_tv": reg.plane_tv,
                "time_smoothness": reg.time_smoothness,
                "plane_l1": reg.plane_l1_to_one,
            }[terminal]
            loss, inputs = fn(planes), planes
        elif terminal == "ray_entropy":
            w = _values(case, (0 if case == "empty_batch" else R, 8, 1))
            loss, inputs = reg.ray_entropy(w, threshold=p["threshold"]), [w]
        else:
            d = _values(case, (0 if case == "empty_batch" else R, 8, 1), 0.0, 5.0)
            loss, inputs = reg.density_sparsity(d, scale=p["scale"]), [d]
        return Run(
            {"loss": p["weight"] * loss}, {"loss": ()}, {"loss": (0.0, None)}, inputs=list(inputs), dtype=dt
        )

    return run


def _camera(terminal: str):
    def run(p: dict, case: str) -> Run:
        from nerfstudio.cameras.camera_optimizers import CameraOptimizerConfig

        module = CameraOptimizerConfig(mode="SO3xR3" if terminal == "so3xr3" else "SE3").setup(
            num_cameras=4, device="cpu"
        )
        with torch.no_grad():
            module.pose_adjustment.normal_(0, 1e-2)
        bundle = ray_bundle(case)
        module.apply_to_raybundle(bundle)
        rays = bundle.origins.shape[0]
        return Run(
            {"origins": bundle.origins, "directions": bundle.directions},
            {"origins": (rays, 3), "directions": (rays, 3)},
            module=module,
        )

    return run


HARNESSES: Dict[str, Harness] = {}


def _add(names, make, cases) -> None:
    for name in names:
        HARNESSES[name] = Harness(
            name,
            make(name) if callable(make) and make.__code__.co_argcount == 1 else make,
            ("nominal", *cases),
        )


_add(
    [
        "positional",
        "integrated_positional",
        "hash",
        "kplanes",
        "kplanes_time",
        "triplane",
        "tensor_vm",
        "tensor_cp",
    ],
    _encoding,
    POINT_CASES,
)
_add(["sh", "frequency"], _encoding, ("zeros", "values_1e8", "empty_batch", "half"))
_add(["mlp", "rgb_mlp", "tensorial_appearance"], _mlp, ("values_1e8", "empty_batch", "half"))
_add(["density_linear", "density_split"], _density, DENSITY_CASES)
_add(["scene_contraction"], _contraction, POINT_CASES)
_add(["appearance_embedding"], _embedding, ("empty_batch",))
_add(["renderer"], _renderer, COMPOSITE_CASES)
_add(["near_far", "hierarchical", "proposal", "occupancy_grid"], _sampler, RAY_CASES)
_add(["l2", "l1", "charbonnier"], _photometric, VALUE_CASES)
_add(
    ["interlevel", "distortion"],
    _sampler_loss,
    (
        "density_0",
        "density_1e8",
        "step_zero",
        "step_huge",
        "near_eq_far",
        "far_1e5",
        "density_1e8_step_huge",
        "empty_batch",
    ),
)
_add(
    ["plane_tv", "time_smoothness", "plane_l1", "ray_entropy", "density_sparsity"], _regularizer, VALUE_CASES
)
_add(["so3xr3", "se3"], _camera, ("empty_batch", "far_1e5"))


def _kplanes_density(p: dict, case: str) -> Run:
    from nerfify_ns.components.kplanes import KPlanesDensityField

    module = KPlanesDensityField(torch.tensor(AABB), resolution=8, num_components=4)
    offset = {"density_raw_0": 0.0, "density_raw_1e8": 1e8, "density_raw_-1e8": -1e8}.get(case)
    if offset is not None:
        module.linear.register_forward_hook(lambda m, i, o: o * 0 + offset)
    x = _points(case, "raw")
    density = module.density_fn(x.float() if case == "half" else x)
    return Run(
        {"density": density}, {"density": (_n(case), 1)}, {"density": (0.0, None)}, module=module, inputs=[x]
    )


HARNESSES["KPlanesDensityField"] = Harness(
    "KPlanesDensityField",
    _kplanes_density,
    (
        "nominal",
        "density_raw_0",
        "density_raw_1e8",
        "density_raw_-1e8",
        "empty_batch",
        "points_outside_contraction",
        "scene_scale_1e3",
    ),
)
OURS_EXTRA = {"KPlanesDensityField": "nerfify_ns.components.kplanes.KPlanesDensityField"}
"""Components of ours that fill a terminal indirectly (a proposal network of k-planes)."""

MODEL_LEVEL = {"tensor_l1", "tensor_tv", "nerfacto", "vanilla-nerf", "mipnerf", "instant-ngp", "tensorf"}
"""Terminals implemented inside a Nerfstudio model: checked through the assembled model."""


def finite_problem(name: str, value: Tensor) -> Optional[str]:
    if value.is_floating_point() and value.numel() and not torch.isfinite(value).all():
        bad = (~torch.isfinite(value)).sum().item()
        return f"{name}: {bad} of {value.numel()} values not finite"
    return None


def check_run(run: Run, grads_required: bool) -> List[str]:
    """Problems of one run: shapes, dtype, device, bounds, finiteness, then gradients after backward."""
    problems: List[str] = []
    for key, value in run.outputs.items():
        if not isinstance(value, Tensor):
            problems.append(f"{key}: not a tensor ({type(value).__name__})")
            continue
        shape = run.shapes.get(key)
        if shape is not None and tuple(value.shape) != tuple(shape):
            problems.append(f"{key}: shape {tuple(value.shape)}, contract says {tuple(shape)}")
        if value.device.type != "cpu":
            problems.append(f"{key}: on {value.device}, inputs on cpu")
        if (
            value.is_floating_point()
            and run.dtype == torch.float32
            and value.dtype not in (torch.float32, torch.float64)
        ):
            problems.append(f"{key}: dtype {value.dtype} from float32 inputs")
        problems += [p for p in [finite_problem(key, value)] if p]
        low, high = run.bounds.get(key, (None, None))
        finite = value[torch.isfinite(value)] if value.is_floating_point() else value
        if finite.numel() and low is not None and float(finite.min()) < low - 1e-4:
            problems.append(f"{key}: min {float(finite.min()):.3g} below {low}")
        if finite.numel() and high is not None and float(finite.max()) > high + 1e-4:
            problems.append(f"{key}: max {float(finite.max()):.3g} above {high}")
    tensors = [v for v in run.outputs.values() if isinstance(v, Tensor) and v.requires_grad]
    if not tensors:
        return problems
    total = sum(torch.where(torch.isfinite(v), v, torch.zeros_like(v)).float().sum() for v in tensors)
    try:
        total.backward()
    except RuntimeError as exc:
        return problems + [f"backward failed: {str(exc).splitlines()[0]}"]
    params = [
        (n, p)
        for n, p in (run.module.named_parameters() if run.module is not None else [])
        if p.requires_grad
    ]
    for name, param in params:
        if param.grad is None:
            if grads_required:
                problems.append(f"parameter {name} receives no gradient")
        elif not torch.isfinite(param.grad).all():
            problems.append(f"gradient of parameter {name} not finite")
    for i, x in enumerate(run.inputs):
        if x.grad is not None and not torch.isfinite(x.grad).all():
            problems.append(f"gradient of input {i} not finite")
    return problems


def terminal_params(grammar, terminal: str, plan_params: Optional[dict]) -> dict:
    if terminal not in grammar.terminals:
        return dict(plan_params or {})
    params = grammar.terminals[terminal].defaults()
    params.update(plan_params or {})
    return small(terminal, params)


def is_finite_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)
