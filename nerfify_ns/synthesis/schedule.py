"""A paper's schedule fitted to a shorter run: the phases a run must get through scaled with it.

A paper trains for ``trainer.max_num_iterations`` (30k for most); a CPU run on a budget trains for a few hundred.
Kept as they are, some of the paper's step counts never play out: a 512-step learning-rate warm-up is still warming
up when a 60-iteration run ends, and TensoRF's grids are never upsampled. :func:`scale_schedule` scales the
parameters counted in iterations that ``schedule.yaml`` lists (data) by ``run / paper`` and returns the change as a
record (the plan's ``schedule`` annotation) and as ns-train arguments for the run. A run on fewer rays per step than
the paper's batch (a CPU run takes 512 of 4096) gets the learning rates ``schedule.yaml`` lists scaled with the batch
(the linear scaling rule): at the paper's rates a small-batch run saturates its colour head within a few dozen
steps and renders grey. Decay horizons and the proposal
sampler's update warm-up and weight annealing (Mip-NeRF 360 Sec. 3, Eq. 18) are not listed: scaled, they were
measured to hurt a short run (``schedule.yaml`` has the figures). The plugin's code keeps the paper's schedule; only
the budgeted run is fitted. Runs that compare fixed schedules (the parity benchmark, ``compose --method``) do not
call it.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from typing import Any

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
    changes: list[dict] = field(default_factory=list)
    """Per scaled value: ``path`` (plan path or ``config:<field>``), ``from``, ``to``."""
    args: list[str] = field(default_factory=list)
    """ns-train arguments that give the run the scaled values."""
    skipped: list[str] = field(default_factory=list)
    """Step-valued parameters that could not be passed to ns-train (no config field for the base), with why."""

    batch: dict | None = None
    """When the run's ray batch is smaller than the paper's: ``paper_rays``, ``run_rays``, ``factor`` (the learning
    rates' scale) and ``rule``; the scaled learning rates are among ``changes``."""
    width: dict | None = None
    """When the run's MLP is narrower than the paper's (a CPU proxy): ``ratio`` (run / paper), ``factor`` (the
    learning rates' scale) and ``rule``; folded into the same scaled learning rates."""

    @property
    def scaled(self) -> bool:
        return bool(self.changes)

    def record(self) -> dict:
        """The plan's ``schedule`` annotation."""
        why = (f"the run trains {self.run_iterations} of the paper's {self.paper_iterations} iterations: every "
               f"step count of the schedule is scaled by {self.factor:.4g}")
        set_at = (self.batch or {}).get("set_at") or {}
        if set_at:
            why += (f"; it trains on {self.batch['run_rays']} of the paper's {self.batch['paper_rays']} rays per "
                    f"step: the learning rates are scaled for it ({self.batch['rule']} scaling rule) from the batch "
                    "they were set for: " + ", ".join(
                        f"{g}'s, from {v['from']}, set for {v['rays']} rays, by {v['factor']:.4g}"
                        for g, v in set_at.items())
                    + ("" if self.batch["factor"] == 1.0 else
                       f"; the paper's own by {self.batch['factor']:.4g}"))
        elif self.batch and self.batch["factor"] != 1.0:
            why += (f"; it trains on {self.batch['run_rays']} of the paper's {self.batch['paper_rays']} rays per "
                    f"step: every learning rate is scaled by {self.batch['factor']:.4g} ({self.batch['rule']} "
                    f"scaling rule)")
        elif self.batch:
            why += (f"; it trains on {self.batch['run_rays']} of the paper's {self.batch['paper_rays']} rays per "
                    f"step with the paper's learning rates (the base's rule: {self.batch['rule']})")
        if self.width:
            why += (f"; its MLP is {self.width['ratio']:.4g} of the paper's width: every learning rate is scaled by "
                    f"{self.width['factor']:.4g} ({self.width['rule']})")
        why += " (the plugin's code keeps the paper's values)"
        return {"paper_iterations": self.paper_iterations, "run_iterations": self.run_iterations,
                "factor": round(self.factor, 6), **({"batch": self.batch} if self.batch else {}),
                **({"width": self.width} if self.width else {}), "reason": why,
                "scaled": self.changes, "ns_train_args": list(self.args),
                **({"not_scaled": self.skipped} if self.skipped else {})}


def _scale(value: Any, factor: float, minimum: int) -> Any:
    if isinstance(value, list):
        out: list[int] = []
        for v in value:  # milestones and upsampling steps stay strictly increasing, as many as before
            out.append(max(_scale(v, factor, minimum), out[-1] + 1 if out else minimum))
        return out
    if not isinstance(value, int) or isinstance(value, bool) or value == 0:
        return value  # a warm-up of 0 stays 0
    return max(minimum, int(round(value * factor)))


def _flag(text: str) -> str:
    return text.replace("_", "-")


def _values(value: Any) -> list[str]:
    return [str(v) for v in value] if isinstance(value, list) else [str(value)]


def scale_schedule(plan: dict, iterations: int, rays: int | None = None, width: float = 1.0) -> ScheduleFit:
    """The schedule of ``plan`` fitted to a run of ``iterations`` on ``rays`` rays per step: its step counts when
    the run is shorter than the paper's ``trainer.max_num_iterations``, its learning rates when ``rays`` is fewer
    than the paper's ``datamanager.train_num_rays_per_batch`` and when ``width`` (the run's MLP width over the
    paper's, a CPU proxy's) is below 1."""
    plan = Plan.of(plan)
    used = derive(plan, load_grammar()).used
    paper = int(((plan.get("trainer") or {}).get("max_num_iterations")) or 0)
    if paper <= 0 or iterations >= paper:
        fit = ScheduleFit(paper or iterations, iterations, 1.0)
    else:
        fit = ScheduleFit(paper, iterations, iterations / paper)
        _scale_steps(plan, used, fit)
    if rays or width < 1.0:
        _scale_learning_rates(plan, used, rays, fit, width)
    return fit


def width_factor(width: float) -> tuple[float, str]:
    """The learning rates' scale for an MLP ``width`` times the paper's (``schedule.yaml``'s ``width``), and the
    rule's name."""
    rule = step_parameters()["width"]
    return (1.0 if width >= 1.0 else width ** -float(rule["exponent"])), rule["rule"]


def width_learning_rates(plan: dict, width: float) -> list[str]:
    """ns-train arguments that scale ``plan``'s learning rates for an MLP ``width`` times the paper's (the smoke
    rung of a budgeted run, which trains at the proxy's floors), nothing else scaled."""
    fit = ScheduleFit(0, 0, 1.0)
    plan = Plan.of(plan)
    _scale_learning_rates(plan, derive(plan, load_grammar()).used, None, fit, width)
    return fit.args

def _value(plan: Plan, path: str, terminal: str, name: str) -> Any:
    """A terminal's parameter as the plan gives it, else the terminal's default (None: no such parameter)."""
    defaults = load_grammar().terminals[terminal].params
    return (plan.get(path) or {}).get(name, defaults[name].default if name in defaults else None)


def _scale_learning_rates(plan: Plan, used: dict[str, str], rays: int | None, fit: ScheduleFit,
                          width: float = 1.0) -> None:
    """The learning rates of ``schedule.yaml``'s ``batch`` section scaled for a run of ``rays`` rays per step and an
    MLP ``width`` times the paper's (``used``: the plan's terminals by path)."""
    paper_rays = int(((plan.get("datamanager") or {}).get("train_num_rays_per_batch")) or 0)
    rule = step_parameters()["batch"]
    parts = rule.get("parts") or {}  # a part, else a base, measured to need its own rule
    own = (next((parts[t] for t in used.values() if t in parts), None)
           or (rule.get("bases") or {}).get(plan.get("base")) or {})
    exponent = own.get("exponent", rule["exponent"])
    set_at = _learning_rates_set_at(plan, paper_rays)
    factors: dict[str, float] = {}
    for group, (reference, _source) in set_at.items():
        factors[group] = (rays / reference) ** exponent if rays and 0 < rays < reference else 1.0
    if rays and any(0 < rays < reference for reference, _ in set_at.values()):
        paper_factor = (rays / paper_rays) ** exponent if 0 < rays < paper_rays else 1.0
        fit.batch = {"paper_rays": paper_rays, "run_rays": rays, "factor": round(paper_factor, 6),
                     "rule": own.get("rule", rule["rule"])}
        base_set = {g: {"rays": r, "from": src, "factor": round(factors[g], 6)} for g, (r, src) in set_at.items()
                    if src and r != paper_rays}
        if base_set:
            fit.batch["set_at"] = base_set
    scale = 1.0
    if width < 1.0:
        scale, name = width_factor(width)
        fit.width = {"ratio": round(width, 6), "factor": round(scale, 6), "rule": name}
    for path, terminal in used.items():
        names = rule["learning_rates"].get(terminal) or []
        if not names or not path.startswith("optimizers."):
            continue
        group, part = path.split(".")[1:3]  # optimizers.<group>.<optimizer|scheduler>.<terminal>
        factor = factors.get(group, 1.0) * scale
        if factor == 1.0:
            continue
        for name in names:
            before = _value(plan, path, terminal, name)
            if not isinstance(before, int | float) or isinstance(before, bool):
                continue
            after = float(f"{before * factor:.6g}")
            fit.changes.append({"path": f"{path}.{name}", "from": before, "to": after})
            fit.args += [f"--optimizers.{_flag(group)}.{part}.{_flag(name)}", str(after)]


def _learning_rates_set_at(plan: Plan, paper_rays: int) -> dict[str, tuple[int, str]]:
    """Per optimiser group, the ray batch its learning rates were set for, and where they come from ('' for the
    paper): the paper's batch, unless the plan keeps its base plan's rates (their evidence says so), which its base
    set for the base's own batch (DyNeRF states 24,576 rays; its space-time planes train at K-Planes' rates, set for
    4,096)."""
    from nerfify_ns.synthesis.plan_from_paper import base_of
    from nerfify_ns.synthesis.resources import load_reference_plan

    out = {}
    for group in plan.get("optimizers") or {}:
        base = base_of(str(plan.evidence.get(f"optimizers.{group}.optimizer", "")))
        reference = paper_rays
        if base:
            try:
                reference = int(load_reference_plan(base)["datamanager"]["train_num_rays_per_batch"])
            except (KeyError, TypeError, ValueError, OSError):
                base = None
        out[group] = (reference or paper_rays, f"the base plan {base!r}" if base else "")
    return out


def training_covers_stages(plan: Plan, unstated: Collection[str] = ()) -> str | None:
    """``plan``'s training made long enough for every stage its schedule hooks end (``schedule.yaml``:
    ``stage_end``): when the last stage ends at or past ``trainer.max_num_iterations``, the training becomes that
    stage and then the stated count, and the line saying so is returned (also kept in the plan's notes and the
    training length's evidence); None when every stage ends within the training. A stage's end among ``unstated``
    (plan paths of values the paper does not give, asked in ``equations.yaml``) lengthens nothing."""
    spec = step_parameters()
    slot = spec.get("hooks") or ""
    key, hooks = spec.get("stage_end"), plan.get(slot)
    stated = plan.get("trainer.max_num_iterations")
    if not key or not isinstance(hooks, dict) or not isinstance(stated, int) or stated < 1:
        return None
    ends = {name: params[key] for name, params in hooks.items()
            if isinstance(params, dict) and isinstance(params.get(key), int) and not isinstance(params[key], bool)
            and f"{slot}.{name}.{key}" not in unstated}
    if not ends or max(ends.values()) < stated:
        return None
    last = max(ends, key=ends.get)
    total = ends[last] + stated
    line = (f"the schedule's {last} stage ends at step {ends[last]}, at or after the plan's {stated} training "
            f"iterations: a stage cannot outlast the training, so that count is read as what follows the stage, and "
            f"the plan trains {total} iterations (the stage, then {stated})")
    plan.set("trainer.max_num_iterations", total)
    evidence = plan.evidence
    evidence["trainer.max_num_iterations"] = (f"{evidence.get('trainer.max_num_iterations', stated)}; then {line}")
    plan.setdefault("notes", []).append(line)
    return line


def _scale_steps(plan: Plan, used: dict[str, str], fit: ScheduleFit) -> None:
    """The step counts of ``schedule.yaml``'s ``terminals`` and ``config`` sections scaled by ``fit.factor``
    (``used``: the plan's terminals by path)."""
    from nerfify_ns.registry import default_registry

    factor = fit.factor
    spec = step_parameters()
    terminals = default_registry().terminals
    base = plan.get("base")
    hooks = spec.get("hooks")
    if hooks and any(path.startswith(hooks + ".") for path in used):
        from nerfify_ns.components.schedule_hooks import STEP_SCALE_FIELD as field_name

        fit.changes.append({"path": f"config:{field_name}", "from": 1.0, "to": round(factor, 6)})
        fit.args += [f"--pipeline.model.{_flag(field_name)}", f"{factor:.6g}"]
    for path, terminal in used.items():
        names = spec["terminals"].get(terminal) or []
        extra = (spec.get("config") or {}).get(terminal) or {}
        if not names and not extra:
            continue
        if path.startswith("optimizers."):  # optimizers.<group>.scheduler.<terminal>
            group = path.split(".")[1]
            flag = lambda name, group=group: f"--optimizers.{_flag(group)}.scheduler.{_flag(name)}"  # noqa: E731
        else:
            fields: dict[str, str] = (terminals[terminal].config or {}).get(base) or {}
            if not fields:
                fit.skipped += [f"{path}.{n}: the base {base!r} has no config field for {terminal}" for n in names]
                continue
            flag = lambda name, fields=fields: f"--pipeline.model.{_flag(fields.get(name, name))}"  # noqa: E731
        for name in names:
            before = _value(plan, path, terminal, name)
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
