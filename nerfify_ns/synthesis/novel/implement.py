"""A paper's novel parts as compiled components: each hole of the derived plan, from its equations.

    result = implement_holes(doc, derived.plan)                     # or with corrections (equations.yaml)
    result.plan                                  # the plan, holes filled through `custom` where compiled
    result.sources                               # {"components.<name>": source} for the composer
    result.records                               # per hole: equations as read, bindings, sizes, status, reason

For one hole (the production its part fills, at its slot):

1. **Equations.** The hole's own equations and those of the sections that continue it (the paper's later,
   final form of the same part), each read by the equation reader; those it refuses keep their reason.
2. **Outputs.** The production's adapter (``adapters.py``) says what the component returns: the quantity of a
   role (the colour head a colour, the renderer a ray's colour, the loss a loss) or, for a backbone, what the
   hole's equations define and nothing else reads. The latest definition in the paper is tried first; a part
   stated as per-sample contributions is their sum over the samples (NeRF's C(r) = sum_i C_i(r)).
3. **Bindings.** Every symbol the outputs need is, in this order: a person's correction; defined by an equation
   of the part; given by the interface (the adapter, by its role: from the paper's own definitions, the cards'
   notation, then the shared table); a learned parameter (W, b); a standard basis bound to Nerfstudio's
   implementation (spherical harmonics); persistent state (defined in terms of itself); a network the paper
   names (its width and depth from the paper's hyperparameters, with the sentence); else the part is not
   implemented and the reason names the symbol and the equation.
4. **Sizes** (``widths.py``): the equations' own constraints, the roles' widths, the paper's stated shapes
   (``Psi in R^{z x h}``) and hyperparameters; an open width is never guessed.
5. **Compile and check** (``equations.compile_equations``) at small sizes (module vs interpreter, gradcheck),
   then lower at the paper's sizes and write the component around it (``adapters.py``). The composer places
   it through the plan's ``custom`` alternative; the ladder checks it like any component.

Nothing here knows a paper: everything paper-specific comes from the paper (or a person's correction).

Modules: ``items.py`` (the paper's equations as read, step 1), ``binding.py`` (outputs, closure, bindings and sizes,
steps 2-4), ``component.py`` (lowering through the one compile path, wiring, the component's own check, step 5),
``results.py`` (the records), ``causes.py`` (why a part was not built); this module orchestrates them per hole and
places what compiled.
"""

from __future__ import annotations

import copy
import hashlib
import json
import re
import time
from typing import Any

from nerfify_ns.equations import (
    Symbol,
    show,
)
from nerfify_ns.equations.reader import OBJECTIVE
from nerfify_ns.equations.shapes import CompileError
from nerfify_ns.equations.show import safe_comment
from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.novel.adapters import (
    ADAPTERS,
    component_source,
)
from nerfify_ns.synthesis.novel.binding import (  # noqa: F401 - re-exported
    MAX_ROOTS,
    _Attempt,
    _composite,
    _Hole,
    _short,
    _Unbound,
    hole_id,
)
from nerfify_ns.synthesis.novel.causes import cause_of
from nerfify_ns.synthesis.novel.component import (  # noqa: F401 - re-exported
    FULL_RUNTIME,
    SMALL_RUNTIME,
    SMALL_SENTINEL,
    _class_name,
    _lower,
    _operator_discrepancies,
    _plain_binding,
    _runtime_width,
    _selfcheck,
    _sizes,
    _wiring,
)
from nerfify_ns.synthesis.novel.items import (  # noqa: F401 - re-exported
    Item,
    _apply_corrections,
    _parse,
    _record_equation,
    describe,
    doc_items,
    equation_counts,
)
from nerfify_ns.synthesis.novel.notation import Notation, PaperWords
from nerfify_ns.synthesis.novel.objective import term_weight
from nerfify_ns.synthesis.novel.results import (  # noqa: F401
    IMPLEMENTED,
    NOT_IMPLEMENTED,
    PARTLY,
    HoleResult,
    Implementation,
)
from nerfify_ns.synthesis.novel.widths import WidthError
from nerfify_ns.synthesis.schedule import training_covers_stages


def plan_context(plan: Plan) -> dict:
    """Facts of the plan the adapters need: the direction encoding and its width."""
    ctx: dict = {}
    for root in ("model.field.MLPField",):
        de = plan.get(f"{root}.dir_encoding") or {}
        if isinstance(de, dict) and de:
            name = next(iter(de))
            params = de[name] or {}
            ctx["dir_encoding"] = name
            ctx["dir_path"] = f"{root}.dir_encoding"
            ctx["dir_dim"] = _encoding_width(name, params)
            if name == "sh":
                ctx["sh_levels"] = params.get("levels")
    return ctx


def _encoding_width(terminal: str, params: dict) -> int | None:
    """The width of a direction encoding from its contract's output shape (``[N, levels ** 2]``)."""
    try:
        from nerfify_ns.registry import default_registry
        from nerfify_ns.registry.contract import dims, eval_dim

        defn = default_registry()[terminal]
        full = {name: spec.default for name, spec in defn.param_specs.items()}
        full.update(params or {})
        (spec,) = defn.contract.outputs.values()
        return int(eval_dim(dims(spec.shape)[-1], full))
    except Exception:  # noqa: BLE001 - a terminal without a computable width: the adapter says so
        return None


def implement_holes(doc: Any, plan: dict, *, corrections: dict | None = None, reuse: dict | None = None,
                    cache: dict | None = None, kb: Any = None) -> Implementation:
    """Compile every hole of ``plan`` from ``doc``'s equations (see the module docstring). ``corrections``: the
    holes a person edited in equations.yaml, ``reuse``: hole id -> the earlier result of a hole not edited (both
    from ``records.read_corrections``; a reused hole is not recompiled); ``cache``: content digest -> result,
    kept by the caller across calls (a benchmark, a test)."""
    start = time.perf_counter()
    plan = Plan.of(copy.deepcopy(dict(plan)))
    notation = Notation.load()
    words = PaperWords.read(doc, notation)
    items = doc_items(doc)
    context = plan_context(plan)
    cards = _cards_in(plan)
    by_id = {h.get("id"): h for h in ((corrections or {}).get("holes") or []) if isinstance(h, dict)}
    records: list[HoleResult] = []
    sources: dict[str, str] = {}
    taken_slots: set[str] = set()
    holes = list(plan.get("holes") or [])
    groups: dict[str, list[dict]] = {}
    for h in holes:
        groups.setdefault(h["slot"], []).append(h)
    new_holes = []
    texts: dict[str, str] = {}
    for slot, group in groups.items():
        merged = _merge(group)
        texts[slot] = str(merged.get("text") or "")
        hid = hole_id(merged)
        corr = by_id.get(hid) or {}
        for it in items:
            it.in_hole = False
        local_items = _apply_corrections(items, corr)
        for it in local_items:
            _parse(it)
            it.in_hole = False
        t0 = time.perf_counter()
        try:
            work = _Hole(merged, local_items, words, notation, plan, context, corr, cards)
            work._basis = {}
            work._concat_used = set()
            digest = _digest(merged, local_items, corr, context)
            if reuse and hid in reuse and reuse[hid].production == merged["production"]:
                result = copy.deepcopy(reuse[hid])
                result.notes = [n for n in result.notes if not n.startswith("not recompiled")] + [
                    "not recompiled: equations.yaml leaves this part as it was (its hash matches)"]
            elif cache is not None and digest in cache:
                result = copy.deepcopy(cache[digest])
                result.notes = list(result.notes) + ["not recompiled: its equations, bindings and sizes did not "
                                                     "change"]
            else:
                result = _implement_one(work)
                result = _try_alternative(result, merged, local_items, words, notation, plan, context, corr, cards)
                result.hash = digest
                if cache is not None:
                    cache[digest] = copy.deepcopy(result)
            from nerfify_ns.synthesis.novel import prose  # a part stated in words: its typed terminals

            result = prose.build(merged, words.sentences, plan, corr, result)
        except Exception as err:  # noqa: BLE001 - the per-part boundary: this part's reason, the run goes on
            result = _failed_part(merged, hid, local_items, err)
        result.seconds = time.perf_counter() - t0
        result.cause = cause_of(result.reason) if result.status == NOT_IMPLEMENTED else ""
        if corr.get("recompiled_because"):  # its generated code was edited since: said, not reused
            result.notes = list(result.notes) + [str(corr["recompiled_because"])]
        records.append(result)
        if result.status in (IMPLEMENTED, PARTLY) and result.source:
            module = result.component["module"]
            sources[module] = result.source
            entry = {k: result.component[k] for k in ("module", "class", "params", "implements", "source",
                                                      "evidence", "weight") if k in result.component}
            result.replaced = copy.deepcopy(plan.get(result.slot))
            _place(plan, result.slot, entry, result.production, hid)
            taken_slots.add(slot)
        for h in group:
            h = dict(h)
            h["stands_in_base"] = h.get("stands_in", "")
            h["status"] = result.status
            h["reason"] = result.reason
            if result.cause:
                h["cause"] = result.cause
            h["compiled"] = result.component.get("module", "") if result.status != NOT_IMPLEMENTED else ""
            if result.status != NOT_IMPLEMENTED:
                h["stands_in"] = result.component.get("stands_in") or (
                    f"{result.component['module']}.{result.component['class']} compiled from "
                    f"{', '.join(result.component['implements'])}")
            new_holes.append(h)
    plan["holes"] = new_holes
    _built_within(records, texts, plan)
    asked = {f"{path}.{name}" for r in records for part in getattr(r, "parts", None) or [] if isinstance(part, dict)
             for path in part.get("placed") or [] for name, choice in (part.get("parameters") or {}).items()
             if isinstance(choice, dict) and choice.get("source") == "asked"}
    training_covers_stages(plan, unstated=asked)  # a stage the paper states ends within the training
    if words.unread:
        where, reason, _ = words.unread[0]
        plan.setdefault("notes", []).append(
            f"notation: {len(words.unread)} sentence(s) or value(s) not read ({where + ': ' if where else ''}"
            f"{reason}); the rest of the paper was read")
    if records:
        done = sum(r.status == IMPLEMENTED for r in records)
        worded = sum(r.status == IMPLEMENTED and r.component.get("source") == "prose" for r in records)
        plan.setdefault("notes", []).append(
            f"equation compiler: {done - worded} of {len(records)} novel part(s) implemented from the paper's "
            "equations" + (f", {worded} from its sentences (typed terminals)" if worded else ""))
    for it in items:
        _parse(it)
    result = Implementation(plan, sources, records, time.perf_counter() - start)
    result.counts = equation_counts(items)
    return result


def _failed_part(hole: dict, hid: str, items: list[Item], err: BaseException) -> HoleResult:
    """The record of a part whose reading, binding or compiling raised: not implemented, the exception (type and
    message) its reason, the equations it names with what the reader made of them."""
    result = HoleResult(id=hid, slot=str(hole.get("slot", "")), production=str(hole.get("production", "")),
                        section=str(hole.get("section", "")))
    result.reason = f"could not compile the part: {describe(err)}"
    try:
        wanted = {str(e.get("number")) for e in hole.get("equations", []) or [] if isinstance(e, dict)}
        result.equations = [_record_equation(it, []) for it in items if it.number and it.number in wanted]
    except Exception:  # noqa: BLE001 - the reason above stands alone
        result.equations = []
    return result


def _cards_in(plan: Plan) -> list[str]:
    text = json.dumps(plan.get("evidence") or {}) + json.dumps(plan.get("holes") or [])
    return [name for name in Notation.load().cards if name in text or name.replace("_", " ") in text.lower()]


def _merge(group: list[dict]) -> dict:
    if len(group) == 1:
        return dict(group[0])
    merged = dict(group[0])
    merged["equations"] = [e for h in group for e in h.get("equations", [])]
    merged["section"] = group[0].get("section", "")
    merged["sections"] = [h.get("section", "") for h in group]
    merged["text"] = " ".join(h.get("text", "") for h in group)
    return merged


def _digest(hole: dict, items: list[Item], corr: dict, context: dict) -> str:
    data = json.dumps({"hole": {k: hole.get(k) for k in ("slot", "production", "equations", "section")},
                       "items": [(it.number, it.latex, it.section) for it in items],
                       "bindings": corr.get("bindings"), "sizes": corr.get("sizes"), "context": context,
                       "version": 1}, sort_keys=True, default=str)
    return hashlib.sha256(data.encode()).hexdigest()[:16]


ALTERNATIVES = {"RGBLoss": ("Regularizers",), "Regularizers": ("RGBLoss",)}


"""Productions that return the same kind of thing (a loss): a part the derivation filed under one whose interface
does not give what its equations read is tried in the other (a loss on the field's densities is a regulariser)."""


def _slot_of(production: str) -> str | None:
    from nerfify_ns.grammar import load_grammar

    return next((path for path, symbol in load_grammar().symbol_paths() if symbol == production), None)


def _try_alternative(result: HoleResult, hole: dict, items, words, notation, plan, context, corr, cards) -> HoleResult:
    if result.status != NOT_IMPLEMENTED or hole["production"] not in ALTERNATIVES or result.component:
        return result
    for production in ALTERNATIVES[hole["production"]]:
        slot = _slot_of(production)
        if slot is None or production not in ADAPTERS:
            continue
        other = dict(hole, production=production, slot=slot)
        work = _Hole(other, items, words, notation, plan, context, corr, cards)
        work._basis, work._concat_used = {}, set()
        alt = _implement_one(work)
        if alt.status != NOT_IMPLEMENTED:
            alt.id, alt.notes = result.id, alt.notes + [
                f"placed as {production} at {slot}: the derivation filed the part under {hole['production']}, whose "
                f"interface does not give what its equations read ({_short(result.reason, 200)})"]
            return alt
    return result


SET_PRODUCTIONS = ("Regularizers", "FieldWrapper", "ScheduleHook")


"""Productions whose slot is a set: the component joins it as a member (``custom_<hole>``)."""


def _member(slot: str, production: str, hid: str) -> str:
    return f"{slot}.custom_{hid}" if production in SET_PRODUCTIONS else slot


def _place(plan: Plan, slot: str, entry: dict, production: str = "", hid: str = "") -> None:
    """The compiled component at the hole's slot, through the production's `custom` alternative (a set's member)."""
    if production in SET_PRODUCTIONS:
        plan.set(_member(slot, production, hid), entry)
    else:
        plan.set(slot, {"custom": entry})


def _words(text: str) -> str:
    return " ".join(re.findall(r"[a-z0-9]+", text.lower()))


def _key_loose(key: str) -> str:
    """The loose key (``notation.loose_key``) of a binding's key (``Symbol.key``: 'hat C^obj', "h'_c")."""
    from nerfify_ns.synthesis.novel.notation import INDEX_LETTERS, loose_key

    m = re.fullmatch(r"([^_^']+)('*)(?:_([^^]+))?(?:\^(.+))?", key.rsplit(" ", 1)[-1])
    if not m:
        return key
    name, primes, sub, sup = m.groups()
    scripts = [x for x in (sub.split(",") if sub else []) if x not in INDEX_LETTERS] + ([sup] if sup else [])
    return loose_key(name, scripts, len(primes))


def _built_within(records: list[HoleResult], texts: dict[str, str], plan: Plan) -> None:
    """A part found at one production and built inside another part: a paragraph that describes networks (the
    architecture section: "MLP with 6 layers (256 units), branching to c^med ... a^bs") which another part's
    equations use, and which that part built from this very paragraph's sentence. The paragraph's part is
    implemented there when (1) the other part's networks took their depth or width from a sentence of this
    paragraph and (2) every labelled quantity the paragraph names (a symbol with a sub- or superscript: the
    paper's own quantities, not the coordinates x, d it evaluates them at) is bound in the other part. Its
    record says where; a revert of the other part takes it back too (``revert``)."""
    from nerfify_ns.synthesis.novel.notation import mentions

    hosts = []  # (record, its networks, the loose keys it binds), each built part's once
    for host in records:
        if host.status == IMPLEMENTED and host.source:
            nets = {k: b["network"] for k, b in host.bindings.items() if isinstance(b.get("network"), dict)}
            hosts.append((host, nets, {_key_loose(k) for k in host.bindings}))
    for r in records:
        if r.status != NOT_IMPLEMENTED or not texts.get(r.slot):
            continue
        words = _words(texts[r.slot])
        named = {m.loose for m in mentions(texts[r.slot]) if not m.loose.endswith("|")}
        for host, nets, bound in hosts:
            quoted = [s for n in nets.values() for s in n.get("sentences") or [] if _words(s) in words]
            if not named or not quoted or not named <= bound:
                continue
            r.status, r.cause = IMPLEMENTED, ""
            r.component = {"within": host.slot, "module": host.component.get("module", ""),
                           "class": host.component.get("class", "")}
            r.reason = (f"built within {host.slot} ({host.component.get('module', '')}): its networks "
                        f"{', '.join(sorted(nets))} take their size from this part's sentence "
                        f"\"{_short(quoted[0], 120)}\", and every quantity this part names "
                        f"({', '.join(sorted(named))}) is bound there")
            for h in plan.get("holes") or []:
                if h.get("slot") == r.slot:
                    h.pop("cause", None)
                    h.update(status=IMPLEMENTED, reason=r.reason, compiled=r.component["module"],
                             stands_in=f"the part at {host.slot}")
            break


def revert(implementation: Implementation, hole_ids: list[str], reason: str) -> Plan:
    """The plan with the compiled components of ``hole_ids`` taken out again (the base's parts stand in), their
    records and holes saying why (a ladder rung failed on them)."""
    from nerfify_ns.synthesis.novel import prose

    plan = implementation.plan
    hosts = {r.slot for r in implementation.records if r.id in hole_ids and r.status != NOT_IMPLEMENTED}
    for r in implementation.records:
        if r.status == NOT_IMPLEMENTED or (r.id not in hole_ids and r.component.get("within") not in hosts):
            continue
        if r.component.get("within"):  # built inside a part the ladder took out: nothing of its own to take
            pass
        elif prose.revert(plan, r):  # typed terminals built from the paper's sentences
            pass
        elif r.production in SET_PRODUCTIONS:
            plan.delete(_member(r.slot, r.production, r.id))
        else:
            plan.set(r.slot, copy.deepcopy(r.replaced))
        implementation.sources.pop(r.component.get("module", ""), None)
        r.status = NOT_IMPLEMENTED
        r.reason = f"compiled, but {reason}; the base's part stands in"
        r.cause = cause_of(r.reason)
        r.checks["ladder"] = reason
        for h in plan.get("holes") or []:
            if h.get("slot") == r.slot:
                h["status"], h["reason"], h["compiled"], h["cause"] = NOT_IMPLEMENTED, r.reason, "", r.cause
                h["stands_in"] = h.get("stands_in_base", h.get("stands_in", ""))
    return plan


def _implement_one(work: _Hole) -> HoleResult:
    res = work.result
    own = work.hole_items()
    for it in own:
        _parse(it)
    if work.adapter is None:
        res.equations = [_record_equation(it, []) for it in own]
        res.reason = (f"the compiler has no adapter for the {res.production} production yet (it places components "
                      f"in: {', '.join(sorted(ADAPTERS))}); the base's part stands in")
        return res
    later = work.following(own)
    if not own and not later:
        flat = [e for e in work.hole.get("equations", []) if not (e.get("latex") or "").strip() and e.get("text")]
        if flat:  # a text extraction's equations: what the compiler parses is LaTeX
            res.reason = ("equations not read: " + "; ".join(f"Eq. {e.get('number') or '?'} is flattened text "
                                                             f"without LaTeX ('{_short(e['text'], 60)}')"
                                                             for e in flat[:3])
                          + " (the compiler parses LaTeX; a PDF or LaTeX source of the paper gives it)")
        else:
            res.reason = "no equation of the paper belongs to this part (the hole names none the reader found)"
        return res
    roots = work.roots(own, later)
    if not roots:
        res.equations = [_record_equation(it, []) for it in own + later]
        unread = [f"({it.number or '?'}) {f}" for it in own for f in it.failures() if OBJECTIVE not in f.reason]
        objectives = [f"({it.number or '?'})" for it in own for f in it.failures() if OBJECTIVE in f.reason]
        if objectives and not unread and not any(it.equations() for it in own + later):
            res.reason = (f"no equation of the paper belongs to this part: its equations {', '.join(objectives)} "
                          "are the training objective (what training minimises), not the part's definition")
            return res
        res.reason = (f"no equation of the part defines what the {res.production} returns "
                      f"({', '.join(work.adapter.output_roles)})"
                      + (f"; equations not read: {'; '.join(unread)}" if unread else ""))
        return res
    failures: list[str] = []
    chosen = None
    for root_eqs, root_items, composite in roots:
        label = ", ".join(f"({e.number})" if e.number else f"'{safe_comment(e.defines or '?', 20)}'" for e in root_eqs)
        try:
            att, bindings = work.attempt(root_eqs, root_items, composite, own, work.items)
            small = _sizes(work, att, bindings, SMALL_RUNTIME, small=True)
            trial = _lower(work, att, bindings, small, "CheckedPart", check=False)
            if trial.lowered is None:
                raise CompileError(trial.reason)
            chosen = (att, bindings, small)
            break
        except (CompileError, WidthError) as err:
            failures.append(f"{label}: {err}")
        except Exception as err:  # noqa: BLE001 - the per-form boundary: this form's reason, the next is tried
            failures.append(f"{label}: could not compile: {describe(err)}")
    considered = list(own)
    if chosen is None:
        res.equations = [_record_equation(it, []) for it in considered]
        gives = ", ".join(sorted(work.provisions)) or "nothing"
        unread = [f"({it.number or '@' + str(it.position)}) {f}" for it in own for f in it.failures()]
        res.reason = (("equations not read: " + "; ".join(unread) + "; so " if unread else "") +
                      "no form of the part compiled: " + " || ".join(_dedupe(failures)[:4]) +
                      f" [the {res.production} interface gives: {gives}; bind a symbol or fix an equation in "
                      "equations.yaml]")
        return res
    att, bindings, small = chosen
    res.notes += att.dropped
    checked = _lower(work, att, bindings, small, "CheckedPart", check=True)
    res.checks = {"lowering": str(checked.report) if checked.report else checked.reason,
                  "check_sizes": {k: list(v.shape) for k, v in small.params.items()}}
    extra = [it for it in att.items if it is not None and not any(it is c for c in considered)]
    res.equations = [_record_equation(it, att.items) for it in considered + extra]
    if not checked.ok:
        res.reason = f"the compiled module failed its check against the interpreter: {checked.reason}"
        return res
    try:
        full = _sizes(work, att, bindings, FULL_RUNTIME, small=False)
        cls = _class_name(res.id)
        full_lowered = _lower(work, att, bindings, full, f"{cls}Equations", check=False)
        if full_lowered.lowered is None:
            raise CompileError(f"lowering at the paper's sizes: {full_lowered.reason}")
        wiring = _wiring(work, att, bindings, full_lowered.lowered, full, cls)
        equations_source = _runtime_width(full_lowered.lowered.source, FULL_RUNTIME, wiring, work.adapter)
    except (CompileError, WidthError) as err:
        res.reason = str(err)
        return res
    from nerfify_ns.synthesis.compose import CompositionError, _format_python

    module = f"components.{res.id}_equations"
    try:
        source = _format_python(component_source(work.adapter, wiring, equations_source, work.context),
                                module.replace(".", "/") + ".py")
    except CompositionError as err:
        res.reason = f"the generated component does not parse (a compiler bug): {err}"
        return res
    try:  # the component itself, built at the check's small sizes, on its interface's example inputs
        small_rt = _sizes(work, att, bindings, SMALL_SENTINEL, small=True)
        small_lowered = _lower(work, att, bindings, small_rt, f"{cls}Equations", check=False).lowered
        small_wiring = _wiring(work, att, copy.deepcopy(bindings), small_lowered, small_rt, cls, small=True)
        small_source = _runtime_width(small_lowered.source, SMALL_SENTINEL, small_wiring, work.adapter)
        problem = _selfcheck(component_source(work.adapter, small_wiring, small_source, work.context), cls,
                             res.production, small_wiring.params)
    except (CompileError, WidthError, AttributeError) as err:
        problem = f"{type(err).__name__}: {err}"
    if problem:
        res.reason = f"the generated component failed its own contract check (a compiler bug): {problem}"
        res.checks["component"] = problem
        return res
    res.checks["component"] = "passed: built and run on the interface's example inputs (nominal case), outputs " \
                              "against the contract, gradients finite"
    res.source = source
    numbers = sorted((f"Eq. {e.number}" for e in att.equations if e.number), key=_number_key)
    unnumbered: dict[str, int] = {}
    for e, it in zip(att.equations, att.items, strict=False):
        if not e.number and e is not att.composite and it is not None:
            unnumbered[it.section] = unnumbered.get(it.section, 0) + 1
    implements = numbers + [f"{n} unnumbered equation(s) of {section}" for section, n in unnumbered.items()]
    res.component = {"module": module, "class": cls, "params": wiring.params, "implements": implements,
                     "source": "compiler",
                     "evidence": _short(f"{', '.join(dict.fromkeys(it.section for it in att.items if it))}: "
                                        + "; ".join(show(e) for e in att.equations if e is not att.composite), 300)}
    res.bindings = {k: _plain_binding(b) for k, b in bindings.items()}
    res.sizes = {k: {"shape": list(v.shape), **full.evidence.get(k, {"source": "equations",
                                                                       "evidence": "fixed by the equations, the "
                                                                                   "roles' widths and the contract"})}
                 for k, v in full.params.items()}
    for key, b in bindings.items():
        if b["as"] in ("network", "state") and full.widths.get(key):
            res.sizes[key] = {"shape": [int(full.widths[key])],
                              **full.evidence.get(key, {"source": "equations", "evidence": "fixed by the equations"})}
    res.state = {k: {"rows": int(b.get("rows", 1)), "initial": b.get("initial", 0.0), "note": b.get("note", ""),
                     **({"rows_evidence": b["rows_evidence"]} if b.get("rows_evidence") else {})}
                 for k, b in bindings.items() if b["as"] == "state"}
    if att.composite is not None and "w_composite" in bindings:
        res.notes.append("the paper's colour is per sample where the Renderer's contract is per ray: the rendered "
                         f"colour is {', '.join(safe_comment(e.defines, 30) for e in att.roots)} composited with the "
                         "renderer's volume-rendering weights, sum_i w_i c_i")
    elif att.composite is not None:
        res.notes.append("the rendered colour is the sum over the samples of the per-sample contributions "
                         f"({', '.join(safe_comment(e.defines, 30) for e in att.roots)}), as NeRF's "
                         "C(r) = sum_i C_i(r)")
    res.notes += wiring.notes + _operator_discrepancies(work, att, full)
    if res.production == "Regularizers":  # the term's weight: its own factor, else its coefficient in the objective
        weighted = term_weight(list(att.outputs), next(iter(att.own_weights), None), work.items, work.words)
        if weighted is not None:
            if weighted.value is not None:
                res.component["weight"] = weighted.value
            res.notes.append(weighted.note)
    res.notes += [f"'{safe_comment(k, 30)}' is per ray where the interface gives it per sample: the "
                  f"{safe_comment(str(b.get('role')), 30)} composited with the renderer's volume-rendering weights "
                  "(sum_i w_i x_i), as the production's contract is per ray" for k, b in bindings.items()
                  if b.get("composited")]
    unread = [e for e in res.equations if e["status"].startswith("not read")]
    not_needed = [e for e in res.equations if e["status"] == "not needed by the component's outputs"]
    touched = set(bindings) | {eq.defines for eq in att.equations}
    missed = [e for e in unread if _defines_text(e["latex"]) in touched]  # an unread definition the part uses
    res.status = PARTLY if (failures or missed) else IMPLEMENTED
    reasons = []
    if failures:
        reasons.append("later forms not compiled: " + " | ".join(failures[:3]))
    if unread:
        reasons.append(("equations not read: " if missed else "equations not read (the outputs compiled without "
                        "them): ") + "; ".join(
            f"({e['number'] or e.get('key')}) {e['status'][len('not read: '):]}" for e in unread[:4]))
    head = f"compiled from {', '.join(implements) or 'the composite output'}"
    if not_needed:
        head += "; not needed by its outputs: " + ", ".join(f"({e['number'] or e.get('key')})" for e in not_needed)
    res.reason = head + ("; " + "; ".join(reasons) if reasons else "")
    return res


def _defines_text(latex: str) -> str | None:
    """The key of the symbol an equation's left side names, read from its LaTeX alone (for an equation the reader
    refused: a derivation step whose left side is an integral names none)."""
    from nerfify_ns.equations import parse_expression

    lhs = re.split(r"(?<![<>!\\])=", latex, maxsplit=1)[0] if "=" in latex else ""
    expr = parse_expression(lhs) if lhs.strip() else None
    return expr.key if isinstance(expr, Symbol) else None


def _dedupe(failures: list[str]) -> list[str]:
    """Failures of alternative forms, each symbol's reason once (later forms repeat earlier ones)."""
    seen, out = set(), []
    for f in failures:
        label, _, rest = f.partition(": ")
        parts = [p for p in rest.split(" | ") if p not in seen]
        seen.update(parts)
        if parts:
            out.append(f"{label}: " + " | ".join(parts))
    return out


def _number_key(text: str) -> tuple:
    digits = re.findall(r"\d+", text)
    return (int(digits[0]) if digits else 1 << 30, text)
