"""Equations made uniform across sources: one LaTeX normaliser for .tex, markdown and PDF equations, the
checks behind an equation's confidence, and the finishing pass of the builder (source, sentence, confidence).

``normalize_latex`` removes the noise converted papers carry and canonicalises spellings that mean the same:

* bold: ``\\pmb``, ``\\boldsymbol``, ``\\bm``, ``\\bold``, ``{\\bf x}`` -> ``\\mathbf{x}``; ``{\\cal L}`` -> ``\\mathcal{L}``,
  ``{\\rm obj}``/``\\textrm``/``\\mbox`` -> ``\\mathrm``/``\\text``; empty ``\\mathbf{}`` and friends dropped;
* markdown's lost escapes: a stray ``*{`` after an atom was ``_{`` (``{\\cal L}*{\\rm reg}``); with evidence of
  lost backslashes in the same text (``!\\big(``, ``!\\left(``): ``!`` -> ``\\!``, top-level ``,`` -> ``\\,``,
  ``[2pt]`` -> ``\\\\``;
* wrappers: a ``\\begin{array}`` around the whole formula or around one cell, LaTeXML's
  ``\\mathopen{}\\mathclose{{\\left( ...}}\\right)``, ``\\displaystyle``, sizes (``\\small``), ``\\big`` sizes,
  ``\\label``/``\\tag``/``\\nonumber``, ``\\limits``;
* spacing: Mathpix's ``L _ { \\mathrm { r e c } }`` -> ``L_{\\mathrm{rec}}``; thin spaces -> a blank; trailing
  sentence punctuation dropped;
* numbers as the equation reader reads them (``equations.normalize.normalize_numbers``): MinerU's spaced digits
  ``1 0 ^ { - 2 }`` -> ``10^{-2}``, ``0 . 0 0 1`` -> ``0.001``, ``8\\,192`` -> ``8192``, ``1e-2`` -> ``0.01``,
  ``10⁻³`` -> ``10^{-3}``;
* Unicode pasted into LaTeX -> commands (``σ`` -> ``\\sigma``); ``\\lVert``/``\\Vert`` -> ``\\|``; ``\\dfrac`` ->
  ``\\frac``; ``{a \\over b}`` -> ``\\frac{a}{b}``; ``\\operatorname*`` -> ``\\operatorname``.

It never guesses mathematics: anything it does not recognise is left as it is.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from functools import lru_cache

from nerfify_ns.equations.mathsym import UNICODE_TO_LATEX, to_latex_char
from nerfify_ns.equations.normalize import normalize_numbers

_FONT_DECL = {"bf": r"\mathbf", "bm": r"\mathbf", "boldmath": r"\mathbf", "cal": r"\mathcal", "rm": r"\mathrm",
              "it": r"\mathit", "sf": r"\mathsf", "tt": r"\mathtt", "mit": r"\mathit"}
_BOLD_CMDS = ("pmb", "boldsymbol", "bm", "bold", "mathbold", "mathbfit", "bmath", "textbf", "mathbf")
_TEXT_CMDS = ("textrm", "textnormal", "mbox", "textup", "textit", "textsf", "texttt", "hbox")
_ARG_CMDS = ("mathbf", "mathrm", "mathcal", "mathbb", "mathfrak", "mathscr", "mathsf", "mathtt", "mathit",
             "hat", "widehat", "tilde", "widetilde", "bar", "overline", "vec", "dot", "ddot", "text",
             "operatorname", "underline", "breve", "check", "acute", "grave")
_SIZE_CMDS = ("displaystyle", "textstyle", "scriptstyle", "scriptscriptstyle", "tiny", "scriptsize",
              "footnotesize", "small", "normalsize", "large", "Large", "LARGE", "huge", "Huge", "limits",
              "nolimits", "nonumber", "notag", "allowbreak", "nobreak", "centering", "medmuskip", "relax")
_THIN_SPACES = re.compile(r"(?<!\\)\\(?:,|;|:|!|>|\s)|\\(?:thinspace|medspace|thickspace|negthinspace)\b|(?<!\\)~")
_LOST_EVIDENCE = re.compile(r"(?:^|[\s})\w])!\\(?:left|big|Big|bigg|Bigg)\b|(?<![\\\s^_])\*\{|\\(?:exp|log)!")
MAX_NORMALIZE_CHARS = 20_000
"""Longer formulas are not normalised (every step here is linear, a few are repeated per nesting level)."""
_STRAY_STAR = re.compile(r"(?<=[A-Za-z0-9})\]])\*\{")


def read_group(s: str, i: int) -> tuple[str | None, int]:
    """The content of the balanced ``{...}`` starting at ``i`` (blanks skipped) and the index after it;
    (None, i) when no group starts there."""
    j = i
    while j < len(s) and s[j] in " \t\n":
        j += 1
    if j >= len(s) or s[j] != "{":
        return None, i
    depth = 0
    k = j
    while k < len(s):
        c = s[k]
        if c == "\\":
            k += 2
            continue
        if c == "{":
            depth += 1
        elif c == "}":
            depth -= 1
            if depth == 0:
                return s[j + 1:k], k + 1
        k += 1
    return None, i


def _arg(s: str, i: int) -> tuple[str | None, int]:
    """A command's argument at ``i``: a group, a control word, or one character (blanks skipped)."""
    content, end = read_group(s, i)
    if content is not None:
        return content, end
    j = i
    while j < len(s) and s[j] in " \t\n":
        j += 1
    if j >= len(s) or s[j] in "}^_&":
        return None, i
    m = re.match(r"\\[A-Za-z]+|\\.|.", s[j:], re.DOTALL)
    return m.group(0), j + len(m.group(0))


def _map_commands(s: str, names: Iterable[str], fn, depth: int = 0) -> str:
    """Replace every ``\\name ARG`` (ARG a group or one token) by ``fn(name, ARG)``, the argument mapped
    first (one pass per nesting level; deeper than 64 levels is left as it is)."""
    rx = _command_rx(tuple(names))
    if depth > 64 or not rx.search(s):
        return s
    out, pos = [], 0
    for m in rx.finditer(s):
        if m.start() < pos:
            continue
        arg, end = _arg(s, m.end())
        if arg is None:
            continue
        out.append(s[pos:m.start()])
        out.append(fn(m.group(1), _map_commands(arg, names, fn, depth + 1)))
        pos = end
    out.append(s[pos:])
    return "".join(out)


@lru_cache(maxsize=16)
def _command_rx(names: tuple) -> re.Pattern:
    return re.compile(r"\\(" + "|".join(sorted(names, key=len, reverse=True)) + r")(?![A-Za-z])\*?")


def _font_declarations(s: str) -> str:
    """``{\\cal L}`` -> ``\\mathcal{L}``, ``^{\\rm obj}`` -> ``^{\\mathrm{obj}}`` (scope: to the group's end)."""
    rx = re.compile(r"\\(" + "|".join(_FONT_DECL) + r")(?![A-Za-z])\s*")
    for _ in range(50):
        m = rx.search(s)
        if not m:
            break
        # the declaration's scope ends at the close of the enclosing group (or the string's end)
        depth, k = 0, m.end()
        while k < len(s):
            c = s[k]
            if c == "\\":
                k += 2
                continue
            if c == "{":
                depth += 1
            elif c == "}":
                if depth == 0:
                    break
                depth -= 1
            k += 1
        body = s[m.end():k].strip()
        cmd = _FONT_DECL[m.group(1)]
        s = s[:m.start()] + (f"{cmd}{{{body}}}" if body else "") + s[k:]
    return s


def _unwrap_mathclose(s: str) -> str:
    """LaTeXML's ``\\mathopen{}\\mathclose{{\\left( X}}\\right)`` -> ``\\left( X\\right)``."""
    s = s.replace(r"\mathopen{}", "")
    for _ in range(100):
        i = s.find(r"\mathclose{")
        if i < 0:
            break
        content, end = read_group(s, i + len(r"\mathclose"))
        if content is None:
            break
        inner, inner_end = read_group(content, 0)
        if inner is not None and inner_end == len(content.rstrip()):
            content = inner
        s = s[:i] + content + s[end:]
    return s


def _top_level_split(body: str, sep: str) -> list[str]:
    """Split at ``sep`` (``\\\\`` or ``&``) outside braces and nested environments."""
    parts, depth, env, cur, i = [], 0, 0, [], 0
    while i < len(body):
        if body.startswith("\\begin{", i):
            env += 1
        elif body.startswith("\\end{", i):
            env -= 1
        c = body[i]
        if c == "\\" and not body.startswith(sep, i):
            cur.append(body[i:i + 2])
            i += 2
            continue
        if c == "{":
            depth += 1
        elif c == "}":
            depth -= 1
        if depth == 0 and env == 0 and body.startswith(sep, i):
            parts.append("".join(cur))
            cur = []
            i += len(sep)
            continue
        cur.append(c)
        i += 1
    parts.append("".join(cur))
    return parts


def _unwrap_arrays(s: str) -> str:
    """A ``\\begin{array}`` around the whole formula, or around a single cell anywhere, is a wrapper."""
    rx = re.compile(r"\\begin\{array\}\s*(?:\[[^\]]*\])?\s*\{([^{}]*)\}")
    budget = 200  # environments examined, in all
    for _ in range(20):
        changed = False
        for m in rx.finditer(s):
            budget -= 1
            if budget < 0:
                break
            end = _env_end(s, m.end(), "array")
            if end is None:
                continue
            body_end, after = end
            body = s[m.end():body_end]
            rows = [r for r in _top_level_split(body, "\\\\") if r.strip()]
            rows = [re.sub(r"^\s*\[[^\]]*\]", "", r) for r in rows]  # \\[2pt] row spacing
            cells = [c for r in rows for c in _top_level_split(r, "&")]
            whole = not s[:m.start()].strip() and not s[after:].strip()
            if len(cells) == 1 or whole:
                inner = " \\\\ ".join(_strip_braces(r.strip()) for r in rows)
                s = s[:m.start()] + inner + s[after:]
                changed = True
                break
        if not changed:
            break
    s = re.sub(r"\\begin\{array\}\s*\[\]", r"\\begin{array}", s)
    return s


def _env_end(s: str, start: int, env: str) -> tuple[int, int] | None:
    """(index of ``\\end{env}``, index after it) matching the environment opened before ``start``."""
    depth, i = 1, start
    opener, closer = f"\\begin{{{env}}}", f"\\end{{{env}}}"
    while True:
        nxt = s.find(closer, i)
        if nxt < 0:
            return None
        nested = s.find(opener, i, nxt)
        if nested >= 0:
            depth, i = depth + 1, nested + len(opener)
            continue
        depth -= 1
        if depth == 0:
            return nxt, nxt + len(closer)
        i = nxt + len(closer)


def _strip_braces(s: str) -> str:
    """``{x+y}`` -> ``x+y`` when one group spans the whole string."""
    while s.startswith("{"):
        content, end = read_group(s, 0)
        if content is None or end != len(s):
            break
        s = content.strip()
    return s


def _over_to_frac(s: str) -> str:
    """``{a \\over b}`` -> ``\\frac{a}{b}`` (one ``\\over`` in a group)."""
    for _ in range(20):
        m = re.search(r"\\over(?![A-Za-z])", s)
        if not m:
            break
        # the enclosing group
        depth, k = 0, m.start() - 1
        while k >= 0:
            c = s[k]
            if c == "}" and (k == 0 or s[k - 1] != "\\"):
                depth += 1
            elif c == "{" and (k == 0 or s[k - 1] != "\\"):
                if depth == 0:
                    break
                depth -= 1
            k -= 1
        if k < 0:
            num, den, end = s[:m.start()], s[m.end():], len(s)
            return f"\\frac{{{num.strip()}}}{{{den.strip()}}}"
        content, end = read_group(s, k)
        if content is None:
            break
        rel = m.start() - (k + 1)
        num, den = content[:rel], content[rel + len(r"\over"):]
        s = s[:k] + f"\\frac{{{num.strip()}}}{{{den.strip()}}}" + s[end:]
    return s


def _mathpix_spacing(s: str, spaced: bool = False) -> str:
    """Blanks next to ``_ ^``, inside ``{ }`` dropped; with ``spaced`` (Mathpix's blank between every token)
    also around brackets and operators; letter-by-letter words inside text commands joined. Blanks after a
    control word stay (``\\alpha x``); TeX ignores the others in math."""
    s = re.sub(r"(?<!\\)\s*([_^])\s*", r"\1", s)
    s = re.sub(r"(?<!\\)\{\s+", "{", s)
    s = re.sub(r"(?<![\\\s])\s+\}", "}", s)
    s = re.sub(r"(\\[A-Za-z]+)\s+\{", r"\1{", s)  # "\pmb {x}" -> "\pmb{x}"
    if spaced:  # Mathpix's "C ( r ) = x" -> "C(r)=x"
        s = re.sub(r"(?<!\\)\s+\{", "{", s)
        s = re.sub(r"(?<!\\)\}\s+(?![A-Za-z\\])", "}", s)
        s = re.sub(r"(?<![\\\s])\s+([()\[\]=+\-,|])", r"\1", s)
        s = re.sub(r"(?<!\\)([(\[=+\-|])\s+(?=[^\s&])", r"\1", s)

    def join(m: re.Match) -> str:
        body = m.group(2)
        if re.fullmatch(r"(?:\S\s)+\S", body.strip()):
            body = body.replace(" ", "")
        return f"\\{m.group(1)}{{{body}}}"

    return re.sub(r"\\(mathrm|text|operatorname|mathit|mathsf|mathtt|mathbf)\{([^{}]*)\}", join, s)


def _unicode(s: str) -> str:
    out = []
    for ch in s:
        if ch.isascii():
            out.append(ch)
            continue
        tex = to_latex_char(ch)
        if tex is None:
            out.append(ch)
        elif tex.startswith("\\") and re.match(r"\\[A-Za-z]+$", tex):
            out.append(tex + " ")
        else:
            out.append(tex)
    return "".join(out)


def has_lost_backslashes(text: str) -> bool:
    """Does ``text`` show markdown's lost escapes (``\\exp!\\left(``, ``{\\cal L}*{...}``)?"""
    return bool(_LOST_EVIDENCE.search(text))


def _restore_lost(s: str) -> str:
    """With evidence of lost backslashes: ``!`` before a delimiter -> ``\\!``, ``,`` at the top level and
    before more math -> ``\\,``, ``[2pt]`` -> a row break, a lone ``\\`` at a line end -> ``\\\\``."""
    s = re.sub(r"(?<=[\w)}\s])!(?=\s*(?:\\(?:left|right|big|Big|bigg|Bigg)[lrm]?\b|\())", r"\\!", s)
    s = re.sub(r"(?<!\\)\\\s*\n", r"\\\\ ", s)
    s = re.sub(r"(?<!\\)(?<!\\\\)\[\s*-?\d+(?:\.\d+)?\s*(?:pt|em|ex|mm)\s*\]", r" \\\\ ", s)
    out, depth, i = [], 0, 0
    while i < len(s):
        c = s[i]
        if c == "\\":
            m = re.match(r"\\(?:[A-Za-z]+|.)", s[i:])
            tok = m.group(0) if m else c
            if tok in (r"\left", r"\bigl", r"\Bigl", r"\biggl", r"\Biggl"):
                depth += 1
            elif tok in (r"\right", r"\bigr", r"\Bigr", r"\biggr", r"\Biggr"):
                depth -= 1
            out.append(tok)
            i += len(tok)
            if tok in (r"\left", r"\right") and i < len(s):  # the delimiter that follows is not a bracket
                out.append(s[i])
                i += 1
            continue
        if c in "([{":
            depth += 1
        elif c in ")]}":
            depth -= 1
        if c == "," and (depth <= 0 or re.match(r"d[a-z](?![A-Za-z])", s[i + 1:])):
            rest = s[i + 1:]
            before = "".join(out).rstrip()
            if rest.strip() and not before.endswith((r"\,", ",")) and not re.match(r"\s*(?:\\quad|\\qquad|\\text)", rest):
                out.append(r"\,")
                i += 1
                continue
        out.append(c)
        i += 1
    return "".join(out)


def normalize_latex(latex: str, lost_backslashes: bool | None = None) -> str:
    """The canonical LaTeX of one equation (see the module's docstring). ``lost_backslashes``: whether the
    source lost its escapes (markdown conversions); None decides from ``latex`` itself."""
    s = latex or ""
    if not s.strip():
        return ""
    if len(s) > MAX_NORMALIZE_CHARS:  # hostile or broken input: blanks only (latex_issues says it is too long)
        return re.sub(r"\s+", " ", s).strip()
    if lost_backslashes is None:
        lost_backslashes = has_lost_backslashes(s)
    s = s.replace("\r", "")
    spaced = len(re.findall(r"\s[_^]\s*\{|\{\s\S\s|\s\(\s", s)) >= 2  # Mathpix: a blank between every token
    s = re.sub(r"(?<!\\)%[^\n]*", "", s)  # comments
    s = re.sub(r"\\(?:label|tag\*?)\s*\{[^{}]*\}", "", s)
    s = _unwrap_mathclose(s)
    s = re.sub(r"\\operatorname\*", r"\\operatorname", s)
    s = re.sub(r"\\(?:mathop|mathrel|mathbin|mathord)\s*(?=\{)", "", s)
    if lost_backslashes:
        s = _restore_lost(s)
    s = _STRAY_STAR.sub("_{", s)
    s = _over_to_frac(s)
    s = _font_declarations(s)
    s = re.sub(r"\\(?:" + "|".join(_SIZE_CMDS) + r")(?![A-Za-z])\s*", " ", s)
    s = re.sub(r"\\(?:[bB]igg?|[bB]igg?[lrm])(?![A-Za-z])\s*", "", s)
    s = re.sub(r"\\(?:d|t)frac(?![A-Za-z])", r"\\frac", s)
    s = re.sub(r"\\(?:lVert|rVert|Vert)(?![A-Za-z])", r"\\|", s)
    s = re.sub(r"\\(?:lvert|rvert|vert)(?![A-Za-z])", "|", s)
    s = re.sub(r"\\(?:" + "|".join(_TEXT_CMDS) + r")(?![A-Za-z])", r"\\text", s)
    s = _map_commands(s, _BOLD_CMDS, lambda name, arg: rf"\mathbf{{{_strip_braces(arg.strip())}}}")
    s = _map_commands(s, _ARG_CMDS, lambda name, arg: rf"\{name}{{{arg.strip()}}}")
    s = re.sub(r"\\mathbf\{\\mathbf\{([^{}]*)\}\}", r"\\mathbf{\1}", s)
    s = re.sub(r"\\(?:mathbf|mathrm|mathcal|mathbb|mathit|mathsf|mathtt|boldsymbol|pmb|text|operatorname)\{\s*\}", "", s)
    s = _unwrap_arrays(s)
    s = normalize_numbers(s)
    s = _unicode(s)
    s = _THIN_SPACES.sub(" ", s)
    s = re.sub(r"\\qquad(?![A-Za-z])", r"\\quad", s)
    s = _mathpix_spacing(s, spaced)
    s = re.sub(r"(?<![\^_A-Za-z}\\])\{(\\math[a-z]+\{[^{}]*\})\}", r"\1", s)
    s = re.sub(r"(?<![\\A-Za-z])\{\}(?=[A-Za-z\\(])", "", s)  # empty groups before an atom
    s = re.sub(r"[ \t]*\n[ \t]*", " ", s)
    s = re.sub(r"\s{2,}", " ", s).strip()
    s = re.sub(r"(?:\s|\\quad|\\,)*[.,;](?:\s|\\quad|\\,)*$", "", s).strip()  # the sentence's punctuation
    s = re.sub(r"(?:\s|\\quad|\\\\)+$", "", s)
    return _strip_braces(s)


# ----- checks -------------------------------------------------------------------------------------------
try:  # every symbol matplotlib's mathtext knows, when it is installed
    from matplotlib._mathtext_data import tex2uni as _TEX2UNI
except Exception:  # pragma: no cover - matplotlib missing or changed
    _TEX2UNI = {}
_KNOWN_CMDS = set(_TEX2UNI) | set(re.findall(r"\\([A-Za-z]+)", " ".join(UNICODE_TO_LATEX.values()))) | {
    "frac", "sqrt", "left", "right", "mathbf", "mathrm", "mathcal", "mathbb", "mathfrak", "mathscr", "mathsf",
    "mathtt", "mathit", "hat", "widehat", "tilde", "widetilde", "bar", "overline", "underline", "vec", "dot",
    "ddot", "text", "operatorname", "begin", "end", "quad", "exp", "log", "ln", "sin", "cos", "tan", "sinh",
    "cosh", "tanh", "min", "max", "arg", "sup", "inf", "lim", "det", "dim", "Pr", "cdot", "sum", "prod", "int",
    "over", "binom", "limits", "prime", "mid", "lVert", "rVert", "lvert", "rvert", "Vert", "vert", "top",
    "intercal", "partial", "overrightarrow", "mathnormal", "not", "breve", "check", "acute", "grave", "ast",
    "star", "dagger", "circ", "hbar", "overbrace", "underbrace", "stackrel", "overset", "underset", "bmod",
    "pmod", "mod", "cfrac", "ldots", "cdots", "dots", "vdots", "ddots", "boldsymbol", "lbrace", "rbrace",
    "lbrack", "rbrack", "backslash", "setminus", "emptyset", "varnothing", "le", "ge", "ne", "gets", "iff",
    "implies", "land", "lor", "lnot", "colon", "vartriangle", "square", "Box", "dotsc", "dotsb", "tfrac",
    "dfrac", "arccos", "arcsin", "arctan", "coth", "sec", "csc", "cot", "gcd", "hom", "ker", "deg", "lg", "liminf",
    "limsup", "injlim", "projlim", "S", "P", "bigl", "bigr", "Bigl", "Bigr", "big", "Big", "mathring", "phantom",
    "hphantom", "vphantom", "smash", "displaystyle", "tag", "label", "nonumber", "notag", "substack", "atop",
    "choose", "bm", "pmb", "textbf", "textit", "textrm", "mbox", "cases", "textstyle", "scriptstyle"}


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


# ----- the builder's finishing pass -------------------------------------------------------------------------
SOURCE_OF_KIND = {"latex": "tex", "markdown": "markdown", "pdf": "pdf", "text": "text"}


def _sentences(text: str) -> list[str]:
    from nerfify_ns.paper.hyperparams import split_sentences

    return split_sentences(text)


def equation_sentence(before: str, after: str, number: str = "") -> str:
    """The sentence an equation belongs to: the text before it back to its sentence's start, the equation
    as ``⟨Eq. n⟩`` (``⟨equation⟩`` unnumbered), and the text after it when it continues the sentence
    (``where ...``, ``with ...``) up to that sentence's end."""
    head = ""
    before = re.sub(r"\s+", " ", before or "").strip()
    if before:
        sents = _sentences(before)
        head = sents[-1] if sents else before
        if re.search(r"[.!?]$", head) and not head.endswith(":"):
            head = ""  # the equation starts a new sentence
    tail = ""
    after = re.sub(r"\s+", " ", after or "").strip()
    if after and re.match(r"[a-z(,;]|where\b|with\b|and\b|in which\b", after):
        sents = _sentences(after)
        tail = sents[0] if sents else after
        if not re.match(r"[a-z(,;]", tail) and head:
            tail = ""
    marker = f"⟨Eq. {number}⟩" if number else "⟨equation⟩"
    return " ".join(p for p in (head, marker, tail) if p).strip()


def annotate_equations(doc) -> None:
    """Give every equation of ``doc`` its source, normalised LaTeX (the original kept in ``latex_raw`` when
    it changed), confidence with its notes, and its sentence (from the paragraphs around it). A reader
    with better knowledge (the PDF's geometry) may overwrite these afterwards."""
    source = SOURCE_OF_KIND.get(doc.kind, doc.kind)
    lost = any(has_lost_backslashes(e.latex) for e in doc.equations)
    paragraphs = sorted(doc.paragraphs(), key=lambda p: p.loc.order)
    orders = [p.loc.order for p in paragraphs]
    import bisect

    for e in doc.equations:
        e.source = e.source or source
        failed = ""
        if e.latex and not e.latex_raw:
            try:
                norm = normalize_latex(e.latex, lost_backslashes=lost)
            except Exception as err:  # noqa: BLE001 - the per-equation boundary: kept as written, said why
                norm = e.latex
                failed = f"not normalised ({type(err).__name__}: {' '.join(str(err).split())[:120]})"
            if norm != e.latex:
                e.latex_raw, e.latex = e.latex, norm
        if failed:
            e.notes = list(e.notes or []) + [failed]
        if e.confidence is None:
            if e.latex:
                e.confidence, notes = source_confidence(e.latex, e.source)
                e.notes = notes + ([failed] if failed else [])
                e.method = e.method or "source"
            else:
                e.confidence, e.method = 0.0, e.method or "none"
                e.notes = ["no LaTeX: only the text layer" if e.text else "empty equation"]
        if not e.sentence and e.loc.order:
            i = bisect.bisect_left(orders, e.loc.order)
            prev = paragraphs[i - 1] if i > 0 and paragraphs[i - 1].section == e.section else None
            nxt = paragraphs[i] if i < len(paragraphs) and paragraphs[i].section == e.section else None
            e.sentence = equation_sentence(prev.text if prev else "", nxt.text if nxt else "", e.number)
