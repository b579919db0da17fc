"""``ns-nerfify report RUN`` re-reads a run folder that anyone may have edited (or handed over): every file is read
within bounds (size, depth, the nodes YAML aliases expand to), only files inside the run folder are read or
inlined, a part shaped wrongly is one line, and the headline printed to the terminal carries no terminal escapes.
A refused folder: one ``error:`` line, exit 2, nothing written (no report.html, no report.json)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from hostile_cli import alias_bomb, assert_one_error, deep_json, deep_yaml, run_cli, snapshot

from nerfify_ns.evaluate.report import ReportError, write_report

PNG = (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x01\x00\x00\x00\x01\x08\x02\x00\x00\x00\x90wS\xde\x00"
       b"\x00\x00\x0cIDATx\x9cc\xf8\xcf\xc0\x00\x00\x03\x01\x01\x00\xc9\xfe\x92\xef\x00\x00\x00\x00IEND\xaeB`\x82")


def _run(tmp_path: Path) -> Path:
    run = tmp_path / "run"
    (run / "eval").mkdir(parents=True)
    (run / "equations").mkdir()
    (run / "run.json").write_text(json.dumps({"ok": True, "headline": "all stages passed", "stages": []}))
    return run


def _refused(tmp_path: Path, run: Path, needle: str, cli: bool) -> None:
    """The real CLI (one line, exit 2, bounded) or, for the rest of the cases, the same call in this process
    (the CLI turns the same error into its one line); either way nothing is written."""
    before = snapshot(tmp_path)
    if cli:
        done = run_cli("report", str(run), cwd=tmp_path)
        assert_one_error(done, needle, seconds=30)
    else:
        start = time.perf_counter()
        with pytest.raises(ReportError) as err:
            write_report(run)
        assert needle in str(err.value) and "\n" not in str(err.value) and time.perf_counter() - start < 10
    assert snapshot(tmp_path) == before  # no report.html, no report.json, no temporary file


CASES = {
    "plan.yaml alias bomb": (lambda run: (run / "plan.yaml").write_text(alias_bomb()),
                             "plan.yaml expands to more than"),
    "plan.yaml 10^5 deep": (lambda run: (run / "plan.yaml").write_text(deep_yaml()), "plan.yaml nests deeper"),
    "equations.yaml alias bomb": (lambda run: (run / "equations.yaml").write_text(alias_bomb()),
                                  "equations.yaml expands to more than"),
    "run.json 10^5 deep": (lambda run: (run / "run.json").write_text(deep_json()), "run.json nests deeper"),
    "summary.json 10^5 deep": (lambda run: (run / "eval" / "summary.json").write_text(deep_json()),
                               "eval/summary.json nests deeper"),
    "diagnostics is a list": (lambda run: (run / "eval" / "summary.json").write_text(json.dumps(
        {"status": "ok", "psnr": 20.0, "diagnostics": [1, 2, 3]})), "not shaped as nerfify-ns writes it"),
    "bindings is a list": (lambda run: (run / "equations.yaml").write_text(
        "holes:\n  - {id: h, status: implemented, bindings: [a, b]}\n"), "not shaped as nerfify-ns writes it"),
    "image outside (absolute)": (lambda run: (run / "equations.yaml").write_text(
        "holes:\n  - {id: h, equations: [{number: '1', image: /etc/hostname}]}\n"), "is an absolute path"),
    "image outside (../)": (lambda run: (run / "equations.yaml").write_text(
        "holes:\n  - {id: h, equations: [{number: '1', crop: ../../secret.png}]}\n"), "resolves outside"),
    "hole id escapes": (lambda run: (run / "equations.yaml").write_text(
        "holes:\n  - {id: ../../secret, status: implemented}\n"), "resolves outside"),
    "panel symlinked out": (lambda run: (
        (run / "eval" / "error_maps.json").write_text(json.dumps([{"view": "v", "psnr": 20.0, "panel": "v.png"}])),
        (run / "eval" / "v.png").symlink_to(run.parent / "secret.png")), "resolves outside"),
    "paper.md symlinked out": (lambda run: (run / "paper.md").symlink_to(run.parent / "secret.png"),
                               "resolves outside"),
    "events folder symlinked out": (lambda run: (
        (run / "eval").rmdir(), (run / "eval").symlink_to(run.parent / "elsewhere")), "resolves outside"),
    "image header 10^5 x 10^5": (lambda run: (run / "citations.png").write_bytes(
        PNG[:16] + (100_000).to_bytes(4, "big") * 2 + PNG[24:]), "declares 100000 x 100000 pixels"),
    "a FIFO for a file": (lambda run: __import__("os").mkfifo(run / "verify.json"), "is not a regular file"),
}


THROUGH_CLI = {"plan.yaml alias bomb", "run.json 10^5 deep", "diagnostics is a list", "image outside (../)"}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_hostile_run_folder_is_one_line_and_writes_nothing(case, tmp_path):
    run = _run(tmp_path)
    (tmp_path / "secret.png").write_bytes(PNG)  # what a hostile path points at: never inlined
    (tmp_path / "secret.py").write_text("KEY = 1\n")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "summary.json").write_text('{"status": "ok"}')
    make, needle = CASES[case]
    make(run)
    _refused(tmp_path, run, needle, cli=case in THROUGH_CLI)


def test_the_headline_prints_no_terminal_escapes(tmp_path):
    run = _run(tmp_path)
    (run / "run.json").write_text(json.dumps({"ok": False, "stages": [],
                                              "headline": "\x1b]0;owned\x07\x1b[2J\x1b[31mred\rback\nnext"}))
    done = run_cli("report", str(run), cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "\x1b" not in done.stdout and "\x07" not in done.stdout and "\r" not in done.stdout
    outcome = [line for line in done.lines if line.startswith("outcome:")]
    assert len(outcome) == 1 and "\\x1b[31mred\\x0dback next" in outcome[0], done.lines


def test_images_inside_the_run_folder_are_still_inlined(tmp_path):
    run = _run(tmp_path)
    (run / "equations" / "h").mkdir()
    (run / "equations" / "h" / "eq0.png").write_bytes(PNG)
    (run / "equations.yaml").write_text("holes:\n  - {id: h, status: implemented, "
                                        "equations: [{number: '1', image: h/eq0.png}]}\n")
    done = run_cli("report", str(run), "--quiet", cwd=tmp_path)
    assert done.returncode == 0 and not done.lines, done.lines
    report = json.loads((run / "report.json").read_text())
    assert report["images"] == ["eq0.png"] and "data:image/png;base64," in (run / "report.html").read_text()
