"""The CPU proxy of a paper's method: what it scales (samples per ray, rays per step, the scene, widths last), how far
(the target of proxy.yaml within the time left), what it records, and where it is never used."""

from dataclasses import replace

import pytest
from test_field_wrappers import plugin_on_path  # noqa: F401

from nerfify_ns.budget import COMPOSE_BUDGET, PAPER_BUDGET, Budget, BudgetError
from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.proxy import Measured, fit_proxy, knobs, proxy_scene, proxy_spec, smoke_samples
from nerfify_ns.synthesis.resources import load_reference_plan

PIXELS = 48 * 48  # one view of the proxy's scene


def _nerf_plan():
    """The vanilla-NeRF reference plan as a paper gives it: 4096 rays, 64 + 128 samples, 8 x 256 MLP."""
    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    plan.set("datamanager.train_num_rays_per_batch", 4096)
    plan.set("model.sampler.hierarchical.num_coarse_samples", 64)
    plan.set("model.sampler.hierarchical.num_importance_samples", 128)
    return plan


WIDE = (256 / 64) ** proxy_spec()["width"]["mlp"]["layer_width"]["exponent"]
"""How much slower a step of the paper's 256-wide MLP is predicted than one at the proxy's floor of 64."""


def _fit(plan, left, seconds_per_iteration=0.6 / WIDE, **kw):
    """A proxy fitted to ``left`` seconds from a smoke rung that trained 128 rays at the proxy's floors (samples and
    width; by default 0.6 s a step at the paper's width)."""
    measured = Measured(seconds_per_iteration, 15.0, 128, smoke_samples(plan)[1])
    return fit_proxy(plan, measured, seconds_left=left, rays=512, exponent=1.0, rays_per_checkpoint=4 * PIXELS,
                     train_pixels=24 * PIXELS, budget=PAPER_BUDGET, most=kw.pop("most", 30000), **kw)


def test_the_knobs_of_a_vanilla_nerf_plan_in_order():
    found = knobs(_nerf_plan(), 512)
    assert [(k.kind, k.path.rsplit(".", 1)[-1]) for k in found] == [
        ("samples", "num_coarse_samples"), ("samples", "num_importance_samples"),
        ("rays", "train_num_rays_per_batch"), ("width", "layer_width")]
    flags = {k.path.rsplit(".", 1)[-1]: k.flag for k in found}
    assert flags["num_coarse_samples"] == "--pipeline.model.num-coarse-samples"
    # the generated field reads its backbone's width from its model config (the plan's value the default)
    assert flags["layer_width"] == "--pipeline.model.mlp-layer-width"


def test_enough_time_keeps_the_papers_settings():
    fit = _fit(_nerf_plan(), 1e6)
    assert not fit.active and fit.args() == [] and fit.reached
    assert fit.seconds_per_iteration == pytest.approx(0.6 * (2 * 64 + 128) / (2 * 16 + 16) * 4)  # 512 of 128 rays


def test_samples_go_first_together_then_rays():
    plan = _nerf_plan()
    roomy = _fit(plan, 4000)  # halving the samples is enough
    assert roomy.active and [k.kind for k in roomy.changed] == ["samples", "samples"]
    assert roomy.args() == ["--pipeline.model.num-coarse-samples", "32", "--pipeline.model.num-importance-samples",
                            "64"]  # halved together: the paper's 1:2 ratio kept
    assert roomy.headline(4096) == ("trained a CPU proxy: 96 instead of 192 samples per ray, 512 instead of 4096 "
                                    "rays per step")
    tight = _fit(plan, 800)
    assert {k.kind for k in tight.changed} == {"samples", "rays"} and tight.rays < 512
    coarse, fine = (k for k in tight.knobs if k.kind == "samples")
    assert coarse.value == fine.value == 16  # both at their floors before any ray was taken away
    assert tight.time.iterations >= proxy_spec()["target"]["iterations"] and tight.reached


def test_a_proxy_that_reaches_the_target_is_the_mildest_that_does():
    plan = _nerf_plan()
    fit = _fit(plan, 4000)
    target = proxy_spec()["target"]
    assert fit.time.iterations >= target["iterations"]
    assert fit.time.iterations * fit.rays >= target["epochs"] * 24 * PIXELS
    stronger = _fit(plan, 4000)
    assert stronger.args() == fit.args()  # deterministic
    # one step milder (the paper's samples) would not have reached it
    milder = Measured(0.6, 15.0, 128, smoke_samples(plan)[1])
    from nerfify_ns.budget import fit_iterations

    step = milder.seconds_per_iteration * (2 * 64 + 128) / (2 * 16 + 16) * 4
    try:
        iterations = fit_iterations(4000, step, 15.0, 4 * PIXELS, 512, PAPER_BUDGET, most=30000).iterations
    except BudgetError:
        iterations = 0
    assert iterations < target["iterations"] or iterations * 512 < target["epochs"] * 24 * PIXELS


def test_the_record_says_what_was_scaled_and_why():
    fit = _fit(_nerf_plan(), 400, scene={"resolution": 48, "n_test": 4, "from_resolution": 64, "from_n_test": 8})
    record = fit.record(4096)
    assert record["headline"].startswith("trained a CPU proxy: 32 instead of 192 samples per ray, ")
    assert "a 48 px scene with 4 test views instead of 64 px with 8" in record["headline"]
    assert {s["path"].rsplit(".", 1)[-1]: (s["paper"], s["proxy"]) for s in record["settings"]}[
        "num_importance_samples"] == (128, 16)
    assert record["ns_train_args"] == fit.args() and "the proxy scales samples per ray, rays per step" in \
        record["reason"]
    assert "not_scaled" not in record  # every knob of the generated field has an ns-train argument


def test_the_width_goes_last_and_the_learning_rates_follow_it():
    from nerfify_ns.synthesis.schedule import scale_schedule

    plan = _nerf_plan()
    assert not any(k.kind == "width" for k in _fit(plan, 800).changed)  # samples and rays were enough
    narrow = _fit(plan, 150)
    kinds = [k.kind for k in narrow.changed]
    assert "width" in kinds and {"samples", "rays"} <= set(kinds)
    assert all(k.value == k.floor for k in narrow.knobs if k.kind in ("samples", "rays"))  # the others first
    width = next(k for k in narrow.knobs if k.kind == "width")
    assert width.value < 256 and ["--pipeline.model.mlp-layer-width", str(width.value)] == narrow.args()[-2:]
    assert f"MLP width {width.value} instead of 256" in narrow.headline(4096)
    assert narrow.width_ratio == width.value / 256
    # the plan keeps the paper's width; the run's learning rates follow the proxy's (paper / proxy, the muP rule)
    assert plan["model"]["field"]["MLPField"]["backbone"].get("layer_width", 256) == 256
    fit = scale_schedule(plan, 300, rays=narrow.rays, width=narrow.width_ratio)
    lr = fit.args[fit.args.index("--optimizers.fields.optimizer.lr") + 1]
    assert float(lr) == pytest.approx(5e-4 * 256 / width.value) and fit.record()["width"]["ratio"] < 1


def test_too_little_time_even_for_the_strongest_proxy_is_the_budgets_error():
    with pytest.raises(BudgetError, match="give a longer --budget"):
        _fit(_nerf_plan(), 40)


def test_the_smoke_rung_measures_at_the_floors():
    args, values = smoke_samples(_nerf_plan())
    assert args[:6] == ["--pipeline.model.num-coarse-samples", "16", "--pipeline.model.num-importance-samples", "16",
                        "--pipeline.model.mlp-layer-width", "64"]
    # the learning rate follows the narrower MLP (schedule.yaml's width rule: 64 of 256 wide, 4x the paper's 5e-4)
    lr = args[args.index("--optimizers.fields.optimizer.lr") + 1]
    assert float(lr) == pytest.approx(5e-4 * 4)
    assert values == {"model.sampler.hierarchical.num_coarse_samples": 16,
                      "model.sampler.hierarchical.num_importance_samples": 16,
                      "model.field.MLPField.backbone.layer_width": 64}
    nerfacto = load_reference_plan("nerfacto")
    args, values = smoke_samples(nerfacto)
    assert "--pipeline.model.num-proposal-samples-per-ray" in args and "--pipeline.model.num-nerf-samples-per-ray" \
        in args
    assert values["model.sampler.proposal.samples_per_ray"] == [32, 32]


def test_the_scene_is_smaller_only_for_a_short_budget_of_a_costly_base():
    scene = proxy_scene("vanilla-nerf", PAPER_BUDGET)
    assert scene["resolution"] < scene["from_resolution"] and scene["n_test"] < scene["from_n_test"]
    below = proxy_spec()["scene"]["vanilla-nerf"]["below"]
    assert proxy_scene("vanilla-nerf", replace(PAPER_BUDGET, seconds=below)) is None
    assert proxy_scene("nerfacto", PAPER_BUDGET) is None  # no entry: its own scene
    given = replace(PAPER_BUDGET, scene={"resolution": 64, "n_test": 8})
    assert proxy_scene("vanilla-nerf", given) is None  # the user's settings stand


def test_fixed_settings_are_never_proxied():
    """compose --method and the benchmarks compare fixed settings: their budgets never train a proxy."""
    assert PAPER_BUDGET.proxy and not COMPOSE_BUDGET.proxy and not Budget().proxy
    assert proxy_scene("vanilla-nerf", replace(COMPOSE_BUDGET, seconds=240)) is None


def test_the_headline_counts_from_the_papers_values_where_the_scene_pruned_them():
    plan = _nerf_plan()
    plan.set("model.sampler.hierarchical.num_coarse_samples", 48)
    plan.set("model.sampler.hierarchical.num_importance_samples", 96)
    plan["pruned"] = [{"rule": "r", "path": "model.sampler.hierarchical.num_coarse_samples", "action": "clamped",
                       "from": 64, "to": 48, "reason": "small images"},
                      {"rule": "r", "path": "model.sampler.hierarchical.num_importance_samples", "action": "clamped",
                       "from": 128, "to": 96, "reason": "small images"}]
    fit = _fit(plan, 400)
    assert fit.headline(4096).startswith("trained a CPU proxy: 32 instead of 192 samples per ray")
    coarse = next(s for s in fit.record(4096)["settings"] if s["path"].endswith("num_coarse_samples"))
    assert (coarse["paper"], coarse["plan"], coarse["proxy"]) == (64, 48, 16)


def test_a_step_scales_with_the_part_its_rays_cost():
    from nerfify_ns.budget import scaled_step

    # no ray share measured: the base's exponent scales the whole step
    assert scaled_step(0.4, 128, 512, ray_share=None, exponent=0.5) == pytest.approx(0.8)
    # a step that is one quarter rays: 4x the rays adds three quarters of that quarter's cost three times over
    assert scaled_step(0.4, 128, 512, ray_share=0.25, exponent=0.5) == pytest.approx(0.4 * (0.75 + 0.25 * 4))
    # the samples per ray scale only the rays' part; a share outside [0, 1] (timing noise) is clamped
    assert scaled_step(0.4, 128, 128, ray_share=0.5, exponent=1.0, per_ray=0.5) == pytest.approx(0.3)
    assert scaled_step(0.4, 128, 64, ray_share=1.7, exponent=1.0) == pytest.approx(0.2)


def test_fewer_rays_are_not_taken_when_the_step_is_mostly_the_models_parameters():
    """A plan whose step is dominated by work over its whole grids (a total-variation prior over planes, the
    optimiser over millions of parameters) gains few iterations from fewer rays and loses passes over the pixels:
    the proxy keeps the rays where halving them brings the run no nearer its target."""
    plan = _nerf_plan()
    rays_bound = Measured(0.6 / WIDE, 15.0, 128, smoke_samples(plan)[1], ray_share=1.0)
    grid_bound = Measured(0.6 / WIDE, 15.0, 128, smoke_samples(plan)[1], ray_share=0.05)
    common = dict(seconds_left=800, rays=512, exponent=1.0, rays_per_checkpoint=4 * PIXELS,
                  train_pixels=24 * PIXELS, budget=PAPER_BUDGET, most=30000)
    bound = fit_proxy(plan, rays_bound, **common)
    assert bound.rays < 512  # as before: the rays are the step's cost
    kept = fit_proxy(plan, grid_bound, **common)
    assert kept.rays == 512 and "rays" not in {k.kind for k in kept.changed}
    # keeping them is what brings the run nearest the target: more passes over the pixels than the halved batch
    halved = kept.time.iterations * 512
    assert halved > bound.time.iterations * bound.rays


def test_a_field_wrappers_sizes_are_widths_that_do_not_move_the_learning_rates():
    """A deformation network run on every sample and per-frame codes appended to the backbone's input cost time
    like the backbone's width: the proxy may lower them last, through the generated config's fields, names each in
    the headline in its own words, and only the backbone's width moves the learning rates."""
    plan = _nerf_plan()
    plan.set("model.field_wrappers", {"deformation": {"num_layers": 8, "layer_width": 256},
                                      "frame_codes": {"num_frames": 24, "dim": 1024}})
    widths = {k.path.rsplit(".", 2)[-2] + "." + k.path.rsplit(".", 1)[-1]: k for k in knobs(plan, 512)
              if k.kind == "width"}
    assert widths["deformation.layer_width"].flag == "--pipeline.model.deformation-layer-width"
    assert widths["frame_codes.dim"].flag == "--pipeline.model.frame-codes-dim"
    assert [k.learning_rates for k in widths.values()] == [True, False, False]  # the backbone's, then the wrappers'
    narrow = _fit(plan, 150)
    changed = {k.path: k for k in narrow.changed if k.kind == "width"}
    codes = changed["model.field_wrappers.frame_codes.dim"]
    assert codes.value < 1024 and f"frame code dimension {codes.value} instead of 1024" in narrow.headline(4096)
    assert "--pipeline.model.frame-codes-dim" in narrow.args()
    backbone = changed.get("model.field.MLPField.backbone.layer_width")
    assert narrow.width_ratio == (backbone.value / 256 if backbone else 1.0)
    # the smoke rung measures at every width's floor; its learning rates follow the backbone's alone
    args, values = smoke_samples(plan)
    assert values["model.field_wrappers.frame_codes.dim"] == 32
    assert values["model.field_wrappers.deformation.layer_width"] == 64
    assert float(args[args.index("--optimizers.fields.optimizer.lr") + 1]) == pytest.approx(5e-4 * 4)


def test_space_time_planes_resolutions_are_a_width_measured_at_the_plans_value():
    """K-Planes' resolutions cost a step through their parameters (Adam, the planes' regularisers): the proxy may
    halve every scale, through the generated config's field, but the smoke rung measures the step at the plan's
    planes (``smoke: plan``), so a run whose planes fit keeps them."""
    plan = Plan.of(load_reference_plan("kplanes-time"))
    planes = next(k for k in knobs(plan, 4096) if k.path.endswith("kplanes_time.resolutions"))
    assert planes.kind == "grid" and planes.flag == "--pipeline.model.kplanes-resolutions"
    assert planes.halved() == [max(32, r // 2) for r in planes.paper] and not planes.learning_rates
    args, values = smoke_samples(plan)
    assert "--pipeline.model.kplanes-resolutions" not in args and planes.path not in values


def test_a_pipeline_that_counts_samples_is_scaled_by_its_samples_marching_steps_and_grid():
    """Instant-NGP's pipeline sizes a step by its samples (the ray batch is no knob of its cost): the proxy marches
    coarser, keeps a coarser occupancy grid and holds fewer samples a step; the smoke rung measures those floors."""
    plan = load_reference_plan("instant-ngp")
    found = {k.path.rsplit(".", 1)[-1]: k for k in knobs(plan, 512)}
    assert [k.kind for k in knobs(plan, 512)][:3] == ["samples", "grid", "rays"]
    assert "train_num_rays_per_batch" not in found  # the pipeline resizes the ray batch itself
    assert found["target_num_samples"].flag == "--pipeline.target-num-samples"
    assert found["render_steps"].flag == "--pipeline.model.render-steps-per-diagonal"  # the generated config's
    assert found["grid_resolution"].flag == "--pipeline.model.grid-resolution"  # the base's own
    args, values = smoke_samples(plan)
    floors = {k.path: k.floor for k in found.values() if k.kind != "width"}
    assert {p: values[p] for p in floors} == floors
    assert args[args.index("--pipeline.target-num-samples") + 1] == str(found["target_num_samples"].floor)

    # a smoke rung of 0.15 s a step at the floors: the paper's 262,144 samples with 1,000 marching steps do not fit
    # a 150 s budget; the proxy's record names each in words and its ns-train arguments set them
    measured = Measured(0.15, 15.0, values["pipeline.target_num_samples"], values)
    fit = fit_proxy(plan, measured, seconds_left=150, rays=512, exponent=1.0, rays_per_checkpoint=4 * PIXELS,
                    train_pixels=24 * PIXELS, budget=PAPER_BUDGET, most=30000)
    assert fit.active and fit.time.iterations >= 100
    changed = {k.path.rsplit(".", 1)[-1]: k.value for k in fit.changed}
    assert changed["render_steps"] < 1000 and changed["target_num_samples"] < 262144
    headline = fit.headline()
    assert "instead of 1000 marching steps across the scene's diagonal" in headline
    assert "instead of 262144 samples per step" in headline and "samples per ray" not in headline
    assert "rays per step" not in headline
    # its rays (passes over the pixels, the learning rates' batch rule) are the samples over those a ray keeps
    kept = found["target_num_samples"].kept_per_ray
    assert fit.rays == int(changed["target_num_samples"] / kept)


def test_the_generated_model_marches_the_plans_steps_across_the_scene_as_the_base_does(plugin_on_path):  # noqa: F811
    """The marching step is a field of the generated config (a proxy may march coarser): at the plan's 1,000 steps
    the generated model's step is the built-in Instant-NGP's, to the bit; at 125 it is eight times longer."""
    import torch
    from nerfstudio.data.scene_box import SceneBox
    from nerfstudio.models.instant_ngp import InstantNGPModelConfig

    from nerfify_ns.verify.assembled import AABB, build_model

    plan = Plan.of(load_reference_plan("instant-ngp"))
    plan.set("model.sampler.occupancy_grid", {"grid_resolution": 16, "grid_levels": 1, "alpha_thre": 0.01,
                                              "cone_angle": 0.0})
    plan.set("model.field.MLPField.pos_encoding", {"hash": {"num_levels": 4, "min_res": 4, "max_res": 32,
                                                            "log2_hashmap_size": 12, "features_per_level": 2}})
    _, config = plugin_on_path(plan)
    method = next(v for k, v in vars(config).items() if k.endswith("_method"))
    model = build_model(method)
    assert model.config.render_steps_per_diagonal == 1000
    builtin = InstantNGPModelConfig(grid_resolution=16, grid_levels=1, log2_hashmap_size=12, max_res=32).setup(
        scene_box=SceneBox(aabb=torch.tensor(AABB)), num_train_data=4, metadata={})
    assert model.config.render_step_size == builtin.config.render_step_size
    method.config.pipeline.model.render_steps_per_diagonal = 125
    assert build_model(method).config.render_step_size == pytest.approx(8 * builtin.config.render_step_size)
