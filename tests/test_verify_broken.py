"""The broken-plugin corpus (tests/broken_plugins/): each is caught at the right rung with the right
rule and message; those with a deterministic fix are repaired and then pass; sandbox escapes are
stopped and reported while our process survives."""

import pytest

from nerfify_ns.verify import run_ladder

from verify_helpers import broken_plugin, corpus, load_case, reference_plugins  # noqa: F401  (fixture)

BASE = "kplanes-static"


def _rungs(case: dict) -> list:
    order = ["static", "contract", "stability", "smoke"]
    if case.get("repaired"):
        return order[:3]  # repaired plugins then pass every probe rung; smoke is covered by the references
    return order[: order.index(case["expect"]["rung"]) + 1]


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if load_case(n).get("slow") else n
                                  for n in corpus()])
def test_broken_plugin_is_caught(name, reference_plugins, tiny_scene, tmp_path):
    case = load_case(name)
    outside = tmp_path / "escaped.txt"
    plugin = broken_plugin(name, reference_plugins[BASE], tmp_path / "plugin", outside)
    expect = case["expect"]
    report = run_ladder(plugin, scene=tiny_scene, out_dir=tmp_path / "out", repair=bool(case.get("repaired")),
                        rungs=_rungs(case), timeout=case.get("timeout", 240), smoke_iterations=20)
    first = report.rounds[0]
    failed = [r for r in first if r.status == "fail"]
    assert failed, f"{name}: nothing caught: {[(r.name, r.status) for r in first]}"
    rung = failed[0]
    assert rung.name == expect["rung"], f"{name}: caught at {rung.name}: {[str(d) for d in rung.failures]}"
    hits = [d for d in rung.failures if d.rule == expect["rule"] and expect["message"] in d.message]
    assert hits, f"{name}: expected {expect}, got {[str(d) for d in rung.failures]}"
    if expect["rung"] in ("static", "contract") and expect["rule"] not in ("timeout",):
        assert any(d.file for d in hits), f"{name}: diagnosis names no file: {[str(d) for d in hits]}"
    if case.get("repaired"):
        assert report.ok and report.patches, f"{name}: not repaired: {[str(d) for d in report.failures]}"
        assert all((tmp_path / "out" / "patches").glob("*.diff"))
    if case.get("sandbox"):
        assert not outside.exists(), "the plugin wrote outside its folder"
    assert (tmp_path / "out" / "verify.json").is_file()
