"""The run folder's file names live in one module (``nerfify_ns/runfolder.py``): no other module of the package writes
one of them as a string literal."""

from __future__ import annotations

import ast
from pathlib import Path

from nerfify_ns import runfolder

PACKAGE = Path(runfolder.__file__).parent
OWN_FOLDERS = ("benchmarks",)
"""The performance scripts write their own result folders (a ``summary.json`` of a benchmark), not run folders."""


def _literals(path: Path) -> list[tuple[int, str]]:
    """(line, value) of every string constant of ``path`` equal to a run-folder file name (f-string parts included,
    docstrings excluded: they are text, a name inside a sentence is never equal to the name)."""
    names = set(runfolder.FILES)
    return [(node.lineno, node.value) for node in ast.walk(ast.parse(path.read_text(), str(path)))
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in names]


def test_run_folder_names_are_written_only_in_the_layout_module():
    found = [f"{path.relative_to(PACKAGE.parent)}:{line}: {value!r}"
             for path in sorted(PACKAGE.rglob("*.py"))
             if path != Path(runfolder.__file__) and not any(p in OWN_FOLDERS for p in path.relative_to(PACKAGE).parts)
             for line, value in _literals(path)]
    assert not found, "use nerfify_ns.runfolder's constants:\n" + "\n".join(found)


def test_the_scan_sees_a_literal(tmp_path):
    """The scan finds a name in a plain string and inside an f-string's expression (so the test above can fail)."""
    probe = tmp_path / "probe.py"
    probe.write_text('a = folder / "plan.yaml"\nb = f"{out / \'report.html\'}"\nc = "see plan.yaml"\n')
    assert _literals(probe) == [(1, runfolder.PLAN), (2, runfolder.REPORT_HTML)]


def test_the_names_are_unique_and_plain():
    assert len(set(runfolder.FILES)) == len(runfolder.FILES)
    assert all("/" not in name and "." in name for name in runfolder.FILES)
