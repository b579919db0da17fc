"""A paper's text split into sentences: the one splitter of the package, with its abbreviation lists.

A leaf module (standard library only), so that both the paper package (hyperparameters, bibliography entries) and
the knowledge package (detection, citations), which imports nothing from the paper package, read sentences the same
way::

    split_sentences("See Fig. 3 by Mildenhall et al. for details. We then train.")
    # ['See Fig. 3 by Mildenhall et al. for details.', 'We then train.']
    split_sentences("Mildenhall, B., Srinivasan, P. P. NeRF. In Proc. ECCV, 2020.", bibliography=True)
    # ['Mildenhall, B., Srinivasan, P. P. NeRF.', 'In Proc. ECCV, 2020.']

A period ends a sentence when whitespace and the start of a new one follow it (a capital, a digit, a bracket, math),
unless it ends an abbreviation, an initial ("A. B. Smith"), or sits inside inline math that is still open (MinerU
writes "$0 . 0 0 1$"; a lone ``$`` holds for at most :data:`MAX_OPEN_MATH` characters).
"""

from __future__ import annotations

import re

ABBREVIATIONS: tuple[str, ...] = (
    "e.g", "i.e", "et al", "etc", "w.r.t", "vs", "cf", "resp", "approx",
    "Fig", "Figs", "Eq", "Eqs", "Eqn", "Eqns", "Sec", "Secs", "Sect", "Tab", "Tabs", "Ref", "Refs", "No", "Alg", "Ch",
)
"""Words a period follows without ending a sentence of a paper's prose."""
BIBLIOGRAPHY_ABBREVIATIONS: tuple[str, ...] = ("et al", "vol", "pp", "no", "Ed", "In", "Proc")
"""The same for a bibliography entry ("vol. 3", "pp. 1-9", "In Proc. CVPR"), whose fields are its sentences."""
MAX_OPEN_MATH = 1000
"""Characters a sentence with an unclosed ``$`` keeps absorbing the next one (a stray ``$`` does not eat a page)."""


def _abbreviation(words: tuple[str, ...]) -> re.Pattern:
    return re.compile(r"(?:\b(?:" + "|".join(map(re.escape, words)) + r")|\b[A-Z])\.$")


_PROSE = (re.compile(r"(?<=[.!?])\s+(?=[A-Z0-9(\[$\\])"), _abbreviation(ABBREVIATIONS))
_BIBLIOGRAPHY = (re.compile(r"(?<=[.?!])\s+"), _abbreviation(BIBLIOGRAPHY_ABBREVIATIONS))


def split_sentences(text: str, *, bibliography: bool = False) -> list[str]:
    """The sentences of ``text``, each an exact substring of it (stripped). ``bibliography``: the fields of one
    bibliography entry (any word may start one; its own abbreviations)."""
    boundary, abbreviation = _BIBLIOGRAPHY if bibliography else _PROSE
    text = text.strip()
    out: list[str] = []
    start = 0
    for m in boundary.finditer(text):
        sentence = text[start:m.start()]
        if abbreviation.search(sentence) or (sentence.count("$") % 2 and len(sentence) < MAX_OPEN_MATH):
            continue
        out.append(sentence)
        start = m.end()
    out.append(text[start:])
    return [s.strip() for s in out if s.strip()]
