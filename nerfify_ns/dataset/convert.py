"""Write a dataset in another format, with its exact poses and intrinsics.

* :func:`write_nerfstudio_transforms`: the Nerfstudio ``transforms.json`` a run reads for a format Nerfstudio
  has no dataparser for (LLFF): absolute image paths, per-frame intrinsics, the dataset's own split as
  ``train_filenames``/``val_filenames``/``test_filenames``.
* :func:`export_dataset`: a whole dataset folder (images copied) as Nerfstudio (with or without masks, with
  intrinsics at the top or per frame), COLMAP (``sparse/0`` binary or text + ``images/``), LLFF
  (``poses_bounds.npy`` + ``images/``), Blender or D-NeRF. Tests build every format from our procedural
  scenes with it.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from nerfify_ns.dataset import colmap as colmap_io
from nerfify_ns.dataset.model import SPLITS, Dataset, Frame, Intrinsics

EXPORT_FORMATS = ("nerfstudio", "colmap", "llff", "blender", "dnerf")
DEFAULT_BOUNDS = (0.1, 100.0)


def _intrinsics_json(intr: Intrinsics) -> dict:
    out = {"fl_x": intr.fx, "fl_y": intr.fy, "cx": intr.cx, "cy": intr.cy, "w": intr.width, "h": intr.height}
    named = dict(intr.distortion)
    if any(k.startswith("d") for k in named):
        out["distortion_params"] = [named[f"d{i}"] for i in range(6)]
    else:
        out.update(named)
    return out


def _camera_model(intr: Intrinsics) -> str:
    return intr.model if intr.model in colmap_io.SUPPORTED else "OPENCV"


def write_nerfstudio_transforms(dataset: Dataset, folder: Path) -> Path:
    """``folder/transforms.json`` naming ``dataset``'s images by absolute path, with per-frame intrinsics and
    the dataset's split (``val`` = the test views when it has no validation views); returns ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    used = [f for f in dataset.frames if f.split in SPLITS]
    frames = [{"file_path": str(f.image.resolve()), "transform_matrix": f.c2w.tolist(),
               **_intrinsics_json(f.intrinsics), **({"mask_path": str(f.mask.resolve())} if f.mask else {})}
              for f in used]
    lists = {s: [str(f.image.resolve()) for f in used if f.split == s] for s in SPLITS}
    lists["val"] = lists["val"] or lists["test"]
    meta = {"camera_model": _camera_model(used[0].intrinsics), "frames": frames,
            **{f"{s}_filenames": names for s, names in lists.items()},
            "nerfify": {"converted_from": dataset.format, "root": str(dataset.root)}}
    (folder / "transforms.json").write_text(json.dumps(meta, indent=1) + "\n")
    return folder


# ------------------------------------------------------------------------------------------ export


def _save_image(frame: Frame, dest: Path, rgb: bool) -> None:
    dest.parent.mkdir(parents=True, exist_ok=True)
    if not rgb:
        if frame.image.suffix.lower() == dest.suffix.lower():
            shutil.copyfile(frame.image, dest)
            return
    from PIL import Image

    with Image.open(frame.image) as im:
        if rgb and im.mode == "RGBA":
            canvas = Image.new("RGB", im.size, (255, 255, 255))
            canvas.paste(im, mask=im.getchannel("A"))
            im = canvas
        im.save(dest)


def _save_mask(frame: Frame, dest: Path) -> None:
    """A mask from the image's alpha channel (255 where anything covers the pixel), or all 255."""
    from PIL import Image

    dest.parent.mkdir(parents=True, exist_ok=True)
    with Image.open(frame.image) as im:
        alpha = np.asarray(im.getchannel("A")) if im.mode == "RGBA" else np.full(im.size[::-1], 255, np.uint8)
    Image.fromarray(np.where(alpha > 0, 255, 0).astype(np.uint8), mode="L").save(dest)


def _names(frames: list[Frame], suffix: str) -> list[str]:
    """Unique, order-preserving file names: ``0007_train_r_3.png``."""
    return [f"{i:04d}_{f.split or 'x'}_{f.stem}{suffix}" for i, f in enumerate(frames)]


def export_dataset(dataset: Dataset, fmt: str, out: Path, *, rgb: bool = False, masks: bool = False,
                   per_frame_intrinsics: bool = False, binary: bool = True, keep_split: bool = False,
                   bounds: tuple | None = None) -> Path:
    """Write ``dataset`` (every frame, images copied) into the new folder ``out`` as ``fmt``.

    ``rgb``: composite RGBA images on white and save RGB; ``masks`` (Nerfstudio): a mask per frame from the
    alpha channel; ``per_frame_intrinsics`` (Nerfstudio): intrinsics on every frame instead of the top;
    ``binary`` (COLMAP): ``.bin`` model files, else ``.txt``; ``keep_split`` (Nerfstudio): the dataset's split as
    ``*_filenames`` lists (else Nerfstudio's own split applies); ``bounds`` (LLFF): near/far of every image
    (default the scene's, else 0.1 and 100)."""
    if fmt not in EXPORT_FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; one of {', '.join(EXPORT_FORMATS)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=False)
    frames = list(dataset.frames)
    if fmt in ("blender", "dnerf"):
        return _export_blender(dataset, frames, out, timed=fmt == "dnerf", rgb=rgb)
    names = _names(frames, ".png" if rgb or frames[0].image.suffix.lower() == ".png" else frames[0].image.suffix)
    for frame, name in zip(frames, names, strict=False):
        _save_image(frame, out / "images" / name, rgb)
    if fmt == "nerfstudio":
        _export_nerfstudio(frames, names, out, masks=masks, per_frame=per_frame_intrinsics, keep_split=keep_split)
    elif fmt == "colmap":
        _export_colmap(frames, names, out / "sparse" / "0", binary)
    else:
        scene = dataset.meta.get("scene") or {}
        near_far = bounds or ((scene["near"], scene["far"]) if scene.get("near") and scene.get("far")
                              else DEFAULT_BOUNDS)
        _export_llff(frames, out, near_far)
    return out


def _export_nerfstudio(frames: list[Frame], names: list[str], out: Path, *, masks: bool, per_frame: bool,
                       keep_split: bool) -> None:
    intr = [_intrinsics_json(f.intrinsics) for f in frames]
    top = not per_frame and all(i == intr[0] for i in intr)
    meta: dict[str, object] = {"camera_model": _camera_model(frames[0].intrinsics)}
    if top:
        meta.update(intr[0])
    rows = []
    for frame, name, cam in zip(frames, names, intr, strict=False):
        row = {"file_path": f"images/{name}", "transform_matrix": frame.c2w.tolist(), **({} if top else cam)}
        if masks:
            mask = f"masks/{Path(name).with_suffix('.png').name}"
            _save_mask(frame, out / mask)
            row["mask_path"] = mask
        rows.append(row)
    meta["frames"] = rows
    if keep_split:
        for split in SPLITS:
            meta[f"{split}_filenames"] = [f"images/{n}" for f, n in zip(frames, names, strict=False)
                                          if f.split == split]
    (out / "transforms.json").write_text(json.dumps(meta, indent=2) + "\n")


def _export_colmap(frames: list[Frame], names: list[str], folder: Path, binary: bool) -> None:
    cameras: dict[tuple, colmap_io.ColmapCamera] = {}
    images = []
    for i, (frame, name) in enumerate(zip(frames, names, strict=False), 1):
        intr = frame.intrinsics
        key = (intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height)
        if key not in cameras:
            cameras[key] = colmap_io.ColmapCamera(len(cameras) + 1, "PINHOLE", intr.width, intr.height,
                                                  (intr.fx, intr.fy, intr.cx, intr.cy))
        c2w_cv = frame.c2w.copy()
        c2w_cv[0:3, 1:3] *= -1  # OpenGL -> OpenCV camera axes
        w2c = np.linalg.inv(c2w_cv)
        q = colmap_io.rotation_to_qvec(w2c[:3, :3])
        images.append(colmap_io.ColmapImage(i, tuple(q), tuple(w2c[:3, 3]), cameras[key].id, name))
    writer = colmap_io.write_model_binary if binary else colmap_io.write_model_text
    writer(folder, list(cameras.values()), images)


def _export_llff(frames: list[Frame], out: Path, near_far: tuple) -> None:
    rows = []
    for frame in frames:
        c2w, intr = frame.c2w, frame.intrinsics
        m = np.zeros((3, 5))
        m[:, 0], m[:, 1], m[:, 2], m[:, 3] = -c2w[:3, 1], c2w[:3, 0], c2w[:3, 2], c2w[:3, 3]  # [down, right, back]
        m[:, 4] = (intr.height, intr.width, intr.fx)
        rows.append(np.concatenate([m.ravel(), near_far]))
    np.save(out / "poses_bounds.npy", np.array(rows, dtype=np.float64))


def _export_blender(dataset: Dataset, frames: list[Frame], out: Path, *, timed: bool, rgb: bool) -> Path:
    import math

    for split in SPLITS:
        rows = []
        chosen = [f for f in frames if f.split == split]
        intr = (chosen or frames)[0].intrinsics
        for i, frame in enumerate(chosen):
            _save_image(frame, out / split / f"r_{i}.png", rgb)
            row = {"file_path": f"./{split}/r_{i}", "transform_matrix": frame.c2w.tolist()}
            if timed:
                row["time"] = frame.time if frame.time is not None else i / max(len(chosen) - 1, 1)
            rows.append(row)
        angle = 2.0 * math.atan(0.5 * intr.width / intr.fx)
        (out / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": angle, "frames": rows},
                                                                 indent=2) + "\n")
    return out
