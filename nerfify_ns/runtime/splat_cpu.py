"""Gaussian splatting on the CPU: gsplat's ``rasterization`` for a machine without CUDA.

Nerfstudio's ``splatfacto`` renders with gsplat 1.4, whose projection, tile intersection and rasterisation run
only as CUDA kernels (its "pure PyTorch" path still calls CUDA for the tile lists), so splatfacto and every method
built on it cannot train on a CPU at all. :func:`rasterize` is a drop-in for
``gsplat.rendering.rasterization`` (same arguments and returns, the ``info`` its densification strategy reads)
that renders exactly what gsplat's CUDA kernels render, differentiable through torch's autograd:

* projection (EWA splatting, 3D Gaussian Splatting, Kerbl et al. 2023, Eqs. 5-6): gsplat's own torch
  reference (``gsplat.cuda._torch_impl``: covariance from quaternion and scale, the Jacobian of the perspective
  projection, the 2D covariance with ``eps2d`` and the 3-sigma radius);
* which pixels a Gaussian touches: every pixel of every 16 x 16 tile its radius box meets, as gsplat's tile
  lists do (so the same pixels see the same Gaussians);
* alpha compositing front to back (Kerbl et al., Eq. 3) in depth order, per pixel, with gsplat's rules: an
  alpha below 1/255 or a negative exponent is skipped, alpha is capped at 0.999, and a pixel stops before the
  Gaussian that would take its transmittance to 1e-4 or below. Transmittance is a segmented cumulative sum of
  ``log(1 - alpha)`` over the pixel's sorted pairs, so the whole image is a handful of tensor operations;
* ``absgrad`` (the densification signal of ``DefaultStrategy(absgrad=True)``): the sum over pixels of the
  absolute gradient with respect to each Gaussian's 2D mean, gathered by a hook on the per-pair means.

Pairs (pixel, Gaussian) whose alpha is below 1/255 are dropped in a first pass without gradients, chunked so
its memory stays bounded; only the survivors are composited with autograd.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0
"""gsplat skips a pair whose alpha is below this."""
ALPHA_MAX = 0.999
"""gsplat caps a pair's alpha here."""
T_MIN = 1e-4
"""A pixel stops before the Gaussian that would take its transmittance to this or below (gsplat's rule)."""
PAIR_CHUNK = 4_000_000
"""Pairs screened at once in the first (gradient-free) pass: bounds its memory (~100 MB a chunk)."""


def _within(lo: Tensor, hi: Tensor, centre: Tensor, half: Tensor) -> tuple[Tensor, Tensor]:
    """The pixel range ``[lo, hi)`` cut to the pixels whose centres (index + 0.5) lie within ``centre +- half``, with
    one pixel of margin for rounding; an infinite ``half`` leaves it as it is."""
    first = torch.ceil(centre - half - 0.5) - 1
    last = torch.floor(centre + half - 0.5) + 2
    first = torch.where(torch.isfinite(first), first, torch.zeros_like(first)).clamp(min=0, max=1 << 30).long()
    last = torch.where(torch.isfinite(last), last, torch.full_like(last, 1 << 30)).clamp(min=0, max=1 << 30).long()
    return torch.maximum(lo, first), torch.minimum(hi, last)


def _pairs(
    means2d: Tensor, radii: Tensor, conics: Tensor, opacities: Tensor, width: int, height: int, tile_size: int,
    alpha_box: bool = True,
) -> tuple[Tensor, Tensor]:
    """(Gaussian, pixel) index pairs gsplat could composite: the pixels of the tiles each visible Gaussian's radius
    box meets, cut to the box of its ellipse ``alpha >= 1/255`` (one pixel of margin): a pixel outside that ellipse
    is skipped by gsplat's alpha test, so leaving it out changes nothing and saves most of the pairs."""
    visible = torch.nonzero(radii > 0).squeeze(-1)
    if visible.numel() == 0:
        empty = torch.zeros(0, dtype=torch.long, device=means2d.device)
        return empty, empty
    m = means2d[visible].detach()
    r = radii[visible].to(m.dtype)
    tiles_w, tiles_h = math.ceil(width / tile_size), math.ceil(height / tile_size)
    tx0 = torch.floor((m[:, 0] - r) / tile_size).clamp(0, tiles_w).long()
    tx1 = torch.ceil((m[:, 0] + r) / tile_size).clamp(0, tiles_w).long()
    ty0 = torch.floor((m[:, 1] - r) / tile_size).clamp(0, tiles_h).long()
    ty1 = torch.ceil((m[:, 1] + r) / tile_size).clamp(0, tiles_h).long()
    x0, y0 = tx0 * tile_size, ty0 * tile_size
    x1 = torch.clamp(tx1 * tile_size, max=width)
    y1 = torch.clamp(ty1 * tile_size, max=height)
    if alpha_box:
        # the ellipse 0.5 d^T conic d <= log(255 o): its box has half-widths sqrt(2 log(255 o) * covariance diagonal)
        a, b, c = conics[visible].detach().unbind(-1)
        det = a * c - b * b
        reach = 2.0 * torch.log(torch.clamp(opacities[visible].detach() * 255.0, min=1e-30))
        definite = (det > 0) & (a > 0)
        inf = torch.full_like(a, float("inf"))
        hx = torch.where(definite, torch.sqrt(torch.clamp(reach * c / det, min=0.0)), inf)
        hy = torch.where(definite, torch.sqrt(torch.clamp(reach * a / det, min=0.0)), inf)
        x0, x1 = _within(x0, x1, m[:, 0], hx)
        y0, y1 = _within(y0, y1, m[:, 1], hy)
        x1 = torch.where(definite & (reach <= 0), x0, x1)  # opacity below 1/255: no pixel passes
    bw, bh = (x1 - x0).clamp(min=0), (y1 - y0).clamp(min=0)
    counts = bw * bh
    keep = counts > 0
    visible, x0, y0, bw, counts = visible[keep], x0[keep], y0[keep], bw[keep], counts[keep]
    gauss = torch.repeat_interleave(visible, counts)
    starts = torch.cumsum(counts, 0) - counts
    k = torch.arange(int(counts.sum()), device=means2d.device) - torch.repeat_interleave(starts, counts)
    owner = torch.repeat_interleave(torch.arange(visible.numel(), device=means2d.device), counts)
    bw_k = bw[owner]
    px = x0[owner] + k % bw_k
    py = y0[owner] + torch.div(k, bw_k, rounding_mode="floor")
    return gauss, py * width + px


def _sigma(means2d: Tensor, conics: Tensor, gauss: Tensor, pixel: Tensor, width: int) -> tuple[Tensor, Tensor]:
    """The exponent ``0.5 d^T conic d`` of each pair (pixel centres at +0.5) and the per-pair 2D means used."""
    m = means2d[gauss]
    px = (pixel % width).to(m.dtype) + 0.5
    py = torch.div(pixel, width, rounding_mode="floor").to(m.dtype) + 0.5
    dx, dy = m[:, 0] - px, m[:, 1] - py
    c = conics[gauss]
    sigma = 0.5 * (c[:, 0] * dx * dx + c[:, 2] * dy * dy) + c[:, 1] * dx * dy
    return sigma, m


def _screen(means2d, conics, opacities, gauss, pixel, width) -> Tensor:
    """The pairs gsplat would composite (alpha >= 1/255, non-negative exponent), screened without gradients."""
    keep = []
    with torch.no_grad():
        for start in range(0, gauss.numel(), PAIR_CHUNK):
            g, p = gauss[start : start + PAIR_CHUNK], pixel[start : start + PAIR_CHUNK]
            sigma, _ = _sigma(means2d, conics, g, p, width)
            alpha = torch.clamp(opacities[g] * torch.exp(-sigma), max=ALPHA_MAX)
            keep.append(torch.nonzero((sigma >= 0) & (alpha >= ALPHA_MIN)).squeeze(-1) + start)
    return torch.cat(keep) if keep else torch.zeros(0, dtype=torch.long)


def _composite(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    colors: Tensor,
    depths: Tensor,
    width: int,
    height: int,
    tile_size: int,
    radii: Tensor,
    absgrad_into: Tensor | None,
    alpha_box: bool = True,
) -> tuple[Tensor, Tensor]:
    """One camera: colours ``[H, W, D]`` and alphas ``[H, W, 1]``, composited front to back."""
    n_pix = width * height
    gauss, pixel = _pairs(means2d, radii, conics, opacities, width, height, tile_size, alpha_box)
    keep = _screen(means2d, conics, opacities, gauss, pixel, width)
    gauss, pixel = gauss[keep], pixel[keep]
    out_c = colors.new_zeros(n_pix, colors.shape[-1])
    out_a = colors.new_zeros(n_pix)
    if gauss.numel() == 0:
        return out_c.view(height, width, -1), out_a.view(height, width, 1)
    rank = torch.empty_like(radii, dtype=torch.long)
    rank[torch.argsort(depths.detach(), stable=True)] = torch.arange(depths.numel(), device=depths.device)
    order = torch.argsort(pixel * depths.numel() + rank[gauss], stable=True)
    gauss, pixel = gauss[order], pixel[order]
    sigma, m_pairs = _sigma(means2d, conics, gauss, pixel, width)
    if absgrad_into is not None and m_pairs.requires_grad:
        ids = gauss

        def gather_abs(grad: Tensor) -> None:
            absgrad_into.index_add_(0, ids, grad.abs())

        m_pairs.register_hook(gather_abs)
    alpha = torch.clamp(opacities[gauss] * torch.exp(-sigma), max=ALPHA_MAX)
    # one running sum over every pixel's pairs, in float64: in float32 a sum over millions of pairs would lose the
    # per-pixel digits when each pixel's start is subtracted
    log_t = torch.log1p(-alpha).double()
    inclusive = torch.cumsum(log_t, 0)
    # segment starts: the first pair of each pixel; transmittance restarts at 1 there
    first = torch.ones_like(pixel, dtype=torch.bool)
    first[1:] = pixel[1:] != pixel[:-1]
    seg_id = torch.cumsum(first.long(), 0) - 1
    base = (inclusive - log_t)[first]  # the cumulative sum before each segment
    inclusive = (inclusive - base[seg_id]).to(alpha.dtype)
    exclusive = inclusive - log_t.to(alpha.dtype)
    included = inclusive.detach() > math.log(T_MIN)  # gsplat stops before the pair taking T to <= 1e-4
    weight = torch.where(included, alpha * torch.exp(exclusive), torch.zeros_like(alpha))
    out_c = out_c.index_add(0, pixel, weight[:, None] * colors[gauss])
    out_a = out_a.index_add(0, pixel, weight)
    return out_c.view(height, width, -1), out_a.view(height, width, 1)


def rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    radius_clip: float = 0.0,
    eps2d: float = 0.3,
    sh_degree: int | None = None,
    packed: bool = True,
    tile_size: int = 16,
    backgrounds: Tensor | None = None,
    render_mode: str = "RGB",
    sparse_grad: bool = False,
    absgrad: bool = False,
    rasterize_mode: str = "classic",
    channel_chunk: int = 32,
    distributed: bool = False,
    camera_model: str = "pinhole",
    covars: Tensor | None = None,
    *,
    alpha_box: bool = True,
) -> tuple[Tensor, Tensor, dict[str, Any]]:
    """``gsplat.rendering.rasterization`` on the CPU: ``(render_colors [C, H, W, D], render_alphas [C, H, W, 1],
    info)``. ``sparse_grad`` and ``channel_chunk`` change only how gsplat's kernels work, not what they return,
    and are accepted; ``distributed`` is not supported. ``alpha_box=False`` screens every pixel of a Gaussian's
    tiles (the same image, more pairs: the benchmark's baseline)."""
    from gsplat.cuda._torch_impl import _fully_fused_projection, _quat_scale_to_covar_preci, _spherical_harmonics

    if distributed:
        raise NotImplementedError("distributed rasterisation needs several GPUs")
    if render_mode not in ("RGB", "D", "ED", "RGB+D", "RGB+ED"):
        raise ValueError(f"unknown render_mode {render_mode!r}")
    n, c = means.shape[0], viewmats.shape[0]
    if covars is None:
        covars, _ = _quat_scale_to_covar_preci(quats, scales, True, False, triu=False)
    radii, means2d, depths, conics, compensations = _fully_fused_projection(
        means, covars, viewmats, Ks, width, height, eps2d=eps2d, near_plane=near_plane, far_plane=far_plane,
        calc_compensations=(rasterize_mode == "antialiased"), camera_model=camera_model,
    )
    if radius_clip > 0:
        radii = torch.where(radii.float() <= radius_clip, torch.zeros_like(radii), radii)
    opac = opacities.expand(c, n) if opacities.dim() == 1 else opacities
    if compensations is not None:
        opac = opac * compensations
    if sh_degree is None:
        cols = colors.expand(c, *colors.shape) if colors.dim() == 2 else colors
    else:
        campos = torch.inverse(viewmats)[:, :3, 3]
        dirs = means[None, :, :] - campos[:, None, :]
        shs = colors.expand(c, *colors.shape) if colors.dim() == 3 else colors
        cols = torch.clamp_min(_spherical_harmonics(sh_degree, dirs, shs) + 0.5, 0.0)
    if render_mode in ("RGB+D", "RGB+ED"):
        cols = torch.cat([cols, depths[..., None]], -1)
    elif render_mode in ("D", "ED"):
        cols = depths[..., None]
    absgrads = torch.zeros_like(means2d) if absgrad else None
    rendered_means2d = means2d
    if packed:  # the strategy reads the visible Gaussians' 2D means: render from those, so they get the gradient
        camera_ids, gaussian_ids = torch.nonzero(radii > 0, as_tuple=True)
        packed_means2d = means2d[camera_ids, gaussian_ids]
        rendered_means2d = torch.zeros_like(means2d).index_put((camera_ids, gaussian_ids), packed_means2d)
    images, alphas = [], []
    for cam in range(c):
        img, a = _composite(
            rendered_means2d[cam], conics[cam], opac[cam], cols[cam], depths[cam], width, height, tile_size, radii[cam],
            absgrads[cam] if absgrads is not None else None, alpha_box,
        )
        if backgrounds is not None:
            bg = backgrounds[cam]
            if render_mode in ("RGB+D", "RGB+ED"):
                bg = torch.cat([bg, bg.new_zeros(1)])
            elif render_mode in ("D", "ED"):
                bg = bg.new_zeros(1)
            img = img + (1.0 - a) * bg
        images.append(img)
        alphas.append(a)
    render_colors, render_alphas = torch.stack(images), torch.stack(alphas)
    if render_mode in ("ED", "RGB+ED"):
        render_colors = torch.cat(
            [render_colors[..., :-1], render_colors[..., -1:] / render_alphas.clamp(min=1e-10)], dim=-1
        )
    info: dict[str, Any] = {
        "camera_ids": None, "gaussian_ids": None, "radii": radii, "means2d": means2d, "depths": depths,
        "conics": conics, "opacities": opac, "width": width, "height": height, "tile_size": tile_size,
        "n_cameras": c, "tile_width": math.ceil(width / tile_size), "tile_height": math.ceil(height / tile_size),
    }
    if absgrads is not None:
        means2d.absgrad = absgrads  # type: ignore[attr-defined]  # filled by the pairs' hooks during backward
    if packed:
        info.update(
            camera_ids=camera_ids, gaussian_ids=gaussian_ids, radii=radii[camera_ids, gaussian_ids],
            means2d=packed_means2d, depths=depths[camera_ids, gaussian_ids],
            conics=conics[camera_ids, gaussian_ids], opacities=opac[camera_ids, gaussian_ids],
        )
        if absgrads is not None and packed_means2d.requires_grad:
            # its gradient arrives after every pair's hook has run: hand the strategy the packed sums then
            packed_means2d.register_hook(
                lambda _g: setattr(packed_means2d, "absgrad", absgrads[camera_ids, gaussian_ids])
            )
    return render_colors, render_alphas, info


class _CudaCallsStayOnCpu:
    """While active, ``tensor.cuda()`` returns the tensor itself: splatfacto calls ``.cuda()`` on its camera
    intrinsics and seed colours, which fails on a machine without CUDA (only entered when CUDA is absent)."""

    def __enter__(self) -> None:
        self._original = torch.Tensor.cuda
        torch.Tensor.cuda = lambda tensor, *args, **kwargs: tensor  # type: ignore[method-assign]

    def __exit__(self, *exc: object) -> None:
        torch.Tensor.cuda = self._original  # type: ignore[method-assign]


def install() -> None:
    """Splatfacto (and gsplat's ``rasterization`` for anything else that calls it) on the CPU: this rasteriser in
    place of gsplat's CUDA one, splatfacto's ``.cuda()`` calls kept on the CPU, and its compiled ``get_viewmat``
    run as the plain function it wraps (compiling a 4 x 4 inverse costs seconds of C++ build on a CPU)."""
    import gsplat
    import gsplat.rendering
    from nerfstudio.models import splatfacto

    if getattr(splatfacto.SplatfactoModel.get_outputs, "_nerfify_wrapped", False):
        return
    gsplat.rendering.rasterization = rasterize
    gsplat.rasterization = rasterize
    splatfacto.rasterization = rasterize
    plain = getattr(splatfacto.get_viewmat, "_torchdynamo_orig_callable", None)
    if plain is not None:
        splatfacto.get_viewmat = plain
    for name in ("get_outputs", "populate_modules"):
        original = getattr(splatfacto.SplatfactoModel, name)

        def on_cpu(self, *args, _original=original, **kwargs):
            if torch.cuda.is_available():
                return _original(self, *args, **kwargs)
            with _CudaCallsStayOnCpu():
                return _original(self, *args, **kwargs)

        on_cpu._nerfify_wrapped = True  # type: ignore[attr-defined]
        on_cpu.__doc__ = original.__doc__
        on_cpu.__wrapped__ = original  # type: ignore[attr-defined]  # its signature is the original's (inspect)
        setattr(splatfacto.SplatfactoModel, name, on_cpu)
