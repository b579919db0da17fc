"""The grammar: validate() accepts exactly the derivations, and its JSON Schema and GBNF exports
accept and reject the same plans (each rule of the grammar, both ways)."""

from __future__ import annotations

import copy
from collections.abc import Callable

import jsonschema
import pytest

from nerfify_ns.grammar import PlanError, check, load_grammar, validate
from nerfify_ns.grammar.gbnf import canonical_json, int_range, to_gbnf
from nerfify_ns.grammar.gbnf_match import GbnfGrammar, GbnfSyntaxError
from nerfify_ns.grammar.json_schema import to_json_schema
from nerfify_ns.synthesis.resources import load_reference_plan, reference_plans


@pytest.fixture(scope="module")
def schema():
    s = to_json_schema()
    jsonschema.Draft202012Validator.check_schema(s)
    return jsonschema.Draft202012Validator(s)


@pytest.fixture(scope="module")
def gbnf():
    return GbnfGrammar(to_gbnf())


CUSTOM = {"module": "components.novel", "class": "NovelPart", "implements": ["Eq. 7"], "source": "hand"}


def ref(name: str) -> dict:
    return copy.deepcopy(load_reference_plan(name))


def mutate(name: str, edit: Callable[[dict], None]) -> dict:
    plan = ref(name)
    edit(plan)
    return plan


def field(plan: dict) -> dict:
    return plan["model"]["field"]["MLPField"]


def _dynamic_kplanes(p: dict) -> None:
    p["scene"]["timestamps"] = True
    field(p)["pos_encoding"] = {"kplanes_time": {"resolutions": [64, 128], "time_resolution": 25}}
    p["model"]["regularizers"] = {"plane_tv": {"weight": 0.0002}, "time_smoothness": {"weight": 0.001},
                                  "plane_l1": {"weight": 0.0001}}


def _tensor_cp(p: dict) -> None:
    dec = p["model"]["field"]["TensorialField"]["decomposition"]
    dec["tensor_cp"] = dec.pop("tensor_vm")
    p["model"]["regularizers"] = {"tensor_l1": {"weight": 0.0005}}


def _dynamic_nerf(p: dict) -> None:
    """A dynamic NeRF: every field wrapper, a pixel map, every schedule hook, custom members of each."""
    p["scene"]["timestamps"] = True
    p["model"]["field_wrappers"] = {"camera_time_offset": {}, "deformation": {"num_layers": 4},
                                    "frame_codes": {"dim": 8}, "time_embedding": {}, "field_blend": {"mode": "mixer"},
                                    "custom": CUSTOM, "custom_flow": CUSTOM}
    p["pixel_sampler"] = {"gradient_importance": {"uniform_fraction": 0.25}}
    p["model"]["schedule_hooks"] = {"anneal": {"target": "deformation.window"}, "freeze": {"module": "deformation"},
                                    "image_curriculum": {"rule": "keyframes"}, "custom_stage": CUSTOM}


VALID: dict[str, dict] = {
    **{f"reference {n}": ref(n) for n in ["instant-ngp", "kplanes-static", "mipnerf", "nerfacto", "tensorf",
                                          "vanilla-nerf"]},
    "dynamic k-planes": mutate("kplanes-static", _dynamic_kplanes),
    "tensorf CP with L1": mutate("tensorf", _tensor_cp),
    "charbonnier and entropy": mutate("nerfacto", lambda p: (
        p["model"]["losses"].update(rgb={"charbonnier": {"eps": 0.001}}),
        p["model"].update(regularizers={"ray_entropy": {"weight": 0.001}, "density_sparsity": {}}))),
    "SE3 camera optimiser, multistep schedule": mutate("nerfacto", lambda p: (
        p["model"].update(camera_optimizer={"se3": {}}),
        p["optimizers"]["fields"].update(scheduler={"multistep": {"milestones": [100, 200], "gamma": 0.5}}))),
    "no scheduler, defaults only": mutate("vanilla-nerf", lambda p: (
        p.update(trainer={}, datamanager={}), p["optimizers"]["fields"].pop("scheduler", None))),
    "L1 loss, triplane": mutate("kplanes-static", lambda p: (
        p["model"]["losses"].update(rgb={"l1": {}}), p["model"].pop("regularizers"),  # plane_tv reads k-planes
        field(p).update(pos_encoding={"triplane": {"resolution": 64, "num_components": 16}}))),
    "no regulariser set at all": mutate("kplanes-static", lambda p: p["model"].pop("regularizers")),
    "integral float for an int": mutate("nerfacto", lambda p: p["trainer"].update(max_num_iterations=100.0)),
    "random Fourier features": mutate("vanilla-nerf", lambda p: field(p).update(
        pos_encoding={"fourier_features": {"num_frequencies": 128, "scale": 10.0}})),
    "custom colour head, position encoding and loss": mutate("vanilla-nerf", lambda p: (
        field(p).update(rgb_head={"custom": {**CUSTOM, "params": {"width": 32, "sizes": [1, 2]}}},
                        pos_encoding={"custom": {**CUSTOM, "input_domain": "unit"}}),
        p["model"]["losses"].update(rgb={"custom": CUSTOM}))),
    "custom regularisers, renderer, density head, backbone": mutate("nerfacto", lambda p: (
        p["model"].update(regularizers={"ray_entropy": {}, "custom": {**CUSTOM, "weight": 0.5},
                                        "custom_memory": {**CUSTOM, "weight": 0.1}},
                          renderer={"custom": CUSTOM}),
        field(p).update(density_head={"custom": CUSTOM}, backbone={"custom": CUSTOM}))),
    "custom field and importance sampler": mutate("vanilla-nerf", lambda p: p["model"].update(
        field={"custom": CUSTOM}, sampler={"custom": CUSTOM})),
    "dynamic NeRF: field wrappers, pixel map, schedule hooks": mutate("vanilla-nerf", _dynamic_nerf),
    "two static fields blended by density, views chosen by a rule": mutate("nerfacto", lambda p: (
        p["model"].update(field_wrappers={"field_blend": {}}),
        p.update(pixel_sampler={"view_selection": {"rule": "first_n", "n": 3}}))),
    "custom pixel map and custom field wrapper": mutate("mipnerf", lambda p: (
        p["model"].update(field_wrappers={"custom": CUSTOM}), p.update(pixel_sampler={"custom": CUSTOM}))),
    "separate density and colour branches, inputs at every layer": mutate("vanilla-nerf", lambda p: field(p)[
        "backbone"].update(skip_every_layer=True, branches=True, density_layers=2, color_width=64)),
}

# (rule the violation must name, plan)
INVALID: dict[str, tuple[str, dict]] = {
    "unknown slot": ("unknown_slot", mutate("nerfacto", lambda p: p["model"].update(shader={}))),
    "missing slot": ("missing_slot", mutate("nerfacto", lambda p: p["model"].pop("renderer"))),
    "two alternatives": ("choice_arity", mutate("vanilla-nerf", lambda p: p["model"]["sampler"].update(
        proposal={}))),
    "unknown production": ("unknown_alternative", mutate("nerfacto", lambda p: field(p).update(
        pos_encoding={"wavelet_features": {}}))),
    "unknown base": ("unknown_alternative", mutate("nerfacto", lambda p: p.update(base="nerf-w"))),
    "unknown regulariser": ("unknown_member", mutate("kplanes-static", lambda p: p["model"]["regularizers"].update(
        magic_tv={}))),
    "unknown optimiser group": ("unknown_member", mutate("nerfacto", lambda p: p["optimizers"].update(
        temporal_distortion=p["optimizers"]["fields"]))),
    "unknown parameter": ("unknown_param", mutate("nerfacto", lambda p: field(p)["pos_encoding"]["hash"].update(
        num_levelz=8))),
    "string for an int": ("param_type", mutate("nerfacto", lambda p: field(p)["pos_encoding"]["hash"].update(
        num_levels="16"))),
    "int for a bool": ("param_type", mutate("nerfacto", lambda p: p["trainer"].update(mixed_precision=1))),
    "bad enum value": ("param_type", mutate("nerfacto", lambda p: p["model"]["renderer"].update(background="pink"))),
    "int for a list": ("param_type", mutate("nerfacto", lambda p: p["model"]["sampler"]["proposal"].update(
        samples_per_ray=64))),
    "non-integral float for an int": ("param_type", mutate("nerfacto", lambda p: p["trainer"].update(
        max_num_iterations=10.5))),
    "int out of range": ("param_range", mutate("nerfacto", lambda p: field(p)["pos_encoding"]["hash"].update(
        log2_hashmap_size=30))),
    "list item out of range": ("param_range", mutate("kplanes-static", lambda p: field(p)["pos_encoding"][
        "kplanes"].update(resolutions=[1, 64]))),
    "negative learning rate": ("param_range", mutate("nerfacto", lambda p: p["optimizers"]["fields"]["optimizer"][
        "adam"].update(lr=-0.01))),
    "empty list": ("param_length", mutate("nerfacto", lambda p: p["model"]["sampler"]["proposal"].update(
        samples_per_ray=[]))),
    "terminal params not a mapping": ("terminal_params", mutate("nerfacto", lambda p: p["model"]["losses"].update(
        rgb={"l2": None}))),
    "sampler of another base": ("requires_base", mutate("nerfacto", lambda p: p["model"].update(
        sampler={"occupancy_grid": {}}))),
    "IPE without Mip-NeRF's loop": ("requires_base", mutate("vanilla-nerf", lambda p: field(p).update(
        pos_encoding={"integrated_positional": {}}))),
    "proposal without interlevel": ("requires_loss", mutate("nerfacto", lambda p: p["model"]["losses"].pop(
        "interlevel"))),
    "contraction on a bounded scene": ("requires_scene", mutate("nerfacto", lambda p: p["scene"].update(
        bounded=True))),
    "time encoding without timestamps": ("requires_scene", mutate("kplanes-static", lambda p: field(p).update(
        pos_encoding={"kplanes_time": {}}))),
    "plane TV without planes": ("requires_terminal", mutate("kplanes-static", lambda p: field(p).update(
        pos_encoding={"hash": {}}))),
    "interlevel without proposals": ("requires_terminal", mutate("vanilla-nerf", lambda p: p["model"][
        "losses"].update(interlevel={}))),
    "near/far on a base without them": ("requires_base", mutate("vanilla-nerf", lambda p: p["model"].update(
        bounds={"near_plane": 2.0}))),
    "TensoRF needs a tensorial field": ("requires_terminal", mutate("tensorf", lambda p: p["model"].update(
        field=ref("vanilla-nerf")["model"]["field"]))),
    "missing optimiser group": ("param_groups", mutate("nerfacto", lambda p: p["optimizers"].pop(
        "proposal_networks"))),
    "optimiser for a group the model lacks": ("param_groups", mutate("nerfacto", lambda p: p["model"].pop(
        "camera_optimizer"))),
    "bad method name": ("method_name", mutate("nerfacto", lambda p: p.update(method="Nerfacto Ref"))),
    "annotation of the wrong type": ("annotation", mutate("nerfacto", lambda p: p.update(evidence=["a quote"]))),
    "custom component outside the plugin": ("custom_component", mutate("nerfacto", lambda p: field(p).update(
        rgb_head={"custom": {**CUSTOM, "module": "os.path"}}) or field(p)["rgb_head"]["custom"].update(
        module="nerfstudio.fields"))),
    "custom class not an identifier": ("custom_component", mutate("nerfacto", lambda p: field(p).update(
        rgb_head={"custom": {**CUSTOM, "class": "__import__('os')"}}))),
    "custom with an unknown key": ("unknown_param", mutate("nerfacto", lambda p: field(p).update(
        rgb_head={"custom": {**CUSTOM, "code": "print(1)"}}))),
    "custom params not a mapping of names": ("param_type", mutate("nerfacto", lambda p: field(p).update(
        rgb_head={"custom": {**CUSTOM, "params": {"not a name": 1}}}))),
    "custom sampler on a proposal base": ("requires_base", mutate("nerfacto", lambda p: (
        p["model"].update(sampler={"custom": CUSTOM}), p["model"]["losses"].pop("interlevel"),
        p["model"]["losses"].pop("distortion"), p["optimizers"].pop("proposal_networks")))),
    "custom regulariser with a bad key": ("unknown_member", mutate("nerfacto", lambda p: p["model"].update(
        regularizers={"customs": CUSTOM}))),
    "a deformation without timestamps": ("requires_scene", mutate("vanilla-nerf", lambda p: p["model"].update(
        field_wrappers={"deformation": {}}))),
    "frame codes on a static scene beside a blend": ("requires_scene", mutate("nerfacto", lambda p: p["model"].update(
        field_wrappers={"field_blend": {}, "frame_codes": {}}))),
    "a field wrapper around a tensorial field": ("requires_terminal", mutate("tensorf", lambda p: p["model"].update(
        field_wrappers={"field_blend": {}}))),
    "a custom field wrapper around a tensorial field": ("requires_terminal", mutate("tensorf", lambda p: p[
        "model"].update(field_wrappers={"custom_warp": CUSTOM}))),
    "unknown field wrapper": ("unknown_member", mutate("vanilla-nerf", lambda p: p["model"].update(
        field_wrappers={"optical_flow": {}}))),
    "unknown pixel sampler": ("unknown_alternative", mutate("vanilla-nerf", lambda p: p.update(
        pixel_sampler={"patches": {}}))),
    "curriculum with a key-frame stride of 0": ("param_range", mutate("vanilla-nerf", lambda p: p["model"].update(
        schedule_hooks={"image_curriculum": {"keyframe_stride": 0}}))),
    "branch width out of range": ("param_range", mutate("vanilla-nerf", lambda p: field(p)["backbone"].update(
        branches=True, density_width=4))),
}


@pytest.mark.parametrize("name", list(VALID))
def test_valid_plans_are_accepted_by_validate_schema_and_gbnf(name, schema, gbnf):
    plan = VALID[name]
    assert check(plan) == []
    assert schema.is_valid(plan), [e.message for e in schema.iter_errors(plan)][:3]
    assert gbnf.accepts(canonical_json(plan))


@pytest.mark.parametrize("name", list(INVALID))
def test_invalid_plans_are_rejected_naming_the_rule_and_by_both_exports(name, schema, gbnf):
    rule, plan = INVALID[name]
    violations = check(plan)
    assert violations, f"{name} was accepted"
    assert rule in {v.rule for v in violations}, [str(v) for v in violations]
    with pytest.raises(PlanError) as info:
        validate(plan)
    assert str(violations[0]) in str(info.value)
    assert not schema.is_valid(plan)
    assert not gbnf.accepts(canonical_json(plan))


def test_every_duty_and_rule_of_the_grammar_is_exercised():
    """The corpus covers every duty kind and every structural rule, so each is tested both ways."""
    g = load_grammar()
    duty_kinds = {next(iter(d)) for t in g.terminals.values() for d in t.duties}
    covered = {rule for rule, _ in INVALID.values()}
    assert duty_kinds <= covered
    assert {"unknown_slot", "missing_slot", "choice_arity", "unknown_alternative", "unknown_member", "unknown_param",
            "param_type", "param_range", "param_length", "param_groups"} <= covered


def test_violation_message_names_production_and_rule():
    _, plan = INVALID["proposal without interlevel"]
    v = check(plan)[0]
    assert (v.path, v.production, v.rule) == ("model.sampler.proposal", "proposal", "requires_loss")
    assert "model.losses.interlevel" in v.message


def test_float_upper_bounds_are_left_to_validate_by_the_gbnf(schema, gbnf):
    """Documented limit of the GBNF export: a float's range is enforced for its sign only."""
    plan = mutate("nerfacto", lambda p: p["optimizers"]["fields"]["optimizer"]["adam"].update(lr=20.0))
    assert [v.rule for v in check(plan)] == ["param_range"]
    assert not schema.is_valid(plan)
    assert gbnf.accepts(canonical_json(plan))


@pytest.mark.parametrize("lo,hi", [(0, 9), (1, 32), (2, 8192), (8, 26), (1, 10_000_000), (37, 412), (100, 100)])
def test_gbnf_integer_ranges_are_exact(lo, hi):
    g = GbnfGrammar(f"root ::= {int_range(lo, hi)}")
    probes = {lo, hi, lo - 1, hi + 1, (lo + hi) // 2, 0, 10, 99, 100, 101, 999, 1000, 4096, 9999, 10_000_001}
    for n in sorted(p for p in probes if p >= 0):
        assert g.accepts(str(n)) == (lo <= n <= hi), n
    assert not g.accepts(f"0{lo}")  # no leading zeros in canonical JSON


def test_gbnf_recogniser_handles_repetition_and_classes():
    g = GbnfGrammar('root ::= "a" [b-d]{2,3} x?\nx ::= ("," [^,])+')
    assert g.accepts("abc") and g.accepts("abcd,e,f")
    assert not g.accepts("ab") and not g.accepts("abcdb") and not g.accepts("abc,")
    with pytest.raises(GbnfSyntaxError):
        GbnfGrammar("root ::= missing-rule")


def test_reference_plans_are_derivations():
    for name in reference_plans():
        derivation = validate(load_reference_plan(name))
        assert derivation.choices["base"] == load_reference_plan(name)["base"]


def test_a_skip_connection_into_the_last_layer_is_refused():
    """Found by the grammar fuzzer: Nerfstudio's MLP takes no skip connection into its last layer, so a plan
    with one composed a backbone that could not run (a matrix shape error in the contract rung)."""
    plan = mutate("vanilla-nerf", lambda p: field(p).update(
        backbone={"num_layers": 4, "layer_width": 64, "skip_connections": [3]}))
    assert [v.rule for v in check(plan)] == ["param_constraint"]
    plan = mutate("vanilla-nerf", lambda p: field(p).update(
        backbone={"num_layers": 4, "layer_width": 64, "skip_connections": [2]}))
    assert check(plan) == []


def test_a_last_sample_background_with_packed_samples_is_refused():
    """Found by the grammar fuzzer: Nerfstudio's renderer cannot composite on the 'last_sample' background
    with instant-ngp's packed samples (NotImplementedError in a training step)."""
    plan = mutate("instant-ngp", lambda p: p["model"]["renderer"].update(background="last_sample"))
    assert [v.rule for v in check(plan)] == ["param_constraint"]
    plan = mutate("nerfacto", lambda p: p["model"]["renderer"].update(background="last_sample"))
    assert check(plan) == []
