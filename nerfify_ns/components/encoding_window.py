"""A coarse-to-fine window over the bands of a position encoding: the frequencies of a sinusoidal encoding or the
levels of a multiresolution grid, switched on from coarse to fine over training.

Band k of the encoding is weighted by w_k(alpha) = (1 - cos(pi clamp(alpha - k, 0, 1))) / 2 (Nerfies, Park et
al. 2021, arXiv 2011.12948, Eq. 9; BARF, Lin et al. 2021, arXiv 2104.06405, Eq. 14). A schedule hook (``Anneal``
on ``encoding_window.window``) writes ``window``, the share of the way from coarse to fine in [0, 1]: for
a sinusoidal encoding alpha = window x L over its L frequencies (BARF's alpha in [0, L]; the raw coordinates it
appends are always on), for a multiresolution grid alpha = 1 + window x (L - 1) over its L levels (the coarsest
level is always on: a grid with no level is no field; the progressive levels of hash-grid methods that activate
"shared hash grids from low to high resolution"). ``window`` starts at 1, every band on: the encoding is unchanged
until a hook says otherwise.

Imports only torch: generated plugins import this module.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

__all__ = ["CoarseToFine", "band_of_columns"]


def band_of_columns(layout: str, bands: int, out_dim: int, in_dim: int = 3) -> Tensor:
    """The band of every output column of an encoding (-1: a column that is always on).

    ``levels``: a grid's output, level-major (level k's features are columns k F .. k F + F - 1, F = out_dim /
    bands), Nerfstudio's ``HashEncoding``. ``sinusoids``: Nerfstudio's ``NeRFEncoding`` (its torch path), the sines
    of every input dimension's ``bands`` frequencies (dimension-major), then their cosines in the same order, then
    the raw input when it is included."""
    if bands < 1:
        raise ValueError(f"a coarse-to-fine window needs at least one band, not {bands}")
    if layout == "levels":
        if out_dim % bands:
            raise ValueError(f"{out_dim} features do not split into {bands} levels")
        return torch.arange(out_dim) // (out_dim // bands)
    if layout == "sinusoids":
        encoded = 2 * in_dim * bands
        if out_dim not in (encoded, encoded + in_dim):
            raise ValueError(f"{out_dim} features are not the sines and cosines of {in_dim} inputs at {bands} "
                             "frequencies (with or without the inputs)")
        column = torch.arange(out_dim)
        return torch.where(column < encoded, column % bands, torch.full_like(column, -1))
    raise ValueError(f"unknown band layout {layout!r} (levels, sinusoids)")


class CoarseToFine(nn.Module):
    """``encoding`` with its bands weighted by the coarse-to-fine window (``window``: see the module)."""

    part_name = "encoding_window"
    """What a schedule hook calls it (``encoding_window.window``), wherever a field holds it."""

    def __init__(self, encoding: nn.Module, bands: int, layout: str = "levels", in_dim: int = 3) -> None:
        super().__init__()
        if layout == "sinusoids" and getattr(encoding, "tcnn_encoding", None) is not None:
            encoding.tcnn_encoding = None  # the torch path's column order is the one the bands are read from
        self.encoding = encoding
        self.bands = int(bands)
        self.always_first = layout == "levels"
        self.register_buffer("band", band_of_columns(layout, self.bands, encoding.get_out_dim(), in_dim),
                             persistent=False)
        self.register_buffer("window", torch.tensor(1.0))

    def get_out_dim(self) -> int:
        return self.encoding.get_out_dim()

    def alpha(self) -> Tensor:
        """Nerfies' alpha from the share ``window`` (clamped to [0, 1])."""
        share = self.window.clamp(0.0, 1.0)
        return 1 + share * (self.bands - 1) if self.always_first else share * self.bands

    def weights(self) -> Tensor:
        """w_k(alpha) per output column (1 for the columns that are always on)."""
        ramp = (self.alpha() - self.band.to(self.window.dtype)).clamp(0.0, 1.0)
        return torch.where(self.band < 0, torch.ones_like(ramp), 0.5 * (1 - torch.cos(math.pi * ramp)))

    def forward(self, x: Tensor, *args, **kwargs) -> Tensor:
        features = self.encoding(x, *args, **kwargs)
        return features * self.weights().to(features.dtype)
