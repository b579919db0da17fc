"""Checks of HexPlane (Cao and Johnson 2023) items: reference functions written from the paper."""

import _refs  # checks/_refs.py: the check's folder is on sys.path in the check process
import torch


def photometric_loss(target):
    """Eq. 7: the mean squared error between rendered and observed colours."""
    assert target.path.endswith(".l2") or "l2" in (target.value or {}), f"colour loss {target.value}, not L2"
    _refs.mse(torch.nn.MSELoss())


def plane_tv(target):
    """Sec. 3.3: a total variation loss on the planes (squared differences of neighbouring cells)."""
    assert float(target.value.get("weight", 0)) > 0, "the TV loss has no weight"
    _refs.plane_tv()


def _bilinear(plane, u, v):
    """A feature plane [C, H, W] read at (u, v) in [-1, 1]^2 (u along W, v along H), corners at the cell centres of
    the first and last cells, by the four-neighbour weights written out: [M, C]."""
    _, h, w = plane.shape
    x = ((u + 1) / 2 * (w - 1)).clamp(0, w - 1)
    y = ((v + 1) / 2 * (h - 1)).clamp(0, h - 1)
    x0, y0 = x.floor().long().clamp(max=w - 2), y.floor().long().clamp(max=h - 2)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    p = plane.permute(1, 2, 0)  # [H, W, C]
    return ((1 - fx) * (1 - fy) * p[y0, x0] + fx * (1 - fy) * p[y0, x0 + 1]
            + (1 - fx) * fy * p[y0 + 1, x0] + fx * fy * p[y0 + 1, x0 + 1])


def hexplane(target):
    """Eqs. 5-6: D(x, y, z, t) = [P^XY_xy * P^ZT_zt ; P^XZ_xz * P^YT_yt ; P^YZ_yz * P^XT_xt] V^{RF}, each subscript
    a bilinear interpolation of a learned plane, * elementwise, ';' concatenation, V^{RF} a learned basis: the
    planes the plan builds (reduce "paired") against it, on random planes and points."""
    from nerfify_ns.components.kplanes import MultiScaleKPlanes

    value = target.value or {}
    params = value.get("kplanes_time", value) if isinstance(value, dict) else {}
    assert params.get("reduce") == "paired", f"the planes combine by {params.get('reduce')!r}, not HexPlane's pairs"
    torch.manual_seed(0)
    enc = MultiScaleKPlanes(resolutions=[5], num_components=3, reduce="paired", time_resolution=4).double()
    planes = {}
    with torch.no_grad():
        for pair, plane in zip(enc.plane_pairs, enc.planes(), strict=True):
            plane.normal_()
            planes[pair] = plane[0]
    g = torch.Generator().manual_seed(1)
    xyz = torch.rand(9, 3, generator=g, dtype=torch.float64) * 2 - 1
    t = torch.rand(9, 1, generator=g, dtype=torch.float64)
    x, y, z, tt = xyz[:, 0], xyz[:, 1], xyz[:, 2], t[:, 0] * 2 - 1  # times in [0, 1] on the planes' [-1, 1]
    axis = {0: x, 1: y, 2: z, 3: tt}

    def read(i, j):
        return _bilinear(planes[(i, j)], axis[i], axis[j])

    stacked = torch.cat([read(0, 1) * read(2, 3), read(0, 2) * read(1, 3), read(1, 2) * read(0, 3)], -1)
    basis = [p for n, p in enc.named_parameters() if n.startswith("basis")]
    assert len(basis) == 1 and tuple(basis[0].shape) == (9, 3), [tuple(b.shape) for b in basis]
    torch.testing.assert_close(enc(xyz, t), stacked @ basis[0], rtol=1e-10, atol=1e-12)
