"""Run the probe (static, contract, stability rungs) and the static rung's parsing in the sandbox and read
their events back. What the sandbox observed (the memory or process limit reached, processes left running)
fails the rung that was running, naming it."""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Sequence
from pathlib import Path

from nerfify_ns.runtime.sandbox import Limits, SandboxResult, python_cmd, run_sandboxed
from nerfify_ns.verify.checker import PipeReader, decode, judge
from nerfify_ns.verify.plugin import PluginInfo, plugin_file
from nerfify_ns.verify.verdicts import Diagnosis, RungResult, clean_data

PROBE_RUNGS = ("static", "contract", "stability")
PARSE_LIMITS = Limits(memory=2 << 30, pids=32)
"""The static rung's parser: plain Python on a few files."""
PARSE_TIMEOUT = 120.0


def read_probe_events(path: Path, max_bytes: int = 64 << 20) -> list[dict]:
    """The probe's JSON-lines events (a line cut off by a crash is skipped; at most ``max_bytes`` are read)."""
    if not path.exists():
        return []
    events = []
    with open(path, "rb") as f:
        data = f.read(max_bytes)
    for line in data.decode("utf-8", errors="replace").splitlines():
        try:
            event = json.loads(line)
        except (ValueError, RecursionError):
            continue
        if isinstance(event, dict):
            events.append(event)
    return events


def sandbox_details(result: SandboxResult) -> dict:
    """What ``verify.json`` records of a sandboxed run: its isolation, limits and what the tree used."""
    return {"mode": result.mode, "limits": result.limits, "usage": result.usage}


def limit_diagnoses(rung: str, result: SandboxResult, left_running: bool = True) -> list[Diagnosis]:
    """The limits the sandboxed process tree ran into, as failures of ``rung`` (rule ``sandbox-limit``)."""
    return [Diagnosis(rung, "sandbox-limit", hit) for hit in result.limit_hits(left_running)]


def _exit_text(result: SandboxResult) -> str:
    """How the process ended: ``exit N``, or the signal that killed it (bwrap reports a command killed by
    signal S as exit 128 + S)."""
    code = result.returncode
    signum = -code if code < 0 else code - 128 if result.mode == "bwrap" and 128 < code < 160 else 0
    if signum:
        try:
            name = signal.Signals(signum).name
        except ValueError:
            name = f"signal {signum}"
        return f"killed by {name}" + (f" (exit {code})" if code > 0 else "")
    return f"exit {code}"


def run_probe(
    info: PluginInfo | None, rungs: Sequence[str], workdir: Path, *, timeout: float, suite: str = "plan",
    limits: Limits | None = None, env: dict[str, str] | None = None,
) -> dict[str, RungResult]:
    """Probe ``rungs`` in one sandboxed process and judge what it sends with the checker
    (:mod:`nerfify_ns.verify.checker`, here, in our process); a rung it never finished is failed (timeout or
    crash). Without a plugin (``info`` None: the component suite, our code only) its own events are the verdict."""
    workdir.mkdir(parents=True, exist_ok=True)
    events_path = workdir / "events.jsonl"
    events_path.unlink(missing_ok=True)
    plugin = str(info.root) if info else "-"
    start = time.perf_counter()
    reader = PipeReader() if info is not None else None
    extra = ["--records", str(reader.write_fd), "--seed", str(int.from_bytes(os.urandom(6), "little"))] \
        if reader else []
    try:
        result = run_sandboxed(
            python_cmd("nerfify_ns.verify.probe", plugin, str(events_path), "--rungs", ",".join(rungs), "--suite",
                       suite, *extra),
            workdir,
            timeout=timeout,
            log_name="probe.log",
            readonly=[info.root] if info else [],
            limits=limits,
            pass_fds=(reader.write_fd,) if reader else (),
            env=env,
        )
    finally:
        data = reader.finish() if reader else b""
    records, wire_problems = decode(data) if reader else ([], [])
    events = [h for h, _ in records if h.get("kind") == "event"] if reader else read_probe_events(events_path)
    rungs_out: dict[str, RungResult] = {}
    started: dict[str, float] = {}
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
            d = Diagnosis.from_dict(e)
            if d.file is not None and info is not None and plugin_file(info.root, d.file) is None:
                d.message += f" (reported in {d.file}, not a file of the plugin)"
                d.file, d.line = None, None
            r.fail(d)
        elif kind in ("case", "component"):
            r.checks += 1
            r.details.setdefault("cases", []).append(clean_data(
                {
                    k: e.get(k)
                    for k in ("component", "implementation", "owner", "case", "status", "problems", "path")
                }
            ))
    if reader is not None:
        _apply_checker(info, rungs, rungs_out, records, wire_problems, reader.overflow)
        failed = [n for n in rungs if n in rungs_out and not rungs_out[n].ok]
        for later in rungs[rungs.index(failed[0]) + 1:] if failed else ():
            rungs_out.pop(later, None)  # the probe ran on (the verdicts are ours, made after); the ladder stops at
            # the first failing rung, so those after it are skipped as before
    # processes left running: named by the probe itself where it has a PID namespace of its own, else counted
    left_named = any(d.rule == "processes" for r in rungs_out.values() for d in r.failures)
    hits = limit_diagnoses("", result, left_running=not left_named)
    for rung in rungs:
        r = rungs_out.get(rung)
        if r is None:
            if any(not x.ok or not x.details.get("finished") for x in rungs_out.values()):
                continue  # an earlier rung failed or never finished: this one did not run
            rungs_out[rung] = r = RungResult(rung)
            if result.timed_out:  # still starting (imports, the sandbox) when the time was up
                r.fail(Diagnosis(rung, "timeout", f"timed out after {timeout:.0f} s before this rung started (the "
                                 "probe was still starting or in an earlier rung)", traceback=result.tail(12)))
            else:
                r.fail(Diagnosis(rung, "probe", f"the probe stopped before this rung ({_exit_text(result)}):\n"
                                 f"{result.tail(12)}"))
        elif not r.details.get("finished"):
            why = (
                f"timed out after {timeout:.0f} s (an infinite loop, or far too slow)"
                if result.timed_out
                else f"the process died ({_exit_text(result)}; memory limit or crash)"
            )
            r.fail(
                Diagnosis(rung, "timeout" if result.timed_out else "crash", why, traceback=result.tail(15))
            )
        r.details.pop("finished", None)
        r.details["isolation"] = result.isolation
        r.details["sandbox"] = sandbox_details(result)
    hits += [Diagnosis("", "escape-attempt", text) for text in result.attempt_sentences()]
    if hits and rungs_out:  # the limits the tree hit fail the last rung that ran (the one running then)
        last = list(rungs_out.values())[-1]
        for d in hits:
            d.rung = last.name
            last.fail(d)
    elapsed = time.perf_counter() - start
    for r in rungs_out.values():
        r.seconds = elapsed / max(len(rungs_out), 1)
    return rungs_out


def _apply_checker(info: PluginInfo, rungs: Sequence[str], rungs_out: dict[str, RungResult], records: list,
                   wire_problems: list[str], overflow: int) -> None:
    """The checker's verdicts on the probe's records: its checks counted, its failures added, and a finished
    rung that delivered nothing to judge failed."""
    from nerfify_ns.plan import Plan

    finished = [n for n in rungs if n in rungs_out and rungs_out[n].details.get("finished") and rungs_out[n].ok]
    plan = Plan.of(info.plan) if info.plan else None
    verdicts = judge(records, plan, rungs, finished)
    for f in verdicts.findings:
        r = rungs_out.get(f.rung)
        if r is None:
            continue
        d = Diagnosis(f.rung, f.rule, f.message, f.file, f.line, component=f.component, case=f.case, data=f.data)
        if d.file is not None and plugin_file(info.root, d.file) is None:
            d.file, d.line = None, None
        r.fail(d)
    for name, r in rungs_out.items():
        r.checks = verdicts.checks.get(name, 0)
        r.details["checked_by"] = "checker"
        if verdicts.cases.get(name):
            r.details["cases"] = [clean_data(c) for c in verdicts.cases[name]]
    problems = wire_problems + ([f"the probe sent more than the checker reads ({overflow} bytes dropped)"]
                                if overflow else [])
    if problems and rungs_out:
        last = list(rungs_out.values())[-1]
        for text in problems:
            last.fail(Diagnosis(last.name, "forged-record", f"the probe's records are not what it sends: {text}"))


def static_ast(info: PluginInfo, workdir: Path, *, timeout: float = PARSE_TIMEOUT,
               limits: Limits | None = None) -> RungResult:
    """The parsing part of the static rung (files parse, the entry point exists), in a sandboxed subprocess
    with its own limits: a file that exhausts the parser fails the rung naming the file, not our process."""
    r = RungResult("static")
    workdir.mkdir(parents=True, exist_ok=True)
    events_path = workdir / "parse.jsonl"
    events_path.unlink(missing_ok=True)
    result = run_sandboxed(python_cmd("nerfify_ns.verify.static", str(info.root), str(events_path)), workdir,
                           timeout=min(timeout, PARSE_TIMEOUT), log_name="parse.log", readonly=[info.root],
                           limits=limits or PARSE_LIMITS)
    events = read_probe_events(events_path)
    parsing = [e.get("file") for e in events if e.get("event") == "parsing"]
    for e in events:
        if e.get("event") == "diagnosis":
            d = Diagnosis.from_dict({**e, "rung": "static"})
            if d.file is not None and plugin_file(info.root, d.file) is None and d.file not in info.python_files:
                d.file = None
            r.fail(d)
    if not any(e.get("event") == "end" for e in events):
        where = parsing[-1] if parsing else None
        if result.timed_out:
            what = f"parsing {where}" if where else "the static check"
            r.fail(Diagnosis("static", "syntax", f"{what} did not finish within {min(timeout, PARSE_TIMEOUT):.0f} s",
                             where, traceback=result.tail(10)))
        elif where:
            r.fail(Diagnosis("static", "syntax", f"parsing {where} crashed the parser ({_exit_text(result)}): too "
                             "deeply nested, too large, or beyond the parser's memory limit", where,
                             traceback=result.tail(10)))
        else:  # it never reached the plugin's files: the sandbox or the checker itself failed
            r.fail(Diagnosis("static", "probe", f"the static check did not start ({_exit_text(result)}):\n"
                             f"{result.tail(12)}", traceback=result.tail(10)))
        for d in limit_diagnoses("static", result):
            r.fail(d)
    for text in result.attempt_sentences():
        r.fail(Diagnosis("static", "escape-attempt", text))
    r.details["isolation"] = result.isolation
    r.details["sandbox"] = sandbox_details(result)
    r.checks = len(info.python_files) + 1
    r.seconds = result.seconds
    return r
