"""nerfify_ns.components against plain loop references (forward and gradients) and at the extremes."""

from __future__ import annotations

import itertools
import math

import pytest
import torch

from nerfify_ns.components import (
    CharbonnierLoss,
    KPlanesDensityField,
    MultiScaleKPlanes,
    charbonnier_loss,
    density_sparsity,
    plane_l1_to_one,
    plane_tv,
    ray_entropy,
    time_smoothness,
)

ATOL = 1e-6
RTOL = 1e-5


def close(a, b, atol=ATOL, rtol=RTOL):
    torch.testing.assert_close(a, b.to(a.dtype), atol=atol, rtol=rtol)


def grads(out, inputs):
    return torch.autograd.grad(out, inputs, allow_unused=False)


def all_finite(*tensors):
    return all(bool(torch.isfinite(t).all()) for t in tensors)


# ---------------------------------------------------------------- references (explicit indexing)
def ref_bilinear(plane, u, v):
    """plane [1, C, H, W]; u indexes W, v indexes H; coordinates in [-1, 1], align_corners=True, border."""
    _, _, h, w = plane.shape
    x = ((u + 1) / 2 * (w - 1)).clamp(0, w - 1)
    y = ((v + 1) / 2 * (h - 1)).clamp(0, h - 1)
    x0 = min(int(math.floor(float(x.detach()))), w - 1)
    y0 = min(int(math.floor(float(y.detach()))), h - 1)
    x1, y1 = min(x0 + 1, w - 1), min(y0 + 1, h - 1)
    fx, fy = x - x0, y - y0
    return (
        (1 - fx) * (1 - fy) * plane[0, :, y0, x0]
        + fx * (1 - fy) * plane[0, :, y0, x1]
        + (1 - fx) * fy * plane[0, :, y1, x0]
        + fx * fy * plane[0, :, y1, x1]
    )


def ref_kplanes(module, coords):
    """coords [N, d] in [-1, 1]; per point, per scale, per coordinate pair; product or sum; concat."""
    pairs = list(itertools.combinations(range(coords.shape[1]), 2))
    rows = []
    for n in range(coords.shape[0]):
        feats = []
        for planes in module.grids:
            acc = None
            for pair, plane in zip(pairs, planes, strict=False):
                value = ref_bilinear(plane, coords[n, pair[0]], coords[n, pair[1]])
                if acc is None:
                    acc = value
                else:
                    acc = acc * value if module.reduce == "product" else acc + value
            feats.append(acc)
        rows.append(torch.cat(feats))
    return torch.stack(rows)


def ref_plane_tv(planes):
    total = 0.0
    for p in planes:
        _, c_n, h, w = p.shape
        sh = sum(
            (p[0, c, i, j] - p[0, c, i - 1, j]) ** 2
            for c in range(c_n)
            for i in range(1, h)
            for j in range(w)
        )
        sw = sum(
            (p[0, c, i, j] - p[0, c, i, j - 1]) ** 2
            for c in range(c_n)
            for i in range(h)
            for j in range(1, w)
        )
        total = total + sh / (c_n * (h - 1) * w) + sw / (c_n * h * (w - 1))
    return total / len(planes)


def ref_time_smoothness(planes):
    total = 0.0
    for p in planes:
        _, c_n, t_n, s_n = p.shape
        s = sum(
            (p[0, c, t - 1, i] - 2 * p[0, c, t, i] + p[0, c, t + 1, i]) ** 2
            for c in range(c_n)
            for t in range(1, t_n - 1)
            for i in range(s_n)
        )
        total = total + s / (c_n * (t_n - 2) * s_n)
    return total / len(planes)


def ref_plane_l1(planes):
    total = 0.0
    for p in planes:
        _, c_n, h, w = p.shape
        total = total + sum(
            abs(1 - p[0, c, i, j]) for c in range(c_n) for i in range(h) for j in range(w)
        ) / (c_n * h * w)
    return total / len(planes)


def ref_ray_entropy(weights, threshold, eps=1e-10):
    terms, count = [], 0
    for r in range(weights.shape[0]):
        acc = sum(weights[r, i, 0] for i in range(weights.shape[1]))
        if float(acc.detach()) <= threshold:
            continue
        h = 0.0
        for i in range(weights.shape[1]):
            p = weights[r, i, 0] / (acc + eps)
            h = h - p * torch.log(p + eps)
        terms.append(h)
        count += 1
    return sum(terms) / max(count, 1)


def ref_sparsity(densities, scale):
    flat = densities.reshape(-1)
    return sum(torch.log(1 + flat[i] ** 2 / scale) for i in range(flat.numel())) / flat.numel()


def ref_charbonnier(pred, target, eps):
    flat_p, flat_t = pred.reshape(-1), target.reshape(-1)
    return (
        sum(torch.sqrt((flat_p[i] - flat_t[i]) ** 2 + eps**2) for i in range(flat_p.numel())) / flat_p.numel()
    )


# ---------------------------------------------------------------- k-planes
@pytest.mark.parametrize("reduce", ["product", "sum"])
@pytest.mark.parametrize("time_resolution", [None, 5])
def test_kplanes_matches_reference(reduce, time_resolution):
    torch.manual_seed(0)
    m = MultiScaleKPlanes(
        resolutions=[4, 7], num_components=3, reduce=reduce, time_resolution=time_resolution
    ).double()
    with torch.no_grad():  # random planes (time planes init to 1 would hide errors)
        for p in m.planes():
            p.uniform_(-1.0, 1.0)
    d = 3 if time_resolution is None else 4
    coords = torch.rand(9, d, dtype=torch.float64) * 2 - 1
    coords[0] = 1.0  # the border
    coords[1] = -1.0
    coords.requires_grad_(True)
    out = m(coords)
    ref = ref_kplanes(m, coords)
    assert out.shape == (9, 2 * 3)
    close(out, ref)
    w = torch.randn_like(out)
    g = grads((out * w).sum(), [coords, *m.planes()])
    g_ref = grads((ref * w).sum(), [coords, *m.planes()])
    for a, b in zip(g, g_ref, strict=False):
        close(a, b)


def test_kplanes_times_argument_maps_unit_interval():
    torch.manual_seed(1)
    m = MultiScaleKPlanes(resolutions=[4], num_components=2, time_resolution=6)
    with torch.no_grad():
        for p in m.planes():
            p.uniform_(0.0, 1.0)
    pos = torch.rand(5, 3) * 2 - 1
    t = torch.rand(5, 1)
    close(m(pos, t), m(torch.cat([pos, 2 * t - 1], dim=-1)))
    close(m(pos[None], t[None]), m(pos, t)[None])  # batch dims kept


def test_kplanes_shapes_init_and_plane_lists():
    m = MultiScaleKPlanes(resolutions=[8, 16, 32], num_components=5)
    assert m.get_out_dim() == 15 and m.in_dim == 3
    assert m(torch.zeros(2, 4, 3)).shape == (2, 4, 15)
    assert len(m.planes()) == 9 and len(m.spatial_planes) == 9 and m.time_planes == []
    for p, r in zip(m.planes(), [8] * 3 + [16] * 3 + [32] * 3, strict=False):
        assert p.shape == (1, 5, r, r)
        assert float(p.detach().min()) >= 0.1 and float(p.detach().max()) <= 0.5

    mt = MultiScaleKPlanes(resolutions=[8, 16], num_components=4, time_resolution=3)
    assert mt.in_dim == 4 and len(mt.planes()) == 12
    assert len(mt.spatial_planes) == 6 and len(mt.time_planes) == 6
    for p in mt.time_planes:
        assert p.shape[-2] == 3 and bool((p == 1).all())  # time on dim -2, initialised to 1
    for p in mt.spatial_planes:
        assert float(p.detach().min()) >= 0.1 and float(p.detach().max()) <= 0.5
    with pytest.raises(ValueError):
        mt(torch.zeros(4, 3))  # no time
    with pytest.raises(ValueError):
        m(torch.zeros(4, 3), torch.zeros(4, 1))  # static model given time
    with pytest.raises(ValueError):
        MultiScaleKPlanes(resolutions=[])


@pytest.mark.parametrize("time_resolution", [None, 4])
def test_kplanes_gradient_reaches_every_plane(time_resolution):
    torch.manual_seed(2)
    m = MultiScaleKPlanes(resolutions=[4, 8], num_components=3, time_resolution=time_resolution)
    pos, t = torch.rand(64, 3) * 2 - 1, torch.rand(64, 1)
    out = m(pos, t if time_resolution else None)
    gs = grads(out.square().sum(), m.planes())
    assert all(bool(g.abs().sum() > 0) and all_finite(g) for g in gs)


def test_kplanes_half_and_empty():
    m = MultiScaleKPlanes(resolutions=[4], num_components=2)
    assert m(torch.zeros(0, 3)).shape == (0, 2)
    out = m.half()(torch.rand(6, 3).half() * 2 - 1)
    assert out.dtype == torch.float16 and all_finite(out)


def _ray_bundle(n=6, near=0.05, far=4.0):
    from nerfstudio.cameras.rays import RayBundle

    torch.manual_seed(3)
    directions = torch.nn.functional.normalize(torch.randn(n, 3), dim=-1)
    origins = -2.5 * directions + 0.1 * torch.randn(n, 3)
    return RayBundle(
        origins=origins,
        directions=directions,
        pixel_area=torch.full((n, 1), 1e-4),
        camera_indices=torch.zeros(n, 1, dtype=torch.long),
        nears=torch.full((n, 1), near),
        fars=torch.full((n, 1), far),
    )


@pytest.mark.parametrize("contracted", [False, True])
def test_kplanes_density_field_in_proposal_sampler(contracted):
    from nerfstudio.field_components.field_heads import FieldHeadNames
    from nerfstudio.field_components.spatial_distortions import SceneContraction
    from nerfstudio.model_components.ray_samplers import ProposalNetworkSampler

    aabb = torch.tensor([[-1.5, -1.5, -1.5], [1.5, 1.5, 1.5]])
    distortion = SceneContraction(order=float("inf")) if contracted else None
    nets = [
        KPlanesDensityField(aabb, resolution=r, num_components=4, spatial_distortion=distortion)
        for r in (8, 16)
    ]
    sampler = ProposalNetworkSampler(
        num_proposal_samples_per_ray=(16, 12),
        num_nerf_samples_per_ray=8,
        num_proposal_network_iterations=2,
        single_jitter=True,
    )
    bundle = _ray_bundle(far=1e3 if contracted else 4.0)
    ray_samples, weights_list, samples_list = sampler(bundle, density_fns=[n.density_fn for n in nets])
    assert ray_samples.frustums.starts.shape == (6, 8, 1)
    assert [w.shape for w in weights_list] == [(6, 16, 1), (6, 12, 1)]
    assert all_finite(ray_samples.frustums.starts, *weights_list)
    loss = sum(w.sum() for w in weights_list)
    params = [p for n in nets for p in n.parameters()]
    assert all_finite(*torch.autograd.grad(loss, params, allow_unused=True))
    out = nets[0](samples_list[0])  # Field.forward: dict with the density
    assert out[FieldHeadNames.DENSITY].shape == (6, 16, 1) and bool((out[FieldHeadNames.DENSITY] >= 0).all())
    assert nets[0].density_fn(torch.zeros(5, 3)).shape == (5, 1)


def test_kplanes_density_field_matches_definition_and_time():
    from nerfstudio.field_components.activations import trunc_exp

    torch.manual_seed(4)
    aabb = torch.tensor([[-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]])
    f = KPlanesDensityField(aabb, resolution=8, num_components=4)
    pos = torch.rand(7, 3) * 3.8 - 1.9
    expected = trunc_exp(f.linear(f.encoding(pos / 2.0)))
    close(f.density_fn(pos), expected)
    outside = f.density_fn(torch.tensor([[3.0, 0.0, 0.0]]))
    assert float(outside.detach()) == 0.0
    assert len(f.planes()) == 3 and len(f.spatial_planes) == 3

    ft = KPlanesDensityField(aabb, resolution=8, num_components=4, time_resolution=5)
    dens = ft.density_fn(pos, times=torch.rand(7, 1))
    assert dens.shape == (7, 1) and all_finite(dens) and len(ft.time_planes) == 3


# ---------------------------------------------------------------- regularisers
def _planes(shapes, seed=5):
    g = torch.Generator().manual_seed(seed)
    return [torch.rand(s, generator=g, dtype=torch.float64).requires_grad_(True) for s in shapes]


@pytest.mark.parametrize(
    "fn, ref, shapes",
    [
        (plane_tv, ref_plane_tv, [(1, 2, 4, 5), (1, 3, 3, 3)]),
        (time_smoothness, ref_time_smoothness, [(1, 2, 5, 4), (1, 2, 3, 6)]),
        (plane_l1_to_one, ref_plane_l1, [(1, 2, 4, 5), (1, 1, 3, 2)]),
    ],
)
def test_plane_regularizers_match_reference(fn, ref, shapes):
    planes = _planes(shapes)
    with torch.no_grad():
        planes[0][0, 0, 0, 0] = 1.7  # |1 - p| on both sides of 1
    out, expected = fn(planes), ref(planes)
    close(out, expected)
    for a, b in zip(grads(out, planes), grads(expected, planes), strict=False):
        close(a, b)
    close(fn(planes[0]), ref(planes[:1]))  # a single tensor is accepted


def test_plane_regularizers_on_kplanes_and_extremes():
    m = MultiScaleKPlanes(resolutions=[4, 8], num_components=2, time_resolution=4).requires_grad_(False)
    assert float(time_smoothness(m.time_planes)) == 0.0 and float(plane_l1_to_one(m.time_planes)) == 0.0
    assert float(plane_tv(m.spatial_planes)) > 0.0
    for fn in (plane_tv, time_smoothness, plane_l1_to_one):
        assert float(fn([])) == 0.0
        tiny = torch.ones(1, 2, 1, 1, requires_grad=True)  # no neighbours at all
        out = fn([tiny])
        assert all_finite(out, *grads(out, [tiny]))
        half = torch.rand(1, 2, 4, 4).half().requires_grad_(True)
        out = fn([half])
        assert all_finite(out, *grads(out, [half]))


def test_ray_entropy_matches_reference():
    g = torch.Generator().manual_seed(6)
    weights = torch.rand(6, 5, 1, generator=g, dtype=torch.float64) * 0.4
    weights[1] = 0.0  # all-zero ray: masked
    weights[2] = 0.01  # accumulation 0.05 < threshold: masked
    weights[3, 2:] = 0.0  # zero weights inside a counted ray
    weights.requires_grad_(True)
    out, expected = ray_entropy(weights, threshold=0.1), ref_ray_entropy(weights, 0.1)
    close(out, expected)
    close(grads(out, [weights])[0], grads(expected, [weights])[0])
    close(ray_entropy(weights[..., 0], threshold=0.1), expected)  # [R, S] accepted
    # a one-hot ray has entropy 0; a uniform ray log(S)
    one_hot = torch.zeros(1, 4, 1)
    one_hot[0, 2] = 1.0
    assert abs(float(ray_entropy(one_hot).detach())) < 1e-6
    assert abs(float(ray_entropy(torch.full((1, 4, 1), 0.25))) - math.log(4)) < 1e-5


@pytest.mark.parametrize(
    "weights",
    [
        torch.zeros(4, 8, 1),
        torch.zeros(0, 8, 1),
        torch.full((3, 8, 1), 1e-30),
        torch.cat([torch.zeros(2, 8, 1), torch.rand(2, 8, 1)]),
        torch.rand(3, 8, 1) * 1e8,
        torch.rand(3, 8, 1).half(),
    ],
    ids=["zero", "empty", "tiny", "mixed", "huge", "half"],
)
def test_ray_entropy_is_finite(weights):
    w = weights.clone().requires_grad_(True)
    out = ray_entropy(w, threshold=0.1)
    assert out.dim() == 0 and all_finite(out, *grads(out, [w]))
    assert float(out.detach()) >= -1e-6


def test_density_sparsity_matches_reference():
    g = torch.Generator().manual_seed(7)
    dens = torch.rand(4, 6, 1, generator=g, dtype=torch.float64) * 3.0
    dens[0, 0] = 0.0
    dens.requires_grad_(True)
    for scale in (0.5, 2.0):
        out, expected = density_sparsity(dens, scale), ref_sparsity(dens, scale)
        close(out, expected)
        close(grads(out, [dens])[0], grads(expected, [dens])[0])


@pytest.mark.parametrize(
    "densities",
    [
        torch.zeros(3, 4, 1),
        torch.zeros(0, 4, 1),
        torch.full((3, 4, 1), 1e8),
        torch.full((2, 2, 1), 1e30),
        torch.tensor([[[0.0], [1e-3], [1e4], [1e8]]]),
        (torch.rand(3, 4, 1) * 6e4).half(),
    ],
    ids=["zero", "empty", "1e8", "1e30", "mixed", "half"],
)
def test_density_sparsity_is_finite(densities):
    d = densities.clone().requires_grad_(True)
    out = density_sparsity(d, scale=0.5)
    assert out.dim() == 0 and all_finite(out, *grads(out, [d])) and float(out.detach()) >= 0.0
    if densities.numel() and bool((densities == 1e8).all()):
        assert abs(float(out.detach()) - math.log1p(1e16 / 0.5)) < 1e-3


# ---------------------------------------------------------------- losses
def test_charbonnier_matches_reference():
    g = torch.Generator().manual_seed(8)
    pred = torch.rand(5, 3, generator=g, dtype=torch.float64).requires_grad_(True)
    target = torch.rand(5, 3, generator=g, dtype=torch.float64)
    for eps in (1e-3, 0.1):
        out, expected = charbonnier_loss(pred, target, eps=eps), ref_charbonnier(pred, target, eps)
        close(out, expected)
        close(grads(out, [pred])[0], grads(expected, [pred])[0])
    close(CharbonnierLoss(eps=0.1)(pred, target), ref_charbonnier(pred, target, 0.1))
    assert charbonnier_loss(pred, target, reduction="none").shape == (5, 3)
    close(charbonnier_loss(pred, target, reduction="sum"), ref_charbonnier(pred, target, 1e-3) * 15)


@pytest.mark.parametrize(
    "pred, target",
    [
        (torch.zeros(4, 3), torch.zeros(4, 3)),
        (torch.zeros(0, 3), torch.zeros(0, 3)),
        (torch.full((2, 3), 1e8), torch.zeros(2, 3)),
        (torch.rand(4, 3).half(), torch.rand(4, 3).half()),
    ],
    ids=["equal", "empty", "huge", "half"],
)
def test_charbonnier_is_finite(pred, target):
    p = pred.clone().requires_grad_(True)
    out = charbonnier_loss(p, target)
    assert out.dim() == 0 and all_finite(out, *grads(out, [p]))
    if pred.numel() and bool((pred == target).all()):
        assert abs(float(out.detach()) - 1e-3) < 1e-7  # the floor is eps


def test_schedule_hooks_read_the_step_scale_at_every_call():
    """A budgeted run's schedule scale may be lowered while it trains (the pace follows a slower run): the hooks'
    callbacks read the model config's ``schedule_step_scale`` at each call, not once when they were made."""
    from torch import nn

    from nerfify_ns.components.schedule_hooks import Anneal, training_callbacks

    class Part(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.window = 0.0

    class Config:
        schedule_step_scale = 0.1

    model = nn.Module()
    model.deformation = Part()
    model.config = Config()
    (callback,) = training_callbacks([Anneal(target="deformation.window", end_value=10.0, end_step=1000)], model, None)
    callback.run_callback(step=20)  # paper step 200 of 1,000
    assert model.deformation.window == pytest.approx(2.0)
    model.config.schedule_step_scale = 0.05
    callback.run_callback(step=20)  # paper step 400
    assert model.deformation.window == pytest.approx(4.0)


def _window_reference(alpha: float, k: int) -> float:
    """Nerfies Eq. 9 (Park et al. 2021), from the paper: w_k(alpha) = (1 - cos(pi clamp(alpha - k, 0, 1))) / 2."""
    return (1 - math.cos(math.pi * min(max(alpha - k, 0.0), 1.0))) / 2


@pytest.mark.parametrize("share", [0.0, 0.2, 0.5, 0.77, 1.0])
def test_coarse_to_fine_window_matches_the_paper_on_sinusoids_and_levels(share):
    from nerfstudio.field_components.encodings import HashEncoding, NeRFEncoding

    from nerfify_ns.components.encoding_window import CoarseToFine

    torch.manual_seed(0)
    x = torch.rand(7, 3, requires_grad=True)
    # sinusoids: L = 5 frequencies, alpha = share x L; sines then cosines, dimension-major; the raw input always on
    pe = CoarseToFine(NeRFEncoding(3, 5, 0.0, 4.0, include_input=True), 5, "sinusoids")
    pe.window.fill_(share)
    plain = pe.encoding(x)
    out = pe(x)
    for column in range(out.shape[-1]):
        weight = 1.0 if column >= 30 else _window_reference(share * 5, (column % 15) % 5)
        close(out[:, column], plain[:, column] * weight)
    # levels: L = 4 grid levels of 2 features, alpha = 1 + share x (L - 1): the coarsest level always on
    grid = CoarseToFine(HashEncoding(num_levels=4, features_per_level=2, log2_hashmap_size=8, min_res=2, max_res=16,
                                     implementation="torch"), 4, "levels")
    grid.window.fill_(share)
    plain, out = grid.encoding(x), grid(x)
    for column in range(8):
        close(out[:, column], plain[:, column] * _window_reference(1 + share * 3, column // 2))
    out.sum().backward()  # the gradient reaches the grid's table through the window
    assert grid.encoding.hash_table.grad is not None and torch.isfinite(grid.encoding.hash_table.grad).all()


def test_coarse_to_fine_window_refuses_a_layout_the_encoding_does_not_have():
    from nerfstudio.field_components.encodings import NeRFEncoding

    from nerfify_ns.components.encoding_window import CoarseToFine, band_of_columns

    with pytest.raises(ValueError, match="sines and cosines"):
        CoarseToFine(NeRFEncoding(3, 5, 0.0, 4.0, include_input=True), 4, "sinusoids")
    with pytest.raises(ValueError, match="do not split"):
        band_of_columns("levels", 3, 8)
    assert band_of_columns("levels", 4, 8).tolist() == [0, 0, 1, 1, 2, 2, 3, 3]
