"""Helpers of the host-process hostile corpus: the real CLI in a subprocess, measured (wall time and the peak
resident memory of the process tree it waited for), and the one-line error contract."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

CLI = Path(sys.executable).with_name("ns-nerfify")
MAX_RSS_MB = 1500
"""Peak resident memory our own process may reach on a hostile input (an idle CLI takes about 60 MB; torch,
imported by some commands, a few hundred)."""


@dataclass
class Done:
    returncode: int
    stdout: str
    stderr: str
    seconds: float
    rss_mb: float

    @property
    def lines(self) -> list:
        return [line for line in (self.stdout + self.stderr).splitlines() if line.strip()]


def _tree_hwm_mb(pid: int) -> float:
    """Peak resident memory (VmHWM) of ``pid`` and its descendants now, in MB. Unlike ``ru_maxrss``, VmHWM starts
    afresh at exec: a child forked from a large pytest worker does not inherit the worker's high-water mark."""
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        try:
            status = Path(f"/proc/{p}/status").read_text()
            total += next((int(line.split()[1]) for line in status.splitlines() if line.startswith("VmHWM:")), 0) / 1024
            for task in Path(f"/proc/{p}/task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except (OSError, ValueError):
            continue
    return total


def run_cli(*args: str, cwd: Path, timeout: float = 120, env: dict | None = None) -> Done:
    """``ns-nerfify ARGS`` in ``cwd``: its exit code, output, wall time and peak RSS (of it and its descendants,
    sampled every 20 ms)."""
    start = time.perf_counter()
    with _Temp() as (out, err):
        proc = subprocess.Popen([str(CLI), *args], cwd=cwd, stdout=out, stderr=err, text=True,
                                env={**os.environ, **(env or {})})
        deadline = start + timeout
        peak = 0.0
        while True:
            peak = max(peak, _tree_hwm_mb(proc.pid))
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() > deadline:
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                raise AssertionError(f"ns-nerfify {' '.join(args)} ran past {timeout} s")
            time.sleep(0.02)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return Done(proc.returncode, out.read(), err.read(), time.perf_counter() - start, peak)


class _Temp:
    def __enter__(self):
        import tempfile

        self.files = (tempfile.TemporaryFile("w+"), tempfile.TemporaryFile("w+"))
        return self.files

    def __exit__(self, *exc):
        for f in self.files:
            f.close()


def assert_one_error(done: Done, needle: str, code: int = 2, seconds: float = 60) -> None:
    """Exit ``code``, no traceback, exactly one line and it is an ``error:`` line holding ``needle``; bounded."""
    text = done.stdout + done.stderr
    assert done.returncode == code, text
    assert "Traceback" not in text, text
    assert len(done.lines) == 1 and done.lines[0].startswith("error:"), done.lines
    assert needle in done.lines[0], done.lines[0]
    assert "\x1b" not in text
    assert done.seconds < seconds and done.rss_mb < MAX_RSS_MB, (done.seconds, done.rss_mb)


def snapshot(folder: Path) -> dict:
    """Every path under ``folder`` with its kind, link target and bytes (what 'nothing changed' compares)."""
    out = {}
    for p in sorted(Path(folder).rglob("*")):
        key = str(p.relative_to(folder))
        if p.is_symlink():
            out[key] = ("link", os.readlink(p))
        elif p.is_file():
            out[key] = ("file", p.read_bytes())
        else:
            out[key] = ("dir", None)
    return out


def alias_bomb(levels: int = 9, width: int = 9) -> str:
    """The "billion laughs" YAML: ``width ** levels`` strings from a few hundred bytes."""
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for i in range(1, levels + 1):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]")
    return "\n".join(lines) + "\n"


def deep_yaml(depth: int = 100_000) -> str:
    return "[" * depth + "]" * depth + "\n"


def deep_json(depth: int = 100_000) -> str:
    return '{"a": ' * depth + "1" + "}" * depth
