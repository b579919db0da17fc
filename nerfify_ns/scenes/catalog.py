"""The scene catalog: scenes are data in ``catalog.yaml``, resolved and validated here.

A catalog entry may name a ``base`` scene; it is deep-merged over the base (mappings merge
key by key, lists and scalars replace), and everything is merged over the catalog's
``defaults``. Resolution validates the whole spec by building it, so a malformed entry fails
with a :class:`SceneSpecError` naming the scene.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Mapping
from importlib import resources
from typing import Any

import numpy as np
import yaml

from .cameras import Rig
from .errors import SceneSpecError, UnknownSceneError
from .floaters import FloaterSpec
from .raycast import build_scene

CATALOG_FILE = "catalog.yaml"
SCENE_FIELDS = frozenset(
    {"name", "description", "base", "primitives", "rig", "light", "flags", "scale", "floaters"}
)
FLAG_FIELDS = frozenset({"bounded", "background", "dynamic"})


def deep_merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """Recursive merge: mappings merge key by key; any other value in ``override`` replaces."""
    merged = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = deep_merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


@functools.lru_cache(maxsize=1)
def _catalog() -> dict[str, Any]:
    text = resources.files(__package__).joinpath(CATALOG_FILE).read_text(encoding="utf-8")
    data = yaml.safe_load(text)
    if (
        not isinstance(data, dict)
        or not isinstance(data.get("scenes"), dict)
        or not isinstance(data.get("defaults"), dict)
    ):
        raise SceneSpecError(f"{CATALOG_FILE} must map 'defaults' and 'scenes'")
    return data


def list_scenes() -> list[str]:
    """Names of the catalog's scenes, in catalog order."""
    return list(_catalog()["scenes"])


def _chain(name: str, scenes: Mapping[str, Any], seen: tuple[str, ...] = ()) -> dict[str, Any]:
    if name not in scenes:
        raise UnknownSceneError(name, scenes)
    if name in seen:
        raise SceneSpecError(f"scene {name!r}: cyclic base chain {' -> '.join((*seen, name))}")
    entry = scenes[name]
    if not isinstance(entry, Mapping):
        raise SceneSpecError(f"scene {name!r} must be a mapping")
    own = {k: v for k, v in entry.items() if k != "base"}
    if "base" in entry:
        return deep_merge(_chain(str(entry["base"]), scenes, (*seen, name)), own)
    return dict(own)


def resolve_spec(spec: Mapping[str, Any], name: str | None = None) -> dict[str, Any]:
    """Merge a (possibly hand-written) spec over the catalog defaults and its base, then validate."""
    catalog = _catalog()
    own = dict(spec)
    if "base" in own:
        base = _chain(str(own.pop("base")), catalog["scenes"])
        own = deep_merge(base, own)
    resolved = deep_merge(catalog["defaults"], own)
    resolved["name"] = str(name if name is not None else resolved.get("name", "custom"))
    validate_spec(resolved)
    return resolved


def scene_spec(name: str) -> dict[str, Any]:
    """The fully resolved spec of a catalog scene (a fresh copy the caller may modify)."""
    scenes = _catalog()["scenes"]
    if name not in scenes:
        raise UnknownSceneError(name, scenes)
    return resolve_spec(_chain(name, scenes), name=name)


def validate_spec(spec: Mapping[str, Any]) -> None:
    """Raise :class:`SceneSpecError` unless the resolved spec builds and its flags are truthful."""
    label = spec.get("name", "custom")
    try:
        unknown = set(spec) - SCENE_FIELDS
        if unknown:
            raise SceneSpecError(f"unknown fields {sorted(unknown)}; valid: {sorted(SCENE_FIELDS)}")
        scene = build_scene(spec)
        Rig.from_spec(spec.get("rig") or {})
        if spec.get("floaters") is not None:
            FloaterSpec.from_spec(spec["floaters"])
        scale = spec.get("scale", 1.0)
        if (
            isinstance(scale, bool)
            or not isinstance(scale, int | float)
            or not np.isfinite(scale)
            or scale <= 0
        ):
            raise SceneSpecError(f"scale must be a positive number, got {scale!r}")
        flags = spec.get("flags") or {}
        if set(flags) != FLAG_FIELDS or not all(isinstance(v, bool) for v in flags.values()):
            raise SceneSpecError(f"flags must set each of {sorted(FLAG_FIELDS)} to a boolean, got {flags!r}")
        if flags["dynamic"] != scene.dynamic:
            raise SceneSpecError(f"flag dynamic={flags['dynamic']} but an object moves: {scene.dynamic}")
        has_background = any(o.background for o in scene.objects)
        if flags["background"] != has_background:
            raise SceneSpecError(
                f"flag background={flags['background']} but background objects: {has_background}"
            )
        box = scene.aabb(include_background=False)
        if flags["bounded"] and (box is None or not np.all(np.isfinite(np.concatenate(box)))):
            raise SceneSpecError("flag bounded=true but the foreground is unbounded")
    except SceneSpecError as exc:
        raise SceneSpecError(f"scene {label!r}: {exc}") from exc
