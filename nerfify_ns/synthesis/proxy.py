"""A CPU proxy of a paper's method: the settings that cost time scaled to a budget, what defines the method kept.

NeRF (Mildenhall et al. 2020, Sec. 5.3) trains 4096 rays a step with 64 + 128 samples per ray through an 8 x 256
MLP: about a GFLOP per ray, a hundred rays a second on two CPU cores. A 4-minute budget cannot fit that, so a
budgeted run trains a proxy of the method: fewer samples per ray (coarse and fine, proposal rounds), fewer rays per
step (the learning rates follow the batch rule of ``schedule.yaml``), a smaller procedural scene, and the width of
MLPs only when nothing else fits. What to scale, in which order, how far and at what cost is data
(``proxy.yaml``, per part of the plan: the terminals, whatever the base), like the schedule's fit.

The step cost of each candidate is predicted from the one measurement the ladder's smoke rung made (seconds per
step at its rays and samples); :func:`fit_proxy` keeps the mildest candidate that reaches ``proxy.yaml``'s target
(iterations and passes over the training pixels) within the time left. The plugin's code keeps the paper's settings;
the proxy's reach ns-train as arguments, are recorded in the plan's ``schedule`` (``proxy``) and named in the
report's headline. ``compose --method`` and the benchmarks never call this (they compare fixed settings).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from importlib import resources
from typing import Any

import yaml

from nerfify_ns.budget import RENDER_COST, Budget, BudgetError, TimeFit, fit_iterations, scaled_step
from nerfify_ns.grammar import derive, load_grammar
from nerfify_ns.plan import Plan

RAYS_PATH = "datamanager.train_num_rays_per_batch"
RAYS_FLAG = "--pipeline.datamanager.train-num-rays-per-batch"
KIND_WORDS = {"samples": "samples per ray", "rays": "rays per step", "grid": "grid resolutions",
              "width": "MLP width"}
SIZES = ("grid", "width")
"""The kinds whose entries are sizes of a part (the generated config declares them: ``config``)."""


@lru_cache(maxsize=1)
def proxy_spec() -> dict:
    """``proxy.yaml``: what a CPU proxy scales, in which order, how far, and at what cost."""
    return yaml.safe_load(resources.files("nerfify_ns.synthesis").joinpath("proxy.yaml").read_text())


@dataclass
class Knob:
    """One setting the proxy may scale."""

    kind: str
    """``samples``, ``rays`` or ``width`` (``proxy.yaml``'s sections)."""
    path: str
    """The plan's path of the value (``model.sampler.hierarchical.num_coarse_samples``)."""
    flag: str | None
    """The ns-train argument that sets it (None: the base has no config field for it; never scaled)."""
    paper: Any
    """The plan's value (an int, or a list of ints for proposal rounds)."""
    floor: int
    weight: float = 1.0
    """Samples: the cost of one sample; widths: the cost's exponent."""
    value: Any = None
    """The proxy's value (None: the plan's)."""
    original: Any = None
    """The paper's value where the plan was pruned for the scene (``pruned``: its ``from``), else None."""
    what: str = ""
    """What the value is, in the report's words (widths: ``MLP width`` unless ``proxy.yaml`` says otherwise)."""
    learning_rates: bool = False
    """Widths: the learning rates follow this one (the backbone's; ``schedule.yaml``'s width rule)."""
    smoke_at_floor: bool = True
    """The smoke rung measures the step at the floor (``proxy.yaml``'s ``smoke: plan``: at the plan's value)."""
    kept_per_ray: float = 1.0
    """A batch of samples (``rays.samples_per_step``): the samples a ray keeps, its rays being the batch over it."""

    @property
    def papers(self) -> Any:
        """The paper's own value (before any pruning for the scene)."""
        return self.paper if self.original is None else self.original

    @property
    def current(self) -> Any:
        return self.paper if self.value is None else self.value

    def halved(self) -> Any | None:
        """The next smaller value (halved, at least the floor), or None at the floor."""
        cur = self.current
        if isinstance(cur, list):
            nxt = [max(self.floor, v // 2) for v in cur]
            return None if nxt == cur else nxt
        return None if cur <= self.floor else max(self.floor, cur // 2)

    def total(self, value: Any = None) -> float:
        value = self.current if value is None else value
        return float(sum(value) if isinstance(value, list) else value)


def _flag(text: str) -> str:
    return text.replace("_", "-")


def knobs(plan: dict, rays: int) -> list[Knob]:
    """What ``proxy.yaml`` lets a proxy of ``plan`` scale, in its order, for a run of ``rays`` rays per step. A
    parameter whose base has no config field for it is listed with ``flag`` None (reported, never scaled)."""
    from nerfify_ns.registry import default_registry

    plan = Plan.of(plan)
    spec = proxy_spec()
    used = derive(plan, load_grammar()).used
    terminals = default_registry().terminals
    base = plan.get("base")
    defaults = load_grammar().terminals
    found: dict[str, list[Knob]] = {kind: [] for kind in spec["order"]}
    pruned = {p.get("path"): p.get("from") for p in plan.get("pruned") or [] if isinstance(p, dict) and "from" in p}
    for kind in ("samples", *SIZES):
        for path, terminal in used.items():
            for name, knob in ((spec.get(kind) or {}).get(terminal) or {}).items():
                params = defaults[terminal].params
                value = (plan.get(path) or {}).get(name, params[name].default if name in params else None)
                if not isinstance(value, int | list) or isinstance(value, bool):
                    continue
                fields = {**((terminals[terminal].config or {}).get(base) or {}),
                          **({name: knob["config"]} if knob.get("config") else {})}
                flag = f"--pipeline.model.{_flag(fields[name])}" if name in fields else None
                found[kind].append(Knob(kind, f"{path}.{name}", flag, value, int(knob["floor"]),
                                        float(knob.get("weight", knob.get("exponent", 1.0))),
                                        original=pruned.get(f"{path}.{name}"),
                                        what=knob.get("what", KIND_WORDS[kind] if kind in SIZES else ""),
                                        learning_rates=bool(knob.get("learning_rates")),
                                        smoke_at_floor=knob.get("smoke", "floor") == "floor"))
    batch = samples_batch(base)
    found["rays"].append(Knob("rays", batch.path, batch.flag, batch.value(plan), batch.floor, what=batch.what,
                              kept_per_ray=batch.kept_per_ray)
                         if batch else Knob("rays", RAYS_PATH, RAYS_FLAG, int(rays), int(spec["rays"]["floor"])))
    return [k for kind in spec["order"] for k in found.get(kind, [])]


@dataclass(frozen=True)
class SamplesBatch:
    """A pipeline that sizes each step by the samples it holds (``proxy.yaml``'s ``rays.samples_per_step``)."""

    name: str
    """The pipeline config's field (``target_num_samples``)."""
    default: int
    """Its default in the base's pipeline config (the paper's, unless the plan sets it)."""
    floor: int
    kept_per_ray: float
    """The samples a ray keeps once the grid has learnt the scene (a step's rays: its samples over this)."""

    @property
    def path(self) -> str:
        return _batch_path(self.name)

    @property
    def flag(self) -> str:
        return f"--pipeline.{_flag(self.name)}"

    what = "samples per step"

    def value(self, plan: Plan) -> int:
        return int((plan.get("pipeline") or {}).get(self.name) or self.default)


def samples_batch(base: str | None) -> SamplesBatch | None:
    """How ``base``'s pipeline sizes a step when it counts samples, not rays (None: a ray batch)."""
    import dataclasses
    import importlib

    from nerfify_ns.registry.bases import plugin_facts

    entry = (proxy_spec()["rays"].get("samples_per_step") or {})
    pipeline = (plugin_facts().get(base or "") or {}).get("pipeline") or {}
    if not entry or not pipeline:
        return None
    cls = getattr(importlib.import_module(pipeline["module"]), pipeline["cls"])
    field_ = next((f for f in dataclasses.fields(cls) if f.name == entry["config"]), None)
    if field_ is None or not isinstance(field_.default, int):
        return None
    return SamplesBatch(entry["config"], int(field_.default), int(entry["floor"]), float(entry["kept_per_ray"]))


def _batch_path(name: str) -> str:
    """The plan's path of a pipeline config field that sizes a step by its samples."""
    return f"pipeline.{name}"


def measured_batch(values: dict[str, Any]) -> int | None:
    """The samples per step a smoke rung trained at when its pipeline counts samples (``values``:
    :func:`smoke_samples`'s, by plan path; the proxy's knob counts them so), else None (a ray batch)."""
    name = (proxy_spec()["rays"].get("samples_per_step") or {}).get("config")
    value = values.get(_batch_path(name)) if name else None
    return int(value) if value is not None else None


def sample_cost(settings: list[Knob], values: dict[str, Any] | None = None) -> float:
    """The samples' cost of a ray (sum of weight x count) at the knobs' current values (or ``values`` by path)."""
    values = values or {}
    return sum(k.weight * k.total(values.get(k.path)) for k in settings if k.kind == "samples") or 1.0


def width_cost(settings: list[Knob], values: dict[str, Any] | None = None) -> float:
    values = values or {}
    return math.prod((k.total(values.get(k.path)) / k.total(k.paper)) ** k.weight
                     for k in settings if k.kind in SIZES) or 1.0


@dataclass
class Measured:
    """The one measurement a proxy is predicted from: the smoke rung's seconds per step at its rays and samples."""

    seconds_per_iteration: float
    startup_seconds: float
    rays: int
    samples: dict[str, Any] = field(default_factory=dict)
    """The sample counts and MLP widths it trained with, by plan path (missing: the plan's)."""
    ray_share: float | None = None
    """The part of that step its rays cost (the rung's ray-cost timing; None: not timed, the base's exponent)."""


@dataclass
class ProxyFit:
    """The settings a budgeted run trains with, how many iterations fit, and why."""

    knobs: list[Knob]
    time: TimeFit
    rays: int
    seconds_per_iteration: float
    target: dict
    reached: bool
    train_pixels: int
    scene: dict | None = None
    """The smaller procedural scene the run rendered for itself (:func:`proxy_scene`), or None."""

    @property
    def width_ratio(self) -> float:
        """The MLP's width over the paper's (1.0: the paper's): the learning rates follow it (``schedule.yaml``)."""
        return min([k.total() / k.total(k.paper) for k in self.changed if k.kind == "width" and k.learning_rates],
                   default=1.0)

    @property
    def changed(self) -> list[Knob]:
        return [k for k in self.knobs if k.value is not None and k.value != k.paper]

    @property
    def active(self) -> bool:
        return bool(self.changed or self.scene)

    def args(self) -> list[str]:
        """ns-train arguments that give the run the proxy's values."""
        out: list[str] = []
        for k in self.changed:
            out += [k.flag, *([str(v) for v in k.value] if isinstance(k.value, list) else [str(k.value)])]
        return out

    def phrases(self, paper_rays: int | None = None) -> list[str]:
        """``64 instead of 192 samples per ray``, ... (what the proxy changed, in words)."""
        parts = []
        samples = [k for k in self.knobs if k.kind == "samples" and not k.what]
        if any(k in self.changed for k in samples):
            before = sum(k.total(k.papers) for k in samples)
            after = sum(k.total() for k in samples)
            parts.append(f"{after:.0f} instead of {before:.0f} samples per ray")
        parts += [f"{k.total():.0f} instead of {k.total(k.papers):.0f} {k.what}" for k in self.knobs
                  if k.kind == "samples" and k.what and k in self.changed]  # counted otherwise (marching steps)
        for k in self.knobs:
            if k.kind == "rays" and k.what and k in self.changed:  # a batch of samples
                parts.append(f"{k.current} instead of {k.paper} {k.what}")
            elif k.kind == "rays" and not k.what and (k in self.changed or (paper_rays or 0) > k.current):
                parts.append(f"{k.current} instead of {paper_rays or k.paper} rays per step")
            elif k.kind in SIZES and k in self.changed:
                parts.append(f"{k.what} {k.value} instead of {k.papers} ({k.path})")
        if self.scene:
            parts.append(f"a {self.scene['resolution']} px scene with {self.scene['n_test']} test views instead of "
                         f"{self.scene['from_resolution']} px with {self.scene['from_n_test']}")
        return parts

    def headline(self, paper_rays: int | None = None) -> str:
        return "trained a CPU proxy: " + ", ".join(self.phrases(paper_rays))

    def record(self, paper_rays: int | None = None) -> dict:
        """The plan's ``schedule.proxy`` annotation."""
        not_scaled = [f"{k.path}: no ns-train argument sets it for this base" for k in self.knobs if k.flag is None]
        passes = self.time.iterations * self.rays / max(self.train_pixels, 1)
        scaled = ", ".join([*dict.fromkeys(k.what or KIND_WORDS[k.kind] for k in self.changed),
                            *(["the scene"] if self.scene else [])])
        why = (f"the paper's settings do not fit the budget: {self.time.describe()}; the proxy scales {scaled} "
               f"({'reaching' if self.reached else 'short of'} the target of {self.target['iterations']} iterations "
               f"and {self.target['epochs']:g} pass(es) over the training pixels: {passes:.2f} passes)")
        return {"headline": self.headline(paper_rays), "reason": why,
                "settings": [{"path": k.path, "paper": k.papers, **({"plan": k.paper} if k.original is not None
                                                                      else {}), "proxy": k.value, "kind": k.kind}
                             for k in self.changed],
                **({"scene": self.scene} if self.scene else {}),
                "ns_train_args": self.args(), "seconds_per_iteration": round(self.seconds_per_iteration, 4),
                **({"not_scaled": not_scaled} if not_scaled else {})}


def _predict(measured: Measured, settings: list[Knob], exponent: float, base_cost: float, base_width: float
             ) -> tuple[float, int]:
    """A step's seconds at the knobs' values, and its rays (a batch of samples: over the samples a ray keeps)."""
    batch = next((k for k in settings if k.kind == "rays"), None)
    size = int(batch.current) if batch else measured.rays
    step = scaled_step(measured.seconds_per_iteration, measured.rays, size, ray_share=measured.ray_share,
                       exponent=exponent, per_ray=sample_cost(settings) / base_cost)
    return step * (width_cost(settings) / base_width), max(1, int(size / (batch.kept_per_ray if batch else 1.0)))


def _fits(left: float, step: float, measured: Measured, rays_per_checkpoint: int, rays: int, budget: Budget,
          most: int | None, render_cost: float) -> TimeFit | None:
    try:
        return fit_iterations(left, step, measured.startup_seconds, rays_per_checkpoint, rays, budget, most=most,
                              render_cost=render_cost)
    except BudgetError:
        return None


def fit_proxy(plan: dict, measured: Measured, *, seconds_left: float, rays: int, exponent: float,
              rays_per_checkpoint: int, train_pixels: int, budget: Budget, most: int | None = None,
              scene: dict | None = None, render_cost: float = RENDER_COST) -> ProxyFit:
    """The mildest proxy of ``plan`` that reaches ``proxy.yaml``'s target in ``seconds_left`` (the paper's settings
    when they do), else the one that comes closest: a knob is halved only while that brings the run nearer the
    target (a step whose time is mostly the model's parameters, not its rays, gains few iterations from fewer rays
    and loses passes over the pixels); ``rays``: the run's batch before scaling; ``exponent``: the base's step-time
    exponent in the batch (used when the rung did not time the rays' share). Raises :class:`BudgetError` (from
    :func:`fit_iterations`) when not even the strongest proxy fits :data:`nerfify_ns.budget.MIN_ITERATIONS`."""
    settings = knobs(plan, rays)
    target = proxy_spec()["target"]
    base_cost = sample_cost(settings, measured.samples)
    base_width = width_cost(settings, measured.samples)

    def attempt() -> tuple[TimeFit | None, float, int]:
        step, r = _predict(measured, settings, exponent, base_cost, base_width)
        return _fits(seconds_left, step, measured, rays_per_checkpoint, r, budget, most, render_cost), step, r

    def enough(fit: TimeFit | None, r: int) -> bool:
        return fit is not None and (fit.iterations >= (most or math.inf) or (
            fit.iterations >= target["iterations"] and fit.iterations * r >= target["epochs"] * train_pixels))

    def progress(fit: TimeFit | None, r: int) -> float:
        """How near the target a fit comes (1: reached; -1: nothing fits)."""
        if fit is None:
            return -1.0
        return min(fit.iterations / target["iterations"], fit.iterations * r / (target["epochs"] * train_pixels))

    fit, step, r = attempt()
    for kind in proxy_spec()["order"]:  # one kind at a time, its knobs halved together (their ratio kept)
        group = [k for k in settings if k.kind == kind and k.flag is not None]
        while not enough(fit, r):
            before = [(knob, knob.value) for knob in group]
            moved = False
            for knob in group:
                smaller = knob.halved()
                if smaller is not None:
                    knob.value, moved = smaller, True
            if not moved:
                break
            trial = attempt()
            if trial[0] is not None and progress(trial[0], trial[2]) <= progress(fit, r):  # no nearer: it stays
                for knob, value in before:
                    knob.value = value
                break
            fit, step, r = trial
        if enough(fit, r):
            break
    if fit is None:  # not even the strongest proxy: the budget's own error, with what it would need
        fit_iterations(seconds_left, step, measured.startup_seconds, rays_per_checkpoint, r, budget, most=most,
                       render_cost=render_cost)
    return ProxyFit(settings, fit, r, step, dict(target), enough(fit, r), train_pixels, scene)


def proxy_scene(base: str | None, budget: Budget) -> dict | None:
    """The smaller procedural scene ``proxy.yaml`` gives a budgeted run of ``base`` (None: the budget's own): only
    for a budget shorter than the entry's ``below`` seconds and settings the user did not give."""
    entry = (proxy_spec().get("scene") or {}).get(base or "")
    if not entry or not budget.proxy or budget.seconds is None or budget.seconds >= entry["below"]:
        return None
    import inspect

    from nerfify_ns.scenes.writer import write_spec

    defaults = {k: p.default for k, p in inspect.signature(write_spec).parameters.items()}
    given = dict(budget.scene)
    chosen = {k: v for k, v in entry.items() if k != "below" and k not in given}
    if not chosen:
        return None
    return {**chosen, "from_resolution": given.get("resolution", defaults["resolution"]),
            "from_n_test": given.get("n_test", defaults["n_test"]),
            "resolution": chosen.get("resolution", given.get("resolution", defaults["resolution"])),
            "n_test": chosen.get("n_test", given.get("n_test", defaults["n_test"])),
            "reason": f"a budget under {entry['below']} s (proxy.yaml, base {base})"}


def with_scene(budget: Budget, scene: dict | None) -> Budget:
    """``budget`` rendering the proxy's scene (unchanged without one)."""
    if not scene:
        return budget
    keys = ("resolution", "n_train", "n_val", "n_test")
    return replace(budget, scene={**budget.scene, **{k: scene[k] for k in keys if k in scene}})


def smoke_samples(plan: dict) -> tuple[list[str], dict[str, Any]]:
    """The smoke rung of a budgeted run trains at the proxy's floors (the cheapest settings the run may take: the
    samples per ray and the MLP widths, the learning rates following the width as in training): ns-train arguments
    and the values by plan path (what :class:`Measured` records)."""
    from nerfify_ns.synthesis.schedule import width_learning_rates

    # every knob but the ray batch (a batch of samples is measured at its floor like the samples per ray)
    settings = [k for k in knobs(plan, 1) if k.path != RAYS_PATH and k.flag is not None and k.smoke_at_floor]
    args: list[str] = []
    values: dict[str, Any] = {}
    for k in settings:
        value = [min(v, k.floor) for v in k.paper] if isinstance(k.paper, list) else min(k.paper, k.floor)
        values[k.path] = value
        args += [k.flag, *([str(v) for v in value] if isinstance(value, list) else [str(value)])]
    width = min([k.total(values[k.path]) / k.total(k.paper) for k in settings
                 if k.kind == "width" and k.learning_rates], default=1.0)
    return [*args, *width_learning_rates(plan, width)], values

