"""Image checks before anything decodes an image: size from the header, modes Nerfstudio reads, integrity.

PNG sizes come from the file's own ``IHDR`` chunk (the first 24 bytes), other formats from Pillow's lazy
``Image.open`` (which parses the header only) with Pillow's decompression-bomb guard turned into our error,
so a 20000x20000 image is refused before a pixel is decoded.
"""

from __future__ import annotations

import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

MIN_SIDE = 8
"""Smallest image side (pixels) we train on: a 1x1 or 4x4 image is degenerate."""
MAX_SIDE = 16384
"""Largest image side (pixels)."""
MAX_PIXELS = 80_000_000
"""Largest image (pixels): beyond this a dataset is refused, not decoded."""
MODES = {"L": 1, "RGB": 3, "RGBA": 4}
"""Pillow modes Nerfstudio's InputDataset reads (as uint8 with 1, 3 or 4 channels)."""
MASK_MODES = {"1": 1, "L": 1, "P": 1}
"""Modes of a mask Nerfstudio reads (one channel)."""
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class ImageProblem(Exception):
    """What is wrong with one image (the reader adds which frame and dataset)."""


@dataclass(frozen=True)
class ImageInfo:
    width: int
    height: int
    mode: str
    format: str

    @property
    def channels(self) -> int:
        return MODES.get(self.mode, 0)


def png_size(path: Path) -> tuple | None:
    """(width, height) from a PNG's IHDR chunk, None when the file is not a PNG."""
    with open(path, "rb") as f:
        head = f.read(24)
    if not head.startswith(PNG_SIGNATURE):
        return None
    if len(head) < 24 or head[12:16] != b"IHDR":
        raise ImageProblem("is a truncated PNG (no IHDR header)")
    return struct.unpack(">II", head[16:24])


def _check_size(width: int, height: int) -> None:
    if width < MIN_SIDE or height < MIN_SIDE:
        raise ImageProblem(f"is {width}x{height} pixels, degenerate (at least {MIN_SIDE}x{MIN_SIDE} needed)")
    if max(width, height) > MAX_SIDE or width * height > MAX_PIXELS:
        raise ImageProblem(f"is {width}x{height} pixels, too large (at most {MAX_SIDE} px a side and "
                           f"{MAX_PIXELS // 1_000_000} megapixels); downscale the dataset")


def inspect_image(path: Path, *, modes=MODES, verify: bool = True) -> ImageInfo:
    """Size, mode and format of the image at ``path``, read from its header; raises :class:`ImageProblem`
    for a missing, unreadable, degenerate, huge or (``verify``) corrupt image, or a mode not in ``modes``."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.exists():
        raise ImageProblem("not found")
    if not path.is_file():
        raise ImageProblem("is not a regular file")
    try:
        size = png_size(path)
        if size is not None:
            _check_size(*size)
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                width, height = im.size
                _check_size(width, height)
                mode, fmt = im.mode, im.format or "?"
                if verify:
                    im.verify()  # chunk CRCs, truncation (PNG); decodes nothing
    except ImageProblem:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise ImageProblem(f"is too large to decode safely ({exc})") from None
    except UnidentifiedImageError:
        raise ImageProblem("is not an image Pillow can read") from None
    except (OSError, SyntaxError, ValueError, struct.error) as exc:
        raise ImageProblem(f"is unreadable ({type(exc).__name__}: {exc})") from None
    if mode not in modes:
        raise ImageProblem(f"has pixel mode {mode}; Nerfstudio reads {', '.join(sorted(modes))} images")
    return ImageInfo(width, height, mode, fmt)
