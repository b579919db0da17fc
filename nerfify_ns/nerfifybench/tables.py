"""The benchmark's outputs: ``results.json``, ``tables.md``, ``tables.tex`` and ``plots/``, from the tasks' results.

Tables, in the layout of the NeRFify paper's (``reference/nerfify_paper.tex``), per paper averaged over its scenes
and seeds:

* **Quality at equal iterations** (Table 2): reported / reference / generated PSNR, SSIM, LPIPS.
* **Quality at equal wall-clock**: both sides at the last checkpoint each reached within the shorter run's training
  time (PSNR and SSIM are scored at every checkpoint; LPIPS only on the final renders, so not here).
* **Executability** (Table 3): imports resolve, trainable, training stability, converges (training and evaluation
  finished, every loss finite, the loss fell and the final PSNR is within 0.5 dB of the reference's or above it).
* **Novelty coverage** (Table 4): C, I, M, W and the weighted score per configuration (the full pipeline and each
  ablation); items counted I only for want of a check are said under the table.
* **Ablations** (Table 5, with ``--ablations``): score, trainable (%) and C per configuration over the papers.
* **Generation**: the plan's base, generation and verification seconds, model calls and cost (empty when no
  model agent took part).
* **Row failures**: every failed task and check error with its reason.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from statistics import mean

from nerfify_ns.ablations import ablation
from nerfify_ns.nerfifybench.tasks import FULL, REFERENCE, Task

DASH = "–"


def _mean(values) -> float | None:
    good = [v for v in values if isinstance(v, int | float) and math.isfinite(v)]
    return mean(good) if good else None


def _fmt(value: float | None, digits: int = 2) -> str:
    return DASH if value is None else f"{value:.{digits}f}"


def _mark(values: list[bool | None]) -> str:
    known = [v for v in values if v is not None]
    if not known:
        return DASH
    if all(known):
        return "✓"
    return "✗" if not any(known) else f"{sum(known)}/{len(known)}"


def at_time(curve: dict, seconds: float) -> tuple[float | None, float | None]:
    """PSNR and SSIM at the last checkpoint reached within ``seconds`` of training (None before the first)."""
    best = None
    for k, s in enumerate(curve.get("seconds") or []):
        if s <= seconds + 1e-9:
            best = k
    if best is None:
        return None, None
    return curve["psnr"][best], (curve.get("ssim") or [None] * (best + 1))[best]


def label(config: str) -> str:
    return "NeRFify (full)" if config == FULL else ablation(config).label


class Tables:
    def __init__(self, meta: dict, results: Sequence[dict], tasks: Sequence[Task]) -> None:
        self.meta, self.tasks = meta, tasks
        self.by_key = {r.get("key"): r for r in results}
        self.papers = list(meta["papers"])
        self.configs = [FULL, *meta.get("ablations", [])]

    def rows(self, paper: str, config: str) -> list[dict]:
        return [self.by_key[t.key] for t in self.tasks if t.paper == paper and t.config == config
                and t.key in self.by_key]

    def pairs(self, paper: str, config: str = FULL) -> list[tuple[dict, dict]]:
        """(reference, generated) results of the same scene and seed."""
        out = []
        for t in self.tasks:
            if t.paper == paper and t.config == config and t.key in self.by_key:
                ref = self.by_key.get(Task(t.paper, t.scene, REFERENCE, t.seed).key)
                if ref is not None:
                    out.append((ref, self.by_key[t.key]))
        return out

    def metric(self, rows: list[dict], name: str) -> float | None:
        return _mean([(r.get("metrics") or {}).get(name) for r in rows if r.get("status") == "ok"])

    # ------------------------------------------------------------------ summaries (results.json)
    def converges(self, ref: dict, gen: dict) -> bool | None:
        ex = gen.get("executability") or {}
        if not ex.get("trains"):
            return False if ex else None
        psnr, ref_psnr = (gen.get("metrics") or {}).get("psnr"), (ref.get("metrics") or {}).get("psnr")
        close = ref_psnr is None or (psnr is not None and psnr >= ref_psnr - 0.5)
        return bool(ex.get("stable") and ex.get("loss_falls") and close)

    def paper_summary(self, paper: str) -> dict:
        p = self.meta["papers"][paper]
        refs, gens = self.rows(paper, REFERENCE), self.rows(paper, FULL)
        equal_time = []
        for ref, gen in self.pairs(paper):
            rc, gc = ref.get("curve") or {}, gen.get("curve") or {}
            if rc.get("seconds") and gc.get("seconds"):
                horizon = min(rc["seconds"][-1], gc["seconds"][-1])
                equal_time.append((horizon, at_time(rc, horizon), at_time(gc, horizon), rc["seconds"][0],
                                   gc["seconds"][0]))
        configs = {}
        for config in self.configs:
            rows = self.rows(paper, config)
            cov = [(r.get("novelty") or {}).get("coverage") or {} for r in rows]
            configs[config] = {
                **{k: _mean([c.get(k) for c in cov]) for k in ("C", "I", "M", "W", "score")},
                "trainable": _mean([float(bool((r.get("executability") or {}).get("trains"))) for r in rows]),
                "unchecked": max([c.get("unchecked", 0) for c in cov], default=0),
                "items": max([c.get("items", 0) for c in cov], default=0),
                "psnr": self.metric(rows, "psnr"), "status": [r.get("status") for r in rows]}
        full = gens[0] if gens else {}
        return {
            "reported": p["reported"], "reference": p["reference"], "reference_note": p["reference_note"],
            "reference_metrics": {m: self.metric(refs, m) for m in ("psnr", "ssim", "lpips", "seconds")},
            "generated_metrics": {m: self.metric(gens, m) for m in ("psnr", "ssim", "lpips", "seconds")},
            "equal_time": {"seconds": _mean([e[0] for e in equal_time]),
                           "reference_psnr": _mean([e[1][0] for e in equal_time]),
                           "reference_ssim": _mean([e[1][1] for e in equal_time]),
                           "generated_psnr": _mean([e[2][0] for e in equal_time]),
                           "generated_ssim": _mean([e[2][1] for e in equal_time]),
                           "reference_first_checkpoint": _mean([e[3] for e in equal_time]),
                           "generated_first_checkpoint": _mean([e[4] for e in equal_time])},
            "executability": {
                "imports": [(r.get("executability") or {}).get("imports") for r in gens],
                "trains": [(r.get("executability") or {}).get("trains") for r in gens],
                "stable": [(r.get("executability") or {}).get("stable") for r in gens],
                "converges": [self.converges(ref, gen) for ref, gen in self.pairs(paper)]},
            "configs": configs,
            "base": full.get("base"),
            "generation_seconds": _mean([r.get("generation_seconds") for r in gens]),
            "verify_seconds": _mean([r.get("verify_seconds") for r in gens]),
            "usage": {"calls": _mean([(r.get("usage") or {}).get("calls") for r in gens]),
                      "cost_usd": _mean([(r.get("usage") or {}).get("cost_usd") for r in gens])},
            "unchecked_items": sorted({i["id"] for r in gens for i in (r.get("novelty") or {}).get("items", [])
                                       if i.get("how") == "no-check"}),
        }

    def failures(self) -> list[str]:
        out = []
        for t in self.tasks:
            r = self.by_key.get(t.key)
            if r is None:
                out.append(f"{t.key}: not run")
                continue
            if r.get("status") != "ok":
                out.append(f"{t.key}: {r.get('reason', '')}")
            for item in (r.get("novelty") or {}).get("items", []):
                if item.get("how") == "check-errored":
                    out.append(f"{t.key}: novelty check {item['id']} raised: {item.get('message', '')}")
        return out

    def ablation_summary(self, summaries: dict[str, dict]) -> dict[str, dict]:
        return {c: {k: _mean([s["configs"][c][k] for s in summaries.values()]) for k in ("score", "trainable", "C")}
                for c in self.configs}

    # ------------------------------------------------------------------ markdown
    def markdown(self, summaries: dict[str, dict]) -> str:
        m = self.meta
        out = [f"# NerfifyBench: {m['suite']}", "",
               f"{m['date']}, executor {m['executor']}, {m['machine']}." + (f" Command: `{m['command']}`."
                                                                            if m.get("command") else ""), ""]
        out += ["## Quality at equal iterations (Table 2 layout)", "",
                "| Paper | Reported PSNR | SSIM | LPIPS | Reference | PSNR | SSIM | LPIPS | NeRFify PSNR | SSIM "
                "| LPIPS | iterations |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        notes = []
        for paper, s in summaries.items():
            rep, ref, gen = s["reported"], s["reference_metrics"], s["generated_metrics"]
            it = self.meta["papers"][paper]["budget"]["iterations"]
            out.append(f"| {paper} | {_fmt(rep.get('psnr'))} | {_fmt(rep.get('ssim'))} | {_fmt(rep.get('lpips'))} "
                       f"| {s['reference']} | {_fmt(ref['psnr'])} | {_fmt(ref['ssim'], 3)} | {_fmt(ref['lpips'], 3)} "
                       f"| {_fmt(gen['psnr'])} | {_fmt(gen['ssim'], 3)} | {_fmt(gen['lpips'], 3)} | {it} |")
            if s["reference_note"]:
                notes.append(f"{paper}: reference {s['reference']}: {s['reference_note']}")
            if rep.get("dataset"):
                notes.append(f"{paper}: reported on {rep['dataset']}")
        out += [""] + [f"- {n}" for n in notes] + ([""] if notes else [])
        out += ["## Quality at equal wall-clock", "",
                "| Paper | training seconds | Reference PSNR | SSIM | NeRFify PSNR | SSIM |",
                "|---|---|---|---|---|---|"]
        for paper, s in summaries.items():
            e = s["equal_time"]
            first = {side: "" if e[f"{side}_psnr"] is not None or e[f"{side}_first_checkpoint"] is None else
                     f" (first checkpoint at {e[f'{side}_first_checkpoint']:.1f} s)"
                     for side in ("reference", "generated")}
            out.append(f"| {paper} | {_fmt(e['seconds'], 1)} | {_fmt(e['reference_psnr'])}{first['reference']} | "
                       f"{_fmt(e['reference_ssim'], 3)} | {_fmt(e['generated_psnr'])}{first['generated']} | "
                       f"{_fmt(e['generated_ssim'], 3)} |")
        out += ["", "Both sides at the last checkpoint each reached within the shorter run's training time (training "
                    "seconds, evaluation excluded); a side with no checkpoint by then shows when its first came. "
                    "Curves: `plots/`.", ""]
        out += ["## Executability (Table 3 layout; NeRFify, full pipeline)", "",
                "| Metric | " + " | ".join(summaries) + " |", "|---|" + "---|" * len(summaries)]
        for name, key in (("Imports resolve", "imports"), ("Trainable", "trains"), ("Training stability", "stable"),
                          ("Converges (loss falls, within 0.5 dB of the reference)", "converges")):
            out.append(f"| {name} | " + " | ".join(_mark(s["executability"][key]) for s in summaries.values()) + " |")
        out += ["", "## Novelty coverage (Table 4 layout)", "",
                "| Paper | " + " | ".join(f"{label(c)}: C | I | M | W | Score" for c in self.configs) + " |",
                "|---|" + "---|---|---|---|---|" * len(self.configs)]
        for paper, s in summaries.items():
            cells = []
            for c in self.configs:
                v = s["configs"][c]
                cells.append(" | ".join(_fmt(v[k]) for k in ("C", "I", "M", "W", "score")))
            out.append(f"| {paper} | " + " | ".join(cells) + " |")
        out += ["", "C correct (its check passed), I incomplete (present but its check failed or raised, or present "
                    "with evidence and no check), M missing; W: share of the items with the paper's values within 10%; "
                    "Score: weighted, C = 1, I = 0.5, M = 0. Computed from the checks and the plan's evidence, no "
                    "model judges."]
        for paper, s in summaries.items():
            if s["unchecked_items"]:
                out.append(f"- {paper}: counted I for want of a check (never C): {', '.join(s['unchecked_items'])}")
        if len(self.configs) > 1:
            out += ["", "## Ablations (Table 5 layout; mean over the papers)", "",
                    "| Configuration | Score | Trainable (%) | Correct novelties (C) |", "|---|---|---|---|"]
            for c, v in self.ablation_summary(summaries).items():
                trainable = DASH if v["trainable"] is None else f"{100 * v['trainable']:.0f}"
                out.append(f"| {label(c)} | {_fmt(v['score'])} | {trainable} | {_fmt(v['C'])} |")
        out += ["", "## Generation", "", "| Paper | base | generation s | verification s | model calls | cost (USD) |",
                "|---|---|---|---|---|---|"]
        for paper, s in summaries.items():
            u = s["usage"]
            out.append(f"| {paper} | {s['base'] or DASH} | {_fmt(s['generation_seconds'], 1)} | "
                       f"{_fmt(s['verify_seconds'], 1)} | {_fmt(u['calls'], 0)} | {_fmt(u['cost_usd'], 4)} |")
        out += ["", "Model calls and cost as the runs recorded them; empty when no model agent took part.", ""]
        fails = self.failures()
        out += ["## Row failures", ""] + ([f"- {f}" for f in fails] if fails else ["none"]) + [""]
        return "\n".join(out)

    # ------------------------------------------------------------------ LaTeX
    def latex(self, summaries: dict[str, dict]) -> str:
        def tex(text: str) -> str:
            return str(text).replace("_", r"\_").replace("&", r"\&").replace("%", r"\%").replace("–", "-")

        def f(v, d=2):
            return "-" if v is None else f"{v:.{d}f}"

        out = [r"% NerfifyBench tables (" + tex(self.meta["suite"]) + ", " + self.meta["date"] + ")",
               r"\begin{tabular}{lccccccccc}", r"\hline",
               r"\textbf{Paper} & \multicolumn{3}{c}{\textbf{Reported}} & \multicolumn{3}{c}{\textbf{Reference}} & "
               r"\multicolumn{3}{c}{\textbf{NeRFify (Ours)}} \\", r"\hline",
               r" & PSNR$\uparrow$ & SSIM$\uparrow$ & LPIPS$\downarrow$ & PSNR$\uparrow$ & SSIM$\uparrow$ & "
               r"LPIPS$\downarrow$ & PSNR$\uparrow$ & SSIM$\uparrow$ & LPIPS$\downarrow$ \\", r"\hline"]
        for paper, s in summaries.items():
            rep, ref, gen = s["reported"], s["reference_metrics"], s["generated_metrics"]
            out.append(f"{tex(paper)} & {f(rep.get('psnr'))} & {f(rep.get('ssim'))} & {f(rep.get('lpips'))} & "
                       f"{f(ref['psnr'])} & {f(ref['ssim'])} & {f(ref['lpips'])} & {f(gen['psnr'])} & "
                       f"{f(gen['ssim'])} & {f(gen['lpips'])} \\\\")
        out += [r"\hline", r"\end{tabular}", "",
                r"\begin{tabular}{l" + "c" * len(summaries) + "}", r"\toprule",
                r"\textbf{Metric} & " + " & ".join(rf"\textbf{{{tex(p)}}}" for p in summaries) + r" \\", r"\midrule"]
        sym = {"✓": r"\checkmark", "✗": r"\texttimes", DASH: "-"}
        for name, key in (("Imports Resolve", "imports"), ("Compiles/Trainable", "trains"),
                          ("Training Stability", "stable"), ("Converges", "converges")):
            marks = [_mark(s["executability"][key]) for s in summaries.values()]
            cells = [sym.get(m, m) for m in marks]
            out.append(f"{name} & " + " & ".join(cells) + r" \\")
        out += [r"\bottomrule", r"\end{tabular}", "",
                r"\begin{tabular}{l|" + "|".join(["ccccc"] * len(self.configs)) + "}", r"\hline",
                "Paper & " + " & ".join(rf"\multicolumn{{5}}{{c}}{{{tex(label(c))}}}" for c in self.configs) + r" \\",
                r"\hline", " & " + " & ".join([r"C$\uparrow$ & I$\downarrow$ & M$\downarrow$ & W$\uparrow$ & "
                                                 r"Score$\uparrow$"] * len(self.configs)) + r" \\", r"\hline"]
        for paper, s in summaries.items():
            cells = [" & ".join(f(s["configs"][c][k]) for k in ("C", "I", "M", "W", "score")) for c in self.configs]
            out.append(f"{tex(paper)} & " + " & ".join(cells) + r" \\")
        out += [r"\hline", r"\end{tabular}"]
        if len(self.configs) > 1:
            out += ["", r"\begin{tabular}{lccc}", r"\toprule",
                    r"\textbf{Configuration} & \textbf{Score} & \textbf{Trainable (\%)} & \textbf{Correct (C)} \\",
                    r"\midrule"]
            for c, v in self.ablation_summary(summaries).items():
                trainable = "-" if v["trainable"] is None else f"{100 * v['trainable']:.0f}"
                out.append(f"{tex(label(c))} & {f(v['score'])} & {trainable} & {f(v['C'])} \\\\")
            out += [r"\bottomrule", r"\end{tabular}"]
        return "\n".join(out) + "\n"

    # ------------------------------------------------------------------ plots
    def plots(self, folder: Path) -> list[str]:
        from nerfify_ns.evaluate.curve import CurvePoint, plot_curves

        written = []
        groups: dict[tuple, list[Task]] = {}
        for t in self.tasks:
            groups.setdefault((t.paper, Path(t.scene).name, t.seed), []).append(t)
        for (paper, scene, seed), tasks in groups.items():
            sources, labels = [], []
            for t in tasks:
                r = self.by_key.get(t.key) or {}
                c = r.get("curve") or {}
                if not c.get("seconds"):
                    continue
                name = f"{r.get('reference', 'reference')} (reference)" if t.config == REFERENCE else label(t.config)
                sources.append([CurvePoint(name, s, sec, p, None) for s, sec, p in
                                zip(c["step"], c["seconds"], c["psnr"], strict=False) if p is not None])
                labels.append(name)
            if sources:
                png = folder / f"{paper}-{scene}-seed{seed}.png"
                plot_curves(sources, png, labels=labels, title=f"{paper} on {scene} (seed {seed}): held-out PSNR "
                                                              "against training time")
                written.append(str(png.relative_to(folder.parent)))
        return written


def write_outputs(out: Path, meta: dict, results: Sequence[dict], tasks: Sequence[Task]) -> dict:
    """results.json, tables.md, tables.tex and plots/ in ``out``; returns the results.json payload."""
    from nerfify_ns.evaluate.run_eval import write_json

    tables = Tables(meta, results, tasks)
    summaries = {p: tables.paper_summary(p) for p in tables.papers}
    plots = tables.plots(Path(out) / "plots")
    payload = {**meta, "summaries": summaries,
               "ablation_summary": tables.ablation_summary(summaries) if len(tables.configs) > 1 else None,
               "failures": tables.failures(), "plots": plots,
               "tasks": {r.get("key"): r for r in results}}
    write_json(Path(out) / "results.json", json.loads(json.dumps(payload, default=str)))
    (Path(out) / "tables.md").write_text(tables.markdown(summaries))
    (Path(out) / "tables.tex").write_text(tables.latex(summaries))
    return payload
