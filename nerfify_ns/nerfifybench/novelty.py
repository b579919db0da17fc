"""Novelty coverage: C (correct), I (incomplete), M (missing), W (values within 10%) and a weighted score.

Computed from the run's own records, never by a language model (the paper's Table 4 uses an LLM score; this is
its deterministic counterpart):

* **Where an item is.** A compiled component whose ``implements`` names one of the item's equations (its ``where``:
  "Eqs. 1-9"), else the first of the item's ``plan`` paths present in ``plan.yaml``, else the slot of a hole the
  run built for the item (compiled, coded or from the paper's sentences; matched as the survey matches it); the
  plan's evidence link for that path (``plan.evidence``: a quote with its page and section, or "from the base
  plan") is kept with it.
* **Its status.** Not found: M. Found with a check: the check (a reference function of the suite, run in the
  sandbox on the generated component: :mod:`.checkrun`) passes: C; it fails (``AssertionError`` or ``False``): I;
  it raises anything else: I, with the error shown as the row's failure. Found without a check: **I, never C**
  (presence and evidence do not show correctness; the tables mark these items).
* **W.** Of the items with ``values`` (the paper's numbers at plan paths), the share whose every value is within
  10% of the plan's (``|theta - theta_hat| < 0.1 |theta|``; text and lists compared exactly / element-wise).
* **Score.** ``sum_i w_i s_i / sum_i w_i`` with ``s`` = 1 for C, 0.5 for I, 0 for M.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns import runfolder
from nerfify_ns.grammar.spec import CUSTOM_MEMBER
from nerfify_ns.nerfifybench.suite import NoveltyItem, PaperEntry

SCORE = {"C": 1.0, "I": 0.5, "M": 0.0}
BASE_EVIDENCE = "from the base plan"


@dataclass
class ItemScore:
    id: str
    kind: str
    weight: float
    status: str
    """C, I or M."""
    how: str
    """check-passed, check-failed, check-error, no-check (present with evidence), not-found."""
    path: str = ""
    evidence: str = ""
    message: str = ""
    values: dict[str, Any] = field(default_factory=dict)
    """Per plan path: the paper's value, the plan's and whether they match."""
    values_match: bool | None = None


def find_customs(plan: Any, prefix: str = "") -> list[tuple[str, dict]]:
    """Every ``custom`` entry of the plan, with its path (also ``custom_<name>`` where a slot holds several parts, as
    the regularisers do)."""
    found: list[tuple[str, dict]] = []
    if isinstance(plan, dict):
        for key, value in plan.items():
            path = f"{prefix}.{key}" if prefix else str(key)
            if CUSTOM_MEMBER.match(str(key)) and isinstance(value, dict) and "class" in value:
                found.append((path, value))
            elif key not in ("custom", "evidence", "holes", "notes", "pruned"):
                found += find_customs(value, path)
    elif isinstance(plan, list):
        for k, value in enumerate(plan):
            found += find_customs(value, f"{prefix}[{k}]")
    return found


def lookup(plan: Any, path: str) -> tuple[bool, Any]:
    """The value at a dotted plan path; a list is searched for an element that is, or is a mapping with, the key."""
    node = plan
    for key in path.split("."):
        if isinstance(node, dict) and key in node:
            node = node[key]
        elif isinstance(node, list):
            hit = next((e for e in node if e == key or (isinstance(e, dict) and key in e)), None)
            if hit is None:
                return False, None
            node = hit[key] if isinstance(hit, dict) else hit
        else:
            return False, None
    return True, node


def evidence_for(evidence: dict[str, str], path: str) -> str:
    """The plan's evidence line for ``path``: its own, else the nearest enclosing or enclosed entry's."""
    if path in evidence:
        return str(evidence[path])
    around = [k for k in evidence if path.startswith(k + ".") or k.startswith(path + ".")]
    return str(evidence[max(around, key=len)]) if around else ""


def _numbers_match(paper: Any, ours: Any) -> bool:
    if isinstance(paper, list):
        return isinstance(ours, list) and len(ours) == len(paper) and all(map(_numbers_match, paper, ours))
    if isinstance(paper, int | float) and not isinstance(paper, bool):
        if isinstance(ours, bool) or not isinstance(ours, int | float) or not math.isfinite(ours):
            return False
        return ours == paper if paper == 0 else abs(paper - ours) < 0.1 * abs(paper)
    return str(paper) == str(ours)


def before_pruning(plan: dict, path: str) -> tuple[bool, Any, str]:
    """The plan's value at ``path`` as derived from the paper: a value the scene's pruning changed (``plan.pruned``:
    path, from, to, reason) is read as it was before, and the pruning is named."""
    for record in plan.get("pruned") or []:
        if record.get("path") == path and "from" in record and record.get("action") not in ("removed", "kept"):
            return True, record["from"], f"pruned for the scene to {record.get('to')!r}: {record.get('reason', '')}"
    found, value = lookup(plan, path)
    return found, value, ""


def compare_values(plan: dict, values: dict[str, Any]) -> tuple[dict[str, Any], bool | None]:
    """Per path: the paper's value, the plan's (before the scene's pruning) and whether they match."""
    if not values:
        return {}, None
    rows = {}
    for path, paper in values.items():
        found, ours, pruned = before_pruning(plan, path)
        rows[path] = {"paper": paper, "plan": ours if found else None, "match": found and _numbers_match(paper, ours),
                      **({"pruned": pruned} if pruned else {})}
    return rows, all(r["match"] for r in rows.values())


def _equation_number(text: str) -> str:
    return str(text).replace("Eq.", "").replace("(", "").replace(")", "").strip()


def locate(item: NoveltyItem, plan: dict) -> tuple[str, dict | None]:
    """The plan path of the item (a compiled component implementing one of its equations first) and, for a
    component, its ``custom`` entry; ("", None) when the plan does not have it."""
    wanted = set(item.equations)
    for path, custom in find_customs(plan):
        implements = {_equation_number(e) for e in custom.get("implements") or []}
        if wanted & implements:
            return path, custom
    for path in item.plan:
        found, value = lookup(plan, path)
        if found:
            return path, value.get("custom") if isinstance(value, dict) and isinstance(value.get("custom"), dict) \
                else None
    hole = built_hole(item, plan)
    if hole is not None:
        for path, custom in find_customs(plan):  # the component compiled for the hole, where its slot holds several
            if hole.get("compiled") and custom.get("module") == hole["compiled"] and \
                    path.startswith(f"{hole['slot']}."):
                return path, custom
        value = lookup(plan, hole["slot"])[1]
        return hole["slot"], value.get("custom") if isinstance(value, dict) and isinstance(value.get("custom"),
                                                                                           dict) else None
    return "", None


def built_hole(item: NoveltyItem, plan: dict) -> dict | None:
    """The plan's hole built for ``item`` (compiled, coded or built from the paper's sentences, and not reverted):
    at the item's production and about it (the survey's match: its phrases or its equations), whose slot the plan
    holds. An item the suite gives no plan path for is found there (a field wrapper, a schedule hook)."""
    from nerfify_ns.nerfifybench.survey import _matches

    for hole in plan.get("holes") or []:
        if not isinstance(hole, dict) or hole.get("status") in (None, "not implemented") or not hole.get("slot"):
            continue
        if item.production and _matches(item, hole) and lookup(plan, hole["slot"])[0]:
            return hole
    return None


def score_items(entry: PaperEntry, run_dir: Path | None, work: Path, *, timeout: float) -> list[ItemScore]:
    """Score every novelty item of ``entry`` against the run folder ``run_dir`` (its plan.yaml, equations.yaml and
    plugin); checks run in the sandbox under ``work``."""
    from nerfify_ns.nerfifybench.checkrun import run_check

    plan_file = Path(run_dir) / runfolder.PLAN if run_dir is not None else None
    plan = yaml.safe_load(plan_file.read_text()) if plan_file is not None and plan_file.is_file() else None
    scores = []
    for item in entry.novelty:
        if plan is None:
            scores.append(ItemScore(item.id, item.kind, item.weight, "M", "not-found", message="no plan was written"))
            continue
        values, match = compare_values(plan, item.values)
        path, custom = locate(item, plan)
        evidence = (custom or {}).get("evidence") or evidence_for(plan.get("evidence") or {}, path) if path else ""
        score = ItemScore(item.id, item.kind, item.weight, "M", "not-found", path=path, evidence=str(evidence),
                          values=values, values_match=match)
        if path and item.check is None:
            score.status, score.how = "I", "no-check"
            score.message = "present with evidence, no check: counted as I" if evidence and \
                BASE_EVIDENCE not in str(evidence) else "present (the base's part, no evidence from the paper)"
        elif path:
            result = run_check(item, plan, path, custom, Path(run_dir), work / item.id, timeout=timeout)
            score.status = "C" if result["status"] == "pass" else "I"
            score.how = f"check-{'passed' if result['status'] == 'pass' else result['status'] + 'ed'}"
            score.message = result.get("message", "")
        scores.append(score)
    return scores


def coverage(scores: list[ItemScore]) -> dict:
    """C, I, M (shares of the items), W (share of the items with values that match), the weighted score, and the
    items counted I only for want of a check."""
    n = len(scores)
    if not n:
        return {"items": 0, "C": None, "I": None, "M": None, "W": None, "score": None, "unchecked": 0,
                "check_errors": []}
    with_values = [s for s in scores if s.values_match is not None]
    weights = sum(s.weight for s in scores)
    return {
        "items": n,
        "C": sum(s.status == "C" for s in scores) / n,
        "I": sum(s.status == "I" for s in scores) / n,
        "M": sum(s.status == "M" for s in scores) / n,
        "W": sum(bool(s.values_match) for s in with_values) / len(with_values) if with_values else None,
        "score": sum(s.weight * SCORE[s.status] for s in scores) / weights if weights else None,
        "unchecked": sum(s.how == "no-check" for s in scores),
        "check_errors": [f"{s.id}: {s.message}" for s in scores if s.how == "check-errored"],
    }


def to_dict(scores: list[ItemScore]) -> list[dict]:
    return [asdict(s) for s in scores]


