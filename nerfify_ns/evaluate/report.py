"""One self-contained report of a nerfify run folder: ``report.html`` and ``report.json``.

:func:`write_report` reads whatever a run folder (``ns-nerfify paper.pdf``'s output) holds and
says "not run" for each part that is absent::

    run.json              the run's outcome: which stages ran, failed (and why) or were not run; the report's top
    plan.yaml             plan with evidence, holes, pruned, paper
    paper.md              the cleaned paper
    evidence.json         technique detections with quotes
    citations.json/.png   the citation graph
    nerfify.json          the generated package lives in the run folder itself (its files are listed
                          there; README.md has the parts table); a plugin/ subfolder is read too
    verify.json           the verification ladder (rungs, rules, stability cases per component)
    eval/summary.json     metrics (evaluate_run); eval/curve.csv + curve.png (error against time)
    eval/error_maps.json  + <view>_errors.png panels (worst regions)
    eval/consistency.json + <view>_inconsistent.png masks
    patches/history.json  the patch loop's decisions

Each section is data: a list of blocks (heading, paragraph, table, figure, "not run", folded text) that
the Jinja2 template ``report.html.j2`` (package data beside this module) renders with autoescaping on, so
every text from the run folder (the paper's, the plugin's) is HTML-escaped. The HTML is one file: CSS
inline, every image a base64 ``data:`` URI, no script and no external URL, so it opens offline.
"""

from __future__ import annotations

import base64
import csv
import datetime as _dt
import io
import itertools
import json
import math
import re
from collections.abc import Callable, Sequence
from contextvars import ContextVar
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import jinja2
import yaml

from nerfify_ns import runfolder, safeio
from nerfify_ns.errors import NerfifyError

NOT_RUN = "not run"
MAX_TEXT = 200_000  # characters of paper.md shown
MAX_ROWS = 200
TEMPLATE = "report.html.j2"
STATUS_CLASSES = {"pass": "pass", "fail": "fail", "skip": "skip", "kept": "kept", "rejected": "rejected",
                  "invalid": "invalid", "ran": "pass", "failed": "fail", NOT_RUN: "skip"}
"""Cell texts shown with a status colour: text -> CSS class."""


class ReportError(NerfifyError):
    """The run folder cannot be reported (missing, or not a folder)."""


# ------------------------------------------------------------------------------------ reading


_ROOT: ContextVar[Path | None] = ContextVar("nerfify_report_root", default=None)
"""The run folder being reported: every file read must resolve inside it."""
MAX_YAML_NODES = 200_000
"""Nodes a run folder's YAML may expand to (ours hold a few thousand)."""
MAX_SOURCE = 1 << 20
"""Bytes of a generated component's code shown."""
MAX_LISTED = 10_000
"""Files of a plugin folder listed."""


def _inside(path: Path) -> Path:
    """``path`` when it resolves inside the run folder (no absolute path elsewhere, no ``..`` out, no link
    pointing out); a :class:`ReportError` otherwise: the report never reads nor inlines a file from elsewhere."""
    root = _ROOT.get()
    if root is None:
        return path
    try:
        relative: Any = Path(path).relative_to(root)
    except ValueError:
        relative = path
    try:
        return safeio.inside(root, relative, what="file")
    except safeio.ReadRefused as exc:
        raise ReportError(f"{root}: {exc}") from None


def _name(path: Path) -> str:
    root = _ROOT.get()
    try:
        return str(Path(path).relative_to(root)) if root is not None else Path(path).name
    except ValueError:
        return str(path)


def _present(path: Path) -> bool:
    return path.exists() or path.is_symlink()


def _refused(exc: safeio.ReadRefused) -> ReportError:
    root = _ROOT.get()
    return ReportError(f"{root}: {exc}" if root is not None else str(exc))


def _read_json(path: Path) -> tuple[Any, str | None]:
    """The JSON in ``path`` (None when absent) and an error text when it does not parse; a file over a limit
    (size, depth) or outside the run folder is a :class:`ReportError`."""
    if not _present(path):
        return None, None
    target = _inside(path)
    try:
        return safeio.load_json(target, what=_name(path)), None
    except safeio.NotParsed as exc:
        return None, str(exc)
    except safeio.ReadRefused as exc:
        raise _refused(exc) from None


def _read_yaml(path: Path) -> tuple[Any, str | None]:
    """The YAML in ``path`` (None when absent) and an error text when it does not parse; a file over a limit
    (size, depth, the nodes its aliases expand to) or outside the run folder is a :class:`ReportError`."""
    if not _present(path):
        return None, None
    target = _inside(path)
    try:
        return safeio.load_yaml(target, what=_name(path), max_nodes=MAX_YAML_NODES), None
    except safeio.NotParsed as exc:
        return None, str(exc)
    except safeio.ReadRefused as exc:
        raise _refused(exc) from None


def _read_text(path: Path, limit: int = safeio.MAX_TEXT) -> str | None:
    """The text of ``path`` (None when absent), read within ``limit`` bytes, inside the run folder."""
    if not _present(path):
        return None
    target = _inside(path)
    try:
        return safeio.read_text(target, limit, what=_name(path))
    except safeio.ReadRefused as exc:
        raise _refused(exc) from None


def _data_uri(path: Path) -> str | None:
    """``path`` as a base64 ``data:`` URI when it is a PNG or JPEG image inside the run folder, within the image
    limits of :mod:`nerfify_ns.safeio` (checked from its header; nothing is decoded)."""
    if not _present(path):
        return None
    target = _inside(path)
    try:
        mime, data = safeio.read_image_bytes(target, what=_name(path))
    except safeio.NotParsed:
        return None
    except safeio.ReadRefused as exc:
        raise _refused(exc) from None
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


# ---------------------------------------------------------------------------- blocks (the template renders them)

Block = dict[str, Any]


def _fmt(value: Any, digits: int = 3) -> str:
    """A value as the report shows it (short floats, yes/no, JSON for containers, '-' for None)."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if not math.isfinite(value):
            return str(value)
        return f"{value:.{digits}g}" if abs(value) < 1e-3 or abs(value) >= 1e5 else f"{value:.{digits}f}".rstrip(
            "0").rstrip(".")
    if isinstance(value, dict | list):
        return json.dumps(value, default=str, ensure_ascii=False)
    return str(value)


def cell(value: Any) -> dict:
    """A table cell: its text and, for a status word, its colour class."""
    text = _fmt(value)
    return {"text": text, "cls": STATUS_CLASSES.get(text)}


def table(rows: Sequence[dict], columns: Sequence[str] | None = None,
          headers: Sequence[str] | None = None) -> Block:
    """A table block of ``rows`` (the first :data:`MAX_ROWS`); '(none)' when there are none."""
    if not rows:
        return text_block("(none)", "muted")
    cols = list(columns) if columns else list(dict.fromkeys(k for r in rows for k in r))
    return {"kind": "table", "headers": list(headers or cols),
            "rows": [[cell(r.get(c)) for c in cols] for r in rows[:MAX_ROWS]],
            "more": max(len(rows) - MAX_ROWS, 0)}


def kv_table(mapping: dict) -> Block:
    return table([{"key": k, "value": v} for k, v in mapping.items()], ["key", "value"])


def text_block(text: str, cls: str | None = None) -> Block:
    """A paragraph (``cls``: muted, fail, notrun...)."""
    return {"kind": "p", "text": text, "cls": cls}


def heading(text: str) -> Block:
    return {"kind": "h3", "text": text}


def folded(summary: str, text: str) -> Block:
    """Preformatted text behind a summary line (plan.yaml, paper.md, ...)."""
    return {"kind": "details", "summary": summary, "text": text}


def pre(text: str) -> Block:
    return {"kind": "pre", "text": text}


def not_run(what: str) -> Block:
    return text_block(f"{what}: {NOT_RUN}", "notrun")


def error(text: str | None) -> list[Block]:
    """A red line for a file that did not parse (nothing when ``text`` is empty)."""
    return [text_block(text, "fail")] if text else []


def figure(path: Path, caption: str, images: list[str]) -> Block:
    """An inlined image (its name added to ``images``), or "not run" when the file is absent."""
    uri = _data_uri(path)
    if uri is None:
        return not_run(f"image {path.name}")
    images.append(path.name)
    return {"kind": "figure", "uri": uri, "caption": caption}


# ------------------------------------------------------------------------------------ sections


class _Builder:
    def __init__(self, run_dir: Path) -> None:
        self.run = run_dir
        self.eval = run_dir / "eval"
        self.images: list[str] = []
        self.sections: list[dict] = []  # {id, title, blocks}
        self.data: dict[str, dict] = {}

    def add(self, key: str, title: str, blocks: list[Block], data: dict) -> None:
        self.sections.append({"id": key, "title": title, "blocks": blocks})
        self.data[key] = data

    # ---------------------------------------------------------------- paper and plan
    def paper_and_plan(self) -> None:
        plan, err = _read_yaml(self.run / runfolder.PLAN)
        paper_md = self.run / runfolder.PAPER
        evidence, err_ev = _read_json(self.run / runfolder.EVIDENCE)
        blocks: list[Block] = error(err)
        data: dict = {"status": "ok" if isinstance(plan, dict) else NOT_RUN, "paper_md": NOT_RUN,
                      "evidence": NOT_RUN}
        if isinstance(plan, dict):
            paper = plan.get("paper") or {}
            info = {
                "method": plan.get("method"), "description": plan.get("description"), "base": plan.get("base"),
                "paper": ", ".join(str(paper[k]) for k in ("title", "year", "arxiv") if paper.get(k)) or None,
                "scene": plan.get("scene"),
            }
            blocks.append(kv_table(info))
            data.update(info)
            plan_evidence = plan.get("evidence") or {}
            blocks += [heading("Evidence for the plan"),
                       table([{"plan entry": k, "evidence": v} for k, v in plan_evidence.items()],
                             ["plan entry", "evidence"])]
            data["plan_evidence"] = plan_evidence
            pruned = plan.get("pruned") or []
            blocks += [heading("Left out for the scene (pruned)"),
                       table(pruned, ["path", "action", "from", "to", "reason"]),
                       folded(runfolder.PLAN, yaml.safe_dump(plan, sort_keys=False))]
            data["pruned"] = pruned
        else:
            blocks.append(not_run("plan (plan.yaml)"))
        text = _read_text(paper_md)
        if text is not None:
            headings = [line.lstrip("#").strip() for line in text.splitlines() if line.startswith("#")]
            data["paper_md"] = {"characters": len(text), "headings": headings[:50]}
            blocks += [heading("Cleaned paper"),
                       text_block(f"{len(text)} characters, {len(headings)} headings: {', '.join(headings[:20])}"),
                       folded(runfolder.PAPER, text[:MAX_TEXT])]
        else:
            blocks.append(not_run("cleaned paper (paper.md)"))
        blocks += [heading("Detected techniques"), *error(err_ev)]
        detections = evidence.get("detections", evidence) if isinstance(evidence, dict) else evidence
        if isinstance(detections, list):
            rows = [_detection_row(d) for d in detections if isinstance(d, dict)]
            blocks.append(table(rows, ["technique", "production", "status", "confidence", "quote", "where"]))
            data["evidence"] = rows
        else:
            blocks.append(not_run("technique detection (evidence.json)"))
        self.add("paper", "Paper and plan", blocks, data)

    # ---------------------------------------------------------------- citations
    def citations(self) -> None:
        graph, err = _read_json(self.run / runfolder.CITATIONS)
        png = self.run / runfolder.CITATIONS_FIGURE
        blocks, data = error(err), {"status": NOT_RUN}
        if png.is_file():
            blocks.append(figure(png, "citation graph (target paper -> cited dependencies)", self.images))
            data["image"] = png.name
        if isinstance(graph, dict):
            g = graph.get("graph", graph)
            nodes = g.get("nodes") or []
            links = g.get("links") or g.get("edges") or []
            data.update(status="ok", nodes=len(nodes), edges=len(links))
            rows = [{"from": lk.get("source"), "to": lk.get("target"), "relation": lk.get("relation"),
                     "components": lk.get("components")} for lk in links if isinstance(lk, dict)]
            blocks += [text_block(f"{len(nodes)} papers, {len(links)} dependencies."),
                       table(rows, ["from", "to", "relation", "components"])]
            resolution = graph.get("resolution")
            if isinstance(resolution, dict):
                blocks.append(folded("resolution", json.dumps(resolution, indent=2, default=str)))
        elif not png.is_file():
            blocks.append(not_run("citation graph (citations.json, citations.png)"))
        self.add("citations", "Citation graph", blocks, data)

    # ---------------------------------------------------------------- components and holes
    def components(self) -> None:
        meta, _ = _read_json(self.run / runfolder.PLUGIN_META)
        plugin = self.run if isinstance(meta, dict) else self.run / "plugin"
        plan, _ = _read_yaml(self.run / runfolder.PLAN)
        blocks: list[Block] = []
        data: dict = {"status": "ok" if plugin.is_dir() else NOT_RUN}
        if plugin.is_dir():
            files = sorted(map(str, meta["files"]))[:MAX_LISTED] if isinstance(meta, dict) else sorted(
                str(p.relative_to(plugin)) for p in itertools.islice(plugin.rglob("*"), MAX_LISTED)
                if p.is_file() and "__pycache__" not in p.parts and ".verify" not in p.parts)
            data["files"] = files
            readme = plugin / "README.md"
            readme_text = _read_text(readme)
            rows = parse_markdown_tables(readme_text) if readme_text is not None else []
            data["parts"] = rows
            blocks += [heading("Generated package"), text_block(f"{len(files)} files"), pre("\n".join(files)),
                       heading("Where each part comes from (README)"),
                       table(rows) if rows else not_run("README parts table")]
        else:
            blocks.append(not_run("generated package (plugin/)"))
            data["files"] = NOT_RUN
        blocks.append(heading("Not implemented (holes)"))
        if isinstance(plan, dict):
            rows = [h if isinstance(h, dict) else {"text": h} for h in plan.get("holes") or []]
            blocks.append(table(rows) if rows else
                          text_block("No holes: every production the plan needs is filled."))
            data["holes"] = rows
        else:
            blocks.append(not_run("plan (plan.yaml)"))
            data["holes"] = NOT_RUN
        self.add("components", "Components implemented and holes", blocks, data)

    # ---------------------------------------------------------------- novel parts (the equation compiler)
    def novel_parts(self) -> None:
        """equations.yaml: per hole, implemented / partly / not implemented with the reason, the equations as read
        (rendered, beside the PDF region they came from), bindings, sizes, state, the generated code, the checks."""
        records, err = _read_yaml(self.run / runfolder.EQUATIONS)
        blocks = error(err)
        if not isinstance(records, dict) or not isinstance(records.get("holes"), list):
            self.add("equations", "Novel parts from the paper's equations",
                     blocks + [not_run("equation compiler (equations.yaml)")], {"status": NOT_RUN})
            return
        holes = [h for h in records["holes"] if isinstance(h, dict)]
        summary = str(records.get("summary") or "")
        counts = records.get("equations") if isinstance(records.get("equations"), dict) else {}
        blocks.append(text_block(summary, "headline"))
        if counts:
            blocks.append(text_block(f"numbered equations found {counts.get('numbered', 0)}, read "
                                     f"{counts.get('read', 0)}; displayed equations {counts.get('displayed', 0)}; "
                                     f"compiler time {records.get('seconds', '?')} s", "muted"))
        agents, _ = _read_json(self.run / runfolder.AGENTS)
        spent = ((agents or {}).get("usage") or {}).get("scopes") or {} if isinstance(agents, dict) else {}
        blocks.append(table([{"part": h.get("id"), "production": h.get("production"), "slot": h.get("slot"),
                              "status": h.get("status"), "written by": _writer(h),
                              **({"model calls / tokens / cost": _spent(spent.get(f"coder:{h.get('id')}"))}
                                 if agents is not None else {}),
                              "reason": h.get("reason")} for h in holes]))
        for h in holes:
            blocks.append(heading(f"{h.get('production')} at {h.get('slot')}: {h.get('status')}"))
            blocks.append(text_block(str(h.get("reason") or "")))
            rows = []
            for e in h.get("equations") or []:
                if not isinstance(e, dict):
                    continue
                rows.append({"eq.": e.get("number") or e.get("key"), "as read": e.get("reading"),
                             "status": e.get("status"), "where": e.get("where")})
                for name, caption in (("image", "as read (rendered)"), ("crop", "in the paper (PDF crop)")):
                    if e.get(name):
                        blocks.append(figure(self.run / "equations" / str(e[name]),
                                             f"({e.get('number') or e.get('key')}) {caption}", self.images))
            if rows:
                blocks.append(table(rows))
            bindings = h.get("bindings") or {}
            if bindings:
                blocks.append(table([{"symbol": k, "as": (v or {}).get("as"), "role": (v or {}).get("role"),
                                      "from": (v or {}).get("source"), "evidence": (v or {}).get("evidence")}
                                     for k, v in bindings.items() if isinstance(v, dict)]))
            sizes = h.get("sizes") or {}
            if sizes:
                blocks.append(table([{"symbol": k, "shape": (v or {}).get("shape"), "from": (v or {}).get("source"),
                                      "evidence": (v or {}).get("evidence")} for k, v in sizes.items()
                                     if isinstance(v, dict)]))
            for key, st in (h.get("state") or {}).items():
                blocks.append(text_block(f"persistent state {key}: {st.get('rows')} rows, starts at "
                                         f"{st.get('initial')}; {st.get('note')}"))
            for note in h.get("notes") or []:
                blocks.append(text_block(str(note), "muted"))
            checks = h.get("checks") or {}
            if checks:
                blocks.append(kv_table({k: v for k, v in checks.items() if k != "check_sizes"}))
            source = self.run / "equations" / f"{h.get('id')}.py"
            code = _read_text(source, MAX_SOURCE)
            if code is not None:
                blocks.append(folded(f"generated code: equations/{source.name}", code))
        n = len(holes)
        self.add("equations", "Novel parts from the paper's equations", blocks,
                 {"status": "ok", "summary": summary, "holes": n, "counts": counts,
                  "implemented": sum(_counts_as_implemented(h) for h in holes),
                  "partly": sum(h.get("status") == "partly implemented" for h in holes)})

    # ---------------------------------------------------------------- model-backed agents (--llm)
    def agents(self) -> None:
        """agents.json: the endpoint (never a key), calls, cache hits, tokens and cost per stage, warnings, the
        planner's disagreements with the deterministic plan, the coder's rounds per hole."""
        data, err = _read_json(self.run / runfolder.AGENTS)
        if data is None and err is None:
            return  # no --llm: the report is the deterministic path's, without this section
        if not isinstance(data, dict):
            self.add("agents", "Model-backed agents (--llm)", error(err or "agents.json is not an object"),
                     {"status": "error"})
            return
        usage = data.get("usage") or {}
        blocks = [kv_table({k: v for k, v in (data.get("endpoint") or {}).items()})]
        rows = [{"stage": name, **{k: _fmt(v) for k, v in (spent or {}).items()}}
                for name, spent in [("total", usage.get("total")), *(usage.get("stages") or {}).items()]]
        blocks.append(table(rows))
        for line in data.get("warnings") or []:
            blocks.append(text_block(f"warning: {line}"))
        planner = data.get("planner") or {}
        if planner.get("disagreements"):
            blocks.append(heading("planner: disagreements with the deterministic plan"))
            blocks.append(table([{"path": d.get("path"), "deterministic": d.get("deterministic"),
                                  "its evidence": d.get("deterministic_evidence"), "model": d.get("model"),
                                  "model's quote": d.get("model_evidence"), "quote in paper": d.get("quote_found"),
                                  "kept": d.get("winner")} for d in planner["disagreements"]]))
        for c in data.get("coder") or []:
            blocks.append(heading(f"coder: {c.get('hole')} ({c.get('production')}): {c.get('status')}"))
            blocks.append(text_block(str(c.get("reason") or "")))
            blocks.append(table([{"round": r.get("round"), "status": r.get("status"), "rungs": r.get("rungs"),
                                  "diagnosis": r.get("diagnosis")} for r in c.get("rounds") or []]))
        self.add("agents", "Model-backed agents (--llm)", blocks,
                 {"status": "ok", "total": usage.get("total"), "stages": usage.get("stages"),
                  "warnings": data.get("warnings") or []})

    # ---------------------------------------------------------------- verification
    def verification(self) -> None:
        report, err = _read_json(self.run / runfolder.VERIFY)
        blocks = error(err)
        if not isinstance(report, dict):
            self.add("verification", "Verification ladder", blocks + [not_run("verification ladder (verify.json)")],
                     {"status": NOT_RUN})
            self.add("stability", "Stability cases", [not_run("stability cases (verify.json)")], {"status": NOT_RUN})
            return
        rungs = [r for r in report.get("rungs") or [] if isinstance(r, dict)]
        rows = [{"rung": r.get("name"), "status": r.get("status"), "checks": r.get("checks"),
                 "seconds": r.get("seconds"), "failures": len(r.get("failures") or []),
                 "notes": "; ".join(map(str, r.get("notes") or []))} for r in rungs]
        ok = report.get("ok")
        failures = [f for f in report.get("failures") or [] if isinstance(f, dict)]
        blocks += [{"kind": "verdict", "label": "Overall", "cell": cell("pass" if ok else "fail" if ok is not None
                                                                       else None)},
                   table(rows, ["rung", "status", "checks", "seconds", "failures", "notes"]),
                   heading("Broken rules"),
                   table([{"rung": f.get("rung"), "rule": f.get("rule"), "where": f.get("file") or f.get("component"),
                           "message": f.get("message")} for f in failures], ["rung", "rule", "where", "message"])]
        if report.get("patches"):
            blocks += [heading("Repairs"), table([p if isinstance(p, dict) else {"patch": p}
                                                  for p in report["patches"]])]
        self.add("verification", "Verification ladder", blocks,
                 {"status": "pass" if ok else "fail", "rungs": rows, "failures": failures})
        cases = [{"rung": r.get("name"), **case} for r in rungs for case in (r.get("details") or {}).get("cases") or []
                 if isinstance(case, dict) and (r.get("name") == "stability" or case.get("case"))]
        stability = [c for c in cases if c["rung"] == "stability"] or cases
        block = table(stability, ["component", "case", "status", "problems", "implementation"]) if stability \
            else not_run("stability cases")
        self.add("stability", "Stability cases", [block], {"status": "ok" if stability else NOT_RUN,
                                                          "cases": stability})

    # ---------------------------------------------------------------- metrics and curve
    def metrics(self) -> None:
        summary, err = _read_json(self.eval / runfolder.SUMMARY)
        if not isinstance(summary, dict):
            self.add("metrics", "Metrics", error(err) + [not_run("evaluation (eval/summary.json)")],
                     {"status": NOT_RUN})
            return
        keys = ["label", "status", "reason", "psnr", "ssim", "lpips", "seconds", "iterations_done", "eval_seconds",
                "worst_regions"]
        row = {k: summary.get(k) for k in keys if k in summary}
        if summary.get("lpips") is None:
            row["lpips"] = "unavailable (no AlexNet weights)"
        row["consistency score"] = (summary.get("consistency") or {}).get("mean_score")
        blocks = [kv_table(row)]
        if summary.get("diagnostics"):
            blocks += [heading("Where the error is"), kv_table(summary["diagnostics"])]
        self.add("metrics", "Metrics", blocks, {"status": summary.get("status", "ok"), **row,
                                                "diagnostics": summary.get("diagnostics")})

    def curve(self) -> None:
        csv_path, png = self.eval / runfolder.CURVE, self.eval / runfolder.CURVE_FIGURE
        blocks, data = [], {"status": NOT_RUN}
        if png.is_file():
            blocks.append(figure(png, "held-out PSNR against training seconds (evaluation time excluded)",
                                 self.images))
            data["image"] = png.name
        text = _read_text(csv_path)
        if text is not None:
            rows = list(csv.DictReader(io.StringIO(text, newline="")))
            blocks.append(table(rows))
            data.update(status="ok", points=rows)
        if not blocks:
            blocks.append(not_run("error against time (eval/curve.csv, eval/curve.png)"))
        self.add("curve", "Error against training time", blocks, data)

    # ---------------------------------------------------------------- error maps, consistency
    def error_maps(self) -> None:
        views, err = _read_json(self.eval / runfolder.ERROR_MAPS)
        if not isinstance(views, list):
            self.add("error_maps", "Error maps and worst regions", error(err) + [not_run("error maps "
                                                                                          "(eval/error_maps.json)")],
                     {"status": NOT_RUN})
            return
        blocks = [text_block("Each panel: ground truth | render | squared error (boxes: worst regions, rank 1 in "
                             "cyan).", "muted")]
        rows = []
        for v in (v for v in views if isinstance(v, dict)):
            if v.get("panel"):
                caption = f"{v.get('view')}: PSNR {_fmt(v.get('psnr'))} dB, SSIM {_fmt(v.get('ssim'))}"
                blocks.append(figure(self.eval / Path(v["panel"]).name, caption, self.images))
            for rank, r in enumerate(v.get("regions") or [], start=1):
                rows.append({"view": v.get("view"), "rank": rank,
                             "box (x0, y0, x1, y1)": [r.get("x0"), r.get("y0"), r.get("x1"), r.get("y1")],
                             "area": r.get("area"), "local PSNR": r.get("local_psnr")})
        blocks += [heading("Worst regions"), table(rows)]
        self.add("error_maps", "Error maps and worst regions", blocks,
                 {"status": "ok", "views": len(views), "regions": rows})

    def consistency(self) -> None:
        report, err = _read_json(self.eval / runfolder.CONSISTENCY)
        if not isinstance(report, dict):
            self.add("consistency", "Cross-view consistency", error(err) + [not_run("consistency "
                                                                                     "(eval/consistency.json)")],
                     {"status": NOT_RUN})
            return
        blocks = [text_block(f"Mean consistency score {_fmt(report.get('mean_score'))} (fraction of checked surface "
                             "pixels that no other view sees through); white pixels in the masks are inconsistent "
                             "(floaters).")]
        views = [v for v in report.get("views") or [] if isinstance(v, dict)]
        for i, v in enumerate(views):
            name = v.get("view") or f"view_{i:03d}"
            blocks.append(figure(self.eval / f"{name}_inconsistent.png", f"{name}: score {_fmt(v.get('score'))}",
                                 self.images))
        blocks.append(table(views))
        self.add("consistency", "Cross-view consistency", blocks,
                 {"status": "ok", "mean_score": report.get("mean_score"), "views": views})

    # ---------------------------------------------------------------- patch loop
    def patches(self) -> None:
        history, err = _read_json(self.run / "patches" / runfolder.PATCH_HISTORY)
        if not isinstance(history, dict):
            self.add("patches", "Patch loop", error(err) + [not_run("patch loop (patches/history.json)")],
                     {"status": NOT_RUN})
            return
        entries = [x for x in history.get("entries") or [] if isinstance(x, dict)]
        rows = [{"round": x.get("round"), "diagnosis": (x.get("diagnosis") or {}).get("name"),
                 "patch": (x.get("patch") or {}).get("rule"),
                 "edits": "; ".join(f"{d.get('op')} {d.get('path')} = {_fmt(d.get('value'))}"
                                    for d in (x.get("patch") or {}).get("edits") or []),
                 "PSNR before": x.get("psnr_before"), "PSNR after": x.get("psnr_after"), "noise": x.get("noise"),
                 "decision": x.get("decision"), "reason": x.get("reason")} for x in entries]
        rounds = [{"round": r.get("round"), "PSNR": r.get("psnr"), "runs": r.get("psnr_runs"),
                   "noise": r.get("noise"), "diagnoses": ", ".join(d.get("name", "") for d in r.get("diagnoses") or []),
                   "kept": r.get("kept")} for r in history.get("rounds") or [] if isinstance(r, dict)]
        blocks = [text_block(str(history.get("noise_definition") or "")),
                  text_block(f"Stopped: {history.get('stopped')}; best PSNR {_fmt(history.get('best_psnr'))} dB."),
                  heading("Rounds"), table(rounds), heading("Decisions"), table(rows)]
        self.add("patches", "Patch-loop history", blocks,
                 {"status": "ok", "stopped": history.get("stopped"), "best_psnr": history.get("best_psnr"),
                  "rounds": rounds, "entries": rows})


def _detection_row(d: dict) -> dict:
    """One detected technique: its best quote and where it is."""
    quotes = [ev for ev in d.get("evidence") or [] if isinstance(ev, dict)]
    best = max(quotes, key=lambda ev: ev.get("weight") or 0, default={})
    where = ", ".join(x for x in (f"p.{best['page']}" if best.get("page") is not None else "",
                                  f"Sec. {best['section']}" if best.get("section") else "") if x)
    return {"technique": d.get("title") or d.get("card"), "production": d.get("production"),
            "status": d.get("status"), "confidence": d.get("confidence"), "quote": best.get("quote"),
            "where": where or None}


def _counts_as_implemented(hole: dict) -> bool:
    """A hole counts as a novel part implemented when its record says so and none of its checks says otherwise:
    no ladder rung took its component out again, and a model's component only when the coder's last round passed
    the sandboxed ladder (a status alone, which a forged or hand-edited record could carry, is not enough)."""
    if hole.get("status") != "implemented":
        return False
    checks = hole.get("checks") if isinstance(hole.get("checks"), dict) else {}
    if checks.get("ladder"):
        return False
    if _writer(hole) == "model":
        rounds = checks.get("coder")
        last = rounds[-1] if isinstance(rounds, list) and rounds else None
        return isinstance(last, dict) and last.get("status") == "pass"
    return True


def _writer(hole: dict) -> str:
    """Who wrote a hole's code: the equation compiler, a model, a person, or nobody (the base's part)."""
    if hole.get("status") == "not implemented":
        return "-"
    source = (hole.get("component") or {}).get("source") if isinstance(hole.get("component"), dict) else None
    return {"compiler": "equation compiler", "model": "model", "hand": "a person"}.get(source or "", source or "-")


def _spent(spent: dict | None) -> str:
    if not spent:
        return "-"
    cost = spent.get("cost_usd")
    return (f"{spent.get('calls', 0)} calls ({spent.get('cache_hits', 0)} cached), {spent.get('tokens', 0)} tokens, "
            + ("cost unknown" if cost is None else f"{cost:.4f} USD"))


def parse_markdown_tables(text: str) -> list[dict]:
    """Rows of the first pipe table in a markdown text (backticks stripped from cells)."""
    rows: list[dict] = []
    header: list[str] | None = None
    for line in text.splitlines():
        line = line.strip()
        if not line.startswith("|"):
            if header is not None:
                break
            continue
        cells = [c.strip().strip("`") for c in line.strip("|").split("|")]
        if header is None:
            header = cells
        elif not all(re.fullmatch(r":?-{2,}:?", c) for c in cells if c):
            rows.append(dict(zip(header, cells, strict=False)))
    return rows


SECTIONS: Sequence[Callable[[_Builder], None]] = (
    _Builder.paper_and_plan, _Builder.citations, _Builder.components, _Builder.novel_parts, _Builder.agents,
    _Builder.verification,
    _Builder.metrics,
    _Builder.curve, _Builder.error_maps, _Builder.consistency, _Builder.patches,
)


# ------------------------------------------------------------------------------------ the outcome (the report's top)


GREY_RENDER_RATIO = 0.5
"""Renders whose foreground colour spread is under this fraction of the ground truth's are grey (measured grey
renders: 0.00-0.09x; the main job's renders 0.7-0.8x): the headline says so, in amber."""


def grey_ratio(diagnostics: Any) -> float | None:
    """The foreground colour spread against the ground truth's when it is under :data:`GREY_RENDER_RATIO` (the
    renders are grey), else None."""
    ratio = diagnostics.get("colour_spread_ratio") if isinstance(diagnostics, dict) else None
    return float(ratio) if isinstance(ratio, int | float) and ratio < GREY_RENDER_RATIO else None


def _smoke_unverified(run_dir: Path) -> bool:
    """Whether the ladder's smoke rung ran out of time (``verify.json``: its verdict "not verified: time"): what was
    built passed the checks before it, not the training."""
    ladder, _ = _read_json(run_dir / runfolder.VERIFY)
    rungs = ladder.get("rungs") if isinstance(ladder, dict) else None
    return any(isinstance(r, dict) and r.get("name") == "smoke" and isinstance(r.get("details"), dict)
               and r["details"].get("verdict") == "not verified: time" for r in rungs or [])


def read_outcome(run_dir: Path, sections: dict[str, dict]) -> dict:
    """The run's outcome from ``run.json`` (written by the pipeline): the stages that ran, the one that failed
    and why, those not run and why. A folder without it gets the parts it holds, stated as such."""
    outcome, err = _read_json(run_dir / runfolder.OUTCOME)
    novel = sections.get("equations") or {}
    counts = ({"found": novel["holes"], "built": novel.get("implemented") or 0}
              if isinstance(novel.get("holes"), int) else None)
    unverified = _smoke_unverified(run_dir)
    verified = ("built; the smoke rung not verified: time (static, contract and stability passed)" if unverified
                else "built and verified")
    novel_line = (f"Novel parts: {counts['built']} of {counts['found']} found {verified}. "
                  if counts and counts.get("found") else
                  (f"Novel parts: {novel['summary']}. " if novel.get("summary") else ""))
    partial = bool(counts) and (counts.get("built", 0) < counts.get("found", 0)
                                or (unverified and counts.get("built", 0) > 0))
    summary, _ = _read_json(run_dir / runfolder.EVAL_DIR / runfolder.SUMMARY)
    ratio = grey_ratio(summary.get("diagnostics") if isinstance(summary, dict) else None)
    if ratio is not None:  # trained, but nothing a person recognises
        novel_line = f"Renders grey: foreground colour spread {ratio:.2f}x the ground truth's. " + novel_line
        partial = True
    if isinstance(summary, dict) and summary.get("stopped"):  # its limit stopped training: evaluated where it was
        novel_line = f"Training {summary['stopped']}. " + novel_line
        partial = True
    if isinstance(outcome, dict) and isinstance(outcome.get("stages"), list):
        stages = [s for s in outcome["stages"] if isinstance(s, dict)]
        return {"known": True, "ok": bool(outcome.get("ok")), "partial": partial,
                "headline": novel_line + str(outcome.get("headline") or ""),
                "until": outcome.get("until"), "command": outcome.get("command"), "failed": outcome.get("failed"),
                "stages": [{k: s.get(k) for k in ("name", "status", "seconds", "summary", "reason")} for s in stages]}
    present = [k for k, v in sections.items() if v.get("status") != NOT_RUN]
    failed = [k for k, v in sections.items() if v.get("status") in ("fail", "failed")]
    headline = (f"{err}; " if err else "no run.json (not written by ns-nerfify's pipeline); ") + \
        f"parts present: {', '.join(present) or 'none'}"
    return {"known": False, "ok": not failed, "partial": partial, "headline": headline, "until": None, "command": None,
            "failed": {"name": failed[0], "reason": "see its section"} if failed else None, "stages": []}


def headline_views(run_dir: Path, images: list[str]) -> tuple[list[Block], str | None]:
    """What the report opens with: ground truth | render | error of the best and of the worst test view (by PSNR),
    and one line of the result (PSNR, the foreground's colour spread against the ground truth's, iterations and
    seconds, the budget). Nothing when the evaluation did not run."""
    views, _ = _read_json(run_dir / "eval" / runfolder.ERROR_MAPS)
    summary, _ = _read_json(run_dir / "eval" / runfolder.SUMMARY)
    blocks: list[Block] = []
    scored = [v for v in views or []
              if isinstance(v, dict) and v.get("panel") and isinstance(v.get("psnr"), int | float)]
    if scored:
        ranked = sorted(scored, key=lambda v: v["psnr"], reverse=True)
        for label, v in (("best", ranked[0]), ("worst", ranked[-1]))[: 1 if len(ranked) == 1 else 2]:
            caption = (f"{label} test view {v.get('view')}: ground truth | render | error, PSNR {_fmt(v['psnr'])} dB, "
                       f"SSIM {_fmt(v.get('ssim'))}")
            blocks.append(figure(run_dir / "eval" / Path(v["panel"]).name, caption, images))
    line = None
    if isinstance(summary, dict) and summary.get("status") == "ok":
        diag = summary.get("diagnostics") or {}
        parts = [f"held-out PSNR {_fmt(summary.get('psnr'))} dB"]
        if diag.get("colour_spread") is not None and diag.get("colour_spread_gt") is not None:
            parts.append(f"foreground colour spread {_fmt(diag['colour_spread'])} (ground truth "
                         f"{_fmt(diag['colour_spread_gt'])})")
        parts.append(f"{summary.get('iterations_done')} iterations in {_fmt(summary.get('seconds'), 1)} s of training")
        budget = summary.get("budget") or {}
        if budget.get("seconds"):
            parts.append(f"budget {_fmt(budget['seconds'])} s: {budget.get('reason')}")
        schedule = summary.get("schedule") or {}
        proxy = schedule.get("proxy") or {}
        if proxy.get("headline"):  # what was trained, when it was not the paper's settings
            parts.insert(0, str(proxy["headline"]))
        if schedule.get("factor"):
            parts.append(f"schedule scaled x{_fmt(schedule['factor'])} from the paper's "
                         f"{schedule.get('paper_iterations')} iterations")
        line = "; ".join(parts)
    return blocks, line


# ------------------------------------------------------------------------------------ page


@lru_cache(maxsize=1)
def _template() -> jinja2.Template:
    """``report.html.j2`` (package data), autoescaped: every text from the run folder is HTML-escaped."""
    source = resources.files("nerfify_ns.evaluate").joinpath(TEMPLATE).read_text(encoding="utf-8")
    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined, trim_blocks=True,
                             lstrip_blocks=True)
    return env.from_string(source)


def render_html(title: str, run_dir: Path, outcome: dict, sections: list[dict]) -> str:
    """The report page from its parts (the template does the markup and escaping)."""
    return _template().render(title=title, run_dir=str(run_dir), outcome=outcome, sections=sections,
                              stamp=_dt.datetime.now().isoformat(timespec="seconds"))


def _write_atomic(path: Path, text: str) -> None:
    """``text`` into ``path`` through a fresh temporary file (never through a link planted in the folder)."""
    import os
    import tempfile

    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _shaped(part: str, build: Callable[[], Any]) -> Any:
    """``build()``, with a file of the run folder that is not shaped as nerfify-ns writes it (a list where a
    mapping belongs, a number where a list does) turned into one :class:`ReportError` naming the part."""
    try:
        return build()
    except (AttributeError, TypeError, KeyError, ValueError, IndexError, RecursionError) as exc:
        raise ReportError(f"{_ROOT.get()}: cannot report its {part.replace('_', ' ')}: a file there is not "
                          f"shaped as nerfify-ns writes it ({type(exc).__name__}: {str(exc)[:160]})") from None


def write_report(run_dir: Path) -> tuple[Path, Path]:
    """Write ``report.html`` and ``report.json`` into ``run_dir``; returns their paths."""
    run_dir = Path(run_dir).absolute()
    if not run_dir.is_dir():
        raise ReportError(f"{run_dir} is not a folder; pass the output folder of 'ns-nerfify PAPER'")
    token = _ROOT.set(run_dir)
    try:
        builder = _Builder(run_dir)
        for section in SECTIONS:
            _shaped(section.__name__, lambda section=section: section(builder))
        outcome = _shaped("outcome", lambda: read_outcome(run_dir, builder.data))
        views, result = _shaped("headline", lambda: headline_views(run_dir, builder.images))
        outcome.update(views=views, result=result)
        plan, _ = _read_yaml(run_dir / runfolder.PLAN)
    finally:
        _ROOT.reset(token)
    title = f"nerfify report: {plan.get('method')}" if isinstance(plan, dict) and plan.get("method") \
        else f"nerfify report: {run_dir.name}"
    html_path, json_path = run_dir / runfolder.REPORT_HTML, run_dir / runfolder.REPORT_JSON
    html = _shaped("page", lambda: render_html(title, run_dir, outcome, builder.sections))
    payload = {
        "title": title,
        "run_dir": str(run_dir),
        "outcome": {**outcome, "views": [v.get("caption") or v.get("text") for v in views]},
        "sections": builder.data,
        "not_run": [k for k, v in builder.data.items() if isinstance(v, dict) and v.get("status") == NOT_RUN],
        "images": builder.images,
    }
    text = _shaped(runfolder.REPORT_JSON, lambda: json.dumps(payload, indent=2, default=str, ensure_ascii=False) + "\n")
    _write_atomic(html_path, html)  # both built before either is written: a refusal writes nothing
    _write_atomic(json_path, text)
    return html_path, json_path
