"""One LaTeX normaliser: how converters' noise is removed lives in ``equations/normalize.py`` alone, its two forms
(the canonical LaTeX a Document stores, the reader's column-keeping pieces) read one table of commands, and the
``equations`` package never imports the ``paper`` package (imports flow one way)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

import nerfify_ns
from nerfify_ns.equations.normalize import (
    BOLD_COMMANDS,
    FONT_DECLARATIONS,
    SIZE_COMMANDS,
    STYLE_COMMANDS,
    normalize,
    normalize_latex,
)

PACKAGE = Path(nerfify_ns.__file__).parent
BOLD = re.compile(r"(?<![A-Za-z])(?:pmb|boldsymbol)(?![A-Za-z])")
STYLE = re.compile(r"(?<![A-Za-z])(?:displaystyle|scriptstyle)(?![A-Za-z])")


def _strings(tree: ast.AST) -> list[str]:
    """The string constants of a module, its docstrings left out (a docstring may name a command)."""
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                docstrings.add(id(first.value))
    return [n.value for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docstrings]


def test_one_module_of_the_package_normalises_latex():
    """A module whose code names both a spelling of bold and a math style to rewrite is a LaTeX normaliser;
    there is one."""
    normalisers = []
    for path in sorted(PACKAGE.rglob("*.py")):
        strings = _strings(ast.parse(path.read_text(encoding="utf-8")))
        if any(BOLD.search(s) for s in strings) and any(STYLE.search(s) for s in strings):
            normalisers.append(path.relative_to(PACKAGE).as_posix())
    assert normalisers == ["equations/normalize.py"]


@pytest.mark.parametrize("command", STYLE_COMMANDS + SIZE_COMMANDS)
def test_both_forms_remove_a_style_or_size_command_of_the_one_table(command):
    latex = rf"y = \{command} x + 1"
    assert normalize_latex(latex) == "y = x + 1"
    (piece,) = normalize(latex).pieces
    assert command not in piece.text and " ".join(piece.text.split()) == "y = x + 1"


@pytest.mark.parametrize("command", BOLD_COMMANDS)
def test_both_forms_read_every_spelling_of_bold_from_the_one_table(command):
    latex = rf"\{command}{{c}} = \sigma"
    assert normalize_latex(latex) == r"\mathbf{c} = \sigma"
    (piece,) = normalize(latex).pieces
    assert " ".join(piece.text.replace("{", " ").replace("}", " ").split()) == r"c = \sigma"


@pytest.mark.parametrize("declaration", sorted(FONT_DECLARATIONS))
def test_both_forms_read_a_font_declaration_as_its_command(declaration):
    command = FONT_DECLARATIONS[declaration]
    assert normalize_latex(rf"{{\{declaration} L}} = x") == rf"{command}{{L}} = x"
    (piece,) = normalize(rf"{{\{declaration} L}} = x").pieces
    assert f"\\{declaration} " not in piece.text and "L" in piece.text


def test_both_forms_restore_a_lost_subscript_and_a_lost_row_break():
    assert normalize_latex(r"P*{\mathrm{new}} = (a)*{b}") == r"P_{\mathrm{new}} = (a)_{b}"
    (piece,) = normalize(r"P*{\mathrm{new}} = (a)*{b}").pieces
    assert re.sub(r"\s", "", piece.text) == r"P_{\mathrm{new}}=(a)_{b}"
    assert [re.sub(r"\s", "", p.text) for p in normalize("a = b [2pt] c = d").pieces] == ["a=b", "c=d"]
    assert normalize_latex("\\begin{array}{l} a = b\\\\ \\end{array}", lost_backslashes=True) == "a = b"


def test_the_equations_package_never_imports_the_paper_package():
    offenders = []
    for path in sorted((PACKAGE / "equations").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
            offenders += [f"{path.name}: {n}" for n in names if n.startswith("nerfify_ns.paper")]
    assert offenders == []
