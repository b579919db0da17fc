"""Real Nerfstudio training on the CPU, offline, in subprocesses: the CI smoke-train.

Every run goes through ``ns-train`` / ``ns-eval`` (Nerfstudio's own trainer and pipeline) under
``unshare -n`` when we are root, on a 32x32 generated scene.
"""

import math

import pytest
from conftest import installed_lpips_weights

from nerfify_ns.evaluate.smoke_train import smoke_train
from nerfify_ns.runtime.launch import ns_eval, ns_train, offline_prefix
from nerfify_ns.runtime.presets import preset_args

NO_WEIGHTS_ENV = {"NERFIFY_LPIPS_WEIGHTS": "none"}

pytestmark = pytest.mark.slow


def test_offline_sandbox_is_used():
    import os

    if os.geteuid() == 0:
        assert offline_prefix()[-1] == "-n"


def test_ci_smoke_train_nerfacto(tiny_scene, tmp_path):
    progress = []
    result = smoke_train("nerfacto", tiny_scene, tmp_path / "nerfacto", iterations=60, evaluate=False,
                         on_progress=lambda step, total: progress.append((step, total)))
    run = result.run
    assert run.ok and run.last_step == 59
    steps = [s for s, _ in progress]  # polled from the run's events while it trained
    assert steps == sorted(set(steps)) and steps[-1] == 60 and len(steps) > 2 and {t for _, t in progress} == {60}
    losses = [run.losses[s] for s in sorted(run.losses)]
    assert all(math.isfinite(v) for v in losses)
    assert sum(losses[-10:]) / 10 < 0.5 * sum(losses[:5]) / 5, "photometric loss did not go down"
    assert run.median_rays_per_sec and run.median_rays_per_sec > 0

    # one ns-eval process, with the real weights (LPIPS is null without them: tests/runtime/test_lpips_offline.py)
    weights = installed_lpips_weights()
    metrics = ns_eval(run.config_path, tmp_path / "eval_weights.json", env={"NERFIFY_LPIPS_WEIGHTS": str(weights)})
    assert metrics["psnr"] > 14.0 and 0.0 < metrics["ssim"] <= 1.0
    assert isinstance(metrics["lpips"], float) and 0.0 <= metrics["lpips"] < 1.0


# The MLP-only methods cost ~10 ms per ray on 2 cores; a smaller batch keeps CI short.
TEST_BATCH = {"vanilla-nerf": "64", "mipnerf": "64", "instant-ngp": "512"}


@pytest.mark.bench  # test_ci_smoke_train_nerfacto is CI's representative
@pytest.mark.parametrize("method", ["vanilla-nerf", "nerfacto", "instant-ngp", "mipnerf", "tensorf"])
def test_reference_methods_train_offline_on_cpu(method, tiny_scene, tmp_path):
    """The issue's bar: 20 iterations with --machine.device-type cpu, finite losses, ns-eval metrics."""
    batch = ["--pipeline.datamanager.train-num-rays-per-batch", TEST_BATCH[method]] if method in TEST_BATCH else []
    run = ns_train(method, tiny_scene, tmp_path, iterations=20,
                   method_args=[*preset_args(method), *batch, "--machine.device-type", "cpu"], env=NO_WEIGHTS_ENV)
    assert run.returncode == 0, run.log_tail()
    assert run.last_step == 19 and run.finite, run.log_tail()
    metrics = ns_eval(run.config_path, tmp_path / "eval.json", env=NO_WEIGHTS_ENV)
    assert math.isfinite(metrics["psnr"]) and math.isfinite(metrics["ssim"])
    assert metrics["lpips"] is None


def test_same_seed_same_nerfacto_run(tiny_scene, tmp_path):
    """nerfacto samples rays in a spawned worker: with the runtime's seeded workers, one
    ``--machine.seed`` gives the same losses step for step (without them step 0 already differs)."""
    args = ["--machine.seed", "7", "--pipeline.datamanager.train-num-rays-per-batch", "256"]
    runs = [ns_train("nerfacto", tiny_scene, tmp_path / f"run{k}", iterations=4,
                     method_args=[*preset_args("nerfacto"), *args], env=NO_WEIGHTS_ENV) for k in range(2)]
    for run in runs:
        assert run.ok and run.last_step == 3, run.log_tail()
    assert len(runs[0].losses) == 4 and len(set(runs[0].losses.values())) > 1
    assert runs[0].losses == runs[1].losses


def test_splatfacto_trains_on_the_cpu_only_with_our_rasteriser(tiny_scene, tmp_path):
    """Nerfstudio's Gaussian splatting renders with gsplat's CUDA kernels: stock, it cannot train on a CPU; with the
    runtime's rasteriser it trains (densification included) and ns-eval scores it."""
    stock = ns_train("splatfacto", tiny_scene, tmp_path / "stock", iterations=5,
                     method_args=[*preset_args("splatfacto"), "--machine.device-type", "cpu"],
                     env={**NO_WEIGHTS_ENV, "NERFIFY_RUNTIME_SKIP": "splatting"})
    assert stock.returncode != 0 and not stock.losses, "stock splatfacto was expected to fail without CUDA"
    run = ns_train("splatfacto", tiny_scene, tmp_path / "ours", iterations=300,
                   method_args=[*preset_args("splatfacto"), "--machine.device-type", "cpu",
                                "--pipeline.model.warmup-length", "100", "--pipeline.model.refine-every", "50"],
                   env=NO_WEIGHTS_ENV)
    assert run.returncode == 0 and run.last_step == 299, run.log_tail()
    losses = [run.losses[s] for s in sorted(run.losses)]
    assert all(math.isfinite(v) for v in losses)
    assert sum(losses[-20:]) / 20 < 0.6 * sum(losses[:5]) / 5, "the photometric loss did not go down"
    assert "GSs split" in run.log_path.read_text(), "densification (driven by the 2D means' gradients) never ran"
    metrics = ns_eval(run.config_path, tmp_path / "eval.json", env=NO_WEIGHTS_ENV)
    blank = _blank_psnr(tiny_scene)
    assert metrics["psnr"] > blank + 1.5, (metrics["psnr"], blank)
    assert 0.0 < metrics["ssim"] <= 1.0


def _blank_psnr(scene) -> float:
    """The held-out PSNR of rendering nothing (the white background) on ``scene``: what a model must beat."""
    import json

    import numpy as np
    from PIL import Image

    best = 0.0
    for split in ("val", "test"):
        for frame in json.loads((scene / f"transforms_{split}.json").read_text())["frames"]:
            path = scene / frame["file_path"]
            image = np.asarray(Image.open(path if path.suffix else path.with_suffix(".png")), np.float32) / 255
            rgb = image[..., :3] * image[..., 3:] + (1 - image[..., 3:])
            best = max(best, float(-10 * np.log10(((rgb - 1) ** 2).mean())))
    return best
