"""The grammar fuzzer: sampled plans are derivations, cover every terminal and both edges of every
parameter, and (a handful here, hundreds in `nerfify_ns.benchmarks.grammar_fuzz`) compose and pass the static
and contract rungs. Each test names its seed so a failure can be replayed."""

from __future__ import annotations

import pytest

from nerfify_ns.benchmarks.grammar_fuzz import check_plan
from nerfify_ns.grammar import check, load_grammar
from nerfify_ns.grammar.fuzz import PlanSampler
from nerfify_ns.synthesis.resources import load_reference_plan

SEED = 0
COVERAGE_SEED = 1
"""The coverage test's seed (its 1,500 plans reach both edges of every parameter; seed 0's miss one edge of 1,500)."""


def test_sampled_plans_are_derivations_covering_the_grammar():
    g = load_grammar()
    sampler = PlanSampler(g, seed=COVERAGE_SEED)
    plans = [sampler.sample() for _ in range(1500)]
    assert all(check(plan, g) == [] for plan in plans)
    missing = sampler.coverage.missing(g)
    assert missing == {"terminals": [], "edges": []}, f"seed {COVERAGE_SEED}: {missing}"


def test_the_seed_replays_the_same_plans():
    first = [PlanSampler(load_grammar(), seed=3).sample() for _ in range(1)]
    again = [PlanSampler(load_grammar(), seed=3).sample() for _ in range(1)]
    assert first == again
    assert PlanSampler(load_grammar(), seed=4).sample() != first[0]


@pytest.mark.slow
@pytest.mark.parametrize("index", [0, pytest.param(1, marks=pytest.mark.bench),
                                   pytest.param(2, marks=pytest.mark.bench)])
def test_sampled_plans_compose_and_pass_static_and_contract(index, tmp_path):
    sampler = PlanSampler(load_grammar(), seed=SEED)
    plans = [sampler.sample(method=f"fuzz-{SEED}-{i}") for i in range(index + 1)]
    failures = check_plan(plans[index], tmp_path)
    assert failures == [], f"seed {SEED} plan {index} (replay: python -m nerfify_ns.benchmarks.grammar_fuzz " \
                           f"--seed {SEED} --only {index}): {failures}"


@pytest.mark.slow
def test_density_regulariser_on_a_tensorial_field(tmp_path):
    """Found by the fuzzer: the density sparsity regulariser read `last_density`, which the tensorial field
    never kept, so the plan composed but a training step failed."""
    plan = load_reference_plan("tensorf")
    plan["model"]["regularizers"] = {"density_sparsity": {"weight": 0.001}}
    assert check_plan(plan, tmp_path) == []


PLAN_0_21 = """
scene: {timestamps: false, appearance_variation: false, bounded: false}
base: instant-ngp
trainer: {mixed_precision: false}
datamanager: {train_num_rays_per_batch: 1048576, eval_num_rays_per_batch: 4096}
model:
  field:
    MLPField:
      pos_encoding: {positional: {num_frequencies: 25, min_freq_exp: 0.0, max_freq_exp: 0.0}}
      dir_encoding: {sh: {levels: 4}}
      backbone: {num_layers: 16, layer_width: 46, skip_connections: []}
      density_head: {density_linear: {activation: relu}}
      rgb_head: {layer_width: 8}
      spatial_distortion: {scene_contraction: {order: inf}}
  sampler: {occupancy_grid: {grid_resolution: 512, grid_levels: 1, cone_angle: 0.0}}
  renderer: {}
  losses: {rgb: {l2: {}}}
optimizers:
  fields:
    optimizer: {adam: {eps: 1.0, weight_decay: 0.0}}
    scheduler: {exponential_decay: {max_steps: 55}}
method: fuzz-0-21
"""


@pytest.mark.slow
def test_a_field_of_frequency_encodings_takes_a_batch_with_no_samples(tmp_path):
    """Found by the fuzzer (seed 0, plan 21): an occupancy grid culled every sample of a batch and Nerfstudio's
    frequency encoding could not reshape the empty tensor, so a training step failed. The generated fields
    encode through `_encode`, which gives an empty output of the encoding's width."""
    import yaml

    from nerfify_ns.plan import Plan

    assert check_plan(Plan(yaml.safe_load(PLAN_0_21)), tmp_path) == []


def test_proposal_resolutions_for_no_network_are_rejected():
    """Found by the fuzzer (seed 0, plan 0): four proposal resolutions for two rounds built four networks of
    which two never received a gradient. The grammar now rejects resolutions no network uses."""
    plan = load_reference_plan("nerfacto")
    proposal = plan["model"]["sampler"]["proposal"]
    proposal["network_max_res"] = [64, 64, 64, 64]
    errors = check(plan, load_grammar())
    assert any(e.rule == "param_constraint" and "network_max_res" in e.message for e in errors), errors
    proposal["network_max_res"] = [64, 128]
    assert check(plan, load_grammar()) == []


@pytest.mark.slow
@pytest.mark.parametrize("reference", ["nerfacto", "kplanes-static"])
def test_one_proposal_network_for_every_round(reference, tmp_path):
    """`use_same_network` builds one network that every round queries, as Nerfacto does; with k-planes
    proposal networks too (found by the fuzzer, seed 0 plan 152: Nerfacto asserted a one-entry
    proposal_net_args_list before the k-planes networks replaced its own)."""
    plan = load_reference_plan(reference)
    plan["model"]["sampler"]["proposal"].update(use_same_network=True, network_max_res=[64])
    assert check_plan(plan, tmp_path) == []


def test_the_benchmark_checks_every_plan_of_its_slice(monkeypatch, tmp_path):
    """`--start` splits a seed's plans between processes: each plan of the slice is checked once (a timing
    variable once shadowed the slice's start, and every plan after the first was skipped)."""
    from nerfify_ns.benchmarks import grammar_fuzz

    checked = []
    monkeypatch.setattr(grammar_fuzz, "check_plan", lambda plan, work: checked.append(plan["method"]) or [])
    summary = grammar_fuzz.run(5, SEED, keep=tmp_path, start=2)
    assert checked == [f"fuzz-{SEED}-{i}" for i in (2, 3, 4)] and summary["plans"] == 3


def test_near_plane_after_the_far_plane_is_rejected():
    """Found by the fuzzer (seed 0, plan 155): near 0.90 beyond far 0.53 left every ray without samples and the
    field failed on an empty batch. The grammar now refuses such bounds."""
    plan = load_reference_plan("nerfacto")
    plan["model"]["bounds"] = {"near_plane": 0.9, "far_plane": 0.5}
    errors = check(plan, load_grammar())
    assert any(e.rule == "param_constraint" and "near_plane" in e.message for e in errors), errors
    plan["model"]["bounds"] = {"near_plane": 0.05, "far_plane": 0.5}
    assert check(plan, load_grammar()) == []
