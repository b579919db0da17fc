"""The composer's promise: every reference plan's plugin installs with pip and trains with `ns-train <its
name> --machine.device-type cpu` for 100 iterations on a generated scene with finite losses (Nerfstudio's own
trainer, a real subprocess). The plugin is installed into a folder of the test's own on ``PYTHONPATH``, never
into the shared environment, where a plugin whose files vanish would break every other ``ns-train``.
CI trains vanilla-nerf's; the others run in the benchmark lane."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import pytest

from nerfify_ns.runtime.launch import ns_train
from nerfify_ns.runtime.presets import generated_smoke_args
from nerfify_ns.synthesis.compose import compose
from nerfify_ns.synthesis.prune import prune_plan
from nerfify_ns.synthesis.resources import load_reference_plan, reference_plans
from nerfify_ns.synthesis.scene_probe import probe_scene

ITERATIONS = 100
RAYS = {"vanilla-nerf": 64, "mipnerf": 64}  # the MLP-only methods are ~10 ms per ray on the CPU


def _pip(*args: str) -> None:
    out = subprocess.run([sys.executable, "-m", "pip", *args], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-1500:] + out.stderr[-1500:]


CI_CASE = "vanilla-nerf"


@pytest.mark.slow
@pytest.mark.parametrize("name", [pytest.param(n, marks=[] if n == CI_CASE else [pytest.mark.bench])
                                  for n in reference_plans()])
def test_reference_plugin_installs_and_trains_100_iterations(name, tiny_scene, tmp_path):
    plan = prune_plan(load_reference_plan(name), probe_scene(tiny_scene))
    plugin = compose(plan, tmp_path / "plugin", record=False)
    site = tmp_path / "site"
    _pip("install", "--no-deps", "--no-build-isolation", "--no-index", "-q", "--target", str(site), str(plugin.out))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    run = ns_train(plugin.method, tiny_scene, tmp_path / "run", iterations=ITERATIONS, timeout=900, env=env,
                   method_args=["--machine.device-type", "cpu", *generated_smoke_args(plan["base"]),
                                "--pipeline.datamanager.train-num-rays-per-batch", str(RAYS.get(name, 256))])
    assert run.ok, run.log_path.read_text()[-3000:]
    assert run.last_step + 1 >= ITERATIONS
    assert run.losses and all(math.isfinite(v) for v in run.losses.values())
