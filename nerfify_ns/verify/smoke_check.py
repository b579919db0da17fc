"""The smoke rung's verdict from values the trained plugin's process cannot write after the fact: the rendered
colours of every training step (sent down our pipe by :mod:`nerfify_ns.verify.recorder`) and the tensors of the
checkpoint it saved (loaded with ``torch.load(weights_only=True)`` here, in our process, which never imports
plugin code; nothing in it is executed).

* every step's rendered colours are finite, and so is every call's output of each part of the model that is not
  torch's or Nerfstudio's (a part that turns non-finite from its N-th call is caught for N up to the calls of the
  run: at least one per iteration, so any N <= iterations, even where the model masks the value);
* the photometric error recomputed here (mean squared error on the opaque pixels) falls below
  :data:`LEARNING_RATIO` of where it started. Judged on the same rays when the run sent them (a ``probe`` record:
  the first training batches rendered again by the trained model, compared with the colours they had when they
  were trained on; their ground truth must be the steps' own), else the last quarter's steps against the first
  quarter's (different rays each step: a noisier verdict);
* the steps reached, counted from the records;
* every floating tensor of the checkpoint (model and optimiser state) is finite.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

LEARNING_RATIO = 0.9
MAX_CHECKPOINT = 2 << 30


def step_errors(records: Sequence[tuple[dict, dict[str, np.ndarray]]]) -> tuple[dict[int, float], list[str]]:
    """(step -> recomputed photometric error, problems) of the recorded training steps."""
    errors: dict[int, float] = {}
    problems: list[str] = []
    for header, arrays in records:
        if header.get("kind") != "step":
            continue
        step = header.get("step")
        if not isinstance(step, int):
            continue
        if step in errors:
            problems.append(f"step {step} was recorded twice (something besides the trainer wrote to the pipe)")
            continue
        for name, calls in arrays.items():
            if name.startswith("mod:") and calls.dtype.kind in "fc" and calls.size and not np.isfinite(calls).all():
                first = int(np.flatnonzero(~np.isfinite(calls))[0]) + 1
                problems.append(f"step {step}: the output of part {name[4:80]} not finite (its call {first} of "
                                f"{calls.size} in this step)")
        rgb, image = arrays.get("rgb"), arrays.get("image")
        if rgb is None or image is None:
            problems.append(f"step {step}: no rendered colours or ground truth recorded")
            continue
        if rgb.ndim != 2 or image.ndim != 2 or rgb.shape[0] != image.shape[0] or rgb.shape[-1] != 3:
            problems.append(f"step {step}: rendered colours {rgb.shape} do not match the batch {image.shape}")
            continue
        if not np.isfinite(rgb).all():
            problems.append(f"step {step}: {int(rgb.size - np.isfinite(rgb).sum())} of {rgb.size} rendered colour "
                            "values not finite")
            errors[step] = float("nan")
            continue
        error, opaque = _opaque_error(rgb, image)
        if opaque:
            errors[step] = error
    return errors, problems


def _opaque_error(rgb: np.ndarray, image: np.ndarray) -> tuple[float, int]:
    """(mean squared error over the opaque pixels, their count) of rendered colours against RGB(A) ground truth."""
    target = image[:, :3].astype(np.float64)
    mask = image[:, 3] > 0.99 if image.shape[-1] == 4 else np.ones(len(image), bool)
    if not mask.any():
        return float("nan"), 0
    return float(((rgb.astype(np.float64) - target) ** 2)[mask].mean()), int(mask.sum())


def probe_errors(records) -> tuple[tuple[float, float, int] | None, list[str]]:
    """((error when trained on, error after training, opaque pixels) of the probe's rays, problems) from the run's
    ``probe`` record and the step records of the steps it names; (None, []) when the run sent no probe."""
    probes = [(h, a) for h, a in records if h.get("kind") == "probe"]
    if not probes:
        return None, []
    if len(probes) > 1:
        return None, ["the probe was recorded more than once (something besides the recorder wrote to the pipe)"]
    header, arrays = probes[0]
    steps = header.get("steps")
    by_step = {h.get("step"): a for h, a in records if h.get("kind") == "step"}
    if not isinstance(steps, list) or not steps or any(s not in by_step for s in steps):
        return None, [f"the probe names steps {steps!r} the run did not record"]
    before_rgb = [by_step[s].get("rgb") for s in steps]
    before_image = [by_step[s].get("image") for s in steps]
    rgb, image = arrays.get("rgb"), arrays.get("image")
    if any(x is None for x in (*before_rgb, *before_image, rgb, image)):
        return None, ["the probe or its steps hold no rendered colours or ground truth"]
    before_image = np.concatenate(before_image)
    if image.shape != before_image.shape or not np.array_equal(image, before_image) or rgb.shape[0] != len(image):
        return None, ["the probe's ground truth is not its steps' (the same rays must be rendered again)"]
    if not np.isfinite(rgb).all():
        return None, ["the probe's rendered colours are not finite after training"]
    before, n = _opaque_error(np.concatenate(before_rgb), before_image)
    after, _ = _opaque_error(rgb, image)
    return ((before, after, n) if n else None), []


def _numpy_globals() -> list:
    """The numpy names a checkpoint's plain values need (a scalar rebuilt from its dtype and bytes; no code)."""
    import importlib

    names = [np.dtype]
    for module in ("numpy.core.multiarray", "numpy._core.multiarray"):
        try:
            names.append(importlib.import_module(module).scalar)
        except (ImportError, AttributeError):
            pass
    names += [type(np.dtype(t)) for t in ("float64", "float32", "int64", "int32", "bool")]
    return names


def checkpoint_problems(run_dir: Path) -> tuple[int | None, list[str]]:
    """(the step it was saved at, problems) of the newest checkpoint under ``run_dir``."""
    import torch

    found = sorted(Path(run_dir).rglob("step-*.ckpt"))
    if not found:
        return None, ["no checkpoint was saved"]
    path = found[-1]
    if path.is_symlink() or not path.is_file() or path.stat().st_size > MAX_CHECKPOINT:
        return None, [f"checkpoint {path.name}: not a regular file under {MAX_CHECKPOINT >> 30} GiB"]
    try:
        with torch.serialization.safe_globals(_numpy_globals()):  # numpy scalars in schedulers' state
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - a file the sandbox wrote: any failure is a finding
        return None, [f"checkpoint {path.name} does not load as plain tensors: {type(exc).__name__}: "
                      f"{str(exc).splitlines()[0][:200] if str(exc) else ''}"]
    problems, bad = [], []

    def walk(value, name: str, depth: int = 0) -> None:
        if depth > 12 or len(bad) > 8:
            return
        if isinstance(value, torch.Tensor):
            if value.is_floating_point() and value.numel() and not torch.isfinite(value).all():
                bad.append(name)
        elif isinstance(value, dict):
            for k, v in value.items():
                walk(v, f"{name}.{k}" if name else str(k), depth + 1)
        elif isinstance(value, list | tuple):
            for i, v in enumerate(value):
                walk(v, f"{name}[{i}]", depth + 1)

    walk(state if isinstance(state, dict) else {}, "")
    if bad:
        problems.append(f"checkpoint {path.name}: tensors not finite: {', '.join(bad[:5])}"
                        f"{' ...' if len(bad) > 5 else ''}")
    step = state.get("step") if isinstance(state, dict) else None
    return step if isinstance(step, int) else None, problems


def ray_cost(records) -> dict | None:
    """The recorder's ``timing`` record (a step's forward, losses and backward at two ray batches with training's
    threads, and at the first with the rung's own) as ``{"rays": [r1, r2], "seconds": [t1, t2], "seconds_per_ray":
    (t2 - t1) / (r2 - r1), "speedup": rung's t1 / training's t1}`` (the speedup within [1, the ratio of threads];
    absent when the record has no second thread count); None when the run sent none, or one that is not two
    increasing batches with finite, positive times. A larger batch measured no slower than a smaller one is noise,
    not a cost: ``seconds_per_ray`` is then None (the budget scales the step by the base's exponent, which errs on
    the long side, where a training that keeps its deadline trains on), and the thread speedup is kept. Not a
    verdict: a budgeted run's prediction of a step at another batch and thread count
    (``nerfify_ns.budget.scaled_step``, ``pipeline._smoke_timing``)."""
    def seconds_ok(t) -> bool:
        return isinstance(t, int | float) and not isinstance(t, bool) and bool(np.isfinite(t)) and t > 0

    found = [h for h, _ in records if h.get("kind") == "timing"]
    if len(found) != 1:
        return None
    head = found[0]
    rays, seconds = head.get("rays"), head.get("seconds")
    if not (isinstance(rays, list) and isinstance(seconds, list) and len(rays) == len(seconds) == 2
            and all(isinstance(r, int) and r > 0 for r in rays) and rays[1] > rays[0]
            and all(seconds_ok(t) for t in seconds)):
        return None
    per_ray = (seconds[1] - seconds[0]) / (rays[1] - rays[0]) if seconds[1] > seconds[0] else None
    out = {"rays": rays, "seconds": [float(t) for t in seconds], "seconds_per_ray": per_ray}
    threads, own, rung = head.get("threads"), head.get("rung_threads"), head.get("rung_seconds")
    if isinstance(threads, int) and isinstance(own, int) and 0 < own <= threads and seconds_ok(rung):
        out.update(threads=threads, rung_threads=own,
                   speedup=min(max(float(rung) / seconds[0], 1.0), threads / own))
    return out


def judge_training(records, run_dir: Path, iterations: int) -> tuple[int, list[tuple[str, str]], dict]:
    """(checks, [(rule, message)], details) of a smoke run from its records and its checkpoint."""
    errors, problems = step_errors(records)
    failures: list[tuple[str, str]] = [("non-finite-output" if "not finite" in p else "forged-record", p)
                                       for p in problems[:3]]
    reached = max(errors) + 1 if errors else 0
    details = {"recorded_steps": len(errors), "iterations_recorded": reached, "ray_cost": ray_cost(records)}
    if reached < iterations and not failures:
        failures.append(("iterations", f"the trainer's records reach {reached} of {iterations} iterations"))
    finite = [errors[s] for s in sorted(errors) if np.isfinite(errors[s])]
    paired, probe_problems = probe_errors(records)
    failures += [("forged-record", p) for p in probe_problems[:1]]
    if not failures and paired is not None and len(finite) >= 4:  # learning needs steps to be judged at all
        before, after, opaque = paired
        details.update({"photometric_first_recomputed": before, "photometric_last_recomputed": after,
                        "judged_on": f"the same {opaque} opaque pixels before and after training"})
        if not after < LEARNING_RATIO * before:
            failures.append(("no-learning", "the photometric error recomputed from the rendered colours does not "
                             f"decrease: {before:.4g} on the first steps' rays when trained on, {after:.4g} on the "
                             f"same rays after training (needs < {LEARNING_RATIO} x)"))
    elif not failures and len(finite) >= 4:
        q = max(len(finite) // 4, 1)
        first, last = float(np.mean(finite[:q])), float(np.mean(finite[-q:]))
        details.update({"photometric_first_recomputed": first, "photometric_last_recomputed": last,
                        "judged_on": "the first quarter's steps against the last quarter's"})
        if not last < LEARNING_RATIO * first:
            failures.append(("no-learning", "the photometric error recomputed from the rendered colours does not "
                             f"decrease: first quarter {first:.4g}, last quarter {last:.4g} "
                             f"(needs < {LEARNING_RATIO} x)"))
    step, ckpt = checkpoint_problems(run_dir)
    details["checkpoint_step"] = step
    failures += [("checkpoint", p) for p in ckpt if "not finite" in p]
    checks = len(errors) + (1 if step is not None else 0)
    return checks, failures, details
