"""Papers of 3D Gaussian splatting stand on splatfacto: the grammar's base of explicit primitives (no field, no ray
sampler), the deformation of the Gaussians at a camera's time (components/field_wrappers.GaussianDeformation), the
schedule hooks a splatting paper states in prose (a warm-up that trains the Gaussians alone, annealed noise on the
time input), the plugin's model (templates/model_splat.py.j2) and the ladder's camera harness. A paper of our own
(tests/data/papers/prose_splatting.md) states each part in words; the slow test runs the ladder on its plan."""

from __future__ import annotations

import copy
import re
from pathlib import Path

import pytest
import torch
import yaml

from nerfify_ns.components.field_wrappers import GaussianDeformation, condition
from nerfify_ns.grammar.validate import check
from nerfify_ns.knowledge.family import detect_family
from nerfify_ns.paper import ingest
from nerfify_ns.paper.hyperparams import NUMBER
from nerfify_ns.synthesis.novel import IMPLEMENTED, implement_holes
from nerfify_ns.synthesis.plan_from_paper import plan_from_paper
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.verify.recorder import as_pixels

PAPERS = Path(__file__).resolve().parents[1] / "data" / "papers"


@pytest.fixture(scope="module")
def splat_paper():
    doc = ingest(PAPERS / "prose_splatting.md")
    derived = plan_from_paper(doc)
    return doc, derived, implement_holes(doc, derived.plan)


@pytest.fixture(scope="module")
def planes_paper():
    """A paper of our own whose deformation reads the Gaussians through K-Planes and whose planes get a TV loss:
    its plan as the pipeline makes it (the paper's own parts built, then the cards they host)."""
    doc = ingest(PAPERS / "prose_splatting_planes.md")
    derived = plan_from_paper(doc)
    built = implement_holes(doc, derived.plan)
    return derived, derived.host_cards(built.plan)


def _splat_plan() -> dict:
    plan = copy.deepcopy(load_reference_plan("splatfacto"))
    plan["method"] = "splat-test"
    plan["scene"]["timestamps"] = True
    plan["datamanager"]["dataparser"] = "dnerf"
    return plan


def _rules(plan: dict) -> set[str]:
    return {f"{v.path}:{v.rule}" for v in check(plan)}


# ------------------------------------------------------------------------------------------ the component
def test_the_gaussian_deformation_starts_at_the_canonical_gaussians_and_learns_all_three_offsets():
    torch.manual_seed(0)
    deform = GaussianDeformation(num_layers=2, layer_width=16, position_frequencies=3, time_frequencies=2)
    means = torch.randn(50, 3, requires_grad=True)
    times = torch.full((50, 1), 0.3)
    moved, same_times, offsets = deform(means, times, torch.zeros(50, dtype=torch.long))
    assert torch.equal(moved, means) and torch.equal(same_times, times)
    assert offsets.shape == (50, 7) and not offsets.any()  # rotation (4) and log-scale (3) offsets start at 0
    (moved.sum() + offsets.sum()).backward()
    head = deform.network[-1]
    assert head.weight.grad is not None and head.weight.grad.abs().sum() > 0
    # Eq. 4's sg: the encoding reads the centre without its gradient, the centre learns through x + dx only
    assert torch.equal(means.grad, torch.ones_like(means))


def test_the_annealed_time_noise_scales_with_the_mean_interval_of_the_training_times():
    torch.manual_seed(0)
    deform = GaussianDeformation(num_layers=1, layer_width=8, position_frequencies=2, time_frequencies=2)
    torch.nn.init.normal_(deform.network[-1].weight)
    deform.time_noise.fill_(0.1)
    x = torch.zeros(4, 3)

    def at(t: float, training: bool = True) -> torch.Tensor:
        deform.train(training)
        return deform(x, torch.full((4, 1), t), torch.zeros(4, dtype=torch.long))[0]

    assert torch.equal(at(0.0), at(0.0))  # one time seen: no interval, no noise
    at(0.5), at(1.0)
    assert deform.time_interval() == pytest.approx(0.5)
    assert not torch.equal(at(0.5), at(0.5))  # beta * dt = 0.05 on gamma(t) while training
    assert torch.equal(at(0.5, training=False), at(0.5, training=False))  # never at evaluation
    deform.time_noise.fill_(0.0)  # annealed to 0
    assert torch.equal(at(0.5), at(0.5))


def test_condition_applies_the_deformation_to_every_gaussian_at_one_time():
    deform = GaussianDeformation(num_layers=1, layer_width=8, position_frequencies=2, time_frequencies=2)
    torch.nn.init.normal_(deform.network[-1].bias)
    means = torch.zeros(6, 3)
    moved, _, offsets = condition([deform], means, torch.full((6, 1), 0.7), None)
    assert moved.shape == (6, 3) and offsets.shape == (6, 7)
    assert torch.allclose(moved, moved[:1].expand(6, 3))  # the same centre at the same time moves the same way


def test_a_deformation_over_planes_reads_the_gaussians_in_their_box_and_learns_the_planes():
    """4D-GS's structure encoder: six planes over (x, y, z, t), the centres mapped into the box of the first ones
    seen; training starts at the canonical Gaussians and the planes and heads receive gradients."""
    torch.manual_seed(0)
    deform = GaussianDeformation(num_layers=1, layer_width=16, encoding="planes", plane_resolution=8,
                                 plane_levels=2, plane_features=4, time_resolution=5)
    assert len(deform.position_encoding.spatial_planes) == 6 and len(deform.position_encoding.time_planes) == 6
    means = torch.rand(40, 3) * 10.0 + 5.0  # a box far from [-1, 1]
    moved, _, offsets = deform(means, torch.full((40, 1), 0.25), torch.zeros(40, dtype=torch.long))
    assert torch.equal(moved, means) and not offsets.any()
    lo, hi = deform.box.clone()
    assert bool((lo < means.min(0).values).all() and (hi > means.max(0).values).all())
    deform(means * 3.0, torch.zeros(40, 1), torch.zeros(40, dtype=torch.long))
    assert torch.equal(deform.box, torch.stack([lo, hi]))  # kept: later centres do not move it
    torch.nn.init.normal_(deform.network[-1].weight)
    moved, _, offsets = deform(means, torch.full((40, 1), 0.25), torch.zeros(40, dtype=torch.long))
    (moved.sum() + offsets.sum()).backward()
    planes = deform.position_encoding.spatial_planes + deform.position_encoding.time_planes
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in planes)
    with torch.no_grad():  # time planes start at 1 (no motion over t); once learned, the motion depends on t
        for plane in deform.position_encoding.time_planes:
            plane.uniform_(0.5, 1.5)
    early, _, _ = deform(means, torch.full((40, 1), 0.25), torch.zeros(40, dtype=torch.long))
    later, _, _ = deform(means, torch.full((40, 1), 0.75), torch.zeros(40, dtype=torch.long))
    assert not torch.allclose(later, early)


# ------------------------------------------------------------------------------------------ the grammar
def test_a_model_of_gaussians_has_no_field_no_sampler_and_takes_only_its_own_wrappers():
    plan = _splat_plan()
    assert check(plan) == []
    with_sampler = copy.deepcopy(plan)
    with_sampler["model"]["sampler"] = {"proposal": {}}
    assert "base:requires_terminal" in _rules(with_sampler)
    deformed = copy.deepcopy(plan)
    deformed["model"]["field_wrappers"] = {"gaussian_deformation": {}}
    assert check(deformed) == []
    static = copy.deepcopy(deformed)
    static["scene"]["timestamps"] = False  # a deformation reads times
    assert "model.field_wrappers.gaussian_deformation:requires_scene" in _rules(static)
    samples = copy.deepcopy(plan)
    samples["model"]["field_wrappers"] = {"deformation": {}}  # a deformation of a field's samples
    assert "model.field_wrappers.deformation:requires_terminal" in _rules(samples)
    for path, value in (("model.regularizers", {"density_sparsity": {}}),
                        ("pixel_sampler", {"gradient_importance": {}})):
        other = copy.deepcopy(deformed)
        node = other
        *parents, last = path.split(".")
        for key in parents:
            node = node[key]
        node[last] = value
        assert any(rule.endswith("param_constraint") for rule in _rules(other)), path
    nerfacto = copy.deepcopy(load_reference_plan("kplanes-time"))
    nerfacto["method"] = "ray-test"
    nerfacto["model"]["field_wrappers"] = {"gaussian_deformation": {}}
    assert "model.field_wrappers.gaussian_deformation:requires_base" in _rules(nerfacto)


def test_plane_regularisers_need_planes_of_the_field_or_of_a_deformation_of_gaussians():
    plan = _splat_plan()
    plan["model"]["field_wrappers"] = {"gaussian_deformation": {}}
    plan["model"]["regularizers"] = {"plane_tv": {}, "time_smoothness": {}}
    assert {"model.regularizers.plane_tv:param_constraint",
            "model.regularizers.time_smoothness:param_constraint"} <= _rules(plan)  # a frequency encoding
    plan["model"]["field_wrappers"]["gaussian_deformation"]["encoding"] = "planes"
    assert check(plan) == []
    hashed = copy.deepcopy(load_reference_plan("nerfacto"))
    hashed["method"] = "hash-test"
    hashed.setdefault("model", {})["regularizers"] = {"plane_tv": {}}
    assert "model.regularizers.plane_tv:param_constraint" in _rules(hashed)
    planes = copy.deepcopy(load_reference_plan("kplanes-time"))
    planes["method"] = "planes-test"
    planes["model"]["regularizers"] = {"plane_tv": {}, "time_smoothness": {}}
    assert check(planes) == []


# ------------------------------------------------------------------------------------------ from a paper
def test_a_dynamic_splatting_paper_stands_on_splatfacto_with_timestamps(splat_paper):
    doc, derived, _ = splat_paper
    family = detect_family(doc)
    assert family.name == "splatting" and family.buildable and "dynamic" in family.also
    assert family.scene.get("timestamps") is True  # the dynamic family's fact, which also passed
    assert derived.plan["base"] == "splatfacto" and derived.plan["scene"]["timestamps"] is True
    assert "field" not in derived.plan["model"] and "sampler" not in derived.plan["model"]


def test_a_splatting_papers_parts_stated_in_prose_are_built(splat_paper):
    _, _, built = splat_paper
    plan = built.plan
    deform = plan["model"]["field_wrappers"]["gaussian_deformation"]
    assert (deform["num_layers"], deform["layer_width"]) == (6, 128)
    hooks = plan["model"]["schedule_hooks"]
    # "During the first 2k iterations we only train the 3D Gaussians": the plan's one other part is held
    assert hooks["freeze"] == {"module": "deformation", "start_step": 0, "end_step": 2000}
    # "Gaussian noise ... scaling factor of 0.05 ... anneal it linearly to zero over the first 10k iterations"
    anneal = hooks["anneal"]
    assert (anneal["target"], anneal["start_value"], anneal["end_value"], anneal["end_step"]) == \
        ("deformation.time_noise", 0.05, 0.0, 10000)
    assert {r.production: r.status for r in built.records} == {"FieldWrapper": IMPLEMENTED,
                                                               "ScheduleHook": IMPLEMENTED}
    freeze = next(p for r in built.records for p in r.parts if p["part"] == "freeze")
    assert freeze["parameters"]["module"]["source"] == "plan"  # the sentence names none: said so
    assert check(plan) == []
    # the Gaussians' own learning rates stay the base's (no sentence gives them)
    assert plan["optimizers"]["means"] == load_reference_plan("splatfacto")["optimizers"]["means"]


def test_a_technique_without_a_slot_in_the_base_lives_in_the_part_that_hosts_it(planes_paper):
    """K-Planes has no field to encode in a model of Gaussians: once the paper's deformation is built, the card
    makes it read the planes (its sentence quoted), and the TV loss on those planes follows; no note says they
    were left out."""
    derived, plan = planes_paper
    assert "gaussian_deformation" not in (derived.plan["model"].get("field_wrappers") or {})  # built from prose
    deform = plan["model"]["field_wrappers"]["gaussian_deformation"]
    assert deform["encoding"] == "planes" and (deform["num_layers"], deform["layer_width"]) == (2, 64)
    assert "K-Planes [2] module" in plan["evidence"]["model.field_wrappers.gaussian_deformation.encoding"]
    assert "plane_tv" in plan["model"]["regularizers"]
    assert "total variation loss" in plan["evidence"]["model.regularizers.plane_tv"]
    assert not [n for n in plan["notes"] if "not used" in n and ("kplanes" in n or "plane_tv" in n)]
    assert check(plan) == []


def test_a_dimension_is_not_a_number_of_a_hyperparameter():
    text = "the learning rate of 3D Gaussians is the official one, a 4-D grid, while 8e-4 and 3 layers are values"
    assert [m.group("num") for m in re.finditer(NUMBER, text)] == ["8e-4", "3"]


def test_rendered_images_are_compared_with_the_ground_truth_at_their_resolution():
    image = torch.zeros(8, 8, 4, dtype=torch.uint8)
    image[:4, :4] = 255
    rgb = torch.full((4, 4, 3), 0.5)
    pixels, target = as_pixels(rgb, image)
    assert pixels.shape == (16, 3) and target.shape == (16, 4)
    assert target[0].tolist() == [1.0, 1.0, 1.0, 1.0] and target[-1].tolist() == [0.0, 0.0, 0.0, 0.0]
    rays = torch.rand(5, 3)
    assert as_pixels(rays, rays)[0] is rays  # a ray batch is left as it is


# ------------------------------------------------------------------------------------------ the plugin
def test_the_plugin_of_a_splatting_plan_subclasses_splatfacto(tmp_path, splat_paper):
    from nerfify_ns.synthesis.compose import write_plugin

    _, _, built = splat_paper
    folder = tmp_path / "plugin"
    write_plugin(copy.deepcopy(built.plan), folder)
    package = next(p for p in folder.iterdir() if (p / "model.py").is_file())
    model = (package / "model.py").read_text()
    assert "class " in model and "(SplatfactoModel):" in model and '"deformation": GaussianDeformation(' in model
    assert 'Freeze(module="deformation"' in model and 'target="deformation.time_noise"' in model
    config = (package / "config.py").read_text()
    assert "FullImageDatamanagerConfig(" in config and "train_num_rays_per_batch" not in config
    assert '"deformation": {' in config


def test_the_plugin_regularises_the_planes_of_its_deformation(tmp_path, planes_paper):
    from nerfify_ns.synthesis.compose import write_plugin

    _, plan = planes_paper
    folder = tmp_path / "plugin"
    write_plugin(copy.deepcopy(plan), folder)
    package = next(p for p in folder.iterdir() if (p / "model.py").is_file())
    model = (package / "model.py").read_text()
    assert 'encoding="planes"' in model
    assert 'plane_tv(self.wrappers["deformation"].position_encoding.spatial_planes)' in re.sub(r"\s+", "", model)


@pytest.mark.slow
def test_a_deformed_splatting_plugin_passes_every_rung(tmp_path, splat_paper):
    """The plan of the paper (sizes cut for a CPU) through `ns-nerfify compose --until verify` on the dynamic scene:
    static, contract (a camera's training step, every group's gradients), stability (camera cases; ray cases
    recorded as not applicable) and smoke (the run's rendered images against the ground truth at their resolution,
    the hooks' schedule compressed into the rung)."""
    import subprocess
    import sys

    _, _, built = splat_paper
    plan = copy.deepcopy(built.plan)
    plan["method"] = "drift-splat-test"
    plan["model"]["field_wrappers"]["gaussian_deformation"].update({"num_layers": 2, "layer_width": 32})
    path = tmp_path / "plan.yaml"
    path.write_text(yaml.safe_dump(plan))
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "nerfify_ns.cli", "compose", str(path), "--scene", "dynamic",
                           "--out", str(out), "--until", "verify"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    verify = yaml.safe_load((out / "verify.json").read_text())
    assert [(r["name"], r["status"]) for r in verify["rungs"]] == [
        ("static", "pass"), ("contract", "pass"), ("stability", "pass"), ("smoke", "pass")]
    cases = {(c["component"], c["case"]): c["status"] for r in verify["rungs"] if r["name"] == "stability"
             for c in r["details"].get("cases", [])}
    assert cases.get(("<model>", "near_eq_far")) == "n/a" and cases.get(("<model>", "scene_scale_1e3")) == "pass"


def test_a_number_in_scientific_notation_is_no_network_size():
    """"a tiny MLP with a learning rate of 1.6×10−3" states no 6 layers of 10 units; "8 × 256" does."""
    from nerfify_ns.synthesis.novel.prose import load_spec

    part = next(p for p in load_spec().parts if p.name == "deformation")
    sizes = {name: [m.group("num") for pattern in part.parameters[name].patterns
                    for text in ("a tiny MLP with a learning rate of 1.6×10−3", "an MLP of 8 × 256")
                    for m in pattern.finditer(text)]
             for name in ("num_layers", "layer_width")}
    assert sizes == {"num_layers": ["8"], "layer_width": ["256"]}


def test_the_harness_trains_a_plain_splatfacto_model_on_a_small_camera():
    """A model of Gaussians without wrappers keeps splatfacto's own get_outputs, which the CPU runtime wraps: the
    harness still knows it renders cameras, and a training step on a small camera gives every group a gradient."""
    from nerfstudio.data.scene_box import SceneBox
    from nerfstudio.models.splatfacto import SplatfactoModelConfig

    from nerfify_ns.runtime import activate
    from nerfify_ns.verify.assembled import grad_problems, renders_cameras, train_step

    activate(force=True)  # the CPU rasteriser (and no LPIPS download), also on a machine with CUDA
    torch.manual_seed(0)
    model = SplatfactoModelConfig(num_random=300).setup(
        scene_box=SceneBox(aabb=torch.tensor([[-1.5, -1.5, -1.5], [1.5, 1.5, 1.5]])), num_train_data=4, metadata={})
    assert renders_cameras(model)
    outputs, losses, total = train_step(model)
    assert outputs["rgb"].ndim == 3 and torch.isfinite(total)
    bad, missing = grad_problems(model, require=True)
    assert bad == [] and missing == [], (bad, missing)
