"""Scene facts of a real capture, measured from its cameras, its images and its structure-from-motion model.

* **Camera layout.** Forward-facing (LLFF-style: every optical axis within ``FORWARD_FACING_DEG`` of the mean
  viewing direction, the cameras side by side) or surrounding a common target (360 degrees: the cameras span
  ``OBJECT_CENTRIC_SPREAD_DEG`` or more around the point closest to every optical axis, their axes not all
  within ``FORWARD_FACING_DEG`` of one direction).
* **Extent.** With a COLMAP model (a COLMAP dataset, or the ``colmap/sparse/0`` that ``ns-process-data`` keeps
  beside ``transforms.json``): the share of triangulated points lying farther from the cameras' centre than
  ``EXTENT_RATIO`` times the cameras' own radius. Content beyond the cameras (walls, the ground running to the
  horizon, far objects) makes the scene unbounded: Nerfstudio's scene box cannot hold it without contraction.
* **Background.** Without points, an opaque image whose border is one uniform colour in every image is an
  object photographed on a backdrop (bounded); any other opaque background is taken as the world beyond.
* **Appearance.** Each COLMAP 3D point is one surface point seen in several images. For a diffuse surface its
  linear colour differs between images only by the camera's exposure and white balance, so per image and
  channel the median log-ratio of its observations to the points' consensus colour (alternating the two
  estimates, as a robust gain model) gives that image's gains; their spread across images in stops (exposure)
  and in red/green and blue/green log-ratios (white balance) says whether an appearance embedding has
  something to explain.

Every fact comes with the evidence that decided it (numbers included), which pruning quotes in its reasons.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from nerfify_ns.dataset import Dataset
from nerfify_ns.dataset.colmap import Observations, read_observations

OBJECT_CENTRIC_SPREAD_DEG = 120.0
FORWARD_FACING_DEG = 40.0
"""Largest angle between an optical axis and the mean viewing direction of a forward-facing capture."""
EXTENT_RATIO = 1.5
"""A point farther than this many camera radii from the cameras' centre lies beyond the cameras."""
UNBOUNDED_SHARE = 0.1
"""The share of points beyond the cameras that makes a scene unbounded."""
EXPOSURE_SPREAD_STOPS = 0.1
"""Standard deviation of per-image exposure (stops) above which appearance varies."""
WHITE_BALANCE_SPREAD = 0.03
"""Standard deviation of per-image red/green or blue/green log gains above which white balance varies."""
MIN_TRACK = 3
MAX_IMAGES = 64
BORDER_PX = 2
UNIFORM_BORDER_STD = 0.03


@dataclass(frozen=True)
class Layout:
    """How the cameras are arranged."""

    forward_facing: bool
    surrounding: bool
    evidence: str


def camera_layout(poses: np.ndarray) -> Layout:
    """Forward-facing or surrounding, from camera-to-world matrices (OpenGL axes)."""
    poses = np.asarray(poses, dtype=np.float64)[:, :3, :]
    centres, forward = poses[:, :, 3], -poses[:, :, 2]
    forward = forward / np.linalg.norm(forward, axis=1, keepdims=True)
    mean = forward.mean(0)
    deviation = 180.0 if np.linalg.norm(mean) < 1e-6 else math.degrees(float(np.arccos(np.clip(
        forward @ (mean / np.linalg.norm(mean)), -1.0, 1.0)).max()))
    proj = np.eye(3)[None] - forward[:, :, None] * forward[:, None, :]
    target = np.linalg.lstsq(proj.sum(0), (proj @ centres[:, :, None]).sum(0), rcond=None)[0][:, 0]
    dirs = centres - target
    dirs /= np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-12)
    spread = math.degrees(float(np.arccos(np.clip(dirs @ dirs.T, -1.0, 1.0)).max()))
    forward_facing = deviation <= FORWARD_FACING_DEG  # (parallel axes meet nowhere: the spread means nothing)
    surrounding = spread >= OBJECT_CENTRIC_SPREAD_DEG and not forward_facing
    text = (f"cameras span {spread:.0f} deg around a common target, optical axes within {deviation:.0f} deg of "
            f"their mean ({'360-degree' if surrounding else 'forward-facing' if forward_facing else 'partial'})")
    return Layout(forward_facing, surrounding, text)


def model_folder(dataset: Dataset) -> Path | None:
    """The COLMAP model that came with the dataset (COLMAP format, or ns-process-data's ``colmap/sparse/0``)."""
    if dataset.format == "colmap":
        return dataset.root / str(dataset.meta["colmap_path"])
    folder = dataset.root / "colmap" / "sparse" / "0"
    return folder if dataset.format == "nerfstudio" and folder.is_dir() else None


def points_beyond_cameras(obs: Observations) -> tuple[float, str]:
    """Share of the model's points farther than ``EXTENT_RATIO`` camera radii from the cameras' centre."""
    centre = obs.centres.mean(0)
    radius = float(np.linalg.norm(obs.centres - centre, axis=1).mean())
    points = np.stack(list(obs.points.values()))
    ratio = np.linalg.norm(points - centre, axis=1) / max(radius, 1e-12)
    share = float((ratio > EXTENT_RATIO).mean())
    return share, (f"{100 * share:.0f}% of {len(points)} COLMAP points lie beyond {EXTENT_RATIO:g}x the cameras' "
                   f"radius (95th percentile at {np.percentile(ratio, 95):.1f}x)")


def uniform_background(dataset: Dataset) -> tuple[bool, str]:
    """Whether every image's border is one uniform colour, the same in all images (a backdrop)."""
    colours = []
    for frame in _sample(dataset):
        with Image.open(frame.image) as im:
            rgb = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
        b = BORDER_PX
        border = np.concatenate([rgb[:b].reshape(-1, 3), rgb[-b:].reshape(-1, 3), rgb[:, :b].reshape(-1, 3),
                                 rgb[:, -b:].reshape(-1, 3)])
        if border.std(0).max() > UNIFORM_BORDER_STD:
            return False, f"the border of {frame.image.name} is not one colour (background present)"
        colours.append(border.mean(0))
    spread = float(np.ptp(np.array(colours), axis=0).max())
    if spread > 2 * UNIFORM_BORDER_STD:
        return False, "image borders differ in colour between images (background present)"
    c = np.mean(colours, 0)
    return True, f"every image's border is one colour ({', '.join(f'{v:.2f}' for v in c)}): an object on a backdrop"


def _sample(dataset: Dataset):
    frames = dataset.frames
    step = max(1, math.ceil(len(frames) / MAX_IMAGES))
    return frames[::step]


def _linear(srgb: np.ndarray) -> np.ndarray:
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


@dataclass(frozen=True)
class Appearance:
    """Per-image gains estimated from the points seen in several images."""

    varies: bool
    exposure_stops: np.ndarray
    """Per image (model order), relative to the median image."""
    white_balance: np.ndarray
    """``(M, 2)`` red/green and blue/green log gains per image, relative to the median image."""
    images: tuple[str, ...]
    evidence: str


def appearance_from_points(dataset: Dataset, obs: Observations) -> Appearance | None:
    """Per-image exposure and white balance from the colours of the model's points in the dataset's images;
    None when too few points are seen in three or more readable images."""
    by_name = {f.image.name: f for f in dataset.frames}
    rows = []
    for index, name in enumerate(obs.image_names):
        frame = by_name.get(Path(name).name)
        if frame is None:
            continue
        with Image.open(frame.image) as im:
            rgb = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
        pick = obs.image == index
        width, height = obs.camera_sizes[index]
        sx, sy = rgb.shape[1] / max(width, 1), rgb.shape[0] / max(height, 1)
        col = np.clip((obs.xy[pick, 0] * sx).astype(int), 0, rgb.shape[1] - 1)
        row = np.clip((obs.xy[pick, 1] * sy).astype(int), 0, rgb.shape[0] - 1)
        values = rgb[row, col]
        ok = (values > 0.02).all(1) & (values < 0.98).all(1)  # neither clipped nor in the noise floor
        rows.append((index, obs.point[pick][ok], np.log(_linear(values[ok]))))
    if len(rows) < 3:
        return None
    image = np.concatenate([np.full(len(r[1]), i) for i, r in enumerate(rows)])
    point = np.concatenate([r[1] for r in rows])
    logv = np.concatenate([r[2] for r in rows])
    ids, point_index, counts = np.unique(point, return_inverse=True, return_counts=True)
    keep = counts[point_index] >= MIN_TRACK
    image, point_index, logv = image[keep], point_index[keep], logv[keep]
    if keep.sum() < 30:
        return None
    gains = np.zeros((len(rows), 3))
    for _ in range(8):  # alternate: points' consensus colour, then each image's gains (medians: robust)
        residual = logv - gains[image]
        consensus = np.zeros((len(ids), 3))
        for c in range(3):
            consensus[:, c] = _group_median(point_index, residual[:, c], len(ids))
        residual = logv - consensus[point_index]
        for c in range(3):
            gains[:, c] = _group_median(image, residual[:, c], len(rows))
        gains -= np.median(gains, axis=0)
    exposure = gains.mean(1) / math.log(2.0)
    balance = np.stack([gains[:, 0] - gains[:, 1], gains[:, 2] - gains[:, 1]], 1)
    e_spread, wb_spread = float(exposure.std()), float(balance.std(0).max())
    varies = e_spread > EXPOSURE_SPREAD_STOPS or wb_spread > WHITE_BALANCE_SPREAD
    names = tuple(obs.image_names[r[0]] for r in rows)
    evidence = (f"{int(keep.sum())} observations of {len(np.unique(point_index))} COLMAP points in {len(rows)} images: "
                f"per-image exposure spread {e_spread:.2f} stops (threshold {EXPOSURE_SPREAD_STOPS:g}), white "
                f"balance spread {wb_spread:.3f} (threshold {WHITE_BALANCE_SPREAD:g})")
    return Appearance(varies, exposure, balance, names, evidence)


def _group_median(groups: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    order = np.lexsort((values, groups))
    g, v = groups[order], values[order]
    starts = np.searchsorted(g, np.arange(n))
    ends = np.searchsorted(g, np.arange(n), side="right")
    out = np.zeros(n)
    for i, (a, b) in enumerate(zip(starts, ends, strict=False)):
        if b > a:
            out[i] = 0.5 * (v[a + (b - a - 1) // 2] + v[a + (b - a) // 2])
    return out


@dataclass(frozen=True)
class CaptureFacts:
    """What a capture needs, measured, with the evidence for each fact."""

    bounded: bool
    forward_facing: bool
    appearance_variation: bool
    evidence: dict


def capture_facts(dataset: Dataset, alpha: bool, exact_poses: bool) -> CaptureFacts:
    """Bounded, forward-facing and appearance variation of ``dataset`` from its cameras, images and COLMAP model
    (``alpha``: the images have a transparent background; ``exact_poses``: a synthetic render)."""
    layout = camera_layout(dataset.poses(dataset.train_frames or dataset.frames))
    evidence = {"forward_facing": layout.evidence}
    folder = model_folder(dataset)
    obs = read_observations(folder) if folder is not None else None
    if obs is not None:
        photos = dataset.root / "images"
        n = len([p for p in photos.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg")]) \
            if photos.is_dir() else 0
        evidence["registered"] = f"COLMAP registered {len(obs.image_names)} of {max(n, len(obs.image_names))} images"
    forward_facing = layout.forward_facing
    if dataset.format == "llff" or forward_facing:
        bounded = False
        evidence["bounded"] = ("LLFF forward-facing capture (poses_bounds.npy): unbounded" if dataset.format == "llff"
                               else f"forward-facing capture ({layout.evidence}): unbounded")
    else:
        if alpha or dataset.has_masks:
            bounded = layout.surrounding
            evidence["bounded"] = f"{layout.evidence} and {'transparent background' if alpha else 'masks'}"
        elif obs is not None:
            share, text = points_beyond_cameras(obs)
            bounded = layout.surrounding and share <= UNBOUNDED_SHARE
            evidence["bounded"] = f"{layout.evidence}; {text}"
        else:
            backdrop, text = uniform_background(dataset)
            bounded = layout.surrounding and backdrop
            evidence["bounded"] = f"{layout.evidence}; {text}"
    if exact_poses:
        variation, evidence["appearance_variation"] = False, "synthetic renders: fixed lighting"
    else:
        measured = appearance_from_points(dataset, obs) if obs is not None else None
        if measured is not None:
            variation, evidence["appearance_variation"] = measured.varies, measured.evidence
        else:
            variation = True
            evidence["appearance_variation"] = ("real capture and no COLMAP points to measure it: exposure and "
                                                "lighting may vary")
    return CaptureFacts(bounded, forward_facing, variation, evidence)
