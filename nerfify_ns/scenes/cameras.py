"""Pinhole cameras in the Blender / NeRF-synthetic convention, camera rigs and ray generation.

Convention (the one Nerfstudio's ``blender`` and ``dnerf`` dataparsers read): a camera-to-world
matrix whose camera looks along its local -z with +y up (OpenGL); square pixels with
``focal = 0.5 * W / tan(0.5 * camera_angle_x)``, principal point at ``(W/2, H/2)``, and the
ray of pixel (row, col) through ``(col + 0.5, row + 0.5)``, exactly as Nerfstudio's
``Cameras.generate_rays`` does. World up is +z. Ray directions are unit length, so a depth
is the Euclidean distance from the camera centre along the ray.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import SceneSpecError
from .geometry import spec_float, spec_vector

Array = NDArray[np.float64]

SPLITS: tuple[str, ...] = ("train", "val", "test")
WORLD_UP = np.array([0.0, 0.0, 1.0])
PIXEL_CENTER = np.array([[0.5, 0.5]])
_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def focal_length(width: int, camera_angle_x: float) -> float:
    """Focal length in pixels from the horizontal field of view (Blender dataparser formula)."""
    return 0.5 * width / float(np.tan(0.5 * camera_angle_x))


def subpixel_offsets(supersample: int) -> Array:
    """``(S*S, 2)`` sample positions (x, y) inside a pixel on a regular S x S grid."""
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    g = (np.arange(supersample) + 0.5) / supersample
    xs, ys = np.meshgrid(g, g, indexing="xy")
    return np.stack([xs.ravel(), ys.ravel()], axis=1)


def pixel_rays(
    c2w: Array, height: int, width: int, camera_angle_x: float, offsets: Array = PIXEL_CENTER
) -> tuple[Array, Array]:
    """Rays through each pixel at the given sub-pixel offsets.

    Returns origins and unit directions, both ``(H, W, S, 3)`` with ``S = len(offsets)``.
    """
    c2w = np.asarray(c2w, dtype=np.float64)
    f = focal_length(width, camera_angle_x)
    rows, cols = np.meshgrid(
        np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij"
    )
    u = cols[..., None] + offsets[:, 0]
    v = rows[..., None] + offsets[:, 1]
    d_cam = np.stack([(u - 0.5 * width) / f, -(v - 0.5 * height) / f, -np.ones_like(u)], axis=-1)
    d_world = d_cam @ c2w[:3, :3].T
    d_world /= np.linalg.norm(d_world, axis=-1, keepdims=True)
    origins = np.broadcast_to(c2w[:3, 3], d_world.shape).copy()
    return origins, d_world


def look_at(position: Array, target: Array, up: Array = WORLD_UP) -> Array:
    """Camera-to-world matrix of a camera at ``position`` looking at ``target`` (OpenGL axes)."""
    z = position - target
    z = z / np.linalg.norm(z)
    x = np.cross(up, z)
    if np.linalg.norm(x) < 1e-9:  # looking straight along the up axis
        x = np.cross(np.array([0.0, 1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, position
    return c2w


RIG_FIELDS = frozenset({"radius", "camera_angle_x", "elevation_deg", "target"})


@dataclass(frozen=True)
class Rig:
    """Cameras on a sphere of ``radius`` around ``target`` in an elevation band, looking at it.

    Train views follow a golden-angle spiral (even coverage of the band); val and test views
    are drawn at random in the band. Each split has its own random stream derived from the
    seed, so changing the number of train views leaves the test cameras unchanged.
    """

    radius: float
    camera_angle_x: float
    elevation_deg: tuple[float, float]
    target: Array

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any]) -> Rig:
        unknown = set(spec) - RIG_FIELDS
        if unknown:
            raise SceneSpecError(f"unknown rig fields {sorted(unknown)}; valid: {sorted(RIG_FIELDS)}")
        lo, hi = spec_vector(spec, "elevation_deg", 2)
        if not -89.0 <= lo <= hi <= 89.0:
            raise SceneSpecError(f"rig elevation_deg must satisfy -89 <= lo <= hi <= 89, got {[lo, hi]}")
        angle = spec_float(spec, "camera_angle_x", positive=True)
        if angle >= np.pi:
            raise SceneSpecError(f"camera_angle_x must be below pi, got {angle}")
        target = spec_vector(spec, "target", 3) if "target" in spec else np.zeros(3)
        return cls(spec_float(spec, "radius", positive=True), angle, (float(lo), float(hi)), target)

    def poses(self, n: int, split: str, seed: int) -> Array:
        """``(n, 4, 4)`` camera-to-world matrices for one split."""
        rng = np.random.default_rng([seed, SPLITS.index(split)])
        s_lo, s_hi = np.sin(np.deg2rad(self.elevation_deg))
        if split == "train":
            sin_el = s_lo + (np.arange(n) + 0.5) / max(n, 1) * (s_hi - s_lo)
            azimuth = rng.uniform(0.0, 2.0 * np.pi) + _GOLDEN_ANGLE * np.arange(n)
        else:
            sin_el = rng.uniform(s_lo, s_hi, size=n)
            azimuth = rng.uniform(0.0, 2.0 * np.pi, size=n)
        cos_el = np.sqrt(1.0 - sin_el**2)
        offsets = self.radius * np.stack([cos_el * np.cos(azimuth), cos_el * np.sin(azimuth), sin_el], axis=1)
        return (
            np.stack([look_at(self.target + o, self.target) for o in offsets]) if n else np.zeros((0, 4, 4))
        )


@dataclass(frozen=True)
class CameraRays:
    """Per-pixel rays of every frame in a transforms file (reusable for reprojection)."""

    origins: Array  # (N, H, W, 3)
    directions: Array  # (N, H, W, 3), unit length
    c2w: Array  # (N, 4, 4)
    camera_angle_x: float
    file_paths: list[str]
    times: Array | None  # (N,) for dynamic scenes

    def points(self, depth: Array, frame: int) -> Array:
        """World points ``(H, W, 3)`` of a depth map (distance along the ray) of one frame."""
        return self.origins[frame] + np.asarray(depth, dtype=np.float64)[..., None] * self.directions[frame]


def image_path(transforms_path: Path, file_path: str, suffix: str = ".png") -> Path:
    """Resolve a frame's ``file_path`` (``./train/r_0``) next to its transforms file."""
    rel = file_path[2:] if file_path.startswith("./") else file_path
    return transforms_path.parent / (rel + suffix)


def camera_rays(transforms: str | Path, resolution: int | Sequence[int] | None = None) -> CameraRays:
    """Rays of every frame of a ``transforms_*.json``.

    ``resolution`` is ``H`` (square) or ``(H, W)``; by default it is read from the first
    frame's image, as Nerfstudio's blender dataparser does.
    """
    path = Path(transforms)
    meta = json.loads(path.read_text())
    frames = meta["frames"]
    if resolution is None:
        from PIL import Image

        with Image.open(image_path(path, frames[0]["file_path"])) as im:
            width, height = im.size
    elif isinstance(resolution, int):
        height = width = resolution
    else:
        height, width = resolution
    angle = float(meta["camera_angle_x"])
    c2w = np.array([f["transform_matrix"] for f in frames], dtype=np.float64).reshape(-1, 4, 4)
    rays = [pixel_rays(m, height, width, angle) for m in c2w]
    origins = np.stack([o[:, :, 0] for o, _ in rays]) if rays else np.zeros((0, height, width, 3))
    directions = np.stack([d[:, :, 0] for _, d in rays]) if rays else np.zeros((0, height, width, 3))
    times = (
        np.array([f["time"] for f in frames], dtype=np.float64) if frames and "time" in frames[0] else None
    )
    return CameraRays(origins, directions, c2w, angle, [f["file_path"] for f in frames], times)
