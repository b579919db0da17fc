"""Physically based renders of textured meshes with Mitsuba 3's CPU path tracer (``scalar_rgb``).

The meshes and textures ship in the pybullet wheel (``pybullet_data``: the COLLADA rubber duck, a soccer ball,
Jenga blocks, a textured torus, a tray, a table, a grass texture); a realistic scene (``realistic.yaml``) places
them, lights them with a procedural sky panorama (an environment emitter, optionally visible from the camera) and
a sun (a directional emitter), and renders each camera with the unidirectional path tracer (indirect light,
soft shadows, a box pixel filter so a pixel is exactly its footprint).

Cameras are given as OpenGL camera-to-world matrices (x right, y up, looking along -z, as Nerfstudio stores
them); Mitsuba's sensor frame is (x left, y up, z forward), hence ``to_world = c2w @ diag(-1, 1, -1, 1)``. The
focal length is ``0.5 * W / tan(camera_angle_x / 2)`` and the principal point the image centre, as Nerfstudio
reads a Blender dataset. ``tests/scenes/test_realistic.py`` projects a marker to check it.

Why ``scalar_rgb``: the ``llvm_ad_rgb`` variant JIT-compiles with the system's LLVM, which aborted the process
on this machine (an LLVM instruction-selection error, 2026-11-24); the scalar variant needs no JIT and renders a
64x64 view of the garden in about a second.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .errors import SceneError

VARIANT = "scalar_rgb"
MITSUBA_TO_OPENGL = np.diag([-1.0, 1.0, -1.0, 1.0])
"""Mitsuba's sensor axes (x left, y up, z forward) from OpenGL's (x right, y up, z backward)."""
PANORAMA_SIZE = (256, 512)
"""Height and width of the procedural sky panorama (equirectangular)."""
GROUND_TEXTURE_SIZE = 1024


class RendererUnavailable(SceneError):
    """Mitsuba 3 or pybullet_data is not installed (``pip install -e .[scenes]``, part of ``setup.sh --dev``)."""


def mitsuba():
    """The ``mitsuba`` module with the scalar RGB variant set."""
    try:
        import mitsuba as mi
    except ImportError:
        raise RendererUnavailable("realistic scenes need Mitsuba 3 (pip install 'nerfify-ns[scenes]', or "
                                  "scripts/setup.sh --dev)") from None
    if mi.variant() != VARIANT:
        mi.set_variant(VARIANT)
    return mi


def pybullet_data_path() -> Path:
    """The folder of meshes and textures in the pybullet wheel."""
    try:
        import pybullet_data
    except ImportError:
        raise RendererUnavailable("realistic scenes need the meshes in pybullet's wheel (pip install "
                                  "'nerfify-ns[scenes]', or scripts/setup.sh --dev)") from None
    return Path(pybullet_data.getDataPath())


def asset(rel: str) -> Path:
    """A file of ``pybullet_data`` (a mesh or a texture) by its path inside it."""
    path = pybullet_data_path() / rel
    if not path.is_file():
        raise SceneError(f"pybullet_data has no {rel} (pybullet's wheel changed?)")
    return path


def mitsuba_version() -> str:
    return mitsuba().__version__


# ------------------------------------------------------------------------------------------ the sky


def value_noise(rng: np.random.Generator, octaves: int, shape, base: int = 4) -> np.ndarray:
    """Smooth multi-octave value noise in [0, 1] of ``shape`` (each octave twice as fine, half as strong)."""
    out = np.zeros(shape)
    for o in range(octaves):
        k = base * 2 ** o
        coarse = rng.random((k // 2 + 1, k + 1))
        ys = np.linspace(0, coarse.shape[0] - 1, shape[0])
        xs = np.linspace(0, coarse.shape[1] - 1, shape[1])
        y0, x0 = np.floor(ys).astype(int), np.floor(xs).astype(int)
        y1, x1 = np.minimum(y0 + 1, coarse.shape[0] - 1), np.minimum(x0 + 1, coarse.shape[1] - 1)
        fy, fx = (ys - y0)[:, None], (xs - x0)[None, :]
        fy, fx = fy * fy * (3 - 2 * fy), fx * fx * (3 - 2 * fx)
        top = coarse[y0][:, x0] * (1 - fx) + coarse[y0][:, x1] * fx
        bottom = coarse[y1][:, x0] * (1 - fx) + coarse[y1][:, x1] * fx
        out += (top * (1 - fy) + bottom * fy) / 2 ** o
    return out / (2 - 2 ** (1 - octaves))


def meadow_texture(seed: int = 3, size: int = GROUND_TEXTURE_SIZE) -> np.ndarray:
    """A linear-RGB ground texture ``(size, size, 3)``: grass whose shade varies at every scale, bare-soil
    patches, and scattered pebbles and flowers, none of it periodic (a tiled photo texture repeats, and
    COLMAP's matcher cannot tell its repeats apart)."""
    rng = np.random.default_rng(seed)
    shade = value_noise(rng, 8, (size, size))
    patches = np.clip((value_noise(rng, 4, (size, size)) - 0.62) * 6.0, 0.0, 1.0)[..., None]
    grass = np.stack([0.05 + 0.10 * shade, 0.16 + 0.22 * shade, 0.03 + 0.05 * shade], -1)
    soil = np.stack([0.28 + 0.12 * shade, 0.20 + 0.09 * shade, 0.12 + 0.05 * shade], -1)
    tex = grass * (1 - patches) + soil * patches
    yy, xx = np.mgrid[0:size, 0:size]
    colours = np.array([[0.8, 0.8, 0.75], [0.85, 0.75, 0.1], [0.7, 0.15, 0.3], [0.35, 0.35, 0.4]])
    for _ in range(size * size // 400):
        cy, cx = rng.integers(0, size, 2)
        r = rng.uniform(1.0, 3.5)
        y0, y1, x0, x1 = max(cy - 4, 0), min(cy + 5, size), max(cx - 4, 0), min(cx + 5, size)
        disk = (yy[y0:y1, x0:x1] - cy) ** 2 + (xx[y0:y1, x0:x1] - cx) ** 2 <= r * r
        tex[y0:y1, x0:x1][disk] = colours[rng.integers(len(colours))] * rng.uniform(0.6, 1.0)
    return tex.astype(np.float32)


def sky_panorama(seed: int = 7, size=PANORAMA_SIZE) -> np.ndarray:
    """A linear-RGB equirectangular panorama ``(H, W, 3)``: a blue sky brightening to the horizon with soft
    clouds, a sun glow, and rolling green-brown hills below a textured far ground, so that distant background
    has structure (a real capture's background is not a flat colour). Deterministic in ``seed``."""
    h, w = size
    rng = np.random.default_rng(seed)
    v = (np.arange(h) + 0.5) / h  # 0 at the zenith, 1 at the nadir
    u = (np.arange(w) + 0.5) / w
    elevation = (0.5 - v)[:, None] * math.pi  # +pi/2 up
    azimuth = u[None, :] * 2.0 * math.pi

    def noise(octaves: int, shape=(h, w)) -> np.ndarray:
        return value_noise(rng, octaves, shape)

    up = np.clip(np.sin(elevation), 0.0, 1.0)
    sky = np.stack([0.25 + 0.55 * (1 - up) ** 3, 0.45 + 0.45 * (1 - up) ** 3, 0.95 + 0.05 * (1 - up)], -1)
    clouds = np.clip(noise(5) * 1.6 - 0.75, 0.0, 1.0)[..., None] * (elevation[..., None] > 0.05)
    sky = sky * (1 - 0.8 * clouds) + 1.1 * clouds
    hills = 0.07 + 0.08 * np.sin(azimuth[0] * 3 + 1.0) + 0.05 * noise(4, (1, w))[0]  # horizon line (rad)
    ground = elevation < hills[None, :]
    soil = noise(6)[..., None]
    far = np.stack([0.18 + 0.2 * soil[..., 0], 0.26 + 0.22 * soil[..., 0], 0.08 + 0.06 * soil[..., 0]], -1)
    pano = np.where(ground[..., None], far * (0.6 + 0.4 * (elevation[..., None] > 0)), sky)
    return (pano * 0.9).astype(np.float32)


# ------------------------------------------------------------------------------------------ the scene


@dataclass(frozen=True)
class View:
    """One rendered camera: a linear RGB image, its coverage (alpha) and the camera."""

    rgb: np.ndarray
    """``(H, W, 3)`` linear radiance (premultiplied by ``alpha`` when the background is hidden)."""
    alpha: np.ndarray
    """``(H, W)`` fraction of the pixel covered by geometry (all ones with a visible background)."""


def _scale_vector(value: Any) -> list[float]:
    if isinstance(value, int | float):
        return [float(value)] * 3
    values = [float(v) for v in value]
    if len(values) != 3:
        raise SceneError(f"scale {value!r}: a number or three numbers are expected")
    return values


def object_to_world(obj: Mapping[str, Any], time: float | None = None) -> np.ndarray:
    """The 4x4 placement of a mesh: scale, rotate about x (y-up meshes to z-up), about z, then translate; with a
    ``motion`` and a ``time`` in [0, 1], an extra turn about z and a lift."""
    sx, sy, sz = _scale_vector(obj.get("scale", 1.0))
    m = np.diag([sx, sy, sz, 1.0])
    ax = math.radians(float(obj.get("rotate_x_deg", 0.0)))
    az = math.radians(float(obj.get("rotate_z_deg", 0.0)))
    translate = np.asarray(obj.get("translate", (0.0, 0.0, 0.0)), dtype=np.float64)
    motion = obj.get("motion")
    if motion and time is not None:
        az += math.radians(float(motion.get("spin_deg", 0.0))) * time
        translate = translate + np.array([0.0, 0.0, float(motion.get("lift", 0.0)) * time])
    rx = np.eye(4)
    rx[1:3, 1:3] = [[math.cos(ax), -math.sin(ax)], [math.sin(ax), math.cos(ax)]]
    rz = np.eye(4)
    rz[0:2, 0:2] = [[math.cos(az), -math.sin(az)], [math.sin(az), math.cos(az)]]
    t = np.eye(4)
    t[:3, 3] = translate
    return t @ rz @ rx @ m


def sensor_dict(c2w: np.ndarray, width: int, height: int, camera_angle_x: float, spp: int, seed: int) -> dict[str, Any]:
    """Mitsuba's perspective sensor of an OpenGL camera-to-world ``c2w`` (box pixel filter, RGBA film)."""
    mi = mitsuba()
    return {
        "type": "perspective", "fov": math.degrees(camera_angle_x), "fov_axis": "x",
        "near_clip": 0.01, "far_clip": 1000.0,
        "to_world": mi.ScalarTransform4f((np.asarray(c2w, dtype=np.float64) @ MITSUBA_TO_OPENGL).tolist()),
        "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
        "film": {"type": "hdrfilm", "width": width, "height": height, "pixel_format": "rgba",
                 "rfilter": {"type": "box"}},
    }


def scene_dict(spec: Mapping[str, Any], time: float | None = None) -> dict[str, Any]:
    """The Mitsuba scene of ``spec`` (a ``load_dict`` dictionary; objects placed at ``time``), without a camera."""
    mi = mitsuba()
    env = spec.get("environment", {})
    visible = bool(env.get("visible", True))
    out: dict[str, Any] = {"type": "scene",
                           "integrator": {"type": "path", "max_depth": 4, "hide_emitters": not visible}}
    out["sky"] = {"type": "envmap", "bitmap": _sky_bitmap(), "scale": float(env.get("strength", 1.0)),
                  "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90)}  # the panorama is z-up, Mitsuba's y-up
    sun = spec.get("sun")
    if sun:
        out["sun"] = {"type": "directional", "direction": [float(v) for v in sun["direction"]],
                      "irradiance": {"type": "rgb", "value": [float(v) for v in sun["irradiance"]]}}
    for i, obj in enumerate(spec.get("objects", [])):
        if obj.get("texture"):
            reflectance = {"type": "bitmap", "filename": str(asset(obj["texture"]))}
        else:
            reflectance = {"type": "rgb", "value": [float(v) for v in obj.get("colour", (0.6, 0.6, 0.6))]}
        shape = {"type": "rectangle"} if obj.get("shape") == "rectangle" else {
            "type": "obj", "filename": str(asset(obj["mesh"])), "face_normals": False}
        out[f"object_{i}"] = {
            **shape,
            "to_world": mi.ScalarTransform4f(object_to_world(obj, time).tolist()),
            "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": reflectance}},
        }
    ground = spec.get("ground")
    if ground:
        size = float(ground["size"])
        tiles = float(ground["tiles"])
        if ground.get("texture") == "meadow":
            texture = {"type": "bitmap", "bitmap": _meadow_bitmap()}
        else:
            texture = {"type": "bitmap", "filename": str(asset(ground["texture"]))}
        out["ground"] = {
            "type": "rectangle", "to_world": mi.ScalarTransform4f().scale([size / 2, size / 2, 1.0]),
            "bsdf": {"type": "diffuse", "reflectance": {**texture,
                                                         "to_uv": mi.ScalarTransform3f().scale([tiles, tiles])}},
        }
    return out


@functools.lru_cache(maxsize=1)
def _meadow_bitmap():
    return mitsuba().Bitmap(meadow_texture())


@functools.lru_cache(maxsize=1)
def _sky_bitmap():
    return mitsuba().Bitmap(sky_panorama())


class Renderer:
    """One scene loaded once (per time, for a moving object), rendered from many cameras."""

    def __init__(self, spec: Mapping[str, Any]) -> None:
        self.spec = spec
        self._scenes: dict[float | None, Any] = {}

    def scene(self, time: float | None):
        if time not in self._scenes:
            if len(self._scenes) > 4:
                self._scenes.clear()
            self._scenes[time] = mitsuba().load_dict(scene_dict(self.spec, time))
        return self._scenes[time]

    def render(self, c2w: np.ndarray, width: int, height: int, camera_angle_x: float, *, spp: int = 32,
               seed: int = 0, time: float | None = None) -> View:
        """Path-trace one camera."""
        mi = mitsuba()
        sensor = mi.load_dict(sensor_dict(c2w, width, height, camera_angle_x, spp, seed))
        image = np.asarray(mi.render(self.scene(time), sensor=sensor, spp=spp, seed=seed), dtype=np.float64)
        rgb = np.nan_to_num(image[..., :3], nan=0.0, posinf=0.0)
        return View(np.clip(rgb, 0.0, None), np.clip(image[..., 3], 0.0, 1.0))


def render_view(spec: Mapping[str, Any], c2w: np.ndarray, width: int, height: int, camera_angle_x: float, *,
                spp: int = 32, seed: int = 0, time: float | None = None) -> View:
    """Path-trace one camera of the scene ``spec``."""
    return Renderer(spec).render(c2w, width, height, camera_angle_x, spp=spp, seed=seed, time=time)


def srgb(linear: np.ndarray) -> np.ndarray:
    """sRGB encoding (IEC 61966-2-1) of linear values clipped to [0, 1]."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def camera_response(view: View, gains: Sequence[float], straight_alpha: bool) -> np.ndarray:
    """The 8-bit image a camera writes: the linear image times per-channel ``gains`` (exposure x white
    balance), sRGB-encoded; with ``straight_alpha`` an RGBA image whose colour is un-premultiplied (the Blender
    convention), else RGB."""
    rgb = view.rgb * np.asarray(gains, dtype=np.float64)[None, None, :]
    if straight_alpha:
        a = view.alpha[..., None]
        rgb = np.where(a > 1e-6, rgb / np.maximum(a, 1e-6), 0.0)
    out = np.round(srgb(rgb) * 255.0).astype(np.uint8)
    if straight_alpha:
        return np.concatenate([out, np.round(view.alpha * 255.0).astype(np.uint8)[..., None]], -1)
    return out
