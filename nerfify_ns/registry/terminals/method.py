"""The method's frame: scene facts, trainer, data manager, base models, optimisers and schedules."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from nerfify_ns.registry.bases import base_definitions
from nerfify_ns.registry.params import param
from nerfify_ns.registry.terminal import Code, Harness, TerminalDef


@dataclass
class Scene:
    bounded: bool = param(True)
    """Content lies in a bounded box (no contraction needed)."""
    timestamps: bool = param(False)
    """Frames carry times (a dynamic scene)."""
    alpha: bool = param(True)
    """Images have an alpha channel (transparent background)."""
    appearance_variation: bool = param(False)
    """Lighting or exposure varies across images."""
    exact_poses: bool = param(True)
    """Camera poses are exact (synthetic)."""
    format: Literal["blender", "dnerf", "nerfstudio", "colmap", "llff"] = param("blender")
    """Dataset format the plan is fitted to (detected by nerfify_ns.dataset); it picks the Nerfstudio dataparser."""
    forward_facing: bool = param(False)
    """The cameras face one way side by side (LLFF-style), not around the scene (measured from the poses)."""


@dataclass
class Trainer:
    max_num_iterations: int = param(30000, range=(1, 10000000))
    """Training iterations."""
    steps_per_eval_batch: int = param(500, range=(1, 10000000))
    """Iterations between evaluations of a batch of rays."""
    steps_per_eval_image: int = param(500, range=(1, 10000000))
    """Iterations between evaluations of one image."""
    steps_per_eval_all_images: int = param(25000, range=(1, 10000000))
    """Iterations between evaluations of every test image."""
    steps_per_save: int = param(2000, range=(1, 10000000))
    """Iterations between checkpoints."""
    mixed_precision: bool = param(False)
    """Train with automatic mixed precision."""


@dataclass
class DataManager:
    train_num_rays_per_batch: int = param(4096, range=(1, 1048576))
    """Rays per training batch."""
    eval_num_rays_per_batch: int = param(4096, range=(1, 1048576))
    """Rays per evaluation batch."""
    dataparser: Literal["blender", "nerfstudio", "dnerf", "colmap"] = param("blender")
    """Nerfstudio dataparser of the dataset format."""


@dataclass
class Adam:
    lr: float = param(0.0005, range=(1.0e-10, 10.0))
    """Learning rate."""
    eps: float = param(1.0e-15, range=(1.0e-20, 1.0))
    """Term added to the denominator for numerical stability."""
    weight_decay: float = param(0.0, range=(0.0, 1.0))
    """L2 penalty."""


@dataclass
class RAdam(Adam):
    eps: float = param(1.0e-8, range=(1.0e-20, 1.0))
    """Term added to the denominator for numerical stability."""


@dataclass
class ExponentialDecay:
    lr_final: float = param(0.0001, range=(1.0e-12, 10.0))
    """Learning rate at max_steps."""
    max_steps: int = param(200000, range=(1, 10000000))
    """Iterations of the decay."""
    warmup_steps: int = param(0, range=(0, 10000000))
    """Iterations of linear warm-up."""


@dataclass
class MultiStep:
    milestones: list[int] = param([10000, 15000, 20000], range=(1, 10000000), length=(1, 16))
    """Iterations at which the learning rate is multiplied by gamma."""
    gamma: float = param(0.33, range=(1.0e-6, 1.0))
    """Factor applied at each milestone."""
    max_steps: int = param(1000000, range=(1, 10000000))
    """Iterations of the schedule."""


@dataclass
class CosineDecay:
    warm_up_end: int = param(5000, range=(0, 10000000))
    """Iteration at which the linear warm-up ends."""
    learning_rate_alpha: float = param(0.05, range=(0.0, 1.0))
    """Final learning rate as a fraction of the initial one."""
    max_steps: int = param(300000, range=(1, 10000000))
    """Iterations of the schedule."""


def base(name: str, b: dict) -> TerminalDef:
    """A base model: the Nerfstudio model whose loop (sampling, rendering, losses) the plugin reuses, as
    ``registry/bases.yaml`` defines it (its one definition: templates, smoke presets and reference plans read it).
    Its duties: the sampler and field it runs (a base of explicit primitives, ``sampler: null``, has none: the
    slots must stay empty)."""
    duties = [{"requires_terminal": {"slot": f"model.{slot}", "any_of": [b[slot], "custom"] if b[slot] else [None]}}
              for slot in ("sampler", "field")]
    return TerminalDef(name, "Base", None, b["doc"], b["model"], card=b["card"], config_class=b["config"],
                       param_groups=tuple(b.get("groups") or ("fields",)), harness=Harness(in_model=True),
                       duties=tuple(duties))


def _ctor(cls: str, args: str) -> str:
    return f"{cls}({args})"


OPTIMIZER = "lr={{ p.lr }}, eps={{ p.eps }}, weight_decay={{ p.weight_decay }}"

TERMINALS = [
    TerminalDef("scene", "Method", Scene,
                "Facts about the target scene; pruning reads them and duties check against them.",
                "nerfify_ns.synthesis.scene_probe.SceneFacts"),
    TerminalDef("trainer", "Method", Trainer, "Nerfstudio's TrainerConfig.", "nerfstudio.engine.trainer.TrainerConfig"),
    TerminalDef("datamanager", "Method", DataManager,
                "Ray batches drawn from the training images (VanillaDataManager).",
                "nerfstudio.data.datamanagers.base_datamanager.VanillaDataManagerConfig",
                code=Code(traits={"dataparsers": {
                    "blender": ["nerfstudio.data.dataparsers.blender_dataparser", "BlenderDataParserConfig"],
                    "nerfstudio": ["nerfstudio.data.dataparsers.nerfstudio_dataparser", "NerfstudioDataParserConfig"],
                    "dnerf": ["nerfstudio.data.dataparsers.dnerf_dataparser", "DNeRFDataParserConfig"],
                    "colmap": ["nerfstudio.data.dataparsers.colmap_dataparser", "ColmapDataParserConfig"]}})),
    *(base(name, b) for name, b in base_definitions().items()),
    TerminalDef("adam", "Optimizer", Adam, "Adam.", "nerfstudio.engine.optimizers.AdamOptimizerConfig",
                code=Code(("from nerfstudio.engine.optimizers import AdamOptimizerConfig",),
                          ctor=_ctor("AdamOptimizerConfig", OPTIMIZER))),
    TerminalDef("radam", "Optimizer", RAdam, "Rectified Adam.", "nerfstudio.engine.optimizers.RAdamOptimizerConfig",
                code=Code(("from nerfstudio.engine.optimizers import RAdamOptimizerConfig",),
                          ctor=_ctor("RAdamOptimizerConfig", OPTIMIZER))),
    TerminalDef("exponential_decay", "Scheduler", ExponentialDecay,
                "Exponential decay from lr to lr_final over max_steps, optional warm-up.",
                "nerfstudio.engine.schedulers.ExponentialDecaySchedulerConfig",
                code=Code(("from nerfstudio.engine.schedulers import ExponentialDecaySchedulerConfig",),
                          ctor=_ctor("ExponentialDecaySchedulerConfig", "lr_final={{ p.lr_final }}, "
                                     "max_steps={{ p.max_steps }}, warmup_steps={{ p.warmup_steps }}"))),
    TerminalDef("multistep", "Scheduler", MultiStep, "Multiply the learning rate by gamma at each milestone.",
                "nerfstudio.engine.schedulers.MultiStepSchedulerConfig",
                code=Code(("from nerfstudio.engine.schedulers import MultiStepSchedulerConfig",),
                          ctor=_ctor("MultiStepSchedulerConfig", "max_steps={{ p.max_steps }}, gamma={{ p.gamma }}, "
                                     "milestones={{ p.milestones | list | tuple_literal }}"))),
    TerminalDef("cosine_decay", "Scheduler", CosineDecay,
                "Linear warm-up then cosine decay to learning_rate_alpha * lr.",
                "nerfstudio.engine.schedulers.CosineDecaySchedulerConfig",
                code=Code(("from nerfstudio.engine.schedulers import CosineDecaySchedulerConfig",),
                          ctor=_ctor("CosineDecaySchedulerConfig", "warm_up_end={{ p.warm_up_end }}, "
                                     "learning_rate_alpha={{ p.learning_rate_alpha }}, max_steps={{ p.max_steps }}"))),
]
