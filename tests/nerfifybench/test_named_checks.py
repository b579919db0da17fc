"""Novelty checks found by name and items found where the run built them: an item the suite names no check for is
checked by ``checks/<paper id>.py:<item id>`` when the suite folder has that function (found without running the
file); an item with no plan path is found at the slot of a hole the run built for it (a typed part from the
paper's sentences), not counted missing; and on the development suite (skips without ../shared) every item a run
of the pipeline finds has a check, so no found item is counted I only for want of one."""

from __future__ import annotations

from pathlib import Path

import pytest

from nerfify_ns.nerfifybench import load_suite
from nerfify_ns.nerfifybench.novelty import locate
from nerfify_ns.nerfifybench.suite import NoveltyItem

ROOT = Path(__file__).resolve().parents[2]
DEV = ROOT / "examples" / "bench" / "dev.yaml"
SHARED = ROOT.parent / "shared" / "papers"

SUITE = """
budget: {iterations: 4, every: 2}
papers:
  - id: p1
    input: paper.md
    scenes: [default]
    reference: nerfacto
    novelty:
      - {id: time-offsets, kind: architecture, weight: 1.0, where: "Sec. 3"}
      - {id: colour-loss, kind: loss, weight: 1.0, where: "Eq. 2", check: "own.py:given"}
      - {id: no-such-check, kind: loss, weight: 1.0, where: "Eq. 3"}
"""


def test_a_check_named_after_the_item_is_found(tmp_path):
    (tmp_path / "checks").mkdir()
    (tmp_path / "checks" / "p1.py").write_text("import not_installed_anywhere\n\n\ndef time_offsets(target):\n"
                                               "    return True\n\n\ndef colour_loss(target):\n    return False\n")
    (tmp_path / "own.py").write_text("def given(target):\n    return True\n")
    (tmp_path / "paper.md").write_text("# P1\n")
    path = tmp_path / "suite.yaml"
    path.write_text(SUITE)
    (paper,) = load_suite(path).papers
    offsets, loss, none = paper.novelty
    assert offsets.check == ((tmp_path / "checks" / "p1.py").resolve(), "time_offsets")  # the import never ran
    assert loss.check == ((tmp_path / "own.py").resolve(), "given")  # the suite's own check stands
    assert none.check is None


def test_an_item_without_a_plan_path_is_found_at_the_hole_built_for_it():
    item = NoveltyItem(id="time-offsets", kind="architecture", weight=1.0, where="Sec. 3.3", production="FieldWrapper",
                       phrases=("one time offset per camera",))
    plan = {"model": {"field_wrappers": {"camera_time_offset": {"init": 0.0}}},
            "holes": [{"production": "FieldWrapper", "slot": "model.field_wrappers", "status": "implemented",
                       "text": "We learn one time offset per camera, initialised to 0."}]}
    assert locate(item, plan) == ("model.field_wrappers", None)
    plan["holes"][0]["status"] = "not implemented"  # reverted by the ladder: not found
    assert locate(item, plan) == ("", None)
    plan["holes"][0].update(status="implemented", production="Renderer")  # another production's hole
    assert locate(item, plan) == ("", None)


@pytest.mark.slow
def test_every_item_the_pipeline_finds_in_the_dev_suite_has_a_check():
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} not present (../shared/papers is outside the project and never committed)")
    from nerfify_ns.pipeline import PaperOptions, run_paper

    unchecked = []
    for entry in load_suite(DEV).papers:
        if not entry.input.is_file():
            continue
        plan = dict(run_paper(entry.input, options=PaperOptions(dry_run=True)).implementation.plan)
        unchecked += [f"{entry.id}:{i.id}" for i in entry.novelty if locate(i, plan)[0] and i.check is None]
    assert not unchecked, unchecked


def test_a_part_compiled_into_a_slot_of_several_is_found_at_its_own_entry():
    """A regulariser compiled from unnumbered equations sits beside the base's regularisers
    (``model.regularizers.custom_regularizers``): the item is found at that entry, with its component, through the
    hole built for it; a hole reverted by the ladder is not found."""
    item = NoveltyItem(id="parsimony", kind="loss", weight=0.5, where="Sec. 4", production="Regularizers",
                       phrases=("penalising the moving field's share",))
    entry = {"module": "components.regularizers_equations", "class": "RegularizersFromEquations", "weight": 0.1}
    plan = {"model": {"regularizers": {"plane_tv": {"weight": 2e-4}, "custom_regularizers": entry}},
            "holes": [{"production": "Regularizers", "slot": "model.regularizers", "status": "implemented",
                       "compiled": "components.regularizers_equations",
                       "text": "A prior penalising the moving field's share of every sample."}]}
    assert locate(item, plan) == ("model.regularizers.custom_regularizers", entry)
    plan["holes"][0]["status"] = "not implemented"
    assert locate(item, plan) == ("", None)
