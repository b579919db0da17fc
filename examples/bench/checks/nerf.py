"""Checks of NeRF (Mildenhall et al., ECCV 2020) items: reference functions written from the paper, called by
``ns-nerfify bench`` (in the sandbox) on what the pipeline generated. Each takes a
``nerfify_ns.nerfifybench.checkrun.Target`` and raises AssertionError when the generated part disagrees."""

import numpy as np
import torch


def positional_encoding(target):
    """Eq. 4: gamma(p) = (sin(2^0 pi p), cos(2^0 pi p), ..., sin(2^{L-1} pi p), cos(2^{L-1} pi p)), L = 10 for x.
    The encoding the plan builds (Nerfstudio's NeRFEncoding with the plan's parameters) must use L octave-spaced
    frequencies (consecutive ratio 2); a global scale of the frequencies is the scene's normalisation, not checked."""
    from nerfstudio.field_components.encodings import NeRFEncoding

    params = target.value["positional"]
    enc = NeRFEncoding(in_dim=1, num_frequencies=params["num_frequencies"], min_freq_exp=params["min_freq_exp"],
                       max_freq_exp=params["max_freq_exp"], include_input=False)
    assert params["num_frequencies"] == 10, f"L = {params['num_frequencies']}, the paper's is 10"
    p = torch.linspace(-1, 1, 257, dtype=torch.float64)[:, None]
    got = enc(p).numpy()
    # recover the frequencies from the sines: sin(w p) has w = pi * 2^k * scale
    freqs = 2.0 ** np.linspace(params["min_freq_exp"], params["max_freq_exp"], params["num_frequencies"])
    scale = 2 * np.pi  # Nerfstudio's encoding multiplies its inputs by 2 pi
    want = np.sin(np.concatenate([p.numpy() * scale * f for f in freqs], -1))
    np.testing.assert_allclose(got[:, : len(freqs)], want, atol=1e-3)  # Nerfstudio computes in float32
    ratios = freqs[1:] / freqs[:-1]
    assert np.allclose(ratios, 2.0), f"frequencies are not octaves (ratio {ratios[0]:.3f}, Eq. 4 has 2)"


def volume_rendering(target):
    """Eq. 3: C(r) = sum_i T_i (1 - exp(-sigma_i delta_i)) c_i, T_i = exp(-sum_{j<i} sigma_j delta_j), against the
    renderer and sample weights the plan uses (Nerfstudio's RGBRenderer, RaySamples.get_weights)."""
    from nerfstudio.cameras.rays import Frustums, RaySamples
    from nerfstudio.model_components.renderers import RGBRenderer

    g = torch.Generator().manual_seed(0)
    starts = torch.sort(torch.rand(4, 32, 1, generator=g, dtype=torch.float64) * 4 + 1, dim=1).values
    ends = torch.cat([starts[:, 1:], starts[:, -1:] + 0.05], 1)
    frustums = Frustums(origins=torch.zeros(4, 32, 3, dtype=torch.float64),
                        directions=torch.ones(4, 32, 3, dtype=torch.float64) / 3 ** 0.5, starts=starts, ends=ends,
                        pixel_area=torch.ones(4, 32, 1, dtype=torch.float64))
    samples = RaySamples(frustums=frustums, deltas=ends - starts)
    sigma = torch.rand(4, 32, 1, generator=g, dtype=torch.float64) * 3
    rgb = torch.rand(4, 32, 3, generator=g, dtype=torch.float64)
    got = RGBRenderer(background_color="black")(rgb=rgb, weights=samples.get_weights(sigma)).numpy()
    s, d = sigma[..., 0].numpy(), samples.deltas[..., 0].numpy()
    trans = np.exp(-np.concatenate([np.zeros((4, 1)), np.cumsum(s * d, 1)[:, :-1]], 1))
    want = ((trans * (1 - np.exp(-s * d)))[..., None] * rgb.numpy()).sum(1)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)
