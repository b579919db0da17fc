"""Space-time feature planes combined in pairs (a spatial plane times the space-time plane over the two other axes,
the products concatenated and projected by a learned basis), stated in a sentence of a paper of our own, built as
the space-time planes' typed option (``reduce: paired``); the component against the reference written from the
equation (values and gradients); a negated or unrelated sentence, or a static plan, builds nothing."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch
from prose_holes import assert_option_stated, build_hole

from nerfify_ns.components.kplanes import MultiScaleKPlanes
from nerfify_ns.plan import Plan
from nerfify_ns.registry import default_registry
from nerfify_ns.synthesis.novel import NOT_IMPLEMENTED
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.verify.components import run_terminal

SLOT = "model.field.MLPField.pos_encoding"
CHECKS = Path(__file__).resolve().parents[2] / "examples" / "bench" / "checks"


def _check_module():
    """The bench's reference for the paired planes (examples/bench/checks/hexplane.py), loaded by path."""
    import sys

    sys.path.insert(0, str(CHECKS))
    try:
        spec = importlib.util.spec_from_file_location("hexplane_check", CHECKS / "hexplane.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(CHECKS))


def _build(text: list[str], plan: Plan):
    return build_hole("PosEncoding", SLOT, text, plan)


@pytest.mark.parametrize("sentence", [
    "Our volume is made of three pairs of planes; each pair has a spatial and a spatio-temporal plane.",
    "The encoder multiplies the features read from paired planes and concatenates the three products.",
    "We take the product of complementary planes and concatenate the results before a learned basis.",
])
def test_a_sentence_stating_paired_planes_builds_the_option(sentence):
    plan = Plan.of(load_reference_plan("kplanes-time"))
    before = dict(plan.get(f"{SLOT}.kplanes_time"))
    result = _build(["Features of a point in space and time are read from learned planes.", sentence], plan)
    assert_option_stated(result, plan.get(f"{SLOT}.kplanes_time"), before, "plane_pairs", "kplanes_time", "reduce",
                         "paired", sentence)


@pytest.mark.parametrize("sentence", [
    "Unlike pairs of a spatial and a spatio-temporal plane, we multiply all six planes together.",
    "Each plane is read with bilinear interpolation and the features are multiplied.",
])
def test_no_statement_of_paired_planes_builds_nothing(sentence):
    plan = Plan.of(load_reference_plan("kplanes-time"))
    result = _build([sentence], plan)
    assert plan.get(f"{SLOT}.kplanes_time")["reduce"] == "product"
    assert result.status == NOT_IMPLEMENTED


def test_a_static_plan_refuses_the_option_with_its_reason():
    plan = Plan.of(load_reference_plan("kplanes-time"))
    plan.set(SLOT, {"kplanes": {"resolutions": [16, 32], "num_components": 8}})
    result = _build(["Each pair has a spatial and a spatio-temporal plane with orthogonal axes."], plan)
    assert plan.get(f"{SLOT}.kplanes") == {"resolutions": [16, 32], "num_components": 8}
    assert result.status == NOT_IMPLEMENTED
    assert "not the kplanes_time terminal" in result.reason


def test_the_component_matches_the_reference_of_the_equation():
    """The bench's check (written from the paper's Eq. 6 with its own bilinear reads) passes on the component, and
    fails on planes paired the wrong way (each spatial plane with a space-time plane sharing an axis)."""
    check = _check_module()

    class Target:
        value = {"kplanes_time": {"reduce": "paired"}}

    check.hexplane(Target())
    wrong = MultiScaleKPlanes.__init__

    def swapped(self, *args, **kwargs):
        wrong(self, *args, **kwargs)
        self.pairs = [(a, b) for a, b in zip([p for p, _ in self.pairs], [b for _, b in self.pairs][1:]
                                             + [self.pairs[0][1]], strict=True)]

    MultiScaleKPlanes.__init__ = swapped
    try:
        with pytest.raises(AssertionError):
            check.hexplane(Target())
    finally:
        MultiScaleKPlanes.__init__ = wrong


def test_every_plane_and_the_basis_receive_gradients():
    torch.manual_seed(0)
    enc = MultiScaleKPlanes(resolutions=[4, 6], num_components=3, reduce="paired", time_resolution=5)
    with torch.no_grad():
        for plane in enc.planes():
            plane.normal_()
    xyz = (torch.rand(16, 3) * 2 - 1).requires_grad_()
    out = enc(xyz, torch.rand(16, 1))
    assert out.shape == (16, enc.get_out_dim()) == (16, 6)
    out.square().sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in enc.parameters())
    assert xyz.grad is not None and torch.isfinite(xyz.grad).all()
    with pytest.raises(ValueError, match="space-time planes"):
        MultiScaleKPlanes(resolutions=[4], reduce="paired")


def test_the_terminal_keeps_its_contract_with_the_option():
    from nerfify_ns.runtime import activate

    activate(force=True)
    result = run_terminal(default_registry()["kplanes_time"],
                          {"resolutions": [8, 16], "num_components": 4, "reduce": "paired", "time_resolution": 6})
    assert result.status == "pass", result
