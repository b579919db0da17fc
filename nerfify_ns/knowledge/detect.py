"""Technique detection: which knowledge-base techniques (cards) a paper uses, with evidence.

    detections = detect_techniques(doc, kb)     # kb: a KnowledgeBase (None: the default one)
    [d.card for d in detections if d.used]

Signals (weights in ``detect.yaml``): card aliases in the text, the card's equation fragments in the
paper's equations, hyperparameters the paper states (``doc.hyperparameters``), and citations of the
paper that introduced the technique (references -> ``match_paper`` -> ``KnownPaper.provides``; a
"we use X of [k]" sentence names the technique explicitly). Each piece of evidence is an exact quote
of the document (``doc.find(quote)`` locates it) with its section and page or line.

Where a sentence sits decides whether it shows a use: the introduction, related work and background
describe other work; "X et al. [12] proposed ...", "unlike Y" and comparisons with baselines are
mentions. A technique with only such evidence is ``mentioned_only``; one whose evidence of use is too
weak is ``uncertain``; ``used`` needs a confidence of at least ``used_threshold``.

``doc`` is any object shaped like ``nerfify_ns.paper.Document`` (this package does not import it).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from nerfify_ns.knowledge.cards import Card
from nerfify_ns.knowledge.citations import find_citation_uses, find_spans
from nerfify_ns.knowledge.kb import KnowledgeBase
from nerfify_ns.knowledge.sentences import Rules, SentenceContext, Unit, read_sentence, role_of_section, sentences
from nerfify_ns.knowledge.text import longest_non_overlapping

STATUSES = ("used", "uncertain", "mentioned_only")


@dataclass
class Evidence:
    """One piece of evidence: an exact quote of the paper, where it is, and what it shows."""

    quote: str
    section: str
    page: int | None
    line: int | None
    kind: str            # alias | equation | hyperparameter | citation | phrase
    detail: str          # the alias, equation fragment, hyperparameter or cited paper that matched
    role: str            # the section's role: method, prior, experiments, abstract, title, conclusion
    weight: float = 0.0  # how much it counts as a use (0: a mention of someone else's work)

    @property
    def usage(self) -> bool:
        return self.weight > 0

    @property
    def where(self) -> str:
        loc = f"p.{self.page}" if self.page is not None else (f"l.{self.line}" if self.line is not None else "")
        return ", ".join(x for x in (loc, f"Sec. {self.section}" if self.section else "") if x)

    def to_dict(self) -> dict:
        return {**asdict(self), "usage": self.usage}


@dataclass
class Detection:
    """A technique (card) found in the paper, its status, confidence of use and evidence."""

    card: str
    title: str
    production: str
    terminals: list[str]
    status: str                       # used | uncertain | mentioned_only
    confidence: float                 # confidence that the paper uses it, in [0, 1]
    evidence: list[Evidence] = field(default_factory=list)

    @property
    def used(self) -> bool:
        return self.status == "used"

    @property
    def uses(self) -> list[Evidence]:
        return [e for e in self.evidence if e.usage]

    @property
    def mentions(self) -> list[Evidence]:
        return [e for e in self.evidence if not e.usage]

    def best(self) -> Evidence | None:
        """The strongest evidence of use (or the first mention)."""
        uses = sorted(self.uses, key=lambda e: -e.weight)
        return uses[0] if uses else (self.evidence[0] if self.evidence else None)

    def to_dict(self) -> dict:
        return {"card": self.card, "title": self.title, "production": self.production,
                "terminals": list(self.terminals), "status": self.status, "used": self.used,
                "confidence": round(self.confidence, 4), "evidence": [e.to_dict() for e in self.evidence]}


def used_cards(detections: list[Detection]) -> list[str]:
    return [d.card for d in detections if d.used]


@dataclass
class SceneCue:
    """A fact about the paper's scenes (``timestamps`` = True for a dynamic scene) and the sentence stating it."""

    flag: str
    value: Any
    quote: str
    section: str
    page: int | None
    line: int | None
    cue: str

    def to_dict(self) -> dict:
        return asdict(self)


def detect_scene(doc: Any, kb: KnowledgeBase | None = None,
                 units: Sequence[Unit] | None = None) -> dict[str, SceneCue]:
    """The scene facts the paper states about its own method (detect.yaml ``scene_cues``), first statement each;
    related work, mentions of other work and contrast clauses state nothing (``units``: the paper's
    sentences when the caller has read them already)."""
    kb = KnowledgeBase.of(kb)
    found: dict[str, SceneCue] = {}
    for unit in (units if units is not None else sentences(doc, kb.rules)):
        if unit.role not in ("title", "abstract", "method"):
            continue
        ctx = unit.context
        if ctx.prior and not ctx.usage:
            continue
        for flag, value, patterns in kb.rules.scene_cues:
            if flag in found:
                continue
            m = next((m for pat in patterns for m in pat.finditer(unit.text)
                      if not ctx.in_contrast(m.start(), m.end())), None)
            if m is not None:
                found[flag] = SceneCue(flag, value, unit.text, unit.section, unit.page, unit.line, m.group(0))
    return found


# ------------------------------------------------------------------------------------------ helpers
_LATEX_NOISE = re.compile(r"\\(?:mathopen|mathclose)\{\}|\\(?:left|right|big|Big|bigg|Bigg|displaystyle|textstyle)\b|"
                          r"\\[,;:! ]|\\q?quad\b|\s+|[{}]")


def norm_latex(s: str) -> str:
    """LaTeX reduced for fragment comparison: no spacing commands, sizing, braces or whitespace."""
    return _LATEX_NOISE.sub("", s or "")


def _ctx_weight(role: str, rules: Rules) -> float:
    """How much evidence in a section of ``role`` counts as a use, without a sentence to read."""
    return SentenceContext(role, False, False, False, (), context_weights=rules.context_weights).use_weight()


# ------------------------------------------------------------------------------------------ detection
def detect_techniques(doc: Any, kb: KnowledgeBase | None = None) -> list[Detection]:
    """Every card of ``kb`` the paper uses or mentions, strongest first (see the module docstring)."""
    kb = KnowledgeBase.of(kb)
    rules = kb.rules
    sw = rules.signal_weights
    cards = kb.cards
    found: dict[str, list[Evidence]] = {}

    def add(card_name: str, ev: Evidence) -> None:
        items = found.setdefault(card_name, [])
        if not any(e.quote == ev.quote and e.kind == ev.kind and e.detail == ev.detail for e in items):
            items.append(ev)

    # 1. aliases and phrases, sentence by sentence
    for unit in sentences(doc, rules):
        for start, end, (name, alias) in longest_non_overlapping(find_spans(unit.text, kb.card_aliases)):
            w = unit.context.use_weight(start, end)
            add(name, Evidence(unit.text, unit.section, unit.page, unit.line, "alias", alias, unit.role,
                               round(sw["alias"] * w, 4)))
        low = unit.text.lower()
        for word, name, phrase, pat in kb.phrase_patterns:
            m = pat.search(unit.text) if word in low else None
            if m:
                w = unit.context.use_weight(m.start(), m.end())
                add(name, Evidence(unit.text, unit.section, unit.page, unit.line, "phrase", phrase, unit.role,
                                   round(sw["phrase"] * w, 4)))
    # 2. equations: the cards' key fragments, and aliases written in the equation ("L = MSE(...)")
    for eq in getattr(doc, "equations", []):
        role = role_of_section(doc, eq.section, rules)
        if role == "ignore":
            continue
        w = _ctx_weight(role, rules)
        latex, text = norm_latex(eq.latex), norm_latex(eq.text)
        quote = eq.latex.strip() or eq.text.strip()
        if not quote:
            continue
        label = f"Eq. {eq.number}" if eq.number else "equation"
        page, line = getattr(eq.loc, "page", None), getattr(eq.loc, "line", None)
        for c in cards.values():
            for frag in c.signals.equations:
                nf = norm_latex(frag)
                if len(nf) < 3:
                    continue
                if (latex and nf in latex) or ("\\" not in frag and text and nf.lower() in text.lower()):
                    add(c.name, Evidence(quote, eq.section, page, line, "equation", f"{label}: {frag}", role,
                                         round(sw["equation"] * w, 4)))
                    break
        for _, _, (name, alias) in find_spans(eq.text or "", kb.card_aliases):
            add(name, Evidence(quote, eq.section, page, line, "equation", f"{label}: {alias}", role,
                               round(sw["equation"] * w, 4)))
    # 3. hyperparameters the paper states
    for h in getattr(doc, "hyperparameters", []):
        names = rules.hyperparameter_cards.get(h.name)
        if not names or not h.sentence:
            continue
        role = role_of_section(doc, h.section, rules)
        w = read_sentence(h.sentence, role, rules).use_weight()
        name = names[0]
        if len(names) > 1:  # the candidate with the most other evidence (num_frequencies: PE or IPE)
            name = max(names, key=lambda n: (sum(e.weight for e in found.get(n, []) if e.kind == "alias"),
                                             -names.index(n)))
        add(name, Evidence(h.sentence, h.section, getattr(h.loc, "page", None), getattr(h.loc, "line", None),
                           "hyperparameter", f"{h.name} = {h.value}", role, round(sw["hyperparameter"] * w, 4)))
    # 4. citations: explicit "we use X of [k]" uses, then any sentence citing the technique's paper
    explicit: set[str] = set()
    for u in find_citation_uses(doc, kb):
        w = read_sentence(u.sentence, u.role, rules).use_weight()
        for name in u.components:
            explicit.add(u.sentence)
            add(name, Evidence(u.sentence, u.section, u.page, u.line, "citation",
                               f"{u.relation} ({u.pattern}) {', '.join(u.papers) or ', '.join(u.keys)}", u.role,
                               round(sw["citation"] * w, 4)))
    refs = {r.key: r for r in getattr(doc, "references", [])}
    matched = {k: kb.match_reference(r) for k, r in refs.items()}
    roles_cache: dict[str, str] = {}
    for c in getattr(doc, "citations", []):
        if c.sentence in explicit:
            continue
        role = roles_cache.setdefault(c.section, role_of_section(doc, c.section, rules))
        if role == "ignore":
            continue
        ctx = read_sentence(c.sentence, role, rules)
        for key in c.keys:
            p = matched.get(key)
            if p is None:
                continue
            markers = [m for m in re.finditer(r"\[([^\[\]]{1,200})\]", c.sentence)
                       if key in [k.strip() for k in re.split(r"[,;]", m.group(1))]]
            contrast = bool(markers) and all(ctx.in_contrast(m.start(), m.end()) for m in markers)
            w = 0.0 if contrast else 0.5 * ctx.use_weight()
            for name in p.provides:
                add(name, Evidence(c.sentence, c.section, getattr(c.loc, "page", None), getattr(c.loc, "line", None),
                                   "citation", f"cites [{key}] {p.key}", role, round(sw["citation"] * w, 4)))
    return _judge(found, cards, rules.used_threshold)


def _confidence(uses: list[Evidence]) -> float:
    """Noisy-or across signal kinds; within a kind each further piece of evidence counts half as much
    as the one before (repeating a name many times in a results section does not make it a use)."""
    by_kind: dict[str, list[float]] = {}
    for e in uses:
        kind = "cites" if e.kind == "citation" and e.detail.startswith("cites ") else e.kind
        by_kind.setdefault(kind, []).append(min(e.weight, 0.95))
    miss = 1.0
    for weights in by_kind.values():
        for i, w in enumerate(sorted(weights, reverse=True)):
            miss *= 1.0 - w * 0.5 ** i
    return round(1.0 - miss, 4)


def _judge(found: dict[str, list[Evidence]], cards: dict[str, Card], threshold: float) -> list[Detection]:
    out: list[Detection] = []
    for name, evidence in found.items():
        strong = [e for e in evidence if e.kind != "phrase"]
        if not strong:
            continue  # a generic phrase alone says nothing
        uses = [e for e in strong if e.usage]
        if uses:
            uses += [e for e in evidence if e.kind == "phrase" and e.usage]
        confidence = _confidence(uses)
        if confidence >= threshold:
            status = "used"
        elif any(e.kind in ("alias", "citation", "equation") and not e.usage for e in strong):
            status = "mentioned_only"
        elif strong:
            status = "uncertain"
        c = cards[name]
        order = {"alias": 0, "citation": 1, "equation": 2, "hyperparameter": 3, "phrase": 4}
        evidence = sorted(evidence, key=lambda e: (not e.usage, order.get(e.kind, 9), -e.weight))
        out.append(Detection(card=name, title=c.title, production=c.production, terminals=list(c.terminals),
                             status=status, confidence=confidence, evidence=evidence))
    out.sort(key=lambda d: (STATUSES.index(d.status), -d.confidence, d.card))
    return out
