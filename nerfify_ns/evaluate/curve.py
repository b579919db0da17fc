"""Held-out PSNR against training time, measured without disturbing the run being timed.

1. Train with Nerfstudio's ``ns-train`` saving a checkpoint every ``every`` steps
   (``--steps-per-save K --save-only-latest-checkpoint False``) and in-training evaluation off
   (``--steps-per-eval-* 0``).
2. Training seconds come from the run's own tensorboard events: the per-iteration
   ``Train Iter (time)`` (Nerfstudio's timer around one training iteration, so checkpoint
   writing and logging are excluded), summed up to each checkpoint's step. Nerfstudio logs a
   running mean over ``logging.max_buffer_size`` steps; we log with a buffer of 1 and undo the
   mean otherwise.
3. Afterwards ONE subprocess (:mod:`nerfify_ns.evaluate.render_views`, with a time limit) loads
   the config once and renders the eval split at every checkpoint; PSNR is the mean of per-image
   PSNRs against white-composited ground truth. Its time is reported apart (``eval_seconds``).

``curve.csv`` columns: ``label, step, train_seconds, psnr, loss`` where ``step`` is the number of
iterations done (checkpoint step + 1) and ``loss`` the mean train loss over the steps since the
previous checkpoint.
"""

from __future__ import annotations

import csv
import json
import re
import sys
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from nerfify_ns import runfolder
from nerfify_ns.dataset import DataLike
from nerfify_ns.errors import NerfifyError
from nerfify_ns.runtime.events import ITER_TIME_TAG, read_scalars
from nerfify_ns.runtime.launch import ProgressHook, TrainRun, ns_train, offline_prefix, run_logged

CURVE_COLUMNS = ("label", "step", "train_seconds", "psnr", "loss")


class CurveError(NerfifyError):
    """A run could not be turned into a PSNR-against-time curve."""


@dataclass(frozen=True)
class CurvePoint:
    label: str
    step: int  # iterations done
    train_seconds: float
    psnr: float
    loss: float | None


@dataclass
class Curve:
    points: list[CurvePoint]
    eval_seconds: float = 0.0  # the evaluation subprocess, measured apart from training
    train_wall_seconds: float = 0.0  # the whole ns-train process (startup included)
    csv_path: Path | None = None
    checkpoints: list[Path] = field(default_factory=list)


def curve_train_args(every: int) -> list[str]:
    """ns-train arguments: keep a checkpoint every ``every`` steps, no evaluation while training,
    raw (unaveraged) iteration times in the events."""
    if every < 1:
        raise ValueError(f"every must be >= 1, got {every}")
    return [
        "--steps-per-save",
        str(every),
        "--save-only-latest-checkpoint",
        "False",
        "--steps-per-eval-batch",
        "0",
        "--steps-per-eval-image",
        "0",
        "--steps-per-eval-all-images",
        "0",
        "--logging.max-buffer-size",
        "1",
    ]


def train_for_curve(
    method: str,
    data: DataLike,
    out_dir: Path,
    *,
    iterations: int,
    every: int,
    method_args: Sequence[str] = (),
    timeout: float = 900,
    env: dict | None = None,
    on_progress: ProgressHook | None = None,
    sandbox: Sequence[Path] | None = None,
) -> TrainRun:
    """``ns_train`` with :func:`curve_train_args` appended to ``method_args`` (``sandbox``: as for ``ns_train``)."""
    return ns_train(
        method,
        data,
        out_dir,
        iterations=iterations,
        method_args=[*method_args, *curve_train_args(every)],
        timeout=timeout,
        env=env,
        on_progress=on_progress,
        sandbox=sandbox,
    )


def _buffer_size(run_dir: Path) -> int:
    config = Path(run_dir) / "config.yml"
    match = re.search(r"max_buffer_size:\s*(\d+)", config.read_text()) if config.exists() else None
    return int(match.group(1)) if match else 20


def undo_running_mean(means: dict[int, float], buffer: int) -> dict[int, float]:
    """Per-step values from Nerfstudio's running mean over the last ``buffer`` steps (steps 0..n)."""
    durations: dict[int, float] = {}
    for step in sorted(means):
        n = min(step + 1, buffer)
        earlier = sum(durations.get(s, 0.0) for s in range(step - n + 1, step))
        durations[step] = max(0.0, n * means[step] - earlier)
    return durations


def step_seconds(run_dir: Path) -> dict[int, float]:
    """Cumulative training seconds at the end of each step, from the run's events."""
    means = read_scalars(run_dir).get(ITER_TIME_TAG, {})
    if not means:
        raise CurveError(f"no '{ITER_TIME_TAG}' events in {run_dir}")
    durations = undo_running_mean(means, _buffer_size(run_dir))
    total, cumulative = 0.0, {}
    for step in sorted(durations):
        total += durations[step]
        cumulative[step] = total
    return cumulative


def checkpoints(run_dir: Path) -> list[Path]:
    """The run's checkpoints, by step."""
    return sorted((Path(run_dir) / "nerfstudio_models").glob("step-*.ckpt"))


def evaluate_checkpoints(
    config_path: Path,
    ckpts: Sequence[Path],
    out_json: Path,
    *,
    timeout: float = 600,
    env: dict | None = None,
    save_dir: Path | None = None,
    sandbox: Sequence[Path] | None = None,
) -> tuple[list[dict], float]:
    """Render and score every checkpoint in one subprocess; returns its results and wall seconds. ``sandbox``:
    the checkpoints are a generated plugin's (its code runs to load them), so the subprocess runs in the
    sandbox with these folders (the plugin, the data) readable and ``out_json``'s folder writable."""
    out_json = Path(out_json).resolve()
    out_json.parent.mkdir(parents=True, exist_ok=True)
    cmd = [
        *(offline_prefix() if sandbox is None else []),
        sys.executable,
        "-m",
        "nerfify_ns.evaluate.render_views",
        str(Path(config_path).resolve()),
        str(out_json),
        "--checkpoints",
        *[str(Path(c).resolve()) for c in ckpts],
    ]
    if save_dir is not None:
        cmd += ["--save-dir", str(Path(save_dir).resolve())]
    log = out_json.with_suffix(".log")
    if sandbox is not None:
        from nerfify_ns.runtime.sandbox import run_sandboxed

        result = run_sandboxed(cmd, out_json.parent, timeout=timeout, log_name=log.name, env=env,
                               readonly=sandbox)
    else:
        result = run_logged(cmd, log, out_json.parent, timeout=timeout, env=env)
    if result.returncode != 0 or result.timed_out or not out_json.exists():
        raise CurveError(
            f"checkpoint evaluation failed (exit {result.returncode}, timed out: {result.timed_out}); "
            f"log {log}:\n{result.tail(15)}"
        )
    return json.loads(out_json.read_text())["results"], result.seconds


def record_curve(
    run: TrainRun,
    out_dir: Path,
    *,
    label: str | None = None,
    timeout: float = 600,
    env: dict | None = None,
    save_dir: Path | None = None,
    sandbox: Sequence[Path] | None = None,
) -> Curve:
    """Evaluate every checkpoint of a finished run and write ``out_dir/curve.csv`` (``sandbox``: as for
    :func:`evaluate_checkpoints`)."""
    if run.run_dir is None or run.config_path is None:
        raise CurveError(f"run of {run.method} left no run folder or config; see {run.log_path}")
    ckpts = checkpoints(run.run_dir)
    if not ckpts:
        raise CurveError(f"run of {run.method} saved no checkpoints in {run.run_dir}")
    seconds = step_seconds(run.run_dir)
    results, eval_seconds = evaluate_checkpoints(
        run.config_path,
        ckpts,
        Path(out_dir) / runfolder.CHECKPOINT_EVAL,
        timeout=timeout,
        env=env,
        save_dir=save_dir,
        sandbox=sandbox,
    )
    label = label or run.method
    points, previous = [], -1
    for result in sorted(results, key=lambda r: r["step"]):
        step = result["step"]
        if step not in seconds:
            raise CurveError(f"no iteration time logged for step {step} in {run.run_dir}")
        window = [v for s, v in run.losses.items() if previous < s <= step]
        loss = sum(window) / len(window) if window else None
        points.append(CurvePoint(label, step + 1, seconds[step], result["psnr"], loss))
        previous = step
    curve = Curve(points, eval_seconds=eval_seconds, train_wall_seconds=run.wall_seconds, checkpoints=ckpts)
    curve.csv_path = write_curve_csv(points, Path(out_dir) / runfolder.CURVE)
    return curve


def write_curve_csv(points: Iterable[CurvePoint], path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CURVE_COLUMNS)
        writer.writeheader()
        for p in points:
            writer.writerow({**asdict(p), "loss": "" if p.loss is None else p.loss})
    return path


def read_curve_csv(path: Path) -> list[CurvePoint]:
    with open(path, newline="") as f:
        return [
            CurvePoint(
                row["label"],
                int(row["step"]),
                float(row["train_seconds"]),
                float(row["psnr"]),
                float(row["loss"]) if row["loss"] else None,
            )
            for row in csv.DictReader(f)
        ]


CurveSource = str | Path | Curve | Sequence[CurvePoint]


def plot_curves(
    sources: Sequence[CurveSource],
    out_png: Path,
    labels: Sequence[str] | None = None,
    title: str = "Held-out PSNR against training time",
) -> Path:
    """One figure, two panels (PSNR vs training seconds, PSNR vs iterations), one line per run.

    ``sources`` are CSV paths, :class:`Curve` objects or lists of points; ``labels`` (one per source)
    override the labels they carry.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if labels is not None and len(labels) != len(sources):
        raise ValueError("give one label per source")
    series: dict[str, list[CurvePoint]] = {}
    for i, source in enumerate(sources):
        points = (
            read_curve_csv(Path(source))
            if isinstance(source, str | Path)
            else source.points
            if isinstance(source, Curve)
            else list(source)
        )
        for p in points:
            series.setdefault(labels[i] if labels is not None else p.label, []).append(p)
    fig, (ax_t, ax_i) = plt.subplots(1, 2, figsize=(10, 4))
    for name, points in series.items():
        points = sorted(points, key=lambda p: p.step)
        ax_t.plot([p.train_seconds for p in points], [p.psnr for p in points], marker="o", label=name)
        ax_i.plot([p.step for p in points], [p.psnr for p in points], marker="o", label=name)
    ax_t.set_xlabel("training time (s)")
    ax_i.set_xlabel("iterations")
    for ax in (ax_t, ax_i):
        ax.set_ylabel("PSNR (dB)")
        ax.grid(alpha=0.3)
    ax_t.legend()
    fig.suptitle(title)
    fig.tight_layout()
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=100)
    plt.close(fig)
    return out_png
