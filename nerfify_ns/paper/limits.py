"""Bounds on what reading a paper may cost: every input a paper can make us read, extract, expand or parse.

Papers come from anywhere, so ingestion is bounded: each limit below is checked while the work is done (never
after it), and going past one raises :class:`~nerfify_ns.paper.errors.PaperLimitError`, a one-line error that
names the limit and the file, and that the CLI turns into ``error: ...`` and exit code 2 with nothing written.
The defaults are far above what a real paper needs (the longest arXiv papers, appendices and figures included,
stay an order of magnitude below each), and every stage of ingestion is linear in them, so a hostile input is
refused within seconds. Tests (and callers that know better) pass a :class:`Limits` with other values.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from nerfify_ns.paper.errors import PaperLimitError

MiB = 1024 * 1024
_DIGIT = re.compile(r"\d")

MAX_FILE_BYTES = 200 * MiB
"""The paper file itself (a PDF with its figures, a tarball), checked from its size before it is opened."""

MAX_PAGES = 300
"""Pages of a PDF (a long paper with appendices has 40-60)."""

MAX_TEXT_CHARS = 2_000_000
"""Characters of a paper's text: a markdown or text file, or a PDF's text layer, counted while it is read. A
10-page paper has about 60,000; a 300-page thesis about 900,000."""

MAX_ARCHIVE_BYTES = 256 * MiB
"""Uncompressed bytes of all members of a LaTeX tarball together (figures included), counted from each
member's header before its data is read, and the decompressed stream is cut there too: a tarball that
inflates further (a "zip bomb") is refused without ever being inflated beyond it. arXiv caps a submission at
50 MB. Only source files (``.tex``, ``.bib``, ``.bbl``, styles) are written to disk; figures are skipped."""

MAX_ARCHIVE_FILES = 10_000
"""Members of a LaTeX tarball, or files and folders visited in a LaTeX folder (arXiv sources: tens to a few
hundred files)."""

MAX_LATEX_CHARS = 4_000_000
"""Characters of one LaTeX source file and of the whole document once every ``\\input``/``\\include`` is inlined
(the source of a long paper: 100,000-400,000)."""

MAX_ELEMENTS = 20_000
"""Elements of a paper: its paragraphs, headings, equations, captions, tables and algorithms, plus every table cell
and algorithm line (LaTeX), all together (a long paper with appendices: 1,000-5,000, most of them table cells).
Bounds the per-element work of parsing (citations, hyperparameters, equations) on a paper made of tiny pieces."""

MAX_NUMBER_TEXT_CHARS = 300_000
"""Characters of the sentences that hold a number, where hyperparameters are looked for (80 patterns per
sentence): a long paper has 20,000-40,000. Bounds the hyperparameter search on a paper made of numbers."""

MAX_INCLUDE_DEPTH = 16
"""Nesting of ``\\input``/``\\include``/``\\subfile``/``\\import`` (real papers: 1-3 levels)."""

MAX_INCLUDES = 1_000
"""``\\input``/``\\include``/``\\subfile``/``\\import`` followed in one document, all files together (real papers: up
to a few dozen). Stops a tree of inputs that includes each file several times from growing exponentially."""

MAX_MACRO_STEPS = 200_000
"""Macro expansions (one user macro replaced by its body) in one document, every pass and block together (a
paper with a hundred macros used a hundred times each needs about 30,000)."""

MAX_MACRO_OUTPUT_CHARS = 8_000_000
"""Characters that macro expansion may insert into one document, all expansions together: a macro whose body
repeats another macro many times, nested a few levels, grows exponentially and is stopped here."""

MAX_BIB_BYTES = 16 * MiB
"""Bytes of the ``.bib`` and ``.bbl`` files of a paper together (a large shared bibliography: 1-5 MB)."""

MAX_BIB_ENTRIES = 50_000
"""Entries of the ``.bib`` files of a paper together (a large shared bibliography: up to 20,000); parsed in one
linear scan, only the cited ones made into references."""

MAX_REFERENCES = 2_000
"""References of one paper: the entries of its ``.bbl`` (a survey cites 300-600). When the paper cites no entry
of its ``.bib``, at most this many of the ``.bib``'s entries stand for its references."""


@dataclass(frozen=True)
class Limits:
    """The limits one ingestion runs under (defaults: the module's constants, documented there)."""

    max_bytes: int = MAX_FILE_BYTES
    max_pages: int = MAX_PAGES
    max_text_chars: int = MAX_TEXT_CHARS
    max_archive_bytes: int = MAX_ARCHIVE_BYTES
    max_archive_files: int = MAX_ARCHIVE_FILES
    max_latex_chars: int = MAX_LATEX_CHARS
    max_elements: int = MAX_ELEMENTS
    max_number_text_chars: int = MAX_NUMBER_TEXT_CHARS
    max_include_depth: int = MAX_INCLUDE_DEPTH
    max_includes: int = MAX_INCLUDES
    max_macro_steps: int = MAX_MACRO_STEPS
    max_macro_output_chars: int = MAX_MACRO_OUTPUT_CHARS
    max_bib_bytes: int = MAX_BIB_BYTES
    max_bib_entries: int = MAX_BIB_ENTRIES
    max_references: int = MAX_REFERENCES


DEFAULT_LIMITS = Limits()


def size_text(n: int) -> str:
    """A byte count as people read it (``16 MB``, ``300 KB``, ``12 bytes``)."""
    if n >= MiB:
        return f"{n / MiB:.0f} MB"
    if n >= 1024:
        return f"{n / 1024:.0f} KB"
    return f"{n} bytes"


def check_elements(blocks: list, source: str, limits: Limits) -> None:
    """Refuse a reader's blocks, before any per-element work is done on them, when the paper has more than
    ``limits.max_elements`` elements (blocks, table cells, algorithm lines) or more than
    ``limits.max_number_text_chars`` characters of sentences with a number."""
    from nerfify_ns.sentence_split import split_sentences

    n = numeric = 0
    for b in blocks:
        n += 1 + sum(len(r) for r in (getattr(b, "rows", None) or []))
        n += b.text.count("\n") if b.kind == "algorithm" else 0
        if n > limits.max_elements:
            raise PaperLimitError(f"{source}: more than {limits.max_elements:,} elements (paragraphs, equations, table "
                                  "cells, algorithm lines; the limit); pass the paper alone")
        if b.kind in ("para", "abstract", "caption", "algorithm") and _DIGIT.search(b.text):
            numeric += sum(len(s) for s in split_sentences(b.text) if _DIGIT.search(s))
            if numeric > limits.max_number_text_chars:
                raise PaperLimitError(f"{source}: more than {limits.max_number_text_chars:,} characters of sentences "
                                      "with numbers (the limit on the text searched for hyperparameters); pass the "
                                      "paper alone")


def read_text_file(path: Path, limits: Limits) -> str:
    """A markdown or text paper's text (undecodable bytes replaced), refused beyond ``limits.max_text_chars``
    characters without reading further."""
    with open(path, "rb") as f:
        data = f.read(4 * limits.max_text_chars + 4)
    text = data.decode("utf-8", errors="replace")
    if len(data) > 4 * limits.max_text_chars or len(text) > limits.max_text_chars:  # a character is <= 4 bytes
        raise PaperLimitError(f"{path.name}: more than {limits.max_text_chars:,} characters of text (the limit on a "
                              "paper's text); pass the paper alone")
    return text
