"""Metrics against closed forms, scikit-image and an independent 2-D windowed SSIM."""

import math

import numpy as np
import pytest
from conftest import installed_lpips_weights
from scipy.signal import correlate2d
from skimage.metrics import structural_similarity

from nerfify_ns.evaluate import metrics as m


def _pair(seed=0, shape=(40, 52, 3), noise=0.1):
    rng = np.random.default_rng(seed)
    gt = rng.random(shape)
    return np.clip(gt + noise * rng.standard_normal(shape), 0.0, 1.0), gt


@pytest.mark.parametrize("d", [0.5, 0.1, 0.01, 1e-3])
def test_psnr_constant_offset_closed_form(d):
    gt = np.full((8, 9, 3), 0.25)
    assert m.psnr(gt + d, gt) == pytest.approx(10 * math.log10(1 / d**2), abs=1e-9)


def test_psnr_identical_is_inf_and_set_is_mean_of_per_image():
    gt = np.random.default_rng(1).random((6, 6, 3))
    assert m.psnr(gt, gt) == math.inf
    a, b = np.full((4, 4, 3), 0.5), np.full((4, 4, 3), 0.5)
    # per-image PSNRs 20 dB and 40 dB -> mean 30, not the PSNR of the pooled MSE (~23 dB)
    assert m.mean_psnr([a + 0.1, b + 0.01], [a, b]) == pytest.approx(30.0, abs=1e-9)


def test_uint8_and_shape_checks():
    gt = np.zeros((4, 4, 3), dtype=np.uint8)
    assert m.psnr(np.full((4, 4, 3), 255, dtype=np.uint8), gt) == pytest.approx(0.0)
    with pytest.raises(ValueError):
        m.psnr(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))


def test_composite_on_white():
    rgba = np.zeros((2, 2, 4))
    rgba[0, 0] = [1.0, 0.0, 0.0, 1.0]  # opaque red
    rgba[0, 1] = [0.0, 0.0, 1.0, 0.5]  # half blue
    out = m.composite_on_background(rgba)
    assert np.allclose(out[0, 0], [1, 0, 0]) and np.allclose(out[0, 1], [0.5, 0.5, 1.0])
    assert np.allclose(out[1, 1], [1, 1, 1])  # empty -> white
    assert np.allclose(m.composite_on_background(rgba, (0, 0, 0))[1, 1], 0)
    u8 = np.round(rgba * 255).astype(np.uint8)
    assert np.allclose(m.as_rgb(u8), out, atol=1 / 255)


def test_ssim_identical_is_one():
    _, gt = _pair()
    assert m.ssim(gt, gt) == pytest.approx(1.0, abs=1e-12)


def test_ssim_matches_skimage_on_the_valid_region():
    """skimage filters with reflect padding, then averages the map cropped by (win-1)/2 = 5 px,
    which is exactly mip-NeRF's valid region: maps agree there and so do the means."""
    pred, gt = _pair()
    value, full = _skimage_ssim(pred, gt)
    ours = m.ssim_map(pred, gt)
    assert ours.shape == (30, 42, 3)
    assert np.max(np.abs(ours - full[5:-5, 5:-5])) < 1e-10
    assert m.ssim(pred, gt) == pytest.approx(value, abs=1e-10)


def _skimage_ssim(pred, gt):
    """scikit-image's SSIM with mip-NeRF's window (Gaussian, sigma 1.5, population covariance): (mean, map)."""
    return structural_similarity(pred, gt, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                 data_range=1, channel_axis=-1, full=True)


def _independent_ssim(x, y):
    """A plain 2-D valid correlation with the outer-product Gaussian, no clipping, per channel."""
    g = np.exp(-0.5 * ((np.arange(11) - 5) / 1.5) ** 2)
    k = np.outer(g, g) / np.outer(g, g).sum()
    c1, c2 = 0.01**2, 0.03**2
    out = []
    for c in range(x.shape[-1]):
        a, b = x[..., c], y[..., c]
        f = lambda z: correlate2d(z, k, mode="valid")  # noqa: E731
        ma, mb = f(a), f(b)
        va, vb, cov = f(a * a) - ma**2, f(b * b) - mb**2, f(a * b) - ma * mb
        out.append(((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma**2 + mb**2 + c1) * (va + vb + c2)))
    return float(np.mean(out))


@pytest.mark.parametrize("seed,noise", [(0, 0.05), (1, 0.2), (2, 0.5)])
def test_ssim_matches_independent_implementation(seed, noise):
    pred, gt = _pair(seed, (33, 29, 3), noise)
    assert m.ssim(pred, gt) == pytest.approx(_independent_ssim(pred, gt), abs=1e-4)


def test_ssim_differs_from_padded_variant_on_small_images():
    """The padded (torchmetrics-style) mean over the full map is a different number."""
    pred, gt = _pair(3, (24, 24, 3), 0.2)
    _, full = _skimage_ssim(pred, gt)
    assert abs(float(full.mean()) - m.ssim(pred, gt)) > 1e-3


def test_lpips_is_none_without_weights(no_lpips_weights):
    pred, gt = _pair(shape=(32, 32, 3))
    assert m.lpips(pred, gt) is None
    assert m.image_metrics(pred, gt)["lpips"] is None


def test_lpips_with_real_weights(monkeypatch):
    weights = installed_lpips_weights()
    monkeypatch.setenv("NERFIFY_LPIPS_WEIGHTS", str(weights))
    pred, gt = _pair(shape=(64, 64, 3), noise=0.2)
    assert m.lpips(gt, gt) == pytest.approx(0.0, abs=1e-6)
    noisy = m.lpips(pred, gt)
    assert isinstance(noisy, float) and 0.01 < noisy < 1.0
    assert m.lpips(np.clip(gt + 0.02, 0, 1), gt) < noisy


def test_colour_spread_is_the_mean_channel_std_over_the_foreground():
    grey = np.full((4, 4, 3), 0.4)
    assert m.colour_spread(grey) == pytest.approx(0.0)
    red = np.zeros((4, 4, 3))
    red[..., 0] = 0.9
    assert m.colour_spread(red) == pytest.approx(np.std([0.9, 0.0, 0.0]))
    rgba = np.zeros((4, 4, 4))
    rgba[:2, :, :3] = [0.9, 0.0, 0.0]  # a red foreground on the top half
    rgba[:2, :, 3] = 1.0
    mask = m.foreground_mask(rgba)
    assert mask.sum() == 8 and mask[:2].all()
    # the transparent half is white once composited: no spread, and outside the mask anyway
    assert m.colour_spread(rgba, mask) == pytest.approx(np.std([0.9, 0.0, 0.0]))
    assert m.colour_spread(rgba) == pytest.approx(np.std([0.9, 0.0, 0.0]) / 2)
    assert m.colour_spread(red, np.zeros((4, 4), bool)) is None
    assert m.foreground_mask(red).all()  # no alpha: every pixel
