"""Procedural test scenes with exact ground truth, written in Nerfstudio's Blender format.

Scenes are data (``catalog.yaml``); this package ray-casts them analytically in numpy and
writes ``transforms_{train,val,test}.json``, RGBA PNGs, exact per-pixel depth and a
``scene.json`` of metadata, readable by Nerfstudio's ``blender`` (and, for the dynamic
scene, ``dnerf``) dataparsers.

    from nerfify_ns.scenes import write_scene, camera_rays, load_depth
    root = write_scene("default", Path("data/default"))
    rays = camera_rays(root / "transforms_test.json")
    points = rays.points(load_depth(root / "test/r_0_depth.npy"), frame=0)
"""

from __future__ import annotations

from .cameras import CameraRays, camera_rays, focal_length, look_at, pixel_rays
from .catalog import list_scenes, resolve_spec, scene_spec
from .errors import SceneError, SceneExistsError, SceneSettingsError, SceneSpecError, UnknownSceneError
from .raycast import Scene, ViewRender, build_scene, render_view
from .writer import check_settings, load_depth, load_floater_mask, view_times, write_scene, write_spec

__all__ = [
    "CameraRays",
    "Scene",
    "SceneError",
    "SceneExistsError",
    "SceneSettingsError",
    "SceneSpecError",
    "UnknownSceneError",
    "ViewRender",
    "build_scene",
    "camera_rays",
    "check_settings",
    "focal_length",
    "list_scenes",
    "load_depth",
    "load_floater_mask",
    "look_at",
    "pixel_rays",
    "render_view",
    "resolve_spec",
    "scene_spec",
    "view_times",
    "write_scene",
    "write_spec",
]
