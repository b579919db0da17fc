"""Procedural solid textures, materials and view-independent Lambertian shading.

Textures are evaluated on the hit point in the primitive's local frame, so they move with
the object and are identical from every view. A pattern returns a weight in [0, 1] that
mixes the material's two colours. Patterns are a registry (name -> function and
parameters), so a catalog entry selects one by name.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import SceneSpecError
from .geometry import spec_float, spec_vector

Array = NDArray[np.float64]
PatternFn = Callable[[Array, Mapping[str, Any]], Array]


def _unit(v: Array) -> Array:
    n = float(np.linalg.norm(v))
    if n == 0.0:
        raise SceneSpecError("direction must be non-zero")
    return v / n


def _solid(p: Array, params: Mapping[str, Any]) -> Array:
    return np.zeros(len(p))


def _checker(p: Array, params: Mapping[str, Any]) -> Array:
    # Cells are centred on the local origin so that faces through it never sit on a cell edge.
    cells = np.floor(p / params["period"] + 0.5).astype(np.int64)
    return (cells.sum(axis=1) % 2).astype(np.float64)


def _stripes(p: Array, params: Mapping[str, Any]) -> Array:
    s = p @ params["direction"]
    return (np.floor(s / params["period"] + 0.5).astype(np.int64) % 2).astype(np.float64)


def _sinusoid(p: Array, params: Mapping[str, Any]) -> Array:
    s = p @ params["direction"]
    return 0.5 + 0.5 * np.sin(2.0 * np.pi * params["frequency"] * s)


def _gradient(p: Array, params: Mapping[str, Any]) -> Array:
    lo, hi = params["range"]
    return np.clip((p @ params["direction"] - lo) / (hi - lo), 0.0, 1.0)


def _parse_period(spec: Mapping[str, Any]) -> dict[str, Any]:
    return {"period": spec_float(spec, "period", positive=True)}


def _parse_directional(spec: Mapping[str, Any], key: str) -> dict[str, Any]:
    direction = _unit(spec_vector(spec, "direction", 3)) if "direction" in spec else np.array([1.0, 0.0, 0.0])
    return {key: spec_float(spec, key, positive=True), "direction": direction}


def _parse_gradient(spec: Mapping[str, Any]) -> dict[str, Any]:
    direction = _unit(spec_vector(spec, "direction", 3)) if "direction" in spec else np.array([0.0, 0.0, 1.0])
    lo, hi = spec_vector(spec, "range", 2)
    if hi <= lo:
        raise SceneSpecError(f"gradient range must increase, got {[lo, hi]}")
    return {"direction": direction, "range": (lo, hi)}


#: pattern name -> (evaluator, parameter parser, accepted fields besides ``kind``/``color``)
PATTERNS: dict[str, tuple[PatternFn, Callable[[Mapping[str, Any]], dict[str, Any]], frozenset[str]]] = {
    "solid": (_solid, lambda spec: {}, frozenset()),
    "checker": (_checker, _parse_period, frozenset({"period"})),
    "stripes": (
        _stripes,
        lambda spec: _parse_directional(spec, "period"),
        frozenset({"period", "direction"}),
    ),
    "sinusoid": (
        _sinusoid,
        lambda spec: _parse_directional(spec, "frequency"),
        frozenset({"frequency", "direction"}),
    ),
    "gradient": (_gradient, _parse_gradient, frozenset({"direction", "range"})),
}


def _colour(spec: Mapping[str, Any], key: str) -> Array:
    c = spec_vector(spec, key, 3)
    if np.any(c < 0.0) or np.any(c > 1.0):
        raise SceneSpecError(f"colour {key!r} must lie in [0, 1], got {spec[key]!r}")
    return c


@dataclass(frozen=True)
class Material:
    """Surface appearance: two colours mixed by a pattern, an opacity and a lighting switch."""

    color: Array
    color2: Array
    pattern: str = "solid"
    params: Mapping[str, Any] = field(default_factory=dict)
    opacity: float = 1.0
    unlit: bool = False

    def albedo(self, local: Array) -> Array:
        w = PATTERNS[self.pattern][0](local, self.params)[:, None]
        return (1.0 - w) * self.color + w * self.color2


MATERIAL_FIELDS = frozenset({"color", "pattern", "opacity", "unlit"})


def material_from_spec(spec: Mapping[str, Any]) -> Material:
    """Build a material from ``{color, pattern: {kind, color, ...}, opacity, unlit}``."""
    unknown = set(spec) - MATERIAL_FIELDS
    if unknown:
        raise SceneSpecError(f"unknown material fields {sorted(unknown)}; valid: {sorted(MATERIAL_FIELDS)}")
    color = _colour(spec, "color") if "color" in spec else np.full(3, 0.8)
    pattern_spec: Mapping[str, Any] = spec.get("pattern") or {"kind": "solid"}
    kind = pattern_spec.get("kind")
    if kind not in PATTERNS:
        raise SceneSpecError(f"unknown pattern {kind!r}; valid: {', '.join(sorted(PATTERNS))}")
    _, parse, fields = PATTERNS[kind]
    unknown = set(pattern_spec) - fields - {"kind", "color"}
    if unknown:
        raise SceneSpecError(f"unknown fields {sorted(unknown)} for pattern {kind!r}")
    color2 = _colour(pattern_spec, "color") if "color" in pattern_spec else color
    opacity = spec_float(spec, "opacity", default=1.0)
    if not 0.0 < opacity <= 1.0:
        raise SceneSpecError(f"opacity must lie in (0, 1], got {opacity}")
    unlit = spec.get("unlit", False)
    if not isinstance(unlit, bool):
        raise SceneSpecError(f"unlit must be a boolean, got {unlit!r}")
    return Material(color, color2, kind, parse(pattern_spec), opacity, unlit)


@dataclass(frozen=True)
class Light:
    """A fixed directional light plus ambient term (view-independent Lambertian shading)."""

    direction: Array  # unit vector pointing *towards* the light
    ambient: float
    diffuse: float

    def shade(self, albedo: Array, normal: Array, ray_dirs: Array, unlit: bool) -> Array:
        if unlit:
            return albedo
        facing = np.where(np.einsum("ij,ij->i", normal, ray_dirs)[:, None] > 0.0, -normal, normal)
        lambert = np.clip(facing @ self.direction, 0.0, None)[:, None]
        return np.clip(albedo * (self.ambient + self.diffuse * lambert), 0.0, 1.0)


LIGHT_FIELDS = frozenset({"direction", "ambient", "diffuse"})


def light_from_spec(spec: Mapping[str, Any]) -> Light:
    unknown = set(spec) - LIGHT_FIELDS
    if unknown:
        raise SceneSpecError(f"unknown light fields {sorted(unknown)}; valid: {sorted(LIGHT_FIELDS)}")
    ambient = spec_float(spec, "ambient")
    diffuse = spec_float(spec, "diffuse")
    if ambient < 0.0 or diffuse < 0.0:
        raise SceneSpecError("light ambient and diffuse must be non-negative")
    return Light(_unit(spec_vector(spec, "direction", 3)), ambient, diffuse)
