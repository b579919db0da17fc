"""A plan with a `custom` component: a colour head written by hand, implementing the colour-head contract,
validates, composes and passes the ladder; the same plan whose component breaks the contract fails the
contract rung with a message naming the tensor, the expected and the actual shape."""

from __future__ import annotations

import subprocess
import sys

import pytest

from nerfify_ns.grammar import validate
from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.compose import CompositionError, compose, plugin_sources
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.verify import run_ladder

HEAD = '''"""A two-layer colour head with a sigmoid output, written by hand for the custom-component test."""

import torch
from torch import nn


class TinyColourHead(nn.Module):
    """rgb = sigmoid(W2 relu(W1 x + b1) + b2): the colour-head contract, [N, in_dim] -> [N, 3] in [0, 1]."""

    def __init__(self, in_dim: int, width: int = 32, channels: int = 3) -> None:
        super().__init__()
        self.hidden = nn.Linear(in_dim, width)
        self.out = nn.Linear(width, channels)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.out(torch.relu(self.hidden(features))))
'''
SOURCES = {"components.tiny_head": HEAD}


def custom_plan(channels: int = 3) -> Plan:
    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    plan["method"] = "custom-head"
    plan.set("model.field.MLPField.rgb_head", {"custom": {
        "module": "components.tiny_head", "class": "TinyColourHead", "params": {"width": 16, "channels": channels},
        "implements": ["Eq. 1"], "source": "hand", "evidence": "a test component written by hand"}})
    plan.set("model.field.MLPField.backbone", {"num_layers": 2, "layer_width": 32, "skip_connections": []})
    plan.set("model.sampler.hierarchical", {"num_coarse_samples": 8, "num_importance_samples": 8})
    plan.set("optimizers.fields", {"optimizer": {"adam": {"lr": 0.005, "eps": 1.0e-15}}})  # learns in 30 steps
    return plan


def test_custom_plan_validates_and_composes(tmp_path):
    plan = custom_plan()
    assert validate(plan).used["model.field.MLPField.rgb_head.custom"] == "custom"
    plugin = compose(plan, tmp_path / "plugin", sources=SOURCES, record=False)
    field = (plugin.out / "custom_head" / "field.py").read_text()
    assert "from .components.tiny_head import TinyColourHead" in field
    head = " ".join(field.split("self.rgb_head = ", 1)[1].split(")\n", 1)[0].split())
    assert head.startswith("TinyColourHead(") and "in_dim=self.direction_encoding.get_out_dim()" in head
    assert "width=16" in head
    assert (plugin.out / "custom_head" / "components" / "tiny_head.py").read_text() == HEAD
    readme = (plugin.out / "README.md").read_text()
    assert "custom_head.components.tiny_head.TinyColourHead" in readme and "a test component written by hand" in readme
    assert plugin_sources(plugin.out, plan) == SOURCES


def test_a_custom_module_without_source_is_refused(tmp_path):
    with pytest.raises(CompositionError, match="components.tiny_head"):
        compose(custom_plan(), tmp_path / "plugin", record=False)
    assert not (tmp_path / "plugin").exists()


def test_compose_command_takes_the_components_folder(tmp_path):
    """`ns-nerfify compose PLAN --components DIR`: the folder's `<name>.py` is the plan's `components.<name>`."""
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "tiny_head.py").write_text(HEAD)
    (tmp_path / "plan.yaml").write_text(custom_plan().dump())
    cmd = [sys.executable, "-m", "nerfify_ns.cli", "compose", str(tmp_path / "plan.yaml"), "--until", "plugin",
           "--out", str(tmp_path / "out")]
    missing = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert missing.returncode == 2 and "components.tiny_head" in missing.stdout + missing.stderr
    assert not (tmp_path / "out").exists()
    given = subprocess.run([*cmd, "--components", str(tmp_path / "parts")], capture_output=True, text=True,
                           timeout=300)
    assert given.returncode == 0, given.stdout + given.stderr
    assert (tmp_path / "out" / "custom_head" / "components" / "tiny_head.py").read_text() == HEAD


@pytest.mark.slow
def test_custom_colour_head_passes_every_rung(tmp_path, tiny_scene):
    plugin = compose(custom_plan(), tmp_path / "plugin", sources=SOURCES, record=False)
    report = run_ladder(plugin.out, scene=tiny_scene, out_dir=tmp_path / "verify", smoke_iterations=30,
                        repair="off")
    assert report.ok, [str(d) for d in report.failures]
    assert [r.name for r in report.rungs] == ["static", "contract", "stability", "smoke"]
    cases = report.rung("contract").details["cases"]
    assert any(c["component"].startswith("custom TinyColourHead") and c["status"] == "pass" for c in cases)


@pytest.mark.slow
def test_a_component_that_breaks_the_contract_fails_the_contract_rung(tmp_path):
    plugin = compose(custom_plan(channels=4), tmp_path / "plugin", sources=SOURCES, record=False)
    report = run_ladder(plugin.out, out_dir=tmp_path / "verify", rungs=["static", "contract"], repair="off")
    assert not report.ok and report.rung("static").status == "pass"
    contract = report.rung("contract")
    messages = [d.message for d in contract.failures if d.rule == "component-contract"]
    assert messages, [str(d) for d in contract.failures]
    assert "rgb: shape (64, 4), contract [N, 3] = (64, 3)" in messages[0]
