"""The ledger of a paper's contributions: what it claims as its own, where each claim is described, whether a
technique card already covers it, and the production of the grammar it changes.

    ledger = read_ledger(doc, kb, base_cards=...)          # Ledger(contributions=[...], parts=[...])
    [c for c in ledger.contributions if c.status == "new"]   # the paper's novel parts: each becomes one hole

1. **Claims.** Sentences of the title, abstract, introduction and method that state the paper's own contribution
   ("we propose / introduce / present", "a novel", "we call", "unlike [x], we"), and the items of a contributions
   list. A claim about the whole paper ("we present X, a method for ...") is kept for the record, not linked.
2. **Parts.** The method's leaf sections and the run-in paragraph headings inside them ("Hierarchical Training.
   Rather than ..."): each with its sentences, equations and hyperparameters. Generic headings (overview,
   preliminaries, implementation details) are parts only when a claim links to them.
3. **Links.** A claim links to the parts whose heading and text share its content words; a part holding a claim
   sentence of its own is claimed by it.
4. **Known or new, by meaning.** A claimed part is *known* when every one of its equations matches a card's by
   structure (``known.CardEquations``: renaming, commutativity, constant factors), or, without equations, when it
   names a card and either only borrows it ("we adopt X from [2]") or the card is the target paper's own technique.
   Otherwise it is *new*. A claim sentence is never evidence for a known card (``claim_sentences``).
5. **Production.** A new part lands where its heading, claims, text and equations' left-hand sides mean most
   (``ledger.yaml``'s ``productions``: weighted word stems and symbols), with the scores kept as the reason.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns.knowledge.citations import cites_earlier_work, find_spans
from nerfify_ns.knowledge.sentences import heading_role, section_roles, split_sentences
from nerfify_ns.synthesis.known import CardEquations

LEDGER_FILE = Path(__file__).resolve().parent / "ledger.yaml"
LINK_THRESHOLD = 0.34
"""A claim links to a part when this share of the claim's content words is found in the part's heading and text
(heading words count double)."""
HEADING_WEIGHT = 6
"""How much a production's word in the part's own heading counts against one in its text (the authors' name for
the part says most about what it is)."""
GENERIC_HEADING_WORDS = ("field", "fields", "model", "network", "networks", "method", "representation", "rendering",
                         "optimisation", "optimization", "training", "loss", "losses", "scene", "scenes", "radiance",
                         "neural", "overview", "details", "design", "architecture", "sampling", "volume", "efficient",
                         "function", "functions", "objective", "objectives")
"""Heading words too common to link a claim about the whole paper to one part."""
_STOP = set("""a an the of for and or to in on with by from as at is are was were be been this that these those we our
it its their which using use used into via each per than then also can may more most such both not only all any
one two three new novel propose proposed present introduce method approach paper work model based show shows""".split())


def _rules() -> dict:
    data = yaml.safe_load(LEDGER_FILE.read_text(encoding="utf-8"))
    comp = lambda items: [re.compile(p, re.IGNORECASE) for p in items]  # noqa: E731
    return {
        "claim": comp(data["claim"]), "borrow": comp(data["cites"] + data["borrow"]),
        "cites": comp(data["cites"]),
        "contributions_intro": re.compile(data["contributions_intro"], re.IGNORECASE),
        "whole_paper": re.compile(data["whole_paper"]),
        "first_person": re.compile(data["first_person"], re.IGNORECASE),
        "generic": re.compile(data["generic_headings"], re.IGNORECASE),
        "run_in": re.compile(data["run_in"]), "run_in_not": re.compile(data["run_in_not"]),
        "schedule_phase": comp(data.get("schedule_phase") or []),
        "component_use": {k: re.compile(v, re.IGNORECASE if k != "source" else 0)
                          for k, v in (data.get("component_use") or {}).items()},
        "several_fields": dict(data.get("several_fields") or {}),
        "family_words": {k: set(v) for k, v in (data.get("family_words") or {}).items()},
        "loss_split": dict(data.get("loss_split") or {}),
        "productions": {name: ([(re.compile(t, re.IGNORECASE), float(w)) for t, w in spec["terms"].items()],
                               list(spec.get("symbols") or []))
                        for name, spec in data["productions"].items()},
    }


_RULES: dict | None = None


def rules() -> dict:
    global _RULES
    if _RULES is None:
        _RULES = _rules()
    return _RULES


def _words(text: str) -> set[str]:
    return {w[:6] for w in re.findall(r"[a-z][a-z-]{2,}", text.lower()) if w not in _STOP}


@dataclass
class Claim:
    text: str
    source: str
    """contributions list | abstract | introduction | method | title"""
    section: str = ""
    page: int | None = None
    line: int | None = None
    whole_paper: bool = False
    parts: list = field(default_factory=list)
    """Ids of the parts it links to."""


@dataclass
class Part:
    """A described part of the method: a leaf section or a run-in paragraph heading."""

    id: str
    heading: str
    section: str
    """The section heading it is in (the part itself for a section)."""
    sentences: list = field(default_factory=list)
    equations: list = field(default_factory=list)
    """{number, latex, text, where, known: card or None, how}"""
    hyperparameters: list = field(default_factory=list)
    page: int | None = None
    line: int | None = None
    generic: bool = False
    lead: bool = False
    """The opening of a section whose run-in paragraphs are the parts (its claims announce them)."""
    appendix: bool = False
    """In an appendix or supplementary section (after the references, or numbered A, B, ...)."""
    parent: str = ""
    """The number of the section its section is a subsection of ("3" for a part of 3.2; "" at the top level)."""
    more_sections: list = field(default_factory=list)
    """The sibling subsections merged into it (their sentences are this part's)."""
    claims: list = field(default_factory=list)
    """The claims that link to it (their text)."""
    own_claims: list = field(default_factory=list)
    """Claim sentences written inside the part."""
    status: str = ""
    """new | known | unclaimed"""
    covered_by: list = field(default_factory=list)
    why: str = ""
    production: str = ""
    production_scores: dict = field(default_factory=dict)
    orders: list = field(default_factory=list)
    """The reading order of the paragraph of each sentence (to find the words around an equation)."""
    hole_equations: list | None = None
    """The equations its hole carries (None: every equation no card has, and those of cards the grammar does not
    compute; a part new through such a card carries that card's equations only)."""

    def equations_for_hole(self) -> list:
        if self.hole_equations is not None:
            return self.hole_equations
        own = [e for e in self.equations if not e["known"]]
        return own or list(self.equations)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["sentences"] = [s[:400] for s in self.sentences[:12]]
        d.pop("orders", None)
        return d


@dataclass
class Ledger:
    claims: list[Claim]
    parts: list[Part]

    @property
    def contributions(self) -> list[Part]:
        return [p for p in self.parts if p.status in ("new", "known")]

    @property
    def new(self) -> list[Part]:
        return [p for p in self.parts if p.status == "new"]

    def claim_sentences(self) -> set[str]:
        """Every sentence that states a contribution of the paper (never evidence for a known card)."""
        out = {c.text for c in self.claims if not c.whole_paper}
        for p in self.parts:
            out.update(p.own_claims)
        return out

    def to_dict(self) -> dict:
        return {"claims": [asdict(c) for c in self.claims], "parts": [p.to_dict() for p in self.parts]}


def _is_claim(sentence: str, r: dict) -> bool:
    return bool(r["first_person"].search(sentence)) and any(p.search(sentence) for p in r["claim"])


_TITLE_WORD = re.compile(r"^(?:[A-Z][\w-]*|of|for|and|the|in|with|via|to|on)$")


def _run_in_sentence(sentence: str, r: dict) -> bool:
    """A sentence that is only a run-in heading ("Ray Importance Sampling.")."""
    words = sentence.rstrip(". ").split()
    return (sentence.endswith(".") and 2 <= len(words) <= 7 and all(_TITLE_WORD.match(w) for w in words)
            and not r["run_in_not"].match(sentence))


def _borrows(sentence: str, r: dict) -> bool:
    return any(p.search(sentence) for p in r["borrow"])


def _loc(loc: Any) -> tuple[int | None, int | None, int]:
    return getattr(loc, "page", None), getattr(loc, "line", None), getattr(loc, "order", 0) or 0


class _Reader:
    def __init__(self, doc: Any, kb: Any, target_cards: set[str], family: str = ""):
        self.doc, self.kb, self.r = doc, kb, rules()
        self.family = family
        self.roles = section_roles(doc, kb.rules)
        self.topic = getattr(doc, "title", "") or ""
        """The paper's subject (its title): its words are in every part's text, so they say little of one part."""
        self.topic_stems = {w[:4].lower() for w in re.findall(r"[A-Za-z]{5,}", self.topic)}
        """The title's words by their first four letters ("Media" is on the topic of "medium")."""
        self.field_labels = self._field_labels()
        """The labels the paper writes on the field's density (sigma^obj, sigma^med): two or more are several
        fields."""
        self.index = CardEquations.of(kb)
        self.target_cards = target_cards
        self.claimless = False
        """The paper states no claim of a part in the first person (set after linking)."""

    # ------------------------------------------------------------------ claims
    def claims(self) -> list[Claim]:
        out: list[Claim] = []
        r = self.r
        blocks = [("abstract", "Abstract", None, None, self.doc.abstract or "")]
        for i, s in enumerate(self.doc.sections):
            role = self.roles[i]
            if role in ("ignore", "experiments", "conclusion"):
                continue
            source = "introduction" if role == "prior" else "method"
            for p in s.paragraphs:
                page, line, _ = _loc(p.loc)
                blocks.append((source, s.heading, page, line, p.text))
        listing = 0
        for source, section, page, line, text in blocks:
            for sentence in split_sentences(text):
                if source == "introduction" and r["contributions_intro"].search(sentence):
                    listing = 6
                    continue
                if listing and source == "introduction":
                    listing -= 1
                    if len(sentence) > 25:
                        out.append(Claim(sentence, "contributions list", section, page, line))
                    continue
                if source == "introduction" and any(p.search(sentence) for p in self.kb.rules.prior):
                    continue
                if _is_claim(sentence, r) and not (_borrows(sentence, r) and not re.search(r"\bnovel|\bnew\b",
                                                                                             sentence, re.I)):
                    out.append(Claim(sentence, source, section, page, line))
            if source != "introduction":
                listing = 0
        unique = {c.text: c for c in out}
        out = list(unique.values())
        title = (self.doc.title or "").strip()
        for c in out:
            c.whole_paper = bool(self.r["whole_paper"].search(c.text)) or (bool(title) and title.split(":")[0] in c.text
                                                                          and len(title.split(":")[0]) > 3)
        return out

    # ------------------------------------------------------------------ parts
    def parts(self) -> list[Part]:
        sections = self.doc.sections
        levels = [getattr(s, "level", 1) or 1 for s in sections]
        parts: list[Part] = []
        equations = list(getattr(self.doc, "equations", []) or [])
        hps = list(getattr(self.doc, "hyperparameters", []) or [])
        after_references = False
        for i, s in enumerate(sections):
            if re.match(r"(?:references?|bibliography)$", (getattr(s, "title", "") or "").strip(), re.I):
                after_references = True
            if self.roles[i] != "method":
                continue
            has_child = i + 1 < len(sections) and levels[i + 1] > levels[i] and self.roles[i + 1] == "method"
            if has_child and not any(e.section == s.heading for e in equations):
                continue  # an introduction to its subsections, which are the parts (its claims link to them)
            heading = s.heading
            title = (getattr(s, "title", "") or heading).strip()
            generic = bool(self.r["generic"].search(title.lower().strip(" .:")))
            number = getattr(s, "number", "") or ""
            appendix = after_references or bool(re.search(r"[A-Za-z]", number)) or \
                bool(re.search(r"\b(?:appendix|supplementa)", title, re.I))
            page, line, order = _loc(s.loc)
            parent = number.rsplit(".", 1)[0] if "." in number else ""
            current = Part(f"p{len(parts) + 1}", title, heading, page=page, line=line, generic=generic,
                           appendix=appendix, parent=parent)
            section_parts = [current]
            orders = [order]
            for p in s.paragraphs:
                m = self.r["run_in"].match(p.text)
                ppage, pline, porder = _loc(p.loc)
                if m and not self.r["run_in_not"].match(m.group("title")) and len(m.group("title")) >= 6:
                    current = Part(f"p{len(parts) + len(section_parts) + 1}", m.group("title"), heading,
                                   page=ppage, line=pline, appendix=section_parts[0].appendix, parent=parent)
                    section_parts.append(current)
                    orders.append(porder)
                    text = p.text[m.end():]
                else:
                    text = p.text
                for sentence in split_sentences(text):
                    if _run_in_sentence(sentence, self.r) and current.sentences:
                        current = Part("", sentence.rstrip(". "), heading, page=ppage, line=pline,
                                       appendix=section_parts[0].appendix, parent=parent)
                        section_parts.append(current)
                        orders.append(porder)
                        continue
                    current.sentences.append(sentence)
                    current.orders.append(porder)
            for e in equations:
                if e.section != heading:
                    continue
                _, _, eorder = _loc(e.loc)
                k = max(j for j in range(len(section_parts)) if j == 0 or orders[j] <= eorder)
                read, match = self.index.read_and_match(e.latex, e.text)
                section_parts[k].equations.append({
                    "number": e.number, "latex": e.latex, "text": e.text,
                    "where": ", ".join(x for x in (f"p.{e.loc.page}" if getattr(e.loc, "page", None) else "",
                                                   f"Sec. {heading}") if x),
                    "known": match.card if match else None, "how": match.how if match else "",
                    "read": read, "order": eorder})
            for h in hps:
                if h.section == heading:
                    section_parts[-1 if len(section_parts) == 1 else 0].hyperparameters.append(
                        {"name": h.name, "value": h.value if isinstance(h.value, int | float | str) else str(h.value),
                         "sentence": (h.sentence or "")[:200]})
            if len(section_parts) > 1 and not section_parts[0].equations:
                section_parts[0].lead = True  # it introduces the run-in parts after it
            # a run-in paragraph of the method's details that reports on the experiments ("Evaluation Metrics.",
            # "Comparison Baselines.", "Datasets.") describes no part of the method
            parts.extend(p for k, p in enumerate(section_parts) if (p.sentences or p.equations)
                         and not (k and heading_role(p.heading) == "experiments"))
        for n, p in enumerate(parts, 1):
            p.id = f"p{n}"
        return parts

    # ------------------------------------------------------------------ links
    def link(self, claims: list[Claim], parts: list[Part]) -> None:
        for p in parts:
            p.own_claims = [s for s in p.sentences if _is_claim(s, self.r) and not _borrows(s, self.r)
                            and not self.r["whole_paper"].search(s)]
        generic = _words(" ".join(GENERIC_HEADING_WORDS))
        for c in claims:
            words = _words(c.text)
            if c.whole_paper:
                for p in parts:
                    distinctive = (_words(p.heading) - generic) & words
                    if distinctive and len(distinctive) >= max(1, len(_words(p.heading) - generic) // 2):
                        c.parts.append(p.id)
                        p.claims.append(c.text)
                continue
            if len(words) < 2:
                continue
            for p in parts:
                head = _words(p.heading)
                body = _words(" ".join(p.sentences[:40]))
                score = (2 * len(words & head) + len(words & body)) / (len(words) + len(head))
                if score >= LINK_THRESHOLD and (words & head or len(words & body) >= 3):
                    c.parts.append(p.id)
                    p.claims.append(c.text)

    # ------------------------------------------------------------------ known or new
    def judge(self, p: Part) -> None:
        eqs = p.equations
        first = [x for x in p.sentences if self.r["first_person"].search(x)]
        borrowed = [x for x in first if _borrows(x, self.r)]
        unmatched = [e for e in eqs if not e["known"]]
        # a part that takes earlier work, unless an equation the parser read is new or is a card's the grammar
        # does not compute (an equation read is meaning; an unreadable one is not evidence either way)
        structural = [e for e in eqs if (not e["known"] and e.get("read")) or (e["known"] and self.unbuilt(e["known"]))]
        takes = not p.own_claims and first and len(borrowed) * 2 > len(first) and not structural
        unbuilt_eqs = [e for e in eqs if e["known"] and self.unbuilt(e["known"])]
        if unbuilt_eqs and not p.appendix:
            self._unbuilt(p, sorted({e["known"] for e in unbuilt_eqs}))
            if unmatched:
                p.why += (f"; its other equation(s) no card has (Eq. {_numbers(unmatched)}) are recorded with the "
                          "part, not built")
            return
        if not p.claims and not p.own_claims:
            if self.claimless and not takes and not p.appendix and not (eqs and not unmatched) \
                    and not self._cards_named(p):
                p.status = "new"
                p.why = ("the paper states no claim in the first person (a condensed or third-person text): every "
                         "method part it describes that no card covers is taken as its own"
                         + (f"; {len(unmatched)} equation(s) no card has" if unmatched else ""))
                return
            read = any(e.get("read") for e in unmatched)
            restates = self._restates(p, first, opening_only=read) if unmatched else ""
            if unmatched and not takes and not p.appendix and not restates:
                p.status = "new"
                p.why = (f"{len(unmatched)} equation(s) no card has (Eq. {_numbers(unmatched)}), in the method, not "
                         "taken from earlier work (the paper claims it in no sentence)")
            elif restates:
                p.status = "unclaimed"
                p.why = (f"it restates earlier work (\"{restates[:120]}\"), claims nothing of it, and "
                         + (f"opens with what it takes (Eq. {_numbers(unmatched)} is that work's, as written here)"
                            if read else f"its equation(s) (Eq. {_numbers(unmatched)}) are text the parser cannot "
                                         "read (no evidence of anything new)"))
            else:
                p.status, p.why = "unclaimed", "the paper claims nothing of it (a description, not a contribution)"
            return
        if not eqs and not p.own_claims and not self._distinctive_link(p):
            p.status, p.why = "unclaimed", "only general claims link to it (no claim of its own, no equation)"
            return
        known = [e["known"] for e in eqs if e["known"]]
        unbuilt = sorted({k for k in known if self.unbuilt(k)})
        if eqs and len(known) == len(eqs) and unbuilt:
            self._unbuilt(p, unbuilt)
            return
        if eqs and len(known) == len(eqs):
            p.status, p.covered_by = "known", sorted(set(known))
            p.why = "every equation of it matches a card's by structure: " + ", ".join(
                f"Eq. {e['number'] or '?'} = {e['known']} ({e['how']})" for e in eqs)
            return
        if takes:
            p.status = "known"
            p.why = f"it takes earlier work (\"{borrowed[0][:120]}\") and claims nothing of its own"
            return
        named = self._cards_named(p)
        if not eqs and named:
            own = [s for s in p.own_claims
                   if re.search(r"\bnovel\b|\bnew\b|\bpropos|\bintroduc|\bwe (?:call|present|design)", s, re.I)]
            mine = sorted(set(named) & self.target_cards)
            if mine or not own:
                p.status, p.covered_by = "known", sorted(set(named))
                p.why = (f"the card(s) {', '.join(mine)} are this paper's own technique(s), already in the knowledge "
                         "base" if mine else
                         f"it uses {', '.join(sorted(set(named)))} (named, no new equation, no claim of its own)")
                return
        p.status = "new"
        p.why = (f"{len(unmatched)} equation(s) no card has (Eq. {', '.join(e['number'] or '?' for e in unmatched)})"
                 if unmatched else "a part the paper claims, described in prose, that no card covers")

    def own_card(self, p: Part) -> None:
        """A new part of a paper the knowledge base knows, landing where one of the paper's own cards does (the
        card's production) with no equation read that no card has, is that card: the paper's technique, already
        in the knowledge base, not a hole (its text or equations may be too garbled to name it)."""
        if not self.target_cards or p.hole_equations is not None \
                or any(not e["known"] and e.get("read") for e in p.equations):
            return
        mine = sorted(c for c in self.target_cards
                      if c in self.kb.cards and self.kb.cards[c].production == p.production)
        if len(mine) != 1:
            return
        p.status, p.covered_by = "known", mine
        p.why = (f"it lands at {p.production}, where this paper's own technique {mine[0]} does (the knowledge base "
                 f"already holds it), and no equation of it that the parser read is new")

    def _restates(self, p: Part, first: list[str], opening_only: bool = False) -> str:
        """The first of the part's sentences in the first person that cites earlier work (a reference marker or a
        known paper's name): the part says what it takes, and whose; "" when none does. ``opening_only``: only the
        part's opening sentence counts (a part that opens with what it takes restates it, whatever its equations)."""
        candidates = [s for s in first if s == p.sentences[0]] if opening_only else first
        return next((s for s in candidates
                     if any(c.search(s) for c in self.r["cites"]) or cites_earlier_work(s, self.kb)), "")

    def _unbuilt(self, p: Part, cards: list) -> None:
        card = self.kb.cards[cards[0]]
        p.status, p.covered_by = "new", cards
        p.hole_equations = [e for e in p.equations if e["known"] in cards]
        p.production = _production_of_slot(card.equation_slot) or card.production
        p.production_scores = {p.production: "the card's equation slot"}
        p.why = (f"its equation is {card.title}'s ({', '.join(cards)}), which the grammar's "
                 f"{'/'.join(card.terminals)} terminal does not compute: the paper's own use of it is built here")

    def unbuilt(self, card: str) -> bool:
        """Whether ``card``'s equation is one the grammar's terminals do not compute (its own slot would)."""
        c = self.kb.cards.get(card)
        return c is not None and not c.implements_equation and bool(c.equation_slot)

    def schedule_phases(self, parts: list[Part]) -> list[Part]:
        """Training phases the paper states in the first person in any method or details section (a warm-up that
        trains one part alone, a freeze after N steps) and that no new part already holds: one ScheduleHook part
        each (``ledger.yaml: schedule_phase``)."""
        held = {x for p in parts if p.status == "new" for x in p.sentences}
        out: list[Part] = []
        for i, s in enumerate(self.doc.sections):
            if self.roles[i] not in ("method", "experiments"):
                continue
            for paragraph in s.paragraphs:
                for sentence in split_sentences(paragraph.text):
                    if sentence in held or not self.r["first_person"].search(sentence) \
                            or any(p.search(sentence) for p in self.r["cites"]):
                        continue
                    if any(p.search(sentence) for p in self.r["schedule_phase"]):
                        page, line, _ = _loc(paragraph.loc)
                        out.append(Part(f"p{len(parts) + len(out) + 1}", f"training phase: {sentence[:80]}",
                                        s.heading, sentences=[sentence], page=page, line=line, status="new",
                                        own_claims=[sentence], production="ScheduleHook",
                                        production_scores={"ScheduleHook": "a training phase the paper states"},
                                        why="a training phase the paper states (one part trained alone, or frozen, "
                                            "for a number of steps)"))
                        held.add(sentence)
        return out

    def _distinctive_link(self, p: Part) -> bool:
        """Whether a claim shares a word of the part's heading that is not a generic heading word."""
        head = _words(p.heading) - _words(" ".join(GENERIC_HEADING_WORDS))
        return any(head & _words(c) for c in p.claims)

    def _cards_named(self, p: Part) -> list[str]:
        text = " ".join([p.heading, *p.own_claims[:3]])
        return [name for _, _, (name, _alias) in find_spans(text, self.kb.card_aliases)]

    def production(self, p: Part) -> None:
        scores = {}
        heading, claims, own = p.heading, " ".join(p.claims + p.own_claims), " ".join(p.own_claims)
        body = _plain(" ".join(p.sentences[:30]))
        named = [e for e in p.equations if not _defines_set(e)]  # a set of rays names no part by its letter
        lhs = " ".join(_lhs_name(e) for e in named)
        new_lhs = " ".join(_lhs_words(e) for e in named if not e["known"])
        family_words = self.r["family_words"].get(self.family, set())
        for name, (terms, symbols) in self.r["productions"].items():
            score = 0.0
            for pattern, weight in terms:
                hits = [m.group(0) for m in pattern.finditer(body)]
                said_here = [m.group(0) for m in pattern.finditer(claims)] + hits
                on_topic = bool(pattern.search(self.topic)) or any(
                    w[:4].lower() in self.topic_stems for w in said_here if len(w) > 4)
                in_body = 0.0 if pattern.pattern in family_words or on_topic else math.sqrt(len(hits))
                # the topic counts in the part's own claims; the family's words (time, in a dynamic paper) in all
                said = pattern.search(own if on_topic and pattern.pattern not in family_words else claims)
                score += weight * (HEADING_WEIGHT * bool(pattern.search(heading)) + 2 * bool(said)
                                   + in_body + 3 * bool(pattern.search(new_lhs)))
            score += 2.0 * sum(1 for s in symbols if s and re.search(rf"(?:^|\s){re.escape(s)}(?:\s|$)", lhs))
            scores[name] = round(score, 2)
        best = max(scores, key=lambda k: scores[k]) if scores else "Backbone"
        p.production = best if scores.get(best, 0) > 0 else "Backbone"
        p.production_scores = dict(sorted(scores.items(), key=lambda kv: -kv[1])[:4])
        labels = self._labels_in(" ".join([*p.sentences, *(e["latex"] or e["text"] for e in p.equations)])) \
            & self.field_labels
        if len(self.field_labels) >= 2 and labels and p.production in self.r["several_fields"].get("productions", ()):
            p.production_scores = {**p.production_scores, "FieldWrapper": (
                f"the paper writes the field's outputs with {len(self.field_labels)} labels "
                f"({', '.join(sorted(self.field_labels))}: several fields) and this network makes the "
                f"{', '.join(sorted(labels))} one")}
            p.production = "FieldWrapper"

    # ------------------------------------------------------------------ several fields
    def _labels_in(self, text: str, quantities: tuple[str, ...] = ("density", "colour")) -> set[str]:
        spec = self.r["several_fields"]
        not_labels = {str(x).lower() for x in spec.get("not_labels") or ()}
        return {m.group("label").lower() for q in quantities if spec.get(q)
                for m in re.finditer(spec[q], text)} - not_labels

    def _field_labels(self) -> set[str]:
        texts = [e.latex or e.text or "" for e in getattr(self.doc, "equations", []) or []]
        for i, s in enumerate(self.doc.sections):
            if self.roles[i] == "method":
                texts += [p.text for p in s.paragraphs]
        return self._labels_in(" ".join(texts), ("density",))

    # ------------------------------------------------------------------ loss terms
    def split_losses(self, parts: list[Part]) -> list[Part]:
        """A new loss part whose equations do different things becomes several parts (``ledger.yaml:
        loss_split``): the term comparing the rendered colour with the observed one stays (RGBLoss), each other
        loss term is a regulariser of its own, with the words around its equation; a sum of the part's terms with
        their weights stays with the part."""
        spec = self.r["loss_split"]
        if not spec:
            return []
        loss_lhs = re.compile(spec["loss_lhs"])
        out: list[Part] = []
        for p in parts:
            if p.status != "new" or p.production != spec["from"] or p.hole_equations is not None:
                continue
            terms = [e for e in p.equations if loss_lhs.search(_lhs(e)) and not _sums_terms(e) and not _defines_set(e)]
            reconstruction = [e for e in terms if _compares_render_and_target(e)]
            others = [e for e in terms if e not in reconstruction and not e["known"]]
            if not reconstruction or not others:
                continue
            for e in others:
                at = e.get("order", 0)
                placed = list(zip(p.sentences, p.orders, strict=False))
                prev = max([x.get("order", 0) for x in p.equations if x.get("order", 0) < at], default=-1)
                near = [s for s, o in placed if prev < o <= at] or [s for s, o in placed if o <= at][-1:]
                after = [s for s, o in placed if at < o][:1]
                title = _plain(near[-1] if near else f"Eq. {e['number'] or '?'}").strip(" :.")[:100]
                p.equations.remove(e)
                out.append(Part(f"p{len(parts) + len(out) + 1}", title, p.section, sentences=near + after,
                                equations=[e], page=p.page, line=p.line, status="new", claims=list(p.claims),
                                own_claims=[s for s in p.own_claims if s in near], production=spec["to"],
                                production_scores={spec["to"]: f"a loss term on other quantities than the rendered "
                                                               f"colour, split from {p.id} ({p.heading})"},
                                why=f"{p.why}; a loss term of its own beside the reconstruction loss of {p.id}"))
            split = ", ".join(x.id for x in out[-len(others):])
            left = [e for e in p.equations if not _sums_terms(e)]
            if left and all(e["known"] for e in left):  # what stays is a card's reconstruction loss
                p.status, p.covered_by = "known", sorted({e["known"] for e in left})
                p.why = (f"its reconstruction loss matches {', '.join(p.covered_by)} by structure; its other loss "
                         f"term(s) are parts of their own ({split})")
            else:
                p.why += f"; its other loss term(s) are parts of their own ({split})"
        return out

    # ------------------------------------------------------------------ network components
    def component_uses(self, parts: list[Part]) -> list[Part]:
        """Network components the paper adds in its method in the first person, citing no source and naming no
        card ("we use Layer Normalization after each fully-connected layer"), that no new part already holds: one
        part each, at the production the sentence's meaning points to (``ledger.yaml: component_use``)."""
        spec = self.r["component_use"]
        if not spec:
            return []
        held = {x for p in parts if p.status in ("new", "merged") for x in p.sentences}
        out: list[Part] = []
        for i, s in enumerate(self.doc.sections):
            if self.roles[i] != "method":
                continue
            for paragraph in s.paragraphs:
                for sentence in split_sentences(paragraph.text):
                    m = spec["components"].search(sentence)
                    if sentence in held or m is None or not spec["verb"].search(sentence) \
                            or spec["source"].search(sentence) or find_spans(sentence, self.kb.card_aliases):
                        continue
                    page, line, order = _loc(paragraph.loc)
                    part = Part(f"p{len(parts) + len(out) + 1}", m.group(0), s.heading, sentences=[sentence],
                                orders=[order], page=page, line=line, status="new", own_claims=[sentence],
                                why="a network component the paper adds in its method (no source cited, no card "
                                    "names it)")
                    self.production(part)
                    out.append(part)
                    held.add(sentence)
        return out


def _production_of_slot(slot: str | None) -> str:
    """The production (nonterminal) at a plan path of the grammar ('model.field.MLPField.rgb_head' -> 'RGBHead')."""
    if not slot:
        return ""
    from nerfify_ns.grammar import load_grammar

    g = load_grammar()
    symbol = dict(g.symbol_paths()).get(slot, "")
    if symbol in g.nonterminals:
        return symbol
    # an open production's path holds its terminal: the production is the nonterminal of that terminal
    return next((name for name, nt in g.nonterminals.items() if getattr(nt, "terminal", None) == symbol), symbol)


def _numbers(equations: list) -> str:
    return ", ".join(e["number"] or "?" for e in equations)


def _plain(text: str) -> str:
    """Text without markdown emphasis (``**stream**`` -> ``stream``)."""
    return re.sub(r"\*\*|__|(?<!\w)\*(?=\w)|(?<=\w)\*(?!\w)", "", text)


def _lhs(e: dict) -> str:
    src = e.get("latex") or e.get("text") or ""
    return src.split("=", 1)[0] if "=" in src else ""


_LOSS_SYMBOL = re.compile(r"\\mathcal\s*\{?\s*[LR]\s*\}?|(?<![A-Za-z\\])[LR](?![A-Za-z])|\\ell\b")


def _defines_set(e: dict) -> bool:
    """Whether the equation defines a set in set-builder notation (``R_C = {r | ...}``: the valid rays), which is
    no loss term whatever its left-hand side's letter."""
    src = e.get("latex") or e.get("text") or ""
    rhs = src.split("=", 1)[1].strip() if "=" in src else ""
    return bool(re.match(r"(?:\\left\s*)?(?:\\\{|\{)", rhs)) and bool(re.search(r"\||\\mid\b", rhs))


def _sums_terms(e: dict) -> bool:
    """Whether the equation only adds loss terms with their weights (``L = L_rec + \\lambda L_reg``)."""
    src = e.get("latex") or e.get("text") or ""
    if "=" not in src:
        return False
    rhs = re.split(r"\\q?quad|,\s*\\|;", src.split("=", 1)[1])[0]
    if len(_LOSS_SYMBOL.findall(rhs)) < 2:
        return False
    rest = _LOSS_SYMBOL.sub("", rhs)
    rest = re.sub(r"_\s*\{(?:[^{}]|\{[^{}]*\})*\}|_\s*\\?\w+|\\(?:mathrm|text|rm|cdot|lambda|alpha|beta|gamma|mu|eta|"
                  r"omega|tau|left|right)\b|\\[,;!]|[\d.]+|[+\s{}()\[\]]|\b[a-z]\b", "", rest)
    return not rest


def _compares_render_and_target(e: dict) -> bool:
    """Whether a loss compares a rendered quantity with its observation: a hatted symbol and the same letter
    unhatted, starred or ground truth (``\\hat C`` and ``C^*``, ``\\hat{\\mathbf C}(r)`` and ``C(r)``)."""
    src = e.get("latex") or e.get("text") or ""
    rhs = src.split("=", 1)[1] if "=" in src else src
    rhs = re.sub(r"\\(?:mathbf|boldsymbol|bm|mathrm)\s*\{\s*([A-Za-z])\s*\}", r"\1", rhs)
    hatted = set(re.findall(r"\\(?:hat|widehat|tilde)\s*\{?\s*([A-Za-z])", rhs)) | \
        {"C" for _ in re.findall("\u0108", rhs)} | {"I" for _ in re.findall("\u00ce", rhs)}
    plain = re.sub(r"\\(?:hat|widehat|tilde)\s*\{?\s*[A-Za-z]", " ", rhs)
    return any(re.search(rf"(?<![A-Za-z\\]){x}(?![A-Za-z])", plain) for x in hatted)


def _lhs_words(e: dict) -> str:
    """The words of an equation's left-hand side, subscripts included (\\mathcal{L}_{\\mathrm{reg}} -> 'L reg')."""
    src = e.get("latex") or e.get("text") or ""
    lhs = src.split("=", 1)[0] if "=" in src else ""
    return " ".join(re.findall(r"[A-Za-z]{2,}", re.sub(r"\\[A-Za-z]+", " ", lhs))).lower()


def _lhs_name(e: dict) -> str:
    src = e.get("latex") or e.get("text") or ""
    lhs = src.split("=", 1)[0] if "=" in src else ""
    lhs = re.sub(r"\\(?:mathbf|mathcal|hat|bar|tilde|boldsymbol|mathrm)\s*\{?", lambda m: "cal " if "cal" in m.group(0)
                 else ("hat " if "hat" in m.group(0) else ""), lhs)
    lhs = re.sub(r"[{}\\()]|_\{?[^ ]*", " ", lhs)
    return " ".join(lhs.split())


def read_ledger(doc: Any, kb: Any, target_cards: set[str] | None = None, family: str = "") -> Ledger:
    """The ledger of ``doc`` (see the module docstring). ``target_cards``: cards whose technique the paper itself
    introduced (the knowledge base already holds them: claiming them is not a hole); ``family``: the paper's family
    (its deciding words count little for where a part lands)."""
    reader = _Reader(doc, kb, set(target_cards or ()), family)
    claims = reader.claims()
    parts = reader.parts()
    reader.link(claims, parts)
    reader.claimless = not claims and not any(p.own_claims for p in parts)
    if all(p.appendix for p in parts):  # an appendix alone (a supplement): its parts are the method we have
        for p in parts:
            p.appendix = False
    for p in parts:
        if p.appendix and not p.own_claims:
            p.status, p.why = "unclaimed", "an appendix part that claims nothing itself (details of the method)"
            continue
        if p.lead:
            p.status = "unclaimed"
            p.why = "it introduces the parts after it in its section (they are judged themselves)"
            continue
        if p.generic and not p.own_claims and not any(not e["known"] or reader.unbuilt(e["known"])
                                                      for e in p.equations):
            p.status, p.why = "unclaimed", "a generic section (details, overview) that claims nothing itself"
            continue
        reader.judge(p)
        if p.status == "new" and not p.production:
            reader.production(p)
            reader.own_card(p)
    parts += reader.split_losses(parts)
    _merge(parts)
    parts += reader.schedule_phases(parts)
    parts += reader.component_uses(parts)
    return Ledger(claims, parts)


def _merge(parts: list[Part]) -> None:
    """Adjacent new parts of one section, or of sibling subsections (3.1, 3.2 of section 3: a representation
    developed over several subsections), that land on the same production are one contribution."""
    last: Part | None = None
    for p in parts:
        if p.status != "new":
            last = None if p.status == "new" else last
            continue
        siblings = last is not None and (last.section == p.section or (p.parent and last.parent == p.parent))
        if siblings and last.production == p.production:
            last.heading = f"{last.heading}; {p.heading}"
            last.sentences += p.sentences
            last.orders += p.orders
            last.equations += p.equations
            last.hyperparameters += p.hyperparameters
            last.claims += [c for c in p.claims if c not in last.claims]
            last.own_claims += p.own_claims
            last.more_sections += [x for x in [p.section, *p.more_sections]
                                   if x != last.section and x not in last.more_sections]
            p.status, p.why = "merged", f"part of {last.id} ({last.heading})"
            continue
        last = p
