"""The backbone's normalisation after each hidden layer (``mlp``'s ``hidden_norm``): the component against a
hand-written Linear -> LayerNorm -> ReLU chain with Nerfstudio's skips (outputs and gradients), the terminal's
contract on the registry's harness with the option on, and the constraint that keeps it off the branched
backbone."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from nerfify_ns.components.mlp_normed import NormedMLP
from nerfify_ns.grammar import PlanError, validate
from nerfify_ns.plan import Plan
from nerfify_ns.registry import default_registry
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.verify.components import run_terminal


@pytest.fixture(scope="module", autouse=True)
def cpu_runtime():
    from nerfify_ns.runtime import activate

    activate(force=True)


def _reference(model: NormedMLP, x: torch.Tensor, skips: set[int], out_projection: bool) -> torch.Tensor:
    """Known-good torch ops on the model's own weights: per layer, concatenate the input before a skip layer,
    linear map, layer norm (mean and biased variance over the units, learned gain and bias), ReLU; the last layer
    is a bare projection when there is an output width."""
    h = x
    n = len(model.layers)
    for i, layer in enumerate(model.layers):
        if i in skips:
            h = torch.cat([x, h], dim=-1)
        h = h @ layer.weight.T + layer.bias
        if not (out_projection and i == n - 1):
            norm = model.norms[i]
            mean = h.mean(-1, keepdim=True)
            var = ((h - mean) ** 2).mean(-1, keepdim=True)
            h = (h - mean) / torch.sqrt(var + norm.eps) * norm.weight + norm.bias
        if i < n - 1:
            h = torch.clamp(h, min=0.0)
    return h


@pytest.mark.parametrize("out_dim", [None, 5])
def test_the_component_matches_a_hand_written_chain_with_gradients(out_dim):
    torch.manual_seed(0)
    model = NormedMLP(in_dim=7, num_layers=5, layer_width=12, out_dim=out_dim, skip_connections=(2, 3))
    with torch.no_grad():  # non-trivial gains and biases, so the check sees them
        for norm in model.norms:
            norm.weight.uniform_(0.5, 1.5)
            norm.bias.uniform_(-0.3, 0.3)
    assert len(model.norms) == (5 if out_dim is None else 4)
    assert all(isinstance(m, nn.LayerNorm) for m in model.norms)
    x = torch.randn(64, 7, requires_grad=True)
    out = model(x)
    assert out.shape == (64, 12 if out_dim is None else 5) and model.get_out_dim() == out.shape[-1]
    x_ref = x.detach().clone().requires_grad_(True)
    ref = _reference(model, x_ref, {2, 3}, out_projection=out_dim is not None)
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5)
    weights = torch.randn_like(out)
    params = list(model.parameters())
    grads = torch.autograd.grad((out * weights).sum(), [x, *params])
    grads_ref = torch.autograd.grad((ref * weights).sum(), [x_ref, *params])
    for g, g_ref in zip(grads, grads_ref, strict=True):
        torch.testing.assert_close(g, g_ref, rtol=1e-4, atol=1e-5)
    assert grads[0].abs().sum() > 0 and all(g.abs().sum() > 0 for g in grads[1:])


def test_each_hidden_layers_pre_activations_are_normalised():
    """Before each activation the units of every sample have zero mean and unit variance (gain 1, bias 0 at
    initialisation), whatever the input's scale."""
    torch.manual_seed(1)
    model = NormedMLP(in_dim=4, num_layers=3, layer_width=16, skip_connections=None)
    seen = []
    for norm in model.norms:
        norm.register_forward_hook(lambda m, i, o: seen.append(o.detach()))
    model(torch.randn(32, 4) * 1e3)
    assert len(seen) == 3
    for h in seen:
        torch.testing.assert_close(h.mean(-1), torch.zeros(32), atol=1e-4, rtol=0)
        torch.testing.assert_close(h.var(-1, unbiased=False), torch.ones(32), atol=1e-3, rtol=0)


def test_without_norms_the_layers_are_nerfstudios_mlp():
    """The same weights with the norms made the identity give Nerfstudio's MLP (skips and all)."""
    from nerfstudio.field_components.mlp import MLP

    torch.manual_seed(2)
    model = NormedMLP(in_dim=6, num_layers=4, layer_width=10, skip_connections=(2,))
    ns = MLP(in_dim=6, num_layers=4, layer_width=10, skip_connections=(2,), activation=nn.ReLU(),
             implementation="torch")
    ns.layers.load_state_dict(model.layers.state_dict())
    for i in range(len(model.norms)):
        model.norms[i] = nn.Identity()
    x = torch.randn(20, 6)
    torch.testing.assert_close(model(x), ns(x))


@pytest.mark.parametrize("case", ["nominal", "values_1e8", "empty_batch", "half"])
def test_the_terminal_with_hidden_norm_satisfies_its_contract(case):
    mlp = default_registry()["mlp"]
    assert mlp.param_specs["hidden_norm"].default == "none"
    params = {"hidden_norm": "layer", "skip_connections": [1]}
    assert mlp.small(params)["hidden_norm"] == "layer"  # the harness runs the option, not the default
    result = run_terminal(mlp, params, case)
    assert result.status == "pass", result.problems


def test_the_harness_builds_the_normed_component_only_when_asked():
    from nerfify_ns.registry.terminals.heads import SMALL, _build_backbone

    params = {**SMALL, "skip_connections": [1], "skip_every_layer": False, "branches": False}
    normed = _build_backbone({**params, "hidden_norm": "layer"}, {"in_dim": 8})
    plain = _build_backbone({**params, "hidden_norm": "none"}, {"in_dim": 8})
    assert isinstance(normed, NormedMLP) and not isinstance(plain, NormedMLP)
    assert not any(isinstance(m, nn.LayerNorm) for m in plain.modules())


def test_hidden_norm_is_refused_with_branches():
    plan = Plan.of(load_reference_plan("vanilla-nerf"))
    plan.get("model.field.MLPField.backbone")["hidden_norm"] = "layer"
    validate(plan)
    plan.get("model.field.MLPField.backbone")["branches"] = True
    plan.set("model.field.MLPField.density_head", {"density_linear": {"activation": "softplus"}})
    with pytest.raises(PlanError, match="hidden_norm"):
        validate(plan)
    plan.get("model.field.MLPField.backbone")["hidden_norm"] = "batch"
    plan.get("model.field.MLPField.backbone")["branches"] = False
    with pytest.raises(PlanError):
        validate(plan)
