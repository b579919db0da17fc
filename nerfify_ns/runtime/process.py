"""The one process runner: a command in its own process group, output to a log file, a time limit.

Every subprocess nerfify starts to train, evaluate, render or probe goes through :func:`run_process`
(the sandbox adds its isolation prefix and resource limits around the same call). On a timeout, an
interrupt (Ctrl-C) or an error in the caller's poll hook, the whole process group is killed, so no
datamanager worker or grandchild outlives the run.

Each child starts a session of its own (``start_new_session``): a terminal's Ctrl-C does not reach it and
a signal sent to us is not passed on, so we stop it ourselves. Every live child process group is kept in a
registry (``_live``); on SIGINT or SIGTERM (:mod:`nerfify_ns.interrupts`) the handler sends
SIGKILL to all of them at once (:func:`signal_all_groups`), and the command's clean-up reaps them
(:func:`kill_all_groups`). A group is also killed when its leader exits, so a worker its leader left
behind does not outlive the run either.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from nerfify_ns import interrupts

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
        from nerfify_ns.safeio import read_tail  # the child wrote it: its tail only, however long it grew

        text = read_tail(self.log_path, 256 << 10) if self.log_path.is_file() else ""
        return "\n".join(text.splitlines()[-lines:])


_live: dict[int, subprocess.Popen] = {}
"""Process groups we started and have not finished with: group id (the leader's pid) -> leader."""


def start_group(cmd: Sequence[str], **popen: object) -> subprocess.Popen:
    """``Popen(cmd, start_new_session=True, **popen)``, registered as a live process group; a signal that
    arrives while it starts waits until it is registered (so the interrupt's clean-up finds it)."""
    with interrupts.held():
        proc = subprocess.Popen(list(cmd), start_new_session=True, **popen)  # type: ignore[call-overload]
        _live[proc.pid] = proc
    return proc


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists (one of another user's counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _killpg(pgid: int) -> bool:
    try:
        os.killpg(pgid, signal.SIGKILL)
        return True
    except (ProcessLookupError, PermissionError):
        return False


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL the process group led by ``proc`` (started with its own session), reap ``proc`` and forget
    the group."""
    _killpg(proc.pid)
    proc.wait()
    _live.pop(proc.pid, None)


_stopped: list[int] = []
"""Groups SIGKILLed by the interrupt handler (for the interrupt's line)."""


def signal_all_groups() -> int:
    """SIGKILL every live child process group without waiting (safe inside a signal handler); how many."""
    killed = [pgid for pgid in list(_live) if _killpg(pgid)]
    _stopped.extend(killed)
    return len(killed)


def kill_all_groups(grace: float = 2.0) -> int:
    """SIGKILL every live child process group, reap the leaders, wait up to ``grace`` seconds for the
    other members to go, and forget them all; how many groups there were."""
    groups = list(_live.items())
    for pgid, _ in groups:
        _killpg(pgid)
    deadline = time.monotonic() + grace
    for pgid, proc in groups:
        try:
            proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            pass
        while time.monotonic() < deadline and _group_alive(pgid):
            time.sleep(0.02)
        _live.pop(pgid, None)
    return len(groups)


def _group_alive(pgid: int) -> bool:
    """Whether any process other than a zombie is left in group ``pgid``."""
    try:
        os.killpg(pgid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    for entry in os.scandir("/proc") if os.path.isdir("/proc") else ():
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z" and int(fields[2]) == pgid:
            return True
    return not os.path.isdir("/proc")


def _interrupt_cleanup() -> str | None:
    """Reap what is left; the number of child process groups the interrupt stopped, in words."""
    count = len(set(_stopped) | set(_live))
    kill_all_groups()
    _stopped.clear()
    return f"stopped {count} child process group{'s' if count != 1 else ''}" if count else None


interrupts.on_interrupt(signal_all_groups)
interrupts.on_cleanup(_interrupt_cleanup, order=0)


def _wait(proc: subprocess.Popen, deadline: float, poll: Poll | None, poll_seconds: float) -> int | None:
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
    env: Mapping[str, str] | None = None,
    preexec_fn: Callable[[], None] | None = None,
    poll: Poll | None = None,
    poll_seconds: float = 1.0,
    pass_fds: Sequence[int] = (),
) -> ProcessResult:
    """Run ``cmd`` in ``cwd`` with stdout and stderr to ``log_path``; kill its process group after
    ``timeout`` seconds. ``env`` is the whole environment (None: ours); ``preexec_fn`` runs in the child
    before ``exec`` (resource limits); ``poll`` is called about every ``poll_seconds`` while it runs; ``pass_fds``
    stay open in the child (a pipe it reports on)."""
    start = time.perf_counter()
    with open(log_path, "w") as log:
        proc = start_group(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=cwd,
                           env=dict(env) if env is not None else None, preexec_fn=preexec_fn,
                           pass_fds=tuple(pass_fds))
        try:
            code = _wait(proc, start + timeout, poll, poll_seconds)
        except BaseException:
            kill_group(proc)  # an interrupt or a failing poll hook must not leave a training behind
            raise
        kill_group(proc)  # reaped already, or killed at the time limit; no worker of it stays behind
        if code is None:
            return ProcessResult(TIMEOUT_CODE, time.perf_counter() - start, True, Path(log_path))
    return ProcessResult(code, time.perf_counter() - start, False, Path(log_path))
