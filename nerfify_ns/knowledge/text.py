"""Text normalisation shared by alias detection and paper matching (titles, arXiv ids)."""

from __future__ import annotations

import re
import unicodedata

__all__ = ["normalize_text", "normalize_title", "normalize_arxiv_id", "alias_pattern",
           "longest_non_overlapping", "strip_latex"]

_LATEX_COMMAND = re.compile(r"\\[A-Za-z]+\*?")   # \emph, \textbf, \mathrm ... (arguments kept)
_LATEX_ESCAPE = re.compile(r"\\[^A-Za-z\s]")     # \" \' \& \% \{ ...
_NON_WORD = re.compile(r"[^0-9a-z]+")

_NEW_STYLE = re.compile(r"(?<![0-9])(\d{4}\.\d{4,5})(?:v\d+)?(?![0-9])")
_OLD_STYLE = re.compile(r"(?<![a-z])([a-z][a-z\-]*)(?:\.[a-z]{2})?/(\d{7})(?:v\d+)?(?![0-9])")


def _strip_accents(text: str) -> str:
    decomposed = unicodedata.normalize("NFKD", text)
    return "".join(ch for ch in decomposed if not unicodedata.combining(ch))


def normalize_text(text: str) -> str:
    """Lower-case ASCII words separated by single spaces: LaTeX commands, braces, accents and
    punctuation removed ("{K}-Planes: \\emph{Explicit}" -> "k planes explicit")."""
    text = _strip_accents(text)
    text = _LATEX_COMMAND.sub(" ", text)
    text = _LATEX_ESCAPE.sub("", text)
    text = text.replace("{", "").replace("}", "").replace("$", "")
    return _NON_WORD.sub(" ", text.lower()).strip()


def normalize_title(title: str) -> str:
    """The key titles are compared by (see ``normalize_text``)."""
    return normalize_text(title)


def normalize_arxiv_id(value: str | None) -> str | None:
    """Canonical arXiv id from an id, a URL or a citation string; ``None`` when there is none.

    New-style ids lose their version ("arXiv:2111.12077v3" -> "2111.12077"); old-style ids lose the
    version and the subject class ("cs.CV/0502076v2" -> "cs/0502076").
    """
    if not value:
        return None
    text = str(value).strip().lower()
    m = _NEW_STYLE.search(text)
    if m:
        return m.group(1)
    m = _OLD_STYLE.search(text)
    if m:
        return f"{m.group(1)}/{m.group(2)}"
    return None


_TYPOGRAPHIC = {"l": "[lℓ]"}
"""Letters papers also set in a typographic variant: the script l of "ℓ2 loss", "ℓ1 regulariser"."""


def alias_pattern(alias: str) -> re.Pattern:
    """A case-insensitive pattern for ``alias`` in running text: whole words only, any run of
    spaces, hyphens, underscores, slashes or "~" between its words, an optional plural 's'/'es'; an "l" also
    matches the script "ℓ" ("ℓ2-loss" is the "l2 loss").
    A '+' in the alias is kept literally ("nerf++" does not match plain "NeRF"). Knowledge-base tables
    compile their aliases once (``KnowledgeBase.card_aliases``); ``re`` caches the rest."""
    tokens = re.findall(r"[0-9a-z]+|\+", _strip_accents(alias).lower())
    if not any(t != "+" for t in tokens):
        raise ValueError(f"empty alias {alias!r}")
    sep = r"(?:[\s\-\u2010-\u2015_~/]|\\,)+"
    parts: list[str] = []
    previous_word = False
    for tok in tokens:
        if tok == "+":
            parts.append(r"\+")
            previous_word = False
            continue
        if previous_word:
            parts.append(sep)
        parts.append("".join(_TYPOGRAPHIC.get(ch, re.escape(ch)) for ch in tok))
        previous_word = True
    suffix = r"(?:e?s)?" if previous_word else ""
    return re.compile(r"(?<![0-9A-Za-z])" + "".join(parts) + suffix + r"(?![0-9A-Za-z+])", re.IGNORECASE)


def strip_latex(text: str) -> str:
    """``text`` without LaTeX commands, escapes, braces and dollars; whitespace collapsed."""
    text = _LATEX_COMMAND.sub(" ", text)
    text = _LATEX_ESCAPE.sub("", text)
    text = text.replace("{", "").replace("}", "").replace("$", "")
    return " ".join(text.split())


def longest_non_overlapping(spans: list[tuple[int, int, object]]) -> list[tuple[int, int, object]]:
    """Greedy: longest spans first, dropping any that overlaps a kept one; result in text order.

    So "integrated positional encoding" counts once, not also as "positional encoding"."""
    kept: list[tuple[int, int, object]] = []
    for span in sorted(spans, key=lambda s: (-(s[1] - s[0]), s[0])):
        if all(span[1] <= k[0] or span[0] >= k[1] for k in kept):
            kept.append(span)
    return sorted(kept, key=lambda s: (s[0], s[1]))
