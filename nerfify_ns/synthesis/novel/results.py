"""What became of a paper's novel parts: one ``HoleResult`` per hole (the record written to ``equations.yaml`` and
shown by the report: status, reason, cause, equations, bindings, sizes, component) and the ``Implementation`` of
them all (the plan with the compiled parts placed, their sources, the records)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from nerfify_ns.plan import Plan

IMPLEMENTED, PARTLY, NOT_IMPLEMENTED = "implemented", "partly implemented", "not implemented"


@dataclass
class HoleResult:
    """What became of one hole: the record written to equations.yaml and shown by the report."""

    id: str
    slot: str
    production: str
    section: str
    status: str = NOT_IMPLEMENTED
    reason: str = ""
    cause: str = ""
    equations: list = field(default_factory=list)
    bindings: dict = field(default_factory=dict)
    sizes: dict = field(default_factory=dict)
    state: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    component: dict = field(default_factory=dict)
    checks: dict = field(default_factory=dict)
    hash: str = ""
    source: str = ""
    seconds: float = 0.0
    replaced: Any = None

    def to_dict(self) -> dict:
        out = {"id": self.id, "slot": self.slot, "production": self.production, "section": self.section,
               "status": self.status, "reason": self.reason, **({"cause": self.cause} if self.cause else {}),
               "equations": self.equations,
               "bindings": self.bindings, "sizes": self.sizes, "state": self.state, "notes": self.notes,
               "component": self.component, "checks": self.checks, "hash": self.hash}
        return out


@dataclass
class Implementation:
    plan: Plan
    sources: dict
    records: list
    seconds: float = 0.0
    counts: dict = field(default_factory=dict)

    def headline(self) -> str:
        n = len(self.records)
        done = sum(r.status == IMPLEMENTED for r in self.records)
        partly = sum(r.status == PARTLY for r in self.records)
        if not n:
            return "the paper has no novel part left as a hole"
        return (f"{done} of {n} novel part(s) of the paper implemented from its equations or sentences"
                + (f", {partly} partly" if partly else "") + f", {n - done - partly} not implemented")
