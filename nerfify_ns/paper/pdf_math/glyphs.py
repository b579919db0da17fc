"""Glyphs of a PDF's text layer as LaTeX tokens: a character, its font and flags -> the token, its role and
its geometry (raw TeX font codes and Unicode math alphabets included)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import lru_cache

from nerfify_ns.equations.mathsym import (
    ACCENT_CHARS,
    BIG_OPERATORS,
    CLOSE,
    CMEX,
    CMMI,
    CMR,
    CMSY,
    OPEN,
    PIECES,
    RELATIONS,
    cmex_depth,
    font_family,
    font_role,
    is_bold_font,
    is_italic_text_font,
    math_alnum,
    to_latex_char,
)

_BINARY = {"+", "-", r"\pm", r"\mp", r"\times", r"\cdot", r"\odot", r"\otimes", r"\oplus", r"\circ", r"\div",
           r"\cup", r"\cap", r"\setminus", "*", "/", r"\star", r"\bullet", r"\wedge", r"\vee", r"\ominus"}
_SYMBOL_GREEK = dict(zip("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ",
                         ["\\alpha", "\\beta", "\\chi", "\\delta", "\\epsilon", "\\phi", "\\gamma", "\\eta", "\\iota",
                          "\\varphi", "\\kappa", "\\lambda", "\\mu", "\\nu", "o", "\\pi", "\\theta", "\\rho",
                          "\\sigma", "\\tau", "\\upsilon", "\\varpi", "\\omega", "\\xi", "\\psi", "\\zeta",
                          "A", "B", "X", "\\Delta", "E", "\\Phi", "\\Gamma", "H", "I", "\\vartheta", "K", "\\Lambda",
                          "M", "N", "O", "\\Pi", "\\Theta", "P", "\\Sigma", "T", "Y", "\\varsigma", "\\Omega", "\\Xi",
                          "\\Psi", "Z"], strict=False))


class Box:
    """The centre of a box that has ``x0, y0, x1, y1`` in page coordinates (a glyph, a laid-out node)."""

    __slots__ = ()

    @property
    def xc(self) -> float:
        return (self.x0 + self.x1) / 2

    @property
    def yc(self) -> float:
        return (self.y0 + self.y1) / 2


@dataclass(eq=False, slots=True)
class Glyph(Box):
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
            kind = k if k in ("op", "open", "close", "middle", "radical") else "ord"
        if not tex and kind != "ignore":
            mapped = False
        if kind in ("open", "close", "middle", "radical"):
            g.extra["tall"] = depth >= 1.15
    elif role in ("italic", "roman", "symbol", "blackboard", "script", "fraktur") and (code < 0x20 or code == 0x7F) \
            and code >= 0:
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
