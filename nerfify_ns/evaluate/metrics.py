"""Image metrics in the NeRF-paper conventions (NeRF, mip-NeRF, Nerfstudio).

* Images are float RGB in [0, 1]; Blender RGBA ground truth is composited over the
  background colour first (white for the NeRF-synthetic benchmark), see
  :func:`composite_on_background` / :func:`as_rgb`.
* PSNR = -10 log10(MSE) per image (data range 1); a set reports the mean of the per-image
  PSNRs, not the PSNR of the pooled MSE. Identical images give ``inf``.
* SSIM follows mip-NeRF's ``compute_ssim``: separable 11x11 Gaussian window, sigma 1.5,
  *valid* filtering (no padding, the map is ``(H-10, W-10)``), k1 = 0.01, k2 = 0.03, data
  range 1, variances clipped at 0, mean over pixels and channels.
* LPIPS (Zhang et al. 2018) uses AlexNet with real local weights only
  (:func:`nerfify_ns.runtime.lpips.find_lpips_weights`); without them it is ``None``.
* Colour spread: the mean over foreground pixels of the standard deviation of a pixel's R, G and B
  (0 for a grey pixel). A render that has learnt shapes but not colours (the greyish mean colour a
  short run converges to first) has a spread far below its ground truth's, whatever its PSNR.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]
WHITE = (1.0, 1.0, 1.0)

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def to_float(image: ArrayLike) -> Array:
    """float64 copy of an image; integer images (uint8/uint16) are scaled to [0, 1]."""
    if hasattr(image, "detach"):  # a torch tensor
        image = image.detach().cpu().numpy()  # type: ignore[union-attr]
    arr = np.asarray(image)
    if np.issubdtype(arr.dtype, np.integer):
        return arr.astype(np.float64) / float(np.iinfo(arr.dtype).max)
    return np.asarray(arr, dtype=np.float64)


def composite_on_background(rgba: ArrayLike, color: Sequence[float] = WHITE) -> Array:
    """``rgb * a + color * (1 - a)`` for un-premultiplied RGBA (the Blender PNGs); ``(H, W, 3)``."""
    img = to_float(rgba)
    if img.shape[-1] != 4:
        raise ValueError(f"expected an RGBA image (..., 4), got shape {img.shape}")
    alpha = img[..., 3:4]
    return img[..., :3] * alpha + np.asarray(color, dtype=np.float64) * (1.0 - alpha)


def as_rgb(image: ArrayLike, background: Sequence[float] = WHITE) -> Array:
    """float RGB in [0, 1]: RGBA is composited over ``background``, grey becomes 3 channels."""
    img = to_float(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    if img.shape[-1] == 4:
        img = composite_on_background(img, background)
    if img.ndim != 3 or img.shape[-1] != 3:
        raise ValueError(f"expected an (H, W, 3|4) image, got shape {img.shape}")
    return img


def _pair(pred: ArrayLike, gt: ArrayLike) -> tuple[Array, Array]:
    p, g = to_float(pred), to_float(gt)
    if p.shape != g.shape:
        raise ValueError(f"prediction {p.shape} and ground truth {g.shape} differ in shape")
    return p, g


def mse(pred: ArrayLike, gt: ArrayLike) -> float:
    p, g = _pair(pred, gt)
    return float(np.mean((p - g) ** 2))


def psnr_from_mse(value: float) -> float:
    """``-10 log10(mse)`` for data range 1; ``inf`` for a zero error."""
    return math.inf if value <= 0.0 else -10.0 * math.log10(value)


def psnr(pred: ArrayLike, gt: ArrayLike) -> float:
    """PSNR of one image pair in dB (data range 1)."""
    return psnr_from_mse(mse(pred, gt))


def mean_psnr(preds: Sequence[ArrayLike], gts: Sequence[ArrayLike]) -> float:
    """Mean of per-image PSNRs over a set (the NeRF papers' reported number)."""
    if len(preds) != len(gts) or not preds:
        raise ValueError("need the same, non-zero number of predictions and ground truths")
    return float(np.mean([psnr(p, g) for p, g in zip(preds, gts, strict=False)]))


def foreground_mask(gt: ArrayLike) -> NDArray[np.bool_]:
    """The ground truth's foreground: alpha >= 0.5 for RGBA, every pixel otherwise (``(H, W)`` bool)."""
    img = to_float(gt)
    if img.ndim == 3 and img.shape[-1] == 4:
        return img[..., 3] >= 0.5
    return np.ones(img.shape[:2], dtype=bool)


def colour_spread(image: ArrayLike, mask: ArrayLike | None = None) -> float | None:
    """Mean over the pixels of ``mask`` (all when None) of the standard deviation of R, G, B (RGBA is composited
    on white first); None for an empty mask."""
    rgb = as_rgb(image)
    spread = rgb.std(axis=-1)
    chosen = spread if mask is None else spread[np.asarray(mask, dtype=bool)]
    return float(chosen.mean()) if chosen.size else None


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> Array:
    """Normalised 1-D Gaussian taps centred on the middle tap (mip-NeRF's ``filt``)."""
    half = size // 2
    x = np.arange(size, dtype=np.float64) - half + (2 * half - size + 1) / 2.0
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def _filter_valid(img: Array, taps: Array) -> Array:
    """Separable correlation with ``taps`` along rows then columns, valid region only."""
    k = len(taps)
    rows = np.lib.stride_tricks.sliding_window_view(img, k, axis=0) @ taps  # (H-k+1, W, C)
    return np.lib.stride_tricks.sliding_window_view(rows, k, axis=1) @ taps  # (H-k+1, W-k+1, C)


def ssim_map(
    pred: ArrayLike,
    gt: ArrayLike,
    *,
    window: int = SSIM_WINDOW,
    sigma: float = SSIM_SIGMA,
    k1: float = SSIM_K1,
    k2: float = SSIM_K2,
    data_range: float = 1.0,
) -> Array:
    """Per-pixel, per-channel SSIM on the valid region: ``(H-window+1, W-window+1, C)``."""
    p, g = _pair(pred, gt)
    if p.ndim == 2:
        p, g = p[..., None], g[..., None]
    if min(p.shape[:2]) < window:
        raise ValueError(f"SSIM needs images of at least {window}x{window} pixels, got {p.shape[:2]}")
    taps = gaussian_window(window, sigma)
    mu0, mu1 = _filter_valid(p, taps), _filter_valid(g, taps)
    mu00, mu11, mu01 = mu0 * mu0, mu1 * mu1, mu0 * mu1
    s00 = np.maximum(0.0, _filter_valid(p * p, taps) - mu00)
    s11 = np.maximum(0.0, _filter_valid(g * g, taps) - mu11)
    s01 = _filter_valid(p * g, taps) - mu01
    s01 = np.sign(s01) * np.minimum(np.sqrt(s00 * s11), np.abs(s01))  # cross-variance bound
    c1, c2 = (k1 * data_range) ** 2, (k2 * data_range) ** 2
    numer = (2.0 * mu01 + c1) * (2.0 * s01 + c2)
    denom = (mu00 + mu11 + c1) * (s00 + s11 + c2)
    return numer / denom


def ssim(pred: ArrayLike, gt: ArrayLike, **kwargs: float) -> float:
    """Mean SSIM of one image pair (mip-NeRF convention, see the module docstring)."""
    return float(np.mean(ssim_map(pred, gt, **kwargs)))


_lpips_cache: dict = {}


def _lpips_model(weights: Path):
    key = str(weights)
    if key not in _lpips_cache:
        from nerfify_ns.runtime.lpips import OfflineLPIPS

        model = OfflineLPIPS(net_type="alex", normalize=True)  # inputs in [0, 1]
        if not model.available:
            return None
        _lpips_cache[key] = model.eval()
    return _lpips_cache[key]


def lpips(pred: ArrayLike, gt: ArrayLike) -> float | None:
    """LPIPS (AlexNet) of one RGB pair in [0, 1]; ``None`` when no real local weights exist."""
    from nerfify_ns.runtime.lpips import find_lpips_weights

    weights = find_lpips_weights()
    if weights is None:
        return None
    import torch

    p, g = _pair(pred, gt)
    to_tensor = lambda a: torch.from_numpy(np.clip(a, 0.0, 1.0)).float().permute(2, 0, 1)[None]  # noqa: E731
    model = _lpips_model(weights)
    if model is None:
        return None
    with torch.no_grad():
        return float(model(to_tensor(p), to_tensor(g)))


def image_metrics(pred: ArrayLike, gt: ArrayLike, *, with_lpips: bool = True) -> dict:
    """PSNR, SSIM and LPIPS (``None`` when unavailable or not asked for) of one pair."""
    return {"psnr": psnr(pred, gt), "ssim": ssim(pred, gt), "lpips": lpips(pred, gt) if with_lpips else None}
