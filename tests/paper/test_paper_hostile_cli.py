"""Hostile papers through the real CLI: `ns-nerfify PAPER` answers one `error:` line and
exit code 2, fast, writes nothing (no output folder, no staging folder, nothing left in the temporary folder),
and prints no host content (a secret in its environment, a canary file beside the paper). Paper text made of
rich markup and terminal escapes is printed as text. Every case of its kind is also tested in process
(test_paper_hostile.py); here one per kind, since each run starts a process."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from hostile_papers import (
    MAIN,
    big_bib,
    chinese_pdf,
    include_tree,
    inflating_tarball,
    latex_folder,
    macro_bomb,
    outside_canary,
    tarball,
    token,
)

ROOT = Path(__file__).resolve().parents[2]
CLI = Path(sys.executable).with_name("ns-nerfify")
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"


def run_cli(*args: str, cwd: Path, env: dict) -> subprocess.CompletedProcess:
    clean = {k: v for k, v in os.environ.items() if k not in ("FORCE_COLOR", "CLICOLOR_FORCE", "TTY_COMPATIBLE")}
    return subprocess.run([str(CLI), *args], capture_output=True, text=True, cwd=cwd, timeout=120,
                          env={**clean, "COLUMNS": "200", **env})


def _hostname() -> str:
    try:
        return Path("/etc/hostname").read_text().strip()
    except OSError:
        return ""


def _secret_folder(tmp: Path) -> Path:
    return latex_folder(tmp / "paper", "\\input{/proc/self/environ}")


def _canary_folder(tmp: Path) -> Path:
    return latex_folder(tmp / "paper", "\\input{../outside/canary}")


def _canary_link(tmp: Path) -> Path:
    paper = latex_folder(tmp / "paper", "\\input{sections/intro}")
    (paper / "sections").mkdir()
    os.symlink(tmp / "outside" / "canary.tex", paper / "sections" / "intro.tex")
    return paper


def _hostname_tarball(tmp: Path) -> Path:
    return tarball(tmp / "src.tar.gz", {"main.tex": MAIN.format(body="\\input{../../../../etc/hostname}")})


def _bib(tmp: Path) -> Path:
    paper = latex_folder(tmp / "paper", "\\cite{key1}\\bibliography{refs}")
    big_bib(paper / "refs.bib", 100_000, pad=60)
    return paper


HOSTILE = {  # maker (given the inputs folder), what the error line says
    "input of /proc/self/environ": (_secret_folder, "\\input{/proc/self/environ} points outside the paper"),
    "input of a canary beside the folder": (_canary_folder, "\\input{../outside/canary} points outside the paper"),
    "link to a canary beside the folder": (_canary_link, "sections/intro.tex: leads outside the paper"),
    "tarball input of /etc/hostname": (_hostname_tarball, "etc/hostname} points outside the paper"),
    "include tree": (lambda tmp: include_tree(tmp / "paper"), "deeper than 16 (the limit)"),
    "macro bomb": (lambda tmp: macro_bomb(tmp / "paper"), "expanding the paper's macros"),
    "archive inflating to 1 GB": (lambda tmp: inflating_tarball(tmp / "bomb.tar.gz", [("main.tex", 1 << 30)]),
                                  "bomb.tar.gz: the archive inflates to more than 256 MB"),
    "bibliography of 100,000 entries": (_bib, "bibliography files are larger than 16 MB"),
    "Chinese PDF": (lambda tmp: chinese_pdf(tmp / "zh.pdf"), "zh.pdf: the paper's text is not in English"),
}


PROCESS = ("input of /proc/self/environ", "archive inflating to 1 GB")
"""Run as a real ``ns-nerfify`` process too (each process costs seconds of start-up; the others run the same
command line in this process, through the CLI's own ``_run``)."""


def _setup(case: str, tmp_path: Path):
    make, needle = HOSTILE[case]
    inputs, work, tmp = tmp_path / "inputs", tmp_path / "work", tmp_path / "tmp"
    for folder in (inputs, work, tmp):
        folder.mkdir()
    _, canary = outside_canary(inputs)
    return make(inputs), needle, work, tmp, (canary, token())


def _assert_refused(code: int, stdout: str, stderr: str, needle: str, work: Path, tmp: Path, leaks: tuple) -> None:
    lines = [line for line in stdout.splitlines() if line.strip()]
    assert code == 2, stdout + stderr
    assert len(lines) == 1 and lines[0].startswith("error:") and needle in stdout, stdout
    assert "Traceback" not in stdout + stderr
    hostname = _hostname()
    for leak in (*leaks, "NERFIFY_TEST_SECRET", *([hostname] if len(hostname) >= 6 else [])):
        assert leak not in stdout + stderr, leak
    assert list(work.iterdir()) == [], "an output or staging folder was left behind"
    assert list(tmp.iterdir()) == [], "extraction left files in the temporary folder"


@pytest.mark.parametrize("case", list(HOSTILE))
def test_hostile_paper_gets_one_line_exit_2_and_leaves_nothing(case, tmp_path, monkeypatch, capsys):
    from nerfify_ns import cli

    paper, needle, work, tmp, (canary, secret) = _setup(case, tmp_path)
    monkeypatch.chdir(work)
    monkeypatch.setenv("NERFIFY_TEST_SECRET", secret)
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr(tempfile, "tempdir", None)
    start = time.perf_counter()
    code = cli._run(["paper", str(paper)])
    seconds = time.perf_counter() - start
    out = capsys.readouterr()
    _assert_refused(code, out.out, out.err, needle, work, tmp, (canary, secret))
    assert seconds < 10, f"{seconds:.1f} s"


@pytest.mark.parametrize("case", PROCESS)
def test_hostile_paper_through_the_ns_nerfify_process(case, tmp_path):
    paper, needle, work, tmp, (canary, secret) = _setup(case, tmp_path)
    out = run_cli(str(paper), cwd=work, env={"NERFIFY_TEST_SECRET": secret, "TMPDIR": str(tmp)})
    _assert_refused(out.returncode, out.stdout, out.stderr, needle, work, tmp, (canary, secret))


def _markup_paper(path: Path) -> Path:
    """The example paper with rich markup, terminal escapes and HTML in its title and in a quoted sentence."""
    text = EXAMPLE.read_text(encoding="utf-8")
    title = "GridLite [/bold] \x1b[31mRED\x1b[0m <script>alert(1)</script>"
    text = text.replace("# GridLite:", f"# {title}:", 1)
    text = text.replace("We adopt the multiresolution hash",
                        "We adopt [/bold] \x1b]0;pwned\x07 the multiresolution hash")
    assert title in text and "[/bold] \x1b]0" in text
    path.write_text(text, encoding="utf-8")
    return path


def _printed_as_text(out: subprocess.CompletedProcess) -> None:
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Traceback" not in out.stdout + out.stderr and "MarkupError" not in out.stdout + out.stderr
    assert "\x1b" not in out.stdout + out.stderr and "\x07" not in out.stdout + out.stderr  # no raw escape
    assert "GridLite [/bold] \\x1b[31mRED\\x1b[0m <script>" in out.stdout  # shown, escaped


def test_paper_text_with_markup_and_escapes_is_printed_as_text(tmp_path):
    """The dry run prints the title and the evidence quotes (the table that crashed on '[/bold]')."""
    paper = _markup_paper(tmp_path / "markup.md")
    work = tmp_path / "work"
    work.mkdir()
    out = run_cli(str(paper), "--dry-run", cwd=work, env={})
    _printed_as_text(out)
    assert "We adopt [/bold] \\x1b]0;pwned\\x07" in out.stdout.replace("\n", " ") or "\\x1b]0;pwned" in out.stdout
    assert list(work.iterdir()) == []


def test_paper_text_with_markup_is_escaped_in_the_console_and_the_report(tmp_path):
    paper = _markup_paper(tmp_path / "markup.md")
    work = tmp_path / "work"
    work.mkdir()
    out = run_cli(str(paper), "--until", "plan", cwd=work, env={})
    _printed_as_text(out)
    reports = list(work.glob("nerfify-out/*/report.html"))
    assert len(reports) == 1, out.stdout
    html = reports[0].read_text(encoding="utf-8")
    assert "<script>alert(1)</script>" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html


def test_an_error_naming_markup_is_one_line(tmp_path):
    """A paper that is not about NeRF gets its error line with its title in it, markup and escapes shown."""
    from paper_pdfs import text_pdf

    paper = text_pdf(tmp_path / "db.pdf", ["We study transaction isolation in relational databases and propose a "
                                           "lock manager for B-trees with lower contention under write-heavy "
                                           "workloads."] * 3, "Lock-Free [/bold] B-Trees [red]for OLTP")
    work = tmp_path / "work"
    work.mkdir()
    out = run_cli(str(paper), cwd=work, env={})
    lines = [line for line in out.stdout.splitlines() if line.strip()]
    assert out.returncode == 2 and len(lines) == 1 and lines[0].startswith("error:"), out.stdout + out.stderr
    assert "Lock-Free [/bold] B-Trees [red]for OLTP" in out.stdout and "Traceback" not in out.stdout + out.stderr
    assert list(work.iterdir()) == []
