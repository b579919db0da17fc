"""The CPU rasteriser renders what gsplat's CUDA kernels render: checked against a per-pixel reference written
from the 3D Gaussian Splatting paper's compositing rule (Kerbl et al. 2023, Eq. 3) with gsplat's thresholds, values
and gradients, on random Gaussians."""

from __future__ import annotations

import math

import pytest
import torch

from nerfify_ns.runtime.splat_cpu import ALPHA_MAX, ALPHA_MIN, T_MIN, rasterize

W, H, TILE = 40, 24, 16


def _scene(n: int = 60, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) - 0.5) * torch.tensor([2.0, 1.2, 1.0])
    means[:, 2] += 3.0  # in front of a camera at the origin looking down +z
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.15 + 0.02
    opacities = torch.rand(n, generator=g) * 0.9 + 0.05
    colors = torch.rand(n, 3, generator=g)
    viewmats = torch.eye(4)[None]
    ks = torch.tensor([[[30.0, 0.0, W / 2], [0.0, 30.0, H / 2], [0.0, 0.0, 1.0]]])
    return means, quats, scales, opacities, colors, viewmats, ks


def _reference(means2d, conics, opacities, colors, depths, radii, width=W, height=H, pixels=None):
    """Per pixel, per Gaussian in depth order, the paper's front-to-back sum with gsplat's rules: only Gaussians
    whose radius box meets the pixel's tile, alpha = min(0.999, o exp(-sigma)), skipped below 1/255 or for a
    negative exponent, stop before transmittance reaches 1e-4."""
    order = torch.argsort(depths, stable=True)
    image = torch.zeros(height, width, colors.shape[-1])
    alpha_img = torch.zeros(height, width, 1)
    for py, px in pixels or [(y, x) for y in range(height) for x in range(width)]:
        if True:
            tx, ty = px // TILE, py // TILE
            t = torch.ones(())
            acc = torch.zeros(colors.shape[-1])
            for i in order.tolist():
                r = float(radii[i])
                if r <= 0:
                    continue
                mx, my = means2d[i].detach().tolist()
                if not (math.floor((mx - r) / TILE) <= tx < math.ceil((mx + r) / TILE)):
                    continue
                if not (math.floor((my - r) / TILE) <= ty < math.ceil((my + r) / TILE)):
                    continue
                dx, dy = means2d[i, 0] - (px + 0.5), means2d[i, 1] - (py + 0.5)
                a, b, c = conics[i]
                sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
                alpha = torch.clamp(opacities[i] * torch.exp(-sigma), max=ALPHA_MAX)
                if sigma < 0 or alpha < ALPHA_MIN:
                    continue
                if t * (1 - alpha) <= T_MIN:
                    break
                acc = acc + colors[i] * alpha * t
                t = t * (1 - alpha)
            image[py, px] = acc
            alpha_img[py, px] = 1 - t
    return image, alpha_img


def test_matches_the_per_pixel_reference_in_values_and_gradients():
    means, quats, scales, opacities, colors, viewmats, ks = _scene()
    for t in (means, scales, opacities, colors):
        t.requires_grad_(True)
    img, alpha, info = rasterize(means, quats, scales, opacities, colors, viewmats, ks, W, H, packed=False)
    assert img.shape == (1, H, W, 3) and alpha.shape == (1, H, W, 1)
    assert (info["radii"] > 0).sum() > 20, "the scene should put most Gaussians on screen"
    ref_img, ref_alpha = _reference(
        info["means2d"][0], info["conics"][0], info["opacities"][0], colors, info["depths"][0], info["radii"][0]
    )
    assert torch.allclose(img[0], ref_img, atol=1e-4)
    assert torch.allclose(alpha[0], ref_alpha, atol=1e-4)
    assert alpha.max() > 0.5, "a covered pixel should be mostly opaque"
    weights = torch.rand(H, W, 3)
    ours = torch.autograd.grad((img[0] * weights).sum(), (means, scales, opacities, colors), retain_graph=True)
    _, _, info2 = rasterize(means, quats, scales, opacities, colors, viewmats, ks, W, H, packed=False)
    ref_img2, _ = _reference(
        info2["means2d"][0], info2["conics"][0], info2["opacities"][0], colors, info2["depths"][0], info2["radii"][0]
    )
    theirs = torch.autograd.grad((ref_img2 * weights).sum(), (means, scales, opacities, colors))
    for a, b in zip(ours, theirs, strict=True):
        assert torch.allclose(a, b, atol=1e-4, rtol=1e-3)
        assert a.abs().sum() > 0


def test_a_pixel_after_millions_of_pairs_keeps_its_precision():
    """Transmittance is a running sum over every pixel's pairs: the last pixels of a large, crowded image (about a
    million pairs before them) still match the per-pixel reference."""
    g = torch.Generator().manual_seed(7)
    n, size = 4000, 160
    means = (torch.rand(n, 3, generator=g) - 0.5) * torch.tensor([3.0, 3.0, 1.0])
    means[:, 2] += 3.0
    quats, scales = torch.randn(n, 4, generator=g), torch.rand(n, 3, generator=g) * 0.05 + 0.03
    opacities, colors = torch.rand(n, generator=g) * 0.3 + 0.02, torch.rand(n, 3, generator=g)
    ks = torch.tensor([[[160.0, 0.0, size / 2], [0.0, 160.0, size / 2], [0.0, 0.0, 1.0]]])
    img, alpha, info = rasterize(means, quats, scales, opacities, colors, torch.eye(4)[None], ks, size, size,
                                 packed=False)
    pixels = [(size - 1 - k, size // 2 + k) for k in range(0, 40, 8)]
    ref_img, ref_alpha = _reference(info["means2d"][0], info["conics"][0], info["opacities"][0], colors,
                                    info["depths"][0], info["radii"][0], size, size, pixels)
    for py, px in pixels:
        assert torch.allclose(img[0, py, px], ref_img[py, px], atol=1e-5)
        assert torch.allclose(alpha[0, py, px], ref_alpha[py, px], atol=1e-5)
    assert alpha[0].sum() > 0.5 * size * size, "the image should be crowded"


def test_cutting_pairs_to_the_alpha_ellipse_changes_nothing():
    """Leaving out the pixels outside each Gaussian's alpha >= 1/255 ellipse (faint, thin, rotated and almost
    transparent Gaussians among them) gives the same image, alphas and gradients as screening every tile pixel."""
    means, quats, scales, opacities, colors, viewmats, ks = _scene(n=200, seed=5)
    scales[:40, 0] *= 8.0  # long thin ellipses
    opacities[40:60] = torch.rand(20) * 0.01  # some below 1/255: no pixel may pass
    for t in (means, scales, opacities, colors):
        t.requires_grad_(True)
    outs = []
    for cut in (True, False):
        img, alpha, _ = rasterize(means, quats, scales, opacities, colors, viewmats, ks, W, H, alpha_box=cut)
        grads = torch.autograd.grad((img * torch.linspace(0, 1, 3)).sum() + alpha.sum(),
                                    (means, scales, opacities, colors))
        outs.append((img, alpha, grads))
    (i1, a1, g1), (i2, a2, g2) = outs
    assert torch.equal(i1, i2) and torch.equal(a1, a2)
    for x, y in zip(g1, g2, strict=True):
        assert torch.allclose(x, y, atol=1e-6)


def test_absgrad_is_the_sum_of_absolute_per_pixel_gradients():
    means, quats, scales, opacities, colors, viewmats, ks = _scene(seed=1)
    means.requires_grad_(True)
    img, _, info = rasterize(
        means, quats, scales, opacities, colors, viewmats, ks, W, H, packed=False, absgrad=True
    )
    info["means2d"].retain_grad()
    img.sum().backward()
    grad, absgrad = info["means2d"].grad, info["means2d"].absgrad
    assert absgrad.shape == grad.shape
    assert torch.all(absgrad >= grad.abs() - 1e-6)  # |sum| <= sum of ||
    assert (absgrad > grad.abs() + 1e-6).any(), "opposite per-pixel signs should make some sums differ"
    invisible = info["radii"] == 0
    assert torch.all(absgrad[invisible] == 0)


def test_packed_info_carries_the_visible_gaussians_with_their_gradient():
    means, quats, scales, opacities, colors, viewmats, ks = _scene(seed=2)
    means.requires_grad_(True)
    img_u, _, _ = rasterize(means, quats, scales, opacities, colors, viewmats, ks, W, H, packed=False)
    img_p, _, info = rasterize(means, quats, scales, opacities, colors, viewmats, ks, W, H, packed=True, absgrad=True)
    assert torch.allclose(img_u, img_p)
    assert info["means2d"].shape == (int((info["radii"] > 0).sum()), 2)
    info["means2d"].retain_grad()
    img_p.sum().backward()
    assert info["means2d"].grad is not None and info["means2d"].grad.abs().sum() > 0
    assert info["means2d"].absgrad.shape == info["means2d"].shape


def test_spherical_harmonics_depth_and_background():
    means, quats, scales, opacities, _, viewmats, ks = _scene(seed=3)
    shs = torch.zeros(means.shape[0], 4, 3)
    shs[:, 0] = 0.3  # degree-0 term only: every Gaussian has the constant colour 0.3 * C0 + 0.5
    background = torch.tensor([0.0, 0.0, 1.0])
    img, alpha, info = rasterize(
        means, quats, scales, opacities, shs, viewmats, ks, W, H, sh_degree=1, render_mode="RGB+ED", packed=False,
        backgrounds=background[None],
    )
    assert img.shape == (1, H, W, 4)
    colour = 0.3 * 0.28209479177387814 + 0.5
    a = alpha[0]
    assert torch.allclose(img[0, ..., :3], colour * a + background * (1 - a), atol=1e-5)
    seen = a[..., 0] > 0.05
    assert seen.any() and (a[..., 0] == 0).any(), "the scene should leave some pixels empty and cover others"
    depth = img[0, ..., 3][seen]
    visible = info["depths"][0][info["radii"][0] > 0]
    assert torch.all((depth >= visible.min() - 1e-4) & (depth <= visible.max() + 1e-4)), (
        "the expected depth lies among the visible Gaussians' depths"
    )


def test_unsupported_distributed_is_refused():
    means, quats, scales, opacities, colors, viewmats, ks = _scene()
    with pytest.raises(NotImplementedError):
        rasterize(means, quats, scales, opacities, colors, viewmats, ks, W, H, distributed=True)


def test_a_whole_image_method_gets_no_ray_batch_options():
    """Splatfacto's data manager loads whole images: tyro would refuse the ray-batch options a ray sampler takes."""
    from nerfify_ns.runtime.presets import RAY_BATCH_FLAGS, for_method

    args = ["--mixed-precision", "False", RAY_BATCH_FLAGS[0], "512", RAY_BATCH_FLAGS[1], "512", "--machine.seed", "3"]
    assert for_method("splatfacto", args) == ["--mixed-precision", "False", "--machine.seed", "3"]
    assert for_method("nerfacto", args) == args
