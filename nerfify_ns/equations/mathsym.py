"""Math symbols as data: Unicode -> LaTeX, the TeX font encodings (CMMI, CMSY, CMEX, CMR and their
cousins) for glyphs a PDF gives as raw codes, and the families of math fonts.

Shared by the LaTeX normaliser (Unicode pasted into LaTeX) and the PDF reconstruction (glyphs to tokens).
"""

from __future__ import annotations

import re
import unicodedata
from functools import lru_cache

# ----- Unicode -> LaTeX ---------------------------------------------------------------------------------
GREEK = {
    "α": r"\alpha", "β": r"\beta", "γ": r"\gamma", "δ": r"\delta", "ϵ": r"\epsilon", "ε": r"\varepsilon",
    "ζ": r"\zeta", "η": r"\eta", "θ": r"\theta", "ϑ": r"\vartheta", "ι": r"\iota", "κ": r"\kappa",
    "λ": r"\lambda", "μ": r"\mu", "µ": r"\mu", "ν": r"\nu", "ξ": r"\xi", "π": r"\pi", "ϖ": r"\varpi",
    "ρ": r"\rho", "ϱ": r"\varrho", "σ": r"\sigma", "ς": r"\varsigma", "τ": r"\tau", "υ": r"\upsilon",
    "ϕ": r"\phi", "φ": r"\varphi", "χ": r"\chi", "ψ": r"\psi", "ω": r"\omega",
    "Γ": r"\Gamma", "Δ": r"\Delta", "∆": r"\Delta", "Θ": r"\Theta", "Λ": r"\Lambda", "Ξ": r"\Xi",
    "Π": r"\Pi", "Σ": r"\Sigma", "Υ": r"\Upsilon", "ϒ": r"\Upsilon", "Φ": r"\Phi", "Ψ": r"\Psi",
    "Ω": r"\Omega", "\u2126": r"\Omega",
}

SYMBOLS = {
    "−": "-", "–": "-", "∗": "*", "⋆": r"\star", "·": r"\cdot", "⋅": r"\cdot", "×": r"\times", "÷": r"\div",
    "±": r"\pm", "∓": r"\mp", "⊙": r"\odot", "⊗": r"\otimes", "⊕": r"\oplus", "⊖": r"\ominus", "∘": r"\circ",
    "•": r"\bullet", "∙": r"\bullet", "◦": r"\circ", "⊘": r"\oslash",
    "≤": r"\leq", "≥": r"\geq", "≦": r"\leq", "≧": r"\geq", "≪": r"\ll", "≫": r"\gg", "≠": r"\neq",
    "≈": r"\approx", "≃": r"\simeq", "≅": r"\cong", "≡": r"\equiv", "∼": r"\sim", "∝": r"\propto",
    "≜": r"\triangleq", "≐": r"\doteq", "≔": ":=", "⩽": r"\leq", "⩾": r"\geq",
    "∈": r"\in", "∉": r"\notin", "∋": r"\ni", "⊂": r"\subset", "⊃": r"\supset", "⊆": r"\subseteq",
    "⊇": r"\supseteq", "∪": r"\cup", "∩": r"\cap", "∖": r"\setminus", "∅": r"\emptyset", "∀": r"\forall",
    "∃": r"\exists", "¬": r"\neg", "∧": r"\wedge", "∨": r"\vee",
    "→": r"\to", "←": r"\leftarrow", "↔": r"\leftrightarrow", "⇒": r"\Rightarrow", "⇐": r"\Leftarrow",
    "⇔": r"\Leftrightarrow", "↦": r"\mapsto", "↑": r"\uparrow", "↓": r"\downarrow", "⟶": r"\longrightarrow",
    "∂": r"\partial", "∇": r"\nabla", "∞": r"\infty", "ℓ": r"\ell", "ℜ": r"\Re", "ℑ": r"\Im", "℘": r"\wp",
    "ℵ": r"\aleph", "ı": r"\imath", "ȷ": r"\jmath", "ℏ": r"\hbar", "⊤": r"\top", "⊥": r"\bot",
    "…": r"\ldots", "⋯": r"\cdots", "⋮": r"\vdots", "⋱": r"\ddots",
    "∑": r"\sum", "∏": r"\prod", "∐": r"\coprod", "∫": r"\int", "∬": r"\iint", "∮": r"\oint",
    "⋃": r"\bigcup", "⋂": r"\bigcap", "⨁": r"\bigoplus", "⨂": r"\bigotimes", "⨀": r"\bigodot",
    "√": r"\sqrt", "‖": r"\|", "∥": r"\|", "∣": "|", "⟨": r"\langle", "⟩": r"\rangle", "〈": r"\langle",
    "〉": r"\rangle", "⌊": r"\lfloor", "⌋": r"\rfloor", "⌈": r"\lceil", "⌉": r"\rceil",
    "′": "'", "″": "''", "‴": "'''", "∠": r"\angle", "△": r"\triangle", "°": r"^{\circ}", "⊎": r"\uplus",
    "⊔": r"\sqcup", "⊓": r"\sqcap", "⊢": r"\vdash", "∤": r"\nmid",
    "\u2061": "", "\u2062": "", "\u2063": "", "\u200b": "",
}

UNICODE_TO_LATEX = {**GREEK, **SYMBOLS}

BIG_OPERATORS = {r"\sum", r"\prod", r"\coprod", r"\int", r"\iint", r"\oint", r"\bigcup", r"\bigcap",
                 r"\bigoplus", r"\bigotimes", r"\bigodot"}
RELATIONS = {"=", "<", ">", r"\leq", r"\geq", r"\neq", r"\approx", r"\sim", r"\simeq", r"\equiv", r"\propto",
             r"\in", r"\to", r"\triangleq", r"\doteq", ":=", r"\mapsto", r"\subset", r"\subseteq"}
FUNCTIONS = ("exp", "log", "ln", "sin", "cos", "tan", "sinh", "cosh", "tanh", "arcsin", "arccos", "arctan",
             "min", "max", "arg", "argmin", "argmax", "sup", "inf", "lim", "det", "dim", "Pr", "sgn", "erf")
LATEX_FUNCTIONS = {"exp", "log", "ln", "sin", "cos", "tan", "sinh", "cosh", "tanh", "arcsin", "arccos", "arctan",
                   "min", "max", "arg", "sup", "inf", "lim", "det", "dim", "Pr"}
"""Functions LaTeX has a command for (``\\exp``); the others are written ``\\operatorname{...}``."""
NAMED_OPERATORS = ("softplus", "sigmoid", "ReLU", "relu", "softmax", "tanh", "MLP", "MSE", "sg", "stopgrad",
                   "concat", "diag", "clamp", "clip", "round", "floor", "ceil", "abs", "sign", "norm", "Tr", "tr",
                   "Var", "Cov", "argmin", "argmax", "erf", "sgn")

# ----- TeX font encodings -------------------------------------------------------------------------------
_GREEK_CAPS = ["\\Gamma", "\\Delta", "\\Theta", "\\Lambda", "\\Xi", "\\Pi", "\\Sigma", "\\Upsilon", "\\Phi",
               "\\Psi", "\\Omega"]
CMMI = {i: g for i, g in enumerate(_GREEK_CAPS)}
CMMI.update({0x0B + i: "\\" + n for i, n in enumerate(
    "alpha beta gamma delta epsilon zeta eta theta iota kappa lambda mu nu xi pi rho sigma tau upsilon phi chi "
    "psi omega varepsilon vartheta varpi varrho varsigma varphi".split())})
CMMI.update({0x28: r"\leftharpoonup", 0x29: r"\leftharpoondown", 0x2A: r"\rightharpoonup",
             0x2B: r"\rightharpoondown", 0x2E: r"\triangleright", 0x2F: r"\triangleleft", 0x3A: ".", 0x3B: ",",
             0x3C: "<", 0x3D: "/", 0x3E: ">", 0x3F: r"\star", 0x40: r"\partial", 0x5B: r"\flat", 0x5C: r"\natural",
             0x5D: r"\sharp", 0x5E: r"\smile", 0x5F: r"\frown", 0x60: r"\ell", 0x7B: r"\imath", 0x7C: r"\jmath",
             0x7D: r"\wp", 0x7E: "ACCENT:vec", 0x7F: "ACCENT:tie"})
CMMI.update({0x30 + i: str(i) for i in range(10)})

CMR = {i: g for i, g in enumerate(_GREEK_CAPS)}
CMR.update({0x7B: "-", 0x7C: "-", 0x5E: "ACCENT:hat", 0x7E: "ACCENT:tilde", 0x5F: "ACCENT:dot",
            0x7F: "ACCENT:ddot", 0x16: "ACCENT:bar", 0x15: "ACCENT:breve", 0x14: "ACCENT:check",
            0x12: "ACCENT:grave", 0x13: "ACCENT:acute", 0x22: '"', 0x3C: "<", 0x3E: ">", 0x0B: "ff", 0x0C: "fi",
            0x0D: "fl", 0x0E: "ffi", 0x0F: "ffl", 0x10: r"\imath", 0x11: r"\jmath"})

CMSY = {0x00: "-", 0x01: r"\cdot", 0x02: r"\times", 0x03: "*", 0x04: r"\div", 0x05: r"\diamond", 0x06: r"\pm",
        0x07: r"\mp", 0x08: r"\oplus", 0x09: r"\ominus", 0x0A: r"\otimes", 0x0B: r"\oslash", 0x0C: r"\odot",
        0x0D: r"\bigcirc", 0x0E: r"\circ", 0x0F: r"\bullet", 0x10: r"\asymp", 0x11: r"\equiv", 0x12: r"\subseteq",
        0x13: r"\supseteq", 0x14: r"\leq", 0x15: r"\geq", 0x16: r"\preceq", 0x17: r"\succeq", 0x18: r"\sim",
        0x19: r"\approx", 0x1A: r"\subset", 0x1B: r"\supset", 0x1C: r"\ll", 0x1D: r"\gg", 0x1E: r"\prec",
        0x1F: r"\succ", 0x20: r"\leftarrow", 0x21: r"\to", 0x22: r"\uparrow", 0x23: r"\downarrow",
        0x24: r"\leftrightarrow", 0x25: r"\nearrow", 0x26: r"\searrow", 0x27: r"\simeq", 0x28: r"\Leftarrow",
        0x29: r"\Rightarrow", 0x2A: r"\Uparrow", 0x2B: r"\Downarrow", 0x2C: r"\Leftrightarrow",
        0x2D: r"\nwarrow", 0x2E: r"\swarrow", 0x2F: r"\propto", 0x30: "'", 0x31: r"\infty", 0x32: r"\in",
        0x33: r"\ni", 0x34: r"\triangle", 0x35: r"\triangledown", 0x36: "/", 0x38: r"\forall", 0x39: r"\exists",
        0x3A: r"\neg", 0x3B: r"\emptyset", 0x3C: r"\Re", 0x3D: r"\Im", 0x3E: r"\top", 0x3F: r"\bot",
        0x40: r"\aleph", 0x5B: r"\cup", 0x5C: r"\cap", 0x5D: r"\uplus", 0x5E: r"\wedge", 0x5F: r"\vee",
        0x60: r"\vdash", 0x61: r"\dashv", 0x62: r"\lfloor", 0x63: r"\rfloor", 0x64: r"\lceil", 0x65: r"\rceil",
        0x66: r"\{", 0x67: r"\}", 0x68: r"\langle", 0x69: r"\rangle", 0x6A: "|", 0x6B: r"\|",
        0x6C: r"\updownarrow", 0x6D: r"\Updownarrow", 0x6E: r"\backslash", 0x6F: r"\wr", 0x70: r"\sqrt",
        0x71: r"\amalg", 0x72: r"\nabla", 0x73: r"\int", 0x74: r"\sqcup", 0x75: r"\sqcap", 0x76: r"\sqsubseteq",
        0x77: r"\sqsupseteq", 0x78: r"\S", 0x79: r"\dagger", 0x7A: r"\ddagger", 0x7B: r"\P"}
CMSY.update({0x41 + i: r"\mathcal{" + chr(0x41 + i) + "}" for i in range(26)})

# CMEX: (token, kind) where kind is "open", "close", "op", "radical", "piece:<delim>:<part>", "accent", "middle"
CMEX: dict[int, tuple[str, str]] = {}
CMEX.update({0x00: ("(", "open"), 0x01: (")", "close"), 0x02: ("[", "open"), 0x03: ("]", "close"),
             0x04: (r"\lfloor", "open"), 0x05: (r"\rfloor", "close"), 0x06: (r"\lceil", "open"),
             0x07: (r"\rceil", "close"), 0x08: (r"\{", "open"), 0x09: (r"\}", "close"), 0x0A: (r"\langle", "open"),
             0x0B: (r"\rangle", "close"), 0x0C: ("|", "middle"), 0x0D: (r"\|", "middle"), 0x0E: ("/", "middle"),
             0x0F: (r"\backslash", "middle"), 0x10: ("(", "open"), 0x11: (")", "close"), 0x12: ("(", "open"),
             0x13: (")", "close"), 0x14: ("[", "open"), 0x15: ("]", "close"), 0x16: (r"\lfloor", "open"),
             0x17: (r"\rfloor", "close"), 0x18: (r"\lceil", "open"), 0x19: (r"\rceil", "close"),
             0x1A: (r"\{", "open"), 0x1B: (r"\}", "close"), 0x1C: (r"\langle", "open"), 0x1D: (r"\rangle", "close"),
             0x1E: ("/", "middle"), 0x1F: (r"\backslash", "middle"), 0x20: ("(", "open"), 0x21: (")", "close"),
             0x22: ("[", "open"), 0x23: ("]", "close"), 0x24: (r"\lfloor", "open"), 0x25: (r"\rfloor", "close"),
             0x26: (r"\lceil", "open"), 0x27: (r"\rceil", "close"), 0x28: (r"\{", "open"), 0x29: (r"\}", "close"),
             0x2A: (r"\langle", "open"), 0x2B: (r"\rangle", "close"), 0x2C: ("/", "middle"),
             0x2D: (r"\backslash", "middle"), 0x2E: ("/", "middle"), 0x2F: (r"\backslash", "middle"),
             0x30: ("(", "piece:open:top"), 0x31: (")", "piece:close:top"), 0x32: ("[", "piece:open:top"),
             0x33: ("]", "piece:close:top"), 0x34: ("[", "piece:open:bottom"), 0x35: ("]", "piece:close:bottom"),
             0x36: ("[", "piece:open:ext"), 0x37: ("]", "piece:close:ext"), 0x38: (r"\{", "piece:open:top"),
             0x39: (r"\}", "piece:close:top"), 0x3A: (r"\{", "piece:open:bottom"), 0x3B: (r"\}", "piece:close:bottom"),
             0x3C: (r"\{", "piece:open:mid"), 0x3D: (r"\}", "piece:close:mid"), 0x3E: (r"\{", "piece:any:ext"),
             0x3F: ("|", "piece:middle:ext"), 0x40: ("(", "piece:open:bottom"), 0x41: (")", "piece:close:bottom"),
             0x42: ("(", "piece:open:ext"), 0x43: (")", "piece:close:ext"), 0x44: (r"\langle", "open"),
             0x45: (r"\rangle", "close"), 0x46: (r"\bigsqcup", "op"), 0x47: (r"\bigsqcup", "op"),
             0x48: (r"\oint", "op"), 0x49: (r"\oint", "op"), 0x4A: (r"\bigodot", "op"), 0x4B: (r"\bigodot", "op"),
             0x4C: (r"\bigoplus", "op"), 0x4D: (r"\bigoplus", "op"), 0x4E: (r"\bigotimes", "op"),
             0x4F: (r"\bigotimes", "op"), 0x50: (r"\sum", "op"), 0x51: (r"\prod", "op"), 0x52: (r"\int", "op"),
             0x53: (r"\bigcup", "op"), 0x54: (r"\bigcap", "op"), 0x55: (r"\biguplus", "op"), 0x56: (r"\bigwedge", "op"),
             0x57: (r"\bigvee", "op"), 0x58: (r"\sum", "op"), 0x59: (r"\prod", "op"), 0x5A: (r"\int", "op"),
             0x5B: (r"\bigcup", "op"), 0x5C: (r"\bigcap", "op"), 0x5D: (r"\biguplus", "op"),
             0x5E: (r"\bigwedge", "op"), 0x5F: (r"\bigvee", "op"), 0x60: (r"\coprod", "op"), 0x61: (r"\coprod", "op"),
             0x62: ("hat", "accent"), 0x63: ("hat", "accent"), 0x64: ("hat", "accent"), 0x65: ("tilde", "accent"),
             0x66: ("tilde", "accent"), 0x67: ("tilde", "accent"), 0x68: ("[", "open"), 0x69: ("]", "close"),
             0x6A: (r"\lfloor", "open"), 0x6B: (r"\rfloor", "close"), 0x6C: (r"\lceil", "open"),
             0x6D: (r"\rceil", "close"), 0x6E: (r"\{", "open"), 0x6F: (r"\}", "close"), 0x70: (r"\sqrt", "radical"),
             0x71: (r"\sqrt", "radical"), 0x72: (r"\sqrt", "radical"), 0x73: (r"\sqrt", "radical"),
             0x74: (r"\sqrt", "radical"), 0x75: (r"\sqrt", "piece:radical:ext"), 0x76: (r"\sqrt", "piece:radical:top"),
             0x77: (r"\|", "piece:middle:ext"), 0x78: (r"\uparrow", "piece:middle:top"),
             0x79: (r"\downarrow", "piece:middle:bottom"), 0x7A: ("", "brace"), 0x7B: ("", "brace"),
             0x7C: ("", "brace"), 0x7D: ("", "brace"), 0x7E: (r"\Uparrow", "piece:middle:top"),
             0x7F: (r"\Downarrow", "piece:middle:bottom")})

# Depth of a CMEX glyph below its origin, in ems (the origin is at the glyph's top in CMEX)
def cmex_depth(code: int) -> float:
    """How far a CMEX glyph hangs below its origin (ems): the text layer's boxes are wrong for CMEX."""
    if code <= 0x0F or 0x70 == code:
        return 1.2
    if code in (0x10, 0x11, 0x2E, 0x2F) or 0x68 <= code <= 0x6F or code == 0x71:
        return 1.8
    if 0x12 <= code <= 0x1F or code == 0x72:
        return 2.4
    if 0x20 <= code <= 0x2D or code == 0x73:
        return 3.0
    if 0x30 <= code <= 0x45 or 0x74 <= code <= 0x7F:
        return 0.9
    if code in (0x52, 0x48):
        return 1.11
    if code in (0x5A, 0x49):
        return 2.22
    if 0x46 <= code <= 0x57 or code == 0x60:
        return 1.0
    if 0x58 <= code <= 0x61:
        return 1.4
    return 0.3


# Unicode pieces of tall delimiters (the Symbol font's private-use code points and Unicode's own)
PIECES = {
    "\uf8eb": ("(", "open", "top"), "\uf8ec": ("(", "open", "ext"), "\uf8ed": ("(", "open", "bottom"),
    "\uf8ee": ("[", "open", "top"), "\uf8ef": ("[", "open", "ext"), "\uf8f0": ("[", "open", "bottom"),
    "\uf8f1": (r"\{", "open", "top"), "\uf8f2": (r"\{", "open", "mid"), "\uf8f3": (r"\{", "open", "bottom"),
    "\uf8f4": (r"\{", "any", "ext"), "\uf8f5": (r"\int", "op", "ext"), "\uf8f6": (")", "close", "top"),
    "\uf8f7": (")", "close", "ext"), "\uf8f8": (")", "close", "bottom"), "\uf8f9": ("]", "close", "top"),
    "\uf8fa": ("]", "close", "ext"), "\uf8fb": ("]", "close", "bottom"), "\uf8fc": (r"\}", "close", "top"),
    "\uf8fd": (r"\}", "close", "mid"), "\uf8fe": (r"\}", "close", "bottom"),
    "⎛": ("(", "open", "top"), "⎜": ("(", "open", "ext"), "⎝": ("(", "open", "bottom"),
    "⎞": (")", "close", "top"), "⎟": (")", "close", "ext"), "⎠": (")", "close", "bottom"),
    "⎡": ("[", "open", "top"), "⎢": ("[", "open", "ext"), "⎣": ("[", "open", "bottom"),
    "⎤": ("]", "close", "top"), "⎥": ("]", "close", "ext"), "⎦": ("]", "close", "bottom"),
    "⎧": (r"\{", "open", "top"), "⎨": (r"\{", "open", "mid"), "⎩": (r"\{", "open", "bottom"),
    "⎪": (r"\{", "any", "ext"), "⎫": (r"\}", "close", "top"), "⎬": (r"\}", "close", "mid"),
    "⎭": (r"\}", "close", "bottom"), "⎮": (r"\int", "op", "ext"), "⌠": (r"\int", "op", "top"),
    "⌡": (r"\int", "op", "bottom"), "⎷": (r"\sqrt", "radical", "bottom"),
}

ACCENT_CHARS = {"^": "hat", "ˆ": "hat", "\u0302": "hat", "~": "tilde", "˜": "tilde", "\u0303": "tilde",
                "¯": "bar", "ˉ": "bar", "\u0304": "bar", "˙": "dot", "\u0307": "dot", "¨": "ddot", "\u0308": "ddot",
                "→": "vec", "\u20d7": "vec", "´": "acute", "`": "grave", "˘": "breve", "ˇ": "check"}

OPEN = {"(", "[", r"\{", r"\langle", r"\lfloor", r"\lceil"}
CLOSE = {")", "]", r"\}", r"\rangle", r"\rfloor", r"\rceil"}

# ----- font families ------------------------------------------------------------------------------------
# role: italic (math letters), roman (math upright: digits, operators, function names), symbol, extension,
# blackboard, calligraphic, fraktur, script
_FONT_RULES = [
    (r"^(?:cmex|lmmathextension|txex|pxex|ntxexx|ntxex|newtxex|mtex|euex|stixsize|mathjax_size|esint|"
     r"cmexb|latinmodernmath-ex|stixintegrals|euclidextra)", "extension"),
    (r"^(?:msbm|bbold|dsrom|bbm|txmia?b?b|mathjax_ams.*bb|stixdoublestruck)", "blackboard"),
    (r"^(?:rsfs|eusm|eus[bm]|mathjax_script|stixscript)", "script"),
    (r"^(?:eufm|eufb|mathjax_fraktur|stixfraktur)", "fraktur"),
    (r"^(?:cmsy|cmbsy|lmmathsymbols|txsy|pxsy|ntxsy|newtxsy|mtsy|msam|mathjax_ams|mathjax_caligraphic|"
     r"stixgeneral|stixnonunicode|stixvariants|eusb|euclidsymbol|symbolmt|symbol$|standardsymlpl|"
     r"standardsyml|rpsyr|psyr|cmbsy|wasy|stmary|txsya|pxsya|ntxsya|mnsymbol|fdsymbol|marvosym)", "symbol"),
    (r"^(?:cmmi|cmmib|lmmathitalic|txmi|pxmi|ntxmi|newtxmi|zxmi|zplmi|rtxmi|mtmi|eurm|eurb|mathjax_math|"
     r"cambriamath|cambria-math|latinmodernmath|stixmath|stixtwomath|xitsmath|asanamath|tex[-_]?gyre.*math|"
     r"euclidmath|mathematica|stixtwomath-regular|libertinusmath|firamath|garamondmath|dejavumath)", "italic"),
    (r"^(?:cmr|cmbx|cmss|cmtt|cmti|cmsl|cmu|lmroman|lmsans|lmmono|mathjax_main|mathjax_typewriter|"
     r"mathjax_sansserif|euclid$|cmbxti|cmcsc)", "roman"),
]
_FONT_RE = [(re.compile(p), role) for p, role in _FONT_RULES]


@lru_cache(maxsize=4096)
def font_key(font: str) -> str:
    """The font name without subset tag and separators, lower-cased: ``ABCDEF+CMMI10`` -> ``cmmi10``."""
    font = font.split("+", 1)[-1]
    return re.sub(r"[\s,]+", "", font).lower()


@lru_cache(maxsize=4096)
def font_family(font: str) -> str:
    """The family without design size and weight suffixes: ``CMMI10`` -> ``cmmi``, ``CMR7`` -> ``cmr``."""
    k = font_key(font)
    return re.sub(r"\d+(?:\.\d+)?$", "", k.split("-")[0]) or k


@lru_cache(maxsize=4096)
def font_role(font: str) -> str | None:
    """italic | roman | symbol | extension | blackboard | script | fraktur for a math font, None for a text font."""
    k = font_key(font)
    for rx, role in _FONT_RE:
        if rx.match(k):
            return role
    return None


def is_bold_font(font: str, flags: int = 0) -> bool:
    """Bold math (CMMIB, CMBX, ...-Bold, bold flag)."""
    k = font_key(font)
    return bool(flags & 16) or bool(re.search(r"bold|cmmib|cmbx|cmbsy|mib\d|bx\d|-b$|demi|heavy|black", k))


def is_italic_text_font(font: str, flags: int = 0) -> bool:
    """A text font's italic (``NimbusRomNo9L-ReguItal``, ``Times-Italic``): letters set in math by mathptmx."""
    k = font_key(font)
    return bool(re.search(r"ital|oblique|-it$|-bi$|italic", k)) or bool(flags & 2)


# ----- mathematical alphanumerics (U+1D400..) ------------------------------------------------------------
def math_alnum(ch: str) -> tuple[str, str] | None:
    """("bold-italic", "x") for U+1D499 and friends; ("blackboard", "R") for ℝ; None for other characters."""
    cp = ord(ch)
    if not (0x1D400 <= cp <= 0x1D7FF or ch in "ℝℕℤℚℂℙℍℒℛℬℰℱℋℐℳℊℯℴℎℭℌℑℜℨ"):
        return None
    try:
        name = unicodedata.name(ch)
    except ValueError:
        return None
    base = unicodedata.normalize("NFKC", ch)
    style = "italic"
    if "DOUBLE-STRUCK" in name:
        style = "blackboard"
    elif "FRAKTUR" in name or "BLACK-LETTER" in name:
        style = "fraktur"
    elif "SCRIPT" in name:
        style = "script"
    elif "MONOSPACE" in name:
        style = "mono"
    elif "SANS-SERIF" in name:
        style = "sans-bold" if "BOLD" in name else "sans"
    elif "BOLD ITALIC" in name:
        style = "bold-italic"
    elif "BOLD" in name:
        style = "bold"
    elif "ITALIC" in name or ch == "ℎ":
        style = "italic"
    elif "DIGIT" in name:
        style = "roman"
    return style, base


def to_latex_char(ch: str) -> str | None:
    """The LaTeX of one Unicode character, or None when it has none here (ASCII comes back as itself)."""
    if ch in UNICODE_TO_LATEX:
        return UNICODE_TO_LATEX[ch]
    if ch.isascii():
        return {"{": r"\{", "}": r"\}", "%": r"\%", "#": r"\#", "&": r"\&", "$": r"\$", "_": r"\_",
                "\\": r"\backslash", "~": r"\sim"}.get(ch, ch)
    alnum = math_alnum(ch)
    if alnum:
        style, base = alnum
        tex = UNICODE_TO_LATEX.get(base, base)
        wrap = {"blackboard": r"\mathbb", "fraktur": r"\mathfrak", "script": r"\mathcal", "bold": r"\mathbf",
                "bold-italic": r"\mathbf", "sans": r"\mathsf", "sans-bold": r"\mathbf", "mono": r"\mathtt"}.get(style)
        return f"{wrap}{{{tex}}}" if wrap else tex
    norm = unicodedata.normalize("NFKC", ch)
    if norm != ch and norm and all(c.isascii() or c in UNICODE_TO_LATEX for c in norm):
        return "".join(UNICODE_TO_LATEX.get(c, c) for c in norm)
    return None
