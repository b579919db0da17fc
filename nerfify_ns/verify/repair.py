"""Repair: deterministic fixes for common failures, as revertible unified-diff patches.

A ``Fixer`` turns diagnoses into ``CodePatch``es (whole-file replacements recorded as unified diffs);
the ladder applies them (or, reporting only, applies them to a scratch copy), records them under
``<out>/patches/`` and re-runs. A fix that has a plan equivalent carries it as ``PlanEdit``s, so a
generated plugin's ``plan.yaml`` can record it (:func:`record_in_plan`); any other fix is recorded in
the plan's ``repairs`` annotation, which the composer re-applies after rendering. A model-backed fixer
implements the same protocol.
"""

from __future__ import annotations

import ast
import copy
import difflib
import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

from nerfify_ns.plan import Plan
from nerfify_ns.verify.errors import VerifyError
from nerfify_ns.verify.plugin import PluginInfo, plugin_file
from nerfify_ns.verify.verdicts import Diagnosis

NAME_CUTOFF = 0.6
"""difflib similarity above which an optimiser key without a group is a misspelling of a group without one."""

EXP_CAP = 20.0
"""Pre-activation cap for exp-type density activations: exp(20) ~ 4.9e8."""


@dataclass
class PlanEdit:
    """The plan equivalent of a code repair: ``set`` ``path`` to ``value``, ``rename`` ``path`` to the path
    ``value`` (same parent, its value and place kept), or ``delete`` ``path``."""

    op: str
    path: str
    value: Any = None

    def apply(self, plan: Plan) -> bool:
        """Apply to ``plan`` in place; whether it changed the plan."""
        if self.op == "set":
            if plan.has(self.path) and plan.get(self.path) == self.value:
                return False
            plan.set(self.path, copy.deepcopy(self.value))
            return True
        if self.op == "delete":
            return plan.delete(self.path) is not None
        if self.op == "rename":
            return _rename(plan, self.path, str(self.value))
        raise ValueError(f"unknown plan edit {self.op!r} (set, rename, delete)")


def _rename(plan: Plan, path: str, new_path: str) -> bool:
    """Rename the last key of ``path`` to that of ``new_path`` in place (same parent; False when absent or
    taken)."""
    parent, key = plan.parent(path)
    new_parent, new_key = plan.parent(new_path)
    if parent is None or key not in parent or new_parent is not parent or new_key in parent:
        return False
    items = list(parent.items())
    parent.clear()
    parent.update((new_key if k == key else k, v) for k, v in items)
    return True


@dataclass
class CodePatch:
    """A change to one file of the plugin, with why (and its plan equivalent, where there is one).
    (The patch loop's ``PlanPatch`` changes a plan; a ``CodePatch`` changes plugin code.)"""

    file: str
    before: str
    after: str
    rule: str
    reason: str
    fixer: str = ""
    plan_edits: list[PlanEdit] = field(default_factory=list)

    def diff(self) -> str:
        return "".join(
            difflib.unified_diff(
                self.before.splitlines(True), self.after.splitlines(True), f"a/{self.file}", f"b/{self.file}"
            )
        )

    def apply(self, root: Path) -> None:
        if plugin_file(root, self.file) is None:
            raise VerifyError(f"refusing to patch {self.file!r}: not a file inside the plugin folder {root}")
        (root / self.file).write_text(self.after)

    def revert(self, root: Path) -> None:
        (root / self.file).write_text(self.before)

    def summary(self) -> dict:
        return {k: v for k, v in asdict(self).items() if k not in ("before", "after")}


class Fixer(Protocol):
    """Turns the diagnoses of a failed round into patches (none: it has nothing to offer)."""

    name: str

    def propose(self, info: PluginInfo, diagnoses: Sequence[Diagnosis]) -> list[CodePatch]: ...


def _read(info: PluginInfo, rel: str) -> str:
    """A file of the plugin (only a regular file inside its folder: diagnoses name files the probe reported)."""
    if plugin_file(info.root, rel) is None:
        raise VerifyError(f"{rel!r} is not a file inside the plugin folder")
    return (info.root / rel).read_text()


def _offset(text: str, lineno: int, col: int) -> int:
    """The character offset of an AST position (``col`` counts UTF-8 bytes)."""
    lines = text.splitlines(True)
    line = lines[lineno - 1] if lineno - 1 < len(lines) else ""
    return sum(len(earlier) for earlier in lines[: lineno - 1]) + len(line.encode()[:col].decode(errors="ignore"))


def _span(text: str, node: ast.AST) -> tuple[int, int]:
    return _offset(text, node.lineno, node.col_offset), _offset(text, node.end_lineno, node.end_col_offset)


def _segment_replace(text: str, node: ast.AST, new: str) -> str:
    start, end = _span(text, node)
    return text[:start] + new + text[end:]


def _splice(text: str, edits: list[tuple[int, int, str]]) -> str:
    """Replace the character ranges ``(start, end, new)`` (not overlapping), last first."""
    for start, end, new in sorted(edits, reverse=True):
        text = text[:start] + new + text[end:]
    return text


def _line_start(text: str, pos: int) -> int:
    """The start of ``pos``'s line when only blanks precede it there, else ``pos``."""
    start = text.rfind("\n", 0, pos) + 1
    return start if not text[start:pos].strip() else pos


def _entry_end(text: str, pos: int, own_line: bool) -> int:
    """Past a dict entry ending at ``pos``: its comma, a trailing comment and (own line) the newline."""
    while pos < len(text) and text[pos] in " \t":
        pos += 1
    if pos < len(text) and text[pos] == ",":
        pos += 1
    rest = text.find("\n", pos)
    rest = len(text) if rest < 0 else rest
    if own_line and (not text[pos:rest].strip() or text[pos:rest].strip().startswith("#")):
        return min(rest + 1, len(text))
    while pos < len(text) and text[pos] in " \t":
        pos += 1
    return pos


def _group_names(d: Diagnosis, key: str, marker: str) -> list[str]:
    """``missing`` / ``extra`` of a param-groups diagnosis: from its data, else parsed from its message."""
    if isinstance(d.data.get(key), list):
        return [str(x) for x in d.data[key]]
    if marker not in d.message:
        return []
    return re.findall(r"'([^']+)'", d.message.split(marker)[1].split(";")[0])


def pair_misspelled(missing: Sequence[str], extra: Sequence[str]) -> dict[str, str]:
    """``{extra key: missing group}`` for every optimiser key that is a close misspelling (difflib) of a
    parameter group without an optimiser; each name is used once, closest pairs first."""
    scored = sorted(((difflib.SequenceMatcher(None, e, m).ratio(), e, m) for e in extra for m in missing),
                    reverse=True)
    pairs: dict[str, str] = {}
    for ratio, e, m in scored:
        if ratio >= NAME_CUTOFF and e not in pairs and m not in pairs.values():
            pairs[e] = m
    return pairs


def _optimizers_dict(text: str, line: int | None) -> ast.Dict | None:
    """The ``optimizers={...}`` dict literal (the one on ``line`` when there are several)."""
    found = [n for n in ast.walk(ast.parse(text))
             if isinstance(n, ast.keyword) and n.arg == "optimizers" and isinstance(n.value, ast.Dict)]
    candidates = [n for n in found if line in (n.lineno, n.value.lineno)] or found
    return candidates[0].value if candidates else None


def _quoted(key_source: str, name: str) -> str:
    """``name`` as a string literal in the quote style of ``key_source``."""
    quote = key_source[0] if key_source[:1] in ("'", '"') else '"'
    return f"{quote}{name}{quote}"


class OptimizerGroupFixer:
    """Optimiser keys must equal the model's parameter groups. A key without a group that is a close
    misspelling of a group without an optimiser is renamed (its settings, the author's, are kept); a group
    with no such key gets a copy of the ``fields`` optimiser; a key with no group left is removed. The dict
    literal is edited in place, so the rest of the file (comments, layout) stays as it was."""

    name = "optimizer-groups"

    def propose(self, info, diagnoses):
        patches = []
        for d in diagnoses:
            if d.rule != "param-groups" or not d.file or not d.line:
                continue
            patch = self._patch(info, d)
            if patch is not None:
                patches.append(patch)
        return patches

    def _patch(self, info: PluginInfo, d: Diagnosis) -> CodePatch | None:
        text = _read(info, d.file)
        missing = _group_names(d, "missing", "missing optimizers:")
        extra = _group_names(d, "extra", "without a group:")
        node = _optimizers_dict(text, d.line)
        if node is None or not (missing or extra):
            return None
        keys = {k.value: k for k in node.keys if isinstance(k, ast.Constant) and isinstance(k.value, str)}
        values = {k.value: v for k, v in zip(node.keys, node.values, strict=False) if isinstance(k, ast.Constant)}
        renames = {e: m for e, m in pair_misspelled(missing, extra).items() if e in keys}
        added = [m for m in missing if m not in renames.values()]
        removed = [e for e in extra if e in keys and e not in renames]
        template = values.get("fields") or next((v for k, v in values.items() if k not in extra), None)
        if added and template is None:
            return None
        edits = [(*_span(text, keys[e]), _quoted(ast.get_source_segment(text, keys[e]), m))
                 for e, m in renames.items()]
        edits += [self._removal(text, keys[e], values[e]) for e in removed]
        if added:
            edits.append(self._insertion(text, node, added, ast.get_source_segment(text, template)))
        after = _splice(text, edits)
        try:
            ast.parse(after)
        except SyntaxError:
            return None
        return CodePatch(d.file, text, after, d.rule, self._reason(renames, added, removed), self.name,
                         self._plan_edits(info.plan, renames, added, removed))

    @staticmethod
    def _removal(text: str, key: ast.AST, value: ast.AST) -> tuple[int, int, str]:
        start = _line_start(text, _span(text, key)[0])
        own_line = start == 0 or text[start - 1] == "\n"
        return start, _entry_end(text, _span(text, value)[1], own_line), ""

    @staticmethod
    def _insertion(text: str, node: ast.Dict, names: Sequence[str], value: str) -> tuple[int, int, str]:
        """New entries ``name: value`` before the closing brace, in the layout of the existing ones."""
        brace = _span(text, node)[1] - 1
        first = node.keys[0] if node.keys else None
        quote = ast.get_source_segment(text, first) if isinstance(first, ast.Constant) else '"'
        start = _line_start(text, brace)
        if start != brace:  # the brace on a line of its own: one entry per line, indented like the first
            first_start = _span(text, first)[0] if first is not None else brace
            indent = text[text.rfind("\n", 0, first_start) + 1:first_start] if first is not None else ""
            body = "".join(f"{indent}{_quoted(quote, n)}: {value},\n" for n in names)
            return start, start, body
        before = text[:brace].rstrip()
        sep = "" if before.endswith((",", "{")) else ", "
        return brace, brace, sep + ", ".join(f"{_quoted(quote, n)}: {value}" for n in names)

    @staticmethod
    def _reason(renames: dict[str, str], added: list[str], removed: list[str]) -> str:
        parts = [f"optimizer key {e!r} renamed to the parameter group {m!r} (its settings kept)"
                 for e, m in renames.items()]
        parts += [f"optimizer for parameter group {m!r} added (a copy of 'fields')" for m in added]
        parts += [f"optimizer {e!r} removed (no such parameter group)" for e in removed]
        return "; ".join(parts)

    @staticmethod
    def _plan_edits(plan: dict | None, renames: dict[str, str], added: list[str],
                    removed: list[str]) -> list[PlanEdit]:
        edits = [PlanEdit("rename", f"optimizers.{e}", f"optimizers.{m}") for e, m in renames.items()]
        fields = Plan.of(plan).get("optimizers.fields") if plan else None
        edits += [PlanEdit("set", f"optimizers.{m}", fields) for m in added if fields is not None]
        edits += [PlanEdit("delete", f"optimizers.{e}") for e in removed]
        return edits


class InterlevelLossFixer:
    """Proposal networks without gradient and an interlevel loss switched off: switch it on (weight 1)."""

    name = "interlevel-loss"

    def propose(self, info, diagnoses):
        if not any(d.rule == "detached-parameter" and "proposal_networks" in d.message for d in diagnoses):
            return []
        rel = info.module_file(info.config_module)
        text = _read(info, rel)
        after = re.sub(r"interlevel_loss_mult=0(\.0*)?\b", "interlevel_loss_mult=1.0", text)
        if after == text:
            return []
        return [
            CodePatch(rel, text, after, "detached-parameter", "a proposal sampler needs its interlevel loss "
                      "(Mip-NeRF 360 Eq. 13): interlevel_loss_mult set to 1.0", self.name,
                      [PlanEdit("set", "model.losses.interlevel.weight", 1.0)])
        ]


class DtypeDeviceFixer:
    """float64 or CUDA-only tensors in plugin code: float32, on the inputs' device."""

    name = "dtype-device"
    RULES = [
        (r"\.double\(\)", ".float()"),
        (r"torch\.float64", "torch.float32"),
        (r"\.cuda\(\)", ""),
        (r"device=[\"']cuda[\"']", 'device="cpu"'),
        (r"\.half\(\)", ".float()"),
    ]

    def propose(self, info, diagnoses):
        relevant = [
            d
            for d in diagnoses
            if re.search(r"dtype|device|cuda|Double|Half|Expected all tensors", d.message + d.traceback)
        ]
        patches = []
        for rel in info.python_files if relevant else []:
            text = _read(info, rel)
            after = text
            for pattern, repl in self.RULES:
                after = re.sub(pattern, repl, after)
            if after != text:
                patches.append(
                    CodePatch(rel, text, after, relevant[0].rule,
                          "float64/half/CUDA-only tensors made float32 on the inputs' device", self.name)
                )
        return patches


class ExpGuardFixer:
    """An exp-type activation overflowing at large pre-activations: clamp its argument at ``EXP_CAP``."""

    name = "exp-guard"
    CALLS = ("trunc_exp", "torch.exp", "exp")

    def propose(self, info, diagnoses):
        if not any(
            d.rung == "stability" and d.case in ("density_raw_1e8", "density_1e8") or "overflow" in d.message
            for d in diagnoses
        ):
            return []
        patches = []
        for rel in info.python_files:
            text = _read(info, rel)
            try:
                tree = ast.parse(text)
            except SyntaxError:
                continue
            calls = [
                n
                for n in ast.walk(tree)
                if isinstance(n, ast.Call)
                and len(n.args) == 1
                and ast.unparse(n.func) in self.CALLS
                and "clamp" not in ast.unparse(n.args[0])
            ]
            after = text
            for call in sorted(calls, key=lambda n: (n.args[0].lineno, n.args[0].col_offset), reverse=True):
                arg = call.args[0]
                after = _segment_replace(
                    after, arg, f"({ast.get_source_segment(text, arg)}).clamp(max={EXP_CAP})"
                )
            if after != text:
                patches.append(
                    CodePatch(rel, text, after, "stiff-case", f"exp-type activations clamped at {EXP_CAP} "
                              "before exp (finite density and gradients for huge pre-activations)", self.name)
                )
        return patches


class EmptyReshapeFixer:
    """``x.view(*shape, -1)`` cannot reshape 0 elements (no samples: near = far, rays missing the box, an
    empty occupancy grid): name the last dimension, ``x.reshape(*shape, x.shape[-1])``, on the line at
    fault."""

    name = "empty-reshape"
    AT = re.compile(r"at ([\w/.-]+\.py):(\d+)")
    VIEW = re.compile(r"(\w+)\.view\((\*[^()]*(?:\([^()]*\))?[^()]*?),\s*-1\)")

    def propose(self, info, diagnoses):
        lines_at = {}
        for d in diagnoses:
            if "reshape tensor of 0 elements" not in d.message + d.traceback:
                continue
            where = [(d.file, d.line)] if d.file and d.line else []
            where += [(m.group(1), int(m.group(2))) for m in self.AT.finditer(d.message)]
            for file, line in where:
                lines_at.setdefault(file, set()).add(line)
        patches = []
        for rel, lines in lines_at.items():
            if rel not in info.python_files:
                continue
            text = _read(info, rel)
            out = text.splitlines(True)
            for line in lines:
                out[line - 1] = self.VIEW.sub(
                    lambda m: f"{m.group(1)}.reshape({m.group(2)}, {m.group(1)}.shape[-1])", out[line - 1]
                )
            after = "".join(out)
            if after != text:
                patches.append(
                    CodePatch(rel, text, after, "stiff-case", "reshape with a named last dimension, so a "
                              "batch without samples keeps its shape", self.name)
                )
        return patches


def default_fixers() -> list[Fixer]:
    return [
        OptimizerGroupFixer(),
        InterlevelLossFixer(),
        DtypeDeviceFixer(),
        ExpGuardFixer(),
        EmptyReshapeFixer(),
    ]


REPAIRS_KEY = "repairs"
"""The plan annotation holding code repairs that have no plan equivalent (re-applied by the composer)."""


def code_repair(patch: CodePatch) -> dict:
    """The ``repairs`` entry of a code patch: file, rule, reason, fixer and the unified diff as a list of
    lines (readable in ``plan.yaml``)."""
    return {"file": patch.file, "rule": patch.rule, "reason": patch.reason, "fixer": patch.fixer,
            "diff": patch.diff().splitlines()}


def record_in_plan(plan: Plan, patches: Sequence[CodePatch]) -> list[str]:
    """Record ``patches`` in ``plan`` (in place), so recomposing the plan keeps them: a patch whose plan
    edits change the plan (and keep it valid) is recorded as those edits; any other (the plan already says
    what the code now says, or nothing in the plan expresses it) as a code repair in ``repairs``. Returns
    one line per patch saying how it was recorded."""
    from nerfify_ns.grammar import PlanError, validate

    lines = []
    for patch in patches:
        trial = plan.copy()
        changed = [e for e in patch.plan_edits if e.apply(trial)]
        if changed:
            try:
                validate(trial)
            except PlanError:
                changed = []
        if changed:
            plan.clear()
            plan.update(trial)
            lines.append(f"{patch.file}: plan edits " + ", ".join(f"{e.op} {e.path}" for e in changed))
            continue
        entry = code_repair(patch)
        repairs = plan.setdefault(REPAIRS_KEY, [])
        if entry not in repairs:
            repairs.append(entry)
        lines.append(f"{patch.file}: recorded in plan.{REPAIRS_KEY}")
    return lines
