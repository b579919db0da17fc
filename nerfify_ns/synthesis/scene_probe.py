"""What a dataset needs: bounded or not, alpha, timestamps, appearance variation, pose quality, size, format.

Reads the typed dataset (:mod:`nerfify_ns.dataset`: Blender, D-NeRF, Nerfstudio, COLMAP or LLFF, read once
and shared by every stage). Facts come from our scenes' ``scene.json`` when there is one, otherwise from the
cameras and images; each fact records how it was found, so a pruning can say why. The format (with what
identified it) is a fact too: the plan records it and it picks the Nerfstudio dataparser.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

import numpy as np
from PIL import Image

from nerfify_ns.dataset import DataLike, Dataset, as_dataset
from nerfify_ns.errors import NerfifyError

OBJECT_CENTRIC_SPREAD_DEG = 120.0
EXACT_POSE_FORMATS = ("blender", "dnerf")
"""Formats of synthetic renders (exact poses, fixed lighting); the others come from reconstructions."""


class SceneProbeError(NerfifyError):
    """The dataset folder is not a scene we can read."""


@dataclass
class SceneFacts:
    """The scene flags of a plan (grammar terminal ``scene``) plus sizes, with evidence."""

    bounded: bool
    timestamps: bool
    alpha: bool
    appearance_variation: bool
    exact_poses: bool
    image_size: Tuple[int, int]
    num_images: int
    evidence: Dict[str, str] = field(default_factory=dict)
    format: str = "blender"
    """The dataset format (:data:`nerfify_ns.dataset.formats.FORMATS`)."""
    near: Optional[float] = None
    """Near plane of a bounded scene in the run's coordinates (:mod:`~nerfify_ns.synthesis.scene_bounds`)."""
    far: Optional[float] = None
    """Far plane of a bounded scene in the run's coordinates."""

    def flags(self) -> dict:
        return {k: getattr(self, k) for k in ("bounded", "timestamps", "alpha", "appearance_variation", "exact_poses",
                                              "format")}

    def bounds(self) -> dict:
        """The near and far planes (None where the scene does not fix them)."""
        return {"near": self.near, "far": self.far}

    def sizes(self) -> dict:
        h, w = self.image_size
        return {"pixels": h * w * self.num_images, "max_side": max(h, w), "num_images": self.num_images}


def _first_image(dataset: Dataset) -> np.ndarray:
    frame = (dataset.train_frames or dataset.frames)[0]
    try:
        with Image.open(frame.image) as im:
            return np.asarray(im)
    except OSError as exc:
        raise SceneProbeError(f"cannot read the first training image {frame.image}: {exc}") from None


def _object_centric(poses: np.ndarray) -> Tuple[bool, str]:
    """Cameras surrounding a common target (an object-centric capture) or not."""
    poses = np.asarray(poses, dtype=np.float64)[:, :3, :]
    centres, forward = poses[:, :, 3], -poses[:, :, 2]
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    # the point closest to every optical axis (least squares)
    proj = np.eye(3)[None] - forward[:, :, None] * forward[:, None, :]
    target = np.linalg.lstsq(proj.sum(0), (proj @ centres[:, :, None]).sum(0), rcond=None)[0][:, 0]
    dirs = centres - target
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    cos = np.clip(dirs @ dirs.T, -1.0, 1.0)
    spread = math.degrees(float(np.arccos(cos.min())))
    return spread >= OBJECT_CENTRIC_SPREAD_DEG, f"cameras span {spread:.0f} deg around a common target"


def probe_scene(data: DataLike) -> SceneFacts:
    """The facts of the dataset ``data`` (a :class:`~nerfify_ns.dataset.Dataset` or its folder)."""
    dataset = as_dataset(data)
    frames = dataset.train_frames or dataset.frames
    image = _first_image(dataset)
    meta = dataset.meta.get("scene")
    evidence: Dict[str, str] = {"format": f"{dataset.format}: {dataset.evidence}"}

    alpha = image.ndim == 3 and image.shape[2] == 4 and bool((image[..., 3] < 255).any())
    evidence["alpha"] = f"first image has {'an' if alpha else 'no'} alpha channel with transparency"
    if dataset.has_masks:
        evidence["alpha"] += "; every frame has a mask"
    timestamps = dataset.has_times
    evidence["timestamps"] = "every frame has a time" if timestamps else "frames have no times"
    exact_poses = dataset.format in EXACT_POSE_FORMATS
    if meta is not None:
        bounded = bool(meta.get("bounded", True))
        evidence["bounded"] = f"scene.json: bounded={bounded}"
        exact_poses, evidence["exact_poses"] = True, "synthetic scene (scene.json): poses are exact"
        appearance_variation = False
        evidence["appearance_variation"] = "synthetic scene (scene.json): fixed lighting"
    else:
        if dataset.format == "llff":
            bounded, evidence["bounded"] = False, "LLFF forward-facing capture (poses_bounds.npy): unbounded"
        else:
            centric, how = _object_centric(dataset.poses(frames))
            bounded = centric and alpha
            evidence["bounded"] = f"{how}{' and transparent background' if alpha else ', background present'}"
        evidence["exact_poses"] = (f"{dataset.format} format (synthetic renders): poses are exact" if exact_poses
                                   else f"poses from a reconstruction ({dataset.format} format)")
        if dataset.meta.get("reprojection_error"):
            error, points = dataset.meta["reprojection_error"]
            evidence["exact_poses"] += f"; COLMAP mean reprojection error {error:.2f} px over {points} points"
        appearance_variation = not exact_poses
        evidence["appearance_variation"] = ("synthetic renders: fixed lighting" if exact_poses
                                            else "real capture: exposure and lighting may vary")
    near = far = None
    if bounded:
        from nerfify_ns.synthesis.scene_bounds import near_far

        near, far, evidence["bounds"] = near_far(dataset)
    return SceneFacts(bounded=bounded, timestamps=timestamps, alpha=alpha, appearance_variation=appearance_variation,
                      exact_poses=exact_poses, image_size=(int(image.shape[0]), int(image.shape[1])),
                      num_images=len(frames), evidence=evidence, format=dataset.format, near=near, far=far)
