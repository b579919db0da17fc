"""The smoke rung starts beside the checks (static, contract, stability: one sandboxed process) once the files
parse, so the two Nerfstudio start-ups overlap; a failing check calls it off (its process killed) and the ladder
reports it skipped, as if it had run after them. The rungs are stood in for by real processes (``sleep``)."""

from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path

from nerfify_ns.dataset import as_dataset
from nerfify_ns.runtime.process import run_process
from nerfify_ns.verify import ladder as ladder_mod
from nerfify_ns.verify.smoke_rung import SmokeCancelled, cancellable
from nerfify_ns.verify.verdicts import Diagnosis, RungResult


def _fake_rungs(monkeypatch, tmp_path: Path, probe_fails: bool, probe_seconds: float = 1.5) -> dict:
    """The probe sleeps and passes or fails; the smoke rung runs ``sleep 30`` (a real process) and records when
    it started, ended and whether it was killed."""
    seen: dict = {}

    def probe(info, rungs, workdir, **kw):
        seen["probe_start"] = time.perf_counter()
        time.sleep(probe_seconds)
        seen["probe_end"] = time.perf_counter()
        out = {name: RungResult(name) for name in rungs}
        if probe_fails:
            out["contract"].fail(Diagnosis("contract", "shape", "wrong shape"))
            out.pop("stability")
        return out

    def smoke(info, scene, workdir, *, cancel=None, **kw):
        seen["smoke_start"] = time.perf_counter()
        seen["smoke_thread"] = threading.current_thread().name
        workdir.mkdir(parents=True, exist_ok=True)
        try:
            run_process(["sleep", "30" if probe_fails else "0.2"], workdir / "sleep.log", cwd=workdir, timeout=60,
                        poll=cancellable(None, cancel), poll_seconds=0.1)
        except SmokeCancelled:
            seen["killed_after"] = time.perf_counter() - seen["smoke_start"]
            raise
        return RungResult("smoke", details={"ran": True})

    monkeypatch.setattr(ladder_mod, "run_probe", probe)
    monkeypatch.setattr(ladder_mod, "smoke_rung", smoke)
    monkeypatch.setattr(ladder_mod, "static_ast", lambda info, workdir, **kw: RungResult("static"))
    return seen


def _plugin(reference_plugins, tmp_path: Path) -> Path:
    plugin = tmp_path / "plugin"
    shutil.copytree(reference_plugins["vanilla-nerf"], plugin)
    return plugin


def test_the_smoke_rung_runs_beside_the_checks(reference_plugins, tiny_scene, monkeypatch, tmp_path):
    seen = _fake_rungs(monkeypatch, tmp_path, probe_fails=False)
    report = ladder_mod.run_ladder(_plugin(reference_plugins, tmp_path), scene=tiny_scene, out_dir=tmp_path / "out",
                                   repair="off")
    assert [(r.name, r.status) for r in report.rungs] == [("static", "pass"), ("contract", "pass"),
                                                          ("stability", "pass"), ("smoke", "pass")]
    assert report.rungs[-1].details["ran"]
    assert seen["smoke_start"] < seen["probe_end"]  # started before the checks ended
    assert seen["smoke_thread"] == "smoke-rung"


def test_a_failing_check_calls_the_smoke_rung_off(reference_plugins, tiny_scene, monkeypatch, tmp_path):
    seen = _fake_rungs(monkeypatch, tmp_path, probe_fails=True)
    start = time.perf_counter()
    report = ladder_mod.run_ladder(_plugin(reference_plugins, tmp_path), scene=tiny_scene, out_dir=tmp_path / "out",
                                   repair="off")
    assert time.perf_counter() - start < 20  # the 30 s smoke process was killed, not waited for
    assert seen["killed_after"] < 20
    statuses = {r.name: r.status for r in report.rungs}
    assert statuses["contract"] == "fail" and statuses["smoke"] == "skip"
    assert report.rungs[-1].notes == ["an earlier rung failed"]


def test_without_overlap_the_smoke_rung_waits_for_the_checks(reference_plugins, tiny_scene, monkeypatch, tmp_path):
    seen = _fake_rungs(monkeypatch, tmp_path, probe_fails=False, probe_seconds=0.5)
    plugin = _plugin(reference_plugins, tmp_path)
    info = ladder_mod.load_plugin(plugin)
    st = ladder_mod._Settings(list(ladder_mod.RUNGS), as_dataset(tiny_scene), 5, 60.0, [], 0, overlap=False)
    results = ladder_mod._round(plugin, tmp_path / "work", st)
    assert info.root == plugin.resolve() and [r.status for r in results] == ["pass"] * 4
    assert seen["smoke_start"] >= seen["probe_end"]
