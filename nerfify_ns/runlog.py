"""The run's log file: warnings and other packages' output go to ``<out>/nerfify.log``, never the terminal.

A leaf module (standard library only), installed by the CLI before anything heavy is imported::

    quiet_console()                       # warnings -> logging; logging held in memory until a log file exists
    with run_log(staging / "nerfify.log"):
        ...                               # the held records and everything logged from now on go to the file

``quiet_console`` routes :mod:`warnings` through :mod:`logging` (``logging.captureWarnings``) and gives
the root logger one handler that keeps records in memory (bounded), so nothing reaches the terminal
through logging's last-resort handler. ``run_log`` writes them, and everything logged afterwards, to
the run's log file; text other packages write to ``sys.stderr`` goes there too while it is open. A
run that writes nothing (a dry run, bad input) drops what was held.
"""

from __future__ import annotations

import contextlib
import io
import logging
import warnings
from collections.abc import Iterator
from pathlib import Path

FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
HELD_RECORDS = 5000
"""Records kept in memory before a run's log file exists (older ones are dropped)."""


class HeldRecords(logging.Handler):
    """Keeps log records in memory until :func:`run_log` writes them to a file."""

    def __init__(self, capacity: int = HELD_RECORDS) -> None:
        super().__init__(logging.DEBUG)
        self.capacity = capacity
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        """Hold ``record``; drop the oldest beyond ``capacity``."""
        self.records.append(record)
        del self.records[:-self.capacity]

    def hand_over(self, target: logging.Handler) -> None:
        """Hand every held record to ``target`` and forget them."""
        records, self.records = self.records, []
        for record in records:
            target.handle(record)


_held: HeldRecords | None = None


def quiet_console(level: int = logging.INFO) -> None:
    """Warnings and logging stay off the terminal from now on (held until a run's log file exists)."""
    global _held
    logging.captureWarnings(True)
    warnings.simplefilter("default")  # every warning reaches the log once per location, none the terminal
    root = logging.getLogger()
    root.setLevel(level)
    if _held is None:
        _held = HeldRecords()
        root.addHandler(_held)


class _StderrToLog(io.TextIOBase):
    """A text stream that logs each complete line written to it (other packages' stderr noise)."""

    def __init__(self, logger: logging.Logger) -> None:
        self.logger, self.pending = logger, ""

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        """Log every complete line of ``text``; keep a trailing partial line for the next write."""
        lines = (self.pending + text).split("\n")
        self.pending = lines.pop()
        for line in lines:
            if line.strip():
                self.logger.warning(line.rstrip())
        return len(text)

    def flush(self) -> None:
        """Log a pending partial line."""
        if self.pending.strip():
            self.logger.warning(self.pending.rstrip())
        self.pending = ""


@contextlib.contextmanager
def run_log(path: Path) -> Iterator[Path]:
    """Write held and new log records (and Python-level stderr) to ``path`` until the block ends."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter(FORMAT))
    root = logging.getLogger()
    if _held is not None:
        _held.hand_over(handler)
        root.removeHandler(_held)  # records go to the file now, not to memory
    elif root.getEffectiveLevel() > logging.INFO:
        root.setLevel(logging.INFO)
    root.addHandler(handler)
    stream = _StderrToLog(logging.getLogger("stderr"))
    try:
        with contextlib.redirect_stderr(stream):
            yield path
    finally:
        stream.flush()
        root.removeHandler(handler)
        handler.close()
        if _held is not None:
            root.addHandler(_held)
