"""What a dataset needs: bounded or not, alpha, timestamps, appearance variation, pose quality, size.

Reads a Blender-format (``transforms_train.json``) or Nerfstudio-format (``transforms.json``)
scene. Facts come from our scenes' ``scene.json`` when there is one, otherwise from the cameras
and images; each fact records how it was found, so a pruning can say why.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
from PIL import Image

from nerfify_ns.errors import NerfifyError

OBJECT_CENTRIC_SPREAD_DEG = 120.0


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

    def flags(self) -> dict:
        return {k: getattr(self, k) for k in ("bounded", "timestamps", "alpha", "appearance_variation", "exact_poses")}

    def sizes(self) -> dict:
        h, w = self.image_size
        return {"pixels": h * w * self.num_images, "max_side": max(h, w), "num_images": self.num_images}


def _transforms(data: Path) -> Tuple[Path, dict, str]:
    for name, kind in (("transforms_train.json", "blender"), ("transforms.json", "nerfstudio")):
        path = data / name
        if path.is_file():
            try:
                return path, json.loads(path.read_text()), kind
            except ValueError as exc:
                raise SceneProbeError(f"{path} is not valid JSON ({exc}); fix or regenerate the dataset") from None
    raise SceneProbeError(f"{data} holds no transforms_train.json (Blender) or transforms.json (Nerfstudio); "
                          "pass a dataset folder")


def _image_path(data: Path, transforms_path: Path, frame: dict) -> Path:
    rel = Path(frame["file_path"])
    path = (transforms_path.parent / rel)
    return path if path.suffix else path.with_suffix(".png")


def _first_image(data: Path, transforms_path: Path, frames: List[dict]) -> np.ndarray:
    try:
        return np.asarray(Image.open(_image_path(data, transforms_path, frames[0])))
    except (OSError, KeyError, IndexError) as exc:
        raise SceneProbeError(f"cannot read the first training image of {data}: {exc}") from None


def _object_centric(frames: List[dict]) -> Tuple[bool, str]:
    """Cameras surrounding a common target (an object-centric capture) or not."""
    poses = np.array([f["transform_matrix"] for f in frames], dtype=np.float64)[:, :3, :]
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


def probe_scene(data: Path) -> SceneFacts:
    """The facts of the dataset in ``data``."""
    data = Path(data)
    if not data.is_dir():
        raise SceneProbeError(f"{data} is not a folder; pass a Blender or Nerfstudio dataset folder")
    transforms_path, transforms, kind = _transforms(data)
    frames = transforms.get("frames") or []
    if not frames:
        raise SceneProbeError(f"{transforms_path} lists no frames")
    image = _first_image(data, transforms_path, frames)
    meta_path = data / "scene.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else None
    evidence: Dict[str, str] = {}

    alpha = image.ndim == 3 and image.shape[2] == 4 and bool((image[..., 3] < 255).any())
    evidence["alpha"] = f"first image has {'an' if alpha else 'no'} alpha channel with transparency"
    timestamps = all("time" in f for f in frames)
    evidence["timestamps"] = "every frame has a time" if timestamps else "frames have no times"
    if meta is not None:
        bounded = bool(meta.get("bounded", True))
        evidence["bounded"] = f"scene.json: bounded={bounded}"
        exact_poses, evidence["exact_poses"] = True, "synthetic scene (scene.json): poses are exact"
        appearance_variation = False
        evidence["appearance_variation"] = "synthetic scene (scene.json): fixed lighting"
    else:
        centric, how = _object_centric(frames)
        bounded = centric and alpha
        evidence["bounded"] = f"{how}{' and transparent background' if alpha else ', background present'}"
        exact_poses = kind == "blender" and "camera_angle_x" in transforms
        evidence["exact_poses"] = ("Blender synthetic format (camera_angle_x)" if exact_poses
                                   else "poses from a reconstruction (Nerfstudio transforms.json)")
        appearance_variation = not exact_poses
        evidence["appearance_variation"] = ("synthetic renders: fixed lighting" if exact_poses
                                            else "real capture: exposure and lighting may vary")
    return SceneFacts(bounded=bounded, timestamps=timestamps, alpha=alpha, appearance_variation=appearance_variation,
                      exact_poses=exact_poses, image_size=(int(image.shape[0]), int(image.shape[1])),
                      num_images=len(frames), evidence=evidence)
