"""The one LaTeX normaliser: how the noise of converted papers is removed before an equation is stored or read.

One table of what converters leave (``STYLE_COMMANDS``, ``SIZE_COMMANDS``, ``BOLD_COMMANDS``,
``FONT_DECLARATIONS``, ``TEXT_COMMANDS``, ``MATH_CLASS_COMMANDS``, ``LOST_SUBSCRIPT``, the row spacing, the
fraction variants) serves its two forms, so a command a converter leaves is taught here once:

``normalize_latex(latex)`` -- the canonical LaTeX of one equation, what a Document stores for .tex, markdown and
PDF equations alike (the original kept in ``latex_raw``):

* bold: ``\\pmb``, ``\\boldsymbol``, ``\\bm``, ``\\bold``, ``{\\bf x}`` -> ``\\mathbf{x}``; ``{\\cal L}`` ->
  ``\\mathcal{L}``, ``{\\rm obj}``/``\\textrm``/``\\mbox`` -> ``\\mathrm``/``\\text``; empty ``\\mathbf{}`` and
  friends dropped;
* markdown's lost escapes: a stray ``*{`` after an atom was ``_{`` (``{\\cal L}*{\\rm reg}``); with evidence of
  lost backslashes in the same text (``!\\big(``, ``!\\left(``): ``!`` -> ``\\!``, top-level ``,`` -> ``\\,``,
  ``[2pt]`` -> ``\\\\``;
* wrappers: a ``\\begin{array}`` around the whole formula or around one cell, LaTeXML's
  ``\\mathopen{}\\mathclose{{\\left( ...}}\\right)``, ``\\displaystyle``, sizes (``\\small``), ``\\big`` sizes,
  ``\\label``/``\\tag``/``\\nonumber``, ``\\limits``;
* spacing: Mathpix's ``L _ { \\mathrm { r e c } }`` -> ``L_{\\mathrm{rec}}``; thin spaces -> a blank; trailing
  sentence punctuation dropped;
* numbers (``normalize_numbers``, below);
* Unicode pasted into LaTeX -> commands (``σ`` -> ``\\sigma``); ``\\lVert``/``\\Vert`` -> ``\\|``;
  ``\\dfrac`` -> ``\\frac``; ``{a \\over b}`` -> ``\\frac{a}{b}``; ``\\operatorname*`` -> ``\\operatorname``.

It never guesses mathematics: anything it does not recognise is left as it is.

``normalize(latex)`` -- the equation reader's form: the pieces (one equation each) of a displayed equation, every
character keeping its column in the original (a reading failure names the column as the paper wrote it, so this
form works on the text as given rather than on ``normalize_latex``'s output):

    $$, \\[ \\], \\displaystyle, \\limits, \\label{..}, \\nonumber      removed
    \\tag{3}                                                       the equation number '3'
    \\pmb, \\boldsymbol, \\bm, \\mathbf, \\vec, {\\bf x}                 dropped (bold is not meaning)
    {\\cal L}, {\\rm x}                                              \\mathcal{L}, \\mathrm{x}
    \\begin{array}{rl} / aligned / align / equation / split        removed; rows split on \\\\ ; & removed
    \\\\[6pt], a lone [2pt] (a lost \\\\), a backslash at a line end  a row break
    \\, \\; \\: \\! \\> ~ \\hspace{..} \\left \\right \\big \\Bigl ...       removed
    \\quad, \\qquad                                                  separate equations (a "where" clause)
    P*{\\mathrm{new}} (a lost _)                                    P_{\\mathrm{new}}
    \\exp!\\big( (a lost \\!)                                         \\exp\\big(
    |x|, \\|x\\|, \\vert, \\Vert                                        \\lvert x \\rvert, \\lVert x \\rVert
    unicode (sigma, odot, minus sign, math italic letters)         LaTeX commands (NFKC)
    trailing . , ; and the comma before \\quad                      removed
    numbers (``read_numbers``): 1 0 ^ { - 2 }, 5 1 2, 0 . 0 0 1    10^{-2}, 512, 0.001
    (MinerU's spaced digits), 8\\,192, 1e-2, 10⁻³, 2¹⁹, 5·10⁻⁴       8192, 0.01, 10^{-3}, 2^{19}, 5\\cdot 10^{-4}
    thousands: 1{,}000, 12{,}345{,}678 (not a decimal comma 0{,}5)    1000, 12345678

``normalize_numbers(text)`` is the same number reading on a plain string: ``normalize_latex`` and the
hyperparameter reader (``paper/hyperparams.py``) call it, so a number is read one way wherever it appears.

Limits (hostile input): the reader's form takes at most ``MAX_CHARS`` characters and ``MAX_DEPTH`` nested
groups, the canonical form normalises at most ``MAX_NORMALIZE_CHARS``; every pattern here is linear in the
length of the text.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

from .mathsym import to_latex_char

MAX_CHARS = 4000
MAX_DEPTH = 32


class NormalizeError(Exception):
    def __init__(self, reason: str, column: int | None = None, fragment: str = ""):
        super().__init__(reason)
        self.reason, self.column, self.fragment = reason, column, fragment


class Mapped:
    """Text whose every character remembers its 0-based column in the original."""

    def __init__(self, text: str, origin: list[int] | None = None):
        self.text = text
        self.origin = list(range(len(text))) if origin is None else origin

    def sub(self, pattern: str | re.Pattern, repl, flags: int = 0) -> Mapped:
        """re.sub keeping origins: a replacement takes the column of the start of its match."""
        rx = re.compile(pattern, flags) if isinstance(pattern, str) else pattern
        out, origin, last = [], [], 0
        for m in rx.finditer(self.text):
            out.append(self.text[last:m.start()])
            origin.extend(self.origin[last:m.start()])
            new = repl(m) if callable(repl) else m.expand(repl)
            out.append(new)
            at = self.origin[m.start()] if m.start() < len(self.origin) else (self.origin[-1] + 1 if self.origin
                                                                                 else 0)
            origin.extend([at] * len(new))
            last = m.end()
        out.append(self.text[last:])
        origin.extend(self.origin[last:])
        return Mapped("".join(out), origin)

    def slice(self, start: int, end: int) -> Mapped:
        return Mapped(self.text[start:end], self.origin[start:end])

    def strip(self) -> Mapped:
        start = len(self.text) - len(self.text.lstrip())
        end = len(self.text.rstrip())
        return self.slice(start, max(start, end))

    def column(self, i: int) -> int:
        """1-based column in the original of position ``i`` of this text."""
        if not self.origin:
            return 1
        return self.origin[min(max(i, 0), len(self.origin) - 1)] + 1


# --- numbers as papers write them ----------------------------------------------------------------------

def _script_chars() -> dict[str, tuple[str, str]]:
    """Unicode superscript and subscript characters -> ('^' or '_', the plain character): ``⁻³`` -> ^, -3."""
    out = {}
    for code in range(0xB0, 0x2C80):
        ch = chr(code)
        kind = unicodedata.decomposition(ch).split(" ", 1)[0]
        if kind in ("<super>", "<sub>") and ch not in "\u00aa\u00ba\u2120\u2122":
            plain = unicodedata.normalize("NFKC", ch).replace("\u2212", "-")
            if len(plain) == 1 and (plain.isalnum() or plain in "+-=()"):
                out[ch] = ("^" if kind == "<super>" else "_", plain)
    return out


_SCRIPTS = _script_chars()
_SCRIPT_RUN = re.compile("[" + re.escape("".join(_SCRIPTS)) + "]+")
_BLANK = r"(?:[ \t\n]|\\[,;:! ]|~|[\u00a0\u2006\u2009\u202f])"
_THIN = r"[\u00a0\u2006\u2009\u202f]"
_SPACED_DIGITS = re.compile(rf"(?<![A-Za-z0-9.\\])\d(?:{_BLANK}*\.{_BLANK}*\d|{_BLANK}+\d|\d)+")
_THOUSANDS = re.compile(rf"(?<![\d.,]){_THIN}*\d{{1,3}}(?:{_THIN}\d{{3}})+(?![\d.,])")
_BRACED_THOUSANDS = re.compile(r"(?<![\d.,])[1-9]\d{0,2}(?:\{\s*,\s*\}\d{3})+(?![\d.,]|\{\s*,)")
"""``1{,}000``, ``10{,}000{,}000``: TeX's braced comma between groups of three digits (a thousands separator);
``0{,}5`` or ``1{,}25`` (a decimal comma) is not matched and is left as it is."""
_E_NOTATION = re.compile(r"(?<![A-Za-z0-9.\\_^])(\d+(?:\.\d+)?)(?:[eE]([-+]?)|\s*[eE]\s*([-+]))\s*(\d{1,4})"
                         r"(?![A-Za-z0-9.])")
MAX_DECIMAL_EXPONENT = 30
"""``1e-40`` is written ``{1 \\times 10^{-40}}`` rather than as a decimal of 40 digits."""


def _scripts(m: Mapped) -> Mapped:
    """Runs of Unicode superscripts/subscripts -> ``^{...}``/``_{...}`` (``10⁻³`` -> ``10^{-3}``, ``xᵢ`` ->
    ``x_{i}``); the minus sign U+2212 -> ``-``."""
    def run(match: re.Match) -> str:
        out, kind_open = [], None
        for ch in match.group(0):
            kind, plain = _SCRIPTS[ch]
            if kind != kind_open:
                if kind_open is not None:
                    out.append("}")
                out.append(kind + "{")
                kind_open = kind
            out.append(plain)
        return "".join(out) + "}"

    return m.sub(_SCRIPT_RUN, run).sub("\u2212", "-")


def _spaced_digits(m: Mapped) -> Mapped:
    """MinerU's digits written one token at a time (``1 0``, ``5 1 2``, ``0 . 0 0 1``) and thin-space thousands
    (``8\\,192``) -> one number. A digit that is a one-character script (``x^2 3``) or ``\\frac``'s
    argument (``\\frac 1 2``) stays apart: TeX takes one character there."""
    text = m.text

    def join(match: re.Match) -> str:
        run = match.group(0)
        if re.search(r"(?:[_^]|\\[dtc]?frac|\\sqrt)\s*$", text[max(0, match.start() - 12):match.start()]):
            return run
        return re.sub(_BLANK, "", run)

    return m.sub(_SPACED_DIGITS, join)


def _e_notation(m: Mapped) -> Mapped:
    """``1e-2``, ``5E-4``, ``1 e - 3`` (MinerU) -> ``0.01``, ``0.0005``, ``0.001``; a larger exponent ->
    ``{1 \\times 10^{-40}}`` (the reader folds it, refusing what overflows)."""
    from decimal import Decimal

    def number(match: re.Match) -> str:
        mantissa, sign, digits = match.group(1), match.group(2) or match.group(3) or "", match.group(4)
        exponent = int(sign + digits) if sign != "+" else int(digits)
        if abs(exponent) > MAX_DECIMAL_EXPONENT:
            return f"{{{mantissa} \\times 10^{{{exponent}}}}}"
        text = format(Decimal(mantissa).scaleb(exponent), "f")
        return text.rstrip("0").rstrip(".") if "." in text else text

    return m.sub(_E_NOTATION, number)


def read_numbers(m: Mapped, *, math: bool = True) -> Mapped:
    """Numbers in every notation papers use, as plain LaTeX numbers (the module docstring's table). ``math``:
    the text is mathematics (a formula, ``$...$``), where any blank between digits is a converter's; in prose
    only thin spaces (and no-break spaces) between groups of three digits join them."""
    m = _scripts(m).sub(_BRACED_THOUSANDS, lambda x: re.sub(r"\{\s*,\s*\}", "", x.group(0)))
    if not math:
        return m.sub(_THOUSANDS, lambda x: re.sub(_THIN, "", x.group(0)))
    return _e_notation(_spaced_digits(m))


_PROSE_WORK = re.compile("[" + re.escape("".join(_SCRIPTS)) + "\u2212]|" + _THOUSANDS.pattern + "|"
                         + _BRACED_THOUSANDS.pattern)


def normalize_numbers(text: str, *, math: bool = True) -> str:
    """``read_numbers`` on a plain string (``1 \\times 1 0 ^ { - 2 }`` -> ``1 \\times 10 ^ { - 2 }``); a text
    with nothing to change is returned as it is (one scan)."""
    if not (_PROSE_WORK.search(text) or (math and (_SPACED_DIGITS.search(text) or _E_NOTATION.search(text)))):
        return text
    return read_numbers(Mapped(text), math=math).text


# --- what converters leave: one table for both forms ----------------------------------------------------------

STYLE_COMMANDS = ("displaystyle", "textstyle", "scriptstyle", "scriptscriptstyle", "limits", "nolimits",
                  "nonumber", "notag")
"""Math styles and numbering switches: how an equation is set, never what it says (removed)."""
SIZE_COMMANDS = ("tiny", "scriptsize", "footnotesize", "small", "normalsize", "large", "Large", "LARGE", "huge",
                 "Huge", "allowbreak", "nobreak", "centering", "medmuskip", "relax")
"""Font sizes and layout switches converters leave inside math (removed)."""
BOLD_COMMANDS = ("pmb", "boldsymbol", "bm", "bold", "mathbold", "mathbfit", "bmath", "textbf", "mathbf")
"""Every spelling of bold: ``\\mathbf`` in the canonical form, dropped by the reader (bold is not meaning)."""
FONT_DECLARATIONS = {"bf": r"\mathbf", "bm": r"\mathbf", "boldmath": r"\mathbf", "cal": r"\mathcal",
                     "rm": r"\mathrm", "it": r"\mathit", "sf": r"\mathsf", "tt": r"\mathtt", "mit": r"\mathit"}
"""Old-style font declarations (``{\\cal L}``) and the command each means."""
TEXT_COMMANDS = ("textrm", "textnormal", "mbox", "textup", "textit", "textsf", "texttt", "hbox")
"""Text in math: ``\\text``."""
MATH_CLASS_COMMANDS = ("mathop", "mathrel", "mathbin", "mathord")
"""Math-class wrappers: spacing only (removed, their argument kept)."""
FRACTION_VARIANTS = ("dfrac", "tfrac", "cfrac")
"""Sized fractions: ``\\frac``."""
LOST_SUBSCRIPT = re.compile(r"(?<=[A-Za-z0-9})\]])\*\s*\{")
"""Markdown's lost ``_``: ``P*{\\mathrm{new}}``, ``{\\cal L}*{\\rm reg}`` were ``P_{...}``, ``{\\cal L}_{...}``."""
ROW_SPACING = r"\[\s*-?[0-9.]+\s*(?:pt|em|ex|mm|cm)\s*\]"
"""``[2pt]``: the spacing argument of a row break whose ``\\\\`` markdown lost."""
_FRACTION_VARIANT = re.compile(r"\\(?:" + "|".join(FRACTION_VARIANTS) + r")(?![A-Za-z])")
_LABEL_OR_TAG = re.compile(r"\\(?:label|tag\*?)\s*\{[^{}]*\}")

# --- the canonical form ---------------------------------------------------------------------------------------
_ARG_CMDS = ("mathbf", "mathrm", "mathcal", "mathbb", "mathfrak", "mathscr", "mathsf", "mathtt", "mathit",
             "hat", "widehat", "tilde", "widetilde", "bar", "overline", "vec", "dot", "ddot", "text",
             "operatorname", "underline", "breve", "check", "acute", "grave")
_THIN_SPACES = re.compile(r"(?<!\\)\\(?:,|;|:|!|>|\s)|\\(?:thinspace|medspace|thickspace|negthinspace)\b|(?<!\\)~")
_LOST_EVIDENCE = re.compile(r"(?:^|[\s})\w])!\\(?:left|big|Big|bigg|Bigg)\b|(?<![\\\s^_])\*\{|\\(?:exp|log)!")
MAX_NORMALIZE_CHARS = 20_000
"""Longer formulas are not normalised (every step here is linear, a few are repeated per nesting level)."""


def read_group(s: str, i: int) -> tuple[str | None, int]:
    """The content of the balanced ``{...}`` starting at ``i`` (blanks skipped) and the index after it;
    (None, i) when no group starts there."""
    j = i
    while j < len(s) and s[j] in " \t\n":
        j += 1
    if j >= len(s) or s[j] != "{":
        return None, i
    close = _group_close(s, j + 1)
    return (s[j + 1:close], close + 1) if close < len(s) else (None, i)


def _group_close(s: str, k: int) -> int:
    """The index of the ``}`` that closes the group ``s[k:]`` stands in (escaped braces skipped); ``len(s)`` when
    the group never closes."""
    depth = 0
    while k < len(s):
        c = s[k]
        if c == "\\":
            k += 2
            continue
        if c == "{":
            depth += 1
        elif c == "}":
            if depth == 0:
                return k
            depth -= 1
        k += 1
    return len(s)


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
    """``{\\cal L}`` -> ``\\mathcal{L}``, ``^{\\rm obj}`` -> ``^{\\mathrm{obj}}`` (scope: to the group's end);
    a declaration given a group is a command of that group (``\\bm{c}``, ``\\rm{d}x`` -> ``\\mathbf{c}``,
    ``\\mathrm{d}x``)."""
    rx = re.compile(r"\\(" + "|".join(FONT_DECLARATIONS) + r")(?![A-Za-z])\s*")
    for _ in range(50):
        m = rx.search(s)
        if not m:
            break
        cmd = FONT_DECLARATIONS[m.group(1)]
        group, after = read_group(s, m.end())
        if group is not None:
            s = s[:m.start()] + f"{cmd}{{{group}}}" + s[after:]
            continue
        # the declaration's scope ends at the close of the enclosing group (or the string's end)
        k = _group_close(s, m.end())
        body = s[m.end():k].strip()
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


def _unicode_commands(s: str) -> str:
    """Unicode pasted into LaTeX -> commands (``σ`` -> ``\\sigma``); what has no command stays."""
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
    s = re.sub(r"(?<!\\)(?<!\\\\)" + ROW_SPACING, r" \\\\ ", s)
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
            spaced_already = before.endswith((r"\,", ",")) or re.match(r"\s*(?:\\quad|\\qquad|\\text)", rest)
            if rest.strip() and not spaced_already:
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
    s = _LABEL_OR_TAG.sub("", s)
    s = _unwrap_mathclose(s)
    s = re.sub(r"\\operatorname\*", r"\\operatorname", s)
    s = re.sub(r"\\(?:" + "|".join(MATH_CLASS_COMMANDS) + r")\s*(?=\{)", "", s)
    if lost_backslashes:
        s = _restore_lost(s)
    s = LOST_SUBSCRIPT.sub("_{", s)
    s = _over_to_frac(s)
    s = _font_declarations(s)
    s = re.sub(r"\\(?:" + "|".join(STYLE_COMMANDS + SIZE_COMMANDS) + r")(?![A-Za-z])\s*", " ", s)
    s = re.sub(r"\\(?:[bB]igg?|[bB]igg?[lrm])(?![A-Za-z])\s*", "", s)
    s = _FRACTION_VARIANT.sub(r"\\frac", s)
    s = re.sub(r"\\(?:lVert|rVert|Vert)(?![A-Za-z])", r"\\|", s)
    s = re.sub(r"\\(?:lvert|rvert|vert)(?![A-Za-z])", "|", s)
    s = re.sub(r"\\(?:" + "|".join(TEXT_COMMANDS) + r")(?![A-Za-z])", r"\\text", s)
    s = _map_commands(s, BOLD_COMMANDS, lambda name, arg: rf"\mathbf{{{_strip_braces(arg.strip())}}}")
    s = _map_commands(s, _ARG_CMDS, lambda name, arg: rf"\{name}{{{arg.strip()}}}")
    s = re.sub(r"\\mathbf\{\\mathbf\{([^{}]*)\}\}", r"\\mathbf{\1}", s)
    s = re.sub(r"\\(?:mathbf|mathrm|mathcal|mathbb|mathit|mathsf|mathtt|boldsymbol|pmb|text|operatorname)\{\s*\}", "",
               s)
    s = _unwrap_arrays(s)
    s = normalize_numbers(s)
    s = _unicode_commands(s)
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


# --- the reader's form ---------------------------------------------------------------------------------------

_READER_DROPPED = re.compile(r"\\(?:" + "|".join(STYLE_COMMANDS + SIZE_COMMANDS + MATH_CLASS_COMMANDS)
                             + r"|mathopen\s*\{\s*\}|mathclose\s*\{\s*\})(?![A-Za-z])")
_READER_FONT_DECLARATION = re.compile(r"\{\s*\\(" + "|".join(FONT_DECLARATIONS) + r"|mathcal|mathrm)\s+([^{}]*)\}")
_READER_UNBOLD = re.compile(r"\\(?:" + "|".join(BOLD_COMMANDS + ("bf", "boldmath", "vec", "mathit", "mathnormal"))
                            + r")(?![A-Za-z])")
"""The reader drops bold, arrows and italics: ``\\mathbf{x}`` and ``x`` name the same symbol."""


@dataclass
class Normalized:
    pieces: list[Mapped]
    number: str | None


_GREEK = {
    "alpha", "beta", "gamma", "delta", "epsilon", "varepsilon", "zeta", "eta", "theta", "vartheta", "iota",
    "kappa", "lambda", "mu", "nu", "xi", "pi", "rho", "varrho", "sigma", "varsigma", "tau", "upsilon", "phi",
    "varphi", "chi", "psi", "omega", "Gamma", "Delta", "Theta", "Lambda", "Xi", "Pi", "Sigma", "Upsilon",
    "Phi", "Psi", "Omega",
}

_UNICODE = {
    "\u2212": "-", "\u00b7": r"\cdot ", "\u22c5": r"\cdot ", "\u00d7": r"\times ", "\u2299": r"\odot ",
    "\u2297": r"\otimes ", "\u2218": r"\circ ", "\u2211": r"\sum ", "\u220f": r"\prod ", "\u222b": r"\int ",
    "\u2264": r"\le ", "\u2265": r"\ge ", "\u2260": r"\ne ", "\u2208": r"\in ", "\u223c": r"\sim ",
    "\u2248": r"\approx ", "\u2225": r"\| ", "\u2016": r"\| ", "\u2032": "'", "\u221e": r"\infty ",
    "\u2202": r"\partial ", "\u2207": r"\nabla ", "\u2192": r"\to ", "\u22a4": r"\top ", "\u2026": r"\ldots ",
    "\u22ef": r"\cdots ", "\u225c": r"\triangleq ", "\u2250": r"\doteq ", "\u2217": "*", "\u2206": r"\Delta ",
    "\u2254": ":=", "\u2308": r"\lceil ", "\u2309": r"\rceil ", "\u230a": r"\lfloor ", "\u230b": r"\rfloor ",
    "\u221a": r"\sqrt ", "\U0001d53c": r"\mathbb{E}", "\u2013": "-", "\u2014": "-", "\u00a0": " ",
    "\u2009": " ", "\u200a": " ", "\u2002": " ", "\u2003": " ", "\u27e8": "(", "\u27e9": ")",
    "\u00b5": r"\mu ", "\u2061": " ", "\u2062": " ", "\u2063": ",",
}

_KEEP_ENVS = ("cases", "pmatrix", "bmatrix", "matrix")
_DROP_ENVS = ("equation", "equation*", "align", "align*", "aligned", "split", "gather", "gather*", "gathered",
              "eqnarray", "eqnarray*", "multline", "multline*", "array", "alignat", "alignat*", "alignedat",
              "displaymath", "math")


def _unicode(m: Mapped) -> Mapped:
    out, origin = [], []
    for i, ch in zip(m.origin, m.text, strict=False):
        if ch in _UNICODE:
            new = _UNICODE[ch]
        elif ch in "\n\r\t\f\v":
            new = "\n" if ch in "\n\r" else " "
        elif ord(ch) < 128:
            new = ch if ch.isprintable() else " "
        else:
            new = unicodedata.normalize("NFKC", ch)
            mapped = []
            for c in new:
                if c in _UNICODE:
                    mapped.append(_UNICODE[c])
                    continue
                name = unicodedata.name(c, "")
                if name.startswith("GREEK ") and " LETTER " in name:
                    word = name.split(" LETTER ")[-1].split()[0].lower()
                    word = {"lamda": "lambda", "final": "varsigma"}.get(word, word)
                    if "CAPITAL" in name:
                        word = word.capitalize()
                    if word in _GREEK:
                        mapped.append("\\" + word + " ")
                        continue
                if unicodedata.category(c).startswith(("Z", "C")):
                    mapped.append(" ")
                    continue
                mapped.append(c)
            new = "".join(mapped)
        out.append(new)
        origin.extend([i] * len(new))
    return Mapped("".join(out), origin)


def _drop_group_command(m: Mapped, names: str) -> Mapped:
    """Remove ``\\name{...}`` with its (brace-balanced, one level of nesting) argument."""
    return m.sub(r"\\(?:" + names + r")\*?\s*\{(?:[^{}]|\{[^{}]*\})*\}", " ")


def _bars(m: Mapped) -> Mapped:
    """Decide which bars open and which close: |x| -> \\lvert x \\rvert, \\|x\\| -> \\lVert x \\rVert."""
    rx = re.compile(r"\\lVert|\\rVert|\\lvert|\\rvert|\\Vert|\\vert|\\\||\|")
    out, origin, last, stack = [], [], 0, []
    text = m.text
    previous = ""  # the last non-space character written
    depth = 0  # brackets around the current position: a bar closes only the bar opened at its own depth
    for match in rx.finditer(text):
        if match.start() > 0 and text[match.start() - 1] == "\\" and match.group() == "|":
            continue  # the second character of \|, handled with it
        chunk = text[last:match.start()]
        out.append(chunk)
        origin.extend(m.origin[last:match.start()])
        if chunk.strip():
            previous = chunk.rstrip()[-1]
            if re.search(r"\\begin\s*\{[A-Za-z*]*\}\s*$", chunk):
                previous = "{"  # \begin{cases}| opens
        depth += sum(chunk.count(c) for c in "{([") - sum(chunk.count(c) for c in "})]")
        tok = match.group()
        kind = "norm" if tok in (r"\lVert", r"\rVert", r"\Vert", r"\|") else "abs"
        if tok in (r"\lVert", r"\lvert"):
            side = "l"
        elif tok in (r"\rVert", r"\rvert"):
            side = "r"
        else:
            operand_end = bool(previous) and (previous.isalnum() or previous in ")]}'")
            side = "r" if (stack and stack[-1] == (kind, depth) and operand_end) else "l"
        if side == "l":
            stack.append((kind, depth))
        elif stack and stack[-1][0] == kind:
            stack.pop()
        new = {("norm", "l"): r"\lVert ", ("norm", "r"): r"\rVert ", ("abs", "l"): r"\lvert ",
               ("abs", "r"): r"\rvert "}[kind, side]
        out.append(new)
        origin.extend([m.origin[match.start()]] * len(new))
        previous = "t" if side == "r" else "{"  # a closed bar ends an operand; an opened one does not
        last = match.end()
    out.append(text[last:])
    origin.extend(m.origin[last:])
    return Mapped("".join(out), origin)


_OPEN = re.compile(r"[{(\[]|\\l[Vv]ert|\\lceil|\\lfloor|\\begin(?![A-Za-z])")
_CLOSE = re.compile(r"[})\]]|\\r[Vv]ert|\\rceil|\\rfloor|\\end(?![A-Za-z])")
_BIG = re.compile(r"\\(?:sum|prod|o?int)(?![A-Za-z])|\\mathbb\{E\}")
MAX_BIG_OPERATORS = 16


def check_depth(m: Mapped, limit: int = MAX_DEPTH) -> None:
    """At most ``limit`` nested groups (braces, parentheses, brackets, bars, environments) and at most
    ``MAX_BIG_OPERATORS`` sums, products, integrals and expectations (each nests what follows it)."""
    for count, match in enumerate(_BIG.finditer(m.text), start=1):
        if count > MAX_BIG_OPERATORS:
            raise NormalizeError(f"more than {MAX_BIG_OPERATORS} sums, products or integrals",
                                 m.column(match.start()), match.group())
    depth, i, text = 0, 0, m.text
    while i < len(text):
        opened = _OPEN.match(text, i)
        if opened:
            depth += 1
            if depth > limit:
                raise NormalizeError(f"nested deeper than {limit} groups", m.column(i), opened.group())
            i = opened.end()
            continue
        closed = _CLOSE.match(text, i)
        if closed:
            depth = max(0, depth - 1)
            i = closed.end()
            continue
        i += 1


def size_refusal(latex: str) -> str | None:
    """Why ``normalize`` refuses ``latex`` for its size alone (longer than ``MAX_CHARS``, nested deeper than
    ``MAX_DEPTH``, more than ``MAX_BIG_OPERATORS``), None when its size is fine. Linear and cheap: whoever
    handles an equation before or beside the reader (drawing it, comparing it) skips what the reader refuses
    as too large."""
    if len(latex) > MAX_CHARS:
        return f"longer than {MAX_CHARS} characters ({len(latex)})"
    try:
        check_depth(Mapped(latex))
    except NormalizeError as err:
        return err.reason
    return None


def _environments(m: Mapped) -> Mapped:
    def env(match: re.Match) -> str:
        name = match.group(2)
        if name in _KEEP_ENVS:
            return match.group(0)
        if name in _DROP_ENVS:
            return " "
        raise NormalizeError(f"environment '{name}' is not read", None, match.group(0))

    m = m.sub(r"\\begin\s*\{(?:array|alignat\*?|alignedat|tabular)\}\s*\{[^{}]*\}", " ")
    try:
        return m.sub(r"\\(begin|end)\s*\{([A-Za-z*]+)\}", env)
    except NormalizeError as err:
        at = m.text.find(err.fragment)
        raise NormalizeError(err.reason, m.column(at), err.fragment) from None


def _split_top(m: Mapped) -> list[Mapped]:
    """Rows (\\\\) and \\quad-separated pieces at the top level (outside braces, cases and matrices)."""
    pieces, depth, env, start, i, text = [], 0, 0, 0, 0, m.text
    while i < len(text):
        if text.startswith(r"\begin", i):
            env += 1
        elif text.startswith(r"\end", i):
            env = max(0, env - 1)
        ch = text[i]
        if ch == "{":
            depth += 1
        elif ch == "}":
            depth = max(0, depth - 1)
        elif depth == 0 and env == 0:
            for sep, kind in ((r"\\", "row"), (r"\qquad", "quad"), (r"\quad", "quad")):
                if text.startswith(sep, i) and not (kind == "quad" and text[i + len(sep):i + len(sep) + 1]
                                                    .isalpha()):
                    pieces.append((m.slice(start, i), kind))
                    start = i + len(sep)
                    i = start - 1
                    break
        i += 1
    pieces.append((m.slice(start, len(text)), "end"))
    # a row that begins with a relation continues the equation of the row before it (aligned =)
    joined: list[Mapped] = []
    previous_kind = "quad"
    for piece, kind in pieces:
        piece = _unwrap_row(piece.sub(r"&", " ").strip())
        piece = _strip_punctuation(piece)
        if not piece.text:
            previous_kind = kind
            continue
        if joined and previous_kind == "row" and re.match(r"(=|\\approx|:=|\\le|\\ge|<|>)", piece.text):
            last = joined.pop()
            joined.append(Mapped(last.text + " " + piece.text, last.origin + [piece.origin[0]] + piece.origin))
        else:
            joined.append(piece)
        previous_kind = kind
    return [chunk for piece in joined for chunk in _top_level_commas(piece)]


def _unwrap_row(m: Mapped) -> Mapped:
    """A row that is one brace group around an equation (``&{\\mathcal{L} = ...}``, the aligned rows some LaTeX
    converters write): the group's content, a leading ``\\quad`` dropped."""
    for _ in range(4):
        content, end = read_group(m.text, 0) if m.text.startswith("{") else (None, 0)
        if content is None or end != len(m.text) or not _RELATION.search(content):
            break
        m = m.slice(1, end - 1).sub(r"^\s*\\q?quad(?![A-Za-z])", " ").strip()
    return m


_RELATION = re.compile(r"(?<![<>\\])=|:=|\\(?:approx|coloneqq|triangleq|doteq|equiv)(?![A-Za-z])")


def _top_level_commas(m: Mapped) -> list[Mapped]:
    """Commas outside every bracket: separators between equations when the chunks are equations
    (``a = b, c = d``), otherwise lost thin spaces (``T(t),\\sigma(t),\\mathbf{c}(t),dt``)."""
    cuts, depth, env, text = [], 0, 0, m.text
    for i, ch in enumerate(text):
        if text.startswith(r"\begin", i):
            env += 1
        elif text.startswith(r"\end", i):
            env = max(0, env - 1)
        if ch in "{([" or text.startswith((r"\lVert", r"\lvert", r"\lceil", r"\lfloor"), i):
            depth += 1
        elif ch in "})]" or text.startswith((r"\rVert", r"\rvert", r"\rceil", r"\rfloor"), i):
            depth = max(0, depth - 1)
        elif ch == "," and depth == 0 and env == 0:
            cuts.append(i)
    if not cuts:
        return [m]
    bounds = [-1, *cuts, len(text)]
    chunks = [m.slice(a + 1, b).strip() for a, b in zip(bounds, bounds[1:], strict=False)]
    if sum(1 for c in chunks if _RELATION.search(c.text)) >= 2:
        return [c for c in chunks if c.text]
    out, origin, last = [], [], 0
    for cut in cuts:
        out.append(text[last:cut] + " ")
        origin.extend(m.origin[last:cut + 1])
        last = cut + 1
    out.append(text[last:])
    origin.extend(m.origin[last:])
    return [Mapped("".join(out), origin)]


_CONNECTIVE = re.compile(r"\s*(?:\\(?:text|mathrm|textrm|mbox)\s*\{\s*(?:with|where|and|for|s\.t\.|since)\s*\}"
                         r"|(?:with|where|and)(?![A-Za-z]))\s*")


def _strip_punctuation(m: Mapped) -> Mapped:
    m = m.strip()
    lead = _CONNECTIVE.match(m.text)
    if lead:  # "\\ \text{with} T_k = ...": a connective word before an equation
        m = m.slice(lead.end(), len(m.text)).strip()
    while m.text and m.text[-1] in ".,;:":
        if m.text.endswith(":="):
            break
        m = m.slice(0, len(m.text) - 1).strip()
    return m


def _protect_cases_ampersands(m: Mapped) -> Mapped:
    """& inside cases/matrices is kept (as \\amp); elsewhere the row splitter drops it."""
    out, origin, depth, i, text = [], [], 0, 0, m.text
    while i < len(text):
        if text.startswith(r"\begin", i):
            depth += 1
        elif text.startswith(r"\end", i):
            depth = max(0, depth - 1)
        if text[i] == "&" and depth > 0:
            out.append(r"\amp ")
            origin.extend([m.origin[i]] * 5)
        else:
            out.append(text[i])
            origin.append(m.origin[i])
        i += 1
    return Mapped("".join(out), origin)


def normalize(latex: str) -> Normalized:
    """The pieces (one equation each) of a displayed equation, cleaned; raises NormalizeError."""
    if len(latex) > MAX_CHARS:
        raise NormalizeError(f"longer than {MAX_CHARS} characters ({len(latex)})", MAX_CHARS + 1)
    m = _unicode(_scripts(Mapped(latex)))
    m = m.sub(r"(?<!\\)%[^\n]*", " ")
    m = m.sub(r"\\\\\s*\[[^\]\n]{0,12}\]", r"\\\\ ")  # \\[6pt]
    m = m.sub(r"(?<!\\)" + ROW_SPACING, r"\\\\ ")  # a lost \\ of \\[2pt]
    m = m.sub(r"(?<!\\)\\[ \t]*\n", r"\\\\ ")  # a backslash ending a line: a lost \\
    m = read_numbers(m.sub(r"\s+", " "))
    number = None
    tag = re.search(r"\\tag\*?\s*\{([^{}]{0,40})\}", m.text)
    if tag:
        number = tag.group(1).strip()
    m = _drop_group_command(m, "tag|label|hspace|vspace|phantom|hphantom|vphantom|mspace")
    m = m.sub(_READER_DROPPED, " ")
    m = m.sub(r"\$+|\\\[|\\\]|\\\(|\\\)", " ")
    m = _environments(m)
    m = m.sub(r"\\(?:left|right|middle)\s*\.", " ")
    m = m.sub(r"\\(?:left|right|middle|[bB]igg?[lrm]?)(?![A-Za-z])", " ")
    m = m.sub(r"\\(?:qquad|quad)(?![A-Za-z])", r" \\quad ")
    m = m.sub(r"(?<!\\)\\[,;:!> ]|~|\\(?:kern|mkern|mskip|hskip)\s*-?[0-9.]+\s*(?:pt|em|mu|ex)?", " ")
    m = m.sub(_READER_FONT_DECLARATION,
              lambda x: FONT_DECLARATIONS.get(x.group(1), "\\" + x.group(1)) + "{" + x.group(2) + "}")
    m = m.sub(_READER_UNBOLD, " ")
    m = m.sub(_FRACTION_VARIANT, r"\\frac")
    m = m.sub(r"\\frac\s*([0-9])\s*([0-9])", r"\\frac{\1}{\2}")  # \frac12
    m = m.sub(r"\\operatorname\*", r"\\operatorname")
    m = m.sub(r"\\mathbb\s*E(?![A-Za-z])|\\mathbb\s*\{\s*E\s*\}", r"\\mathbb{E}")
    m = m.sub(LOST_SUBSCRIPT, "_{")  # P*{\mathrm{new}}: a lost _
    m = m.sub(r"(?<=[A-Za-z})\]])(\s*)!(?=\s*[\\({\[])", r"\1 ")  # \exp!\big(: a lost \!
    if r"\int" in m.text:  # \sigma(s),ds: the lost thin space before an integral's differential
        m = m.sub(r",(?=\s*d\s*[A-Za-z](?![A-Za-z]))", " ")
    m = m.sub(r"\.\.\.|\\dots[bcmio]?(?![A-Za-z])", r"\\ldots ")
    m = m.sub(r"([_^])\s*(?:\{\s*\\(max|min)\s*\}|\\(max|min)(?![A-Za-z]))",
              lambda x: x.group(1) + r"{\mathrm{" + (x.group(2) or x.group(3)) + "}}")  # \ell_{\max}: a label
    m = m.sub(r"[.,;]\s*(?=\\end\s*\{|\\\\)", " ")  # a row's or environment's trailing punctuation
    m = _bars(m)
    check_depth(m)
    m = _protect_cases_ampersands(m)
    pieces = _split_top(m)
    return Normalized([p.sub(r"\\quad", " ") for p in pieces], number)
