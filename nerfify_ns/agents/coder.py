"""The coder agent: code for the holes the equation compiler did not fully implement, checked like all code.

For each such hole (a production with a ``custom`` interface, ``registry/terminals/custom.py``):

1. **Frozen interface.** The module (``components.<hole>_model``), the class name, the constructor arguments the
   composer passes and the contract (named tensors, symbolic shapes, ranges) come from the production's
   interface; the model writes only the body.
2. **Ask.** The paper's text of the hole, its equations as read, the compiler's partial result and its exact
   reason, the interface and contract. The answer is JSON: ``{code, implements, sentences}`` (the equations and
   the paper's sentences the node implements), schema-constrained where the backend takes one.
3. **Check in the sandbox.** The node is installed through the plugin's file DAG (the plan's ``custom``
   alternative at the hole's slot; ``write_plugin`` renders it with the other files in topological order) and
   the ladder runs on it: static, contract and stability rungs (``smoke=True``: then the smoke rung, the
   integration check). Model-written code runs only there (``run_sandboxed``), never in this process.
4. **Feed back.** A failure goes back to the model as the ladder's diagnosis (rung, rule, file, line, message,
   traceback excerpt), for at most ``rounds`` rounds; then the hole stays as the compiler left it, and the
   record says why (the last diagnosis).

An accepted node becomes the hole's component (``source: model``) with its equations (``implements``) and the
sentences it implements (``evidence``); its record says which rounds it took.
"""

from __future__ import annotations

import copy
import json
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nerfify_ns.agents.client import Client
from nerfify_ns.agents.errors import AgentError, InvalidAnswer

ANSWER_SCHEMA = {
    "type": "object",
    "properties": {
        "code": {"type": "string", "description": "the whole Python module"},
        "implements": {"type": "array", "items": {"type": "string"}, "description": "equations, e.g. 'Eq. 3'"},
        "sentences": {"type": "array", "items": {"type": "string"}, "description": "the paper's sentences"},
    },
    "required": ["code", "implements", "sentences"],
    "additionalProperties": False,
}
"""The coder's answer (strict-compatible JSON Schema)."""
CHECK_RUNGS = ("static", "contract", "stability")
TRACEBACK_EXCERPT = 1500


@dataclass
class CoderRound:
    round: int
    status: str                   # pass | fail | no-answer
    diagnosis: str = ""
    rungs: dict = field(default_factory=dict)
    seconds: float = 0.0


@dataclass
class CoderResult:
    hole: str
    production: str
    status: str                   # accepted | rejected | error | skipped
    reason: str
    rounds: list[CoderRound] = field(default_factory=list)
    component: dict = field(default_factory=dict)
    endpoint_failed: bool = False
    """The endpoint, a truncated answer or the budget failed (not the model's code): later asks would too."""

    def to_dict(self) -> dict:
        return {"hole": self.hole, "production": self.production, "status": self.status, "reason": self.reason,
                "component": self.component, "rounds": [r.__dict__ for r in self.rounds]}


def frozen_interface(record: Any) -> dict:
    """The module, class and interface of the model's node for ``record``'s hole (from the production's
    contract; the model does not choose them)."""
    from nerfify_ns.registry.terminals.custom import INTERFACES

    interface = INTERFACES[record.production]
    cls = "".join(p.capitalize() for p in re.split(r"[^a-zA-Z0-9]+", record.id) if p) + "ModelPart"
    return {"module": f"components.{record.id}_model", "class": cls, "production": record.production,
            "signature": interface.doc, "constructor_arguments": list(interface.ctor),
            "contract": interface.contract.to_data(), "stiff_cases": list(interface.cases),
            "get_out_dim": interface.out_dim}


def coder_messages(record: Any, hole: dict, frozen: dict) -> list[dict]:
    """The coder's prompt for one hole."""
    equations = [{"number": e.get("number"), "latex": e.get("latex"), "as read": e.get("reading"),
                  "status": e.get("status")} for e in record.equations if isinstance(e, dict)]
    system = ("You write one Python module for a Nerfstudio plugin: a torch.nn.Module implementing a NeRF paper's "
              "novel part behind a frozen interface. Use only torch, numpy, math and nerfstudio. Keep it finite for "
              "extreme inputs (values of 1e8, empty batches). Reply with JSON: {\"code\": the whole module, "
              "\"implements\": the paper's equations it implements, \"sentences\": the paper's sentences it "
              "implements}.")
    user = (f"The frozen interface (do not change names or arguments):\n{json.dumps(frozen, indent=1)}\n\n"
            f"Define `class {frozen['class']}(torch.nn.Module)` in the module; its constructor takes "
            f"{', '.join(frozen['constructor_arguments']) or 'no required arguments'} as keyword arguments "
            f"(accept **kwargs for the rest)"
            + (" and it has get_out_dim() returning its output width" if frozen["get_out_dim"] else "") + ".\n\n"
            + (f"The paper's contribution this part belongs to: {str(hole.get('contribution'))[:300]}\n"
               if hole.get("contribution") else "")
            + (f"The paper's claim of this part: {str(hole.get('claim'))[:600]}\n\n" if hole.get("claim") else "")
            + (f"Why it is a novel part here: {str(hole.get('why'))[:400]}\n\n" if hole.get("why") else "")
            + f"The paper's text of this part:\n{str(hole.get('text') or '')[:4000]}\n\n"
            + _prose_lines(record)
            + (f"The paper's hyperparameters stated with it:\n"
               f"{json.dumps(hole.get('hyperparameters'), indent=1, default=str)[:2000]}\n\n"
               if hole.get("hyperparameters") else "")
            + f"Its equations as the equation compiler read them:\n{json.dumps(equations, indent=1)[:6000]}\n\n"
            f"What the equation compiler made of it: {record.status}; reason: {record.reason}\n"
            + (f"The compiler's partial code:\n{record.source[:4000]}\n" if record.source else ""))
    return [{"role": "system", "content": system}, {"role": "user", "content": user}]


def _prose_lines(record: Any) -> str:
    """What the deterministic reading of the part's sentences found (each typed part it stated, with the quoted
    sentence and the sizes read, and why it was not built), so that the model starts from the paper's own words."""
    parts = getattr(record, "parts", None) or []
    if not parts:
        return ""
    lines = []
    for part in parts[:6]:
        sizes = {k: v.get("value") for k, v in (part.get("parameters") or {}).items()
                 if v.get("source") in ("paper", "statement", "correction")}
        lines.append(f"- {part.get('part')}: \"{str((part.get('statement') or {}).get('quote', ''))[:300]}\""
                     + (f"; sizes stated: {json.dumps(sizes, default=str)}" if sizes else "")
                     + (f"; not built: {str(part.get('reason'))[:300]}" if part.get("reason") else ""))
    return "The paper's sentences that state this part (as the deterministic reader found them):\n" + \
        "\n".join(lines) + "\n\n"


def answer_problems(frozen: dict):
    def check(value: Any) -> list[str]:
        if not isinstance(value, dict) or not isinstance(value.get("code"), str) or not value["code"].strip():
            return ["the answer must be a JSON object with a non-empty string `code`"]
        if f"class {frozen['class']}" not in value["code"]:
            return [f"the code must define class {frozen['class']} (the frozen interface)"]
        for key in ("implements", "sentences"):
            if not isinstance(value.get(key, []), list):
                return [f"`{key}` must be a list of strings"]
        return []
    return check


def describe_failure(ladder: Any) -> str:
    """The ladder's first failure as the model is told it: rung, rule, file, line, message, traceback excerpt."""
    failures = getattr(ladder, "failures", None) or []
    if not failures:
        return "the ladder failed without a diagnosis"
    d = failures[0]
    where = f"{d.file}:{d.line}" if d.file and d.line else (d.file or d.component or "-")
    text = f"rung {d.rung}, rule {d.rule}, at {where}" + (f", case {d.case}" if d.case else "") + f": {d.message}"
    if d.traceback:
        text += "\ntraceback (end):\n" + d.traceback[-TRACEBACK_EXCERPT:]
    return text


def _hole_of(plan: dict, record: Any) -> dict:
    return next((h for h in plan.get("holes") or [] if h.get("slot") == record.slot), {})


def code_hole(client: Client, implementation: Any, record: Any, work: Path, *, rounds: int = 3,
              smoke: bool = False, scene: Any = None, timeout: float = 300,
              smoke_iterations: int | None = None) -> CoderResult:
    """One hole: ask, install, check in the sandbox, feed back (see the module docstring). On acceptance the
    implementation (plan, sources, record) is updated in place."""
    import time

    from nerfify_ns.plan import Plan
    from nerfify_ns.synthesis.compose import write_plugin
    from nerfify_ns.synthesis.novel import IMPLEMENTED
    from nerfify_ns.synthesis.novel.implement import _place
    from nerfify_ns.verify import run_ladder

    frozen = frozen_interface(record)
    hole = _hole_of(implementation.plan, record)
    messages = coder_messages(record, hole, frozen)
    result = CoderResult(record.id, record.production, "rejected", "")
    scope = f"coder:{record.id}"
    rungs = list(CHECK_RUNGS) + (["smoke"] if smoke else [])
    for k in range(1, rounds + 1):
        try:
            answer = client.ask(scope, messages, schema=ANSWER_SCHEMA, check=answer_problems(frozen),
                                schema_name="component")
        except AgentError as exc:
            result.rounds.append(CoderRound(k, "no-answer", str(exc)))
            result.status, result.reason = "error", f"no usable answer in round {k}: {exc}"
            result.endpoint_failed = not isinstance(exc, InvalidAnswer)
            return result
        value = answer.value
        entry = {"module": frozen["module"], "class": frozen["class"], "params": {},
                 "implements": [str(x) for x in value.get("implements") or []][:20], "source": "model",
                 "evidence": " / ".join(str(x) for x in value.get("sentences") or [])[:1000]}
        plan = Plan.of(copy.deepcopy(dict(implementation.plan)))
        replaced = copy.deepcopy(plan.get(record.slot))
        _place(plan, record.slot, entry, record.production, record.id)
        sources = {**implementation.sources, frozen["module"]: value["code"]}
        folder = work / record.id / f"round-{k}"
        shutil.rmtree(folder, ignore_errors=True)
        (folder / "plugin").mkdir(parents=True)
        start = time.perf_counter()
        try:
            write_plugin(plan, folder / "plugin", sources=sources)
        except Exception as exc:  # noqa: BLE001 - a plan the composer refuses is a diagnosis like any other
            diagnosis = f"the plugin could not be composed with this node: {type(exc).__name__}: {exc}"
            ladder = None
        else:
            ladder = run_ladder(folder / "plugin", out_dir=folder / "verify", repair="off", rungs=rungs,
                                scene=scene, timeout=timeout, smoke_iterations=smoke_iterations)
            diagnosis = "" if ladder.ok else describe_failure(ladder)
        # the round's folder is no business of the model's (and would make each rerun's feedback differ)
        diagnosis = diagnosis.replace(str(folder / "plugin"), "<plugin>").replace(str(folder), "<round>")
        seconds = time.perf_counter() - start
        status = {r.name: r.status for r in ladder.rungs} if ladder is not None else {}
        result.rounds.append(CoderRound(k, "pass" if ladder is not None and ladder.ok else "fail", diagnosis,
                                        status, round(seconds, 1)))
        shutil.rmtree(folder / "plugin", ignore_errors=True)  # the verdict and diagnosis are kept, not the copy
        if ladder is not None and ladder.ok:
            implementation.plan = plan
            implementation.sources[frozen["module"]] = value["code"]
            record.replaced = replaced
            record.status, record.source = IMPLEMENTED, value["code"]
            record.component = dict(entry)
            record.reason = (f"written by the model ({client.config.backend}:{client.config.model}) in round {k} of "
                             f"{rounds}; passed the {', '.join(rungs)} rung(s) in the sandbox; the compiler had: "
                             f"{record.reason}")
            record.checks["coder"] = [r.__dict__ for r in result.rounds]
            for h in implementation.plan.get("holes") or []:
                if h.get("slot") == record.slot:
                    h["status"], h["reason"], h["compiled"] = IMPLEMENTED, record.reason, frozen["module"]
                    h["stands_in"] = f"{frozen['module']}.{frozen['class']} written by the model"
            result.status, result.component = "accepted", entry
            result.reason = f"accepted in round {k}"
            return result
        messages = messages + [
            {"role": "assistant", "content": json.dumps(value)},
            {"role": "user", "content": "The verification ladder rejected this node (it ran in the sandbox):\n"
             + diagnosis + "\nFix it and answer again with the whole module."}]
    last = result.rounds[-1].diagnosis if result.rounds else ""
    result.reason = f"no passing node within {rounds} round(s); last diagnosis: {last.splitlines()[0] if last else '-'}"
    record.checks["coder"] = [r.__dict__ for r in result.rounds]
    record.notes = list(record.notes) + [f"model coder: {result.reason}"]
    return result


def code_holes(client: Client, implementation: Any, work: Path, *, rounds: int = 3, smoke: bool = False,
               scene: Any = None, timeout: float = 300, only: list[str] | None = None) -> list[CoderResult]:
    """Every hole the compiler did not fully implement and whose production has an interface, in the plan's
    order (``only``: these hole ids). A spent budget stops the loop with what was done so far."""
    from nerfify_ns.agents.errors import BudgetExceeded
    from nerfify_ns.registry.terminals.custom import INTERFACES
    from nerfify_ns.synthesis.novel import IMPLEMENTED

    results: list[CoderResult] = []
    for record in list(implementation.records):
        if only is not None and record.id not in only:
            continue
        if record.status == IMPLEMENTED:
            continue
        if record.production not in INTERFACES:
            results.append(CoderResult(record.id, record.production, "skipped",
                                       f"{record.production} has no custom interface"))
            continue
        try:
            client.ledger.before_call(f"coder:{record.id}")
        except BudgetExceeded as exc:
            results.append(CoderResult(record.id, record.production, "error", str(exc), endpoint_failed=True))
            break
        results.append(code_hole(client, implementation, record, work, rounds=rounds, smoke=smoke, scene=scene,
                                 timeout=timeout))
        if results[-1].endpoint_failed:
            break
    return results
