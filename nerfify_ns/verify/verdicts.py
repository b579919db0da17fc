"""What the ladder found: diagnoses, per-rung results and the whole report (``verify.json``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from nerfify_ns.safetext import clean

RUNGS = ("static", "contract", "stability", "smoke")


@dataclass
class Diagnosis:
    """One broken rule: which rung, which rule, where (file and line) and why."""

    rung: str
    rule: str
    message: str
    file: str | None = None
    line: int | None = None
    traceback: str = ""
    component: str | None = None
    case: str | None = None
    data: dict[str, Any] = field(default_factory=dict)
    """Structured facts the probe reported with it (e.g. ``missing`` / ``extra`` optimiser groups)."""

    MESSAGE_LIMIT = 2000
    TRACEBACK_LIMIT = 4000

    def __post_init__(self) -> None:
        """Messages, tracebacks and names often carry text of the plugin's (an exception's message, a log
        line): control characters escaped and lengths bounded here, once, so no console or report shows
        them raw."""
        self.message = clean(self.message, self.MESSAGE_LIMIT)
        self.traceback = clean(self.traceback or "", self.TRACEBACK_LIMIT, keep="tail")
        for name in ("file", "component", "case"):
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, clean(value, 300, newlines=False))
        if not isinstance(self.line, int) or isinstance(self.line, bool):
            self.line = None
        self.data = clean_data(self.data)

    def where(self) -> str:
        if not self.file:
            return self.component or "-"
        return f"{self.file}:{self.line}" if self.line else self.file

    def __str__(self) -> str:
        return f"[{self.rung}/{self.rule}] {self.where()}: {self.message}"

    @classmethod
    def from_dict(cls, data: dict) -> Diagnosis:
        """From a probe event or ``verify.json``: known fields as such, any other key (but the event's kind)
        into ``data``."""
        known = {k: data.get(k) for k in cls.__dataclass_fields__ if k in data and k != "data"}
        extra = {k: v for k, v in data.items() if k not in cls.__dataclass_fields__ and k != "event"}
        return cls(**known, data={**(data.get("data") or {}), **extra})


def clean_data(value: Any, depth: int = 0) -> Any:
    """JSON-like ``value`` from untrusted code with every string cleaned, containers bounded (64 items, 4 deep)."""
    if isinstance(value, str):
        return clean(value, 500)
    if depth >= 4:
        return clean(repr(value), 200)
    if isinstance(value, dict):
        return {clean(k, 100, newlines=False): clean_data(v, depth + 1) for k, v in list(value.items())[:64]}
    if isinstance(value, list | tuple):
        return [clean_data(v, depth + 1) for v in list(value)[:64]]
    if value is None or isinstance(value, bool | int | float):
        return value
    return clean(repr(value), 200)


@dataclass
class RungResult:
    """One rung: passed, failed or skipped (with why), its checks and its failures."""

    name: str
    status: str = "pass"  # pass | fail | skip
    seconds: float = 0.0
    checks: int = 0
    failures: list[Diagnosis] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status != "fail"

    def fail(self, diagnosis: Diagnosis) -> None:
        self.failures.append(diagnosis)
        self.status = "fail"

    def to_dict(self) -> dict:
        data = asdict(self)
        data["seconds"] = round(self.seconds, 2)
        return data


@dataclass
class LadderReport:
    """Every rung of every round on the plugin; ``rungs`` are those of the last round. ``repair`` is the
    mode it ran with (off, propose, apply); ``patches`` are the repairs applied to the plugin (apply);
    ``proposal`` is the repair computed on a scratch copy without touching the plugin (propose); ``diff``
    is the unified diff of all repairs (applied or proposed), as text."""

    plugin: str
    rungs: list[RungResult] = field(default_factory=list)
    rounds: list[list[RungResult]] = field(default_factory=list)
    patches: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    repair: str = "apply"
    proposal: dict | None = None
    diff: str = ""

    @property
    def ok(self) -> bool:
        return bool(self.rungs) and all(r.ok for r in self.rungs)

    @property
    def failures(self) -> list[Diagnosis]:
        return [d for r in self.rungs for d in r.failures]

    def rung(self, name: str) -> RungResult | None:
        return next((r for r in self.rungs if r.name == name), None)

    def to_dict(self) -> dict:
        return {
            "plugin": self.plugin,
            "ok": self.ok,
            "rungs": [r.to_dict() for r in self.rungs],
            "failures": [asdict(d) for d in self.failures],
            "patches": self.patches,
            "notes": self.notes,
            "repair": self.repair,
            "proposal": self.proposal,
            "rounds": [
                [{"name": r.name, "status": r.status, "failures": [str(d) for d in r.failures]} for r in rnd]
                for rnd in self.rounds
            ],
        }
