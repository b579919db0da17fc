"""Plain-text reader: paragraphs by blank lines, numbered-heading heuristics, equations by trailing (n)."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

from nerfify_ns.paper.builder import CAPTION, Block, build, heading_level, split_heading
from nerfify_ns.paper.document import Document, Location
from nerfify_ns.paper.language import prose, require_english
from nerfify_ns.paper.limits import DEFAULT_LIMITS, Limits, check_elements, read_text_file
from nerfify_ns.paper.pagesplit import flat_blocks

NUMBERED_HEADING = re.compile(r"^(?:\d+(?:\.\d+){0,3}\.?|[A-Z]\.(?:\d+\.?)*|Appendix [A-Z0-9]+\.?)"
                              r"\s+[A-Z][^.!?]{1,90}$")
NAMED_HEADING = re.compile(r"^(?:abstract|references|bibliography|acknowledge?ments?|introduction|related work|"
                           r"conclusions?|method|methods|experiments|results|appendix)\s*:?$", re.IGNORECASE)
EQ_LINE = re.compile(r"^(?P<body>.*\S)\s+\((?P<num>\d+[a-z]?)\)\s*$")
MATHY = re.compile(r"[=+∑∫∏σαβγδλθ^_\\≈≤≥×·∈→‖]")


def read_text(path: Path, limits: Limits = DEFAULT_LIMITS) -> Document:
    """Ingest a ``.txt`` file (at most ``limits.max_text_chars`` characters; English prose only)."""
    text = read_text_file(path, limits)
    blocks = flat_blocks(text) or text_blocks(text)
    check_elements(blocks, path.name, limits)
    require_english(prose(blocks), path.name)
    return build(blocks, source=str(path), kind="text")


def is_equation_line(line: str) -> bool:
    """A short line with math symbols and a trailing ``(n)``."""
    m = EQ_LINE.match(line.strip())
    return bool(m and len(m.group("body")) < 200 and MATHY.search(m.group("body")))


def _chunks(lines: list[str]) -> Iterator[tuple[int, list[str]]]:
    start, cur = 0, []
    for i, line in enumerate(lines):
        if line.strip():
            if not cur:
                start = i
            cur.append(line.rstrip())
        elif cur:
            yield start, cur
            cur = []
    if cur:
        yield start, cur


def text_blocks(text: str) -> list[Block]:
    """The blocks of a plain text, in order."""
    blocks: list[Block] = []
    for start, chunk in _chunks(text.splitlines()):
        para: list[str] = []
        para_start = start
        for j, line in enumerate(chunk):
            s = line.strip()
            loc = Location(line=start + j + 1)
            kind = _line_kind(s, first=not blocks and not para, chunk_start=j == 0)
            if kind == "para":
                if not para:
                    para_start = start + j
                para.append(s)
                continue
            if para:
                blocks.append(_para(para, para_start))
                para = []
            if kind == "title":
                blocks.append(Block("title", s, loc))
            elif kind == "heading":
                number, title = split_heading(s)
                blocks.append(Block("heading", title.rstrip(":"), loc, level=heading_level(number), number=number))
            else:
                m = EQ_LINE.match(s)
                blocks.append(Block("equation", m.group("body"), loc, number=m.group("num")))
        if para:
            blocks.append(_para(para, para_start))
    return blocks


def _line_kind(s: str, first: bool, chunk_start: bool) -> str:
    if first and len(s) < 200 and not s.endswith("."):
        return "title"
    if NAMED_HEADING.match(s) or (chunk_start and NUMBERED_HEADING.match(s) and len(s.split()) <= 12):
        return "heading"
    if is_equation_line(s):
        return "equation"
    return "para"


def _para(lines: list[str], start: int) -> Block:
    text = re.sub(r"-\s*\n(?=[a-z])", "", "\n".join(lines))
    text = re.sub(r"\s+", " ", text).strip()
    return Block("caption" if CAPTION.match(text) else "para", text, Location(line=start + 1))
