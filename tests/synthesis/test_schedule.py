"""A paper's schedule fitted to a shorter run (warm-ups, decay horizons, proposal annealing), as data."""

import pytest

from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.synthesis.schedule import scale_schedule


def _plan(**trainer):
    plan = Plan.of(load_reference_plan("nerfacto")).copy()
    plan["trainer"]["max_num_iterations"] = 30000
    plan.set("optimizers.fields.scheduler", {"exponential_decay": {"lr_final": 1e-4, "max_steps": 30000,
                                                                   "warmup_steps": 512}})
    return plan


def test_warm_ups_scale_with_the_run_and_decays_do_not():
    fit = scale_schedule(_plan(), 300)
    assert fit.factor == pytest.approx(0.01)
    changes = {c["path"]: (c["from"], c["to"]) for c in fit.changes}
    assert changes == {"optimizers.fields.scheduler.exponential_decay.warmup_steps": (512, 5)}
    assert fit.args == ["--optimizers.fields.scheduler.warmup-steps", "5"]
    record = fit.record()
    assert record["paper_iterations"] == 30000 and record["run_iterations"] == 300
    assert record["ns_train_args"] == fit.args


def test_a_run_as_long_as_the_paper_changes_nothing():
    fit = scale_schedule(_plan(), 30000)
    assert not fit.scaled and fit.args == [] and fit.factor == 1.0


def test_a_model_parameter_and_a_config_field_in_iterations_reach_ns_train(monkeypatch):
    from nerfify_ns.synthesis import schedule

    spec = {"terminals": {"proposal": ["warmup"], "exponential_decay": ["max_steps"]},
            "config": {"proposal": {"proposal_weights_anneal_max_num_iters": 1000}}}
    monkeypatch.setattr(schedule, "step_parameters", lambda: spec)
    fit = schedule.scale_schedule(_plan(), 300)
    args = fit.args
    assert args[args.index("--pipeline.model.proposal-warmup") + 1] == "50"
    assert args[args.index("--pipeline.model.proposal-weights-anneal-max-num-iters") + 1] == "10"
    assert args[args.index("--optimizers.fields.scheduler.max-steps") + 1] == "300"


def test_step_lists_stay_increasing_and_as_long():
    plan = Plan.of(load_reference_plan("tensorf")).copy()
    plan["trainer"]["max_num_iterations"] = 30000
    fit = scale_schedule(plan, 60)
    (upsampling,) = [c for c in fit.changes if c["path"].endswith("upsampling_iters")]
    before, after = upsampling["from"], upsampling["to"]
    assert len(after) == len(before) and all(b > a for a, b in zip(after, after[1:], strict=False))
    flag = fit.args.index("--pipeline.model.upsampling-iters")
    assert fit.args[flag + 1: flag + 1 + len(after)] == [str(v) for v in after]


def test_a_smaller_ray_batch_scales_every_learning_rate_linearly():
    plan = _plan()
    paper_rays = plan["datamanager"]["train_num_rays_per_batch"]
    fit = scale_schedule(plan, 30000, rays=paper_rays // 8)
    assert fit.batch == {"paper_rays": paper_rays, "run_rays": paper_rays // 8, "factor": 0.125, "rule": "linear"}
    changes = {c["path"]: (c["from"], c["to"]) for c in fit.changes}
    for group, spec in plan["optimizers"].items():
        ((optimizer, params),) = spec["optimizer"].items()
        lr = f"optimizers.{group}.optimizer.{optimizer}.lr"
        assert changes[lr] == (params["lr"], pytest.approx(params["lr"] / 8))
        flag = f"--optimizers.{group.replace('_', '-')}.optimizer.lr"
        assert float(fit.args[fit.args.index(flag) + 1]) == pytest.approx(params["lr"] / 8)
    final = "optimizers.fields.scheduler.exponential_decay.lr_final"
    assert changes[final] == (1e-4, pytest.approx(1.25e-5))
    assert f"{paper_rays // 8} of the paper's {paper_rays} rays" in fit.record()["reason"]
    assert fit.record()["batch"] == fit.batch


def test_the_paper_s_batch_or_a_larger_one_keeps_the_learning_rates():
    plan = _plan()
    rays = plan["datamanager"]["train_num_rays_per_batch"]
    for run in (rays, 2 * rays):
        fit = scale_schedule(plan, 30000, rays=run)
        assert fit.batch is None and not fit.scaled and fit.args == []


def test_a_part_measured_to_need_its_own_batch_rule_goes_before_its_base():
    """Space-time planes on a nerfacto base take the square-root rule (their part's, measured), not the base's
    linear one; the same base without the part keeps the linear rule."""
    plan = Plan.of(load_reference_plan("kplanes-time")).copy()
    assert plan["base"] == "nerfacto"
    paper_rays = plan["datamanager"]["train_num_rays_per_batch"]
    fit = scale_schedule(plan, int(plan["trainer"]["max_num_iterations"]), rays=paper_rays // 16)
    assert fit.batch["factor"] == pytest.approx(0.25) and fit.batch["rule"].startswith("square root")
    lr = plan["optimizers"]["fields"]["optimizer"]["adam"]["lr"]
    flag = fit.args.index("--optimizers.fields.optimizer.lr")
    assert float(fit.args[flag + 1]) == pytest.approx(lr / 4)
    assert scale_schedule(_plan(), 30000, rays=_plan()["datamanager"]["train_num_rays_per_batch"] // 16
                          ).batch["rule"] == "linear"


def test_schedule_hooks_of_a_shorter_run_read_the_paper_s_schedule_compressed():
    """A budgeted run shorter than the paper's passes one factor to every schedule hook (the plugin keeps the paper's
    steps): a keyframe curriculum that ends at the paper's step 300,000 ends within a 600-iteration run."""
    import torch

    from nerfify_ns.components.schedule_hooks import STEP_SCALE_FIELD, ImageCurriculum

    plan = Plan.of(load_reference_plan("kplanes-time"))
    plan["trainer"]["max_num_iterations"] = 300_000
    plan["model"]["schedule_hooks"] = {"image_curriculum": {"rule": "keyframes", "keyframe_stride": 30,
                                                             "end_step": 300_000, "start_fraction": 0.25}}
    fit = scale_schedule(plan, 600)
    flag = f"--pipeline.model.{STEP_SCALE_FIELD.replace('_', '-')}"
    assert flag in fit.args and float(fit.args[fit.args.index(flag) + 1]) == 0.002
    assert {"path": f"config:{STEP_SCALE_FIELD}", "from": 1.0, "to": 0.002} in fit.changes
    assert "model.schedule_hooks" not in " ".join(c["path"] for c in fit.changes)  # the plan's steps stay

    hook, written = ImageCurriculum("keyframes", 0.25, 30, 300_000), []
    hook.write = lambda value, model, datamanager: written.append(value)
    for step in (0, 599, 600):
        hook.run(step, torch.nn.Module(), None, scale=0.002)
    # every image from the run's step 600 on, as from the paper's 300,000
    assert written == pytest.approx([1 / 30, 1 / 30, 1.0])
    hook.run(600, torch.nn.Module(), None)  # unscaled: still on its keyframes
    assert written[-1] == pytest.approx(1 / 30)
    assert STEP_SCALE_FIELD not in " ".join(scale_schedule(Plan.of(load_reference_plan("kplanes-time")), 600).args)


def test_a_plugin_with_schedule_hooks_has_the_step_scale_field(tmp_path):
    """The generated model config carries the field the budgeted run sets (``ns-train`` refuses an unknown one), with
    the paper's schedule (1.0) as its default; a plugin without hooks has none."""
    import ast

    from nerfify_ns.components.schedule_hooks import STEP_SCALE_FIELD
    from nerfify_ns.synthesis.compose import compose

    plan = Plan.of(load_reference_plan("kplanes-time"))
    plan["method"] = "hooked"
    plan["model"]["schedule_hooks"] = {"image_curriculum": {"rule": "keyframes", "keyframe_stride": 4,
                                                             "end_step": 2000, "start_fraction": 0.25}}
    out = compose(plan, tmp_path / "hooked", record=False).out
    source = next(out.rglob("model.py")).read_text()
    fields = {n.target.id: n for c in ast.walk(ast.parse(source)) if isinstance(c, ast.ClassDef)
              and c.name.endswith("ModelConfig") for n in c.body if isinstance(n, ast.AnnAssign)}
    assert ast.literal_eval(fields[STEP_SCALE_FIELD].value) == 1.0
    plain = compose(Plan.of(load_reference_plan("kplanes-time")), tmp_path / "plain", record=False).out
    assert STEP_SCALE_FIELD not in next(plain.rglob("model.py")).read_text()


def _staged(stated: int, end: int) -> Plan:
    plan = Plan.of(load_reference_plan("kplanes-time"))
    plan["trainer"]["max_num_iterations"] = stated
    plan.evidence["trainer.max_num_iterations"] = f'p.6: "trained at {stated} iterations"'
    plan["model"]["schedule_hooks"] = {"image_curriculum": {"rule": "keyframes", "keyframe_stride": 30,
                                                             "end_step": end, "start_fraction": 0.25}}
    return plan


def test_a_stage_that_ends_after_the_stated_training_lengthens_it():
    """A paper trains a first stage for 300,000 iterations and states 200,000 elsewhere: the stated count cannot hold
    the stage, so the plan trains the stage and then the stated count, and says why; a run's compression then ends
    the stage within the run (at 300 / 500 of it) instead of past its end."""
    from nerfify_ns.synthesis.schedule import training_covers_stages

    plan = _staged(200_000, 300_000)
    line = training_covers_stages(plan)
    assert plan["trainer"]["max_num_iterations"] == 500_000
    assert line and "image_curriculum" in line and "300000" in line and "500000" in line
    assert line in plan["notes"] and line in plan.evidence["trainer.max_num_iterations"]
    assert plan.evidence["trainer.max_num_iterations"].startswith('p.6: "trained at 200000 iterations"')
    assert plan["model"]["schedule_hooks"]["image_curriculum"]["end_step"] == 300_000  # the paper's stage stays
    assert training_covers_stages(plan) is None  # once is enough
    assert scale_schedule(plan, 500).factor == pytest.approx(0.001)  # the stage ends at the run's step 300


def test_stages_within_the_training_change_nothing():
    from nerfify_ns.synthesis.schedule import training_covers_stages

    for plan in (_staged(30_000, 3_000), Plan.of(load_reference_plan("nerfacto"))):
        before = plan.copy()
        assert training_covers_stages(plan) is None
        assert plan == before
    # a stage's end the paper does not give (asked in equations.yaml, a default) lengthens nothing
    plan = _staged(1_000, 2_000)
    before = plan.copy()
    assert training_covers_stages(plan, unstated={"model.schedule_hooks.image_curriculum.end_step"}) is None
    assert plan == before


def test_learning_rates_kept_from_the_base_scale_from_the_base_s_batch():
    """A paper that states a batch of 24,576 rays but whose plan keeps its base's learning rates (K-Planes' 1e-2,
    set for 4,096): a 512-ray run scales those from 4,096, not from the paper's 24,576 (which would make them 2.4x
    smaller still); a rate the paper states scales from the paper's batch. The record says which batch each was
    set for."""
    from nerfify_ns.synthesis.plan_from_paper import FROM_BASE, base_of

    plan = Plan.of(load_reference_plan("kplanes-time"))
    base_rays = plan["datamanager"]["train_num_rays_per_batch"]
    plan["datamanager"]["train_num_rays_per_batch"] = 24576
    groups = [g for g in plan["optimizers"] if g != "camera_opt"]
    for g in groups:
        plan.evidence[f"optimizers.{g}.optimizer"] = FROM_BASE.format(base="kplanes-time")
    assert base_of(plan.evidence[f"optimizers.{groups[0]}.optimizer"]) == "kplanes-time"
    lr = {g: plan.get(f"optimizers.{g}.optimizer.adam.lr") for g in groups}
    fit = scale_schedule(plan, 30000, rays=512)
    for g in groups:
        change = next(c for c in fit.changes if c["path"] == f"optimizers.{g}.optimizer.adam.lr")
        assert change["to"] == pytest.approx(lr[g] * (512 / base_rays) ** 0.5, rel=1e-5)
    assert fit.batch["set_at"][groups[0]]["rays"] == base_rays
    assert "set for 4096 rays" in fit.record()["reason"]

    plan.evidence[f"optimizers.{groups[0]}.optimizer"] = 'p.6: "a learning rate of 5e-4"'  # the paper's own
    fit = scale_schedule(plan, 30000, rays=512)
    change = next(c for c in fit.changes if c["path"] == f"optimizers.{groups[0]}.optimizer.adam.lr")
    assert change["to"] == pytest.approx(lr[groups[0]] * (512 / 24576) ** 0.5, rel=1e-5)
    assert base_of('p.6: "a learning rate of 5e-4"') is None
