"""Embedded LaTeX: the ``/ActualText`` strings ``axessibility`` writes into a page's content stream, and the
skeletons that tell which display equation such a string renders."""

from __future__ import annotations

import re
import unicodedata
from collections import Counter

from nerfify_ns.equations.mathsym import FUNCTIONS, LATEX_FUNCTIONS, UNICODE_TO_LATEX

from .glyphs import Glyph


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


def latex_skeleton(latex: str) -> Counter:
    """The letters, digits and Greek a LaTeX formula shows (function names spelled out, markup dropped)."""
    s = re.sub(r"\\(?:label|tag)\s*\{[^{}]*\}|\\(?:begin|end)\s*\{[^{}]*\}(?:\{[^{}]*\})?", "", latex)

    def command(m: re.Match) -> str:
        name = m.group(1)
        if name in FUNCTIONS or name in LATEX_FUNCTIONS:
            return name
        return _COMMAND_CHAR.get(name, "")

    return _skeleton(re.sub(r"\\([A-Za-z]+)", command, s))


def glyph_skeleton(glyphs: list[Glyph]) -> Counter:
    return latex_skeleton(" ".join(g.tex for g in glyphs if g.mapped and g.kind not in ("accent", "ignore")))


def similarity(a: Counter, b: Counter) -> float:
    if not a or not b:
        return 0.0
    inter = sum((a & b).values())
    return 2 * inter / (sum(a.values()) + sum(b.values()))
