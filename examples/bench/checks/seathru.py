"""Checks of SeaThru-NeRF items: reference functions written from the condensed text's final model."""

import numpy as np
import torch


def medium_rendering(target):
    """The final model: C = sum_i T_i^obj exp(-a^attn s_i)(1 - exp(-sigma_i delta_i)) c_i
    + T_i^obj exp(-a^bs s_i)(1 - exp(-a^bs delta_i)) c^med, with a^attn, a^bs, c^med networks of the ray direction:
    the generated renderer against it in float64."""
    from nerfstudio.cameras.rays import Frustums, RaySamples

    assert target.cls is not None, "no compiled renderer"
    renderer = target.cls().double()
    g = torch.Generator().manual_seed(0)
    n, k = 4, 16
    starts = torch.sort(torch.rand(n, k, 1, generator=g, dtype=torch.float64) * 4 + 0.5, dim=1).values
    ends = torch.cat([starts[:, 1:], starts[:, -1:] + 0.1], 1)
    dirs = torch.nn.functional.normalize(torch.randn(n, 1, 3, generator=g, dtype=torch.float64), dim=-1)
    frustums = Frustums(origins=torch.zeros(n, k, 3, dtype=torch.float64), directions=dirs.expand(n, k, 3),
                        starts=starts, ends=ends, pixel_area=torch.ones(n, k, 1, dtype=torch.float64))
    samples = RaySamples(frustums=frustums, deltas=ends - starts)
    density = torch.rand(n, k, 1, generator=g, dtype=torch.float64) * 2
    rgb = torch.rand(n, k, 3, generator=g, dtype=torch.float64)
    renderer.bind_samples(samples, density)
    got = renderer(rgb=rgb, weights=samples.get_weights(density)).detach().numpy()
    enc = renderer.direction_encoding(samples.frustums.directions[:, 0, :]).to(torch.float64)
    nets = {name: net(enc).detach().numpy() for name, net in renderer.named_children() if name.startswith("net_")}
    c_med, a_attn, a_bs = nets["net_c_med"], nets["net_a_attn"], nets["net_a_bs"]
    sigma, delta = density[..., 0].numpy(), samples.deltas[..., 0].numpy()
    s = ((samples.frustums.starts + samples.frustums.ends) / 2)[..., 0].numpy()
    trans = np.exp(-np.concatenate([np.zeros((n, 1)), np.cumsum(sigma * delta, 1)[:, :-1]], 1))
    obj = trans[..., None] * np.exp(-a_attn[:, None] * s[..., None]) * (1 - np.exp(-sigma * delta))[..., None] \
        * rgb.numpy()
    med = trans[..., None] * np.exp(-a_bs[:, None] * s[..., None]) * (1 - np.exp(-a_bs[:, None] * delta[..., None])) \
        * c_med[:, None]
    np.testing.assert_allclose(got, (obj + med).sum(1), rtol=1e-9)


def reconstruction_loss(target):
    """L_recon(C_hat, C*) = ((C_hat - C*) / (stopgrad(C_hat) + eps))^2, eps = 1e-3, as a mean."""
    assert target.cls is not None, "no compiled loss"
    module = target.cls()
    pred, gt = torch.rand(5, 3, dtype=torch.float64), torch.rand(5, 3, dtype=torch.float64)
    torch.testing.assert_close(module(pred, gt), (((pred - gt) / (pred + 1e-3)) ** 2).mean())
