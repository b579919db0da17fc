"""``ns-nerfify verify DIR`` reports before it changes anything; ``--fix`` repairs keeping the author's intent;
a generated plugin's repairs are recorded in its plan and survive recomposition. Static rung only (a sandboxed
probe that builds the model: about 20-40 s a round on 2 cores)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.compose import compose, write_plugin
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.verify import revert_patches, run_ladder

pytestmark = pytest.mark.slow

CONFIG = "nerfacto_ref/config.py"
GOOD_KEY, BAD_KEY = '"proposal_networks": {', '"proposal_network": {'
DISTINCT_LR = "lr=0.0123"


def _misspelled_plugin(out: Path) -> Path:
    """The nerfacto reference plugin with its proposal optimiser's key misspelled and a distinctive lr."""
    plugin = compose(load_reference_plan("nerfacto"), out, record=False).out
    config = plugin / CONFIG
    text = config.read_text()
    start = text.index(GOOD_KEY)
    lr = text.index("lr=", start)
    text = text[:start] + BAD_KEY + text[start + len(GOOD_KEY):lr] + DISTINCT_LR + text[text.index(",", lr):]
    config.write_text(text)
    return plugin


def _verify(*args: str) -> subprocess.CompletedProcess:
    cli = Path(sys.executable).with_name("ns-nerfify")
    return subprocess.run([str(cli), "verify", *args, "--rungs", "static"], capture_output=True, text=True,
                          timeout=900, env={"COLUMNS": "200", "PATH": "/usr/bin:/bin", "HOME": str(Path.home())})


def test_verify_reports_then_fix_renames_the_key(tmp_path):
    plugin = _misspelled_plugin(tmp_path / "plugin")
    files = {p: p.read_bytes() for p in plugin.rglob("*") if p.is_file()}

    reported = _verify(str(plugin), "--out", str(tmp_path / "report"))
    assert reported.returncode == 1, reported.stdout + reported.stderr
    assert {p: p.read_bytes() for p in plugin.rglob("*") if p.is_file()} == files, "report-only changed files"
    diff = (tmp_path / "report" / "repair.diff").read_text()
    config_diff, plan_diff = diff.split("--- a/plan.yaml")  # the config, then the plan recording it
    changed = [line for line in config_diff.splitlines() if line[:1] in "+-" and line[:3] not in ("+++", "---")]
    assert changed == [f"-            {BAD_KEY}", f"+            {GOOD_KEY}"], changed  # a rename, lr kept
    assert config_diff.startswith("--- a/nerfacto_ref/config.py") and "+repairs:" in plan_diff
    assert f"+            {GOOD_KEY}" in reported.stdout and "apply it with" in reported.stdout
    data = json.loads((tmp_path / "report" / "verify.json").read_text())
    assert data["ok"] is False and data["repair"] == "propose" and data["proposal"]["ok"] is True
    assert data["failures"][0]["rule"] == "param-groups"

    fixed = _verify(str(plugin), "--out", str(tmp_path / "fix"), "--fix")
    assert fixed.returncode == 0, fixed.stdout + fixed.stderr
    text = (plugin / CONFIG).read_text()
    start = text.index(GOOD_KEY)
    assert BAD_KEY not in text and text.index(DISTINCT_LR, start) < text.index('"scheduler"', start)
    data = json.loads((tmp_path / "fix" / "verify.json").read_text())
    assert data["ok"] and [r["status"] for r in data["rungs"]] == ["pass"] and data["repair"] == "apply"
    assert [p["file"] for p in data["patches"]] == [CONFIG, "plan.yaml"]  # the plan records the repair

    from nerfify_ns.verify.verdicts import LadderReport

    revert_patches(LadderReport(plugin=str(plugin), patches=data["patches"]))  # revertible, as before
    assert {p: p.read_bytes() for p in plugin.rglob("*") if p.is_file() and ".verify" not in p.parts} == files


def test_generated_plugin_repair_survives_recomposition(tmp_path, monkeypatch):
    """A renderer that misspells the proposal optimiser (a template bug) -> the ladder repairs the plugin and
    records the code repair in its plan.yaml -> rendering that plan again (same bug) re-applies it."""
    from nerfify_ns.synthesis import compose as composer

    render = composer._render

    def buggy(env, f, ctx, plan, sources):
        text = render(env, f, ctx, plan, sources)
        return text.replace(GOOD_KEY, BAD_KEY) if f.path.endswith("config.py") else text

    monkeypatch.setattr(composer, "_render", buggy)
    plan = load_reference_plan("nerfacto")
    plugin = compose(plan, tmp_path / "plugin", record=False).out
    assert BAD_KEY in (plugin / CONFIG).read_text()
    report = run_ladder(plugin, out_dir=tmp_path / "verify", rungs=["static"], repair="apply")
    assert report.ok and [p["file"] for p in report.patches] == [CONFIG, "plan.yaml"], report.notes
    recorded = Plan.load(plugin / "plan.yaml")
    (entry,) = recorded["repairs"]
    assert entry["file"] == CONFIG and entry["rule"] == "param-groups" and "renamed" in entry["reason"]

    control = tmp_path / "control"
    control.mkdir()
    write_plugin(plan, control)  # the same plan without the recorded repair: the bug is back
    assert BAD_KEY in (control / CONFIG).read_text()

    again = tmp_path / "again"
    again.mkdir()
    result = write_plugin(recorded, again)
    assert [r["status"] for r in result.repairs] == ["applied"]
    assert GOOD_KEY in (again / CONFIG).read_text() and BAD_KEY not in (again / CONFIG).read_text()
    assert "Recorded repairs" in (again / "README.md").read_text()
    checked = run_ladder(again, out_dir=tmp_path / "verify-again", rungs=["static"], repair="off")
    assert checked.ok, [str(d) for d in checked.failures]
