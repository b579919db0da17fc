"""How much a run computes on the CPU: the scene, the ladder's smoke rung, training and evaluation.

A leaf module (standard library only): the CLI reads the defaults for its ``--help`` without importing the
pipeline. Longer runs are one flag away (``--iterations``, ``--every``, ``--smoke-iterations``). A budget checks
its own numbers when it is built (:class:`BudgetError`); the scene settings are checked where the scene is
rendered (``nerfify_ns.scenes.check_settings``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Tuple

from nerfify_ns.errors import NerfifyError


class BudgetError(NerfifyError):
    """A number of the budget out of its range (``--iterations 0``, ``--every -5``...)."""


def check_count(option: str, value: object, minimum: int = 1) -> None:
    """Raise :class:`BudgetError` unless ``value`` is a whole number >= ``minimum``; ``option`` names it as the
    user typed it (``--iterations``)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise BudgetError(f"{option} must be a whole number, got {value!r}")
    if value < minimum:
        raise BudgetError(f"{option} must be at least {minimum}, got {value}")


def check_seconds(option: str, value: object) -> None:
    """Raise :class:`BudgetError` unless ``value`` is a finite number of seconds > 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise BudgetError(f"{option} must be a positive number of seconds, got {value!r}")


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

    def __post_init__(self) -> None:
        """Every number in its range (a budget is built from command-line options: one clear error)."""
        check_count("--iterations", self.iterations)
        check_count("--every", self.every)
        if self.smoke_iterations is not None:
            check_count("--smoke-iterations", self.smoke_iterations)
        check_seconds("the time limit", self.timeout)


PAPER_BUDGET = Budget()
"""``ns-nerfify PAPER``: the evaluation run the report is about; the smoke rung as short as the ladder's own tests
(``--until verify`` on the example paper within a minute)."""
COMPOSE_BUDGET = Budget(iterations=30, every=15, cpu_presets=True,
                        train_args=("--pipeline.datamanager.train-num-rays-per-batch", "256"),
                        scene={"resolution": 32, "n_train": 12, "n_val": 2, "n_test": 2})
"""``ns-nerfify compose``: every reference plan within about 2 minutes on a 2-core CPU (measured in README)."""
