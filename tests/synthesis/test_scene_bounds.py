"""Near and far planes of a bounded scene from its cameras and the dataparser's box."""

import itertools

import numpy as np

from nerfify_ns.dataset import read_dataset
from nerfify_ns.scenes import write_scene
from nerfify_ns.synthesis.prune import prune_plan
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.synthesis.scene_bounds import near_far
from nerfify_ns.synthesis.scene_probe import probe_scene


def test_every_point_of_the_box_lies_between_near_and_far(tmp_path):
    data = read_dataset(write_scene("default", tmp_path / "s", resolution=16, n_train=6, n_val=1, n_test=2))
    near, far, why = near_far(data)
    centres = data.poses(data.frames)[:, :3, 3]
    box = np.array(list(itertools.product((-1.5, 1.5), repeat=3)))
    rng = np.random.default_rng(0)
    points = np.concatenate([box, rng.uniform(-1.5, 1.5, (2000, 3))])
    distances = np.linalg.norm(points[None] - centres[:, None], axis=2)
    assert near <= distances.min() and distances.max() <= far
    assert distances.min() - near < 0.02 and far - distances.max() < 0.02  # tight: the box, not a guess
    assert "blender dataparser's box" in why


def test_pruning_sets_the_planes_and_the_first_samples_for_a_bounded_scene(tmp_path):
    data = read_dataset(write_scene("default", tmp_path / "s", resolution=16, n_train=6, n_val=1, n_test=2))
    facts = probe_scene(data)
    plan = prune_plan(load_reference_plan("nerfacto"), facts)
    assert plan["model"]["bounds"] == {"near_plane": facts.near, "far_plane": facts.far}
    assert plan["model"]["sampler"]["proposal"]["initial_sampler"] == "uniform"
    rules = {p["rule"] for p in plan["pruned"]}
    assert {"near_far_for_bounded_scene", "uniform_first_samples_for_bounded_scene"} <= rules


def test_a_camera_inside_the_box_keeps_the_plans_near_plane(tmp_path):
    data = read_dataset(write_scene("scale_1e-3", tmp_path / "s", resolution=16, n_train=6, n_val=1, n_test=2))
    near, far, why = near_far(data)
    assert near is None and far is not None and "inside" in why
    plan = prune_plan(load_reference_plan("nerfacto"), probe_scene(data))
    assert plan["model"]["bounds"]["near_plane"] == 0.05 and plan["model"]["bounds"]["far_plane"] == far
