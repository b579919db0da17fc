"""Plain-text extractions of a PDF split by page (``## Page N`` headings): the page markers are locations, not
sections; the paper's own numbered headings, title, abstract, paragraphs, captions and numbered equations are
recovered from the running text.

Such a text is what a PDF-to-text tool writes: lines wrapped at the column width, words hyphenated across lines,
headings on a line of their own ("3.1. Representation"), glued to the end of the previous one ("Research.1.
Introduction") or with the number alone on the line before the title ("3.1" / "SCENE REPRESENTATIONS"; a running
header printed under every page number is never a title), equations flattened onto one line ending in their number
("F: (x, d, t) -> (c, sigma), (1)") or set in short lines above their number alone ("Lσd = E(σd)" / "(6)"). A heading
is only taken when its number follows the previous heading's (2 -> 2.1 -> 2.2 -> 3, A.1 -> A.2), so a line that
merely starts with a number ("5123. The emptiness voxel ...") is never a section.
"""

from __future__ import annotations

import re
import statistics
from collections import Counter
from dataclasses import dataclass

from nerfify_ns.paper.builder import CAPTION, Block
from nerfify_ns.paper.document import Location

# a page marker: "## Page 3", the HTML comment some converters leave ("<!-- page 3 -->"), or a numberless break
# ("---Page Break---": the next page)
PAGE_MARK = re.compile(r"^\s*(?:#{1,3}\s*Page\s+(\d{1,4})|<!--\s*page\s+(\d{1,4})\s*-->"
                       r"|[-=*]{2,}\s*page\s*break\s*[-=*]{2,})\s*$", re.IGNORECASE)
_RULE = re.compile(r"^\s*(?:-{3,}|\*{3,}|_{3,})\s*$")
# "3.1. Representation", "3.2.1 Anchor Point Initialization", "A.2. Hyperparameter Settings", "4 Method"
_HEADING = re.compile(r"^(?P<num>(?:\d{1,2}|[A-H])(?:\.\d{1,2}){0,3})(?:\.\s?|\s)"
                      r"(?P<title>(?:[A-Z]|\d[A-Z]\b)[^\n]{1,90})$")
# a heading glued to the end of the previous line: "...Research.1. Introduction" (not a cross-reference's
# number: "...see Sections 4.2 and 4.4. Beyond existing approaches" holds no heading)
_GLUED = re.compile(r"^(?P<before>.*[a-z)\]]\.?)(?P<num>\d{1,2}(?:\.\d{1,2}){0,3})\.\s?"
                    r"(?P<title>[A-Z][A-Za-z-]+(?: [A-Za-z-]+){0,6})$")
# a markdown heading: hashes, a space, text (a lone "#" is what an extractor leaves of a formula's bracket)
_MD_HEADING = re.compile(r"^#{1,6}\s+\S")
# a heading's number alone on its line, its title on the next ("3.1" then "SCENE REPRESENTATIONS": the layout
# pdftotext gives a heading whose number and title are set apart)
_NUMBER_ALONE = re.compile(r"^(?P<num>(?:\d{1,2}|[A-H])(?:\.\d{1,2}){0,3})\.?$")
_NAMED = re.compile(r"^(?P<name>Abstract|References|Acknowledge?ments?)\b[.:]?\s*(?P<rest>.*)$", re.IGNORECASE)
# a line ending with an equation's number ("Δx = D(γ(x), γ(t)), (1)"): a flattened equation when its body is math
NUMBERED_LINE = re.compile(r"^(?P<body>.*?\S)\s*\(\s*(?P<num>\d{1,3})\s*\)\s*$")
# an equation's number alone on its line, its body on the short lines above it (pdftotext sets a display equation's
# pieces on lines of their own: "Lσd = E(σd)" then "(6)")
_EQ_NUM_ALONE = re.compile(r"^\(\s*(?P<num>\d{1,3})\s*\)$")
# a paragraph that opens with a run-in heading ("Ray Importance Sampling. We ...") starts on a line of its own
_RUN_IN = re.compile(r"^[A-Z][\w-]*(?: (?:[A-Z0-9][\w-]*|of|for|and|the|in|with|via|to|on)){1,6}\.\s+[A-Z]")
# or in sentence case when its last word is capitalised ("Delayed use of Ambient Dimensions. Motion ..."), unless it
# reads as a sentence: it opens with a pronoun, an article or a connective, or holds a verb ("Results are shown in
# Table. We ...")
_RUN_IN_SENTENCE_CASE = re.compile(r"^(?P<title>[A-Z][a-z][\w-]*(?: [a-z][\w-]*){1,4}(?: [A-Z][\w-]*){1,2})\.\s+[A-Z]")
_NOT_A_TITLE = re.compile(r"^(?:We|Our|The|This|These|It|Its|In|For|As|To|On|At|By|If|Here|Note|Then|Thus|A|An)\b"
                          r"|\b(?:is|are|was|were|be|been|has|have|had|can|could|will|would|we|shown|see|use[sd])\b")


def _run_in(s: str) -> bool:
    """Whether line ``s`` opens with a run-in heading ("Ray Importance Sampling. We ...")."""
    if _RUN_IN.match(s):
        return True
    m = _RUN_IN_SENTENCE_CASE.match(s)
    return bool(m) and not _NOT_A_TITLE.search(m.group("title"))

_MATHY = re.compile(r"[=+∑∫∏σαβγδλθμτφψωΣΦΨΩ^_\\≈≤≥×·∈→−‖∥⊙⊗]")
_FUNCTION_WORDS = {"a", "an", "the", "of", "for", "and", "with", "in", "on", "via", "from", "to", "by", "as", "at",
                   "is", "are", "using", "towards", "through", "into"}


FLAT_HEADINGS_FIRST = 3
"""Numbered plain-text headings ("1. Introduction", "2. Related Work", ...) before a text's first markdown heading
that make it a flat extraction whatever its later ``#`` lines are (a table's "# Gaussians" column, "# 100K")."""


def is_page_split(text: str) -> bool:
    """Whether ``text`` is a flat extraction: at least two ``## Page N`` markers and few other headings, many lines
    with no markdown heading at all (a PDF's text saved as ``.md``), or :data:`FLAT_HEADINGS_FIRST` numbered
    plain-text headings, the first numbered 1, before any markdown heading (the paper's sections are plain text;
    a ``#`` line further on is what an extractor left of a table)."""
    lines = text.splitlines()
    pages = sum(1 for line in lines if PAGE_MARK.match(line))
    others = sum(1 for line in lines if _MD_HEADING.match(line) and not PAGE_MARK.match(line))
    return ((pages >= 2 and others <= pages) or (others == 0 and len(lines) >= 100)
            or (len(lines) >= 100 and _plain_headings_first(lines)))


def _plain_headings_first(lines: list[str]) -> bool:
    """Whether :data:`FLAT_HEADINGS_FIRST` numbered plain-text headings, the first numbered 1, come before the
    first markdown heading (page markers aside)."""
    numbers: list[str] = []
    for line in lines:
        s = line.strip()
        if _MD_HEADING.match(s) and not PAGE_MARK.match(s):
            break
        m = _HEADING.match(s)
        if m and m.group("num")[0].isdigit() and (numbers or m.group("num") == "1"):
            numbers.append(m.group("num"))
    return len(numbers) >= FLAT_HEADINGS_FIRST


@dataclass
class _Line:
    text: str
    page: int
    line: int


def _lines(text: str, origin: list[int] | None = None) -> list[_Line]:
    """Every non-empty line with its page, page markers and rules dropped; ``origin``: the line of the file each
    line of ``text`` comes from (a rearranged text), else its own."""
    out, page = [], 1
    for i, raw in enumerate(text.splitlines(), 1):
        m = PAGE_MARK.match(raw)
        if m:
            page = int(m.group(1) or m.group(2) or page + 1)
            continue
        s = raw.strip()
        if s and not _RULE.match(s):
            out.append(_Line(s, page, origin[i - 1] if origin and i <= len(origin) else i))
    return out


def _number_key(num: str) -> tuple:
    return tuple(int(p) if p.isdigit() else ord(p) - ord("A") + 100 for p in num.split("."))


def _follows(previous: str | None, num: str) -> bool:
    """Whether heading number ``num`` can come right after ``previous`` (None: the first heading)."""
    new = _number_key(num)
    if previous is None:
        return new in ((1,), (0,)) or (len(new) == 1 and new[0] <= 2)
    old = _number_key(previous)
    if new[0] >= 100 and old[0] < 100:  # the appendix starts: A or A.1
        return new in ((100,), (100, 1))
    for depth in range(min(len(old), len(new))):  # same prefix, then one step at the first level that changes
        if new[:depth] != old[:depth]:
            return False
        if depth == len(new) - 1:
            return old[depth] < new[depth] <= old[depth] + 2  # one heading may have been lost by the extractor
    return len(new) == len(old) + 1 and new[:len(old)] == old and new[-1] in (1, 2)


def _title_like(title: str) -> bool:
    """Whether ``title`` reads as a heading's title: short, mostly letters, not a clause; a run-in title with its
    sentence after it ("Efficiency. Large and detailed scenes ...": an item of a numbered list) is running text."""
    words = title.rstrip(".").split()
    if not words or len(words) > 12 or title.endswith((",", ";")) or "=" in title or CAPTION.match(title):
        return False  # ... or a caption ("Table 3. Comparisons ...") after a page number alone on its line
    if re.search(r"[a-z]\.\s+[A-Z][a-z]*\s+[a-z]", title):
        return False
    letters = sum(c.isalpha() for c in title)
    return letters >= 0.6 * len(title.replace(" ", "")) and not re.search(r"\d{3,}", title)


def _running_lines(lines: list[_Line], least: int = 3) -> frozenset[str]:
    """Lines that follow a bare number (a page number) at least ``least`` times: running headers and footers
    ("Preprint", a venue's banner) printed under every page number, which are never a heading's title."""
    after = Counter(b.text for a, b in zip(lines, lines[1:], strict=False) if _NUMBER_ALONE.match(a.text))
    return frozenset(text for text, n in after.items() if n >= least and not _NUMBER_ALONE.match(text))


def _split_heading(s: str, following: _Line | None, previous: str | None,
                   running: frozenset[str]) -> tuple[str, str] | None:
    """(number, title) when ``s`` is a heading's number alone and the next line its title (a title that ends a
    sentence is running text): the two read as one heading line, "3.1 SCENE REPRESENTATIONS"."""
    m = _NUMBER_ALONE.match(s)
    if m is None or following is None or following.text in running or following.text.endswith("."):
        return None
    head = _heading(f"{m.group('num')} {following.text}", previous)
    return (head[1], head[2]) if head is not None and not head[0] else None


def _heading(s: str, previous: str | None) -> tuple[str, str, str] | None:
    """(text before, number, title) when ``s`` holds the heading that follows ``previous``."""
    for pattern in (_HEADING, _GLUED):
        m = pattern.match(s)
        if m and _title_like(m.group("title")) and _follows(previous, m.group("num")):
            return (m.groupdict().get("before") or ""), m.group("num"), m.group("title").rstrip(".").strip()
    return None


def _title_lines(lines: list[_Line]) -> tuple[str, int]:
    """The title (one or more lines at the top of page 1) and how many lines it takes."""
    if not lines:
        return "", 0
    parts = [lines[0].text]
    i = 1
    while i < len(lines) and i < 3:
        words = lines[i].text.split()
        lowered = [w for w in words if w.lower() in _FUNCTION_WORDS]
        if re.search(r"\d|,|@|University|Institute", lines[i].text) or not words or not words[0][0].isupper() \
                or _NAMED.match(lines[i].text):
            break
        if len(words) > 3 and not lowered:
            break  # a line of names
        parts.append(lines[i].text)
        i += 1
    return " ".join(parts), i


def _dehyphenate(lines: list[str]) -> str:
    text = ""
    for s in lines:
        if text.endswith("-") and s[:1].islower():
            text = text[:-1] + s
        elif text.endswith("\u00ad"):
            text = text[:-1] + s
        else:
            text = f"{text} {s}" if text else s
    return re.sub(r"\s+", " ", text).strip()


def _display_end(s: str) -> bool:
    """Whether ``s`` may be the last line of a display equation set above its number: a bare full stop, or a short
    line of math ("Ishifted[i, j] = Ir[i - di, j - dj].")."""
    return not s.strip(".,;: ") or (bool(_MATHY.search(s)) and len(s.split()) <= 12)


def _equation_lines(para: list[_Line], most: int = 40) -> list[_Line]:
    """The lines at the end of ``para`` that make a display equation: short, with math in them or a few symbols,
    back to the prose that introduces it (a line ending a sentence or a clause, or a long line)."""
    body: list[_Line] = []
    for k, x in enumerate(reversed(para[-most:])):
        t = x.text
        closing = k == 0 and _display_end(t)  # the equation's own full stop
        if x.page != para[-1].page:  # an equation is set on one page (the previous page's number is not of it)
            break
        if len(t) > 80 or (t.endswith((".", ":", ";")) and not closing) or (len(t.split()) > 4 and not
                                                                             _MATHY.search(t)):
            break
        body.insert(0, x)
    return body if body and any(_MATHY.search(x.text) for x in body) else []


def flat_blocks(text: str) -> list[Block] | None:
    """The blocks of ``text`` when it is a flat extraction (:func:`is_page_split`; two-column pages read column by
    column first, :mod:`nerfify_ns.paper.columns`), else None (a markdown or plain text of its own kind)."""
    from nerfify_ns.paper.columns import one_column

    text, origin = one_column(text)
    return page_split_blocks(text, origin) if is_page_split(text) else None


def page_split_blocks(text: str, origin: list[int] | None = None) -> list[Block]:
    """The blocks of a page-split extraction (see the module docstring), in reading order; ``origin``: the file's
    line of each line of ``text`` when it was rearranged."""
    lines = _lines(text, origin)
    blocks: list[Block] = []
    title, start = _title_lines(lines)
    if title:
        blocks.append(Block("title", title, Location(page=lines[0].page, line=lines[0].line)))
    widths = [len(x.text) for x in lines if len(x.text) > 20]
    full = statistics.median(widths) if widths else 60
    para: list[_Line] = []
    previous: str | None = None
    next_equation = 1
    in_abstract = False
    running = _running_lines(lines)
    skip = False

    def flush() -> None:
        if para:
            body = _dehyphenate([x.text for x in para])
            kind = "caption" if CAPTION.match(body) else "para"
            blocks.append(Block(kind, body, Location(page=para[0].page, line=para[0].line)))
            para.clear()

    rest = lines[start:]
    for k, x in enumerate(rest):
        if skip:  # the title of a heading whose number was the line before
            skip = False
            continue
        s = x.text
        loc = Location(page=x.page, line=x.line)
        following = rest[k + 1] if k + 1 < len(rest) and rest[k + 1].page == x.page else None  # a page number
        split = _split_heading(s, following, previous, running)  # ends its page: the next page's line is no title
        if split is not None:
            flush()
            number, heading = split
            blocks.append(Block("heading", heading, loc, level=number.count(".") + 1, number=number))
            previous, skip = number, True
            continue
        named = _NAMED.match(s)
        if named and (len(s) < 20 or named.group("name").lower() == "abstract") and previous is None \
                and named.group("name").lower() == "abstract" and not in_abstract:
            flush()
            blocks.append(Block("heading", "Abstract", loc, level=1))
            in_abstract = True
            if named.group("rest"):
                para.append(_Line(named.group("rest"), x.page, x.line))
            continue
        if named and named.group("name").lower() != "abstract" and len(s) < 25:
            flush()
            blocks.append(Block("heading", named.group("name").title(), loc, level=1))
            continue
        head = _heading(s, previous)
        if head is not None and k + 1 < len(rest) and rest[k + 1].text[:1].islower() and not s.endswith((".", "-")):
            head = None  # "A Gaussian" / "expands when ...": a sentence wrapped at a line that looks like a heading
        if head is not None:
            before, number, heading = head
            if before:
                para.append(_Line(before, x.page, x.line))
            flush()
            blocks.append(Block("heading", heading, loc, level=number.count(".") + 1, number=number))
            previous = number
            continue
        alone = _EQ_NUM_ALONE.match(s)
        if alone and int(alone.group("num")) in (next_equation, next_equation + 1):
            body = _equation_lines(para)
            if body:
                del para[len(para) - len(body):]
                flush()
                blocks.append(Block("equation", " ".join(x.text for x in body), Location(page=body[0].page,
                                                                                         line=body[0].line),
                                    number=alone.group("num")))
                next_equation = int(alone.group("num")) + 1
                continue
        eq = NUMBERED_LINE.match(s)
        if eq and int(eq.group("num")) in (next_equation, next_equation + 1) and _MATHY.search(eq.group("body")) \
                and len(eq.group("body")) < 240:
            flush()
            blocks.append(Block("equation", eq.group("body").rstrip(",. "), loc, number=eq.group("num")))
            next_equation = int(eq.group("num")) + 1
            continue
        if (CAPTION.match(s) or _run_in(s)) and para:
            flush()
        para.append(x)
        if s.endswith((".", ":", "?")) and len(s) < 0.75 * full and not _display_end(s):
            flush()  # a short line ending a sentence ends its paragraph (not a display equation's full stop)
    flush()
    return blocks
