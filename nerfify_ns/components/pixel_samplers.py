"""Pixel samplers that draw training rays by a per-image probability map.

:class:`MapPixelSampler` is a Nerfstudio ``PixelSampler``: each training batch draws pixels with probability
proportional to a **map** ``weights(images [B, H, W, 3], image_indices [B]) -> [B, H, W] >= 0`` (the PixelSampler
contract of the grammar), computed once per image batch (the map is a function of the images), times the mask
of the dataset where it has one, times the images a curriculum has made active (``active`` set by a schedule
hook). A map that is zero for an image leaves that view out of training; where the map is zero or not finite
everywhere the pixels are drawn uniformly.

Maps:

- :class:`UniformMap`: every pixel alike (Nerfstudio's default sampler), for a curriculum alone.
- :class:`GradientImportance`: rays drawn by importance, p ~ (1 - u) |grad I| / sum |grad I| + u / HW: the ray
  importance sampling of DyNeRF (Li et al. 2022, arXiv 2103.02597, "Ray Importance Sampling": per-ray weights
  normalised, then inverse transform sampling) with the luminance gradient as the weight; ``uniform_fraction`` u
  keeps every pixel reachable.
- :class:`ViewSelection`: training views chosen by a rule (every n-th view, or the first n views; the sparse-view
  setting of RegNeRF, Niemeyer et al. 2022, arXiv 2112.00724, Sec. 4).

Imports only torch and nerfstudio: generated plugins import this module.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from nerfstudio.data.pixel_samplers import PixelSampler, PixelSamplerConfig
from torch import Tensor, nn

__all__ = ["UniformMap", "GradientImportance", "ViewSelection", "MapPixelSampler", "MapPixelSamplerConfig",
           "draw_pixels"]


class UniformMap(nn.Module):
    """Every pixel of every image alike."""

    def forward(self, images: Tensor, image_indices: Tensor) -> Tensor:
        return torch.ones(images.shape[:3], dtype=torch.float32, device=images.device)


class GradientImportance(nn.Module):
    """p(pixel) ~ (1 - uniform_fraction) * g / sum(g) + uniform_fraction / (H W) per image, g the magnitude of the
    luminance gradient (central differences)."""

    def __init__(self, uniform_fraction: float = 0.5) -> None:
        super().__init__()
        self.uniform_fraction = float(uniform_fraction)

    def forward(self, images: Tensor, image_indices: Tensor) -> Tensor:
        lum = images[..., :3].float().mean(dim=-1)  # [B, H, W]
        gy = torch.zeros_like(lum)
        gx = torch.zeros_like(lum)
        if lum.shape[1] > 2:
            gy[:, 1:-1] = (lum[:, 2:] - lum[:, :-2]) / 2
        if lum.shape[2] > 2:
            gx[:, :, 1:-1] = (lum[:, :, 2:] - lum[:, :, :-2]) / 2
        g = torch.sqrt(gx * gx + gy * gy)
        g = torch.where(torch.isfinite(g), g, torch.zeros_like(g))
        total = g.sum(dim=(1, 2), keepdim=True)
        pixels = max(lum.shape[1] * lum.shape[2], 1)
        detail = torch.where(total > 0, g / total.clamp_min(1e-12), torch.full_like(g, 1.0 / pixels))
        return (1 - self.uniform_fraction) * detail + self.uniform_fraction / pixels


class ViewSelection(nn.Module):
    """1 on the pixels of the chosen views, 0 elsewhere: ``rule="every_nth"`` keeps views whose index is a
    multiple of n; ``rule="first_n"`` keeps views 0..n-1 (indices of the training set)."""

    def __init__(self, rule: str = "every_nth", n: int = 8) -> None:
        super().__init__()
        if rule not in ("every_nth", "first_n"):
            raise ValueError(f"rule must be 'every_nth' or 'first_n', got {rule!r}")
        self.rule, self.n = rule, max(int(n), 1)

    def forward(self, images: Tensor, image_indices: Tensor) -> Tensor:
        index = image_indices.reshape(-1).long()
        keep = (index % self.n == 0) if self.rule == "every_nth" else (index < self.n)
        return keep.float().view(-1, 1, 1).expand(*images.shape[:3]).clone()


def draw_pixels(weights: Tensor, count: int, generator: torch.Generator | None = None) -> Tensor:
    """``count`` pixel indices [count, 3] (image, row, column) drawn with probability proportional to
    ``weights`` [B, H, W] (uniformly where the weights are all zero or not finite)."""
    b, h, w = weights.shape
    flat = weights.reshape(-1).float()
    flat = torch.where(torch.isfinite(flat) & (flat > 0), flat, torch.zeros_like(flat))
    if flat.numel() == 0:
        raise ValueError("no pixels to sample from")
    if float(flat.sum()) <= 0:
        flat = torch.ones_like(flat)
    choice = torch.multinomial(flat, count, replacement=True, generator=generator)
    image = choice // (h * w)
    rest = choice % (h * w)
    return torch.stack([image, rest // w, rest % w], dim=-1)


@dataclass
class MapPixelSamplerConfig(PixelSamplerConfig):
    """Configuration of :class:`MapPixelSampler` (a plugin subclasses it to name its own map)."""

    _target: type = field(default_factory=lambda: MapPixelSampler)


class MapPixelSampler(PixelSampler):
    """Pixels drawn by a per-image probability map (``make_map``, overridden by the plugin; uniform here), times
    the dataset's mask and the images made active by a curriculum (``active``: a callable of the image indices
    [B] -> bool [B], or None for all)."""

    config: MapPixelSamplerConfig

    def __init__(self, config: MapPixelSamplerConfig, **kwargs) -> None:
        super().__init__(config, **kwargs)
        self.weight_map = self.make_map()
        self.active = None
        self._cache: dict[int, Tensor] = {}

    def make_map(self) -> nn.Module:
        """The map of pixel probabilities (the plan's PixelSampler)."""
        return UniformMap()

    def weights(self, batch: dict) -> Tensor:
        """The map of the batch's images (cached per image tensor: a map is a function of the images)."""
        images = batch["image"]
        key = id(images)
        if key not in self._cache:
            with torch.no_grad():
                indices = batch.get("image_idx", torch.arange(images.shape[0]))
                w = self.weight_map(images[..., :3], torch.as_tensor(indices, device=images.device)).float()
            if tuple(w.shape) != tuple(images.shape[:3]):
                raise ValueError(f"the pixel map returned shape {tuple(w.shape)}, expected {tuple(images.shape[:3])}")
            self._cache = {key: w}
        return self._cache[key]

    def collate_image_dataset_batch(self, batch: dict, num_rays_per_batch: int, keep_full_image: bool = False):
        images = batch["image"]
        device = images.device
        weights = self.weights(batch)
        if "mask" in batch and not self.config.ignore_mask:
            weights = weights * batch["mask"][..., 0].to(weights)
        if self.active is not None:
            indices = torch.as_tensor(batch["image_idx"], device=device)
            weights = weights * self.active(indices).to(weights).view(-1, 1, 1)
        indices = draw_pixels(weights, num_rays_per_batch).to(device)
        c, y, x = (i.flatten() for i in torch.split(indices, 1, dim=-1))
        c, y, x = c.cpu(), y.cpu(), x.cpu()
        collated = {key: value[c, y, x] for key, value in batch.items() if key != "image_idx" and value is not None}
        indices[:, 0] = torch.as_tensor(batch["image_idx"])[c]
        collated["indices"] = indices
        if keep_full_image:
            collated["full_image"] = batch["image"]
        return collated
