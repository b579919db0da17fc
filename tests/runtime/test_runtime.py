"""The runtime layer switches itself on without CUDA, off with it, and registers with Nerfstudio."""

import json
import subprocess
import sys
import textwrap

import pytest
import torch

CUDA = torch.cuda.is_available()
AUTO = {"NERFIFY_RUNTIME": "auto"}
"""The runtime's default switch (the suite forces the CPU path on a machine with CUDA: tests/conftest.py)."""

PROBE = """
import json, sys, torch
{prelude}
from nerfify_ns.runtime import activate
applied = activate()
import torchmetrics.image.lpip as tm
from nerfstudio.field_components.encodings import HashEncoding
from nerfify_ns.runtime import nerfacc_cpu
from nerfstudio.engine.optimizers import OptimizerConfig
from nerfstudio.field_components.spatial_distortions import SceneContraction
from nerfacc.estimators.occ_grid import OccGridEstimator
print(json.dumps({{
    "optimizer": OptimizerConfig.setup.__module__,
    "contraction": SceneContraction.forward.__module__,
    "occupancy": OccGridEstimator._update.__module__,
    "denormal_kept": bool((torch.full((1 << 20,), 1e-39) * 1.0 != 0).any()),
    "applied": applied,
    "lpips": tm.LearnedPerceptualImagePatchSimilarity.__name__,
    "hash": HashEncoding.pytorch_fwd.__module__,
    "nerfacc": nerfacc_cpu.is_installed(),
}}))
"""


def probe(prelude: str = "", env: dict | None = None) -> dict:
    import os

    code = PROBE.format(prelude=textwrap.dedent(prelude))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(CUDA, reason="CUDA is available here: the runtime layer stays off (see the test below)")
def test_active_without_cuda():
    state = probe(env=AUTO)
    assert state["applied"] == ["lpips", "nerfacc", "hashgrid", "cpu_default", "seeded_workers", "denormals",
                                "fused_optimizer", "contraction", "occupancy_chunks", "freed_memory",
                                "density_reuse", "splatting"]
    assert state["lpips"] == "OfflineLPIPS"
    assert {state[k] for k in ("optimizer", "contraction", "occupancy")} == {"nerfify_ns.runtime.fused"}
    assert state["denormal_kept"] is False
    assert state["hash"] == "nerfify_ns.runtime.hashgrid"
    assert state["nerfacc"] is True


@pytest.mark.skipif(not CUDA, reason="no CUDA on this machine (the mocked test above covers the switch)")
def test_changes_nothing_on_a_machine_with_cuda():
    """The real thing, not a mock: with a GPU, nothing is patched and Nerfstudio's own classes stay."""
    state = probe(env=AUTO)
    assert state["applied"] == []
    assert state["lpips"] == "LearnedPerceptualImagePatchSimilarity"
    assert state["hash"] == "nerfstudio.field_components.encodings"
    assert state["nerfacc"] is False
    assert state["optimizer"] == "nerfstudio.engine.optimizers"
    assert state["contraction"] == "nerfstudio.field_components.spatial_distortions"
    assert state["occupancy"] == "nerfacc.estimators.occ_grid"
    assert state["denormal_kept"] is True


def test_changes_nothing_when_cuda_is_available():
    state = probe("torch.cuda.is_available = lambda: True", env=AUTO)  # the suite forces the runtime on CUDA machines
    assert state["applied"] == []
    assert state["lpips"] == "LearnedPerceptualImagePatchSimilarity"
    assert state["hash"] == "nerfstudio.field_components.encodings"
    assert state["nerfacc"] is False
    assert state["optimizer"] == "nerfstudio.engine.optimizers"
    assert state["contraction"] == "nerfstudio.field_components.spatial_distortions"
    assert state["occupancy"] == "nerfacc.estimators.occ_grid"
    assert state["denormal_kept"] is True


def test_switch_off_and_skip():
    assert probe(env={"NERFIFY_RUNTIME": "off"})["applied"] == []
    state = probe(env={"NERFIFY_RUNTIME_SKIP": "hashgrid"})
    assert "hashgrid" not in state["applied"] and state["hash"] == "nerfstudio.field_components.encodings"


def test_unknown_skip_name_is_an_error(monkeypatch):
    from nerfify_ns import runtime

    monkeypatch.setenv(runtime.ENV_SKIP, "hashgird")
    with pytest.raises(ValueError, match="hashgird"):
        runtime.activate(force=True)  # forced: with CUDA present, activate() would not read the names at all


def test_entry_point_registers_a_method_specification():
    from importlib.metadata import entry_points

    from nerfstudio.plugins.types import MethodSpecification

    (ep,) = [e for e in entry_points(group="nerfstudio.method_configs") if e.name == "nerfify-generated"]
    spec = ep.load()
    assert isinstance(spec, MethodSpecification)
    assert spec.config.method_name == "nerfify-generated"


@pytest.mark.skipif(CUDA, reason="CUDA is available here: methods keep Nerfstudio's cuda default")
def test_plain_ns_train_discovers_us_and_defaults_to_cpu():
    code = ("from nerfstudio.configs.method_configs import all_methods;"
            "from nerfify_ns.runtime import active_patches;"
            "print(all_methods['nerfacto'].machine.device_type, 'nerfify-generated' in all_methods,"
            " 'hashgrid' in active_patches())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env={**__import__("os").environ, **AUTO})
    assert out.stdout.split() == ["cpu", "True", "True"], out.stderr[-2000:]


def test_nerfstudio_checkpoints_with_numpy_scalars_load_safely(tmp_path):
    import numpy as np
    import torch

    from nerfify_ns.runtime import activate

    activate()
    path = tmp_path / "step.ckpt"
    torch.save({"step": np.int64(7), "scale": np.float64(0.5)}, path)
    loaded = torch.load(path, map_location="cpu")  # weights_only=True is torch's default
    assert int(loaded["step"]) == 7 and float(loaded["scale"]) == 0.5
