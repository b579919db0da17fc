"""Run untrusted plugin code in a separate process: time limit, memory limit, no network, no writes
outside its folder.

Where we are root and ``unshare`` exists, the process gets a new network namespace (no network)
and a new mount namespace in which the whole root filesystem is remounted read-only except the
run's own folder (``workdir``) and a fresh ``/dev/shm``; ``TMPDIR`` points inside ``workdir``.
Memory is capped with ``RLIMIT_AS``; on timeout the whole process group is killed.
"""

from __future__ import annotations

import os
import resource
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

from nerfify_ns.runtime.process import Poll, ProcessResult, run_process

DEFAULT_MEMORY = 12 << 30

# Runs inside the new mount namespace before the command: everything read-only but $1.
_INNER = (
    'set -e; W="$1"; shift; mount --make-rprivate /; mount --bind "$W" "$W"; '
    "mount -o remount,bind,ro /; mount -t tmpfs -o size=2g tmpfs /dev/shm; "
    'mount -o remount,bind,rw "$W"; cd "$W"; exec "$@"'
)


@dataclass
class SandboxResult(ProcessResult):
    """How the sandboxed process ended, and which isolation it had."""

    isolation: List[str] = field(default_factory=list)


def isolation_available() -> bool:
    """True when we can give a process its own network and mount namespaces."""
    return shutil.which("unshare") is not None and hasattr(os, "geteuid") and os.geteuid() == 0


def sandbox_prefix(workdir: Path, isolate: bool = True) -> List[str]:
    """The command prefix giving a process no network and a read-only filesystem but ``workdir`` (none when
    isolation is unavailable or not asked for)."""
    if not (isolate and isolation_available()):
        return []
    return [shutil.which("unshare"), "-n", "-m", "sh", "-c", _INNER, "sh", str(workdir)]


def _limits(memory: int):
    """A pre-exec hook capping the address space at ``memory`` bytes (0: no cap) and disabling core dumps."""
    def apply() -> None:
        if memory:
            resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))

    return apply


def sandbox_env(workdir: Path, extra: Optional[Dict[str, str]] = None) -> Dict[str, str]:
    """Our environment with temporary files, caches and bytecode kept inside ``workdir``, plus ``extra``."""
    tmp = workdir / ".tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.update(
        {
            "TMPDIR": str(tmp),
            "MPLCONFIGDIR": str(tmp / "mpl"),
            "PYTHONDONTWRITEBYTECODE": "1",
            "PYTHONWARNINGS": "ignore",
            "XDG_CACHE_HOME": str(tmp / "cache"),
            "NERFIFY_SANDBOX": "1",
        }
    )
    env.update(extra or {})
    return env


def run_sandboxed(
    cmd: Sequence[str],
    workdir: Path,
    *,
    timeout: float,
    log_name: str = "run.log",
    memory: int = DEFAULT_MEMORY,
    env: Optional[Dict[str, str]] = None,
    isolate: bool = True,
    poll: Optional[Poll] = None,
) -> SandboxResult:
    """Run ``cmd`` with its working directory ``workdir`` (created), output to ``workdir/log_name``, through
    the runtime's process runner (time limit, process group killed) inside the isolation prefix and under
    the memory limit; ``poll`` is called about every second while it runs."""
    workdir = Path(workdir).resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    prefix = sandbox_prefix(workdir, isolate)
    isolation = ["timeout", "rlimit_as"] + (["no-network", "read-only-fs"] if prefix else [])
    result = run_process([*prefix, *cmd], workdir / log_name, cwd=workdir, timeout=timeout,
                         env=sandbox_env(workdir, env), preexec_fn=_limits(memory), poll=poll)
    return SandboxResult(result.returncode, result.seconds, result.timed_out, result.log_path, isolation)


def python_cmd(module: str, *args: str) -> List[str]:
    """``python -m module args`` with our interpreter."""
    return [sys.executable, "-m", module, *args]
