"""The checker's parts, fast: every call of a plugin's parts watched from outside their code (a NaN the caller masks
is still seen, on the call it appeared), the repeated passes judged per pass, the smoke rung's per-call records,
the record pipe unaffected by patches made after it was built, and a sandbox that does not say it is one."""

from __future__ import annotations

import json
import os
import socket
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from nerfify_ns.runtime.sandbox import available_modes
from nerfify_ns.verify import checker
from nerfify_ns.verify.assembled import MODEL_CASES
from nerfify_ns.verify.checker import (
    REPEAT_CASE,
    REPEAT_STEPS,
    ModuleWatch,
    PipeReader,
    RecordPipe,
    decode,
    judge,
    judge_repeated,
    watched_modules,
)
from nerfify_ns.verify.smoke_check import judge_training, step_errors


class TurnsNaN(torch.nn.Module):
    """A part whose output is NaN from its ``after``-th call on (test double of a plugin's part)."""

    def __init__(self, after: int) -> None:
        super().__init__()
        self.after, self.calls = after, 0

    def forward(self, x):
        self.calls += 1
        return {"rgb": x * float("nan") if self.calls >= self.after else x}


class Masking(torch.nn.Module):
    """A caller that hides its part's NaN (``nan_to_num``), as a renderer in eval mode does."""

    def __init__(self, after: int) -> None:
        super().__init__()
        self.part = TurnsNaN(after)
        self.linear = torch.nn.Linear(3, 3)

    def forward(self, x):
        return torch.nan_to_num(self.linear(self.part(x)["rgb"]))


def _record_of(pipe_fn):
    reader = PipeReader()
    pipe = RecordPipe(reader.write_fd)
    pipe_fn(pipe)
    os.close(reader.write_fd)
    reader.write_fd = -1
    return decode(reader.finish())


def test_watch_sees_the_call_a_caller_masks():
    model = Masking(after=5)
    cap = checker.Captured()
    names = [n for n, _ in watched_modules(model)]
    assert names == ["part"], "torch's own modules and the model itself are not watched"
    watch = ModuleWatch(cap, watched_modules(model))
    outputs = [model(torch.rand(4, 3)) for _ in range(7)]
    assert all(torch.isfinite(o).all() for o in outputs), "the caller masks the NaN"
    calls = watch.take()["mod:part"]
    assert calls.shape == (7,) and np.isfinite(calls[:4]).all() and not np.isfinite(calls[4:]).any()
    assert watch.take() == {}, "a take empties the watch"
    watch.close()
    model(torch.rand(4, 3))
    assert watch.take() == {}, "a closed watch records nothing"


def test_repeated_passes_are_judged_per_pass():
    ok = {"out:rgb": np.ones(REPEAT_STEPS), "mod:field": np.ones(REPEAT_STEPS * 2)}
    assert judge_repeated({"status": "ran", "steps": REPEAT_STEPS}, ok) == []
    late = dict(ok, **{"mod:field": np.r_[np.ones(60), np.full(REPEAT_STEPS * 2 - 60, np.nan)]})
    (problem,) = judge_repeated({"status": "ran", "steps": REPEAT_STEPS}, late)
    assert problem.startswith("the output of part field not finite from call 61 of 128")
    short = judge_repeated({"status": "ran", "steps": 3}, {"out:rgb": np.ones(3)})
    assert short == [f"3 of {REPEAT_STEPS} repeated forward passes recorded"]
    raised = judge_repeated({"status": "raised", "message": "forward pass 31 of 64 raised ValueError"}, {})
    assert raised == ["forward pass 31 of 64 raised ValueError"]
    assert judge_repeated({"status": "ran", "steps": REPEAT_STEPS}, {}) == ["the repeated passes recorded no outputs"]


def test_the_repeated_check_is_owed_and_gates():
    """Without a plan: the model's checks. The repeated passes are owed by the stability rung; missing, the rung
    fails; NaN from a late pass fails it naming the rule."""
    stable = [({"kind": "model", "rung": "stability", "component": "<model>", "case": c, "status": "ran",
                "grads": {}}, {"out:rgb": np.ones((4, 3), np.float32)})
              for c in MODEL_CASES]
    missing = judge(stable, None, ["stability"], ["stability"])
    assert [(f.rule, f.case) for f in missing.findings] == [("missing-check", REPEAT_CASE)]
    late = np.r_[np.ones(40), np.full(REPEAT_STEPS - 40, np.nan)]
    repeated = ({"kind": "model", "rung": "stability", "component": "<model>", "case": REPEAT_CASE, "status": "ran",
                 "steps": REPEAT_STEPS}, {"out:rgb": late})
    found = judge([*stable, repeated], None, ["stability"], ["stability"]).findings
    assert [f.rule for f in found] == ["repeated-calls"] and "not finite from pass 41" in found[0].message


def test_smoke_records_name_a_part_that_turns_nan():
    image = np.c_[np.random.rand(8, 3), np.ones(8)].astype(np.float32)
    records = []
    for step in range(8):
        rgb = np.random.rand(8, 3).astype(np.float32)
        part = np.array([1.0, np.nan if step >= 5 else 2.0])
        records.append(({"kind": "step", "step": step}, {"rgb": rgb, "image": image, "mod:field.mlp_head": part}))
    errors, problems = step_errors(records)
    assert len(errors) == 8, "the rendered colours stay finite: the NaN is masked"
    assert problems[0] == "step 5: the output of part field.mlp_head not finite (its call 2 of 2 in this step)"
    checks, failures, _ = judge_training(records, Path("/nonexistent"), 8)
    assert failures[0][0] == "non-finite-output"


def test_record_pipe_ignores_patches_made_after_it_was_built():
    def send(pipe):
        checker.RecordPipe.send = lambda self, header, arrays=None: None  # what a plugin might patch
        original = checker.encode
        checker.encode = lambda header, arrays=None: b""
        try:
            pipe.send({"kind": "component", "case": "nominal"}, {"rgb": np.full(3, np.nan)})
        finally:
            checker.encode = original
            del checker.RecordPipe.send

    records, problems = _record_of(send)
    assert problems == [] and len(records) == 1 and np.isnan(records[0][1]["rgb"]).all()


@pytest.mark.skipif("bwrap" not in available_modes(), reason="needs root and bubblewrap (scripts/setup.sh installs it)")
def test_the_sandbox_does_not_say_it_is_one(tmp_path):
    """No variable names the sandbox, the host name is ours, the user name is ours; the probe still finds its own
    PID namespace (from /proc, not from the environment)."""
    from nerfify_ns.runtime.sandbox import run_sandboxed
    from nerfify_ns.verify.probe import own_pid_namespace

    code = ("import getpass, json, os, socket\nfrom nerfify_ns.verify.probe import own_pid_namespace\n"
            "print(json.dumps({'env': sorted(os.environ), 'host': socket.gethostname(), 'user': getpass.getuser(), "
            "'own_pids': own_pid_namespace(), 'uid': os.getuid()}))")
    tmp_path.chmod(0o755)
    result = run_sandboxed([sys.executable, "-c", code], tmp_path / "w", timeout=60)
    assert result.returncode == 0, result.tail()
    seen = json.loads((tmp_path / "w" / "run.log").read_text().strip().splitlines()[-1])
    assert not any("SANDBOX" in k for k in seen["env"])
    assert seen["host"] == socket.gethostname() and seen["host"] != "sandbox"
    assert seen["user"] != "nobody" and seen["own_pids"] is True
    assert seen["uid"] == 65534  # what stays detectable (docs/sandbox.md)
    assert own_pid_namespace() is False


def _smoke_records(steps: int, improve: float, seed: int = 0):
    """A smoke run's step records (different rays each step, a slowly falling error) and its probe: the first 4
    batches rendered again, their error ``improve`` times what it was when trained on."""
    rng = np.random.default_rng(seed)
    records, batches = [], []
    for step in range(steps):
        image = np.c_[rng.random((32, 3)), (rng.random(32) > 0.5)].astype(np.float32)
        rgb = np.clip(image[:, :3] + rng.normal(0, 0.3 * (1 - 0.005 * step), (32, 3)), 0, 1).astype(np.float32)
        records.append(({"kind": "step", "step": step}, {"rgb": rgb, "image": image}))
        batches.append((rgb, image))
    first = batches[:4]
    image = np.concatenate([i for _, i in first])
    rgb = np.concatenate([i[:, :3] + (r - i[:, :3]) * np.sqrt(improve) for r, i in first]).astype(np.float32)
    return records, ({"kind": "probe", "steps": [0, 1, 2, 3]}, {"rgb": rgb, "image": image})


def test_the_smoke_verdict_compares_the_same_rays_before_and_after():
    """A run that sent its probe is judged on the same rays (paired); one that lowered their error by half passes
    even where the per-step quarters, drawn on different rays, barely move; one that did not fails; a probe whose
    ground truth is not its steps' is a forged record; without a probe the quarters decide, as before."""
    records, probe = _smoke_records(20, improve=0.5)
    _, failures, details = judge_training([*records, probe], Path("/nonexistent"), 20)
    assert not [f for f in failures if f[0] != "checkpoint"], failures
    assert details["judged_on"].startswith("the same ") and details["photometric_last_recomputed"] < \
        0.9 * details["photometric_first_recomputed"]
    records, probe = _smoke_records(20, improve=1.0)
    _, failures, _ = judge_training([*records, probe], Path("/nonexistent"), 20)
    assert failures[0][0] == "no-learning" and "does not decrease" in failures[0][1] and "same rays" in failures[0][1]
    header, arrays = probe
    forged = (header, {"rgb": arrays["rgb"], "image": np.roll(arrays["image"], 1, axis=0)})
    _, failures, _ = judge_training([*records, forged], Path("/nonexistent"), 20)
    assert failures[0] == ("forged-record", "the probe's ground truth is not its steps' (the same rays must be "
                                            "rendered again)")
    _, _, details = judge_training(records, Path("/nonexistent"), 20)
    assert details["judged_on"] == "the first quarter's steps against the last quarter's"


def test_the_ray_cost_timing_is_read_only_when_it_is_well_formed():
    """The recorder's timing of a step at two ray batches gives the seconds a ray costs (a budget input, not a
    verdict); a missing, repeated or malformed record gives none, and a larger batch measured no slower gives no
    cost per ray (the thread speedup stays)."""
    from nerfify_ns.verify.smoke_check import ray_cost

    records, _ = _smoke_records(8, improve=0.5)
    timing = ({"kind": "timing", "rung": "smoke", "rays": [128, 512], "seconds": [0.2, 0.5]}, {})
    cost = ray_cost([*records, timing])
    assert cost["seconds_per_ray"] == pytest.approx(0.3 / 384) and cost["rays"] == [128, 512]
    assert judge_training([*records, timing], Path("/nonexistent"), 8)[2]["ray_cost"] == cost
    assert ray_cost(records) is None and ray_cost([*records, timing, timing]) is None
    for bad in ({"rays": [512, 128], "seconds": [0.2, 0.5]}, {"rays": [128, 512], "seconds": [0.2, float("nan")]},
                {"rays": [128, 512], "seconds": [0.2, -1]}, {"rays": "128", "seconds": [0.2, 0.5]},
                {"rays": [128, 512, 1024], "seconds": [0.2, 0.5, 0.9]}):
        assert ray_cost([*records, ({"kind": "timing", **bad}, {})]) is None, bad
    # a larger batch measured faster (seen: 0.68 s at 128 rays, 0.12 s at 512) is noise, not a free ray: a budget
    # that read it as "rays cost nothing" planned a vanilla-NeRF step at 0.32 s that took 4.4 s
    for noisy in ([0.5, 0.4], [0.68, 0.12], [0.3, 0.3]):
        cost = ray_cost([({"kind": "timing", "rays": [128, 512], "seconds": noisy, "threads": 2, "rung_threads": 1,
                           "rung_seconds": 0.9}, {})])
        assert cost["seconds_per_ray"] is None and cost["speedup"] == pytest.approx(min(0.9 / noisy[0], 2.0)), noisy
    # the rung's own threads against training's: the speedup, within [1, the ratio of threads]
    for rung, want in ((0.3, 1.5), (0.1, 1.0), (0.9, 2.0)):
        timed = ({"kind": "timing", "rays": [128, 512], "seconds": [0.2, 0.5], "threads": 2, "rung_threads": 1,
                  "rung_seconds": rung}, {})
        assert ray_cost([timed])["speedup"] == pytest.approx(want)
    odd = ({"kind": "timing", "rays": [128, 512], "seconds": [0.2, 0.5], "threads": 1, "rung_threads": 2,
            "rung_seconds": 0.3}, {})
    assert "speedup" not in ray_cost([odd])
