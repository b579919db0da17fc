"""Datasets we must refuse, each with one line naming the frame or file and what was expected.

The cases of the real-data and hostile-input issues go through the real CLI (``ns-nerfify PAPER --data DIR``):
exit 2, one ``error:`` line, no output folder and no staging folder left. The rest are checked on the reader
(the CLI path is the same: the dataset is read before anything is written).
"""

from __future__ import annotations

import json
import re
import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from nerfify_ns.dataset import DatasetError, read_dataset
from nerfify_ns.dataset.convert import export_dataset
from nerfify_ns.scenes import write_scene

ROOT = Path(__file__).resolve().parents[2]
CLI = Path(sys.executable).with_name("ns-nerfify")
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"
SMALL = dict(resolution=16, n_train=8, n_val=1, n_test=3)


@pytest.fixture(scope="module")
def sources(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("hostile-sources")
    blender = write_scene("default", root / "blender", **SMALL)
    source = read_dataset(blender)
    return {"blender": blender, "nerfstudio": export_dataset(source, "nerfstudio", root / "nerfstudio", rgb=True),
            "colmap": export_dataset(source, "colmap", root / "colmap", rgb=True),
            "llff": export_dataset(source, "llff", root / "llff", rgb=True),
            "dnerf": write_scene("dynamic", root / "dnerf", **SMALL)}


def copy(sources: dict, kind: str, tmp_path: Path) -> Path:
    return Path(shutil.copytree(sources[kind], tmp_path / f"{kind}-data"))


def edit_json(path: Path, change) -> None:
    meta = json.loads(path.read_text())
    change(meta)
    path.write_text(json.dumps(meta))  # NaN is written as the NaN literal Python's JSON reads


def frame_image(folder: Path, index: int) -> Path:
    return folder / json.loads((folder / "transforms.json").read_text())["frames"][index]["file_path"]


def huge_png_header(path: Path, width: int = 20000, height: int = 20000) -> None:
    """A PNG whose header declares width x height (RGB, 8 bit) with one tiny IDAT: decoding it would need
    1.2 GB; only the header may be read."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64))
                     + chunk(b"IEND", b""))


# --------------------------------------------------------------------------------------------- the CLI cases


def nan_pose(folder: Path) -> None:
    edit_json(folder / "transforms.json", lambda m: m["frames"][3]["transform_matrix"][0].__setitem__(3, float("nan")))


def wrong_shape(folder: Path) -> None:
    edit_json(folder / "transforms.json",
              lambda m: m["frames"][2].__setitem__("transform_matrix", [[1, 0, 0], [0, 1, 0], [0, 0, 1]]))


def size_mismatch(folder: Path) -> None:
    edit_json(folder / "transforms.json", lambda m: m.update(w=24))


def one_by_one(folder: Path) -> None:
    Image.new("RGB", (1, 1)).save(frame_image(folder, 5))


def huge_png(folder: Path) -> None:
    huge_png_header(frame_image(folder, 4))


def mixed_sizes(folder: Path) -> None:  # Blender: one size for the dataset (Nerfstudio reads the first image's)
    Image.new("RGBA", (24, 24)).save(folder / "train" / "r_2.png")


def missing_image(folder: Path) -> None:
    frame_image(folder, 6).unlink()


def unreadable_image(folder: Path) -> None:
    frame_image(folder, 1).write_bytes(b"this is not a PNG at all" * 10)


def one_image(folder: Path) -> None:
    edit_json(folder / "transforms.json", lambda m: m.update(frames=m["frames"][:1]))


def unknown_folder(folder: Path) -> None:
    for item in list(folder.iterdir()):
        shutil.rmtree(item) if item.is_dir() else item.unlink()
    (folder / "photos").mkdir()
    Image.new("RGB", (16, 16)).save(folder / "photos" / "a.png")
    (folder / "notes.txt").write_text("my capture")


CLI_CASES = {
    # case: (source kind, damage, what the line must say)
    "nan-pose": ("nerfstudio", nan_pose, r"transforms\.json frame 3 \(images/0003_train_r_3\.png\): transform_matrix "
                                         r"has non-finite entries"),
    "wrong-shape-matrix": ("nerfstudio", wrong_shape, r"frame 2 \(images/0002_train_r_2\.png\): transform_matrix has "
                                                     r"shape \(3, 3\), a 4x4 matrix is expected"),
    "size-disagrees-with-intrinsics": ("nerfstudio", size_mismatch, r"frame images/0000_train_r_0\.png: image "
                                       r"images/0000_train_r_0\.png is 16x16 pixels, but transforms\.json \(w, h\) "
                                       r"declares 24x16"),
    "1x1-image": ("nerfstudio", one_by_one, r"frame images/0005_train_r_5\.png: .* is 1x1 pixels, degenerate"),
    "20000x20000-png": ("nerfstudio", huge_png, r"frame images/0004_train_r_4\.png: .* is 20000x20000 pixels, "
                                                r"too large"),
    "mixed-sizes": ("blender", mixed_sizes, r"frame \./train/r_2: image train/r_2\.png is 24x24 pixels, but the first "
                                            r"image \(a Blender dataset has one image size\) declares 16x16"),
    "missing-image": ("nerfstudio", missing_image, r"frame images/0006_train_r_6\.png: image "
                                                   r"images/0006_train_r_6\.png not found"),
    "unreadable-image": ("nerfstudio", unreadable_image, r"frame images/0001_train_r_1\.png: .* is not an image "
                                                         r"Pillow can read"),
    "one-image": ("nerfstudio", one_image, r"holds 1 image; at least 2 are needed"),
    "unknown-folder": ("nerfstudio", unknown_folder, r"is not a dataset in a format we read; looked for "
                                                     r"transforms_train\.json .*transforms\.json .*poses_bounds\.npy"
                                                     r" .*sparse/0"),
}


@pytest.mark.parametrize("case", list(CLI_CASES))
def test_the_cli_refuses_a_hostile_dataset_in_one_line_and_writes_nothing(case, sources, tmp_path):
    kind, damage, needle = CLI_CASES[case]
    data = copy(sources, kind, tmp_path)
    damage(data)
    out = tmp_path / "out"
    done = subprocess.run([str(CLI), str(EXAMPLE), "--data", str(data), "--out", str(out)], capture_output=True,
                          text=True, cwd=tmp_path, timeout=120)
    lines = [line for line in (done.stdout + done.stderr).splitlines() if line.strip()]
    assert done.returncode == 2, done.stdout + done.stderr
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert re.search(needle, lines[0]), lines[0]
    assert str(data) in lines[0]
    assert not out.exists() and not list(tmp_path.glob(".out.*"))


# --------------------------------------------------------------------------------------------- on the reader


def refuses(folder: Path, needle: str) -> str:
    with pytest.raises(DatasetError) as info:
        read_dataset(folder)
    message = str(info.value)
    assert "\n" not in message and re.search(needle, message), message
    return message


def test_malformed_poses_in_every_format(sources, tmp_path):
    data = copy(sources, "nerfstudio", tmp_path)
    edit_json(data / "transforms.json", lambda m: m["frames"][0].__setitem__("transform_matrix", "identity"))
    refuses(data, r"frame 0 .*transform_matrix is not a 4x4 matrix of numbers")
    edit_json(data / "transforms.json", lambda m: m["frames"][0].__setitem__(
        "transform_matrix", (np.diag([2.0, 1.0, 1.0, 1.0])).tolist()))
    refuses(data, r"frame 0 .*does not hold a rotation")
    edit_json(data / "transforms.json", lambda m: m["frames"][0].__setitem__(
        "transform_matrix", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 1]]))
    refuses(data, r"frame 0 .*bottom row")

    blender = copy(sources, "blender", tmp_path)
    edit_json(blender / "transforms_test.json", lambda m: m["frames"][1]["transform_matrix"][2].__setitem__(
        1, float("inf")))
    refuses(blender, r"transforms_test\.json frame 1 \(\./test/r_1\): transform_matrix has non-finite")

    llff = copy(sources, "llff", tmp_path)
    poses = np.load(llff / "poses_bounds.npy")
    poses[4, 3] = np.nan
    np.save(llff / "poses_bounds.npy", poses)
    refuses(llff, r"poses_bounds\.npy pose 4 \(0004_train_r_4\.png\): has non-finite entries")
    np.save(llff / "poses_bounds.npy", poses[:, :15])
    refuses(llff, r"poses_bounds\.npy has shape \(12, 15\)")

    colmap = copy(sources, "colmap", tmp_path)
    images = colmap / "sparse" / "0" / "images.bin"
    images.write_bytes(images.read_bytes()[:100])
    refuses(colmap, r"COLMAP model sparse/0/images\.bin (ends early|declares)")
    images.write_bytes(struct.pack("<Q", 10**12))
    refuses(colmap, r"images\.bin declares 1000000000000 images but holds 0 bytes")


def test_colmap_text_models_are_checked_too(sources, tmp_path):
    colmap = copy(sources, "colmap", tmp_path)
    folder = colmap / "sparse" / "0"
    for name in ("cameras.bin", "images.bin", "points3D.bin"):
        (folder / name).unlink()
    (folder / "cameras.txt").write_text("1 PINHOLE 16 16 22.2 22.2 8 8\n")
    (folder / "images.txt").write_text("1 0.5 0.5 0.5 0.5 0 0 4 1 0000_train_r_0.png\n\n"
                                       "2 1 0 0 0 0 0 4 7 0001_train_r_1.png\n\n")
    refuses(colmap, r"image 2 \(0001_train_r_1\.png\): camera 7 is not in sparse/0/cameras\.txt")
    (folder / "images.txt").write_text("1 0.9 0.5 0.5 0.5 0 0 4 1 0000_train_r_0.png\n\n")
    refuses(colmap, r"image 1 \(0000_train_r_0\.png\): the quaternion has norm")
    (folder / "cameras.txt").write_text("1 THIN_PRISM_FISHEYE 16 16 " + " ".join(["1"] * 12) + "\n")
    (folder / "images.txt").write_text("1 1 0 0 0 0 0 4 1 0000_train_r_0.png\n\n")
    refuses(colmap, r"camera model THIN_PRISM_FISHEYE is not one we read")


def test_intrinsics_and_sizes(sources, tmp_path):
    data = copy(sources, "nerfstudio", tmp_path)
    edit_json(data / "transforms.json", lambda m: m.pop("fl_x"))
    refuses(data, r"frame 0 \(images/0000_train_r_0\.png\): no fl_x, and transforms\.json sets none")
    edit_json(data / "transforms.json", lambda m: m.update(fl_x=-3))
    refuses(data, r"fl_x is -3\.0, a positive finite number is expected")
    edit_json(data / "transforms.json", lambda m: m.update(fl_x=20, cx=80))
    refuses(data, r"principal point \(80, 8\) lies outside the 16x16 image")

    colmap = copy(sources, "colmap", tmp_path)
    Image.new("RGB", (16, 12)).save(colmap / "images" / "0007_train_r_7.png")
    refuses(colmap, r"frame 0007_train_r_7\.png: .* is 16x12 pixels, but its camera in sparse/0/cameras\.bin "
                    r"declares 16x16")

    llff = copy(sources, "llff", tmp_path)
    (llff / "images" / "0011_test_r_2.png").unlink()
    refuses(llff, r"poses_bounds\.npy holds 12 poses but images/ holds 11 images")


def test_images_nerfstudio_cannot_batch(sources, tmp_path):
    data = copy(sources, "nerfstudio", tmp_path)
    Image.new("RGBA", (16, 16)).save(frame_image(data, 3))
    refuses(data, r"frame images/0003_train_r_3\.png: .* has an alpha channel but images/0000_train_r_0\.png has no "
                  r"alpha channel")
    Image.new("P", (16, 16)).save(frame_image(data, 3))
    refuses(data, r"has pixel mode P; Nerfstudio reads L, RGB, RGBA images")
    Image.new("RGB", (16, 16)).save(frame_image(data, 3))
    path = frame_image(data, 3)
    path.write_bytes(path.read_bytes()[:-20])  # truncated: the end of its data and IEND are gone
    refuses(data, r"frame images/0003_train_r_3\.png: .* is unreadable")


def test_masks_on_every_frame_or_none_and_of_the_image_size(sources, tmp_path):
    source = read_dataset(sources["blender"])
    data = export_dataset(source, "nerfstudio", tmp_path / "masked", masks=True)
    edit_json(data / "transforms.json", lambda m: m["frames"][4].pop("mask_path"))
    refuses(data, r"frame 4: no mask_path, but 11 other frames have one")
    data = export_dataset(source, "nerfstudio", tmp_path / "masked2", masks=True)
    Image.new("L", (8, 8)).save(data / "masks" / "0002_train_r_2.png")
    refuses(data, r"frame images/0002_train_r_2\.png: mask masks/0002_train_r_2\.png is 8x8 pixels but its image "
                  r"is 16x16")


def test_splits_views_and_layouts(sources, tmp_path):
    data = copy(sources, "nerfstudio", tmp_path)
    edit_json(data / "transforms.json", lambda m: m.update(frames=m["frames"][:9]))
    refuses(data, r"no held-out \(test\) view among its 9 images; the held-out views come from test_filenames, else "
                  r"10% of the frames")
    edit_json(data / "transforms.json", lambda m: m.update(train_filenames=["images/0000_train_r_0.png"]))
    refuses(data, r"lists train_filenames but not val_filenames, test_filenames")
    edit_json(data / "transforms.json", lambda m: m.update(val_filenames=[], test_filenames=["images/nope.png"]))
    refuses(data, r"test_filenames names images/nope\.png, which no frame has")

    still = copy(sources, "nerfstudio", tmp_path / "still")
    edit_json(still / "transforms.json", lambda m: [f.__setitem__("transform_matrix", np.eye(4).tolist())
                                                   for f in m["frames"]])
    refuses(still, r"all 12 cameras are at the same position")

    blender = copy(sources, "blender", tmp_path)
    (blender / "transforms_val.json").unlink()
    refuses(blender, r"a Blender dataset needs transforms_train\.json, transforms_val\.json and transforms_test\.json; "
                     r"missing transforms_val\.json")
    blender = copy(sources, "blender", tmp_path / "suffixed")
    edit_json(blender / "transforms_train.json", lambda m: m["frames"][0].update(file_path="./train/r_0.png"))
    refuses(blender, r"frame 0 \(\./train/r_0\.png\): Nerfstudio's blender-data reads train/r_0\.png\.png "
                     r"\(file_path \+ '\.png'\), which does not exist")
    dnerf = copy(sources, "dnerf", tmp_path)
    edit_json(dnerf / "transforms_val.json", lambda m: m["frames"][0].pop("time"))
    refuses(dnerf, r"transforms_val\.json frame 0 \(\./val/r_0\): no time")

    (tmp_path / "file").write_text("x")
    refuses(tmp_path / "file", r"is not a folder")
    refuses(tmp_path / "nowhere", r"does not exist")
    bad = copy(sources, "nerfstudio", tmp_path / "bad")
    (bad / "transforms.json").write_text("[1, 2")
    refuses(bad, r"transforms\.json is not valid JSON")
    (bad / "transforms.json").write_text("[1, 2]")
    refuses(bad, r"transforms\.json holds a list, not a JSON object")


def test_control_characters_in_names_stay_on_one_line(sources, tmp_path):
    data = copy(sources, "nerfstudio", tmp_path)
    edit_json(data / "transforms.json",
              lambda m: m["frames"][0].__setitem__("file_path", "images/evil\nname\x1b[31m.png"))
    message = refuses(data, r"evil\\nname\\x1b\[31m\.png")
    assert "\x1b" not in message


def test_compose_refuses_a_hostile_dataset_the_same_way(sources, tmp_path):
    data = copy(sources, "colmap", tmp_path)
    huge_png_header(data / "images" / "0003_train_r_3.png")
    out = tmp_path / "out"
    done = subprocess.run([str(CLI), "compose", "--method", "nerfacto", "--data", str(data), "--out", str(out)],
                          capture_output=True, text=True, cwd=tmp_path, timeout=120)
    lines = [line for line in (done.stdout + done.stderr).splitlines() if line.strip()]
    assert done.returncode == 2 and len(lines) == 1, lines
    assert lines[0].startswith("error: ") and "frame 0003_train_r_3.png" in lines[0] and "20000x20000" in lines[0]
    assert not out.exists() and not list(tmp_path.glob(".out.*"))
