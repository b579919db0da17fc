"""Error against run time for one generated plugin: train, curve, renders, error maps, consistency.

:func:`evaluate_run` trains a composed plugin (``ns-train GENERATED_METHOD`` with
``$NERFIFY_GENERATED`` pointing at it) with :func:`nerfify_ns.evaluate.curve.train_for_curve`
(checkpoints every ``every`` steps, evaluation time excluded from the training seconds), then in
``out_dir`` writes:

* ``curve.csv`` / ``curve.png``: held-out PSNR against training seconds (and iterations), with
  optional comparison curves (e.g. the reference method) on the same plot;
* ``renders/``: RGB, depth and accumulation of the test views at the final checkpoint;
* ``error_maps.json`` + ``<view>_errors.png``: per-view error maps with worst regions;
* ``consistency.json`` + ``<view>_inconsistent.png``: cross-view depth consistency of the
  rendered depths (pixels with accumulation < 0.5 count as "no surface") under the scene's
  test cameras;
* ``summary.json``: PSNR and SSIM of the final checkpoint (float renders, mean over test views),
  LPIPS (AlexNet, on the saved 8-bit renders; ``None`` without real weights), training seconds, loss
  statistics, per-image diagnostics (background error share, high-frequency error ratio,
  sharpness) and the paths above. It is returned as a dict.

A run that fails or goes non-finite is not an exception: its summary has ``status: failed`` and
the reason, so a patch loop can diagnose it (divergence) and move on.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image
from scipy import ndimage

from nerfify_ns import runfolder
from nerfify_ns.budget import Limit
from nerfify_ns.dataset import DataLike, as_dataset
from nerfify_ns.errors import NerfifyError
from nerfify_ns.evaluate.consistency import check_consistency, views_from_frames
from nerfify_ns.evaluate.curve import CurveError, CurveSource, plot_curves, record_curve, train_for_curve
from nerfify_ns.evaluate.error_maps import analyze_views
from nerfify_ns.evaluate.metrics import as_rgb, colour_spread, foreground_mask, lpips, psnr, ssim, to_float
from nerfify_ns.runtime.launch import ENV_GENERATED, GENERATED_METHOD, ProgressHook

CPU_ARGS = ("--mixed-precision", "False", "--pipeline.datamanager.train-num-rays-per-batch", "512")
ACCUMULATION_SURFACE = 0.5  # rendered pixels with less accumulation have no surface (consistency)
HIGH_FREQUENCY_QUANTILE = 0.8  # the top 20% of ground-truth gradient magnitude is "high frequency"


class RunEvalError(NerfifyError):
    """The inputs of an evaluation are unusable (no plugin, no scene, no test split)."""


def _json_default(value):
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.floating | np.integer):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value)}")


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def write_json(path: Path, payload) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, default=_json_default, allow_nan=False) + "\n")
    tmp.replace(path)
    return path


def loss_stats(losses: dict) -> dict:
    """First/last/min of the train loss (means over the first and last tenth of the logged steps)."""
    if not losses:
        return {"finite": False, "steps": 0, "first": None, "last": None, "min": None}
    steps = sorted(losses)
    values = [float(losses[s]) for s in steps]
    finite = all(math.isfinite(v) for v in values)
    k = max(1, len(values) // 10)
    good = [v for v in values if math.isfinite(v)]
    return {
        "finite": finite,
        "steps": len(values),
        "first": _finite(float(np.mean(values[:k]))) if finite else None,
        "last": _finite(float(np.mean(values[-k:]))) if finite else None,
        "min": _finite(min(good)) if good else None,
        "first_nonfinite_step": None if finite else next(s for s, v in zip(steps, values, strict=False)
                                                         if not math.isfinite(v)),
    }


def _gradient_energy(img: np.ndarray) -> np.ndarray:
    grey = img.mean(axis=-1)
    return ndimage.sobel(grey, axis=0) ** 2 + ndimage.sobel(grey, axis=1) ** 2


def image_diagnostics(pred: np.ndarray, gt_rgba: np.ndarray) -> dict:
    """Where one view's error lies: on the background (GT alpha 0), in high-frequency regions,
    how sharp the render is relative to the ground truth, and how much colour its foreground has
    (:func:`~nerfify_ns.evaluate.metrics.colour_spread` of the render and of the ground truth)."""
    gt = as_rgb(gt_rgba)
    p = as_rgb(pred)
    err = np.mean((p - gt) ** 2, axis=-1)
    total = float(err.sum())
    rgba = to_float(gt_rgba)
    background = rgba[..., 3] <= 1e-3 if rgba.ndim == 3 and rgba.shape[-1] == 4 else np.zeros(err.shape, bool)
    grad_gt, grad_pred = _gradient_energy(gt), _gradient_energy(p)
    high = grad_gt >= np.quantile(grad_gt, HIGH_FREQUENCY_QUANTILE)
    high &= grad_gt > 1e-6
    low = ~high
    foreground = ~background
    interior = ndimage.binary_erosion(foreground, iterations=2)  # texture, not the silhouette
    interior = interior if interior.any() else foreground
    solid = foreground_mask(gt_rgba)
    return {
        "colour_spread": colour_spread(p, solid),
        "colour_spread_gt": colour_spread(gt, solid),
        "background_fraction": float(background.mean()),
        "background_error_share": float(err[background].sum() / total) if total > 0 else 0.0,
        "background_psnr": _finite(psnr(p[background], gt[background])) if background.any() else None,
        "foreground_psnr": _finite(psnr(p[foreground], gt[foreground])) if foreground.any() else None,
        "high_frequency_error_ratio": float(err[high].mean() / max(err[low].mean(), 1e-12))
        if high.any() and low.any()
        else 1.0,
        "sharpness": float(grad_pred[interior].sum() / max(grad_gt[interior].sum(), 1e-12))
        if interior.any()
        else 1.0,
    }


def _mean(values: Sequence[float | None]) -> float | None:
    good = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(good)) if good and len(good) == len(values) else None


def _final_ssim(out_dir: Path) -> float | None:
    """Mean SSIM of the last checkpoint from the render subprocess (float renders, like the PSNR)."""
    path = out_dir / runfolder.CHECKPOINT_EVAL
    if not path.is_file():
        return None
    results = json.loads(path.read_text()).get("results") or []
    return _finite(max(results, key=lambda r: r["step"]).get("ssim")) if results else None


def _evaluable_after_limit(run) -> bool:
    """A training its time limit stopped that had saved a checkpoint and logged only finite losses: its
    checkpoints are evaluated (the limit is the budget's, not a fault of the method), and the summary says where it
    stopped."""
    from nerfify_ns.evaluate.curve import checkpoints

    return (run.timed_out and run.run_dir is not None and run.config_path is not None
            and bool(checkpoints(run.run_dir)) and bool(run.losses)
            and all(math.isfinite(v) for v in run.losses.values()))


def _planned(iterations: int, estimated: int | None) -> str:
    """What a run stopped short of: its iterations, or, for a paced run, the budget's estimate and its ceiling."""
    if estimated is None or estimated == iterations:
        return f"{iterations} iterations"
    return f"the {estimated} iterations estimated to fit (at most {iterations})"


def evaluate_run(
    plugin_dir: Path,
    scene: DataLike,
    out_dir: Path,
    *,
    iterations: int,
    every: int,
    label: str = "generated",
    method_args: Sequence[str] = CPU_ARGS,
    seed: int | None = None,
    compare: Sequence[CurveSource] = (),
    compare_labels: Sequence[str] | None = None,
    env: dict | None = None,
    timeout: float | None = None,
    limit: Limit | None = None,
    on_progress: ProgressHook | None = None,
    estimated: int | None = None,
) -> dict:
    """Train the plugin in ``plugin_dir`` on ``scene`` (a dataset or its folder, any format the dataset reader
    reads, through its Nerfstudio dataparser) and evaluate it into ``out_dir``.

    ``method_args`` are ns-train arguments (default: CPU settings, 512 rays per batch); ``seed``
    adds ``--machine.seed``. ``compare`` adds curves (CSV paths, curves or point lists, e.g. the
    reference method's) to ``curve.png``; ``on_progress(step, total)`` is called while it trains. ``limit``: the
    time limit of the training and of the rendering process and where it comes from (named in the reason when it
    is reached); ``timeout``: a limit in seconds without a name; neither: no limit. Returns the summary also
    written to ``summary.json``.
    """
    limit = limit or Limit(timeout, "the caller's timeout" if timeout is not None else "none")
    timeout = limit.timeout
    plugin_dir, out_dir = Path(plugin_dir).resolve(), Path(out_dir).resolve()
    if not (plugin_dir / runfolder.PLUGIN_META).is_file():
        raise RunEvalError(f"{plugin_dir} is not a composed plugin (no nerfify.json)")
    dataset = as_dataset(scene)
    test_frames = dataset.eval_frames
    frames = [{"name": f.stem, "gt": f.image} for f in test_frames]
    out_dir.mkdir(parents=True, exist_ok=True)
    # the plugin's code runs in training and in loading its checkpoints: both in the sandbox, which passes on
    # only an allow-list of our environment plus run_env
    run_env = {**(env or {}), ENV_GENERATED: str(plugin_dir)}
    readable = [plugin_dir, dataset.root]
    args = [*method_args, *(["--machine.seed", str(seed)] if seed is not None else [])]
    run = train_for_curve(
        GENERATED_METHOD, dataset, out_dir / "train", iterations=iterations, every=every, method_args=args,
        timeout=timeout, env=run_env, on_progress=on_progress, sandbox=[plugin_dir],
    )
    summary: dict = {
        "label": label,
        "plugin": str(plugin_dir),
        "scene": str(dataset.root),
        "dataset": dataset.to_dict(),
        "iterations": iterations,
        "every": every,
        "seed": seed,
        "method_args": list(args),
        "train_log": str(run.log_path),
        "train_wall_seconds": run.wall_seconds,
        "isolation": run.isolation,
        "iterations_done": run.last_step + 1,
        "losses": loss_stats(run.losses),
    }
    stopped = ""
    if not run.ok:
        reason = (
            f"stopped at {run.last_step + 1} of {_planned(iterations, estimated)}: {limit.describe()}" if run.timed_out
            else f"exit code {run.returncode}" if run.returncode != 0
            else "non-finite training loss" if run.losses
            else "no training loss logged"
        )
        if not _evaluable_after_limit(run):
            summary.update(status="failed", reason=reason, psnr=None, ssim=None, lpips=None, seconds=None,
                           log_tail=run.log_tail(15))
            write_json(out_dir / runfolder.SUMMARY, summary)
            return summary
        stopped = reason  # its limit reached after a checkpoint: what it learnt until then is evaluated
    renders = out_dir / "renders"
    started = time.perf_counter()
    try:
        curve = record_curve(run, out_dir, label=label, timeout=timeout, env=run_env, save_dir=renders,
                             sandbox=readable)
    except CurveError as exc:
        spent = time.perf_counter() - started
        why = (f"rendering the checkpoints stopped after {spent:.0f} s: {limit.describe()}"
               if limit.seconds is not None and spent >= limit.seconds else f"evaluation failed: {exc}")
        summary.update(status="failed", reason=why, psnr=None, ssim=None, lpips=None, seconds=None)
        write_json(out_dir / runfolder.SUMMARY, summary)
        return summary
    plot_curves(
        [curve, *compare],
        out_dir / runfolder.CURVE_FIGURE,
        labels=None if compare_labels is None else [label, *compare_labels],
    )
    preds = [np.asarray(Image.open(renders / f"{f['name']}.png").convert("RGB")) for f in frames]
    gts = [np.asarray(Image.open(f["gt"])) for f in frames]
    names = [f["name"] for f in frames]
    error_maps = analyze_views(preds, gts, out_dir, names)
    depths, valid = [], []
    for f in frames:
        depths.append(np.load(renders / f"{f['name']}_depth.npy"))
        acc_path = renders / f"{f['name']}_accumulation.npy"
        valid.append(np.load(acc_path) >= ACCUMULATION_SURFACE if acc_path.exists() else np.ones_like(depths[-1], bool))
    report = check_consistency(views_from_frames(test_frames, depths, valid))
    report.save(out_dir)
    consistency = report.summary()
    per_view = [image_diagnostics(to_float(p), g) for p, g in zip(preds, gts, strict=False)]
    diagnostics = {
        key: _mean([v[key] for v in per_view])
        for key in ("colour_spread", "colour_spread_gt", "background_fraction", "background_error_share",
                    "background_psnr", "foreground_psnr", "high_frequency_error_ratio", "sharpness")
    }
    if diagnostics["colour_spread"] is not None and diagnostics["colour_spread_gt"]:
        diagnostics["colour_spread_ratio"] = diagnostics["colour_spread"] / diagnostics["colour_spread_gt"]
    lpips_values = [lpips(p, as_rgb(g)) for p, g in zip(preds, gts, strict=False)]
    last = curve.points[-1]
    if stopped:
        stopped += f"; evaluated at its last checkpoint, iteration {last.step}"
    summary.update(
        status="ok",
        reason="",
        stopped=stopped,
        evaluated_iterations=last.step,
        psnr=_finite(last.psnr),
        ssim=_final_ssim(out_dir) or _mean([ssim(as_rgb(p), as_rgb(g)) for p, g in zip(preds, gts, strict=False)]),
        lpips=_mean(lpips_values) if all(v is not None for v in lpips_values) else None,
        per_view_psnr=[_finite(v["psnr"]) for v in error_maps],
        seconds=last.train_seconds,
        eval_seconds=curve.eval_seconds,
        consistency={k: consistency[k] for k in ("mean_score", "inconsistent_fraction")},
        worst_regions=sum(len(v["regions"]) for v in error_maps),
        diagnostics=diagnostics,
        per_view_diagnostics=[{"view": n, **d} for n, d in zip(names, per_view, strict=False)],
        paths={
            "curve_csv": runfolder.CURVE,
            "curve_png": runfolder.CURVE_FIGURE,
            "error_maps": runfolder.ERROR_MAPS,
            "consistency": runfolder.CONSISTENCY,
            "renders": "renders",
            "panels": [v["panel"] for v in error_maps],
            "masks": [f"{n}_inconsistent.png" for n in names],
        },
    )
    write_json(out_dir / runfolder.SUMMARY, summary)
    return summary
