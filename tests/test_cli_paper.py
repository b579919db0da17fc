"""`ns-nerfify PAPER` as a user runs it (a real process): the dry run, and bad input -> one line, a
non-zero exit code, and no output folder."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pymupdf
import pytest
from paper_pdfs import text_pdf, two_column_pdf

ROOT = Path(__file__).resolve().parents[1]
CLI = Path(sys.executable).with_name("ns-nerfify")
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(CLI), *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def assert_clean_failure(out: subprocess.CompletedProcess, needle: str, cwd: Path) -> None:
    lines = [line for line in out.stdout.splitlines() if line.strip()]
    assert out.returncode == 2, out.stdout + out.stderr
    assert lines[-1].startswith("error:") and needle in out.stdout, out.stdout
    assert "Traceback" not in out.stdout + out.stderr
    assert not (cwd / "nerfify-out").exists() or not any((cwd / "nerfify-out").iterdir())


def test_dry_run_prints_plan_evidence_and_holes_and_writes_nothing(tmp_path):
    out = run_cli(str(EXAMPLE), "--dry-run", cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "base nerfacto" in out.stdout
    assert "We adopt the multiresolution hash" in out.stdout  # evidence quote from the paper
    assert "hole" in out.stdout and "not implemented" in out.stdout  # the luminance prior (Eq. 2)
    assert "method: gridlite" in out.stdout
    assert list(tmp_path.iterdir()) == []


def _encrypted(path: Path) -> Path:
    doc = pymupdf.open()
    doc.new_page().insert_text((72, 72), "Neural radiance fields")
    doc.save(path, encryption=pymupdf.PDF_ENCRYPT_AES_256, user_pw="user", owner_pw="owner")
    return path


def _scanned(path: Path) -> Path:
    doc = pymupdf.open()
    page = doc.new_page()
    pix = pymupdf.Pixmap(pymupdf.csRGB, pymupdf.IRect(0, 0, 200, 200), False)
    pix.clear_with(200)
    page.insert_image(page.rect, pixmap=pix)
    doc.save(path)
    return path


def _blank(path: Path) -> Path:
    doc = pymupdf.open()
    doc.new_page()
    doc.save(path)
    return path


def _not_nerf(path: Path) -> Path:
    return text_pdf(path, ["We study transaction isolation in relational databases and propose a lock manager "
                           "for B-trees with lower contention under write-heavy workloads."] * 3,
                    "Lock-Free B-Tree Indexing for OLTP Databases")


def _latex_missing_input(path: Path) -> Path:
    path.mkdir()
    (path / "main.tex").write_text("\\documentclass{article}\\title{FooNeRF}\\begin{document}\\maketitle\n"
                                   "\\input{sections/method}\n\\end{document}\n")
    return path


def _huge(path: Path) -> Path:
    with open(path, "wb") as f:  # sparse: no disk space used, but larger than the 200 MB limit
        f.truncate(201 * 1024 * 1024)
    return path


BAD = {
    "encrypted PDF": (_encrypted, "enc.pdf", "encrypted"),
    "corrupt PDF": (lambda p: (p.write_bytes(b"%PDF-1.7\n" + b"\x00garbage" * 50), p)[1], "bad.pdf",
                    "cannot open the PDF"),
    "scanned PDF": (_scanned, "scan.pdf", "scanned"),
    "empty PDF": (_blank, "blank.pdf", "no text"),
    "zero-byte file": (lambda p: (p.write_bytes(b""), p)[1], "zero.pdf", "empty"),
    "not a NeRF paper": (_not_nerf, "db.pdf", "NeRF"),
    "LaTeX with a missing file": (_latex_missing_input, "latex", "sections/method"),
    "huge input": (_huge, "huge.pdf", "more than the limit"),
    "unsupported input": (lambda p: (p.write_text("x"), p)[1], "paper.docx", "docx"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_gets_one_line_and_leaves_nothing(case, tmp_path):
    make, name, needle = BAD[case]
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    paper = make(inputs / name)
    work = tmp_path / "work"
    work.mkdir()
    out = run_cli(str(paper), cwd=work)
    assert_clean_failure(out, needle, work)


def test_existing_output_folder_is_refused(tmp_path):
    paper = two_column_pdf(tmp_path / "tiny.pdf")
    target = tmp_path / "nerfify-out" / "mine"
    target.mkdir(parents=True)
    (target / "notes.txt").write_text("keep me")
    out = run_cli(str(paper), "--out", str(target), cwd=tmp_path)
    assert out.returncode == 2 and "exists and is not empty" in out.stdout
    assert (target / "notes.txt").read_text() == "keep me" and sorted(p.name for p in target.iterdir()) == ["notes.txt"]


def test_compose_a_reference_plan_until_the_plugin(tmp_path):
    env_cache = tmp_path / "cache"
    out = subprocess.run([str(CLI), "compose", "--method", "kplanes-static", "--until", "plugin", "--out",
                          str(tmp_path / "kp")], capture_output=True, text=True, cwd=tmp_path, timeout=300,
                         env={**__import__("os").environ, "NERFIFY_CACHE": str(env_cache)})
    assert out.returncode == 0, out.stdout + out.stderr
    plugin = tmp_path / "kp"
    assert (plugin / "kplanes_static" / "model.py").is_file() and (plugin / "scene" / "scene.json").is_file()
    plan = __import__("yaml").safe_load((plugin / "plan.yaml").read_text())
    assert any(r["rule"] == "kplanes_resolution_for_small_images" for r in plan["pruned"])
    assert "pruned" in out.stdout and "ns-train nerfify-generated" in out.stdout
    assert "not run: verify, train" in out.stdout and not (plugin / "verify.json").exists()
    assert f"NERFIFY_GENERATED={plugin} ns-train nerfify-generated" in out.stdout
    assert not env_cache.exists()  # no global "last generated" pointer


def test_compose_needs_exactly_one_plan_source(tmp_path):
    out = run_cli("compose", cwd=tmp_path)
    assert out.returncode == 2 and "give a plan file or --method NAME" in out.stdout
