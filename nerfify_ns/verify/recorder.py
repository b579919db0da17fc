"""The smoke rung's training, recorded for the checker: ``ns-train`` in the sandbox, with every training step's
rendered colours and the batch's ground truth sent as arrays down a pipe our process holds.

    python -m nerfify_ns.verify.recorder FD ns-train-arguments...

The hook wraps Nerfstudio's ``VanillaPipeline.get_train_loss_dict`` (Nerfstudio's code, not the plugin's) before
the plugin is imported; the verdict (finite outputs at every step, a photometric error that falls, the steps
reached, a finite checkpoint) is computed by :func:`nerfify_ns.verify.smoke_check.judge_training` in our process,
never from the run's tensorboard files, which the plugin's process writes.
"""

from __future__ import annotations

import sys

RGB_KEYS = ("rgb", "rgb_fine")
"""Where a model's training outputs hold its rendered colour, in order of preference."""

PROBE_STEPS = 4
"""The first training batches kept (as drawn, before the model sees them) and rendered again after training: the
smoke rung's paired comparison, the same rays before and after (:func:`render_probe`)."""

COST_RAYS = (1, 4)
"""The ray batches :func:`time_ray_cost` times a training step's forward, losses and backward at, as multiples of the
first probe batch: what a step's time owes to its rays (and what to the model's parameters) is their difference."""


def as_pixels(rgb, image):
    """(rendered colours, ground truth) as rows of pixels ``[N, C]``. A model that renders whole images (splatting)
    gives an image ``[h, w, 3]`` and its batch the full image ``[H, W, C]`` (8-bit when cached so): the ground truth
    is taken to [0, 1] and averaged over d x d blocks when the model renders at 1/d of the resolution (splatfacto's
    first steps), here, not by the model's code; ray batches are returned as they are."""
    import torch

    if not (torch.is_tensor(rgb) and torch.is_tensor(image)) or rgb.ndim != 3 or image.ndim != 3:
        return rgb, image
    target = image.float() / 255.0 if image.dtype == torch.uint8 else image.float()
    factor = target.shape[0] // max(rgb.shape[0], 1)
    if factor > 1 and target.shape[0] == rgb.shape[0] * factor and target.shape[1] == rgb.shape[1] * factor:
        target = torch.nn.functional.avg_pool2d(target.permute(2, 0, 1)[None], factor)[0].permute(1, 2, 0)
    return rgb.reshape(-1, rgb.shape[-1]), target.reshape(-1, target.shape[-1])


def install(pipe) -> dict:
    """Record (step, the rendered colour (``RGB_KEYS``), batch['image']) of every training step, and the summed
    absolute output of every call of the model's parts that are not torch's or Nerfstudio's (``mod:NAME``, one value
    per call since the previous step: a part whose NaN the model masks is still seen)."""
    from nerfstudio.pipelines.base_pipeline import VanillaPipeline

    from nerfify_ns.verify.checker import ModuleWatch, watched_modules

    original = VanillaPipeline.get_train_loss_dict
    cap = pipe.cap
    last = {}

    def get_train_loss_dict(self, step: int):
        model = getattr(self, "model", None)
        if last.get("model") is not model and model is not None:
            if last.get("watch") is not None:
                last["watch"].close()
            last["model"], last["watch"] = model, ModuleWatch(cap, watched_modules(model))
        dm = self.datamanager
        if "wrapped" not in last or last["wrapped"] is not dm:
            inner = dm.next_train

            def next_train(step_, _inner=inner):
                out = _inner(step_)
                last["batch"] = out
                probe = last.setdefault("probe", [])
                if len(probe) < PROBE_STEPS and isinstance(out, tuple) and len(out) == 2:
                    bundle, batch = out  # a copy: the model may change the bundle in place (collider, camera)
                    probe.append((int(step_), bundle._apply_fn_to_fields(lambda t: t.detach().clone()), batch))
                return out

            dm.next_train = next_train
            last["wrapped"] = dm
        last["pipeline"] = self
        outputs, losses, metrics = original(self, step)
        arrays = {}
        batch = last.get("batch")
        # the model's rendered colour: nerfacto-like models write "rgb", vanilla-nerf and mipnerf "rgb_fine"
        rgb = next((outputs[k] for k in RGB_KEYS if isinstance(outputs, dict) and k in outputs), None)
        image = batch[1].get("image") if isinstance(batch, tuple) and len(batch) == 2 and isinstance(
            batch[1], dict) else None
        rgb, image = as_pixels(rgb, image)
        if cap.is_tensor(rgb):
            arrays["rgb"] = cap.array(rgb)[0]
        if last.get("watch") is not None:
            arrays.update(last["watch"].take())
        if cap.is_tensor(image):
            arrays["image"] = cap.array(image)[0]
        pipe.send({"kind": "step", "rung": "smoke", "step": int(step)}, arrays)
        return outputs, losses, metrics

    VanillaPipeline.get_train_loss_dict = get_train_loss_dict
    return last


def render_probe(pipe, last: dict) -> None:
    """After training: the first :data:`PROBE_STEPS` batches rendered again by the trained model (train mode, no
    gradient), sent as one ``probe`` record with the steps they were drawn at; the checker compares them with the
    colours the same rays had when they were trained on."""
    import numpy as np
    import torch

    pipeline, probe = last.get("pipeline"), last.get("probe") or []
    model = getattr(pipeline, "model", None)
    if model is None or not probe:
        return
    cap = pipe.cap
    rgbs, images = [], []
    model.train(True)
    with torch.no_grad():
        for _, bundle, batch in probe:
            outputs = model(bundle)  # Model.forward: the collider, then get_outputs
            rgb = next((outputs[k] for k in RGB_KEYS if isinstance(outputs, dict) and k in outputs), None)
            if not cap.is_tensor(rgb) or not isinstance(batch, dict) or not cap.is_tensor(batch.get("image")):
                return
            rgb, image = as_pixels(rgb, batch["image"])
            rgbs.append(cap.array(rgb)[0])
            images.append(cap.array(image)[0])
    pipe.send({"kind": "probe", "rung": "smoke", "steps": [s for s, _, _ in probe]},
              {"rgb": np.concatenate(rgbs), "image": np.concatenate(images)})


def time_ray_cost(pipe, last: dict, repeats: int = 2) -> None:
    """After training: a training step's forward, losses and backward (no optimiser step) timed at the first probe
    batch and at :data:`COST_RAYS` times its rays (the batch repeated: the same work per ray), each after an
    untimed pass, the faster of ``repeats`` each, with the threads training will have
    (``NERFIFY_TIMING_THREADS``; the rung itself may run with fewer, beside the checks), and the first batch again
    with the rung's own threads; sent as one ``timing`` record. A budgeted run predicts a step at another batch
    from it: the difference is what the rays cost, the rest of a step (the optimiser, regularisers over whole
    grids) does not change with the batch, and the two thread counts say how much faster training's threads make a
    step. Gradients are left as they were found."""
    import os
    import time

    import torch

    pipeline, probe = last.get("pipeline"), last.get("probe") or []
    model = getattr(pipeline, "model", None)
    if model is None or not probe:
        return
    _, bundle, batch = probe[0]
    rays = len(bundle)
    saved = {n: p.grad for n, p in model.named_parameters()}
    own = torch.get_num_threads()
    wanted = os.environ.get("NERFIFY_TIMING_THREADS", "")
    threads = int(wanted) if wanted.isdigit() and int(wanted) > 0 else own
    model.train(True)

    def timed(factor: int, once: bool = False) -> float:
        index = torch.arange(rays * factor) % rays
        many = bundle[index]
        targets = {k: v[index] if torch.is_tensor(v) and v.shape[:1] == (rays,) else v for k, v in batch.items()}
        best = float("inf")
        for _ in range(1 if once else repeats):
            model.zero_grad(set_to_none=True)
            start = time.perf_counter()
            outputs = model(many._apply_fn_to_fields(lambda t: t.clone()))
            losses = model.get_loss_dict(outputs, targets, model.get_metrics_dict(outputs, targets))
            sum(v for v in losses.values() if torch.is_tensor(v)).backward()
            best = min(best, time.perf_counter() - start)
        return best

    try:
        timed(1, once=True)  # warm-up: the first pass after training pays one-off allocations
        rung_seconds = timed(1)
        torch.set_num_threads(threads)
        timed(COST_RAYS[-1], once=True)  # and again with training's threads (a new thread pool, larger buffers)
        seconds = [timed(f) for f in COST_RAYS]
    finally:
        torch.set_num_threads(own)
        for n, p in model.named_parameters():
            p.grad = saved.get(n)
    pipe.send({"kind": "timing", "rung": "smoke", "rays": [rays * f for f in COST_RAYS], "seconds": seconds,
               "threads": threads, "rung_threads": own, "rung_seconds": rung_seconds}, {})


def main() -> None:
    from nerfify_ns.verify.checker import RecordPipe

    pipe = RecordPipe(int(sys.argv[1]))  # bound before any plugin code runs
    last = install(pipe)
    sys.argv = ["ns-train", *sys.argv[2:]]
    from nerfstudio.scripts.train import entrypoint

    entrypoint()
    try:
        render_probe(pipe, last)
    except Exception as exc:  # noqa: BLE001 - no probe: the checker judges the steps alone (and says so)
        print(f"nerfify recorder: the probe was not rendered after training: {type(exc).__name__}: {exc}",
              file=sys.stderr)
    try:
        time_ray_cost(pipe, last)
    except Exception as exc:  # noqa: BLE001 - no timing: a budgeted run scales the step by the base's exponent
        print(f"nerfify recorder: the ray cost was not timed after training: {type(exc).__name__}: {exc}",
              file=sys.stderr)


if __name__ == "__main__":
    main()
