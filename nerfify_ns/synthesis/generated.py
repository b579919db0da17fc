"""The generated method (``GENERATED_METHOD``): what ``ns-train nerfify-generated`` trains.

It is the plugin folder named by $NERFIFY_GENERATED, else the newest plugin under the current directory's
``nerfify-out/`` (:func:`nerfify_ns.synthesis.plugin_lookup.resolve_generated`; no global "last generated"
pointer, so parallel runs never train each other's plugin), imported from its folder, so a user can train it
without installing it. ``ns-train nerfify-generated`` says on its first line which plugin it trains and how
it was chosen. When there is none, or it cannot be imported, it is a CPU-sized Nerfacto (proposal sampling
and a hash grid cut down to a small bounded scene), the configuration our smoke training uses, and that
first line says why.
"""

from __future__ import annotations

import copy
import sys

from nerfstudio.cameras.camera_optimizers import CameraOptimizerConfig
from nerfstudio.configs.base_config import MachineConfig, ViewerConfig
from nerfstudio.data.datamanagers.base_datamanager import VanillaDataManagerConfig
from nerfstudio.data.dataparsers.blender_dataparser import BlenderDataParserConfig
from nerfstudio.engine.optimizers import AdamOptimizerConfig
from nerfstudio.engine.schedulers import ExponentialDecaySchedulerConfig
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.models.nerfacto import NerfactoModelConfig
from nerfstudio.pipelines.base_pipeline import VanillaPipelineConfig
from nerfstudio.plugins.types import MethodSpecification

from nerfify_ns.runtime import default_device_type
from nerfify_ns.runtime.launch import ENV_GENERATED, GENERATED_METHOD
from nerfify_ns.synthesis.plugin_lookup import GeneratedPluginError, load_plugin_method, resolve_generated


def cpu_nerfacto_config(method_name: str = GENERATED_METHOD) -> TrainerConfig:
    """Nerfacto sized for a small bounded synthetic scene on the CPU."""
    return TrainerConfig(
        method_name=method_name,
        steps_per_eval_batch=100,
        steps_per_eval_image=10_000,
        steps_per_eval_all_images=100_000,
        steps_per_save=1_000,
        max_num_iterations=3_000,
        mixed_precision=False,
        machine=MachineConfig(device_type=default_device_type()),
        pipeline=VanillaPipelineConfig(
            datamanager=VanillaDataManagerConfig(
                dataparser=BlenderDataParserConfig(),
                train_num_rays_per_batch=1024,
                eval_num_rays_per_batch=1024,
            ),
            model=NerfactoModelConfig(
                eval_num_rays_per_chunk=1 << 12,
                num_levels=8,
                log2_hashmap_size=15,
                max_res=256,
                num_nerf_samples_per_ray=32,
                num_proposal_samples_per_ray=(64, 32),
                disable_scene_contraction=True,
                use_appearance_embedding=False,
                background_color="white",
                camera_optimizer=CameraOptimizerConfig(mode="off"),
                average_init_density=1.0,
            ),
        ),
        optimizers={
            "proposal_networks": {
                "optimizer": AdamOptimizerConfig(lr=1e-2, eps=1e-15),
                "scheduler": ExponentialDecaySchedulerConfig(lr_final=1e-4, max_steps=3_000),
            },
            "fields": {
                "optimizer": AdamOptimizerConfig(lr=1e-2, eps=1e-15),
                "scheduler": ExponentialDecaySchedulerConfig(lr_final=1e-4, max_steps=3_000),
            },
        },
        viewer=ViewerConfig(num_rays_per_chunk=1 << 12),
        vis="tensorboard",
    )


def _fallback(reason: str) -> MethodSpecification:
    return MethodSpecification(config=cpu_nerfacto_config(),
                               description=f"nerfify: {reason}; until then a CPU-sized nerfacto")


def _training_us(argv: list[str] | None = None) -> bool:
    """Whether this process is ``ns-train GENERATED_METHOD ...`` (other ns-* commands load us too)."""
    argv = sys.argv if argv is None else argv
    return len(argv) > 1 and argv[1] == GENERATED_METHOD


def _say(line: str) -> None:
    """The first line of ``ns-train nerfify-generated``: which plugin it trains (only when it trains us)."""
    if _training_us():
        print(f"{GENERATED_METHOD}: {line}", flush=True)


def generated_method() -> MethodSpecification:
    """The method ``ns-train GENERATED_METHOD`` resolves to."""
    plugin, how = resolve_generated()
    if plugin is None:
        _say(f"no plugin to train ({how}; set ${ENV_GENERATED}=PLUGIN_DIR or run from the folder holding "
             f"nerfify-out/): training a CPU-sized nerfacto")
        return _fallback(f"no plugin ({how})")
    try:
        spec = load_plugin_method(plugin)
    except GeneratedPluginError as exc:
        _say(f"cannot load the plugin {plugin} ({how}): training a CPU-sized nerfacto instead")
        print(f"{GENERATED_METHOD}: {exc}", file=sys.stderr)
        return _fallback(f"the plugin in {plugin} cannot be loaded")
    _say(f"training the plugin {plugin} ({how})")
    config = copy.deepcopy(spec.config)
    config.method_name = GENERATED_METHOD
    config.machine.device_type = default_device_type()
    return MethodSpecification(config=config, description=f"nerfify: the plugin {plugin} ({how})")
