"""How much a run computes on the CPU: the scene, the ladder's smoke rung, training and evaluation.

A leaf module (standard library only): the CLI reads the defaults for its ``--help`` without importing the
pipeline. Longer runs are one flag away (``--iterations``, ``--every``, ``--smoke-iterations``, ``--budget``). A
budget checks its own numbers when it is built (:class:`BudgetError`); the scene settings are checked where the
scene is rendered (``nerfify_ns.scenes.check_settings``).

A wall-clock budget (``seconds``, ``--budget 4m``) bounds the whole run, evaluation included: the stages before
training take what they take (reading, planning, the verification ladder), and :func:`fit_iterations` turns the
time left into training iterations from what the ladder's smoke rung measured (seconds per iteration, the
start-up of a sandboxed Nerfstudio process), leaving room for rendering the checkpoints afterwards.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

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
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise BudgetError(f"{option} must be a positive number of seconds, got {value!r}")


_DURATION = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*(s|sec|m|min|h)?\s*$", re.IGNORECASE)
_UNIT_SECONDS = {"s": 1.0, "sec": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0}


def parse_duration(text: object) -> float:
    """Seconds from ``--budget``'s text: ``4m``, ``90s``, ``1.5min``, ``0.5h``, or a bare number of minutes."""
    match = _DURATION.match(str(text))
    if match is None:
        raise BudgetError(f"--budget must be a duration such as 4m, 90s or 0.5h (a bare number is minutes), "
                          f"got {text!r}")
    seconds = float(match.group(1)) * _UNIT_SECONDS[(match.group(2) or "m").lower()]
    check_seconds("--budget", seconds)
    return seconds


@dataclass
class Budget:
    """The CPU budget of one run."""

    iterations: int = 200
    """Training iterations of the evaluation run."""
    every: int | None = 50
    """Checkpoint cadence of the error-against-time curve (each checkpoint is rendered and scored); None: the
    iterations spread over ``checkpoints``."""
    smoke_iterations: int | None = None
    """Iterations of the verification ladder's smoke-training rung (None: the base's own, ``smoke_iterations`` in
    ``runtime/smoke_presets.yaml``)."""
    timeout: float | None = None
    """Time limit of each process of the run (the ladder's, training, rendering), seconds, when the user or a suite
    gives one. None: with ``seconds`` each limit derives from the time left (:func:`smoke_limit`,
    :func:`training_limit`, :func:`check_limit`); without, the check rungs (static, contract, stability) take at most
    :data:`CHECK_SECONDS` each and nothing else has a limit."""
    scene: dict = field(default_factory=dict)
    """Settings of a rendered scene (``write_scene`` keywords: resolution, n_train, n_val, n_test)."""
    cpu_presets: bool = False
    """Train with the base method's CPU preset (ray batch, sample caps; ``runtime/smoke_presets.yaml``) on top
    of the evaluation's CPU settings."""
    train_args: tuple[str, ...] = ()
    """ns-train arguments of the evaluation run after those (they win)."""
    seconds: float | None = None
    """Wall-clock budget of the whole run, evaluation included (None: ``iterations`` decide). With it,
    ``iterations`` is an upper bound and the run trains as many as fit (:func:`fit_iterations`), at most the
    plan's own ``trainer.max_num_iterations``."""
    checkpoints: int = 3
    """Checkpoints rendered for the error-against-time curve when ``every`` is None."""
    proxy: bool = False
    """Train a CPU proxy of the method when the paper's settings do not fit ``seconds`` (fewer samples per ray,
    rays per step, a smaller scene; ``nerfify_ns.synthesis.proxy``); off where fixed settings are compared."""
    scale_schedule: bool = False
    """Scale the plan's step counts listed in ``synthesis/schedule.yaml`` (warm-ups, upsampling steps) to the run
    when it is shorter than the paper's schedule (``nerfify_ns.synthesis.schedule``); off where fixed schedules are
    compared."""

    def __post_init__(self) -> None:
        """Every number in its range (a budget is built from command-line options: one clear error)."""
        check_count("--iterations", self.iterations)
        if self.every is not None:
            check_count("--every", self.every)
        if self.smoke_iterations is not None:
            check_count("--smoke-iterations", self.smoke_iterations)
        if self.timeout is not None:
            check_seconds("the time limit", self.timeout)
        if self.seconds is not None:
            check_seconds("--budget", self.seconds)
        check_count("checkpoints", self.checkpoints)

    def cadence(self, iterations: int) -> int:
        """Iterations between checkpoints of a run of ``iterations``."""
        return self.every if self.every is not None else max(1, math.ceil(iterations / self.checkpoints))


CHECK_SECONDS = 300.0
"""Time limit of each sandboxed check process of the ladder (static, contract, stability: seconds of work; an
infinite loop in generated code must end) when no budget bounds the run."""
SMOKE_SHARE = 0.35
"""The share of a budget's time left, when the ladder starts, that its smoke rung may take: the rest trains and
evaluates (training and rendering cost several smoke rungs' worth)."""


@dataclass(frozen=True)
class Limit:
    """A time limit and where it comes from, named in the message when it is reached."""

    seconds: float | None
    """None: no limit."""
    source: str

    def describe(self) -> str:
        return f"the {self.seconds:.0f} s limit of {self.source}" if self.seconds is not None else "no time limit"

    @property
    def timeout(self) -> float:
        """For the process runner (infinity: none)."""
        return math.inf if self.seconds is None else self.seconds


GIVEN = "each process (the budget's timeout)"


def smoke_limit(budget: Budget, seconds_left: float | None) -> Limit:
    """The smoke rung's time limit: the budget's ``timeout`` when given; with a wall-clock budget its share of
    ``seconds_left`` (:data:`SMOKE_SHARE`); otherwise none."""
    if budget.timeout is not None:
        return Limit(budget.timeout, GIVEN)
    if budget.seconds is None or seconds_left is None:
        return Limit(None, "none")
    seconds = max(SMOKE_SHARE * seconds_left, 1.0)
    return Limit(seconds, f"the smoke rung's share of the {_duration(budget.seconds)} budget "
                          f"({SMOKE_SHARE:.0%} of the {max(seconds_left, 0):.0f} s left when the ladder started)")


def check_limit(budget: Budget, seconds_left: float | None) -> Limit:
    """Each check process's limit: the time left of a wall-clock budget (at most :data:`CHECK_SECONDS`), else
    :data:`CHECK_SECONDS`; the budget's ``timeout`` when given."""
    if budget.timeout is not None:
        return Limit(budget.timeout, GIVEN)
    if budget.seconds is not None and seconds_left is not None and seconds_left < CHECK_SECONDS:
        return Limit(max(seconds_left, 1.0), f"the {_duration(budget.seconds)} budget (the time it had left)")
    return Limit(CHECK_SECONDS, "a check process of the ladder")


def training_limit(budget: Budget, seconds_left: float | None) -> Limit:
    """The training's and the rendering's limit: with a wall-clock budget, the time it had left when training
    started (a misestimate is cut off, not left running); without, the budget's ``timeout`` when given (a
    benchmark suite's), else none (``--iterations`` alone runs them all)."""
    if budget.seconds is None or seconds_left is None:
        return Limit(budget.timeout, GIVEN) if budget.timeout is not None else Limit(None, "none")
    return Limit(max(seconds_left, 1.0), f"the {_duration(budget.seconds)} budget (the time it had left when "
                                         f"training started)")


def _duration(seconds: float) -> str:
    """``4-minute``, ``90-second``: a budget as the user gave it."""
    if seconds >= 60 and seconds % 60 == 0:
        return f"{seconds / 60:.0f}-minute"
    return f"{seconds:.0f}-second"


MIN_ITERATIONS = 10
"""Fewer training iterations than this are not a run worth evaluating: the budget is too short."""
RENDER_COST = 0.35
"""Rendering a ray costs about this fraction of training on it (a forward pass without backward or optimiser
step; measured on the gridlite plan)."""
POST_SECONDS = 10.0
"""Error maps, consistency, LPIPS and the report after rendering (64 px scenes; a few seconds)."""


@dataclass
class TimeFit:
    """How a budget's time left became training iterations."""

    iterations: int
    every: int
    seconds_left: float
    seconds_per_iteration: float
    startup_seconds: float
    render_seconds: float
    """Estimated rendering of every checkpoint (startup excluded)."""
    render_one_seconds: float = 0.0
    """Estimated rendering of one checkpoint's test views."""

    def describe(self) -> str:
        return (f"{self.iterations} iterations fit the {self.seconds_left:.0f} s left (measured "
                f"{self.seconds_per_iteration:.2f} s per iteration, {self.startup_seconds:.0f} s to start each "
                f"Nerfstudio process, about {self.render_seconds:.0f} s to render the checkpoints)")


def scaled_step(seconds: float, rays_from: int, rays_to: int, *, ray_share: float | None, exponent: float,
                per_ray: float = 1.0) -> float:
    """A training step's seconds at ``rays_to`` rays from one measured at ``rays_from``. With ``ray_share`` (the part
    of the measured step that its rays cost: the smoke rung's ray-cost timing) that part scales with the rays and by
    ``per_ray`` (e.g. the samples per ray against those measured), the rest of the step (the optimiser, regularisers
    over whole grids) stays; without it the whole step scales as ``(rays_to / rays_from) ** exponent * per_ray``
    (the base's measured exponent)."""
    ratio = rays_to / max(rays_from, 1)
    if ray_share is None:
        return seconds * ratio ** exponent * per_ray
    share = min(max(ray_share, 0.0), 1.0)
    return seconds * ((1.0 - share) + share * ratio * per_ray)


def fit_iterations(seconds_left: float, seconds_per_iteration: float, startup_seconds: float,
                   rays_per_checkpoint: int, rays_per_iteration: int, budget: Budget,
                   most: int | None = None, render_cost: float = RENDER_COST) -> TimeFit:
    """Training iterations that fit ``seconds_left``: a training process (``startup_seconds`` + iterations), a
    rendering process (``startup_seconds`` + each checkpoint's ``rays_per_checkpoint`` rays at
    ``render_cost`` of a training ray, :data:`RENDER_COST` unless the base's preset measured its own) and
    :data:`POST_SECONDS`; at most ``most``. Raises
    :class:`BudgetError` when fewer than :data:`MIN_ITERATIONS` fit."""
    per_ray = seconds_per_iteration / max(rays_per_iteration, 1)
    render_one = rays_per_checkpoint * per_ray * render_cost
    checkpoints = budget.checkpoints
    if budget.every is not None:  # a fixed cadence: as many checkpoints as the iterations that fit make
        per_iteration = seconds_per_iteration + render_one / budget.every
    else:
        per_iteration = seconds_per_iteration
    fixed = 2 * startup_seconds + (0 if budget.every else checkpoints * render_one) + POST_SECONDS
    spare = seconds_left - fixed
    iterations = int(spare // per_iteration) if spare > 0 else 0
    if most is not None:
        iterations = min(iterations, most)
    render = math.ceil(iterations / budget.cadence(max(iterations, 1))) * render_one
    if iterations < MIN_ITERATIONS:
        need = fixed + MIN_ITERATIONS * per_iteration  # the time left at which MIN_ITERATIONS fit
        raise BudgetError(f"the budget leaves {max(seconds_left, 0):.0f} s for training and evaluation, and "
                          f"{MIN_ITERATIONS} iterations with their evaluation need about {need:.0f} s (measured "
                          f"{seconds_per_iteration:.2f} s per iteration and {startup_seconds:.0f} s to start each "
                          f"of the two Nerfstudio processes); give a longer --budget")
    return TimeFit(iterations, budget.cadence(iterations), seconds_left, seconds_per_iteration, startup_seconds,
                   render, render_one)


PACE_CEILING = 2.0
"""A budgeted training's ``ns-train`` iterations: this many times the estimate that fits (at most the plan's own
and the budget's): the training keeps the budget's deadline itself (:mod:`nerfify_ns.runtime.pace`), so a
pessimistic estimate leaves no time unused and an optimistic one stops with a checkpoint."""
PACE_MARGIN = 0.04
"""The share of the time left when training starts that a paced training keeps in hand (at least
:data:`PACE_MARGIN_SECONDS`)."""
PACE_MARGIN_SECONDS = 3.0


def pace_margin(seconds: float) -> float:
    """The time a paced process of ``seconds`` keeps in hand: :data:`PACE_MARGIN` of it, at least
    :data:`PACE_MARGIN_SECONDS`."""
    return max(PACE_MARGIN * seconds, PACE_MARGIN_SECONDS)


def within_budget(record: dict | None, summary: dict) -> bool | None:
    """Whether a budgeted run's training and evaluation fit its wall-clock budget (``within_budget`` of the run's
    ``eval/summary.json``): it trained and its checkpoints were evaluated without reaching the limit, which is the
    time the budget had left when training started (a training that kept the budget's deadline itself fits it,
    however many iterations that was). ``record``: the run's budget record (the summary's ``budget``); None without
    a wall-clock budget (``--iterations`` alone). A budget that left too little to train at all ends the train stage
    with the budget's own error before any summary is written."""
    if not record or record.get("seconds") is None:
        return None
    return summary.get("status") == "ok" and not summary.get("stopped")


DEFAULT_BUDGET_SECONDS = 240.0
"""``ns-nerfify PAPER`` without ``--iterations`` or ``--budget``: 4 minutes of wall-clock, everything included."""
PAPER_BUDGET = Budget(iterations=30000, every=None, seconds=DEFAULT_BUDGET_SECONDS, scale_schedule=True,
                      checkpoints=2, proxy=True)
"""``ns-nerfify PAPER``: the evaluation run the report is about, as long as the budget allows (at most the paper's
30k iterations), two checkpoints rendered (half-way and the end: each costs a third of a training step per pixel of
every test view); the smoke rung as short as the ladder's own tests; a CPU proxy of the method when the paper's
settings do not fit."""
COMPOSE_BUDGET = Budget(iterations=30, every=15, cpu_presets=True,
                        train_args=("--pipeline.datamanager.train-num-rays-per-batch", "256"),
                        scene={"resolution": 32, "n_train": 12, "n_val": 2, "n_test": 2})
"""``ns-nerfify compose``: every reference plan within about 2 minutes on a 2-core CPU (measured in README)."""
