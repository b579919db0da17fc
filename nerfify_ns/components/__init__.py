"""Components missing from Nerfstudio, imported by generated plugins.

A leaf package: it imports only torch, nerfstudio and the standard library.
"""

from nerfify_ns.components.kplanes import KPlanesDensityField, MultiScaleKPlanes
from nerfify_ns.components.photometric_losses import CharbonnierLoss, charbonnier_loss
from nerfify_ns.components.regularizers import (
    density_sparsity,
    plane_l1_to_one,
    plane_tv,
    ray_entropy,
    time_smoothness,
)

__all__ = [
    "MultiScaleKPlanes",
    "KPlanesDensityField",
    "charbonnier_loss",
    "CharbonnierLoss",
    "plane_tv",
    "time_smoothness",
    "plane_l1_to_one",
    "ray_entropy",
    "density_sparsity",
]
