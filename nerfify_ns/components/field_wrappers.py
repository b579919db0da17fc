"""Wrappers around a radiance field: what dynamic NeRFs add to a static one.

A **conditioner** changes what the field is queried with. Every conditioner has the same interface (the
FieldWrapper contract of the grammar): ``forward(positions [N, 3], times [N, 1], camera_indices [N])`` returns
``(positions [N, 3], times [N, 1], features [N, get_out_dim()])``: the position and time the field is queried
at, and features appended to the input of the field's backbone (width 0 for a conditioner that adds none).
Positions are world positions (before the field's normalisation or contraction); times are in [0, 1].

- :class:`DeformationNetwork`: a deformation network into a canonical space, Psi_t(x, t) = Delta x, the field
  queried at x + Delta x, with Psi_t(x, 0) = 0 so the scene at t = 0 is the canonical one (D-NeRF, Pumarola
  et al. 2021, arXiv 2011.13961, Sec. 4, Eqs. 2-3); its own sinusoidal encodings of x and t; optionally the
  coarse-to-fine window over the frequencies of x (Nerfies, Park et al. 2021, arXiv 2011.12948, Eqs. 8-9), which
  a schedule hook may anneal (``window``).
- :class:`GaussianDeformation`: the deformation of a set of 3D Gaussians from a canonical space to time t, an MLP
  F(gamma(x), gamma(t)) -> (Delta x, Delta r, Delta s) of each Gaussian's centre, rotation (a quaternion) and
  log-scale (Deformable 3D Gaussians, Yang et al. 2024, arXiv 2309.13101, Sec. 3.2, Eqs. 4-5; the multi-head
  decoder of 4D Gaussian Splatting, Wu et al. 2024, arXiv 2310.08528, Eq. 8): the conditioner's positions are the
  deformed centres, its features the rotation and scale offsets ``[N, 7]``, which the splatting model adds to the
  canonical ones. Optionally annealed Gaussian noise on its time input (``time_noise``, the annealing smooth training
  of Deformable 3D Gaussians, Sec. 3.3, Eq. 6), which a schedule hook may anneal.
- :class:`TimeEmbedding`: a learned embedding of continuous time, an MLP on the sinusoidal encoding gamma(t),
  concatenated to the field's features (the time input of D-NeRF's T-NeRF baseline, Sec. 5, through an MLP).
- :class:`FrameCodes`: learned time-variant latent codes z_t, one per frame, concatenated to the encoded position
  (DyNeRF, Li et al. 2022, arXiv 2103.02597, Sec. 3.1, Eq. 2: F(x, d, z_t)); between frames the codes are
  interpolated linearly (DyNeRF's interpolation of latent codes).
- :class:`CameraTimeOffset`: one learned time offset per training camera, t + delta_c (for unsynchronised
  capture; Nerfstudio's camera index is the training image); evaluation cameras use no offset.

A **blend** combines several fields (:class:`BlendedField` around :class:`FieldBlend`): by density,
sigma = sum_k sigma_k, c = sum_k sigma_k c_k / sigma (the static + transient composition of NeRF-W,
Martin-Brualla et al. 2021, arXiv 2008.02268, Eq. 10), or by a learned per-sample mixer,
w = softmax(MLP(gamma(x), t)), sigma = sum_k w_k sigma_k, c = sum_k w_k c_k (the decomposition field of
NeRFPlayer, Song et al. 2023, arXiv 2210.15947, Sec. 3.1, with K fields).

Imports only torch, nerfstudio and the k-planes component: generated plugins import this module.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from nerfstudio.cameras.rays import RaySamples
from nerfstudio.field_components.field_heads import FieldHeadNames
from nerfstudio.fields.base_field import Field
from torch import Tensor, nn

from .kplanes import MultiScaleKPlanes

__all__ = ["Sinusoids", "DeformationNetwork", "GaussianDeformation", "TimeEmbedding", "FrameCodes", "CameraTimeOffset",
           "FieldBlend", "BlendedField", "condition", "mlp"]

Conditioned = tuple[Tensor, Tensor, Tensor]


class Sinusoids(nn.Module):
    """gamma(p) = (p, sin(2^k pi p), cos(2^k pi p)) for k < num_frequencies (NeRF Eq. 4), optionally weighted
    per frequency by the coarse-to-fine window of Nerfies (Eq. 9): w_k(alpha) = (1 - cos(pi clamp(alpha - k,
    0, 1))) / 2; ``window`` = alpha starts at ``num_frequencies`` (every frequency on). Handles empty batches."""

    def __init__(self, in_dim: int, num_frequencies: int, include_input: bool = True) -> None:
        super().__init__()
        self.in_dim, self.num_frequencies, self.include_input = in_dim, num_frequencies, include_input
        self.register_buffer("freqs", (2.0 ** torch.arange(num_frequencies)) * math.pi, persistent=False)
        self.register_buffer("window", torch.tensor(float(num_frequencies)))

    def get_out_dim(self) -> int:
        return self.in_dim * (2 * self.num_frequencies + int(self.include_input))

    def forward(self, x: Tensor) -> Tensor:
        scaled = x[..., None, :] * self.freqs.to(x)[:, None]  # [..., F, D]
        weights = 0.5 * (1 - torch.cos(math.pi * (self.window - torch.arange(self.num_frequencies, device=x.device))
                                       .clamp(0.0, 1.0))).to(x)[:, None]
        parts = [torch.sin(scaled) * weights, torch.cos(scaled) * weights]
        out = torch.cat(parts, dim=-2).reshape(*x.shape[:-1], 2 * self.num_frequencies * self.in_dim)
        return torch.cat([x, out], dim=-1) if self.include_input else out


def mlp(in_dim: int, width: int, layers: int, out_dim: int) -> nn.Sequential:
    """``layers`` hidden ReLU layers of ``width`` units, then a linear output of ``out_dim``."""
    modules: list[nn.Module] = []
    dim = in_dim
    for _ in range(layers):
        modules += [nn.Linear(dim, width), nn.ReLU()]
        dim = width
    modules.append(nn.Linear(dim, out_dim))
    return nn.Sequential(*modules)


def _float(x: Tensor) -> Tensor:
    return x if x.dtype in (torch.float32, torch.float64) else x.float()


class DeformationNetwork(nn.Module):
    """D-NeRF's deformation network Psi_t: (gamma(x), gamma(t)) -> Delta x (an MLP of ``num_layers`` x
    ``layer_width``); the field is queried at the canonical position x + Delta x. With ``zero_at_t0`` the
    displacement is 0 at t = 0 (D-NeRF Eq. 2: the canonical space is the scene at t = 0). The last layer starts
    at zero, so training starts from the identity map."""

    def __init__(self, num_layers: int = 8, layer_width: int = 256, position_frequencies: int = 10,
                 time_frequencies: int = 6, zero_at_t0: bool = True) -> None:
        super().__init__()
        self.position_encoding = Sinusoids(3, position_frequencies)
        self.time_encoding = Sinusoids(1, time_frequencies)
        self.network = mlp(self.position_encoding.get_out_dim() + self.time_encoding.get_out_dim(), layer_width,
                           num_layers, 3)
        nn.init.zeros_(self.network[-1].weight)
        nn.init.zeros_(self.network[-1].bias)
        self.zero_at_t0 = zero_at_t0

    @property
    def window(self) -> Tensor:
        """The coarse-to-fine window over the frequencies of x (Nerfies' alpha), for schedule hooks."""
        return self.position_encoding.window

    def get_out_dim(self) -> int:
        return 0

    def forward(self, positions: Tensor, times: Tensor, camera_indices: Tensor) -> Conditioned:
        x, t = _float(positions), _float(times)
        delta = self.network.to(x.dtype)(torch.cat([self.position_encoding(x), self.time_encoding(t)], dim=-1))
        if self.zero_at_t0:
            delta = delta * (t != 0).to(delta)
        return (x + delta).to(positions.dtype), times, positions.new_zeros(*positions.shape[:-1], 0)


class GaussianDeformation(DeformationNetwork):
    """Deformable 3D Gaussians' deformation field (Yang et al. 2024, arXiv 2309.13101, Sec. 3.2, Eq. 4):
    (Delta x, Delta r, Delta s) = F_theta(gamma(sg(x)), gamma(t)), an MLP of ``num_layers`` x ``layer_width`` on the
    encodings of a canonical Gaussian's centre and of time, with three heads (centre, rotation quaternion, log-scale;
    the multi-head decoder of 4D-GS, Eq. 8). The Gaussian at time t has centre x + Delta x, rotation r + Delta r and
    log-scale s + Delta s (Eq. 5). The heads start at zero, so training starts from the canonical Gaussians; with
    ``zero_at_t0`` there is no deformation at t = 0; with ``stop_gradient`` the encoding reads the centre without
    its gradient (Eq. 4's sg; the centre still learns through x + Delta x). ``time_noise``: beta of the annealing
    smooth training (Sec. 3.3, Eq. 6): while training, gamma(t) + N(0, 1) beta Delta t, Delta t the mean interval
    between the training times seen so far (0 noise until two were seen); a schedule hook anneals beta to 0.

    ``encoding="planes"``: 4D-GS's spatial-temporal structure encoder (Wu et al. 2024, arXiv 2310.08528, Sec. 4.2,
    Eq. 7) in place of gamma: the features of the six planes (x, y), (x, z), (y, z), (x, t), (y, t), (z, t) at
    ``plane_levels`` resolutions ``plane_resolution`` x 2^l, bilinearly interpolated, multiplied over the planes of
    a level and concatenated over the levels (a 4D K-Planes module), read by the MLP (the tiny MLP phi_d). The
    centres are mapped into the planes' [-1, 1] by the box of the canonical Gaussians first seen (with a margin;
    the bounding plane voxels of 4D-GS), kept as a buffer; the time noise is added to t itself. ``position_encoding``
    is then the planes (``spatial_planes`` and ``time_planes`` for the grid regularisers).

    Conditioner interface: ``forward(positions [N, 3], times [N, 1], camera_indices [N])`` returns the deformed
    centres, the times, and features ``[N, 7]`` = (Delta r [4], Delta s [3])."""

    HEADS = (3, 4, 3)
    """Widths of the centre, rotation (quaternion) and log-scale offsets."""
    BOX_MARGIN = 0.1
    """Margin of the planes' box around the canonical centres first seen, as a fraction of its size per axis."""

    def __init__(self, num_layers: int = 8, layer_width: int = 256, position_frequencies: int = 10,
                 time_frequencies: int = 6, zero_at_t0: bool = False, stop_gradient: bool = True,
                 encoding: str = "frequency", plane_resolution: int = 64, plane_levels: int = 2,
                 plane_features: int = 32, time_resolution: int = 25) -> None:
        super().__init__(num_layers, layer_width, position_frequencies, time_frequencies, zero_at_t0)
        if encoding not in ("frequency", "planes"):
            raise ValueError(f"encoding must be 'frequency' or 'planes', got {encoding!r}")
        self.stop_gradient = stop_gradient
        self.encoding_kind = encoding
        if encoding == "planes":
            self.position_encoding = MultiScaleKPlanes(
                [int(plane_resolution) * 2 ** level for level in range(int(plane_levels))], int(plane_features),
                reduce="product", time_resolution=int(time_resolution))
            self.network = mlp(self.position_encoding.get_out_dim(), layer_width, num_layers, sum(self.HEADS))
        else:
            last = self.network[-1]
            self.network[-1] = nn.Linear(last.in_features, sum(self.HEADS))
        nn.init.zeros_(self.network[-1].weight)
        nn.init.zeros_(self.network[-1].bias)
        self.register_buffer("box", torch.zeros(2, 3))
        """The planes' box [min, max] (``encoding="planes"``); all zero until the first centres are seen."""
        self.register_buffer("time_noise", torch.tensor(0.0))
        self.seen_times: set[float] = set()
        """Distinct training times seen (at most :data:`MAX_TIMES`): their mean interval scales the noise."""

    def get_out_dim(self) -> int:
        return sum(self.HEADS[1:])

    MAX_TIMES = 100_000

    def time_interval(self) -> float:
        """The mean interval between the distinct training times seen (0 before two were)."""
        if len(self.seen_times) < 2:
            return 0.0
        return (max(self.seen_times) - min(self.seen_times)) / (len(self.seen_times) - 1)

    def _in_box(self, x: Tensor) -> Tensor:
        """Centres mapped into the planes' [-1, 1]^3 (the box set from the first centres seen; outside it, clamped)."""
        if not bool(self.box.any()) and x.numel():
            lo, hi = x.detach().amin(0), x.detach().amax(0)
            pad = (hi - lo).clamp(min=1e-6) * self.BOX_MARGIN
            self.box.copy_(torch.stack([lo - pad, hi + pad]).to(self.box))
        lo, hi = self.box[0].to(x), self.box[1].to(x)
        return (((x - lo) / (hi - lo).clamp(min=1e-12)) * 2.0 - 1.0).clamp(-1.0, 1.0)

    def forward(self, positions: Tensor, times: Tensor, camera_indices: Tensor) -> Conditioned:
        x, t = _float(positions), _float(times)
        noise = 0.0
        if self.training and t.numel():
            if len(self.seen_times) < self.MAX_TIMES:
                self.seen_times.update(round(float(v), 6) for v in torch.unique(t.detach()).tolist()[:64])
            noise = float(self.time_noise) * self.time_interval()  # Eq. 6: X(i) = N(0, 1) beta Delta t
        read = x.detach() if self.stop_gradient else x
        if self.encoding_kind == "planes":
            t_in = t + torch.randn_like(t) * noise if noise > 0 else t
            encoded = self.position_encoding.to(x.dtype)(self._in_box(read), t_in.clamp(0.0, 1.0))
        else:
            encoded_t = self.time_encoding(t)
            if noise > 0:
                encoded_t = encoded_t + torch.randn_like(encoded_t) * noise
            encoded = torch.cat([self.position_encoding(read), encoded_t], dim=-1)
        delta = self.network.to(x.dtype)(encoded)
        if self.zero_at_t0:
            delta = delta * (_float(times) != 0).to(delta)
        move, rest = delta.split([self.HEADS[0], sum(self.HEADS[1:])], dim=-1)
        return (x + move).to(positions.dtype), times, rest.to(positions.dtype)


class TimeEmbedding(nn.Module):
    """A learned embedding of continuous time: an MLP (``num_layers`` x ``layer_width``, ``out_dim`` outputs)
    on the sinusoidal encoding gamma(t) with ``num_frequencies`` frequencies, appended to the field's input."""

    def __init__(self, num_frequencies: int = 6, layer_width: int = 64, num_layers: int = 2, out_dim: int = 16) -> None:
        super().__init__()
        self.encoding = Sinusoids(1, num_frequencies)
        self.network = mlp(self.encoding.get_out_dim(), layer_width, num_layers, out_dim)
        self.out_dim = out_dim

    def get_out_dim(self) -> int:
        return self.out_dim

    def forward(self, positions: Tensor, times: Tensor, camera_indices: Tensor) -> Conditioned:
        t = _float(times)
        return positions, times, self.network.to(t.dtype)(self.encoding(t)).to(positions.dtype)


class FrameCodes(nn.Module):
    """DyNeRF's time-variant latent codes: ``num_frames`` learned codes of ``dim`` values over t in [0, 1]
    (frame k at t = k / (num_frames - 1)), read with linear interpolation and appended to the field's input.
    Initialised at random, N(0, 0.01^2) (DyNeRF: randomly initialised independently across frames)."""

    def __init__(self, num_frames: int = 64, dim: int = 32) -> None:
        super().__init__()
        self.codes = nn.Parameter(torch.randn(num_frames, dim) * 0.01)
        self.num_frames, self.dim = num_frames, dim

    def get_out_dim(self) -> int:
        return self.dim

    def forward(self, positions: Tensor, times: Tensor, camera_indices: Tensor) -> Conditioned:
        t = _float(times).reshape(-1).clamp(0.0, 1.0) * (self.num_frames - 1)
        low = t.floor().long().clamp(0, self.num_frames - 1)
        high = (low + 1).clamp(max=self.num_frames - 1)
        frac = (t - low.to(t)).unsqueeze(-1)
        codes = self.codes.to(t.dtype)
        code = codes[low] * (1 - frac) + codes[high] * frac
        return positions, times, code.reshape(*positions.shape[:-1], self.dim).to(positions.dtype)


class CameraTimeOffset(nn.Module):
    """One learned time offset per training camera (Nerfstudio's camera index), added to the sample's time:
    t' = t + delta_c, delta starting at ``init``. Evaluation cameras (``self.training`` off) use no offset:
    their indices are not the training cameras'."""

    def __init__(self, num_images: int, init: float = 0.0) -> None:
        super().__init__()
        self.offsets = nn.Parameter(torch.full((max(int(num_images), 1), 1), float(init)))

    def get_out_dim(self) -> int:
        return 0

    def forward(self, positions: Tensor, times: Tensor, camera_indices: Tensor) -> Conditioned:
        if not self.training:
            return positions, times, positions.new_zeros(*positions.shape[:-1], 0)
        index = camera_indices.reshape(-1).long().clamp(0, self.offsets.shape[0] - 1)
        shifted = times + self.offsets[index].reshape(times.shape).to(times)
        return positions, shifted, positions.new_zeros(*positions.shape[:-1], 0)


def condition(wrappers: Sequence[nn.Module], positions: Tensor, times: Tensor | None,
              camera_indices: Tensor | None) -> tuple[Tensor, Tensor, Tensor | None]:
    """Apply the conditioners in order to samples of any leading shape ``[..., 3]``: (positions [..., 3], times
    [..., 1], the features they add [..., F] or None). Missing times are 0, missing camera indices 0."""
    shape = positions.shape[:-1]
    x = positions.reshape(-1, 3)
    t = times.reshape(-1, 1).to(x) if times is not None else x.new_zeros(x.shape[0], 1)
    cams = (camera_indices.reshape(-1).long() if camera_indices is not None
            else torch.zeros(x.shape[0], dtype=torch.long, device=x.device))
    extras = []
    for wrapper in wrappers:
        x, t, extra = wrapper(x, t, cams)
        if extra.shape[-1]:
            extras.append(extra)
    features = torch.cat(extras, dim=-1) if extras else None
    features = features.reshape(*shape, features.shape[-1]) if features is not None else None
    return x.reshape(*shape, 3), t.reshape(*shape, 1), features


class FieldBlend(nn.Module):
    """Blend the outputs of ``num_fields`` fields per sample: ``mode="density"`` (sigma = sum sigma_k, colour
    weighted by density; where every density is 0 the colour is the mean of the fields') or ``mode="mixer"``
    (w = softmax of an MLP, ``mixer_layers`` x ``mixer_width``, on (gamma(x), t); sigma = sum w_k sigma_k,
    c = sum w_k c_k). ``forward(densities [N, K, 1], rgbs [N, K, 3], positions [N, 3], times [N, 1])`` ->
    ``(density [N, 1], rgb [N, 3])``."""

    def __init__(self, num_fields: int = 2, mode: str = "density", mixer_width: int = 64, mixer_layers: int = 2,
                 mixer_frequencies: int = 4) -> None:
        super().__init__()
        if mode not in ("density", "mixer"):
            raise ValueError(f"mode must be 'density' or 'mixer', got {mode!r}")
        self.num_fields, self.mode = num_fields, mode
        self.last_shares: Tensor | None = None
        """Each field's share of every sample of the last call [N, K] (they sum to 1): the mixer's weights, or each
        density over their sum."""
        if mode == "mixer":
            self.encoding = Sinusoids(3, mixer_frequencies)
            self.mixer = mlp(self.encoding.get_out_dim() + 1, mixer_width, mixer_layers, num_fields)

    def weights(self, positions: Tensor, times: Tensor) -> Tensor:
        """The mixer's per-sample weights [N, K] (they sum to 1)."""
        x, t = _float(positions), _float(times)
        return torch.softmax(self.mixer.to(x.dtype)(torch.cat([self.encoding(x), t], dim=-1)), dim=-1)

    def forward(self, densities: Tensor, rgbs: Tensor, positions: Tensor, times: Tensor) -> tuple[Tensor, Tensor]:
        if self.mode == "mixer":
            w = self.weights(positions, times).unsqueeze(-1).to(densities)  # [N, K, 1]
            self.last_shares = w[..., 0]
            return (w * densities).sum(dim=-2), (w * rgbs).sum(dim=-2).clamp(0.0, 1.0)
        sigma = _float(densities)
        total = sigma.sum(dim=-2)
        eps = 1e-6
        self.last_shares = ((sigma + eps / sigma.shape[-2]) / (total.unsqueeze(-2) + eps))[..., 0].to(densities.dtype)
        rgb = ((sigma * _float(rgbs)).sum(dim=-2) + eps * _float(rgbs).mean(dim=-2)) / (total + eps)
        return total.to(densities.dtype), rgb.clamp(0.0, 1.0).to(rgbs.dtype)


class BlendedField(Field):
    """Several Nerfstudio fields queried at the same samples and blended by :class:`FieldBlend`; a Nerfstudio
    field itself, so a base model installs it as its own field (its ``density_fn`` serves occupancy grids and
    proposal samplers). Keeps ``last_density`` (the blended density), ``last_deltas`` (the samples' steps) and
    ``last_weights`` (each field's share of every sample [.., S, K], in the order of its fields) of its last
    evaluation for regularisers."""

    def __init__(self, fields: Sequence[nn.Module], blend: FieldBlend) -> None:
        super().__init__()
        if len(fields) != blend.num_fields:
            raise ValueError(f"{len(fields)} fields for a blend of {blend.num_fields}")
        self.fields = nn.ModuleList(fields)
        self.blend = blend
        self.last_density: Tensor | None = None
        self.last_deltas: Tensor | None = None
        self.last_weights: Tensor | None = None

    SHARED = ("position_encoding", "spatial_distortion", "direction_encoding")
    """The parts of its first field a blend answers for (the plan's regularisers of the field, plane TV and time
    smoothness, read its encoding); nothing else, so Nerfstudio's own buffers (``aabb``) stay the blend's."""

    def __getattr__(self, name: str):
        try:
            return super().__getattr__(name)
        except AttributeError:
            fields = self._modules.get("fields")
            if name not in self.SHARED or fields is None or not len(fields):
                raise
            return getattr(fields[0], name)

    def _blend(self, ray_samples: RaySamples, densities: list[Tensor], rgbs: list[Tensor]) -> tuple[Tensor, Tensor]:
        shape = densities[0].shape[:-1]
        positions = ray_samples.frustums.get_positions().reshape(-1, 3)
        times = (ray_samples.times.reshape(-1, 1) if ray_samples.times is not None
                 else positions.new_zeros(positions.shape[0], 1))
        k = len(densities)
        density, rgb = self.blend(torch.stack(densities, dim=-2).reshape(-1, k, 1),
                                  torch.stack(rgbs, dim=-2).reshape(-1, k, 3), positions, times.to(positions))
        return density.reshape(*shape, 1), rgb.reshape(*shape, 3)

    def forward(self, ray_samples: RaySamples, compute_normals: bool = False) -> dict[FieldHeadNames, Tensor]:
        outputs = [f(ray_samples) for f in self.fields]
        density, rgb = self._blend(ray_samples, [o[FieldHeadNames.DENSITY] for o in outputs],
                                   [o[FieldHeadNames.RGB] for o in outputs])
        self.last_density, self.last_deltas = density, ray_samples.deltas
        shares = getattr(self.blend, "last_shares", None)  # a blend of the paper's own may keep none
        self.last_weights = None if shares is None else shares.reshape(*density.shape[:-1], shares.shape[-1])
        return {FieldHeadNames.DENSITY: density, FieldHeadNames.RGB: rgb}

    def get_density(self, ray_samples: RaySamples) -> tuple[Tensor, None]:
        densities = [f.get_density(ray_samples)[0] for f in self.fields]
        zeros = [torch.zeros(*d.shape[:-1], 3, dtype=d.dtype, device=d.device) for d in densities]
        return self._blend(ray_samples, densities, zeros)[0], None

    def get_outputs(self, ray_samples: RaySamples, density_embedding: Tensor | None = None) -> dict:
        return {FieldHeadNames.RGB: self.forward(ray_samples)[FieldHeadNames.RGB]}
