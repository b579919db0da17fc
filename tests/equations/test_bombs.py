"""Paper bombs: equations built to hang or exhaust our own process are refused before the work, quickly, with a
recorded reason, and in bounded memory: three nested \\sum_{k=1}^{4096} (the interpreter-vs-module check, the
lowering, the interpreter), a 10,000-term sum and 600 KB of nested braces (the reader, the paper's normaliser,
the equation renderer), and all three as a part of a paper through the compiler and its records.

The standalone bombs run in a child process under RLIMIT_AS; the child reports its time and how much its
resident memory grew (VmHWM after warming up: imports and one ordinary equation)."""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

NESTED = r"y = \sum_{k=1}^{4096} \sum_{l=1}^{4096} \sum_{m=1}^{4096} x"
SUM_TERMS = 10_000
BRACES = 300_000  # 600 KB
CHILD_ADDRESS_SPACE = 5 << 30  # torch alone reserves about 3.3 GB of address space
MAX_GROWTH_MB = 300
SECONDS = 15.0  # each bomb; the refusals take well under a second on an idle machine


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (CHILD_ADDRESS_SPACE, CHILD_ADDRESS_SPACE))


_PRELUDE = textwrap.dedent("""
    import json, sys, time

    def hwm_mb():
        with open("/proc/self/status") as f:
            return int(next(l for l in f if l.startswith("VmHWM")).split()[1]) // 1024

    def bomb(name, fn):
        before, start = hwm_mb(), time.perf_counter()
        result = fn()
        print(json.dumps({"name": name, "result": result, "seconds": time.perf_counter() - start,
                          "grown_mb": hwm_mb() - before}), flush=True)
""")


def run_bombs(code: str, timeout: float) -> dict:
    proc = subprocess.run([sys.executable, "-c", _PRELUDE + textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=timeout, preexec_fn=_limit, cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    out = {}
    for line in proc.stdout.splitlines():
        if line.startswith("{"):
            row = json.loads(line)
            out[row["name"]] = row
    return out


def _bounded(row: dict) -> None:
    assert row["seconds"] < SECONDS, row
    assert row["grown_mb"] < MAX_GROWTH_MB, row


def test_nested_ranges_are_refused_before_the_check_the_lowering_and_the_interpreter_run():
    rows = run_bombs(f"""
        import numpy as np
        from nerfify_ns.equations import CompileError, Equation, check_lowering, interpret, lower, parse_equation
        eq = parse_equation({NESTED!r})
        assert isinstance(eq, Equation)
        ok = parse_equation(r"y = \\sum_{{k=1}}^{{4}} x")
        check_lowering([ok], {{"x": ("R",)}}, {{}}, ["y"])  # warm up: torch, the lowering
        bomb("check", lambda: str(check_lowering([eq], {{"x": ("R",)}}, {{}}, ["y"])))

        def refused(fn):
            try:
                fn()
            except CompileError as err:
                return str(err)
            return "not refused"
        bomb("lower", lambda: refused(lambda: lower([eq], {{"x": ("R",)}}, ["y"])))
        bomb("interpret", lambda: refused(lambda: interpret([eq], {{"x": np.ones(3)}}, None, {{}}, ["y"])))
    """, timeout=180)
    assert set(rows) == {"check", "lower", "interpret"}
    for row in rows.values():
        _bounded(row)
        assert "iterations of finite ranges" in row["result"] and "at most 4,096" in row["result"], row
    assert rows["check"]["result"].startswith("failed: lowering:")


@pytest.mark.parametrize("name", ["sum", "braces"])
def test_huge_equations_are_refused_by_the_reader_the_normaliser_and_the_renderer(name, tmp_path):
    latex = ("y = " + " + ".join(f"x_{{{i}}}" for i in range(1, SUM_TERMS + 1)) if name == "sum"
             else "y = " + "{" * BRACES + "x" + "}" * BRACES)
    source = tmp_path / "bomb.tex"
    source.write_text(latex)
    png = tmp_path / "bomb.png"
    rows = run_bombs(f"""
        from pathlib import Path
        from nerfify_ns.equations import parse_equations, parse_expression
        from nerfify_ns.equations.eqcheck import render_latex_png
        from nerfify_ns.equations.confidence import latex_issues
        from nerfify_ns.equations.normalize import normalize_latex
        latex = Path({str(source)!r}).read_text()
        render_latex_png(r"y = \\frac{{a}}{{b}}", {str(tmp_path / 'warm.png')!r})  # warm up: matplotlib, mathtext
        parse_equations("y = x")
        bomb("parse", lambda: [str(r) for r in parse_equations(latex)] + [str(parse_expression(latex))])
        bomb("render", lambda: list(render_latex_png(latex, {str(png)!r})[:2]))
        bomb("normalise", lambda: [len(normalize_latex(latex))] + latex_issues(latex))
    """, timeout=180)
    for row in rows.values():
        _bounded(row)
    assert all("longer than 4000 characters" in r for r in rows["parse"]["result"])
    ok, error = rows["render"]["result"]
    assert ok is False and error.startswith("not drawn: longer than 4000 characters") and png.is_file()
    assert any("too long" in issue for issue in rows["normalise"]["result"][1:])


def test_the_renderer_skips_what_the_reader_refuses_for_its_size(tmp_path):
    from nerfify_ns.equations.eqcheck import MAX_DRAW_CHARS, render_latex_png
    from nerfify_ns.equations.normalize import MAX_BIG_OPERATORS, MAX_DEPTH

    cases = {
        "deep": "y = " + "(" * (MAX_DEPTH + 1) + "x" + ")" * (MAX_DEPTH + 1),
        "big operators": "y = " + r"\sum_i " * (MAX_BIG_OPERATORS + 1) + "x_i",
        "long for mathtext": "y = " + "+".join(["x"] * (MAX_DRAW_CHARS // 2 + 10)),
    }
    for name, latex in cases.items():
        start = time.perf_counter()
        ok, error, _, _ = render_latex_png(latex, tmp_path / "eq.png")
        assert not ok and error.startswith("not drawn:"), (name, error)
        assert time.perf_counter() - start < 10, name
    ok, error, _, _ = render_latex_png(r"C = \sum_i T_i \alpha_i c_i", tmp_path / "fine.png")
    assert ok and not error
    # text shown as text is escaped: a $ never starts mathtext in the fallback
    ok, error, _, _ = render_latex_png(r"y = \unknowncommand{$x$} + $z$", tmp_path / "dollars.png")
    assert (tmp_path / "dollars.png").is_file()


def test_a_paper_of_bombs_compiles_to_recorded_reasons(tmp_path):
    """The three bombs as equations of one part of a paper: the compiler records each one's reason, its records
    (with the equations drawn) are written, all within seconds."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "synthesis"))
    from novel_papers import GATENERF

    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.novel import NOT_IMPLEMENTED, implement_holes
    from nerfify_ns.synthesis.novel.records import write_records
    from nerfify_ns.synthesis.resources import load_reference_plan

    original = r"\mathbf{h}_{o} = [\mathbf{m} \odot \mathbf{h}_a, \mathbf{h}_b] \tag{3}"
    nested = r"\mathbf{h}_{o} = \sum_{k=1}^{4096} \sum_{l=1}^{4096} \sum_{n=1}^{4096} " \
             r"[\mathbf{m} \odot \mathbf{h}_a, " \
             r"\mathbf{h}_b] \tag{3}"
    assert original in GATENERF
    terms = " + ".join(f"x_{{{i}}}" for i in range(1, SUM_TERMS + 1))
    text = GATENERF.replace(original, nested).replace(
        "which feeds the density", f"$$\ny = {terms} \\tag{{4}}\n$$\n\n$$\ny = {'{' * BRACES}x{'}' * BRACES} "
                                   f"\\tag{{5}}\n$$\n\nwhich feeds the density")
    paper = tmp_path / "bombs.md"
    paper.write_text(text)
    start = time.perf_counter()
    doc = ingest(paper)
    plan = load_reference_plan("vanilla-nerf")
    plan["holes"] = [{"production": "Backbone", "slot": "model.field.MLPField.backbone",
                      "section": "3.1 Gated embeddings", "equations": [{"number": n} for n in "12345"]}]
    result = implement_holes(doc, plan)
    (record,) = result.records
    assert record.status == NOT_IMPLEMENTED
    assert "(4) longer than 4000 characters" in record.reason and "(5) longer than 4000 characters" in record.reason
    assert "iterations of finite ranges" in record.reason
    write_records(tmp_path / "run", result, doc, images=True)
    drawn = {e["number"]: e for e in record.equations}
    assert drawn["4"]["render_error"].startswith("not drawn") and drawn["5"]["render_error"].startswith("not drawn")
    assert (tmp_path / "run" / "equations" / record.id / "eq3.png").is_file()
    assert time.perf_counter() - start < 60
