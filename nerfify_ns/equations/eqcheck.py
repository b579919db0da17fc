"""The visual check of equations read from a paper: the LaTeX we read, rendered with matplotlib's mathtext,
next to the crop of the PDF region it came from, so a person can compare them at a glance.

``write_equation_check(eq, folder, pdf=...)`` writes both PNGs of one equation and returns their paths;
``write_equation_checks(doc, folder)`` does every equation of a Document (opening its PDF once). A formula
mathtext cannot draw is never dropped silently: ``EquationCheck.render_error`` says why, and the image
then shows the LaTeX as text with that reason. ``render_checks_html(checks)`` fills the Jinja2 partial
``equation_check.html.j2`` (beside this module; images inlined as ``data:`` URIs) for a report to include.

Bounded: an equation the equation reader refuses for its size (``equations.normalize.size_refusal``: longer
than its character limit, nested too deeply, too many big operators), or longer than ``MAX_DRAW_CHARS``, is
not given to mathtext (its time and memory grow with the input: minutes and GBs for a 600 KB formula); its
image says why it was not drawn. Text shown as text is drawn with ``parse_math=False``, so a ``$`` in it
never starts mathtext either.

Usage: ``python -m nerfify_ns.paper.equation_check PAPER OUT_DIR`` reads a paper and writes the PNGs and
``equations.html``.
"""

from __future__ import annotations

import base64
import re
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .normalize import STYLE_COMMANDS

PARTIAL = "equation_check.html.j2"
MAX_DRAW_CHARS = 1000
"""The longest equation given to mathtext (its time grows with the length, about 1 s per 1000 characters on
one core; the longest equations of real papers have 300-800)."""
_ENVS = {"pmatrix": ("(", ")"), "bmatrix": ("[", "]"), "Bmatrix": (r"\{", r"\}"), "vmatrix": ("|", "|"),
         "Vmatrix": (r"\|", r"\|"), "matrix": (".", "."), "smallmatrix": (".", "."), "cases": (r"\{", "."),
         "array": (".", "."), "aligned": (".", "."), "align": (".", "."), "align*": (".", "."),
         "gathered": (".", "."), "split": (".", "."), "eqnarray": (".", "."), "eqnarray*": (".", ".")}


@dataclass
class EquationCheck:
    """One equation's visual check: the PNGs written (None when there is nothing to show) and what happened."""

    index: int
    number: str
    latex: str
    source: str = ""
    method: str = ""
    confidence: float | None = None
    page: int | None = None
    notes: list[str] = field(default_factory=list)
    rendered: Path | None = None
    crop: Path | None = None
    render_error: str = ""
    mathtext: str = ""
    approximated: bool = False

    def to_dict(self) -> dict:
        d = asdict(self)
        d["rendered"] = str(self.rendered) if self.rendered else None
        d["crop"] = str(self.crop) if self.crop else None
        return d


# ----- LaTeX -> what mathtext can draw ---------------------------------------------------------------------
def _split_rows(latex: str) -> list[str]:
    """Top-level rows (``\\\\`` outside environments and braces)."""
    rows, depth, env, cur, i = [], 0, 0, [], 0
    while i < len(latex):
        if latex.startswith("\\begin{", i):
            env += 1
        elif latex.startswith("\\end{", i):
            env -= 1
        c = latex[i]
        if latex.startswith("\\\\", i) and depth == 0 and env == 0:
            rows.append("".join(cur))
            cur = []
            i += 2
            continue
        if c == "\\":
            cur.append(latex[i:i + 2])
            i += 2
            continue
        depth += (c == "{") - (c == "}")
        cur.append(c)
        i += 1
    rows.append("".join(cur))
    return [r.strip() for r in rows if r.strip()]


def _flatten_envs(s: str) -> tuple[str, bool]:
    """Environments mathtext lacks become one line: ``\\left[ a, b;\\ c, d \\right]`` (an approximation)."""
    changed = False
    for _ in range(20):
        m = re.search(r"\\begin\{([A-Za-z*]+)\}(?:\s*\[[^\]]*\])?(?:\s*\{[^{}]*\})?", s)
        if not m:
            break
        env = m.group(1)
        end_tag = f"\\end{{{env}}}"
        # innermost first: an environment with no nested \begin before its \end
        start, body_start = m.start(), m.end()
        nested = s.find("\\begin{", body_start)
        stop = s.find(end_tag, body_start)
        if stop < 0:
            s = s[:start] + s[body_start:]
            changed = True
            continue
        if 0 <= nested < stop:
            inner = _flatten_envs(s[nested:stop + len(end_tag)])[0]
            s = s[:nested] + inner + s[stop + len(end_tag):]
            changed = True
            continue
        body = s[body_start:stop]
        left, right = _ENVS.get(env, (".", "."))
        body = re.sub(r"\\\\(?:\s*\[[^\]]*\])?", r";\\ ", body)
        body = body.replace("&", r"\ ")
        s = s[:start] + rf"\left{left} {body.strip()} \right{right}" + s[stop + len(end_tag):]
        changed = True
    return s, changed


def to_mathtext(latex: str) -> tuple[list[str], bool]:
    """The rows mathtext is given for ``latex`` and whether anything was approximated (environments)."""
    s, approx = _flatten_envs(latex)
    s = re.sub(r"\\(?:label|tag\*?)\{[^{}]*\}|\\(?:" + "|".join(STYLE_COMMANDS) + r")\b", "", s)
    s = re.sub(r"\\(?:[bB]igg?[lrm]?)(?![A-Za-z])", "", s)
    s = re.sub(r"(?<!\\)&", "", s)
    s = re.sub(r"\\text\{([^{}]*)\}", lambda m: r"\ \text{" + m.group(1).strip() + r"}\ ", s)  # words set apart
    rows = _split_rows(s)
    return rows or [""], approx


def _parse_error(row: str) -> str:
    from matplotlib.mathtext import MathTextParser

    try:
        MathTextParser("path").parse(f"${row}$")
        return ""
    except Exception as e:  # mathtext raises ValueError with a caret diagram
        return re.sub(r"\s+", " ", str(e)).strip()[:300] or type(e).__name__


def _simplify(row: str) -> str:
    """A last try for mathtext: unknown commands as upright names, ``\\operatorname`` as ``\\mathrm``."""
    from matplotlib._mathtext_data import tex2uni

    known = set(tex2uni) | {"frac", "sqrt", "left", "right", "mathbf", "mathrm", "mathcal", "mathbb", "mathit",
                            "mathsf", "mathtt", "mathfrak", "hat", "widehat", "tilde", "widetilde", "bar",
                            "overline", "vec", "dot", "ddot", "text", "operatorname", "quad", "qquad", "exp",
                            "log", "ln", "sin", "cos", "tan", "tanh", "sinh", "cosh", "min", "max", "arg", "sup",
                            "inf", "lim", "det", "dim", "Pr", "boldsymbol", "mathdefault", "underline"}
    row = re.sub(r"\\operatorname\{", r"\\mathrm{", row)
    row = re.sub(r"\\([A-Za-z]+)", lambda m: m.group(0) if m.group(1) in known else rf"\mathrm{{{m.group(1)}}}", row)
    return row


def _placeholder(path: Path, latex: str, reason: str, dpi: int) -> None:
    """A small image that says why an equation was not drawn (plain text only)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 0.8), dpi=dpi)
    FigureCanvasAgg(fig)
    fig.text(0.01, 0.55, " ".join(latex[:120].split()), fontsize=9, family="monospace", color="#b00020",
             parse_math=False)
    fig.text(0.01, 0.15, reason[:150], fontsize=8, color="#b00020", parse_math=False)
    fig.savefig(path, dpi=dpi, facecolor="white")


def render_latex_png(latex: str, path: str | Path, dpi: int = 150,
                     fontsize: float = 14) -> tuple[bool, str, str, bool]:
    """Render ``latex`` (one equation, rows allowed) to ``path``. Returns (ok, error, mathtext given,
    approximated). On a parse failure the image shows the LaTeX as text with the reason, and ok is False. An
    equation too large for the equation reader is not drawn (the image says so); nothing here raises for what
    a paper wrote: a failure is the error returned."""
    from .normalize import size_refusal

    path = Path(path)
    latex = str(latex or "")
    refusal = size_refusal(latex) or (f"longer than {MAX_DRAW_CHARS} characters ({len(latex)}), the most drawn"
                                      if len(latex) > MAX_DRAW_CHARS else None)
    try:
        if refusal:
            error = f"not drawn: {refusal}"
            _placeholder(path, latex, error, dpi)
            return False, error, "", False
        return _render(latex, path, dpi, fontsize)
    except Exception as err:  # noqa: BLE001 - the per-equation boundary: the record says why, the run goes on
        error = f"could not draw: {type(err).__name__}: {' '.join(str(err).split())[:200]}"
        try:
            _placeholder(path, latex, error, dpi)
        except Exception:  # noqa: BLE001 - no image at all: the error says why
            pass
        return False, error, "", False


def _render(latex: str, path: Path, dpi: int, fontsize: float) -> tuple[bool, str, str, bool]:
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows, approx = to_mathtext(latex)
    errors = []
    lines = []
    for row in rows:
        err = _parse_error(row)
        if err:
            simple = _simplify(row)
            if simple != row and not _parse_error(simple):
                lines.append(("math", simple))
                errors.append(f"mathtext could not parse the row as written ({err}); drawn with unknown "
                              "commands as names")
                approx = True
                continue
            lines.append(("text", row))
            errors.append(f"mathtext could not parse: {err}")
        else:
            lines.append(("math", row))
    ok = not any(kind == "text" for kind, _ in lines)
    height = 0.55 * (fontsize / 14) * max(1, len(lines)) + (0.35 if not ok else 0)
    fig = Figure(figsize=(8, height), dpi=dpi)
    FigureCanvasAgg(fig)
    y = 1.0
    step = 1.0 / (len(lines) + (1 if not ok else 0))
    with matplotlib.rc_context({"mathtext.fontset": "cm", "text.usetex": False}):
        for kind, row in lines:
            y -= step
            if kind == "math":
                fig.text(0.01, y + step * 0.25, f"${row}$", fontsize=fontsize)
            else:
                fig.text(0.01, y + step * 0.25, row, fontsize=fontsize * 0.7, family="monospace",
                         color="#b00020", parse_math=False)
        if not ok:
            fig.text(0.01, 0.02, "mathtext could not draw this equation: shown as LaTeX text", fontsize=9,
                     color="#b00020")
        try:
            fig.savefig(path, dpi=dpi, bbox_inches="tight", pad_inches=0.08, facecolor="white")
        except Exception as e:  # a failure only at layout time (e.g. a glyph missing from the font)
            fig2 = Figure(figsize=(8, 0.8), dpi=dpi)
            FigureCanvasAgg(fig2)
            fig2.text(0.01, 0.5, latex[:200], fontsize=9, family="monospace", color="#b00020", parse_math=False)
            fig2.text(0.01, 0.1, f"mathtext failed: {str(e)[:120]}", fontsize=8, color="#b00020", parse_math=False)
            fig2.savefig(path, dpi=dpi, bbox_inches="tight", facecolor="white")
            errors.append(f"mathtext failed while drawing: {re.sub(chr(10), ' ', str(e))[:200]}")
            ok = False
    return ok, "; ".join(errors), r" \\ ".join(r for _, r in lines), approx


def crop_png(pdf, page: int, bbox: Iterable[float], path: str | Path, dpi: int = 150, pad: float = 4.0) -> Path:
    """The PDF region ``bbox`` (points) of ``page`` (1-based), padded, as a PNG."""
    import pymupdf

    x0, y0, x1, y1 = bbox
    pg = pdf[page - 1]
    clip = pymupdf.Rect(x0 - pad, y0 - pad, x1 + pad, y1 + pad) & pg.rect
    pg.get_pixmap(clip=clip, dpi=dpi).save(str(path))
    return Path(path)


# ----- one equation, a document ---------------------------------------------------------------------------
def write_equation_check(eq, folder: str | Path, pdf=None, stem: str | None = None, index: int = 0,
                         dpi: int = 150) -> EquationCheck:
    """Write ``<stem>_latex.png`` (our reading, rendered) and, for a PDF equation, ``<stem>_pdf.png`` (the
    page region it came from) into ``folder``; return both paths with what happened. ``pdf`` is an open
    pymupdf document or a path (needed for the crop)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    number = getattr(eq, "number", "") or ""
    stem = stem or (f"eq{_safe(number)}" if number else f"eq_{index + 1:03d}")
    check = EquationCheck(index=index, number=number, latex=eq.latex, source=getattr(eq, "source", ""),
                          method=getattr(eq, "method", ""), confidence=getattr(eq, "confidence", None),
                          page=getattr(eq, "page", None), notes=list(getattr(eq, "notes", []) or []))
    if eq.latex.strip():
        out = folder / f"{stem}_latex.png"
        ok, err, used, approx = render_latex_png(eq.latex, out, dpi=dpi)
        check.rendered, check.render_error, check.mathtext, check.approximated = out, err, used, approx
    else:
        check.render_error = "no LaTeX was read for this equation"
    bbox = getattr(eq, "bbox", None)
    if pdf is not None and bbox and check.page:
        close = False
        if not hasattr(pdf, "page_count"):
            import pymupdf

            pdf, close = pymupdf.open(str(pdf)), True
        try:
            check.crop = crop_png(pdf, check.page, bbox, folder / f"{stem}_pdf.png", dpi=dpi)
        finally:
            if close:
                pdf.close()
    return check


def _safe(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", s)[:20]


def write_equation_checks(doc, folder: str | Path, pdf=None, dpi: int = 150) -> list[EquationCheck]:
    """``write_equation_check`` for every equation of ``doc`` (its PDF opened once when it is one)."""
    close = False
    if pdf is None and getattr(doc, "kind", "") == "pdf" and Path(doc.source).is_file():
        import pymupdf

        pdf, close = pymupdf.open(doc.source), True
    try:
        checks, seen = [], set()
        for i, eq in enumerate(doc.equations):
            stem = f"eq{_safe(eq.number)}" if eq.number else f"eq_{i + 1:03d}"
            if stem in seen:
                stem = f"{stem}_{i + 1:03d}"
            seen.add(stem)
            checks.append(write_equation_check(eq, folder, pdf=pdf, stem=stem, index=i, dpi=dpi))
        return checks
    finally:
        if close:
            pdf.close()


# ----- HTML -----------------------------------------------------------------------------------------------
def _data_uri(path: Path | None) -> str:
    if not path or not Path(path).is_file():
        return ""
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def checks_context(checks: list[EquationCheck], inline: bool = True, base: Path | None = None) -> list[dict]:
    """What the partial needs per equation: its fields plus image sources (``data:`` URIs when ``inline``,
    else paths relative to ``base``)."""
    out = []
    for c in checks:
        d = c.to_dict()
        for key, p in (("rendered_src", c.rendered), ("crop_src", c.crop)):
            if inline:
                d[key] = _data_uri(p)
            else:
                d[key] = (str(Path(p).relative_to(base)) if base and p else str(p)) if p else ""
        d["confidence_pct"] = "" if c.confidence is None else f"{100 * c.confidence:.0f}%"
        out.append(d)
    return out


def _partial_template():
    from importlib import resources

    import jinja2

    source = resources.files("nerfify_ns.equations").joinpath(PARTIAL).read_text(encoding="utf-8")
    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    return env.from_string(source)


def render_checks_html(checks: list[EquationCheck], inline: bool = True, base: Path | None = None) -> str:
    """The HTML fragment (the partial filled): one row per equation, reading next to the PDF crop."""
    return _partial_template().render(equations=checks_context(checks, inline=inline, base=base))
