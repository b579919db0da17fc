"""Training-step time of a generated plugin's model against Nerfstudio's built-in model, interleaved.

    python -m nerfify_ns.benchmarks.step_timing PLUGIN_DIR BUILTIN_METHOD [--rays 1024] [--repeats 15]
    python -m nerfify_ns.benchmarks.step_timing --flops METHOD [--plugin PLUGIN_DIR] [--rays 1024]
    python -m nerfify_ns.benchmarks.step_timing --variants METHOD [--plugin PLUGIN_DIR] [--rays 1024] [--repeats 15]

``ns-train`` rays/s of two separate processes differ by up to ~10% on a shared 2-core machine even
for computationally identical models (measured: vanilla-nerf 77 vs 68 rays/s, same losses). This
measures what the parity claim is about, the model's training step, without the process-level
noise: both models are built in ONE process from their own configs (same seed, same scene box),
then alternate forward + losses + backward on the same ray batch; the medians and their ratio are
printed as JSON. The plugin is imported here, so the parity bench runs this module in a
subprocess (generated code never runs in the bench's own process).
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import time
from collections.abc import Callable

from nerfify_ns.interrupts import run_interruptible


def build_model(config, seed: int = 0):
    """The model of a method config, built on the CPU from ``seed`` with a [-1.5, 1.5]^3 scene box."""
    import torch
    from nerfstudio.data.scene_box import SceneBox

    torch.manual_seed(seed)
    aabb = torch.tensor([[-1.5] * 3, [1.5] * 3])
    return config.pipeline.model.setup(scene_box=SceneBox(aabb=aabb), num_train_data=4, metadata={}, device="cpu")


def ray_batch(rays: int, seed: int = 1):
    """``rays`` rays from a 4-unit sphere towards the scene box (as the bundled scenes' cameras), with
    random colours: a RayBundle and the batch dict a model's losses read."""
    import torch
    from nerfstudio.cameras.rays import RayBundle

    g = torch.Generator().manual_seed(seed)
    origins = torch.nn.functional.normalize(torch.randn(rays, 3, generator=g), dim=-1) * 4.0
    targets = (torch.rand(rays, 3, generator=g) - 0.5) * 1.8
    directions = torch.nn.functional.normalize(targets - origins, dim=-1)
    bundle = RayBundle(origins=origins, directions=directions, pixel_area=torch.full((rays, 1), 1e-4),
                       camera_indices=torch.zeros(rays, 1, dtype=torch.long),
                       nears=torch.full((rays, 1), 2.0), fars=torch.full((rays, 1), 6.0))
    return bundle, {"image": torch.rand(rays, 3, generator=g)}


def run_before_iteration_callbacks(model, step: int) -> None:
    """The model's own before-iteration training callbacks, as the trainer runs them (Instant-NGP
    updates its occupancy grid there); they need no optimisers or trainer."""
    from nerfstudio.engine.callbacks import TrainingCallbackAttributes, TrainingCallbackLocation

    for callback in model.get_training_callbacks(TrainingCallbackAttributes(None, None, None, None)):
        callback.run_callback_at_location(step, TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)


def _step_fn(model, bundle, batch) -> Callable[[], float]:
    """One training step as the trainer does it: the model's before-iteration callbacks (Instant-NGP
    updates its occupancy grid there), forward, losses, backward. A fresh copy of the rays each time:
    a camera optimiser adjusts them in place."""
    import copy

    count = itertools.count()

    def step() -> float:
        rays = copy.deepcopy(bundle)
        model.train()
        model.zero_grad(set_to_none=True)
        start = time.perf_counter()
        run_before_iteration_callbacks(model, next(count))
        outputs = model.get_outputs(rays)
        losses = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))
        sum(losses.values()).backward()
        return time.perf_counter() - start

    return step


def time_steps(plugin_dir: str, builtin: str, rays: int, repeats: int, warmup: int = 2) -> dict[str, object]:
    from nerfstudio.configs.method_configs import all_methods

    from nerfify_ns.runtime import activate
    from nerfify_ns.synthesis.plugin_lookup import load_plugin_method

    activate()
    bundle, batch = ray_batch(rays)
    steps = {"generated": _step_fn(build_model(load_plugin_method(plugin_dir).config), bundle, batch),
             "builtin": _step_fn(build_model(all_methods[builtin]), bundle, batch)}
    times: dict[str, list[float]] = {name: [] for name in steps}
    for k in range(warmup + repeats):
        for name in (("builtin", "generated") if k % 2 == 0 else ("generated", "builtin")):
            seconds = steps[name]()
            if k >= warmup:
                times[name].append(seconds)
    median = {name: statistics.median(t) for name, t in times.items()}
    return {"builtin": builtin, "rays": rays, "repeats": repeats,
            "median_step_seconds_builtin": median["builtin"], "median_step_seconds_generated": median["generated"],
            "throughput_ratio": median["builtin"] / median["generated"]}


VARIANTS = ("stock", "before", "after")
"""``stock``: Nerfstudio's own code paths; ``before``: our runtime without its fused paths (the hash-grid kernel
only); ``after``: the runtime as shipped (:mod:`nerfify_ns.runtime.fused` too)."""


def time_variants(method: str, rays: int, repeats: int, plugin_dir: str = "", warmup: int = 2) -> dict[str, object]:
    """A full training step (callbacks, forward, losses, backward, optimiser step) of one method under the
    three runtime :data:`VARIANTS`, interleaved in one process, so the machine's load hits all alike.

    Each variant trains its own model (same seed, same ray batch) with its own optimisers (built by the
    variant's ``OptimizerConfig.setup``); before each step the variant's code paths are switched in:
    Nerfstudio's hash-encoding fallback or ours, the stock or fused contraction, occupancy-grid update and
    optimiser, denormals kept or flushed. Must run in a fresh process (it captures the stock code before
    the runtime patches it)."""
    import sys

    import torch
    from nerfacc.estimators.occ_grid import OccGridEstimator
    from nerfstudio.engine.optimizers import OptimizerConfig, Optimizers
    from nerfstudio.field_components.encodings import HashEncoding
    from nerfstudio.field_components.spatial_distortions import SceneContraction

    if "nerfstudio.configs.method_configs" in sys.modules:
        raise RuntimeError("time_variants must capture Nerfstudio's code before the runtime is activated")
    stock_hash, stock_setup = HashEncoding.__dict__["pytorch_fwd"], OptimizerConfig.__dict__["setup"]
    from nerfstudio.configs.method_configs import all_methods

    from nerfify_ns.runtime import activate, hashgrid_ext
    from nerfify_ns.runtime.fused import fused_optimizer_setup

    activate(force=True)
    ours_hash = HashEncoding.__dict__["pytorch_fwd"]
    ours_contraction, ours_update = SceneContraction.forward, OccGridEstimator._update
    stock_contraction = getattr(ours_contraction, "_nerfify_stock", ours_contraction)
    stock_update = getattr(ours_update, "_nerfify_stock", ours_update)
    ext = hashgrid_ext.load()

    def switch(variant: str) -> None:
        after = variant == "after"
        HashEncoding.pytorch_fwd = stock_hash if variant == "stock" else ours_hash
        SceneContraction.forward = ours_contraction if after else stock_contraction
        OccGridEstimator._update = ours_update if after else stock_update
        torch.set_flush_denormal(after)
        if ext is not None and hasattr(ext, "set_flush_denormal_all_threads"):
            ext.set_flush_denormal_all_threads(after)

    if plugin_dir:
        from nerfify_ns.synthesis.plugin_lookup import load_plugin_method

        config = load_plugin_method(plugin_dir).config
    else:
        config = all_methods[method]
    bundle, batch = ray_batch(rays)
    trainers = {}
    for variant in VARIANTS:
        switch(variant)
        model = build_model(config)
        OptimizerConfig.setup = fused_optimizer_setup if variant == "after" else stock_setup
        optimizers = Optimizers(config.optimizers, model.get_param_groups())
        trainers[variant] = (_step_fn(model, bundle, batch), optimizers)
    OptimizerConfig.setup = fused_optimizer_setup
    times: dict[str, list[float]] = {v: [] for v in VARIANTS}
    for k in range(warmup + repeats):
        for variant in VARIANTS[k % 3:] + VARIANTS[:k % 3]:
            switch(variant)
            step, optimizers = trainers[variant]
            seconds = step()
            start = time.perf_counter()
            optimizers.optimizer_step_all()
            optimizers.zero_grad_all()
            seconds += time.perf_counter() - start
            if k >= warmup:
                times[variant].append(seconds)
    median = {v: statistics.median(t) for v, t in times.items()}
    return {"method": method, "plugin": plugin_dir or None, "rays": rays, "repeats": repeats,
            "threads": torch.get_num_threads(), "step_seconds": times,
            **{f"{v}_median_step_seconds": m for v, m in median.items()},
            **{f"{v}_rays_per_s": rays / m for v, m in median.items()}}


def _flop_counter_class():
    from torch.utils._python_dispatch import TorchDispatchMode
    from torch.utils.flop_counter import flop_registry

    class FlopCounter(TorchDispatchMode):
        """Sums torch's FLOP formulas (``flop_registry``: matrix products, convolutions, attention) over the
        ops dispatched inside it. ``FlopCounterMode`` itself also tracks modules with backward hooks, which
        fail on modules whose outputs carry no gradient (Instant-NGP's occupancy-grid sampling)."""

        def __init__(self) -> None:
            super().__init__()
            self.flops = 0

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            kwargs = kwargs or {}
            out = func(*args, **kwargs)
            formula = flop_registry.get(func._overloadpacket)
            if formula is not None:
                self.flops += int(formula(*args, **kwargs, out_val=out))
            return out

    return FlopCounter


def _FlopCounter():  # noqa: N802 - a class built on first use (torch's dispatch modes import lazily)
    return _flop_counter_class()()


def step_flops(method: str, rays: int, plugin_dir: str = "") -> dict[str, object]:
    """Floating-point operations of one training step (forward, losses, backward), counted by
    ``torch.utils.flop_counter`` (matrix products and convolutions: the work a FLOP bound is about),
    of a built-in method or, with ``plugin_dir``, the plugin's method; per step and per ray. The
    model is fresh (an Instant-NGP occupancy grid has not pruned yet: its count is an upper bound)."""
    from nerfstudio.configs.method_configs import all_methods

    from nerfify_ns.runtime import activate

    activate()
    if plugin_dir:
        from nerfify_ns.synthesis.plugin_lookup import load_plugin_method

        config = load_plugin_method(plugin_dir).config
    else:
        config = all_methods[method]
    bundle, batch = ray_batch(rays)
    step = _step_fn(build_model(config), bundle, batch)
    step()  # the first step builds lazy state (Instant-NGP's grid update runs here at step 0)
    counter = _FlopCounter()
    with counter:
        step()
    flops = counter.flops
    return {"method": method, "plugin": plugin_dir or None, "rays": rays, "flops_per_step": flops,
            "flops_per_ray": flops / rays}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("plugin_dir", nargs="?")
    parser.add_argument("builtin", nargs="?")
    parser.add_argument("--rays", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--flops", metavar="METHOD", help="count one training step's FLOPs of METHOD instead")
    parser.add_argument("--variants", metavar="METHOD", help="time METHOD's step under stock/before/after instead")
    parser.add_argument("--plugin", default="", help="with --flops/--variants: the plugin folder of METHOD's config")
    ns = parser.parse_args()
    if ns.variants:
        print(json.dumps(time_variants(ns.variants, ns.rays, ns.repeats, ns.plugin)))
        return
    if ns.flops:
        print(json.dumps(step_flops(ns.flops, ns.rays, ns.plugin)))
        return
    if not ns.plugin_dir or not ns.builtin:
        parser.error("PLUGIN_DIR and BUILTIN_METHOD are required (or --flops METHOD)")
    print(json.dumps(time_steps(ns.plugin_dir, ns.builtin, ns.rays, ns.repeats)))


if __name__ == "__main__":
    run_interruptible(main)
