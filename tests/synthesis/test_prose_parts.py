"""Parts a paper states in prose, built from its sentences into typed terminals (synthesis/novel/prose.py): two
papers of our own (tests/data/papers/prose_parts.md, a dynamic scene: a deformation MLP with its depth and width,
a second field blended by density, one time offset per camera, a keyframe curriculum; prose_backbone.md, a static
scene: inputs fed to every layer, separate density and colour branches, pixels drawn by the image gradient), each
part built from its sentence with the record quoting it and the sizes the paper does not give asked in
equations.yaml; negations, duties and approximations; a person's value read back with --equations; the pruning of
time parts for a static scene; the built parts train, and pass every rung of the ladder (slow)."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import yaml
from prose_holes import build_hole
from test_field_wrappers import _ladder, _train, dynamic_scene, nerfacto_plan, plugin_on_path, small  # noqa: F401

from nerfify_ns.grammar import validate
from nerfify_ns.paper import ingest
from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.novel import IMPLEMENTED, NOT_IMPLEMENTED, PARTLY, implement_holes, prose
from nerfify_ns.synthesis.novel.causes import cause_of
from nerfify_ns.synthesis.novel.implement import revert
from nerfify_ns.synthesis.novel.records import read_corrections, to_yaml
from nerfify_ns.synthesis.plan_from_paper import plan_from_paper
from nerfify_ns.synthesis.resources import load_reference_plan

PAPERS = Path(__file__).resolve().parents[1] / "data" / "papers"


@pytest.fixture(scope="module")
def dynamic_paper():
    doc = ingest(PAPERS / "prose_parts.md")
    return doc, plan_from_paper(doc).plan


@pytest.fixture(scope="module")
def dynamic_built(dynamic_paper):
    doc, plan = dynamic_paper
    return implement_holes(doc, plan)


@pytest.fixture(scope="module")
def static_built():
    doc = ingest(PAPERS / "prose_backbone.md")
    return implement_holes(doc, plan_from_paper(doc).plan)


def _record(result, production):
    return next(r for r in result.records if r.production == production)


def _part(record, name):
    return next(p for p in record.parts if p["part"] == name)


# ------------------------------------------------------------------------------------------ from the papers
def test_the_dynamic_papers_parts_are_built_from_their_sentences(dynamic_built):
    plan = dynamic_built.plan
    validate(plan)
    wrappers = plan["model"]["field_wrappers"]
    assert wrappers["deformation"]["num_layers"] == 6 and wrappers["deformation"]["layer_width"] == 96
    assert wrappers["camera_time_offset"] == {"init": 0.0}
    assert wrappers["field_blend"]["mode"] == "density" and wrappers["field_blend"]["num_fields"] == 2
    record = _record(dynamic_built, "FieldWrapper")
    assert record.status == IMPLEMENTED and record.component["source"] == "prose"
    deformation = _part(record, "deformation")
    for name in ("num_layers", "layer_width"):  # each size quotes the sentence that states it
        assert deformation["parameters"][name]["source"] == "paper"
        assert "MLP with 6 layers of width 96" in deformation["parameters"][name]["quote"]
    assert "deformation network maps each sample position" in deformation["statement"]["quote"]
    offset = _part(record, "camera_time_offset")
    assert "one time offset per camera" in offset["statement"]["quote"]
    blend = _part(record, "field_blend")
    assert "blended by their densities" in blend["parameters"]["mode"]["quote"]
    assert blend["parameters"]["mixer_width"]["source"] == "not used"  # a density blend has no mixer
    # what the paper does not give is asked, with the terminal's default, never set silently
    assert set(record.asked) == {"deformation.position_frequencies", "deformation.time_frequencies",
                                 "deformation.zero_at_t0"}
    assert record.asked["deformation.position_frequencies"]["value"] == 10


def test_a_keyframe_curriculum_is_built_from_its_sentence(dynamic_built):
    hooks = dynamic_built.plan["model"]["schedule_hooks"]
    assert hooks["image_curriculum"]["rule"] == "keyframes"
    assert hooks["image_curriculum"]["keyframe_stride"] == 4 and hooks["image_curriculum"]["end_step"] == 2000
    part = _part(_record(dynamic_built, "ScheduleHook"), "keyframe_curriculum")
    assert "every 4th frame" in part["parameters"]["keyframe_stride"]["quote"]
    assert "after 2000 iterations" in part["parameters"]["end_step"]["quote"]
    assert part["parameters"]["start_fraction"]["source"] == "not used"


def test_the_static_papers_backbone_and_sampler_are_built(static_built):
    plan = static_built.plan
    validate(plan)
    backbone = plan.get("model.field.MLPField.backbone")
    assert backbone["skip_every_layer"] is True and backbone["branches"] is True
    assert (backbone["density_layers"], backbone["density_width"], backbone["color_layers"],
            backbone["color_width"]) == (2, 64, 1, 96)
    assert plan.get("pixel_sampler") == {"gradient_importance": {"uniform_fraction": 0.3}}
    sampler = _record(static_built, "PixelSampler")
    assert sampler.status == IMPLEMENTED  # the paper's weight is the image gradient: the terminal's own
    assert "30% of the pixels" in _part(sampler, "importance_sampling")["parameters"]["uniform_fraction"]["quote"]
    backbone_record = next(r for r in static_built.records if any(p["terminal"] == "mlp" for p in r.parts))
    every = _part(backbone_record, "inputs_to_every_layer")
    assert "fed to every layer" in every["statement"]["quote"]
    if backbone_record.production != "Backbone":  # filed elsewhere by the derivation: said in the record
        assert any("placed as Backbone" in n for n in backbone_record.notes)


def test_records_quote_and_ask_in_equations_yaml(dynamic_paper, dynamic_built, tmp_path):
    doc, _ = dynamic_paper
    data = yaml.safe_load(to_yaml(dynamic_built, doc))
    hole = next(h for h in data["holes"] if h["production"] == "FieldWrapper")
    assert hole["source"] == "prose" and hole["status"] == IMPLEMENTED
    assert "deformation.time_frequencies" in hole["asked"]
    assert {p["part"] for p in hole["prose"]} == {"deformation", "camera_time_offset", "field_blend"}
    # a person answers what was asked: the rerun builds with their value, said as a correction
    hole["asked"]["deformation.time_frequencies"]["value"] = 4
    path = tmp_path / "equations.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    corrections, reuse = read_corrections(path)
    assert not reuse and {h["id"] for h in corrections["holes"]} >= {"field_wrappers"}
    again = implement_holes(doc, plan_from_paper(doc).plan, corrections=corrections, reuse=reuse)
    assert again.plan["model"]["field_wrappers"]["deformation"]["time_frequencies"] == 4
    chosen = _part(_record(again, "FieldWrapper"), "deformation")["parameters"]["time_frequencies"]
    assert chosen["source"] == "correction" and "asked" in chosen["why"]
    assert "deformation.time_frequencies" not in _record(again, "FieldWrapper").asked
    assert _part(_record(again, "FieldWrapper"), "deformation")["parameters"]["num_layers"]["source"] == "paper"


def test_a_failed_ladder_takes_the_built_terminals_out_again(dynamic_paper):
    doc, plan = dynamic_paper
    result = implement_holes(doc, plan)
    record = _record(result, "FieldWrapper")
    out = revert(result, [record.id], "the ladder's contract rung failed (test)")
    assert "field_wrappers" not in out["model"] or not out["model"]["field_wrappers"]
    assert record.status == NOT_IMPLEMENTED and record.checks["ladder"]
    assert out["model"]["schedule_hooks"]["image_curriculum"]  # the other hole's part stays


# ------------------------------------------------------------------------------------------ single statements
def _dynamic_plan() -> Plan:
    return small(Plan.of(load_reference_plan("vanilla-nerf")), "prose-unit")


def _build(production, slot, sentences, plan=None, corr=None):
    plan = plan if plan is not None else _dynamic_plan()
    return build_hole(production, slot, sentences, plan, corr), plan


def _built_anneal(sentence: str, plan: Plan) -> tuple[tuple, Plan]:
    """The anneal a ScheduleHook hole's sentence builds, as (target, start value, end value, end step), and the plan
    it joined (validated)."""
    result, plan = _build("ScheduleHook", "model.schedule_hooks", [sentence], plan=plan)
    assert result.status == IMPLEMENTED, result.reason
    validate(plan)
    a = plan["model"]["schedule_hooks"]["anneal"]
    return (a["target"], a["start_value"], a["end_value"], a["end_step"]), plan


def test_a_negated_statement_builds_nothing():
    result, plan = _build("FieldWrapper", "model.field_wrappers",
                          ["Unlike D-NeRF, we do not use a deformation network; the field takes time as an input."])
    assert result.status == NOT_IMPLEMENTED and not isinstance(result, prose.ProseResult)
    assert "field_wrappers" not in plan["model"]


def test_a_time_wrapper_needs_timestamps():
    plan = Plan.of(load_reference_plan("vanilla-nerf"))  # a static scene: its frames carry no times
    result, plan = _build("FieldWrapper", "model.field_wrappers",
                          ["We learn one time offset per camera, initialised to 0."], plan=plan)
    assert result.status == NOT_IMPLEMENTED
    assert "requires_scene" in result.reason and "timestamps" in result.reason
    assert "field_wrappers" not in plan["model"]  # taken out again
    validate(plan)


def test_an_anneal_of_something_the_plan_does_not_expose_is_refused():
    result, plan = _build("ScheduleHook", "model.schedule_hooks",
                          ["We anneal the weight of the sparsity loss from 1 to 0 over 5000 iterations."])
    assert result.status == NOT_IMPLEMENTED and "no terminal of the plan exposes" in result.reason
    assert "schedule_hooks" not in plan["model"]


@pytest.mark.parametrize("sentence, built", [
    # the anneal's clause is the bracket: it changes a pruning threshold, which no terminal exposes, not the grid
    ("Every thousand iterations, we prune grid voxels whose density falls below the pruning threshold (which we "
     "anneal linearly from 0 to 0.2).", False),
    ("We progressively activate the levels of the hash grid from low to high resolution over 2000 iterations.", True),
    # a bracket opened by a relative pronoun names what it anneals just before it
    ("Training starts from the coarsest levels of the hash grid (which we anneal to the finest over 2000 "
     "iterations).", True),
])
def test_an_anneal_names_what_it_changes_in_its_own_clause(sentence, built):
    plan = small(Plan.of(load_reference_plan("nerfacto")), "prose-clause")
    result, plan = _build("ScheduleHook", "model.schedule_hooks", [sentence], plan=plan)
    if built:
        assert result.status == IMPLEMENTED, result.reason
        assert plan["model"]["schedule_hooks"]["anneal"]["target"] == "encoding_window.window"
    else:
        assert result.status == NOT_IMPLEMENTED and "no terminal of the plan exposes" in result.reason
        assert cause_of(result.reason) == "no terminal for what it states"
        assert "schedule_hooks" not in plan["model"]


def test_an_anneal_of_the_deformations_window_is_built():
    plan = _dynamic_plan()
    plan.set("model.field_wrappers", {"deformation": {}})
    anneal, _ = _built_anneal("The coarse-to-fine window of the deformation's positional encoding is annealed from 0 "
                              "to 8 over 4000 iterations.", plan)
    assert anneal == ("deformation.window", 0.0, 8.0, 4000)


@pytest.mark.parametrize("sentence, encoding, bands", [
    ("Following BARF, we progressively activate the frequencies of the positional encoding from low to high over "
     "the first 6 iterations.", "positional", 4),
    ("We adopt a coarse-to-fine strategy: the levels of the hash grid are switched on from low to high resolution "
     "over the first 6 iterations.", "hash", 3),
])
def test_a_coarse_to_fine_schedule_of_the_fields_encoding_is_built_and_trains(
        plugin_on_path, sentence, encoding, bands):  # noqa: F811
    """A paper that switches its field's encoding on band by band (frequencies or grid levels) in words: an anneal of
    the encoding's window from 0 to 1, and the generated field's encoding wrapped in the window it anneals."""
    from nerfify_ns.components.encoding_window import CoarseToFine

    plan = _dynamic_plan()
    plan["method"] = f"coarse-to-fine-{encoding}"
    if encoding == "hash":
        plan.set("model.field.MLPField.pos_encoding", {"hash": {"num_levels": 3, "min_res": 4, "max_res": 16,
                                                                "log2_hashmap_size": 10, "features_per_level": 2}})
    anneal, plan = _built_anneal(sentence, plan)
    assert anneal == ("encoding_window.window", 0.0, 1.0, 6)
    _, config = plugin_on_path(plan)
    model, losses = _train(getattr(config, f"coarse_to_fine_{encoding}_method"), steps=8)
    windows = [m for m in model.modules() if type(m).__name__ == CoarseToFine.__name__]  # the plugin's own copy
    assert len(windows) == 2 and {w.bands for w in windows} == {bands}  # vanilla NeRF's coarse and fine fields
    assert all(float(w.window) == 1.0 for w in windows)  # annealed to every band by step 6
    assert all(math.isfinite(x) for x in losses)
    for hook in model.schedule_hooks:  # step 0 again: nothing but the coarsest level (or the raw input) is on
        hook.run(0, model)
    assert all(float(w.window) == 0.0 and float(w.weights()[w.band >= 1].max()) == 0.0 for w in windows)


def test_an_annealed_pruning_threshold_is_built_into_the_occupancy_grid(plugin_on_path):  # noqa: F811
    """"We anneal the pruning threshold" on a base with an occupancy grid: an anneal of the grid's threshold, and the
    generated model's grid prunes below what the hook last wrote."""
    from nerfstudio.engine.callbacks import TrainingCallbackAttributes, TrainingCallbackLocation

    from nerfify_ns.verify.assembled import build_model

    plan = Plan.of(load_reference_plan("instant-ngp"))
    plan["method"] = "pruned-grid"
    plan.set("model.sampler.occupancy_grid", {"grid_resolution": 16, "grid_levels": 1, "alpha_thre": 0.01,
                                              "cone_angle": 0.0})
    plan.set("model.field.MLPField.pos_encoding", {"hash": {"num_levels": 4, "min_res": 4, "max_res": 32,
                                                            "log2_hashmap_size": 12, "features_per_level": 2}})
    anneal, plan = _built_anneal(
        "Every 16 iterations, cells of the occupancy grid whose density falls below the pruning threshold are "
        "pruned; we anneal the pruning threshold linearly from zero to α = 0.2 over 5000 iterations.", plan)
    assert anneal == ("occupancy_grid.threshold", 0.0, 0.2, 5000)
    _, config = plugin_on_path(plan)
    model = build_model(config.pruned_grid_method)
    model.train()
    callbacks = model.get_training_callbacks(TrainingCallbackAttributes(None, None, None, None))
    for step in (0, 2500):
        for cb in callbacks:
            cb.run_callback_at_location(step, TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
        assert abs(model.occupancy_grid.threshold - step / 25000) < 1e-6  # 0 at step 0, 0.1 at step 2500
    assert model.occupancy_grid.binaries.any()  # the grid's update ran with the threshold written


def test_importance_by_a_quantity_of_the_paper_is_an_approximation():
    result, plan = _build("PixelSampler", "pixel_sampler",
                          ["We sample rays with a probability proportional to the temporal variation of their colour."])
    assert result.status == PARTLY and "luminance gradient" in result.reason
    assert "gradient_importance" in plan["pixel_sampler"]


def test_a_skip_at_a_stated_layer_counts_as_the_paper_does():
    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    sentence = "A skip connection concatenates the encoded input to the 6th layer's activation."
    result, plan = _build("Backbone", "model.field.MLPField.backbone", [sentence], plan=plan)
    assert result.status == IMPLEMENTED
    assert plan.get("model.field.MLPField.backbone")["skip_connections"] == [5]


def test_sizes_outside_the_terminals_range_are_not_taken():
    result, plan = _build("FieldWrapper", "model.field_wrappers",
                          ["We learn time-dependent latent codes z_t.", "Each latent code has 100000 dimensions, "
                           "and we use 8192-dimensional latent codes in the ablation."])
    codes = _part(result, "frame_codes")["parameters"]["dim"]
    assert codes["source"] == "asked" and plan["model"]["field_wrappers"]["frame_codes"]["dim"] == 32


# ------------------------------------------------------------------------------------------ pruning
def test_time_parts_and_their_hooks_are_pruned_for_a_static_scene(dynamic_built):
    from nerfify_ns.synthesis.prune import prune_plan
    from nerfify_ns.synthesis.scene_probe import SceneFacts

    plan = copy.deepcopy(dynamic_built.plan)
    plan["model"]["schedule_hooks"]["anneal"] = {"target": "deformation.window", "end_step": 100}
    validate(plan)
    facts = SceneFacts(bounded=True, timestamps=False, alpha=True, appearance_variation=False, exact_poses=True,
                       image_size=(32, 32), num_images=12, evidence={"timestamps": "frames have no times"})
    pruned = prune_plan(plan, facts)
    wrappers = pruned["model"].get("field_wrappers") or {}
    assert "deformation" not in wrappers and "camera_time_offset" not in wrappers
    assert "field_blend" in wrappers  # a blend reads no time of its own
    hooks = pruned["model"]["schedule_hooks"]
    assert "anneal" not in hooks and "image_curriculum" in hooks
    rules = {r["rule"]: r for r in pruned["pruned"]}
    assert "no_deformation_for_static_scene" in rules and "no_camera_time_offsets_for_static_scene" in rules
    assert "deformation" in rules["schedule_hook_target"]["reason"]
    validate(pruned)


# ------------------------------------------------------------------------------------------ training
def _transplant(built: Plan, target: Plan) -> Plan:
    """The prose-built parts of ``built`` on a small plan (sizes the paper states are kept)."""
    for key in ("field_wrappers", "schedule_hooks"):
        if key in built["model"]:
            target["model"][key] = copy.deepcopy(built["model"][key])
    if "pixel_sampler" in built:
        target["pixel_sampler"] = copy.deepcopy(built["pixel_sampler"])
    options = {k: v for k, v in built.get("model.field.MLPField.backbone").items()
               if k in ("skip_every_layer", "branches", "density_layers", "density_width", "color_layers",
                        "color_width")}
    target.get("model.field.MLPField.backbone").update(options)
    return target


def _both(dynamic_built, static_built, name: str) -> Plan:
    plan = _transplant(dynamic_built.plan, small(Plan.of(load_reference_plan("vanilla-nerf")), name))
    plan = _transplant(static_built.plan, plan)
    plan.get("model.field.MLPField.backbone").update({"num_layers": 4, "layer_width": 32})
    plan["model"]["schedule_hooks"]["image_curriculum"]["end_step"] = 4
    validate(plan)
    return plan


@pytest.mark.slow
def test_the_built_parts_train(plugin_on_path, dynamic_built, static_built):  # noqa: F811
    plan = _both(dynamic_built, static_built, "prose-built")
    _, config = plugin_on_path(plan)
    model, losses = _train(config.prose_built_method)
    assert all(math.isfinite(x) for x in losses) and losses[-1] < losses[0], losses
    names = {n for n, _ in model.named_modules()}
    assert any(n.endswith("wrappers.deformation") for n in names)
    assert any(n.endswith("wrappers.camera_time_offset") for n in names)


@pytest.mark.slow
def test_the_built_parts_pass_every_rung(tmp_path, dynamic_scene, dynamic_built, static_built):  # noqa: F811
    report = _ladder(nerfacto_plan(_both(dynamic_built, static_built, "prose-ladder")), tmp_path, dynamic_scene)
    assert report.ok, [str(d) for d in report.failures]
    assert [r.name for r in report.rungs] == ["static", "contract", "stability", "smoke"]
    checked = {c["component"] for c in report.rung("contract").details["cases"] if c["status"] == "pass"}
    assert {"deformation", "camera_time_offset", "field_blend", "image_curriculum", "gradient_importance",
            "mlp"} <= checked


def test_a_loss_term_naming_the_part_it_acts_on_stays_a_loss():
    """A regulariser's sentences name the network it penalises; that does not make the regulariser a deformation
    network (the hole stays where the derivation filed it, not built from those sentences)."""
    plan = _dynamic_plan()
    plan["scene"]["timestamps"] = True
    result, plan = _build("Regularizers", "model.regularizers",
                          ["We regularize the offsets of the deformation network that maps each point into the "
                           "canonical space by penalising their mean squared magnitude."], plan=plan)
    assert result.status == NOT_IMPLEMENTED and not isinstance(result, prose.ProseResult)
    assert "field_wrappers" not in plan["model"]
    # the same sentences filed as a backbone hole are placed where they state a part
    result, plan = _build("Backbone", "model.field.MLPField.backbone",
                          ["A deformation network maps each point into the canonical space."], plan=plan)
    assert isinstance(result, prose.ProseResult) and result.production == "FieldWrapper"


def test_a_part_whose_sentences_name_a_member_another_part_built_is_not_that_member():
    """A schedule part ("we delay the ambient dimensions ...") that says motion can also be encoded by the
    deformation another part already built is not refiled to that deformation: it built nothing of its own, so it
    stays unbuilt (a part filed elsewhere whose sentences state a member the plan lacks is still placed there)."""
    plan = _dynamic_plan()
    plan["scene"]["timestamps"] = True
    sentences = ["Motion can be encoded by a deformation network that maps each point into the canonical space, "
                 "or by moving along the ambient dimensions.",
                 "We therefore delay the use of the ambient dimensions for a number of iterations."]
    first, plan = _build("ScheduleHook", "model.schedule_hooks", sentences, plan=plan)
    assert isinstance(first, prose.ProseResult) and first.production == "FieldWrapper"  # the plan had none
    assert plan["model"]["field_wrappers"]["deformation"]
    again, plan = _build("ScheduleHook", "model.schedule_hooks", sentences, plan=plan)
    assert again.status == NOT_IMPLEMENTED and not isinstance(again, prose.ProseResult), again
