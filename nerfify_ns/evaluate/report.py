"""One self-contained report of a nerfify run folder: ``report.html`` and ``report.json``.

:func:`write_report` reads whatever a run folder (``ns-nerfify paper.pdf``'s output) holds and
says "not run" for each part that is absent::

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

The HTML is one file: CSS inline, every image a base64 ``data:`` URI, no script and no external
URL, so it opens offline; every text from the run folder is HTML-escaped.
"""

from __future__ import annotations

import base64
import csv
import datetime as _dt
import html
import json
import math
import re
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import yaml

from nerfify_ns.errors import NerfifyError

NOT_RUN = "not run"
MAX_TEXT = 200_000  # characters of paper.md shown
MAX_ROWS = 200


class ReportError(NerfifyError):
    """The run folder cannot be reported (missing, or not a folder)."""


# ------------------------------------------------------------------------------------ reading


def _read_json(path: Path) -> Tuple[Any, Optional[str]]:
    if not path.is_file():
        return None, None
    try:
        return json.loads(path.read_text(errors="replace")), None
    except ValueError as exc:
        return None, f"{path.name} is not valid JSON: {exc}"


def _read_yaml(path: Path) -> Tuple[Any, Optional[str]]:
    if not path.is_file():
        return None, None
    try:
        return yaml.safe_load(path.read_text(errors="replace")), None
    except yaml.YAMLError as exc:
        return None, f"{path.name} is not valid YAML: {exc}"


def _data_uri(path: Path) -> Optional[str]:
    if not path.is_file():
        return None
    data = path.read_bytes()
    mime = "image/png" if data[:8] == b"\x89PNG\r\n\x1a\n" else "image/jpeg" if data[:2] == b"\xff\xd8" else None
    if mime is None:
        return None
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


# ------------------------------------------------------------------------------------ html bits

e = html.escape

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:0;background:#f6f7f9;color:#1d2330}
main{max-width:1100px;margin:0 auto;padding:24px}
h1{font-size:1.7em;margin:0 0 4px} h2{border-bottom:2px solid #dde2ea;padding-bottom:4px;margin-top:32px}
section{background:#fff;border:1px solid #e1e5ec;border-radius:8px;padding:12px 18px;margin:16px 0}
table{border-collapse:collapse;margin:8px 0;font-size:.9em;width:100%}
th,td{border:1px solid #dde2ea;padding:4px 8px;text-align:left;vertical-align:top;overflow-wrap:anywhere}
th{background:#eef1f6} code,pre{font-family:ui-monospace,Menlo,Consolas,monospace;font-size:.88em}
pre{background:#f3f5f8;padding:8px;overflow:auto;max-height:420px;white-space:pre-wrap}
.notrun{color:#8a6d00;background:#fff8db;border:1px solid #f0dc8c;padding:6px 10px;border-radius:6px}
.pass{color:#17702d;font-weight:600}.fail{color:#b3261e;font-weight:600}.skip{color:#7a7a7a}
.kept{color:#17702d;font-weight:600}.rejected{color:#b3261e}.invalid{color:#7a7a7a}
figure{display:inline-block;margin:8px 12px 8px 0;vertical-align:top}
figcaption{font-size:.85em;color:#4a5263} img{max-width:100%;image-rendering:pixelated;border:1px solid #dde2ea}
.muted{color:#5d6677;font-size:.9em} nav a{margin-right:10px;font-size:.9em}
"""


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if not math.isfinite(value):
            return str(value)
        return f"{value:.{digits}g}" if abs(value) < 1e-3 or abs(value) >= 1e5 else f"{value:.{digits}f}".rstrip(
            "0").rstrip(".")
    if isinstance(value, (dict, list)):
        return json.dumps(value, default=str, ensure_ascii=False)
    return str(value)


def _cell(value: Any) -> str:
    text = _fmt(value)
    if text in ("pass", "fail", "skip", "kept", "rejected", "invalid"):
        return f'<span class="{text}">{e(text)}</span>'
    return e(text)


def table(rows: Sequence[dict], columns: Optional[Sequence[str]] = None, headers: Optional[Sequence[str]] = None) -> str:
    if not rows:
        return '<p class="muted">(none)</p>'
    cols = list(columns) if columns else list(dict.fromkeys(k for r in rows for k in r))
    head = "".join(f"<th>{e(h)}</th>" for h in (headers or cols))
    body = "".join("<tr>" + "".join(f"<td>{_cell(r.get(c))}</td>" for c in cols) + "</tr>" for r in rows[:MAX_ROWS])
    more = f'<p class="muted">({len(rows) - MAX_ROWS} more rows in the JSON)</p>' if len(rows) > MAX_ROWS else ""
    return f"<table><tr>{head}</tr>{body}</table>{more}"


def kv_table(mapping: dict) -> str:
    return table([{"key": k, "value": v} for k, v in mapping.items()], ["key", "value"])


def figure(path: Path, caption: str, images: List[str]) -> str:
    uri = _data_uri(path)
    if uri is None:
        return f'<p class="notrun">image {e(path.name)}: {NOT_RUN}</p>'
    images.append(path.name)
    return f'<figure><img src="{uri}" alt="{e(caption)}"><figcaption>{e(caption)}</figcaption></figure>'


def not_run(what: str) -> str:
    return f'<p class="notrun">{e(what)}: {NOT_RUN}</p>'


# ------------------------------------------------------------------------------------ sections


class _Builder:
    def __init__(self, run_dir: Path) -> None:
        self.run = run_dir
        self.eval = run_dir / "eval"
        self.images: List[str] = []
        self.sections: List[Tuple[str, str, str]] = []  # (id, title, html)
        self.data: Dict[str, dict] = {}

    def add(self, key: str, title: str, body: str, data: dict) -> None:
        self.sections.append((key, title, body))
        self.data[key] = data

    # ---------------------------------------------------------------- paper and plan
    def paper_and_plan(self) -> None:
        plan, err = _read_yaml(self.run / "plan.yaml")
        paper_md = self.run / "paper.md"
        evidence, err_ev = _read_json(self.run / "evidence.json")
        parts: List[str] = []
        data: dict = {"status": "ok" if isinstance(plan, dict) else NOT_RUN, "paper_md": NOT_RUN,
                      "evidence": NOT_RUN}
        if err:
            parts.append(f'<p class="fail">{e(err)}</p>')
        if isinstance(plan, dict):
            paper = plan.get("paper") or {}
            info = {
                "method": plan.get("method"), "description": plan.get("description"), "base": plan.get("base"),
                "paper": ", ".join(str(paper[k]) for k in ("title", "year", "arxiv") if paper.get(k)) or None,
                "scene": plan.get("scene"),
            }
            parts.append(kv_table(info))
            data.update({k: v for k, v in info.items()})
            plan_evidence = plan.get("evidence") or {}
            parts.append("<h3>Evidence for the plan</h3>")
            parts.append(table([{"plan entry": k, "evidence": v} for k, v in plan_evidence.items()],
                               ["plan entry", "evidence"]) if plan_evidence else '<p class="muted">(none)</p>')
            data["plan_evidence"] = plan_evidence
            pruned = plan.get("pruned") or []
            parts.append("<h3>Left out for the scene (pruned)</h3>")
            parts.append(table(pruned, ["path", "action", "from", "to", "reason"]))
            data["pruned"] = pruned
            parts.append(f"<details><summary>plan.yaml</summary><pre>{e(yaml.safe_dump(plan, sort_keys=False))}</pre>"
                         "</details>")
        else:
            parts.append(not_run("plan (plan.yaml)"))
        if paper_md.is_file():
            text = paper_md.read_text(errors="replace")
            headings = [line.lstrip("#").strip() for line in text.splitlines() if line.startswith("#")]
            data["paper_md"] = {"characters": len(text), "headings": headings[:50]}
            parts.append(f"<h3>Cleaned paper</h3><p>{len(text)} characters, {len(headings)} headings: "
                         f"{e(', '.join(headings[:20]))}</p><details><summary>paper.md</summary>"
                         f"<pre>{e(text[:MAX_TEXT])}</pre></details>")
        else:
            parts.append(not_run("cleaned paper (paper.md)"))
        parts.append("<h3>Detected techniques</h3>")
        if err_ev:
            parts.append(f'<p class="fail">{e(err_ev)}</p>')
        detections = evidence.get("detections", evidence) if isinstance(evidence, dict) else evidence
        if isinstance(detections, list):
            rows = []
            for d in detections:
                if not isinstance(d, dict):
                    continue
                quotes = [ev for ev in d.get("evidence") or [] if isinstance(ev, dict)]
                best = max(quotes, key=lambda ev: ev.get("weight") or 0, default={})
                where = ", ".join(x for x in (f"p.{best['page']}" if best.get("page") is not None else "",
                                              f"Sec. {best['section']}" if best.get("section") else "") if x)
                rows.append({"technique": d.get("title") or d.get("card"), "production": d.get("production"),
                             "status": d.get("status"), "confidence": d.get("confidence"),
                             "quote": best.get("quote"), "where": where or None})
            parts.append(table(rows, ["technique", "production", "status", "confidence", "quote", "where"]))
            data["evidence"] = rows
        else:
            parts.append(not_run("technique detection (evidence.json)"))
        self.add("paper", "Paper and plan", "".join(parts), data)

    # ---------------------------------------------------------------- citations
    def citations(self) -> None:
        graph, err = _read_json(self.run / "citations.json")
        png = self.run / "citations.png"
        parts, data = [], {"status": NOT_RUN}
        if err:
            parts.append(f'<p class="fail">{e(err)}</p>')
        if png.is_file():
            parts.append(figure(png, "citation graph (target paper -> cited dependencies)", self.images))
            data["image"] = png.name
        if isinstance(graph, dict):
            g = graph.get("graph", graph)
            nodes = g.get("nodes") or []
            links = g.get("links") or g.get("edges") or []
            data.update(status="ok", nodes=len(nodes), edges=len(links))
            parts.append(f"<p>{len(nodes)} papers, {len(links)} dependencies.</p>")
            rows = [{"from": lk.get("source"), "to": lk.get("target"), "relation": lk.get("relation"),
                     "components": lk.get("components")} for lk in links if isinstance(lk, dict)]
            parts.append(table(rows, ["from", "to", "relation", "components"]))
            resolution = graph.get("resolution")
            if isinstance(resolution, dict):
                parts.append(f"<details><summary>resolution</summary><pre>{e(json.dumps(resolution, indent=2, default=str))}"
                             "</pre></details>")
        elif not png.is_file():
            parts.append(not_run("citation graph (citations.json, citations.png)"))
        self.add("citations", "Citation graph", "".join(parts), data)

    # ---------------------------------------------------------------- components and holes
    def components(self) -> None:
        meta, _ = _read_json(self.run / "nerfify.json")
        plugin = self.run if isinstance(meta, dict) else self.run / "plugin"
        plan, _ = _read_yaml(self.run / "plan.yaml")
        parts: List[str] = []
        data: dict = {"status": "ok" if plugin.is_dir() else NOT_RUN}
        if plugin.is_dir():
            files = sorted(meta["files"]) if isinstance(meta, dict) else sorted(
                str(p.relative_to(plugin)) for p in plugin.rglob("*")
                if p.is_file() and "__pycache__" not in p.parts and ".verify" not in p.parts)
            data["files"] = files
            parts.append(f"<h3>Generated package</h3><p>{len(files)} files</p>"
                         f"<pre>{e(chr(10).join(files))}</pre>")
            readme = plugin / "README.md"
            rows = parse_markdown_tables(readme.read_text(errors="replace")) if readme.is_file() else []
            data["parts"] = rows
            parts.append("<h3>Where each part comes from (README)</h3>")
            parts.append(table(rows) if rows else not_run("README parts table"))
        else:
            parts.append(not_run("generated package (plugin/)"))
            data["files"] = NOT_RUN
        holes = (plan or {}).get("holes") if isinstance(plan, dict) else None
        parts.append("<h3>Not implemented (holes)</h3>")
        if isinstance(plan, dict):
            rows = [h if isinstance(h, dict) else {"text": h} for h in holes or []]
            parts.append(table(rows) if rows else "<p>No holes: every production the plan needs is filled.</p>")
            data["holes"] = rows
        else:
            parts.append(not_run("plan (plan.yaml)"))
            data["holes"] = NOT_RUN
        self.add("components", "Components implemented and holes", "".join(parts), data)

    # ---------------------------------------------------------------- verification
    def verification(self) -> None:
        report, err = _read_json(self.run / "verify.json")
        parts: List[str] = []
        if err:
            parts.append(f'<p class="fail">{e(err)}</p>')
        if not isinstance(report, dict):
            parts.append(not_run("verification ladder (verify.json)"))
            self.add("verification", "Verification ladder", "".join(parts), {"status": NOT_RUN})
            self.add("stability", "Stability cases", not_run("stability cases (verify.json)"), {"status": NOT_RUN})
            return
        rungs = [r for r in report.get("rungs") or [] if isinstance(r, dict)]
        rows = [{"rung": r.get("name"), "status": r.get("status"), "checks": r.get("checks"),
                 "seconds": r.get("seconds"), "failures": len(r.get("failures") or []),
                 "notes": "; ".join(map(str, r.get("notes") or []))} for r in rungs]
        ok = report.get("ok")
        parts.append(f"<p>Overall: {_cell('pass' if ok else 'fail') if ok is not None else '-'}</p>")
        parts.append(table(rows, ["rung", "status", "checks", "seconds", "failures", "notes"]))
        failures = [f for f in report.get("failures") or [] if isinstance(f, dict)]
        parts.append("<h3>Broken rules</h3>")
        parts.append(table([{"rung": f.get("rung"), "rule": f.get("rule"), "where": f.get("file") or f.get("component"),
                             "message": f.get("message")} for f in failures], ["rung", "rule", "where", "message"]))
        if report.get("patches"):
            parts.append("<h3>Repairs</h3>" + table([p if isinstance(p, dict) else {"patch": p}
                                                     for p in report["patches"]]))
        self.add("verification", "Verification ladder", "".join(parts),
                 {"status": "pass" if ok else "fail", "rungs": rows, "failures": failures})
        cases = []
        for r in rungs:
            for case in (r.get("details") or {}).get("cases") or []:
                if isinstance(case, dict) and (r.get("name") == "stability" or case.get("case")):
                    cases.append({"rung": r.get("name"), **case})
        stability = [c for c in cases if c["rung"] == "stability"] or cases
        body = table(stability, ["component", "case", "status", "problems", "implementation"]) if stability \
            else not_run("stability cases")
        self.add("stability", "Stability cases", body, {"status": "ok" if stability else NOT_RUN, "cases": stability})

    # ---------------------------------------------------------------- metrics and curve
    def metrics(self) -> None:
        summary, err = _read_json(self.eval / "summary.json")
        if not isinstance(summary, dict):
            self.add("metrics", "Metrics", (f'<p class="fail">{e(err)}</p>' if err else "")
                     + not_run("evaluation (eval/summary.json)"), {"status": NOT_RUN})
            return
        keys = ["label", "status", "reason", "psnr", "ssim", "lpips", "seconds", "iterations_done", "eval_seconds",
                "worst_regions"]
        row = {k: summary.get(k) for k in keys if k in summary}
        if summary.get("lpips") is None:
            row["lpips"] = "unavailable (no AlexNet weights)"
        consistency = summary.get("consistency") or {}
        row["consistency score"] = consistency.get("mean_score")
        body = kv_table(row)
        if summary.get("diagnostics"):
            body += "<h3>Where the error is</h3>" + kv_table(summary["diagnostics"])
        self.add("metrics", "Metrics", body, {"status": summary.get("status", "ok"), **row,
                                                 "diagnostics": summary.get("diagnostics")})

    def curve(self) -> None:
        csv_path, png = self.eval / "curve.csv", self.eval / "curve.png"
        parts, data = [], {"status": NOT_RUN}
        if png.is_file():
            parts.append(figure(png, "held-out PSNR against training seconds (evaluation time excluded)",
                                self.images))
            data["image"] = png.name
        if csv_path.is_file():
            with open(csv_path, newline="") as f:
                rows = list(csv.DictReader(f))
            parts.append(table(rows))
            data.update(status="ok", points=rows)
        if not parts:
            parts.append(not_run("error against time (eval/curve.csv, eval/curve.png)"))
        self.add("curve", "Error against training time", "".join(parts), data)

    # ---------------------------------------------------------------- error maps, consistency
    def error_maps(self) -> None:
        views, err = _read_json(self.eval / "error_maps.json")
        if not isinstance(views, list):
            self.add("error_maps", "Error maps and worst regions", (f'<p class="fail">{e(err)}</p>' if err else "")
                     + not_run("error maps (eval/error_maps.json)"), {"status": NOT_RUN})
            return
        parts = ['<p class="muted">Each panel: ground truth | render | squared error (boxes: worst regions, '
                 'rank 1 in cyan).</p>']
        rows = []
        for v in views:
            if not isinstance(v, dict):
                continue
            panel = v.get("panel")
            if panel:
                caption = f"{v.get('view')}: PSNR {_fmt(v.get('psnr'))} dB, SSIM {_fmt(v.get('ssim'))}"
                parts.append(figure(self.eval / Path(panel).name, caption, self.images))
            for rank, r in enumerate(v.get("regions") or [], start=1):
                rows.append({"view": v.get("view"), "rank": rank,
                             "box (x0, y0, x1, y1)": [r.get("x0"), r.get("y0"), r.get("x1"), r.get("y1")],
                             "area": r.get("area"), "local PSNR": r.get("local_psnr")})
        parts.append("<h3>Worst regions</h3>" + table(rows))
        self.add("error_maps", "Error maps and worst regions", "".join(parts),
                 {"status": "ok", "views": len(views), "regions": rows})

    def consistency(self) -> None:
        report, err = _read_json(self.eval / "consistency.json")
        if not isinstance(report, dict):
            self.add("consistency", "Cross-view consistency", (f'<p class="fail">{e(err)}</p>' if err else "")
                     + not_run("consistency (eval/consistency.json)"), {"status": NOT_RUN})
            return
        parts = [f"<p>Mean consistency score {_fmt(report.get('mean_score'))} (fraction of checked surface pixels "
                 "that no other view sees through); white pixels in the masks are inconsistent (floaters).</p>"]
        views = [v for v in report.get("views") or [] if isinstance(v, dict)]
        for i, v in enumerate(views):
            name = v.get("view") or f"view_{i:03d}"
            parts.append(figure(self.eval / f"{name}_inconsistent.png", f"{name}: score {_fmt(v.get('score'))}",
                                self.images))
        parts.append(table(views))
        self.add("consistency", "Cross-view consistency", "".join(parts),
                 {"status": "ok", "mean_score": report.get("mean_score"), "views": views})

    # ---------------------------------------------------------------- patch loop
    def patches(self) -> None:
        history, err = _read_json(self.run / "patches" / "history.json")
        if not isinstance(history, dict):
            self.add("patches", "Patch loop", (f'<p class="fail">{e(err)}</p>' if err else "")
                     + not_run("patch loop (patches/history.json)"), {"status": NOT_RUN})
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
        body = (f"<p>{e(str(history.get('noise_definition') or ''))}</p>"
                f"<p>Stopped: {e(str(history.get('stopped')))}; best PSNR {_fmt(history.get('best_psnr'))} dB.</p>"
                "<h3>Rounds</h3>" + table(rounds) + "<h3>Decisions</h3>" + table(rows))
        self.add("patches", "Patch-loop history", body,
                 {"status": "ok", "stopped": history.get("stopped"), "best_psnr": history.get("best_psnr"),
                  "rounds": rounds, "entries": rows})

    # ---------------------------------------------------------------- page
    def html(self, title: str) -> str:
        nav = "".join(f'<a href="#{k}">{e(t)}</a>' for k, t, _ in self.sections)
        body = "".join(f'<section id="{k}"><h2>{e(t)}</h2>{b}</section>' for k, t, b in self.sections)
        stamp = _dt.datetime.now().isoformat(timespec="seconds")
        return ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
                f"<title>{e(title)}</title><style>{CSS}</style></head><body><main>"
                f"<h1>{e(title)}</h1><p class=\"muted\">run folder {e(str(self.run))}; report written {e(stamp)}</p>"
                f"<nav>{nav}</nav>{body}</main></body></html>")


def parse_markdown_tables(text: str) -> List[dict]:
    """Rows of the first pipe table in a markdown text (backticks stripped from cells)."""
    rows: List[dict] = []
    header: Optional[List[str]] = None
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
            rows.append(dict(zip(header, cells)))
    return rows


SECTIONS: Sequence[Callable[[_Builder], None]] = (
    _Builder.paper_and_plan, _Builder.citations, _Builder.components, _Builder.verification, _Builder.metrics,
    _Builder.curve, _Builder.error_maps, _Builder.consistency, _Builder.patches,
)


def write_report(run_dir: Path) -> Tuple[Path, Path]:
    """Write ``report.html`` and ``report.json`` into ``run_dir``; returns their paths."""
    run_dir = Path(run_dir).absolute()
    if not run_dir.is_dir():
        raise ReportError(f"{run_dir} is not a folder; pass the output folder of 'ns-nerfify PAPER'")
    builder = _Builder(run_dir)
    for section in SECTIONS:
        section(builder)
    plan, _ = _read_yaml(run_dir / "plan.yaml")
    title = f"nerfify report: {plan.get('method')}" if isinstance(plan, dict) and plan.get("method") \
        else f"nerfify report: {run_dir.name}"
    html_path, json_path = run_dir / "report.html", run_dir / "report.json"
    tmp = html_path.with_suffix(".html.tmp")
    tmp.write_text(builder.html(title), encoding="utf-8")
    tmp.replace(html_path)
    payload = {
        "title": title,
        "run_dir": str(run_dir),
        "sections": builder.data,
        "not_run": [k for k, v in builder.data.items() if isinstance(v, dict) and v.get("status") == NOT_RUN],
        "images": builder.images,
    }
    tmp = json_path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(payload, indent=2, default=str, ensure_ascii=False) + "\n")
    tmp.replace(json_path)
    return html_path, json_path
