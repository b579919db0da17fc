"""The critic agent with a scripted model: a run's error maps summarised as text (or sent as images where the
backend reads them), the deterministic findings kept, the model's patches returned in the patch loop's own format
(``PlanPatch``), which ``apply_patch`` validates like the rule table's: a valid one applies, one the grammar refuses
does not; a failing model leaves the deterministic critic as it was (one warning)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from nerfify_ns.agents import LLMConfig
from nerfify_ns.agents.cache import ResponseCache
from nerfify_ns.agents.client import Client
from nerfify_ns.agents.critic import ModelCritic
from nerfify_ns.agents.providers import ScriptedProvider
from nerfify_ns.agents.usage import Ledger

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture()
def artifacts(tmp_path):
    from nerfify_ns.evaluate.patch_loop import RunArtifacts

    eval_dir = tmp_path / "eval"
    eval_dir.mkdir()
    (eval_dir / "summary.json").write_text(json.dumps({"status": "ok", "psnr": 18.5, "ssim": 0.6,
                                                       "losses": {"first": 0.1, "last": 0.2, "finite": True}}))
    (eval_dir / "error_maps.json").write_text(json.dumps([{"view": "r_0", "psnr": 18.0, "regions": [
        {"x0": 4, "y0": 4, "x1": 20, "y1": 20, "area": 256, "local_psnr": 11.2, "mean_error": 0.07}]}]))
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(eval_dir / "r_0_errors.png")
    plan = yaml.safe_load((ROOT / "method_configs" / "nerfacto.yaml").read_text())
    return RunArtifacts.load(eval_dir, plan, tmp_path)


def critic(answers, images=False):
    warnings = []
    config = LLMConfig(backend="scripted", model="m")
    provider = ScriptedProvider({"critic": answers})
    c = ModelCritic(Client(config, provider, ResponseCache(None), Ledger("m", True)), images, warnings.append)
    return c, provider, warnings


def test_model_patches_in_the_loops_format(artifacts):
    from nerfify_ns.evaluate.patch_loop import PatchError, apply_patch
    from nerfify_ns.grammar import PlanError

    answer = {"findings": [{"name": "blurry_edges", "severity": 3.0, "evidence": "the worst box is at the edge"}],
              "patches": [{"reason": "more samples near surfaces",
                           "edits": [{"op": "set", "path": "model.sampler.proposal.nerf_samples", "value": 64}]},
                          {"reason": "nonsense", "edits": [{"op": "set", "path": "model.sampler.proposal.nerf_samples",
                                                            "value": -5}]}]}
    c, provider, warnings = critic([json.dumps(answer)])
    findings = c.diagnose(artifacts)
    names = [f.name for f in findings]
    assert "loss_rising" in names and "model:blurry_edges" in names  # the deterministic finding stays
    text = provider.requests[0].messages[1]["content"]
    assert isinstance(text, str) and '"local_psnr": 11.2' in text and "loss_rising" in text
    good, bad = c.propose(artifacts.plan, findings, artifacts)
    assert good.rule == "model_patch_0" and good.edits[0].path == "model.sampler.proposal.nerf_samples"
    assert apply_patch(artifacts.plan, good).get("model.sampler.proposal.nerf_samples") == 64
    with pytest.raises((PatchError, PlanError)):
        apply_patch(artifacts.plan, bad)  # the loop logs it as invalid and does not train it
    assert not warnings


def test_images_where_the_backend_reads_them_and_a_failing_model(artifacts):
    c, provider, warnings = critic(['{"findings": [], "patches": []}'], images=True)
    c.diagnose(artifacts)
    parts = provider.requests[0].messages[1]["content"]
    assert [p["type"] for p in parts] == ["text", "image"] and parts[1]["png_base64"]
    broken, _, warned = critic([{"error": "http", "message": "HTTP 500"}])
    assert {f.name for f in broken.diagnose(artifacts)} == {"loss_rising", "large_error_regions"}  # deterministic
    assert broken.propose({}, [], artifacts) == []
    assert len(warned) == 1 and warned[0].startswith("llm critic: HTTP 500")
