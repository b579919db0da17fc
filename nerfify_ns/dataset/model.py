"""The typed dataset every stage shares: format, frames (camera-to-world, intrinsics, split, image, mask,
time), what identified the format, and the Nerfstudio dataparser that reads it.

Conventions, whatever the format on disk:

* ``Frame.c2w`` is a 4x4 camera-to-world matrix in the dataset's own world frame with OpenGL camera axes
  (x right, y up, the camera looking along -z), as Nerfstudio's Blender and Nerfstudio formats store them.
  COLMAP's world-to-camera poses (OpenCV axes) and LLFF's ``[down, right, back]`` columns are converted to it.
* ``Intrinsics`` are pixels of the image on disk: focal lengths, principal point (pixel centres at +0.5, as
  Nerfstudio's cameras), width, height, the camera model and its distortion coefficients.
* ``Frame.split`` is the split Nerfstudio's dataparser gives the frame with the arguments of
  :meth:`Dataset.dataparser`: ``train``, ``val`` or ``test``; ``eval`` frames (``Dataset.eval_frames``) are
  the ones Nerfstudio renders for its test split, in its order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nerfify_ns.errors import NerfifyError

SPLITS = ("train", "val", "test")


class DatasetError(NerfifyError):
    """A dataset we cannot train on: unknown format, malformed poses or intrinsics, missing, unreadable or
    degenerate images. The message is one line naming the file or frame and what was expected."""

    def __init__(self, message: str) -> None:
        super().__init__(one_line(message))


def one_line(text: Any) -> str:
    """``text`` on one line: newlines and other control characters are escaped (``\\n``, ``\\x1b``)."""
    out = []
    for ch in str(text):
        out.append(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii"))
    return "".join(out)


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera (plus distortion) in pixels of the image on disk."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    model: str = "PINHOLE"
    """The camera model as the format names it (COLMAP's and Nerfstudio's ``camera_model`` names)."""
    distortion: tuple[tuple[str, float], ...] = ()
    """Distortion coefficients by name (``k1``, ``k2``, ``p1``, ...), as the format gives them."""

    def matrix(self) -> np.ndarray:
        """The 3x3 calibration matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Dataparser:
    """How Nerfstudio reads the dataset: ``ns-train METHOD --data DATA ... NAME ARGS``."""

    name: str
    """The dataparser's ``ns-train`` subcommand (``blender-data``, ``nerfstudio-data``, ``colmap``, ``dnerf-data``)."""
    args: tuple[str, ...]
    """Its arguments (after the subcommand)."""
    data: Path
    """What ``--data`` gets: the dataset folder, or a converted copy of its cameras (LLFF)."""


@dataclass(eq=False)
class Frame:
    """One image of the dataset with its camera."""

    name: str
    """The frame as the dataset names it (a ``file_path`` or a COLMAP image name)."""
    image: Path
    c2w: np.ndarray
    intrinsics: Intrinsics
    split: str
    mask: Path | None = None
    time: float | None = None

    @property
    def stem(self) -> str:
        """The image's file stem (Nerfstudio's renders of an eval view are saved under it)."""
        return self.image.stem


@dataclass(eq=False)
class Dataset:
    """A dataset folder read once: its format, its frames and how Nerfstudio reads it."""

    format: str
    """One of :data:`nerfify_ns.dataset.formats.FORMATS` (``blender``, ``dnerf``, ``nerfstudio``, ``colmap``,
    ``llff``)."""
    root: Path
    frames: list[Frame]
    evidence: str
    """What identified the format (the files found)."""
    meta: dict[str, Any] = field(default_factory=dict)
    """Format-specific facts: ``camera_angle_x`` (Blender), ``bounds`` (LLFF near/far per image), ``scene``
    (our procedural scenes' ``scene.json``), ``colmap_path`` (COLMAP model folder), ..."""

    def split(self, name: str) -> list[Frame]:
        return [f for f in self.frames if f.split == name]

    @property
    def train_frames(self) -> list[Frame]:
        return self.split("train")

    @property
    def eval_frames(self) -> list[Frame]:
        """The frames Nerfstudio renders and scores for its test split, in its order."""
        return self.split("test")

    @property
    def has_masks(self) -> bool:
        return any(f.mask is not None for f in self.frames)

    @property
    def has_times(self) -> bool:
        return bool(self.frames) and all(f.time is not None for f in self.frames)

    @property
    def image_size(self) -> tuple[int, int]:
        """(height, width) of the first training image."""
        first = (self.train_frames or self.frames)[0].intrinsics
        return first.height, first.width

    def poses(self, frames: list[Frame] | None = None) -> np.ndarray:
        """Camera-to-world matrices ``(N, 4, 4)`` of ``frames`` (default: all)."""
        chosen = self.frames if frames is None else frames
        return np.stack([f.c2w for f in chosen]) if chosen else np.zeros((0, 4, 4))

    def folders(self) -> list[Path]:
        """The folders a run reads: the dataset's own and any outside it that holds one of its images or masks
        (a sandbox makes these readable)."""
        out = [self.root]
        for f in self.frames:
            for path in (f.image, f.mask):
                if path is not None and not any(path.is_relative_to(d) for d in out):
                    out.append(path.parent)
        return out

    def describe(self) -> str:
        """One line: format, evidence, frame counts."""
        counts = ", ".join(f"{len(self.split(s))} {s}" for s in SPLITS if self.split(s))
        return f"{self.format} ({self.evidence}; {len(self.frames)} images: {counts})"

    def dataparser(self, workdir: Path | None = None) -> Dataparser:
        """The Nerfstudio dataparser that reads this dataset, the ONE choice every run uses (smoke rung,
        training, evaluation renders, patch loop, benchmarks). Formats Nerfstudio cannot read directly (LLFF)
        are converted into ``workdir`` (a Nerfstudio ``transforms.json`` naming the original images)."""
        from nerfify_ns.dataset.formats import dataparser_for

        return dataparser_for(self, workdir)

    def to_dict(self) -> dict:
        """A JSON summary (no per-frame data): format, evidence, root, counts, image size."""
        h, w = self.image_size
        return {"format": self.format, "evidence": self.evidence, "root": str(self.root),
                "images": len(self.frames), **{s: len(self.split(s)) for s in SPLITS},
                "image_size": [h, w], "masks": self.has_masks, "times": self.has_times}

    def __repr__(self) -> str:
        return f"Dataset({self.describe()!r}, root={str(self.root)!r})"


