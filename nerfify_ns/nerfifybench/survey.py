"""The paper survey: every paper of a folder or a suite through the pipeline up to its plan (and the equation
compiler), in a process of its own, and what it made of each: the family, the base and why, the paper's
contributions as read, each novel part with the production it changes and its status; against a suite's labelled
novelty items, found / implemented / spurious.

    ns-nerfify survey ../shared/papers            # every .pdf/.md/.tex/.txt paper under the folder
    ns-nerfify survey examples/bench/dev.yaml     # the suite's papers, scored against its novelty items
    ns-nerfify survey examples/bench/dev.yaml --train   # and each trained by the whole pipeline in its budget

Scoring (deterministic, from the run's own plan.yaml):
* an item of the paper's own (``NoveltyItem.novel``) is **found** when a hole (or a compiled ``custom`` part) lands
  at its production and shares one of its phrases' content words with the hole's claim, contribution heading, text
  or equations' numbers, or is the only hole at that production; items without a production (a paper that is not a
  training method) are matched by their phrases alone;
* **implemented**: the hole that found it is no longer "not implemented" (compiled, or written by the model coder);
* a hole is **spurious** when it matches no novel item and no ``known_from`` item (a known card's part, or a part
  the paper does not add);
* the **family** is correct when the plan's family is the suite's.
Each paper runs as ``ns-nerfify PAPER --until plan`` (``--verify``: ``--until verify``) in a subprocess with a time
and memory limit; a paper that fails is a row with its one-line reason, never a traceback here.

``--train``: each paper runs the whole pipeline, ``ns-nerfify PAPER`` with the default budget
(``budget.DEFAULT_BUDGET_SECONDS``), one paper at a time, in a process group bounded by the budget plus
:data:`TRAIN_MARGIN`; the row adds what its run folder states (:func:`read_training`): the exit code, the iterations
trained of those planned, whether the run fitted its budget (the summary's ``within_budget``, with the run's wall time
against the budget), PSNR, the colour ratio (``diagnostics.colour_spread_ratio``: the render's foreground colour
spread over the ground truth's), the CPU proxy the plan's ``schedule.proxy`` records, and how many of the found parts
were built and verified. A paper of a family the grammar cannot build (splatting, not a training method) stops after
its plan: its row says why it was not trained.
"""

from __future__ import annotations

import json
import os
import re
import resource
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nerfify_ns import runfolder
from nerfify_ns.budget import DEFAULT_BUDGET_SECONDS
from nerfify_ns.errors import NerfifyError
from nerfify_ns.knowledge.family import stands_on
from nerfify_ns.nerfifybench.suite import NoveltyItem, PaperEntry, load_suite
from nerfify_ns.safeio import load_json, load_yaml
from nerfify_ns.synthesis.novel.causes import NAMES, cause_of

PAPER_SUFFIXES = (".pdf", ".md", ".tex", ".txt")
TIME_LIMIT = 300
"""Seconds one paper's run may take (the read and plan stages take seconds; the ladder, with --verify, minutes)."""
MEMORY_LIMIT = 8 * 2**30
TRAIN_MARGIN = 180
"""Seconds a ``--train`` run may take past its budget before it is stopped (start-up of Python, torch and
Nerfstudio in each process, and a loaded machine; ``within_budget`` judges the budget itself)."""
TRAIN_MEMORY_LIMIT = 12 * 2**30
"""Address space of a ``--train`` run (the pipeline and the training processes it starts inherit it)."""
BUILT = ("implemented", "partly implemented")
"""Statuses of a found part that was built (compiled from the paper's equations or sentences)."""
_STOP = set("a an the of for and or to in on with by from as at is are we our its their this that each per".split())


@dataclass
class PaperRow:
    id: str
    path: str
    exit_code: int | None = None
    error: str = ""
    family: str = ""
    family_expected: str = ""
    base: str = ""
    base_reason: str = ""
    contributions: list = field(default_factory=list)
    holes: list = field(default_factory=list)
    items: list = field(default_factory=list)
    """Per novel item: {id, production, found, implemented, hole}."""
    spurious: list = field(default_factory=list)
    seconds: float = 0.0
    train: dict = field(default_factory=dict)
    """``--train`` only: what the run folder states (:func:`read_training`)."""

    @property
    def family_ok(self) -> bool | None:
        return None if not self.family_expected else self.family == self.family_expected

    def to_dict(self) -> dict:
        d = dict(self.__dict__)
        d["family_ok"] = self.family_ok
        return d


def _words(text: str) -> set[str]:
    return {w[:6] for w in re.findall(r"[a-z][a-z-]{2,}", (text or "").lower()) if w not in _STOP}


def _hole_text(h: dict) -> str:
    eqs = " ".join(f"Eq. {e.get('number', '')}" for e in h.get("equations", []))
    return " ".join([h.get("contribution", ""), h.get("claim", ""), h.get("text", ""), h.get("section", ""), eqs])


def _matches(item: NoveltyItem, hole: dict) -> bool:
    text = _hole_text(hole)
    words = _words(text)
    by_phrase = any(len(_words(p) & words) >= max(1, min(2, len(_words(p)))) for p in item.phrases)
    numbers = set(item.equations)
    by_number = bool(numbers) and any(str(e.get("number", "")) in numbers for e in hole.get("equations", []))
    if not item.production or item.production == "Primitive":
        return by_phrase
    return hole.get("production") == item.production and (by_phrase or by_number)


def score_row(row: PaperRow, entry: PaperEntry) -> None:
    """Found / implemented per novel item of ``entry``, spurious holes, against ``row.holes``."""
    novel = [i for i in entry.novelty if i.novel]
    used: set[int] = set()
    for item in novel:
        hit = next((k for k, h in enumerate(row.holes) if _matches(item, h)), None)
        if hit is None and item.production:
            same = [k for k, h in enumerate(row.holes) if h.get("production") == item.production]
            siblings = [i for i in novel if i.production == item.production]
            if len(same) == 1 and len(siblings) == 1:
                hit = same[0]
        hole = row.holes[hit] if hit is not None else None
        if hit is not None:
            used.add(hit)
        row.items.append({"id": item.id, "production": item.production, "found": hole is not None,
                          "implemented": bool(hole) and hole.get("status") not in ("not implemented", None),
                          "status": hole.get("status") if hole else "not found",
                          "hole": f"{hole.get('production')}: {hole.get('contribution', '')}" if hole else ""})
    borrowed = [i for i in entry.novelty if i.known_from]
    for k, h in enumerate(row.holes):
        if k in used or any(_matches(i, h) for i in novel) or any(_matches(i, h) for i in borrowed):
            continue
        row.spurious.append(f"{h.get('production')}: {h.get('contribution') or h.get('section')}")


def _limits(memory: int = MEMORY_LIMIT):  # pragma: no cover - runs in the child
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
    return apply


def _run_bounded(command: list[str], timeout: float, memory: int) -> tuple[int, str] | None:
    """(exit code, output) of ``command`` in a process group of its own; None when it ran past ``timeout`` seconds
    (the whole group is killed then: the pipeline's training processes with it)."""
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=_limits(memory), start_new_session=True)
    try:
        output, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.communicate()
        return None
    return proc.returncode, output


def run_paper_row(pid: str, paper: Path, out: Path, verify: bool = False, timeout: int = TIME_LIMIT,
                  train: bool = False) -> PaperRow:
    """One paper through ``ns-nerfify PAPER --until plan`` (or verify, or with ``train`` the whole pipeline with the
    default budget) in its own process; the row from its plan (and run folder)."""
    row = PaperRow(pid, str(paper))
    cli = Path(sys.executable).with_name("ns-nerfify")
    memory = MEMORY_LIMIT
    if train:
        command = [str(cli), str(paper), "--out", str(out), "--overwrite"]
        timeout, memory = int(DEFAULT_BUDGET_SECONDS + TRAIN_MARGIN), TRAIN_MEMORY_LIMIT
    elif verify:
        command = [str(cli), str(paper), "--until", "verify", "--out", str(out), "--overwrite"]
    else:
        command = [sys.executable, "-m", "nerfify_ns.nerfifybench.survey", str(paper), str(out)]
    start = time.perf_counter()
    done = _run_bounded(command, timeout, memory)
    row.seconds = round(time.perf_counter() - start, 1)
    if done is None:
        row.error = f"stopped after the {timeout} s limit of one paper"
        if train:
            row.train = {"trained": False, "within_budget": False, "wall_seconds": row.seconds,
                         "budget_seconds": DEFAULT_BUDGET_SECONDS,
                         "why": f"stopped after {timeout} s (the budget and a {TRAIN_MARGIN} s margin)"}
        return row
    row.exit_code, output = done
    lines = [x for x in output.splitlines() if x.strip()]
    failed = next((x for x in lines if x.startswith(("failed ", "error:"))), "")
    if "Traceback" in output:
        row.error = "a traceback: " + (lines[-1] if lines else "")
    elif failed:
        row.error = failed
    read_plan(row, out, lines)
    if train:
        read_training(row, out, DEFAULT_BUDGET_SECONDS)
    return row


def read_plan(row: PaperRow, out: Path, lines: list[str] | None = None) -> None:
    """The row's family, base, contributions and holes (a compiled ``custom`` part among them) from ``out``'s plan."""
    lines = lines or []
    plan_file = out / runfolder.PLAN
    if not plan_file.is_file():
        row.error = row.error or (lines[-1] if lines else f"exit {row.exit_code}, no plan")
        return
    try:
        plan = load_yaml(plan_file, what="the paper's plan") or {}
    except NerfifyError as exc:
        row.error = row.error or f"its plan could not be read: {exc}"
        return
    family = plan.get("family") or {}
    row.family = family.get("name", "")
    row.base = plan.get("base", "")
    note = next((n for n in plan.get("notes", []) if str(n).startswith("base: ")), "")
    row.base_reason = note[6:300]
    chosen = out / "base.json"
    if chosen.is_file():  # the reference plan the base is (a time-capable one stands on nerfacto's loop)
        data = load_json(chosen, what="the base chosen")
        row.base, row.base_reason = str(data.get("base") or row.base), str(data.get("reason") or "")[:300]
    method = stands_on(plan)
    if method != plan.get("base", ""):  # the family's own method, not a ray-marched base
        row.base, row.base_reason = method, f"the {row.family} family's Nerfstudio method; nothing built"
    row.contributions = plan.get("contributions", [])
    row.holes = plan.get("holes", [])
    for path, custom in _customs(plan):
        row.holes.append({"production": custom.get("production", ""), "contribution": custom.get("contribution", ""),
                          "claim": custom.get("claim", ""), "text": custom.get("text", ""),
                          "equations": [{"number": n} for n in custom.get("implements", [])],
                          "status": custom.get("status", "implemented"), "slot": path})


def _load(path: Path, what: str) -> dict:
    try:
        data = load_json(path, what=what) if path.is_file() else {}
    except NerfifyError:
        return {}
    return data if isinstance(data, dict) else {}


def read_training(row: PaperRow, out: Path, budget_seconds: float | None = None) -> None:
    """``row.train`` from the run folder ``out`` of ``ns-nerfify PAPER`` (``run.json``, ``eval/summary.json``,
    ``plan.yaml``; ``read_plan`` has filled the holes): trained or why not, the iterations done of those planned,
    ``within_budget`` with the run's wall time (``row.seconds``) and the budget, PSNR, the colour ratio, the CPU proxy
    (``schedule.proxy``), and the found parts built and verified (built: compiled; verified: built, and the ladder's
    rungs all passed, none "not verified: time"). ``budget_seconds``: the budget the run was given, for a run that
    stopped before its summary recorded one; a paper the tool can build that did not train did not fit it. A paper
    of a family the grammar cannot build (the plan's ``family.buildable``) was not trained, and says why."""
    stages = {s.get("name"): s for s in _load(out / runfolder.OUTCOME, "the run's outcome").get("stages", [])}
    summary = _load(out / runfolder.EVAL_DIR / runfolder.SUMMARY, "the evaluation summary")
    record = summary.get("budget") or {}
    plan = {}
    if (out / runfolder.PLAN).is_file():
        try:
            plan = load_yaml(out / runfolder.PLAN, what="the paper's plan") or {}
        except NerfifyError:
            plan = {}
    schedule = summary.get("schedule") or plan.get("schedule") or {}
    proxy = schedule.get("proxy") if isinstance(schedule, dict) else None
    ladder = stages.get("verify") or {}
    ladder_ok = ladder.get("status") == "ran" and "not verified" not in str(ladder.get("summary", ""))
    built = [h for h in row.holes if h.get("status") in BUILT]
    train = stages.get("train") or {}
    trained = summary.get("status") == "ok"
    family = plan.get("family") if isinstance(plan.get("family"), dict) else {}
    buildable = family.get("buildable", True) is not False
    why = ""
    if not trained:
        failed = next((s for s in stages.values() if s.get("status") == "failed"), None)
        why = (f"{failed['name']} failed: {failed.get('reason', '')}" if failed else
               summary.get("reason") or row.error or f"the train stage {train.get('status') or 'did not run'}")
        if not buildable:
            why = f"not built: a {family.get('name', '?')} paper" + (f": {family['why']}" if family.get("why") else "")
    within = summary.get("within_budget")
    if within is None and not trained and buildable and (record.get("seconds") or budget_seconds) is not None:
        within = False
    diagnostics = summary.get("diagnostics") or {}
    row.train = {
        "trained": trained, "why": why[:300],
        "iterations": summary.get("iterations_done"), "planned": record.get("iterations", summary.get("iterations")),
        "within_budget": within, "wall_seconds": row.seconds,
        "budget_seconds": record.get("seconds", budget_seconds if buildable else None),
        "train_seconds": summary.get("seconds"),
        "psnr": summary.get("psnr"), "colour_ratio": diagnostics.get("colour_spread_ratio"),
        "proxy": (proxy.get("headline") if isinstance(proxy, dict) else None),
        "found": len(row.holes), "built": len(built), "verified": len(built) if ladder_ok else 0,
    }


def _customs(plan: Any, prefix: str = "") -> list:
    out = []
    if isinstance(plan, dict):
        for key, value in plan.items():
            if key in ("holes", "evidence", "notes", "contributions", "family"):
                continue
            path = f"{prefix}.{key}" if prefix else str(key)
            if key == "custom" and isinstance(value, dict) and value.get("production"):
                out.append((path, value))
            else:
                out.extend(_customs(value, path))
    return out


def _read_paper(paper: Path, out: Path) -> int:
    """The child of one survey row: the paper's read stage (ingest, families, ledger, plan, the equation compiler),
    as ``ns-nerfify PAPER --dry-run`` runs it, with the plan written to ``out/plan.yaml``. 2: bad input, one line."""
    from nerfify_ns.errors import NerfifyError
    from nerfify_ns.pipeline import FamilyError, PaperOptions, run_paper
    from nerfify_ns.plan import Plan

    try:
        result = run_paper(paper, options=PaperOptions(dry_run=True))
    except NerfifyError as exc:
        print(f"error: {exc}")
        return 2
    out.mkdir(parents=True, exist_ok=True)
    (out / runfolder.PLAN).write_text(Plan.of(result.plan).dump())
    (out / "base.json").write_text(json.dumps({"base": result.derived.base, "reason": result.derived.base_reason}))
    family = result.derived.family
    if family is not None and not family.buildable:
        print(f"failed plan: {FamilyError(family, len(result.derived.holes))}")
        return 1
    return 0


def papers_of(target: Path) -> list[tuple[str, Path, PaperEntry | None]]:
    """(id, paper, suite entry or None) for a suite file or every paper under a folder."""
    if target.is_file() and target.suffix in (".yaml", ".yml"):
        suite = load_suite(target)
        return [(p.id, p.input, p) for p in suite.papers]
    files = sorted(f for f in target.rglob("*") if f.suffix.lower() in PAPER_SUFFIXES and f.name != "SOURCE.md")
    return [(f.stem, f, None) for f in files]


def survey(target: Path, work: Path | None = None, verify: bool = False, train: bool = False,
           on_row: Callable[[list[PaperRow]], None] | None = None) -> list[PaperRow]:
    """Every paper of ``target``, one at a time; ``on_row(rows so far)`` after each (a long survey's partial table).
    ``work``: where the run folders stay (a temporary folder when None)."""
    rows: list[PaperRow] = []
    with tempfile.TemporaryDirectory(prefix="nerfify-survey-") as tmp:
        base = Path(work or tmp)
        for pid, paper, entry in papers_of(target):
            row = run_paper_row(pid, paper, base / pid, verify, train=train)
            if entry is not None:
                row.family_expected = entry.family
                score_row(row, entry)
            rows.append(row)
            if on_row is not None:
                on_row(rows)
    return rows


def causes(rows: list[PaperRow]) -> dict:
    """Histogram: cause -> number of found parts not built (the buildable papers' holes)."""
    out: dict = {}
    for r in rows:
        if r.exit_code == 1 and "failed plan" in r.error:  # a family the grammar cannot build: nothing was tried
            continue
        for h in r.holes:
            if h.get("status") == "implemented":
                continue
            reason = str(h.get("reason") or h.get("why") or "")
            c = h.get("cause") if h.get("cause") in NAMES else cause_of(reason)
            out[c] = out.get(c, 0) + 1
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def totals(rows: list[PaperRow]) -> dict:
    items = [i for r in rows for i in r.items]
    holes = sum(len(r.holes) for r in rows)
    spurious = sum(len(r.spurious) for r in rows)
    found = sum(i["found"] for i in items)
    return {"papers": len(rows), "items": len(items), "found": found,
            "found_share": round(found / len(items), 3) if items else None,
            "implemented": sum(i["implemented"] for i in items),
            "implemented_share_of_found": round(sum(i["implemented"] for i in items) / found, 3) if found else None,
            "holes": holes, "spurious": spurious, "spurious_share": round(spurious / holes, 3) if holes else 0.0,
            "family_ok": sum(1 for r in rows if r.family_ok),
            "family_labelled": sum(1 for r in rows if r.family_expected),
            "tracebacks": sum(1 for r in rows if r.error.startswith("a traceback")), "not_built_causes": causes(rows)}


def table(rows: list[PaperRow]) -> str:
    """The survey as a markdown table, then the totals."""
    lines = ["| paper | family | base | contributions (new/known) | novel parts: found / implemented | spurious holes "
             "| exit |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        new = sum(1 for c in r.contributions if c.get("status") == "new")
        known = sum(1 for c in r.contributions if c.get("status") == "known")
        fam = r.family + ("" if r.family_ok in (None, True) else f" (labelled {r.family_expected})")
        items = (f"{sum(i['found'] for i in r.items)}/{len(r.items)} found, {sum(i['implemented'] for i in r.items)} "
                 "implemented") if r.items else f"{len(r.holes)} hole(s)"
        missing = [i["id"] for i in r.items if not i["found"]]
        if missing:
            items += f" (not found: {', '.join(missing)})"
        spur = "; ".join(r.spurious) if r.spurious else "0"
        lines.append(f"| {r.id} | {fam or '-'} | {r.base or '-'} | {new}/{known} | {items} | {spur} | "
                     f"{r.exit_code if r.exit_code is not None else '-'}{(': ' + r.error[:120]) if r.error else ''} |")
    t = totals(rows)
    lines.append("")
    lines.append(f"found {t['found']}/{t['items']} ({t['found_share']}), implemented {t['implemented']} of the found, "
                 f"spurious holes {t['spurious']}/{t['holes']} ({t['spurious_share']}), family "
                 f"{t['family_ok']}/{t['family_labelled']}, tracebacks {t['tracebacks']}")
    if t["not_built_causes"]:
        lines.append("why found parts were not built (papers the grammar can build): " + ", ".join(
            f"{name} {n}" for name, n in t["not_built_causes"].items()))
    return "\n".join(lines)


def _num(value: Any, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def train_table(rows: list[PaperRow]) -> str:
    """``--train``: one line a paper: exit, iterations trained and the budget's estimate (a training keeps the
    budget's deadline, so it may train more or fewer), within the budget (wall time against
    the budget), PSNR, colour ratio, the CPU proxy, the found parts built and verified, and why it did not train."""
    lines = ["| paper | exit | trained (iterations; the budget's estimate) | within budget (wall / budget) | PSNR (dB) "
             "| colour ratio | CPU proxy | found parts built / verified | why not trained |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        t = r.train
        if not t:
            continue
        trained = f"yes ({t.get('iterations')}; {t.get('planned')} estimated)" if t.get("trained") else "no"
        fits = {True: "yes", False: "no", None: "-"}[t.get("within_budget")]
        fits += f" ({_num(t.get('wall_seconds'), '.0f')} s / {_num(t.get('budget_seconds'), '.0f')} s)"
        parts = f"{t.get('built', 0)} / {t.get('verified', 0)} of {t.get('found', 0)}" if "found" in t else "-"
        lines.append(f"| {r.id} | {r.exit_code if r.exit_code is not None else '-'} | {trained} | {fits} | "
                     f"{_num(t.get('psnr'), '.2f')} | {_num(t.get('colour_ratio'), '.2f')} | "
                     f"{'yes: ' + t['proxy'] if t.get('proxy') else 'no'} | {parts} | {t.get('why') or ''} |")
    return "\n".join(lines)


def write(rows: list[PaperRow], out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "survey.json").write_text(json.dumps({"rows": [r.to_dict() for r in rows], "totals": totals(rows)},
                                                indent=2, default=str))
    trained = train_table(rows) if any(r.train for r in rows) else ""
    (out / "survey.md").write_text(table(rows) + "\n" + (f"\n{trained}\n" if trained else ""))


USAGE = ("usage: python -m nerfify_ns.nerfifybench.survey PAPER OUT  (one survey row's child: the paper's plan into "
         "OUT; run `ns-nerfify survey DIR|SUITE` for the survey)")


def main(argv: list[str]) -> int:
    """The child entry point: ``PAPER OUT``; anything else is the usage line, exit 2."""
    if len(argv) != 2 or argv[0].startswith("-"):
        print(USAGE, file=sys.stderr)
        return 2
    return _read_paper(Path(argv[0]), Path(argv[1]))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
