"""What a dataset needs: bounded or not, alpha, timestamps, appearance variation, pose quality, size, format.

Reads the typed dataset (:mod:`nerfify_ns.dataset`: Blender, D-NeRF, Nerfstudio, COLMAP or LLFF, read once
and shared by every stage). Facts come from our scenes' ``scene.json`` when there is one, otherwise from the
cameras and images; each fact records how it was found, so a pruning can say why. The format (with what
identified it) is a fact too: the plan records it and it picks the Nerfstudio dataparser.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from PIL import Image

from nerfify_ns.dataset import DataLike, Dataset, as_dataset
from nerfify_ns.errors import NerfifyError

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
    image_size: tuple[int, int]
    num_images: int
    evidence: dict[str, str] = field(default_factory=dict)
    format: str = "blender"
    """The dataset format (:data:`nerfify_ns.dataset.formats.FORMATS`)."""
    forward_facing: bool = False
    """The cameras face one way, side by side (LLFF-style), rather than surrounding the scene."""
    near: float | None = None
    """Near plane of a bounded scene in the run's coordinates (:mod:`~nerfify_ns.synthesis.scene_bounds`)."""
    far: float | None = None
    """Far plane of a bounded scene in the run's coordinates."""

    def flags(self) -> dict:
        return {k: getattr(self, k) for k in ("bounded", "timestamps", "alpha", "appearance_variation", "exact_poses",
                                              "format", "forward_facing")}

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


def probe_scene(data: DataLike) -> SceneFacts:
    """The facts of the dataset ``data`` (a :class:`~nerfify_ns.dataset.Dataset` or its folder)."""
    dataset = as_dataset(data)
    frames = dataset.train_frames or dataset.frames
    image = _first_image(dataset)
    meta = dataset.meta.get("scene")
    evidence: dict[str, str] = {"format": f"{dataset.format}: {dataset.evidence}"}

    alpha = image.ndim == 3 and image.shape[2] == 4 and bool((image[..., 3] < 255).any())
    evidence["alpha"] = f"first image has {'an' if alpha else 'no'} alpha channel with transparency"
    if dataset.has_masks:
        evidence["alpha"] += "; every frame has a mask"
    timestamps = dataset.has_times
    evidence["timestamps"] = "every frame has a time" if timestamps else "frames have no times"
    exact_poses = dataset.format in EXACT_POSE_FORMATS
    forward_facing = False
    if meta is not None:
        bounded = bool(meta.get("bounded", True))
        evidence["bounded"] = f"scene.json: bounded={bounded}"
        exact_poses, evidence["exact_poses"] = True, "synthetic scene (scene.json): poses are exact"
        appearance_variation = False
        evidence["appearance_variation"] = "synthetic scene (scene.json): fixed lighting"
    else:  # measured from the cameras, the images and the COLMAP model (nerfify_ns.synthesis.capture_facts)
        from nerfify_ns.synthesis.capture_facts import capture_facts

        measured = capture_facts(dataset, alpha, exact_poses)
        bounded, appearance_variation = measured.bounded, measured.appearance_variation
        forward_facing = measured.forward_facing
        evidence.update({k: v for k, v in measured.evidence.items() if k != "registered"})
        evidence["exact_poses"] = (f"{dataset.format} format (synthetic renders): poses are exact" if exact_poses
                                   else f"poses from a reconstruction ({dataset.format} format)")
        if dataset.meta.get("reprojection_error"):
            error, points = dataset.meta["reprojection_error"]
            evidence["exact_poses"] += f"; COLMAP mean reprojection error {error:.2f} px over {points} points"
        if "registered" in measured.evidence:
            evidence["exact_poses"] += f"; {measured.evidence['registered']}"
    near = far = None
    if bounded:
        from nerfify_ns.synthesis.scene_bounds import near_far

        near, far, evidence["bounds"] = near_far(dataset)
    return SceneFacts(bounded=bounded, timestamps=timestamps, alpha=alpha, appearance_variation=appearance_variation,
                      exact_poses=exact_poses, forward_facing=forward_facing,
                      image_size=(int(image.shape[0]), int(image.shape[1])),
                      num_images=len(frames), evidence=evidence, format=dataset.format, near=near, far=far)
