"""``run_ladder``: static -> contract -> stability -> smoke, with bounded deterministic repair rounds.

What happens to repairs is explicit (``repair``):

* ``"off"``: the ladder only.
* ``"propose"`` (``ns-nerfify verify DIR``): the ladder runs on the folder; when it fails and a
  deterministic repair exists, the repair is applied to a scratch copy (``OUT/proposal/plugin``), the
  ladder re-runs there to show whether the repair makes it pass, and the unified diff of the whole
  repair is written to ``OUT/repair.diff``. The folder itself is not changed.
* ``"apply"`` (``ns-nerfify verify DIR --fix``, and the default for Python callers such as the pipeline,
  which verifies the plugin it generated in a staging folder it owns): repairs are applied to the folder,
  each recorded as a revertible diff under ``OUT/patches/``, and the ladder re-runs.

A plugin with a ``plan.yaml`` (a generated one) records its repairs in its plan, as plan edits where the
fix has a plan equivalent and as code repairs in the ``repairs`` annotation otherwise (the composer
re-applies those), so recomposing the plan keeps them. That change of ``plan.yaml`` is itself a recorded,
revertible patch.
"""

from __future__ import annotations

import difflib
import json
import os
import shutil
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from nerfify_ns import runfolder
from nerfify_ns.budget import Limit
from nerfify_ns.dataset import Dataset, as_dataset
from nerfify_ns.plan import Plan, PlanFileError
from nerfify_ns.runtime.launch import ProgressHook
from nerfify_ns.runtime.presets import smoke_iterations as smoke_iterations_for
from nerfify_ns.runtime.sandbox import Limits
from nerfify_ns.verify.errors import VerifyError
from nerfify_ns.verify.plugin import load_plugin
from nerfify_ns.verify.repair import CodePatch, Fixer, default_fixers, record_in_plan
from nerfify_ns.verify.rungs import PROBE_RUNGS, run_probe, static_ast
from nerfify_ns.verify.smoke_rung import smoke_rung
from nerfify_ns.verify.verdicts import RUNGS, Diagnosis, LadderReport, RungResult

RepairMode = Literal["off", "propose", "apply"]
REPAIR_MODES = ("off", "propose", "apply")
DIFF_NAME = "repair.diff"
"""The unified diff of every repair of a run (applied or proposed), in the output folder."""


@dataclass
class _Settings:
    """What every round of one ladder run shares."""

    rungs: list[str]
    scene: Dataset | None
    smoke_iterations: int
    timeout: float
    fixers: list[Fixer]
    max_rounds: int
    on_progress: ProgressHook | None = None
    limits: Limits | None = None
    """The sandbox's limits for the probe and the smoke rung (None: the sandbox's defaults)."""
    smoke_limit: Limit | None = None
    """The smoke rung's time limit and where it comes from (None: ``timeout``, as for the check rungs)."""
    smoke_args: list[str] = field(default_factory=list)
    """ns-train arguments of the smoke rung (a budgeted run's proxy samples)."""
    overlap: bool = True
    """Start the smoke rung beside the checks (static, contract, stability: one sandboxed process) once the files
    parse, so the two Nerfstudio start-ups overlap on a machine with two cores; it is called off (killed) and
    skipped when a check fails, as if it had run after them."""


@dataclass
class _Climb:
    """The rounds on one plugin folder, the patches applied to it and each patched file's first text."""

    rounds: list[list[RungResult]] = field(default_factory=list)
    patches: list[dict] = field(default_factory=list)
    originals: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _passed(results: Sequence[RungResult]) -> bool:
    return bool(results) and all(r.ok for r in results)


def _round(plugin_dir: Path, work: Path, st: _Settings) -> list[RungResult]:
    """One climb of the ladder on ``plugin_dir``; rungs after a failure are skipped."""
    info = load_plugin(plugin_dir)
    rungs = st.rungs
    results: list[RungResult] = []
    if "static" in rungs:
        ast_result = static_ast(info, work / "static", timeout=st.timeout)
        if not ast_result.ok:
            return [ast_result] + [RungResult(r, "skip", notes=["an earlier rung failed"]) for r in rungs[1:]]
    probe_rungs = [r for r in rungs if r in PROBE_RUNGS]
    beside, shared = None, None
    if "smoke" in rungs and probe_rungs and st.overlap and all(r.status == "pass" for r in results):
        shared = shared_cores()
        beside = _Beside(lambda cancel: _smoke(info, work, st, cancel, env=shared))
    finished = False
    try:
        if probe_rungs:
            found = run_probe(info, probe_rungs, work / "probe", timeout=st.timeout, limits=st.limits, env=shared)
            for name in probe_rungs:
                results.append(found.get(name) or RungResult(name, "skip", notes=["an earlier rung failed"]))
            if info.plan is None and "contract" in rungs:
                note = (
                    "no plan.yaml: plan-based contract checks skipped; the assembled field and model were checked"
                )
                next(r for r in results if r.name == "contract").notes.append(note)
        finished = True
    finally:  # a failed check (or an interrupt) calls the smoke rung off
        checks_passed = finished and all(r.status == "pass" for r in results)
        if beside is not None and not checks_passed:
            beside.call_off()
    if "smoke" in rungs:
        if checks_passed:
            results.append(beside.result() if beside is not None else _smoke(info, work, st))
        else:
            results.append(RungResult("smoke", "skip", notes=["an earlier rung failed"]))
    return results


def process_threads() -> int:
    """The threads a torch process of ours gets: ``OMP_NUM_THREADS`` when set, else every core we may use."""
    given = os.environ.get("OMP_NUM_THREADS", "")
    return int(given) if given.isdigit() and int(given) > 0 else len(os.sched_getaffinity(0))


def shared_cores() -> dict[str, str]:
    """Thread counts for two processes that run at once (the checks and the smoke rung): half the cores each, so
    that their thread pools do not oversubscribe the machine (on two cores, two processes of two threads made the
    smoke rung's steps up to 30 times slower, 1.28 s against 0.04 s, measured; :mod:`torch`'s pools spin while they
    wait); a smaller ``OMP_NUM_THREADS`` of the user's stays."""
    n = str(max(1, min(len(os.sched_getaffinity(0)) // 2, process_threads())))
    # the smoke rung's recorder times a step with the threads training will have (verify/recorder.py)
    return {"OMP_NUM_THREADS": n, "MKL_NUM_THREADS": n, "NERFIFY_TIMING_THREADS": str(process_threads())}


def _smoke(info, work: Path, st: _Settings, cancel=None, env: dict[str, str] | None = None) -> RungResult:
    scene = st.scene or _scene(work)
    limit = st.smoke_limit or Limit(st.timeout, "each verification process")
    return smoke_rung(info, scene, work / "smoke", iterations=st.smoke_iterations, timeout=limit.timeout,
                      limit=limit, extra_args=st.smoke_args or None, on_progress=st.on_progress, limits=st.limits,
                      cancel=cancel, env=env)


class _Beside:
    """The smoke rung running in a thread beside the checks; :meth:`call_off` kills it and waits for it."""

    def __init__(self, run: Callable) -> None:
        self._cancel = threading.Event()
        self._out: dict = {}

        def target() -> None:
            try:
                self._out["result"] = run(self._cancel)
            except BaseException as exc:  # noqa: BLE001 - handed to the ladder's thread (result)
                self._out["error"] = exc

        self._thread = threading.Thread(target=target, name="smoke-rung", daemon=True)
        self._thread.start()

    def call_off(self) -> None:
        self._cancel.set()
        self._thread.join()

    def result(self) -> RungResult:
        self._thread.join()
        if "error" in self._out:
            raise self._out["error"]
        return self._out["result"]


def _scene(work: Path) -> Path:
    from nerfify_ns.scenes import write_scene

    path = work.parent / "scene"
    if not (path / "transforms_train.json").exists():
        write_scene("default", path, resolution=32, n_train=12, n_val=2, n_test=2, overwrite=True)
    return path


def _climb(target: Path, out: Path, st: _Settings, *, repair: bool,
           first: list[RungResult] | None = None) -> _Climb:
    """Rounds on ``target`` (work folders and patches under ``out``), repairing it between rounds when
    ``repair``; ``first`` is an already known result of round 0 on the same files."""
    climb = _Climb()
    for round_no in range(st.max_rounds + 1):
        if round_no == 0 and first is not None:
            results = first
        else:
            start = time.perf_counter()
            results = _round(target, out / f"round-{round_no}", st)
            climb.notes.append(f"round {round_no}: {time.perf_counter() - start:.1f} s")
        climb.rounds.append(results)
        if _passed(results) or not repair or round_no == st.max_rounds:
            break
        patches = _propose(load_plugin(target), [d for r in results for d in r.failures], st.fixers)
        if not patches:
            break
        patches += _plan_record(target, patches, climb.notes)
        for patch in patches:
            _record(patch, out, target, round_no, climb)
    return climb


def _repair_mode(repair: str | bool) -> str:
    """``repair`` as a mode (``True`` is ``"apply"``, ``False`` is ``"off"``, as before modes existed)."""
    if isinstance(repair, bool):
        return "apply" if repair else "off"
    if repair not in REPAIR_MODES:
        raise VerifyError(f"unknown repair mode {repair!r}; the modes are {', '.join(REPAIR_MODES)}")
    return repair


def run_ladder(
    plugin_dir,
    *,
    scene=None,
    out_dir=None,
    repair: RepairMode | bool = "apply",
    max_rounds: int = 3,
    rungs: Sequence[str] | None = None,
    smoke_iterations: int | None = None,
    timeout: float = 300,
    fixers: Sequence[Fixer] | None = None,
    on_progress: ProgressHook | None = None,
    limits: Limits | None = None,
    smoke_limit: Limit | None = None,
    smoke_args: Sequence[str] | None = None,
) -> LadderReport:
    """Verify the plugin in ``plugin_dir``; the smoke rung trains on ``scene`` (a dataset, or its folder in any
    format :func:`nerfify_ns.dataset.read_dataset` reads; default a generated 32 px scene). Write
    ``verify.json`` (and patches, ``repair.diff``) to ``out_dir`` (default ``PLUGIN/.verify``).
    ``repair``: ``"off"``, ``"propose"`` (repair a scratch copy,
    leave the folder alone) or ``"apply"`` (repair the folder); see the module docstring.
    ``on_progress(step, total)`` is called while the smoke rung trains. ``limits``: the sandbox's limits on each
    process tree that runs plugin code (memory, processes, open files; default :class:`Limits`). ``timeout``: each
    check process's time limit, seconds; ``smoke_limit``: the smoke rung's (default: ``timeout``), named in its
    message when reached; ``smoke_args``: ns-train arguments of the smoke rung."""
    plugin_dir = Path(plugin_dir).resolve()
    if scene is not None:
        scene = as_dataset(scene)  # a bad dataset is refused before anything is written
    mode = _repair_mode(repair)
    rungs = list(rungs or RUNGS)
    unknown = [r for r in rungs if r not in RUNGS]
    if unknown:
        raise VerifyError(f"unknown rung(s) {unknown}; the rungs are {', '.join(RUNGS)}")
    out = Path(out_dir).resolve() if out_dir else plugin_dir / ".verify"
    out.mkdir(parents=True, exist_ok=True)
    info = load_plugin(plugin_dir)  # NotAPluginError early
    iterations = smoke_iterations_for((info.plan or {}).get("base"), smoke_iterations)
    st = _Settings([r for r in RUNGS if r in rungs], scene, iterations,
                   timeout, list(default_fixers() if fixers is None else fixers), max_rounds, on_progress, limits,
                   smoke_limit, list(smoke_args or []))
    report = LadderReport(plugin=str(plugin_dir), repair=mode)
    climb = _climb(plugin_dir, out, st, repair=mode == "apply")
    report.rounds, report.rungs, report.patches = climb.rounds, climb.rounds[-1], climb.patches
    report.notes += climb.notes
    report.notes += _sandbox_notes(report.rungs)
    if mode == "apply" and climb.patches:
        report.diff = combined_diff(climb.originals, plugin_dir)
    if mode == "propose" and not report.ok:
        report.proposal = _proposal(plugin_dir, out, st, climb.rounds[0], report)
    (out / DIFF_NAME).unlink(missing_ok=True)
    if report.diff:
        (out / DIFF_NAME).write_text(report.diff)
    (out / runfolder.VERIFY).write_text(json.dumps(report.to_dict(), indent=2, default=str))
    return report


def _sandbox_notes(results: Sequence[RungResult]) -> list[str]:
    """A note when plugin code ran with less isolation than bubblewrap gives (the fallback, or none)."""
    modes = {r.details.get("sandbox", {}).get("mode") for r in results} - {None}
    weaker = sorted(m for m in modes if m != "bwrap")
    if not weaker:
        return []
    return [f"sandbox: plugin code ran with isolation {', '.join(weaker)}, weaker than bubblewrap (see the README's "
            "Sandbox section): install bubblewrap and run as root for the full sandbox"]


def _copy_ignore(plugin_dir: Path, out: Path) -> Callable[[str, list[str]], set]:
    """Leave caches and the verification output (when it lies inside the plugin) out of the scratch copy."""
    def ignore(folder: str, names: list[str]) -> set:
        here = Path(folder).resolve()
        return {n for n in names if n == "__pycache__" or here / n in (out, plugin_dir / ".verify")}

    return ignore


def _proposal(plugin_dir: Path, out: Path, st: _Settings, first: list[RungResult],
              report: LadderReport) -> dict:
    """Repair a scratch copy of the plugin and climb the ladder on it; the folder itself is not touched."""
    scratch = out / "proposal"
    shutil.rmtree(scratch, ignore_errors=True)
    copy = scratch / "plugin"
    shutil.copytree(plugin_dir, copy, ignore=_copy_ignore(plugin_dir, out), symlinks=True)  # links stay links
    climb = _climb(copy, scratch, st, repair=True, first=first)
    report.notes += [f"proposal {note}" for note in climb.notes]
    if not climb.patches:
        return {"plugin": str(copy), "ok": False, "patches": [],
                "note": "no deterministic repair for these failures"}
    report.diff = combined_diff(climb.originals, copy)
    last = climb.rounds[-1]
    return {
        "plugin": str(copy),
        "ok": _passed(last),
        "rungs": [r.to_dict() for r in last],
        "rounds": [[{"name": r.name, "status": r.status, "failures": [str(d) for d in r.failures]}
                    for r in rnd] for rnd in climb.rounds],
        "patches": climb.patches,
        "diff": str(out / DIFF_NAME),
        "apply": f"ns-nerfify verify {plugin_dir} --fix  (or: patch -p1 -d {plugin_dir} < {out / DIFF_NAME})",
    }


def combined_diff(originals: dict[str, str], root: Path) -> str:
    """One unified diff (``a/FILE`` -> ``b/FILE``, for ``patch -p1``) from each file's original text to its
    text in ``root`` now."""
    parts = []
    for rel in sorted(originals):
        after = (root / rel).read_text() if (root / rel).exists() else ""
        parts.append("".join(difflib.unified_diff(originals[rel].splitlines(True), after.splitlines(True),
                                                  f"a/{rel}", f"b/{rel}")))
    return "".join(parts)


def _propose(info, failures: Sequence[Diagnosis], fixers: Sequence[Fixer]) -> list[CodePatch]:
    """The fixers' patches for ``failures``: one per file (the first fixer wins), each a real change."""
    patches: list[CodePatch] = []
    seen = set()
    for fixer in fixers:
        try:
            proposed = fixer.propose(info, failures)
        except VerifyError:  # a diagnosis naming no file of the plugin: nothing to repair there
            continue
        for patch in proposed:
            if patch.file not in seen and patch.after != patch.before:
                seen.add(patch.file)
                patches.append(patch)
    return patches


def _plan_record(target: Path, patches: Sequence[CodePatch], notes: list[str]) -> list[CodePatch]:
    """The change of ``target/plan.yaml`` that records ``patches`` in the plan (none without a plan)."""
    path = target / runfolder.PLAN
    if not path.is_file():
        return []
    try:
        plan = Plan.load(path)
    except PlanFileError:
        notes.append("plan.yaml is not a plan: the repairs are not recorded in it")
        return []
    before = path.read_text()
    lines = record_in_plan(plan, patches)
    after = plan.dump()
    if after == before:
        return []
    notes.extend(f"recorded in the plan: {line}" for line in lines)
    return [CodePatch(runfolder.PLAN, before, after, "record-repair",
                      "the repairs recorded in the plan, so recomposing it keeps them: " + "; ".join(lines),
                      "plan-record")]


def _record(patch: CodePatch, out: Path, target: Path, round_no: int, climb: _Climb) -> None:
    """Write the patch's diff under ``out/patches``, apply it to ``target``, list it with how to revert it."""
    folder = out / "patches"
    folder.mkdir(parents=True, exist_ok=True)
    name = f"{len(climb.patches) + 1:02d}-{patch.fixer}-{patch.file.replace('/', '_')}.diff"
    (folder / name).write_text(patch.diff())
    climb.originals.setdefault(patch.file, patch.before)
    patch.apply(target)
    climb.patches.append(
        {
            **patch.summary(),
            "round": round_no,
            "diff": str(folder / name),
            "revert": f"patch -R -p1 -d {target} < {folder / name}",
        }
    )


def revert_patches(report: LadderReport) -> None:
    """Undo every recorded patch of ``report`` (newest first)."""
    for p in reversed(report.patches):
        subprocess.run(
            ["patch", "-R", "-p1", "-d", report.plugin, "-i", p["diff"]], check=True, capture_output=True
        )
