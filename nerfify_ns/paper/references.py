"""Reference-list parsing: split a bibliography into entries and read title, authors, year, venue, ids."""

from __future__ import annotations

import re

from nerfify_ns.paper.document import Reference
from nerfify_ns.sentence_split import split_sentences

ARXIV = re.compile(r"(?:arxiv(?:\s*preprint)?\s*(?:arxiv)?\s*[:/]?\s*|abs/|arxiv\.org/(?:abs|pdf)/)"
                   r"(\d{4}\.\d{4,5}|[a-z\-]+(?:\.[A-Z]{2})?/\d{7})(?:v\d+)?", re.IGNORECASE)
DOI = re.compile(r"\b(10\.\d{4,9}/[^\s,;\"<>]+)", re.IGNORECASE)
YEAR = re.compile(r"(?<!\d)((?:19|20)\d{2})[a-z]?(?!\d)")
_NUMBERED = re.compile(r"^\s*\[(\d{1,4})\]\s+")
_DOTTED = re.compile(r"^\s*(\d{1,4})\.\s+(?=[A-Z])")
_LINE_START = re.compile(r"(?m)^\s*\[(\d{1,4})\]\s+")
_VENUE_HINT = re.compile(r"^\s*(?:In\b|Proc|Proceedings|arXiv|CoRR|IEEE|ACM|Advances|Journal|Trans|"
                         r"International|Conference|European|Computer|SIGGRAPH|NeurIPS|CVPR|ICCV|ECCV)",
                         re.IGNORECASE)


def split_entries(text: str) -> list[tuple[str, str]]:
    """(key, raw text) of each entry in a bibliography's text; numbered ``[n]``, ``n.`` or one per block."""
    text = text.strip()
    starts = list(_LINE_START.finditer(text))
    if len(starts) < 2:
        starts = list(re.finditer(r"(?:^|(?<=\s))\[(\d{1,4})\]\s+", text))
    if len(starts) >= 2:
        return [(m.group(1), text[m.end(): nxt.start() if nxt else len(text)])
                for m, nxt in zip(starts, [*starts[1:], None], strict=False)]
    dotted = list(re.finditer(r"(?m)^\s*(\d{1,4})\.\s+(?=[A-Z])", text))
    if len(dotted) >= 2:
        return [(m.group(1), text[m.end(): nxt.start() if nxt else len(text)])
                for m, nxt in zip(dotted, [*dotted[1:], None], strict=False)]
    blocks = [b for b in re.split(r"\n\s*\n", text) if b.strip()]
    return [(str(i + 1), b) for i, b in enumerate(blocks)]


def _clean(raw: str) -> str:
    raw = re.sub(r"-\n(?=[a-z])", "", raw)  # de-hyphenate line breaks
    return re.sub(r"\s+", " ", raw).strip()


def _trailing_backrefs(raw: str) -> str:
    """Drop CVPR-style back-reference page lists ("... 2022. 2, 5, 6")."""
    return re.sub(r"(?<=\.)\s*\d{1,3}(?:\s*,\s*\d{1,3})*\s*$", "", raw).strip()


def _authors(s: str) -> list[str]:
    s = re.sub(r"\bet al\.?", "", s).strip(" ,.")
    names = [n.strip() for n in re.split(r",\s*(?:and\s+)?|\s+and\s+|\s*&\s*", s) if n.strip()]
    if len(names) > 1 and all(re.fullmatch(r"(?:[A-Z]\.?\s*-?)+", n) for n in names[1::2]) \
            and re.fullmatch(r"[^\s,]+(?: [^\s,.]+)?", names[0]):
        names = [f"{a.strip()}, {b.strip()}" for a, b in zip(names[::2], names[1::2], strict=False)]  # "Last, F., ..."
    return [n.strip() for n in names if n.strip() and len(n.strip()) > 1]


def parse_reference(raw: str, key: str = "", index: int = 0) -> Reference:
    """Best-effort fields of one bibliography entry in common author-title-venue-year styles."""
    raw = _clean(raw)
    ref = Reference(key=key or str(index), raw=raw, index=index)
    if (m := ARXIV.search(raw)):
        ref.arxiv = m.group(1)
    if (m := DOI.search(raw)):
        ref.doi = m.group(1).rstrip(".")
    body = _trailing_backrefs(raw)
    quoted = re.search(r"[“\"]([^”\"]{8,})[”\"]", body)
    paren_year = re.search(r"\(((?:19|20)\d{2})[a-z]?\)\.?", body)
    if quoted:  # IEEE: A. Author, "Title," in Venue, 2021.
        ref.authors = _authors(body[: quoted.start()])
        ref.title = quoted.group(1).strip(" ,.")
        ref.venue = re.sub(r"^[\s,.]*(?:in\s+)?", "", body[quoted.end():], flags=re.IGNORECASE).strip(" ,.")
    elif paren_year:  # APA: Author, A., & Author, B. (2021). Title. Venue.
        ref.authors = _authors(body[: paren_year.start()])
        rest = split_sentences(body[paren_year.end():], bibliography=True)
        ref.title = rest[0].strip(" .") if rest else ""
        ref.venue = " ".join(rest[1:]).strip(" .")
    else:  # CVPR/ACM: Authors. Title. In Venue, pages, 2021.
        parts = split_sentences(body, bibliography=True)
        if len(parts) >= 2:
            ref.authors = _authors(parts[0])
            ref.title = parts[1].strip(" .")
            ref.venue = " ".join(parts[2:]).strip(" .")
            if _VENUE_HINT.match(ref.title) and len(parts) == 2:
                ref.title, ref.venue = "", ref.title
        else:
            ref.title = body.strip(" .")
    ref.venue = re.sub(r"^In\s+", "", ref.venue).strip(" ,.")
    plain = DOI.sub(" ", ARXIV.sub(" ", body))
    years = [y for y in YEAR.findall(paren_year.group(0) if paren_year else plain)]
    ref.year = int(years[-1]) if years else None
    return ref


def parse_reference_text(text: str) -> list[Reference]:
    """Every entry of a reference section's text."""
    refs = []
    for i, (key, raw) in enumerate(split_entries(text), start=1):
        if len(raw.strip()) >= 10:
            refs.append(parse_reference(raw, key, i))
    return refs


def is_references_heading(title: str) -> bool:
    return bool(re.fullmatch(r"\s*(?:\d+\.?\s*)?(?:references|bibliography|literature cited|works cited)\s*",
                             title, re.IGNORECASE))


