"""Page reading: the text layer's spans -> glyphs, the body font, columns, lines, equation numbers set apart at a
column's edge, and which lines are math, prose or inline math in running text."""

from __future__ import annotations

import bisect
import re
import statistics
from collections import Counter
from dataclasses import dataclass, field

from nerfify_ns.equations.mathsym import font_family, font_role, is_bold_font, is_italic_text_font

from .glyphs import Glyph, make_glyph

EQ_NUMBER = re.compile(r"^\(\s*((?:[A-Z]{1,2}\.?\s?)?\d{1,3}(?:\.\d{1,3})?[a-z]?)\s*\)$")
_CONNECTIVES = {"with", "and", "if", "for", "where", "otherwise", "else", "when", "all", "s.t.", "st", "subject",
                "to", "or", "is", "in", "of", "as", "then", "such", "that", "let", "on", "at", "by"}


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


def raw_spans(page) -> list[tuple]:
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


def page_glyphs(spans: list[tuple], body_family: str) -> list[Glyph]:
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


def body_font(spans_by_page: list[list[tuple]]) -> tuple[str, float]:
    fonts, sizes = Counter(), Counter()
    for spans in spans_by_page:
        for font, size, _, chars in spans:
            fonts[font_family(font)] += len(chars)
            sizes[round(size, 1)] += len(chars)
    fam = fonts.most_common(1)[0][0] if fonts else ""
    size = sizes.most_common(1)[0][0] if sizes else 10.0
    return fam, float(size)


def find_columns(glyphs: list[Glyph], width: float, body: float) -> tuple[bool, float]:
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


def drop_margins(glyphs: list[Glyph], width: float, height: float) -> list[Glyph]:
    """Without running headers, footers and a review copy's line numbers in the outer margins."""
    out = []
    for g in glyphs:
        if g.base < 0.055 * height or g.y0 > 0.945 * height:
            continue
        if (g.x1 < 0.08 * width or g.x0 > 0.92 * width) and (g.c.isdigit() or g.c in "#"):
            continue
        out.append(g)
    return out


def build_lines(glyphs: list[Glyph], body: float) -> list[list[Glyph]]:
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


def split_number(line: Line, col_x0: float, col_x1: float, body: float) -> None:
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
        if near_edge:
            line.number = m.group(1).replace(" ", "")
            line.number_glyphs = run
            line.glyphs = rest
            return


def classify_line(line: Line) -> None:
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


def inline_math_is_prose(lines: list[Line], cx0: float, cx1: float, body: float) -> None:
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


def flow_text(line: Line, body: float, height: float) -> bool:
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
