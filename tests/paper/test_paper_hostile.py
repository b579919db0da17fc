"""Hostile papers, in process: LaTeX that names files outside the paper, include and
macro bombs, archives that inflate, huge bibliographies and texts, pathological shapes, papers not in English.
Each is refused with its typed one-line error naming the file or limit, fast (well under 10 s), reading nothing
outside the paper and leaving nothing behind. The same cases through the real CLI: test_paper_hostile_cli.py."""

from __future__ import annotations

import glob
import os
import tarfile
import tempfile
import time
from pathlib import Path

import pytest
from hostile_papers import (
    big_bib,
    chinese_pdf,
    fifo,
    german_markdown,
    include_tree,
    inflating_tarball,
    latex_folder,
    macro_bomb,
    outside_canary,
    russian_text,
    tarball,
    token,
)

from nerfify_ns.paper import (
    NotEnglishError,
    OutsidePaperError,
    PaperError,
    PaperLimitError,
    UnsafeArchiveError,
    ingest,
    latex_source,
)
from nerfify_ns.paper.bibtex import bib_entries
from nerfify_ns.paper.limits import DEFAULT_LIMITS, MAX_BIB_ENTRIES, Limits

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared"
FAST = 10.0
"""Seconds a hostile input may take to be refused (generous: each takes well under 2 s here)."""


def refused(path: Path, error: type, *needles: str, limits: Limits | None = None, leaks: tuple = ()) -> str:
    """Ingest ``path``: the typed error, within FAST seconds, its message on one line holding ``needles`` and
    none of ``leaks``."""
    start = time.perf_counter()
    with pytest.raises(error) as info:
        ingest(path, limits)
    seconds = time.perf_counter() - start
    message = str(info.value)
    assert seconds < FAST, f"{seconds:.1f} s to refuse: {message}"
    assert "\n" not in message and all(n in message for n in needles), message
    assert not any(leak in message for leak in leaks), message
    return message


@pytest.fixture()
def private_tmp(tmp_path, monkeypatch):
    """TMPDIR of its own, so the test can check that extraction leaves nothing behind."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr(tempfile, "tempdir", None)
    yield tmp
    assert list(tmp.iterdir()) == [], "extraction left files behind"


# ----- paper input stays inside the paper ------------------------------------------------------------------
ESCAPES = {
    "absolute input": ("\\input{/etc/passwd}", "\\input{/etc/passwd}"),
    "environment of the process": ("\\input{/proc/self/environ}", "/proc/self/environ"),
    "dot-dot input": ("\\input{../../../../etc/hostname}", "../../../../etc/hostname"),
    "dot-dot include of a canary": ("\\include{../outside/canary}", "../outside/canary"),
    "bare input": ("\\input /etc/hostname ", "/etc/hostname"),
    "subfile": ("\\subfile{/etc/passwd}", "\\subfile{/etc/passwd}"),
    "import": ("\\import{/etc/}{passwd}", "\\import{/etc/}{passwd}"),
    "subimport of a canary": ("\\subimport{../outside/}{canary}", "../outside/"),
    "bibliography of a canary": ("\\cite{leak}\\bibliography{../outside/refs}", "\\bibliography{../outside/refs}"),
    "absolute bibliography": ("\\bibliography{/etc/passwd}", "/etc/passwd"),
}


@pytest.mark.parametrize("case", list(ESCAPES))
def test_includes_outside_the_folder_are_refused(case, tmp_path, monkeypatch):
    body, named = ESCAPES[case]
    _, secret = outside_canary(tmp_path)
    monkeypatch.setenv("NERFIFY_TEST_SECRET", secret)
    paper = latex_folder(tmp_path / "paper", body)
    message = refused(paper, OutsidePaperError, named, "outside the paper", leaks=(secret,))
    assert "main.tex" in message or "bibliography" in message


LINKS = {  # link in the paper's folder, its target, main.tex's body, what the error names
    "input through a link to a canary": ("sections/intro.tex", "../../outside/canary.tex", "\\input{sections/intro}",
                                         "sections/intro.tex"),
    "folder link to /etc": ("sections", "/etc", "\\input{sections/hostname}", "sections/hostname"),
    "bibliography link to the environment": ("refs.bib", "/proc/self/environ", "\\cite{x}\\bibliography{refs}",
                                             "\\bibliography{refs}"),
    "source link to a device": ("big.tex", "/dev/zero", "", "big.tex"),
    "link loop": ("loop.tex", "loop.tex", "\\input{loop}", "loop"),
}


@pytest.mark.parametrize("case", list(LINKS))
def test_links_leading_outside_are_refused(case, tmp_path, monkeypatch):
    link, target, body, named = LINKS[case]
    _, secret = outside_canary(tmp_path)
    monkeypatch.setenv("NERFIFY_TEST_SECRET", secret)
    paper = latex_folder(tmp_path / "paper", body)
    (paper / link).parent.mkdir(parents=True, exist_ok=True)
    os.symlink(target, paper / link)
    refused(paper, OutsidePaperError, named, leaks=(secret,))


def test_a_pipe_among_the_sources_is_refused_not_read(tmp_path):
    """A FIFO named .tex would block a reader forever; it is not a regular file, so it is never opened."""
    paper = latex_folder(tmp_path / "paper", "\\input{sections/pipe}")
    fifo(paper / "sections" / "pipe.tex")
    refused(paper, OutsidePaperError, "sections/pipe.tex", "not a regular file")


def test_a_single_tex_file_reads_only_its_own_folder(tmp_path):
    _, secret = outside_canary(tmp_path)
    paper = latex_folder(tmp_path / "paper", "\\input{../outside/canary}")
    refused(paper / "main.tex", OutsidePaperError, "../outside/canary", leaks=(secret,))


@pytest.mark.parametrize("body, named", [("\\input{/proc/self/environ}", "/proc/self/environ"),
                                         ("\\input{../../../../etc/hostname}", "etc/hostname"),
                                         ("\\bibliography{/etc/passwd}", "/etc/passwd")])
def test_includes_outside_a_tarball_are_refused(body, named, tmp_path, private_tmp, monkeypatch):
    secret = token()
    monkeypatch.setenv("NERFIFY_TEST_SECRET", secret)
    from hostile_papers import MAIN

    paper = tarball(tmp_path / "src.tar.gz", {"main.tex": MAIN.format(body=body)})
    refused(paper, OutsidePaperError, named, leaks=(secret,))


def test_inputs_inside_the_folder_still_work(tmp_path):
    """Subfolders, \\import/\\subimport, suffixless names and links that stay inside are followed."""
    paper = latex_folder(tmp_path / "paper", "\\input{sec/a}\n\\import{sec/}{b}\n\\subfile{c.tex}\n\\input{d}\n", {
        "sec/a.tex": "We sample camera rays. \\subimport{deeper/}{e}\n",
        "sec/b.tex": "The radiance field is queried along each ray.\n",
        "sec/deeper/e.tex": "Volume rendering composites the samples.\n",
        "c.tex": "A proposal network places the samples.\n",
        "real.tex": "An alias stays inside the folder.\n"})
    os.symlink("real.tex", paper / "d.tex")
    text = ingest(paper).text()
    for words in ("camera rays", "queried along", "composites the samples", "proposal network", "alias stays"):
        assert words in text


# ----- bombs: every limit refuses fast ----------------------------------------------------------------------
def test_an_include_tree_is_stopped(tmp_path):
    """Each file inputs the next four times: 20 levels (4**20 inclusions) hit the depth limit, 8 levels (65,536
    inclusions within the depth) the count."""
    refused(include_tree(tmp_path / "deep"), PaperLimitError, f"deeper than {DEFAULT_LIMITS.max_include_depth}")
    refused(include_tree(tmp_path / "wide", depth=8), PaperLimitError, f"more than {DEFAULT_LIMITS.max_includes}")


def test_an_include_cycle_is_stopped_by_the_depth(tmp_path):
    paper = latex_folder(tmp_path / "paper", "\\input{a}", {"a.tex": "\\input{b}", "b.tex": "\\input{a}"})
    refused(paper, PaperLimitError, f"deeper than {DEFAULT_LIMITS.max_include_depth}")


def test_a_macro_bomb_is_stopped_by_the_expansion_limits(tmp_path):
    """200 repetitions, 6 levels: 64e12 characters if expanded; stopped at 8 million, no MemoryError."""
    refused(macro_bomb(tmp_path / "paper"), PaperLimitError, "macros", "the limit")


def test_a_recursive_macro_is_stopped_by_the_step_limit(tmp_path):
    paper = latex_folder(tmp_path / "paper", "\\def\\a{\\a\\a\\a\\a}\n" + "The field \\a. " * 1000)
    refused(paper, PaperLimitError, "steps")


def test_a_huge_bibliography_is_refused_fast(tmp_path):
    """100,000 entries in 16 MB (494 s before): refused by its size, and by its entries when it is smaller."""
    paper = latex_folder(tmp_path / "paper", "\\cite{key1}\\bibliography{refs}")
    big_bib(paper / "refs.bib", 100_000, pad=60)
    assert (paper / "refs.bib").stat().st_size > DEFAULT_LIMITS.max_bib_bytes
    refused(paper, PaperLimitError, "refs", "bibliography")
    big_bib(paper / "refs.bib", MAX_BIB_ENTRIES + 1)
    assert (paper / "refs.bib").stat().st_size < DEFAULT_LIMITS.max_bib_bytes
    refused(paper, PaperLimitError, "refs", f"{MAX_BIB_ENTRIES:,} bibliography entries")


def test_bibliography_parsing_is_linear(tmp_path):
    """Parsing time grows with the entries, not with their square: 4x the entries cost about 4x the time."""
    def seconds(n: int) -> float:
        text = big_bib(tmp_path / f"{n}.bib", n).read_text()
        start = time.perf_counter()
        assert sum(1 for _ in bib_entries(text)) == n
        return time.perf_counter() - start

    small, large = seconds(5_000), seconds(20_000)
    assert large < FAST and large < 12 * small + 0.5, (small, large)


def test_a_bbl_with_too_many_references_is_refused(tmp_path):
    items = "".join(f"\\bibitem{{k{n}}} A. Author. A radiance field. In CVPR, 2020.\n" for n in range(2_001))
    paper = latex_folder(tmp_path / "paper", "\\cite{k1}", {"main.bbl": items})
    refused(paper, PaperLimitError, "main.bbl", "more than 2,000 references")


@pytest.mark.parametrize("text", ["@a{" * 300_000, "\\bibitem[" * 200_000, "\\bibitem{" * 200_000])
def test_unclosed_bibliography_shapes_are_linear(text):
    from nerfify_ns.paper.bibtex import parse_bbl

    start = time.perf_counter()
    assert list(bib_entries(text)) == [] and parse_bbl(text) == []
    assert time.perf_counter() - start < FAST


def test_an_unclosed_bibliography_value_ends_the_parse(tmp_path):
    text = "@article{a, title={never closed\n" + "@article{b, title={x}}\n" * 50_000
    start = time.perf_counter()
    assert [k for k, _ in bib_entries(text)] == ["a"]
    assert time.perf_counter() - start < FAST


def test_an_archive_that_inflates_to_a_gigabyte_is_refused_unread(tmp_path, private_tmp):
    """About 1 MB on disk, 1 GB inflated: refused from the member's header, before its data is read."""
    bomb = inflating_tarball(tmp_path / "bomb.tar.gz", [("main.tex", 1 << 30)])
    assert bomb.stat().st_size < 2 << 20
    refused(bomb, PaperLimitError, "bomb.tar.gz", "inflates to more than")


def test_an_archive_of_many_figures_is_stopped_at_the_limit(tmp_path, private_tmp):
    """Members below the limit each, together above it: counted while streaming, figures never written."""
    limits = Limits(max_archive_bytes=8 << 20)
    bomb = inflating_tarball(tmp_path / "figs.tar.gz", [(f"fig{k}.png", 1 << 20) for k in range(64)])
    refused(bomb, PaperLimitError, "inflates to more than 8 MB", limits=limits)


def test_an_archive_never_lands_on_disk_beyond_the_limit(tmp_path, private_tmp, monkeypatch):
    """Source members are written while streaming; the disk never holds more than the limit."""
    limits = Limits(max_archive_bytes=4 << 20)
    largest = []
    write = latex_source._write_member

    def watched(tar, member, target):
        write(tar, member, target)
        root = Path(tempfile.gettempdir())
        largest.append(sum(p.stat().st_size for p in root.rglob("*") if p.is_file()))

    monkeypatch.setattr(latex_source, "_write_member", watched)
    bomb = inflating_tarball(tmp_path / "tex.tar.gz", [(f"sec{k}.tex", 1 << 20) for k in range(40)])
    refused(bomb, PaperLimitError, "inflates to more than 4 MB", limits=limits)
    assert largest and max(largest) <= 4 << 20


def test_an_oversized_archive_header_is_cut_while_decompressing(tmp_path, private_tmp):
    """A pax header of 64 MB would be read into memory by tarfile; the decompressed stream is cut first."""
    limits = Limits(max_archive_bytes=1 << 20, max_archive_files=16)
    bomb = inflating_tarball(tmp_path / "pax.tar.gz", [("pax", 64 << 20)], header_type=tarfile.XHDTYPE)
    refused(bomb, PaperLimitError, "inflates to more than 1 MB", limits=limits)


def test_an_archive_of_many_empty_members_is_refused(tmp_path, private_tmp):
    limits = Limits(max_archive_files=500)
    refused(inflating_tarball(tmp_path / "many.tar.gz", [(f"f{k}.png", 0) for k in range(600)]), PaperLimitError,
            "more than 500 members", limits=limits)


def test_links_and_escapes_in_archives_are_still_refused(tmp_path, private_tmp):
    path = tmp_path / "link.tar.gz"
    with tarfile.open(path, "w:gz") as tar:
        info = tarfile.TarInfo("main.tex")
        info.type, info.linkname = tarfile.SYMTYPE, "/etc/passwd"
        tar.addfile(info)
    refused(path, UnsafeArchiveError, "link")


def test_a_folder_with_too_many_files_is_refused(tmp_path):
    paper = latex_folder(tmp_path / "paper", "")
    for k in range(60):
        (paper / f"f{k}.txt").write_text("")
    refused(paper, PaperLimitError, "more than 50 files", limits=Limits(max_archive_files=50))
    # a single .tex file in a crowded folder is still read: the look-up of a .bib beside it stops at the limit
    assert ingest(paper / "main.tex", Limits(max_archive_files=50)).title.startswith("HostNeRF")


@pytest.mark.parametrize("suffix", [".md", ".txt"])
def test_text_beyond_the_limit_is_refused_without_reading_it_all(suffix, tmp_path):
    path = tmp_path / f"huge{suffix}"
    with open(path, "wb") as f:  # sparse: 100 MB of NUL bytes, none on disk
        f.truncate(100 << 20)
    refused(path, PaperLimitError, f"more than {DEFAULT_LIMITS.max_text_chars:,} characters")


def test_a_pdf_with_more_text_than_the_limit_is_refused(tmp_path):
    from paper_pdfs import two_column_pdf

    refused(two_column_pdf(tmp_path / "p.pdf"), PaperLimitError, "characters of text",
            limits=Limits(max_text_chars=500))


def test_a_latex_source_beyond_the_limit_is_refused(tmp_path):
    body = "The radiance field. " * 30_000
    paper = latex_folder(tmp_path / "paper", "\\input{a}\\input{b}", {"a.tex": body, "b.tex": body})
    refused(paper, PaperLimitError, "b.tex", "longer than 1,000,000 characters",
            limits=Limits(max_latex_chars=1_000_000))
    refused(paper, PaperLimitError, "a.tex", "more than 488 KB of LaTeX source", limits=Limits(max_latex_chars=500_000))


# Pathological shapes of about 250 KB: each is read or refused within FAST seconds (quadratic work would take
# minutes to hours). The same shapes at the limits' sizes (4 MB of LaTeX, 2 MB of text) run in 1-5 s each.
N = 40_000
LATEX_SHAPES = {
    "unclosed optional arguments": "\\item[" * N,
    "unclosed citations": "\\cite{" * N,
    "unclosed section options": "\\section[" * N,
    "unclosed captions": "\\begin{figure}" + "\\caption{" * N + "\\end{figure}",
    "nested figures": "\\begin{figure}" * N + "\\end{figure}",
    "blank lines of spaces": "x" + "\n \n" * N,
    "open braces": "{" * N,
    "line breaks": "\n" * (6 * N),
    "many definitions": "".join(f"\\def\\m{chr(97 + k % 26)}{chr(97 + k // 26 % 26)}{{x}}" for k in range(N // 4)),
    "unclosed macro arguments": "\\newcommand{\\f}[1]{#1#1}" + "\\f{" * N,
    "unclosed optional macro arguments": "\\newcommand{\\p}[2][a]{(#1,#2)}" + "\\p[" * N,
    "a huge align": "\\begin{align}" + "a&=b\\\\" * N + "\\end{align}",
    "dollars": "$" * N,
    "display math openers": "\\[" * N,
    "references": "\\ref{" * N,
    "a huge table": "\\begin{table}\\begin{tabular}{cc}" + "1 & 2 \\\\" * N + "\\end{tabular}\\end{table}",
}
MARKDOWN_SHAPES = {
    "unclosed display math": "$$\n" + "x = y\n" * N,
    "display math of spaces": "$$\n" + " " * (6 * N) + "\n$$\n",
    "a huge table": "| a | b |\n|---|---|\n" + "| 1 | 2 |\n" * N,
    "headings": "## 1 H\n\n" * N,
    "an unclosed fence of blank lines": "```\n" + "\n" * (6 * N),
    "citations": "see [1, 2, 3] and [4]. " * (N // 4),
    "numbers": "1 2 3 4 5 6 7 8 9 " * (N // 2),
    "sentences with numbers": "The 1. " * N,
    "duplicated math": "σ\\sigma " * 6 + "\n\n" + "\\a" * (3 * N),
    "equation cells": "".join(f"| {'α' * 900}\\alpha{'x' * 2000} | (1) |\n" for _ in range(100)),
}
MD_HEAD = ("# A NeRF paper\n\n## Abstract\n\nWe present a neural radiance field with volume rendering of the rays for "
           "the view synthesis of a scene.\n\n## Method\n\n")


def _read_or_refused(path: Path) -> None:
    start = time.perf_counter()
    try:
        ingest(path)
    except PaperError:
        pass
    assert time.perf_counter() - start < FAST


@pytest.mark.parametrize("shape", list(LATEX_SHAPES))
def test_pathological_latex_is_linear(shape, tmp_path):
    _read_or_refused(latex_folder(tmp_path / "paper", LATEX_SHAPES[shape]))


@pytest.mark.parametrize("shape", list(MARKDOWN_SHAPES))
def test_pathological_markdown_is_linear(shape, tmp_path):
    path = tmp_path / "paper.md"
    path.write_text(MD_HEAD + MARKDOWN_SHAPES[shape], encoding="utf-8")
    _read_or_refused(path)


# ----- papers not in English -----------------------------------------------------------------------------
def test_a_chinese_pdf_is_refused_as_not_english(tmp_path):
    """It used to get "no text found": the text layer is there, in another script."""
    refused(chinese_pdf(tmp_path / "zh.pdf"), NotEnglishError, "zh.pdf", "not in English", "CJK")


def test_a_german_paper_is_refused_as_not_english(tmp_path):
    refused(german_markdown(tmp_path / "de.md"), NotEnglishError, "de.md", "not in English", "English words")


def test_a_russian_text_is_refused_as_not_english(tmp_path):
    refused(russian_text(tmp_path / "ru.txt"), NotEnglishError, "ru.txt", "not in English", "CYRILLIC")


def test_a_chinese_latex_paper_is_refused_as_not_english(tmp_path):
    from hostile_papers import ZH_PARA

    paper = latex_folder(tmp_path / "paper", f"\\section{{方法}}\n{ZH_PARA * 6}\n\n{ZH_PARA * 6}\n")
    refused(paper, NotEnglishError, "not in English", "CJK")


ENGLISH = sorted(glob.glob(str(ROOT / "examples" / "*.md"))) + sorted(
    p for p in glob.glob(str(SHARED / "papers" / "*" / "*")) if not p.endswith("SOURCE.md")) + [
    str(SHARED / "reference" / "nerfify_paper.tex")]


@pytest.mark.parametrize("path", ENGLISH, ids=[Path(p).name for p in ENGLISH])
def test_english_papers_pass_the_language_check(path):
    if not Path(path).exists():
        pytest.skip(f"{path} not present (the shared folder is outside the project)")
    doc = ingest(path)
    assert doc.title
