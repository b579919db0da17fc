"""Scene-adaptive pruning: facts probed from real dataset folders, rules applied with reasons, plans stay valid."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from nerfify_ns.dataset import DatasetError
from nerfify_ns.grammar import check, validate
from nerfify_ns.scenes import write_scene
from nerfify_ns.synthesis.prune import adopt_scene, prune_plan
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.synthesis.scene_probe import probe_scene


def _small(name, tmp_path, **kw):
    return write_scene(name, tmp_path / name, resolution=16, n_train=6, n_val=1, n_test=1, **kw)


def _records(plan):
    return {r["path"]: r for r in plan["pruned"]}


def test_bounded_synthetic_scene_prunes_what_it_does_not_need(tmp_path):
    facts = probe_scene(_small("default", tmp_path))
    assert facts.flags() == {"bounded": True, "timestamps": False, "alpha": True, "appearance_variation": False,
                             "exact_poses": True, "format": "blender", "forward_facing": False}
    plan = prune_plan(load_reference_plan("nerfacto"), facts)
    records = _records(plan)
    field = plan["model"]["field"]["MLPField"]
    assert "spatial_distortion" not in field and "appearance_embedding" not in field
    assert "camera_optimizer" not in plan["model"] and "camera_opt" not in plan["optimizers"]
    assert records["model.field.MLPField.spatial_distortion"]["reason"].startswith("the scene is bounded")
    assert records["optimizers.camera_opt"]["action"] == "removed"
    assert plan["model"]["renderer"]["background"] == "white"
    hash_params = field["pos_encoding"]["hash"]
    assert hash_params["log2_hashmap_size"] < 19 and hash_params["max_res"] <= 4 * 16 * 4
    assert records["model.field.MLPField.pos_encoding.hash.log2_hashmap_size"]["from"] == 19
    assert plan["scene"] == facts.flags()
    assert check(plan) == []


def test_unbounded_scene_keeps_contraction(tmp_path):
    facts = probe_scene(_small("unbounded", tmp_path))
    assert facts.bounded is False
    plan = prune_plan(load_reference_plan("nerfacto"), facts)
    assert "spatial_distortion" in plan["model"]["field"]["MLPField"]
    kept = _records(plan)["model.field.MLPField.spatial_distortion"]  # kept, and the record says why
    assert kept["action"] == "kept" and kept["reason"].startswith("the scene is unbounded (scene.json")


def _dynamic_plan():
    plan = load_reference_plan("kplanes-static")
    plan["scene"]["timestamps"] = True
    plan["model"]["field"]["MLPField"]["pos_encoding"] = {
        "kplanes_time": {"resolutions": [32, 64], "time_resolution": 8}}
    plan["model"]["regularizers"].update(time_smoothness={"weight": 0.001}, plane_l1={"weight": 0.0001})
    return validate(plan) and plan


def test_time_encoding_is_kept_for_timestamps_and_pruned_without(tmp_path):
    dynamic = prune_plan(_dynamic_plan(), probe_scene(_small("dynamic", tmp_path)))
    assert "kplanes_time" in dynamic["model"]["field"]["MLPField"]["pos_encoding"]
    static = prune_plan(_dynamic_plan(), probe_scene(_small("default", tmp_path)))
    encoding = static["model"]["field"]["MLPField"]["pos_encoding"]
    assert list(encoding) == ["kplanes"] and "time_resolution" not in encoding["kplanes"]
    assert set(static["model"]["regularizers"]) == {"plane_tv"}
    assert _records(static)["model.field.MLPField.pos_encoding"]["reason"].startswith("the scene has no timestamps")


def test_a_keyframe_curriculum_keeps_four_key_frames_of_a_small_scene(tmp_path):
    """A video paper's stride (DyNeRF: key frames 30 apart) on a scene of 12 training images would leave one image
    to learn from until the curriculum ends: the stride is capped at a quarter of the images, and the record says
    why; a stride that leaves enough stays."""
    scene = write_scene("dynamic", tmp_path / "dynamic", resolution=16, n_train=12, n_val=1, n_test=1)
    plan = _dynamic_plan()
    plan["model"]["schedule_hooks"] = {"image_curriculum": {"rule": "keyframes", "keyframe_stride": 30,
                                                             "end_step": 300000, "start_fraction": 0.25}}
    pruned = prune_plan(plan, probe_scene(scene))
    assert pruned["model"]["schedule_hooks"]["image_curriculum"]["keyframe_stride"] == 3
    record = _records(pruned)["model.schedule_hooks.image_curriculum.keyframe_stride"]
    assert "12 training images" in record["reason"]
    plan["model"]["schedule_hooks"]["image_curriculum"]["keyframe_stride"] = 2
    assert prune_plan(plan, probe_scene(scene))["model"]["schedule_hooks"]["image_curriculum"]["keyframe_stride"] == 2


def test_keep_all_changes_nothing_but_notes(tmp_path):
    plan = load_reference_plan("nerfacto")
    kept = adopt_scene(plan, probe_scene(_small("default", tmp_path)))
    assert {k: v for k, v in kept.items() if k != "notes"} == {k: v for k, v in plan.items() if k != "notes"}
    assert "pruning off" in kept["notes"][-1]


def test_real_capture_without_metadata_is_treated_as_unbounded_with_varying_appearance(tmp_path):
    """A Nerfstudio-format capture (forward-facing cameras, opaque images, no scene.json)."""
    root = tmp_path / "capture"
    (root / "images").mkdir(parents=True)
    frames = []
    for i in range(12):  # 11 train, 1 held out (Nerfstudio's 90% split)
        Image.fromarray(np.full((8, 8, 3), 20 * i, np.uint8)).save(root / "images" / f"{i:02d}.png")
        pose = np.eye(4)
        pose[:3, 3] = [0.2 * i, 0.0, 0.0]  # a sideways sweep, all looking down -z
        frames.append({"file_path": f"images/{i:02d}.png", "transform_matrix": pose.tolist()})
    (root / "transforms.json").write_text(json.dumps({"fl_x": 10, "fl_y": 10, "cx": 4, "cy": 4, "w": 8, "h": 8,
                                                      "frames": frames}))
    facts = probe_scene(root)
    assert facts.flags() == {"bounded": False, "timestamps": False, "alpha": False, "appearance_variation": True,
                             "exact_poses": False, "format": "nerfstudio", "forward_facing": True}
    assert facts.evidence["format"].startswith("nerfstudio: transforms.json")
    assert facts.evidence["bounded"].startswith("forward-facing capture")
    plan = prune_plan(load_reference_plan("nerfacto"), facts)
    assert "camera_optimizer" in plan["model"] and "spatial_distortion" in plan["model"]["field"]["MLPField"]
    assert plan["scene"]["format"] == "nerfstudio" and plan["datamanager"]["dataparser"] == "nerfstudio"


def test_probe_errors_name_the_problem(tmp_path):
    with pytest.raises(DatasetError, match="does not exist"):
        probe_scene(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="transforms_train.json"):
        probe_scene(tmp_path / "empty")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "transforms.json").write_text("{not json")
    with pytest.raises(DatasetError, match="not valid JSON"):
        probe_scene(tmp_path / "bad")
