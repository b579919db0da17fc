"""The planner agent: a plan from the model, constrained by the grammar, merged with the deterministic one.

1. **Ask.** The cleaned paper (cut to ``context_chars``), the knowledge-base cards the detections found (the
   deterministic detections, with their quotes) and the reference plans most relevant to the paper (the bases
   the base choice scored highest) as in-context examples. The answer is constrained by the grammar where the
   backend takes a constraint: our GBNF (``to_gbnf(annotations=False, structure_only=True)``: the derivation's
   choices with every terminal at its defaults, an evidence map, strings bounded: a short answer a small local
   model decodes in seconds) for llama.cpp, the grammar's JSON Schema otherwise; then always checked by ``check``
   (the grammar's own rules, duties included), re-asked with the violations within the retry bound.
2. **Merge.** The decisions of both plans are compared: the base, the alternative at every choice, the
   terminals present (set members, optional slots). Every disagreement is listed with both sides' evidence
   (the deterministic plan's evidence at that path; the model's quote from its ``evidence`` map). The
   deterministic choice wins unless the model's is backed by a quote of at least :data:`MIN_QUOTE` characters
   that :meth:`Document.find` finds in the paper; a model choice taken must leave the merged plan valid, else
   the deterministic one stays (and the record says why).

A model plan that is not valid after the retries, a truncated answer, an endpoint that fails or a spent budget:
one warning line, and the deterministic plan is used as it is.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field
from typing import Any

from nerfify_ns.agents.client import Client
from nerfify_ns.agents.errors import AgentError, InvalidAnswer

MIN_QUOTE = 20
"""The shortest quote (characters) that can back a model's choice."""
MAX_STRING = 120
"""The longest string (characters) of a model's plan under our GBNF (a method name, a quote)."""


@dataclass
class Disagreement:
    path: str
    kind: str                     # base | choice | added | omitted
    deterministic: Any
    deterministic_evidence: str
    model: Any
    model_evidence: str
    quote_found: bool
    winner: str                   # deterministic | model
    why: str

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class PlannerResult:
    plan: dict
    used_model: bool
    disagreements: list[Disagreement] = field(default_factory=list)
    warning: str = ""
    notes: list[str] = field(default_factory=list)
    model_plan: dict | None = None
    endpoint_failed: bool = False

    def to_dict(self) -> dict:
        return {"used_model": self.used_model, "warning": self.warning, "notes": self.notes,
                "disagreements": [d.to_dict() for d in self.disagreements],
                "taken_from_model": [d.path for d in self.disagreements if d.winner == "model"],
                "model_plan": self.model_plan}


def plan_problems(value: Any) -> list[str]:
    """What our grammar says against ``value`` as a plan (empty: valid)."""
    from nerfify_ns.grammar import check

    if not isinstance(value, dict):
        return [f"a plan is a JSON object, got {type(value).__name__}"]
    try:
        return [str(v) for v in check(value)]
    except Exception as exc:  # noqa: BLE001 - a malformed plan can trip the checker itself: that is a problem too
        return [f"not a plan: {type(exc).__name__}: {exc}"]


def planner_constraint(backend_structured: str) -> tuple:
    """(JSON Schema, GBNF) sent for the backend's structured mode (only the one it uses is built)."""
    from nerfify_ns.grammar.gbnf import to_gbnf
    from nerfify_ns.grammar.json_schema import to_json_schema

    if backend_structured == "llamacpp_gbnf":
        return None, to_gbnf(annotations=False, max_string=MAX_STRING, structure_only=True)
    if backend_structured == "none":
        return None, None
    return to_json_schema(), None


def _reference_plans(derived: Any, limit: int) -> list[dict]:
    from nerfify_ns.synthesis.resources import load_reference_plan, reference_plans

    names = []
    choice = getattr(derived, "base_choice", None)
    for score in sorted(getattr(choice, "scores", []) or [], key=lambda s: -s.score):
        if score.name in reference_plans() and score.name not in names:
            names.append(score.name)
    for name in reference_plans():
        if len(names) >= limit:
            break
        if name not in names:
            names.append(name)
    out = []
    for name in names[:limit]:
        plan = load_reference_plan(name)
        out.append({k: v for k, v in plan.items() if k not in ("notes", "paper", "description")})
    return out


def planner_messages(doc: Any, derived: Any, *, context_chars: int = 6000, examples: int = 2) -> list[dict]:
    """The planner's prompt: instructions, the paper, the detections (cards, quotes), reference plans."""
    from nerfify_ns.paper import clean_markdown

    paper = clean_markdown(doc)[:context_chars]
    detections = [{"technique": d.card, "card": d.title, "production": d.production, "status": d.status,
                   "quote": (d.uses[0].quote if d.uses else (d.evidence[0].quote if d.evidence else ""))[:200]}
                  for d in getattr(derived, "detections", []) or [] if d.status != "mentioned_only"]
    refs = _reference_plans(derived, examples)
    system = ("You turn a NeRF paper into a nerfify plan: a JSON object that is a derivation of the nerfify grammar "
              "(keys method, scene, base, trainer, datamanager, model, optimizers, evidence). Reply with the JSON "
              "plan only. For every choice you make, put an exact quote of the paper (copied word for word) in "
              "`evidence` under the plan path it supports.")
    user = ("Paper (cleaned):\n" + paper + "\n\nTechniques detected in the paper (knowledge-base cards):\n"
            + json.dumps(detections, indent=1) + "\n\nReference plans (examples of valid plans):\n"
            + "\n".join(json.dumps(r, separators=(",", ":")) for r in refs) + "\n\nThe plan for this paper:")
    return [{"role": "system", "content": system}, {"role": "user", "content": user}]


def _decisions(plan: dict) -> dict:
    """path -> what the plan decides there: the base, the alternative of every choice, each terminal present."""
    from nerfify_ns.grammar import derive

    d = derive(plan)
    out = {"base": ("base", plan.get("base"))}
    for path, alt in d.choices.items():
        out[path] = ("choice", alt)
    for path, term in d.used.items():
        parent = path.rsplit(".", 1)[0] if "." in path else ""
        if parent in d.choices and d.choices[parent] == path.rsplit(".", 1)[-1]:
            continue  # the choice already says it
        out.setdefault(path, ("present", term))
    return out


def _model_evidence(model: dict, path: str) -> str:
    evidence = model.get("evidence") or {}
    if not isinstance(evidence, dict):
        return ""
    probe = path
    while probe:
        if isinstance(evidence.get(probe), str):
            return evidence[probe]
        probe = probe.rsplit(".", 1)[0] if "." in probe else ""
    return ""


def merge_plans(deterministic: dict, model: dict, doc: Any) -> tuple:
    """(merged plan, disagreements): see the module docstring."""
    from nerfify_ns.plan import Plan

    det, mod = Plan.of(copy.deepcopy(dict(deterministic))), Plan.of(copy.deepcopy(dict(model)))
    mine, theirs = _decisions(det), _decisions(mod)
    found: list[Disagreement] = []
    for path in sorted(set(mine) | set(theirs), key=lambda p: (p.count("."), p)):
        a, b = mine.get(path), theirs.get(path)
        if a == b:
            continue
        if any(path.startswith(d.path + ".") for d in found if d.kind in ("choice", "added", "omitted")):
            continue  # inside a subtree already in dispute
        kind = "base" if path == "base" else "choice" if (a or b)[0] == "choice" and a and b else \
            "added" if a is None else "omitted" if b is None else "choice"
        quote = _model_evidence(mod, path)
        backed = len(quote.strip()) >= MIN_QUOTE and doc.find(quote) is not None
        found.append(Disagreement(
            path=path, kind=kind, deterministic=a[1] if a else None, deterministic_evidence=det.evidence_for(path),
            model=b[1] if b else None, model_evidence=quote, quote_found=backed, winner="deterministic",
            why="the model's choice has no quote found in the paper" if not backed else ""))
    for d in found:
        if not d.quote_found:
            continue
        trial = Plan.of(copy.deepcopy(dict(det)))
        if d.kind == "omitted":
            trial.delete(d.path)
        else:
            trial.set(d.path, copy.deepcopy(mod.get(d.path)))
        problems = plan_problems(trial)
        if problems:
            d.why = f"backed by the paper, but the merged plan would be invalid ({problems[0]})"
            continue
        det = trial
        d.winner, d.why = "model", "the model's choice is backed by a quote found in the paper"
        det.setdefault("evidence", {})[d.path] = f"model (quote found in the paper): {d.model_evidence}"
    return det, found


def run_planner(client: Client, doc: Any, derived: Any, *, context_chars: int = 6000,
                examples: int = 2) -> PlannerResult:
    """The planner (see the module docstring); never raises an :class:`AgentError`: a failure is a warning and
    the deterministic plan."""
    deterministic = derived.plan
    try:
        structured = client.config.info.structured if client.config.constrained else "none"
        schema, grammar = planner_constraint(structured)
        answer = client.ask("planner", planner_messages(doc, derived, context_chars=context_chars,
                                                        examples=examples),
                            schema=schema, grammar=grammar, check=plan_problems, schema_name="plan")
    except InvalidAnswer as exc:
        return PlannerResult(deterministic, False, warning=f"llm planner: {exc}; using the deterministic plan")
    except AgentError as exc:  # the endpoint, a truncated answer, the budget: later stages would fail the same way
        return PlannerResult(deterministic, False, warning=f"llm planner: {exc}; using the deterministic plan",
                             endpoint_failed=True)
    merged, disagreements = merge_plans(deterministic, answer.value, doc)
    taken = sum(d.winner == "model" for d in disagreements)
    merged.setdefault("notes", []).append(
        f"planner (model {client.config.backend}:{client.config.model}): {len(disagreements)} disagreement(s) with "
        f"the deterministic plan, {taken} taken from the model (quotes found in the paper)")
    return PlannerResult(merged, True, disagreements, notes=answer.notes, model_plan=answer.value)
