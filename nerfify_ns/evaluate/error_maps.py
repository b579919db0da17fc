"""Where a rendered view is wrong: per-pixel error, local PSNR/SSIM maps and the worst regions.

Per test view (prediction against white-composited ground truth):

* ``error``: per-pixel squared error averaged over channels (the MSE that PSNR uses);
* ``psnr_map``: PSNR of the mean squared error in a ``window`` x ``window`` box around each
  pixel (reflect padding, same size as the image);
* ``ssim_map``: mip-NeRF SSIM map (valid filtering) averaged over channels, placed at its
  pixel centres, NaN on the 5-px border it does not cover;
* worst regions: the error box-averaged over ``smooth`` px (a local MSE, so a region of noisy
  errors counts as one), thresholded at ``max(Otsu, floor)`` (``floor`` = the MSE of a
  ``floor_psnr`` dB window, so a clean render has none), a binary opening then closing,
  8-connected components, ranked by total squared error. Boxes are ``(x0, y0, x1, y1)``, end exclusive.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from PIL import Image
from scipy import ndimage

from nerfify_ns import runfolder
from nerfify_ns.evaluate.metrics import SSIM_WINDOW, as_rgb, psnr, psnr_from_mse, ssim_map

Array = NDArray[np.float64]

FLOOR_PSNR = 20.0  # a pixel is "bad" only if its own error is worse than a 20 dB pixel
PSNR_CAP = 60.0  # local PSNR of a perfect window (finite, for maps and JSON)


@dataclass(frozen=True)
class Region:
    """One bad region: box (x0, y0, x1, y1; end exclusive), pixel area, PSNR in the box, mean error."""

    x0: int
    y0: int
    x1: int
    y1: int
    area: int
    local_psnr: float
    mean_error: float

    @property
    def box(self) -> tuple:
        return (self.x0, self.y0, self.x1, self.y1)


@dataclass
class ViewErrors:
    """The error analysis of one view."""

    error: Array  # (H, W) squared error, mean over channels
    psnr_map: Array  # (H, W) local PSNR in dB, capped at PSNR_CAP
    ssim_map: Array  # (H, W) local SSIM, NaN on the uncovered border
    threshold: float
    regions: list[Region] = field(default_factory=list)
    psnr: float = float("nan")
    ssim: float = float("nan")

    def summary(self) -> dict:
        finite = lambda v: None if not np.isfinite(v) else float(v)  # noqa: E731
        return {
            "psnr": finite(self.psnr),
            "ssim": finite(self.ssim),
            "threshold": self.threshold,
            "regions": [asdict(r) for r in self.regions],
        }


def error_map(pred: ArrayLike, gt: ArrayLike) -> Array:
    """Per-pixel squared error averaged over channels, ``(H, W)``."""
    p, g = as_rgb(pred), as_rgb(gt)
    return np.mean((p - g) ** 2, axis=-1)


def local_psnr_map(error: Array, window: int = SSIM_WINDOW) -> Array:
    """PSNR of the box-averaged squared error around each pixel (reflect padding), capped."""
    local = ndimage.uniform_filter(error, size=window, mode="reflect")
    with np.errstate(divide="ignore"):
        return np.minimum(-10.0 * np.log10(np.maximum(local, 0.0)), PSNR_CAP)


def local_ssim_map(pred: Array, gt: Array, window: int = SSIM_WINDOW) -> Array:
    """Channel-mean SSIM map (valid filtering) embedded in a full-size NaN map."""
    valid = ssim_map(pred, gt, window=window).mean(axis=-1)
    full = np.full(pred.shape[:2], np.nan)
    half = window // 2
    full[half : half + valid.shape[0], half : half + valid.shape[1]] = valid
    return full


def _otsu(values: Array) -> float:
    from skimage.filters import threshold_otsu

    return (
        float(threshold_otsu(values)) if values.size and np.ptp(values) > 0 else float(values.max(initial=0))
    )


def worst_regions(
    error: Array,
    *,
    floor_psnr: float = FLOOR_PSNR,
    open_size: int = 3,
    close_size: int = 3,
    min_area: int = 4,
    max_regions: int = 5,
    smooth: int = 5,
) -> tuple[list[Region], float]:
    """Ranked bad regions of an error map and the threshold used (see the module docstring)."""
    local = ndimage.uniform_filter(error, size=smooth, mode="reflect") if smooth > 1 else error
    threshold = max(_otsu(local), 10.0 ** (-floor_psnr / 10.0))
    mask = local > threshold
    pad = max(open_size, close_size)
    mask = np.pad(mask, pad)  # so closing does not erode regions touching the border
    if open_size > 1:
        mask = ndimage.binary_opening(mask, structure=np.ones((open_size, open_size)))
    if close_size > 1:
        mask = ndimage.binary_closing(mask, structure=np.ones((close_size, close_size)))
    mask = mask[pad:-pad, pad:-pad]
    labels, count = ndimage.label(mask, structure=np.ones((3, 3)))
    regions = []
    for index, slices in enumerate(ndimage.find_objects(labels), start=1):
        if slices is None:
            continue
        component = labels[slices] == index
        area = int(component.sum())
        if area < min_area:
            continue
        ys, xs = slices
        regions.append(
            (
                float(error[slices][component].sum()),
                Region(
                    x0=int(xs.start),
                    y0=int(ys.start),
                    x1=int(xs.stop),
                    y1=int(ys.stop),
                    area=area,
                    local_psnr=min(psnr_from_mse(float(error[slices].mean())), PSNR_CAP),
                    mean_error=float(error[slices][component].mean()),
                ),
            )
        )
    regions.sort(key=lambda item: (-item[0], item[1].y0, item[1].x0))
    return [r for _, r in regions[:max_regions]], threshold


def analyze_view(pred: ArrayLike, gt: ArrayLike, *, window: int = SSIM_WINDOW, **region_args) -> ViewErrors:
    """Error maps and worst regions of one view; RGBA ground truth is composited on white."""
    p, g = as_rgb(pred), as_rgb(gt)
    err = error_map(p, g)
    regions, threshold = worst_regions(err, **region_args)
    smap = local_ssim_map(p, g, window)
    return ViewErrors(
        error=err,
        psnr_map=local_psnr_map(err, window),
        ssim_map=smap,
        threshold=threshold,
        regions=regions,
        psnr=psnr(p, g),
        ssim=float(np.nanmean(smap)),
    )


def _heatmap(values: Array, vmax: float) -> NDArray[np.uint8]:
    from matplotlib import colormaps

    scaled = np.clip(values / vmax, 0.0, 1.0) if vmax > 0 else np.zeros_like(values)
    return (colormaps["inferno"](scaled)[..., :3] * 255).round().astype(np.uint8)


def _draw_box(img: NDArray[np.uint8], box: tuple, color: tuple, width: int) -> None:
    x0, y0, x1, y1 = box
    h, w = img.shape[:2]
    x1, y1 = min(x1, w), min(y1, h)
    img[y0 : y0 + width, x0:x1] = color
    img[max(y1 - width, 0) : y1, x0:x1] = color
    img[y0:y1, x0 : x0 + width] = color
    img[y0:y1, max(x1 - width, 0) : x1] = color


def render_panel(
    pred: ArrayLike, gt: ArrayLike, view: ViewErrors, *, scale: int | None = None
) -> NDArray[np.uint8]:
    """ground truth | prediction | error heatmap with the ranked boxes (rank 1 in cyan), uint8."""
    p, g = as_rgb(pred), as_rgb(gt)
    h, w = view.error.shape
    s = scale or max(1, int(np.ceil(192 / max(h, w))))
    up = lambda a: np.kron(a, np.ones((s, s, 1), dtype=a.dtype))  # noqa: E731
    to8 = lambda a: (np.clip(a, 0, 1) * 255).round().astype(np.uint8)  # noqa: E731
    heat = up(_heatmap(view.error, max(float(view.error.max()), 10.0 ** (-FLOOR_PSNR / 10.0))))
    for rank, region in reversed(list(enumerate(view.regions))):
        color = (0, 255, 255) if rank == 0 else (0, 255, 0)
        _draw_box(heat, tuple(v * s for v in region.box), color, max(1, s // 2))
    gap = np.full((h * s, max(2, s), 3), 255, dtype=np.uint8)
    return np.concatenate([up(to8(g)), gap, up(to8(p)), gap, heat], axis=1)


def save_panel(path: Path, pred: ArrayLike, gt: ArrayLike, view: ViewErrors) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(render_panel(pred, gt, view)).save(path, format="PNG")
    return path


def analyze_views(
    preds: Sequence[ArrayLike], gts: Sequence[ArrayLike], out_dir: Path, names: Sequence[str] | None = None
) -> list[dict]:
    """Analyse every view, write ``<name>_errors.png`` panels and ``error_maps.json``; returns summaries."""
    out_dir = Path(out_dir)
    names = list(names) if names is not None else [f"view_{i:03d}" for i in range(len(preds))]
    if not (len(preds) == len(gts) == len(names)):
        raise ValueError("need as many predictions, ground truths and names")
    summaries = []
    for name, pred, gt in zip(names, preds, gts, strict=False):
        view = analyze_view(pred, gt)
        panel = save_panel(out_dir / f"{name}_errors.png", pred, gt, view)
        summaries.append({"view": name, "panel": panel.name, **view.summary()})
    (out_dir / runfolder.ERROR_MAPS).write_text(json.dumps(summaries, indent=2) + "\n")
    return summaries
