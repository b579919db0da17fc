"""Checks of 4D Gaussian Splatting (Wu et al. 2024) items: reference functions written from the paper."""

import _refs  # checks/_refs.py: the check's folder is on sys.path in the check process
import torch


def structure_encoder(target):
    """Eq. 7: the spatial-temporal structure encoder: multi-resolution planes over (x, y), (x, z), (y, z), (x, t),
    (y, t), (z, t), each read by bilinear interpolation, the six features of a resolution multiplied (Hadamard)
    and the resolutions concatenated: six planes per resolution, combined by product."""
    from nerfify_ns.components.kplanes import MultiScaleKPlanes

    if target.path.startswith("model.field_wrappers.gaussian_deformation"):  # the encoder of the deformation field
        from nerfify_ns.components.field_wrappers import GaussianDeformation

        params = dict(target.plan["model"]["field_wrappers"]["gaussian_deformation"])
        assert params.get("encoding") == "planes", \
            f"the deformation reads {params.get('encoding', 'frequency')} encodings of x and t, Eq. 7 planes"
        params.update(plane_resolution=8, plane_features=2, time_resolution=5, num_layers=1, layer_width=4)
        enc = GaussianDeformation(**params).position_encoding
        assert isinstance(enc, MultiScaleKPlanes) and enc.reduce == "product", "planes not combined by product"
        assert len(enc.resolutions) == 2, f"{len(enc.resolutions)} resolutions, Eq. 7 has l in {{1, 2}}"
        enc = MultiScaleKPlanes(resolutions=[8], num_components=2, time_resolution=5, reduce=enc.reduce).double()
    else:
        v = _refs.as_derived(target)
        assert v.get("reduce") == "product", f"planes combined by {v.get('reduce')}, Eq. 7 by product"
        assert len(v["resolutions"]) >= 1 and v.get("time_resolution", 0) > 1, v
        enc = MultiScaleKPlanes(resolutions=[8], num_components=2, time_resolution=5, reduce=v["reduce"]).double()
    assert len(enc.plane_pairs) == 6, f"{len(enc.plane_pairs)} planes per resolution, Eq. 7 has six"
    values = [(k + 2) / 4 for k in range(6)]
    with torch.no_grad():
        for plane, value in zip(enc.grids[0], values, strict=True):
            plane.fill_(value)  # a constant plane reads its constant at every point (bilinear interpolation)
    x = torch.rand(5, 3, dtype=torch.float64) * 2 - 1
    got = enc(x, torch.rand(5, 1, dtype=torch.float64))
    want = torch.full((5, 2), float(torch.tensor(values).prod()), dtype=torch.float64)
    torch.testing.assert_close(got, want)


def l1_loss(target):
    """Eq. 9: the L1 colour loss, |C_hat - C| as a mean."""
    from nerfstudio.model_components.losses import L1Loss

    assert target.path.endswith(".l1"), f"colour loss at {target.path}, not L1"
    g = torch.Generator().manual_seed(0)
    pred, gt = torch.rand(32, 3, generator=g), torch.rand(32, 3, generator=g)
    torch.testing.assert_close(L1Loss()(pred, gt), (pred - gt).abs().mean())


def tv_loss(target):
    """Eq. 9: the grid-based total variation loss on the planes."""
    assert float(target.value.get("weight", 0)) > 0, "the TV loss has no weight"
    _refs.plane_tv()


def gaussian_deformation_field(target):
    """Sec. 4.2, Eq. 8: the multi-head decoder gives position, rotation and scaling offsets of each canonical
    Gaussian at time t (only one set of canonical Gaussians is kept)."""
    d3dgs = _refs.load("deformable_3dgs")
    d3dgs.deformation_of(d3dgs._part(target, "gaussian_deformation"))


def gaussian_warmup(target):
    """Sec. 4.3: "We optimize 3D Gaussians at initial 3000 iterations for warm-up"."""
    d3dgs = _refs.load("deformable_3dgs")
    d3dgs.warmup_of(d3dgs._part(target, "freeze"), 3000)


def gaussians(target):
    """Sec. 3.1 (3D-GS's Gaussians): the canonical Gaussians are what the deformation field moves."""
    _refs.load("deformable_3dgs").gaussians(target)
