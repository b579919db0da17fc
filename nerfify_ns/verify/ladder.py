"""``run_ladder``: static -> contract -> stability -> smoke, with bounded deterministic repair rounds."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import List, Optional, Sequence

from nerfify_ns.verify.errors import VerifyError
from nerfify_ns.verify.plugin import load_plugin
from nerfify_ns.verify.repair import Fixer, Patch, default_fixers
from nerfify_ns.verify.report import RUNGS, LadderReport, RungResult
from nerfify_ns.verify.rungs import PROBE_RUNGS, run_probe, static_ast
from nerfify_ns.verify.smoke import smoke_rung


def _round(
    plugin_dir: Path,
    rungs: Sequence[str],
    work: Path,
    scene: Optional[Path],
    smoke_iterations: int,
    timeout: float,
    notes: List[str],
) -> List[RungResult]:
    info = load_plugin(plugin_dir)
    results: List[RungResult] = []
    if "static" in rungs:
        ast_result = static_ast(info)
        if not ast_result.ok:
            return [ast_result] + [RungResult(r, "skip", notes=["an earlier rung failed"]) for r in rungs[1:]]
    probe_rungs = [r for r in rungs if r in PROBE_RUNGS]
    if probe_rungs:
        found = run_probe(info, probe_rungs, work / "probe", timeout=timeout)
        for name in probe_rungs:
            results.append(found.get(name) or RungResult(name, "skip", notes=["an earlier rung failed"]))
        if info.plan is None and "contract" in rungs:
            note = (
                "no plan.yaml: plan-based contract checks skipped; the assembled field and model were checked"
            )
            next(r for r in results if r.name == "contract").notes.append(note)
    if "smoke" in rungs:
        if all(r.status == "pass" for r in results):
            results.append(
                smoke_rung(
                    info, scene or _scene(work), work / "smoke", iterations=smoke_iterations, timeout=timeout
                )
            )
        else:
            results.append(RungResult("smoke", "skip", notes=["an earlier rung failed"]))
    return results


def _scene(work: Path) -> Path:
    from nerfify_ns.scenes import write_scene

    path = work.parent / "scene"
    if not (path / "transforms_train.json").exists():
        write_scene("default", path, resolution=32, n_train=12, n_val=2, n_test=2, overwrite=True)
    return path


def run_ladder(
    plugin_dir,
    *,
    scene=None,
    out_dir=None,
    repair: bool = True,
    max_rounds: int = 3,
    rungs: Optional[Sequence[str]] = None,
    smoke_iterations: int = 30,
    timeout: float = 300,
    fixers: Optional[Sequence[Fixer]] = None,
) -> LadderReport:
    """Verify the plugin in ``plugin_dir``; write ``verify.json`` (and patches) to ``out_dir``."""
    plugin_dir = Path(plugin_dir).resolve()
    rungs = list(rungs or RUNGS)
    unknown = [r for r in rungs if r not in RUNGS]
    if unknown:
        raise VerifyError(f"unknown rung(s) {unknown}; the rungs are {', '.join(RUNGS)}")
    rungs = [r for r in RUNGS if r in rungs]
    out = Path(out_dir).resolve() if out_dir else plugin_dir / ".verify"
    out.mkdir(parents=True, exist_ok=True)
    load_plugin(plugin_dir)  # NotAPluginError early
    report = LadderReport(plugin=str(plugin_dir))
    fixers = list(default_fixers() if fixers is None else fixers)
    for round_no in range(max_rounds + 1):
        work = out / f"round-{round_no}"
        start = time.perf_counter()
        results = _round(
            plugin_dir, rungs, work, Path(scene) if scene else None, smoke_iterations, timeout, report.notes
        )
        report.rounds.append(results)
        report.rungs = results
        report.notes.append(f"round {round_no}: {time.perf_counter() - start:.1f} s")
        if report.ok or not repair or round_no == max_rounds:
            break
        patches = _propose(load_plugin(plugin_dir), report, fixers)
        if not patches:
            break
        for patch in patches:
            _record(patch, out, plugin_dir, round_no, report)
    (out / "verify.json").write_text(json.dumps(report.to_dict(), indent=2, default=str))
    return report


def _propose(info, report: LadderReport, fixers: Sequence[Fixer]) -> List[Patch]:
    patches: List[Patch] = []
    seen = set()
    for fixer in fixers:
        for patch in fixer.propose(info, report.failures):
            if patch.file not in seen and patch.after != patch.before:
                seen.add(patch.file)
                patches.append(patch)
    return patches


def _record(patch: Patch, out: Path, plugin_dir: Path, round_no: int, report: LadderReport) -> None:
    folder = out / "patches"
    folder.mkdir(exist_ok=True)
    name = f"{len(report.patches) + 1:02d}-{patch.fixer}-{patch.file.replace('/', '_')}.diff"
    (folder / name).write_text(patch.diff())
    patch.apply(plugin_dir)
    report.patches.append(
        {
            **patch.summary(),
            "round": round_no,
            "diff": str(folder / name),
            "revert": f"patch -R -p1 -d {plugin_dir} < {folder / name}",
        }
    )


def revert_patches(report: LadderReport) -> None:
    """Undo every recorded patch of ``report`` (newest first)."""
    import subprocess

    for p in reversed(report.patches):
        subprocess.run(
            ["patch", "-R", "-p1", "-d", report.plugin, "-i", p["diff"]], check=True, capture_output=True
        )
