"""Dataset formats as data: one row per format (what identifies it, how it is read, which Nerfstudio
dataparser reads it), tried in order by :func:`nerfify_ns.dataset.read_dataset`.

=============  ===========================================================  ==================
format         identified by                                                Nerfstudio parser
=============  ===========================================================  ==================
``dnerf``      ``transforms_train.json`` whose frames carry ``time``        ``dnerf-data``
``blender``    ``transforms_train.json`` (+ ``_val``, ``_test``)            ``blender-data``
``nerfstudio`` ``transforms.json`` (``ns-process-data`` output)             ``nerfstudio-data``
``llff``       ``poses_bounds.npy`` + ``images/``                           ``nerfstudio-data``
                                                                            (converted copy)
``colmap``     ``sparse/0`` (or ``colmap/sparse/0``, ``sparse``) with       ``colmap``
               ``cameras``/``images`` ``.bin``/``.txt`` + ``images/``
=============  ===========================================================  ==================

Every reader mirrors what Nerfstudio's dataparser (1.1.5) does with the same files and the arguments
:func:`dataparser_for` passes: which image each frame names, the frame order and the train/eval split, so that
``Dataset.eval_frames`` are exactly the views Nerfstudio renders for its test split.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nerfify_ns import safeio
from nerfify_ns.dataset import colmap as colmap_io
from nerfify_ns.dataset.model import SPLITS, Dataparser, Dataset, DatasetError, Frame, Intrinsics

MAX_JSON_BYTES = 64 << 20
MAX_NPY_BYTES = 64 << 20
MAX_FRAMES = 20000
NERFSTUDIO_TRAIN_FRACTION = 0.9
"""nerfstudio-data's default split (``--eval-mode fraction``): 90% of the frames (sorted by file name) train."""
COLMAP_EVAL_INTERVAL = 8
"""colmap's default split (``--eval-mode interval``): every 8th image (by COLMAP image id) is held out."""
LLFF_HOLDOUT = 8
"""LLFF's convention (``llffhold``): every 8th image (by file name) is held out."""
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
NERFSTUDIO_CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE")
"""Nerfstudio ``camera_model`` values we read (perspective and fisheye; Nerfstudio also knows
equirectangular, omnidirectional-stereo, VR180, orthophoto and FISHEYE624 cameras, which we do not train on)."""
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
COLMAP_MODEL_DIRS = ("sparse/0", "colmap/sparse/0", "sparse")


# ------------------------------------------------------------------------------------------ helpers


def show(path: Path, root: Path) -> str:
    """``path`` relative to ``root`` when inside it (shorter messages)."""
    try:
        return str(Path(path).relative_to(root))
    except ValueError:
        return str(path)


def load_json(path: Path, root: Path) -> dict:
    """A JSON object from ``path``; malformed, huge or non-object files are a :class:`DatasetError`."""
    size = path.stat().st_size
    if size > MAX_JSON_BYTES:
        raise DatasetError(f"{root}: {show(path, root)} is {size} bytes (at most {MAX_JSON_BYTES})")
    try:
        meta = json.loads(path.read_bytes())
    except (ValueError, RecursionError) as exc:
        raise DatasetError(f"{root}: {show(path, root)} is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise DatasetError(f"{root}: {show(path, root)} holds a {type(meta).__name__}, not a JSON object")
    return meta


def frames_of(meta: dict, where: str) -> list:
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        raise DatasetError(f"{where} lists no frames (a non-empty 'frames' list is expected)")
    if len(frames) > MAX_FRAMES:
        raise DatasetError(f"{where} lists {len(frames)} frames (at most {MAX_FRAMES})")
    bad = next((i for i, f in enumerate(frames) if not isinstance(f, dict)), None)
    if bad is not None:
        raise DatasetError(f"{where} frame {bad} is a {type(frames[bad]).__name__}, not an object")
    return frames


def number(value, what: str, where: str, *, positive: bool = False) -> float:
    """A finite (``positive``: > 0) number, else a :class:`DatasetError` naming ``where`` and ``what``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise DatasetError(f"{where}: {what} is {value!r}, not a number")
    value = float(value)
    if not math.isfinite(value) or (positive and value <= 0):
        raise DatasetError(f"{where}: {what} is {value}, a {'positive ' if positive else ''}finite number is expected")
    return value


def integer(value, what: str, where: str) -> int:
    v = number(value, what, where, positive=True)
    if v != int(v):
        raise DatasetError(f"{where}: {what} is {value!r}, a positive integer is expected")
    return int(v)


def pose_matrix(value, where: str, key: str = "transform_matrix") -> np.ndarray:
    """A 4x4 camera-to-world matrix: numbers, finite, bottom row (0, 0, 0, 1), a rotation block."""
    try:
        m = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: {key} is not a 4x4 matrix of numbers") from None
    if m.shape != (4, 4):
        raise DatasetError(f"{where}: {key} has shape {m.shape}, a 4x4 matrix is expected")
    return checked_pose(m, where, key)


def checked_pose(m: np.ndarray, where: str, key: str) -> np.ndarray:
    if not np.isfinite(m).all():
        raise DatasetError(f"{where}: {key} has non-finite entries (NaN or inf)")
    if not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0), atol=1e-4):
        raise DatasetError(f"{where}: {key} has bottom row {m[3].tolist()}, (0, 0, 0, 1) is expected")
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    if err > 1e-2 or np.linalg.det(r) <= 0:
        raise DatasetError(f"{where}: {key} does not hold a rotation (orthonormality error {err:.3g}, "
                           f"determinant {np.linalg.det(r):.3g})")
    return m


def nerfstudio_split(names: Sequence[str], fraction: float = NERFSTUDIO_TRAIN_FRACTION) -> list[str]:
    """Nerfstudio's ``get_train_eval_split_fraction`` over frames sorted by file name: train or test each."""
    n = len(names)
    n_train = math.ceil(n * fraction)
    train = set(np.linspace(0, n - 1, n_train, dtype=int).tolist()) if n_train else set()
    return ["train" if i in train else "test" for i in range(n)]


def interval_split(n: int, interval: int) -> list[str]:
    """Nerfstudio's ``get_train_eval_split_interval``: index ``i % interval == 0`` is held out."""
    return ["test" if i % interval == 0 else "train" for i in range(n)]


# ------------------------------------------------------------------------------------------ Blender, D-NeRF


def _blender_json(root: Path) -> dict | None:
    path = root / "transforms_train.json"
    if not path.is_file() or path.stat().st_size > MAX_JSON_BYTES:
        return None
    try:
        meta = json.loads(path.read_bytes())
    except (ValueError, RecursionError):
        return None
    return meta if isinstance(meta, dict) else None


def detect_dnerf(root: Path) -> str | None:
    meta = _blender_json(root)
    frames = meta.get("frames") if meta else None
    if isinstance(frames, list) and frames and any(isinstance(f, dict) and "time" in f for f in frames):
        return "transforms_train/val/test.json whose frames carry a time (D-NeRF)"
    return None


def detect_blender(root: Path) -> str | None:
    if (root / "transforms_train.json").is_file():
        return "transforms_train/val/test.json with camera_angle_x (Blender synthetic)"
    return None


def read_blender(root: Path, evidence: str, *, timed: bool = False) -> Dataset:
    """Nerfstudio's blender-data (dnerf-data with ``timed``): per split ``transforms_SPLIT.json``, images at
    ``file_path`` + ``.png``, focal from ``camera_angle_x`` and the first image's width, centred principal
    point, one image size."""
    from nerfify_ns.dataset.images import ImageProblem, inspect_image

    missing = [f"transforms_{s}.json" for s in SPLITS if not (root / f"transforms_{s}.json").is_file()]
    if missing:
        raise DatasetError(f"{root}: a {'D-NeRF' if timed else 'Blender'} dataset needs transforms_train.json, "
                           f"transforms_val.json and transforms_test.json; missing {', '.join(missing)}")
    frames: list[Frame] = []
    size: tuple[int, int] | None = None
    angle = None
    for split in SPLITS:
        name = f"transforms_{split}.json"
        meta = load_json(root / name, root)
        where = f"{root}: {name}"
        angle_here = number(meta.get("camera_angle_x"), "camera_angle_x", where, positive=True)
        if angle_here >= math.pi:
            raise DatasetError(f"{where}: camera_angle_x is {angle_here} rad, a field of view below pi is expected")
        angle = angle if angle is not None else angle_here
        for i, frame in enumerate(frames_of(meta, where)):
            fwhere = f"{where} frame {i}"
            file_path = frame.get("file_path")
            if not isinstance(file_path, str) or not file_path:
                raise DatasetError(f"{fwhere}: no file_path")
            fwhere += f" ({file_path})"
            c2w = pose_matrix(frame.get("transform_matrix"), fwhere)
            time = None
            if timed:
                if "time" not in frame:
                    raise DatasetError(f"{fwhere}: no time, but other frames have one (D-NeRF needs a time "
                                       "on every frame)")
                time = number(frame["time"], "time", fwhere)
            image = root / (file_path.replace("./", "") + ".png")  # exactly as blender-data/dnerf-data
            if not image.exists() and (root / file_path).is_file():
                raise DatasetError(f"{fwhere}: Nerfstudio's {'dnerf' if timed else 'blender'}-data reads "
                                   f"{show(image, root)} (file_path + '.png'), which does not exist; write "
                                   "file_path without the extension")
            if size is None:
                try:
                    info = inspect_image(image)
                except ImageProblem as exc:
                    raise DatasetError(f"{fwhere}: image {show(image, root)} {exc}") from None
                size = (info.width, info.height)
            w, h = size
            focal = 0.5 * w / math.tan(0.5 * angle_here)
            intr = Intrinsics(focal, focal, w / 2.0, h / 2.0, w, h)
            frames.append(Frame(file_path, image, c2w, intr, split, time=time))
    scene = root / "scene.json"
    meta_out: dict[str, object] = {"camera_angle_x": angle,
                                   "declares_size": "the first image (a Blender dataset has one image size)"}
    if scene.is_file():
        try:
            meta_out["scene"] = load_json(scene, root)
        except DatasetError:
            pass
    return Dataset("dnerf" if timed else "blender", root, frames, evidence, meta_out)


def read_dnerf(root: Path, evidence: str) -> Dataset:
    return read_blender(root, evidence, timed=True)


# ------------------------------------------------------------------------------------------ Nerfstudio


def detect_nerfstudio(root: Path) -> str | None:
    if (root / "transforms.json").is_file():
        return "transforms.json (Nerfstudio format)"
    return None


def _intrinsic(meta: dict, frame: dict, key: str, where: str):
    if key in frame:
        return frame[key]
    if key in meta:
        return meta[key]
    raise DatasetError(f"{where}: no {key}, and transforms.json sets none for all frames (Nerfstudio needs "
                       f"{', '.join(INTRINSIC_KEYS)} at the top or on every frame)")


def _distortion(meta: dict, frame: dict, where: str) -> tuple[tuple[str, float], ...]:
    source = frame if any(k in frame for k in (*DISTORTION_KEYS, "distortion_params")) else meta
    if "distortion_params" in source:
        values = source["distortion_params"]
        if not isinstance(values, list) or len(values) != 6:
            raise DatasetError(f"{where}: distortion_params is not a list of 6 numbers")
        return tuple((f"d{i}", number(v, "distortion_params", where)) for i, v in enumerate(values))
    return tuple((k, number(source[k], k, where)) for k in DISTORTION_KEYS if k in source)


def read_nerfstudio(root: Path, evidence: str) -> Dataset:
    """Nerfstudio's nerfstudio-data with ``--downscale-factor 1``: frames sorted by image path, intrinsics at
    the top or per frame, masks on every frame or none, the split from ``*_filenames`` lists or 90% train."""
    meta = load_json(root / "transforms.json", root)
    where = f"{root}: transforms.json"
    model = meta.get("camera_model", "OPENCV")
    if model not in NERFSTUDIO_CAMERA_MODELS:
        raise DatasetError(f"{where}: camera_model {model!r} is not one we train on "
                           f"({', '.join(NERFSTUDIO_CAMERA_MODELS)})")
    raw = frames_of(meta, where)
    rows = []
    for i, frame in enumerate(raw):
        fwhere = f"{where} frame {i}"
        file_path = frame.get("file_path")
        if not isinstance(file_path, str) or not file_path:
            raise DatasetError(f"{fwhere}: no file_path")
        fwhere += f" ({file_path})"
        c2w = pose_matrix(frame.get("transform_matrix"), fwhere)
        fx, fy, cx, cy = (number(_intrinsic(meta, frame, k, fwhere), k, fwhere, positive=k.startswith("fl"))
                          for k in ("fl_x", "fl_y", "cx", "cy"))
        w, h = (integer(_intrinsic(meta, frame, k, fwhere), k, fwhere) for k in ("w", "h"))
        intr = Intrinsics(fx, fy, cx, cy, w, h, model, _distortion(meta, frame, fwhere))
        mask = frame.get("mask_path")
        if mask is not None and not isinstance(mask, str):
            raise DatasetError(f"{fwhere}: mask_path is not a path")
        rows.append((root / file_path, file_path, c2w, intr, None if mask is None else root / mask, fwhere))
    with_masks = sum(r[4] is not None for r in rows)
    if 0 < with_masks < len(rows):
        frame_no = next(i for i, r in enumerate(rows) if r[4] is None)
        raise DatasetError(f"{where} frame {frame_no}: no mask_path, but {with_masks} other frames have one "
                           "(Nerfstudio needs a mask on every frame or none)")
    order = sorted(range(len(rows)), key=lambda i: rows[i][0])
    rows = [rows[i] for i in order]
    for a, b in zip(rows, rows[1:], strict=False):
        if a[0] == b[0]:
            raise DatasetError(f"{b[5]}: names the same image as another frame")
    splits = _listed_splits(meta, [r[0] for r in rows], root, where)
    if splits is None:
        splits = nerfstudio_split([str(r[0]) for r in rows])
    frames = [Frame(r[1], r[0], r[2], r[3], s, mask=r[4]) for r, s in zip(rows, splits, strict=False)]
    per_frame = any(k in f for f in raw for k in INTRINSIC_KEYS)
    declares = "its frame (w, h)" if per_frame else "transforms.json (w, h)"
    details = [f"camera_model {model}" if "camera_model" in meta else "no camera_model (perspective)",
               "per-frame intrinsics" if per_frame else "intrinsics at the top"]
    if with_masks:
        details.append("masks")
    model_dir = root / "colmap" / "sparse" / "0"  # ns-process-data keeps the COLMAP model it ran
    return Dataset("nerfstudio", root, frames, f"{evidence}: {', '.join(details)}",
                   {"declares_size": declares, "camera_model": model,
                    "reprojection_error": _reprojection_error(model_dir) if model_dir.is_dir() else None})


def _listed_splits(meta: dict, images: list[Path], root: Path, where: str) -> list[str] | None:
    """Splits from ``train_filenames``/``val_filenames``/``test_filenames`` (None when there are none)."""
    keys = [f"{s}_filenames" for s in SPLITS]
    if not any(k in meta for k in keys):
        return None
    missing = [k for k in keys if k not in meta]
    if missing:
        raise DatasetError(f"{where} lists {', '.join(k for k in keys if k in meta)} but not {', '.join(missing)} "
                           "(Nerfstudio needs every split's list once one is given)")
    members: dict[str, set] = {}
    known = set(images)
    for split, key in zip(SPLITS, keys, strict=False):
        names = meta[key]
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise DatasetError(f"{where}: {key} is not a list of file names")
        paths = {root / n for n in names}
        unknown = sorted(paths - known)
        if unknown:
            raise DatasetError(f"{where}: {key} names {show(unknown[0], root)}, which no frame has")
        members[split] = paths
    return ["test" if p in members["test"] else "train" if p in members["train"] else
            "val" if p in members["val"] else "unused" for p in images]


# ------------------------------------------------------------------------------------------ COLMAP


def _colmap_dir(root: Path) -> Path | None:
    for rel in COLMAP_MODEL_DIRS:
        folder = root / rel
        if any((folder / f"cameras.{ext}").is_file() and (folder / f"images.{ext}").is_file()
               for ext in ("bin", "txt")):
            return folder
    return None


def detect_colmap(root: Path) -> str | None:
    folder = _colmap_dir(root)
    if folder is None or not (root / "images").is_dir():
        return None
    ext = "txt" if (folder / "cameras.txt").is_file() else "bin"
    rel = show(folder, root)
    return f"COLMAP sparse model {rel}/cameras.{ext} + images.{ext} and images/"


def read_colmap(root: Path, evidence: str) -> Dataset:
    """Nerfstudio's colmap dataparser with ``--colmap-path`` the model found, ``--images-path images``,
    ``--downscale-factor 1`` and (when ``masks/`` exists) ``--masks-path masks``: images by COLMAP image id,
    OpenCV cameras turned into OpenGL ones, one camera model, every 8th image held out (or the
    ``*_list.txt`` files)."""
    folder = _colmap_dir(root)
    rel = show(folder, root)
    try:
        cameras, images, ext = colmap_io.read_model(folder)
    except colmap_io.ColmapFormatError as exc:
        raise DatasetError(f"{root}: COLMAP model {rel}/{exc}") from None
    if len(images) > MAX_FRAMES:
        raise DatasetError(f"{root}: {rel}/images.{ext} holds {len(images)} images (at most {MAX_FRAMES})")
    if not images:
        raise DatasetError(f"{root}: {rel}/images.{ext} registers no images")
    masks = root / "masks"
    models = set()
    frames = []
    for image_id in sorted(images):
        im = images[image_id]
        where = f"{root}: {rel}/images.{ext} image {image_id} ({im.name})"
        cam = cameras.get(im.camera_id)
        if cam is None:
            raise DatasetError(f"{where}: camera {im.camera_id} is not in {rel}/cameras.{ext}")
        if cam.model not in colmap_io.SUPPORTED:
            raise DatasetError(f"{where}: camera model {cam.model} is not one we read exactly "
                               f"({', '.join(colmap_io.SUPPORTED)})")
        models.add(cam.model)
        q = np.asarray(im.qvec, dtype=np.float64)
        if not np.isfinite(q).all() or not np.isfinite(im.tvec).all():
            raise DatasetError(f"{where}: the pose has non-finite entries (NaN or inf)")
        if abs(float(np.linalg.norm(q)) - 1.0) > 1e-3:
            raise DatasetError(f"{where}: the quaternion has norm {np.linalg.norm(q):.6g}, a unit quaternion "
                               "is expected")
        c2w = np.linalg.inv(im.w2c())
        c2w[0:3, 1:3] *= -1  # OpenCV camera axes -> OpenGL (as Nerfstudio's colmap dataparser)
        c2w[3] = (0.0, 0.0, 0.0, 1.0)
        checked_pose(c2w, where, "pose")
        fx, fy, cx, cy, dist = cam.intrinsics()
        for value, what in ((fx, "fx"), (fy, "fy")):
            number(value, what, where, positive=True)
        for value, what in ((cx, "cx"), (cy, "cy")):
            number(value, what, where)
        intr = Intrinsics(fx, fy, cx, cy, int(cam.width), int(cam.height), cam.model, dist)
        mask = (masks / im.name).with_suffix(".png") if masks.is_dir() else None
        frames.append(Frame(im.name, root / "images" / im.name, c2w, intr, "", mask=mask))
    if len(models) > 1:
        raise DatasetError(f"{root}: {rel}/cameras.{ext} mixes camera models {', '.join(sorted(models))} "
                           "(Nerfstudio's colmap dataparser needs one)")
    splits = _colmap_lists(root, frames) or interval_split(len(frames), COLMAP_EVAL_INTERVAL)
    for frame, split in zip(frames, splits, strict=False):
        frame.split = split
    details = f"{evidence}{', masks/' if masks.is_dir() else ''}"
    return Dataset("colmap", root, frames, details,
                   {"colmap_path": rel, "declares_size": f"its camera in {rel}/cameras.{ext}",
                    "reprojection_error": _reprojection_error(folder)})


def _reprojection_error(folder: Path) -> tuple[float, int] | None:
    """The COLMAP model's mean reprojection error and point count (pose quality), None when unknown; a model
    whose points cannot be read is not refused for it (runs do not read the points)."""
    try:
        return colmap_io.reprojection_error(folder)
    except (colmap_io.ColmapFormatError, OSError):
        return None


def _colmap_lists(root: Path, frames: list[Frame]) -> list[str] | None:
    names = {"train": "train_list.txt", "val": "val_list.txt", "test": "test_list.txt"}
    present = {s: root / n for s, n in names.items() if (root / n).is_file()}
    if not present and not (root / "validation_list.txt").is_file():
        return None
    missing = [n for s, n in names.items() if s not in present]
    if missing:
        raise DatasetError(f"{root}: has {', '.join(p.name for p in present.values()) or 'validation_list.txt'} "
                           f"but not {', '.join(missing)} (Nerfstudio's colmap dataparser needs every split's "
                           "list once one is given)")
    members = {}
    known = {f.name for f in frames}
    for split, path in present.items():
        listed = [line.strip() for line in path.read_text(errors="replace").splitlines() if line.strip()]
        unknown = [n for n in listed if n not in known]
        if unknown:
            raise DatasetError(f"{root}: {path.name} names {unknown[0]}, which the COLMAP model does not hold")
        members[split] = set(listed)
    return ["test" if f.name in members["test"] else "train" if f.name in members["train"] else
            "val" if f.name in members["val"] else "unused" for f in frames]


# ------------------------------------------------------------------------------------------ LLFF


def detect_llff(root: Path) -> str | None:
    if (root / "poses_bounds.npy").is_file():
        return "poses_bounds.npy + images/ (LLFF forward-facing)"
    return None


def llff_images(root: Path) -> list[Path]:
    folder = root / "images"
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def read_llff(root: Path, evidence: str) -> Dataset:
    """LLFF (Mildenhall et al. 2019): ``poses_bounds.npy`` holds per image a 3x5 matrix (rotation columns
    [down, right, backwards], the camera centre, then height, width, focal) and near/far bounds; the images are
    ``images/`` sorted by name; every 8th is held out. Nerfstudio has no LLFF dataparser: runs read a
    converted Nerfstudio ``transforms.json`` (:func:`dataparser_for`)."""
    path = root / "poses_bounds.npy"
    where = f"{root}: poses_bounds.npy"
    if path.stat().st_size > MAX_NPY_BYTES:
        raise DatasetError(f"{where} is {path.stat().st_size} bytes (at most {MAX_NPY_BYTES})")
    try:  # the header's shape against the bytes the file holds, before any array is allocated
        safeio.npy_header(path, MAX_NPY_BYTES, what=where)
    except safeio.ReadRefused as exc:
        raise DatasetError(str(exc)) from None
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise DatasetError(f"{where} is not a numpy array file ({exc})") from None
    if array.ndim != 2 or array.shape[1] != 17 or not np.issubdtype(array.dtype, np.number):
        raise DatasetError(f"{where} has shape {array.shape} ({array.dtype}); (N, 17) numbers are expected")
    array = array.astype(np.float64)
    images = llff_images(root)
    if len(images) != len(array):
        raise DatasetError(f"{where} holds {len(array)} poses but images/ holds {len(images)} images "
                           f"({', '.join(IMAGE_SUFFIXES)}); one image per pose, sorted by name, is expected")
    frames = []
    splits = interval_split(len(images), LLFF_HOLDOUT)
    for i, (row, image) in enumerate(zip(array, images, strict=False)):
        fwhere = f"{where} pose {i} ({image.name})"
        if not np.isfinite(row).all():
            raise DatasetError(f"{fwhere}: has non-finite entries (NaN or inf)")
        m = row[:15].reshape(3, 5)
        h, w, focal = m[:, 4]
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = m[:, 1], -m[:, 0], m[:, 2], m[:, 3]
        checked_pose(c2w, fwhere, "pose")
        near, far = row[15:17]
        if not 0 < near < far:
            raise DatasetError(f"{fwhere}: bounds near={near:g}, far={far:g}; 0 < near < far is expected")
        focal = number(focal, "focal", fwhere, positive=True)
        w, h = integer(w, "width", fwhere), integer(h, "height", fwhere)
        intr = Intrinsics(focal, focal, w / 2.0, h / 2.0, w, h)
        frames.append(Frame(image.name, image, c2w, intr, splits[i]))
    return Dataset("llff", root, frames, evidence,
                   {"bounds": array[:, 15:17].tolist(), "declares_size": "its pose in poses_bounds.npy"})


# ------------------------------------------------------------------------------------------ the table


@dataclass(frozen=True)
class Format:
    """One dataset format: what identifies it, how it is read, which Nerfstudio dataparser reads it."""

    name: str
    title: str
    looks_for: str
    detect: Callable[[Path], str | None]
    read: Callable[[Path, str], Dataset]
    dataparser: str
    converted: bool = False
    """Nerfstudio cannot read it directly: runs get a Nerfstudio transforms.json written from the dataset."""


FORMATS: tuple[Format, ...] = (
    Format("dnerf", "D-NeRF", "transforms_train.json", detect_dnerf, read_dnerf, "dnerf-data"),
    Format("blender", "Blender synthetic", "transforms_train.json", detect_blender, read_blender, "blender-data"),
    Format("nerfstudio", "Nerfstudio", "transforms.json", detect_nerfstudio, read_nerfstudio, "nerfstudio-data"),
    Format("llff", "LLFF", "poses_bounds.npy", detect_llff, read_llff, "nerfstudio-data", converted=True),
    Format("colmap", "COLMAP", "sparse/0/cameras.bin|txt + images.bin|txt with images/", detect_colmap,
           read_colmap, "colmap"),
)
BY_NAME = {f.name: f for f in FORMATS}
CONVERTED_NAME = "nerfstudio-data"
"""Folder (inside a run's work folder) of the Nerfstudio transforms.json a converted format is read from."""


def looked_for() -> str:
    """What detection looks for, one entry per marker file: ``transforms_train.json (D-NeRF or Blender
    synthetic), ...``."""
    titles: dict[str, list[str]] = {}
    for f in FORMATS:
        titles.setdefault(f.looks_for, []).append(f.title)
    return ", ".join(f"{marker} ({' or '.join(names)})" for marker, names in titles.items())


def dataparser_for(dataset: Dataset, workdir: Path | None = None) -> Dataparser:
    """The Nerfstudio dataparser (subcommand, arguments, ``--data``) reading ``dataset`` the way its reader
    did; formats Nerfstudio cannot read are converted to a Nerfstudio ``transforms.json`` in ``workdir``."""
    fmt = BY_NAME[dataset.format]
    if fmt.converted:
        if workdir is None:
            raise ValueError(f"a {fmt.title} dataset is converted for Nerfstudio: give a work folder")
        from nerfify_ns.dataset.convert import write_nerfstudio_transforms

        folder = write_nerfstudio_transforms(dataset, Path(workdir) / CONVERTED_NAME)
        return Dataparser("nerfstudio-data", ("--downscale-factor", "1"), folder)
    if fmt.name == "nerfstudio":
        args = ("--downscale-factor", "1", "--eval-mode", "fraction", "--train-split-fraction",
                str(NERFSTUDIO_TRAIN_FRACTION))
    elif fmt.name == "colmap":
        args = ("--colmap-path", str(dataset.meta["colmap_path"]), "--images-path", "images",
                "--downscale-factor", "1", "--eval-mode", "interval", "--eval-interval", str(COLMAP_EVAL_INTERVAL),
                "--load-3D-points", "False", *(("--masks-path", "masks") if dataset.has_masks else ()))
    else:
        args = ()
    return Dataparser(fmt.dataparser, args, dataset.root)
