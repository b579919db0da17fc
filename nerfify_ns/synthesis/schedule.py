"""A paper's schedule fitted to a shorter run: the phases a run must get through scaled with it.

A paper trains for ``trainer.max_num_iterations`` (30k for most); a CPU run on a budget trains for a few hundred.
Kept as they are, some of the paper's step counts never play out: a 512-step learning-rate warm-up is still warming
up when a 60-iteration run ends, and TensoRF's grids are never upsampled. :func:`scale_schedule` scales the
parameters counted in iterations that ``schedule.yaml`` lists (data) by ``run / paper`` and returns the change as a
record (the plan's ``schedule`` annotation) and as ns-train arguments for the run. Decay horizons and the proposal
sampler's update warm-up and weight annealing (Mip-NeRF 360 Sec. 3, Eq. 18) are not listed: scaled, they were
measured to hurt a short run (``schedule.yaml`` has the figures). The plugin's code keeps the paper's schedule; only
the budgeted run is fitted. Runs that compare fixed schedules (the parity benchmark, ``compose --method``) do not
call it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from typing import Any, Dict, List

import yaml

from nerfify_ns.grammar import derive, load_grammar
from nerfify_ns.plan import Plan


@lru_cache(maxsize=1)
def step_parameters() -> dict:
    """``schedule.yaml``: the parameters counted in iterations."""
    return yaml.safe_load(resources.files("nerfify_ns.synthesis").joinpath("schedule.yaml").read_text())


@dataclass
class ScheduleFit:
    """How a run's schedule differs from the paper's."""

    paper_iterations: int
    run_iterations: int
    factor: float
    """run / paper (1.0: nothing scaled)."""
    changes: List[dict] = field(default_factory=list)
    """Per scaled value: ``path`` (plan path or ``config:<field>``), ``from``, ``to``."""
    args: List[str] = field(default_factory=list)
    """ns-train arguments that give the run the scaled values."""
    skipped: List[str] = field(default_factory=list)
    """Step-valued parameters that could not be passed to ns-train (no config field for the base), with why."""

    @property
    def scaled(self) -> bool:
        return bool(self.changes)

    def record(self) -> dict:
        """The plan's ``schedule`` annotation."""
        why = (f"the run trains {self.run_iterations} of the paper's {self.paper_iterations} iterations: every "
               f"step count of the schedule is scaled by {self.factor:.4g} (the plugin's code keeps the paper's)")
        return {"paper_iterations": self.paper_iterations, "run_iterations": self.run_iterations,
                "factor": round(self.factor, 6), "reason": why, "scaled": self.changes,
                "ns_train_args": list(self.args), **({"not_scaled": self.skipped} if self.skipped else {})}


def _scale(value: Any, factor: float, minimum: int) -> Any:
    if isinstance(value, list):
        out: List[int] = []
        for v in value:  # milestones and upsampling steps stay strictly increasing, as many as before
            out.append(max(_scale(v, factor, minimum), out[-1] + 1 if out else minimum))
        return out
    if not isinstance(value, int) or isinstance(value, bool) or value == 0:
        return value  # a warm-up of 0 stays 0
    return max(minimum, int(round(value * factor)))


def _flag(text: str) -> str:
    return text.replace("_", "-")


def _values(value: Any) -> List[str]:
    return [str(v) for v in value] if isinstance(value, list) else [str(value)]


def scale_schedule(plan: dict, iterations: int) -> ScheduleFit:
    """The schedule of ``plan`` fitted to a run of ``iterations``: nothing when the run is at least as long as
    the paper's ``trainer.max_num_iterations``."""
    from nerfify_ns.registry import default_registry

    plan = Plan.of(plan)
    paper = int(((plan.get("trainer") or {}).get("max_num_iterations")) or 0)
    if paper <= 0 or iterations >= paper:
        return ScheduleFit(paper or iterations, iterations, 1.0)
    factor = iterations / paper
    fit = ScheduleFit(paper, iterations, factor)
    spec = step_parameters()
    grammar = load_grammar()
    terminals = default_registry().terminals
    base = plan.get("base")
    for path, terminal in derive(plan, grammar).used.items():
        names = spec["terminals"].get(terminal) or []
        extra = (spec.get("config") or {}).get(terminal) or {}
        if not names and not extra:
            continue
        params = plan.get(path) or {}
        if path.startswith("optimizers."):  # optimizers.<group>.scheduler.<terminal>
            group = path.split(".")[1]
            flag = lambda name: f"--optimizers.{_flag(group)}.scheduler.{_flag(name)}"  # noqa: E731
        else:
            fields: Dict[str, str] = (terminals[terminal].config or {}).get(base) or {}
            if not fields:
                fit.skipped += [f"{path}.{n}: the base {base!r} has no config field for {terminal}" for n in names]
                continue
            flag = lambda name: f"--pipeline.model.{_flag(fields.get(name, name))}"  # noqa: E731
        defaults = grammar.terminals[terminal].params
        for name in names:
            before = params.get(name, defaults[name].default if name in defaults else None)
            after = _scale(before, factor, 0 if "warmup" in name and before == 0 else 1)
            if before is None or after == before:
                continue
            fit.changes.append({"path": f"{path}.{name}", "from": before, "to": after})
            fit.args += [flag(name), *_values(after)]
        for name, default in extra.items():
            after = _scale(default, factor, 1)
            if after != default:
                fit.changes.append({"path": f"config:{name}", "from": default, "to": after})
                fit.args += [f"--pipeline.model.{_flag(name)}", str(after)]
    return fit
