"""Realistic test scenes we did not draw ourselves: textured meshes from pybullet's wheel, path-traced by Mitsuba 3
(:mod:`nerfify_ns.scenes.pbr`), written as the datasets a researcher brings (``realistic.yaml`` is the data):

* ``duck-white``: a bounded object on a transparent (white) background, Blender format, exact poses;
* ``duck-dynamic``: the same object moving over time, D-NeRF format;
* ``garden-360``: an unbounded 360-degree capture with a visible background, a per-image exposure and white
  balance, in Nerfstudio's ``ns-process-data`` layout with poses estimated by COLMAP from the images alone
  (:mod:`nerfify_ns.scenes.sfm`), or the renderer's exact poses with ``poses="exact"``.

Every written scene holds ``ground_truth.json``: the renderer's camera (OpenGL camera-to-world, intrinsics),
exposure, white balance and time of each image, keyed by the image's path in the folder, and the scene's true
facts (bounded, alpha, appearance variation, exact poses, timestamps). The dataset readers never read it.

Scenes are cached: the folder is content-addressed by everything that decides its bytes (the scene's entry,
the settings, the renderer's and COLMAP's versions, the meshes' and textures' SHA-256) under
``$NERFIFY_SCENE_CACHE`` (default ``~/.cache/nerfify/scenes``), built in a temporary folder and renamed into
place; :func:`write_realistic` copies (or exports to another format) from the cache.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import json
import math
import os
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image

from nerfify_ns.atomic import atomic_dir, check_target

from . import pbr
from .cameras import SPLITS, Rig, look_at
from .errors import SceneExistsError, SceneSettingsError, UnknownSceneError
from .writer import view_times

REALISTIC_FILE = "realistic.yaml"
CACHE_VERSION = 1
"""Bumped when the cache layout changes (the renderer's own source files are hashed into every key)."""
GROUND_TRUTH = "ground_truth.json"
ENV_SCENE_CACHE = "NERFIFY_SCENE_CACHE"
POSES = ("exact", "colmap")
EXPORT_FORMATS = ("blender", "dnerf", "nerfstudio", "colmap", "llff")
MAX_RESOLUTION = 512
MAX_VIEWS = 400
MAX_SPP = 1024


@functools.lru_cache(maxsize=1)
def _specs() -> dict[str, Any]:
    return yaml.safe_load(resources.files(__package__).joinpath(REALISTIC_FILE).read_text(encoding="utf-8"))["scenes"]


def list_realistic() -> list[str]:
    """Names of the realistic scenes, in file order."""
    return list(_specs())


def realistic_spec(name: str) -> dict[str, Any]:
    """A copy of the entry of ``name`` in ``realistic.yaml``."""
    specs = _specs()
    if name not in specs:
        raise UnknownSceneError(name, specs)
    return copy.deepcopy(specs[name])


@dataclass(frozen=True)
class RealisticSettings:
    """What decides a realistic scene's bytes (with its entry in ``realistic.yaml``)."""

    name: str
    resolution: int = 64
    """Image height and width (pixels)."""
    n_train: int = 24
    """Training views (Blender/D-NeRF); a Nerfstudio capture renders n_train + n_val + n_test views and
    Nerfstudio's own split holds out 10%."""
    n_val: int = 4
    n_test: int = 8
    seed: int = 0
    """Cameras, per-image exposure and white balance, the path tracer's samples, COLMAP's RANSAC."""
    spp: int = 32
    """Path-traced samples per pixel."""
    poses: str | None = None
    """``exact`` or ``colmap`` (Nerfstudio format only); None: the scene's own choice."""
    sfm_factor: int = 4
    """With COLMAP poses: the images COLMAP sees are rendered this many times larger (a capture's full-size
    photographs) and box-downscaled to ``resolution`` for training, intrinsics scaled to match (as training on
    ns-process-data's ``images_4`` does); SIFT finds too few features in 64 px images."""

    def render_size(self) -> int:
        """The side of the rendered images (the COLMAP input with COLMAP poses)."""
        return self.resolution * (self.sfm_factor if self.resolved_poses() == "colmap" else 1)

    def resolved_poses(self) -> str:
        return self.poses or realistic_spec(self.name).get("poses", "exact")


def check_realistic_settings(settings: RealisticSettings) -> None:
    realistic_spec(settings.name)
    problems = []
    if not 8 <= settings.resolution <= MAX_RESOLUTION:
        problems.append(f"resolution {settings.resolution} (8 to {MAX_RESOLUTION})")
    if settings.n_train < 1:
        problems.append(f"n_train {settings.n_train} (at least 1)")
    if min(settings.n_val, settings.n_test) < 0 or settings.n_train + settings.n_val + settings.n_test > MAX_VIEWS:
        problems.append(f"view counts {settings.n_train}/{settings.n_val}/{settings.n_test} (0 or more each, "
                        f"{MAX_VIEWS} in all)")
    if not 1 <= settings.spp <= MAX_SPP:
        problems.append(f"spp {settings.spp} (1 to {MAX_SPP})")
    if settings.seed < 0:
        problems.append(f"seed {settings.seed} (0 or more)")
    if not 1 <= settings.sfm_factor <= 8 or settings.render_size() > 1024:
        problems.append(f"sfm_factor {settings.sfm_factor} (1 to 8, and resolution x sfm_factor at most 1024)")
    if settings.poses is not None and settings.poses not in POSES:
        problems.append(f"poses {settings.poses!r} ({' or '.join(POSES)})")
    fmt = realistic_spec(settings.name)["format"]
    if settings.resolved_poses() == "colmap" and fmt != "nerfstudio":
        problems.append(f"poses 'colmap' for a {fmt} scene (COLMAP poses are written in Nerfstudio format)")
    if problems:
        raise SceneSettingsError(f"realistic scene {settings.name!r}: bad settings: {'; '.join(problems)}")


# ------------------------------------------------------------------------------------------ the cache


def _file_hash(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def cache_key(settings: RealisticSettings) -> str:
    """SHA-256 of everything that decides the scene's bytes."""
    spec = realistic_spec(settings.name)
    objects = spec.get("objects", [])
    assets = sorted({o["mesh"] for o in objects if "mesh" in o} | {o["texture"] for o in objects if o.get("texture")}
                    | ({spec["ground"]["texture"]} if spec.get("ground", {}).get("texture", "meadow") != "meadow"
                       else set()))
    code = {m: _file_hash(Path(__file__).with_name(m)) for m in ("pbr.py", "realistic.py", "sfm.py", "cameras.py")}
    payload = {"version": CACHE_VERSION, "spec": spec, "settings": asdict(settings),
               "poses": settings.resolved_poses(), "mitsuba": pbr.mitsuba_version(), "variant": pbr.VARIANT,
               "assets": {a: _file_hash(pbr.asset(a)) for a in assets}, "code": code}
    if settings.resolved_poses() == "colmap":
        from .sfm import pycolmap_module

        payload["pycolmap"] = pycolmap_module().__version__
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def scene_cache_dir() -> Path:
    """``$NERFIFY_SCENE_CACHE``, default ``$NERFIFY_CACHE/scenes`` (``~/.cache/nerfify/scenes``)."""
    from nerfify_ns.runtime.paths import nerfify_cache_dir

    return Path(os.environ.get(ENV_SCENE_CACHE) or nerfify_cache_dir() / "scenes")


def cached_realistic(settings: RealisticSettings, progress: Callable[[str], None] | None = None) -> Path:
    """The folder of the scene ``settings`` describe in the cache, rendered (atomically) when not there yet."""
    check_realistic_settings(settings)
    folder = scene_cache_dir() / f"{settings.name}-{cache_key(settings)[:20]}"
    if (folder / GROUND_TRUTH).is_file():
        return folder
    with atomic_dir(folder, overwrite=True) as staging:
        render_realistic(settings, staging, progress)
    return folder


# ------------------------------------------------------------------------------------------ rendering


@dataclass(frozen=True)
class Shot:
    """One image to render: where it goes, its camera, split, time and camera response."""

    file_path: str
    c2w: np.ndarray
    split: str
    time: float | None
    exposure_ev: float
    white_balance: tuple


def _cameras(spec: dict[str, Any], settings: RealisticSettings) -> list[Shot]:
    rig_spec = dict(spec["rig"])
    jitter = float(rig_spec.pop("jitter", 0.0))
    rig = Rig.from_spec(rig_spec)
    fmt = spec["format"]
    appearance = spec.get("appearance", {})
    ev, wb = float(appearance.get("ev", 0.0)), float(appearance.get("wb", 0.0))
    rng = np.random.default_rng([settings.seed, 17])
    if fmt == "nerfstudio":  # one capture; Nerfstudio's dataparser splits it
        n = settings.n_train + settings.n_val + settings.n_test
        groups = [("train", rig.poses(n, "train", settings.seed), [f"images/frame_{i + 1:05d}.png" for i in range(n)])]
    else:
        groups = [(s, rig.poses(k, s, settings.seed), [f"{s}/r_{i}" for i in range(k)])
                  for s, k in zip(SPLITS, (settings.n_train, settings.n_val, settings.n_test), strict=False)]
    times = view_times({"train": settings.n_train, "val": settings.n_val, "test": settings.n_test})
    shots = []
    for split, poses, names in groups:
        for i, (c2w, name) in enumerate(zip(poses, names, strict=False)):
            if jitter:
                position = c2w[:3, 3] + rng.normal(0.0, jitter, 3)
                c2w = look_at(position, rig.target + rng.normal(0.0, jitter / 2, 3))
            e = float(rng.uniform(-ev, ev)) if ev else 0.0
            r, b = (float(np.exp(rng.uniform(-wb, wb))) for _ in range(2)) if wb else (1.0, 1.0)
            time = float(times[split][i]) if fmt == "dnerf" else None
            shots.append(Shot(name, c2w, split, time, e, (r, 1.0, b)))
    return shots


def true_facts(spec: dict[str, Any], settings: RealisticSettings) -> dict[str, Any]:
    """The facts the renderer knows (what the scene probe should find from the images and cameras)."""
    visible = bool(spec.get("environment", {}).get("visible", True))
    appearance = spec.get("appearance", {})
    return {"bounded": not visible and not spec.get("ground"), "alpha": not visible,
            "forward_facing": False, "timestamps": spec["format"] == "dnerf",
            "appearance_variation": bool(appearance.get("ev") or appearance.get("wb")),
            "exact_poses": settings.resolved_poses() == "exact", "format": spec["format"]}


def render_realistic(settings: RealisticSettings, out: Path, progress: Callable[[str], None] | None = None) -> None:
    """Render the scene into the (existing, empty) folder ``out``: images, cameras in the scene's format,
    ``ground_truth.json``; COLMAP poses estimated when asked for."""
    spec = realistic_spec(settings.name)
    fmt = spec["format"]
    size, rendered = settings.resolution, settings.render_size()
    angle = float(spec["rig"]["camera_angle_x"])
    focal = 0.5 * size / math.tan(0.5 * angle)
    straight_alpha = not spec.get("environment", {}).get("visible", True)
    shots = _cameras(spec, settings)
    renderer = pbr.Renderer(spec)
    truth = []
    for k, shot in enumerate(shots):
        if progress:
            progress(f"rendering {settings.name} view {k + 1}/{len(shots)} ({rendered}x{rendered}, {settings.spp} spp)")
        view = renderer.render(shot.c2w, rendered, rendered, angle, spp=settings.spp, seed=settings.seed * 100003 + k,
                               time=shot.time)
        gains = 2.0 ** shot.exposure_ev * np.asarray(shot.white_balance)
        image = pbr.camera_response(view, gains, straight_alpha)
        rel = shot.file_path if fmt == "nerfstudio" else shot.file_path + ".png"
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(image).save(out / rel)
        truth.append({"file_path": rel, "split": shot.split, "c2w": shot.c2w.tolist(), "fl_x": focal, "fl_y": focal,
                      "cx": size / 2.0, "cy": size / 2.0, "w": size, "h": size, "exposure_ev": shot.exposure_ev,
                      "white_balance": list(shot.white_balance), "time": shot.time})
    sfm = None
    if fmt in ("blender", "dnerf"):
        for split in SPLITS:
            rows = [{"file_path": f"./{s.file_path}", "transform_matrix": s.c2w.tolist(),
                     **({"time": s.time} if s.time is not None else {})} for s in shots if s.split == split]
            (out / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": angle, "frames": rows},
                                                                     indent=2) + "\n")
    elif settings.resolved_poses() == "colmap":
        from .sfm import estimate_poses

        if progress:
            progress(f"estimating poses of {len(shots)} images with COLMAP (pycolmap, CPU)")
        sfm = {**asdict(estimate_poses(out, seed=settings.seed)), "image_size": rendered}
        if rendered != size:
            _downscale_capture(out, rendered // size)
    else:  # the renderer's cameras, in ns-process-data's layout
        meta = {"camera_model": "OPENCV", "fl_x": focal, "fl_y": focal, "cx": size / 2.0, "cy": size / 2.0,
                "w": size, "h": size, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
                "frames": [{"file_path": s.file_path, "transform_matrix": s.c2w.tolist()} for s in shots]}
        (out / "transforms.json").write_text(json.dumps(meta, indent=2) + "\n")
    (out / GROUND_TRUTH).write_text(json.dumps({
        "scene": settings.name, "description": " ".join(spec["description"].split()), "format": fmt,
        "settings": asdict(settings), "poses": settings.resolved_poses(),
        "renderer": {"mitsuba": pbr.mitsuba_version(), "variant": pbr.VARIANT, "camera_angle_x": angle,
                     "rendered_size": rendered},
        "facts": true_facts(spec, settings), "sfm": sfm, "frames": truth}, indent=1) + "\n")


def _downscale_capture(folder: Path, factor: int) -> None:
    """Box-downscale every image of ``folder/images`` by ``factor`` and scale ``transforms.json``'s intrinsics
    to match (a pixel centre at ``(u + 0.5)`` maps to ``(u + 0.5) / factor``); the COLMAP model keeps the size it
    was estimated at."""
    for path in sorted((folder / "images").iterdir()):
        with Image.open(path) as im:
            pixels = np.asarray(im, dtype=np.float64)
        h, w = pixels.shape[0] // factor, pixels.shape[1] // factor
        small = pixels[:h * factor, :w * factor].reshape(h, factor, w, factor, -1).mean(axis=(1, 3))
        Image.fromarray(np.round(small).astype(np.uint8).squeeze()).save(path)
    meta = json.loads((folder / "transforms.json").read_text())
    for key in ("fl_x", "fl_y", "cx", "cy"):
        meta[key] = meta[key] / factor
    meta["w"], meta["h"] = meta["w"] // factor, meta["h"] // factor
    (folder / "transforms.json").write_text(json.dumps(meta, indent=4) + "\n")


# ------------------------------------------------------------------------------------------ writing


def load_ground_truth(folder: Path) -> dict[str, Any]:
    """``ground_truth.json`` of a written realistic scene."""
    return json.loads((Path(folder) / GROUND_TRUTH).read_text())


def _retarget_ground_truth(truth: dict[str, Any], source, exported_root: Path) -> dict[str, Any]:
    """Ground truth keyed by the exported dataset's image paths: each exported frame is matched to the source
    frame with the same camera (export copies poses exactly)."""
    from nerfify_ns.dataset import read_dataset

    by_path = {(source.root / f["file_path"]).resolve(): f for f in truth["frames"]}
    src = [(fr.c2w, by_path[fr.image.resolve()]) for fr in source.frames]
    exported = read_dataset(exported_root)
    frames = []
    for fr in exported.frames:
        _, row = min(src, key=lambda s: float(np.abs(s[0] - fr.c2w).sum()))
        frames.append({**row, "file_path": str(fr.image.relative_to(exported_root)), "split": fr.split})
    return {**truth, "format": exported.format, "frames": frames}


def write_realistic(settings: RealisticSettings, out: Path, *, fmt: str | None = None, overwrite: bool = False,
                    progress: Callable[[str], None] | None = None) -> Path:
    """Write the realistic scene ``settings`` to ``out`` (atomically, from the cache): in its own format, or
    exported to ``fmt`` (``blender``, ``dnerf``, ``nerfstudio``, ``colmap``, ``llff``) with
    :func:`nerfify_ns.dataset.convert.export_dataset`, ``ground_truth.json`` following the images."""
    check_realistic_settings(settings)
    native = realistic_spec(settings.name)["format"]
    if fmt is not None and fmt not in EXPORT_FORMATS:
        raise SceneSettingsError(f"format {fmt!r}: one of {', '.join(EXPORT_FORMATS)}")
    out = Path(out).absolute()
    check_target(out, overwrite, SceneExistsError)
    cached = cached_realistic(settings, progress)
    with atomic_dir(out, overwrite=overwrite, exists_error=SceneExistsError) as staging:
        if fmt is None or fmt == native:
            shutil.copytree(cached, staging, dirs_exist_ok=True)
        else:
            from nerfify_ns.dataset import read_dataset
            from nerfify_ns.dataset.convert import export_dataset

            source = read_dataset(cached)
            export_dataset(source, fmt, staging / "export", rgb=fmt not in ("blender", "dnerf"))
            for child in (staging / "export").iterdir():
                child.rename(staging / child.name)
            (staging / "export").rmdir()
            truth = _retarget_ground_truth(load_ground_truth(cached), source, staging)
            (staging / GROUND_TRUTH).write_text(json.dumps(truth, indent=1) + "\n")
    return out


# ------------------------------------------------------------------------------------------ pose accuracy


@dataclass(frozen=True)
class PoseAccuracy:
    """Estimated cameras against the renderer's, after the similarity that best aligns their centres."""

    frames: int
    rotation_deg_median: float
    rotation_deg_max: float
    position_median: float
    """Median centre error as a fraction of the true cameras' mean distance from their centroid."""
    position_max: float


def pose_accuracy(estimated: list[np.ndarray], true: list[np.ndarray]) -> PoseAccuracy:
    """Compare camera-to-world matrices (OpenGL axes, matched by index) up to a similarity transform (Umeyama
    1991: the least-squares rotation, translation and scale between the two sets of camera centres)."""
    est = np.stack([np.asarray(m, dtype=np.float64) for m in estimated])
    ref = np.stack([np.asarray(m, dtype=np.float64) for m in true])
    a, b = est[:, :3, 3], ref[:, :3, 3]
    ma, mb = a.mean(0), b.mean(0)
    cov = (b - mb).T @ (a - ma) / len(a)
    u, d, vt = np.linalg.svd(cov)
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rot = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / ((a - ma) ** 2).sum(1).mean())
    aligned = scale * (a - ma) @ rot.T + mb
    spread = float(np.linalg.norm(b - mb, axis=1).mean())
    pos = np.linalg.norm(aligned - b, axis=1) / spread
    rel = np.einsum("nij,njk->nik", np.transpose(ref[:, :3, :3], (0, 2, 1)), rot @ est[:, :3, :3])
    angles = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))
    return PoseAccuracy(len(est), float(np.median(angles)), float(angles.max()), float(np.median(pos)),
                        float(pos.max()))


def dataset_pose_accuracy(folder: Path) -> PoseAccuracy:
    """The poses the dataset reader reads from a written realistic scene against its ``ground_truth.json``."""
    from nerfify_ns.dataset import read_dataset

    folder = Path(folder)
    dataset = read_dataset(folder)
    truth = {(folder / f["file_path"]).resolve(): np.asarray(f["c2w"]) for f in load_ground_truth(folder)["frames"]}
    pairs = [(f.c2w, truth[f.image.resolve()]) for f in dataset.frames]
    return pose_accuracy([p[0] for p in pairs], [p[1] for p in pairs])
