"""One dataset reader for every common format, read once and shared by every stage.

    from nerfify_ns.dataset import read_dataset
    ds = read_dataset("data/lego")          # Blender, D-NeRF, Nerfstudio, COLMAP or LLFF, detected
    ds.format, ds.evidence                  # 'nerfstudio', 'transforms.json (Nerfstudio format): ...'
    ds.eval_frames[0].c2w, .intrinsics      # OpenGL camera-to-world, pixels
    ds.dataparser(workdir)                  # the Nerfstudio dataparser every run uses

The formats are a table (:data:`nerfify_ns.dataset.formats.FORMATS`); a folder matching none, and any dataset
with a malformed pose, a missing, unreadable, degenerate or huge image, an image whose size disagrees with
its intrinsics, or too few views, is a one-line :class:`DatasetError`. A leaf package: numpy and Pillow only.
"""

from __future__ import annotations

from pathlib import Path

from nerfify_ns.dataset.checks import check_dataset
from nerfify_ns.dataset.formats import FORMATS, Format, dataparser_for, looked_for
from nerfify_ns.dataset.model import Dataparser, Dataset, DatasetError, Frame, Intrinsics, one_line

DataLike = str | Path | Dataset

__all__ = ["FORMATS", "DataLike", "Dataparser", "Dataset", "DatasetError", "Format", "Frame", "Intrinsics",
           "as_dataset", "dataparser_for", "read_dataset"]


def read_dataset(path: str | Path) -> Dataset:
    """The dataset in the folder ``path``: its format detected (the first row of ``FORMATS`` that matches),
    read and checked. Raises :class:`DatasetError` (one line) when it cannot be trained on."""
    root = Path(path).expanduser()
    if not root.exists():
        raise DatasetError(f"{root} does not exist; pass a dataset folder")
    if not root.is_dir():
        raise DatasetError(f"{root} is not a folder; pass a dataset folder (looked for {looked_for()})")
    root = root.absolute()
    try:
        for fmt in FORMATS:
            evidence = fmt.detect(root)
            if evidence:
                return check_dataset(fmt.read(root, evidence))
    except OSError as exc:
        raise DatasetError(f"{root}: cannot be read ({one_line(exc)})") from None
    raise DatasetError(f"{root} is not a dataset in a format we read; looked for {looked_for()}")


def as_dataset(data: DataLike) -> Dataset:
    """``data`` itself when it is a :class:`Dataset`, else the dataset read from that folder."""
    return data if isinstance(data, Dataset) else read_dataset(data)
