"""One call for a caller that holds a hole's equations: read them, lower what the outputs need, check it.

``compile_equations([(latex, number), ...], inputs, outputs, sizes, class_name)`` -> ``Compiled``: the
equations read, the failures (each with its reason and column), the lowered module (or why not) and the
check report. Items may also be equations already read (``Equation``: a caller that selected and rewrote
them, as the binder of ``synthesis.novel`` does). Nothing raises for a problem of the paper's equations;
``Compiled.ok`` says whether the module exists and passed its checks, ``Compiled.reason`` why not.
``domains`` gives an input's value range in the check (a density is non-negative, a weight lies in [0, 1]).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from .check import CheckReport, check_lowering
from .ir import Equation, ParseFailure, inline_functions
from .lower import Lowered, lower_module
from .parser import parse_equations
from .shapes import CompileError


@dataclass
class Compiled:
    equations: list[Equation] = field(default_factory=list)
    failures: list[ParseFailure] = field(default_factory=list)
    lowered: Lowered | None = None
    report: CheckReport | None = None
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.lowered is not None and (self.report is None or self.report.ok)

    @property
    def source(self) -> str:
        return self.lowered.source if self.lowered is not None else ""


def _describe(err: BaseException) -> str:
    message = " ".join(str(err).split())[:200]
    return f"{type(err).__name__}: {message}" if message else type(err).__name__


def _inline(equations: list[Equation]) -> list[Equation]:
    """Each application of a function the equations define with a dummy argument (``q(u) = ...`` read as
    ``q(v)``) replaced by its definition with the argument put in (``ir.inline_functions``)."""
    definitions: dict[str, list[Equation]] = {}
    for eq in equations:
        if eq.defines:
            definitions.setdefault(eq.defines, []).append(eq)
    out = []
    for eq in equations:
        rhs, applied = inline_functions(eq.rhs, definitions)
        out.append(Equation(eq.lhs, rhs, eq.number, eq.relation, eq.source, eq.also, eq.free_index) if applied
                   else eq)
    return out


def compile_equations(latex: Iterable[str | tuple[str, str | None] | Equation], inputs: dict, outputs: list[str],
                      sizes: dict | None = None, class_name: str = "CompiledEquations", *, check: bool = True,
                      domains: dict | None = None) -> Compiled:
    """Read every equation (a string, (latex, number), or an ``Equation`` already read), lower those the outputs
    need, check the module against the interpreter (``check=False``: lower only)."""
    out = Compiled()
    for item in latex:
        if isinstance(item, Equation):
            out.equations.append(item)
            continue
        text, number = (item, None) if isinstance(item, str) else item
        for result in parse_equations(text, number=number):
            (out.equations if isinstance(result, Equation) else out.failures).append(result)
    out.equations = _inline(out.equations)
    try:
        out.lowered = lower_module(out.equations, inputs, outputs, sizes, class_name)
    except CompileError as err:
        unread = "; ".join(f"({f.number or '?'}) {f}" for f in out.failures)
        out.reason = str(err) + (f" (equations not read: {unread})" if unread else "")
        return out
    except Exception as err:  # noqa: BLE001 - a lowering failure on what a paper wrote: the reason, never a raise
        out.reason = f"lowering: {_describe(err)}"
        return out
    if check:
        out.report = check_lowering(out.equations, inputs, sizes, outputs, domains=domains, class_name=class_name)
        if not out.report.ok:
            out.reason = out.report.reason
    return out
