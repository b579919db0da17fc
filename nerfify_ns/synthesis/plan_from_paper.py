"""Plan derivation: a paper (ingested, techniques detected, citations recovered) -> a plan the grammar accepts.

    kb = KnowledgeBase.load()                                   # or KnowledgeBase.load(folder)
    detections = detect_techniques(doc, kb)
    graph = build_citation_graph(doc, detections, kb=kb)
    derived = derive_plan(doc, detections, graph, kb=kb)        # derived.plan validates; derived.holes lists gaps

1. The base is the reference plan (``method_configs/``) the paper says it builds on, else the one whose
   techniques best cover what the paper uses (detections, weighted by confidence) and what citation
   recovery took from cited work (``base_choice.py``; a close call is recorded with both candidates).
2. The detected terminals replace the base's where the grammar allows it: where a card's terminal goes
   is read from the grammar (its path, and whether its slot is a choice, a set or a sequence); each
   substitution is checked, and one the grammar refuses is reported in ``notes``, never forced.
3. The paper's hyperparameters replace the base's values: each card says which of the paper's
   hyperparameters set which parameter of its terminal (``hyperparameters`` in the card), read by one
   loop over the plan's terminals; the trainer's (learning rate and schedule, ray batch, iterations)
   concern no technique and are read here.
4. Every value carries evidence in ``plan["evidence"]`` (plan path -> quote with page/section);
   values kept from the base plan say so.
5. Paper-specific parts no card covers (its own equations) become ``plan["holes"]``: the production
   they would fill, its contract, the paper's text and equations, status "not implemented", and what
   stands in their place (the base's component, so the plan still trains).
"""

from __future__ import annotations

import ast
import copy
import dataclasses
import math
import operator
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from nerfify_ns.errors import NerfifyError
from nerfify_ns.grammar import Grammar, check, load_grammar, validate
from nerfify_ns.knowledge.bases import find_base_statements
from nerfify_ns.knowledge.cards import Card, HyperparameterMap
from nerfify_ns.knowledge.citations import CitationGraph, build_citation_graph, find_spans, match_target
from nerfify_ns.knowledge.detect import Detection, detect_scene, detect_techniques
from nerfify_ns.knowledge.family import Family, detect_family, family_rules
from nerfify_ns.knowledge.kb import KnowledgeBase
from nerfify_ns.knowledge.sentences import role_of_section, section_roles, sentences
from nerfify_ns.plan import Hole, Plan, free_method_name
from nerfify_ns.synthesis.base_choice import BaseDecision, choose_base, exclusive_cards
from nerfify_ns.synthesis.ledger import Ledger, read_ledger
from nerfify_ns.synthesis.resources import load_reference_plan, reference_plans

__all__ = ["DerivedPlan", "Hole", "TerminalSlot", "HyperparameterError", "derive_plan", "plan_from_paper",
           "terminal_slots", "slot_table", "evaluate", "slug"]

# the production (grammar nonterminal) each kind of hole is a part of; its slot and stand-in come from the grammar
HOLE_SYMBOLS = {
    "spatial_distortion": "SpatialDistortion", "renderer": "Renderer", "regularizer": "Regularizers",
    "loss": "RGBLoss", "sampler": "Sampler", "pos_encoding": "PosEncoding", "dir_encoding": "DirEncoding",
    "backbone": "Backbone", "rgb_head": "RGBHead",
}


def _scalar(hp) -> bool:
    """A hyperparameter read as one number (not a range or a list of values)."""
    return hp is not None and isinstance(hp.value, int | float) and not isinstance(hp.value, bool)


class HyperparameterError(NerfifyError):
    """A card's hyperparameter expression that cannot be evaluated (a bug in the card, named with it)."""


@dataclass
class DerivedPlan:
    """The derived plan (``validate`` accepts it), its holes, the base chosen and why, and the evidence
    of every value (plan path -> {source: paper | citation | card | base, quote, section, page, line}).

    ``base_choice`` holds every candidate base with its score and coverage, the paper's statement of
    its base when it makes one, and ``close_call``: the sentence saying why one of two bases within the
    close margin was chosen ("" when the choice was clear; also in ``plan["notes"]``)."""

    plan: Plan
    holes: list[dict]
    base: str
    base_reason: str
    evidence: dict
    detections: list[Detection] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    base_choice: BaseDecision | None = None
    family: Family | None = None
    """What kind of method the paper describes (static, dynamic, splatting, surface, not-training) and why."""
    ledger: Ledger | None = None
    """The paper's claims and described parts, each known (a card covers it) or new (a hole)."""
    deriver: Any = field(default=None, repr=False, compare=False)
    """What derived the plan (its cards found and placed, notes, evidence): :meth:`host_cards` continues it."""

    @property
    def close_call(self) -> str:
        return self.base_choice.close_call if self.base_choice else ""

    def host_cards(self, plan: dict) -> dict:
        """``plan`` (the derived plan with the paper's own parts built into it) with the paper's cards that had no
        slot in the base put where those parts host them (:meth:`_Deriver.host`), their evidence added and the notes
        that said they were not used dropped; ``plan`` itself when there is nothing (left) to host: a card is hosted
        once, by the first plan given."""
        d = self.deriver
        if d is None or not any(name not in d.placed for name in d.used):
            return plan
        out = Plan.of(copy.deepcopy(dict(plan)))
        before = list(d.notes)
        d.host(out)
        dropped = set(before) - set(d.notes)
        out["notes"] = [n for n in out.get("notes") or [] if n not in dropped] + [n for n in d.notes
                                                                                 if n not in before]
        out["evidence"] = {**(out.get("evidence") or {}),
                           **{path: _evidence_line(e) for path, e in sorted(d.evidence.items())
                              if path not in (out.get("evidence") or {})}}
        validate(out, d.g)
        return out

    def to_dict(self) -> dict:
        return {"plan": self.plan.to_dict(), "holes": self.holes, "base": self.base, "base_reason": self.base_reason,
                "base_choice": self.base_choice.to_dict() if self.base_choice else None,
                "evidence": self.evidence, "missing": self.missing,
                "family": self.family.to_dict() if self.family else None,
                "ledger": self.ledger.to_dict() if self.ledger else None,
                "detections": [d.to_dict() for d in self.detections]}


# ------------------------------------------------------------------------------------------ grammar slots
@dataclass(frozen=True)
class TerminalSlot:
    """Where a terminal goes in a plan, read from the grammar.

    ``path`` holds the terminal's parameters (``model.sampler.proposal``); ``slot`` is the position it
    fills (``model.sampler``); ``kind`` is how: ``choice`` (one alternative, ``{terminal: params}``),
    ``set`` (a member among others), ``sequence`` (the slot is the terminal) or ``enum`` (the slot's
    value is the terminal's name: the base, chosen by the base choice, never substituted)."""

    terminal: str
    path: str
    slot: str
    kind: str


def slot_table(grammar: Grammar) -> dict[str, list[TerminalSlot]]:
    """Every terminal's slots, from one walk over the grammar's derivable paths."""
    symbols = dict(grammar.symbol_paths())
    table: dict[str, list[TerminalSlot]] = {}
    for path, symbol in symbols.items():
        nt = grammar.nonterminals.get(symbol)
        if nt is not None and nt.kind == "enum":
            for t in nt.alternatives:
                table.setdefault(t, []).append(TerminalSlot(t, path, path, "enum"))
        if symbol not in grammar.terminals:
            continue
        parent = path.rsplit(".", 1)[0] if "." in path else ""
        owner = grammar.nonterminals.get(symbols.get(parent, grammar.start)) if parent else None
        kind = owner.kind if owner is not None and owner.kind in ("choice", "set") else "sequence"
        table.setdefault(symbol, []).append(TerminalSlot(symbol, path, parent if kind != "sequence" else path, kind))
    return table


def terminal_slots(grammar: Grammar, terminal: str) -> list[TerminalSlot]:
    """Where ``terminal`` goes in a plan ([] for a name the grammar cannot place)."""
    return slot_table(grammar).get(terminal, [])


def _reachable(plan: Plan, path: str, grammar: Grammar, symbols: dict[str, str]) -> bool:
    """Whether every choice alternative on the way to ``path`` is the plan's (an MLP-field slot is not
    reachable in a plan whose field is tensorial)."""
    parts = path.split(".")
    for i in range(1, len(parts)):
        parent, here = ".".join(parts[:i]), ".".join(parts[:i + 1])
        nt = grammar.nonterminals.get(symbols.get(parent, ""))
        if nt is not None and nt.kind == "choice" and here != path and not plan.has(here):
            return False
    return True


# ------------------------------------------------------------------------------------------ expressions
_BINARY: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
    ast.FloorDiv: operator.floordiv, ast.Pow: operator.pow, ast.Mod: operator.mod}
_COMPARE: dict[type, Callable[[Any, Any], bool]] = {
    ast.Lt: operator.lt, ast.LtE: operator.le, ast.Gt: operator.gt, ast.GtE: operator.ge, ast.Eq: operator.eq,
    ast.NotEq: operator.ne}


def exact_log2(value: Any) -> int | None:
    """log2 of a positive power of two, else None ("2^19 entries" -> 19; 500000 -> None)."""
    if not isinstance(value, int | float) or value <= 0:
        return None
    exponent = math.log2(value)
    return int(exponent) if exponent.is_integer() else None


FUNCTIONS: dict[str, Callable[..., Any]] = {"exact_log2": exact_log2, "max": max, "min": min, "int": int,
                                            "float": float, "round": round, "abs": abs}


def evaluate(expression: str, names: dict[str, Any]) -> Any:
    """The value of a card's hyperparameter expression (arithmetic, comparisons, ``x if c else y``, lists and
    the functions of ``FUNCTIONS``) over ``names``; anything else raises ``HyperparameterError``."""
    try:
        return _eval(ast.parse(expression, mode="eval").body, names)
    except HyperparameterError:
        raise
    except (SyntaxError, TypeError, ValueError, ZeroDivisionError, OverflowError) as exc:
        raise HyperparameterError(f"cannot evaluate {expression!r}: {exc}") from None


def _eval(node: ast.AST, names: dict[str, Any]) -> Any:
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name):
        if node.id not in names:
            raise HyperparameterError(f"unknown name {node.id!r} (known: {', '.join(sorted(names))})")
        return names[node.id]
    if isinstance(node, ast.List | ast.Tuple):
        return [_eval(e, names) for e in node.elts]
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd | ast.Not):
        value = _eval(node.operand, names)
        return -value if isinstance(node.op, ast.USub) else (not value if isinstance(node.op, ast.Not) else value)
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        return _BINARY[type(node.op)](_eval(node.left, names), _eval(node.right, names))
    if isinstance(node, ast.Compare) and len(node.ops) == 1 and type(node.ops[0]) in _COMPARE:
        return _COMPARE[type(node.ops[0])](_eval(node.left, names), _eval(node.comparators[0], names))
    if isinstance(node, ast.BoolOp):
        values = [_eval(v, names) for v in node.values]
        return all(values) if isinstance(node.op, ast.And) else any(values)
    if isinstance(node, ast.IfExp):
        return _eval(node.body, names) if _eval(node.test, names) else _eval(node.orelse, names)
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS \
            and not node.keywords:
        args = [_eval(a, names) for a in node.args]
        return None if any(a is None for a in args) else FUNCTIONS[node.func.id](*args)
    raise HyperparameterError(f"{ast.unparse(node)!r} is not allowed in a card's hyperparameter expression")


def _coerce(value: Any, kind: str) -> Any:
    """``value`` as the grammar's parameter type ``kind`` (None when it is not one: the statement is skipped)."""
    if value is None or isinstance(value, bool) and kind not in ("bool",):
        return None
    if kind == "int":
        return int(value) if isinstance(value, int | float) and float(value).is_integer() else None
    if kind == "float":
        return float(value) if isinstance(value, int | float) else None
    if kind in ("int_list", "float_list"):
        if not isinstance(value, list):
            return None
        items = [_coerce(v, kind.split("_")[0]) for v in value]
        return None if any(v is None for v in items) else items
    return value


# ------------------------------------------------------------------------------------------ helpers
def _where(page: int | None, line: int | None, section: str) -> str:
    loc = f"p.{page}" if page is not None else (f"l.{line}" if line is not None else "")
    return ", ".join(x for x in (loc, f"Sec. {section}" if section else "") if x)


def _short(text: str, limit: int = 240) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3].rstrip() + "..."


def slug(doc: Any) -> str:
    """A method name from the paper's title ("GH-NeRF: ..." -> "gh-nerf"), with '-paper' added when the name
    would shadow a Nerfstudio method, an installed plugin or module, or is a Python keyword."""
    title = (getattr(doc, "title", "") or "").strip()
    head = re.split(r"[:\u2013\u2014]| - ", title, maxsplit=1)[0].strip() if title else ""
    if not head or len(head) > 40:
        words = re.findall(r"[A-Za-z0-9]+", title)[:4]
        head = "-".join(words)
    name = re.sub(r"[^a-z0-9]+", "-", head.lower()).strip("-")
    if not name or not name[0].isalpha():
        name = f"paper-{name}" if name else "paper-method"
    name = name[:62].strip("-")
    name = name if len(name) >= 2 else f"{name}-method"
    return free_method_name(name)  # 'TensoRF: ...' -> 'tensorf-paper' (Nerfstudio's tensorf is taken)


def hosted_cards(grammar: Grammar, names: Sequence[str]) -> dict[str, frozenset]:
    """Reference plan -> the cards of the terminals it uses."""
    out = {}
    for name in names:
        d = validate(load_reference_plan(name), grammar)
        out[name] = frozenset(grammar.terminals[t].card for t in d.used.values()
                              if t in grammar.terminals and grammar.terminals[t].card)
    return out


def base_order(kb: KnowledgeBase) -> list[str]:
    """The reference plans a plan can start from, in the knowledge base's order of preference (plainest
    first), then any other reference plan."""
    available = reference_plans()
    listed = [m for m in kb.bases.order if m in available]
    return listed + [m for m in available if m not in listed]


# ------------------------------------------------------------------------------------------ derivation
class _Deriver:
    def __init__(self, doc: Any, detections: Sequence[Detection], graph: CitationGraph, grammar: Grammar,
                 kb: KnowledgeBase):
        self.doc = doc
        self.g = grammar
        self.kb = kb
        self.detections = list(detections)
        self.graph = graph
        self.res = graph.resolution if graph.resolution.needed else graph.resolve()
        self.cards = kb.cards
        self.evidence: dict[str, dict] = {}
        self.notes: list[str] = []
        self.placed: set[str] = set()  # cards substitution put (or confirmed) in the plan
        self.used = {d.card: d for d in self.detections if d.used and d.card in kb.cards}
        self.roles = section_roles(doc, kb.rules)
        self.units = list(sentences(doc, kb.rules))  # read once: base statements and scene cues scan them
        self.paths = list(grammar.symbol_paths())
        self.symbols = dict(self.paths)  # path -> the innermost symbol there (an open production's terminal)
        self.slots = slot_table(grammar)
        self.own_cards: set[str] = set()
        """Cards of the techniques the paper itself introduced (a paper the knowledge base knows)."""
        self.novel_sentences: dict[str, str] = {}
        """Sentences of the paper's new parts (the ledger's) -> the production of their part: a number stated there
        sets no known card's parameter of another production (a deformation MLP's width is not the backbone's)."""

    # ----------------------------------------------------------------- evidence
    def paper_evidence(self, path: str, quote: str, section: str, page, line, card: str = "",
                       source: str = "paper", what: str = "") -> None:
        self.evidence[path] = {"source": source, "quote": quote, "section": section, "page": page, "line": line,
                               "card": card, "what": what}

    def base_evidence(self, path: str, base: str) -> None:
        self.evidence.setdefault(path, {"source": "base", "quote": "", "section": "", "page": None, "line": None,
                                        "card": "", "what": FROM_BASE.format(base=base)})

    # ----------------------------------------------------------------- base
    def candidates(self) -> dict[str, float]:
        """Cards the paper uses (confidence) or takes from cited work (less); a paper the knowledge base knows
        uses the techniques it introduced (its own cards), however garbled the text that describes them."""
        weights: dict[str, float] = {}
        for name, d in self.used.items():
            weights[name] = max(weights.get(name, 0.0), d.confidence)
        for name in self.own_cards:
            weights[name] = 1.0
        for comp in self.res.taken:
            if comp.card in self.cards:
                w = self.kb.bases.choice.citation_weight(comp.relation)
                weights[comp.card] = max(weights.get(comp.card, 0.0), w)
        return weights

    def choose_base(self) -> BaseDecision:
        """The base (see ``base_choice.py``): the paper's statement, else the best-covering reference plan."""
        order = base_order(self.kb)
        hosted = hosted_cards(self.g, order)
        decision = choose_base(self.candidates(), hosted, exclusive_cards(hosted, self.g), self.kb.bases.choice,
                               order, find_base_statements(self.doc, self.kb, self.units))
        st = decision.statement
        if st is not None:
            self.paper_evidence("base", st.quote, st.section, st.page, st.line, "", "paper",
                                f"the paper names the model it builds on ({', '.join(st.bases)})")
        if decision.close_call:
            self.notes.append(decision.close_call)
        return decision

    # ----------------------------------------------------------------- scene
    def scene(self, plan: Plan) -> None:
        """Scene facts the paper states (a dynamic scene has timestamps), with their quotes."""
        for flag, cue in detect_scene(self.doc, self.kb, self.units).items():
            plan.set(f"scene.{flag}", cue.value)
            self.paper_evidence(f"scene.{flag}", cue.quote, cue.section, cue.page, cue.line, "", "paper",
                                f"{flag} = {cue.value} ({cue.cue})")

    # ----------------------------------------------------------------- substitutions
    def _card_quote(self, card: str) -> tuple[str, str, Any, Any, str] | None:
        d = self.used.get(card)
        if d is not None:
            e = d.best()
            if e is not None:
                return e.quote, e.section, e.page, e.line, "paper"
        for comp in self.res.taken:
            if comp.card == card and comp.quote:
                return comp.quote, comp.section, comp.page, comp.line, "citation"
        return None

    def substitute(self, plan: Plan, only: Sequence[str] | None = None) -> None:
        """Each card of the paper (then each recovered from citations) put where the grammar places its
        primary terminal; its other terminals only confirm what the plan already holds. ``only``: these cards."""
        ordered = list(self.used) + [c.card for c in self.res.taken if c.card not in self.used]
        for card_name in dict.fromkeys(ordered):
            if only is not None and card_name not in only:
                continue
            c = self.cards.get(card_name)
            if c is None or c.terminal not in self.g.terminals:
                continue
            primary = [s for s in self.slots.get(c.terminal, ()) if s.kind != "enum"]
            for ts in primary:
                if _reachable(plan, ts.path, self.g, self.symbols):
                    self._place(plan, c, ts)
            for t in c.terminals[1:]:
                for ts in self.slots.get(t, ()):
                    if ts.kind != "enum" and plan.has(ts.path) and not any(ts.slot == p.slot for p in primary):
                        self._record_card(ts.slot, c)

    def host(self, plan: Plan) -> None:
        """The paper's cards that substitution left out because the base has no slot for them, once the paper's
        own parts are in the plan: each put inside a part that hosts it (the card's ``hosted_in``: K-Planes as the
        encoding of a deformation of Gaussians), then the rest placed again (a plane regulariser, once the plan has
        planes). A card placed here loses the note that said it was not used."""
        pending = [name for name in self.used if name not in self.placed and name in self.cards]
        if not pending:
            return
        for name in pending:
            c = self.cards[name]
            used = validate(plan, self.g).used
            for terminal, params in c.hosted_in.items():
                for path in [p for p, t in used.items() if t == terminal]:
                    given = plan.get(path) if isinstance(plan.get(path), dict) else {}
                    trial = plan.copy()
                    trial.set(path, {**given, **params})
                    problems = check(trial, self.g)
                    if problems:
                        self.notes.append(f"{c.name} ({c.title}) was found in the paper but cannot be hosted at "
                                          f"{path}: {problems[0].message}")
                        continue
                    plan.set(path, {**given, **params})
                    self._record_card(f"{path}.{next(iter(params))}", c)
        self.substitute(plan, only=[name for name in pending if name not in self.placed])
        placed = [name for name in pending if name in self.placed]
        self.notes = [n for n in self.notes if not any(n.startswith(f"{name} (") and "not used" in n
                                                       for name in placed)]

    def _variants(self, c: Card, ts: TerminalSlot) -> tuple[list[str], list[str]]:
        """The card's terminals for the slot of ``ts``: (those with scene duties: a space-time encoding for a
        scene with timestamps, the others), each in the card's order."""
        same = [t for t in c.terminals if any(s.slot == ts.slot and s.kind == ts.kind for s in self.slots.get(t, ()))]
        specific = [t for t in same if any("requires_scene" in d for d in self.g.terminals[t].duties)]
        return specific, [t for t in same if t not in specific]

    def _place(self, plan: Plan, c: Card, ts: TerminalSlot) -> None:
        """Put card ``c`` at the slot of ``ts``. What the plan holds of the card stays, unless a variant with
        scene duties fits (kplanes -> kplanes_time for a scene with timestamps); otherwise the first variant
        the grammar accepts. A choice the paper made itself is not replaced by one recovered from citations."""
        if ts.kind != "choice" and plan.has(ts.path):
            self._record_card(ts.path, c)
            return
        current = plan.get(ts.slot)
        held = next(iter(current), None) if ts.kind == "choice" and isinstance(current, dict) else None
        if held is not None and held not in c.terminals:
            other = self.g.terminals.get(held)
            if other is not None and other.card in self.used and c.name not in self.used:
                return  # the paper's own choice beats a component recovered from citations
            if other is not None and other.card in self.used and c.name in self.used and \
                    other.card in self.placed and self.used[other.card].confidence >= self.used[c.name].confidence:
                self.notes.append(f"{c.name} ({c.title}) was also found in the paper, less surely "
                                  f"({self.used[c.name].confidence:.2f} against "
                                  f"{self.used[other.card].confidence:.2f}) "
                                  f"than {other.card}; {held} stays at {ts.slot}")
                return  # two of the paper's own techniques for one slot: the surer detection wins
        specific, others = self._variants(c, ts)
        problems: dict[str, str] = {}
        if held in specific or self._try_variants(plan, c, ts, [t for t in specific if t != held], problems):
            return
        if held in c.terminals or self._try_variants(plan, c, ts, others, problems):
            if held in c.terminals:
                self._record_card(ts.slot, c)
            return
        problem = problems.get(c.terminal) or next(iter(problems.values()), "")
        self.notes.append(f"{c.name} ({c.terminal}) was found in the paper but is not used at {ts.slot}: "
                          f"{problem} (the base's part stays)")

    def _try_variants(self, plan: Plan, c: Card, ts: TerminalSlot, variants: list[str], problems: dict) -> bool:
        """Set the first of ``variants`` the grammar accepts at the slot of ``ts`` (True), noting the others'
        problems in ``problems``."""
        for terminal in variants:
            value = {terminal: self._params(c, terminal)} if ts.kind == "choice" else self._params(c, terminal)
            path = ts.slot if ts.kind == "choice" else next(s.path for s in self.slots[terminal] if s.slot == ts.slot)
            trial = plan.copy()
            trial.set(path, value)
            found = check(trial, self.g)
            if not found:
                plan.set(path, value)
                self._record_card(ts.slot if ts.kind == "choice" else path, c)
                return True
            problems[terminal] = found[0].message
        return False

    def _params(self, c: Card, terminal: str) -> dict:
        term = self.g.terminals[terminal]
        return {k: v for k, v in c.params_for(terminal).items() if k in term.params}

    def _record_card(self, slot: str, c: Card) -> None:
        self.placed.add(c.name)
        q = self._card_quote(c.name)
        if q:
            quote, section, page, line, source = q
            self.paper_evidence(slot, quote, section, page, line, c.name, source,
                                f"{c.title} ({c.paper.title}, {c.equation.ref or 'card'})")
        else:
            self.evidence[slot] = {"source": "card", "quote": "", "section": "", "page": None, "line": None,
                                   "card": c.name, "what": f"{c.title}: recovered from cited work via the "
                                                           f"knowledge base ({c.paper.title})"}

    # ----------------------------------------------------------------- hyperparameters
    def _hp(self, name: str, qualifier: str | None = None, sentence: str = "") -> Any | None:
        """The paper's statement of hyperparameter ``name`` (with ``qualifier``, in a sentence matching
        ``sentence``): method sections first, then reading order."""
        rank = {"method": 0, "abstract": 1, "title": 1, "experiments": 2, "conclusion": 3}
        found = []
        for i, h in enumerate(getattr(self.doc, "hyperparameters", [])):
            if h.name != name or (qualifier is not None and h.qualifier != qualifier):
                continue
            if sentence and not re.search(sentence, h.sentence or "", re.IGNORECASE):
                continue
            role = role_of_section(self.doc, h.section, self.kb.rules)
            if role in ("prior", "ignore"):
                continue
            found.append((rank.get(role, 2), i, h))
        found.sort(key=lambda x: (x[0], x[1]))
        return found[0][2] if found else None

    def _apply(self, plan: Plan, path: str, value: Any, h: Any, what: str) -> bool:
        trial = plan.copy()
        trial.set(path, value)
        problems = check(trial, self.g)
        if problems:
            self.notes.append(f"the paper's {what} ({h.raw or h.value}) does not fit {path}: {problems[0].message}")
            return False
        plan.set(path, value)
        self.paper_evidence(path, h.sentence, h.section, getattr(h.loc, "page", None), getattr(h.loc, "line", None),
                            "", "paper", what)
        return True

    def _statement(self, m: HyperparameterMap) -> Any | None:
        """The paper's statement ``m`` reads (its qualifiers tried in order)."""
        for qualifier in (m.qualifiers or (None,)):
            h = self._hp(m.name, qualifier, m.sentence)
            if h is not None:
                return h
        return None

    def terminal_hyperparameters(self, plan: Plan, hole_slots: set[str]) -> None:
        """The paper's hyperparameters set on the plan's terminals, as their cards say (one generic loop)."""
        for path, terminal in validate(plan, self.g).used.items():
            term = self.g.terminals.get(terminal)
            c = self.cards.get(term.card) if term is not None and term.card else None
            if c is None or terminal not in c.terminals or self._in_hole(path, terminal, hole_slots):
                continue
            done: set[str] = set()
            for m in c.hyperparameters_for(terminal):
                if m.param in done or (m.card_used and c.name not in self.used):
                    continue
                if self._apply_map(plan, path, c, terminal, m):
                    done.add(m.param)
                    done.update(p.param for p in c.hyperparameters_for(terminal) if p.name in m.together)

    def _in_hole(self, path: str, terminal: str, hole_slots: set[str]) -> bool:
        """Whether the paper's own part (a hole) replaces the terminal at ``path``: its values are the hole's."""
        return any(s.path == path and s.kind != "set" and s.slot in hole_slots for s in self.slots.get(terminal, ()))

    def _apply_map(self, plan: Plan, path: str, c: Card, terminal: str, m: HyperparameterMap) -> bool:
        """Apply one hyperparameter of a card (with its partners and derived parameters) at ``path``."""
        h = self._statement(m)
        if h is None or self._of_another_part(h.sentence or "", c):
            return False
        group = [m] + [p for p in c.hyperparameters_for(terminal) if p.name in m.together]
        statements = [h] + [self._hp(p.name) for p in group[1:]]
        if any(s is None or s.sentence != h.sentence for s in statements):
            return False
        term = self.g.terminals[terminal]
        current = plan.get(path)
        names = {**term.defaults(), **(current if isinstance(current, dict) else {})}  # the parameters before
        values = {}
        for p, s in zip(group, statements, strict=False):
            spec = term.params.get(p.param)
            value = _coerce(evaluate(p.value, {**names, "value": s.value}), spec.type) if spec else None
            if value is None:
                return False
            values[p.param] = value
        for param, expression in m.also:
            spec = term.params.get(param)
            value = _coerce(evaluate(expression, {**names, "value": values[m.param]}), spec.type) if spec else None
            if value is None:
                return False
            if value != names.get(param) or param in (current or {}):  # an unchanged default stays implicit
                values[param] = value
        what = ", ".join(f"{p.name} = {s.value}" + (f" (as {p.param} = {values[p.param]})"
                                                    if p.param != p.name or values[p.param] != s.value else "")
                         for p, s in zip(group, statements, strict=False))
        if m.grouped:
            return self._apply(plan, path, {**(current or {}), **values}, h, what)
        return self._apply(plan, f"{path}.{m.param}", values[m.param], h, what)

    def _of_another_part(self, sentence: str, card: Card) -> bool:
        """Whether ``sentence`` describes a new part of the paper that lands at another production than ``card``'s
        and does not name the card itself."""
        sentence = sentence.strip()
        if not sentence or any(name == card.name for _, _, (name, _a) in find_spans(sentence, self.kb.card_aliases)):
            return False
        return any((sentence in s or s in sentence) and p != card.production for s, p in self.novel_sentences.items())

    def trainer(self, plan: Plan) -> None:
        """The trainer's hyperparameters (no technique's): ray batch, iterations, optimiser and schedule."""
        h = self._hp("batch_size")
        if h is not None and isinstance(h.value, int) and (h.unit or "rays") in ("rays", "pixels"):
            self._apply(plan, "datamanager.train_num_rays_per_batch", h.value, h,
                        f"batch of {h.value} {h.unit or 'rays'}")
        iterations = self.iterations(plan)
        self.optimizer(plan, iterations)

    def iterations(self, plan: Plan) -> int | None:
        """The paper's number of iterations (the upper end of a range), or None."""
        h = self._hp("num_iterations")
        if h is None:
            if (e := self._hp("num_epochs")) is not None:
                self.notes.append(f"the paper states {e.raw} (epochs, not iterations); the base's iteration count "
                                  "is kept")
            return None
        value = max(h.value) if isinstance(h.value, list) else h.value
        if not isinstance(value, int | float) or value < 1:
            return None
        iterations = int(value)
        if self._apply(plan, "trainer.max_num_iterations", iterations, h, f"{iterations} iterations") \
                and isinstance(h.value, list):
            self.notes.append(f"the paper gives a range of iterations ({h.raw}); the plan trains for "
                              f"the upper end, {iterations}")
        return iterations

    def optimizer(self, plan: Plan, iterations: int | None) -> None:
        h = self._hp("learning_rate")
        final = self._hp("learning_rate_final")
        eps = self._hp("adam_eps")
        if not _scalar(h):
            return
        grids = self._stand_in_grids(plan)
        if grids:
            self.notes.append(f"the paper's learning rate ({h.raw or h.value}) is set for its own parameters; the "
                              f"plan trains feature grids the paper does not state ({', '.join(grids)}, from the "
                              "base), whose learning rates the base's configuration tunes, so the base's stay")
            return
        groups = [g for g in (plan.get("optimizers") or {}) if g != "camera_opt"]
        sentence = h.sentence.lower()
        named = [g for g in groups if re.search(rf"\b{re.escape(g.split('_')[0][:6])}\w*\b[^.;:]{{0,80}}"
                                                 rf"{re.escape(str(h.raw or h.value).lower())}", sentence)]
        if named:  # "the learning rate of the deformation network decays from 8e-4 to 1.6e-6": that group's
            groups = named
        elif len(groups) > 3:  # a model of many groups (a splatting base's per-attribute rates)
            self.notes.append(f"the paper's learning rate ({h.raw or h.value}) names none of the model's "
                              f"{len(groups)} parameter groups ({', '.join(groups)}); the base's rates stay")
            return
        for group in groups:
            current = plan.get(f"optimizers.{group}")
            kind = next(iter(current["optimizer"]))
            if re.search(r"\bradam\b", sentence):
                kind = "radam"
            elif re.search(r"\badam\b", sentence):
                kind = "adam"
            params = {"lr": float(h.value)}
            if kind == "adam":
                params["eps"] = float(eps.value) if _scalar(eps) and eps.sentence == h.sentence else \
                    float(current["optimizer"].get(kind, {}).get("eps", 1e-15)
                          if kind in current["optimizer"] else 1e-15)
            elif "eps" in current["optimizer"].get(kind, {}):
                params["eps"] = current["optimizer"][kind]["eps"]
            self._apply(plan, f"optimizers.{group}.optimizer", {kind: params}, h,
                        f"{kind} with learning rate {h.value}")
            if _scalar(final) and final.value < h.value:
                steps = iterations or int(plan.get("trainer.max_num_iterations") or 200000)
                kind_s = "exponential_decay"
                if not re.search(r"exponential", final.sentence, re.IGNORECASE):
                    self.notes.append("the paper decays the learning rate to its final value without saying how; "
                                      "the plan decays it exponentially")
                self._apply(plan, f"optimizers.{group}.scheduler", {kind_s: {"lr_final": float(final.value),
                                                                            "max_steps": steps}}, final,
                            f"exponential decay of the learning rate to {final.value} over {steps} steps")

    def _stand_in_grids(self, plan: Plan) -> list[str]:
        """The plan's feature-grid terminals (hash tables, planes, tensors: the registry's ``feature_grid`` trait)
        that stand in from the base: no sentence of the paper states them."""
        from nerfify_ns.grammar import derive
        from nerfify_ns.registry import default_registry

        registry, out = default_registry(), []
        for path, terminal in derive(plan, self.g).used.items():
            if terminal not in registry.terminals or not registry[terminal].code.traits.get("feature_grid"):
                continue
            stated = any(path == k or path.startswith(k + ".") for k, e in self.evidence.items()
                         if e.get("source") == "paper")
            if not stated:
                out.append(terminal)
        return out

    # ----------------------------------------------------------------- holes
    def contribution_holes(self, plan: Plan, ledger: Ledger) -> list[Hole]:
        """One hole per new contribution of the ledger, at the production it changes, with the claim it comes from."""
        holes = []
        for part in ledger.new:
            grp = {"equations": [{k: e[k] for k in ("number", "latex", "text", "where")}
                                 for e in part.equations_for_hole()],
                   "text": part.sentences[:6], "section": part.section, "loc": None}
            named = re.search(r"Eqs?\.?\s*\(?(\d+)\)?(?:\s*[-\u2013]\s*\(?(\d+)\)?)?", part.section)
            if named and not any(e["number"] for e in grp["equations"]):  # "Derivation of Eqs. (10-11)"
                lo, hi = int(named.group(1)), int(named.group(2) or named.group(1))
                grp["numbers"] = [str(n) for n in range(lo, hi + 1)] if hi - lo < 20 else [named.group(1)]
            hole = self._hole_at(plan, part.production, grp)
            at = f"p.{part.page}" if part.page else (f"l.{part.line}" if part.line else "")
            hole.where = ", ".join(x for x in (at, f"Sec. {part.section}") if x)
            hole.contribution = f"{part.id}: {part.heading}"
            hole.claim = (part.own_claims or part.claims or [""])[0][:400]
            hole.hyperparameters = [dict(h) for h in part.hyperparameters[:20]]
            hole.sections = list(part.more_sections)
            hole.why = (f"{part.why}; lands at {part.production} (meaning scores "
                        f"{', '.join(f'{k} {v}' for k, v in part.production_scores.items())})")
            holes.append(hole)
        return holes

    def _hole_at(self, plan: Plan, production: str, grp: dict) -> Hole:
        kind = next((k for k, v in HOLE_SYMBOLS.items() if v == production), None)
        if kind is not None:
            return self._hole(plan, kind, grp)
        paths = [p for p, sym in self.paths if sym == production]
        slot = paths[0] if paths else ""
        nt = self.g.nonterminals.get(production)
        term = self.g.terminals.get(getattr(nt, "terminal", None) or "") if nt is not None else None
        contract = _plainify(dict(term.contract)) if term is not None and term.contract else \
            {"doc": getattr(nt, "doc", "") if nt is not None else f"{production}: not a production of the grammar yet"}
        return Hole(production=production, slot=slot, contract=contract,
                    text=" ".join(_short(t, 600) for t in grp["text"][:4]),
                    equations=[{k: _short(str(v), 400) for k, v in eq.items()} for eq in grp["equations"]],
                    status="not implemented",
                    stands_in=f"nothing: the base has no {production} (its behaviour without it)",
                    section=grp["section"])

    def _hole_slot(self, plan: Plan, kind: str) -> tuple[str, str, str | None]:
        """(slot, production, the terminal standing in when the plan has none) of a hole of ``kind``, read
        from the grammar: the production's path (inside the plan's field when there are several) and its
        terminal (an open production's, or a choice's only alternative besides ``custom``)."""
        production = HOLE_SYMBOLS[kind]
        paths = [p for p, s in self.paths if s == production]
        path = next((p for p in paths if _reachable(plan, p, self.g, self.symbols)), paths[0])
        nt = self.g.nonterminals[production]
        named = [a for a in nt.alternatives if a != "custom"]
        fallback = getattr(nt, "terminal", None) or (named[0] if nt.kind == "choice" and len(named) == 1 else None)
        return path, production, fallback

    def _hole(self, plan: Plan, kind: str, grp: dict) -> Hole:
        slot, production, fallback = self._hole_slot(plan, kind)
        current = plan.get(slot)
        symbol = self.symbols.get(slot, "")
        nt = self.g.nonterminals.get(symbol)
        terminal = None
        if isinstance(current, dict) and nt is not None and nt.kind == "choice":
            terminal = next(iter(current), None)
        elif current is not None and symbol in self.g.terminals:
            terminal = symbol
        if terminal is None and nt is not None and nt.kind == "choice":
            fallback = fallback or nt.alternatives[0]  # the contract of the production's first alternative
        term = self.g.terminals.get(terminal or fallback or "")
        contract = dict(term.contract) if term is not None else {}
        if term is not None and not contract:
            contract = {"doc": term.doc}
        if current is None:
            stands_in = f"nothing: the plan has no {slot} (the base's behaviour without it)"
        elif term is None and isinstance(current, dict):  # the members of a set
            stands_in = f"{', '.join(current)} from the base plan, with {_plainify(current)!r}"
        else:
            stands_in = f"{terminal} ({term.doc if term else ''}) from the base plan, with {_plainify(current)!r}"
        text = " ".join(_short(t, 600) for t in grp["text"][:4])
        if grp.get("why"):
            text = f"{grp['why']}. Paper: {text}"
        equations = grp["equations"]
        if grp.get("numbers"):
            equations = [{"number": n, "latex": "", "text": "", "where": grp["section"]}
                         for n in grp["numbers"]] + equations
        loc = grp.get("loc")
        return Hole(production=production, slot=slot, contract=_plainify(contract), text=text,
                    equations=[{k: _short(str(v), 400) for k, v in eq.items()} for eq in equations],
                    status="not implemented", stands_in=stands_in, section=grp["section"],
                    where=_where(getattr(loc, "page", None), getattr(loc, "line", None), grp["section"]))


def _plainify(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _plainify(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plainify(v) for v in obj]
    return obj


def derive_plan(doc: Any, detections: Sequence[Detection] | None = None,
                graph: CitationGraph | None = None, grammar: Grammar | None = None,
                kb: KnowledgeBase | None = None, reference_plans: bool = True) -> DerivedPlan:
    """The plan of ``doc`` (see the module docstring) from the knowledge base ``kb`` (default: the
    package's); ``validate(result.plan)`` accepts it. ``reference_plans=False`` (the ablation
    ``no-reference-plans``): the base is not chosen among the reference plans (the paper's statement, the best
    host of its techniques) but is always the knowledge base's plainest one."""
    g = grammar or load_grammar()
    kb = KnowledgeBase.of(kb)
    detections = list(detect_techniques(doc, kb) if detections is None else detections)
    graph = graph if graph is not None else build_citation_graph(doc, detections, kb=kb)
    family = detect_family(doc, kb.rules)
    own = _own_cards(doc, kb)
    ledger = read_ledger(doc, kb, target_cards=own, family=family.name)
    detections = _without_claims(detections, ledger)
    d = _Deriver(doc, detections, graph, g, kb)
    d.own_cards = own
    d.novel_sentences = {x.strip(): p.production for p in ledger.new for x in p.sentences if len(x.strip()) > 20}
    decision = d.choose_base() if reference_plans else BaseDecision(
        base_order(kb)[0], "the knowledge base's plainest base (ablation no-reference-plans: the reference plans "
        "are not consulted)", [], criterion="ablation")
    decision = _base_for_family(decision, family, kb)
    base = decision.base
    plan = _start(doc, base, kb)
    d.scene(plan)
    for flag, value in family.scene.items():  # the family's scene facts (a dynamic paper's timestamps)
        plan.set(f"scene.{flag}", value)
        if family.evidence:
            e = family.evidence[0]
            d.paper_evidence(f"scene.{flag}", e["quote"], e["section"], e["page"], e["line"], "", "paper",
                             f"{flag} = {value} (the paper's family: {family.name})")
    d.substitute(plan)
    holes = d.contribution_holes(plan, ledger)
    d.terminal_hyperparameters(plan, {h.slot for h in holes})
    d.trainer(plan)
    _base_evidence(d, plan, g, base)
    missing = list(d.res.missing)
    title = (getattr(doc, "title", "") or "").strip()
    plan["description"] = (f"{title or plan['method']}: derived from the paper by nerfify (base {base}; "
                           f"{len(holes)} part(s) of the paper beyond the base, listed under holes).")
    plan["holes"] = [h.to_dict() for h in holes]
    notes = list(d.notes)
    if missing:
        notes.append("not recovered from the paper or its citations (the base's parts stand in): "
                     + ", ".join(missing))
    notes.append(f"base: {decision.reason}")
    plan["notes"] = notes
    plan["evidence"] = {path: _evidence_line(e) for path, e in sorted(d.evidence.items())}
    plan["family"] = {"name": family.name, "buildable": family.buildable, "why": family.why, "also": family.also,
                      **({"method": family.method} if family.method else {}),
                      "evidence": [f"{_where(e['page'], e['line'], e['section'])}: \"{_short(e['quote'])}\""
                                   for e in family.evidence]}
    plan["contributions"] = [{"part": p.id, "heading": p.heading, "status": p.status, "why": p.why,
                              **({"production": p.production} if p.status == "new" else {}),
                              **({"covered_by": p.covered_by} if p.covered_by else {}),
                              "claim": _short((p.own_claims or p.claims or [""])[0])}
                             for p in ledger.parts if p.status in ("new", "known")]
    if not family.buildable:
        notes.append(f"family {family.name}: {family.why}; the plan records what was read, nothing is built"
                     + (f"; {family.method_line()}; the base above is only the nearest ray-marched model"
                        if family.method else ""))
    validate(plan, g)
    return DerivedPlan(plan=plan, holes=plan["holes"], base=base, base_reason=decision.reason, evidence=d.evidence,
                       detections=detections, missing=missing, base_choice=decision, family=family, ledger=ledger,
                       deriver=d)


def _own_cards(doc: Any, kb: KnowledgeBase) -> set[str]:
    """Cards of techniques the paper itself introduced (the knowledge base already holds them)."""
    known = match_target(doc, kb)
    if known is None:
        return set()
    out = set()
    for name, c in kb.cards.items():
        same = (known.arxiv and c.paper.arxiv == known.arxiv) or \
            (c.paper.title and known.title and c.paper.title.strip().lower() == known.title.strip().lower())
        if same:
            out.add(name)
    return out


def _without_claims(detections: list[Detection], ledger: Ledger) -> list[Detection]:
    """Detections whose every use is a sentence stating one of the paper's new contributions are not uses:
    a sentence describing a contribution is never evidence for a known card."""
    claims = {s for p in ledger.new for s in (p.own_claims + p.claims)}
    out = []
    for det in detections:
        uses = det.uses
        if det.used and uses and all(any(e.quote.strip() and e.quote.strip() in c for c in claims) for e in uses):
            det = dataclasses.replace(det, status="mentioned_only",
                                      evidence=[dataclasses.replace(e, weight=0.0) for e in det.evidence])
        out.append(det)
    return out


def _base_for_family(decision: BaseDecision, family: Family, kb: KnowledgeBase) -> BaseDecision:
    """The family's own base when it has one (a splatting paper stands on splatfacto's 3D Gaussians, which hold a
    dynamic scene's times through the plan's wrappers); never a base another family reserves (a NeRF paper that
    names 3D-GS does not stand on Gaussians); and the base must hold the family's scene facts (a dynamic paper stands
    on a time-capable base): when the chosen one does not, the first reference plan in the knowledge base's order
    that does, with the reason."""
    if family.base:
        if decision.base == family.base:
            return decision
        return dataclasses.replace(decision, base=family.base, reason=(
            f"{family.base}: the paper is a {family.headline()} one, whose primitives only {family.base} holds "
            f"(the best host of its other techniques was {decision.base}: {decision.reason})"))
    reserved = {spec.base for spec in family_rules().families.values() if spec.base}
    if decision.base in reserved:
        other = next((b for b in base_order(kb) if b not in reserved), None)
        if other is not None:
            decision = dataclasses.replace(decision, base=other, reason=(
                f"{other}: the plainest base; {decision.base} (the best host of the paper's techniques: "
                f"{decision.reason}) is the base of another family's papers, not a {family.name} one's"))
    if not family.scene:
        return decision
    def fits(name: str) -> bool:
        scene = load_reference_plan(name).get("scene") or {}
        return all(scene.get(k) == v for k, v in family.scene.items())
    if fits(decision.base):
        return decision
    other = next((b for b in base_order(kb) if fits(b)), None)
    if other is None:
        return decision
    facts = ", ".join(f"{k} = {v}" for k, v in family.scene.items())
    return dataclasses.replace(decision, base=other, reason=f"{other}: the paper is a {family.name} one ({facts}); "
                               f"{decision.base} cannot hold that (it was the best host of the paper's techniques: "
                               f"{decision.reason})")


def _start(doc: Any, base: str, kb: KnowledgeBase) -> Plan:
    """The base's reference plan without its annotations, named after the paper."""
    plan = Plan.of(load_reference_plan(base))
    for key in ("evidence", "notes", "holes", "pruned"):
        plan.delete(key)
    known = match_target(doc, kb)
    plan["method"] = slug(doc)
    plan["paper"] = {"title": (getattr(doc, "title", "") or "").strip() or None,
                     "year": known.year if known else None, "arxiv": known.arxiv if known else None}
    return plan


def _base_evidence(d: _Deriver, plan: Plan, g: Grammar, base: str) -> None:
    """Every slot the paper did not set keeps the base's value, and says so."""
    for path in validate(plan, g).used:
        parts = path.split(".")
        slot = path.rsplit(".", 1)[0] if len(parts) >= 3 and parts[-2] not in ("losses", "regularizers") else path
        if not any(k == slot or k.startswith(slot + ".") or slot.startswith(k + ".") for k in d.evidence):
            d.base_evidence(slot, base)
    d.base_evidence("base", base)


FROM_BASE = "from the base plan {base!r}, not stated in the paper"
"""The evidence of a value the plan keeps from its base plan (read back by :func:`base_of`)."""


def base_of(evidence: str) -> str | None:
    """The base plan a value comes from, when its evidence line says it is the base's (:data:`FROM_BASE`)."""
    head, _, tail = FROM_BASE.partition("{base!r}")
    if not (evidence.startswith(head) and evidence.endswith(tail)):
        return None
    name = evidence[len(head):len(evidence) - len(tail)]
    return name[1:-1] if len(name) > 2 and name[0] == name[-1] and name[0] in "'\"" else None


def _evidence_line(e: dict) -> str:
    if e["source"] == "base":
        return e["what"]
    if not e.get("quote"):
        return e.get("what", "")
    where = _where(e.get("page"), e.get("line"), e.get("section", ""))
    label = {"paper": "", "citation": "citation: "}.get(e["source"], "")
    return f"{label}{where}: \"{_short(e['quote'])}\"" + (f" ({e['what']})" if e.get("what") else "")


def plan_from_paper(doc: Any, kb: KnowledgeBase | None = None) -> DerivedPlan:
    """Detect, recover citations and derive, in one call, all from the knowledge base ``kb``."""
    kb = KnowledgeBase.of(kb)
    detections = detect_techniques(doc, kb)
    return derive_plan(doc, detections, build_citation_graph(doc, detections, kb=kb), kb=kb)
