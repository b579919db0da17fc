"""Finding the display equations of a PDF: math-dominated regions per column, split at equation numbers, each
read from its ``/ActualText`` when one renders it, otherwise rebuilt from its glyphs (``find_equations``)."""

from __future__ import annotations

import re
import time
from collections.abc import Iterable
from dataclasses import dataclass

from nerfify_ns.equations.confidence import latex_issues
from nerfify_ns.equations.normalize import normalize_latex
from nerfify_ns.paper.annotate import equation_sentence

from .actualtext import actual_texts, glyph_skeleton, latex_skeleton, similarity
from .glyphs import Glyph
from .layout import (
    Line,
    PdfEquation,
    body_font,
    build_lines,
    classify_line,
    drop_margins,
    find_columns,
    flow_text,
    glyph_text,
    inline_math_is_prose,
    page_glyphs,
    raw_spans,
    split_number,
)
from .structure import reconstruct

MAX_EQUATION_GLYPHS = 1000
"""A display region with more glyphs is not read as one equation (the layout passes are quadratic in it)."""
MAX_EQUATIONS = 2000
"""At most this many equations per document."""
MAX_RULES = 120
"""At most this many drawn rules considered in one equation."""
TIME_BUDGET_S = 5.0
"""Equations not reached within this many seconds are listed, unread, with the reason."""


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
    spans = {p: raw_spans(pdf[p - 1]) for p in page_nos}
    body_family, body = body_font(list(spans.values()))
    found: list[PdfEquation] = []
    order: list[tuple] = []  # reading order of lines: (page, column, y0, kind, payload)
    for p in page_nos:
        page = pdf[p - 1]
        width = page.rect.width
        glyphs = drop_margins(page_glyphs(spans[p], body_family), width, page.rect.height)
        if not glyphs:
            continue
        two, gutter = find_columns(glyphs, width, body)
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
            lines = [Line(gs, ci) for gs in build_lines(col, body)]
            for ln in lines:
                split_number(ln, cx0, cx1, body)
                classify_line(ln)
            inline_math_is_prose(lines, cx0, cx1, body)
            regs = [r for r in _regions(lines, body, p, ci) if _region_ok(r)]
            if regs and images is None:
                images = _image_boxes(page)
            regs = [r for r in regs if not _inside_image(r.bbox, images or [])]
            page_regions.extend(regs)
            in_region = {id(ln) for r in regs for ln in r.lines}
            height = page.rect.height
            for ln in lines:
                if id(ln) not in in_region and ln.cls == "prose" and flow_text(ln, body, height):
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
                notes = [f"{len(gl)} glyphs, {len(rr)} rules: too many for one equation, not read"]
                latex, conf = "", 0.0
            elif time.perf_counter() - started > TIME_BUDGET_S:
                notes = [f"not read: the PDF equation reader's {TIME_BUDGET_S:.0f} s budget was spent"]
                latex, conf = "", 0.0
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
    sks = [latex_skeleton(a) for a in actual]
    pairs = []
    for ei, (_eq, gl) in enumerate(page_eqs):
        sk = glyph_skeleton(gl)
        for ai, sa in enumerate(sks):
            sim = similarity(sk, sa)
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
