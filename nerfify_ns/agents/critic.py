"""The critic agent: a trained run's error maps, worst regions and renders (images when the backend reads them,
text summaries otherwise) go to the model, and come back as plan patches in the patch loop's own format
(:class:`~nerfify_ns.evaluate.patch_loop.PlanPatch`: edits ``{op: set|add|remove, path, value}`` with a reason).

It is a :class:`~nerfify_ns.evaluate.patch_loop.Critic`: ``diagnose`` returns the deterministic critic's findings
(plus the model's, when it names some), and ``propose(plan, findings, artifacts)`` the model's patches, which the
patch loop applies, validates and trains like any other candidate, keeping one only when it measurably helps.
A model failure leaves the deterministic critic's findings and rule patches as they are (one warning).
"""

from __future__ import annotations

import base64
import json
from pathlib import Path
from typing import Any

from nerfify_ns.agents.client import Client
from nerfify_ns.agents.errors import AgentError

ANSWER_SCHEMA = {
    "type": "object",
    "properties": {
        "findings": {"type": "array", "items": {
            "type": "object", "properties": {"name": {"type": "string"}, "severity": {"type": "number"},
                                             "evidence": {"type": "string"}},
            "required": ["name", "severity", "evidence"], "additionalProperties": False}},
        "patches": {"type": "array", "items": {
            "type": "object", "properties": {
                "reason": {"type": "string"},
                "edits": {"type": "array", "items": {
                    "type": "object", "properties": {"op": {"type": "string", "enum": ["set", "add", "remove"]},
                                                     "path": {"type": "string"}, "value": {}},
                    "required": ["op", "path", "value"], "additionalProperties": False}}},
            "required": ["reason", "edits"], "additionalProperties": False}},
    },
    "required": ["findings", "patches"],
    "additionalProperties": False,
}
MAX_PATCHES = 3
MAX_IMAGES = 2


def summarize(artifacts: Any) -> dict:
    """A text summary of a run (what a model without images reads): metrics, the loss's first and last values,
    the image diagnostics, each test view's worst regions (box, area, local PSNR), cross-view consistency."""
    s = artifacts.summary or {}
    views = [{"view": v.get("view"), "psnr": v.get("psnr"), "ssim": v.get("ssim"),
              "worst_regions": [{k: r.get(k) for k in ("x0", "y0", "x1", "y1", "area", "local_psnr")}
                                for r in (v.get("regions") or [])[:3]]}
             for v in (artifacts.error_maps or [])[:4]]
    return {"metrics": {k: s.get(k) for k in ("psnr", "ssim", "lpips", "iterations_done", "status", "reason")},
            "loss": {k: (s.get("losses") or {}).get(k) for k in ("first", "last", "finite")},
            "diagnostics": s.get("diagnostics") or {},
            "error_maps": views,
            "consistency": {k: (artifacts.consistency or {}).get(k) for k in ("mean_score",)}}


class ModelCritic:
    """The deterministic critic's findings plus the model's patches (see the module docstring)."""

    name = "model"

    def __init__(self, client: Client, images: bool, warn) -> None:
        from nerfify_ns.evaluate.patch_loop import DeterministicCritic, load_rules

        self.client, self.images, self.warn = client, images, warn
        self.base = DeterministicCritic(load_rules().get("critic"))
        self.name = f"model ({client.config.backend}:{client.config.model}) + deterministic"
        self._answer: dict = {}

    def _messages(self, artifacts: Any, findings: list[Any]) -> list[dict]:
        text = ("A NeRF method was trained with this plan:\n" + json.dumps(dict(artifacts.plan), default=str)[:6000]
                + "\n\nWhat its evaluation shows:\n" + json.dumps(summarize(artifacts), default=str)[:6000]
                + "\n\nThe deterministic critic's findings:\n"
                + json.dumps([f.to_json() for f in findings]) + "\n\nPropose at most "
                f"{MAX_PATCHES} plan patches (edits op set/add/remove at dot paths of the plan) that should raise "
                "held-out PSNR, each with its reason; name further findings if you see them.")
        content: list[dict] = [{"type": "text", "text": text}]
        if self.images:
            for panel in sorted(Path(artifacts.eval_dir).glob("*_errors.png"))[:MAX_IMAGES]:
                content.append({"type": "image", "png_base64": base64.b64encode(panel.read_bytes()).decode()})
        return [{"role": "system", "content": "You are the critic of a NeRF training run. Reply with JSON only."},
                {"role": "user", "content": content if len(content) > 1 else text}]

    def diagnose(self, artifacts: Any) -> list[Any]:
        from nerfify_ns.evaluate.patch_loop import Finding

        findings = list(self.base.diagnose(artifacts))
        try:
            answer = self.client.ask("critic", self._messages(artifacts, findings), schema=ANSWER_SCHEMA,
                                     check=_problems, schema_name="critique")
        except AgentError as exc:
            self.warn(f"llm critic: {exc}; the deterministic critic's findings and rules stand")
            self._answer = {}
            return findings
        self._answer = answer.value
        known = {f.name for f in findings}
        for f in answer.value.get("findings") or []:
            if f["name"] not in known:
                findings.append(Finding(f"model:{f['name']}", float(f["severity"]), str(f["evidence"])[:500], "model"))
        return findings

    def propose(self, plan: dict, findings: list[Any], artifacts: Any) -> list[Any]:
        """The model's patches as :class:`PlanPatch` (the loop validates, applies and measures them)."""
        from nerfify_ns.evaluate.patch_loop import Edit, Finding, PlanPatch

        out = []
        answered = Finding("model_critique", 0.5, "the model's reading of the run's error maps", "model")
        for k, p in enumerate((self._answer.get("patches") or [])[:MAX_PATCHES]):
            edits = [Edit(e["op"], e["path"], e.get("value")) for e in p.get("edits") or []]
            if edits:
                out.append(PlanPatch(rule=f"model_patch_{k}", finding=answered, edits=edits,
                                     reason=f"model critic: {str(p.get('reason', ''))[:300]}"))
        return out


def _problems(value: Any) -> list[str]:
    if not isinstance(value, dict):
        return ["the answer must be a JSON object {findings, patches}"]
    problems = []
    for p in value.get("patches") or []:
        if not isinstance(p, dict) or not isinstance(p.get("edits"), list):
            problems.append("each patch needs a list of edits")
            continue
        for e in p["edits"]:
            if not isinstance(e, dict) or e.get("op") not in ("set", "add", "remove") or not isinstance(
                    e.get("path"), str):
                problems.append(f"bad edit {e!r}: op must be set, add or remove, path a dot path")
    for f in value.get("findings") or []:
        if not isinstance(f, dict) or not isinstance(f.get("name"), str) or not isinstance(
                f.get("severity"), int | float):
            problems.append(f"bad finding {f!r}: needs name, severity, evidence")
    return problems
