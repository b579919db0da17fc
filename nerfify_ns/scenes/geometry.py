"""Analytic ray-primitive intersection, exact surface distances and bounding boxes.

Every primitive lives in a rigid local frame (origin + rotation). Rays are batches of
float64 origins and *unit* directions of shape ``(R, 3)``; because the frame is rigid, the
ray parameter ``t`` is the same in local and world space, so ``t`` is the exact distance
along the ray. A miss is ``t = +inf``.

``distance(points)`` is the exact unsigned distance to the primitive's surface, written
independently of the intersection code, so tests can check one against the other.
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import SceneSpecError

Array = NDArray[np.float64]

#: Hits closer than this (in scene units, scenes are built at unit scale) are ignored.
T_EPSILON = 1e-9


@dataclass(frozen=True)
class Hit:
    """Nearest positive intersection of a ray batch with one primitive.

    ``t`` covers every ray; ``index``, ``normal`` and ``local`` cover only the rays that hit.
    """

    t: Array  # (R,) distance along the unit ray, +inf where missed
    index: NDArray[np.intp]  # (M,) indices of the rays that hit
    normal: Array  # (M, 3) unit world-space normal (orientation arbitrary)
    local: Array  # (M, 3) hit point in the primitive's local frame (texture space)

    @property
    def mask(self) -> NDArray[np.bool_]:
        return np.isfinite(self.t)


def rotation_from_euler_deg(angles: Any) -> Array:
    """World-from-local rotation ``Rz @ Ry @ Rx`` for XYZ Euler angles in degrees."""
    rx, ry, rz = np.deg2rad(np.asarray(angles, dtype=np.float64))
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    mx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    my = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    mz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return mz @ my @ mx


def basis_from_axis(axis: Array) -> Array:
    """A rotation whose third column is the unit vector ``axis`` (deterministic choice)."""
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


@dataclass(frozen=True)
class Frame:
    """Rigid frame: ``world = origin + rotation @ local``."""

    origin: Array
    rotation: Array

    def points_to_local(self, p: Array) -> Array:
        return (p - self.origin) @ self.rotation

    def dirs_to_local(self, d: Array) -> Array:
        return d @ self.rotation

    def dirs_to_world(self, v: Array) -> Array:
        return v @ self.rotation.T

    def translated(self, offset: Array) -> Frame:
        return Frame(self.origin + offset, self.rotation)


def _nearest_positive(candidates: Array) -> tuple[Array, NDArray[np.intp]]:
    """Smallest candidate ``t > T_EPSILON`` per ray; candidates is (C, R) with inf/nan = invalid."""
    c = np.where(np.isfinite(candidates) & (candidates > T_EPSILON), candidates, np.inf)
    index = np.argmin(c, axis=0)
    return np.take_along_axis(c, index[None], axis=0)[0], index


def _stable_roots(a: Array, b: Array, c: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Roots of ``a t^2 + 2 b t + c = 0`` without cancellation; returns (r0, r1, real)."""
    disc = b * b - a * c
    real = (disc >= 0.0) & (a > 0.0)
    q = np.sqrt(np.where(real, disc, 0.0))
    h = -(b + np.copysign(q, b))
    with np.errstate(divide="ignore", invalid="ignore"):
        r0 = np.where(real, h / a, np.nan)
        r1 = np.where(real & (h != 0.0), c / h, np.nan)
    return r0, r1, real


class Primitive(ABC):
    """A shape in a rigid frame; subclasses implement the local-frame maths."""

    frame: Frame

    def intersect(self, origins: Array, dirs: Array) -> Hit:
        """Nearest hit ``t > T_EPSILON`` of each ray (origins and unit directions, ``(R, 3)``)."""
        t = np.full(len(origins), np.inf)
        candidates = self._candidates(origins, dirs)
        o = self.frame.points_to_local(origins[candidates])
        d = self.frame.dirs_to_local(dirs[candidates])
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            t_sub, n_local = self._intersect_local(o, d)
        hit = np.isfinite(t_sub)
        index = candidates[hit]
        t[index] = t_sub[hit]
        local = o[hit] + t_sub[hit, None] * d[hit]
        return Hit(t=t, index=index, normal=self.frame.dirs_to_world(n_local[hit]), local=local)

    @functools.cached_property
    def bounding_sphere(self) -> tuple[Array, float] | None:
        """A sphere holding the primitive (None when unbounded), used to cull rays."""
        lo, hi = self.aabb()
        if not np.all(np.isfinite(lo) & np.isfinite(hi)):
            return None
        return (lo + hi) / 2.0, float(np.linalg.norm(hi - lo)) / 2.0

    def _candidates(self, origins: Array, dirs: Array) -> NDArray[np.intp]:
        """Indices of rays that reach the bounding sphere ahead of their origin (conservative)."""
        if self.bounding_sphere is None:
            return np.arange(len(origins))
        centre, radius = self.bounding_sphere
        oc = origins - centre
        b = np.einsum("ij,ij->i", oc, dirs)
        c = np.einsum("ij,ij->i", oc, oc)
        r = radius * (1.0 + 1e-6) + 1e-12
        keep = (b * b - (c - r * r) >= 0.0) & ((b <= 0.0) | (c <= r * r))
        return np.flatnonzero(keep)

    def distance(self, points: Array) -> Array:
        """Exact unsigned distance from world points ``(N, 3)`` to the surface."""
        return self._distance_local(self.frame.points_to_local(np.asarray(points, dtype=np.float64)))

    def translated(self, offset: Array) -> Primitive:
        moved = self.frame.translated(np.asarray(offset, dtype=np.float64))
        return replace(self, frame=moved)  # type: ignore[type-var]  # subclasses are dataclasses

    @abstractmethod
    def _intersect_local(self, o: Array, d: Array) -> tuple[Array, Array]: ...

    @abstractmethod
    def _distance_local(self, p: Array) -> Array: ...

    @abstractmethod
    def aabb(self) -> tuple[Array, Array]:
        """Exact axis-aligned bounding box ``(lo, hi)`` in world space."""


@dataclass(frozen=True)
class Sphere(Primitive):
    frame: Frame
    radius: float

    def _intersect_local(self, o: Array, d: Array) -> tuple[Array, Array]:
        b = np.einsum("ij,ij->i", o, d)
        c = np.einsum("ij,ij->i", o, o) - self.radius**2
        r0, r1, _ = _stable_roots(np.ones_like(b), b, c)
        t, _ = _nearest_positive(np.stack([r0, r1]))
        p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
        return t, p / self.radius

    def _distance_local(self, p: Array) -> Array:
        return np.abs(np.linalg.norm(p, axis=-1) - self.radius)

    def aabb(self) -> tuple[Array, Array]:
        return self.frame.origin - self.radius, self.frame.origin + self.radius


@dataclass(frozen=True)
class Box(Primitive):
    frame: Frame
    half: Array  # (3,) half extents

    def _intersect_local(self, o: Array, d: Array) -> tuple[Array, Array]:
        t1 = (-self.half - o) / d
        t2 = (self.half - o) / d
        lo, hi = np.minimum(t1, t2), np.maximum(t1, t2)
        parallel = d == 0.0
        inside = np.abs(o) <= self.half
        lo = np.where(parallel, np.where(inside, -np.inf, np.inf), lo)
        hi = np.where(parallel, np.where(inside, np.inf, -np.inf), hi)
        t_near, t_far = lo.max(axis=1), hi.min(axis=1)
        valid = t_near <= t_far
        t, _ = _nearest_positive(np.stack([np.where(valid, t_near, np.nan), np.where(valid, t_far, np.nan)]))
        p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
        axis = np.argmax(np.abs(p) / self.half, axis=1)
        normal = np.zeros_like(p)
        rows = np.arange(len(p))
        normal[rows, axis] = np.sign(p[rows, axis])
        return t, normal

    def _distance_local(self, p: Array) -> Array:
        q = np.abs(p) - self.half
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        inside = np.minimum(q.max(axis=-1), 0.0)
        return np.abs(outside + inside)

    def aabb(self) -> tuple[Array, Array]:
        extent = np.abs(self.frame.rotation) @ self.half
        return self.frame.origin - extent, self.frame.origin + extent


@dataclass(frozen=True)
class Cylinder(Primitive):
    """Capped cylinder from the frame origin along local +z for ``length``."""

    frame: Frame
    radius: float
    length: float

    def _intersect_local(self, o: Array, d: Array) -> tuple[Array, Array]:
        a = np.einsum("ij,ij->i", d[:, :2], d[:, :2])
        b = np.einsum("ij,ij->i", o[:, :2], d[:, :2])
        c = np.einsum("ij,ij->i", o[:, :2], o[:, :2]) - self.radius**2
        r0, r1, _ = _stable_roots(a, b, c)
        candidates = []
        for r in (r0, r1):
            z = o[:, 2] + r * d[:, 2]
            candidates.append(np.where((z >= 0.0) & (z <= self.length), r, np.nan))
        for z_cap in (0.0, self.length):
            r = (z_cap - o[:, 2]) / d[:, 2]
            x, y = o[:, 0] + r * d[:, 0], o[:, 1] + r * d[:, 1]
            candidates.append(np.where(x * x + y * y <= self.radius**2, r, np.nan))
        t, which = _nearest_positive(np.stack(candidates))
        p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
        side = np.stack([p[:, 0] / self.radius, p[:, 1] / self.radius, np.zeros(len(p))], axis=1)
        cap = np.zeros_like(p)
        cap[:, 2] = np.where(which == 2, -1.0, 1.0)
        return t, np.where((which < 2)[:, None], side, cap)

    def _distance_local(self, p: Array) -> Array:
        dr = np.hypot(p[..., 0], p[..., 1]) - self.radius
        dz = np.maximum(-p[..., 2], p[..., 2] - self.length)
        outside = np.hypot(np.maximum(dr, 0.0), np.maximum(dz, 0.0))
        inside = np.minimum(np.maximum(dr, dz), 0.0)
        return np.abs(outside + inside)

    def aabb(self) -> tuple[Array, Array]:
        start = self.frame.origin
        axis = self.frame.rotation[:, 2]
        end = start + self.length * axis
        extent = self.radius * np.sqrt(np.clip(1.0 - axis**2, 0.0, None))
        return np.minimum(start, end) - extent, np.maximum(start, end) + extent


@dataclass(frozen=True)
class Plane(Primitive):
    """The local z = 0 plane; a rectangle of ``half`` = (hx, hy) or infinite if ``half`` is None."""

    frame: Frame
    half: Array | None

    def _intersect_local(self, o: Array, d: Array) -> tuple[Array, Array]:
        r = -o[:, 2] / d[:, 2]
        if self.half is not None:
            x, y = o[:, 0] + r * d[:, 0], o[:, 1] + r * d[:, 1]
            r = np.where((np.abs(x) <= self.half[0]) & (np.abs(y) <= self.half[1]), r, np.nan)
        t, _ = _nearest_positive(r[None])
        normal = np.zeros_like(o)
        normal[:, 2] = 1.0
        return t, normal

    def _distance_local(self, p: Array) -> Array:
        if self.half is None:
            return np.abs(p[..., 2])
        dx = np.maximum(np.abs(p[..., 0]) - self.half[0], 0.0)
        dy = np.maximum(np.abs(p[..., 1]) - self.half[1], 0.0)
        return np.sqrt(dx * dx + dy * dy + p[..., 2] ** 2)

    def aabb(self) -> tuple[Array, Array]:
        u, v = self.frame.rotation[:, 0], self.frame.rotation[:, 1]
        if self.half is None:
            extent = np.where((u != 0.0) | (v != 0.0), np.inf, 0.0)
        else:
            extent = np.abs(u) * self.half[0] + np.abs(v) * self.half[1]
        return self.frame.origin - extent, self.frame.origin + extent


# --------------------------------------------------------------------------- spec parsing


def spec_vector(spec: Mapping[str, Any], key: str, size: int, *, positive: bool = False) -> Array:
    """Read a finite float vector of ``size`` entries from a spec mapping."""
    try:
        value = np.asarray(spec[key], dtype=np.float64)
    except KeyError as exc:
        raise SceneSpecError(f"missing field {key!r} in {dict(spec)!r}") from exc
    except (TypeError, ValueError) as exc:
        raise SceneSpecError(f"field {key!r} must be numeric, got {spec[key]!r}") from exc
    if value.shape != (size,) or not np.all(np.isfinite(value)):
        raise SceneSpecError(f"field {key!r} must be {size} finite numbers, got {spec[key]!r}")
    if positive and np.any(value <= 0.0):
        raise SceneSpecError(f"field {key!r} must be positive, got {spec[key]!r}")
    return value


def spec_float(
    spec: Mapping[str, Any], key: str, *, positive: bool = False, default: float | None = None
) -> float:
    """Read one finite float from a spec mapping (``default`` when absent, if given)."""
    if key not in spec:
        if default is None:
            raise SceneSpecError(f"missing field {key!r} in {dict(spec)!r}")
        return float(default)
    if isinstance(spec[key], bool):
        raise SceneSpecError(f"field {key!r} must be a number, got {spec[key]!r}")
    return float(spec_vector({key: [spec[key]]}, key, 1, positive=positive)[0])


def _rotation(spec: Mapping[str, Any]) -> Array:
    return (
        rotation_from_euler_deg(spec_vector(spec, "rotation_deg", 3)) if "rotation_deg" in spec else np.eye(3)
    )


def _sphere(spec: Mapping[str, Any]) -> Primitive:
    return Sphere(
        Frame(spec_vector(spec, "center", 3), _rotation(spec)), spec_float(spec, "radius", positive=True)
    )


def _box(spec: Mapping[str, Any]) -> Primitive:
    half = spec_vector(spec, "size", 3, positive=True) / 2.0
    return Box(Frame(spec_vector(spec, "center", 3), _rotation(spec)), half)


def _cylinder(spec: Mapping[str, Any]) -> Primitive:
    start, end = spec_vector(spec, "start", 3), spec_vector(spec, "end", 3)
    length = float(np.linalg.norm(end - start))
    if length <= 0.0:
        raise SceneSpecError(f"cylinder start and end coincide: {dict(spec)!r}")
    return Cylinder(
        Frame(start, basis_from_axis(end - start)), spec_float(spec, "radius", positive=True), length
    )


def _plane(spec: Mapping[str, Any]) -> Primitive:
    half = spec_vector(spec, "size", 2, positive=True) / 2.0 if "size" in spec else None
    return Plane(Frame(spec_vector(spec, "center", 3), _rotation(spec)), half)


#: shape name -> (builder, fields the shape accepts)
SHAPES: dict[str, tuple[Callable[[Mapping[str, Any]], Primitive], frozenset[str]]] = {
    "sphere": (_sphere, frozenset({"center", "radius", "rotation_deg"})),
    "box": (_box, frozenset({"center", "size", "rotation_deg"})),
    "cylinder": (_cylinder, frozenset({"start", "end", "radius"})),
    "plane": (_plane, frozenset({"center", "size", "rotation_deg"})),
}


def shape_from_spec(spec: Mapping[str, Any]) -> Primitive:
    """Build a primitive from its spec mapping (``type`` plus the shape's fields)."""
    kind = spec.get("type")
    if kind not in SHAPES:
        raise SceneSpecError(f"unknown primitive type {kind!r}; valid: {', '.join(sorted(SHAPES))}")
    builder, _ = SHAPES[kind]
    return builder(spec)


def union_aabb(boxes: list[tuple[Array, Array]]) -> tuple[Array, Array]:
    """Smallest box holding all the given boxes."""
    lo = np.min(np.stack([b[0] for b in boxes]), axis=0)
    hi = np.max(np.stack([b[1] for b in boxes]), axis=0)
    return lo, hi
