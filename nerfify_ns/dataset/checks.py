"""What a dataset must satisfy before anything trains on it, checked once on the typed dataset.

Formats check their own syntax while reading (poses are finite 4x4 rigid transforms, intrinsics positive and
finite); here: enough views, a training and a held-out split, every image present, readable, neither
degenerate nor huge (sizes from the header, nothing decoded) and of the size its intrinsics declare, one
channel layout, masks the size of their images, principal points inside the image, cameras not all in one
place. Each failure is a one-line :class:`DatasetError` naming the frame and what was expected.
"""

from __future__ import annotations

import numpy as np

from nerfify_ns.dataset.formats import BY_NAME, show
from nerfify_ns.dataset.images import MASK_MODES, ImageProblem, inspect_image
from nerfify_ns.dataset.model import Dataset, DatasetError, Frame

MIN_IMAGES = 2
"""Fewest images of a dataset: one to train on and one held out, at the very least."""

SPLIT_RULES = {
    "blender": "transforms_test.json",
    "dnerf": "transforms_test.json",
    "nerfstudio": "test_filenames, else 10% of the frames (Nerfstudio's nerfstudio-data split)",
    "colmap": "test_list.txt, else every 8th image (Nerfstudio's colmap split)",
    "llff": "every 8th image (the LLFF convention)",
}


def _where(ds: Dataset, frame: Frame) -> str:
    return f"{ds.root}: frame {frame.name}"


def check_dataset(ds: Dataset) -> Dataset:
    """``ds`` when it can be trained on, else the first problem as a :class:`DatasetError`."""
    if len(ds.frames) < MIN_IMAGES:
        raise DatasetError(f"{ds.root}: the {BY_NAME[ds.format].title} dataset holds {len(ds.frames)} image; "
                           f"at least {MIN_IMAGES} are needed (views to train on and a held-out view)")
    for split, needed in (("train", "training"), ("test", "held-out (test)")):
        if not ds.split(split):
            raise DatasetError(f"{ds.root}: no {needed} view among its {len(ds.frames)} images; the held-out "
                               f"views come from {SPLIT_RULES[ds.format]}")
    channels: dict[int, Frame] = {}
    for frame in ds.frames:
        _check_frame(ds, frame, channels)
    centres = ds.poses()[:, :3, 3]
    spread = float(np.abs(centres - centres[0]).max())
    if spread <= 1e-9 * max(1.0, float(np.abs(centres).max())):
        raise DatasetError(f"{ds.root}: all {len(ds.frames)} cameras are at the same position "
                           f"{centres[0].round(6).tolist()}; a NeRF needs views from different places")
    return ds


def _check_frame(ds: Dataset, frame: Frame, channels: dict[int, Frame]) -> None:
    where = _where(ds, frame)
    intr = frame.intrinsics
    try:
        info = inspect_image(frame.image)
    except ImageProblem as exc:
        raise DatasetError(f"{where}: image {show(frame.image, ds.root)} {exc}") from None
    if (info.width, info.height) != (intr.width, intr.height):
        declared = ds.meta.get("declares_size", "its intrinsics")
        raise DatasetError(f"{where}: image {show(frame.image, ds.root)} is {info.width}x{info.height} pixels, "
                           f"but {declared} declares {intr.width}x{intr.height}")
    if not (0.0 <= intr.cx <= intr.width and 0.0 <= intr.cy <= intr.height):
        raise DatasetError(f"{where}: principal point ({intr.cx:g}, {intr.cy:g}) lies outside the "
                           f"{intr.width}x{intr.height} image (intrinsics for another image size?)")
    layout = 4 if info.channels == 4 else 3  # Nerfstudio turns grey images into 3 channels
    channels.setdefault(layout, frame)
    if len(channels) > 1:
        first = channels[7 - layout]
        raise DatasetError(f"{where}: image {show(frame.image, ds.root)} has {'an' if layout == 4 else 'no'} "
                           f"alpha channel but {first.name} has {'no' if layout == 4 else 'an'} alpha channel "
                           "(Nerfstudio batches images of one channel layout)")
    if frame.mask is not None:
        try:
            mask = inspect_image(frame.mask, modes=MASK_MODES)
        except ImageProblem as exc:
            raise DatasetError(f"{where}: mask {show(frame.mask, ds.root)} {exc}") from None
        if (mask.width, mask.height) != (info.width, info.height):
            raise DatasetError(f"{where}: mask {show(frame.mask, ds.root)} is {mask.width}x{mask.height} pixels "
                               f"but its image is {info.width}x{info.height}")
