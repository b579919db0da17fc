"""View-inconsistent "floaters": small semi-opaque blobs placed in front of one camera only.

A floater is rendered into a single test view and exists in no other view, so it breaks
cross-view consistency by construction. The chosen views, the blobs and a per-view mask of
the pixels they touch are written next to the scene, to validate consistency checks.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import SceneSpecError
from .geometry import Frame, Sphere, spec_float, spec_vector
from .raycast import Layer
from .textures import Material

Array = NDArray[np.float64]

FLOATER_FIELDS = frozenset({"fraction", "per_view", "radius", "opacity", "distance", "color", "spread"})
_VIEW_STREAM = 7001
_BLOB_STREAM = 7002


@dataclass(frozen=True)
class Blob:
    """One floater: a semi-opaque sphere."""

    center: Array
    radius: float
    opacity: float
    color: Array

    def layer(self) -> Layer:
        material = Material(self.color, self.color, opacity=self.opacity)
        return Layer(Sphere(Frame(self.center, np.eye(3)), self.radius), material, flagged=True)

    def to_json(self, scale: float) -> dict[str, Any]:
        return {
            "center": (self.center * scale).tolist(),
            "radius": self.radius * scale,
            "opacity": self.opacity,
            "color": self.color.tolist(),
        }


def _range(spec: Mapping[str, Any], key: str, default: tuple[float, float]) -> tuple[float, float]:
    lo, hi = spec_vector(spec, key, 2) if key in spec else default
    if not 0.0 < lo <= hi:
        raise SceneSpecError(f"floaters.{key} must satisfy 0 < lo <= hi, got {[lo, hi]}")
    return float(lo), float(hi)


@dataclass(frozen=True)
class FloaterSpec:
    """How many test views get floaters, and how the blobs are drawn."""

    fraction: float
    per_view: int
    radius: tuple[float, float]
    opacity: tuple[float, float]
    distance: tuple[float, float]  # from the camera centre
    color: Array
    spread: float  # blobs lie on rays through the central ``spread`` fraction of the image

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any]) -> FloaterSpec:
        unknown = set(spec) - FLOATER_FIELDS
        if unknown:
            raise SceneSpecError(f"unknown floater fields {sorted(unknown)}; valid: {sorted(FLOATER_FIELDS)}")
        fraction = spec_float(spec, "fraction", default=0.5)
        per_view = spec.get("per_view", 3)
        spread = spec_float(spec, "spread", default=0.6)
        if not 0.0 < fraction <= 1.0 or not 0.0 < spread <= 1.0:
            raise SceneSpecError("floaters.fraction and floaters.spread must lie in (0, 1]")
        if isinstance(per_view, bool) or not isinstance(per_view, int) or per_view < 1:
            raise SceneSpecError(f"floaters.per_view must be a positive integer, got {per_view!r}")
        opacity = _range(spec, "opacity", (0.5, 0.8))
        if opacity[1] > 1.0:
            raise SceneSpecError("floaters.opacity must not exceed 1")
        color = spec_vector(spec, "color", 3) if "color" in spec else np.full(3, 0.9)
        return cls(
            fraction=fraction,
            per_view=per_view,
            radius=_range(spec, "radius", (0.05, 0.1)),
            opacity=opacity,
            distance=_range(spec, "distance", (1.2, 2.2)),
            color=np.clip(color, 0.0, 1.0),
            spread=spread,
        )

    def choose_views(self, n_test: int, seed: int) -> list[int]:
        """Indices of the test views that get floaters (at least one when there are test views)."""
        if n_test == 0:
            return []
        k = min(n_test, max(1, round(self.fraction * n_test)))
        rng = np.random.default_rng([seed, _VIEW_STREAM])
        return sorted(int(i) for i in rng.choice(n_test, size=k, replace=False))

    def blobs(self, c2w: Array, camera_angle_x: float, seed: int, view: int) -> list[Blob]:
        """Blobs for one view, on rays through the central part of its image."""
        rng = np.random.default_rng([seed, _BLOB_STREAM, view])
        half_width = np.tan(0.5 * camera_angle_x)
        out = []
        for _ in range(self.per_view):
            x, y = rng.uniform(-self.spread, self.spread, size=2) * half_width
            d = c2w[:3, :3] @ np.array([x, y, -1.0])
            d /= np.linalg.norm(d)
            center = c2w[:3, 3] + rng.uniform(*self.distance) * d
            out.append(
                Blob(center, float(rng.uniform(*self.radius)), float(rng.uniform(*self.opacity)), self.color)
            )
        return out
