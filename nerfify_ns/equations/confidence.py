"""How far an equation's LaTeX can be trusted as written: ``latex_issues`` (unbalanced groups, unmatched
``\\left``/``\\right`` and environments, unknown commands, characters without LaTeX) and ``source_confidence``,
the confidence of an equation whose LaTeX came from the source (.tex, markdown). The commands the normaliser
(``normalize.py``) removes or canonicalises are known here from its tables.
"""

from __future__ import annotations

import re

from .mathsym import UNICODE_TO_LATEX
from .normalize import BOLD_COMMANDS, MAX_NORMALIZE_CHARS, STYLE_COMMANDS, TEXT_COMMANDS

try:  # every symbol matplotlib's mathtext knows, when it is installed
    from matplotlib._mathtext_data import tex2uni as _TEX2UNI
except Exception:  # pragma: no cover - matplotlib missing or changed
    _TEX2UNI = {}
_KNOWN_CMDS = set(_TEX2UNI) | set(re.findall(r"\\([A-Za-z]+)", " ".join(UNICODE_TO_LATEX.values()))) | set(
    STYLE_COMMANDS + BOLD_COMMANDS + TEXT_COMMANDS) | {
    "frac", "sqrt", "left", "right", "mathbf", "mathrm", "mathcal", "mathbb", "mathfrak", "mathscr", "mathsf",
    "mathtt", "mathit", "hat", "widehat", "tilde", "widetilde", "bar", "overline", "underline", "vec", "dot",
    "ddot", "text", "operatorname", "begin", "end", "quad", "exp", "log", "ln", "sin", "cos", "tan", "sinh",
    "cosh", "tanh", "min", "max", "arg", "sup", "inf", "lim", "det", "dim", "Pr", "cdot", "sum", "prod", "int",
    "over", "binom", "prime", "mid", "lVert", "rVert", "lvert", "rvert", "Vert", "vert", "top",
    "intercal", "partial", "overrightarrow", "mathnormal", "not", "breve", "check", "acute", "grave", "ast",
    "star", "dagger", "circ", "hbar", "overbrace", "underbrace", "stackrel", "overset", "underset", "bmod",
    "pmod", "mod", "cfrac", "ldots", "cdots", "dots", "vdots", "ddots", "lbrace", "rbrace",
    "lbrack", "rbrack", "backslash", "setminus", "emptyset", "varnothing", "le", "ge", "ne", "gets", "iff",
    "implies", "land", "lor", "lnot", "colon", "vartriangle", "square", "Box", "dotsc", "dotsb", "tfrac",
    "dfrac", "arccos", "arcsin", "arctan", "coth", "sec", "csc", "cot", "gcd", "hom", "ker", "deg", "lg", "liminf",
    "limsup", "injlim", "projlim", "S", "P", "bigl", "bigr", "Bigl", "Bigr", "big", "Big", "mathring", "phantom",
    "hphantom", "vphantom", "smash", "tag", "label", "substack", "atop",
    "choose", "cases", }


def latex_issues(latex: str) -> list[str]:
    """What is wrong with a LaTeX formula as written (never judging its mathematics): unbalanced groups,
    unmatched ``\\left``/``\\right`` and environments, commands we do not know, characters without LaTeX."""
    issues: list[str] = []
    if len(latex) > MAX_NORMALIZE_CHARS:
        issues.append(f"too long for one equation ({len(latex)} characters): not normalised")
    s = re.sub(r"\\[{}]", "", latex)
    depth = 0
    for c in s:
        depth += (c == "{") - (c == "}")
        if depth < 0:
            break
    if depth:
        issues.append(f"unbalanced braces ({'+' if depth > 0 else ''}{depth})")
    lefts, rights = len(re.findall(r"\\left(?![A-Za-z])", latex)), len(re.findall(r"\\right(?![A-Za-z])", latex))
    if lefts != rights:
        issues.append(f"\\left/\\right unmatched ({lefts} vs {rights})")
    begins = re.findall(r"\\begin\{([^}]*)\}", latex)
    ends = re.findall(r"\\end\{([^}]*)\}", latex)
    if sorted(begins) != sorted(ends):
        issues.append("\\begin/\\end unmatched")
    unknown = sorted({c for c in re.findall(r"\\([A-Za-z]+)", latex) if c not in _KNOWN_CMDS})
    if unknown:
        issues.append("unknown commands: " + ", ".join("\\" + u for u in unknown[:6]))
    odd = sorted({c for c in latex if not c.isascii()})
    if odd:
        issues.append("characters without LaTeX: " + "".join(odd[:10]))
    return issues


def source_confidence(latex: str, source: str) -> tuple[float, list[str]]:
    """Confidence in an equation whose LaTeX came from the source (.tex, markdown): the source's own
    LaTeX is trusted, less so for a converter's; each issue of ``latex_issues`` costs."""
    if not latex.strip():
        return 0.0, ["no LaTeX in the source (text only)"]
    base = {"tex": 1.0, "latex": 1.0, "markdown": 0.95, "pdf": 0.95, "text": 0.5}.get(source, 0.8)
    issues = latex_issues(latex)
    penalty = 0.0
    for issue in issues:
        penalty += 0.1 if issue.startswith(("unknown commands", "characters")) else 0.3
    return round(max(0.05, base - penalty), 3), issues
