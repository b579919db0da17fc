"""The CPU and offline layer: makes Nerfstudio 1.1.5 train and evaluate with no GPU and no network.

:func:`activate` runs automatically when our ``nerfstudio.method_configs`` entry point is loaded
(so a plain ``ns-train`` gets it) and whenever ``nerfify_ns`` drives Nerfstudio itself. It does
nothing when CUDA is available, unless forced. Each patch is small and named:

* ``lpips``         LPIPS from local AlexNet weights only; ``null`` when there are none
                    (:mod:`nerfify_ns.runtime.lpips`);
* ``nerfacc``       torch implementations of nerfacc's CUDA ops, no JIT build
                    (:mod:`nerfify_ns.runtime.nerfacc_cpu`);
* ``hashgrid``      a fast torch multi-resolution hash encoding in place of Nerfstudio's fallback,
                    same parameter layout (:mod:`nerfify_ns.runtime.hashgrid`);
* ``cpu_default``   ``--machine.device-type`` defaults to ``cpu`` for every registered method;
* ``seeded_workers`` the parallel datamanager's ray-sampling workers are seeded from
                    ``--machine.seed``, so a seed fixes the whole run (:mod:`nerfify_ns.runtime.seeding`);
* ``denormals``     denormal floats flushed to zero in every compute thread;
* ``fused_optimizer`` Adam/AdamW built with their fused CPU kernel;
* ``contraction``   the scene contraction's L-inf norm as ``abs().amax()``;
* ``occupancy_chunks`` the occupancy grid's density evaluated in chunks during its updates;
* ``freed_memory``  glibc reuses freed blocks instead of unmapping them (no page faults per activation);
* ``density_reuse`` the hash encodings of nerfacc's alpha test reused by the field's pass over the
                    surviving samples (the last six: :mod:`nerfify_ns.runtime.fused`, each exact to
                    float rounding);
* ``splatting``     Gaussian splatting (splatfacto, gsplat's ``rasterization``) rendered by a torch rasteriser
                    that composites what gsplat's CUDA kernels do (:mod:`nerfify_ns.runtime.splat_cpu`).

One compatibility fix is applied always, GPU or not, because it concerns the pinned torch, not the
device: Nerfstudio 1.1.5 checkpoints hold numpy scalars, which torch >= 2.6's safe ``torch.load``
refuses, so ``ns-eval`` and ``--load-dir`` fail; :func:`allow_numpy_scalars_in_checkpoints`
admits exactly those numpy types (no arbitrary code) to the safe loader. A budgeted training keeps its deadline
whatever the device (:mod:`nerfify_ns.runtime.pace`, when the pipeline sets ``NERFIFY_TRAIN_PACE``).

``NERFIFY_RUNTIME=off`` disables it; ``NERFIFY_RUNTIME=force`` applies it even with CUDA;
``NERFIFY_RUNTIME_SKIP=hashgrid,...`` leaves the named patches out (baselines, debugging).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

ENV_SWITCH = "NERFIFY_RUNTIME"
ENV_SKIP = "NERFIFY_RUNTIME_SKIP"

_applied: list[str] = []


def cuda_available() -> bool:
    import torch  # imported on use: tools that never train (a dry run) should not pay for torch

    return torch.cuda.is_available()


def _patch_lpips() -> None:
    import torchmetrics.image.lpip as tm_lpip
    from nerfstudio.pipelines import base_pipeline

    from nerfify_ns.runtime.lpips import OfflineLPIPS, nullify_unavailable_lpips, torchmetrics_lpips_class

    torchmetrics_lpips_class()  # record the original before replacing it
    tm_lpip.LearnedPerceptualImagePatchSimilarity = OfflineLPIPS  # models import it at init time
    original = base_pipeline.VanillaPipeline.get_average_eval_image_metrics
    if getattr(original, "_nerfify_wrapped", False):
        return

    def get_average_eval_image_metrics(self, *args, **kwargs):
        return nullify_unavailable_lpips(original(self, *args, **kwargs))

    get_average_eval_image_metrics._nerfify_wrapped = True  # type: ignore[attr-defined]
    base_pipeline.VanillaPipeline.get_average_eval_image_metrics = get_average_eval_image_metrics


def _patch_nerfacc() -> None:
    from nerfify_ns.runtime import nerfacc_cpu

    nerfacc_cpu.install(force=True)


def _patch_hashgrid() -> None:
    from nerfstudio.field_components.encodings import HashEncoding

    from nerfify_ns.runtime.hashgrid import fast_pytorch_fwd

    HashEncoding.pytorch_fwd = fast_pytorch_fwd


def _patch_cpu_default() -> None:
    """Registered methods train on the CPU unless ``--machine.device-type`` says otherwise: a machine config made
    from now on defaults to ``cpu``, and :func:`cpu_default_sweep` moves the configs already made."""
    from nerfstudio.configs.base_config import MachineConfig

    defaults = list(MachineConfig.__init__.__defaults__ or ())
    if "cuda" in defaults:
        defaults[defaults.index("cuda")] = "cpu"
        MachineConfig.__init__.__defaults__ = tuple(defaults)
    cpu_default_sweep()


def cpu_default_sweep() -> None:
    """``cpu`` for every method config Nerfstudio registers: its own, and those of the plugins' entry points (a
    pip-installed plugin's config is made when its module is imported, which may be before this runtime was: the
    entry points are loaded here, as Nerfstudio's discovery would load them, and the same objects are registered).
    Runs whenever the runtime is activated while Nerfstudio discovers its methods."""
    module = sys.modules.get("nerfstudio.configs.method_configs")
    if module is None:
        return
    configs = list(getattr(module, "method_configs", {}).values())
    from importlib.metadata import entry_points

    for point in entry_points(group="nerfstudio.method_configs"):
        loading = sys.modules.get(point.module)
        if loading is not None and not hasattr(loading, point.attr or ""):
            continue  # being imported right now (our own entry point): it is made after the runtime
        try:
            spec = point.load()
        except Exception:  # noqa: BLE001 - Nerfstudio's discovery reports a plugin that does not load
            continue
        configs.append(getattr(spec, "config", None))
    for config in configs:
        machine = getattr(config, "machine", None)
        if machine is not None and machine.device_type == "cuda":
            machine.device_type = "cpu"


def _patch_seeded_workers() -> None:
    from nerfify_ns.runtime.seeding import seed_parallel_workers

    seed_parallel_workers()


def _patch_denormals() -> None:
    from nerfify_ns.runtime.fused import flush_denormals

    flush_denormals()


def _patch_fused_optimizer() -> None:
    from nerfstudio.engine.optimizers import OptimizerConfig

    from nerfify_ns.runtime.fused import fused_optimizer_setup

    OptimizerConfig.setup = fused_optimizer_setup


def _patch_contraction() -> None:
    from nerfstudio.field_components.spatial_distortions import SceneContraction

    from nerfify_ns.runtime.fused import make_contraction_forward

    if not hasattr(SceneContraction.forward, "_nerfify_stock"):
        SceneContraction.forward = make_contraction_forward(SceneContraction.forward)


def _patch_occupancy_chunks() -> None:
    from nerfacc.estimators.occ_grid import OccGridEstimator

    from nerfify_ns.runtime.fused import make_chunked_occupancy_update

    if not hasattr(OccGridEstimator._update, "_nerfify_stock"):
        OccGridEstimator._update = make_chunked_occupancy_update(OccGridEstimator._update)


def _patch_freed_memory() -> None:
    from nerfify_ns.runtime.fused import reuse_freed_memory

    reuse_freed_memory()


def _patch_splatting() -> None:
    from nerfify_ns.runtime import splat_cpu

    splat_cpu.install()


def _patch_density_reuse() -> None:
    import nerfacc.estimators.occ_grid as occ_grid
    from nerfstudio.model_components.ray_samplers import VolumetricSampler

    from nerfify_ns.runtime.fused import make_recording_sigma_fn, make_visibility_recorder

    if not hasattr(VolumetricSampler.get_sigma_fn, "_nerfify_stock"):
        VolumetricSampler.get_sigma_fn = make_recording_sigma_fn(VolumetricSampler.get_sigma_fn)
    if not hasattr(occ_grid.render_visibility_from_density, "_nerfify_stock"):
        occ_grid.render_visibility_from_density = make_visibility_recorder(occ_grid.render_visibility_from_density)


PATCHES: dict[str, Callable[[], None]] = {
    "lpips": _patch_lpips,
    "nerfacc": _patch_nerfacc,
    "hashgrid": _patch_hashgrid,
    "cpu_default": _patch_cpu_default,
    "seeded_workers": _patch_seeded_workers,
    "denormals": _patch_denormals,
    "fused_optimizer": _patch_fused_optimizer,
    "contraction": _patch_contraction,
    "occupancy_chunks": _patch_occupancy_chunks,
    "freed_memory": _patch_freed_memory,
    "density_reuse": _patch_density_reuse,
    "splatting": _patch_splatting,
}


def allow_numpy_scalars_in_checkpoints() -> None:
    """Let torch's weights-only loader read the numpy scalars inside Nerfstudio checkpoints."""
    import numpy as np
    import torch

    torch.serialization.add_safe_globals(
        [np.core.multiarray.scalar, np.dtype, type(np.dtype("float64")), type(np.dtype("int64"))]
    )


def activate(force: bool = False) -> list[str]:
    """Apply the CPU/offline patches (idempotent); returns the names applied so far.

    Without ``force`` nothing is changed when CUDA is available or ``NERFIFY_RUNTIME=off``.
    """
    allow_numpy_scalars_in_checkpoints()
    from nerfify_ns.runtime.pace import ENV_PACE, install

    if os.environ.get(ENV_PACE):
        install()
    switch = os.environ.get(ENV_SWITCH, "auto").lower()
    if switch == "off":
        return list(_applied)
    if cuda_available() and not (force or switch == "force"):
        return list(_applied)
    skipped = {name.strip() for name in os.environ.get(ENV_SKIP, "").split(",") if name.strip()}
    unknown = skipped - set(PATCHES)
    if unknown:
        raise ValueError(f"{ENV_SKIP} names unknown patches {sorted(unknown)}; known: {sorted(PATCHES)}")
    for name, patch in PATCHES.items():
        if name not in _applied and name not in skipped:
            patch()
            _applied.append(name)
        elif name == "cpu_default" and name in _applied:
            cpu_default_sweep()  # activated before Nerfstudio discovered its methods: move those made since
    return list(_applied)


def default_device_type() -> str:
    """``cuda`` when a GPU is there, else ``cpu``: the device our own configs default to."""
    return "cuda" if cuda_available() else "cpu"


def active_patches() -> list[str]:
    return list(_applied)
