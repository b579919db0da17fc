"""Shared fixtures: small generated scenes, the shared paper folder, LPIPS weight isolation."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from nerfify_ns.runtime.lpips import CONVERTED_ALEXNET_FILE, nerfify_cache_dir

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory) -> Path:
    """The default scene at 32x32 with few views: the CI smoke-train scene."""
    from nerfify_ns.scenes import write_scene

    return write_scene("default", tmp_path_factory.mktemp("scenes") / "default", resolution=32,
                       n_train=12, n_val=2, n_test=2)


@pytest.fixture()
def no_lpips_weights(tmp_path, monkeypatch):
    """An environment where no AlexNet weights can be found."""
    from nerfify_ns.runtime import lpips

    monkeypatch.setenv(lpips.ENV_WEIGHTS, "")  # recorded, so set_lpips_weights() is undone after the test
    monkeypatch.setenv(lpips.ENV_CACHE, str(tmp_path / "cache"))
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.setattr(lpips, "_explicit_path", None)
    monkeypatch.setattr(lpips, "_warned", False)
    return tmp_path


def installed_lpips_weights() -> Path:
    """The converted weights from ``scripts/setup.sh --lpips`` (CI runs it), or skip saying so."""
    path = Path(os.environ.get("NERFIFY_LPIPS_WEIGHTS", nerfify_cache_dir() / "lpips" / CONVERTED_ALEXNET_FILE))
    if not path.is_file():
        pytest.skip(f"real LPIPS weights not installed at {path}: run 'scripts/setup.sh --lpips' (CI does)")
    return path


@pytest.fixture(scope="session", autouse=True)
def cpu_path_even_with_cuda():
    """The suite checks the CPU and offline path. On a machine with CUDA the runtime layer stays off by design
    (``nerfify_ns.runtime.activate``), so there the suite asks for it (``NERFIFY_RUNTIME=force``, inherited by every
    ns-train and sandboxed probe it starts); ``tests/runtime/test_runtime.py`` checks the default (``auto``) on
    the hardware itself."""
    import torch

    if not torch.cuda.is_available() or os.environ.get("NERFIFY_RUNTIME"):
        yield
        return
    os.environ["NERFIFY_RUNTIME"] = "force"
    try:
        yield
    finally:
        os.environ.pop("NERFIFY_RUNTIME", None)
