"""What a run did, stage by stage: the progress a user watches and the outcome the report states.

A leaf module (standard library only). The pipeline runs each stage inside :meth:`Outcome.stage`::

    outcome = Outcome("paper", until="verify", progress=progress)
    if outcome.wants("verify"):
        with outcome.stage("verify", "verifying the plugin") as stage:
            ladder = run_ladder(...)
            if not ladder.ok:
                stage.fail("smoke rung: the photometric loss does not decrease")
    outcome.write(folder / "run.json")       # the report's top reads it

A stage either ran, failed (with its reason) or was not run (stopped by ``--until``, or an earlier
stage failed); ``run.json`` lists every stage of the command in order with its status. The progress
object is what the user sees (the CLI's rich bars); the base :class:`Progress` shows nothing.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import logging
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

from nerfify_ns.errors import NerfifyError

LOG = logging.getLogger("nerfify.stages")

STAGES: dict[str, tuple[str, ...]] = {
    "paper": ("read", "equations", "plan", "plugin", "verify", "train", "patches"),
    "compose": ("plan", "plugin", "verify", "train", "patches"),
    "demo": ("scene", "train"),
}
"""The stages of each command, in order."""
STOPPABLE = ("plan", "plugin", "verify", "train")
"""Stages a user can stop after (``--until``)."""

RAN, FAILED, NOT_RUN = "ran", "failed", "not run"


class UntilError(NerfifyError):
    """``--until`` names a stage the command does not have."""


class Progress:
    """What the user sees of a run; every method does nothing here (a quiet run). The CLI shows bars."""

    def start(self, stage: str, label: str, total: int | None = None) -> None:
        """A stage begins; ``total`` steps when known (training iterations, checkpoints...)."""

    def advance(self, done: int, total: int | None = None) -> None:
        """``done`` of ``total`` steps of the current stage (an ``on_progress(step, total)`` hook)."""

    def note(self, text: str) -> None:
        """What the current stage is doing now."""

    def finish(self, stage: str, summary: str, seconds: float) -> None:
        """The current stage succeeded."""

    def fail(self, stage: str, reason: str, seconds: float) -> None:
        """The current stage failed, for ``reason``."""

    def abandon(self, stage: str) -> None:
        """The current stage ended with an exception that its caller reports (bad input: one error line)."""



@dataclass
class StageRecord:
    """One stage of a run: its status (ran, failed, not run), what it did or why it failed or did not run."""

    name: str
    status: str = NOT_RUN
    summary: str = ""
    reason: str = ""
    seconds: float | None = None


class Stage:
    """The handle of a running stage: set its summary, report steps, or mark it failed."""

    def __init__(self, record: StageRecord, progress: Progress) -> None:
        self.record, self.progress = record, progress

    @property
    def summary(self) -> str:
        return self.record.summary

    @summary.setter
    def summary(self, text: str) -> None:
        self.record.summary = text

    def fail(self, reason: str) -> None:
        """Mark the stage failed (the run goes on to write its report; later stages are not run)."""
        self.record.status, self.record.reason = FAILED, reason

    def advance(self, done: int, total: int | None = None) -> None:
        """Progress within the stage; pass as ``on_progress`` to whatever polls a long process."""
        self.progress.advance(done, total)

    def note(self, text: str) -> None:
        self.progress.note(text)


@dataclass
class Outcome:
    """Every stage of one command's run, in order, with ``--until`` and the first failure."""

    command: str
    until: str | None = None
    progress: Progress = field(default_factory=Progress)
    records: list[StageRecord] = field(default_factory=list)
    started: str = field(default_factory=lambda: _dt.datetime.now().isoformat(timespec="seconds"))
    ablations: list[str] = field(default_factory=list)
    """Stages switched off for this run (``nerfify_ns.ablations`` names), written into run.json."""

    def __post_init__(self) -> None:
        stages = STAGES[self.command]
        if self.until is not None and self.until not in stages:
            raise UntilError(f"--until {self.until}: {self.command} has the stages {', '.join(stages)}")
        self.records = [StageRecord(name) for name in stages]

    def record(self, name: str) -> StageRecord:
        return next(r for r in self.records if r.name == name)

    @property
    def failed(self) -> StageRecord | None:
        """The stage that failed, if one did."""
        return next((r for r in self.records if r.status == FAILED), None)

    @property
    def ok(self) -> bool:
        return self.failed is None

    def _stopped_before(self, name: str) -> bool:
        stages = STAGES[self.command]
        return self.until is not None and stages.index(name) > stages.index(self.until)

    def wants(self, name: str) -> bool:
        """Whether stage ``name`` runs: not past ``--until`` and no earlier stage failed. Records why not."""
        failed = self.failed
        reason = (f"{failed.name} failed" if failed else f"stopped after {self.until} (--until {self.until})"
                  if self._stopped_before(name) else "")
        if reason:
            self.skip(name, reason)
        return not reason

    def skip(self, name: str, reason: str) -> None:
        """Record that stage ``name`` is not run, and why."""
        record = self.record(name)
        record.status, record.reason = NOT_RUN, reason

    @contextlib.contextmanager
    def stage(self, name: str, label: str, total: int | None = None,
              failures: tuple[type[BaseException], ...] = ()) -> Iterator[Stage]:
        """Run stage ``name``: progress shown, time measured, status recorded. An exception of a type in
        ``failures`` fails the stage (the run goes on); any other propagates."""
        record = self.record(name)
        record.status = RAN
        handle = Stage(record, self.progress)
        self.progress.start(name, label, total)
        LOG.info("stage %s: %s", name, label)
        start = time.perf_counter()
        try:
            yield handle
        except failures as exc:
            handle.fail(str(exc))
        except BaseException as exc:
            record.status, record.reason = FAILED, f"{type(exc).__name__}: {exc}"
            record.seconds = round(time.perf_counter() - start, 2)
            self.progress.abandon(name)
            raise
        record.seconds = round(time.perf_counter() - start, 2)
        if record.status == FAILED:
            LOG.warning("stage %s failed: %s", name, record.reason)
            self.progress.fail(name, record.reason, record.seconds)
        else:
            LOG.info("stage %s done in %.1f s: %s", name, record.seconds, record.summary)
            self.progress.finish(name, record.summary, record.seconds)

    def headline(self) -> str:
        """One line: what ran, what failed and why, where it stopped."""
        ran = [r.name for r in self.records if r.status == RAN]
        failed = self.failed
        if failed:
            return f"{failed.name} failed: {failed.reason}"
        text = f"ran {', '.join(ran) or 'nothing'}"
        return f"{text}; stopped after {self.until} (--until {self.until})" if self.until else text

    def to_dict(self) -> dict:
        return {
            "command": self.command,
            "started": self.started,
            "until": self.until,
            "ablations": list(self.ablations),
            "ok": self.ok,
            "headline": self.headline(),
            "failed": asdict(self.failed) if self.failed else None,
            "stages": [asdict(r) for r in self.records],
        }

    def write(self, path: Path) -> Path:
        """``run.json``: the outcome the report states at its top."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return Path(path)
