"""Hyperparameter extraction from sentences. The name patterns of generic hyperparameters live in
``hyperparams.yaml``; those a technique introduces live in its knowledge card (``hyperparameter_patterns``)."""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Iterable
from functools import cache
from pathlib import Path

import yaml

from nerfify_ns.equations.normalize import normalize_numbers
from nerfify_ns.paper.document import Hyperparameter, Location
from nerfify_ns.sentence_split import split_sentences

Value = int | float | list
PATTERNS_FILE = Path(__file__).with_name("hyperparams.yaml")

# ----- numbers ----------------------------------------------------------------------------------------
_SCI = r"\d+(?:\.\d+)?\s*(?:×|\*|·|x(?=\s*10))\s*10\s*\^?\s*[-−–]?\s*\d+"
_POW = r"(?:2|10)\s*\^\s*[-−–]?\s*\d+"
_UPOW = r"10\s*−\s*\d+"  # "10−7": a flattened superscript with a true minus sign
_E = r"\d+(?:\.\d+)?[eE][-−+]?\d+"
_PLAIN = r"(?:\d{1,3}(?:,\d{3})+(?!\d)|\d+(?:\.\d+)?|\.\d+)(?:[kKM](?![A-Za-z]))?"
_VAL = rf"(?:{_SCI}|{_E}|{_POW}|{_UPOW}|{_PLAIN})"
NUMBER = rf"(?<![\w.^/])(?P<num>[-−]?{_VAL}(?:\s*[–—]\s*{_VAL}|-(?=\d){_VAL})?)(?![\d])(?![-]?D\b)"
"""A number in any notation; never the count of a dimension ("3D Gaussians", "4-D"), which names a thing."""
INTEGER = r"(?P<num>\d+)(?![\d.])"

_INLINE_MATH = re.compile(r"\$([^$]{1,400})\$")
_GREEK = {"lambda": "λ", "beta": "β", "epsilon": "ϵ", "varepsilon": "ε", "gamma": "γ", "sigma": "σ",
          "alpha": "α", "delta": "δ", "theta": "θ", "phi": "ϕ", "mu": "μ", "omega": "ω", "tau": "τ"}


def normalize_math(s: str) -> str:
    """Flatten inline LaTeX so patterns see ``N_c=64``, ``5 × 10^-4``, ``λ_rgb = 0.1``. Numbers are read first
    as the equation reader reads them (``equations.normalize.normalize_numbers``): in inline math MinerU's
    spaced digits (``$1 \\times 1 0 ^ { - 2 }$``, ``$5 1 2$``), ``1e-2``; everywhere Unicode superscripts
    (``10⁻³``, ``2¹⁹``) and thin-space thousands (``8 192``)."""
    s = normalize_numbers(s, math=False)
    if "$" in s:
        s = _INLINE_MATH.sub(lambda m: "$" + normalize_numbers(m.group(1)) + "$", s)
    s = unicodedata.normalize("NFKC", s).replace("$", "")
    s = re.sub(r"\\(?:times|cdot)(?![A-Za-z])", " × ", s)
    s = re.sub(r"\\(" + "|".join(_GREEK) + r")(?![A-Za-z])", lambda m: _GREEK[m.group(1)], s)
    for _ in range(3):
        s = re.sub(r"\\(?:mathrm|mathbf|mathit|text|textrm|textit|textbf|operatorname|boldsymbol|bm)\s*\{([^{}]*)\}",
                   r"\1", s)
    s = re.sub(r"([_^])\{([^{}]*)\}", r"\1\2", s)
    s = re.sub(r"\\[,;:! ]|\\mathopen\{\}|\\mathclose\{\}|\\left|\\right", " ", s)
    s = s.replace("{", "").replace("}", "")
    s = re.sub(r"(?<=\d)\s*\^\s*", "^", s)
    s = re.sub(r"(\d)\s*e\s*[−-]\s*(\d)", r"\1e-\2", s)  # "5e −4" from PDFs
    s = re.sub(r"×\s*10([−-]?\d{1,2})(?![\d.])", r"× 10^\1", s)  # "2 × 105": a flattened superscript
    return re.sub(r"\s+", " ", s).strip()


def _one(s: str) -> float:
    s = s.strip().replace("−", "-").replace("–", "-")
    m = re.fullmatch(r"(-?\d+(?:\.\d+)?)\s*(?:×|\*|·|x)\s*10\s*\^?\s*(-?)\s*(\d+)", s)
    if m:
        return float(m.group(1)) * 10.0 ** int(m.group(2) + m.group(3))
    powered = "^" in s or re.fullmatch(r"-?10\s*-\s*\d+", s)
    m = re.fullmatch(r"(-?)(2|10)\s*\^?\s*(-?)\s*(\d+)", s) if powered else None
    if m:
        return float(m.group(1) + "1") * float(m.group(2)) ** int(m.group(3) + m.group(4))
    mult = {"k": 1e3, "K": 1e3, "M": 1e6}.get(s[-1], 1.0)
    return float(s.rstrip("kKM").replace(",", "")) * mult


def _tidy(x: float) -> int | float:
    return int(x) if x.is_integer() and abs(x) >= 1 else x


def parse_number(text: str) -> Value:
    """``"5 × 10^-4"`` -> 0.0005, ``"2^19"`` -> 524288, ``"300k"`` -> 300000, ``"100–300k"`` -> [100000, 300000]."""
    text = text.strip()
    signed = re.search(r"[eE]-|\^\s*-|10\s*−", text)  # a minus sign of an exponent is no range
    parts = [text] if signed else re.split(r"\s*[–—]\s*|(?<=\d)-(?=\d)(?![^×]*×)", text)
    if len(parts) == 2 and parts[0] and parts[1]:
        lo, hi = parts
        if hi[-1] in "kKM" and lo[-1] not in "kKM":
            lo += hi[-1]
        return [_tidy(_one(lo)), _tidy(_one(hi))]
    return _tidy(_one(text))


# ----- patterns ---------------------------------------------------------------------------------------
@cache
def load_specs(path: str = str(PATTERNS_FILE), cards: bool = True) -> tuple:
    """(name, unit, [compiled patterns], self-qualified) for each entry of the YAML file, then (``cards``) for each
    hyperparameter a technique card introduces (``hyperparameter_patterns``, cards in name order)."""
    entries = [(e["name"], e.get("unit", ""), e["patterns"], bool(e.get("self_qualified")))
               for e in yaml.safe_load(Path(path).read_text(encoding="utf-8"))]
    if cards:
        entries += [(name, p["unit"], p["patterns"], p["self_qualified"]) for name, p in card_patterns()]
    return tuple((name, unit, [re.compile(p.replace("{num}", NUMBER).replace("{int}", INTEGER), re.IGNORECASE)
                               for p in patterns], qualified) for name, unit, patterns, qualified in entries)


def card_patterns() -> list[tuple[str, dict]]:
    """(hyperparameter name, its patterns) of every technique card of the packaged knowledge base."""
    from nerfify_ns.knowledge.cards import CARDS_DIR, read_cards

    return [(name, p) for c in sorted(read_cards(CARDS_DIR).values(), key=lambda c: c.name)
            for name, p in c.hyperparameter_patterns.items()]


_QUALIFIERS = [("direction",
                r"^\s*(?:for|of|on)?\s*(?:the\s+)?(?:γ\s*\(\s*d\s*\)|\(?d\)|view(?:ing)? direction|direction)"),
               ("position", r"^\s*(?:for|of|on)?\s*(?:the\s+)?(?:γ\s*\(\s*x\s*\)|\(?x\)|position|location)"),
               ("coarse", r"^[^.;,]{0,25}\bcoarse\b"), ("fine", r"^[^.;,]{0,25}\bfine\b"),
               ("proposal", r"^[^.;,]{0,25}\bproposal\b")]
_STOP_SUBS = {"a", "the", "loss", "an", "with", "and", "of", "its", "each", "this", "same", "total", "initial"}


def _qualifier(after: str, self_qualified: bool) -> str:
    for name, pat in _QUALIFIERS:
        if self_qualified and name not in ("direction", "position"):
            continue
        if re.search(pat, after, re.IGNORECASE):
            return name
    return ""


def extract_from_sentence(sentence: str, loc: Location | None = None, section: str = "") -> list[Hyperparameter]:
    """Every hyperparameter the patterns find in one sentence."""
    norm = normalize_math(sentence)
    found: list[Hyperparameter] = []
    seen: set = set()
    for name, unit, pats, self_qualified in load_specs():
        for pat in pats:
            for m in pat.finditer(norm):
                h = _make(name, unit, m, norm, sentence, loc, section, self_qualified)
                key = (h.name, str(h.value), h.qualifier) if h else None
                if h and key not in seen:
                    seen.add(key)
                    found.append(h)
    return found


def _make(name, unit, m, norm, sentence, loc, section, self_qualified=False) -> Hyperparameter | None:
    try:
        value = parse_number(m.group("num"))
    except (ValueError, OverflowError):
        return None
    groups = m.groupdict()
    sub = (groups.get("sub") or "").strip().lower()
    if name == "lambda" and sub:
        words = [w for w in re.split(r"\W+", sub) if w and w not in _STOP_SUBS]
        if not words:
            return None
        name = "lambda_" + "_".join(words)
    return Hyperparameter(name=name, value=value, unit=groups.get("unit") or unit, sentence=sentence.strip(),
                          raw=m.group(0).strip(), qualifier=_qualifier(norm[m.end():m.end() + 60], self_qualified),
                          loc=loc or Location(), section=section)


def extract_hyperparameters(items: Iterable[tuple[str, Location, str]],
                            warnings: list | None = None) -> list[Hyperparameter]:
    """Hyperparameters of (paragraph text, location, section) items, sentence by sentence. A sentence whose reading
    raises is skipped, its reason appended to ``warnings`` (the others are read)."""
    out: list[Hyperparameter] = []
    for text, loc, section in items:
        for sentence in split_sentences(text):
            if re.search(r"\d", sentence):
                try:
                    out.extend(extract_from_sentence(sentence, loc, section))
                except Exception as err:  # noqa: BLE001 - the per-sentence boundary
                    if warnings is not None:
                        warnings.append(f"hyperparameters of a sentence not read ({type(err).__name__}: "
                                        f"{' '.join(str(err).split())[:120]}): {sentence[:80]}")
    return out
