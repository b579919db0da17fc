"""Realistic scenes (Mitsuba 3 renders of pybullet's textured meshes): the camera convention, every dataset format
built from them read by Nerfstudio's own dataparser with the renderer's ground-truth cameras, the content-addressed
cache, the command, and the scene facts and pruning they lead to. Small versions (16 to 32 px, a dozen views)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mitsuba", reason="realistic scenes need the [scenes] extra (scripts/setup.sh --dev installs it)")
pytest.importorskip("pybullet_data", reason="realistic scenes need pybullet's meshes (the [scenes] extra)")

from nerfify_ns.dataset import read_dataset  # noqa: E402
from nerfify_ns.scenes import pbr, realistic  # noqa: E402
from nerfify_ns.scenes.cameras import look_at  # noqa: E402
from nerfify_ns.scenes.errors import SceneSettingsError  # noqa: E402
from nerfify_ns.scenes.realistic import RealisticSettings, load_ground_truth, write_realistic  # noqa: E402
from nerfify_ns.synthesis.prune import prune_plan  # noqa: E402
from nerfify_ns.synthesis.resources import load_reference_plan  # noqa: E402
from nerfify_ns.synthesis.scene_probe import probe_scene  # noqa: E402

SMALL = dict(resolution=32, n_train=8, n_val=1, n_test=3, spp=4)  # 12 views
CLI = Path(sys.executable).with_name("ns-nerfify")

# format -> (scene, export format or None for the scene's own, Nerfstudio dataparser)
FORMATS = {
    "blender": ("duck-white", None, "blender-data"),
    "dnerf": ("duck-dynamic", None, "dnerf-data"),
    "nerfstudio": ("garden-360", None, "nerfstudio-data"),
    "colmap": ("garden-360", "colmap", "colmap"),
    "llff": ("garden-360", "llff", "nerfstudio-data"),
}


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A scene cache of this module's own (never the user's)."""
    folder = tmp_path_factory.mktemp("scene-cache")
    patch = pytest.MonkeyPatch()
    patch.setenv(realistic.ENV_SCENE_CACHE, str(folder))
    yield folder
    patch.undo()


@pytest.fixture(scope="module")
def built(cache, tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("realistic")
    out = {}
    for fmt, (name, export, _) in FORMATS.items():
        poses = "exact" if name == "garden-360" else None
        out[fmt] = write_realistic(RealisticSettings(name, poses=poses, **SMALL), root / fmt, fmt=export)
    return out


def nerfstudio_outputs(dataset, workdir: Path, split: str):
    """Nerfstudio's own dataparser for ``dataset``, configured from the arguments our runs pass it."""
    import tyro
    from nerfstudio.configs.dataparser_configs import all_dataparsers

    chosen = dataset.dataparser(workdir)
    default = all_dataparsers[chosen.name]
    config = tyro.cli(type(default), default=default, args=list(chosen.args), config=(tyro.conf.FlagConversionOff,))
    config.data = chosen.data
    return config.setup().get_dataparser_outputs(split)


def test_renderer_camera_is_the_written_camera():
    """A small ball at a known point lands where the OpenGL camera (focal from camera_angle_x, principal point at
    the centre) projects it: Mitsuba's sensor frame is converted right."""
    point = np.array([0.4, -0.3, 0.5])
    spec = {"environment": {"visible": False}, "objects": [
        {"mesh": "soccerball.obj", "colour": [0.8, 0.8, 0.8], "scale": 0.06, "translate": point.tolist()}]}
    c2w = look_at(np.array([3.0, 1.0, 1.0]), np.array([0.0, 0.0, 0.2]))
    width, height, angle = 48, 32, 0.9
    view = pbr.render_view(spec, c2w, width, height, angle, spp=16)
    ys, xs = np.nonzero(view.alpha > 0.01)
    w = view.alpha[ys, xs]
    centroid = np.array([(xs + 0.5) @ w, (ys + 0.5) @ w]) / w.sum()
    focal = 0.5 * width / math.tan(0.5 * angle)
    cam = np.linalg.inv(c2w) @ np.append(point, 1.0)
    projected = np.array([width / 2 + focal * cam[0] / -cam[2], height / 2 - focal * cam[1] / -cam[2]])
    np.testing.assert_allclose(centroid, projected, atol=0.15)
    assert view.alpha[0, 0] == 0.0  # a hidden environment leaves the background transparent


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_each_format_from_the_renderer_reads_the_renderers_cameras(fmt, built, tmp_path):
    folder = built[fmt]
    dataset = read_dataset(folder)
    assert dataset.format == fmt and len(dataset.frames) == 12
    truth = {(folder / f["file_path"]).resolve(): f for f in load_ground_truth(folder)["frames"]}
    assert dataset.dataparser(tmp_path).name == FORMATS[fmt][2]
    for split in ("train", "test"):
        outputs = nerfstudio_outputs(dataset, tmp_path, split)
        ours = dataset.split(split)
        assert [Path(p).name for p in outputs.image_filenames] == [f.image.name for f in ours]
        rows = [truth[f.image.resolve()] for f in ours]
        transform = np.eye(4)
        transform[:3] = outputs.dataparser_transform.numpy()
        expected = np.stack([transform @ np.asarray(r["c2w"]) for r in rows])
        expected[:, :3, 3] *= outputs.dataparser_scale
        np.testing.assert_allclose(outputs.cameras.camera_to_worlds.numpy(), expected[:, :3, :4], atol=2e-5)
        cams = outputs.cameras
        theirs = np.concatenate([cams.fx, cams.fy, cams.cx, cams.cy, cams.width, cams.height], 1).astype(float)
        mine = np.array([[r["fl_x"], r["fl_y"], r["cx"], r["cy"], r["w"], r["h"]] for r in rows])
        np.testing.assert_allclose(theirs, mine, rtol=1e-5)
        if fmt == "dnerf":
            np.testing.assert_allclose(cams.times.numpy()[:, 0], [r["time"] for r in rows], atol=1e-6)


def test_the_cache_is_content_addressed_atomic_and_reused(built, cache, tmp_path, monkeypatch):
    settings = RealisticSettings("duck-white", **SMALL)
    entries = sorted(p.name for p in cache.iterdir())
    assert all(not p.startswith(".") for p in entries)  # no staging folder left behind
    assert any(p.startswith("duck-white-") for p in entries)
    monkeypatch.setattr(pbr.Renderer, "render", lambda *a, **k: pytest.fail("a cached scene was rendered again"))
    again = write_realistic(settings, tmp_path / "again")
    assert (again / "transforms_train.json").read_bytes() == (built["blender"] / "transforms_train.json").read_bytes()
    assert realistic.cache_key(settings) != realistic.cache_key(RealisticSettings("duck-white", **{**SMALL, "seed": 1}))
    assert realistic.cache_key(settings) != realistic.cache_key(RealisticSettings("duck-white", **{**SMALL, "spp": 5}))


def test_bad_settings_are_refused_before_anything_is_written(tmp_path):
    for bad in (dict(resolution=4), dict(spp=0), dict(poses="colmap")):
        with pytest.raises(SceneSettingsError):
            write_realistic(RealisticSettings("duck-white", **{**SMALL, **bad}), tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_scene_command_writes_a_realistic_scene(cache, tmp_path):
    env = {"NERFIFY_SCENE_CACHE": str(cache), "PATH": str(CLI.parent)}
    done = subprocess.run([str(CLI), "scene", "garden-360", str(tmp_path / "g"), "--resolution", "16", "--n-train", "9",
                           "--n-val", "0", "--n-test", "2", "--spp", "2", "--poses", "exact", "--format", "colmap"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "wrote scene 'garden-360'" in done.stdout
    dataset = read_dataset(tmp_path / "g")
    assert dataset.format == "colmap" and len(dataset.frames) == 11
    bad = subprocess.run([str(CLI), "scene", "garden-360", str(tmp_path / "bad"), "--resolution", "4"],
                         capture_output=True, text=True, env=env, timeout=120)
    assert bad.returncode == 2 and bad.stdout.count("\n") == 1 and "resolution 4" in bad.stdout
    assert not (tmp_path / "bad").exists()


def test_facts_and_pruning_bounded_object_on_white_vs_unbounded_capture(built):
    """The bounded object on white loses contraction, appearance codes and the camera optimiser; the unbounded
    capture (background to the horizon, exposure varying, no COLMAP model: assumed) keeps them, saying why."""
    plan = load_reference_plan("nerfacto")
    duck = probe_scene(built["blender"])
    assert (duck.bounded, duck.alpha, duck.appearance_variation, duck.exact_poses) == (True, True, False, True)
    assert not duck.forward_facing and "360-degree" in duck.evidence["forward_facing"]
    pruned = {r["path"]: r for r in prune_plan(plan, duck)["pruned"]}
    for path in ("model.field.MLPField.spatial_distortion", "model.field.MLPField.appearance_embedding",
                 "model.camera_optimizer"):
        assert pruned[path]["action"] == "removed", path

    garden = probe_scene(built["nerfstudio"])
    assert (garden.bounded, garden.alpha, garden.exact_poses) == (False, False, False)
    assert "background present" in garden.evidence["bounded"]
    records = {r["path"]: r for r in prune_plan(plan, garden)["pruned"]}
    for path, words in (("model.field.MLPField.spatial_distortion", "unbounded"),
                        ("model.field.MLPField.appearance_embedding", "appearance varies"),
                        ("model.camera_optimizer", "estimated")):
        assert records[path]["action"] == "kept" and words in records[path]["reason"], records[path]
    truth = load_ground_truth(built["nerfstudio"])["facts"]
    assert truth["bounded"] is False and truth["appearance_variation"] is True


def test_forward_facing_layout_from_the_poses():
    from nerfify_ns.synthesis.capture_facts import camera_layout

    facing = np.stack([look_at(np.array([x, -4.0, z]), np.array([x * 0.2, 0.0, z * 0.2]))
                       for x in (-0.6, 0.0, 0.6) for z in (-0.3, 0.3)])
    layout = camera_layout(facing)
    assert layout.forward_facing and not layout.surrounding and "forward-facing" in layout.evidence
    ring = np.stack([look_at(3 * np.array([math.cos(a), math.sin(a), 0.4]), np.zeros(3))
                     for a in np.linspace(0, 2 * math.pi, 12, endpoint=False)])
    layout = camera_layout(ring)
    assert layout.surrounding and not layout.forward_facing


def test_appearance_from_point_tracks_recovers_per_image_gains(tmp_path):
    """Points seen in several images: per-image exposure and white balance come back from their colours (and a
    capture with fixed gains shows no variation)."""
    from PIL import Image

    from nerfify_ns.dataset.colmap import Observations
    from nerfify_ns.dataset.model import Dataset, Frame, Intrinsics
    from nerfify_ns.synthesis.capture_facts import appearance_from_points

    rng = np.random.default_rng(0)
    n_images, n_points, size = 8, 300, 40
    albedo = rng.uniform(0.05, 0.6, (n_points, 3))
    for varying in (True, False):
        ev = rng.uniform(-0.6, 0.6, n_images) if varying else np.zeros(n_images)
        wb = np.exp(rng.uniform(-0.12, 0.12, (n_images, 2))) if varying else np.ones((n_images, 2))
        frames, rows = [], []
        for i in range(n_images):
            seen = rng.choice(n_points, 240, replace=False)  # neighbouring views share most points
            xy = rng.choice(size * size, 240, replace=False)
            gains = 2.0 ** ev[i] * np.array([wb[i, 0], 1.0, wb[i, 1]])
            linear = np.full((size, size, 3), 0.2)
            linear.reshape(-1, 3)[xy] = albedo[seen] * gains
            image = np.round(pbr.srgb(linear) * 255).astype(np.uint8)
            path = tmp_path / f"{varying}_{i}.png"
            Image.fromarray(image).save(path)
            frames.append(Frame(path.name, path, np.eye(4), Intrinsics(1, 1, 1, 1, size, size), "train"))
            rows.append((np.full(240, i), np.stack([xy % size + 0.5, xy // size + 0.5], 1), seen))
        obs = Observations(tuple(f.name for f in frames), ((size, size),) * n_images,
                           np.concatenate([r[0] for r in rows]), np.concatenate([r[1] for r in rows]),
                           np.concatenate([r[2] for r in rows]), {i: np.zeros(3) for i in range(n_points)},
                           np.zeros((n_images, 3)))
        found = appearance_from_points(Dataset("nerfstudio", tmp_path, frames, "test"), obs)
        assert found is not None and found.varies == varying, found.evidence
        if varying:
            assert np.corrcoef(found.exposure_stops, ev)[0, 1] > 0.98
            assert np.corrcoef(found.white_balance[:, 0], np.log(wb[:, 0]))[0, 1] > 0.95
        else:
            assert np.abs(found.exposure_stops).max() < 0.02
