"""A backbone MLP with layer normalisation after each hidden layer.

Nerfstudio's MLP (``nerfstudio.field_components.mlp.MLP``: ``num_layers`` linear layers of ``layer_width`` units,
ReLU, the input concatenated again before the layers in ``skip_connections``, NeRF, Mildenhall et al. 2020, arXiv
2003.08934, Appendix A) with Layer Normalization (Ba, Kiros and Hinton 2016, arXiv 1607.06450, Eq. 3-4: each
sample's pre-activations normalised over the units to zero mean and unit variance, then a learned per-unit gain
and bias) after every hidden layer's linear map and before its activation. A hidden layer is each linear map of
``layer_width`` units: every layer but an output projection to ``out_dim``.

Imports only torch and nerfstudio: generated plugins import this module.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from nerfstudio.field_components.base_field_component import FieldComponent
from torch import Tensor, nn

__all__ = ["NormedMLP"]


class NormedMLP(FieldComponent):
    """``num_layers`` x ``layer_width`` MLP: Linear -> LayerNorm -> ReLU per hidden layer (skips as Nerfstudio's
    MLP); with ``out_dim`` the last layer is a plain linear projection followed by ``out_activation``."""

    def __init__(self, in_dim: int, num_layers: int = 8, layer_width: int = 256, out_dim: int | None = None,
                 skip_connections: Sequence[int] | None = (4,), out_activation: nn.Module | None = None,
                 eps: float = 1e-5) -> None:
        super().__init__()
        if in_dim <= 0 or num_layers < 1 or layer_width < 1:
            raise ValueError("NormedMLP needs in_dim > 0, num_layers >= 1 and layer_width >= 1")
        self.in_dim, self.num_layers, self.layer_width = in_dim, num_layers, layer_width
        self.out_dim = layer_width if out_dim is None else out_dim
        self.skips = frozenset(s for s in (skip_connections or ()) if 0 < s < num_layers)
        widths_in = [in_dim] + [layer_width + (in_dim if i in self.skips else 0) for i in range(1, num_layers)]
        widths_out = [layer_width] * (num_layers - 1) + [self.out_dim]
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(widths_in, widths_out, strict=True))
        # a norm after every hidden layer: all but a final projection to out_dim
        normed = num_layers if out_dim is None else num_layers - 1
        self.norms = nn.ModuleList(nn.LayerNorm(layer_width, eps=eps) for _ in range(normed))
        self.activation = nn.ReLU()
        self.out_activation = out_activation

    def get_out_dim(self) -> int:
        return self.out_dim

    def forward(self, in_tensor: Tensor) -> Tensor:
        x = in_tensor
        last = self.num_layers - 1
        for i, layer in enumerate(self.layers):
            if i in self.skips:
                x = torch.cat([in_tensor, x], dim=-1)
            x = layer(x)
            if i < len(self.norms):
                x = self.norms[i](x)
            if i < last:
                x = self.activation(x)
        if self.out_activation is not None:
            x = self.out_activation(x)
        return x
