"""Recorded code repairs, re-applied after rendering.

When the verification ladder repairs a generated plugin and the fix has no plan equivalent, it records
the fix in the plan's ``repairs`` annotation (file, unified diff, rule, reason). :func:`reapply_repairs`
runs at the end of :func:`nerfify_ns.synthesis.compose.write_plugin`: each recorded diff is applied to
the freshly rendered file; one already present is left as it is; one that no longer applies (the
template or the plan changed the lines it touched) is reported in the plugin's README, never dropped
silently.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from nerfify_ns.errors import NerfifyError

REPAIRS_KEY = "repairs"
HUNK = re.compile(r"^@@ -(\d+)(?:,(\d+))? \+(\d+)(?:,(\d+))? @@")


class DiffError(NerfifyError):
    """A unified diff that cannot be read, or does not apply to the text it is meant for."""


@dataclass
class Hunk:
    """One hunk: where it starts in the old text (1-based), the old lines and the new lines."""

    start: int
    old: list[str]
    new: list[str]


def parse_hunks(diff: str) -> list[Hunk]:
    """The hunks of a one-file unified diff; a hunk's body is read by its line counts, so a removed line
    that starts with ``--`` is not taken for a header."""
    hunks: list[Hunk] = []
    old_left = new_left = 0
    for line in diff.splitlines(True):
        if old_left <= 0 and new_left <= 0:
            match = HUNK.match(line)
            if match:
                hunks.append(Hunk(int(match.group(1)), [], []))
                old_left = int(match.group(2)) if match.group(2) is not None else 1
                new_left = int(match.group(4)) if match.group(4) is not None else 1
            elif not line.startswith(("--- ", "+++ ", "diff ", "\\")):
                raise DiffError(f"not a unified diff line: {line[:60]!r}")
            continue
        kind, body = line[:1], line[1:]
        if kind == "\\":
            continue  # "\ No newline at end of file"
        if kind in (" ", "-"):
            hunks[-1].old.append(body)
            old_left -= 1
        if kind in (" ", "+"):
            hunks[-1].new.append(body)
            new_left -= 1
        if kind not in (" ", "-", "+"):
            raise DiffError(f"not a unified diff line: {line[:60]!r}")
    if not hunks:
        raise DiffError("the diff has no hunks")
    if old_left > 0 or new_left > 0:
        raise DiffError("the diff ends inside a hunk")
    return hunks


def _find(lines: Sequence[str], block: Sequence[str], near: int, after: int) -> int:
    """Where ``block`` occurs in ``lines`` from ``after`` on, the occurrence nearest ``near``; -1: none."""
    n = len(block)
    hits = [i for i in range(after, len(lines) - n + 1) if list(lines[i:i + n]) == list(block)]
    return min(hits, key=lambda i: abs(i - near)) if hits else -1


def apply_hunks(text: str, hunks: Sequence[Hunk]) -> str:
    """``text`` with ``hunks`` applied exactly (every context and removed line must match; a hunk may have
    moved, as ``patch`` allows, but not changed). Raises DiffError otherwise."""
    lines = text.splitlines(True)
    out: list[str] = []
    position = 0
    for hunk in hunks:
        at = _find(lines, hunk.old, hunk.start - 1, position)
        if at < 0:
            raise DiffError(f"the lines of the hunk at line {hunk.start} are not in the file")
        out += lines[position:at] + hunk.new
        position = at + len(hunk.old)
    return "".join(out + lines[position:])


def apply_diff(text: str, diff: str) -> str:
    """``text`` with the unified ``diff`` applied exactly (:func:`apply_hunks`)."""
    return apply_hunks(text, parse_hunks(diff))


def is_applied(text: str, diff: str) -> bool:
    """Whether ``text`` already holds what ``diff`` makes (undoing it would apply exactly)."""
    try:
        apply_hunks(text, [Hunk(h.start, h.new, h.old) for h in parse_hunks(diff)])
    except DiffError:
        return False
    return True


def diff_text(diff) -> str:
    """A recorded diff as text: ``plan.yaml`` keeps it as a list of lines (a string is taken as it is)."""
    if isinstance(diff, list):
        return "".join(f"{line}\n" for line in diff)
    return str(diff or "")


def reapply_one(folder: Path, repair: dict) -> tuple[str, str]:
    """Apply one recorded repair in ``folder``: (status, detail) with status ``applied``, ``already present``
    or ``does not apply``."""
    rel = str(repair.get("file") or "")
    path = Path(folder) / rel
    if not rel or not path.is_file():
        return "does not apply", f"no file {rel or '(none named)'} in the plugin"
    text = path.read_text()
    diff = diff_text(repair.get("diff"))
    try:
        path.write_text(apply_diff(text, diff))
        return "applied", ""
    except DiffError as exc:
        if is_applied(text, diff):
            return "already present", ""
        return "does not apply", f"{exc} (the rendered file differs from the one that was repaired)"


def reapply_repairs(plan: dict, folder: Path) -> list[dict]:
    """Re-apply every code repair recorded in ``plan['repairs']`` to the plugin rendered in ``folder``; each
    outcome (file, rule, reason, status, detail) is returned and listed in the plugin's README."""
    outcomes = []
    for repair in plan.get(REPAIRS_KEY) or []:
        if not isinstance(repair, dict):
            continue
        status, detail = reapply_one(folder, repair)
        outcomes.append({"file": repair.get("file"), "rule": repair.get("rule"),
                         "reason": repair.get("reason"), "status": status, "detail": detail})
    if outcomes:
        _readme_section(Path(folder) / "README.md", outcomes)
    return outcomes


def _readme_section(readme: Path, outcomes: list[dict]) -> None:
    """Append the recorded repairs and what became of each to the plugin's README."""
    lines = ["", "## Recorded repairs", "",
             "Repairs the verification ladder made to an earlier rendering of this plan (`plan.yaml`, "
             "`repairs`), re-applied after rendering:", ""]
    for o in outcomes:
        detail = f": {o['detail']}" if o["detail"] else ""
        lines.append(f"- `{o['file']}` ({o['rule']}): {o['reason']} -- **{o['status']}**{detail}")
    text = readme.read_text() if readme.is_file() else ""
    readme.write_text(text.rstrip("\n") + "\n" + "\n".join(lines) + "\n")
