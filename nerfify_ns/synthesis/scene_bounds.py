"""Near and far planes of a bounded scene: where the cameras' rays can meet the box the field lives in.

A bounded scene's field has density only inside the dataparser's scene box (no contraction: Nerfacto's field
zeroes the density outside it). Nerfacto's defaults, near 0.05 and far 1000, are made for contracted unbounded
scenes; on a bounded one the proposal sampler's first round puts most of its samples where nothing can be (half
of them uniformly before distance 1, the rest spaced in disparity out to 1000), so a short run spends its samples
on empty space. Here near is the smallest distance from a camera centre to the box (kept as the plan has it when
a camera is inside the box) and far the largest distance from a camera centre to a corner of the box: every
point of the box seen by any camera lies between them.

Only for formats whose dataparser uses the poses as given, with a fixed box (Nerfstudio's ``blender-data`` and
``dnerf-data``: ``[-1.5, 1.5]^3``, ``scale_factor`` 1); the others rescale the poses when they are read, and are
left as the plan has them.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from nerfify_ns.dataset import Dataset

RUN_BOX_HALF_SIZE = {"blender": 1.5, "dnerf": 1.5}
"""Half the side of the scene box the format's Nerfstudio dataparser uses (poses as given)."""


def _round(value: float, up: bool) -> float:
    """``value`` to 3 significant digits, rounded down (near) or up (far) so the box stays between the planes."""
    step = 10.0 ** (math.floor(math.log10(value)) - 2)
    return round((math.ceil(value / step) if up else math.floor(value / step)) * step, 12)


def near_far(dataset: Dataset) -> tuple[float | None, float | None, str]:
    """``(near, far, evidence)`` for the run's coordinates; ``None`` where not known (the plan's value stays)."""
    half = RUN_BOX_HALF_SIZE.get(dataset.format)
    if half is None:
        return None, None, f"{dataset.format} poses are rescaled by the dataparser; the plan's planes stay"
    centres = np.asarray(dataset.poses(dataset.frames), dtype=np.float64)[:, :3, 3]
    inside = np.clip(centres, -half, half)
    nearest = np.linalg.norm(inside - centres, axis=1)
    corners = np.array(list(itertools.product((-half, half), repeat=3)))
    farthest = np.linalg.norm(centres[:, None, :] - corners[None], axis=2).max()
    far = _round(float(farthest), up=True)
    box = f"the {dataset.format} dataparser's box [-{half}, {half}]^3"
    if (nearest <= 0).any():
        return None, far, f"a camera is inside {box}; far {far} reaches its farthest corner"
    near = _round(float(nearest.min()), up=False)
    return near, far, (f"{len(centres)} cameras {nearest.min():.3g} to {farthest:.3g} from {box}: near {near}, "
                       f"far {far}")
