"""The broken-plugin corpus (tests/broken_plugins/): each is caught at the right rung with the right
rule and message; those with a deterministic fix are repaired and then pass; sandbox escapes are
stopped and reported while our process survives."""

import pytest
from verify_helpers import broken_plugin, corpus, load_case

from nerfify_ns.verify import run_ladder

BASE = "kplanes-static"
ORDER = ["static", "contract", "stability", "smoke"]


def _rungs(case: dict) -> list:
    if case.get("repaired"):
        return ORDER[:3]  # repaired plugins then pass every probe rung; smoke is covered by the references
    return ORDER[: ORDER.index(case["expect"]["rung"]) + 1]


def _marks(case: dict) -> list:
    """`slow: true` cases train (the smoke rung); `bench: true` repeats a verdict CI checks elsewhere."""
    return [getattr(pytest.mark, lane) for lane in ("slow", "bench") if case.get(lane)]


@pytest.mark.parametrize("name", [pytest.param(n, marks=_marks(load_case(n))) for n in corpus()])
def test_broken_plugin_is_caught(name, reference_plugins, tiny_scene, tmp_path):
    case = load_case(name)
    outside = tmp_path / "escaped.txt"
    plugin = broken_plugin(name, reference_plugins[BASE], tmp_path / "plugin", outside)
    expect = case["expect"]
    report = run_ladder(
        plugin,
        scene=tiny_scene,
        out_dir=tmp_path / "out",
        repair=True,
        rungs=_rungs(case),
        timeout=case.get("timeout", 240),
        smoke_iterations=20,
    )
    # the first failing rung of some round (a deterministic repair may fix something else first, e.g. the
    # exp guard the reference plugins still need) is the expected one, with the expected rule and message
    caught = [
        next(r for r in rnd if r.status == "fail")
        for rnd in report.rounds
        if any(r.status == "fail" for r in rnd)
    ]
    assert caught, f"{name}: nothing caught: {[(r.name, r.status) for r in report.rounds[0]]}"
    hits = [
        d
        for r in caught
        if r.name == expect["rung"]
        for d in r.failures
        if d.rule == expect["rule"] and expect["message"] in d.message
    ]
    assert hits, f"{name}: expected {expect}, got {[(r.name, [str(d) for d in r.failures]) for r in caught]}"
    if expect["rung"] in ("static", "contract") and expect["rule"] != "timeout":
        assert any(d.file for d in hits), f"{name}: diagnosis names no file: {[str(d) for d in hits]}"
    if case.get("repaired"):
        assert caught[0].name == expect["rung"], "a repaired plugin is caught in the first round"
        assert report.ok and report.patches, f"{name}: not repaired: {[str(d) for d in report.failures]}"
        assert list((tmp_path / "out" / "patches").glob("*.diff"))
    else:
        assert not report.ok, f"{name}: the ladder passed a broken plugin"
    if case.get("sandbox"):
        assert not outside.exists(), "the plugin wrote outside its folder"
    assert (tmp_path / "out" / "verify.json").is_file()
