"""One dataset reader for every common format: each format is built from a procedural scene with exact poses
(nerfify_ns.dataset.convert), detected, read back exactly, and read the same way by Nerfstudio's own dataparser
for that format, with the arguments our runs pass it (the same images per split, in the same order; the same
intrinsics; the same poses up to the dataparser's documented ``dataparser_transform`` and ``dataparser_scale``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from nerfify_ns.dataset import FORMATS, read_dataset
from nerfify_ns.dataset.colmap import qvec_to_rotation, rotation_to_qvec
from nerfify_ns.dataset.convert import export_dataset
from nerfify_ns.evaluate.consistency import DepthView, views_from_frames, views_from_transforms
from nerfify_ns.runtime.launch import RunLayout, train_command
from nerfify_ns.scenes import load_depth, write_scene
from nerfify_ns.synthesis.prune import prune_plan
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.synthesis.scene_probe import probe_scene

SMALL = dict(resolution=16, n_train=8, n_val=1, n_test=3)  # 12 images: Nerfstudio's 90% split holds one out

# name -> (export format, export options, expected format, Nerfstudio dataparser)
CASES = {
    "blender": (None, {}, "blender", "blender-data"),
    "dnerf": (None, {}, "dnerf", "dnerf-data"),
    "nerfstudio": ("nerfstudio", {"rgb": True}, "nerfstudio", "nerfstudio-data"),
    "nerfstudio-masks-per-frame": ("nerfstudio", {"masks": True, "per_frame_intrinsics": True}, "nerfstudio",
                                   "nerfstudio-data"),
    "nerfstudio-split-lists": ("nerfstudio", {"rgb": True, "keep_split": True}, "nerfstudio", "nerfstudio-data"),
    "colmap-bin": ("colmap", {"rgb": True}, "colmap", "colmap"),
    "colmap-txt": ("colmap", {"rgb": True, "binary": False}, "colmap", "colmap"),
    "llff": ("llff", {"rgb": True}, "llff", "nerfstudio-data"),
}


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("formats")
    return {"blender": write_scene("default", root / "blender", **SMALL),
            "dnerf": write_scene("dynamic", root / "dnerf", **SMALL), "root": root}


def build(case: str, scenes: dict) -> tuple:
    """(source dataset, the dataset folder of ``case``)."""
    fmt, options, _, _ = CASES[case]
    source = read_dataset(scenes["dnerf" if case == "dnerf" else "blender"])
    if fmt is None:
        return source, source.root
    out = scenes["root"] / case
    if not out.exists():
        export_dataset(source, fmt, out, **options)
    return source, out


def nerfstudio_outputs(dataset, workdir: Path, split: str):
    """Nerfstudio's own dataparser for the dataset, configured from the very arguments our runs pass."""
    import tyro
    from nerfstudio.configs.dataparser_configs import all_dataparsers

    chosen = dataset.dataparser(workdir)
    default = all_dataparsers[chosen.name]
    # ns-train parses booleans as values (`--load-3D-points False`), not flags
    config = tyro.cli(type(default), default=default, args=list(chosen.args),
                      config=(tyro.conf.FlagConversionOff,))
    config.data = chosen.data
    return config.setup().get_dataparser_outputs(split)


@pytest.mark.parametrize("case", list(CASES))
def test_each_format_is_detected_and_read_with_exact_poses_and_intrinsics(case, scenes):
    source, folder = build(case, scenes)
    dataset = read_dataset(folder)
    assert dataset.format == CASES[case][2]
    assert dataset.evidence and len(dataset.frames) == len(source.frames) == 12
    for i, frame in enumerate(dataset.frames):
        # an exported image is named after its source frame's index: 0007_train_r_3.png
        src = source.frames[int(frame.image.stem[:4]) if CASES[case][0] else i]
        np.testing.assert_allclose(frame.c2w, src.c2w, atol=1e-12)
        a, b = frame.intrinsics, src.intrinsics
        assert (a.fx, a.fy, a.cx, a.cy, a.width, a.height) == pytest.approx((b.fx, b.fy, b.cx, b.cy, b.width,
                                                                               b.height), abs=1e-12)
        assert (frame.time is not None) == (case == "dnerf")
        if case == "dnerf":
            assert frame.time == src.time
        assert (frame.mask is not None) == ("masks" in case)
    if case == "nerfstudio-split-lists":
        assert [f.split for f in dataset.frames] == [f.split for f in source.frames]


@pytest.mark.parametrize("case", list(CASES))
def test_nerfstudio_reads_the_same_cameras_per_split(case, scenes, tmp_path):
    _, folder = build(case, scenes)
    dataset = read_dataset(folder)
    assert dataset.dataparser(tmp_path).name == CASES[case][3]
    for split in ("train", "test"):
        outputs = nerfstudio_outputs(dataset, tmp_path, split)
        ours = dataset.split(split)
        assert ours, split
        assert [Path(p).name for p in outputs.image_filenames] == [f.image.name for f in ours]
        transform = np.eye(4)
        transform[:3] = outputs.dataparser_transform.numpy()
        expected = np.stack([transform @ f.c2w for f in ours])
        expected[:, :3, 3] *= outputs.dataparser_scale
        np.testing.assert_allclose(outputs.cameras.camera_to_worlds.numpy(), expected[:, :3, :4], atol=2e-6)
        cams = outputs.cameras
        theirs = np.concatenate([cams.fx, cams.fy, cams.cx, cams.cy, cams.width, cams.height], 1).astype(float)
        mine = np.array([[f.intrinsics.fx, f.intrinsics.fy, f.intrinsics.cx, f.intrinsics.cy,
                          f.intrinsics.width, f.intrinsics.height] for f in ours])
        np.testing.assert_allclose(theirs, mine, rtol=1e-6)
        if dataset.has_times:
            np.testing.assert_allclose(cams.times.numpy()[:, 0], [f.time for f in ours], atol=1e-7)
        if dataset.has_masks:
            assert [Path(p).name for p in outputs.mask_filenames] == [f.mask.name for f in ours]


def test_the_one_dataparser_choice_is_what_ns_train_gets(scenes, tmp_path):
    """``train_command`` (every run: smoke rung, training, benchmarks) takes the dataset's dataparser; LLFF is
    read through a converted transforms.json in the run's folder."""
    for case in ("blender", "dnerf", "nerfstudio", "colmap-bin", "llff"):
        _, folder = build(case, scenes)
        layout = RunLayout(tmp_path / case, "nerfacto")
        cmd = train_command("nerfacto", folder, layout, iterations=2)
        parser = CASES[case][3]
        assert cmd[cmd.index(parser) - 1] == "True"  # the subcommand follows the method arguments
        data = Path(cmd[cmd.index("--data") + 1])
        assert data == (tmp_path / case / "nerfstudio-data" if case == "llff" else folder)
    explicit = train_command("nerfacto", scenes["blender"], RunLayout(tmp_path, "x"), iterations=2,
                             dataparser="blender-data", dataparser_args=["--scale-factor", "2"])
    assert explicit[-3:] == ["blender-data", "--scale-factor", "2"]


def test_formats_are_a_table_tried_in_order():
    names = [f.name for f in FORMATS]
    assert names.index("dnerf") < names.index("blender")  # a Blender layout with times is D-NeRF
    assert names.index("nerfstudio") < names.index("colmap")  # ns-process-data output holds both
    assert all(f.looks_for and f.dataparser for f in FORMATS)


def test_scene_facts_name_the_format_and_the_plan_takes_its_dataparser(scenes):
    for case, dataparser in (("blender", "blender"), ("nerfstudio", "nerfstudio"), ("colmap-bin", "colmap"),
                             ("llff", "nerfstudio")):
        _, folder = build(case, scenes)
        facts = probe_scene(folder)
        assert facts.format == CASES[case][2] and facts.evidence["format"].startswith(facts.format)
        plan = prune_plan(load_reference_plan("nerfacto"), facts)
        assert plan["scene"]["format"] == facts.format and plan["datamanager"]["dataparser"] == dataparser
        assert f"format: {facts.format}" in plan["evidence"]["scene"]
    llff = probe_scene(build("llff", scenes)[1])
    assert llff.bounded is False and "forward-facing" in llff.evidence["bounded"]


def test_consistency_views_use_each_frames_camera(scenes):
    """The consistency check reads the dataset's cameras: on the Blender scene the same views as the old
    Blender-only path; a general pinhole camera (fx != fy, off-centre principal point) projects its own points
    back onto its pixels."""
    dataset = read_dataset(scenes["blender"])
    frames = dataset.eval_frames
    depths = [load_depth(f.image.with_name(f.stem + "_depth.npy")) for f in frames]
    new = views_from_frames(frames, depths)
    old = views_from_transforms(dataset.root / "transforms_test.json", depths)
    for a, b in zip(new, old, strict=False):
        np.testing.assert_allclose(np.nan_to_num(a.points(), posinf=0), np.nan_to_num(b.points(), posinf=0))
    view = DepthView(np.full((12, 16), 3.0), np.eye(4), 20.0, fx=20.0, fy=14.0, cx=9.5, cy=5.0)
    row, col, dist, inside = view.project(view.points())
    assert inside.all() and np.allclose(dist, 3.0)
    assert (row == np.arange(12)[:, None]).all() and (col == np.arange(16)[None]).all()


def test_colmap_quaternions_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        r = qvec_to_rotation(q)
        assert np.allclose(r.T @ r, np.eye(3)) and math.isclose(np.linalg.det(r), 1.0)
        np.testing.assert_allclose(qvec_to_rotation(rotation_to_qvec(r)), r, atol=1e-12)


def test_colmap_reprojection_error_is_a_pose_quality_fact(scenes, tmp_path):
    """Each COLMAP 3D point stores its mean reprojection error (points3D.txt / .bin): the probe states their mean."""
    import shutil
    import struct

    for binary in (False, True):
        _, folder = build("colmap-bin" if binary else "colmap-txt", scenes)
        data = Path(shutil.copytree(folder, tmp_path / f"model-{binary}"))
        model = data / "sparse" / "0"
        if binary:
            points = [struct.pack("<Q3d3Bd", i, 0.0, 0.0, 0.0, 1, 2, 3, err) + struct.pack("<Q", 1)
                      + struct.pack("<ii", 1, 0) for i, err in ((1, 0.5), (2, 1.5))]
            (model / "points3D.bin").write_bytes(struct.pack("<Q", 2) + b"".join(points))
        else:
            (model / "points3D.txt").write_text("# comment\n1 0 0 0 1 2 3 0.5 1 0\n2 0 0 0 1 2 3 1.5 1 0 2 0\n")
        assert read_dataset(data).meta["reprojection_error"] == (1.0, 2)
        facts = probe_scene(data)
        assert facts.exact_poses is False
        assert "COLMAP mean reprojection error 1.00 px over 2 points" in facts.evidence["exact_poses"]
