"""The IR as one line of plain text in the paper's notation (for comments, reports and failures).

``show(parse_equation(r"T_i = \\exp(-\\sum_{j<i} \\sigma_j \\delta_j)"))`` ->
``T_i = exp(-sum_{j<i} sigma_j delta_j)``. The output is ASCII; ``safe_comment`` further strips it to
the characters a generated source comment may hold.
"""

from __future__ import annotations

import math
import re

from .ir import (
    Apply,
    BinOp,
    Cases,
    Compare,
    Concat,
    Equation,
    Expectation,
    Expr,
    Integral,
    Neg,
    Norm,
    Number,
    Reduce,
    Symbol,
)

_PREC = {"+": 1, "-": 1, "*": 2, "odot": 2, "/": 2, "^": 4}


def _sym(s: Symbol) -> str:
    prefix = "".join(f"{d} " for d in s.decorations if d != "prime")
    text = prefix + s.name + "'" * s.decorations.count("prime")
    subs = list(s.subscripts)
    if s.index is not None:
        off = s.index.offset
        subs.insert(0, s.index.var + (f"{off:+d}" if off else ""))
    if subs and not (s.index is not None and s.name == s.index.var and len(subs) == 1):
        text += "_" + (subs[0] if len(subs) == 1 and len(subs[0]) == 1 else "{" + ",".join(subs) + "}")
    if s.superscript:
        text += "^" + (s.superscript if len(s.superscript) == 1 else "{" + s.superscript + "}")
    if s.args:
        text += "(" + ", ".join(show(a) for a in s.args) + ")"
    return text


def _num(n: Number) -> str:
    if n.text in (r"\pi",):
        return "pi"
    if math.isinf(n.value):
        return "inf" if n.value > 0 else "-inf"
    return f"{n.value:g}"


def show(e: Expr | Equation, prec: int = 0) -> str:
    if isinstance(e, Equation):
        rel = {"=": "=", ":=": ":=", "~=": "~=", "propto": "propto"}.get(e.relation, "=")
        return f"{show(e.lhs)} {rel} {show(e.rhs)}"
    if isinstance(e, Symbol):
        return _sym(e)
    if isinstance(e, Number):
        return _num(e)
    if isinstance(e, Neg):
        inner = "-" + show(e.arg, 3)
        return f"({inner})" if prec > 1 else inner
    if isinstance(e, BinOp):
        p = _PREC[e.op]
        op = {"*": " ", "odot": " (.) ", "^": "^", "/": "/", "+": " + ", "-": " - "}[e.op]
        right_prec = p + 1 if e.op in ("-", "/", "^") else p
        text = show(e.left, p + (1 if e.op == "^" else 0)) + op + show(e.right, right_prec)
        return f"({text})" if p < prec else text
    if isinstance(e, Apply):
        if e.func == "abs":
            return "|" + show(e.args[0]) + "|"
        return e.func + "(" + ", ".join(show(a) for a in e.args) + ")"
    if isinstance(e, Compare):
        op = {"in": " in "}.get(e.op, f" {e.op} ")
        return show(e.left, 2) + op + show(e.right, 2)
    if isinstance(e, Norm):
        order = "" if e.order == 2 else ("_inf" if math.isinf(e.order) else f"_{e.order:g}")
        return "||" + show(e.arg) + "||" + order
    if isinstance(e, Concat):
        return "[" + ", ".join(show(a) for a in e.items) + "]"
    if isinstance(e, Cases):
        parts = [f"{show(v)} if {show(c)}" if c is not None else f"{show(v)} otherwise" for v, c in e.branches]
        return "{" + "; ".join(parts) + "}"
    if isinstance(e, Expectation):
        text = f"E_{e.index} " + show(e.body, 2)
        return f"({text})" if prec > 1 else text
    if isinstance(e, Reduce):
        if e.condition is not None:
            limits = "_{" + show(e.condition) + "}"
        elif e.lower is not None:
            limits = "_{" + e.index + "=" + show(e.lower) + "}"
        else:
            limits = "_" + e.index
        if e.upper is not None:
            limits += "^{" + show(e.upper) + "}"
        text = f"{e.kind}{limits} " + show(e.body, 2)
        return f"({text})" if prec > 1 else text
    if isinstance(e, Integral):
        limits = ""
        if e.lower is not None:
            limits += "_{" + show(e.lower) + "}"
        if e.upper is not None:
            limits += "^{" + show(e.upper) + "}"
        text = f"int{limits} " + show(e.body, 2) + f" d{e.var}"
        return f"({text})" if prec > 1 else text
    return type(e).__name__  # pragma: no cover


_UNSAFE = re.compile(r"[^A-Za-z0-9 _^{}()\[\]+\-*/=<>,.|:;']")


def safe_comment(text: str, limit: int = 160) -> str:
    """Printable ASCII from a fixed set, one line, at most ``limit`` characters (ends with '...')."""
    text = _UNSAFE.sub("?", text.replace("\n", " ").replace("\r", " "))
    return text if len(text) <= limit else text[:limit - 3] + "..."
