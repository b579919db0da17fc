"""Render a scene's train/val/test views and write them atomically in Blender format.

Layout of a written scene::

    scene.json                       metadata: spec, flags, bounds, near/far, floaters
    transforms_{train,val,test}.json camera_angle_x + frames (file_path, transform_matrix[, time])
    {split}/r_{i}.png                RGBA uint8, un-premultiplied colour, alpha = coverage
    {split}/r_{i}_depth.npy          float32 distance along the pixel-centre ray, inf on a miss
    test/r_{k}_floaters.png          floater views only: L mask, 255 where a floater is seen
    test/r_{k}_depth_clean.npy       floater views only: depth of the scene without floaters

``scene.json`` also records ``bbox`` (exact box of all content, swept over time for dynamic
scenes), ``foreground_bbox`` (without background objects), ``near``/``far`` (smallest and
largest distance from any camera centre to ``bbox``) and ``depth_range`` (the finite depths
actually rendered, floaters excluded).

Scenes are rendered at unit scale and ``scale`` is applied as an exact similarity transform
(camera centres and depths are multiplied by it; the images are unchanged), which is what
rendering the scaled geometry would give.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from PIL import Image

from nerfify_ns.atomic import atomic_dir, check_target

from .cameras import SPLITS, Rig, focal_length, pixel_rays
from .catalog import resolve_spec, scene_spec
from .errors import SceneExistsError, SceneSettingsError
from .floaters import Blob, FloaterSpec
from .raycast import Layer, build_scene, render_view, trace
from .textures import Light

Array = NDArray[np.float64]

FORMAT_VERSION = 1
DEPTH_SUFFIX = "_depth.npy"
CLEAN_DEPTH_SUFFIX = "_depth_clean.npy"
FLOATER_MASK_SUFFIX = "_floaters.png"

MAX_RESOLUTION = 1024
"""Largest image side rendered (pixels): 512 px takes about 3 s and 400 MB per view on a CPU, memory growing
with the square of the side; procedural test scenes for CPU training need far less."""
MAX_SUPERSAMPLED = 2048
"""Largest ``resolution * supersample`` (the side actually ray-cast)."""
MAX_SUPERSAMPLE = 4
MAX_VIEWS = 1000
"""Most views per split."""


def check_settings(resolution: int, n_train: int, n_val: int, n_test: int, seed: int = 0,
                   supersample: int = 2) -> None:
    """Raise :class:`SceneSettingsError` naming the first setting out of its range: the resolution in
    [1, MAX_RESOLUTION], supersampling in [1, MAX_SUPERSAMPLE] (and their product at most MAX_SUPERSAMPLED),
    at least one training view, validation and test views >= 0, at most MAX_VIEWS per split, a seed in
    [0, 2**32)."""
    def whole(name: str, value: Any, lo: int, hi: int, unit: str = "") -> None:
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise SceneSettingsError(f"{name} must be a whole number, got {value!r}")
        if not lo <= value <= hi:
            raise SceneSettingsError(f"{name} must be between {lo} and {hi}{unit}, got {value}")

    whole("resolution", resolution, 1, MAX_RESOLUTION, " pixels")
    whole("supersample", supersample, 1, MAX_SUPERSAMPLE)
    if resolution * supersample > MAX_SUPERSAMPLED:
        raise SceneSettingsError(f"resolution x supersample must be at most {MAX_SUPERSAMPLED}, got "
                                 f"{resolution} x {supersample}")
    whole("n_train (training views)", n_train, 1, MAX_VIEWS)
    whole("n_val (validation views)", n_val, 0, MAX_VIEWS)
    whole("n_test (test views)", n_test, 0, MAX_VIEWS)
    whole("seed", seed, 0, 2**32 - 1)


def view_times(counts: Mapping[str, int]) -> dict[str, Array]:
    """Timestamps in [0, 1]: train spans the interval, val and test fall between train times."""
    n_train = counts["train"]
    train = np.linspace(0.0, 1.0, n_train) if n_train > 1 else np.zeros(n_train)
    return {
        "train": train,
        "val": (np.arange(counts["val"]) + 1.0 / 3.0) / max(counts["val"], 1),
        "test": (np.arange(counts["test"]) + 2.0 / 3.0) / max(counts["test"], 1),
    }


def load_depth(path: str | Path) -> NDArray[np.float32]:
    """Load a ``*_depth.npy`` map: ``(H, W)`` float32, distance along the ray, ``inf`` on a miss."""
    depth = np.load(Path(path), allow_pickle=False)
    if depth.ndim != 2 or depth.dtype != np.float32:
        raise ValueError(f"{path}: expected a 2-D float32 depth map, got {depth.dtype} {depth.shape}")
    return depth


def load_floater_mask(path: str | Path) -> NDArray[np.bool_]:
    """Load a ``*_floaters.png`` mask as booleans (True where a floater is visible)."""
    with Image.open(Path(path)) as im:
        return np.asarray(im.convert("L")) > 127


def _bounds_json(box: tuple[Array, Array] | None, scale: float) -> list[list[float | None]] | None:
    if box is None:
        return None
    return [[float(v * scale) if np.isfinite(v) else None for v in corner] for corner in box]


def _near_far(box: tuple[Array, Array] | None, centres: Array) -> tuple[float | None, float | None]:
    """Closest and farthest distance from any camera centre to the box (0 when inside)."""
    if box is None or len(centres) == 0 or not np.all(np.isfinite(np.concatenate(box))):
        return None, None
    lo, hi = box
    gap = np.maximum(np.maximum(lo - centres, centres - hi), 0.0)
    far = np.maximum(np.abs(centres - lo), np.abs(centres - hi))
    return float(np.linalg.norm(gap, axis=1).min()), float(np.linalg.norm(far, axis=1).max())


def _save_png(path: Path, array: NDArray[np.uint8]) -> None:
    Image.fromarray(array).save(path, format="PNG")


def _save_depth(path: Path, depth: Array, scale: float) -> None:
    np.save(path, (depth * scale).astype(np.float32), allow_pickle=False)


def _center_depth(layers: list[Layer], light: Light, c2w: Array, resolution: int, angle: float) -> Array:
    origins, dirs = pixel_rays(c2w, resolution, resolution, angle)
    return trace(layers, light, origins.reshape(-1, 3), dirs.reshape(-1, 3)).depth.reshape(
        resolution, resolution
    )


@dataclass
class _Stats:
    depth_min: float = np.inf
    depth_max: float = -np.inf
    centres: list[Array] = field(default_factory=list)

    def add(self, depth: Array) -> None:
        finite = depth[np.isfinite(depth)]
        if finite.size:
            self.depth_min = min(self.depth_min, float(finite.min()))
            self.depth_max = max(self.depth_max, float(finite.max()))


def write_scene(name: str, out: str | Path, **settings: Any) -> Path:
    """Render the catalog scene ``name`` into ``out``; keywords (resolution, view counts, seed,
    supersample, overwrite) as for :func:`write_spec`."""
    return write_spec(scene_spec(name), out, **settings)


def write_spec(
    spec: Mapping[str, Any],
    out: str | Path,
    *,
    resolution: int = 64,
    n_train: int = 24,
    n_val: int = 8,
    n_test: int = 8,
    seed: int = 0,
    supersample: int = 2,
    overwrite: bool = False,
) -> Path:
    """Render a scene spec (catalog entry or hand-written) into ``out`` atomically.

    Everything is rendered into a temporary sibling folder that is renamed to ``out`` at the
    end; on any failure it is removed and ``out`` is left as it was. Raises
    :class:`SceneExistsError` if ``out`` exists and is not empty unless ``overwrite``, and
    :class:`SceneSettingsError` for a setting out of its range (:func:`check_settings`).
    """
    check_settings(resolution, n_train, n_val, n_test, seed, supersample)
    out = Path(out).absolute()
    check_target(out, overwrite, SceneExistsError)
    resolved = resolve_spec(spec, name=spec.get("name"))
    with atomic_dir(out, overwrite, SceneExistsError) as tmp:
        _render_into(
            tmp, resolved, resolution, {"train": n_train, "val": n_val, "test": n_test}, seed, supersample
        )
    return out


def _render_into(
    root: Path, spec: dict[str, Any], resolution: int, counts: dict[str, int], seed: int, supersample: int
) -> None:
    scene = build_scene(spec)
    rig = Rig.from_spec(spec["rig"])
    scale = float(spec["scale"])
    angle = rig.camera_angle_x
    dynamic = bool(spec["flags"]["dynamic"])
    times = view_times(counts) if dynamic else None
    floaters = FloaterSpec.from_spec(spec["floaters"]) if spec.get("floaters") is not None else None
    floater_views = floaters.choose_views(counts["test"], seed) if floaters else []
    floater_blobs: dict[str, list[dict[str, Any]]] = {}
    stats = _Stats()

    for split in SPLITS:
        (root / split).mkdir()
        frames: list[dict[str, Any]] = []
        for i, c2w in enumerate(rig.poses(counts[split], split, seed)):
            time = float(times[split][i]) if times is not None else None
            layers = scene.layers(time)
            blobs: list[Blob] = []
            if floaters and split == "test" and i in floater_views:
                blobs = floaters.blobs(c2w, angle, seed, i)
                floater_blobs[str(i)] = [b.to_json(scale) for b in blobs]
            view = render_view(
                layers + [b.layer() for b in blobs],
                scene.light,
                c2w,
                resolution,
                angle,
                supersample=supersample,
            )
            stem = root / split / f"r_{i}"
            _save_png(stem.with_name(stem.name + ".png"), view.rgba8())
            _save_depth(stem.with_name(stem.name + DEPTH_SUFFIX), view.depth, scale)
            if blobs:
                clean = _center_depth(layers, scene.light, c2w, resolution, angle)
                _save_depth(stem.with_name(stem.name + CLEAN_DEPTH_SUFFIX), clean, scale)
                _save_png(
                    stem.with_name(stem.name + FLOATER_MASK_SUFFIX),
                    np.where(view.flagged, 255, 0).astype(np.uint8),
                )
                stats.add(clean)
            else:
                stats.add(view.depth)
            pose = c2w.copy()
            pose[:3, 3] *= scale
            stats.centres.append(pose[:3, 3])
            frame: dict[str, Any] = {"file_path": f"./{split}/r_{i}", "transform_matrix": pose.tolist()}
            if time is not None:
                frame["time"] = time
            frames.append(frame)
        transforms = {"camera_angle_x": angle, "frames": frames}
        (root / f"transforms_{split}.json").write_text(json.dumps(transforms, indent=2) + "\n")

    box = scene.aabb()
    scaled_box = None if box is None else (box[0] * scale, box[1] * scale)
    near, far = _near_far(scaled_box, np.array(stats.centres).reshape(-1, 3))
    flags = spec["flags"]
    meta = {
        "format_version": FORMAT_VERSION,
        "name": spec["name"],
        "description": spec.get("description", ""),
        "seed": seed,
        "resolution": resolution,
        "supersample": supersample,
        "views": counts,
        "scale": scale,
        "camera_angle_x": angle,
        "focal_length": focal_length(resolution, angle),
        "camera_radius": rig.radius * scale,
        "bounded": flags["bounded"],
        "has_background": flags["background"],
        "transparent_background": not flags["background"],
        "has_timestamps": flags["dynamic"],
        "bbox": _bounds_json(box, scale),
        "foreground_bbox": _bounds_json(scene.aabb(include_background=False), scale),
        "near": near,
        "far": far,
        "depth_range": [stats.depth_min * scale, stats.depth_max * scale]
        if np.isfinite(stats.depth_min)
        else None,
        "depth": {
            "meaning": "distance along the unit pixel-centre ray from the camera centre",
            "suffix": DEPTH_SUFFIX,
            "dtype": "float32",
            "miss": "inf",
        },
        "floaters": None
        if floaters is None
        else {
            "views": floater_views,
            "split": "test",
            "mask_suffix": FLOATER_MASK_SUFFIX,
            "clean_depth_suffix": CLEAN_DEPTH_SUFFIX,
            "blobs": floater_blobs,
        },
        "spec": spec,
    }
    (root / "scene.json").write_text(json.dumps(meta, indent=2, allow_nan=False) + "\n")
