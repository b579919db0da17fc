"""Where the benchmark's tasks run: local processes (default) or Ray tasks, resumably.

Every task is one process, ``python -m nerfify_ns.nerfifybench.tasks SUITE KEY FOLDER``, with its numeric libraries'
threads pinned to the cores it declares (``budget.cpus``). It writes ``FOLDER/result.json`` last, so a task is done
when that file is there with the paper entry's fingerprint; a killed bench leaves the folder of the task it was
running without one, and a rerun removes that folder and runs the task again, skipping every finished one.

* :class:`LocalExecutor`: one task at a time (their training wall-clock goes into the tables, so two trainings
  never share the cores), each process group stopped on SIGINT/SIGTERM like every child of ours.
* :class:`RayExecutor`: ``ray.init()`` (a local cluster) or ``ray.init(address=...)`` (an existing one); every task
  is a Ray task declaring ``num_cpus``/``num_gpus`` from its paper's budget. It runs the same process in a
  temporary folder on its worker and returns the result with the folder as a gzipped tar (checkpoints left out),
  which is unpacked into the run folder here. Workers must see the suite, its checks and the papers at the same
  paths (the same checkout and ``../shared`` on every node, or a shared file system). Ray is an optional extra
  (``pip install nerfify-ns[ray]``, installed by ``scripts/setup.sh --dev``). SIGINT or SIGTERM stops it like every
  command of ours: our handlers are put back after ``ray.init()`` (which installs its own), the pending tasks are
  cancelled, the cluster it started is shut down (its task processes die with their workers), and the command
  prints one ``interrupted:`` line and exits 130 or 143.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from nerfify_ns import interrupts
from nerfify_ns.errors import NerfifyError
from nerfify_ns.nerfifybench.tasks import RESULT, Task, thread_env

OnDone = Callable[[Task, dict], None]
SKIP_SUFFIXES = (".ckpt",)
"""Artefacts not shipped back from a Ray worker (checkpoints: large, and the tables do not read them)."""


class ExecutorError(NerfifyError):
    """An executor that cannot start (Ray not installed, no cluster at the address)."""


def task_folder(out: Path, task: Task) -> Path:
    return Path(out) / "tasks" / task.key


def finished(out: Path, task: Task, fingerprint: str) -> dict | None:
    """The task's result when it finished before with the same paper entry (else None)."""
    result = _read_result(task_folder(out, task) / RESULT)
    return result if result is not None and result.get("fingerprint") == fingerprint else None


MAX_RESULT = 16 << 20
"""Bytes of a task's result.json read back (a few KB when our task process wrote it)."""


def _read_result(path: Path) -> dict | None:
    """A task's result.json (a JSON object within the bounds of :mod:`nerfify_ns.safeio`), else None: a folder
    with a missing, damaged or oversized result counts as not finished."""
    from nerfify_ns import safeio

    if not path.is_file():
        return None
    try:
        result = safeio.load_json(path, MAX_RESULT)
    except safeio.ReadRefused:
        return None
    return result if isinstance(result, dict) else None


def task_command(suite_path: Path, task: Task, folder: Path) -> list[str]:
    return [sys.executable, "-m", "nerfify_ns.nerfifybench.tasks", str(suite_path), task.key, str(folder)]


def _fail(task: Task, reason: str) -> dict:
    return {"status": "failed", "reason": reason, "key": task.key}


class LocalExecutor:
    """Tasks one after another in local processes (see the module docstring)."""

    name = "local"

    def run(self, suite_path: Path, out: Path, tasks: Sequence[Task], needs: dict[str, tuple], on_done: OnDone,
            timeout: float = 24 * 3600) -> None:
        from nerfify_ns.runtime.process import run_process

        for task in tasks:
            folder = task_folder(out, task)
            shutil.rmtree(folder, ignore_errors=True)  # an unfinished earlier attempt
            folder.mkdir(parents=True)
            env = {**os.environ, **thread_env(needs[task.key][0])}
            proc = run_process(task_command(suite_path, task, folder), folder / "task.log", cwd=folder,
                               timeout=timeout, env=env)
            result = _read_result(folder / RESULT)
            if result is not None:
                on_done(task, result)
            else:
                on_done(task, _fail(task, f"the task process ended without a result (exit {proc.returncode}); "
                                          f"see {folder / 'task.log'}"))


def _die_with_parent() -> None:
    """In a task process started by a Ray worker: SIGTERM when the worker dies (the cluster shut down), so no
    task outlives the cluster that ran it (Linux; elsewhere a no-op)."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _ray_task(suite_path: str, key: str, threads: dict[str, str]) -> tuple:
    """On a Ray worker: run the task process in a temporary folder; its result and the folder as a tar.gz."""
    import subprocess

    with tempfile.TemporaryDirectory(prefix="nerfify-bench-") as tmp:
        folder = Path(tmp) / "task"
        folder.mkdir()
        with open(folder / "task.log", "w") as log:
            code = subprocess.call([sys.executable, "-m", "nerfify_ns.nerfifybench.tasks", suite_path, key,
                                    str(folder)], stdout=log, stderr=subprocess.STDOUT, cwd=folder,
                                   env={**os.environ, **threads}, start_new_session=True,
                                   preexec_fn=_die_with_parent)
        buffer = io.BytesIO()
        with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
            tar.add(folder, arcname=".", filter=lambda info: None if info.name.endswith(SKIP_SUFFIXES)
                    or info.issym() else info)
        result = json.loads((folder / RESULT).read_text()) if (folder / RESULT).is_file() else None
        return code, result, buffer.getvalue()


def _unpack(data: bytes, folder: Path) -> None:
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        tar.extractall(folder, filter="data")


class RayExecutor:
    """Tasks as Ray tasks (see the module docstring)."""

    name = "ray"

    def __init__(self, address: str | None = None) -> None:
        try:
            import ray
        except ImportError:
            raise ExecutorError("--ray needs Ray: pip install 'nerfify-ns[ray]' (scripts/setup.sh --dev installs "
                                "it)") from None
        self.ray, self.address = ray, address

    def _init(self) -> None:
        """``ray.init()`` with our SIGINT/SIGTERM handling kept: Ray would install its own SIGTERM handler (exit 15,
        or a native stack dump) for the rest of the command; a signal during the start waits for it to end, so the
        cluster that started is then stopped."""
        ray = self.ray
        utils = getattr(getattr(ray, "_private", None), "utils", None)
        own = getattr(utils, "set_sigterm_handler", None)
        if own is not None:
            utils.set_sigterm_handler = lambda handler: None
        try:
            with interrupts.held():
                try:
                    ray.init(address=self.address, include_dashboard=False, log_to_driver=False,
                             logging_level="ERROR")
                except Exception as exc:  # noqa: BLE001 - Ray's own errors: one line
                    where = f" at {self.address}" if self.address else ""
                    raise ExecutorError(f"cannot start or reach the Ray cluster{where}: {exc}") from None
                finally:
                    if own is not None:
                        utils.set_sigterm_handler = own
                    interrupts.install()  # ours, whatever the start installed
        finally:
            if own is not None:
                utils.set_sigterm_handler = own

    def run(self, suite_path: Path, out: Path, tasks: Sequence[Task], needs: dict[str, tuple], on_done: OnDone,
            timeout: float = 24 * 3600) -> None:
        ray = self.ray
        started_here = not ray.is_initialized()
        pending: dict = {}
        try:
            if started_here:
                self._init()
            for task in tasks:
                cpus, gpus = needs[task.key]
                remote = ray.remote(num_cpus=cpus, num_gpus=gpus, max_retries=0)(_ray_task)
                pending[remote.remote(str(suite_path), task.key, thread_env(cpus))] = task
            deadline = time.monotonic() + timeout
            while pending:
                # short waits: a signal is handled between two (a wait of hours would hold it in Ray's C++ code)
                done, _ = ray.wait(list(pending), num_returns=1, timeout=WAIT_SLICE)
                if not done:
                    if time.monotonic() < deadline:
                        continue
                    for task in pending.values():
                        on_done(task, _fail(task, "Ray task timed out"))
                    break
                ref = done[0]
                task = pending.pop(ref)
                folder = task_folder(out, task)
                shutil.rmtree(folder, ignore_errors=True)
                folder.mkdir(parents=True)
                try:
                    code, result, data = ray.get(ref)
                    _unpack(data, folder)
                except Exception as exc:  # noqa: BLE001 - a worker lost or a task that raised: its row
                    result, code = None, f"Ray: {type(exc).__name__}: {str(exc)[:300]}"
                on_done(task, result if result is not None else _fail(
                    task, f"the task ended without a result ({code}); see {folder / 'task.log'}"))
        except interrupts.Interrupted:
            for ref in pending:
                try:
                    ray.cancel(ref, force=True)
                except Exception:  # noqa: BLE001 - already finished or the cluster is going away
                    pass
            if started_here:
                _STOPPED.append("stopped the Ray cluster it started")
            raise
        finally:
            if started_here:
                with interrupts.held():
                    ray.shutdown()  # also after a start cut short: what it started is stopped


WAIT_SLICE = 1.0
"""Seconds of one wait for a finished Ray task (how soon a signal is acted on)."""
_STOPPED: list[str] = []
"""What an interrupt's clean-up stopped (for the interrupted line)."""


def _stopped_line() -> str | None:
    line = ", ".join(_STOPPED) or None
    _STOPPED.clear()
    return line


interrupts.on_cleanup(_stopped_line, order=20)
