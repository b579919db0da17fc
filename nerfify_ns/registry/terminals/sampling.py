"""Samplers, the renderer, near/far bounds and camera optimisers."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from nerfify_ns.registry.contract import Contract, T
from nerfify_ns.registry.examples import AABB, COMPOSITE_CASES, RAY_CASES, SCALES, NotApplicable
from nerfify_ns.registry.params import param
from nerfify_ns.registry.terminal import Code, Constraint, Harness, TerminalDef

SMALL = {"num_coarse_samples": 8, "num_importance_samples": 8, "nerf_samples": 8, "grid_resolution": 16,
         "grid_levels": 1, "network_max_res": 32, "network_num_levels": 2, "network_log2_hashmap_size": 10,
         "samples_per_ray": 8}
RAYS = {"ray_bundle": T("[R]", "rays", role="rays", doc="rays with near and far bounds")}


@dataclass
class Hierarchical:
    num_coarse_samples: int = param(64, range=(1, 4096))
    """Stratified samples per ray of the coarse pass, N_c (NeRF: 64)."""
    num_importance_samples: int = param(128, range=(1, 4096))
    """Samples per ray drawn from the coarse weights, N_f (NeRF: 128)."""
    coarse_loss_weight: float = param(1.0, range=(0.0, 100.0))
    """Weight of the coarse pass's photometric loss."""


@dataclass
class Proposal:
    samples_per_ray: list[int] = param([256, 96], range=(1, 4096), length=(1, 4))
    """Samples of each proposal round."""
    nerf_samples: int = param(48, range=(1, 4096))
    """Samples per ray of the NeRF field."""
    network: Literal["hash", "kplanes"] = param("hash")
    """The proposal density fields: small hash grids (Nerfacto) or k-planes."""
    network_max_res: list[int] = param([128, 256], range=(8, 4096), length=(1, 4))
    """Finest resolution of each proposal network."""
    network_num_levels: int = param(5, range=(1, 16))
    """Levels of each proposal hash grid."""
    network_log2_hashmap_size: int = param(17, range=(8, 24))
    """log2 of each proposal hash table size."""
    network_hidden_dim: int = param(16, range=(4, 256))
    """Hidden width of each proposal MLP."""
    update_every: int = param(5, range=(1, 1000))
    """Iterations between proposal updates after the warm-up."""
    warmup: int = param(5000, range=(1, 1000000))
    """Iterations over which proposal updates become less frequent."""
    use_same_network: bool = param(False)
    """One proposal network for every round."""
    single_jitter: bool = param(True)
    """One jitter per ray rather than per sample."""
    initial_sampler: Literal["piecewise", "uniform"] = param("piecewise")
    """The first round's sampler."""
    weight_anneal: bool = param(True)
    """Anneal the proposal weights early in training."""


@dataclass
class OccupancyGrid:
    grid_resolution: int = param(128, range=(8, 512))
    """Resolution of the occupancy grid."""
    grid_levels: int = param(4, range=(1, 8))
    """Cascaded grid levels for unbounded scenes."""
    alpha_thre: float = param(0.01, range=(0.0, 1.0))
    """Opacity below which samples are skipped."""
    cone_angle: float = param(0.004, range=(0.0, 1.0))
    """Step size grows with distance by this factor (0: uniform steps)."""
    render_steps: int = param(1000, range=(8, 100000))
    """Marching steps across the scene box's diagonal: the base step is the diagonal over this count (Nerfstudio's
    Instant-NGP: 1000)."""


@dataclass
class Renderer:
    background: Literal["white", "black", "random", "last_sample"] = param("white")
    """Colour behind the scene."""


@dataclass
class NearFar:
    near_plane: float = param(0.05, range=(0.0, 1.0e6))
    """Distance of the near plane."""
    far_plane: float = param(1000.0, range=(1.0e-6, 1.0e9))
    """Distance of the far plane."""


def _samples_out(samples, rays: int, expected: int):
    import torch

    return torch.cat([samples.frustums.starts, samples.frustums.ends], -1), samples.frustums.get_positions()


def _call_hierarchical(module, inputs, env):
    import torch
    from nerfstudio.model_components import ray_samplers as rs

    bundle = inputs["ray_bundle"]
    rays = bundle.origins.shape[0]
    coarse = rs.UniformSampler(num_samples=env["num_coarse_samples"])(bundle)
    weights = torch.rand(rays, env["num_coarse_samples"], 1).requires_grad_(True)
    samples = rs.PDFSampler(num_samples=env["num_importance_samples"])(bundle, coarse, weights)
    edges, positions = _samples_out(samples, rays, 0)
    return {"ray_samples": edges, "positions": positions}


def proposal_resolutions(p) -> list[int]:
    """The finest resolution of each proposal network, as Nerfacto builds them: one network per round (one
    in all with ``use_same_network``), network i taking ``network_max_res[min(i, len - 1)]``."""
    res = list(p["network_max_res"])
    networks = 1 if p["use_same_network"] else len(p["samples_per_ray"])
    return [res[min(i, len(res) - 1)] for i in range(networks)]


PROPOSAL_ROUNDS = Constraint(
    "network_max_res gives at most one resolution per proposal network (one network per round of "
    "samples_per_ray, one in all with use_same_network); a resolution for no network is never used",
    lambda p, plan: len(p["network_max_res"]) <= len(proposal_resolutions(p)))


def _proposal_networks(p):
    import torch
    from torch import nn

    aabb = torch.tensor(AABB)
    if p["network"] == "kplanes":
        from nerfify_ns.components.kplanes import KPlanesDensityField

        return nn.ModuleList([KPlanesDensityField(aabb, resolution=r, num_components=4)
                              for r in proposal_resolutions(p)])
    from nerfstudio.fields.density_fields import HashMLPDensityField

    return nn.ModuleList([HashMLPDensityField(aabb, num_levels=p["network_num_levels"], max_res=r,
                                              log2_hashmap_size=p["network_log2_hashmap_size"],
                                              implementation="torch") for r in proposal_resolutions(p)])


def _call_proposal(nets, inputs, env):
    import torch
    from nerfstudio.model_components import ray_samplers as rs

    bundle = inputs["ray_bundle"]
    rays = bundle.origins.shape[0]
    initial = rs.UniformSampler(single_jitter=env["single_jitter"]) if env["initial_sampler"] == "uniform" else None
    sampler = rs.ProposalNetworkSampler(num_proposal_samples_per_ray=tuple(env["samples_per_ray"]),
                                        num_nerf_samples_per_ray=env["nerf_samples"],
                                        num_proposal_network_iterations=len(env["samples_per_ray"]),
                                        single_jitter=env["single_jitter"], initial_sampler=initial)
    rounds = len(env["samples_per_ray"])
    density_fns = [nets[min(i, len(nets) - 1)].density_fn for i in range(rounds)]
    samples, weights_list, _ = sampler(bundle, density_fns=density_fns)
    edges, positions = _samples_out(samples, rays, 0)
    return {"ray_samples": edges, "positions": positions,
            "weights_list": torch.cat([w.reshape(rays, -1) for w in weights_list], dim=-1)}


def _call_occupancy(module, inputs, env):
    import nerfacc
    import torch
    from nerfstudio.model_components import ray_samplers as rs

    if env.get("case") == "empty_batch":
        raise NotApplicable("nerfacc's marcher takes at least one ray")
    bundle = inputs["ray_bundle"]
    grid = nerfacc.OccGridEstimator(roi_aabb=torch.tensor(AABB).flatten(), resolution=env["grid_resolution"],
                                    levels=env["grid_levels"])
    sampler = rs.VolumetricSampler(occupancy_grid=grid,
                                   density_fn=lambda x: torch.nn.functional.softplus(module(x)))
    samples, ray_indices = sampler(bundle, render_step_size=0.05, near_plane=float(bundle.nears.min()),
                                   far_plane=float(bundle.fars.max()), alpha_thre=env["alpha_thre"],
                                   cone_angle=env["cone_angle"])
    return {"ray_samples": torch.cat([samples.frustums.starts, samples.frustums.ends], -1),
            "ray_indices": ray_indices}


def _build_linear_density(p, env):
    from torch import nn

    return nn.Linear(3, 1)


def _call_renderer(module, inputs, env):
    from nerfstudio.model_components.renderers import AccumulationRenderer, DepthRenderer, RGBRenderer

    ray_samples, densities = inputs["ray_samples"]
    dtype = inputs["rgb"].dtype
    weights = ray_samples.get_weights(densities.to(dtype) if env.get("case") == "half" else densities)
    background = env["background"] if env["background"] != "random" else "white"
    inputs["densities"] = densities
    return {"rgb": RGBRenderer(background_color=background)(rgb=inputs["rgb"], weights=weights),
            "accumulation": AccumulationRenderer()(weights=weights),
            "depth": DepthRenderer(method="median")(weights=weights, ray_samples=ray_samples),
            "expected_depth": DepthRenderer(method="expected")(weights=weights, ray_samples=ray_samples)}


def _call_near_far(module, inputs, env):
    from nerfstudio.model_components.scene_colliders import NearFarCollider

    bundle = inputs["ray_bundle"]
    bundle.nears = bundle.fars = None
    scale = SCALES.get(env.get("case", ""), 1.0)
    far = 1e5 if env.get("case") == "far_1e5" else env["far_plane"] * scale
    near = far if env.get("case") == "near_eq_far" else env["near_plane"] * scale
    bounded = NearFarCollider(near_plane=near, far_plane=far)(bundle)
    return {"nears": bounded.nears, "fars": bounded.fars}


def _camera_builder(mode: str):
    def build(p, env):
        import torch
        from nerfstudio.cameras.camera_optimizers import CameraOptimizerConfig

        module = CameraOptimizerConfig(mode=mode).setup(num_cameras=int(env["cameras"]), device="cpu")
        with torch.no_grad():
            module.pose_adjustment.normal_(0, 1e-2)
        return module

    return build


def _call_camera(module, inputs, env):
    bundle = inputs["ray_bundle"]
    module.apply_to_raybundle(bundle)
    return {"origins": bundle.origins, "directions": bundle.directions}


SAMPLE_EDGES = "starts and ends of each sample along its ray"
PACKED_BACKGROUND = Constraint(
    "a 'last_sample' background needs samples padded per ray; instant-ngp's packed samples have no last one",
    lambda p, plan: not (p["background"] == "last_sample" and plan.get("base") == "instant-ngp"))
"""Nerfstudio's RGBRenderer raises NotImplementedError for 'last_sample' with packed samples."""
NEAR_BEFORE_FAR = Constraint("the near plane lies before the far plane: near_plane < far_plane",
                             lambda p, plan: p["near_plane"] < p["far_plane"])
"""Otherwise every ray is empty: no sample, no colour, and a field given zero samples (found by the fuzzer)."""

TERMINALS = [
    TerminalDef(
        "hierarchical", "Sampler", Hierarchical,
        "Stratified coarse samples, then importance samples from the coarse weights (NeRF Sec. 5.2).",
        "nerfstudio.model_components.ray_samplers.PDFSampler", card="hierarchical_sampling",
        contract=Contract(RAYS, {
            "ray_samples": T("[R, num_importance_samples + num_coarse_samples + 1, 2]", doc=SAMPLE_EDGES),
            "positions": T("[R, num_importance_samples + num_coarse_samples + 1, 3]", doc="sample positions")}),
        harness=Harness(build=lambda p, env: None, call=_call_hierarchical, cases=RAY_CASES, small=SMALL),
        config={"vanilla-nerf": {"num_coarse_samples": "num_coarse_samples",
                                 "num_importance_samples": "num_importance_samples"},
                "mipnerf": {"num_coarse_samples": "num_coarse_samples",
                            "num_importance_samples": "num_importance_samples"},
                "tensorf": {"num_coarse_samples": "num_uniform_samples", "num_importance_samples": "num_samples"}},
        duties=({"requires_base": ["vanilla-nerf", "mipnerf", "tensorf"]},)),
    TerminalDef(
        "proposal", "Sampler", Proposal, "Proposal networks distilled from the NeRF weights (Mip-NeRF 360 Sec. 3).",
        "nerfstudio.model_components.ray_samplers.ProposalNetworkSampler", card="proposal_networks",
        param_groups=("proposal_networks",),
        contract=Contract(RAYS, {
            "ray_samples": T("[R, nerf_samples, 2]", doc=SAMPLE_EDGES),
            "positions": T("[R, nerf_samples, 3]", doc="sample positions"),
            "weights_list": T("[R, sum(samples_per_ray)]", range=(0.0, 1.0 + 1e-3),
                              doc="proposal weights of every round")}),
        harness=Harness(build=lambda p, env: _proposal_networks(p), call=_call_proposal, cases=RAY_CASES,
                        small=SMALL),
        config={"nerfacto": {"samples_per_ray": "num_proposal_samples_per_ray",
                             "nerf_samples": "num_nerf_samples_per_ray", "update_every": "proposal_update_every",
                             "warmup": "proposal_warmup", "use_same_network": "use_same_proposal_network",
                             "single_jitter": "use_single_jitter", "initial_sampler": "proposal_initial_sampler",
                             "weight_anneal": "use_proposal_weight_anneal"}},
        duties=({"requires_base": ["nerfacto"]}, {"requires_loss": "interlevel"}),
        constraints=(PROPOSAL_ROUNDS,)),
    TerminalDef(
        "occupancy_grid", "Sampler", OccupancyGrid,
        "Occupancy grid skipping empty space, marched with nerfacc (Instant-NGP Sec. 5.1).",
        "nerfstudio.model_components.ray_samplers.VolumetricSampler", card="occupancy_grid",
        contract=Contract(RAYS, {"ray_samples": T("[M, 2]", doc=SAMPLE_EDGES + " (packed)"),
                                 "ray_indices": T("[M]", "long", doc="the ray of each sample")}, free=("M",)),
        harness=Harness(build=_build_linear_density, call=_call_occupancy, cases=RAY_CASES, small=SMALL),
        config={"instant-ngp": {"grid_resolution": "grid_resolution", "grid_levels": "grid_levels",
                                "alpha_thre": "alpha_thre", "cone_angle": "cone_angle"}},
        # the grid's pruning threshold: an anneal of it makes the model's grid take it from an attribute
        # (`schedule_wrap`: what the generated model installs then, components.occupancy_threshold)
        code=Code(traits={"schedulable": ["occupancy_grid.threshold"], "schedule_wrap": {
            "imports": ["from .components.occupancy_threshold import scheduled_threshold"],
            "component": "occupancy_threshold", "attr": "occupancy_grid",
            "ctor": "scheduled_threshold(self.occupancy_grid)"},
            # the marching step from the plan's count (a field of the generated config, so a CPU proxy may march
            # coarser without editing the code), set before the base builds its model as the base sets its own
            "config_fields": [{"name": "render_steps_per_diagonal", "param": "render_steps",
                               "doc": "Marching steps across the scene box's diagonal when render_step_size is "
                                      "None (the plan's value; a CPU proxy may march coarser)."}],
            "before_base": [
                "if self.config.render_step_size is None:  # the box's diagonal over the plan's marching steps",
                "    aabb = self.scene_box.aabb.flatten()",
                "    diagonal = ((aabb[3:] - aabb[:3]) ** 2).sum().sqrt().item()",
                "    self.config.render_step_size = diagonal / self.config.render_steps_per_diagonal"]}),
        duties=({"requires_base": ["instant-ngp"]},)),
    TerminalDef(
        "renderer", "Renderer", Renderer,
        "Volume rendering of colour, depth and accumulation (NeRF Eq. 3) over a background.",
        "nerfstudio.model_components.renderers.RGBRenderer", card="background_model",
        contract=Contract(
            {"ray_samples": T("[R, S]", "samples", role="samples", doc="samples with step sizes and densities"),
             "rgb": T("[R, S, 3]", range=(0.0, 1.0), grad=True, doc="colour of every sample")},
            {"rgb": T("[R, 3]", range=(0.0, 1.0), doc="pixel colour C(r)"),
             "accumulation": T("[R, 1]", range=(0.0, 1.0 + 1e-3), doc="opacity of the ray"),
             "depth": T("[R, 1]", doc="median depth"), "expected_depth": T("[R, 1]", doc="expected depth")}),
        harness=Harness(build=lambda p, env: None, call=_call_renderer, cases=COMPOSITE_CASES),
        constraints=(PACKED_BACKGROUND,)),
    TerminalDef(
        "near_far", "Model", NearFar, "Near and far planes of every ray (NearFarCollider).",
        "nerfstudio.model_components.scene_colliders.NearFarCollider", card="background_model",
        contract=Contract(RAYS, {"nears": T("[R, 1]", range=(0.0, None)), "fars": T("[R, 1]")}),
        harness=Harness(build=lambda p, env: None, call=_call_near_far, cases=RAY_CASES),
        config={"nerfacto": {"near_plane": "near_plane", "far_plane": "far_plane"},
                "instant-ngp": {"near_plane": "near_plane", "far_plane": "far_plane"}},
        duties=({"requires_base": ["nerfacto", "instant-ngp"]},), constraints=(NEAR_BEFORE_FAR,)),
    TerminalDef(
        "so3xr3", "CameraOptimizer", None,
        "Camera pose refinement, rotation on SO(3) and translation in R^3 (Nerfacto).",
        "nerfstudio.cameras.camera_optimizers.CameraOptimizer", card="camera_optimizer", param_groups=("camera_opt",),
        contract=Contract(RAYS, {"origins": T("[R, 3]"), "directions": T("[R, 3]")}),
        code=Code(traits={"mode": "SO3xR3"}),
        harness=Harness(build=_camera_builder("SO3xR3"), call=_call_camera, cases=("empty_batch", "far_1e5")),
        duties=({"requires_base": ["nerfacto", "tensorf"]},)),
    TerminalDef(
        "se3", "CameraOptimizer", None, "Camera pose refinement on SE(3) (BARF-style).",
        "nerfstudio.cameras.camera_optimizers.CameraOptimizer", card="camera_optimizer", param_groups=("camera_opt",),
        contract=Contract(RAYS, {"origins": T("[R, 3]"), "directions": T("[R, 3]")}),
        code=Code(traits={"mode": "SE3"}),
        harness=Harness(build=_camera_builder("SE3"), call=_call_camera, cases=("empty_batch", "far_1e5")),
        duties=({"requires_base": ["nerfacto", "tensorf"]},)),
]
