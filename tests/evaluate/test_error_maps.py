"""Error maps find planted corruptions and stay quiet on a clean render."""

import json

import numpy as np
import pytest
from PIL import Image

from nerfify_ns.evaluate import error_maps as em
from nerfify_ns.evaluate.metrics import psnr


def _texture(h=64, w=80):
    yy, xx = np.mgrid[0:h, 0:w] / 8.0
    return np.stack([0.5 + 0.3 * np.sin(xx), 0.5 + 0.3 * np.cos(yy), 0.5 + 0.2 * np.sin(xx + yy)], axis=-1)


def _noisy(gt, sigma, seed=0):
    return np.clip(gt + sigma * np.random.default_rng(seed).standard_normal(gt.shape), 0, 1)


def _iou(a, b):
    ix = max(0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    area = lambda r: (r[2] - r[0]) * (r[3] - r[1])  # noqa: E731
    return inter / (area(a) + area(b) - inter)


def _planted(gt, box, seed=1):
    x0, y0, x1, y1 = box
    pred = _noisy(gt, 0.01)
    pred[y0:y1, x0:x1] = np.random.default_rng(seed).random((y1 - y0, x1 - x0, 3))
    return pred


@pytest.mark.parametrize("box", [(20, 10, 36, 22), (0, 40, 12, 64), (60, 5, 78, 30)])
def test_top_region_overlaps_planted_rectangle(box):
    gt = _texture()
    view = em.analyze_view(_planted(gt, box), gt)
    assert view.regions, "the corrupted rectangle was not found"
    top = view.regions[0]
    assert _iou(top.box, box) > 0.5
    assert top.local_psnr < 15.0 and top.mean_error > view.threshold
    x0, y0, x1, y1 = box
    cy, cx = (y0 + y1) // 2, (x0 + x1) // 2
    assert view.psnr_map[cy, cx] < 15.0 and np.nanmin(view.ssim_map[cy - 1 : cy + 2, cx - 1 : cx + 2]) < 0.5


def test_regions_ranked_by_total_error():
    gt = _texture()
    small, large = (5, 5, 13, 13), (40, 30, 70, 55)
    pred = _planted(gt, large, seed=2)
    pred[5:13, 5:13] = 1.0 - gt[5:13, 5:13]
    view = em.analyze_view(pred, gt)
    assert len(view.regions) >= 2
    assert _iou(view.regions[0].box, large) > 0.5 and _iou(view.regions[1].box, small) > 0.5
    assert view.regions[0].area > view.regions[1].area


def test_clean_prediction_has_no_regions():
    gt = _texture()
    pred = _noisy(gt, 0.03)  # ~30 dB of white noise: everywhere a bit wrong, nowhere badly
    view = em.analyze_view(pred, gt)
    assert view.regions == []
    assert view.threshold >= 0.01
    assert view.psnr == pytest.approx(psnr(pred, gt))
    assert 25.0 < np.median(view.psnr_map) < 35.0


def test_rgba_ground_truth_is_composited_on_white():
    gt = np.zeros((32, 32, 4))  # fully transparent: white after compositing
    pred = np.ones((32, 32, 3))
    view = em.analyze_view(pred, gt)
    assert view.psnr == np.inf and view.regions == [] and np.all(view.error == 0)


def test_panel_and_json_are_written_deterministically(tmp_path):
    gt = _texture(32, 32)
    pred = _planted(gt, (8, 8, 20, 20))
    first = em.analyze_views([pred, gt], [gt, gt], tmp_path / "a", names=["bad", "clean"])
    em.analyze_views([pred, gt], [gt, gt], tmp_path / "b", names=["bad", "clean"])
    assert first[0]["regions"] and not first[1]["regions"]
    assert json.loads((tmp_path / "a" / "error_maps.json").read_text()) == first
    assert first[1]["psnr"] is None  # inf is not JSON
    for name in ("bad", "clean"):
        a, b = tmp_path / "a" / f"{name}_errors.png", tmp_path / "b" / f"{name}_errors.png"
        assert a.read_bytes() == b.read_bytes()
    panel = np.asarray(Image.open(tmp_path / "a" / "bad_errors.png"))
    assert panel.shape[0] == 192 and panel.shape[1] > 3 * 192
    assert (panel == [0, 255, 255]).all(axis=-1).sum() > 50  # the rank-1 box is drawn
