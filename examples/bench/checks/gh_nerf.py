"""Checks of GH-NeRF items: reference functions written from the paper's equations."""

import _refs  # checks/_refs.py: the check's folder is on sys.path in the check process
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


def integrated_positional_encoding(target):
    """Eqs. 8-9 (mip-NeRF's integrated positional encoding): for a Gaussian (mu, Sigma), gamma = [sin(2^l mu)
    exp(-2^(2l-1) diag Sigma), cos(2^l mu) exp(-2^(2l-1) diag Sigma)], l = 0 .. L-1: the encoding the plan builds
    (Nerfstudio's NeRFEncoding with covariances) against it, frequencies octave-spaced as in Eq. 8."""
    import numpy as np
    from nerfstudio.field_components.encodings import NeRFEncoding

    v = _refs.as_derived(target)
    freqs = 2.0 ** np.linspace(v["min_freq_exp"], v["max_freq_exp"], v["num_frequencies"])
    assert np.allclose(freqs[1:] / freqs[:-1], 2.0), f"frequencies are not octaves (ratio {freqs[1] / freqs[0]:.3f})"
    enc = NeRFEncoding(in_dim=3, num_frequencies=v["num_frequencies"], min_freq_exp=v["min_freq_exp"],
                       max_freq_exp=v["max_freq_exp"], include_input=False)
    g = torch.Generator().manual_seed(0)
    mu = torch.rand(4, 3, generator=g, dtype=torch.float64) * 0.1
    var = torch.rand(4, 3, generator=g, dtype=torch.float64) * 1e-4
    got = enc(mu, covs=torch.diag_embed(var)).numpy()
    w = 2 * np.pi * freqs  # Nerfstudio scales its inputs by 2 pi
    arg = (mu.numpy()[..., None] * w).reshape(4, -1)
    damp = np.exp(-0.5 * (var.numpy()[..., None] * w ** 2)).reshape(4, -1)
    np.testing.assert_allclose(got, np.concatenate([np.sin(arg) * damp, np.cos(arg) * damp], -1), atol=1e-5)


def coarse_to_fine(target):
    """Eq. 10: the fine samples drawn from the coarse weights' piecewise-constant PDF by inverse transform
    sampling (the plan's hierarchical sampler)."""
    _refs.inverse_transform_sampling(int(target.value["num_importance_samples"]))


def layer_norm(target):
    """Sec. 3.1 ("we use Layer Normalization after each fully-connected layer"): the backbone the plan builds
    normalises every hidden layer, and its network is Linear -> LayerNorm -> ReLU per layer (the last one without
    its ReLU, as Nerfstudio's MLP) (Ba et al. 2016:
    each sample's units to zero mean and unit variance, then a learned gain and bias), checked against that chain
    written here."""
    from nerfify_ns.components.mlp_normed import NormedMLP

    value = target.value or {}
    params = value.get("mlp", value) if isinstance(value, dict) else {}
    assert params.get("hidden_norm") == "layer", f"the backbone's hidden_norm is {params.get('hidden_norm')!r}"
    torch.manual_seed(0)
    net = NormedMLP(in_dim=5, num_layers=3, layer_width=8).double()
    x = torch.randn(6, 5, dtype=torch.float64)
    linears = [m for m in net.modules() if isinstance(m, torch.nn.Linear)]
    norms = [m for m in net.modules() if isinstance(m, torch.nn.LayerNorm)]
    assert len(linears) == len(norms) == 3, (len(linears), len(norms))
    h = x
    for i, (linear, norm) in enumerate(zip(linears, norms, strict=True)):
        z = linear(h)
        z = (z - z.mean(-1, keepdim=True)) / torch.sqrt(z.var(-1, unbiased=False, keepdim=True) + norm.eps)
        h = z * norm.weight + norm.bias
        h = torch.relu(h) if i < len(linears) - 1 else h  # Nerfstudio's MLP: no activation after its last layer
    torch.testing.assert_close(net(x), h, rtol=1e-10, atol=1e-12)
