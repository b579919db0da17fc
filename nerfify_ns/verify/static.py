"""The in-process (pure AST) part of the static rung: every file parses, the entry point names a
module file of the plugin that assigns the variable. No plugin code runs here."""

from __future__ import annotations

import ast
from typing import List

from nerfify_ns.verify.plugin import PluginInfo
from nerfify_ns.verify.report import Diagnosis


def ast_checks(info: PluginInfo) -> List[Diagnosis]:
    """Every Python file parses; the entry point names a module of the plugin assigning its variable."""
    found: List[Diagnosis] = []
    trees = {}
    for rel in info.python_files:
        try:
            trees[rel] = ast.parse((info.root / rel).read_text(), filename=rel)
        except SyntaxError as exc:
            found.append(Diagnosis("static", "syntax", f"does not parse: {exc.msg}", rel, exc.lineno))
        except (OSError, UnicodeDecodeError) as exc:
            found.append(Diagnosis("static", "syntax", f"cannot be read: {exc}", rel))
    module, _, var = info.config.partition(":")
    rel = info.module_file(module)
    if rel not in trees and rel not in {d.file for d in found}:
        found.append(
            Diagnosis(
                "static",
                "entry-point",
                f"entry point {info.config}: no module file {rel}",
                "pyproject.toml",
                info.entry_line,
            )
        )
    elif rel in trees and not any(
        isinstance(n, (ast.Assign, ast.AnnAssign)) and var in _targets(n) for n in trees[rel].body
    ):
        found.append(
            Diagnosis(
                "static",
                "entry-point",
                f"entry point {info.config}: {rel} assigns no {var}",
                "pyproject.toml",
                info.entry_line,
            )
        )
    return found


def _targets(node) -> List[str]:
    """The names an assignment binds."""
    targets = node.targets if isinstance(node, ast.Assign) else [node.target]
    return [t.id for t in targets if isinstance(t, ast.Name)]
