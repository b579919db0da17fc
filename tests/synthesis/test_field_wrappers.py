"""Where recent papers' contributions land: the FieldWrapper, PixelSampler and ScheduleHook productions and the
typed backbone options. Each production is a slot a hole can point at (its `custom` alternative validates at the
hole's slot); components written by hand for each (a deformation MLP, a density blend, a probability-map pixel
sampler, an annealing hook) compose, meet their interface's contract, and a broken one fails it naming the
tensor; the typed options (deformation, time embedding, frame codes, per-camera time offsets, a blend by density
or by a mixer, inputs at every layer, separate density and colour branches, gradient importance, view selection,
anneal, freeze, image curriculum) compose and their models train a few steps; the full ladder (static, contract,
stability, smoke) passes on a dynamic scene (slow)."""

from __future__ import annotations

import importlib
import math
import re
import sys
from pathlib import Path

import pytest

from nerfify_ns.grammar import check, load_grammar, validate
from nerfify_ns.plan import Plan
from nerfify_ns.registry import default_registry
from nerfify_ns.synthesis.compose import compose
from nerfify_ns.synthesis.resources import load_reference_plan

DEFORM = '''"""A deformation MLP into a canonical space, written by hand for the field-wrapper test."""

import torch
from torch import nn


class TinyDeformation(nn.Module):
    """x' = x + s * MLP([x, t]): the FieldWrapper conditioner interface; ``warp_scale`` s is annealed by a hook.
    ``position_width`` other than 3 (positions padded with zeros) breaks the interface on purpose."""

    def __init__(self, num_images: int, width: int = 16, position_width: int = 3) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(4, width), nn.ReLU(), nn.Linear(width, position_width))
        self.position_width = position_width
        self.warp_scale = 1.0

    def get_out_dim(self) -> int:
        return 0

    def forward(self, positions, times, camera_indices):
        x = torch.cat([positions, times.to(positions)], dim=-1)
        base = nn.functional.pad(positions, (0, self.position_width - 3))
        moved = base + self.warp_scale * self.net.to(positions.dtype)(x)
        return moved, times, positions.new_zeros(positions.shape[0], 0)
'''

BLEND = '''"""Two fields blended by density, written by hand for the field-wrapper test."""

import torch
from torch import nn


class DensityBlend(nn.Module):
    """sigma = sum_k sigma_k, c = sum_k sigma_k c_k / sigma: a blend of K fields (wrapper: blend)."""

    def __init__(self, num_images: int, num_fields: int = 2) -> None:
        super().__init__()
        self.num_fields = num_fields

    def forward(self, densities, rgbs, positions, times):
        total = densities.sum(dim=-2)
        rgb = (densities * rgbs).sum(dim=-2) / total.clamp_min(1e-6)
        return total, rgb.clamp(0.0, 1.0)
'''

PIXMAP = '''"""A per-image probability map, written by hand for the pixel-sampler test."""

import torch
from torch import nn


class CentreWeighted(nn.Module):
    """p ~ exp(-r^2 / (2 spread^2)), r the pixel's distance to the image centre in [-1, 1] coordinates."""

    def __init__(self, spread: float = 0.5) -> None:
        super().__init__()
        self.spread = spread

    def forward(self, images, image_indices):
        n, h, w = images.shape[:3]
        ys = torch.linspace(-1.0, 1.0, h).view(h, 1)
        xs = torch.linspace(-1.0, 1.0, w).view(1, w)
        weights = torch.exp(-(ys * ys + xs * xs) / (2 * self.spread ** 2))
        return weights.expand(n, h, w).clone()
'''

HOOK = '''"""An annealing hook, written by hand for the schedule-hook test."""

import torch

from .schedule_hooks import ScheduleHook


class WarpWarmUp(ScheduleHook):
    """The deformation fades in: warp_scale = min(step / end_step, 1) on every part with a ``warp_scale``."""

    def __init__(self, end_step: int = 10) -> None:
        super().__init__()
        self.end_step = end_step

    def forward(self, steps):
        return (steps.float() / self.end_step).clamp(0.0, 1.0)

    def check(self, model) -> None:
        if not any(hasattr(m, "warp_scale") for m in model.modules()):
            raise ValueError("WarpWarmUp: no part of the model has a warp_scale")

    def write(self, value, model, datamanager) -> None:
        for module in model.modules():
            if hasattr(module, "warp_scale"):
                module.warp_scale = float(value)
'''

SOURCES = {"components.tiny_deformation": DEFORM, "components.density_blend": BLEND,
           "components.centre_map": PIXMAP, "components.warp_warm_up": HOOK}


def custom(module: str, cls: str, params: dict, **extra) -> dict:
    return {"module": module, "class": cls, "params": params, "implements": ["Sec. 3"], "source": "hand",
            "evidence": "written by hand for the test", **extra}


def small(plan: Plan, name: str) -> Plan:
    """A vanilla-NeRF plan on a dynamic scene, sized to train in seconds."""
    plan["method"] = name
    plan.set("scene.timestamps", True)
    plan.set("scene.format", "dnerf")
    plan.set("datamanager.dataparser", "dnerf")
    plan.set("datamanager.train_num_rays_per_batch", 64)
    plan.set("model.field.MLPField.pos_encoding", {"positional": {"num_frequencies": 4, "max_freq_exp": 3.0}})
    plan.set("model.field.MLPField.backbone", {"num_layers": 3, "layer_width": 32, "skip_connections": [1]})
    plan.set("model.field.MLPField.rgb_head", {"num_layers": 1, "layer_width": 16})
    plan.set("model.sampler.hierarchical", {"num_coarse_samples": 8, "num_importance_samples": 8})
    plan.set("optimizers.fields", {"optimizer": {"adam": {"lr": 0.005, "eps": 1.0e-15}}})
    return plan


def hand_plan(channels: int = 3) -> Plan:
    """The four hand-written components at the new productions' slots."""
    plan = small(Plan.of(load_reference_plan("vanilla-nerf")), "hand-wrapped")
    plan.set("model.field_wrappers", {
        "custom": custom("components.tiny_deformation", "TinyDeformation", {"width": 16, "position_width": channels}),
        "custom_blend": custom("components.density_blend", "DensityBlend", {"num_fields": 2}, wrapper="blend")})
    plan.set("pixel_sampler", {"custom": custom("components.centre_map", "CentreWeighted", {"spread": 0.6})})
    plan.set("model.schedule_hooks", {"custom": custom("components.warp_warm_up", "WarpWarmUp", {"end_step": 10})})
    return plan


def options_plan() -> Plan:
    """Every typed option of the new productions and of the backbone, at small sizes."""
    plan = small(Plan.of(load_reference_plan("vanilla-nerf")), "typed-options")
    plan.set("model.field.MLPField.backbone", {"num_layers": 4, "layer_width": 32, "skip_every_layer": True,
                                                "branches": True, "density_layers": 1, "density_width": 16,
                                                "color_layers": 2, "color_width": 24})
    plan.set("model.field_wrappers", {
        "camera_time_offset": {"init": 0.01},
        "deformation": {"num_layers": 2, "layer_width": 32, "position_frequencies": 4, "time_frequencies": 2},
        "frame_codes": {"num_frames": 8, "dim": 4},
        "time_embedding": {"num_frequencies": 2, "layer_width": 16, "num_layers": 1, "out_dim": 4},
        "field_blend": {"num_fields": 2, "mode": "mixer", "mixer_width": 16, "mixer_layers": 1}})
    plan.set("pixel_sampler", {"gradient_importance": {"uniform_fraction": 0.3}})
    plan.set("model.schedule_hooks", {
        "anneal": {"target": "deformation.window", "start_value": 0.0, "end_value": 4.0, "end_step": 20},
        "freeze": {"module": "frame_codes", "start_step": 0, "end_step": 5},
        "image_curriculum": {"rule": "keyframes", "keyframe_stride": 3, "end_step": 10}})
    return plan


# ------------------------------------------------------------------------------------------ the grammar
@pytest.mark.parametrize("production", ["FieldWrapper", "PixelSampler", "ScheduleHook"])
def test_each_new_production_is_a_slot_a_hole_can_point_at(production):
    """The grammar derives the production at one slot; a `custom` entry there (as the hole filler places it)
    validates and is filed under the production, whose interface has a contract."""
    g = load_grammar()
    slots = [p for p, s in g.symbol_paths() if s == production]
    assert len(slots) == 1, slots
    slot = slots[0]
    interface = default_registry().interfaces[production]
    assert interface.contract.inputs and interface.contract.outputs
    plan = small(Plan.of(load_reference_plan("vanilla-nerf")), "hole-slot")
    plan.set(slot, {"custom": custom("components.novel_part", "NovelPart", {})})
    derivation = validate(plan)
    assert derivation.used[f"{slot}.custom"] == "custom"
    assert g.production_at(f"{slot}.custom") == production


def test_time_wrappers_need_timestamps_and_a_neural_field():
    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    plan.set("model.field_wrappers", {"deformation": {}})
    assert "requires_scene" in {v.rule for v in check(plan)}
    tensorial = Plan.of(load_reference_plan("tensorf"))
    tensorial.set("model.field_wrappers", {"custom": custom("components.novel_part", "NovelPart", {})})
    assert "requires_terminal" in {v.rule for v in check(tensorial)}


def test_a_time_offset_needs_a_part_that_reads_the_times():
    """A per-camera time offset only shifts the samples' times: on a field that reads none (static planes, no time
    wrapper) its offsets would get no gradient (the grammar fuzzer's plan); with space-time planes or a
    deformation that reads them it is valid."""
    plan = small(Plan.of(load_reference_plan("vanilla-nerf")), "offset-unread")
    plan.set("scene.timestamps", True)
    plan.set("model.field_wrappers", {"camera_time_offset": {}})
    violations = check(plan)
    assert [v.rule for v in violations] == ["param_constraint"]
    assert "needs a part that reads them" in violations[0].message
    plan.set("model.field_wrappers", {"deformation": {}, "camera_time_offset": {}})
    assert check(plan) == []
    timed = Plan.of(load_reference_plan("kplanes-time"))
    timed.set("model.field_wrappers", {"camera_time_offset": {}})
    assert check(timed) == []


def test_a_hook_must_write_a_part_the_plan_has():
    plan = small(Plan.of(load_reference_plan("vanilla-nerf")), "hook-target")
    plan.set("model.schedule_hooks", {"anneal": {"target": "deformation.window"}})
    assert [v.rule for v in check(plan)] == ["param_constraint"]
    plan.set("model.field_wrappers", {"deformation": {}})
    assert check(plan) == []


# ------------------------------------------------------------------------------------------ composition
def _generated(plugin, name: str) -> str:
    return (plugin.out / plugin.package / name).read_text()


def _flat(code: str) -> str:
    """Generated code on one line, as written before formatting (no breaks inside calls)."""
    return re.sub(r",\s*\)", ")", re.sub(r"\(\s+", "(", " ".join(code.split())))


def test_hand_written_components_compose_at_the_new_slots(tmp_path):
    plugin = compose(hand_plan(), tmp_path / "plugin", sources=SOURCES, record=False)
    field = _generated(plugin, "field.py")
    assert '"custom": TinyDeformation(num_images=num_images, width=16, position_width=3)' in _flat(field)
    assert "class HandWrappedField(BlendedField)" in field
    assert "DensityBlend(num_images=num_images, num_fields=2)" in _flat(field)
    assert "in_dim=self.position_encoding.get_out_dim() + self.wrapper_dim" in field
    model = _flat(_generated(plugin, "model.py"))
    assert "WarpWarmUp(end_step=10)" in model and "training_callbacks(self.schedule_hooks" in model
    sampler = _generated(plugin, "pixel_sampler.py")
    assert "return CentreWeighted(spread=0.6)" in sampler
    config = _generated(plugin, "config.py")
    assert "pixel_sampler=HandWrappedPixelSamplerConfig()" in config and "VanillaDataManagerConfig(" in config
    for module in ("schedule_hooks", "pixel_samplers", "field_wrappers", *[m.split(".")[1] for m in SOURCES]):
        assert (plugin.out / plugin.package / "components" / f"{module}.py").is_file(), module


def test_typed_options_compose(tmp_path):
    plugin = compose(options_plan(), tmp_path / "plugin", record=False)
    field = _flat(_generated(plugin, "field.py"))
    assert "skip_connections=(1, 2)" in field and "BranchedMLP(" in field and "color_width=24" in field
    for ctor in ("CameraTimeOffset(num_images=num_images, init=0.01)",
                 "DeformationNetwork(num_layers=2, layer_width=deformation_layer_width",
                 "FrameCodes(num_frames=8, dim=frame_codes_dim)", "TimeEmbedding(num_frequencies=2",
                 'FieldBlend(num_fields=2, mode="mixer"'):
        assert ctor in field, ctor
    assert "conditioned=k > 0" in field  # the blend's first field is static
    model = _flat(_generated(plugin, "model.py"))
    assert 'Anneal(target="deformation.window"' in model and 'Freeze(module="frame_codes"' in model
    assert "GradientImportance(uniform_fraction=0.3)" in _generated(plugin, "pixel_sampler.py")


# ------------------------------------------------------------------------------------------ in-process checks
@pytest.fixture()
def plugin_on_path(tmp_path):
    """Compose a plan and import its package (as the sandboxed probe does); removed again afterwards."""
    from nerfify_ns.runtime import activate

    activate(force=True)
    imported = []

    def load(plan, sources=None):
        plugin = compose(plan, tmp_path / plan["method"], sources=sources or {}, record=False)
        sys.path.insert(0, str(plugin.out))
        imported.append((str(plugin.out), plugin.package))
        return plugin, importlib.import_module(f"{plugin.package}.config")

    yield load
    for path, package in imported:
        sys.path.remove(path)
        for name in [m for m in sys.modules if m == package or m.startswith(package + ".")]:
            del sys.modules[name]


def _custom_results(plan: Plan, package: str):
    from nerfify_ns.verify.components import run_custom

    g = load_grammar()
    registry = default_registry()
    results = {}
    for path, term in validate(plan).used.items():
        if term != "custom":
            continue
        interface = registry.interfaces[g.production_at(path)]
        for case in ("nominal", *interface.cases):
            results[(path, case)] = run_custom(interface, plan.get(path), package, case)
    return results


def test_hand_written_components_meet_their_interfaces(plugin_on_path):
    plan = hand_plan()
    plugin, _ = plugin_on_path(plan, SOURCES)
    results = _custom_results(plan, plugin.package)
    assert {path for path, _ in results} == {"model.field_wrappers.custom", "model.field_wrappers.custom_blend",
                                            "pixel_sampler.custom", "model.schedule_hooks.custom"}
    failed = {k: r.problems for k, r in results.items() if r.status != "pass"}
    assert not failed, failed


def test_a_deformation_that_breaks_the_contract_is_named(plugin_on_path):
    plan = hand_plan(channels=4)
    plan["method"] = "broken-wrapper"
    plugin, _ = plugin_on_path(plan, SOURCES)
    result = _custom_results(plan, plugin.package)[("model.field_wrappers.custom", "nominal")]
    assert result.status == "fail"
    assert any("positions" in p and "(64, 4)" in p for p in result.problems), result.problems


def _train(spec, steps: int = 8):
    """A few Adam steps of the plugin's model on one fixed batch of rays with times: the losses, first to last."""
    import torch

    from nerfify_ns.registry.examples import collide, ray_bundle
    from nerfify_ns.verify.assembled import build_model

    torch.manual_seed(0)
    model = build_model(spec)
    model.train()
    hooks = model.get_training_callbacks(None)
    optimizer = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=5e-3)
    bundle = collide(ray_bundle("nominal", rays=32, times=True))
    target = torch.rand(32, 3, generator=torch.Generator().manual_seed(1))
    losses = []
    for step in range(steps):
        from nerfstudio.engine.callbacks import TrainingCallbackLocation

        for hook in hooks:
            hook.run_callback_at_location(step, TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
        outputs = model(bundle)
        loss = model.get_loss_dict(outputs, {"image": target}, {})
        total = sum(loss.values())
        optimizer.zero_grad()
        total.backward()
        optimizer.step()
        losses.append(float(total))
    return model, losses


def test_the_typed_options_train(plugin_on_path):
    plan = options_plan()
    _, config = plugin_on_path(plan)
    spec = config.typed_options_method
    model, losses = _train(spec)
    assert all(math.isfinite(x) for x in losses) and losses[-1] < losses[0], losses
    windows = [float(m.window) for n, m in model.named_modules() if n.endswith("wrappers.deformation")]
    assert windows and all(abs(w - 4.0 * 7 / 20) < 1e-5 for w in windows), windows  # annealed to step 7
    codes = [p for n, p in model.named_parameters() if "frame_codes" in n]
    assert codes and all(p.requires_grad for p in codes)  # frozen for steps 0-4 only


def test_a_wrappers_sizes_are_config_fields_a_proxy_can_lower(plugin_on_path):
    """The deformation network's width, the time embedding's and the frame codes' dimension are fields of the
    generated model config, the plan's values their defaults: the plugin builds them from the plan's sizes, and a
    run that lowers one (a CPU proxy's ns-train argument) trains the smaller wrapper, the plugin's code unchanged."""
    import dataclasses

    from nerfify_ns.verify.assembled import build_model

    plan = options_plan()
    _, config = plugin_on_path(plan)
    spec = config.typed_options_method
    model_config = spec.config.pipeline.model
    assert (model_config.deformation_layer_width, model_config.time_embedding_layer_width,
            model_config.frame_codes_dim) == (32, 16, 4)

    def sizes(model):
        found = {}
        for name, module in model.named_modules():
            if name.endswith("wrappers.frame_codes"):
                found["codes"] = tuple(module.codes.shape)
            if name.endswith("wrappers.deformation"):
                found["deformation"] = max(m.out_features for m in module.modules() if hasattr(m, "out_features"))
        return found

    assert sizes(build_model(spec)) == {"codes": (8, 4), "deformation": 32}
    lowered = dataclasses.replace(model_config, deformation_layer_width=8, frame_codes_dim=2)
    spec.config.pipeline.model = lowered
    model = build_model(spec)
    assert sizes(model) == {"codes": (8, 2), "deformation": 8}
    spec.config.pipeline.model = model_config


def test_space_time_planes_are_built_from_the_configs_resolutions(plugin_on_path):
    """The field's space-time planes read their resolutions from the generated model config (the plan's the
    default): a run that halves them (a CPU proxy) trains smaller planes, the plugin's code unchanged."""
    import dataclasses

    from nerfify_ns.verify.assembled import build_model

    plan = small(Plan.of(load_reference_plan("vanilla-nerf")), "plane-sizes")
    plan.set("model.field.MLPField.pos_encoding", {"kplanes_time": {"resolutions": [8, 16], "num_components": 4,
                                                                     "time_resolution": 5}})
    _, config = plugin_on_path(plan)
    spec = config.plane_sizes_method
    model_config = spec.config.pipeline.model
    assert tuple(model_config.kplanes_resolutions) == (8, 16)

    def resolutions(model):
        return {tuple(m.resolutions) for m in model.modules() if type(m).__name__ == "MultiScaleKPlanes"}

    assert resolutions(build_model(spec)) == {(8, 16)}  # the coarse and the fine field alike
    spec.config.pipeline.model = dataclasses.replace(model_config, kplanes_resolutions=(4, 8))
    assert resolutions(build_model(spec)) == {(4, 8)}
    spec.config.pipeline.model = model_config


def test_hand_written_components_train(plugin_on_path):
    _, config = plugin_on_path(hand_plan(), SOURCES)
    model, losses = _train(config.hand_wrapped_method)
    assert losses[-1] < losses[0], losses
    scales = {m.warp_scale for m in model.modules() if hasattr(m, "warp_scale")}
    assert len(scales) == 1 and abs(scales.pop() - 0.7) < 1e-6  # the hand-written hook wrote step 7 of 10


def test_the_pixel_sampler_draws_by_its_map(plugin_on_path):
    import torch

    plan = options_plan()
    plan["method"] = "pixel-map"
    plan.set("pixel_sampler", {"view_selection": {"rule": "every_nth", "n": 2}})
    _, config = plugin_on_path(plan)
    sampler = config.pixel_map_method.config.pipeline.datamanager.pixel_sampler.setup(num_rays_per_batch=256)
    images = torch.rand(6, 5, 4, 3)
    batch = sampler.sample({"image": images, "image_idx": torch.arange(10, 16)})
    assert batch["indices"].shape == (256, 3)
    assert set(batch["indices"][:, 0].tolist()) == {10, 12, 14}  # only the chosen views
    sampler.active = lambda index: index < 12
    again = sampler.sample({"image": images, "image_idx": torch.arange(10, 16)})
    assert set(again["indices"][:, 0].tolist()) == {10}


# ------------------------------------------------------------------------------------------ the ladder
@pytest.fixture(scope="module")
def dynamic_scene(tmp_path_factory) -> Path:
    from nerfify_ns.scenes import write_scene

    return write_scene("dynamic", tmp_path_factory.mktemp("scenes") / "dynamic", resolution=32, n_train=12,
                       n_val=2, n_test=2)


def _ladder(plan: Plan, tmp_path, scene, sources=None, rungs=None):
    from nerfify_ns.verify import run_ladder

    plugin = compose(plan, tmp_path / "plugin", sources=sources, record=False)
    return run_ladder(plugin.out, scene=scene, out_dir=tmp_path / "verify", smoke_iterations=20, repair="off",
                      rungs=rungs)


def nerfacto_plan(plan: Plan) -> Plan:
    """The same parts on Nerfacto's loop (its outputs name the rendered colour `rgb`), at small sizes."""
    base = Plan.of(load_reference_plan("nerfacto"))
    base["method"] = plan["method"]
    for key in ("scene", "datamanager", "pixel_sampler"):
        if key in plan:
            base[key] = plan[key]
    base.set("scene.bounded", True)
    base.set("scene.appearance_variation", False)
    field = base.get("model.field.MLPField")
    field.pop("spatial_distortion")
    field.pop("appearance_embedding")
    field["backbone"] = plan.get("model.field.MLPField.backbone")
    field["pos_encoding"] = {"hash": {"num_levels": 4, "max_res": 64, "log2_hashmap_size": 12}}
    base["model"].pop("camera_optimizer")
    base["optimizers"].pop("camera_opt")
    base.set("model.sampler.proposal", {"samples_per_ray": [16], "nerf_samples": 8, "network_max_res": [32],
                                        "network_num_levels": 2, "network_log2_hashmap_size": 10})
    if field["backbone"].get("branches"):
        field["density_head"] = {"density_linear": {"activation": "trunc_exp"}}
    for key in ("field_wrappers", "schedule_hooks"):
        if key in plan["model"]:
            base["model"][key] = plan["model"][key]
    base.set("trainer.mixed_precision", False)
    return base


@pytest.mark.slow
def test_hand_written_components_pass_every_rung(tmp_path, dynamic_scene):
    report = _ladder(nerfacto_plan(hand_plan()), tmp_path, dynamic_scene, SOURCES)
    assert report.ok, [str(d) for d in report.failures]
    assert [r.name for r in report.rungs] == ["static", "contract", "stability", "smoke"]
    checked = {c["component"] for c in report.rung("contract").details["cases"] if c["status"] == "pass"}
    for cls in ("TinyDeformation", "DensityBlend", "CentreWeighted", "WarpWarmUp"):
        assert any(cls in c for c in checked), (cls, checked)


@pytest.mark.slow
def test_typed_options_pass_every_rung(tmp_path, dynamic_scene):
    report = _ladder(nerfacto_plan(options_plan()), tmp_path, dynamic_scene)
    assert report.ok, [str(d) for d in report.failures]
    checked = {c["component"] for c in report.rung("contract").details["cases"] if c["status"] == "pass"}
    assert {"deformation", "time_embedding", "frame_codes", "camera_time_offset", "field_blend",
            "gradient_importance", "anneal", "freeze", "image_curriculum", "mlp"} <= checked


@pytest.mark.slow
def test_a_broken_wrapper_fails_the_contract_rung(tmp_path):
    report = _ladder(hand_plan(channels=4), tmp_path, None, SOURCES, rungs=["static", "contract"])
    assert report.rung("static").status == "pass" and not report.ok
    messages = [d.message for d in report.rung("contract").failures if d.rule == "component-contract"]
    assert any("TinyDeformation" in m and "positions: shape (64, 4)" in m for m in messages), messages


def test_a_blend_keeps_each_fields_share_of_every_sample():
    """The blended field keeps each field's share of its last evaluation's samples [R, S, K] (what a regulariser
    over a decomposition reads): the mixer's softmax weights, or each density over their sum; they sum to 1."""
    import torch
    from nerfstudio.cameras.rays import Frustums, RaySamples
    from nerfstudio.field_components.field_heads import FieldHeadNames
    from torch import nn

    from nerfify_ns.components.field_wrappers import BlendedField, FieldBlend

    class Constant(nn.Module):
        def __init__(self, value: float) -> None:
            super().__init__()
            self.value = value

        def forward(self, samples):
            shape = samples.frustums.starts.shape[:-1]
            return {FieldHeadNames.DENSITY: torch.full((*shape, 1), self.value),
                    FieldHeadNames.RGB: torch.full((*shape, 3), 0.5)}

    r, s = 4, 5
    frustums = Frustums(origins=torch.rand(r, s, 3), directions=torch.rand(r, s, 3), starts=torch.rand(r, s, 1),
                        ends=torch.rand(r, s, 1) + 1, pixel_area=torch.ones(r, s, 1))
    samples = RaySamples(frustums=frustums, deltas=torch.full((r, s, 1), 0.1), times=torch.rand(r, s, 1))
    by_density = BlendedField([Constant(1.0), Constant(3.0)], FieldBlend(2, "density"))
    by_density(samples)
    torch.testing.assert_close(by_density.last_weights, torch.tensor([0.25, 0.75]).expand(r, s, 2),
                               rtol=1e-5, atol=1e-5)
    mixer = FieldBlend(3, "mixer")
    by_mixer = BlendedField([Constant(1.0), Constant(2.0), Constant(3.0)], mixer)
    by_mixer(samples)
    assert by_mixer.last_weights.shape == (r, s, 3)
    torch.testing.assert_close(by_mixer.last_weights.reshape(-1, 3),
                               mixer.weights(frustums.get_positions().reshape(-1, 3), samples.times.reshape(-1, 1)))
    torch.testing.assert_close(by_mixer.last_weights.sum(-1), torch.ones(r, s))
