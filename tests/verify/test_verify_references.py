"""The ladder passes every reference plan's plugin (composed after pruning for the tiny scene): static and
contract rungs on all six (CI keeps one of each kind of field: nerfacto's hash grid, vanilla-nerf's MLP, tensorf's
tensors; the others in the benchmark lane); the full ladder, smoke training included, on kplanes-static."""

import json
import shutil

import pytest

from nerfify_ns.synthesis.resources import reference_plans
from nerfify_ns.verify import component_suite, run_ladder
from nerfify_ns.verify.components import suite_components

IN_CI = {"nerfacto", "vanilla-nerf", "tensorf"}


@pytest.mark.slow
@pytest.mark.parametrize("name", [pytest.param(n, marks=[] if n in IN_CI else [pytest.mark.bench])
                                  for n in reference_plans()])
def test_static_and_contract_pass(name, reference_plugins, tmp_path):
    report = run_ladder(reference_plugins[name], out_dir=tmp_path, rungs=["static", "contract"], repair=False)
    assert report.ok, [str(d) for d in report.failures]
    assert [r.name for r in report.rungs] == ["static", "contract"]


@pytest.mark.slow
def test_full_ladder_kplanes_static(reference_plugins, tiny_scene, tmp_path):
    plugin = shutil.copytree(reference_plugins["kplanes-static"], tmp_path / "plugin")
    report = run_ladder(plugin, scene=tiny_scene, out_dir=tmp_path / "out", smoke_iterations=20, timeout=300)
    assert report.ok, [str(d) for d in report.failures]
    smoke = report.rung("smoke")
    assert smoke.status == "pass" and smoke.details["iterations"] == 20
    assert smoke.details["photometric_last"] < smoke.details["photometric_first"]
    assert "no-network" in smoke.details["isolation"] and "read-only-fs" in smoke.details["isolation"]
    # after training the recorder timed a step at the rung's batch and at 4x it: what the rays cost of a step
    cost = smoke.details["ray_cost"]
    assert cost["rays"][1] == 4 * cost["rays"][0] and all(t > 0 for t in cost["seconds"])
    assert cost["seconds_per_ray"] >= 0
    # with the threads training will have, and the rung's own: how much faster training's threads make a step
    assert 1.0 <= cost["speedup"] <= cost["threads"] / cost["rung_threads"]
    data = json.loads((tmp_path / "out" / "verify.json").read_text())
    cases = [c for r in data["rungs"] if r["name"] == "stability" for c in r["details"]["cases"]]
    assert {c["case"] for c in cases if c["component"] == "<model>"} >= {
        "far_1e5",
        "near_eq_far",
        "grazing_rays",
        "density_1e8",
        "scene_scale_1e3",
    }
    for p in report.patches:  # every repair is recorded as a revertible unified diff
        assert p["diff"].endswith(".diff") and "patch -R" in p["revert"]


@pytest.mark.slow
def test_component_suite_every_terminal(tmp_path):
    """Every terminal with a contract on every stiff case; no component of ours fails any case."""
    result = component_suite(tmp_path)
    assert result.ok, [str(d) for d in result.failures]
    cases = result.details["cases"]
    assert {c["component"] for c in cases} == {name for name, *_ in suite_components()}
    ours = [c for c in cases if c["owner"] == "ours"]
    assert ours and all(c["status"] in ("pass", "n/a") for c in ours)
    assert {"kplanes", "charbonnier", "plane_tv", "KPlanesDensityField"} <= {c["component"] for c in ours}
