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


VARIANTS = ("stock", "before", "fused", "after")
"""``stock``: Nerfstudio's own code paths; ``before``: our runtime without its fused paths (the hash-grid kernel
only); ``fused``: with the fused optimiser, contraction, chunked occupancy updates and flushed denormals;
``after``: the runtime as shipped (also the reused heap memory and the alpha test's reused encodings)."""

#: The runtime patches of :mod:`nerfify_ns.runtime.fused` each variant switches on.
VARIANT_PATCHES = {"stock": (), "before": (),
                   "fused": ("denormals", "fused_optimizer", "contraction", "occupancy_chunks"),
                   "after": ("denormals", "fused_optimizer", "contraction", "occupancy_chunks", "freed_memory",
                             "density_reuse")}


def _dynamic_batch(config) -> tuple[int, int] | None:
    """``(target samples, first rays)`` of Nerfstudio's ``DynamicBatchPipeline`` (Instant-NGP): it starts at
    ``target // max samples per ray`` rays and then scales the rays so each step has about ``target`` samples."""
    target = getattr(config.pipeline, "target_num_samples", None)
    if not target:
        return None
    return int(target), int(target) // int(config.pipeline.max_num_samples_per_ray)


def time_variants(method: str, rays: int, repeats: int, plugin_dir: str = "", warmup: int = 2,
                  variants: tuple[str, ...] = VARIANTS, real_batch: bool = False,
                  grid_updates: int = 1) -> dict[str, object]:
    """A full training step (callbacks, forward, losses, backward, optimiser step) of one method under the
    runtime ``variants`` (:data:`VARIANTS`), interleaved in one process, so the machine's load hits all alike.

    Each variant trains its own model (same seed, same ray batch) with its own optimisers (built by the
    variant's ``OptimizerConfig.setup``); before each step the variant's code paths are switched in:
    Nerfstudio's hash-encoding fallback or ours, then the patches of :data:`VARIANT_PATCHES`. With
    ``real_batch`` a method trained by Nerfstudio's dynamic batch (Instant-NGP) gets its real batch: each
    variant's rays per step follow the pipeline's rule (about 262,144 samples a step) instead of ``rays``.
    A method with an occupancy grid also has ``grid_updates`` of its warm-up updates (all cells, every 16
    steps under the trainer) timed per variant, interleaved; ``*_rays_per_s_with_grid_updates`` adds a
    sixteenth of one to each step, as the trainer's wall time does. Must run in a fresh process (it
    captures the stock code before the runtime patches it)."""
    import sys

    import nerfacc.estimators.occ_grid as occ_grid
    import torch
    from nerfacc.estimators.occ_grid import OccGridEstimator
    from nerfstudio.engine.optimizers import OptimizerConfig, Optimizers
    from nerfstudio.field_components.encodings import HashEncoding
    from nerfstudio.field_components.spatial_distortions import SceneContraction
    from nerfstudio.model_components.ray_samplers import VolumetricSampler

    if "nerfstudio.configs.method_configs" in sys.modules:
        raise RuntimeError("time_variants must capture Nerfstudio's code before the runtime is activated")
    stock_hash, stock_setup = HashEncoding.__dict__["pytorch_fwd"], OptimizerConfig.__dict__["setup"]
    from nerfstudio.configs.method_configs import all_methods

    from nerfify_ns.runtime import activate, hashgrid_ext
    from nerfify_ns.runtime.fused import fused_optimizer_setup, reuse_freed_memory

    activate(force=True)
    ours_hash = HashEncoding.__dict__["pytorch_fwd"]
    ours_contraction, ours_update = SceneContraction.forward, OccGridEstimator._update
    ours_sigma, ours_vis = VolumetricSampler.get_sigma_fn, occ_grid.render_visibility_from_density
    stock_contraction = getattr(ours_contraction, "_nerfify_stock", ours_contraction)
    stock_update = getattr(ours_update, "_nerfify_stock", ours_update)
    stock_sigma, stock_vis = getattr(ours_sigma, "_nerfify_stock", ours_sigma), getattr(ours_vis, "_nerfify_stock",
                                                                                       ours_vis)
    ext = hashgrid_ext.load()

    def switch(variant: str) -> None:
        on = set(VARIANT_PATCHES[variant])
        HashEncoding.pytorch_fwd = stock_hash if variant == "stock" else ours_hash
        SceneContraction.forward = ours_contraction if "contraction" in on else stock_contraction
        OccGridEstimator._update = ours_update if "occupancy_chunks" in on else stock_update
        VolumetricSampler.get_sigma_fn = ours_sigma if "density_reuse" in on else stock_sigma
        occ_grid.render_visibility_from_density = ours_vis if "density_reuse" in on else stock_vis
        reuse_freed_memory("freed_memory" in on)
        torch.set_flush_denormal("denormals" in on)
        if ext is not None and hasattr(ext, "set_flush_denormal_all_threads"):
            ext.set_flush_denormal_all_threads("denormals" in on)

    if plugin_dir:
        from nerfify_ns.synthesis.plugin_lookup import load_plugin_method

        config = load_plugin_method(plugin_dir).config
    else:
        config = all_methods[method]
    dynamic = _dynamic_batch(config) if real_batch else None
    models, optimizers = {}, {}
    for variant in variants:
        switch(variant)
        models[variant] = build_model(config)
        OptimizerConfig.setup = fused_optimizer_setup if "fused_optimizer" in VARIANT_PATCHES[variant] else stock_setup
        optimizers[variant] = Optimizers(config.optimizers, models[variant].get_param_groups())
    OptimizerConfig.setup = fused_optimizer_setup
    batch_rays = {v: dynamic[1] if dynamic else rays for v in variants}
    times: dict[str, list[float]] = {v: [] for v in variants}
    step_rays: dict[str, list[int]] = {v: [] for v in variants}
    samples: dict[str, list[int]] = {v: [] for v in variants}
    for k in range(warmup + repeats):
        for variant in variants[k % len(variants):] + variants[:k % len(variants)]:
            switch(variant)
            bundle, batch = ray_batch(batch_rays[variant], seed=1 + k)
            seconds, n_samples = _train_step(models[variant], optimizers[variant], bundle, batch, k)
            if k >= warmup:
                times[variant].append(seconds)
                step_rays[variant].append(batch_rays[variant])
                samples[variant].append(n_samples)
            if dynamic and n_samples:
                batch_rays[variant] = int(batch_rays[variant] * (dynamic[0] / n_samples))
    rays_per_s = {v: statistics.median(r / t for r, t in zip(step_rays[v], times[v], strict=True)) for v in variants}
    out: dict[str, object] = {
        "method": method, "plugin": plugin_dir or None, "rays": rays if not dynamic else "dynamic",
        "real_batch": bool(dynamic), "repeats": repeats, "threads": torch.get_num_threads(), "step_seconds": times,
        "step_rays": step_rays, "step_samples": samples,
        **{f"{v}_median_step_seconds": statistics.median(times[v]) for v in variants},
        **{f"{v}_rays_per_s": rays_per_s[v] for v in variants}}
    if grid_updates and all(hasattr(m, "occupancy_grid") for m in models.values()):
        updates: dict[str, list[float]] = {v: [] for v in variants}
        for j in range(grid_updates):
            for variant in variants[j % len(variants):] + variants[:j % len(variants)]:
                switch(variant)
                models[variant].train()
                start = time.perf_counter()
                run_before_iteration_callbacks(models[variant], 16 * (j + 1))  # inside the 256-step warm-up
                updates[variant].append(time.perf_counter() - start)
        out["grid_update_seconds"] = updates
        for v in variants:
            per_step = statistics.median(times[v]) + statistics.median(updates[v]) / 16
            out[f"{v}_rays_per_s_with_grid_updates"] = statistics.median(step_rays[v]) / per_step
    switch("after")
    return out


def _train_step(model, optimizers, bundle, batch, step: int) -> tuple[float, int]:
    """One training step as the trainer runs it (callbacks, forward, losses, backward, optimiser step and
    zeroing): its seconds and its samples (``num_samples_per_batch``, 0 where the model does not report it)."""
    model.train()
    start = time.perf_counter()
    run_before_iteration_callbacks(model, step)
    outputs = model.get_outputs(bundle)
    metrics = model.get_metrics_dict(outputs, batch)
    losses = model.get_loss_dict(outputs, batch, metrics)
    sum(losses.values()).backward()
    optimizers.optimizer_step_all()
    optimizers.zero_grad_all()
    seconds = time.perf_counter() - start
    return seconds, int(metrics.get("num_samples_per_batch", 0))


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
    parser.add_argument("--which", default=",".join(VARIANTS), help="with --variants: the variants, comma-separated")
    parser.add_argument("--real-batch", action="store_true",
                        help="with --variants: Nerfstudio's dynamic batch where the method has one (Instant-NGP)")
    parser.add_argument("--grid-updates", type=int, default=1,
                        help="with --variants: warm-up occupancy-grid updates timed per variant (0: none)")
    ns = parser.parse_args()
    if ns.variants:
        which = tuple(v.strip() for v in ns.which.split(",") if v.strip())
        unknown = set(which) - set(VARIANTS)
        if unknown:
            parser.error(f"unknown variants {sorted(unknown)}; known: {', '.join(VARIANTS)}")
        print(json.dumps(time_variants(ns.variants, ns.rays, ns.repeats, ns.plugin, variants=which,
                                       real_batch=ns.real_batch, grid_updates=ns.grid_updates)))
        return
    if ns.flops:
        print(json.dumps(step_flops(ns.flops, ns.rays, ns.plugin)))
        return
    if not ns.plugin_dir or not ns.builtin:
        parser.error("PLUGIN_DIR and BUILTIN_METHOD are required (or --flops METHOD)")
    print(json.dumps(time_steps(ns.plugin_dir, ns.builtin, ns.rays, ns.repeats)))


if __name__ == "__main__":
    run_interruptible(main)
