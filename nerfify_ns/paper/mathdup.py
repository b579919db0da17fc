"""Undo the "math twice" artefact of HTML-to-markdown conversions (arXiv/LaTeXML).

Such files print each formula as its unicode rendering immediately followed by its LaTeX source,
e.g. ``𝐱=(x,y,z)\\mathbf{x}=(x,y,z)`` or ``L=10L=10``. We find the LaTeX part, check that it renders
to the unicode part, and keep ``$LaTeX$`` only.
"""

from __future__ import annotations

import re
import unicodedata
from typing import Optional

_SYMBOLS = {
    "alpha": "α", "beta": "β", "gamma": "γ", "delta": "δ", "epsilon": "ϵ", "varepsilon": "ε", "zeta": "ζ",
    "eta": "η", "theta": "θ", "Theta": "Θ", "lambda": "λ", "Lambda": "Λ", "mu": "μ", "nu": "ν", "pi": "π",
    "rho": "ρ", "sigma": "σ", "Sigma": "Σ", "tau": "τ", "phi": "ϕ", "varphi": "φ", "Phi": "Φ", "psi": "ψ",
    "omega": "ω", "Omega": "Ω", "Delta": "Δ", "Gamma": "Γ", "xi": "ξ", "chi": "χ", "kappa": "κ",
    "times": "×", "cdot": "⋅", "sum": "∑", "int": "∫", "prod": "∏", "to": "→", "rightarrow": "→",
    "in": "∈", "sim": "∼", "circ": "∘", "prime": "′", "partial": "∂", "nabla": "∇", "leq": "≤", "geq": "≥",
    "le": "≤", "ge": "≥", "approx": "≈", "cdots": "⋯", "ldots": "…", "dots": "…", "top": "⊤",
    "degree": "°", "lVert": "‖", "rVert": "‖", "|": "‖", "infty": "∞", "pm": "±", "odot": "⊙", "oplus": "⊕",
    "uparrow": "↑", "downarrow": "↓", "exp": "exp", "log": "log", "sin": "sin", "cos": "cos", "max": "max",
    "min": "min", "neq": "≠", "cup": "∪", "cap": "∩", "forall": "∀", "mid": "∣", "star": "⋆", "ell": "ℓ",
}
_ACCENTS = {"hat": "^", "widehat": "^", "tilde": "~", "bar": "¯", "overline": "¯", "dot": "˙", "vec": "→"}
_UNI_DASH = str.maketrans({"−": "-", "–": "-", "∗": "*", "ε": "ϵ"})


def render(latex: str) -> str:
    """A rough unicode rendering of a LaTeX fragment (enough to compare with a converter's rendering)."""
    s = re.sub(r"\\begin\{[^}]*\}(?:\[[^\]]*\])?(?:\{[clr|]*\})?|\\end\{[^}]*\}|\\\\(?:\[[^\]]*\])?", "", latex)
    s = re.sub(r"\\(?:mathopen|mathclose)\{\}|\\left|\\right|\\displaystyle|\\[,;:! ]|\\quad|\\qquad", "", s)
    s = re.sub(r"\\(" + "|".join(_ACCENTS) + r")\s*\{((?:[^{}]|\{[^{}]*\})*)\}",
               lambda m: "{" + m.group(2) + "}" + _ACCENTS[m.group(1)], s)
    s = re.sub(r"\\([A-Za-z]+)", lambda m: _SYMBOLS.get(m.group(1), ""), s)
    s = re.sub(r"\\(.)", r"\1", s)
    return re.sub(r"[{}^_&\s]", "", s)


def _strict(s: str) -> str:
    s = unicodedata.normalize("NFKC", s).translate(_UNI_DASH)
    s = s.replace("OPEN", "").replace("CLOSE", "")
    return re.sub(r"[\s{}^_]", "", s)


def _loose(s: str) -> str:
    return re.sub(r"[^\w]|_", "", _strict(s))


def _split_point(text: str, start: int, occ: int, end: int) -> Optional[int]:
    """The p in (start, occ] where text[start:p] renders text[p:end], strict comparison first."""
    for norm in (_strict, _loose):
        for p in range(occ, start, -1):
            u, lx = text[start:p], text[p:end]
            if u and norm(u) and norm(u) == norm(render(lx)):
                return p
    return None


def _split_by_ends(cell: str, occ: int, k: int = 3) -> Optional[int]:
    """Fallback split: the first/last ``k`` symbols of both renderings agree."""
    for p in range(occ, 0, -1):
        u, lx = _loose(cell[:p]), _loose(render(cell[p:]))
        if len(u) >= k and u[:k] == lx[:k] and u[-k:] == lx[-k:]:
            return p
    return None


def split_display(cell: str) -> tuple[str, str]:
    """(unicode, latex) of a display-equation cell; ("", cell) when no LaTeX part is found."""
    cell = cell.strip()
    occ = cell.find("\\")
    if occ < 0:
        return cell, ""
    p = _split_point(cell, 0, occ, len(cell))
    if p is None:
        p = _split_by_ends(cell, occ)
    if p is None:
        return "", cell
    return cell[:p].replace("OPEN", "").replace("CLOSE", "").strip(), cell[p:].strip()


def _latex_end(text: str, occ: int) -> int:
    """Where the inline LaTeX fragment containing ``occ`` ends (braces balanced, next word is prose)."""
    depth, i, n = 0, occ, len(text)
    while i < n:
        c = text[i]
        if c == "{":
            depth += 1
        elif c == "}":
            depth = max(0, depth - 1)
        elif depth == 0 and c.isspace():
            nxt = re.match(r"\s*(\S+)", text[i:])
            tok = nxt.group(1) if nxt else ""
            if not re.search(r"[\\{}^_=]", tok) and not re.fullmatch(r"[\d.]+[}\\]?.*", tok):
                return i
        elif depth == 0 and c in ",;" and i + 1 < n and text[i + 1] == " ":
            return i
        i += 1
    return n


def _dedupe_repeat(tok: str) -> Optional[str]:
    """"L=10L=10" -> "$L=10$", "33.2033.20" -> "33.20", "NN" -> "$N$"; None if not a repeat."""
    core = tok.rstrip(",.;:")
    if core.endswith(")") and core.count(")") > core.count("("):
        core = core[:-1]
    core = core.lstrip("(") if core.count("(") > core.count(")") else core
    lead = tok[: tok.index(core)]
    tail = tok[len(lead) + len(core):]
    if len(core) < 2 or len(core) % 2:
        return None
    first, half = core[: len(core) // 2], core[len(core) // 2:]
    if first.translate(_UNI_DASH) != half.translate(_UNI_DASH):
        return None
    if re.fullmatch(r"[\d.,]+", half):
        return lead + half + tail
    if re.fullmatch(r"[a-z]{3,}", half) and half not in {"xyz"}:
        return None  # a real doubled word, leave it
    return f"{lead}${half}${tail}"


def has_duplicated_math(text: str) -> bool:
    """Does the text show the unicode+LaTeX artefact (e.g. ``σ\\sigma``) often enough?"""
    return len(re.findall(r"[^\s$\\]\\(?:mathbf|sigma|theta|mathrm|mathcal|times|hat)\b", text)) >= 5


def fix_inline(text: str) -> str:
    """Replace each unicode+LaTeX pair in running text by ``$LaTeX$``, and plain repeats by one copy."""
    out, pos = [], 0
    for m in re.finditer(r"\\[A-Za-z]+|[_^]\{", text):
        occ = m.start()
        if occ < pos:
            continue
        start = occ
        while start > pos and not text[start - 1].isspace():
            start -= 1
        end = _latex_end(text, occ)
        while text[end - 1:end] in (")", "]") and text[start:end].count(text[end - 1]) > \
                text[start:end].count("(" if text[end - 1] == ")" else "["):
            end -= 1  # a bracket closing the surrounding prose
        p = _split_point(text, start, occ, end)
        if p is None:
            continue
        latex = text[p:end]
        trail = ""
        while latex and latex[-1] in ".,;:" and not latex.endswith("\\,"):
            trail, latex = latex[-1] + trail, latex[:-1]
        out.append(text[pos:start] + f"${latex.strip()}$" + trail)
        pos = end
    out.append(text[pos:])
    joined = "".join(out)
    return re.sub(r"(?<![\S])([^\s$]{2,})(?![\S])", lambda m: _dedupe_repeat(m.group(1)) or m.group(1), joined)
