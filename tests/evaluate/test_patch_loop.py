"""The patch loop: plan patches, the deterministic critic, keep/reject decisions, and one real loop."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from nerfify_ns.evaluate import patch_loop as pl
from nerfify_ns.grammar import PlanError, validate
from nerfify_ns.plan import Plan

NO_WEIGHTS_ENV = {"NERFIFY_LPIPS_WEIGHTS": "none"}
WEAK_SAMPLES = {"samples_per_ray": [4, 4], "nerf_samples": 2}


@pytest.fixture(scope="module")
def floaters_scene(tmp_path_factory) -> Path:
    from nerfify_ns.scenes import write_scene

    return write_scene("floaters", tmp_path_factory.mktemp("scenes") / "floaters", resolution=32, n_train=12,
                       n_val=1, n_test=4)


def pruned_nerfacto(scene: Path) -> dict:
    from nerfify_ns.synthesis.prune import prune_plan
    from nerfify_ns.synthesis.resources import load_reference_plan
    from nerfify_ns.synthesis.scene_probe import probe_scene

    plan = prune_plan(load_reference_plan("nerfacto"), probe_scene(scene))
    plan["trainer"]["mixed_precision"] = False  # CPU
    return plan


def weakened(scene: Path) -> dict:
    """Nerfacto pruned for the scene, then broken on purpose: no distortion loss and 4/4 proposal and 2 NeRF
    samples per ray (the pruned plan has 32/32 and 16)."""
    plan = pruned_nerfacto(scene)
    plan["model"]["losses"].pop("distortion")
    plan["model"]["sampler"]["proposal"].update(WEAK_SAMPLES)
    validate(plan)
    return plan


# ------------------------------------------------------------------------------ patches (fast)


def test_edits_set_add_remove_and_wildcards(floaters_scene):
    plan = weakened(floaters_scene)
    paths = Plan.of(plan).expand("optimizers.*.optimizer.*.lr")
    assert sorted(paths) == ["optimizers.fields.optimizer.adam.lr", "optimizers.proposal_networks.optimizer.adam.lr"]
    edited = Plan.of(plan).copy()
    assert pl.apply_edit(edited, pl.Edit("add", "model.losses.distortion", {"weight": 0.002})) is None
    assert pl.apply_edit(edited, pl.Edit("set", "model.losses.distortion.weight", 0.01)) == 0.002
    assert pl.apply_edit(edited, pl.Edit("remove", "model.losses.distortion")) == {"weight": 0.01}
    assert edited == plan
    with pytest.raises(pl.PatchError):
        pl.apply_edit(edited, pl.Edit("add", "model.losses.interlevel", {"weight": 1.0}))  # already there
    with pytest.raises(pl.PatchError):
        pl.apply_edit(edited, pl.Edit("remove", "model.losses.distortion"))
    with pytest.raises(pl.PatchError):
        pl.apply_edit(edited, pl.Edit("set", "model.nothing.here", 1))


def test_patches_come_from_the_rule_table_and_stay_valid(floaters_scene):
    plan = weakened(floaters_scene)
    rules = pl.load_rules()["rules"]
    diagnoses = [pl.Finding("floaters", 3.0, "many floaters"), pl.Finding("blur_high_frequency", 2.0, "blurry")]
    patches = pl.propose_patches(plan, diagnoses, rules, floaters_scene)
    names = [p.rule for p in patches]
    # round-robin over diagnoses, rules in table order; raise_distortion_loss needs a distortion loss
    assert names[:2] == ["add_distortion_loss", "more_proposal_samples"]
    assert "raise_distortion_loss" not in names and "raise_near_plane" in names
    samples = patches[1]
    assert [e.to_json() for e in samples.edits] == [
        {"op": "set", "path": "model.sampler.proposal.samples_per_ray", "value": [16, 16]},
        {"op": "set", "path": "model.sampler.proposal.nerf_samples", "value": 8},
    ]
    near = next(p for p in patches if p.rule == "raise_near_plane")
    scene_near = json.loads((floaters_scene / "scene.json").read_text())["near"]
    assert near.edits[0].value == round(0.9 * scene_near, 3) and "blurry" not in near.reason
    for patch in patches:
        patched = pl.apply_patch(plan, patch)  # validates
        assert patched != plan and patched["notes"][-1].startswith(f"patch loop: {patch.rule}")
        assert plan["model"]["sampler"]["proposal"]["nerf_samples"] == 2  # the original is untouched
    assert samples.before == {"model.sampler.proposal.samples_per_ray": [4, 4],
                              "model.sampler.proposal.nerf_samples": 2}
    # a rule whose edit breaks a grammar duty is refused by validate
    bad = pl.PlanPatch("drop_interlevel", diagnoses[0], [pl.Edit("remove", "model.losses.interlevel")], "test")
    with pytest.raises(PlanError):
        pl.apply_patch(plan, bad)
    # nothing is proposed that would not change the plan
    assert not any(p.rule == "white_background" for p in
                   pl.propose_patches(plan, [pl.Finding("background_errors", 1, "")], rules, floaters_scene))


def test_critic_reads_run_artifacts(tmp_path, floaters_scene):
    plan = weakened(floaters_scene)
    critic = pl.DeterministicCritic()
    healthy = {"status": "ok", "psnr": 25.0, "losses": {"finite": True, "first": 0.1, "last": 0.01},
               "diagnostics": {"background_fraction": 0.6, "background_error_share": 0.1, "background_psnr": 35.0,
                               "sharpness": 0.95, "high_frequency_error_ratio": 1.2}}
    art = pl.RunArtifacts(tmp_path, plan, floaters_scene, summary=healthy, consistency={"mean_score": 0.99})
    assert critic.diagnose(art) == []
    art.summary = {**healthy, "diagnostics": {**healthy["diagnostics"], "background_error_share": 0.8,
                                              "background_psnr": 15.0, "sharpness": 0.3}}
    art.consistency = {"mean_score": 0.6}
    assert {d.name for d in critic.diagnose(art)} == {"background_errors", "blur_high_frequency", "floaters"}
    art.summary = {"status": "failed", "reason": "non-finite training loss", "psnr": None,
                   "losses": {"finite": False, "first_nonfinite_step": 12}}
    (diag,) = critic.diagnose(art)
    assert diag.name == "divergence" and "step 12" in diag.evidence
    assert isinstance(critic, pl.Critic)


def _fake_eval(psnrs: dict):
    """A stand-in for training: PSNR by (plan's nerf samples, seed); writes the artefacts a critic reads."""

    def evaluate(self, plan, folder, seed, label):
        key = (plan["model"]["sampler"]["proposal"]["nerf_samples"], "distortion" in plan["model"]["losses"], seed)
        summary = {"status": "ok", "psnr": psnrs[key], "seconds": 1.0,
                   "losses": {"finite": True, "first": 0.1, "last": 0.05},
                   "diagnostics": {"background_fraction": 0.6, "background_error_share": 0.1,
                                   "background_psnr": 30.0, "sharpness": 0.2 if key[0] < 8 else 0.9,
                                   "high_frequency_error_ratio": 1.0}}
        run = folder / f"seed_{seed}"
        run.mkdir(parents=True, exist_ok=True)
        (run / "summary.json").write_text(json.dumps(summary))
        (run / "consistency.json").write_text(json.dumps({"mean_score": 0.5 if not key[1] else 0.97}))
        return summary

    return evaluate


def test_loop_keeps_only_improvements_beyond_noise(tmp_path, floaters_scene, monkeypatch):
    """Decision logic without training: round 0 tries the distortion loss (+0.1 dB, noise 0.3) and 4x samples
    (+4 dB); round 1 measures the new best (noise 0.2) and rejects the distortion loss again."""
    psnrs = {(2, False, 0): 10.5, (2, False, 1): 10.8, (2, True, 0): 10.75, (8, False, 0): 14.65,
             (8, False, 1): 14.45, (8, True, 0): 14.6}
    monkeypatch.setattr(pl.PatchLoop, "_evaluate", _fake_eval(psnrs))
    result = pl.run_patch_loop(weakened(floaters_scene), floaters_scene, tmp_path / "patches", iterations=10,
                               rounds=3, only_rules=["add_distortion_loss", "more_proposal_samples"])
    history = json.loads((tmp_path / "patches" / "history.json").read_text())
    assert history == json.loads(json.dumps(result.history))
    decisions = [(e["round"], e["patch"]["rule"], e["decision"]) for e in history["entries"]]
    assert decisions == [(0, "add_distortion_loss", "rejected"), (0, "more_proposal_samples", "kept"),
                         (1, "add_distortion_loss", "rejected")]
    first = history["entries"][0]
    assert first["psnr_before"] == pytest.approx(10.65) and first["noise"] == pytest.approx(0.3)
    assert first["improvement"] == pytest.approx(0.1) and "does not exceed" in first["reason"]
    kept = history["entries"][1]
    assert kept["improvement"] == pytest.approx(4.0) and kept["diagnosis"]["name"] == "blur_high_frequency"
    assert history["rounds"][1]["psnr_runs"] == [14.65, 14.45]  # seed 0 reused from the kept candidate
    assert history["stopped"] == "no candidate improved by more than the noise"
    best = yaml.safe_load((tmp_path / "patches" / "best_plan.yaml").read_text())
    assert best["model"]["sampler"]["proposal"]["nerf_samples"] == 8 and best == result.best_plan
    assert pl.revert(tmp_path / "patches", 0)["model"]["sampler"]["proposal"]["nerf_samples"] == 2
    for entry in history["entries"]:
        assert (tmp_path / "patches" / entry["plan"]).is_file()


# ------------------------------------------------------------------------------ the real loop (slow)


@pytest.mark.slow
def test_real_loop_keeps_more_samples_and_rejects_distortion(tmp_path, floaters_scene):
    """Weakened nerfacto on the 32x32 floaters scene, 60 iterations per run, 4 runs (2 seeds of the weak
    plan for the noise, then the 2 candidates); 10.5 min on 2 heavily shared cores.

    Measured here: weak plan 10.34 / 10.67 dB (seeds 0/1, noise 0.33), 4x samples 16.10 dB (+5.59, kept),
    + distortion loss 10.51 dB (+0.00, rejected). Earlier, 100 iterations, seeds 42/7: weak 10.56 / 10.91,
    + distortion 10.71, 4x samples 14.8. Two repeats can agree by chance, so the threshold has a 0.5 dB floor
    (the distortion loss moved PSNR by at most 0.15 dB in every measurement)."""
    messages = []
    result = pl.run_patch_loop(
        weakened(floaters_scene), floaters_scene, tmp_path / "patches", iterations=60, rounds=1, repeats=2,
        seeds=(0, 1), max_candidates=2, noise_floor=0.5, only_rules=["add_distortion_loss", "more_proposal_samples"],
        env=NO_WEIGHTS_ENV, timeout=600, progress=messages.append,
    )
    history = result.history
    print(json.dumps([{k: e[k] for k in ("psnr_before", "psnr_before_runs", "psnr_after", "noise", "decision")}
                      for e in history["entries"]], indent=1))
    round0 = history["rounds"][0]
    assert {"floaters", "blur_high_frequency"} <= {d["name"] for d in round0["diagnoses"]}
    by_rule = {e["patch"]["rule"]: e for e in history["entries"]}
    kept, rejected = by_rule["more_proposal_samples"], by_rule["add_distortion_loss"]
    assert kept["threshold"] == max(kept["noise"], 0.5)
    assert kept["decision"] == "kept" and kept["improvement"] > kept["threshold"] + 1.0
    assert rejected["decision"] == "rejected" and rejected["improvement"] <= rejected["threshold"]
    assert result.best_plan["model"]["sampler"]["proposal"]["nerf_samples"] == 8
    assert (tmp_path / "patches" / kept["run"] / "error_maps.json").is_file()
    assert history["stopped"].startswith("round budget")
