"""The runtime benchmark's measurements: the FLOP count of a training step and the interleaved variant timing."""

import json
import os
import subprocess
import sys

import pytest


def test_vanilla_nerf_step_flops_match_its_mlp():
    """NeRF's 8 x 256 MLP (skip at layer 4) and 2 x 128 head over 64 coarse samples and 64 + 128 fine ones
    (Nerfstudio's PDF sampler keeps the coarse samples): the counted FLOPs of a training step are those of
    the MLPs' matrix products, forward and backward (3x forward), within 25%."""
    from nerfify_ns.benchmarks.step_timing import step_flops

    counted = step_flops("vanilla-nerf", rays=4)["flops_per_ray"]
    position, direction, width = 2 * 3 * 10 + 3, 2 * 3 * 4 + 3, 256
    trunk = position * width + 6 * width * width + (width + position) * width
    head = width * 1 + (width + direction) * 128 + 128 * 128 + 128 * 3  # density; view-dependent head, rgb
    forward_per_sample = 2 * (trunk + head)
    expected = 3 * forward_per_sample * (64 + 64 + 128)
    assert 0.75 * expected < counted < 1.25 * expected, (counted, expected)


@pytest.mark.bench
def test_variants_timing_runs_all_variants_interleaved():
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "ignore"}
    proc = subprocess.run([sys.executable, "-m", "nerfify_ns.benchmarks.step_timing", "--variants", "nerfacto",
                           "--rays", "64", "--repeats", "1"], capture_output=True, text=True, timeout=1800, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert set(result["step_seconds"]) == {"stock", "before", "fused", "after"}
    assert all(len(t) == 1 and t[0] > 0 for t in result["step_seconds"].values())
    assert result["after_rays_per_s"] == pytest.approx(64 / result["after_median_step_seconds"])
