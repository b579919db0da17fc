"""Is the paper written in English? Two cheap signals over its prose, no model and nothing downloaded.

1. The script: the share of its letters that are neither Latin nor Greek (Greek letters are mathematics in an
   English paper). A Chinese, Japanese, Korean, Russian or Arabic paper is refused on this alone.
2. The words: the share of its words that are common English function words ("the", "of", "and", "we", ...).
   English prose has 20-35 % of them, telegraphic notes and mathematics-heavy English still 10 %; German, French,
   Spanish or Italian prose almost none (words those languages share, such as "a", "in", "on", are not counted).

Only the prose is read (title, abstract, headings, paragraphs and captions; not equations, tables or
references), at most :data:`SAMPLE_CHARS` characters of it, so the check is linear and fast. Too little prose
(a stub, a test snippet) is never refused: the other checks of ingestion speak about it.
"""

from __future__ import annotations

import re
import unicodedata
from collections import Counter
from collections.abc import Iterable

from nerfify_ns.paper.errors import NotEnglishError

SAMPLE_CHARS = 200_000
"""Characters of prose examined (the first ones: title, abstract, introduction, method)."""

MIN_LETTERS = 200
"""Below this many letters the script is not judged."""

MAX_FOREIGN_SCRIPT = 0.30
"""Largest share of letters in another script (not Latin, not Greek) an English paper has."""

MIN_WORDS = 150
"""Below this many words the word signal is not judged."""

MIN_ENGLISH_WORDS = 0.05
"""Smallest share of common English function words an English paper has (measured: 0.10-0.32 on the example
and shared papers, the telegraphic condensed ones and a PDF appendix full of mathematics included; 0.00-0.02
on German, French, Spanish and Italian prose)."""

PROSE_KINDS = ("title", "abstract", "heading", "para", "caption")

STOP_WORDS = frozenset("""
about above after all and any are at be because been being between both but by can could did does each either
for from has have having here how however if into is it its itself many may more most must not of one only or
other our ours over same should since some such than that the their them then there these they this those
through thus to too under until upon very we were what when where whether which while who whose why with
within without would you your
""".split())
"""Common English function words. Words that are also frequent in German, French, Spanish, Italian or Dutch
("a", "in", "an", "on", "so", "also", "was", "die", "de", ...) are left out, so only English scores."""

_WORD = re.compile(r"[^\W\d_]+(?:['’][^\W\d_]+)?")
_NOT_PROSE = re.compile(r"\$\$.*?\$\$|\$[^$\n]{0,500}\$|\\[A-Za-z]+", re.DOTALL)
"""Inline and display math and LaTeX commands: not words of any language."""


def _latin_or_greek(ch: str) -> bool:
    o = ord(ch)
    return (o < 0x0250 or 0x1E00 <= o < 0x2000 or 0x0370 <= o < 0x0400 or 0xFF21 <= o <= 0xFF5A
            or 0x1D400 <= o < 0x1D800)  # mathematical alphanumerics


def _script(ch: str) -> str:
    """The script of a letter, from its Unicode name ("CJK", "HIRAGANA", "CYRILLIC", "HANGUL", ...)."""
    try:
        return unicodedata.name(ch).split()[0]
    except ValueError:
        return "unknown"


def prose(blocks: Iterable) -> str:
    """The prose of a reader's blocks (see :data:`PROSE_KINDS`), at most :data:`SAMPLE_CHARS` characters."""
    parts, n = [], 0
    for b in blocks:
        if b.kind in PROSE_KINDS and b.text:
            parts.append(b.text)
            n += len(b.text) + 1
            if n >= SAMPLE_CHARS:
                break
    return "\n".join(parts)[:SAMPLE_CHARS]


def english_signals(text: str) -> dict:
    """The measures the check decides on: letters, the share in another script (and which), words, the share of
    common English words."""
    text = _NOT_PROSE.sub(" ", text[:SAMPLE_CHARS])
    letters = [ch for ch in text if ch.isalpha()]
    foreign = Counter(_script(ch) for ch in letters if not _latin_or_greek(ch))
    words = [w.lower() for w in _WORD.findall(text)]
    latin_words = [w for w in words if all(_latin_or_greek(ch) for ch in w)]
    return {
        "letters": len(letters),
        "foreign_share": sum(foreign.values()) / max(1, len(letters)),
        "script": foreign.most_common(1)[0][0] if foreign else "",
        "words": len(latin_words),
        "english_share": sum(w in STOP_WORDS for w in latin_words) / max(1, len(latin_words)),
    }


def require_english(text: str, source: str) -> None:
    """Raise :class:`NotEnglishError` (one line naming the paper and why) when ``text`` is not English prose."""
    s = english_signals(text)
    if s["letters"] >= MIN_LETTERS and s["foreign_share"] > MAX_FOREIGN_SCRIPT:
        raise NotEnglishError(
            f"{source}: the paper's text is not in English ({s['foreign_share']:.0%} of its letters are "
            f"{s['script']}); nerfify-ns reads English papers only, pass the English version")
    if s["words"] >= MIN_WORDS and s["english_share"] < MIN_ENGLISH_WORDS:
        raise NotEnglishError(
            f"{source}: the paper's text is not in English (only {s['english_share']:.0%} of its words are common "
            "English words); nerfify-ns reads English papers only, pass the English version")
