"""A budgeted training that keeps its deadline: it stops itself, with a checkpoint, when one more step would leave
too little time to render its checkpoints, and trains on while time is left.

A wall-clock budget becomes a number of iterations from the ladder's smoke rung, which measured a few steps minutes
earlier; a machine's pace changes (another process, a slower phase of the method), so that number is an estimate.
The pipeline gives the training process its deadline (:data:`ENV_PACE`, a :class:`Pace`), and ``ns-train`` a
ceiling above the estimate; :func:`install` (applied by the runtime whenever the variable is set, GPU or not)
measures each step's wall time in the trainer and, after each iteration, stops the run when the time left would no
longer cover another step (at the pace of the last steps), starting the rendering process and rendering every
checkpoint saved (at the whole run's pace against the one planned) with a margin. Nerfstudio's own loop then saves
the last checkpoint at the step reached, so a stop always leaves something to evaluate. The process's hard limit
stays behind it.

What the training process says about itself is not a verdict: the iterations done are read from its events and its
time is measured outside, as for every run.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

ENV_PACE = "NERFIFY_TRAIN_PACE"
"""The training's :class:`Pace` as JSON (set by the pipeline for a budgeted run)."""
MEASURED_STEPS = 10
"""Steps timed before the pace decides anything (the first ones pay one-off costs; a burst of load over three steps
once stopped a run at its fourth)."""
WINDOW = 16
"""The next step's cost is the median of the last this many steps' wall times."""
STOP_LINE = "nerfify: stopped by the budget's deadline"
"""How the training's log says that it stopped itself."""


@dataclass(frozen=True)
class Pace:
    """When a budgeted training must be done, and what follows it."""

    end: float
    """Wall-clock time (``time.time()``) by which the training and the rendering of its checkpoints are done."""
    step_seconds: float
    """A training step's seconds the budget planned with."""
    render_seconds: float
    """Rendering one checkpoint's test views at that planned pace."""
    startup_seconds: float
    """Starting the rendering process (a Nerfstudio process)."""
    margin_seconds: float
    """Time kept in hand for what no estimate covers."""
    iterations: float = 0.0
    """The iterations the run's schedule was compressed for (its model config's ``schedule_step_scale``); 0: none."""

    def to_env(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_env(cls, text: str | None) -> Pace | None:
        """The pace in ``text`` (:data:`ENV_PACE`'s value); None when unset or not a pace (the hard limit then
        stands alone)."""
        if not text:
            return None
        try:
            fields = json.loads(text)
            pace = cls(**{k: float(fields[k]) for k in cls.__dataclass_fields__ if k != "iterations"},
                       iterations=float(fields.get("iterations", 0.0)))
        except (ValueError, TypeError, KeyError):
            return None
        return pace if pace.step_seconds > 0 else None


class PaceKeeper:
    """Decides after each training step whether the run stops there (:meth:`after_step`)."""

    def __init__(self, pace: Pace, clock: Callable[[], float] = time.time) -> None:
        self.pace = pace
        self.clock = clock
        self.durations: deque[float] = deque(maxlen=WINDOW)
        self.every: list[float] = []
        self.last: float | None = None
        self.planned_scale: float | None = None
        """The model config's ``schedule_step_scale`` as the run started (:func:`_follow_deadline`)."""

    def step_seconds(self) -> float | None:
        """The next step's expected seconds (median of the recent steps), None before :data:`MEASURED_STEPS` were
        timed."""
        return statistics.median(self.durations) if len(self.every) >= MEASURED_STEPS else None

    def finish(self, checkpoints_after: int) -> float | None:
        """When the evaluation would be done if the run trained one more step and then stopped with
        ``checkpoints_after`` checkpoints to render; None while the pace is unmeasured. The rendering is charged
        at the whole run's pace against the planned one (a forward pass of the same model on the same machine;
        not the last steps', whose bursts a rendering minutes later need not share)."""
        step = self.step_seconds()
        if step is None:
            return None
        slower = statistics.median(self.every) / self.pace.step_seconds
        return (self.clock() + step + self.pace.startup_seconds
                + checkpoints_after * self.pace.render_seconds * slower + self.pace.margin_seconds)

    def expected_iterations(self, step: int, checkpoints_after: int) -> float | None:
        """The iterations the run will have trained when it stops, at the recent steps' pace, after training step
        ``step`` (counted from 0); None while the pace is unmeasured."""
        finish, seconds = self.finish(checkpoints_after), self.step_seconds()
        if finish is None or not seconds:
            return None
        return step + 1 + (1 + (self.pace.end - finish) / seconds if finish <= self.pace.end else 0.0)

    def after_step(self, checkpoints_after: int) -> bool:
        """Record a step that just ended; True when the run should stop now (``checkpoints_after``: the checkpoints
        there will be to render when it stops here, its final one included)."""
        now = self.clock()
        if self.last is not None:
            self.durations.append(now - self.last)
            self.every.append(now - self.last)
        self.last = now
        finish = self.finish(checkpoints_after)
        return finish is not None and finish > self.pace.end


def _checkpoints_before(folder: Path, step: int) -> int:
    """Checkpoints saved in ``folder`` at steps before ``step``."""
    count = 0
    for path in Path(folder).glob("step-*.ckpt"):
        try:
            count += int(path.stem.split("-", 1)[1]) < step
        except ValueError:
            continue
    return count


def _follow_deadline(model: Any, keeper: PaceKeeper, step: int, checkpoints: int) -> None:
    """A run slower than planned compresses its schedule further: the model config's ``schedule_step_scale`` (set
    for the planned iterations) times the iterations now expected over the planned ones, never raised (a stage
    that ended stays ended), so the paper's stages end within the steps the run gets."""
    from nerfify_ns.components.schedule_hooks import STEP_SCALE_FIELD  # torch: only in the training process

    config = getattr(model, "config", None)
    if keeper.pace.iterations <= 0 or not hasattr(config, STEP_SCALE_FIELD):
        return
    planned = keeper.planned_scale
    if planned is None:
        planned = keeper.planned_scale = float(getattr(config, STEP_SCALE_FIELD) or 1.0)
    expected = keeper.expected_iterations(step, checkpoints)
    if expected is not None:
        scale = planned * min(1.0, expected / keeper.pace.iterations)
        setattr(config, STEP_SCALE_FIELD, min(float(getattr(config, STEP_SCALE_FIELD) or 1.0), scale))


def install(text: str | None = None) -> bool:
    """Keep the deadline of :data:`ENV_PACE` (or ``text``) in Nerfstudio's trainer; False when there is none."""
    pace = Pace.from_env(text if text is not None else os.environ.get(ENV_PACE))
    if pace is None:
        return False
    from nerfstudio.engine.trainer import Trainer

    if getattr(Trainer.train_iteration, "_nerfify_pace", False):
        return True
    keeper = PaceKeeper(pace)
    train_iteration, after_train = Trainer.train_iteration, Trainer._after_train

    def paced_train_iteration(self, step: int):
        result = train_iteration(self, step)
        checkpoints = _checkpoints_before(self.checkpoint_dir, step) + 1
        if not self.stop_training and keeper.after_step(checkpoints):
            self.stop_training = True  # Nerfstudio's loop ends before the next step and saves this one
            self._nerfify_stopped_at = step
            print(f"{STOP_LINE}: after step {step}, a step taking {keeper.step_seconds():.3f} s "
                  f"(planned {pace.step_seconds:.3f} s)", file=sys.stderr, flush=True)
        elif not self.stop_training:
            _follow_deadline(getattr(getattr(self, "pipeline", None), "model", None), keeper, step, checkpoints)
        return result

    def paced_after_train(self):
        stopped = getattr(self, "_nerfify_stopped_at", None)
        if stopped is not None:
            self.step = stopped  # the loop moved on to a step it did not train; its checkpoint is the last trained
        return after_train(self)

    paced_train_iteration._nerfify_pace = True  # type: ignore[attr-defined]
    Trainer.train_iteration = paced_train_iteration
    Trainer._after_train = paced_after_train
    return True
