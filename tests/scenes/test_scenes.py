"""Procedural scenes: Blender-format output, exact depth, variants and atomic writing."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from nerfify_ns import scenes
from nerfify_ns.scenes import (
    SceneExistsError,
    SceneSpecError,
    UnknownSceneError,
    build_scene,
    camera_rays,
    list_scenes,
    load_depth,
    load_floater_mask,
    render_view,
    scene_spec,
    write_scene,
    write_spec,
)
from nerfify_ns.scenes import writer as scene_writer
from nerfify_ns.scenes.cameras import look_at

REQUIRED = {
    "default",
    "scale_1e-3",
    "scale_1e3",
    "thin",
    "hifreq",
    "sparse",
    "translucent",
    "unbounded",
    "dynamic",
    "floaters",
}
SMALL = {"resolution": 32, "n_train": 4, "n_val": 2, "n_test": 4}
SPLITS = ("train", "val", "test")


def rgba(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        assert im.mode == "RGBA"
        return np.asarray(im)


@pytest.fixture(scope="session")
def make(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., Path]:
    """Write a catalog scene once per (name, options) for the whole session."""
    cache: dict[tuple[str, tuple[tuple[str, Any], ...]], Path] = {}
    root = tmp_path_factory.mktemp("scenes")

    def _make(name: str, **options: Any) -> Path:
        key = (name, tuple(sorted(options.items())))
        if key not in cache:
            cache[key] = write_scene(name, root / f"{name}-{len(cache)}", **options)
        return cache[key]

    return _make


@pytest.fixture(scope="session")
def default_scene(make: Callable[..., Path]) -> Path:
    start = time.perf_counter()
    root = make("default")  # full size: 64 x 64, 24 + 8 + 8 views
    elapsed = time.perf_counter() - start
    assert elapsed < 20.0, f"default scene took {elapsed:.1f} s to render"
    return root


def surface_distance(spec: dict[str, Any], points: np.ndarray, t: float | None = None) -> np.ndarray:
    """Distance from world points (unit scale) to the nearest primitive surface."""
    layers = build_scene(spec).layers(t)
    return np.min([layer.shape.distance(points) for layer in layers], axis=0)


# --------------------------------------------------------------------------- catalog


def test_catalog_lists_required_scenes_and_resolves_them() -> None:
    names = list_scenes()
    assert set(names) >= REQUIRED
    for name in names:
        spec = scene_spec(name)
        assert spec["name"] == name and spec["description"]
        assert spec["primitives"]


def test_unknown_scene_raises_with_valid_names(tmp_path: Path) -> None:
    with pytest.raises(UnknownSceneError) as info:
        scene_spec("no-such-scene")
    assert "no-such-scene" in str(info.value) and "default" in str(info.value)
    with pytest.raises(UnknownSceneError):
        write_scene("no-such-scene", tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "change",
    [
        {"colour": [1, 0, 0]},
        {"flags": {"bounded": True, "background": False, "dynamic": True}},
        {"primitives": [{"type": "torus", "center": [0, 0, 0]}]},
        {"primitives": [{"type": "sphere", "center": [0, 0, 0], "radius": -1.0}]},
        {"primitives": [{"type": "sphere", "center": [0, 0, 0], "radius": 0.5, "material": {"opacity": 0}}]},
    ],
)
def test_malformed_specs_are_rejected(change: dict[str, Any], tmp_path: Path) -> None:
    with pytest.raises(SceneSpecError):
        write_spec({"base": "default", **change}, tmp_path / "bad", **SMALL)
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- format


def test_default_scene_files_exist_and_parse(default_scene: Path) -> None:
    meta = json.loads((default_scene / "scene.json").read_text())
    assert meta["name"] == "default" and meta["seed"] == 0 and meta["scale"] == 1.0
    assert meta["bounded"] is True and meta["has_background"] is False and meta["has_timestamps"] is False
    lo, hi = np.array(meta["bbox"])
    assert np.all(lo >= -1.5) and np.all(hi <= 1.5) and np.all(lo < hi)
    assert 0.0 < meta["near"] < meta["depth_range"][0] <= meta["depth_range"][1] < meta["far"]
    for split, count in zip(SPLITS, (24, 8, 8), strict=True):
        transforms = json.loads((default_scene / f"transforms_{split}.json").read_text())
        assert transforms["camera_angle_x"] == pytest.approx(0.6911, abs=1e-3)
        assert len(transforms["frames"]) == count
        for frame in transforms["frames"]:
            assert "time" not in frame
            c2w = np.array(frame["transform_matrix"])
            assert c2w.shape == (4, 4) and np.allclose(c2w[3], [0, 0, 0, 1])
            assert np.allclose(c2w[:3, :3].T @ c2w[:3, :3], np.eye(3), atol=1e-12)
            assert np.linalg.norm(c2w[:3, 3]) == pytest.approx(4.0)
            assert c2w[2, 3] > 0.0  # upper hemisphere
            # the camera looks along its -z axis at the origin
            assert np.allclose(-c2w[:3, 2], -c2w[:3, 3] / 4.0, atol=1e-12)
            stem = default_scene / frame["file_path"]
            image = rgba(stem.with_name(stem.name + ".png"))
            assert image.shape == (64, 64, 4) and image.dtype == np.uint8
            depth = load_depth(stem.with_name(stem.name + "_depth.npy"))
            assert depth.shape == (64, 64) and depth.dtype == np.float32


def test_default_alpha_is_zero_on_background_and_255_on_hits(
    default_scene: Path, make: Callable[..., Path]
) -> None:
    for i in range(8):
        image = rgba(default_scene / f"test/r_{i}.png")
        depth = load_depth(default_scene / f"test/r_{i}_depth.npy")
        alpha = image[..., 3]
        miss = ~np.isfinite(depth)
        # pixels whose 3x3 neighbourhood is all background or all object are not edge pixels
        pad = np.pad(miss, 1, constant_values=True)
        window = np.stack([pad[dy : dy + 64, dx : dx + 64] for dy in range(3) for dx in range(3)])
        assert np.all(alpha[window.all(axis=0)] == 0)
        assert np.all(image[window.all(axis=0)][:, :3] == 0)
        assert np.all(alpha[(~window).all(axis=0)] == 255)
        assert alpha[0, 0] == 0 and (alpha == 255).sum() > 200 and (alpha == 0).sum() > 1000
    # without supersampling, alpha is exactly the pixel-centre ray's coverage
    exact = make("default", supersample=1, **SMALL)
    for i in range(4):
        alpha = rgba(exact / f"test/r_{i}.png")[..., 3]
        depth = load_depth(exact / f"test/r_{i}_depth.npy")
        assert np.array_equal(alpha == 255, np.isfinite(depth))
        assert np.all((alpha == 0) | (alpha == 255))


def test_camera_rays_match_the_pixel_convention(default_scene: Path) -> None:
    rays = camera_rays(default_scene / "transforms_test.json")
    assert rays.origins.shape == rays.directions.shape == (8, 64, 64, 3)
    assert np.allclose(np.linalg.norm(rays.directions, axis=-1), 1.0)
    c2w = rays.c2w[0]
    # the four pixels around the image centre are symmetric about the optical axis
    centre = rays.directions[0, 31:33, 31:33].mean(axis=(0, 1))
    assert np.allclose(centre / np.linalg.norm(centre), -c2w[:3, 2], atol=1e-12)
    # +x of the camera is to the right (column grows), +y is up (row shrinks)
    assert (rays.directions[0, 32, 63] - rays.directions[0, 32, 0]) @ c2w[:3, 0] > 0
    assert (rays.directions[0, 0, 32] - rays.directions[0, 63, 32]) @ c2w[:3, 1] > 0


# --------------------------------------------------------------------------- exact depth


def test_single_sphere_depth_is_exact(tmp_path: Path) -> None:
    radius, resolution = 0.5, 33  # odd: the centre pixel's ray is the optical axis
    spec = {
        "name": "one_sphere",
        "primitives": [{"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": radius}],
    }
    root = write_spec(spec, tmp_path / "one", resolution=resolution, n_train=3, n_val=1, n_test=3)
    rays = camera_rays(root / "transforms_test.json")
    for i in range(3):
        depth = load_depth(root / f"test/r_{i}_depth.npy")
        distance = float(np.linalg.norm(rays.c2w[i][:3, 3]))
        assert depth[16, 16] == pytest.approx(distance - radius, rel=1e-6)
        # perpendicular distance of each pixel-centre ray's line from the sphere centre
        o, d = rays.origins[i], rays.directions[i]
        closest = np.linalg.norm(o - np.einsum("hwc,hwc->hw", o, d)[..., None] * d, axis=-1)
        hit = np.isfinite(depth)
        assert np.array_equal(hit, closest <= radius) and 0 < hit.sum() < hit.size
        points = rays.points(depth, i)[hit]
        assert np.allclose(np.linalg.norm(points, axis=-1), radius, rtol=1e-4, atol=0)


@pytest.mark.parametrize(
    "name", ["default", "scale_1e-3", "scale_1e3", "thin", "hifreq", "sparse", "translucent", "unbounded"]
)
def test_depth_reprojects_onto_primitive_surfaces(
    name: str, default_scene: Path, make: Callable[..., Path]
) -> None:
    root = default_scene if name == "default" else make(name, **SMALL)
    spec = scene_spec(name)
    scale = spec["scale"]
    rays = camera_rays(root / "transforms_test.json")
    for i in range(len(rays.file_paths)):
        depth = load_depth(root / f"test/r_{i}_depth.npy").astype(np.float64)
        points = rays.points(depth, i)[np.isfinite(depth)]
        assert len(points) > 0
        gap = surface_distance(spec, points / scale)
        assert gap.max() <= 1e-4 * float(np.linalg.norm(rays.c2w[i][:3, 3])) / scale


def test_scale_variants_scale_depth_by_exactly_the_factor(make: Callable[..., Path]) -> None:
    base = make("default", **SMALL)
    base_meta = json.loads((base / "scene.json").read_text())
    for name, factor in (("scale_1e-3", 1e-3), ("scale_1e3", 1e3)):
        root = make(name, **SMALL)
        meta = json.loads((root / "scene.json").read_text())
        assert meta["scale"] == factor
        assert np.allclose(np.array(meta["bbox"]), np.array(base_meta["bbox"]) * factor, rtol=1e-12)
        assert meta["near"] == pytest.approx(base_meta["near"] * factor, rel=1e-12)
        assert meta["far"] == pytest.approx(base_meta["far"] * factor, rel=1e-12)
        for split in SPLITS:
            a = json.loads((base / f"transforms_{split}.json").read_text())["frames"]
            b = json.loads((root / f"transforms_{split}.json").read_text())["frames"]
            for i, (fa, fb) in enumerate(zip(a, b, strict=True)):
                ma, mb = np.array(fa["transform_matrix"]), np.array(fb["transform_matrix"])
                assert np.allclose(mb[:3, :3], ma[:3, :3], rtol=0, atol=0)
                assert np.allclose(mb[:3, 3], ma[:3, 3] * factor, rtol=1e-12, atol=0)
                da = load_depth(base / f"{split}/r_{i}_depth.npy")
                db = load_depth(root / f"{split}/r_{i}_depth.npy")
                assert np.array_equal(np.isfinite(da), np.isfinite(db))
                finite = np.isfinite(da)
                assert np.allclose(db[finite], da[finite].astype(np.float64) * factor, rtol=1e-6, atol=0)
                assert np.array_equal(rgba(base / f"{split}/r_{i}.png"), rgba(root / f"{split}/r_{i}.png"))


# --------------------------------------------------------------------------- scene variants


def test_dynamic_scene_has_interleaved_times_and_the_object_moves(make: Callable[..., Path]) -> None:
    root = make("dynamic", resolution=32, n_train=8, n_val=3, n_test=4)
    meta = json.loads((root / "scene.json").read_text())
    assert meta["has_timestamps"] is True
    times = {}
    for split in SPLITS:
        frames = json.loads((root / f"transforms_{split}.json").read_text())["frames"]
        times[split] = np.array([f["time"] for f in frames])
        assert np.all((times[split] >= 0.0) & (times[split] <= 1.0))
    assert times["train"].min() == 0.0 and times["train"].max() == 1.0
    for split in ("val", "test"):  # held-out times fall between train times, not in a block
        assert len(set(np.searchsorted(times["train"], times[split]))) == len(times[split])
        assert not np.isin(times[split], times["train"]).any()

    spec = scene_spec("dynamic")
    rays = camera_rays(root / "transforms_test.json")
    ball = next(o for o in build_scene(spec).objects if o.name == "rolling_ball")
    for i, t in enumerate(times["test"]):
        depth = load_depth(root / f"test/r_{i}_depth.npy").astype(np.float64)
        points = rays.points(depth, i)[np.isfinite(depth)]
        assert surface_distance(spec, points, t).max() < 1e-4 * 4.0
        on_ball = ball.at_time(t).distance(points) < 1e-4
        assert on_ball.sum() > 3
        if t > 0.5:  # moved by more than its diameter: those points are not where the ball was
            assert ball.at_time(0.0).distance(points[on_ball]).min() > 0.05

    # same camera, two times: the images differ
    scene = build_scene(spec)
    c2w = look_at(np.array([0.0, -3.0, 2.6]), np.zeros(3))
    early = render_view(scene.layers(0.0), scene.light, c2w, 32, 0.69)
    late = render_view(scene.layers(1.0), scene.light, c2w, 32, 0.69)
    assert np.abs(early.rgb - late.rgb).max() > 0.3
    both = np.isfinite(early.depth) & np.isfinite(late.depth)
    assert (np.abs(early.depth - late.depth)[both] > 0.05).sum() > 10


def test_unbounded_scene_is_opaque_everywhere(make: Callable[..., Path]) -> None:
    root = make("unbounded", **SMALL)
    meta = json.loads((root / "scene.json").read_text())
    assert meta["bounded"] is False and meta["has_background"] is True
    assert meta["transparent_background"] is False
    assert np.array(meta["bbox"]).max() >= 50.0
    assert np.all(np.abs(np.array(meta["foreground_bbox"])) <= 1.5)
    far = 0.0
    for split in SPLITS:
        for i in range(SMALL[f"n_{split}"]):
            assert np.all(rgba(root / f"{split}/r_{i}.png")[..., 3] == 255)
            depth = load_depth(root / f"{split}/r_{i}_depth.npy")
            assert np.all(np.isfinite(depth))
            far = max(far, float(depth.max()))
    assert far > 50.0  # some views see the distant sky


def test_translucent_scene_has_intermediate_alpha(make: Callable[..., Path]) -> None:
    root = make("translucent", **SMALL)
    spec = scene_spec("translucent")
    glass = next(o for o in build_scene(spec).objects if o.name == "glass_ball")
    assert glass.material.opacity == pytest.approx(0.45)
    rays = camera_rays(root / "transforms_test.json")
    for i in range(SMALL["n_test"]):
        alpha = rgba(root / f"test/r_{i}.png")[..., 3]
        assert (alpha == round(0.45 * 255)).sum() > 20  # glass over the background
        assert ((alpha > 20) & (alpha < 235)).sum() > 20
        assert (alpha == 255).sum() > 20
        # the depth of a glass-over-background pixel is the glass surface
        depth = load_depth(root / f"test/r_{i}_depth.npy").astype(np.float64)
        points = rays.points(depth, i)[alpha == round(0.45 * 255)]
        assert glass.shape.distance(points).max() < 1e-4 * 4.0


def test_floaters_appear_in_the_recorded_views_only(make: Callable[..., Path]) -> None:
    options = {"resolution": 32, "n_train": 3, "n_val": 2, "n_test": 6}
    clean, root = make("default", **options), make("floaters", **options)
    meta = json.loads((root / "scene.json").read_text())
    views = meta["floaters"]["views"]
    assert 0 < len(views) < 6 and sorted(meta["floaters"]["blobs"]) == sorted(str(v) for v in views)
    for split in ("train", "val"):
        for i in range(options[f"n_{split}"]):
            assert np.array_equal(rgba(clean / f"{split}/r_{i}.png"), rgba(root / f"{split}/r_{i}.png"))
    for i in range(6):
        a, b = rgba(clean / f"test/r_{i}.png"), rgba(root / f"test/r_{i}.png")
        mask_file = root / f"test/r_{i}_floaters.png"
        if i not in views:
            assert np.array_equal(a, b) and not mask_file.exists()
            continue
        mask = load_floater_mask(mask_file)
        changed = (a != b).any(axis=-1)
        assert changed.any() and mask.any()
        assert not changed[~mask].any()  # nothing changes outside the mask
        assert changed[mask].mean() > 0.5
        clean_depth = load_depth(root / f"test/r_{i}_depth_clean.npy")
        assert np.array_equal(clean_depth, load_depth(clean / f"test/r_{i}_depth.npy"))
        floater_depth = load_depth(root / f"test/r_{i}_depth.npy")
        assert (floater_depth < clean_depth).sum() > 0


def test_every_catalog_scene_writes(make: Callable[..., Path]) -> None:
    for name in list_scenes():
        root = make(name, resolution=16, n_train=2, n_val=1, n_test=2)
        meta = json.loads((root / "scene.json").read_text())
        assert meta["name"] == name and meta["resolution"] == 16
        for split, n in zip(SPLITS, (2, 1, 2), strict=True):
            frames = json.loads((root / f"transforms_{split}.json").read_text())["frames"]
            assert [f["file_path"] for f in frames] == [f"./{split}/r_{i}" for i in range(n)]
            assert all(("time" in f) == meta["has_timestamps"] for f in frames)
            for i in range(n):
                assert rgba(root / f"{split}/r_{i}.png").shape == (16, 16, 4)


# --------------------------------------------------------------------------- writing


def test_failed_write_leaves_nothing_behind(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls = {"n": 0}
    real = scene_writer._save_depth

    def failing(*args: Any, **kwargs: Any) -> None:
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError("disk full")
        real(*args, **kwargs)

    monkeypatch.setattr(scene_writer, "_save_depth", failing)
    with pytest.raises(OSError, match="disk full"):
        write_scene("default", tmp_path / "out", **SMALL)
    assert list(tmp_path.iterdir()) == []


def test_existing_output_is_refused_unless_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()  # an empty folder may be written into
    write_scene("sparse", out, seed=1, **SMALL)
    before = (out / "transforms_test.json").read_bytes()
    with pytest.raises(SceneExistsError):
        write_scene("sparse", out, seed=2, **SMALL)
    assert (out / "transforms_test.json").read_bytes() == before
    write_scene("sparse", out, seed=2, overwrite=True, **SMALL)
    assert (out / "transforms_test.json").read_bytes() != before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_rendering_is_deterministic_given_seed(tmp_path: Path) -> None:
    a = write_scene("floaters", tmp_path / "a", seed=3, **SMALL)
    b = write_scene("floaters", tmp_path / "b", seed=3, **SMALL)
    c = write_scene("floaters", tmp_path / "c", seed=4, **SMALL)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    assert (a / "transforms_train.json").read_bytes() != (c / "transforms_train.json").read_bytes()


# --------------------------------------------------------------------------- nerfstudio


def test_nerfstudio_dataparsers_read_the_scenes(default_scene: Path, make: Callable[..., Path]) -> None:
    blender = pytest.importorskip("nerfstudio.data.dataparsers.blender_dataparser")
    dnerf = pytest.importorskip("nerfstudio.data.dataparsers.dnerf_dataparser")
    outputs = blender.BlenderDataParserConfig(data=default_scene).setup().get_dataparser_outputs(split="test")
    assert len(outputs.image_filenames) == 8 and all(Path(f).exists() for f in outputs.image_filenames)
    ours = camera_rays(default_scene / "transforms_test.json")
    for i in (0, 5):
        bundle = outputs.cameras.generate_rays(camera_indices=i)
        assert np.allclose(bundle.origins.numpy(), ours.origins[i], atol=1e-5)
        assert np.allclose(bundle.directions.numpy(), ours.directions[i], atol=1e-5)

    root = make("dynamic", resolution=32, n_train=8, n_val=3, n_test=4)
    outputs = dnerf.DNeRFDataParserConfig(data=root).setup().get_dataparser_outputs(split="test")
    frames = json.loads((root / "transforms_test.json").read_text())["frames"]
    assert np.allclose(outputs.cameras.times.numpy().ravel(), [f["time"] for f in frames], atol=1e-6)


def test_public_api_is_exported() -> None:
    for name in ("list_scenes", "scene_spec", "write_scene", "camera_rays", "load_depth", "SceneExistsError"):
        assert hasattr(scenes, name)
