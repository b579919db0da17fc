"""Scene-adaptive pruning: leave out what the scene does not need, and say why.

Rules are data (``pruning.yaml``). Each applied rule is recorded in ``plan["pruned"]`` with the
part, the action, the old and new values and the reason; the result is validated again.
"""

from __future__ import annotations

import math
from functools import lru_cache
from importlib import resources
from typing import Any

import yaml

from nerfify_ns.grammar import Grammar, derive, load_grammar, validate
from nerfify_ns.grammar import check as validate_check
from nerfify_ns.grammar.validate import expected_param_groups
from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.scene_probe import SceneFacts

_FUNCTIONS = {"ceil": math.ceil, "log2": math.log2, "max": max, "min": min}
SETS = ("regularizers", "field_wrappers", "schedule_hooks")
"""Set slots of the model: one the pruning empties is removed."""


@lru_cache(maxsize=1)
def pruning_rules() -> list[dict]:
    return yaml.safe_load(resources.files("nerfify_ns.synthesis").joinpath("pruning.yaml").read_text())["rules"]


def _cap(value: Any, limit: int, dedupe: bool) -> Any:
    if not isinstance(value, list):
        return min(value, limit)
    capped = [min(v, limit) for v in value]
    return list(dict.fromkeys(capped)) if dedupe else capped


class _Pruner:
    def __init__(self, plan: Plan, facts: SceneFacts, grammar: Grammar) -> None:
        self.plan, self.facts, self.grammar = plan, facts, grammar
        self.records: list[dict] = []
        self.env = {**facts.sizes(), **facts.flags(), **facts.bounds()}

    def reason(self, rule: dict) -> str:
        return rule["reason"].format(evidence=self.facts.evidence, **self.env)

    def record(self, rule: dict, path: str, action: str, before: Any, after: Any) -> None:
        self.records.append({"rule": rule["name"], "path": path, "action": action, "from": before, "to": after,
                             "reason": self.reason(rule)})

    def remove(self, rule: dict, path: str) -> None:
        parent, key = self.plan.parent(path)
        if parent is not None and key in parent:
            self.record(rule, path, "removed", parent.pop(key), None)
            for name in SETS:  # a set left empty goes with its last member
                if parent == {} and path.startswith(f"model.{name}."):
                    self.plan["model"].pop(name)

    def keep(self, rule: dict, path: str) -> None:
        """Record that an optional part the scene needs stays (a real capture's contraction, appearance codes,
        camera optimiser), with the reason."""
        parent, key = self.plan.parent(path)
        if parent is not None and key in parent:
            self.record(rule, path, "kept", parent[key], parent[key])

    def replace(self, rule: dict, spec: dict) -> None:
        parent, key = self.plan.parent(spec["path"])
        slot = parent.get(key) if parent else None
        if isinstance(slot, dict) and spec["from"] in slot:
            params = {k: v for k, v in slot[spec["from"]].items() if k not in spec.get("drop_params", [])}
            parent[key] = {spec["to"]: params}
            self.record(rule, spec["path"], "replaced", spec["from"], spec["to"])

    def set(self, rule: dict, spec) -> None:
        if isinstance(spec, list):  # several parameters of one rule
            for one in spec:
                self.set(rule, one)
            return
        if "expr" in spec:  # a value from the scene's facts (None: the scene does not fix it, the plan's stays)
            value = eval(spec["expr"], {"__builtins__": {}, **_FUNCTIONS}, dict(self.env))  # our own YAML
            if value is None:
                return
            spec = {**spec, "value": value}
        parent, key = self.plan.parent(spec["path"])
        node = parent.get(key) if parent else None
        if isinstance(node, dict) and "custom" in node:
            # a component of the plugin stands at the slot: the value goes to its params (a custom renderer takes
            # the background, the part of the renderer's interface the scene decides)
            params = node["custom"].setdefault("params", {})
            if spec["param"] == "background" and params.get("background") != spec["value"]:
                before = params.get("background")
                params["background"] = spec["value"]
                self.record(rule, f"{spec['path']}.custom.params.background", "set", before, spec["value"])
            return
        if isinstance(node, dict) and node.get(spec["param"]) != spec["value"]:
            terminal = derive(self.plan, self.grammar).used.get(spec["path"], key)  # a slot names its terminal
            before = node.get(spec["param"], self.grammar.terminals[terminal].params[spec["param"]].default)
            node[spec["param"]] = spec["value"]
            self.record(rule, f"{spec['path']}.{spec['param']}", "set", before, spec["value"])

    def clamp(self, rule: dict, spec: dict) -> None:
        limit = int(eval(spec["max"], {"__builtins__": {}, **_FUNCTIONS}, dict(self.env)))  # our own YAML
        derivation = derive(self.plan, self.grammar)
        for path, terminal in derivation.used.items():
            if terminal != spec["terminal"]:
                continue
            params = self.plan.get(path)
            value = params.get(spec["param"], self.grammar.terminals[terminal].params[spec["param"]].default)
            capped = _cap(value, limit, spec.get("dedupe", False))
            if capped != value:
                params[spec["param"]] = capped
                self.record(rule, f"{path}.{spec['param']}", "clamped", value, capped)

    def drop_orphan_hooks(self) -> None:
        """A schedule hook whose target went with a pruned part (an anneal of the deformation's window when the
        deformation was dropped for a static scene) goes too, with the reason."""
        gone = [r["path"].rsplit(".", 1)[-1] for r in self.records if r["action"] == "removed"]
        if not gone:
            return
        for v in validate_check(self.plan, self.grammar):
            if not v.path.startswith("model.schedule_hooks.") or v.rule != "param_constraint":
                continue
            parent, key = self.plan.parent(v.path)
            if parent is None or key not in parent:
                continue
            before = parent.pop(key)
            self.records.append({"rule": "schedule_hook_target", "path": v.path, "action": "removed", "from": before,
                                 "to": None, "reason": "its target went with the pruned part(s) "
                                                       f"{', '.join(gone)}: {v.message}"})
            if parent == {}:
                self.plan["model"].pop("schedule_hooks")

    def drop_orphan_optimizers(self) -> None:
        expected = set(expected_param_groups(self.grammar, derive(self.plan, self.grammar)))
        for group in [g for g in self.plan.get("optimizers", {}) if g not in expected]:
            before = self.plan["optimizers"].pop(group)
            self.records.append({"rule": "param_groups", "path": f"optimizers.{group}", "action": "removed",
                                 "from": before, "to": None,
                                 "reason": f"the pruned model has no parameter group {group!r}"})

    def run(self) -> None:
        for rule in pruning_rules():
            if any(self.env.get(k) != v for k, v in (rule.get("when") or {}).items()):
                continue
            for action in ("remove", "keep", "replace", "set", "clamp"):
                if action in rule:
                    getattr(self, action)(rule, rule[action])
        self.drop_orphan_hooks()
        self.drop_orphan_optimizers()


def prune_plan(plan: dict, facts: SceneFacts, grammar: Grammar | None = None) -> dict:
    """A copy of ``plan`` for the scene ``facts`` describe, with ``pruned`` records; validated."""
    g = grammar or load_grammar()
    validate(plan, g)
    pruned = Plan.of(plan).copy()
    pruned["scene"] = facts.flags()
    pruner = _Pruner(pruned, facts, g)
    pruner.run()
    pruned["pruned"] = list(plan.get("pruned") or []) + pruner.records
    pruned.setdefault("evidence", {})["scene"] = "; ".join(f"{k}: {v}" for k, v in facts.evidence.items())
    validate(pruned, g)
    return pruned


def adopt_scene(plan: dict, facts: SceneFacts) -> dict[str, Any]:
    """With pruning off (--keep-all): the plan unchanged except for a note of the scene's facts."""
    kept = Plan.of(plan).copy()
    kept.setdefault("notes", []).append(
        "pruning off (--keep-all); the scene would allow: " + ", ".join(f"{k}={v}" for k, v in facts.flags().items()))
    return kept
