"""Run the probe (static, contract, stability rungs) in the sandbox and read its events back."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Dict, List, Optional, Sequence

from nerfify_ns.verify.plugin import PluginInfo
from nerfify_ns.verify.report import Diagnosis, RungResult
from nerfify_ns.verify.sandbox import python_cmd, run_sandboxed
from nerfify_ns.verify.static import ast_checks

PROBE_RUNGS = ("static", "contract", "stability")


def read_probe_events(path: Path) -> List[dict]:
    """The probe's JSON-lines events (a line cut off by a crash is skipped)."""
    if not path.exists():
        return []
    events = []
    for line in path.read_text(errors="replace").splitlines():
        try:
            events.append(json.loads(line))
        except ValueError:
            pass
    return events


def run_probe(
    info: Optional[PluginInfo], rungs: Sequence[str], workdir: Path, *, timeout: float, suite: str = "plan"
) -> Dict[str, RungResult]:
    """Probe ``rungs`` in one sandboxed process; a rung it never finished is failed (timeout or crash)."""
    workdir.mkdir(parents=True, exist_ok=True)
    events_path = workdir / "events.jsonl"
    events_path.unlink(missing_ok=True)
    plugin = str(info.root) if info else "-"
    start = time.perf_counter()
    result = run_sandboxed(
        python_cmd(
            "nerfify_ns.verify.probe", plugin, str(events_path), "--rungs", ",".join(rungs), "--suite", suite
        ),
        workdir,
        timeout=timeout,
        log_name="probe.log",
    )
    events = read_probe_events(events_path)
    rungs_out: Dict[str, RungResult] = {}
    started: Dict[str, float] = {}
    for e in events:
        rung = e.get("rung")
        if rung not in rungs:
            continue
        r = rungs_out.setdefault(rung, RungResult(rung))
        kind = e.get("event")
        if kind == "start":
            started[rung] = time.perf_counter()
        elif kind == "end":
            r.details["finished"] = True
        elif kind == "diagnosis":
            r.fail(Diagnosis.from_dict(e))
        elif kind in ("case", "component"):
            r.checks += 1
            r.details.setdefault("cases", []).append(
                {
                    k: e.get(k)
                    for k in ("component", "implementation", "owner", "case", "status", "problems", "path")
                }
            )
    for rung in rungs:
        r = rungs_out.get(rung)
        if r is None:
            if any(not x.ok or not x.details.get("finished") for x in rungs_out.values()):
                continue  # an earlier rung failed or never finished: this one did not run
            rungs_out[rung] = r = RungResult(rung)
            r.fail(
                Diagnosis(
                    rung,
                    "probe",
                    f"the probe stopped before this rung (exit {result.returncode}):\n" f"{result.tail(12)}",
                )
            )
        elif not r.details.get("finished"):
            why = (
                f"timed out after {timeout:.0f} s (an infinite loop, or far too slow)"
                if result.timed_out
                else f"the process died (exit {result.returncode}; memory limit or crash)"
            )
            r.fail(
                Diagnosis(rung, "timeout" if result.timed_out else "crash", why, traceback=result.tail(15))
            )
        r.details.pop("finished", None)
        r.details["isolation"] = result.isolation
    elapsed = time.perf_counter() - start
    for r in rungs_out.values():
        r.seconds = elapsed / max(len(rungs_out), 1)
    return rungs_out


def static_ast(info: PluginInfo) -> RungResult:
    """The in-process part of the static rung (files parse, the entry point exists); no plugin code runs."""
    r = RungResult("static")
    for d in ast_checks(info):
        r.fail(d)
    r.checks = len(info.python_files) + 1
    return r
