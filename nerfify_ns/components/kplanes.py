"""Multi-scale K-Planes (Fridovich-Keil et al., "K-Planes: Explicit Radiance Fields in Space, Time,
and Appearance", CVPR 2023, arXiv 2301.10241).

A point q in [-1, 1]^d (d = 3, or 4 with time) is projected onto the plane of every coordinate pair
c = (i, j); each plane P_c is a learned [1, C, n_j, n_i] feature grid read with bilinear interpolation
(``grid_sample``, ``align_corners=True``, border padding):

    f(q)_c = psi(P_c, pi_c(q))                     (K-Planes Eq. 1)
    f(q)   = prod_{c in C} f(q)_c                  (Eq. 2, Hadamard product; ``reduce="sum"`` sums)
    f(q)   = concat_{s in scales} f_s(q)           (Eq. 3, multi-scale features concatenated)

``reduce="paired"`` (space-time only) is HexPlane's combination (Cao and Johnson, "HexPlane: A Fast
Representation for Dynamic Scenes", CVPR 2023, arXiv 2301.09632, Eqs. 5-6): the six planes form three
pairs, each a spatial plane and the space-time plane over the two other axes (XY/ZT, XZ/YT, YZ/XT); the
two planes of a pair are multiplied elementwise, the three products concatenated and multiplied by a
learned basis V^{RF} (R = 3C rows, F = C columns) so that a scale still yields C features:

    f_s(q) = [P_XY(x,y) * P_ZT(z,t); P_XZ(x,z) * P_YT(y,t); P_YZ(y,z) * P_XT(x,t)] V^{RF}   (HexPlane Eq. 6)

Spatial planes are initialised uniformly in [0.1, 0.5] and planes that involve time to 1, so a
dynamic model starts static (K-Planes Sec. 3.2). Time has one resolution for every scale (the paper
is multi-scale in space only).

Imports only torch and nerfstudio: generated plugins import this module.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Literal

import torch
import torch.nn.functional as F
from nerfstudio.cameras.rays import RaySamples
from nerfstudio.data.scene_box import SceneBox
from nerfstudio.field_components.activations import trunc_exp
from nerfstudio.field_components.spatial_distortions import SpatialDistortion
from nerfstudio.fields.base_field import Field
from torch import Tensor, nn

__all__ = ["MultiScaleKPlanes", "KPlanesDensityField", "sample_plane"]

TIME_AXIS = 3
MAX_LOG_DENSITY = 20.0
"""Pre-activation density cap of the proposal field: exp(20) ~ 4.9e8 keeps density finite."""


def sample_plane(plane: Tensor, coords: Tensor) -> Tensor:
    """Bilinear read of ``plane`` [1, C, H, W] at ``coords`` [M, 2] in [-1, 1] (x -> W, y -> H): [M, C]."""
    grid = coords.reshape(1, 1, -1, 2).to(plane.dtype)
    out = F.grid_sample(plane, grid, mode="bilinear", padding_mode="border", align_corners=True)
    return out.reshape(plane.shape[1], -1).transpose(0, 1)  # [M, C]


class MultiScaleKPlanes(nn.Module):
    """Multi-scale k-planes over 3D space (3 planes per scale) or 4D space-time (6 planes per scale).

    Args:
        resolutions: spatial resolution of each scale (K-Planes: 64, 128, 256, 512).
        num_components: features per plane, C (K-Planes: 32).
        reduce: ``"product"`` (Hadamard product, Eq. 2) or ``"sum"`` over the planes of one scale;
            ``"paired"`` (space-time only): HexPlane's paired products concatenated and multiplied by a learned
            basis V^{RF} [3C, C] (HexPlane Eq. 6).
        time_resolution: resolution of the time axis; ``None`` for a static (3D) model.
        init_a, init_b: uniform initialisation range of the spatial planes (K-Planes: 0.1, 0.5).

    ``forward(positions, times=None)``: ``positions`` [..., 3] in [-1, 1]; ``times`` [..., 1] in
    [0, 1] (mapped to [-1, 1]) for a space-time model. Alternatively pass [..., 4] coordinates
    already in [-1, 1] and no ``times``. Returns [..., len(resolutions) * num_components].

    Plane p of scale s covers the coordinate pair ``plane_pairs[p] = (i, j)`` and has shape
    [1, C, n_j, n_i]; for a space-time plane (i, 3) the time axis is dim -2: [1, C, T, n_i].
    """

    def __init__(
        self,
        resolutions: Sequence[int] = (64, 128, 256, 512),
        num_components: int = 32,
        reduce: Literal["product", "sum", "paired"] = "product",
        time_resolution: int | None = None,
        init_a: float = 0.1,
        init_b: float = 0.5,
    ) -> None:
        super().__init__()
        resolutions = [int(r) for r in resolutions]
        if not resolutions or any(r < 2 for r in resolutions):
            raise ValueError(f"resolutions must be a non-empty list of integers >= 2, got {resolutions}")
        if num_components < 1:
            raise ValueError(f"num_components must be >= 1, got {num_components}")
        if reduce not in ("product", "sum", "paired"):
            raise ValueError(f"reduce must be 'product', 'sum' or 'paired', got {reduce!r}")
        if reduce == "paired" and time_resolution is None:
            raise ValueError("reduce='paired' (HexPlane's plane pairs) needs space-time planes: set time_resolution")
        if time_resolution is not None and int(time_resolution) < 2:
            raise ValueError(f"time_resolution must be >= 2, got {time_resolution}")
        self.resolutions = resolutions
        self.num_components = int(num_components)
        self.reduce = reduce
        self.time_resolution = None if time_resolution is None else int(time_resolution)
        self.in_dim = 3 if time_resolution is None else 4
        self.plane_pairs: list[tuple[int, int]] = list(itertools.combinations(range(self.in_dim), 2))

        self.grids = nn.ModuleList()
        for res in resolutions:
            planes = nn.ParameterList()
            for pair in self.plane_pairs:
                sizes = [self.time_resolution if axis == TIME_AXIS else res for axis in pair]
                plane = nn.Parameter(torch.empty(1, self.num_components, sizes[1], sizes[0]))
                if TIME_AXIS in pair:
                    nn.init.ones_(plane)
                else:
                    nn.init.uniform_(plane, a=init_a, b=init_b)
                planes.append(plane)
            self.grids.append(planes)
        self.pairs: list[tuple[int, int]] = []
        """Plane indices (spatial, space-time) of HexPlane's pairs, each over complementary axes (``paired``)."""
        self.basis = nn.ParameterList()
        """Per scale, HexPlane's V^{RF} [3C, C] (``paired`` only)."""
        if reduce == "paired":
            for p, pair in enumerate(self.plane_pairs):
                if TIME_AXIS not in pair:
                    rest = tuple(a for a in range(self.in_dim) if a not in pair)
                    self.pairs.append((p, self.plane_pairs.index(rest)))
            width = len(self.pairs) * self.num_components
            for _ in resolutions:
                basis = nn.Parameter(torch.empty(width, self.num_components))
                nn.init.normal_(basis, std=width ** -0.5)
                self.basis.append(basis)

    # ------------------------------------------------------------------ plane access (regularisers)
    def get_out_dim(self) -> int:
        return len(self.resolutions) * self.num_components

    def planes(self) -> list[Tensor]:
        """Every plane of every scale, scale-major, in ``plane_pairs`` order."""
        return [plane for planes in self.grids for plane in planes]

    @property
    def spatial_planes(self) -> list[Tensor]:
        """Planes over two spatial axes (input of ``plane_tv``, K-Planes Eq. 4)."""
        return [p for planes in self.grids for pair, p in zip(self.plane_pairs, planes, strict=False)
                if TIME_AXIS not in pair]

    @property
    def time_planes(self) -> list[Tensor]:
        """Space-time planes [1, C, T, n] (input of ``time_smoothness`` / ``plane_l1_to_one``, Eq. 5-6)."""
        return [p for planes in self.grids for pair, p in zip(self.plane_pairs, planes, strict=False)
                if TIME_AXIS in pair]

    # ------------------------------------------------------------------ forward
    def _coordinates(self, positions: Tensor, times: Tensor | None) -> Tensor:
        if times is not None:
            if self.in_dim != 4:
                raise ValueError("times given to a static (3D) MultiScaleKPlanes; set time_resolution")
            if positions.shape[-1] != 3:
                raise ValueError(f"positions must be [..., 3] when times are given, "
                                 f"got {tuple(positions.shape)}")
            times = times.to(positions.dtype)
            if times.shape[-1] != 1 or times.dim() != positions.dim():
                times = times.reshape(*positions.shape[:-1], 1)
            return torch.cat([positions, times * 2.0 - 1.0], dim=-1)
        if positions.shape[-1] != self.in_dim:
            what = "positions [..., 3]" if self.in_dim == 3 else "positions [..., 3] and times, or [..., 4]"
            raise ValueError(f"expected {what}, got {tuple(positions.shape)}")
        return positions

    def forward(self, positions: Tensor, times: Tensor | None = None) -> Tensor:
        coords = self._coordinates(positions, times)
        batch_shape = coords.shape[:-1]
        flat = coords.reshape(-1, self.in_dim)
        scales = []
        for s, planes in enumerate(self.grids):
            if self.reduce == "paired":
                products = [sample_plane(planes[a], flat[:, list(self.plane_pairs[a])])
                            * sample_plane(planes[b], flat[:, list(self.plane_pairs[b])]) for a, b in self.pairs]
                scales.append(torch.cat(products, dim=-1) @ self.basis[s])
                continue
            feature: Tensor | None = None
            for pair, plane in zip(self.plane_pairs, planes, strict=False):
                value = sample_plane(plane, flat[:, list(pair)])
                if feature is None:
                    feature = value
                elif self.reduce == "product":
                    feature = feature * value
                else:
                    feature = feature + value
            assert feature is not None
            scales.append(feature)
        return torch.cat(scales, dim=-1).reshape(*batch_shape, self.get_out_dim())


class KPlanesDensityField(Field):
    """K-Planes proposal network: one scale of k-planes and a linear decoder to density.

    K-Planes (arXiv 2301.10241, Sec. 3.4 / supplement) replaces Mip-NeRF 360's proposal MLPs
    (Barron et al. 2022, arXiv 2111.12077) with small k-planes (8 features, resolutions 128 and 256)
    decoded linearly; density = trunc_exp(linear(f(q))). Same interface as Nerfstudio's
    ``HashMLPDensityField``: ``get_density(ray_samples) -> (density, None)``, ``density_fn(positions)``,
    ``forward(ray_samples)`` returning a dict holding the density; usable in a ``ProposalNetworkSampler``.

    Args:
        aabb: [2, 3] scene box; positions are normalised to [-1, 1] with it (no spatial distortion).
        resolution: spatial resolution of the planes.
        num_components: features per plane.
        spatial_distortion: e.g. ``SceneContraction``; contracted positions (norm < 2) are halved.
        time_resolution: resolution of the time axis for dynamic scenes (times from ``ray_samples.times``).
        average_init_density: density scale, as in ``HashMLPDensityField``.
        reduce: plane combination, as in ``MultiScaleKPlanes``.
    """

    aabb: Tensor

    def __init__(
        self,
        aabb: Tensor,
        resolution: int = 128,
        num_components: int = 8,
        spatial_distortion: SpatialDistortion | None = None,
        time_resolution: int | None = None,
        average_init_density: float = 1.0,
        reduce: Literal["product", "sum"] = "product",
    ) -> None:
        super().__init__()
        self.register_buffer("aabb", aabb)
        self.spatial_distortion = spatial_distortion
        self.average_init_density = average_init_density
        self.encoding = MultiScaleKPlanes(
            resolutions=[resolution], num_components=num_components, reduce=reduce,
            time_resolution=time_resolution,
        )
        self.linear = nn.Linear(self.encoding.get_out_dim(), 1)

    def planes(self) -> list[Tensor]:
        return self.encoding.planes()

    @property
    def spatial_planes(self) -> list[Tensor]:
        return self.encoding.spatial_planes

    @property
    def time_planes(self) -> list[Tensor]:
        return self.encoding.time_planes

    def density_fn(self, positions: Tensor, times: Tensor | None = None) -> Tensor:
        if times is None:
            return super().density_fn(positions)
        return self._density(positions, times)

    def _density(self, positions: Tensor, times: Tensor | None) -> Tensor:
        if self.spatial_distortion is not None:
            positions = self.spatial_distortion(positions) / 2.0  # ball of radius 2 -> [-1, 1]
        else:
            positions = SceneBox.get_normalized_positions(positions, self.aabb) * 2.0 - 1.0
        inside = ((positions > -1.0) & (positions < 1.0)).all(dim=-1, keepdim=True)
        if self.encoding.in_dim == 4 and times is None:
            raise ValueError("this KPlanesDensityField is time-conditioned: ray samples must carry times")
        if self.encoding.in_dim == 3:
            times = None
        features = self.encoding(positions, times)
        raw = self.linear(features.to(self.linear.weight.dtype))
        # trunc_exp's forward is a plain exp (inf above ~88 in float32): clamp the pre-activation first
        density = self.average_init_density * trunc_exp(raw.clamp(max=MAX_LOG_DENSITY))
        return density * inside.to(density.dtype)

    def get_density(self, ray_samples: RaySamples) -> tuple[Tensor, None]:
        positions = ray_samples.frustums.get_positions()
        return self._density(positions, ray_samples.times), None

    def get_outputs(self, ray_samples: RaySamples, density_embedding: Tensor | None = None) -> dict:
        return {}
