"""The pure-AST part of the static rung: every file parses, the entry point names a module file of the plugin
that assigns the variable. No plugin code runs here, but parsing untrusted code can still exhaust the parser
(a 300,000-deep expression: RecursionError, MemoryError, or worse), so the ladder runs it as a sandboxed
subprocess with limits (:func:`nerfify_ns.verify.rungs.static_ast`)::

    python -m nerfify_ns.verify.static PLUGIN_DIR EVENTS_JSONL

writes one JSON object per line: ``{"event": "parsing", "file"}`` before each file, each diagnosis, and
``{"event": "end"}``; a crash leaves the file being parsed as the last ``parsing`` event.
"""

from __future__ import annotations

import ast
import json
import sys
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

from nerfify_ns.verify.plugin import PluginInfo, plugin_file
from nerfify_ns.verify.verdicts import Diagnosis

MAX_SOURCE_BYTES = 4 << 20
"""A plugin module larger than this is refused unparsed (generated ones are a few kilobytes)."""


def ast_checks(info: PluginInfo, on_file: Callable[[str], None] | None = None) -> list[Diagnosis]:
    """Every Python file parses; the entry point names a module of the plugin assigning its variable.
    ``on_file(rel)`` is called before each file is parsed."""
    found: list[Diagnosis] = []
    trees = {}
    for rel in info.python_files:
        if on_file is not None:
            on_file(rel)
        path = info.root / rel
        if plugin_file(info.root, rel) is None:
            found.append(Diagnosis("static", "syntax", "not a regular file inside the plugin folder (a link "
                                   "leading out of it?)", rel))
            continue
        try:
            if path.stat().st_size > MAX_SOURCE_BYTES:
                found.append(Diagnosis("static", "syntax", f"too large to parse ({path.stat().st_size} bytes, at "
                                       f"most {MAX_SOURCE_BYTES})", rel))
                continue
            trees[rel] = ast.parse(path.read_text(), filename=rel)
        except SyntaxError as exc:
            found.append(Diagnosis("static", "syntax", f"does not parse: {exc.msg}", rel, exc.lineno))
        except (RecursionError, MemoryError) as exc:
            found.append(Diagnosis("static", "syntax", f"does not parse: too deeply nested or too complex for the "
                                   f"parser ({type(exc).__name__}: {exc})", rel))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
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
        isinstance(n, ast.Assign | ast.AnnAssign) and var in _targets(n) for n in trees[rel].body
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


def _targets(node) -> list[str]:
    """The names an assignment binds."""
    targets = node.targets if isinstance(node, ast.Assign) else [node.target]
    return [t.id for t in targets if isinstance(t, ast.Name)]


def main(argv=None) -> int:
    """Parse the plugin in ``argv[0]``, writing events to ``argv[1]`` (run only sandboxed)."""
    from nerfify_ns.verify.plugin import load_plugin

    plugin, events_path = (argv if argv is not None else sys.argv[1:])[:2]
    with open(events_path, "a") as events:
        def emit(**event) -> None:
            events.write(json.dumps(event, default=str) + "\n")
            events.flush()

        info = load_plugin(Path(plugin))
        for d in ast_checks(info, on_file=lambda rel: emit(event="parsing", file=rel)):
            emit(event="diagnosis", **asdict(d))
        emit(event="end", files=len(info.python_files))
    return 0


if __name__ == "__main__":
    sys.exit(main())
