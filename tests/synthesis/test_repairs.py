"""Ladder repairs recorded in the plan survive recomposition: plan edits where the fix has a plan equivalent,
code repairs (file, unified diff) re-applied by the composer otherwise, and reported when they no longer apply."""

from __future__ import annotations

import difflib

import pytest

from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.compose import compose, write_plugin
from nerfify_ns.synthesis.repairs import DiffError, apply_diff, is_applied, parse_hunks
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.verify.plugin import load_plugin
from nerfify_ns.verify.repair import CodePatch, InterlevelLossFixer, record_in_plan
from nerfify_ns.verify.verdicts import Diagnosis

BEFORE = "".join(f"line {i}\n" for i in range(1, 21))


def _diff(before: str, after: str, name: str = "f.py") -> str:
    return "".join(difflib.unified_diff(before.splitlines(True), after.splitlines(True), f"a/{name}", f"b/{name}"))


def test_apply_diff_exactly_or_not_at_all():
    after = BEFORE.replace("line 5\n", "line five\n").replace("line 15\n", "-- line 15\n")
    diff = _diff(BEFORE, after)
    assert apply_diff(BEFORE, diff) == after
    assert is_applied(after, diff) and not is_applied(BEFORE, diff)
    moved = "header\n" * 3 + BEFORE  # a hunk may move, as with `patch`
    assert apply_diff(moved, diff) == "header\n" * 3 + after
    with pytest.raises(DiffError):
        apply_diff(BEFORE.replace("line 4\n", "line four\n"), diff)  # a context line changed
    removed = _diff(after, BEFORE)  # removes the line "-- line 15": not a header inside a hunk
    assert [len(h.old) for h in parse_hunks(removed)] == [7, 7] and apply_diff(after, removed) == BEFORE
    with pytest.raises(DiffError):
        parse_hunks("not a diff\n")


def _nerfacto(tmp_path, name: str, **plan_changes) -> tuple:
    plan = Plan.of(load_reference_plan("nerfacto"))
    for path, value in plan_changes.items():
        plan.set(path, value)
    return plan, compose(plan, tmp_path / name, record=False).out


def test_interlevel_repair_is_recorded_as_a_plan_edit(tmp_path):
    plan, plugin = _nerfacto(tmp_path, "weightless", **{"model.losses.interlevel.weight": 0.0})
    config = plugin / "nerfacto_ref" / "config.py"
    assert "interlevel_loss_mult=0.0" in config.read_text()
    found = Diagnosis("contract", "detached-parameter", "trainable parameter(s) proposal_networks.0.x receive "
                      "no gradient from the losses", "nerfacto_ref/model.py", 1)
    (patch,) = InterlevelLossFixer().propose(load_plugin(plugin), [found])
    recorded = Plan.load(plugin / "plan.yaml")
    lines = record_in_plan(recorded, [patch])
    assert recorded.get("model.losses.interlevel.weight") == 1.0 and "repairs" not in recorded, lines
    again = compose(recorded, tmp_path / "again", record=False)
    assert "interlevel_loss_mult=1.0" in (again.out / "nerfacto_ref" / "config.py").read_text()
    assert again.repairs == []


def test_code_repair_is_reapplied_after_rendering_or_reported(tmp_path):
    plan, plugin = _nerfacto(tmp_path, "original")
    rel = "nerfacto_ref/field.py"
    text = (plugin / rel).read_text()
    fixed = text.replace('"""', '"""Repaired by the ladder. ', 1)
    patch = CodePatch(rel, text, fixed, "stiff-case", "a code fix with no plan equivalent", "test-fixer")
    lines = record_in_plan(plan, [patch])
    assert plan["repairs"] == [{"file": rel, "rule": "stiff-case", "reason": patch.reason, "fixer": "test-fixer",
                                "diff": patch.diff().splitlines()}], lines
    record_in_plan(plan, [patch])
    assert len(plan["repairs"]) == 1  # recorded once
    saved = tmp_path / "plan.yaml"
    saved.write_text(plan.dump())
    folder = tmp_path / "recomposed"
    folder.mkdir()
    result = write_plugin(Plan.load(saved), folder)
    assert (folder / rel).read_text() == fixed
    assert [r["status"] for r in result.repairs] == ["applied"]
    assert "## Recorded repairs" in (folder / "README.md").read_text()
    assert Plan.load(folder / "plan.yaml")["repairs"] == plan["repairs"]  # carried forward

    healed = plan.copy()  # recorded against a broken rendering; the renderer now produces the fixed text
    broken = text.replace('"""', '"""Broken. ', 1)
    healed["repairs"] = [{**plan["repairs"][0], "diff": _diff(broken, text, rel).splitlines()}]
    healed_folder = tmp_path / "healed"
    healed_folder.mkdir()
    assert [o["status"] for o in write_plugin(healed, healed_folder).repairs] == ["already present"]
    assert (healed_folder / rel).read_text() == text

    stale = plan.copy()  # a repair recorded against lines the renderer no longer produces
    diff = patch.diff().splitlines()
    first_context = next(i for i, line in enumerate(diff) if i > 2 and line.startswith(" "))
    diff[first_context] = " # a line this rendering does not have"
    stale["repairs"][0]["diff"] = diff
    stale_folder = tmp_path / "stale"
    stale_folder.mkdir()
    outcome = write_plugin(stale, stale_folder).repairs
    assert [o["status"] for o in outcome] == ["does not apply"] and outcome[0]["detail"]
    assert (stale_folder / rel).read_text() == text  # left as rendered
    readme = (stale_folder / "README.md").read_text()
    assert "does not apply" in readme and "a code fix with no plan equivalent" in readme
