"""One call for a caller that holds a hole's equations: read them, lower what the outputs need, check it.

``compile_equations([(latex, number), ...], inputs, outputs, sizes, class_name)`` -> ``Compiled``: the
equations read, the failures (each with its reason and column), the lowered module (or why not) and the
check report. Nothing raises for a problem of the paper's equations; ``Compiled.ok`` says whether the module
exists and passed its checks, ``Compiled.reason`` why not.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from .check import CheckReport, check_lowering
from .ir import Equation, ParseFailure
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


def compile_equations(latex: Iterable[str | tuple[str, str | None]], inputs: dict, outputs: list[str],
                      sizes: dict | None = None, class_name: str = "CompiledEquations", *, check: bool = True,
                      domains: dict | None = None) -> Compiled:
    """Read every equation (a string, or (latex, number)), lower those the outputs need, check the module."""
    out = Compiled()
    for item in latex:
        text, number = (item, None) if isinstance(item, str) else item
        for result in parse_equations(text, number=number):
            (out.equations if isinstance(result, Equation) else out.failures).append(result)
    try:
        out.lowered = lower_module(out.equations, inputs, outputs, sizes, class_name)
    except CompileError as err:
        unread = "; ".join(f"({f.number or '?'}) {f}" for f in out.failures)
        out.reason = str(err) + (f" (equations not read: {unread})" if unread else "")
        return out
    if check:
        out.report = check_lowering(out.equations, inputs, sizes, outputs, domains=domains, class_name=class_name)
        if not out.report.ok:
            out.reason = out.report.reason
    return out
