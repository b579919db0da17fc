"""A technique added as one card and one terminal definition (random Fourier features, Tancik et al. 2020)
is detected in a paper, placed in the derived plan with its evidence, composed, and passes every rung of
the ladder, smoke training included."""

from __future__ import annotations

from pathlib import Path

import pytest

from nerfify_ns.paper import ingest
from nerfify_ns.registry import default_registry
from nerfify_ns.scenes import write_scene
from nerfify_ns.synthesis.compose import compose
from nerfify_ns.synthesis.plan_from_paper import plan_from_paper
from nerfify_ns.synthesis.prune import prune_plan
from nerfify_ns.synthesis.scene_probe import probe_scene
from nerfify_ns.verify import run_ladder

PAPER = Path(__file__).resolve().parents[2] / "examples" / "fourierfield_paper.md"
SLOT = "model.field.MLPField.pos_encoding"


@pytest.fixture(scope="module")
def derived():
    return plan_from_paper(ingest(PAPER))


def test_the_technique_is_one_registry_entry_with_a_card():
    term = default_registry()["fourier_features"]
    assert term.card == "fourier_features" and term.production == "PosEncoding"
    assert term.implementation == "nerfstudio.field_components.encodings.RFFEncoding"


def test_the_paper_gets_random_fourier_features_with_evidence(derived):
    assert derived.plan.get(SLOT) == {
        "fourier_features": {"num_frequencies": 128, "scale": 4.0, "include_input": False}}
    assert "mapping size of m = 128" in derived.plan.evidence_for(f"{SLOT}.fourier_features.scale")
    evidence = derived.plan.evidence_for(SLOT)
    assert "random Fourier features" in evidence and "3.1" in evidence
    assert any("positional_encoding" in n and "less surely" in n for n in derived.plan.notes)


@pytest.mark.slow
def test_the_composed_plugin_passes_every_rung_and_trains(derived, tmp_path):
    scene = write_scene("default", tmp_path / "scene", resolution=32, n_train=12, n_val=2, n_test=2)
    plan = prune_plan(derived.plan, probe_scene(scene))
    plugin = compose(plan, tmp_path / "plugin", record=False)
    assert "RFFEncoding(" in (plugin.out / plugin.package / "field.py").read_text()
    report = run_ladder(plugin.out, scene=scene, out_dir=tmp_path / "verify", smoke_iterations=30, repair="off")
    assert report.ok, [str(d) for d in report.failures]
    smoke = report.rung("smoke")
    assert smoke.details["iterations"] == 30 and smoke.details["photometric_last"] < smoke.details["photometric_first"]
