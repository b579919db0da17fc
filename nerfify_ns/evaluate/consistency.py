"""Cross-view depth consistency: free-space violations (floaters) found by reprojection.

Depth convention (``nerfify_ns.scenes`` and Nerfstudio's ``depth`` output alike): distance along
the unit pixel-centre ray from the camera centre, OpenGL/Blender cameras looking along -z, pixel
``(row, col)`` through ``(col + 0.5, row + 0.5)``; ``inf``/NaN (or ``valid == False``, e.g.
accumulation < 0.5 for a NeRF render) means no surface.

Every surface point X of a target view is projected into each reference view j. With ``s`` the
distance from camera j to X and ``D`` the depths seen by j in the 3x3 pixels around X's
projection (background = ``inf``):

* ``s < min(D) (1 - rel_tol)``: X lies in space that view j sees as empty (it looks through X
  at something farther, or at nothing): a **violation**;
* ``min(D) (1 - rel_tol) <= s <= max(D) (1 + rel_tol)``: view j sees a surface at X: **support**;
* farther: X is occluded in view j, which says nothing (not evidence either way).

A pixel is inconsistent when it has at least ``min_votes`` violations and violations make at least
``min_fraction`` of its evidence. A view's score is the fraction of its pixels with evidence that
are consistent. Surface points that fall inside no reference view's frustum cannot be checked;
they are reported apart as ``unobserved`` (geometry no reference view constrains). Taking the
3x3 min/max makes the test conservative at silhouettes and grazing surfaces, where one pixel's
depth jumps.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from PIL import Image
from scipy import ndimage

from nerfify_ns import runfolder
from nerfify_ns.scenes import camera_rays, focal_length, load_depth

Array = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass
class DepthView:
    """One view's depth map and pinhole camera (OpenGL axes): ``focal`` alone is the Blender camera (square
    pixels, principal point at the image centre); ``fx``, ``fy``, ``cx``, ``cy`` (pixels) override it."""

    depth: Array  # (H, W) distance along the unit ray; inf where there is no surface
    c2w: Array  # (4, 4) camera-to-world, OpenGL axes
    focal: float  # pixels
    name: str = ""
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None

    def __post_init__(self) -> None:
        depth = np.asarray(self.depth, dtype=np.float64)
        if depth.ndim == 3 and depth.shape[-1] == 1:
            depth = depth[..., 0]
        if depth.ndim != 2:
            raise ValueError(f"depth of view {self.name!r} must be (H, W), got {depth.shape}")
        self.depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.inf)
        self.c2w = np.asarray(self.c2w, dtype=np.float64).reshape(4, 4)
        h, w = self.depth.shape
        self.fx = float(self.focal if self.fx is None else self.fx)
        self.fy = float(self.focal if self.fy is None else self.fy)
        self.cx = float(0.5 * w if self.cx is None else self.cx)
        self.cy = float(0.5 * h if self.cy is None else self.cy)

    @classmethod
    def of_frame(cls, depth: ArrayLike, frame, *, valid: ArrayLike | None = None) -> DepthView:
        """The view of a dataset frame (:class:`nerfify_ns.dataset.Frame`: its camera-to-world and
        intrinsics, rescaled when the depth map is not the image's size); distortion is ignored."""
        d = np.array(depth, dtype=np.float64).reshape(np.shape(depth)[:2])
        if valid is not None:
            d[~np.asarray(valid, dtype=bool).reshape(d.shape)] = np.inf
        intr = frame.intrinsics
        sx, sy = d.shape[1] / intr.width, d.shape[0] / intr.height
        return cls(d, frame.c2w, intr.fx * sx, frame.stem, fx=intr.fx * sx, fy=intr.fy * sy, cx=intr.cx * sx,
                   cy=intr.cy * sy)

    @classmethod
    def blender(
        cls,
        depth: ArrayLike,
        c2w: ArrayLike,
        camera_angle_x: float,
        *,
        valid: ArrayLike | None = None,
        name: str = "",
    ) -> DepthView:
        d = np.array(depth, dtype=np.float64).reshape(np.shape(depth)[:2])
        if valid is not None:
            d[~np.asarray(valid, dtype=bool).reshape(d.shape)] = np.inf
        return cls(d, np.asarray(c2w), focal_length(d.shape[1], camera_angle_x), name)

    def points(self) -> Array:
        """World points ``(H, W, 3)`` (non-finite where there is no surface)."""
        h, w = self.depth.shape
        rows, cols = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
        d_cam = np.stack([(cols - self.cx) / self.fx, -(rows - self.cy) / self.fy, -np.ones_like(cols)], -1)
        d_world = d_cam @ self.c2w[:3, :3].T
        d_world /= np.linalg.norm(d_world, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore"):
            return self.c2w[:3, 3] + self.depth[..., None] * d_world

    def project(self, points: Array) -> tuple[NDArray[np.int64], NDArray[np.int64], Array, BoolArray]:
        """Pixel (row, col) of world points, their distance to this camera, and whether they land
        in the image in front of the camera."""
        rel = points - self.c2w[:3, 3]
        cam = rel @ self.c2w[:3, :3]  # R^T (X - t)
        z = -cam[..., 2]
        h, w = self.depth.shape
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * cam[..., 0] / z + self.cx
            v = -self.fy * cam[..., 1] / z + self.cy
            inside = (z > 1e-9) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        col = np.where(inside, np.floor(np.nan_to_num(u)), 0).astype(np.int64)
        row = np.where(inside, np.floor(np.nan_to_num(v)), 0).astype(np.int64)
        return row, col, np.linalg.norm(rel, axis=-1), inside


def views_from_frames(
    frames: Sequence, depths: Sequence[ArrayLike], valid: Sequence[ArrayLike] | None = None
) -> list[DepthView]:
    """DepthViews for dataset frames (:class:`nerfify_ns.dataset.Frame`, any format) and their rendered depth
    maps, in order."""
    if len(depths) != len(frames):
        raise ValueError(f"{len(frames)} frames but {len(depths)} depth maps were given")
    return [DepthView.of_frame(d, f, valid=None if valid is None else valid[i])
            for i, (d, f) in enumerate(zip(depths, frames, strict=False))]


def views_from_transforms(
    transforms: Path, depths: Sequence[ArrayLike], valid: Sequence[ArrayLike] | None = None
) -> list[DepthView]:
    """DepthViews for the frames of a ``transforms_*.json`` and rendered depth maps, in frame order."""
    meta = json.loads(Path(transforms).read_text())
    frames = meta["frames"]
    if len(depths) != len(frames):
        raise ValueError(f"{transforms} has {len(frames)} frames but {len(depths)} depth maps were given")
    return [
        DepthView.blender(
            d,
            f["transform_matrix"],
            float(meta["camera_angle_x"]),
            valid=None if valid is None else valid[i],
            name=Path(f["file_path"]).name,
        )
        for i, (d, f) in enumerate(zip(depths, frames, strict=False))
    ]


def scene_views(root: Path, split: str, *, clean: bool = False) -> list[DepthView]:
    """The exact depth maps a generated scene wrote for ``split`` (``clean``: floater-free depth
    where a view has it)."""
    root = Path(root)
    rays = camera_rays(root / f"transforms_{split}.json")
    views = []
    for i, file_path in enumerate(rays.file_paths):
        stem = root / split / Path(file_path).name
        clean_path = stem.with_name(stem.name + "_depth_clean.npy")
        path = clean_path if clean and clean_path.exists() else stem.with_name(stem.name + "_depth.npy")
        views.append(DepthView.blender(load_depth(path), rays.c2w[i], rays.camera_angle_x, name=stem.name))
    return views


@dataclass
class ViewConsistency:
    name: str
    mask: BoolArray  # (H, W) inconsistent pixels
    violations: NDArray[np.int64]  # (H, W) number of views that see through the pixel's point
    support: NDArray[np.int64]  # (H, W) number of views that see a surface at the point
    unobserved: BoolArray  # (H, W) surface pixels inside no reference view's frustum
    score: float  # consistent fraction of pixels with evidence, in [0, 1]

    def summary(self) -> dict:
        evidence = self.violations + self.support > 0
        return {
            "view": self.name,
            "score": self.score,
            "inconsistent_pixels": int(self.mask.sum()),
            "pixels_with_evidence": int(evidence.sum()),
            "unobserved_pixels": int(self.unobserved.sum()),
            "inconsistent_fraction": float(self.mask.mean()),
        }


@dataclass
class ConsistencyReport:
    views: list[ViewConsistency] = field(default_factory=list)

    @property
    def mean_score(self) -> float:
        return float(np.mean([v.score for v in self.views])) if self.views else 1.0

    def summary(self) -> dict:
        return {
            "mean_score": self.mean_score,
            "inconsistent_fraction": float(np.mean([v.mask.mean() for v in self.views]))
            if self.views
            else 0.0,
            "views": [v.summary() for v in self.views],
        }

    def save(self, out_dir: Path) -> Path:
        """``<view>_inconsistent.png`` masks (255 = inconsistent) and ``consistency.json``."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        for i, view in enumerate(self.views):
            name = view.name or f"view_{i:03d}"
            Image.fromarray(np.where(view.mask, 255, 0).astype(np.uint8)).save(
                out_dir / f"{name}_inconsistent.png"
            )
        path = out_dir / runfolder.CONSISTENCY
        path.write_text(json.dumps(self.summary(), indent=2) + "\n")
        return path


def _same_camera(a: DepthView, b: DepthView) -> bool:
    return (a.depth.shape == b.depth.shape and np.allclose(a.c2w, b.c2w, atol=1e-9)
            and (a.fx, a.fy, a.cx, a.cy) == (b.fx, b.fy, b.cx, b.cy))


def check_view(
    target: DepthView,
    references: Sequence[DepthView],
    *,
    rel_tol: float = 0.03,
    min_votes: int = 1,
    min_fraction: float = 0.5,
) -> ViewConsistency:
    """Free-space check of one view's depth against the reference views (itself excluded)."""
    points = target.points()
    surface = np.isfinite(target.depth)
    violations = np.zeros(target.depth.shape, dtype=np.int64)
    support = np.zeros_like(violations)
    observed = np.zeros(target.depth.shape, dtype=bool)
    for ref in references:
        if _same_camera(target, ref):
            continue
        near = ndimage.minimum_filter(ref.depth, size=3, mode="nearest")
        far_in = np.where(np.isfinite(ref.depth), ref.depth, -np.inf)
        far = ndimage.maximum_filter(far_in, size=3, mode="nearest")
        row, col, dist, inside = ref.project(np.where(surface[..., None], points, 0.0))
        inside &= surface
        observed |= inside
        lo = near[row, col] * (1.0 - rel_tol)
        hi = far[row, col] * (1.0 + rel_tol)
        violations += inside & (dist < lo)
        support += inside & (dist >= lo) & (dist <= hi)
    evidence = violations + support
    with np.errstate(invalid="ignore", divide="ignore"):
        fraction = np.where(evidence > 0, violations / np.maximum(evidence, 1), 0.0)
    mask = (violations >= min_votes) & (fraction >= min_fraction)
    checked = int((evidence > 0).sum())
    score = 1.0 - float(mask.sum()) / checked if checked else 1.0
    return ViewConsistency(target.name, mask, violations, support, surface & ~observed, score)


def check_consistency(
    targets: Sequence[DepthView], references: Sequence[DepthView] | None = None, **kwargs
) -> ConsistencyReport:
    """Check every target view against ``references`` (default: the other targets)."""
    refs = list(targets) if references is None else list(references)
    return ConsistencyReport([check_view(t, refs, **kwargs) for t in targets])


def mask_scores(predicted: BoolArray, truth: BoolArray) -> dict:
    """Pixel recall and precision of a predicted mask against a ground-truth mask."""
    tp = int((predicted & truth).sum())
    return {
        "recall": tp / int(truth.sum()) if truth.any() else 1.0,
        "precision": tp / int(predicted.sum()) if predicted.any() else 1.0,
        "true_positives": tp,
        "predicted": int(predicted.sum()),
        "truth": int(truth.sum()),
    }
