"""Checks of GH-NeRF items: reference functions written from the paper's equations."""

import torch


def sh_colour_head(target):
    """Eq. 7: c(d; k) = sigmoid(sum_l sum_m k_l^m Y_l^m(d)), the coefficients k predicted by a network of the
    geometry feature, Y Nerfstudio's spherical harmonics (l_max = 2, 9 functions): the generated head against it."""
    from nerfstudio.field_components.encodings import SHEncoding

    assert target.cls is not None, "no compiled component implements Eq. 7"
    head = target.cls(in_dim=9 + 6, dir_dim=9).double()
    d = torch.nn.functional.normalize(torch.randn(8, 3, dtype=torch.float64), dim=-1)
    y = SHEncoding(levels=3).pytorch_fwd(d)
    geometry = torch.randn(8, 6, dtype=torch.float64)
    net = next(m for name, m in head.named_children() if name.startswith("net_"))
    want = torch.sigmoid((net(geometry).reshape(8, 3, 9) * y[:, None, :]).sum(-1))
    torch.testing.assert_close(head(torch.cat([y, geometry], -1)), want, rtol=1e-10, atol=1e-12)
