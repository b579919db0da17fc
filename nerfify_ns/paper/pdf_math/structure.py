"""The structure of one display equation from its glyphs and drawn rules: fraction bars and radicals, big
operators' limits, scripts from size and baseline, tall delimiters as cases and matrices, rows and cells; the
LaTeX and its confidence (``reconstruct``)."""

from __future__ import annotations

import re
import statistics
from collections import Counter
from dataclasses import dataclass, field

from nerfify_ns.equations.confidence import latex_issues
from nerfify_ns.equations.mathsym import FUNCTIONS, LATEX_FUNCTIONS, NAMED_OPERATORS
from nerfify_ns.equations.normalize import normalize_latex

from .actualtext import glyph_skeleton, latex_skeleton, similarity
from .glyphs import Box, Glyph


@dataclass(eq=False)
class Node(Box):
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
        left = [m for m in big
                if n.x0 - 1.5 * size <= m.x1 <= n.x0 + 0.5 * size and m.y0 - 0.3 * size <= n.yc <= m.y1 + 0.3 * size]
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
    kept = similarity(latex_skeleton(latex), glyph_skeleton(glyphs))
    if kept < 0.97:
        stats.note(f"the reading renders {100 * kept:.0f}% of the glyphs' letters and digits", 1.0 - kept)
    share = stats.mapped / max(1, stats.glyphs)
    conf = max(0.05, min(0.9, 0.9 * share - stats.penalty))
    return latex, round(conf, 3), stats.notes
