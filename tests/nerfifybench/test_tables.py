"""The tables from the tasks' results: the paper's layouts, equal wall-clock, converges, row failures."""

from __future__ import annotations

import json

from nerfify_ns.nerfifybench.tables import at_time, write_outputs
from nerfify_ns.nerfifybench.tasks import Task


def curve(seconds, psnr):
    return {"step": [10 * (k + 1) for k in range(len(seconds))], "seconds": seconds, "psnr": psnr,
            "ssim": [p / 40 for p in psnr], "loss": [None] * len(seconds)}


def generated(psnr, seconds, psnr_curve, score, trains=True):
    return {"status": "ok" if trains else "failed", "reason": "" if trains else "train: non-finite loss",
            "metrics": {"psnr": psnr, "ssim": 0.5, "lpips": None},
            "curve": curve(seconds, psnr_curve), "base": "nerfacto", "generation_seconds": 3.0, "verify_seconds": 9.0,
            "executability": {"imports": True, "trains": trains, "stable": trains, "loss_falls": True},
            "usage": {}, "novelty": {"coverage": {"C": 0.5, "I": 0.5, "M": 0.0, "W": 1.0, "score": score,
                                                  "unchecked": 1, "items": 2},
                                     "items": [{"id": "a", "how": "check-passed"}, {"id": "b", "how": "no-check"}]}}


def test_tables_in_the_papers_layouts(tmp_path):
    tasks = [Task("p1", "default", c, 0) for c in ("reference", "full", "no-citations")] + \
            [Task("p2", "default", c, 0) for c in ("reference", "full", "no-citations")]
    results = [
        {"status": "ok", "metrics": {"psnr": 20.0, "ssim": 0.6, "lpips": 0.3},
         "curve": curve([5.0, 10.0], [15.0, 20.0]), "executability": {"trains": True}, "reference": "nerfacto"},
        generated(19.8, [4.0, 8.0], [16.0, 19.8], 0.75),
        generated(12.0, [4.0, 8.0], [10.0, 12.0], 0.25, trains=False),
        {"status": "failed", "reason": "reference kplanes: ns-train kplanes: exit code 2: invalid choice",
         "metrics": {}, "curve": {}, "executability": {"trains": False}},
        generated(25.0, [4.0, 8.0], [20.0, 25.0], 1.0),
        {**generated(24.0, [4.0, 8.0], [20.0, 24.0], 0.5),
         "novelty": {"coverage": {"C": 0.0, "I": 1.0, "M": 0.0, "W": None, "score": 0.5, "items": 1},
                     "items": [{"id": "x", "how": "check-errored", "message": "ZeroDivisionError: division by zero"}]}},
    ]
    for t, r in zip(tasks, results, strict=False):
        r["key"] = t.key
    meta = {"suite": "s", "date": "2026-11-24", "executor": "local", "machine": "x86_64",
            "command": "ns-nerfify bench s", "ablations": ["no-citations"],
            "papers": {p: {"reported": {"psnr": 21.0}, "reference": "nerfacto" if p == "p1" else "kplanes",
                           "reference_note": "", "budget": {"iterations": 20}} for p in ("p1", "p2")}}
    payload = write_outputs(tmp_path, meta, results, tasks)
    s1 = payload["summaries"]["p1"]
    # equal wall-clock: the shorter run ends at 8 s; the reference's last checkpoint within 8 s is at 5 s
    assert s1["equal_time"]["seconds"] == 8.0 and s1["equal_time"]["reference_psnr"] == 15.0
    assert s1["equal_time"]["generated_psnr"] == 19.8
    assert s1["executability"]["converges"] == [True]  # 19.8 is within 0.5 dB of 20.0
    assert payload["ablation_summary"]["no-citations"]["trainable"] == 0.5
    md = (tmp_path / "tables.md").read_text()
    assert "| p1 | 21.00 | – | – | nerfacto | 20.00 | 0.600 | 0.300 | 19.80 | 0.500 | – | 20 |" in md
    assert "w/o citation recovery" in md and "| NeRFify (full) | 0.88 | 100 | 0.50 |" in md
    assert "p2/default/reference/seed0: reference kplanes: ns-train kplanes: exit code 2" in md
    assert "novelty check x raised: ZeroDivisionError" in md and "p2/default/no-citations/seed0" in md
    assert "counted I for want of a check (never C): b" in md
    tex = (tmp_path / "tables.tex").read_text()
    assert r"\multicolumn{3}{c}{\textbf{Reported}}" in tex
    assert r"Converges & \checkmark & \checkmark" in tex  # p2: no reference PSNR to compare with, the loss fell
    assert (tmp_path / "plots" / "p1-default-seed0.png").is_file()
    assert json.loads((tmp_path / "results.json").read_text())["failures"]


def test_value_at_a_time():
    c = curve([2.0, 4.0, 6.0], [10.0, 12.0, 14.0])
    assert at_time(c, 1.0) == (None, None) and at_time(c, 4.0) == (12.0, 0.3) and at_time(c, 100) == (14.0, 0.35)
