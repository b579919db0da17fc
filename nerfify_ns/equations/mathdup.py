"""Undo the "math twice" artefact of HTML-to-markdown conversions (arXiv/LaTeXML).

Such files print each formula as its unicode rendering immediately followed by its LaTeX source,
e.g. ``𝐱=(x,y,z)\\mathbf{x}=(x,y,z)`` or ``L=10L=10``. We find the LaTeX part, check that it renders
to the unicode part, and keep ``$LaTeX$`` only.

Bounded: a formula is looked for within :data:`MAX_FRAGMENT` characters of its first command, and a document's
de-duplication scans and renders at most :data:`MAX_WORK_CHARS` characters in all (a :class:`Budget` shared by
its paragraphs and cells); past that the text is kept as written, so a hostile text costs linear time.
"""

from __future__ import annotations

import re
import unicodedata

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
MAX_FRAGMENT = 1000
"""Characters looked at on each side of a formula's first command (a unicode+LaTeX pair is far shorter)."""

MAX_WORK_CHARS = 4_000_000
"""Characters one document's de-duplication may scan and render, all formulas together (the NeRF paper converted
from arXiv uses about 530,000); past it the rest of the text is kept as written (a few seconds at most)."""


class Budget:
    """What de-duplication may still scan and render in one document."""

    def __init__(self, chars: int = MAX_WORK_CHARS):
        self.left = chars

    def take(self, n: int) -> bool:
        """Spend ``n`` characters; False (nothing spent) when the budget cannot afford them."""
        if n > self.left:
            self.left = 0
            return False
        self.left -= n
        return True


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


def _split_point(text: str, start: int, occ: int, end: int, budget: Budget | None = None) -> int | None:
    """The p in (start, occ] where text[start:p] renders text[p:end], strict comparison first."""
    budget = budget or Budget()
    for norm in (_strict, _loose):
        for p in range(occ, start, -1):
            if not budget.take(end - start):
                return None
            u, lx = text[start:p], text[p:end]
            if u and norm(u) and norm(u) == norm(render(lx)):
                return p
    return None


def _split_by_ends(cell: str, occ: int, k: int = 3, budget: Budget | None = None) -> int | None:
    """Fallback split: the first/last ``k`` symbols of both renderings agree."""
    budget = budget or Budget()
    for p in range(occ, 0, -1):
        if not budget.take(len(cell)):
            return None
        u, lx = _loose(cell[:p]), _loose(render(cell[p:]))
        if len(u) >= k and u[:k] == lx[:k] and u[-k:] == lx[-k:]:
            return p
    return None


def split_display(cell: str, budget: Budget | None = None) -> tuple[str, str]:
    """(unicode, latex) of a display-equation cell; ("", cell) when no LaTeX part is found (or the cell is
    longer than a formula pair, or the budget is spent)."""
    cell = cell.strip()
    occ = cell.find("\\")
    if occ < 0:
        return cell, ""
    if occ > MAX_FRAGMENT or len(cell) > 4 * MAX_FRAGMENT:
        return "", cell
    p = _split_point(cell, 0, occ, len(cell), budget)
    if p is None:
        p = _split_by_ends(cell, occ, budget=budget)
    if p is None:
        return "", cell
    return cell[:p].replace("OPEN", "").replace("CLOSE", "").strip(), cell[p:].strip()


_NEXT_WORD = re.compile(r"\s*(\S+)")


def _latex_end(text: str, occ: int, stop: int | None = None) -> int:
    """Where the inline LaTeX fragment containing ``occ`` ends (braces balanced, next word is prose), at most
    ``stop``."""
    depth, i, n = 0, occ, min(len(text), stop if stop is not None else len(text))
    while i < n:
        c = text[i]
        if c == "{":
            depth += 1
        elif c == "}":
            depth = max(0, depth - 1)
        elif depth == 0 and c.isspace():
            nxt = _NEXT_WORD.match(text, i, min(len(text), i + MAX_FRAGMENT))
            tok = nxt.group(1) if nxt else ""
            if not re.search(r"[\\{}^_=]", tok) and not re.fullmatch(r"[\d.]+[}\\]?.*", tok):
                return i
        elif depth == 0 and c in ",;" and i + 1 < n and text[i + 1] == " ":
            return i
        i += 1
    return n


def _dedupe_repeat(tok: str) -> str | None:
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


def fix_inline(text: str, budget: Budget | None = None) -> str:
    """Replace each unicode+LaTeX pair in running text by ``$LaTeX$``, and plain repeats by one copy; within
    ``budget`` (the document's), the rest kept as written."""
    budget = budget or Budget()
    out, pos = [], 0
    for m in re.finditer(r"\\[A-Za-z]+|[_^]\{", text):
        occ = m.start()
        if occ < pos:
            continue
        if not budget.take(2 * MAX_FRAGMENT if budget.left > 2 * MAX_FRAGMENT else budget.left + 1):
            break
        start, floor = occ, max(pos, occ - MAX_FRAGMENT)
        while start > floor and not text[start - 1].isspace():
            start -= 1
        end = _latex_end(text, occ, occ + MAX_FRAGMENT)
        count = {c: text.count(c, start, end) for c in "()[]"}
        while text[end - 1:end] in (")", "]") and end > start and \
                count[text[end - 1]] > count["(" if text[end - 1] == ")" else "["]:
            count[text[end - 1]] -= 1
            end -= 1  # a bracket closing the surrounding prose
        p = _split_point(text, start, occ, end, budget)
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
