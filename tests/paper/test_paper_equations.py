"""Equations as LaTeX from every input, without ../shared: the normaliser, the typed Equation record for
LaTeX and markdown, PDF reconstruction on PDFs made here in TeX's math fonts (scripts by size and baseline,
a big operator's limits, a drawn fraction bar, TeX font codes, embedded ActualText), and the visual check."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pymupdf
import pytest

from nerfify_ns.benchmarks.pdf_math_bench import MathWriter, make_math_pdf
from nerfify_ns.equations.confidence import latex_issues
from nerfify_ns.equations.eqcheck import render_checks_html, render_latex_png, to_mathtext, write_equation_checks
from nerfify_ns.equations.normalize import has_lost_backslashes, normalize_latex
from nerfify_ns.paper import ingest
from nerfify_ns.paper.annotate import equation_sentence
from nerfify_ns.paper.pdf_math import actual_texts, find_equations, make_glyph, reconstruct
from nerfify_ns.paper.pdf_math.actualtext import _pdf_string

# ------------------------------------------------------------------------------------------- normaliser


@pytest.mark.parametrize("raw, want", [
    (r"\pmb{x} + \boldsymbol{\mu} + \bm{W}", r"\mathbf{x} + \mathbf{\mu} + \mathbf{W}"),
    (r"{\bf x}^{\rm obj}", r"\mathbf{x}^{\mathrm{obj}}"),
    (r"{\cal L}*{\mathrm{reg}}=\alpha", r"\mathcal{L}_{\mathrm{reg}}=\alpha"),  # markdown's _ became *
    (r"P_* + \operatorname*{argmin}_x f", r"P_* + \operatorname{argmin}_x f"),  # a real star and a starred command stay
    (r"\mathbf{}x+\mathbf{ }y", r"x+y"),
    (r"\begin{array}{r}{\pmb v=\sum_{*}P_{*}\pmb v_{*}}\end{array}", r"\mathbf{v}=\sum_{*}P_{*}\mathbf{v}_{*}"),
    (r"\begin{array}{l} a=1 \\ b=2 \end{array}", r"a=1 \\ b=2"),
    (r"\exp\mathopen{}\mathclose{{\left(-\sigma_{i}\delta_{i}}}\right)", r"\exp\left(-\sigma_{i}\delta_{i}\right)"),
    (r"L _ { \mathrm { r e c } } = \sum _ { \pmb { r } \in \mathcal { R } } "
     r"| \pmb { C } ( \pmb { r } ) | _ { 2 } ^ { 2 } ,",
     r"L_{\mathrm{rec}}=\sum_{\mathbf{r} \in \mathcal{R}}|\mathbf{C}(\mathbf{r})|_{2}^{2}"),
    (r"\displaystyle a \,=\, \dfrac{1}{2}\Big( x \Big) \label{eq:a} .", r"a = \frac{1}{2}( x )"),
    (r"{a \over b} + \lVert x \rVert", r"\frac{a}{b} + \| x \|"),
    ("σ_i δ_i", r"\sigma_i \delta_i"),
    (r"\mathbf r + \hat C", r"\mathbf{r} + \hat{C}"),
])
def test_normaliser_removes_converter_noise(raw, want):
    assert normalize_latex(raw) == want


def test_normaliser_keeps_clean_latex_and_is_idempotent():
    for clean in (r"C = \sum_i T_i \alpha_i c_i", r"T_i = \exp(-\sum_{j<i} \sigma_j \delta_j)", "a &= b", "z = 1",
                  r"M=\begin{pmatrix}a&0\\ 0&b\end{pmatrix}"):
        assert normalize_latex(clean) == clean
    for raw in (r"{\cal L}*{\mathrm{reg}}=\alpha ,\overline{P*{\mathrm{deform}}}",
                r"T(t)=\exp!\left(-\int\sigma(s),ds\right)",
                r"\mathopen{}\mathclose{{\left[x}}\right]"):
        once = normalize_latex(raw)
        assert normalize_latex(once) == once


def test_lost_backslashes_are_restored_only_with_evidence():
    lost = r"T(t)=\exp!\left(-\int_{t_n}^{t}\sigma(s),ds\right)"
    assert has_lost_backslashes(lost)
    assert normalize_latex(lost) == r"T(t)=\exp \left(-\int_{t_n}^{t}\sigma(s) ds\right)"
    lost_commas = r"C(\mathbf r)=T(t),\sigma(t),dt"
    assert normalize_latex(lost_commas, lost_backslashes=True) == r"C(\mathbf{r})=T(t) \sigma(t) dt"
    assert normalize_latex(r"f(x,y)=x,y") == r"f(x,y)=x,y"  # no evidence: commas are commas
    assert normalize_latex(r"(\sigma,\mathbf c)", lost_backslashes=True) == r"(\sigma,\mathbf{c})"  # inside brackets


def test_latex_issues_name_what_is_wrong():
    assert latex_issues(r"\frac{a}{b}") == []
    assert latex_issues(r"\frac{a}{b") == ["unbalanced braces (+1)"]
    assert any("\\left" in i for i in latex_issues(r"\left( x"))
    assert latex_issues(r"\foo x") == ["unknown commands: \\foo"]


def test_equation_sentence():
    s = equation_sentence("We render rays. The colour is computed as follows:",
                          "where T_i is the transmittance. Next.", "3")
    assert s == "The colour is computed as follows: ⟨Eq. 3⟩ where T_i is the transmittance."
    assert equation_sentence("A sentence ends.", "Another starts.", "") == "⟨equation⟩"


# ------------------------------------------------------------------------------------------- tex / markdown
MD = """# TinyNeRF

## 3 Method

We render each ray with the quadrature rule:

$$
\\hat C(\\pmb r)=\\sum_{i=1}^{N}T_i\\big(1-\\exp(-\\sigma_i\\delta_i)\\big)\\pmb c_i ,
$$
(3)

where $\\delta_i$ is the distance between samples. The loss is

$$ {\\cal L}*{\\mathrm{rec}} = \\| C - \\hat C \\|^2 $$
"""


def test_markdown_equations_are_typed_and_normalised(tmp_path):
    path = tmp_path / "paper.md"
    path.write_text(MD, encoding="utf-8")
    doc = ingest(path)
    eq, loss = doc.equations
    assert (eq.number, eq.source, eq.method) == ("3", "markdown", "source")
    assert eq.latex == r"\hat{C}(\mathbf{r})=\sum_{i=1}^{N}T_i(1-\exp(-\sigma_i\delta_i))\mathbf{c}_i"
    assert r"\pmb" in eq.latex_raw and eq.page is None and eq.bbox is None
    assert eq.confidence == pytest.approx(0.95) and eq.notes == []
    assert eq.sentence == ("We render each ray with the quadrature rule: ⟨Eq. 3⟩ where $\\delta_i$ is the distance "
                           "between samples.")
    assert loss.latex == r"\mathcal{L}_{\mathrm{rec}} = \| C - \hat{C} \|^2"
    assert loss.to_dict()["confidence"] == pytest.approx(0.95)


def test_latex_source_equations_are_trusted(tmp_path):
    tex = tmp_path / "paper.tex"
    tex.write_text("\\documentclass{article}\\begin{document}\\section{Method}\nWe use\n"
                   "\\begin{equation}\\boldsymbol{w}_i = T_i \\alpha_i \\label{eq:w}\\end{equation}\n"
                   "where $T_i$ is the transmittance.\n\\end{document}\n", encoding="utf-8")
    eq, = ingest(tex).equations
    assert (eq.number, eq.label, eq.source, eq.method, eq.confidence) == ("1", "eq:w", "tex", "source", 1.0)
    assert eq.latex == r"\mathbf{w}_i = T_i \alpha_i" and eq.latex_raw.startswith(r"\boldsymbol")


# ------------------------------------------------------------------------------------------- PDFs made here
@pytest.fixture(scope="module")
def math_pdf(tmp_path_factory) -> Path:
    """Two pages, two columns, one numbered equation per column: T_i = exp(-sum_{j=1}^{i-1} sigma_j delta_j)
    (scripts at lowered baselines, a CMEX sum with limits above and below) and w = a/(b+c) + x^2 (a drawn
    fraction bar, a raised superscript), in matplotlib's copies of TeX's math fonts."""
    return make_math_pdf(tmp_path_factory.mktemp("mathpdf") / "math.pdf", pages=2, per_page=4)


def test_scripts_limits_and_fraction_bars_are_recovered(math_pdf):
    with pymupdf.open(str(math_pdf)) as pdf:
        eqs = find_equations(pdf)
    assert [e.number for e in eqs] == ["1", "2", "3", "4", "5", "6", "7", "8"]
    assert [e.page for e in eqs] == [1, 1, 1, 1, 2, 2, 2, 2]
    for e in eqs:
        assert e.method == "layout" and e.confidence >= 0.85 and not e.notes
    assert eqs[0].latex == r"T_{i}=\exp(-\sum_{j=1}^{i-1}\sigma_{j}\delta_{j})"
    assert eqs[1].latex == r"w=\frac{a}{b+c}+x^{2}"
    assert eqs[0].sentence == ("The transmittance is computed as follows: ⟨Eq. 1⟩ where each symbol is defined in the "
                               "text above.")
    x0, y0, x1, y1 = eqs[2].bbox
    assert x0 > 306 and y1 - y0 < 40  # the right column's first equation, only its own lines


def test_ingest_gives_pdf_equations_their_record(math_pdf):
    doc = ingest(math_pdf)
    assert [e.number for e in doc.equations] == [str(i) for i in range(1, 9)]
    e = doc.equations[0]
    assert (e.source, e.method, e.page) == ("pdf", "layout", 1) and len(e.bbox) == 4
    assert e.latex == r"T_{i}=\exp(-\sum_{j=1}^{i-1}\sigma_{j}\delta_{j})" and e.to_dict()["bbox"] == e.bbox


def test_sub_and_superscripts_by_size_and_baseline(tmp_path):
    doc = pymupdf.open()
    page = doc.new_page(width=612, height=792)
    w = MathWriter(page)
    for k in range(8):
        w.put(72, 90 + 12 * k, "Prose of the paper fills the page so that its body font is the text font.", "times")
    b, x = 250.0, 200.0
    x = w.put(x, b, "W", "cmmi")
    w.put(x, b - 4.2, "f", "cmmi", 7)  # a superscript and a subscript stacked on one nucleus
    x = w.put(x, b + 2.0, "c", "cmmi", 7) + 1
    x = w.put(x, b, "h", "cmmi")
    x = w.put(x, b + 1.5, "t", "cmmi", 7)
    x = w.put(x, b + 2.5, "n", "cmmi", 5)  # a script's own script
    x = w.put(x, b, "+", "cmr")
    x = w.put(x, b, "e", "cmmi")
    x = w.put(x, b - 4.0, "-", "cmr", 7)
    x = w.put(x, b - 4.0, "x", "cmmi", 7)
    w.put(x, b - 6.5, "2", "cmr", 5)
    w.right = 540
    w.number(b, "7")
    path = tmp_path / "scripts.pdf"
    doc.save(str(path))
    with pymupdf.open(str(path)) as pdf:
        eq, = find_equations(pdf)
    assert eq.number == "7"
    assert eq.latex == r"W_{c}^{f}h_{t_{n}}+e^{-x^{2}}"


def test_tex_font_codes_map_to_latex():
    def tok(ch, font):
        return make_glyph(ch, font, 10.0, 0, (0, 0, 5, 10), (0, 8), "nimbusromno9l")

    assert tok("\x1b", "CMMI10").tex == r"\sigma"  # a raw TeX code (no Unicode in the font)
    assert tok("\x00", "CMR10").tex == r"\Gamma"
    assert tok("\x00", "CMSY10").tex == "-"
    assert (tok("X", "CMEX10").tex, tok("X", "CMEX10").kind) == (r"\sum", "op")  # display sum
    assert (tok("P", "ABCDEF+CMEX10").tex, tok("Z", "CMEX10").tex) == (r"\sum", r"\int")
    assert (tok("\x10", "CMEX10").tex, tok("\x10", "CMEX10").kind) == ("(", "open")
    assert tok("R", "CMSY7").tex == r"\mathcal{R}" and tok("R", "MSBM10").tex == r"\mathbb{R}"
    assert tok("σ", "CMMI10").tex == r"\sigma" and tok("W", "CMMIB10").tex == r"\mathbf{W}"
    assert tok("x", "LMMathItalic10-Regular").math and tok("⊙", "txsy").tex == r"\odot"
    assert tok("𝜎", "CambriaMath").tex == r"\sigma" and tok("ℝ", "STIXGeneral").tex == r"\mathbb{R}"
    assert tok("a", "Symbol").tex == r"\alpha"
    assert not tok("\x7f", "CMSY10").mapped and tok("\x7f", "CMSY10").tex == "?"
    g = tok("x", "NimbusRomNo9L-Regu")
    assert not g.math and g.kind == "text"


def test_extension_glyphs_with_unicode_hang_below_their_origin():
    """pdfTeX with glyphtounicode maps CMEX's sum to U+2211; its origin is still at its top."""
    def g(c, font, size, x, base):
        return make_glyph(c, font, size, 0, (x, base - size, x + 0.6 * size, base), (x, base), "times")

    row = 200.0
    glyphs = [g("C", "CMMI10", 10, 100, row), g("=", "CMR10", 10, 108, row), g("∑", "CMEX10", 10, 118, row - 9.2),
              g("i", "CMMI7", 7, 121, row + 10.5), g("x", "CMMI10", 10, 134, row), g("(", "CMEX10", 10, 141, row - 7.5),
              g("y", "CMMI10", 10, 147, row), g(")", "CMEX10", 10, 153, row - 7.5)]
    assert reconstruct(glyphs, [])[0] == r"C=\sum_{i}x(y)"


def test_unmapped_glyphs_lower_the_confidence_and_say_so():
    chars = [("x", "CMMI10"), ("=", "CMR10"), ("\x7f", "CMSY10"), ("y", "CMMI10")]
    glyphs = [make_glyph(c, f, 10.0, 0, (x, 0, x + 5, 10), (x, 100), "times")
              for x, (c, f) in zip(range(0, 50, 6), chars, strict=False)]
    latex, conf, notes = reconstruct(glyphs, [])
    assert latex == "x=?y" and conf < 0.7
    assert any("1 of 4 glyphs without a LaTeX mapping" in n for n in notes)


def test_pdf_strings_decode():
    assert _pdf_string(rb"(\\int\040_{t}\(x\))") == r"\int _{t}(x)"
    assert _pdf_string(b"<FEFF03C3005F0069>") == "σ_i"


def test_embedded_actualtext_latex_is_preferred(tmp_path):
    """A PDF carrying each formula's LaTeX as ActualText (the axessibility package): that LaTeX is used."""
    path = make_math_pdf(tmp_path / "a.pdf", pages=1, per_page=1, columns=1)
    doc = pymupdf.open(str(path))
    page = doc[0]
    xrefs = page.get_contents()
    data = b"".join(doc.xref_stream(x) for x in xrefs)
    # wrap the equation's own drawing (the first cmmi glyph up to the number) in a marked-content span
    latex = rb"T_i=\\exp\\left(-\\sum_{j=1}^{i-1}\\sigma_j\\delta_j\\right) \\label{eq:T}"
    ops = data.split(b"\n")
    start = next(i for i, ln in enumerate(ops) if b"/cmmi" in ln)
    end = max(i for i, ln in enumerate(ops) if b"/stixi" in ln or b"/cmex" in ln or b"/cmr" in ln)
    while ops[start] != b"q" and start > 0:
        start -= 1
    end = next(i for i in range(end, len(ops)) if ops[i] == b"Q")
    new = ops[:start] + [b"/Span<</ActualText(" + latex + b")>>BDC"] + ops[start:end + 1] + [b"EMC"] + ops[end + 1:]
    doc.update_stream(xrefs[0], b"\n".join(new))
    for x in xrefs[1:]:
        doc.update_stream(x, b"")
    out = tmp_path / "actual.pdf"
    doc.save(str(out))
    with pymupdf.open(str(out)) as pdf:
        assert actual_texts(pdf[0]) == [r"T_i=\exp\left(-\sum_{j=1}^{i-1}\sigma_j\delta_j\right) \label{eq:T}"]
        eq, = find_equations(pdf)
    assert (eq.method, eq.label, eq.number) == ("actualtext", "eq:T", "1")
    assert eq.latex == r"T_i=\exp\left(-\sum_{j=1}^{i-1}\sigma_j\delta_j\right)" and eq.confidence > 0.9
    assert eq.layout_latex == r"T_{i}=\exp(-\sum_{j=1}^{i-1}\sigma_{j}\delta_{j})"


def test_prose_pdf_has_no_equations(tmp_path):
    from paper_pdfs import text_pdf

    path = text_pdf(tmp_path / "prose.pdf", ["We train a radiance field with a learning rate of 5e-4 and 4096 rays "
                                             "per batch for 300k iterations."] * 4, "A Paper Without Math")
    with pymupdf.open(str(path)) as pdf:
        assert find_equations(pdf) == []


def test_reconstruction_time_is_small(tmp_path):
    """15 pages, 30 numbered equations: a fraction of the equation compiler's 5 s budget (CPU time)."""
    path = make_math_pdf(tmp_path / "bench.pdf", pages=15, per_page=2)
    with pymupdf.open(str(path)) as pdf:
        find_equations(pdf)  # warm the glyph caches
        t = time.process_time()
        eqs = find_equations(pdf)
        spent = time.process_time() - t
    assert len([e for e in eqs if e.number]) == 30
    assert spent < 1.0, f"find_equations took {spent:.2f} s of CPU for 15 pages"


# ------------------------------------------------------------------------------------------- the visual check
def test_visual_check_writes_rendering_and_crop(math_pdf, tmp_path):
    doc = ingest(math_pdf)
    checks = write_equation_checks(doc, tmp_path / "eqs")
    assert len(checks) == 8
    first = checks[0]
    assert first.rendered.name == "eq1_latex.png" and first.crop.name == "eq1_pdf.png"
    for c in checks:
        assert c.rendered.stat().st_size > 500 and c.crop.stat().st_size > 500 and c.render_error == ""
    with pymupdf.open(str(first.crop)) as img:  # the crop is the equation's region, padded
        assert img[0].rect.width > 100
    html = render_checks_html(checks)
    assert html.count("data:image/png;base64,") == 16 and "T_{i}=\\exp" in html
    assert "<script" not in html


def test_visual_check_says_when_mathtext_cannot_draw(tmp_path):
    ok, err, used, approx = render_latex_png(r"\frac{a}{b", tmp_path / "bad.png")
    assert not ok and err.startswith("mathtext could not parse") and (tmp_path / "bad.png").stat().st_size > 200
    ok, err, used, approx = render_latex_png(r"\mathcal{F}(x) = \weirdop{x}", tmp_path / "odd.png")
    assert ok and approx and "unknown commands as names" in err and r"\mathrm{weirdop}" in used
    rows, approx = to_mathtext(r"\begin{cases} a & x>0 \\ b & x \le 0 \end{cases} \\ y = 1")
    assert approx and len(rows) == 2 and rows[0].startswith(r"\left\{")
    assert not re.search(r"\\begin|&", " ".join(rows))


def test_html_partial_escapes_paper_text(tmp_path):
    from nerfify_ns.paper.document import Equation

    eq = Equation(latex="x<script>alert(1)</script>", number="1", notes=["<b>note</b>"], confidence=0.3)
    from nerfify_ns.equations.eqcheck import write_equation_check

    check = write_equation_check(eq, tmp_path)
    html = render_checks_html([check])
    assert "<script>" not in html and "&lt;script&gt;" in html and "&lt;b&gt;note" in html
    assert "30%" in html and 'class="low"' in html


def test_equation_check_cli_refuses_a_paper_it_cannot_read_in_one_line(tmp_path, capsys):
    from nerfify_ns.paper.equation_check import main

    out = tmp_path / "eqs"
    assert main([str(tmp_path / "missing.pdf"), str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "missing.pdf" in err and "Traceback" not in err
    assert not out.exists()
    assert main([]) == 2
