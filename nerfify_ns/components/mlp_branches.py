"""A backbone MLP with separate density and colour branches.

A trunk MLP (with Nerfstudio's skip connections: the encoded input concatenated again before the given layers,
NeRF, Mildenhall et al. 2020, arXiv 2003.08934, Appendix A, Fig. 7) followed by two branches: one whose output the
density head reads and one whose output (the geometry features) the colour head reads, each with its own depth
and width (the density and colour pathways of NeRF's architecture, Fig. 7, made separate MLPs).
``forward(x) -> cat(density branch, colour branch)``; ``density_dim`` and ``color_dim`` say where the split lies.

Imports only torch and nerfstudio: generated plugins import this module.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from nerfstudio.field_components.mlp import MLP
from torch import Tensor, nn

__all__ = ["BranchedMLP"]


class BranchedMLP(nn.Module):
    """trunk (``num_layers`` x ``layer_width``, ReLU, skips) -> density branch (``density_layers`` x
    ``density_width``) and colour branch (``color_layers`` x ``color_width``), both ReLU."""

    def __init__(self, in_dim: int, num_layers: int = 8, layer_width: int = 256,
                 skip_connections: Sequence[int] | None = (4,), density_layers: int = 1, density_width: int = 128,
                 color_layers: int = 1, color_width: int = 128, implementation: str = "torch") -> None:
        super().__init__()
        skips = tuple(s for s in (skip_connections or ()) if 0 < s < num_layers - 1) or None
        self.trunk = MLP(in_dim=in_dim, num_layers=num_layers, layer_width=layer_width, skip_connections=skips,
                         activation=nn.ReLU(), out_activation=nn.ReLU(), implementation=implementation)
        self.density_branch = MLP(in_dim=layer_width, num_layers=density_layers, layer_width=density_width,
                                  activation=nn.ReLU(), out_activation=nn.ReLU(), implementation=implementation)
        self.color_branch = MLP(in_dim=layer_width, num_layers=color_layers, layer_width=color_width,
                                activation=nn.ReLU(), out_activation=nn.ReLU(), implementation=implementation)
        self.density_dim, self.color_dim = density_width, color_width

    def get_out_dim(self) -> int:
        return self.density_dim + self.color_dim

    def forward(self, x: Tensor) -> Tensor:
        h = self.trunk(x)
        return torch.cat([self.density_branch(h), self.color_branch(h)], dim=-1)
