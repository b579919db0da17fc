"""How much a run computes on the CPU: the scene, the ladder's smoke rung, training and evaluation.

A leaf module (standard library only): the CLI reads the defaults for its ``--help`` without importing the
pipeline. Longer runs are one flag away (``--iterations``, ``--every``, ``--smoke-iterations``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Tuple


@dataclass
class Budget:
    """The CPU budget of one run."""

    iterations: int = 200
    """Training iterations of the evaluation run."""
    every: int = 50
    """Checkpoint cadence of the error-against-time curve (each checkpoint is rendered and scored)."""
    smoke_iterations: Optional[int] = None
    """Iterations of the verification ladder's smoke-training rung (None: the base's own, ``smoke_iterations`` in
    ``runtime/smoke_presets.yaml``)."""
    timeout: float = 300.0
    """Time limit of each sandboxed verification process, seconds."""
    scene: dict = field(default_factory=dict)
    """Settings of a rendered scene (``write_scene`` keywords: resolution, n_train, n_val, n_test)."""
    cpu_presets: bool = False
    """Train with the base method's CPU preset (ray batch, sample caps; ``runtime/smoke_presets.yaml``) on top
    of the evaluation's CPU settings."""
    train_args: Tuple[str, ...] = ()
    """ns-train arguments of the evaluation run after those (they win)."""


PAPER_BUDGET = Budget()
"""``ns-nerfify PAPER``: the evaluation run the report is about; the smoke rung as short as the ladder's own tests
(``--until verify`` on the example paper within a minute)."""
COMPOSE_BUDGET = Budget(iterations=30, every=15, cpu_presets=True,
                        train_args=("--pipeline.datamanager.train-num-rays-per-batch", "256"),
                        scene={"resolution": 32, "n_train": 12, "n_val": 2, "n_test": 2})
"""``ns-nerfify compose``: every reference plan within about 2 minutes on a 2-core CPU (measured in README)."""
