"""One task of the benchmark: a (paper, scene, configuration, seed), run in a process of its own.

    python -m nerfify_ns.nerfifybench.tasks SUITE.yaml TASK_KEY OUT_DIR      # writes OUT_DIR/result.json last

Configurations: ``full`` (the pipeline as it is), an ablation name (the pipeline with that stage switched off,
:mod:`nerfify_ns.ablations`), and ``reference``. A generated configuration runs ``run_paper`` on the paper with the
scene as its data and the suite's budget (training iterations, checkpoint cadence, ray batch and ``--machine.seed``
through the budget's training arguments), then scores the paper's novelty items on the run folder. The reference is
trained with the same data, batch, iterations, seed and checkpoint cadence: a method name through ``ns-train`` in a
process whose method discovery sees only that method's entry point (:mod:`nerfify_ns.runtime.isolated`), a plan
through ``run_compose``. Both are evaluated with our metrics (PSNR and SSIM per checkpoint, LPIPS on the final
renders). Whatever goes wrong in a task (a missing paper file, an unknown method, a failed training) is its
``status: failed`` with the reason: a row failure, never the benchmark's crash. ``result.json`` is written
atomically at the very end, so its presence means the task finished (the executor's resume test).
"""

from __future__ import annotations

import json
import math
import os
import re
import sys
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path

from nerfify_ns import runfolder
from nerfify_ns.nerfifybench.suite import BenchBudget, PaperEntry, Suite, load_suite

RESULT = "result.json"
REFERENCE = "reference"
FULL = "full"


@dataclass(frozen=True)
class Task:
    paper: str
    scene: str
    config: str
    seed: int

    @property
    def key(self) -> str:
        """``paper/scene/config/seedN`` (a scene folder is named by its last part)."""
        return f"{self.paper}/{Path(self.scene).name or 'scene'}/{self.config}/seed{self.seed}"

    @property
    def generated(self) -> bool:
        return self.config != REFERENCE

    @classmethod
    def from_key(cls, suite: Suite, key: str) -> Task:
        paper, scene_name, config, seed = key.split("/")
        entry = suite.paper(paper)
        scene = next(s for s in entry.scenes if (Path(s).name or "scene") == scene_name)
        return cls(paper, scene, config, int(seed.removeprefix("seed")))


def tasks_of(suite: Suite, ablations: list[str]) -> list[Task]:
    """Every task of the suite: per paper, scene and seed the reference, the full pipeline and each ablation."""
    out = []
    for entry in suite.papers:
        for scene in entry.scenes:
            for seed in entry.seeds:
                out += [Task(entry.id, scene, c, seed) for c in (REFERENCE, FULL, *ablations)]
    return out


def thread_env(cpus: float) -> dict:
    """Thread counts of every numeric library pinned to the task's cores (so parallel tasks do not oversubscribe)."""
    n = str(max(1, int(cpus)))
    return {k: n for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS")}


def train_args(budget: BenchBudget, seed: int) -> tuple:
    """The ns-train arguments both sides get: ray batch (training and evaluation) and seed."""
    return ("--pipeline.datamanager.train-num-rays-per-batch", str(budget.rays),
            "--pipeline.datamanager.eval-num-rays-per-batch", str(max(budget.rays, 256)),
            "--machine.seed", str(seed))


def _scene(suite: Suite, entry: PaperEntry, task: Task, folder: Path) -> Path:
    """The task's dataset folder: the suite's folder, or the procedural scene rendered (deterministically) here."""
    given = suite.scene_path(task.scene)
    if given is not None:
        return given
    from nerfify_ns.scenes import write_scene

    b = entry.budget
    return write_scene(task.scene, folder / "scene", resolution=b.resolution, n_train=b.n_train, n_val=1,
                       n_test=b.n_test, overwrite=True)


def _json(path: Path) -> dict | None:
    try:
        return json.loads(Path(path).read_text()) if Path(path).is_file() else None
    except (OSError, ValueError):
        return None


def _finite(v) -> float | None:
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else None


def _curve(eval_dir: Path) -> dict:
    """Per checkpoint: iterations done, training seconds, PSNR, loss (curve.csv) and SSIM (checkpoint_eval.json)."""
    from nerfify_ns.evaluate.curve import read_curve_csv

    points = read_curve_csv(eval_dir / runfolder.CURVE) if (eval_dir / runfolder.CURVE).is_file() else []
    ssim = {r["step"] + 1: _finite(r.get("ssim")) for r in (_json(eval_dir / runfolder.CHECKPOINT_EVAL) or {})
            .get("results", [])}
    return {"step": [p.step for p in points], "seconds": [p.train_seconds for p in points],
            "psnr": [_finite(p.psnr) for p in points], "ssim": [ssim.get(p.step) for p in points],
            "loss": [_finite(p.loss) for p in points]}


def _executability(summary: dict | None, verify: dict | None, ladder_ran: bool) -> dict:
    """Imports resolve (the ladder's static rung, else a training that logged a step), trains (training and
    evaluation finished), stable (every logged loss finite), loss falls (last tenth below the first)."""
    losses = (summary or {}).get("losses") or {}
    trained = bool(summary) and summary.get("status") == "ok"
    static = next((r for r in (verify or {}).get("rungs", []) if r["name"] == "static"), None)
    imports = (static["status"] != "fail") if static is not None and ladder_ran else (
        (summary or {}).get("iterations_done", 0) > 0 if summary else None)
    return {"imports": imports, "trains": trained if summary is not None else False,
            "stable": bool(losses.get("finite")) if summary else None,
            "loss_falls": (losses.get("last") is not None and losses.get("first") is not None
                           and losses["last"] < losses["first"]) if summary else None}


def _usage(run_dir: Path) -> dict:
    """Model calls and cost as the run recorded them (``agents.json``'s usage ledger, written when model agents took
    part); empty otherwise."""
    data = (_json(run_dir / runfolder.AGENTS) or {}).get("usage") or {}
    total = data.get("total", data) if isinstance(data, dict) else {}
    calls = total.get("calls")
    cost = total.get("cost_usd", total.get("cost"))
    return {"calls": calls, "cost_usd": cost} if calls is not None or cost is not None else {}


def run_generated(suite: Suite, entry: PaperEntry, task: Task, folder: Path) -> dict:
    from nerfify_ns.ablations import Ablations
    from nerfify_ns.budget import Budget
    from nerfify_ns.errors import NerfifyError
    from nerfify_ns.nerfifybench.novelty import coverage, score_items, to_dict
    from nerfify_ns.pipeline import PaperOptions, run_paper

    b = entry.budget
    ablations = Ablations.of([] if task.config == FULL else [task.config])
    budget = Budget(iterations=b.iterations, every=b.every, smoke_iterations=b.smoke_iterations, timeout=b.timeout,
                    train_args=train_args(b, task.seed))
    run_dir = folder / "run"
    result: dict = {"status": "ok", "reason": ""}
    try:
        data = _scene(suite, entry, task, folder)
        run_paper(entry.input, run_dir, options=PaperOptions(data=data, budget=budget, patch_rounds=b.patch_rounds,
                                                             ablations=ablations, overwrite=True))
    except NerfifyError as exc:
        result.update(status="failed", reason=f"{type(exc).__name__}: {exc}")
    run = _json(run_dir / runfolder.OUTCOME) or {}
    stages = {s["name"]: s for s in run.get("stages", [])}
    if run.get("failed") and result["status"] == "ok":
        result.update(status="failed", reason=f"{run['failed']['name']}: {run['failed']['reason']}")
    summary = _json(run_dir / "eval" / runfolder.SUMMARY)
    seconds = lambda *names: round(sum(stages.get(n, {}).get("seconds") or 0.0 for n in names), 2)  # noqa: E731
    scores = score_items(entry, run_dir if run_dir.is_dir() else None, folder / "checks",
                         timeout=b.check_timeout)
    result.update(
        stages={n: {"status": s["status"], "reason": s.get("reason", "")} for n, s in stages.items()},
        ablations=run.get("ablations", list(ablations.names)),
        executability=_executability(summary, _json(run_dir / runfolder.VERIFY), stages.get("verify", {}).get(
            "status") == "ran"),
        metrics=_metrics(summary), curve=_curve(run_dir / "eval"),
        generation_seconds=seconds("read", "equations", "plan", "plugin"), verify_seconds=seconds("verify"),
        usage=_usage(run_dir), novelty={"items": to_dict(scores), "coverage": coverage(scores)},
        base=_plan_base(run_dir))
    return result


def _plan_base(run_dir: Path) -> str | None:
    """The method the run's plan stands on (a splatting paper's splatfacto; else the plan's base)."""
    import yaml

    from nerfify_ns.knowledge.family import stands_on

    plan = run_dir / runfolder.PLAN
    return (stands_on(yaml.safe_load(plan.read_text()) or {}) or None) if plan.is_file() else None


def _metrics(summary: dict | None) -> dict:
    s = summary or {}
    return {"psnr": _finite(s.get("psnr")), "ssim": _finite(s.get("ssim")), "lpips": _finite(s.get("lpips")),
            "seconds": _finite(s.get("seconds")), "iterations": s.get("iterations_done"),
            "status": s.get("status"), "reason": s.get("reason", "")}


def run_reference(suite: Suite, entry: PaperEntry, task: Task, folder: Path) -> dict:
    """Train and evaluate the reference (see the module docstring)."""
    from nerfify_ns.errors import NerfifyError

    ref = entry.reference
    try:
        data = _scene(suite, entry, task, folder)
        summary = _reference_plan(entry, task, data, folder) if ref.plan is not None else \
            _reference_method(entry, task, data, folder)
    except NerfifyError as exc:
        summary = {"status": "failed", "reason": f"{type(exc).__name__}: {exc}"}
    ok = summary.get("status") == "ok"
    return {"status": "ok" if ok else "failed", "reason": "" if ok else f"reference {ref.label}: "
            f"{summary.get('reason') or 'failed'}", "metrics": _metrics(summary),
            "curve": _curve(folder / "eval"), "executability": _executability(summary, None, False),
            "reference": ref.label, "note": ref.note}


def _reference_plan(entry: PaperEntry, task: Task, data: Path, folder: Path) -> dict:
    from nerfify_ns.budget import Budget
    from nerfify_ns.pipeline import RunOptions, run_compose
    from nerfify_ns.plan import Plan

    b = entry.budget
    budget = Budget(iterations=b.iterations, every=b.every, smoke_iterations=b.smoke_iterations, timeout=b.timeout,
                    train_args=train_args(b, task.seed))
    result = run_compose(Plan.load(entry.reference.plan), folder / "compose",
                         options=RunOptions(data=data, budget=budget, overwrite=True))
    eval_dir = folder / "compose" / "eval"
    if eval_dir.is_dir():
        os.symlink(eval_dir, folder / "eval")
    if result.summary is None:
        return {"status": "failed", "reason": result.outcome.headline()}
    return result.summary


ERROR_WORDS = ("error", "unrecognized", "invalid")


def error_excerpt(log: str, limit: int = 400) -> str:
    """What a failed command said, in one line: from its first line naming an error (a traceback's last line, a
    tyro box's "Unrecognized or misplaced options:" and the options under it) the next few non-empty lines, box
    drawing stripped; else its last lines."""
    lines = [line.strip(" │╭╮╰╯─┃━") for line in log.splitlines()]
    lines = [line for line in lines if line]
    if any(line.startswith("Traceback") for line in lines):
        raised = [line for line in lines if re.match(r"^[\w.]+(Error|Exception|Interrupt)\b", line)]
        if raised:
            return raised[-1][:limit]
    first = next((i for i, line in enumerate(lines) if any(w in line.lower() for w in ERROR_WORDS)), None)
    said = lines[first:first + 4] if first is not None else lines[-6:]
    return " | ".join(said)[:limit]


def _reference_method(entry: PaperEntry, task: Task, data: Path, folder: Path) -> dict:
    """``ns-train METHOD`` (method discovery isolated), its checkpoints rendered and scored, LPIPS on the final
    renders."""
    import numpy as np
    from PIL import Image

    from nerfify_ns.dataset import read_dataset
    from nerfify_ns.evaluate.curve import CurveError, record_curve, train_for_curve
    from nerfify_ns.evaluate.metrics import as_rgb, lpips
    from nerfify_ns.evaluate.run_eval import CPU_ARGS, loss_stats
    from nerfify_ns.runtime.isolated import isolation_env
    from nerfify_ns.runtime.presets import for_method

    b, method = entry.budget, entry.reference.method
    dataset = read_dataset(data)
    env = isolation_env(folder / "isolation", [method])
    out = folder / "eval"
    run = train_for_curve(method, dataset, out / "train", iterations=b.iterations, every=b.every,
                          method_args=for_method(method, [*CPU_ARGS, *train_args(b, task.seed)]), timeout=b.timeout,
                          env=env)
    summary = {"iterations_done": run.last_step + 1, "losses": loss_stats(run.losses),
               "train_log": str(run.log_path)}
    if not run.ok:
        why = "timed out" if run.timed_out else f"exit code {run.returncode}"
        return {**summary, "status": "failed",
                "reason": f"ns-train {method}: {why}: {error_excerpt(run.log_tail(5000))}"}
    try:
        curve = record_curve(run, out, label=f"{method} (reference)", timeout=b.timeout, env=env,
                             save_dir=out / "renders")
    except CurveError as exc:
        return {**summary, "status": "failed", "reason": f"evaluation failed: {str(exc)[:400]}"}
    frames = dataset.eval_frames
    values = [lpips(np.asarray(Image.open(out / "renders" / f"{f.stem}.png").convert("RGB")),
                    as_rgb(np.asarray(Image.open(f.image)))) for f in frames]
    ssim = (_json(out / runfolder.CHECKPOINT_EVAL) or {}).get("results") or [{}]
    return {**summary, "status": "ok", "psnr": curve.points[-1].psnr,
            "ssim": max(ssim, key=lambda r: r.get("step", -1)).get("ssim"),
            "lpips": float(np.mean(values)) if values and all(v is not None for v in values) else None,
            "seconds": curve.points[-1].train_seconds}


def run_task(suite: Suite, task: Task, folder: Path) -> dict:
    """Run ``task`` into ``folder`` and write its ``result.json`` (atomically, last)."""
    from nerfify_ns.evaluate.run_eval import write_json

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    entry = suite.paper(task.paper)
    start = time.perf_counter()
    try:
        result = (run_generated if task.generated else run_reference)(suite, entry, task, folder)
    except Exception as exc:  # noqa: BLE001 - a task never takes the benchmark down: its row says why
        frame = traceback.extract_tb(exc.__traceback__)[-1]
        result = {"status": "failed", "reason": f"{type(exc).__name__}: {exc} ({Path(frame.filename).name}:"
                                                f"{frame.lineno})"}
    result.update(task=asdict(task), key=task.key, fingerprint=entry.fingerprint(),
                  task_seconds=round(time.perf_counter() - start, 2))
    write_json(folder / RESULT, result)
    return result


def main(argv: list[str]) -> int:
    from nerfify_ns.runlog import quiet_console

    quiet_console()
    suite = load_suite(Path(argv[0]))
    task = Task.from_key(suite, argv[1])
    result = run_task(suite, task, Path(argv[2]))
    print(json.dumps({"key": task.key, "status": result["status"], "reason": result.get("reason", "")}))
    return 0


if __name__ == "__main__":
    from nerfify_ns.interrupts import run_interruptible

    run_interruptible(lambda: sys.exit(main(sys.argv[1:])))
