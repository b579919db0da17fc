"""Parts stated in prose with their sizes in words, through the real pipeline: a paper of our own
(tests/data/papers/prose_sizes.md, LoomNeRF, a dynamic scene) states three parts in sentences, each in a section
of its own: encoded inputs re-fed to every layer of a backbone of "six layers with sixty-four channels", a second
field that ignores time blended by density, and one learned time offset per camera. Each is built from its
sentence (the record quotes it, the sizes are read from words), the re-fed inputs are the backbone's wiring (not a
positional encoding, wherever the derivation first filed the part), what the paper does not state is asked in
equations.yaml; then ``ns-nerfify``'s own path (ingest, plan, implement, plugin, the sandboxed ladder, training)
passes every rung and trains (slow)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import yaml

from nerfify_ns.synthesis.novel import IMPLEMENTED, prose

PAPER = Path(__file__).resolve().parents[1] / "data" / "papers" / "prose_sizes.md"


@pytest.fixture(scope="module")
def built():
    from nerfify_ns.pipeline import PaperOptions, run_paper

    return run_paper(PAPER, options=PaperOptions(dry_run=True)).implementation


def _part(record, name):
    return next(p for p in record.parts if p["part"] == name)


def test_numbers_in_words_are_read():
    spec = prose.load_spec()
    assert [prose.word_number(spec, t) for t in ("six", "sixty-four", "two hundred and fifty-six",
                                                 "one hundred twenty-eight", "nineteen", "tint")] == [
        6, 64, 256, 128, 19, None]


def test_inputs_to_every_layer_are_the_backbones_wiring_with_its_size_in_words(built):
    backbone = built.plan.get("model.field.MLPField.backbone")
    assert backbone["skip_every_layer"] is True
    assert (backbone["num_layers"], backbone["layer_width"]) == (6, 64)
    record = next(r for r in built.records if any(p["part"] == "inputs_to_every_layer" for p in r.parts))
    assert record.production == "Backbone" and record.slot == "model.field.MLPField.backbone"
    assert record.status == IMPLEMENTED
    hole = next(h for h in built.plan["holes"] if h.get("slot") == record.slot)
    assert hole["production"] == "Backbone"  # the plan's hole, the report and the survey name the real production
    every = _part(record, "inputs_to_every_layer")
    assert "re-fed to every layer" in every["statement"]["quote"]
    size = _part(record, "backbone_size")["parameters"]
    for name in ("num_layers", "layer_width"):
        assert size[name]["source"] == "paper" and "six layers with sixty-four channels" in size[name]["quote"]


def test_a_density_blended_second_field_and_per_camera_offsets_from_their_own_sections(built):
    wrappers = built.plan["model"]["field_wrappers"]
    assert wrappers["field_blend"]["mode"] == "density" and wrappers["field_blend"]["num_fields"] == 2
    assert wrappers["field_blend"]["static_first"] is True  # "a second field that ignores time"
    assert wrappers["camera_time_offset"] == {"init": 0.0}
    record = next(r for r in built.records if r.production == "FieldWrapper")
    assert record.status == IMPLEMENTED and not record.asked
    blend = _part(record, "field_blend")
    assert "blended by their densities" in blend["parameters"]["mode"]["quote"]
    assert "ignores time" in blend["parameters"]["static_first"]["quote"]
    offset = _part(record, "camera_time_offset")
    assert "one time offset per camera" in offset["statement"]["quote"]
    assert offset["parameters"]["init"]["source"] == "paper"


def test_an_unstated_size_keeps_the_bases_value_and_is_asked():
    from nerfify_ns.plan import Plan
    from nerfify_ns.synthesis.novel.implement import HoleResult
    from nerfify_ns.synthesis.resources import load_reference_plan

    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    base = dict(plan.get("model.field.MLPField.backbone"))
    text = ["The encoded inputs are fed to every layer of the trunk.", "The trunk has 4 layers."]
    hole = {"production": "Backbone", "slot": "model.field.MLPField.backbone", "section": "3 Method",
            "text": " ".join(text), "claim": "", "where": "Sec. 3"}
    compiled = HoleResult(id="backbone", slot=hole["slot"], production="Backbone", section="3 Method",
                          reason="no equation")
    result = prose.build(hole, [(s, "Sec. 3", "3 Method") for s in text], plan, None, compiled)
    backbone = plan.get("model.field.MLPField.backbone")
    assert backbone["num_layers"] == 4 and backbone["layer_width"] == base["layer_width"]
    assert result.asked["backbone_size.layer_width"]["value"] == base["layer_width"]
    assert "base plan's value" in result.asked["backbone_size.layer_width"]["why"]


def test_a_size_alone_is_no_novel_part():
    from nerfify_ns.plan import Plan
    from nerfify_ns.synthesis.novel.implement import NOT_IMPLEMENTED, HoleResult
    from nerfify_ns.synthesis.resources import load_reference_plan

    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    before = dict(plan.get("model.field.MLPField.backbone"))
    text = ["Our backbone has twelve layers of 128 channels."]
    hole = {"production": "Backbone", "slot": "model.field.MLPField.backbone", "section": "3 Method",
            "text": text[0], "claim": "", "where": "Sec. 3"}
    compiled = HoleResult(id="backbone", slot=hole["slot"], production="Backbone", section="3 Method",
                          reason="no equation")
    result = prose.build(hole, [(text[0], "Sec. 3", "3 Method")], plan, None, compiled)
    assert result is compiled and result.status == NOT_IMPLEMENTED
    assert dict(plan.get("model.field.MLPField.backbone")) == before


def test_a_member_stated_elsewhere_by_citing_sentence_is_not_built():
    from test_field_wrappers import small

    from nerfify_ns.plan import Plan
    from nerfify_ns.synthesis.novel.implement import HoleResult
    from nerfify_ns.synthesis.resources import load_reference_plan

    plan = small(Plan.of(load_reference_plan("kplanes-time")), "prose-cite")  # space-time planes read the times
    own = "We learn one time offset per camera, initialised to 0."
    other = "D-NeRF [7] uses a deformation network that maps each sample into a canonical space."
    hole = {"production": "FieldWrapper", "slot": "model.field_wrappers", "section": "3.2 Clocks", "text": own,
            "claim": "", "where": "Sec. 3.2"}
    compiled = HoleResult(id="field_wrappers", slot=hole["slot"], production="FieldWrapper", section="3.2 Clocks",
                          reason="no equation")
    sentences = [(own, "Sec. 3.2", "3.2 Clocks"), (other, "Sec. 3.1", "3.1 Motion")]
    result = prose.build(hole, sentences, plan, None, compiled)
    assert {p["part"] for p in result.parts} == {"camera_time_offset"}
    assert "deformation" not in plan["model"]["field_wrappers"]


@pytest.mark.slow
def test_the_paper_passes_every_rung_of_the_sandboxed_ladder_and_trains(tmp_path):
    from nerfify_ns.budget import Budget
    from nerfify_ns.pipeline import PaperOptions, run_paper
    from nerfify_ns.runtime.events import losses, read_scalars

    # the dynamic base (k-planes over space and time) needs 60 steps for the smoke rung's 10% fall of the error
    budget = Budget(iterations=60, every=60, smoke_iterations=60, cpu_presets=True,
                    train_args=("--pipeline.datamanager.train-num-rays-per-batch", "256"),
                    scene={"resolution": 32, "n_train": 12, "n_val": 2, "n_test": 2})
    result = run_paper(PAPER, tmp_path / "run", options=PaperOptions(budget=budget))
    assert result.outcome.failed is None, result.outcome.failed
    ladder = json.loads((result.out / "verify.json").read_text())
    assert ladder["ok"] and [r["name"] for r in ladder["rungs"]] == ["static", "contract", "stability", "smoke"]
    checked = {c["component"] for r in ladder["rungs"] for c in (r.get("details") or {}).get("cases", [])
               if c["status"] == "pass"}
    assert {"camera_time_offset", "field_blend", "mlp"} <= checked, checked
    records = yaml.safe_load((result.out / "equations.yaml").read_text())
    assert all(h["status"] == IMPLEMENTED for h in records["holes"]), [(h["id"], h["reason"]) for h in
                                                                       records["holes"]]
    plan = yaml.safe_load((result.out / "plan.yaml").read_text())
    assert plan["model"]["field"]["MLPField"]["backbone"]["skip_every_layer"] is True
    assert {"camera_time_offset", "field_blend"} <= set(plan["model"]["field_wrappers"])
    runs = [p.parent for p in (result.out / "eval" / "train").rglob("events.out.tfevents*")]
    values = [v for _, v in sorted(losses(read_scalars(runs[0])).items())]
    k = max(1, len(values) // 5)
    assert all(math.isfinite(v) for v in values) and sum(values[-k:]) / k < sum(values[:k]) / k, values


def test_branches_and_a_time_embedding_with_sizes_in_words():
    from test_field_wrappers import small

    from nerfify_ns.plan import Plan
    from nerfify_ns.synthesis.novel.implement import HoleResult
    from nerfify_ns.synthesis.resources import load_reference_plan

    plan = small(Plan.of(load_reference_plan("vanilla-nerf")), "prose-words")
    text = ["We embed the continuous time with a small MLP into a learned time embedding.",
            "The time embedding network has three layers of forty-eight units and outputs a twelve-dimensional "
            "time embedding."]
    hole = {"production": "FieldWrapper", "slot": "model.field_wrappers", "section": "3 Method",
            "text": " ".join(text), "claim": "", "where": "Sec. 3"}
    compiled = HoleResult(id="field_wrappers", slot=hole["slot"], production="FieldWrapper", section="3 Method",
                          reason="no equation")
    result = prose.build(hole, [(s, "Sec. 3", "3 Method") for s in text], plan, None, compiled)
    embedding = plan["model"]["field_wrappers"]["time_embedding"]
    assert (embedding["num_layers"], embedding["layer_width"], embedding["out_dim"]) == (3, 48, 12), embedding
    assert result.status == IMPLEMENTED and set(result.asked) == {"time_embedding.num_frequencies"}

    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    text = ["After the shared trunk the network has separate branches for density and colour.",
            "The density branch has two layers of sixty-four units, and the colour branch has one layer of "
            "ninety-six units."]
    hole = {"production": "Backbone", "slot": "model.field.MLPField.backbone", "section": "3 Method",
            "text": " ".join(text), "claim": "", "where": "Sec. 3"}
    compiled = HoleResult(id="backbone", slot=hole["slot"], production="Backbone", section="3 Method",
                          reason="no equation")
    prose.build(hole, [(s, "Sec. 3", "3 Method") for s in text], plan, None, compiled)
    backbone = plan.get("model.field.MLPField.backbone")
    assert (backbone["density_layers"], backbone["density_width"], backbone["color_layers"],
            backbone["color_width"]) == (2, 64, 1, 96), backbone
