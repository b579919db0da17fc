"""Render a trained run's eval views at several checkpoints, loading its config once.

Run as a subprocess (it builds Nerfstudio's pipeline, which may spawn datamanager workers that
re-import ``__main__``; hence the guard at the bottom)::

    python -m nerfify_ns.evaluate.render_views CONFIG OUT.json --checkpoints A.ckpt B.ckpt \
        [--save-dir DIR]

For each checkpoint: load its weights into the pipeline, render every image of the eval split
with ``model.get_outputs_for_camera``, and score it with :mod:`nerfify_ns.evaluate.metrics` against
the ground-truth PNG composited on white (mean of per-image PSNR and SSIM). ``--save-dir`` keeps
the last checkpoint's renders: ``<stem>.png`` (RGB), ``<stem>_depth.npy`` (distance along the
unit ray, in the transforms' units) and ``<stem>_accumulation.npy``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np


def evaluate_checkpoints(
    config_path: Path, checkpoints: Sequence[Path], save_dir: Path | None = None
) -> list[dict]:
    """Per-checkpoint ``{checkpoint, step, psnr, ssim, per_view_psnr, render_seconds}``."""
    from PIL import Image

    from nerfify_ns.runtime import activate

    activate()
    from nerfstudio.utils.eval_utils import eval_setup

    from nerfify_ns.evaluate.metrics import as_rgb

    _, pipeline, _, _ = eval_setup(
        Path(config_path), test_mode="test", update_config_callback=_serial_datamanager
    )
    dataset = pipeline.datamanager.eval_dataset
    outputs_meta = dataset._dataparser_outputs
    scale = float(getattr(outputs_meta, "dataparser_scale", 1.0))
    filenames = [Path(f) for f in outputs_meta.image_filenames]
    gts = [as_rgb(np.asarray(Image.open(f))) for f in filenames]
    results = []
    with _over_white(pipeline.model):
        for index, checkpoint in enumerate(checkpoints):
            results.append(_score(pipeline, dataset, gts, filenames, checkpoint, scale,
                                  save_dir if index == len(checkpoints) - 1 else None))
    return results


def _over_white(model):
    """Renders composited over white, the background the ground truth is composited on (``metrics.as_rgb``),
    for a model trained over random backgrounds (Nerfstudio renders those over black); a no-op otherwise."""
    import contextlib

    import torch
    from nerfstudio.model_components.renderers import background_color_override_context

    renderer = getattr(model, "renderer_rgb", None)
    if getattr(renderer, "background_color", None) != "random":
        return contextlib.nullcontext()
    return background_color_override_context(torch.ones(3))


def _score(pipeline, dataset, gts, filenames, checkpoint, scale, save_dir) -> dict:
    """One checkpoint loaded and scored on every view (renders saved into ``save_dir`` when given)."""
    import torch

    from nerfify_ns.evaluate.metrics import psnr, ssim

    start = time.perf_counter()
    state = torch.load(checkpoint, map_location="cpu")
    pipeline.load_pipeline(state["pipeline"], state["step"])
    pipeline.eval()
    psnrs, ssims = [], []
    for i, gt in enumerate(gts):
        camera = dataset.cameras[i : i + 1].to(pipeline.device)
        with torch.no_grad():
            out = pipeline.model.get_outputs_for_camera(camera)
        out = fine_outputs(out)
        rgb = out["rgb"].detach().cpu().numpy().astype(np.float64)
        psnrs.append(psnr(rgb, gt))
        ssims.append(ssim(rgb, gt))
        if save_dir is not None:
            _save_render(Path(save_dir), filenames[i].stem, rgb, out, scale)
    return {
        "checkpoint": str(checkpoint),
        "step": int(state["step"]),
        "psnr": float(np.mean(psnrs)),
        "ssim": float(np.mean(ssims)),
        "per_view_psnr": [float(v) for v in psnrs],
        "render_seconds": time.perf_counter() - start,
    }


def fine_outputs(outputs: dict) -> dict:
    """Coarse-to-fine models (NeRF, Mip-NeRF) name their final outputs ``rgb_fine``, ``depth_fine``, ...;
    they are the ones that count."""
    fine = {key[: -len("_fine")]: value for key, value in outputs.items() if key.endswith("_fine")}
    return {**outputs, **fine}


def _serial_datamanager(config):
    """Nerfstudio's parallel datamanager starts a worker that keeps sampling training rays (and
    re-imports ``__main__``); rendering needs only the eval split, so use the serial one."""
    from nerfstudio.data.datamanagers.base_datamanager import VanillaDataManager
    from nerfstudio.data.datamanagers.parallel_datamanager import ParallelDataManager

    datamanager = config.pipeline.datamanager
    if getattr(datamanager, "_target", None) is ParallelDataManager:
        datamanager._target = VanillaDataManager
    return config


def _save_render(out: Path, stem: str, rgb: np.ndarray, outputs: dict, scale: float) -> None:
    from PIL import Image

    out.mkdir(parents=True, exist_ok=True)
    Image.fromarray((np.clip(rgb, 0, 1) * 255).round().astype(np.uint8)).save(out / f"{stem}.png")
    for key in ("depth", "accumulation"):
        if key in outputs:
            value = outputs[key].detach().cpu().numpy().astype(np.float32)[..., 0]
            np.save(out / f"{stem}_{key}.npy", value / scale if key == "depth" else value)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("config", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--checkpoints", type=Path, nargs="+", required=True)
    parser.add_argument("--save-dir", type=Path, default=None)
    args = parser.parse_args(argv)
    start = time.perf_counter()
    results = evaluate_checkpoints(args.config, args.checkpoints, args.save_dir)
    payload = {"results": results, "seconds": time.perf_counter() - start}
    tmp = args.out.with_suffix(args.out.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, allow_nan=True) + "\n")
    tmp.replace(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
