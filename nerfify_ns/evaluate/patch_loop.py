"""The patch loop: diagnose a trained plan, propose plan patches, keep only measured improvements.

One round:

1. **Measure the current best plan.** Compose it and train it ``repeats`` times on the same
   scene for the same budget (``iterations``) with different seeds (``--machine.seed``
   ``seeds[0..repeats-1]``); the first run is a full :func:`evaluate_run` (curve, renders, error
   maps, consistency) whose artefacts are diagnosed. A patch kept in the previous round brings
   its own seeds[0] run along, so only the other seeds are trained.
2. **Noise.** ``noise`` = the spread (max - min) of the held-out PSNRs of those repeats: the
   run-to-run variation of the unchanged config. A candidate must beat the *mean* of the repeats
   by more than ``threshold = max(noise, noise_floor)`` to be kept; ``noise_floor`` (default
   0.1 dB) guards against repeats that agree by chance (the range of two draws is a noisy
   estimate of the spread: use more ``repeats`` or a higher floor where runs are cheap or short).
3. **Diagnose** with a :class:`Critic` (default :class:`DeterministicCritic`, thresholds in
   ``patch_rules.yaml``): floaters (cross-view consistency), blur in high-frequency regions and
   large worst regions (error maps), background errors (error where the ground-truth alpha is
   0), divergence / rising loss (training curve).
4. **Propose** candidate patches from the rule table (``patch_rules.yaml``, data): each a small
   structured edit of the plan (``path``, ``op`` set/add/remove, ``value``) recorded with its rule
   and reason; a patch must change the plan and keep it valid (:func:`nerfify_ns.grammar.validate`).
5. **Try** up to ``max_candidates`` of them, most severe diagnosis first: each is applied to a
   copy of the plan, composed, and trained with seeds[0] for the same budget. The best candidate
   that beats the threshold is kept; the others are rejected. Every decision goes to
   ``history.json`` (round, diagnosis, patch, PSNR before/after, noise, kept/rejected, reason).

The loop stops when no diagnosis remains, no applicable patch is left, no candidate improved,
the round budget is spent, or the target PSNR (the paper's, when known and comparable) is
reached. Everything is revertible: every candidate plan is kept on disk
(``rounds/rNN/cNN_<rule>/plan.yaml``), each round's starting plan is ``rounds/rNN/plan.yaml``
and ``best_plan.yaml`` is always the best plan so far.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
import yaml

from nerfify_ns import runfolder
from nerfify_ns.dataset import DataLike, as_dataset
from nerfify_ns.errors import NerfifyError
from nerfify_ns.evaluate.curve import CurvePoint, read_curve_csv
from nerfify_ns.evaluate.run_eval import CPU_ARGS, evaluate_run, write_json
from nerfify_ns.grammar import PlanError, derive, load_grammar, validate
from nerfify_ns.plan import Plan, PlanPathError, split_path
from nerfify_ns.synthesis.compose import compose

NOISE_DEFINITION = (
    "noise = max - min of the held-out test PSNR of the current best plan trained `repeats` times with "
    "different seeds (--machine.seed), same scene and iterations; a candidate (trained with the first seed) "
    "is kept only if its PSNR exceeds the mean of those repeats by more than max(noise, noise_floor)"
)

_FUNCTIONS = {"min": min, "max": max, "round": round, "int": int, "abs": abs}


class PatchError(NerfifyError):
    """A patch cannot be applied to a plan (a missing path, a path that exists for 'add', ...)."""


class PatchLoopError(NerfifyError):
    """The patch loop cannot start (invalid starting plan, unusable scene or rule table)."""


# ---------------------------------------------------------------------------------------- data


@dataclass(frozen=True)
class Finding:
    """Something wrong with a trained run, found by a critic: its name (a rule-table key), how bad it is
    (higher first), the evidence in words, and which artefact showed it. (The verification ladder's
    ``Diagnosis`` is a broken rule of plugin code; a ``Finding`` is about a run's renders and curves.)"""

    name: str
    severity: float
    evidence: str
    source: str = ""

    def to_json(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Edit:
    """One structured edit of a plan: ``op`` (set, add, remove) at the dot ``path``."""

    op: str
    path: str
    value: Any = None

    def to_json(self) -> dict:
        return {"op": self.op, "path": self.path, "value": self.value}


@dataclass
class PlanPatch:
    """A candidate plan change: its edits, the rule that proposed it, the finding it answers and why.
    (The ladder's ``CodePatch`` changes plugin code; a ``PlanPatch`` changes the plan.)"""

    rule: str
    finding: Finding
    edits: list[Edit]
    reason: str
    before: dict[str, Any] = field(default_factory=dict)  # path -> value before (None if absent)

    def to_json(self) -> dict:
        return {
            "rule": self.rule,
            "diagnosis": self.finding.name,
            "reason": self.reason,
            "edits": [e.to_json() for e in self.edits],
            "before": self.before,
        }


@dataclass
class RunArtifacts:
    """What a critic reads: one evaluated run (``evaluate_run``'s folder) and the plan it trained."""

    eval_dir: Path
    plan: dict
    scene: Path
    summary: dict = field(default_factory=dict)
    error_maps: list[dict] = field(default_factory=list)
    consistency: dict | None = None
    curve: list[CurvePoint] = field(default_factory=list)

    @classmethod
    def load(cls, eval_dir: Path, plan: dict, scene: Path) -> RunArtifacts:
        eval_dir = Path(eval_dir)

        def read(name: str):
            path = eval_dir / name
            return json.loads(path.read_text()) if path.is_file() else None

        curve_path = eval_dir / runfolder.CURVE
        return cls(
            eval_dir=eval_dir,
            plan=plan,
            scene=Path(scene),
            summary=read(runfolder.SUMMARY) or {},
            error_maps=read(runfolder.ERROR_MAPS) or [],
            consistency=read(runfolder.CONSISTENCY),
            curve=read_curve_csv(curve_path) if curve_path.is_file() else [],
        )


@runtime_checkable
class Critic(Protocol):
    """Turns a run's artefacts into diagnoses. The default is :class:`DeterministicCritic`; a
    model- or VLM-backed critic (reading the panels and curve images) implements the same method, and may also
    offer ``propose(plan, findings, artifacts) -> [PlanPatch]``: its own patches, which the loop validates, trains
    and keeps or rejects exactly like the rule table's (``nerfify_ns.agents.critic``)."""

    name: str

    def diagnose(self, artifacts: RunArtifacts) -> list[Finding]:
        ...


# ---------------------------------------------------------------------------------------- rules


@lru_cache(maxsize=1)
def _default_rules_text() -> str:
    return resources.files("nerfify_ns.evaluate").joinpath("patch_rules.yaml").read_text()


def load_rules(path: Path | None = None) -> dict:
    """The rule table (``patch_rules.yaml`` by default): ``{critic: {...}, rules: [...]}``."""
    text = Path(path).read_text() if path is not None else _default_rules_text()
    table = yaml.safe_load(text)
    if not isinstance(table, dict) or not isinstance(table.get("rules"), list):
        raise PatchLoopError(f"{path or 'patch_rules.yaml'} has no 'rules' list")
    for rule in table["rules"]:
        missing = {"name", "diagnosis", "edits", "reason"} - set(rule)
        if missing:
            raise PatchLoopError(f"rule {rule.get('name', '?')!r} lacks {sorted(missing)}")
        for edit in rule["edits"]:
            if edit.get("op") not in ("set", "add", "remove"):
                raise PatchLoopError(f"rule {rule['name']!r}: op must be set, add or remove, got {edit.get('op')!r}")
    table.setdefault("critic", {})
    return table


# ---------------------------------------------------------------------------------------- critic


class DeterministicCritic:
    """Threshold tests over ``evaluate_run``'s summary, error maps, consistency and loss curve."""

    name = "deterministic"

    def __init__(self, thresholds: dict | None = None) -> None:
        self.t = thresholds if thresholds is not None else load_rules()["critic"]

    def _on(self, name: str) -> dict | None:
        return self.t.get(name) if name in self.t else None

    def diagnose(self, artifacts: RunArtifacts) -> list[Finding]:
        s = artifacts.summary
        out: list[Finding] = []
        losses = s.get("losses") or {}
        if self._on("divergence") is not None:
            psnr = s.get("psnr")
            if s.get("status") == "failed" or losses.get("finite") is False or psnr is None:
                step = losses.get("first_nonfinite_step")
                why = s.get("reason") or "no finite PSNR"
                out.append(Finding("divergence", 100.0, f"training failed: {why}"
                                     + (f" (first non-finite loss at step {step})" if step is not None else ""),
                                     "curve"))
                return out  # nothing else is measurable
        t = self._on("loss_rising")
        if t is not None and losses.get("first") and losses.get("last") is not None:
            ratio = losses["last"] / losses["first"]
            if ratio >= t.get("min_ratio", 1.25):
                out.append(Finding("loss_rising", 10.0 * ratio, f"train loss rose {ratio:.2f}x "
                                     f"({losses['first']:.4g} -> {losses['last']:.4g})", "curve"))
        t = self._on("floaters")
        if t is not None and artifacts.consistency:
            bad = 1.0 - float(artifacts.consistency.get("mean_score", 1.0))
            if bad >= t.get("min_inconsistent_fraction", 0.05):
                out.append(Finding("floaters", 20.0 * bad, f"{100 * bad:.1f}% of checked surface pixels lie in "
                                     "space other views see as empty", "consistency"))
        diag = s.get("diagnostics") or {}
        t = self._on("background_errors")
        share, frac = diag.get("background_error_share"), diag.get("background_fraction")
        if t is not None and share is not None and frac is not None:
            bg_psnr = diag.get("background_psnr")
            if (share >= t.get("min_share", 0.5) and frac >= t.get("min_background_fraction", 0.05)
                    and (bg_psnr is None or bg_psnr <= t.get("max_background_psnr", 30.0))):
                out.append(Finding("background_errors", 10.0 * share,
                                     f"{100 * share:.0f}% of the squared error is on background pixels (GT alpha 0"
                                     f", {100 * frac:.0f}% of the image; background PSNR "
                                     f"{'n/a' if bg_psnr is None else f'{bg_psnr:.1f} dB'})", "error_maps"))
        t = self._on("blur_high_frequency")
        sharp, hf = diag.get("sharpness"), diag.get("high_frequency_error_ratio")
        if t is not None and sharp is not None and hf is not None:
            if sharp <= t.get("max_sharpness", 0.7) or hf >= t.get("min_high_frequency_error_ratio", 2.0):
                out.append(Finding("blur_high_frequency", 10.0 * max(1.0 - sharp, 0.0) + hf,
                                     f"renders keep {100 * sharp:.0f}% of the ground truth's gradient energy; "
                                     f"error is {hf:.1f}x higher in high-frequency regions", "error_maps"))
        t = self._on("large_error_regions")
        if t is not None and artifacts.error_maps:
            sizes = [_view_pixels(artifacts, v) for v in artifacts.error_maps]
            fractions = [sum(r["area"] for r in v.get("regions", [])) / max(n, 1)
                         for v, n in zip(artifacts.error_maps, sizes, strict=False)]
            frac = float(np.mean(fractions))
            if frac >= t.get("min_area_fraction", 0.1):
                worst = min((r["local_psnr"] for v in artifacts.error_maps for r in v.get("regions", [])),
                            default=float("nan"))
                out.append(Finding("large_error_regions", 10.0 * frac,
                                     f"worst regions cover {100 * frac:.0f}% of the test pixels (worst box "
                                     f"{worst:.1f} dB)", "error_maps"))
        return sorted(out, key=lambda d: -d.severity)


def _view_pixels(artifacts: RunArtifacts, view: dict) -> int:
    renders = artifacts.eval_dir / "renders" / f"{view['view']}.png"
    if renders.is_file():
        from PIL import Image

        w, h = Image.open(renders).size
        return w * h
    return 1


# ---------------------------------------------------------------------------------------- patches


def _grammar_default(plan: dict, path: str) -> Any:
    """The grammar default of a terminal parameter left out of the plan (``None`` if not one)."""
    parent, _, param = path.rpartition(".")
    try:
        g = load_grammar()
        terminal = derive(plan, g).used.get(parent)
    except Exception:  # noqa: BLE001 - an invalid plan has no defaults to offer
        return None
    if terminal is None or param not in g.terminals[terminal].params:
        return None
    return copy.deepcopy(g.terminals[terminal].params[param].default)


def apply_edit(plan: Plan, edit: Edit) -> Any:
    """Apply one edit to ``plan`` in place; returns the value before (``None`` if absent). ``set`` needs the
    path to exist or to be a parameter with a grammar default; ``add`` needs it absent (mappings on the way
    are created); ``remove`` needs it present."""
    if not split_path(edit.path):
        raise PatchError("an edit needs a path")
    if edit.op not in ("set", "add", "remove"):
        raise PatchError(f"unknown op {edit.op!r} (set, add, remove)")
    present = plan.has(edit.path)
    before = copy.deepcopy(plan.get(edit.path))
    try:
        if edit.op == "add":
            if present:
                raise PatchError(f"add {edit.path}: already present")
            plan.set(edit.path, copy.deepcopy(edit.value))
        elif edit.op == "remove":
            if not present:
                raise PatchError(f"remove {edit.path}: not present")
            plan.delete(edit.path)
        else:
            if not present and _grammar_default(plan, edit.path) is None:
                raise PatchError(f"set {edit.path}: no such slot or parameter in the plan")
            plan.set(edit.path, copy.deepcopy(edit.value), create=False)
    except PlanPathError as exc:
        raise PatchError(str(exc)) from None
    return before


def apply_patch(plan: dict, patch: PlanPatch) -> Plan:
    """A validated copy of ``plan`` with the patch applied; records the old values on the patch."""
    patched = Plan.of(plan).copy()
    patch.before = {}
    for edit in patch.edits:
        patch.before[edit.path] = apply_edit(patched, edit)
    # the grammar's plan annotations have no 'patches' entry: the patch is recorded as a note
    edits = "; ".join(f"{e.op} {e.path}" + ("" if e.op == "remove" else f" = {e.value}") for e in patch.edits)
    patched["notes"] = list(patched.get("notes") or []) + [
        f"patch loop: {patch.rule} ({patch.finding.name}): {edits}; {patch.reason}"
    ]
    validate(patched)
    return patched


def scene_bounds(scene: DataLike) -> dict[str, float | None]:
    """``scene_near`` / ``scene_far`` of the dataset: a generated scene's ``scene.json``, LLFF's per-image
    bounds (their extremes); ``None`` when unknown."""
    dataset = as_dataset(scene)
    meta = dataset.meta.get("scene") or {}
    if dataset.meta.get("bounds"):
        bounds = dataset.meta["bounds"]
        meta = {"near": min(b[0] for b in bounds), "far": max(b[1] for b in bounds)}
    return {"scene_near": meta.get("near"), "scene_far": meta.get("far")}


def _eval_expr(expr: str, value: Any, env: dict) -> Any:
    if isinstance(value, list):
        return [_eval_expr(expr, v, env) for v in value]
    if value is None:
        raise PatchError(f"{expr!r}: no current value")
    result = eval(expr, {"__builtins__": {}, **_FUNCTIONS}, {**env, "value": value})  # our own YAML
    return int(result) if isinstance(value, bool) is False and isinstance(value, int) else result


def _format_reason(template: str, evidence: str, env: dict) -> str:
    try:
        return template.format(evidence=evidence, **{k: (v if v is not None else float("nan")) for k, v in env.items()})
    except (KeyError, ValueError, IndexError):
        return template


def propose_patches(plan: dict, findings: Sequence[Finding], rules: Sequence[dict],
                    scene: DataLike) -> list[PlanPatch]:
    """Candidate patches for ``findings``: applicable, changing the plan, each set of edits once.
    Ordered round-robin over the findings (most severe first): the first rule of every finding,
    then the second ones, ..., so a short candidate budget covers every finding."""
    env = scene_bounds(scene)
    plan = Plan.of(plan)
    per_finding: list[list[PlanPatch]] = []
    seen = set()
    for finding in findings:
        patches: list[PlanPatch] = []
        per_finding.append(patches)
        for rule in rules:
            names = rule["diagnosis"] if isinstance(rule["diagnosis"], list) else [rule["diagnosis"]]
            if finding.name not in names:
                continue
            if any(not plan.has(p) for p in rule.get("if_present") or []):
                continue
            if any(plan.has(p) for p in rule.get("if_absent") or []):
                continue
            try:
                edits = _concrete_edits(plan, rule, env)
            except PatchError:
                continue
            if not edits:
                continue
            key = json.dumps([e.to_json() for e in edits], sort_keys=True, default=str)
            if key in seen:
                continue
            seen.add(key)
            patches.append(PlanPatch(rule["name"], finding, edits,
                                     _format_reason(rule["reason"], finding.evidence, env)))
    ordered: list[PlanPatch] = []
    for rank in range(max((len(p) for p in per_finding), default=0)):
        ordered.extend(p[rank] for p in per_finding if rank < len(p))
    return ordered


def _concrete_edits(plan: Plan, rule: dict, env: dict) -> list[Edit]:
    edits: list[Edit] = []
    for spec in rule["edits"]:
        paths = plan.expand(spec["path"]) if "*" in spec["path"] else [spec["path"]]
        for path in paths:
            current = plan.get(path)
            if current is None and spec["op"] == "set":
                current = _grammar_default(plan, path)
            if spec["op"] == "remove":
                if current is not None:
                    edits.append(Edit("remove", path))
                continue
            if "expr" in spec:
                if any(env.get(k) is None for k in ("scene_near", "scene_far") if k in spec["expr"]):
                    raise PatchError(f"{rule['name']}: the scene's bounds are unknown")
                value = _eval_expr(spec["expr"], current, env)
            else:
                value = copy.deepcopy(spec.get("value"))
            if spec["op"] == "set" and value == current:
                continue  # no change
            edits.append(Edit(spec["op"], path, value))
    return edits


# ---------------------------------------------------------------------------------------- the loop


def plan_digest(plan: dict) -> str:
    body = {k: v for k, v in plan.items() if k not in ("evidence", "pruned", "notes", "holes", "description")}
    return hashlib.sha256(json.dumps(body, sort_keys=True, default=str).encode()).hexdigest()[:12]


def _write_plan(path: Path, plan: dict) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".yaml.tmp")
    tmp.write_text(yaml.safe_dump(plan, sort_keys=False))
    tmp.replace(path)
    return path


@dataclass
class Measurement:
    """The current best plan, measured: PSNR of each seed's run, their mean and spread."""

    psnrs: list[float | None]
    eval_dirs: list[Path]

    @property
    def finite(self) -> list[float]:
        return [p for p in self.psnrs if p is not None and math.isfinite(p)]

    @property
    def mean(self) -> float | None:
        return float(np.mean(self.finite)) if self.finite else None

    @property
    def noise(self) -> float | None:
        return float(max(self.finite) - min(self.finite)) if len(self.finite) >= 2 else None


@dataclass
class PatchLoopResult:
    out_dir: Path
    best_plan: dict
    best_plan_path: Path
    best_psnr: float | None
    history: dict
    history_path: Path

    @property
    def entries(self) -> list[dict]:
        return self.history["entries"]

    def kept(self) -> list[dict]:
        return [e for e in self.entries if e["decision"] == "kept"]

    def rejected(self) -> list[dict]:
        return [e for e in self.entries if e["decision"] == "rejected"]


Progress = Callable[[str], None]


class PatchLoop:
    """See the module docstring. ``run()`` returns a :class:`PatchLoopResult`."""

    def __init__(
        self,
        plan: dict,
        scene: DataLike,
        out_dir: Path,
        *,
        iterations: int,
        every: int | None = None,
        rounds: int = 3,
        repeats: int = 2,
        seeds: Sequence[int] = (0, 1, 2, 3),
        max_candidates: int = 3,
        noise_floor: float = 0.1,
        target_psnr: float | None = None,
        critic: Critic | None = None,
        rules: None | Path | dict = None,
        only_rules: Sequence[str] | None = None,
        method_args: Sequence[str] = CPU_ARGS,
        env: dict | None = None,
        timeout: float = 900,
        progress: Progress = lambda message: None,
        sources: dict[str, str] | None = None,
    ) -> None:
        if repeats < 2:
            raise PatchLoopError("repeats must be >= 2: noise is the spread of repeated runs of one config")
        if len(seeds) < repeats:
            raise PatchLoopError(f"need {repeats} seeds, got {list(seeds)}")
        try:
            validate(plan)
        except PlanError as exc:
            raise PatchLoopError(f"the starting plan is invalid: {exc}") from None
        self.plan = Plan.of(plan).copy()
        self.dataset = as_dataset(scene)  # read once, shared by every candidate's runs
        self.scene = self.dataset.root
        self.out = Path(out_dir).resolve()
        self.iterations, self.every = iterations, every or iterations
        self.rounds, self.repeats, self.seeds = rounds, repeats, list(seeds)
        self.max_candidates, self.noise_floor, self.target_psnr = max_candidates, noise_floor, target_psnr
        table = rules if isinstance(rules, dict) else load_rules(rules)
        self.rules = [r for r in table["rules"] if only_rules is None or r["name"] in only_rules]
        self.critic: Critic = critic or DeterministicCritic(table.get("critic"))
        self.method_args, self.env, self.timeout, self.progress = list(method_args), env, timeout, progress
        self.sources = dict(sources or {})
        """Custom component sources (``components.<name>`` -> code) every candidate plugin is composed with."""

    # -------------------------------------------------------------------------------- helpers

    def _evaluate(self, plan: dict, folder: Path, seed: int, label: str) -> dict:
        plugin = compose(plan, folder / "plugin", overwrite=True, record=False, sources=self.sources)
        started = time.perf_counter()
        summary = evaluate_run(
            plugin.out, self.dataset, folder / f"seed_{seed}", iterations=self.iterations, every=self.every,
            label=label, method_args=self.method_args, seed=seed, env=self.env, timeout=self.timeout,
        )
        summary["wall_seconds"] = time.perf_counter() - started
        return summary

    def _measure(self, plan: dict, folder: Path, have: dict[int, tuple[float | None, Path]]) -> Measurement:
        psnrs, dirs = [], []
        for seed in self.seeds[: self.repeats]:
            if seed not in have:
                self.progress(f"measuring the current plan, seed {seed}")
                summary = self._evaluate(plan, folder, seed, f"best seed {seed}")
                have[seed] = (summary.get("psnr"), folder / f"seed_{seed}")
            psnrs.append(have[seed][0])
            dirs.append(have[seed][1])
        return Measurement(psnrs, dirs)

    def _save_history(self, history: dict) -> Path:
        return write_json(self.out / runfolder.PATCH_HISTORY, history)

    # -------------------------------------------------------------------------------- run

    def run(self) -> PatchLoopResult:
        self.out.mkdir(parents=True, exist_ok=True)
        best = self.plan.copy()
        best_path = _write_plan(self.out / runfolder.BEST_PLAN, best)
        _write_plan(self.out / runfolder.START_PLAN, best)
        history: dict = {
            "method": best.get("method"),
            "scene": str(self.scene),
            "iterations": self.iterations,
            "repeats": self.repeats,
            "seeds": self.seeds[: self.repeats],
            "noise_definition": NOISE_DEFINITION,
            "noise_floor": self.noise_floor,
            "critic": getattr(self.critic, "name", type(self.critic).__name__),
            "target_psnr": self.target_psnr,
            "rounds": [],
            "entries": [],
            "stopped": None,
            "best_plan": runfolder.BEST_PLAN,
        }
        have: dict[int, tuple[float | None, Path]] = {}
        tried: set = set()
        stopped = f"round budget ({self.rounds}) spent"
        measurement: Measurement | None = None
        for rnd in range(self.rounds):
            folder = self.out / "rounds" / f"r{rnd:02d}"
            _write_plan(folder / runfolder.PLAN, best)
            base_folder = folder / "base"
            # a kept candidate's seed-0 run lives in its own folder; the other seeds go to base/
            measurement = self._measure(best, base_folder, have)
            mean, noise = measurement.mean, measurement.noise
            threshold = max(noise if noise is not None else 0.0, self.noise_floor)
            artifacts = RunArtifacts.load(measurement.eval_dirs[0], best, self.scene)
            diagnoses = self.critic.diagnose(artifacts)
            round_record = {
                "round": rnd,
                "plan": str((folder / runfolder.PLAN).relative_to(self.out)),
                "psnr_runs": measurement.psnrs,
                "psnr": mean,
                "noise": noise,
                "threshold": threshold,
                "diagnosed_run": str(measurement.eval_dirs[0].relative_to(self.out))
                if measurement.eval_dirs[0].is_relative_to(self.out) else str(measurement.eval_dirs[0]),
                "diagnoses": [d.to_json() for d in diagnoses],
                "candidates": [],
                "kept": None,
            }
            history["rounds"].append(round_record)
            history["best_psnr"] = mean
            self._save_history(history)
            self.progress(f"round {rnd}: PSNR {mean} (runs {measurement.psnrs}), noise {noise}, "
                          f"diagnoses {[d.name for d in diagnoses]}")
            if self.target_psnr is not None and mean is not None and mean >= self.target_psnr:
                stopped = f"target PSNR {self.target_psnr} reached ({mean:.2f} dB)"
                break
            if not diagnoses:
                stopped = "no diagnosis remains"
                break
            patches = [p for p in propose_patches(best, diagnoses, self.rules, self.dataset)]
            propose = getattr(self.critic, "propose", None)  # a critic of its own patches (a model's), tried alike
            patches += list(propose(best, diagnoses, artifacts)) if callable(propose) else []
            candidates: list[tuple[PlanPatch, dict]] = []
            for patch in patches:
                try:
                    patched = apply_patch(best, patch)
                except (PatchError, PlanError) as exc:
                    entry = self._entry(rnd, patch, mean, measurement, noise, threshold, None,
                                        "invalid", f"the patched plan is invalid: {exc}", None)
                    history["entries"].append(entry)
                    round_record["candidates"].append(len(history["entries"]) - 1)
                    continue
                digest = plan_digest(patched)
                if digest in tried:
                    continue
                tried.add(digest)
                candidates.append((patch, patched))
            candidates = candidates[: self.max_candidates]
            if not candidates:
                stopped = "no applicable patch for the remaining diagnoses"
                self._save_history(history)
                break
            results = []
            for k, (patch, patched) in enumerate(candidates):
                cand_folder = folder / f"c{k:02d}_{patch.rule}"
                _write_plan(cand_folder / runfolder.PLAN, patched)
                write_json(cand_folder / runfolder.PATCH, patch.to_json())
                self.progress(f"round {rnd}: trying {patch.rule} ({patch.finding.name})")
                summary = self._evaluate(patched, cand_folder, self.seeds[0], patch.rule)
                results.append((patch, patched, cand_folder, summary))
            best_gain, best_index = None, None
            for index, (_, _, _, summary) in enumerate(results):
                psnr = summary.get("psnr")
                gain = None if psnr is None or mean is None else psnr - mean
                if psnr is not None and mean is None:
                    gain = math.inf  # the current plan does not even train; anything finite is better
                if gain is not None and gain > threshold and (best_gain is None or gain > best_gain):
                    best_gain, best_index = gain, index
            for index, (patch, _, cand_folder, summary) in enumerate(results):
                psnr = summary.get("psnr")
                gain = None if psnr is None or mean is None else psnr - mean
                if index == best_index:
                    decision = "kept"
                    reason = (f"PSNR +{gain:.2f} dB over the mean of {self.repeats} runs exceeds the noise threshold "
                              f"{threshold:.2f} dB" if gain is not None and math.isfinite(gain)
                              else "the current plan fails to train; this one trains")
                elif psnr is None:
                    decision, reason = "rejected", f"the patched plan failed: {summary.get('reason')}"
                elif gain is not None and gain > threshold:
                    decision = "rejected"
                    reason = f"improves by {gain:.2f} dB, but {results[best_index][0].rule} improves more"
                else:
                    decision = "rejected"
                    reason = (f"PSNR change {gain:+.2f} dB does not exceed the noise threshold {threshold:.2f} dB"
                              if gain is not None else "no PSNR to compare")
                entry = self._entry(rnd, patch, mean, measurement, noise, threshold, summary, decision, reason,
                                    cand_folder)
                history["entries"].append(entry)
                round_record["candidates"].append(len(history["entries"]) - 1)
            if best_index is None:
                stopped = "no candidate improved by more than the noise"
                self._save_history(history)
                break
            patch, patched, cand_folder, summary = results[best_index]
            best = patched
            best_path = _write_plan(self.out / runfolder.BEST_PLAN, best)
            round_record["kept"] = patch.rule
            have = {self.seeds[0]: (summary.get("psnr"), cand_folder / f"seed_{self.seeds[0]}")}
            history["best_psnr"] = summary.get("psnr")
            self._save_history(history)
        history["stopped"] = stopped
        history["best_plan_digest"] = plan_digest(best)
        path = self._save_history(history)
        self.progress(f"stopped: {stopped}")
        return PatchLoopResult(self.out, best, best_path, history.get("best_psnr"), history, path)

    def _entry(self, rnd: int, patch: PlanPatch, mean: float | None, measurement: Measurement,
               noise: float | None, threshold: float, summary: dict | None, decision: str, reason: str,
               folder: Path | None) -> dict:
        psnr = summary.get("psnr") if summary else None
        return {
            "round": rnd,
            "diagnosis": patch.finding.to_json(),
            "patch": patch.to_json(),
            "psnr_before": mean,
            "psnr_before_runs": measurement.psnrs,
            "psnr_after": psnr,
            "improvement": None if psnr is None or mean is None else psnr - mean,
            "noise": noise,
            "threshold": threshold,
            "decision": decision,
            "reason": reason,
            "plan": str((folder / runfolder.PLAN).relative_to(self.out)) if folder else None,
            "run": str((folder / f"seed_{self.seeds[0]}").relative_to(self.out)) if folder and summary else None,
            "train_seconds": summary.get("seconds") if summary else None,
        }


def run_patch_loop(plan: dict, scene: DataLike, out_dir: Path, **kwargs) -> PatchLoopResult:
    """``PatchLoop(plan, scene, out_dir, **kwargs).run()``."""
    return PatchLoop(plan, scene, out_dir, **kwargs).run()


def revert(out_dir: Path, round_index: int) -> dict:
    """The plan a round started from (before its patch): ``rounds/rNN/plan.yaml``."""
    path = Path(out_dir) / "rounds" / f"r{round_index:02d}" / runfolder.PLAN
    if not path.is_file():
        raise PatchLoopError(f"no round {round_index} in {out_dir}")
    return yaml.safe_load(path.read_text())


