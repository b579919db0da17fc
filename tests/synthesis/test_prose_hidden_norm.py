"""A normalisation layer after each hidden layer, stated in a sentence of a paper of our own, built as the
backbone's typed option (``hidden_norm: layer``) with the record quoting the sentence; a negated statement builds
nothing; the composed plugin's field builds its backbone from the NormedMLP component (no training)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from prose_holes import assert_option_stated, build_hole

from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.novel import IMPLEMENTED
from nerfify_ns.synthesis.resources import load_reference_plan

SLOT = "model.field.MLPField.backbone"

_BUILD = textwrap.dedent('''
    import json, sys, torch
    from nerfify_ns.runtime import activate
    activate(force=True)  # offline: LPIPS from local weights only
    from nerfify_ns.benchmarks.step_timing import build_model, ray_batch
    from nerfify_ns.synthesis.plugin_lookup import load_plugin_method

    config = load_plugin_method(sys.argv[1]).config
    config.pipeline.model.eval_num_rays_per_chunk = 64
    model = build_model(config, seed=0)
    model.train(True)
    bundle, _ = ray_batch(32)
    outputs = model.get_outputs(bundle)
    rgb = torch.cat([v for k, v in outputs.items() if k.startswith("rgb")], dim=-1)  # coarse and fine
    rgb.sum().backward()
    norms = [m for m in model.modules() if isinstance(m, torch.nn.LayerNorm)]
    print(json.dumps({"norms": len(norms), "finite": bool(torch.isfinite(rgb).all()),
                      "norm_grads": all(m.weight.grad is not None and m.weight.grad.abs().sum() > 0
                                        for m in norms)}))
''')


def _build(text: list[str], plan: Plan):
    return build_hole("Backbone", SLOT, text, plan)


@pytest.mark.parametrize("sentence", [
    "After each fully-connected layer of the backbone we apply layer normalization.",
    "We use LayerNorm after every hidden layer of the MLP to stabilise training.",
    "Every linear layer of the network is followed by a layer normalisation.",
])
def test_a_sentence_stating_a_norm_after_each_layer_builds_hidden_norm(sentence):
    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    before = dict(plan.get(SLOT))
    result = _build(["The backbone maps the encoded positions to features.", sentence], plan)
    assert_option_stated(result, plan.get(SLOT), before, "hidden_layer_norm", "mlp", "hidden_norm", "layer", sentence)


@pytest.mark.parametrize("sentence", [
    "Unlike prior work, we do not use layer normalization after each layer.",
    "We apply layer normalization to the input coordinates.",
])
def test_no_statement_of_a_norm_after_each_layer_builds_nothing(sentence):
    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    _build([sentence], plan)
    assert plan.get(SLOT).get("hidden_norm", "none") == "none"


def _normed_plugin(tmp_path):
    from nerfify_ns.grammar import validate
    from nerfify_ns.synthesis.compose import compose

    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    _build(["After each fully-connected layer of the backbone we apply layer normalization."], plan)
    plan["method"] = "normed-backbone"
    plan.get(SLOT).update({"num_layers": 3, "layer_width": 32, "skip_connections": [1]})  # small, as stated
    plan.set("model.field.MLPField.pos_encoding", {"positional": {"num_frequencies": 4, "max_freq_exp": 3.0}})
    plan.set("model.field.MLPField.rgb_head", {"num_layers": 1, "layer_width": 16})
    plan.set("model.sampler.hierarchical", {"num_coarse_samples": 8, "num_importance_samples": 8})
    validate(plan)
    return plan, compose(plan, tmp_path / "normed", record=False)


def test_the_composed_field_uses_the_normed_component(tmp_path):
    from nerfify_ns.synthesis.compose import compose

    _, plugin = _normed_plugin(tmp_path)
    pkg = plugin.package
    field = (plugin.out / pkg / "field.py").read_text()
    assert "from .components.mlp_normed import NormedMLP" in field
    assert "self.backbone = NormedMLP(" in field and "out_activation=nn.ReLU()" in field
    component = plugin.out / pkg / "components" / "mlp_normed.py"
    assert component.is_file() and "nn.LayerNorm" in component.read_text()
    plain = compose(Plan.of(load_reference_plan("vanilla-nerf")), tmp_path / "plain", record=False)
    assert "NormedMLP" not in (plain.out / plain.package / "field.py").read_text()


@pytest.mark.slow
def test_the_generated_model_renders_through_the_norms(tmp_path):
    """Built in a subprocess (generated code is untrusted): one norm per hidden layer in the coarse and the fine
    field, finite colours, and every norm's gain receives a gradient."""
    plan, plugin = _normed_plugin(tmp_path)
    out = subprocess.run([sys.executable, "-c", _BUILD, str(plugin.out)], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["finite"] and result["norm_grads"]
    assert result["norms"] == 2 * plan.get(SLOT)["num_layers"]


GHNERF = Path(__file__).resolve().parents[2].parent / "shared" / "papers" / "gh_nerf" / "gh_nerf.pdf"


def test_a_real_papers_layer_normalisation_is_built():
    """GH-NeRF states "we use Layer Normalization after each fully-connected layer": its Backbone hole is the
    option, quoting the sentence."""
    if not GHNERF.is_file():
        pytest.skip(f"real paper {GHNERF} not present (../shared/papers is outside the project and never committed)")
    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.novel import implement_holes
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    doc = ingest(GHNERF)
    result = implement_holes(doc, plan_from_paper(doc).plan)
    assert result.plan.get(SLOT)["hidden_norm"] == "layer"
    record = next(r for r in result.records if r.production == "Backbone")
    assert record.status == IMPLEMENTED
    part = next(p for p in record.parts if p["part"] == "hidden_layer_norm")
    assert "Layer Normalization after each fully-connected layer" in part["statement"]["quote"]
