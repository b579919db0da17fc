"""The one Nerfstudio-run layer: build ``ns-train`` / ``ns-eval`` command lines, know where a run puts its
files, run them, and read back what they logged.

Training never runs in our process: a subprocess (:func:`nerfify_ns.runtime.process.run_process`) with a
time limit, no network (``unshare -n`` where available, or the sandbox's prefix given by the caller)
and its working directory inside the output folder. Results (iterations reached, losses, rays per
second) are read from the run's own tensorboard events (:mod:`nerfify_ns.runtime.events`), never from
text printed by a generator. ``on_progress(step, total)`` is called while a training runs (about every
second, when the step changed), ``step`` being the iterations done so far.

The generated method's name lives here (:data:`GENERATED_METHOD`); everything that trains or names it
imports it.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from nerfify_ns.dataset import DataLike, Dataset, as_dataset
from nerfify_ns.runtime.errors import RuntimeLayerError
from nerfify_ns.runtime.events import EventReader, Scalars, losses, rays_per_sec
from nerfify_ns.runtime.process import Poll, ProcessResult, run_process

GENERATED_METHOD = "nerfify-generated"
"""The method ``ns-train`` trains for a generated plugin (our ``nerfstudio.method_configs`` entry point)."""
ENV_GENERATED = "NERFIFY_GENERATED"
"""Environment variable naming the plugin folder ``GENERATED_METHOD`` loads (else the newest plugin under the
current directory's ``nerfify-out/``); every run of ours sets it."""

ProgressHook = Callable[[int, int], None]
"""``on_progress(step, total)``: iterations done so far, iterations asked for."""


class TrainLaunchError(RuntimeLayerError):
    """ns-train or ns-eval could not be run, or produced nothing usable."""


@dataclass(frozen=True)
class RunLayout:
    """Where one ``ns-train`` run puts its files: ``OUTPUT/EXPERIMENT/METHOD/TIMESTAMP/`` holds
    ``config.yml``, the tensorboard events and ``nerfstudio_models/step-*.ckpt``; the log is ours."""

    output_dir: Path
    """``--output-dir`` (also the process's working directory)."""
    method: str
    """The method trained (a folder level of Nerfstudio's layout)."""
    experiment: str = "run"
    """``--experiment-name``."""
    timestamp: str = "run"
    """``--timestamp`` (fixed, so the run folder is known before the run)."""
    log_name: str = ""
    """File name of the process log in ``output_dir`` (default ``METHOD.train.log``)."""

    @property
    def run_dir(self) -> Path:
        return Path(self.output_dir) / self.experiment / self.method / self.timestamp

    @property
    def config(self) -> Path:
        return self.run_dir / "config.yml"

    @property
    def checkpoints(self) -> Path:
        return self.run_dir / "nerfstudio_models"

    @property
    def log(self) -> Path:
        return Path(self.output_dir) / (self.log_name or f"{self.method}.train.log")

    def args(self) -> list[str]:
        """The ns-train arguments that put the run here."""
        return ["--output-dir", str(self.output_dir), "--experiment-name", self.experiment,
                "--timestamp", self.timestamp]


@dataclass
class TrainRun:
    """What one ``ns-train`` process did, read from its own outputs."""

    method: str
    returncode: int
    wall_seconds: float
    log_path: Path
    run_dir: Path | None = None
    config_path: Path | None = None
    timed_out: bool = False
    losses: dict[int, float] = field(default_factory=dict)
    """Train loss per logged step."""
    rays_per_sec: list[float] = field(default_factory=list)
    """Nerfstudio's per-step ``Train Rays / Sec`` (steps after the first two)."""
    scalars: Scalars = field(default_factory=dict)
    """Every scalar the run logged (tag -> step -> value)."""
    isolation: list[str] = field(default_factory=list)
    """The sandbox's isolation tags when the run was sandboxed (``bwrap``, ``no-network``...), else empty."""

    @property
    def last_step(self) -> int:
        return max(self.losses) if self.losses else -1

    @property
    def finite(self) -> bool:
        return bool(self.losses) and all(math.isfinite(v) for v in self.losses.values())

    @property
    def median_rays_per_sec(self) -> float | None:
        if not self.rays_per_sec:
            return None
        values = sorted(self.rays_per_sec)
        return values[len(values) // 2]

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and not self.timed_out and self.finite

    def log_tail(self, lines: int = 25) -> str:
        from nerfify_ns.safeio import read_tail  # the child wrote it: its tail only, however long it grew

        text = read_tail(self.log_path, 256 << 10) if self.log_path.is_file() else ""
        return "\n".join(text.splitlines()[-lines:])


def console_script(name: str) -> str:
    """The console script ``name`` of the interpreter we run under."""
    candidate = Path(sys.executable).with_name(name)
    return str(candidate) if candidate.exists() else (shutil.which(name) or name)


def offline_prefix() -> list[str]:
    """``unshare -n`` (a process with no network) when we may use it, else nothing."""
    unshare = shutil.which("unshare")
    if unshare and hasattr(os, "geteuid") and os.geteuid() == 0:
        return [unshare, "-n"]
    return []


def launch_env(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """Our environment with ``env`` on top; Nerfstudio's Future/User warnings off unless set."""
    full = dict(os.environ, **(env or {}))
    full.setdefault("PYTHONWARNINGS", "ignore::FutureWarning,ignore::UserWarning")
    return full


def train_command(
    method: str,
    data: DataLike,
    layout: RunLayout,
    *,
    iterations: int,
    method_args: Sequence[str] = (),
    dataparser: str | None = None,
    dataparser_args: Sequence[str] = (),
    prefix: Sequence[str] = (),
) -> list[str]:
    """The ``ns-train`` command line: ``prefix`` (``unshare -n``, a sandbox, or nothing), the method, the
    data, the run layout, the iterations, tensorboard logging every step, then ``method_args`` (presets and
    extra arguments) and the dataparser subcommand with its arguments. ``data`` is a dataset or its folder;
    the dataparser is the dataset's (:meth:`nerfify_ns.dataset.Dataset.dataparser`, formats Nerfstudio cannot
    read converted under ``layout.output_dir``) unless ``dataparser`` names one, and ``dataparser_args`` follow
    its own arguments."""
    if dataparser is None:
        chosen = as_dataset(data).dataparser(Path(layout.output_dir))
        data, dataparser, dataparser_args = chosen.data, chosen.name, [*chosen.args, *dataparser_args]
    data = data.root if isinstance(data, Dataset) else data  # a dataset under an explicit dataparser: its folder
    return [
        *prefix,
        console_script("ns-train"), method,
        "--data", str(Path(data).resolve()),
        *layout.args(),
        "--max-num-iterations", str(iterations),
        "--vis", "tensorboard",
        "--logging.steps-per-log", "1",
        "--viewer.quit-on-train-completion", "True",
        *method_args,
        dataparser, *dataparser_args,
    ]


def eval_command(config_path: Path, output_path: Path, *, prefix: Sequence[str] = ()) -> list[str]:
    """The ``ns-eval`` command line for a trained run's ``config.yml``."""
    return [*prefix, console_script("ns-eval"), "--load-config", str(config_path), "--output-path", str(output_path)]


def progress_poll(run_dir: Path, total: int, on_progress: ProgressHook | None) -> Poll | None:
    """A poll hook for :func:`run_process` calling ``on_progress(step, total)`` when the run's events show
    a new step (None when there is no hook)."""
    if on_progress is None:
        return None
    reader, reported = EventReader(run_dir), [-1]

    def poll() -> None:
        if not reader.run_dir.is_dir():
            return
        reader.poll()
        done = min(reader.last_step() + 1, total)
        if done > reported[0]:
            reported[0] = done
            on_progress(done, total)

    return poll


def read_run(run: TrainRun, layout: RunLayout) -> TrainRun:
    """Fill ``run`` from its folder: run dir, config, scalars, losses and rays/s (left empty without a folder)."""
    if layout.run_dir.is_dir():
        run.run_dir = layout.run_dir
        run.config_path = layout.config if layout.config.exists() else None
        run.scalars = EventReader(layout.run_dir).poll()
        run.losses, run.rays_per_sec = losses(run.scalars), rays_per_sec(run.scalars)
    return run


def ns_train(
    method: str,
    data: DataLike,
    out_dir: Path,
    *,
    iterations: int,
    method_args: Sequence[str] = (),
    dataparser: str | None = None,
    dataparser_args: Sequence[str] = (),
    timeout: float = math.inf,
    env: dict | None = None,
    offline: bool = True,
    on_progress: ProgressHook | None = None,
    sandbox: Sequence[Path] | None = None,
) -> TrainRun:
    """Train ``method`` on ``data`` (a dataset or its folder) with Nerfstudio's trainer in a subprocess; the
    dataparser as for :func:`train_command`. ``sandbox``: the method runs code we do not trust (a generated
    plugin), so the run goes through :func:`nerfify_ns.runtime.sandbox.run_sandboxed` with these folders (the
    plugin) and the data's readable and ``out_dir`` the only writable one; ``env`` is then all it gets of ours
    beyond the sandbox's allow-list. ``timeout``: the caller's limit (none by default: a limit is the caller's,
    derived from its budget and named when reached)."""
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    layout = RunLayout(out_dir, method)
    data = as_dataset(data) if sandbox is not None else data
    cmd = train_command(method, data, layout, iterations=iterations, method_args=method_args, dataparser=dataparser,
                        dataparser_args=dataparser_args,
                        prefix=offline_prefix() if offline and sandbox is None else ())
    poll = progress_poll(layout.run_dir, iterations, on_progress)
    if sandbox is not None:
        from nerfify_ns.runtime.sandbox import run_sandboxed

        result = run_sandboxed(cmd, out_dir, timeout=timeout, log_name=layout.log.name, env=env, poll=poll,
                               readonly=[*sandbox, data.root])
    else:
        result = run_process(cmd, layout.log, cwd=out_dir, timeout=timeout, env=launch_env(env), poll=poll)
    if poll is not None:
        poll()  # the last steps, logged after the previous poll
    run = TrainRun(method=method, returncode=result.returncode, wall_seconds=result.seconds, log_path=layout.log,
                   timed_out=result.timed_out, isolation=list(getattr(result, "isolation", [])))
    return read_run(run, layout)


def headline_metrics(results: dict) -> dict[str, float | None]:
    """PSNR, SSIM and LPIPS of an ``ns-eval`` result; coarse-to-fine models report the fine ones."""
    def pick(name: str) -> float | None:
        return results.get(f"fine_{name}", results.get(name))

    return {"psnr": pick("psnr"), "ssim": pick("ssim"), "lpips": pick("lpips")}


def run_logged(cmd: Sequence[str], log_path: Path, cwd: Path, *, timeout: float,
               env: dict | None = None) -> ProcessResult:
    """:func:`run_process` under :func:`launch_env` (for helpers such as ns-eval or the checkpoint renderer)."""
    return run_process(cmd, log_path, cwd=cwd, timeout=timeout, env=launch_env(env))


def ns_eval(config_path: Path, output_path: Path, *, timeout: float = math.inf, env: dict | None = None) -> dict:
    """Evaluate a trained run with ``ns-eval``; returns its headline metrics (LPIPS ``None`` when unavailable)
    merged over all of ``results``."""
    output_path = Path(output_path).resolve()
    log_path = output_path.with_suffix(".log")
    result = run_logged(eval_command(config_path, output_path, prefix=offline_prefix()), log_path,
                        output_path.parent, timeout=timeout, env=env)
    if result.returncode != 0 or result.timed_out or not output_path.exists():
        raise TrainLaunchError(f"ns-eval failed for {config_path} (exit {result.returncode}, timed out: "
                               f"{result.timed_out}):\n{result.tail(15)}")
    results = json.loads(output_path.read_text())["results"]
    return {**results, **headline_metrics(results)}
