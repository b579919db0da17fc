"""Display equations of a PDF as LaTeX, rebuilt from its text layer (pymupdf), each with a confidence.

Two ways, the better one first:

1. **Embedded LaTeX.** Papers made with ``axessibility`` (loaded by the CVPR/ICCV author kits) carry each
   formula's LaTeX source as the ``/ActualText`` of a marked-content span. We read those strings from the
   page's content stream and give each to the display equation whose glyphs it renders (``method="actualtext"``).
2. **Layout.** Otherwise the glyphs themselves (``method="layout"``): pymupdf's ``rawdict`` gives every
   glyph's font, size and baseline, so math-italic, symbol and extension fonts (CMMI/CMSY/CMEX/CMR/MSBM and
   their Type 1/TrueType cousins, Unicode math fonts) map to LaTeX tokens (raw TeX font codes included);
   sub- and superscripts are smaller glyphs on raised or lowered baselines; big operators take the small
   glyphs centred above and below them as limits; horizontal rules from ``page.get_drawings()`` are
   fraction bars (numerator above, denominator below) or radical overbars; tall delimiters assembled from
   pieces span rows of cases and matrices.

Display equations are found per column: lines dominated by math glyphs, grouped while they stay close,
split at equation numbers ("(n)" set apart at the column's edge). The confidence is the share of glyphs
mapped times what the structure checks leave (``notes`` says what lowered it). Nothing here guesses a
symbol it cannot read: it is written ``?`` and counted.

Entry points: ``find_equations(pdf)`` -> ``list[PdfEquation]``; ``enrich_document(doc, pdf)`` merges them
into a ``Document`` read by ``pdf.py``.
"""

from __future__ import annotations

import bisect
import re
import statistics
import time
import unicodedata
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import lru_cache

from nerfify_ns.equations.mathnorm import equation_sentence, latex_issues, normalize_latex
from nerfify_ns.equations.mathsym import (
    ACCENT_CHARS,
    BIG_OPERATORS,
    CLOSE,
    CMEX,
    CMMI,
    CMR,
    CMSY,
    FUNCTIONS,
    LATEX_FUNCTIONS,
    NAMED_OPERATORS,
    OPEN,
    PIECES,
    RELATIONS,
    UNICODE_TO_LATEX,
    cmex_depth,
    font_family,
    font_role,
    is_bold_font,
    is_italic_text_font,
    math_alnum,
    to_latex_char,
)

MAX_EQUATION_GLYPHS = 1000
"""A display region with more glyphs is not read as one equation (the layout passes are quadratic in it)."""
MAX_EQUATIONS = 2000
"""At most this many equations per document."""
MAX_RULES = 120
"""At most this many drawn rules considered in one equation."""
TIME_BUDGET_S = 5.0
"""Equations not reached within this many seconds are listed, unread, with the reason."""
EQ_NUMBER = re.compile(r"^\(\s*((?:[A-Z]{1,2}\.?\s?)?\d{1,3}(?:\.\d{1,3})?[a-z]?)\s*\)$")
_BINARY = {"+", "-", r"\pm", r"\mp", r"\times", r"\cdot", r"\odot", r"\otimes", r"\oplus", r"\circ", r"\div",
           r"\cup", r"\cap", r"\setminus", "*", "/", r"\star", r"\bullet", r"\wedge", r"\vee", r"\ominus"}
_CONNECTIVES = {"with", "and", "if", "for", "where", "otherwise", "else", "when", "all", "s.t.", "st", "subject",
                "to", "or", "is", "in", "of", "as", "then", "such", "that", "let", "on", "at", "by"}
_SYMBOL_GREEK = dict(zip("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ",
                         ["\\alpha", "\\beta", "\\chi", "\\delta", "\\epsilon", "\\phi", "\\gamma", "\\eta", "\\iota",
                          "\\varphi", "\\kappa", "\\lambda", "\\mu", "\\nu", "o", "\\pi", "\\theta", "\\rho",
                          "\\sigma", "\\tau", "\\upsilon", "\\varpi", "\\omega", "\\xi", "\\psi", "\\zeta",
                          "A", "B", "X", "\\Delta", "E", "\\Phi", "\\Gamma", "H", "I", "\\vartheta", "K", "\\Lambda",
                          "M", "N", "O", "\\Pi", "\\Theta", "P", "\\Sigma", "T", "Y", "\\varsigma", "\\Omega", "\\Xi",
                          "\\Psi", "Z"], strict=False))


# ======================================================================================= glyphs
@dataclass(eq=False, slots=True)
class Glyph:
    """One glyph of the text layer, as a LaTeX token with its geometry."""

    c: str
    tex: str
    kind: str  # ord | op | bin | rel | open | close | middle | punct | accent | radical | piece | prime | text | num
    font: str
    role: str | None
    size: float
    x0: float
    y0: float
    x1: float
    y1: float
    base: float
    bold: bool = False
    italic: bool = False
    mapped: bool = True
    math: bool = False
    extra: dict = field(default_factory=dict)

    @property
    def xc(self) -> float:
        return (self.x0 + self.x1) / 2

    @property
    def yc(self) -> float:
        return (self.y0 + self.y1) / 2


def _classify_tex(tex: str) -> str:
    if tex in BIG_OPERATORS:
        return "op"
    if tex in RELATIONS:
        return "rel"
    if tex in _BINARY:
        return "bin"
    if tex in OPEN:
        return "open"
    if tex in CLOSE:
        return "close"
    if tex in ("|", r"\|"):
        return "middle"
    if tex in (",", ";", ":", ".", "!", "?"):
        return "punct"
    if tex in ("'", "''", "'''"):
        return "prime"
    if tex == r"\sqrt":
        return "radical"
    if re.fullmatch(r"\d", tex):
        return "num"
    return "ord"


def _wrap_style(tex: str, role: str | None, bold: bool) -> str:
    if re.fullmatch(r"[A-Za-z]", tex) or re.fullmatch(r"\\[A-Za-z]+", tex) and tex[1:] in _GREEK_NAMES:
        if role == "blackboard":
            return rf"\mathbb{{{tex}}}"
        if role == "script":
            return rf"\mathcal{{{tex}}}"
        if role == "fraktur":
            return rf"\mathfrak{{{tex}}}"
        if bold:
            return rf"\mathbf{{{tex}}}"
    return tex


_GREEK_NAMES = {v[1:] for v in CMMI.values() if isinstance(v, str) and v.startswith("\\")} | {
    "Gamma", "Delta", "Theta", "Lambda", "Xi", "Pi", "Sigma", "Upsilon", "Phi", "Psi", "Omega"}


def make_glyph(ch: str, font: str, size: float, flags: int, bbox, origin, body_family: str) -> Glyph:
    """The token of one glyph: its LaTeX, its kind, whether it is math, whether we could map it."""
    proto = _token(ch, font, flags, body_family)
    x0, _, x1, _ = bbox
    ox, oy = origin
    extra = proto.extra
    if extra:
        g = Glyph(ch, proto.tex, proto.kind, font, proto.role, size, x0, oy - 0.72 * size, x1, oy + 0.22 * size, oy,
                  proto.bold, proto.italic, proto.mapped, proto.math, dict(extra))
        if "depth" in extra:
            g.y0, g.y1 = oy - extra["top"] * size, oy + extra["depth"] * size
        return g
    return Glyph(ch, proto.tex, proto.kind, font, proto.role, size, x0, oy - 0.72 * size, x1, oy + 0.22 * size, oy,
                 proto.bold, proto.italic, proto.mapped, proto.math, {})


@lru_cache(maxsize=20000)
def _token(ch: str, font: str, flags: int, body_family: str) -> Glyph:
    """The size-free part of a glyph (cached: a paper has few distinct glyphs)."""
    return _make_token(ch, font, 10.0, flags, (0, 0, 1, 1), (0, 0), body_family)


def _make_token(ch: str, font: str, size: float, flags: int, bbox, origin, body_family: str) -> Glyph:
    role = font_role(font)
    fam = font_family(font)
    if role == "roman" and fam == body_family:
        role = None  # a paper set in Computer Modern: CMR is its text font
    bold = is_bold_font(font, flags)
    x0, y0, x1, y1 = bbox
    ox, oy = origin
    g = Glyph(ch, "", "ord", font, role, size, x0, oy - 0.72 * size, x1, oy + 0.22 * size, oy, bold=bold)
    code = ord(ch) if len(ch) == 1 else -1
    tex, kind, mapped = None, None, True
    if ch in PIECES:
        tex, side, part = PIECES[ch]
        kind = "piece"
        g.extra = {"side": side, "part": part}
        if role == "extension":  # TeX's pieces hang below their origin
            brace = tex in (r"\{", r"\}")
            depth = {"mid": 1.8, "ext": 0.3 if brace else 0.6}.get(part, 0.9 if brace else 1.8)
            g.extra.update({"top": 0.06, "depth": depth})
    elif role == "extension" and 0 <= code < 0x80 and ch not in "()[]{}|/\\<>":
        tex, k = CMEX.get(code, ("", "ord"))
        depth = cmex_depth(code)
        if k.startswith("piece:"):
            part = k.split(":")[2]
            brace = tex in (r"\{", r"\}")
            depth = {"mid": 1.8, "ext": 0.3 if brace else 0.6}.get(part, 0.9 if brace else 1.8)
        g.extra = {"top": 0.06, "depth": depth}
        if k.startswith("piece:"):
            _, side, part = k.split(":")
            kind = "piece"
            g.extra.update({"side": side, "part": part})
        elif k == "accent":
            kind = "accent"
            g.extra = {"accent": tex, "wide": True, "top": 0.1, "depth": 0.25}
        elif k == "brace":
            kind, tex = "ignore", ""
        else:
            kind = {"op": "op", "open": "open", "close": "close", "middle": "middle", "radical": "radical"}.get(k, "ord")
        if not tex and kind != "ignore":
            mapped = False
        if kind in ("open", "close", "middle", "radical"):
            g.extra["tall"] = depth >= 1.15
    elif role in ("italic", "roman", "symbol", "blackboard", "script", "fraktur") and (0 <= code < 0x20 or code == 0x7F):
        # a raw TeX font code: the font had no Unicode for this glyph
        table = {"italic": CMMI, "roman": CMR, "symbol": CMSY}.get(role, CMR)
        tex = table.get(code)
        if tex is None:
            tex, mapped = "?", False
    elif role == "symbol" and fam.startswith(("cmsy", "cmbsy", "lmmathsymbols", "txsy", "pxsy", "ntxsy", "newtxsy")) \
            and "A" <= ch <= "Z":
        tex = rf"\mathcal{{{ch}}}"
    elif role in ("symbol",) and fam in ("symbol", "standardsyml", "standardsymlpl", "rpsyr", "psyr", "symbolmt") \
            and ch.isascii() and ch.isalpha():
        tex = _SYMBOL_GREEK.get(ch, ch)
    elif role in ("blackboard", "script", "fraktur") and ch.isascii() and ch.isalpha():
        tex = _wrap_style(ch, role, False)
    else:
        if ch in ACCENT_CHARS and (role is not None or ch not in "^~"):
            kind, tex = "accent", ACCENT_CHARS[ch]
            g.extra = {"accent": tex}
        else:
            alnum = math_alnum(ch)
            if alnum:
                style, base_ch = alnum
                tex = to_latex_char(ch)
                g.italic = style in ("italic", "bold-italic")
                bold = bold or style.startswith("bold")
            else:
                tex = to_latex_char(ch)
                if tex is None:
                    tex, mapped = "?", False
    if ch == "√" and role == "symbol":  # CMSY's surd, like CMEX's radicals, hangs below its origin
        g.extra = {"top": 0.06, "depth": 0.96}
    if role == "extension" and "depth" not in g.extra and fam.startswith(("cmex", "lmmathextension", "txex", "pxex",
                                                                          "ntxex", "newtxex", "esint")):
        # a TeX extension glyph given as Unicode (a ToUnicode map): it still hangs below its origin
        depth = 2.0 if tex in (r"\int", r"\oint", r"\iint") else 1.2
        g.extra = {**g.extra, "top": 0.06, "depth": depth}
    if isinstance(tex, str) and tex.startswith("ACCENT:"):
        kind, tex = "accent", tex.split(":", 1)[1]
        g.extra = {"accent": tex}
    g.tex = tex or ""
    g.mapped = mapped
    if kind is None:
        kind = _classify_tex(g.tex)
    g.kind = kind
    g.bold = bold
    if role is not None:
        g.italic = g.italic or role == "italic"
        if kind == "ord" and role in ("italic", "roman", "symbol") and not g.tex.startswith(r"\math"):
            g.tex = _wrap_style(g.tex, role, bold and not g.tex.startswith("\\") or bold and role == "italic")
        g.math = True
    else:
        g.italic = g.italic or is_italic_text_font(font, flags)
        # a text font: math only for math symbols (Greek, operators); letters and digits are text
        g.math = kind in ("op", "rel", "bin", "radical") or g.tex.startswith("\\") and kind == "ord"
        if kind == "ord" and ch.isalpha() and ch.isascii():
            g.kind = "text"
    return g


# ======================================================================================= page reading
@dataclass(eq=False)
class Line:
    glyphs: list[Glyph]
    column: int
    number: str = ""
    number_glyphs: list[Glyph] = field(default_factory=list)
    cls: str = "prose"  # prose | math | number | empty

    @property
    def x0(self) -> float:
        return min(g.x0 for g in self.all)

    @property
    def x1(self) -> float:
        return max(g.x1 for g in self.all)

    @property
    def y0(self) -> float:
        return min(g.y0 for g in self.all)

    @property
    def y1(self) -> float:
        return max(g.y1 for g in self.all)

    @property
    def base(self) -> float:
        main = [g.base for g in self.glyphs if g.kind not in ("piece", "op", "open", "close", "radical")] or \
            [g.base for g in self.all]
        return statistics.median(main)

    @property
    def all(self) -> list[Glyph]:
        return self.glyphs + self.number_glyphs

    def text(self) -> str:
        return glyph_text(self.all)


def glyph_text(glyphs: list[Glyph]) -> str:
    """Plain text of glyphs in x order, a blank where the gap is wide."""
    out, last = [], None
    for g in sorted(glyphs, key=lambda g: g.x0):
        if last is not None and g.x0 - last.x1 > 0.2 * max(g.size, last.size):
            out.append(" ")
        out.append(g.c)
        last = g
    return "".join(out)


@dataclass
class PdfEquation:
    """A display equation found on a page."""

    page: int
    bbox: list[float]
    latex: str
    number: str = ""
    label: str = ""
    text: str = ""
    confidence: float = 0.0
    method: str = "layout"
    notes: list[str] = field(default_factory=list)
    sentence: str = ""
    column: int = 0
    layout_latex: str = ""

    def to_dict(self) -> dict:
        from dataclasses import asdict

        return asdict(self)


_FLAGS = None


def _flags() -> int:
    global _FLAGS
    if _FLAGS is None:
        import pymupdf

        _FLAGS = (pymupdf.TEXT_PRESERVE_WHITESPACE | pymupdf.TEXT_MEDIABOX_CLIP
                  | getattr(pymupdf, "TEXT_IGNORE_ACTUALTEXT", 0) | getattr(pymupdf, "TEXT_CID_FOR_UNKNOWN_UNICODE", 0))
    return _FLAGS


def _raw_spans(page) -> list[tuple]:
    """(font, size, flags, [(char, bbox, origin), ...]) of every horizontal span on the page."""
    out = []
    for b in page.get_text("rawdict", flags=_flags())["blocks"]:
        if b.get("type") != 0:
            continue
        for ln in b["lines"]:
            if abs(ln["dir"][0] - 1) > 0.01:
                continue
            prev = None
            for s in ln["spans"]:
                chars = [(ch["c"], ch["bbox"], ch["origin"]) for ch in s["chars"] if ch["c"]]
                if not chars:
                    continue
                key = (s["font"], s["size"], s["flags"])
                if prev is not None and prev[:3] == key and abs(prev[3][-1][2][1] - chars[0][2][1]) < 0.01:
                    prev[3].extend(chars)  # the same font on the same baseline: one run (words split by spaces)
                    continue
                prev = (*key, chars)
                out.append(prev)
    return out


_SPACES = {"\u00a0", "\u2002", "\u2003", "\u2009", "\u200a", "\u202f", "\u3000", "\u2004", "\u2005", "\u2006",
           "\u2007", "\u2008", "\u205f"}


_PROSE = re.compile(r"[A-Za-z0-9\s.,;:'\"’‘“”()\[\]\-–—!?/%&]+")


def _glyphs(spans: list[tuple], body_family: str) -> list[Glyph]:
    """The page's glyphs; a long span of plain words in a text font is one glyph (running text: its letters
    are never read one by one, and making a glyph per letter would cost most of the time)."""
    out = []
    for font, size, flags, chars in spans:
        if len(chars) >= 12 and font_role(font) is None:
            text = "".join(c for c, _, _ in chars)
            if _PROSE.fullmatch(text) and text.strip():
                out.append(_span_glyph(text, chars, font, size, flags))
                continue
        for c, bbox, origin in chars:
            if c != " " and c not in _SPACES:
                out.append(make_glyph(c, font, size, flags, bbox, origin, body_family))
    return out


def _span_glyph(text: str, chars: list, font: str, size: float, flags: int) -> Glyph:
    solid = [ch for ch in chars if not ch[0].isspace()]
    oy = solid[0][2][1]
    word = re.sub(r"\s+", " ", text).strip()
    return Glyph(word, r"\text{" + re.sub(r"([{}%$&#_\\])", r"\\\1", word) + "}", "text", font, None, size,
                 solid[0][1][0], oy - 0.72 * size, solid[-1][1][2], oy + 0.22 * size, oy,
                 is_bold_font(font, flags), is_italic_text_font(font, flags), True, False, {"span": True})


def _body_font(spans_by_page: list[list[tuple]]) -> tuple[str, float]:
    fonts, sizes = Counter(), Counter()
    for spans in spans_by_page:
        for font, size, _, chars in spans:
            fonts[font_family(font)] += len(chars)
            sizes[round(size, 1)] += len(chars)
    fam = fonts.most_common(1)[0][0] if fonts else ""
    size = sizes.most_common(1)[0][0] if sizes else 10.0
    return fam, float(size)


def _columns(glyphs: list[Glyph], width: float, body: float) -> tuple[bool, float]:
    """(two-column page?, the gutter's x): few text lines have a glyph across the gutter (only full-width
    ones: title, wide captions), while on a one-column page nearly every line does."""
    text = [g for g in glyphs if g.size >= 0.6 * body and g.size <= 1.3 * body]
    total = sum(len(g.c) for g in text)
    if total < 200:
        return False, width / 2
    lines = {round(g.base / 3) for g in text}
    best = None
    for gx in [width / 2 + d for d in (0, -6, 6, -12, 12, -18, 18, -24, 24)]:
        cross = {round(g.base / 3) for g in text if g.x0 < gx + 4 and g.x1 > gx - 4}
        if len(cross) <= 0.25 * len(lines):
            left_mass = sum(len(g.c) for g in text if g.x1 <= gx)
            right_mass = sum(len(g.c) for g in text if g.x0 >= gx)
            if left_mass > 0.15 * total and right_mass > 0.15 * total and (best is None or len(cross) < best[0]):
                best = (len(cross), gx)
    return (True, best[1]) if best else (False, width / 2)


def _drop_margins(glyphs: list[Glyph], width: float, height: float) -> list[Glyph]:
    """Without running headers, footers and a review copy's line numbers in the outer margins."""
    out = []
    for g in glyphs:
        if g.base < 0.055 * height or g.y0 > 0.945 * height:
            continue
        if (g.x1 < 0.08 * width or g.x0 > 0.92 * width) and (g.c.isdigit() or g.c in "#"):
            continue
        out.append(g)
    return out


def _build_lines(glyphs: list[Glyph], body: float) -> list[list[Glyph]]:
    """Glyphs of one column grouped into baseline lines; small glyphs join the nearest line."""
    main, rest = [], []
    for g in glyphs:
        (main if g.size >= 0.8 * body and g.kind != "piece" and g.role != "extension" else rest).append(g)
    main.sort(key=lambda g: g.base)
    lines: list[list[Glyph]] = []
    anchor = None
    for g in main:
        if lines and g.base - anchor <= 0.25 * body:
            lines[-1].append(g)
        else:
            lines.append([g])
            anchor = g.base
    bases = [statistics.median([x.base for x in ln]) for ln in lines]
    boxes = [(min(x.y0 for x in ln), max(x.y1 for x in ln)) for ln in lines]
    orphans = []
    for g in rest:
        best, bd = None, None
        k = bisect.bisect_left(bases, g.base)
        for i in range(max(0, k - 3), min(len(bases), k + 3)):
            b, (y0, y1) = bases[i], boxes[i]
            if g.kind in ("piece", "op", "open", "close", "radical", "middle", "accent") or g.role == "extension":
                overlap = min(g.y1, y1 + 0.3 * body) - max(g.y0, y0 - 0.3 * body)
                d = abs(g.yc - (y0 + y1) / 2) if overlap > 0 else None
            else:
                d = abs(g.base - b)
                d = d if d <= 0.75 * body else None
            if d is not None and (bd is None or d < bd):
                best, bd = i, d
        if best is None:
            orphans.append(g)
        else:
            lines[best].append(g)
    orphans.sort(key=lambda g: g.base)
    extra: list[list[Glyph]] = []
    for g in orphans:
        if extra and abs(g.base - extra[-1][-1].base) <= 0.45 * g.size:
            extra[-1].append(g)
        else:
            extra.append([g])
    return lines + extra


def _split_number(line: Line, col_x0: float, col_x1: float, body: float) -> None:
    """Take a trailing (or leading) "(n)" set apart from the rest of the line as its equation number."""
    gl = sorted(line.glyphs, key=lambda g: g.x0)
    if not gl or gl[-1].c != ")" and gl[0].c != "(":
        return
    # trailing run after the last wide gap
    for side in ("right", "left"):
        run = []
        seq = gl[::-1] if side == "right" else gl
        for i, g in enumerate(seq):
            run.append(g)
            nxt = seq[i + 1] if i + 1 < len(seq) else None
            gap = (g.x0 - nxt.x1) if side == "right" and nxt else (nxt.x0 - g.x1) if nxt else 99
            if gap > 0.9 * body:
                break
        run = sorted(run, key=lambda g: g.x0)
        txt = "".join(g.c for g in run).replace(" ", "")
        m = EQ_NUMBER.match(txt)
        if not m:
            continue
        ids = {id(g) for g in run}
        rest = [g for g in gl if id(g) not in ids]
        near_edge = run[-1].x1 >= col_x1 - 1.5 * body if side == "right" else run[0].x0 <= col_x0 + 1.5 * body
        if near_edge and (rest or True):
            line.number = m.group(1).replace(" ", "")
            line.number_glyphs = run
            line.glyphs = rest
            return


def _classify(line: Line) -> None:
    if not line.glyphs:
        line.cls = "number" if line.number else "empty"
        return
    words = _text_words(line.glyphs)
    n_text = sum(len(w) for w in words if w.lower().strip(".,;:") not in _CONNECTIVES)
    n_math = sum(1 for g in line.glyphs if g.math)
    strong = any(g.math and (g.role in ("italic", "symbol", "extension", "blackboard", "script", "fraktur")
                             or g.kind in ("op", "rel", "bin", "radical")) for g in line.glyphs)
    if n_math == 0 or not strong and n_text > 0:
        line.cls = "prose"
    elif n_text == 0 or n_math >= 1.5 * n_text and n_text <= 12:
        line.cls = "math"
    else:
        line.cls = "prose"


def _long_words(line: Line) -> list[str]:
    return [w for w in _text_words(line.glyphs) if len(w) >= 3 and w.lower() not in _CONNECTIVES]


def _inline_math_is_prose(lines: list[Line], cx0: float, cx1: float, body: float) -> None:
    """A "math" line that is really running text with inline math: it has words and either fills the
    column's width (justified) or sits between prose lines at the paragraph's own leading."""
    order = sorted(lines, key=lambda ln: ln.base)
    main = [ln for ln in order if ln.glyphs and max(g.size for g in ln.glyphs) >= 0.8 * body]
    lead = 1.65 * body

    def continues(a: Line | None, b: Line) -> bool:  # b follows a at the paragraph's leading, flush left
        return a is not None and 0 < b.base - a.base <= lead and b.x0 <= cx0 + 0.6 * body

    for k, ln in enumerate(main):
        if ln.cls != "math" or ln.number:
            continue
        words = _long_words(ln)
        prev = main[k - 1] if k > 0 else None
        nxt = main[k + 1] if k + 1 < len(main) else None
        full = words and ln.x0 <= cx0 + 0.6 * body and ln.x1 >= cx1 - 1.2 * body
        hyphen = sorted(ln.glyphs, key=lambda g: g.x1)[-1].c in "-‐" and bool(words)
        after_prose = prev is not None and prev.cls == "prose" and continues(prev, ln)
        inside = after_prose and (words or nxt is not None and continues(ln, nxt) and bool(_long_words(nxt)))
        centred = abs((ln.x0 + ln.x1) / 2 - (cx0 + cx1) / 2) <= 0.15 * (cx1 - cx0)
        if full or hyphen or inside or after_prose and not centred:
            ln.cls = "prose"


def _flow_text(line: Line, body: float, height: float) -> bool:
    """Running text (not a footnote, header or page number), for an equation's sentence."""
    sizes = sorted((g.size, len(g.c)) for g in line.glyphs)  # the median size by characters
    half, acc, median = sum(n for _, n in sizes) / 2, 0, body
    for size, n in sizes:
        acc += n
        if acc >= half:
            median = size
            break
    if not 0.88 * body <= median <= 1.15 * body:  # footnotes, titles
        return False
    return not (line.y1 < 0.07 * height or line.y0 > 0.93 * height)


def _text_words(glyphs: list[Glyph]) -> list[str]:
    words, cur, last = [], [], None
    for g in sorted(glyphs, key=lambda g: g.x0):
        if len(g.c) > 1:  # a span of running text
            if cur:
                words.append("".join(cur))
            cur, last = [], g
            words.extend(re.findall(r"[A-Za-z]+", g.c))
            continue
        is_letter = g.kind == "text"
        if is_letter and cur and last is not None and g.x0 - last.x1 < 0.2 * g.size and abs(g.base - last.base) < 1:
            cur.append(g.c)
        elif is_letter:
            if cur:
                words.append("".join(cur))
            cur = [g.c]
        else:
            if cur:
                words.append("".join(cur))
            cur = []
        last = g
    if cur:
        words.append("".join(cur))
    return words


# ======================================================================================= structure
@dataclass(eq=False)
class Node:
    """A laid-out element: a glyph or a composite (fraction, radical, operator with limits, fence, word)."""

    kind: str
    x0: float
    y0: float
    x1: float
    y1: float
    base: float
    size: float
    tex: str = ""
    glyph: Glyph | None = None
    parts: dict = field(default_factory=dict)

    @property
    def xc(self) -> float:
        return (self.x0 + self.x1) / 2

    @property
    def yc(self) -> float:
        return (self.y0 + self.y1) / 2

    @property
    def composite(self) -> bool:
        return self.kind in ("frac", "sqrt", "oplim", "fence", "matrix", "overline", "accent")


def _node(g: Glyph) -> Node:
    return Node(g.kind, g.x0, g.y0, g.x1, g.y1, g.base, g.size, g.tex, g)


class _Stats:
    def __init__(self) -> None:
        self.glyphs = 0
        self.mapped = 0
        self.notes: list[str] = []
        self.penalty = 0.0

    def note(self, text: str, cost: float) -> None:
        if text not in self.notes:
            self.notes.append(text)
        self.penalty += cost


def _merge_pieces(nodes: list[Node]) -> list[Node]:
    """Delimiter pieces (top, extension, middle, bottom) stacked at one x become one tall delimiter."""
    def stackable(n: Node) -> bool:
        return n.kind == "piece" or n.kind == "middle" and n.glyph is not None and n.glyph.role == "extension"

    pieces = sorted((n for n in nodes if stackable(n)), key=lambda n: (round(n.x0), n.y0))
    others = [n for n in nodes if not stackable(n)]
    groups: list[list[Node]] = []
    for p in pieces:
        for grp in groups:
            last = grp[-1]
            if abs(p.x0 - last.x0) < 2.0 and p.y0 - last.y1 < 1.0 * p.size and p.kind == last.kind:
                grp.append(p)
                break
        else:
            groups.append([p])
    out = others
    for grp in groups:
        if grp[0].kind == "middle":
            if len(grp) == 1:
                out.append(grp[0])
                continue
            for n in grp:
                n.glyph.extra["side"] = "middle"
        sides = [n.glyph.extra.get("side") for n in grp]
        texs = [n.tex for n in grp if n.glyph.extra.get("side") != "any"] or [grp[0].tex]
        side = next((s for s in sides if s in ("open", "close", "middle", "radical", "op")), "open")
        tex = Counter(texs).most_common(1)[0][0]
        y0, y1 = min(n.y0 for n in grp), max(n.y1 for n in grp)
        if side == "any":
            side = "open"
        kind = {"open": "open", "close": "close", "middle": "middle", "radical": "radical", "op": "op"}[side]
        size = grp[0].size
        node = Node(kind, min(n.x0 for n in grp), y0, max(n.x1 for n in grp), y1, (y0 + y1) / 2 + 0.25 * size, size,
                    tex)
        node.parts["tall"] = True
        out.append(node)
    return out


def _center_tall(nodes: list[Node]) -> None:
    """Big delimiters, radicals and operators sit on the math axis: their baseline is the row's."""
    for n in nodes:
        g = n.glyph
        if g is not None and g.role == "extension" and n.kind in ("open", "close", "middle", "op", "radical"):
            n.base = n.yc + 0.25 * n.size


def _words(nodes: list[Node], stats: _Stats) -> list[Node]:
    """Upright letters side by side become a word: a function (``\\exp``), ``\\mathrm{...}`` or ``\\text{...}``;
    italic runs spelling a known operator (``tanh``, ``MSE``) become one too."""
    letters = sorted((n for n in nodes if n.glyph is not None and _letter(n.glyph)), key=lambda n: (n.x0))
    others = [n for n in nodes if not (n.glyph is not None and _letter(n.glyph))]
    runs: list[list[Node]] = []
    for n in letters:
        for run in runs:
            last = run[-1]
            if abs(n.base - last.base) <= 0.15 * n.size and abs(n.size - last.size) <= 0.1 * n.size \
                    and -0.3 * n.size <= n.x0 - last.x1 <= 0.12 * n.size and _upright(n.glyph) == _upright(last.glyph):
                run.append(n)
                break
        else:
            runs.append([n])
    out = list(others)
    for run in runs:
        # blockers: anything else at the same height between two letters splits the run
        word = "".join(x.glyph.c for x in run)
        g = run[0].glyph
        upright = _upright(g)
        tex = None
        if word in FUNCTIONS and (upright or word in ("exp", "log", "sin", "cos", "tanh", "min", "max")):
            tex = f"\\{word}" if word in LATEX_FUNCTIONS else rf"\operatorname{{{word}}}"
        elif word in NAMED_OPERATORS or word.lower() in ("softplus", "sigmoid", "relu", "softmax"):
            tex = rf"\operatorname{{{word}}}"
        elif upright and len(run) >= 2 and not g.bold:  # bold letters side by side are vectors (dd^T)
            tex = rf"\text{{{word}}}" if g.role is None else rf"\mathrm{{{word}}}"
        if tex is None:
            out.extend(run)
            continue
        n = run[0]
        node = Node("word", run[0].x0, min(x.y0 for x in run), run[-1].x1, max(x.y1 for x in run),
                    statistics.median(x.base for x in run), n.size, tex)
        node.parts["fn"] = word in FUNCTIONS or tex.startswith(r"\operatorname")
        node.parts["limits"] = word in ("min", "max", "argmin", "argmax", "lim", "sup", "inf")
        out.append(node)
    return out


def _letter(g: Glyph) -> bool:
    return len(g.c) == 1 and g.c.isascii() and g.c.isalpha() and g.kind in ("ord", "text") \
        and g.role not in ("blackboard", "script", "fraktur", "symbol") and g.tex in (g.c, f"\\mathbf{{{g.c}}}")


def _upright(g: Glyph) -> bool:
    return g.role == "roman" or g.role is None and not g.italic


def _accents(nodes: list[Node], stats: _Stats) -> list[Node]:
    """An accent glyph over a symbol wraps it: ``\\hat{C}``."""
    accs = [n for n in nodes if n.kind == "accent"]
    rest = [n for n in nodes if n.kind != "accent"]
    for a in accs:
        wide = a.glyph is not None and a.glyph.extra.get("wide")
        under = [n for n in rest if n.y1 > a.y1 - 0.1 * a.size and n.base > a.base - 0.05 * a.size
                 and min(n.x1, a.x1) - max(n.x0, a.x0) > 0.3 * min(n.x1 - n.x0, a.x1 - a.x0)
                 and n.y0 < a.y1 + 1.2 * a.size]
        if not under:
            if a.tex == "hat":  # a circumflex alone: a superscript caret, keep it visible
                rest.append(Node("ord", a.x0, a.y0, a.x1, a.y1, a.base, a.size, r"\hat{}"))
                stats.note("an accent with nothing under it", 0.05)
            continue
        if not wide:
            under = [min(under, key=lambda n: abs(n.xc - a.xc))]
        under.sort(key=lambda n: n.x0)
        inner = _emit_seq(under, stats)
        cmd = {"hat": "widehat", "tilde": "widetilde"}.get(a.tex, a.tex) if wide and len(under) > 1 else a.tex
        node = Node("accent", min(n.x0 for n in under), min(a.y0, *(n.y0 for n in under)),
                    max(n.x1 for n in under), max(n.y1 for n in under), under[0].base,
                    max(n.size for n in under), rf"\{cmd}{{{inner}}}")
        for n in under:
            rest.remove(n)
        rest.append(node)
    return rest


def _rules_pass(nodes: list[Node], rules: list[tuple], stats: _Stats) -> list[Node]:
    """Fraction bars and radical overbars, shortest first (inner structures before outer ones)."""
    used = set()
    for ri, (rx0, ry, rx1) in sorted(enumerate(rules), key=lambda r: r[1][2] - r[1][0]):
        width = rx1 - rx0
        # a radical: its sign ends where the bar starts
        rad = [n for n in nodes if n.kind == "radical" and abs(n.x1 - rx0) < 2.5 and n.y0 - 3 <= ry <= n.yc]
        inside = [n for n in nodes if n.xc >= rx0 - 0.5 and n.xc <= rx1 + 0.5 and n.kind != "radical" or False]
        if rad:
            r = min(rad, key=lambda n: abs(n.x1 - rx0))
            inner = [n for n in inside if n.y0 >= ry - 0.4 * n.size and n.yc <= r.y1 + 0.2 * n.size]
            if inner:
                tex = _emit_rows(inner, stats)
                node = Node("sqrt", r.x0, min(ry, r.y0), rx1, max(r.y1, *(n.y1 for n in inner)),
                            statistics.median(n.base for n in inner), max(n.size for n in inner), rf"\sqrt{{{tex}}}")
                nodes = [n for n in nodes if n is not r and not any(n is m for m in inner)] + [node]
                used.add(ri)
                continue
        above = [n for n in inside if n.y1 <= ry + 0.35 * n.size and n.base < ry]
        below = [n for n in inside if n.y0 >= ry - 0.35 * n.size and n.base > ry]
        num = _connected(above, ry, up=True)
        den = _connected(below, ry, up=False)
        # a fraction's parts fit under its bar
        num = [n for n in num if n.x0 >= rx0 - 0.25 * n.size and n.x1 <= rx1 + 0.25 * n.size]
        den = [n for n in den if n.x0 >= rx0 - 0.25 * n.size and n.x1 <= rx1 + 0.25 * n.size]
        if num and den:
            size = max(n.size for n in num + den)
            node = Node("frac", rx0, min(n.y0 for n in num), rx1, max(n.y1 for n in den), ry + 0.25 * size, size,
                        rf"\frac{{{_emit_rows(num, stats)}}}{{{_emit_rows(den, stats)}}}")
            drop = {id(n) for n in num + den}
            nodes = [n for n in nodes if id(n) not in drop] + [node]
            used.add(ri)
        elif den and not num and width > 2:
            size = max(n.size for n in den)
            node = Node("overline", rx0, ry - 0.1 * size, rx1, max(n.y1 for n in den),
                        statistics.median(n.base for n in den), size, rf"\overline{{{_emit_seq(den, stats)}}}")
            drop = {id(n) for n in den}
            nodes = [n for n in nodes if id(n) not in drop] + [node]
            used.add(ri)
    for ri in range(len(rules)):
        if ri not in used:
            stats.note("a rule in the equation that is neither a fraction bar nor a radical", 0.03)
    return nodes


def _connected(cands: list[Node], ry: float, up: bool) -> list[Node]:
    """A numerator (``up``) or denominator: the nodes whose baseline sits where TeX puts a fraction's part
    (just above or below the bar), plus the smaller scripts hanging on them."""
    if not cands:
        return []
    if up:  # the numerator's bottom sits just over the bar
        seed = [n for n in cands if (0 < ry - n.base <= 1.15 * n.size or n.composite) and ry - n.y1 <= 0.6 * n.size]
    else:  # the denominator's top just under it
        seed = [n for n in cands if (0 < n.base - ry <= 1.75 * n.size or n.composite) and n.y0 - ry <= 0.5 * n.size]
    if not seed:
        return []
    chosen = {id(n) for n in seed}
    members = [(n, n.size) for n in seed]  # (node, size of the seed it hangs from)
    for _ in range(8):
        grew = False
        for n in cands:
            if id(n) in chosen:
                continue
            # a script: smaller than the seed it hangs from, touching a member, near that member's height
            for m, anchor in members:
                if n.size < 0.95 * anchor and abs(n.yc - m.yc) <= 0.75 * anchor and \
                        m.x0 - 0.2 * m.size <= n.x0 <= m.x1 + 0.35 * m.size:
                    chosen.add(id(n))
                    members.append((n, anchor))
                    grew = True
                    break
        if not grew:
            break
    return [n for n in cands if id(n) in chosen]


def _limits_pass(nodes: list[Node], stats: _Stats) -> list[Node]:
    """Small glyphs centred under or over a big operator (or min/max/lim) are its limits."""
    top = max((n.size for n in nodes), default=0)
    # integrals keep their limits at the side (TeX's default): those are scripts, read later
    ops = sorted((n for n in nodes if n.kind == "op" and n.tex not in (r"\int", r"\iint", r"\oint")
                  or n.kind == "word" and n.parts.get("limits") and n.size >= 0.85 * top), key=lambda n: n.x0)
    if not ops:
        return nodes

    def owner(n: Node) -> Node | None:
        best, score = None, None
        for op in ops:
            w = op.x1 - op.x0
            if min(n.x1, op.x1 + 0.6 * w) - max(n.x0, op.x0 - 0.6 * w) <= 0:
                continue
            if n.y0 >= op.y1 - 0.25 * op.size:
                gap = n.y0 - op.y1
            elif n.y1 <= op.y0 + 0.25 * op.size:
                gap = op.y0 - n.y1
            else:
                continue
            sc = abs(n.xc - op.xc) + 2 * max(0.0, gap)
            if score is None or sc < score:
                best, score = op, sc
        return best

    owners = {id(n): owner(n) for n in nodes if n.kind != "op"}
    for op in ops:
        lower, upper = [], []
        for n in nodes:
            if n is op or n.kind == "op" or n.size > 0.85 * op.size or owners.get(id(n)) is not op:
                continue
            if n.y0 >= op.y1 - 0.25 * op.size and n.base - op.y1 < 1.6 * n.size:
                lower.append(n)
            elif n.y1 <= op.y0 + 0.25 * op.size and op.y0 - n.y1 < 1.2 * n.size and n.base < op.base - 0.6 * op.size:
                upper.append(n)
        lower = _grow_run(lower, nodes, op, owners)
        upper = _grow_run(upper, nodes, op, owners)
        # a limit is centred on its operator; a script to the right is not a limit
        lower = lower if lower and _centred(lower, op) else []
        upper = upper if upper and _centred(upper, op) else []
        if not lower and not upper:
            continue
        tex = op.tex
        if lower:
            tex += f"_{{{_emit_seq(lower, stats)}}}"
        if upper:
            tex += f"^{{{_emit_seq(upper, stats)}}}"
        members = lower + upper
        node = Node("oplim", min(op.x0, *(n.x0 for n in members)), min(op.y0, *(n.y0 for n in members)),
                    max(op.x1, *(n.x1 for n in members)), max(op.y1, *(n.y1 for n in members)), op.base, op.size, tex)
        node.parts["op"] = op
        drop = {id(n) for n in members} | {id(op)}
        nodes = [n for n in nodes if id(n) not in drop] + [node]
    return nodes


def _grow_run(seed: list[Node], nodes: list[Node], op: Node, owners: dict) -> list[Node]:
    """Extend limit glyphs sideways along their own baseline (a limit may be wider than its operator)."""
    if not seed:
        return []
    run = list(seed)
    ids = {id(n) for n in run}
    changed = True
    while changed:
        changed = False
        for n in nodes:
            if id(n) in ids or n is op or n.kind == "op" or owners.get(id(n)) not in (op, None):
                continue
            near = any(abs(n.yc - m.yc) < 0.6 * max(n.size, m.size) and
                       (0 <= n.x0 - m.x1 < 0.45 * m.size or 0 <= m.x0 - n.x1 < 0.45 * m.size or
                        min(n.x1, m.x1) - max(n.x0, m.x0) > 0) for m in run)
            if near and n.size <= op.size * 0.85 and (n.y0 >= op.y1 - 0.25 * op.size or n.y1 <= op.y0 + 0.25 * op.size):
                run.append(n)
                ids.add(id(n))
                changed = True
    return run


def _centred(run: list[Node], op: Node) -> bool:
    top = max(n.size for n in run)
    bases = [n.base for n in run if n.size >= 0.9 * top]
    if max(bases) - min(bases) > 0.5 * top:  # a limit is one line
        return False
    x0, x1 = min(n.x0 for n in run), max(n.x1 for n in run)
    centre = (x0 + x1) / 2
    return abs(centre - op.xc) <= 0.3 * max(x1 - x0, op.x1 - op.x0) + 1.0 and x0 < op.x1 and x1 > op.x0


def _rows(nodes: list[Node]) -> list[list[Node]]:
    """Nodes grouped into rows (multi-line equations, cases, matrices) by their main baselines."""
    if not nodes:
        return []
    size = max(n.size for n in nodes if n.kind != "op") if any(n.kind != "op" for n in nodes) else nodes[0].size
    main = sorted((n for n in nodes if n.size >= 0.85 * size), key=lambda n: n.base)
    bases: list[list[float]] = []
    for n in main:
        if bases and n.base - statistics.median(bases[-1]) <= 1.0 * size:
            bases[-1].append(n.base)
        else:
            bases.append([n.base])
    centres = [statistics.median(b) for b in bases]
    if len(centres) <= 1:
        return [nodes]
    rows: list[list[Node]] = [[] for _ in centres]
    row_of: dict[int, int] = {}
    big = [n for n in nodes if n.size >= 0.85 * size]
    for n in big:
        i = min(range(len(centres)), key=lambda k: abs(n.base - centres[k]))
        rows[i].append(n)
        row_of[id(n)] = i
    for n in nodes:
        if id(n) in row_of:
            continue
        # a script goes with its nucleus: the big node just left of it, level with it
        left = [m for m in big if n.x0 - 1.5 * size <= m.x1 <= n.x0 + 0.5 * size and m.y0 - 0.3 * size <= n.yc <= m.y1 + 0.3 * size]
        if left:
            i = row_of[id(max(left, key=lambda m: m.x1))]
        else:
            i = min(range(len(centres)), key=lambda k: abs(n.base - centres[k]))
        rows[i].append(n)
    return [r for r in rows if r]


def _fences(nodes: list[Node], stats: _Stats) -> list[Node]:
    """A tall delimiter spanning several rows: cases (a lone ``{``) or a matrix (matching pair)."""
    for _ in range(10):
        talls = sorted((n for n in nodes if n.kind in ("open", "close") and (n.parts.get("tall") or
                        n.glyph is not None and n.glyph.extra.get("tall")) and n.y1 - n.y0 > 2.2 * n.size),
                       key=lambda n: n.y1 - n.y0)
        done = False
        for op in [n for n in talls if n.kind == "open"]:
            closes = [c for c in talls if c.kind == "close" and c.x0 > op.x1 and
                      min(c.y1, op.y1) - max(c.y0, op.y0) > 0.6 * (op.y1 - op.y0)]
            cl = min(closes, key=lambda c: c.x0) if closes else None
            right = cl.x0 if cl else float("inf")
            inner = [n for n in nodes if n is not op and n is not cl and n.x0 >= op.x1 - 0.5 and n.x1 <= right + 0.5
                     and n.yc >= op.y0 and n.yc <= op.y1]
            rows = _rows(inner)
            if len(rows) < 2:
                continue
            if cl is None and op.tex != r"\{":
                continue
            row_tex = []
            for r in rows:
                cells = _cells(r)
                row_tex.append(" & ".join(_emit_rows(c, stats) for c in cells))
            if cl is None:
                tex = r"\begin{cases} " + r" \\ ".join(row_tex) + r" \end{cases}"
            else:
                env = {"(": "pmatrix", "[": "bmatrix", r"\{": "Bmatrix", "|": "vmatrix", r"\|": "Vmatrix"}.get(op.tex,
                                                                                                              "pmatrix")
                tex = rf"\begin{{{env}}} " + r" \\ ".join(row_tex) + rf" \end{{{env}}}"
            x1 = cl.x1 if cl else max(n.x1 for n in inner)
            node = Node("matrix", op.x0, op.y0, x1, op.y1, op.base, max(n.size for n in inner), tex)
            drop = {id(n) for n in inner} | {id(op)} | ({id(cl)} if cl else set())
            nodes = [n for n in nodes if id(n) not in drop] + [node]
            stats.note("rows inside a tall delimiter read as a matrix/cases", 0.03)
            done = True
            break
        if not done:
            break
    return nodes


def _cells(row: list[Node]) -> list[list[Node]]:
    """A row split into cells at wide gaps (a matrix's columns, a case's condition)."""
    seq = sorted(row, key=lambda n: n.x0)
    cells, cur, right = [], [], None
    for n in seq:
        if cur and right is not None and n.x0 - right > 0.55 * n.size:
            cells.append(cur)
            cur = []
        cur.append(n)
        right = max(right, n.x1) if right is not None and cur[:-1] else n.x1
    if cur:
        cells.append(cur)
    return cells


def _emit_rows(nodes: list[Node], stats: _Stats) -> str:
    rows = _rows(nodes)
    if len(rows) > 1:
        return r" \\ ".join(_emit_seq(r, stats) for r in rows)
    return _emit_seq(nodes, stats)


def _level(n: Node, base: float, size: float) -> bool:
    if n.composite or n.kind in ("op", "word") and n.size >= 0.8 * size:
        return abs(n.base - base) <= 0.6 * size or n.kind != "word"
    if n.kind in ("open", "close", "middle") and (n.y1 - n.y0) > 1.3 * size:
        return True
    if n.kind == "prime":
        return False
    return abs(n.base - base) <= 0.1 * size and n.size >= 0.6 * size or \
        abs(n.base - base) <= 0.25 * size and n.size >= 0.85 * size


def _emit_seq(nodes: list[Node], stats: _Stats, base: float | None = None, size: float | None = None,
              depth: int = 0) -> str:
    """One row: nuclei left to right, each with the scripts (smaller, raised or lowered) that follow it."""
    if not nodes:
        return ""
    seq = sorted(nodes, key=lambda n: (n.x0, n.base))
    if size is None:
        core = [n for n in seq if n.kind not in ("op", "open", "close") or not n.parts.get("tall")]
        size = max(n.size for n in (core or seq))
    if base is None:
        main = [n.base for n in seq if n.size >= 0.9 * size and n.kind not in ("open", "close", "op", "radical")]
        base = statistics.median(main) if main else statistics.median(n.base for n in seq)
    level = [_level(n, base, size) for n in seq]
    if not any(level):  # nothing on the baseline: take the largest, lowest-x node as the nucleus
        k = max(range(len(seq)), key=lambda j: (seq[j].size, -seq[j].x0))
        level[k] = True
    if depth > 12:
        stats.note("scripts nested too deep; flattened", 0.2)
        return _join([n.tex for n in seq])
    items: list[list] = []  # [nucleus tex, sub nodes, sup nodes, primes, node]
    i = 0
    while i < len(seq):
        n = seq[i]
        if level[i]:
            items.append([n.tex, [], [], "", n])
            i += 1
            continue
        run = []
        while i < len(seq) and not level[i]:
            run.append(seq[i])
            i += 1
        if not items:
            items.append(["{}", [], [], "", None])
            stats.note("a script with nothing before it", 0.03)
        top = max(m.size for m in run)
        primes = [m for m in run if m.kind == "prime" and m.size >= 0.9 * top and m.base < base]
        run = [m for m in run if not any(m is q for q in primes)]
        items[-1][3] += "".join(m.tex for m in primes)
        if run:
            top = max(m.size for m in run)
            first = [m for m in run if m.size >= 0.9 * top and m.kind != "prime"] or run[:1]
            sup_first = [m for m in first if m.base < base - 0.12 * size]
            sub_first = [m for m in first if m not in sup_first]
            sups, subs = list(sup_first), list(sub_first)
            for m in run:
                if m in first:
                    continue
                # a deeper script belongs to the first-level script it follows
                owner = min(first, key=lambda f: (0 if f.x0 <= m.x0 + 0.5 else 1,
                                                  abs(m.x0 - f.x1) + 1.5 * abs(m.yc - f.yc)))
                (sups if owner in sup_first else subs).append(m)
            items[-1][1].extend(subs)
            items[-1][2].extend(sups)
    parts = []
    prev_right = None
    for nucleus, subs, sups, primes, node in items:
        tex = nucleus
        if node is not None and node.kind == "word" and node.parts.get("fn") is False:
            pass
        tex += primes
        if subs:
            tex += "_{" + _emit_seq(subs, stats, depth=depth + 1) + "}"
        if sups:
            tex += "^{" + _emit_seq(sups, stats, depth=depth + 1) + "}"
        if node is not None and prev_right is not None and node.x0 - prev_right > 1.4 * size:
            parts.append(r"\quad")
        parts.append(tex)
        if node is not None:
            prev_right = max([node.x1] + [m.x1 for m in subs + sups])
    return _join(parts)


def _join(parts: list[str]) -> str:
    out = ""
    for p in parts:
        if not p:
            continue
        if out and (re.search(r"\\[A-Za-z]+$", out) and re.match(r"[A-Za-z0-9]", p) or
                    p.startswith(r"\quad") or out.endswith(r"\quad") or
                    p.startswith(r"\text") or re.search(r"\\text\{[^{}]*\}$", out)):
            out += " "
        out += p
    return out


def reconstruct(glyphs: list[Glyph], rules: list[tuple]) -> tuple[str, float, list[str]]:
    """LaTeX of one display equation from its glyphs and the horizontal rules over it, with a confidence
    (share of glyphs mapped times what the structure checks leave) and the notes behind it."""
    stats = _Stats()
    stats.glyphs = len(glyphs)
    stats.mapped = sum(1 for g in glyphs if g.mapped)
    nodes = [_node(g) for g in glyphs if g.kind != "ignore"]
    nodes = _merge_pieces(nodes)
    _center_tall(nodes)
    nodes = _words(nodes, stats)
    nodes = _accents(nodes, stats)
    nodes = _limits_pass(nodes, stats)
    nodes = _rules_pass(nodes, rules, stats)
    nodes = _fences(nodes, stats)
    rows = _rows(nodes)
    if len(rows) > 1:
        stats.note(f"{len(rows)} rows", 0.02 * (len(rows) - 1))
    latex = r" \\ ".join(_emit_seq(r, stats) for r in rows)
    latex = normalize_latex(latex)
    unmapped = stats.glyphs - stats.mapped
    if unmapped:
        odd = "".join(sorted({g.c if g.c.isprintable() else f"\\x{ord(g.c):02x}" for g in glyphs if not g.mapped}))
        stats.note(f"{unmapped} of {stats.glyphs} glyphs without a LaTeX mapping ({odd[:20]})", 0.0)
    for issue in latex_issues(latex):
        stats.note(issue, 0.25 if issue.startswith(("unbalanced", "\\left", "\\begin")) else 0.05)
    opens = len(re.findall(r"(?<!\\)[(\[]", latex))
    closes = len(re.findall(r"(?<!\\)[)\]]", latex))
    if opens != closes:
        stats.note(f"unmatched brackets ({opens} open, {closes} closed)", 0.1)
    # round trip: the letters and digits our LaTeX renders against those of the glyphs read
    kept = _similarity(_latex_skeleton(latex), _glyph_skeleton(glyphs))
    if kept < 0.97:
        stats.note(f"the reading renders {100 * kept:.0f}% of the glyphs' letters and digits", 1.0 - kept)
    share = stats.mapped / max(1, stats.glyphs)
    conf = max(0.05, min(0.9, 0.9 * share - stats.penalty))
    return latex, round(conf, 3), stats.notes


# ======================================================================================= ActualText
def _pdf_string(raw: bytes) -> str:
    """A PDF literal or hex string's text (PDFDocEncoding or UTF-16BE with a BOM)."""
    if raw.startswith(b"<"):
        data = bytes.fromhex(re.sub(rb"[^0-9A-Fa-f]", b"", raw[1:-1]).decode("ascii") or "")
    else:
        body = raw[1:-1]
        out = bytearray()
        i = 0
        while i < len(body):
            c = body[i]
            if c == 0x5C and i + 1 < len(body):  # backslash
                n = body[i + 1]
                esc = {ord("n"): 10, ord("r"): 13, ord("t"): 9, ord("b"): 8, ord("f"): 12}
                if n in esc:
                    out.append(esc[n])
                    i += 2
                elif 0x30 <= n <= 0x37:
                    m = re.match(rb"[0-7]{1,3}", body[i + 1:i + 4])
                    out.append(int(m.group(0), 8) & 0xFF)
                    i += 1 + len(m.group(0))
                elif n in (10, 13):
                    i += 2
                else:
                    out.append(n)
                    i += 2
            else:
                out.append(c)
                i += 1
        data = bytes(out)
    if data.startswith(b"\xfe\xff"):
        return data[2:].decode("utf-16-be", errors="replace")
    return data.decode("latin-1")


_ACTUAL = re.compile(rb"/ActualText\s*(\((?:\\.|[^\\()]|\((?:\\.|[^\\()])*\))*\)|<[0-9A-Fa-f\s]*>)", re.DOTALL)


def actual_texts(page) -> list[str]:
    """The LaTeX strings a page carries as ``/ActualText`` (axessibility), in content order."""
    try:
        data = page.read_contents()
    except Exception:
        return []
    if b"/ActualText" not in data:
        return []
    out = []
    for m in _ACTUAL.finditer(data):
        s = _pdf_string(m.group(1)).strip()
        if re.search(r"\\[A-Za-z]+|[_^]", s):
            out.append(s)
    return out


def _skeleton(s: str) -> Counter:
    """Letters, digits and Greek of a rendering, as a multiset (order-free comparison)."""
    s = unicodedata.normalize("NFKC", s).replace("∆", "Δ").replace("Ω", "Ω")
    return Counter(c for c in s if c.isalnum())


_COMMAND_CHAR = {v[1:]: k for k, v in UNICODE_TO_LATEX.items() if re.fullmatch(r"\\[A-Za-z]+", v) and len(k) == 1}


def _latex_skeleton(latex: str) -> Counter:
    """The letters, digits and Greek a LaTeX formula shows (function names spelled out, markup dropped)."""
    s = re.sub(r"\\(?:label|tag)\s*\{[^{}]*\}|\\(?:begin|end)\s*\{[^{}]*\}(?:\{[^{}]*\})?", "", latex)

    def command(m: re.Match) -> str:
        name = m.group(1)
        if name in FUNCTIONS or name in LATEX_FUNCTIONS:
            return name
        return _COMMAND_CHAR.get(name, "")

    return _skeleton(re.sub(r"\\([A-Za-z]+)", command, s))


def _glyph_skeleton(glyphs: list[Glyph]) -> Counter:
    return _latex_skeleton(" ".join(g.tex for g in glyphs if g.mapped and g.kind not in ("accent", "ignore")))


def _similarity(a: Counter, b: Counter) -> float:
    if not a or not b:
        return 0.0
    inter = sum((a & b).values())
    return 2 * inter / (sum(a.values()) + sum(b.values()))


# ======================================================================================= finding equations
@dataclass
class _Region:
    lines: list[Line]
    column: int
    page: int

    @property
    def glyphs(self) -> list[Glyph]:
        return [g for ln in self.lines for g in ln.glyphs]

    @property
    def numbers(self) -> list[tuple[str, float, list[Glyph]]]:
        return [(ln.number, ln.base, ln.number_glyphs) for ln in self.lines if ln.number]

    @property
    def bbox(self) -> list[float]:
        gl = [g for ln in self.lines for g in ln.all]
        return [min(g.x0 for g in gl), min(g.y0 for g in gl), max(g.x1 for g in gl), max(g.y1 for g in gl)]


def _page_rules(page, clip) -> list[tuple]:
    """Thin horizontal rules (lines and filled thin rectangles) inside ``clip``: (x0, y, x1)."""
    out = []
    try:
        drawings = page.get_drawings()
    except Exception:
        return out
    for d in drawings:
        r = d.get("rect")
        if r is None:
            continue
        for item in d.get("items", []):
            if item[0] == "l":
                p1, p2 = item[1], item[2]
                if abs(p1.y - p2.y) < 0.6 and abs(p2.x - p1.x) >= 2.0:
                    out.append((min(p1.x, p2.x), (p1.y + p2.y) / 2, max(p1.x, p2.x)))
            elif item[0] == "re":
                rr = item[1]
                if rr.height < 1.3 and rr.width >= 2.0:
                    out.append((rr.x0, (rr.y0 + rr.y1) / 2, rr.x1))
    return [(x0, y, x1) for x0, y, x1 in out
            if clip[0] - 2 <= x0 and x1 <= clip[2] + 2 and clip[1] - 2 <= y <= clip[3] + 2]


def _image_boxes(page) -> list[tuple]:
    try:
        return [tuple(info["bbox"]) for info in page.get_image_info()]
    except Exception:
        return []


def _inside_image(bbox: list[float], images: list[tuple]) -> bool:
    x0, y0, x1, y1 = bbox
    area = max(1e-6, (x1 - x0) * (y1 - y0))
    for ix0, iy0, ix1, iy1 in images:
        w = min(x1, ix1) - max(x0, ix0)
        h = min(y1, iy1) - max(y0, iy0)
        if w > 0 and h > 0 and w * h > 0.5 * area:
            return True
    return False


def _regions(lines: list[Line], body: float, page: int, column: int) -> list[_Region]:
    """Consecutive math lines of a column grouped while close; split between equation numbers."""
    regions: list[_Region] = []
    cur: list[Line] = []
    for ln in sorted(lines, key=lambda ln: ln.y0):
        if ln.cls in ("math", "number"):
            if cur and ln.y0 - max(x.y1 for x in cur) > 1.1 * body:
                regions.append(_Region(cur, column, page))
                cur = []
            cur.append(ln)
        elif ln.cls == "prose":
            if cur:
                regions.append(_Region(cur, column, page))
                cur = []
    if cur:
        regions.append(_Region(cur, column, page))
    out = []
    for r in regions:
        nums = r.numbers
        if len(nums) <= 1:
            out.append(r)
            continue
        parts: dict[int, list[Line]] = {i: [] for i in range(len(nums))}
        for ln in r.lines:
            i = min(range(len(nums)), key=lambda k: abs(ln.base - nums[k][1]))
            parts[i].append(ln)
        out.extend(_Region(parts[i], column, page) for i in range(len(nums)) if parts[i])
    return out


def _region_ok(r: _Region) -> bool:
    gl = r.glyphs
    strong = sum(1 for g in gl if g.math and (g.role in ("italic", "symbol", "extension", "blackboard", "script",
                                                           "fraktur") or g.kind in ("op", "rel", "bin", "radical")))
    if not gl:
        return False
    if r.numbers:
        return strong >= 1
    has_relation = any(g.kind in ("rel", "op") for g in gl) or any(g.tex in ("=",) for g in gl)
    return strong >= 3 and has_relation


def find_equations(pdf, pages: Iterable[int] | None = None) -> list[PdfEquation]:
    """Every display equation of an open pymupdf document (or of ``pages``, 1-based), in reading order."""
    started = time.perf_counter()
    page_nos = list(pages) if pages is not None else list(range(1, pdf.page_count + 1))
    spans = {p: _raw_spans(pdf[p - 1]) for p in page_nos}
    body_family, body = _body_font(list(spans.values()))
    found: list[PdfEquation] = []
    order: list[tuple] = []  # reading order of lines: (page, column, y0, kind, payload)
    for p in page_nos:
        page = pdf[p - 1]
        width = page.rect.width
        glyphs = _drop_margins(_glyphs(spans[p], body_family), width, page.rect.height)
        if not glyphs:
            continue
        two, gutter = _columns(glyphs, width, body)
        columns = {0: [g for g in glyphs if g.xc < gutter], 1: [g for g in glyphs if g.xc >= gutter]} if two \
            else {0: glyphs}
        images = None
        actual = actual_texts(page)
        page_regions: list[_Region] = []
        for ci, col in columns.items():
            if not col:
                continue
            cx0 = min(g.x0 for g in col if not g.math) if any(not g.math for g in col) else min(g.x0 for g in col)
            cx1 = max(g.x1 for g in col if not g.math) if any(not g.math for g in col) else max(g.x1 for g in col)
            lines = [Line(gs, ci) for gs in _build_lines(col, body)]
            for ln in lines:
                _split_number(ln, cx0, cx1, body)
                _classify(ln)
            _inline_math_is_prose(lines, cx0, cx1, body)
            regs = [r for r in _regions(lines, body, p, ci) if _region_ok(r)]
            if regs and images is None:
                images = _image_boxes(page)
            regs = [r for r in regs if not _inside_image(r.bbox, images or [])]
            page_regions.extend(regs)
            in_region = {id(ln) for r in regs for ln in r.lines}
            height = page.rect.height
            for ln in lines:
                if id(ln) not in in_region and ln.cls == "prose" and _flow_text(ln, body, height):
                    order.append((p, ci, ln.y0, "text", (ln.text(), ln.y1)))
            for r in regs:
                order.append((p, ci, r.bbox[1], "eq", r))
        if not page_regions:
            continue
        page_box = [min(r.bbox[0] for r in page_regions), min(r.bbox[1] for r in page_regions),
                    max(r.bbox[2] for r in page_regions), max(r.bbox[3] for r in page_regions)]
        rules = _page_rules(page, page_box)
        page_eqs = []
        for r in page_regions:
            if len(found) >= MAX_EQUATIONS:
                break
            gl = sorted(r.glyphs, key=lambda g: (g.x0, g.base))
            bx = r.bbox
            rr = [ru for ru in rules if bx[0] - 2 <= ru[0] and ru[2] <= bx[2] + 2 and bx[1] - 2 <= ru[1] <= bx[3] + 2]
            if len(gl) > MAX_EQUATION_GLYPHS or len(rr) > MAX_RULES:
                latex, conf, notes = "", 0.0, [f"{len(gl)} glyphs, {len(rr)} rules: too many for one equation, not read"]
            elif time.perf_counter() - started > TIME_BUDGET_S:
                latex, conf, notes = "", 0.0, [f"not read: the PDF equation reader's {TIME_BUDGET_S:.0f} s budget was spent"]
            else:
                latex, conf, notes = reconstruct(gl, rr)
            nums = r.numbers
            eq = PdfEquation(page=p, bbox=[round(v, 2) for v in bx], latex=latex, number=nums[0][0] if nums else "",
                             text=glyph_text(gl), confidence=conf, method="layout", notes=notes, column=r.column,
                             layout_latex=latex)
            page_eqs.append((eq, gl))
            found.append(eq)
            r.eq = eq  # type: ignore[attr-defined]
        if actual:
            _match_actual(page_eqs, actual)
    # sentences: the prose before and after each equation in reading order, within its paragraph
    order.sort(key=lambda t: (t[0], t[1], t[2]))
    for k, item in enumerate(order):
        if item[3] != "eq":
            continue
        before, after = [], []
        j, top = k - 1, (item[0], item[1], item[2])
        while j >= 0 and order[j][3] == "text" and len(before) < 6:
            text, y1 = order[j][4]
            if (order[j][0], order[j][1]) == top[:2] and top[2] - y1 > 3.0 * body:
                break  # a paragraph break (or a heading) above
            before.insert(0, text)
            top = (order[j][0], order[j][1], order[j][2])
            j -= 1
        j = k + 1
        while j < len(order) and order[j][3] == "text" and len(after) < 6:
            after.append(order[j][4][0])
            j += 1
        eq = item[4].eq
        eq.sentence = equation_sentence(_dehyphen(" ".join(before)), _dehyphen(" ".join(after)), eq.number)
    found.sort(key=lambda e: (e.page, e.column, e.bbox[1]))
    return found


def _match_actual(page_eqs: list[tuple], actual: list[str]) -> None:
    """Give each embedded LaTeX string to the equation whose glyphs it renders best (best pairs first)."""
    sks = [_latex_skeleton(a) for a in actual]
    pairs = []
    for ei, (eq, gl) in enumerate(page_eqs):
        sk = _glyph_skeleton(gl)
        for ai, sa in enumerate(sks):
            sim = _similarity(sk, sa)
            if sim >= 0.6:
                pairs.append((sim, ei, ai))
    taken_e, taken_a = set(), set()
    for sim, ei, ai in sorted(pairs, reverse=True):
        if ei in taken_e or ai in taken_a:
            continue
        taken_e.add(ei)
        taken_a.add(ai)
        eq, a = page_eqs[ei][0], actual[ai]
        label = re.search(r"\\label\s*\{([^{}]*)\}", a)
        eq.label = label.group(1).strip() if label else ""
        eq.latex = normalize_latex(a)
        eq.method = "actualtext"
        issues = latex_issues(eq.latex)
        eq.confidence = round(max(0.05, min(0.98, 0.7 + 0.28 * sim) - 0.1 * len(issues)), 3)
        eq.notes = [f"LaTeX embedded in the PDF (ActualText), matching the glyphs at {sim:.2f}"] + issues


def _dehyphen(s: str) -> str:
    return re.sub(r"(?<=[a-z])- (?=[a-z])", "", s)


# ======================================================================================= into the Document
def enrich_document(doc, pdf) -> dict:
    """Merge the PDF's display equations into ``doc.equations``: an equation the reader found by its
    number gets the LaTeX, box, confidence and sentence; one it missed (unnumbered, or not recognised)
    is added in reading order; one the layout reader cannot confirm keeps its text and says so.
    Returns timing and counts."""
    from nerfify_ns.paper.document import Equation, Location

    t0 = time.perf_counter()
    try:
        found = find_equations(pdf)
    except Exception as e:  # never let equation reading break ingestion
        for eq in doc.equations:
            eq.notes = eq.notes + [f"PDF equation reading failed: {e}"]
        return {"seconds": round(time.perf_counter() - t0, 3), "found": 0, "error": str(e)}
    by_key = {}
    for f in found:
        if f.number:
            by_key.setdefault((f.page, f.number), f)
    rank = {id(f): i for i, f in enumerate(found)}
    used = set()
    keys: dict[int, float] = {}
    last = -1.0
    for eq in doc.equations:
        f = by_key.get((eq.loc.page, eq.number)) if eq.number else None
        if f is not None and id(f) in used:
            f = None
        if f is None:
            keys[id(eq)] = last + 0.001
            last = keys[id(eq)]
            eq.source = "pdf"
            if not eq.latex:
                eq.method, eq.confidence = "none", 0.0
                eq.notes = ["no display math found at this equation's place by the layout reader; text only"]
            continue
        used.add(id(f))
        _apply(eq, f)
        keys[id(eq)] = last = float(rank[id(f)])
    added = 0
    for f in found:
        if id(f) in used:
            continue
        loc = Location(page=f.page)
        section = ""
        before = f.sentence.split("⟨")[0].strip() if f.sentence else ""
        anchor = doc.find(before[-60:]) if len(before) >= 12 else None
        if anchor is not None:
            sec = doc.section_of(anchor)
            section = sec.heading if sec else ""
            loc.order = anchor.order + 0.5  # just after the paragraph that introduces it
        else:  # the last section starting on this page or before
            on = [sec for sec in doc.sections if sec.loc.page is not None and sec.loc.page <= f.page]
            section = on[-1].heading if on else ""
        eq = Equation(text=f.text, number=f.number, loc=loc, section=section)
        _apply(eq, f)
        keys[id(eq)] = rank[id(f)] + 0.0005
        doc.equations.append(eq)
        added += 1
    doc.equations.sort(key=lambda e: keys[id(e)])
    return {"seconds": round(time.perf_counter() - t0, 3), "found": len(found), "added": added,
            "numbered": sum(1 for f in found if f.number)}


def _apply(eq, f: PdfEquation) -> None:
    eq.source = "pdf"
    eq.method = f.method
    eq.page = f.page
    eq.bbox = list(f.bbox)
    if eq.latex and eq.latex != f.latex and not eq.latex_raw:
        eq.latex_raw = eq.latex
    eq.latex = f.latex
    eq.confidence = f.confidence
    eq.notes = list(f.notes)
    eq.sentence = f.sentence or eq.sentence
    if f.label and not eq.label:
        eq.label = f.label
    if not eq.text:
        eq.text = f.text
