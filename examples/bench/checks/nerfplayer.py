"""Checks of NeRFPlayer (Song et al. 2023) items: reference functions written from the paper, run against the
generated component (a typed field wrapper of the plan, built from the paper's sentences)."""

import _refs  # checks/_refs.py: the check's folder is on sys.path in the check process
import torch


def decomposition(target):
    """Sec. 3.2: the scene is decomposed into static, deforming and new areas, each with its own field; a
    decomposition field gives every sample the probabilities (P_static, P_deform, P_new) of belonging to each
    (a softmax), and the sample's density and colour are the probability-weighted sums of the three fields'."""
    from nerfify_ns.components.field_wrappers import FieldBlend

    params = (_refs.as_derived(target) or {}).get("field_blend")
    assert params, "no blend of fields in the plan"
    assert params["num_fields"] == 3, f"{params['num_fields']} fields, the paper's static, deforming and new"
    assert params["mode"] == "mixer", \
        f"blended by {params['mode']}, the paper by the decomposition field's probabilities"
    blend = FieldBlend(num_fields=3, mode="mixer", mixer_width=params["mixer_width"],
                       mixer_layers=params["mixer_layers"]).double()
    g = torch.Generator().manual_seed(0)
    x, t = torch.rand(6, 3, generator=g, dtype=torch.float64), torch.rand(6, 1, generator=g, dtype=torch.float64)
    sigma = torch.rand(6, 3, 1, generator=g, dtype=torch.float64) * 3
    rgb = torch.rand(6, 3, 3, generator=g, dtype=torch.float64)
    p = blend.weights(x, t)
    torch.testing.assert_close(p.sum(-1), torch.ones(6, dtype=torch.float64))
    assert (p >= 0).all()
    density, colour = blend(sigma, rgb, x, t)
    torch.testing.assert_close(density, (p[..., None] * sigma).sum(1))
    torch.testing.assert_close(colour, (p[..., None] * rgb).sum(1))


def deformation_field(target):
    """Sec. 3.2 (after D-NeRF): the deforming area's field is queried at a canonical position x + Delta x(x, t),
    Delta x predicted by a deformation network from the position and the time: the plan's deformation moves
    samples by a learned offset that depends on t and keeps the time."""
    from nerfify_ns.components.field_wrappers import DeformationNetwork

    params = (_refs.as_derived(target) or {}).get("deformation")
    assert params, "no deformation into a canonical space in the plan"
    net = DeformationNetwork(**params).double()
    torch.nn.init.normal_(net.network[-1].weight, std=0.1)  # trained weights: the offset is no longer zero
    g = torch.Generator().manual_seed(0)
    x = torch.rand(5, 3, generator=g, dtype=torch.float64)
    cams = torch.zeros(5, dtype=torch.long)
    moved_a, t_a, _ = net(x, torch.full((5, 1), 0.3, dtype=torch.float64), cams)
    moved_b, _, _ = net(x, torch.full((5, 1), 0.7, dtype=torch.float64), cams)
    assert moved_a.shape == x.shape and torch.equal(t_a, torch.full((5, 1), 0.3, dtype=torch.float64))
    assert not torch.allclose(moved_a, moved_b), "the offset does not depend on the time"
    assert not torch.allclose(moved_a, x), "the samples are not moved"


def parsimony_loss(target):
    """Sec. 3.4: L_reg = alpha * mean(P_deform) + mean(P_new), alpha = 0.01, weighted lambda = 0.1 in
    L = L_rec + lambda L_reg: the decomposition field's probabilities of the deforming and the new area (its second
    and third outputs), averaged over the samples. The compiled regulariser against it in float64, on a blend's
    shares of each sample (a softmax over the three fields), and its weight in the objective."""
    assert target.cls is not None, "no compiled regulariser implements the parsimony loss"
    loss = target.cls().double()
    g = torch.Generator().manual_seed(0)
    sigma = torch.rand(4, 12, 1, generator=g, dtype=torch.float64)
    delta = torch.rand(4, 12, 1, generator=g, dtype=torch.float64) * 0.2 + 0.01
    p = torch.softmax(torch.randn(4, 12, 3, generator=g, dtype=torch.float64), dim=-1)
    got = float(loss(densities=sigma, deltas=delta, weights=p))
    want = float(0.01 * p[..., 1].mean() + p[..., 2].mean())
    assert abs(got - want) < 1e-9 * max(1.0, abs(want)), f"the regulariser gives {got}, the parsimony loss {want}"
    entry = target.value if isinstance(target.value, dict) else {}
    assert entry.get("weight") == 0.1, f"weighted {entry.get('weight')} in the objective, the paper's lambda 0.1"
