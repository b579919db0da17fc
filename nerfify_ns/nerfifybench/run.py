"""``ns-nerfify bench``: every task of a suite on an executor, then results.json, tables and plots.

    result = run_bench(load_suite(path), out, ablations=["no-citations"], executor=LocalExecutor())

The tasks (:func:`nerfify_ns.nerfifybench.tasks.tasks_of`) already finished in ``out`` with the same paper entry are
skipped (resume); the rest run on the executor, the progress object told of each (one step per task, so the bar's
ETA is the suite's). The tables are written from every task's ``result.json``.
"""

from __future__ import annotations

import datetime as _dt
import platform
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from nerfify_ns.ablations import Ablations
from nerfify_ns.nerfifybench.executor import LocalExecutor, finished
from nerfify_ns.nerfifybench.suite import Suite
from nerfify_ns.nerfifybench.tasks import Task, tasks_of
from nerfify_ns.outcome import Progress


@dataclass
class BenchResult:
    out: Path
    results: dict
    ran: int
    skipped: int
    failed: list[str]


def run_bench(suite: Suite, out: Path, *, ablations: Sequence[str] = (), executor=None,
              progress: Progress | None = None, command: str = "") -> BenchResult:
    """Run (or resume) the suite into ``out``; write results.json, tables.md, tables.tex and plots/."""
    ablations = list(Ablations.of(ablations).names)  # unknown names refused before anything runs
    executor = executor or LocalExecutor()
    progress = progress or Progress()
    out = Path(out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    tasks = tasks_of(suite, ablations)
    fingerprints = {p.id: p.fingerprint() for p in suite.papers}
    results: dict[str, dict] = {}
    pending: list[Task] = []
    for task in tasks:
        done = finished(out, task, fingerprints[task.paper])
        if done is not None:
            results[task.key] = done
        else:
            pending.append(task)
    skipped = len(results)
    progress.start("bench", f"{suite.name}: {len(tasks)} task(s), {skipped} done before, {len(pending)} to run "
                   f"({executor.name})", total=len(tasks))
    progress.advance(skipped, len(tasks))
    needs = {t.key: (suite.paper(t.paper).budget.cpus, suite.paper(t.paper).budget.gpus) for t in tasks}

    def on_done(task: Task, result: dict) -> None:
        results[task.key] = result
        progress.advance(len(results), len(tasks))
        progress.note(f"{task.key}: {result.get('status')}" + (f" ({result.get('reason', '')[:80]})"
                                                             if result.get("status") != "ok" else ""))

    start = time.perf_counter()
    executor.run(suite.path, out, pending, needs, on_done)
    progress.finish("bench", f"{len(pending)} task(s) run, {skipped} skipped (done before)",
                    time.perf_counter() - start)
    payload = write_tables(suite, out, ablations, executor.name, command, results)
    failed = [f"{k}: {r.get('reason', '')}" for k, r in results.items() if r.get("status") != "ok"]
    return BenchResult(out, payload, len(pending), skipped, failed)


def write_tables(suite: Suite, out: Path, ablations: Sequence[str], executor: str, command: str = "",
                 results: dict[str, dict] | None = None) -> dict:
    """results.json, tables.md, tables.tex and plots/ from the tasks' results (default: every task finished in ``out``
    so far; the others are listed as not run)."""
    from nerfify_ns.nerfifybench.tables import write_outputs

    tasks = tasks_of(suite, list(ablations))
    if results is None:
        results = {}
        for task in tasks:
            done = finished(out, task, suite.paper(task.paper).fingerprint())
            if done is not None:
                results[task.key] = done
    meta = {"suite": suite.name, "suite_file": str(suite.path), "date": _dt.date.today().isoformat(),
            "command": command, "executor": executor, "ablations": list(ablations),
            "machine": f"{platform.machine()}, {platform.system()}, Python {platform.python_version()}",
            "papers": {p.id: {"input": str(p.input), "scenes": list(p.scenes), "seeds": list(p.seeds),
                              "reference": p.reference.label, "reference_note": p.reference.note,
                              "reported": p.reported, "budget": asdict(p.budget),
                              "novelty": [{"id": i.id, "kind": i.kind, "weight": i.weight, "where": i.where,
                                           "check": bool(i.check)} for i in p.novelty]}
                       for p in suite.papers}}
    return write_outputs(Path(out), meta, [results[t.key] for t in tasks if t.key in results], tasks)
