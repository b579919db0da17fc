"""Repair: deterministic fixes for common failures, as revertible unified-diff patches.

A ``Fixer`` turns diagnoses into ``Patch``es (whole-file replacements recorded as unified diffs);
the ladder applies them, records them under ``<out>/patches/`` and re-runs. A model-backed fixer
implements the same protocol.
"""

from __future__ import annotations

import ast
import difflib
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import List, Protocol, Sequence

from nerfify_ns.verify.plugin import PluginInfo
from nerfify_ns.verify.report import Diagnosis

EXP_CAP = 20.0
"""Pre-activation cap for exp-type density activations: exp(20) ~ 4.9e8."""


@dataclass
class Patch:
    """A change to one file of the plugin, with why."""

    file: str
    before: str
    after: str
    rule: str
    reason: str
    fixer: str = ""

    def diff(self) -> str:
        return "".join(
            difflib.unified_diff(
                self.before.splitlines(True), self.after.splitlines(True), f"a/{self.file}", f"b/{self.file}"
            )
        )

    def apply(self, root: Path) -> None:
        (root / self.file).write_text(self.after)

    def revert(self, root: Path) -> None:
        (root / self.file).write_text(self.before)

    def summary(self) -> dict:
        return {k: v for k, v in asdict(self).items() if k not in ("before", "after")}


class Fixer(Protocol):
    """Turns the diagnoses of a failed round into patches (none: it has nothing to offer)."""

    name: str

    def propose(self, info: PluginInfo, diagnoses: Sequence[Diagnosis]) -> List[Patch]: ...


def _read(info: PluginInfo, rel: str) -> str:
    return (info.root / rel).read_text()


def _segment_replace(text: str, node: ast.AST, new: str) -> str:
    lines = text.splitlines(True)
    start = sum(len(l) for l in lines[: node.lineno - 1]) + node.col_offset
    end = sum(len(l) for l in lines[: node.end_lineno - 1]) + node.end_col_offset
    return text[:start] + new + text[end:]


class OptimizerGroupFixer:
    """Missing optimiser for a parameter group: copy the ``fields`` entry; an optimiser without a group: drop it."""

    name = "optimizer-groups"

    def propose(self, info, diagnoses):
        patches = []
        for d in diagnoses:
            if d.rule != "param-groups" or not d.file or not d.line:
                continue
            text = _read(info, d.file)
            missing = (
                re.findall(r"'([^']+)'", d.message.split("missing optimizers:")[1].split(";")[0])
                if "missing optimizers:" in d.message
                else []
            )
            extra = (
                re.findall(r"'([^']+)'", d.message.split("without a group:")[1])
                if "without a group:" in d.message
                else []
            )
            node = next(
                (
                    n.value
                    for n in ast.walk(ast.parse(text))
                    if isinstance(n, ast.keyword) and n.arg == "optimizers" and isinstance(n.value, ast.Dict)
                ),
                None,
            )
            if node is None:
                continue
            entries = {
                k.value: ast.get_source_segment(text, v)
                for k, v in zip(node.keys, node.values)
                if isinstance(k, ast.Constant)
            }
            template = entries.get("fields") or next((v for k, v in entries.items() if k not in extra), None)
            if template is None and missing:
                continue
            kept = {k: v for k, v in entries.items() if k not in extra}
            kept.update({k: template for k in missing})
            body = "{\n" + "".join(f"            {k!r}: {v},\n" for k, v in kept.items()) + "        }"
            after = _segment_replace(text, node, body)
            patches.append(
                Patch(d.file, text, after, d.rule, f"optimizers for groups {missing} added (copied from "
                      f"'fields'), optimizers without a group {extra} removed", self.name)
            )
        return patches


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
            Patch(rel, text, after, "detached-parameter", "a proposal sampler needs its interlevel loss "
                  "(Mip-NeRF 360 Eq. 13): interlevel_loss_mult set to 1.0", self.name)
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
                    Patch(rel, text, after, relevant[0].rule,
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
                    Patch(rel, text, after, "stiff-case", f"exp-type activations clamped at {EXP_CAP} before "
                          "exp (finite density and gradients for huge pre-activations)", self.name)
                )
        return patches


class EmptyReshapeFixer:
    """``x.view(*shape, -1)`` cannot reshape 0 elements (no samples: near = far, rays missing the box, an
    empty occupancy grid): name the last dimension, ``x.reshape(*shape, x.shape[-1])``, on the line at fault."""

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
                    Patch(rel, text, after, "stiff-case",
                          "reshape with a named last dimension, so a batch without samples keeps its shape", self.name)
                )
        return patches


def default_fixers() -> List[Fixer]:
    return [
        OptimizerGroupFixer(),
        InterlevelLossFixer(),
        DtypeDeviceFixer(),
        ExpGuardFixer(),
        EmptyReshapeFixer(),
    ]
