"""The one process runner: a command in its own process group, output to a log file, a time limit.

Every subprocess nerfify starts to train, evaluate, render or probe goes through :func:`run_process`
(the sandbox adds its isolation prefix and resource limits around the same call). On a timeout, an
interrupt (Ctrl-C) or an error in the caller's poll hook, the whole process group is killed, so no
datamanager worker or grandchild outlives the run.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Optional, Sequence

Poll = Callable[[], None]
"""Called about every ``poll_seconds`` while the process runs (e.g. to report training progress)."""

TIMEOUT_CODE = -9
"""The return code of a process killed at its time limit (SIGKILL)."""


@dataclass
class ProcessResult:
    """How a process ended: its exit code, wall seconds, whether it hit the time limit, and its log."""

    returncode: int
    seconds: float
    timed_out: bool
    log_path: Path

    def tail(self, lines: int = 30) -> str:
        """The last ``lines`` lines of the log ('' when there is none)."""
        text = self.log_path.read_text(errors="replace") if self.log_path.exists() else ""
        return "\n".join(text.splitlines()[-lines:])


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL the process group led by ``proc`` (started with its own session) and reap ``proc``."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


def _wait(proc: subprocess.Popen, deadline: float, poll: Optional[Poll], poll_seconds: float) -> Optional[int]:
    """Wait for ``proc`` until ``deadline`` (perf_counter), calling ``poll`` in between; None when time ran out."""
    while True:
        left = deadline - time.perf_counter()
        if left <= 0:
            return None
        try:
            return proc.wait(timeout=min(left, poll_seconds) if poll else left)
        except subprocess.TimeoutExpired:
            if poll is not None:
                poll()


def run_process(
    cmd: Sequence[str],
    log_path: Path,
    *,
    cwd: Path,
    timeout: float,
    env: Optional[Mapping[str, str]] = None,
    preexec_fn: Optional[Callable[[], None]] = None,
    poll: Optional[Poll] = None,
    poll_seconds: float = 1.0,
) -> ProcessResult:
    """Run ``cmd`` in ``cwd`` with stdout and stderr to ``log_path``; kill its process group after
    ``timeout`` seconds. ``env`` is the whole environment (None: ours); ``preexec_fn`` runs in the child
    before ``exec`` (resource limits); ``poll`` is called about every ``poll_seconds`` while it runs."""
    start = time.perf_counter()
    with open(log_path, "w") as log:
        proc = subprocess.Popen(list(cmd), stdout=log, stderr=subprocess.STDOUT, cwd=cwd,
                                env=dict(env) if env is not None else None, start_new_session=True,
                                preexec_fn=preexec_fn)
        try:
            code = _wait(proc, start + timeout, poll, poll_seconds)
        except BaseException:
            kill_group(proc)  # an interrupt or a failing poll hook must not leave a training behind
            raise
        if code is None:
            kill_group(proc)
            return ProcessResult(TIMEOUT_CODE, time.perf_counter() - start, True, Path(log_path))
    return ProcessResult(code, time.perf_counter() - start, False, Path(log_path))
