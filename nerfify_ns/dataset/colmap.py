"""A COLMAP sparse model (``cameras`` and ``images``, ``.bin`` or ``.txt``) read with numpy and ``struct``,
following COLMAP's documented formats (https://colmap.github.io/format.html); bounded against hostile files
(every count is checked against the bytes left before anything is allocated).

Binary ``cameras.bin``: ``uint64`` count, then per camera ``int32 id, int32 model, uint64 width,
uint64 height, float64 params[n(model)]``. Binary ``images.bin``: ``uint64`` count, then per image
``int32 id, float64 qw qx qy qz, float64 tx ty tz, int32 camera_id, name (NUL-terminated), uint64 n,
n x (float64 x, float64 y, int64 point3D_id)``. Text files hold the same fields, one camera per line and two
lines per image (the second lists its 2D points). Poses are world-to-camera with OpenCV camera axes
(x right, y down, z forward); the quaternion is scalar first.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MODELS: dict[int, tuple[str, int]] = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5), 4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5), 8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
}
MODEL_IDS = {name: (model_id, n) for model_id, (name, n) in MODELS.items()}
SUPPORTED = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE")
"""The camera models we map to Nerfstudio's cameras exactly (its colmap dataparser's perspective and fisheye
models without the coefficients it rejects)."""
MAX_FILE = 1 << 30
MAX_NAME = 4096


class ColmapFormatError(Exception):
    """The model files do not follow COLMAP's format (the reader names the file)."""


@dataclass(frozen=True)
class ColmapCamera:
    id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]

    def intrinsics(self) -> tuple[float, float, float, float, tuple[tuple[str, float], ...]]:
        """fx, fy, cx, cy and the named distortion coefficients of a supported model."""
        p = self.params
        if self.model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
            fx = fy = p[0]
            cx, cy = p[1], p[2]
            dist = {"SIMPLE_PINHOLE": (), "SIMPLE_RADIAL": (("k1", p[3]),),
                    "RADIAL": (("k1", p[3]), ("k2", p[4]))}[self.model]
        else:
            fx, fy, cx, cy = p[:4]
            names = {"PINHOLE": (), "OPENCV": ("k1", "k2", "p1", "p2"),
                     "OPENCV_FISHEYE": ("k1", "k2", "k3", "k4")}[self.model]
            dist = tuple(zip(names, p[4:], strict=False))
        return fx, fy, cx, cy, tuple((k, float(v)) for k, v in dist)


@dataclass(frozen=True)
class ColmapImage:
    id: int
    qvec: tuple[float, float, float, float]
    tvec: tuple[float, float, float]
    camera_id: int
    name: str

    def w2c(self) -> np.ndarray:
        """World-to-camera 4x4 (OpenCV camera axes)."""
        m = np.eye(4)
        m[:3, :3] = qvec_to_rotation(np.asarray(self.qvec, dtype=np.float64))
        m[:3, 3] = self.tvec
        return m


def qvec_to_rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * z * x + 2 * w * y],
        [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
        [2 * z * x - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y],
    ])


def rotation_to_qvec(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)``, ``w >= 0``, of a rotation matrix."""
    r = np.asarray(r, dtype=np.float64)
    k = np.array([
        [r[0, 0] - r[1, 1] - r[2, 2], 0, 0, 0],
        [r[0, 1] + r[1, 0], r[1, 1] - r[0, 0] - r[2, 2], 0, 0],
        [r[0, 2] + r[2, 0], r[1, 2] + r[2, 1], r[2, 2] - r[0, 0] - r[1, 1], 0],
        [r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1], r[0, 0] + r[1, 1] + r[2, 2]],
    ]) / 3.0
    values, vectors = np.linalg.eigh(k)
    q = vectors[[3, 0, 1, 2], np.argmax(values)]
    return -q if q[0] < 0 else q


class _Reader:
    """Little-endian reads with every length checked against what is left."""

    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 0

    def left(self) -> int:
        return len(self.data) - self.pos

    def take(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.left() < size:
            raise ColmapFormatError(f"ends early (byte {self.pos}, {size} more needed)")
        values = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return values

    def count(self, each: int, what: str) -> int:
        (n,) = self.take("<Q")
        if n * each > self.left():
            raise ColmapFormatError(f"declares {n} {what} but holds {self.left()} bytes")
        return n

    def name(self) -> str:
        end = self.data.find(b"\x00", self.pos, self.pos + MAX_NAME)
        if end < 0:
            raise ColmapFormatError(f"has an image name without its NUL terminator (byte {self.pos})")
        raw = self.data[self.pos:end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise ColmapFormatError(f"has an image name that is not UTF-8 (byte {self.pos})") from None


def _read_bytes(path: Path) -> bytes:
    size = path.stat().st_size
    if size > MAX_FILE:
        raise ColmapFormatError(f"is {size} bytes (at most {MAX_FILE})")
    return path.read_bytes()


def _model(model_id: int) -> tuple[str, int]:
    if model_id not in MODELS:
        raise ColmapFormatError(f"has unknown camera model id {model_id}")
    return MODELS[model_id]


def read_cameras_binary(path: Path) -> dict[int, ColmapCamera]:
    r = _Reader(_read_bytes(path))
    cameras = {}
    for _ in range(r.count(24, "cameras")):
        cam_id, model_id, width, height = r.take("<iiQQ")
        name, n = _model(model_id)
        cameras[cam_id] = ColmapCamera(cam_id, name, int(width), int(height), r.take(f"<{n}d"))
    return cameras


def read_images_binary(path: Path) -> dict[int, ColmapImage]:
    r = _Reader(_read_bytes(path))
    images = {}
    for _ in range(r.count(64 + 1 + 8, "images")):
        image_id, qw, qx, qy, qz, tx, ty, tz, cam_id = r.take("<i7di")
        name = r.name()
        n_points = r.count(24, "2D points")
        r.pos += 24 * n_points
        images[image_id] = ColmapImage(image_id, (qw, qx, qy, qz), (tx, ty, tz), cam_id, name)
    return images


def _text_lines(path: Path) -> list[str]:
    return _read_bytes(path).decode("utf-8", errors="replace").splitlines()


def _parse(values: list[str], kinds: str, line_no: int) -> list:
    if len(values) < len(kinds):
        raise ColmapFormatError(f"line {line_no} has {len(values)} fields, {len(kinds)} expected")
    try:
        return [int(v) if k == "i" else float(v) for k, v in zip(kinds, values, strict=False)]
    except ValueError:
        raise ColmapFormatError(f"line {line_no} has a field that is not a number") from None


def read_cameras_text(path: Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for no, line in enumerate(_text_lines(path), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) < 4 or parts[1] not in MODEL_IDS:
            raise ColmapFormatError(f"line {no} is not 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...' with a COLMAP model")
        n = MODEL_IDS[parts[1]][1]
        cam_id, width, height = _parse([parts[0], parts[2], parts[3]], "iii", no)
        params = _parse(parts[4:], "f" * n, no)
        if len(parts) != 4 + n:
            raise ColmapFormatError(f"line {no}: {parts[1]} has {n} parameters, {len(parts) - 4} given")
        cameras[cam_id] = ColmapCamera(cam_id, parts[1], width, height, tuple(params))
    return cameras


def read_images_text(path: Path) -> dict[int, ColmapImage]:
    """Two lines per image (the header, then its 2D points, possibly empty), comments skipped, as COLMAP's
    own reader (and Nerfstudio's copy of it) does."""
    lines = _text_lines(path)
    images, i = {}, 0
    while i < len(lines):
        line = lines[i].strip()
        i += 1
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) < 10:
            raise ColmapFormatError(f"line {i} is not 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")
        values = _parse(parts[:9], "ifffffffi", i)
        name = " ".join(parts[9:])
        images[values[0]] = ColmapImage(values[0], tuple(values[1:5]), tuple(values[5:8]), values[8], name)
        i += 1  # the points line
    return images


def read_model(folder: Path) -> tuple[dict[int, ColmapCamera], dict[int, ColmapImage], str]:
    """Cameras and images of the model in ``folder`` (text files first, as Nerfstudio reads them)."""
    for ext in ("txt", "bin"):
        cameras, images = folder / f"cameras.{ext}", folder / f"images.{ext}"
        if cameras.is_file() and images.is_file():
            readers = (read_cameras_text, read_images_text) if ext == "txt" else (read_cameras_binary,
                                                                                   read_images_binary)
            return _wrap(readers[0], cameras), _wrap(readers[1], images), ext
    raise ColmapFormatError(f"{folder} holds no cameras.bin + images.bin or cameras.txt + images.txt")


def _wrap(reader, path: Path):
    try:
        return reader(path)
    except ColmapFormatError as exc:
        raise ColmapFormatError(f"{path.name} {exc}") from None


def reprojection_error(folder: Path) -> tuple[float, int] | None:
    """Mean reprojection error (pixels) over the model's 3D points and their count, from ``points3D.bin`` or
    ``points3D.txt`` (each point stores its mean error); None when there are no points or no such file.
    Binary record: ``uint64 id, float64 xyz[3], uint8 rgb[3], float64 error, uint64 n, n x (int32, int32)``."""
    errors: list[float] = []
    if (folder / "points3D.txt").is_file():
        for no, line in enumerate(_text_lines(folder / "points3D.txt"), 1):
            parts = line.split()
            if parts and not parts[0].startswith("#"):
                errors.append(_parse(parts[:8], "ifffffff", no)[7])
    elif (folder / "points3D.bin").is_file():
        r = _Reader(_read_bytes(folder / "points3D.bin"))
        for _ in range(r.count(51, "3D points")):
            errors.append(r.take("<Q3d3Bd")[-1])
            track = r.count(8, "track entries")
            r.pos += 8 * track
    else:
        return None
    good = [e for e in errors if np.isfinite(e)]
    return (float(np.mean(good)), len(good)) if good else None


@dataclass(frozen=True)
class Observations:
    """Where the model's 3D points are seen: one row per observation (a 2D point with a 3D point)."""

    image_names: tuple[str, ...]
    """Image name by image index."""
    camera_sizes: tuple[tuple[int, int], ...]
    """(width, height) of each image's camera (the size the 2D points are measured in)."""
    image: np.ndarray
    """Image index of each observation."""
    xy: np.ndarray
    """``(N, 2)`` pixel coordinates (COLMAP's: the top-left corner of the image at 0, pixel centres at +0.5)."""
    point: np.ndarray
    """3D point id of each observation."""
    points: dict[int, np.ndarray]
    """3D point positions by id (world coordinates of the model)."""
    centres: np.ndarray
    """``(M, 3)`` camera centres of the images (world coordinates of the model)."""


MAX_OBSERVATIONS = 5_000_000


def read_observations(folder: Path) -> Observations | None:
    """The observations of a binary model's triangulated points (``images.bin`` 2D points with a 3D point id,
    ``points3D.bin`` positions); None when the model is text, has no points, or does not read."""
    try:
        cameras = read_cameras_binary(folder / "cameras.bin")
        r = _Reader(_read_bytes(folder / "images.bin"))
        names, sizes, image_rows, xy_rows, point_rows, centres = [], [], [], [], [], []
        for _ in range(r.count(64 + 1 + 8, "images")):
            image_id, qw, qx, qy, qz, tx, ty, tz, cam_id = r.take("<i7di")
            rot = qvec_to_rotation(np.array([qw, qx, qy, qz]) / max(np.linalg.norm([qw, qx, qy, qz]), 1e-12))
            centres.append(-rot.T @ np.array([tx, ty, tz]))
            name = r.name()
            n = r.count(24, "2D points")
            block = np.frombuffer(r.data, dtype=np.dtype([("x", "<f8"), ("y", "<f8"), ("p", "<i8")]), count=n,
                                  offset=r.pos)
            r.pos += 24 * n
            keep = block["p"] >= 0
            cam = cameras.get(cam_id)
            names.append(name)
            sizes.append((cam.width, cam.height) if cam else (0, 0))
            image_rows.append(np.full(int(keep.sum()), len(names) - 1))
            xy_rows.append(np.stack([block["x"][keep], block["y"][keep]], 1))
            point_rows.append(block["p"][keep])
            if sum(len(p) for p in point_rows) > MAX_OBSERVATIONS:
                break
        r = _Reader(_read_bytes(folder / "points3D.bin"))
        points = {}
        for _ in range(r.count(51, "3D points")):
            pid, x, y, z, _r, _g, _b, _err = r.take("<Q3d3Bd")
            points[pid] = np.array([x, y, z])
            track = r.count(8, "track entries")
            r.pos += 8 * track
    except (ColmapFormatError, OSError):
        return None
    if not points or not image_rows:
        return None
    return Observations(tuple(names), tuple(sizes), np.concatenate(image_rows), np.concatenate(xy_rows),
                        np.concatenate(point_rows), points, np.array(centres))


def write_model_text(folder: Path, cameras: list[ColmapCamera], images: list[ColmapImage]) -> None:
    """Write ``cameras.txt``, ``images.txt`` and an empty ``points3D.txt`` (tests and conversions)."""
    folder.mkdir(parents=True, exist_ok=True)
    cam_lines = ["# Camera list with one line of data per camera:",
                 "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    cam_lines += [" ".join([str(c.id), c.model, str(c.width), str(c.height), *(repr(float(p)) for p in c.params)])
                  for c in cameras]
    (folder / "cameras.txt").write_text("\n".join(cam_lines) + "\n")
    img_lines = ["# Image list with two lines of data per image:",
                 "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    for im in images:
        img_lines += [" ".join([str(im.id), *(repr(float(v)) for v in (*im.qvec, *im.tvec)), str(im.camera_id),
                                im.name]), ""]
    (folder / "images.txt").write_text("\n".join(img_lines) + "\n")
    (folder / "points3D.txt").write_text("# 3D point list (empty)\n")


def write_model_binary(folder: Path, cameras: list[ColmapCamera], images: list[ColmapImage]) -> None:
    """Write ``cameras.bin``, ``images.bin`` and an empty ``points3D.bin``."""
    folder.mkdir(parents=True, exist_ok=True)
    out = [struct.pack("<Q", len(cameras))]
    for c in cameras:
        model_id, n = MODEL_IDS[c.model]
        out.append(struct.pack(f"<iiQQ{n}d", c.id, model_id, c.width, c.height, *c.params))
    (folder / "cameras.bin").write_bytes(b"".join(out))
    out = [struct.pack("<Q", len(images))]
    for im in images:
        out.append(struct.pack("<i7di", im.id, *im.qvec, *im.tvec, im.camera_id))
        out.append(im.name.encode("utf-8") + b"\x00" + struct.pack("<Q", 0))
    (folder / "images.bin").write_bytes(b"".join(out))
    (folder / "points3D.bin").write_bytes(struct.pack("<Q", 0))
