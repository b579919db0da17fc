"""Scene objects and the analytic ray caster: per-pixel alpha compositing of primitive hits.

Each primitive contributes one layer at its nearest surface along a ray, with its material's
opacity (a translucent object is a single semi-transparent layer). Layers are composited
front to back, so ``alpha = 1 - prod(1 - opacity_i)`` over the surfaces the ray hits and
the colour is the usual over-operator result. Colour and alpha are averaged over an S x S
grid of sub-pixel rays (antialiasing); depth is the exact distance to the first surface
along the pixel-centre ray, ``inf`` where that ray hits nothing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .cameras import PIXEL_CENTER, pixel_rays, subpixel_offsets
from .errors import SceneSpecError
from .geometry import SHAPES, Primitive, shape_from_spec, spec_vector, union_aabb
from .textures import Light, Material, light_from_spec, material_from_spec

Array = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

OBJECT_FIELDS = frozenset({"type", "name", "material", "motion", "background"})
MOTION_FIELDS = frozenset({"translate"})


@dataclass(frozen=True)
class Layer:
    """One primitive with its material, as the ray caster sees it at one instant."""

    shape: Primitive
    material: Material
    flagged: bool = False  # its visible pixels are reported in ViewRender.flagged (floaters)


@dataclass(frozen=True)
class SceneObject:
    """A catalog primitive: shape, material, linear motion over time t in [0, 1], role."""

    name: str
    shape: Primitive
    material: Material
    translate: Array  # displacement from t = 0 to t = 1
    background: bool = False

    @property
    def moves(self) -> bool:
        return bool(np.any(self.translate != 0.0))

    def at_time(self, time: float) -> Primitive:
        return self.shape.translated(time * self.translate) if self.moves else self.shape

    def swept_aabb(self) -> tuple[Array, Array]:
        """Exact box of everything the object covers for t in [0, 1] (motion is linear)."""
        return union_aabb([self.at_time(0.0).aabb(), self.at_time(1.0).aabb()])


@dataclass(frozen=True)
class Scene:
    """The renderable form of a resolved scene spec (at unit scale)."""

    objects: tuple[SceneObject, ...]
    light: Light

    @property
    def dynamic(self) -> bool:
        return any(o.moves for o in self.objects)

    def layers(self, time: float | None = None) -> list[Layer]:
        t = 0.0 if time is None else float(time)
        return [Layer(o.at_time(t), o.material) for o in self.objects]

    def aabb(self, *, include_background: bool = True) -> tuple[Array, Array] | None:
        boxes = [o.swept_aabb() for o in self.objects if include_background or not o.background]
        return union_aabb(boxes) if boxes else None


def _object_from_spec(index: int, spec: Mapping[str, Any]) -> SceneObject:
    if not isinstance(spec, Mapping):
        raise SceneSpecError(f"primitive #{index} must be a mapping, got {spec!r}")
    kind = spec.get("type")
    allowed = OBJECT_FIELDS | (SHAPES[kind][1] if kind in SHAPES else frozenset())
    unknown = set(spec) - allowed
    if unknown:
        raise SceneSpecError(
            f"primitive #{index} ({kind}): unknown fields {sorted(unknown)}; valid: {sorted(allowed)}"
        )
    motion = spec.get("motion") or {}
    if set(motion) - MOTION_FIELDS:
        raise SceneSpecError(
            f"primitive #{index}: unknown motion fields {sorted(set(motion) - MOTION_FIELDS)}"
        )
    translate = spec_vector(motion, "translate", 3) if "translate" in motion else np.zeros(3)
    background = spec.get("background", False)
    if not isinstance(background, bool):
        raise SceneSpecError(f"primitive #{index}: background must be a boolean")
    return SceneObject(
        name=str(spec.get("name", f"{kind}_{index}")),
        shape=shape_from_spec(spec),
        material=material_from_spec(spec.get("material") or {}),
        translate=translate,
        background=background,
    )


def build_scene(spec: Mapping[str, Any]) -> Scene:
    """Build the renderable scene from a resolved spec (``primitives`` and ``light``)."""
    primitives = spec.get("primitives")
    if not isinstance(primitives, Sequence) or not primitives:
        raise SceneSpecError("a scene needs a non-empty list of primitives")
    objects = tuple(_object_from_spec(i, p) for i, p in enumerate(primitives))
    return Scene(objects, light_from_spec(spec.get("light") or {}))


@dataclass(frozen=True)
class TraceResult:
    premultiplied: Array  # (R, 3)
    alpha: Array  # (R,)
    depth: Array  # (R,) first surface, inf on a miss
    flagged: BoolArray  # (R,) a flagged layer contributes to the ray's colour


def trace(layers: Sequence[Layer], light: Light, origins: Array, dirs: Array) -> TraceResult:
    """Composite all layers along a batch of rays, front to back."""
    n, k = len(origins), len(layers)
    t_all = np.full((k, n), np.inf)
    a_all = np.zeros((k, n))
    c_all = np.zeros((k, n, 3))
    for i, layer in enumerate(layers):
        hit = layer.shape.intersect(origins, dirs)
        t_all[i] = hit.t
        a_all[i, hit.index] = layer.material.opacity
        albedo = layer.material.albedo(hit.local)
        c_all[i, hit.index] = light.shade(albedo, hit.normal, dirs[hit.index], layer.material.unlit)
    flags = np.array([layer.flagged for layer in layers], dtype=bool)
    order = np.argsort(t_all, axis=0, kind="stable")
    t_sorted = np.take_along_axis(t_all, order, axis=0)
    transmittance = np.ones(n)
    premultiplied = np.zeros((n, 3))
    flagged = np.zeros(n, dtype=bool)
    for rank in range(k):  # the rank-th surface along each ray that still has one
        rays = np.flatnonzero(np.isfinite(t_sorted[rank]))
        if rays.size == 0:
            break
        layer_of = order[rank, rays]
        a = a_all[layer_of, rays]
        w = transmittance[rays] * a
        premultiplied[rays] += w[:, None] * c_all[layer_of, rays]
        flagged[rays] |= flags[layer_of] & (w > 0.0)
        transmittance[rays] *= 1.0 - a
    depth = t_sorted[0] if k else np.full(n, np.inf)
    return TraceResult(premultiplied, 1.0 - transmittance, depth, flagged)


@dataclass(frozen=True)
class ViewRender:
    """One rendered view: un-premultiplied colour, coverage, exact depth, flagged-layer mask."""

    rgb: Array  # (H, W, 3) in [0, 1]; 0 where alpha == 0
    alpha: Array  # (H, W) in [0, 1]
    depth: Array  # (H, W) distance along the pixel-centre ray, inf on a miss
    flagged: BoolArray  # (H, W) any sub-pixel or centre ray sees a flagged layer

    def rgba8(self) -> NDArray[np.uint8]:
        rgba = np.concatenate([self.rgb, self.alpha[..., None]], axis=-1)
        return np.round(np.clip(rgba, 0.0, 1.0) * 255.0).astype(np.uint8)


def render_view(
    layers: Sequence[Layer],
    light: Light,
    c2w: Array,
    resolution: int,
    camera_angle_x: float,
    *,
    supersample: int = 2,
) -> ViewRender:
    """Render one square view of ``resolution`` pixels per side."""
    offsets = np.concatenate([PIXEL_CENTER, subpixel_offsets(supersample)])
    origins, dirs = pixel_rays(c2w, resolution, resolution, camera_angle_x, offsets)
    shape = origins.shape[:3]
    r = trace(layers, light, origins.reshape(-1, 3), dirs.reshape(-1, 3))
    premultiplied = r.premultiplied.reshape(*shape, 3)[:, :, 1:].mean(axis=2)
    alpha = r.alpha.reshape(shape)[:, :, 1:].mean(axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        rgb = np.where(alpha[..., None] > 0.0, premultiplied / alpha[..., None], 0.0)
    return ViewRender(
        rgb=np.clip(rgb, 0.0, 1.0),
        alpha=alpha,
        depth=r.depth.reshape(shape)[:, :, 0],
        flagged=r.flagged.reshape(shape).any(axis=2),
    )
