"""Parts a paper states in words, built from its sentences into the grammar's typed terminals.

Most of what recent NeRF papers add around the field, on the data side or in the schedule is written in prose:
"a deformation network maps (x, t) into a canonical space" (D-NeRF Eqs. 2-3), "time-variant latent codes z_t"
(DyNeRF Eq. 2), "one learnable time offset per camera", "the two fields are blended by their densities" (NeRF-W
Eq. 10), "the inputs are fed to every layer", "separate branches for density and colour", "we sample rays by
importance" (DyNeRF's ray importance sampling), "we first train on keyframes" (DyNeRF's hierarchical training),
"the window is annealed over N iterations" (Nerfies Eq. 9). The equation compiler has nothing to bind them to; the
grammar has typed terminals for them (``docs/productions.md``). For a hole at FieldWrapper, PixelSampler,
ScheduleHook, Backbone or PosEncoding that the compiler left not implemented:

1. **Statements.** The hole's sentences (its text, its claim and the sentences of its sections) are searched for
   the statement patterns of each part of ``prose.yaml`` whose production is the hole's; a statement preceded by a
   negation ("we do not use a deformation network") is none.
2. **Parameters.** Each parameter of the part's terminal is, in this order: a person's correction
   (``equations.yaml``), fixed by the statement itself (``sets``, ``captures``), a number the paper states about
   the part (a pattern of the parameter in a sentence about the part's noun: the hole's sentences first, then the
   rest of the paper outside the introduction and related work), a named value the paper's sentences choose
   (``choices``), else the terminal's default, **asked**: listed under ``asked`` in ``equations.yaml`` with its
   unit, never guessed silently. Every stated value keeps the sentence it comes from.
3. **Placement.** The terminal joins the hole's set (FieldWrapper, ScheduleHook), is the hole's choice
   (PixelSampler), or sets the typed options of the terminal at the slot (the backbone, the space-time planes);
   the plan is checked after each part, and a part the grammar refuses there (a time wrapper on a plan without
   timestamps, a hook whose target the plan lacks) is taken out again, its reason the rule it broke.

The record (``source: prose``) quotes the statement and each stated parameter's sentence. Nothing here knows a
paper: the patterns are data, the terminals the registry's.
"""

from __future__ import annotations

import copy
import dataclasses
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns import runfolder
from nerfify_ns.synthesis.novel.implement import IMPLEMENTED, NOT_IMPLEMENTED, PARTLY, HoleResult
from nerfify_ns.synthesis.novel.notation import _short

SPEC_FILE = Path(__file__).with_name("prose.yaml")
PRODUCTIONS = ("FieldWrapper", "PixelSampler", "ScheduleHook", "Backbone", "PosEncoding")
GROUP_GAP = 15
"""Noun mentions closer than this (characters) are one phrase ("deformation field", "time embedding MLP")."""
MAX_SENTENCE = 2000


# ------------------------------------------------------------------------------------------ the spec
@dataclass
class ParamRule:
    name: str
    unit: str = ""
    patterns: list = field(default_factory=list)
    percent: bool = False
    choices: list = field(default_factory=list)          # (value, compiled pattern)
    only_when: dict = field(default_factory=dict)
    noun: re.Pattern | None = None
    required: str = ""
    sole: bool = False
    """A required choice the sentences do not make is the plan's only part among the choices (what a hook can
    reach): "we solely train the Gaussians for the first 3k iterations" freezes the one other part there is."""
    default_by: dict = field(default_factory=dict)
    """{other parameter: {its value: this one's default}}: a default that depends on what the part changes (an
    annealed noise ends at 0, a coarse-to-fine window at every frequency)."""
    named_only: tuple = ()
    """Choices taken only when a sentence names them, never as the plan's sole part (what exists only once a hook
    changes it: the window of the field's encoding)."""


@dataclass
class Part:
    name: str
    production: str
    terminal: str
    place: str
    statements: list
    noun: re.Pattern | None
    parameters: dict
    sets: dict = field(default_factory=dict)
    captures: list = field(default_factory=list)
    exact_unless: re.Pattern | None = None
    approximation: str = ""
    also: list = field(default_factory=list)
    companion: bool = False
    """Built only beside another stated part of its production (a backbone's size alone is no novel part)."""
    alternatives: list = field(default_factory=list)
    """Other terminals that build the same statement in another kind of model (a deformation of a field's samples,
    or of 3D Gaussians): the first of ``terminal`` and these the grammar accepts in the plan builds it."""


@dataclass
class Spec:
    negation: re.Pattern
    window: int
    out_of_scope: re.Pattern
    mentions: list                 # every noun pattern (the parts', their parameters', other networks')
    number_words: dict
    ordinal_words: dict
    parts: list
    tens_words: dict = field(default_factory=dict)
    scale_words: dict = field(default_factory=dict)
    kept_losses: tuple = ()          # productions of loss terms a hole is never refiled from (prose.yaml)


def _compile(pattern: str, spec_words: dict) -> re.Pattern:
    from nerfify_ns.paper.hyperparams import NUMBER

    counts = _word_number_pattern(spec_words)
    ordinals = "|".join(spec_words["ordinal_words"])
    text = (pattern.replace("{int}", r"(?P<num>\d+)(?!\d|\.\d)").replace("{num}", NUMBER)
            .replace("{count}", rf"(?<![\d.])(?P<num>\d+|{counts})(?![\w.-]*\d)")
            .replace("{ordinal}", rf"(?P<num>\d+(?:st|nd|rd|th)|{ordinals})"))
    return re.compile(text, re.IGNORECASE)


def _word_number_pattern(spec_words: dict) -> str:
    """A number written in words ("six", "sixty-four", "two hundred and fifty-six"): the spec's units and teens,
    tens joined to a unit by a hyphen or a space, hundreds and thousands (longest alternatives first)."""
    units = sorted(spec_words["number_words"], key=len, reverse=True)
    tens = sorted(spec_words.get("tens_words") or {}, key=len, reverse=True)
    unit = "|".join(units)
    below_100 = (rf"(?:(?:{'|'.join(tens)})(?:[- ](?:{unit}))?|{unit})" if tens else rf"(?:{unit})")
    scales = "|".join(sorted(spec_words.get("scale_words") or {}, key=len, reverse=True))
    if not scales:
        return below_100
    return rf"{below_100}(?:\s+(?:{scales})(?:\s+(?:and\s+)?{below_100})?)*"


def word_number(spec: Spec, text: str) -> int | None:
    """The value of a number written in words (see :func:`_word_number_pattern`); None when it is not one."""
    total, current, seen = 0, 0, False
    for token in re.split(r"[\s-]+", text.strip().lower()):
        if token == "and":
            continue
        if token in spec.number_words:
            current += int(spec.number_words[token])
        elif token in spec.tens_words:
            current += int(spec.tens_words[token])
        elif token in spec.scale_words:
            scale = int(spec.scale_words[token])
            if scale >= 1000:
                total, current = total + max(current, 1) * scale, 0
            else:
                current = max(current, 1) * scale
        else:
            return None
        seen = True
    return total + current if seen else None


@lru_cache(maxsize=1)
def load_spec(path: str = str(SPEC_FILE)) -> Spec:
    """The parts of ``prose.yaml``, their patterns compiled (numbers in every notation, as the hyperparameter
    reader reads them)."""
    data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    words = {key: dict(data.get(key) or {}) for key in ("number_words", "ordinal_words", "tens_words",
                                                         "scale_words")}
    comp = lambda p: _compile(p, words)  # noqa: E731
    parts, mentions = [], [comp(p) for p in data.get("other_nouns") or []]
    for entry in data["parts"]:
        params = {}
        for name, rule in (entry.get("parameters") or {}).items():
            rule = rule or {}
            params[name] = ParamRule(
                name, str(rule.get("unit", "")), [comp(p) for p in rule.get("patterns") or []],
                bool(rule.get("percent")), [(value, comp(p)) for value, p in (rule.get("choices") or {}).items()],
                dict(rule.get("only_when") or {}), comp(rule["noun"]) if rule.get("noun") else None,
                str(rule.get("required") or ""), bool(rule.get("sole")), dict(rule.get("default_by") or {}),
                tuple(rule.get("named_only") or ()))
            if params[name].noun is not None:
                mentions.append(params[name].noun)
        part = Part(entry["name"], entry["production"], entry["terminal"], entry["place"],
                    [comp(p) for p in entry["statements"]], comp(entry["noun"]) if entry.get("noun") else None,
                    params, dict(entry.get("sets") or {}), list(entry.get("captures") or []),
                    comp(entry["exact_unless"]) if entry.get("exact_unless") else None,
                    " ".join(str(entry.get("approximation") or "").split()), list(entry.get("also") or []),
                    bool(entry.get("companion")), list(entry.get("alternatives") or []))
        if part.noun is not None:
            mentions.append(part.noun)
        parts.append(part)
    return Spec(comp(data["negation"]), int(data["negation_window"]), comp(data["out_of_scope_sections"]),
                mentions, words["number_words"], words["ordinal_words"], parts, words["tens_words"],
                words["scale_words"], tuple(data.get("kept_losses") or ()))


# ------------------------------------------------------------------------------------------ sentences
@dataclass
class Sentence:
    text: str          # as the paper writes it
    flat: str          # inline math flattened, numbers read (what the patterns see)
    where: str
    section: str
    rank: int          # 0: the hole's own sentences, 1: the rest of the method
    order: int


def _flat(text: str) -> str:
    from nerfify_ns.paper.hyperparams import normalize_math

    try:
        flat = normalize_math(text[:MAX_SENTENCE])
    except Exception:  # noqa: BLE001 - a sentence the normaliser cannot read is searched as written
        flat = " ".join(text[:MAX_SENTENCE].split())
    return _GLUED.sub(r"\1 ", flat)


_GLUED = re.compile(r"(\d[kKM]?)(?=(?:iterations|steps|epochs|frames|layers|units|channels|neurons)\b)")
"""A number a flattened PDF glued to its unit ("300Kiterations"): separated."""


def _same_section(a: str, b: str) -> bool:
    a, b = (a or "").strip().lower(), (b or "").strip().lower()
    return bool(a and b) and (a == b or a.endswith(" " + b) or b.endswith(" " + a))


def hole_sentences(hole: dict, sentences: list, spec: Spec) -> list[Sentence]:
    """The hole's own sentences (rank 0: its text, its claim, the sentences of its sections), then the paper's
    other sentences outside the introduction, related work and conclusions (rank 1), in reading order."""
    from nerfify_ns.knowledge.sentences import split_sentences

    sections = [s for s in [hole.get("section", "")] + list(hole.get("sections") or []) if s]
    out: list[Sentence] = []
    seen: set = set()

    def add(text: str, where: str, section: str, rank: int) -> None:
        text = " ".join(str(text).split())
        key = text.lower()
        if len(text) < 8 or key in seen:
            return
        seen.add(key)
        out.append(Sentence(text, _flat(text), where, section, rank, len(out)))

    own_where = str(hole.get("where") or (f"Sec. {sections[0]}" if sections else ""))
    for text in split_sentences(str(hole.get("claim") or "")) + split_sentences(str(hole.get("text") or "")):
        add(text, own_where, sections[0] if sections else "", 0)
    rest = []
    for text, where, section in sentences:
        if any(_same_section(section, s) for s in sections):
            add(text, where, section, 0)
        elif not spec.out_of_scope.search(section or ""):
            rest.append((text, where, section))
    for text, where, section in rest:
        add(text, where, section, 1)
    return out


_CLAUSE_END = re.compile(r"[;:]|\.\s")
_RELATIVE = re.compile(r"\s*(?:which|that|whose)\b", re.IGNORECASE)
# what ends the noun phrase before a bracket: punctuation, a preposition, a verb of being, a conjunction
_NOUN_BEFORE = re.compile(r"[,;:]|\b(?:below|above|under|over|for|of|in|at|to|with|from|than|by|on|into|is|are|was|"
                          r"were|be|and|or)\b", re.IGNORECASE)


def _clause(text: str, start: int, end: int) -> tuple[int, int]:
    """The span of the clause of ``text`` that holds ``text[start:end]``: the brackets around it ("we prune voxels
    below a threshold (we anneal it linearly)": the anneal's clause names no encoding), with the words before them
    when the brackets open with a relative pronoun ("the threshold (which we anneal ...)"), else up to the nearest
    semicolon, colon or sentence end on either side."""
    opened: list[int] = []
    for i, ch in enumerate(text[:start]):
        if ch == "(":
            opened.append(i)
        elif ch == ")" and opened:
            opened.pop()
    if opened:
        close = text.find(")", end)
        if close >= 0 and "(" not in text[end:close]:
            if _RELATIVE.match(text, opened[-1] + 1):  # "the threshold (which we anneal ...)": what it refers to
                ends = [m.end() for m in _NOUN_BEFORE.finditer(text, 0, opened[-1])]
                return (ends[-1] if ends else 0), close
            return opened[-1] + 1, close
    before = [m.end() for m in _CLAUSE_END.finditer(text, 0, start)]
    after = _CLAUSE_END.search(text, end)
    return (before[-1] if before else 0, after.start() if after else len(text))


# ------------------------------------------------------------------------------------------ reading
@dataclass
class Statement:
    part: Part
    sentence: Sentence
    match: re.Match
    pattern: int


def _negated(spec: Spec, flat: str, start: int) -> bool:
    before = flat[max(0, start - spec.window):start]
    before = re.split(r"[;.!?]", before)[-1]
    return bool(spec.negation.search(before))


_CITATION = re.compile(r"\[\d+(?:\s*[,–-]\s*\d+)*\]|\bet al\.")
"""A sentence that cites other work describes that work: it states no part of the paper's own outside the hole."""


def statements(part: Part, scope: list[Sentence], spec: Spec, rank: int = 0) -> list[Statement]:
    """Every sentence of ``rank`` (0: the hole's own; 1: the rest of the method, sentences citing other work left
    out) that states ``part``, with its first match."""
    found = []
    for s in scope:
        if s.rank != rank or (rank > 0 and _CITATION.search(s.text)):
            continue
        for k, pattern in enumerate(part.statements):
            m = next((m for m in pattern.finditer(s.flat) if not _negated(spec, s.flat, m.start())), None)
            if m is not None:
                found.append(Statement(part, s, m, k))
                break
    return found


def _groups(spec: Spec, flat: str) -> list[tuple[int, int]]:
    """The noun phrases of a sentence: mentions of any part's or network's noun, those closer than GROUP_GAP
    merged (spans)."""
    spans = sorted((m.start(), m.end()) for p in spec.mentions for m in p.finditer(flat))
    groups: list[list[int]] = []
    for a, b in spans:
        if groups and a - groups[-1][1] <= GROUP_GAP:
            groups[-1][1] = max(groups[-1][1], b)
        else:
            groups.append([a, b])
    return [(a, b) for a, b in groups]


def _belongs(spec: Spec, noun: re.Pattern | None, flat: str, m: re.Match) -> bool:
    """A number belongs to the part whose noun is in its own match, or in the nearest noun phrase before it (the
    first one after it when none precedes)."""
    if noun is None:
        return False
    if noun.search(m.group(0)):
        return True
    groups = _groups(spec, flat)
    before = [g for g in groups if g[1] <= m.start()]
    after = [g for g in groups if g[0] >= m.end()]
    group = before[-1] if before else (after[0] if after else None)
    return group is not None and bool(noun.search(flat[group[0]:group[1]]))


def _number(spec: Spec, m: re.Match, percent: bool) -> Any:
    from nerfify_ns.paper.hyperparams import parse_number

    raw = (m.groupdict().get("num") or "").strip()
    low = raw.lower()
    if low in spec.number_words:
        return spec.number_words[low]
    if re.fullmatch(r"[a-z][a-z\s-]*", low) and (worded := word_number(spec, low)) is not None:
        return worded
    if low in spec.ordinal_words:
        return spec.ordinal_words[low]
    raw = re.sub(r"(?<=\d)(?:st|nd|rd|th)$", "", raw)
    try:
        value = parse_number(raw)
    except (ValueError, OverflowError):
        return None
    if isinstance(value, list):
        return None
    if percent and "%" in m.string[m.end("num"):m.end("num") + 3]:
        value = value / 100.0
    return value


def _coerce(spec_param: Any, value: Any) -> tuple[Any, str]:
    """``value`` as the terminal's parameter takes it, or (None, why not)."""
    kind = getattr(spec_param, "type", "")
    lo, hi = (spec_param.range or (None, None)) if spec_param is not None else (None, None)
    if kind == "bool":
        return (value, "") if isinstance(value, bool) else (None, f"{value!r} is not true or false")
    if kind in ("str", "enum"):
        allowed = getattr(spec_param, "values", ()) or ()
        if not isinstance(value, str) or (allowed and value not in allowed):
            return None, f"{value!r} is not one of {', '.join(map(str, allowed))}"
        return value, ""
    if isinstance(value, bool):
        return None, f"{value!r} is not a number"
    if kind.endswith("_list") and not isinstance(value, list):
        value = [value]
    items = value if isinstance(value, list) else [value]
    out = []
    for item in items:
        if not isinstance(item, int | float):
            return None, f"{item!r} is not a number"
        if "int" in str(kind):
            if float(item) != int(item):
                return None, f"{item} is not a whole number"
            item = int(item)
        if (lo is not None and item < lo) or (hi is not None and item > hi):
            return None, f"{item} is outside the terminal's range [{lo}, {hi}]"
        out.append(item)
    return (out if isinstance(value, list) else out[0]), ""


@dataclass
class Choice:
    value: Any
    source: str                    # statement | paper | correction | asked | not used
    quote: str = ""
    where: str = ""
    unit: str = ""
    why: str = ""

    def to_dict(self) -> dict:
        return {k: v for k, v in (("value", self.value), ("source", self.source), ("quote", self.quote),
                                  ("where", self.where), ("unit", self.unit), ("why", self.why)) if v not in ("", None)
                or k == "value"}


class _Reader:
    def __init__(self, part: Part, found: list[Statement], scope: list[Sentence], spec: Spec, corrected: dict,
                 base: dict | None = None, plan: Any = None):
        from nerfify_ns.registry import default_registry

        self.plan = plan
        """The plan the part joins (what a ``sole`` choice chooses among)."""

        self.part, self.found, self.scope, self.spec, self.corrected = part, found, scope, spec, corrected
        self.base = base if part.place == "options" and isinstance(base, dict) else {}
        """The options already at the slot (the base's backbone): what an unstated size stays at."""
        self.params = default_registry()[part.terminal].param_specs
        self.choices: dict[str, Choice] = {}
        self.problems: list[str] = []
        self.missing: list[str] = []       # a required parameter the paper's statement does not name

    def quote(self, s: Sentence) -> str:
        return _short(s.text, 220)

    def run(self) -> dict[str, Choice]:
        first = self.found[0]
        names = list(self.part.parameters)
        for name, value in self.part.sets.items():
            self.set(name, value, "statement", first.sentence)
        for cap in self.part.captures:
            st = next((s for s in self.found if s.pattern == cap.get("pattern")), None)
            if st is None or cap["param"] in self.choices:
                continue
            value = _number(self.spec, st.match, False)
            if isinstance(value, int | float):
                value = value + int(cap.get("offset", 0))
                self.set(cap["param"], [value] if cap.get("list") else value, "statement", st.sentence)
        for name in sorted(names, key=lambda n: bool(self.part.parameters[n].only_when)):
            if name in self.choices:
                continue
            rule = self.part.parameters[name]
            if rule.only_when and any(self.value(k) != v for k, v in rule.only_when.items()):
                self.choices[name] = Choice(self.default(name), "not used", unit=rule.unit, why=(
                    "used only when " + ", ".join(f"{k} is {v}" for k, v in rule.only_when.items())))
                continue
            if rule.choices and self.choose(rule):
                continue
            if rule.patterns and self.number(rule):
                continue
            if rule.sole and not self.corrected_value(name) and self.sole(rule):
                continue
            if rule.required and not self.corrected_value(name):
                self.missing.append(f"{rule.required} (\"{_short(first.sentence.text, 160)}\", "
                                    f"{first.sentence.where})")
                continue
            self.choices[name] = Choice(self.default(name), "asked", unit=rule.unit,
                                        why="the paper does not state it: the base plan's value, to be confirmed "
                                            "in equations.yaml (asked)" if name in self.base else
                                        "the paper does not state it: the terminal's default, to be confirmed "
                                        "in equations.yaml (asked)")
        for name in self.corrected:  # a person's value where it differs from what was read (or asked)
            if name in self.params and (name not in self.choices or self.choices[name].value != self.corrected[name]):
                self.corrected_value(name)
        return self.choices

    # -------------------------------------------------------------- sources of a value
    def set(self, name: str, value: Any, source: str, sentence: Sentence | None) -> bool:
        value, why = _coerce(self.params.get(name), value)
        if value is None:
            if sentence is not None:
                self.problems.append(f"{name}: the paper's value is not usable ({why})")
            return False
        rule = self.part.parameters.get(name)
        self.choices[name] = Choice(value, source, self.quote(sentence) if sentence else "",
                                    sentence.where if sentence else "", rule.unit if rule else "")
        return True

    def corrected_value(self, name: str) -> bool:
        if name not in self.corrected:
            return False
        value, why = _coerce(self.params.get(name), self.corrected[name])
        if value is None:
            self.problems.append(f"{name}: the value in equations.yaml is not usable ({why})")
            return False
        rule = self.part.parameters.get(name)
        was = self.choices.get(name)
        if was is not None and was.value == value:
            return True
        self.choices[name] = Choice(value, "correction", where=runfolder.EQUATIONS, unit=rule.unit if rule else "",
                                    why=f"set in equations.yaml (read: {was.value!r}, {was.source})" if was else
                                    "set in equations.yaml")
        return True

    def choose(self, rule: ParamRule) -> bool:
        noun = rule.noun or self.part.noun
        choices = rule.choices
        if rule.sole and isinstance(self.plan, dict):  # the choices are parts of the plan: only those it holds
            from nerfify_ns.registry.terminals.training import schedulable_parts

            held = schedulable_parts(self.plan)
            choices = [(value, pattern) for value, pattern in choices if value in held]
        if rule.required:  # what the statement acts on is named in its own clause, not elsewhere in the paper
            pool = [(st.sentence, _clause(st.sentence.flat, st.match.start(), st.match.end())) for st in self.found]
        else:
            statement_sentences = [st.sentence for st in self.found]
            own = [s for s in self.scope if s.rank == 0 and s not in statement_sentences]
            rest = [s for s in self.scope if s.rank > 0 and noun is not None and noun.search(s.flat)]
            # the statements, the hole's sentences, then about its noun
            pool = [(s, (0, len(s.flat))) for s in statement_sentences + own + rest]
        for s, (start, end) in pool:
            for value, pattern in choices:
                m = pattern.search(s.flat, start, end)
                if m is not None and not _negated(self.spec, s.flat, m.start()):
                    return self.set(rule.name, value, "paper", s)
        return False

    def sole(self, rule: ParamRule) -> bool:
        """The rule's one choice the plan holds (a part a schedule hook can reach), when there is exactly one."""
        from nerfify_ns.registry.terminals.training import schedulable_parts

        held = schedulable_parts(self.plan) if isinstance(self.plan, dict) else set()
        options = [value for value, _ in rule.choices if value in held and value not in rule.named_only]
        if len(options) != 1:
            return False
        value, _ = _coerce(self.params.get(rule.name), options[0])
        if value is None:
            return False
        self.choices[rule.name] = Choice(value, "plan", unit=rule.unit, why=(
            f"the paper's sentence names no part; {value} is the plan's only part among "
            f"{', '.join(v for v, _ in rule.choices)}"))
        return True

    def number(self, rule: ParamRule) -> bool:
        noun = rule.noun or self.part.noun
        stating = {id(st.sentence) for st in self.found}  # the sentences that state the part first
        spans = {id(st.sentence): (st.match.start(), st.match.end()) for st in self.found}
        for s in sorted(self.scope, key=lambda x: (x.rank, id(x) not in stating, x.order)):
            for pattern in rule.patterns:
                for m in pattern.finditer(s.flat):
                    span = spans.get(id(s))  # a number inside the statement's own words is the part's
                    inside = span is not None and span[0] <= m.start("num") < span[1]
                    if not inside and not _belongs(self.spec, noun, s.flat, m):
                        continue
                    value = _number(self.spec, m, rule.percent)
                    if value is None:
                        continue
                    coerced, _ = _coerce(self.params.get(rule.name), value)
                    if coerced is None:  # a number of the sentence the terminal cannot take: not this one
                        continue
                    return self.set(rule.name, coerced, "paper", s)
        return False

    def value(self, name: str) -> Any:
        return self.choices[name].value if name in self.choices else self.default(name)

    def default(self, name: str) -> Any:
        if name in self.base:
            return copy.deepcopy(self.base[name])
        rule = self.part.parameters.get(name)
        for other, table in (rule.default_by if rule else {}).items():
            if other in self.choices and self.choices[other].value in table:
                return copy.deepcopy(table[self.choices[other].value])
        spec = self.params.get(name)
        return copy.deepcopy(spec.default) if spec is not None else None


# ------------------------------------------------------------------------------------------ building
@dataclass
class ProseResult(HoleResult):
    """A hole built from the paper's sentences: which terminals, their parameters with the sentence of each, the
    parameters asked, and the plan paths it placed (with what stood there, to take it out again)."""

    parts: list = field(default_factory=list)
    asked: dict = field(default_factory=dict)
    placed: list = field(default_factory=list)       # (path, previous value or None)

    def to_dict(self) -> dict:
        out = super().to_dict()
        out["source"] = "prose"
        out["prose"] = self.parts
        out["asked"] = self.asked
        return out


def _corrections(corr: dict) -> dict[str, dict]:
    """part name -> {parameter: value} from a person's equations.yaml (``asked`` and the ``prose`` parts)."""
    out: dict[str, dict] = {}
    for entry in corr.get("prose") or []:
        if isinstance(entry, dict) and isinstance(entry.get("parameters"), dict):
            for name, choice in entry["parameters"].items():
                if isinstance(choice, dict) and choice.get("source") in ("correction", "asked", "paper", "statement"):
                    out.setdefault(str(entry.get("part")), {})[str(name)] = choice.get("value")
    for key, entry in (corr.get("asked") or {}).items():
        part, _, name = str(key).partition(".")
        value = entry.get("value") if isinstance(entry, dict) else entry
        out.setdefault(part, {})[name] = value
    return out


def _snapshot(plan: Any) -> dict:
    return copy.deepcopy(dict(plan))


def _restore(plan: Any, data: dict) -> None:
    plan.clear()
    plan.update(copy.deepcopy(data))


def _terminal_at(plan: Any, slot: str) -> str | None:
    from nerfify_ns.grammar import derive

    try:
        return derive(plan).used.get(slot)
    except Exception:  # noqa: BLE001 - a plan the grammar cannot derive has no terminal there
        return None


def _options_path(plan: Any, slot: str, terminal: str) -> str:
    """Where the options of ``terminal`` at ``slot`` are: the slot itself for a production of one terminal (the
    backbone's MLP), ``slot.terminal`` for a slot that chooses among terminals (an encoding)."""
    return slot if _terminal_at(plan, slot) is not None else f"{slot}.{terminal}"


def _violations(plan: Any) -> list:
    from nerfify_ns.grammar import check

    return list(check(plan))


def _place(part: Part, slot: str, params: dict, plan: Any, notes: list) -> list[tuple[str, Any]]:
    """Write the part into the plan; the paths written with what stood there."""
    written = []
    if part.place == "member":
        path = f"{slot}.{part.terminal}"
        before = copy.deepcopy(plan.get(path))
        plan.set(path, {**(before if isinstance(before, dict) else {}), **params})
        written.append((path, before))
        _order_members(plan.get(slot))
    elif part.place == "choice":
        before = copy.deepcopy(plan.get(slot))
        plan.set(slot, {part.terminal: params})
        written.append((slot, before))
    else:  # options of the terminal at the slot
        path = _options_path(plan, slot, part.terminal)
        node = plan.get(path)
        if not isinstance(node, dict) or _terminal_at(plan, path) != part.terminal:
            chosen = plan.get(slot)
            used = _terminal_at(plan, slot) or (next(iter(chosen), None) if isinstance(chosen, dict) else None)
            raise ValueError(f"the plan's {slot} is {used or 'absent'}, not the {part.terminal} terminal whose "
                             "typed options state this")
        before = copy.deepcopy(node)
        node.update(params)
        written.append((path, before))
    parent = slot.rsplit(".", 1)[0]
    for also in part.also:
        path = f"{parent}.{also['slot']}"
        if _terminal_at(plan, path) != also["terminal"]:
            before = copy.deepcopy(plan.get(path))
            plan.set(path, {also["terminal"]: {}})
            written.append((path, before))
            notes.append(" ".join(str(also.get("note", "")).split()) or f"{path}: {also['terminal']}")
    return written


def _variant(part: Part, slot: str, plan: Any) -> Part:
    """``part`` with the first of its terminals (its own, then ``alternatives``) that the grammar accepts at
    ``slot`` in ``plan`` (tried at its defaults, the plan left as it was); its own when none is."""
    if not part.alternatives or part.place != "member":
        return part
    standing = {str(v) for v in _violations(plan)}
    for terminal in [part.terminal, *part.alternatives]:
        candidate = dataclasses.replace(part, terminal=terminal)
        before = _snapshot(plan)
        try:
            _place(candidate, slot, {}, plan, [])
            accepted = not [v for v in _violations(plan) if str(v) not in standing]
        except Exception:  # noqa: BLE001 - refused here; the next terminal is tried
            accepted = False
        _restore(plan, before)
        if accepted:
            return candidate
    return part


def _order_members(members: Any) -> None:
    """Members of a set applied in order (the field's conditioners): a member whose contract writes the samples'
    times (a per-camera time offset) before the members that read them, so that what it writes is read; the
    others keep their order."""
    from nerfify_ns.registry import default_registry

    if not isinstance(members, dict):
        return
    registry = default_registry()

    def writes_times(name: str) -> bool:
        try:
            return name in registry.terminals and "times" in registry[name].contract.outputs
        except Exception:  # noqa: BLE001 - a member without a contract keeps its place
            return False

    ordered = sorted(members.items(), key=lambda kv: not writes_times(str(kv[0])))
    members.clear()
    members.update(ordered)


def build(hole: dict, sentences: list, plan: Any, corr: dict | None, compiled: HoleResult) -> HoleResult:
    """The hole built from its sentences (a ProseResult, the plan changed in place), or ``compiled`` unchanged
    when the compiler implemented it or no sentence of the hole states a typed part. A part of the hole's own
    production is looked for first; a hole the derivation filed under another production (an encoding) whose own
    sentences state a typed part of one of PRODUCTIONS is placed there, and its record says so (never a loss term's
    hole: ``kept_losses``)."""
    if compiled.status != NOT_IMPLEMENTED or not hole.get("slot"):
        return compiled
    spec = load_spec()
    scope = hole_sentences(hole, sentences, spec)
    slot, production = hole["slot"], hole["production"]
    stated = _stated_parts(spec, production, scope)
    refiled = ""
    others = [p for p in PRODUCTIONS if p != production] if production not in spec.kept_losses else []
    for other in others if not stated else []:
        # the derivation filed the part elsewhere, but its own sentences state a typed part of another production
        # (one the plan does not hold yet: a member another part already built is that part's, and a sentence here
        # that names it, "motion can be encoded by deforming points ...", does not make this part the same one)
        other_slot = _slot_in(plan, other)
        stated = [(p, found) for p, found in _stated_parts(spec, other, scope)
                  if not (p.place == "member" and other_slot and plan.get(f"{other_slot}.{p.terminal}") is not None)]
        if stated and other_slot:
            refiled, slot = other, other_slot
            break
        stated = []
    elsewhere = _stated_elsewhere(spec, refiled or production, scope, stated) if stated else []
    if not stated:
        return compiled
    if refiled:
        _refile_hole(plan, hole, refiled, slot)
    corrected = _corrections(corr or {})
    res = ProseResult(id=compiled.id, slot=compiled.slot, production=compiled.production, section=compiled.section,
                      equations=compiled.equations, hash=compiled.hash)
    if compiled.reason:
        res.notes.append(f"the equation compiler: {_short(compiled.reason, 300)}")
    if refiled:
        res.notes.append(f"placed as {refiled} at {slot}: the derivation filed the part under {production} at "
                         f"{hole['slot']}, but its sentences state a part of {refiled} (below)")
        res.production, res.slot = refiled, slot
    built, refused, approximate = [], [], []
    for stated_part, found in stated + elsewhere:
        optional = (stated_part, found) in elsewhere
        part = _variant(stated_part, slot, plan)
        base = plan.get(_options_path(plan, slot, part.terminal)) if part.place == "options" else None
        reader = _Reader(part, found, scope, spec, corrected.get(part.name, {}), base, plan)
        choices = reader.run()
        st = found[0]
        record = {"part": part.name, "terminal": part.terminal,
                  "statement": {"quote": _short(st.sentence.text, 220), "where": st.sentence.where,
                                "matched": _short(st.match.group(0), 120)},
                  "parameters": {k: c.to_dict() for k, c in choices.items()}}
        if optional:
            record["statement"]["elsewhere"] = ("stated in the method outside the hole's section: a part of the same "
                                                "production the hole's slot takes")
        if reader.missing and optional:
            res.notes.append(f"{part.terminal} stated at {st.sentence.where}, not built: {'; '.join(reader.missing)}")
            continue
        if reader.missing:
            record["status"] = NOT_IMPLEMENTED
            record["reason"] = "; ".join(reader.missing)
            refused.append(record)
            res.parts.append(record)
            continue
        params = {k: c.value for k, c in choices.items() if c.source != "not used"}
        if part.place == "member" or part.place == "choice":  # the unused ones at their defaults, written out
            params.update({k: c.value for k, c in choices.items() if c.source == "not used"})
        before = _snapshot(plan)
        standing = {str(v) for v in _violations(plan)}
        notes: list[str] = []
        try:
            written = _place(part, slot, params, plan, notes)
            broken = [v for v in _violations(plan) if str(v) not in standing]
        except Exception as err:  # noqa: BLE001 - this part's reason; the others are still built
            written, broken = [], [f"{type(err).__name__}: {err}"]
        if broken and optional:
            _restore(plan, before)
            res.notes.append(f"{part.terminal} stated at {st.sentence.where}, not built: the grammar refuses it here: "
                             + "; ".join(_short(str(v), 200) for v in broken[:2]))
            continue
        if broken:
            _restore(plan, before)
            record["status"] = NOT_IMPLEMENTED
            record["reason"] = "the grammar refuses it in this plan: " + "; ".join(
                _short(str(v), 240) for v in broken[:3])
            refused.append(record)
            res.parts.append(record)
            continue
        res.placed.extend(written)
        record["placed"] = [p for p, _ in written]
        record["notes"] = notes + reader.problems
        exact = part.exact_unless is None or any(part.exact_unless.search(s.flat) for s in scope if s.rank == 0)
        if not exact:
            record["approximation"] = part.approximation
            approximate.append(record)
        record["status"] = IMPLEMENTED if exact else PARTLY
        for name, c in choices.items():
            if c.source == "asked":
                res.asked[f"{part.name}.{name}"] = {"value": c.value, "terminal": part.terminal,
                                                     "unit": c.unit, "why": c.why}
        built.append(record)
        res.parts.append(record)
    res.status = (IMPLEMENTED if built and not refused and not approximate else PARTLY if built else NOT_IMPLEMENTED)
    res.reason = _reason(built, refused, approximate, res.asked)
    if built:
        res.component = {"source": "prose", "terminals": [r["terminal"] for r in built],
                         "implements": [f"{r['statement']['where']}: \"{_short(r['statement']['quote'], 120)}\""
                                        for r in built],
                         "evidence": _short("; ".join(r["statement"]["quote"] for r in built), 300),
                         "stands_in": "built from the paper's sentences: " + ", ".join(
                             f"{r['terminal']} at {', '.join(r['placed'])}" for r in built)}
        res.checks["component"] = ("typed terminals of the registry: their contracts are checked by the ladder's "
                                   "contract rung like every terminal's")
    return res


def _stated_parts(spec: Spec, production: str, scope: list[Sentence]) -> list[tuple[Part, list[Statement]]]:
    """The parts of ``production`` the hole's sentences state (a choice's first one only, in the spec's order; a
    companion only beside another stated part)."""
    stated = [(p, found) for p in spec.parts if p.production == production and (found := statements(p, scope, spec))]
    if not any(not p.companion for p, _ in stated):
        return []
    return stated[:1] if stated and stated[0][0].place == "choice" else stated


def _stated_elsewhere(spec: Spec, production: str, scope: list[Sentence],
                      stated: list) -> list[tuple[Part, list[Statement]]]:
    """Members of a set production (field wrappers, schedule hooks) that the rest of the method states outside the
    hole's section, in sentences citing no other work: one hole stands for the production's slot, and a paper
    describes each of its members in a section of its own. A part already stated by the hole is not repeated;
    one that cannot be built there is left out (a note), not refused."""
    have = {p.name for p, _ in stated}
    return [(p, found) for p in spec.parts if p.production == production and p.place == "member"
            and not p.companion and p.name not in have and (found := statements(p, scope, spec, rank=1))]


def _refile_hole(plan: Any, hole: dict, production: str, slot: str) -> None:
    """The plan's hole entry moves to the production its sentences state (with where the derivation had filed
    it), so that the records, the report and the survey name the part's real production."""
    for h in plan.get("holes") or []:
        if isinstance(h, dict) and h.get("slot") == hole.get("slot") and h.get("production") == hole.get(
                "production"):
            h["filed_as"] = {"production": h["production"], "slot": h["slot"]}
            h["production"], h["slot"] = production, slot


def _slot_in(plan: Any, production: str) -> str:
    """The plan's slot of ``production``: a path of the grammar that the plan holds, else one whose parent it
    holds ('' when the plan has neither: the base has no such part)."""
    from nerfify_ns.grammar import load_grammar

    paths = [p for p, s in load_grammar().symbol_paths() if s == production]
    held = [p for p in paths if plan.get(p) is not None]
    parent = [p for p in paths if "." not in p or plan.get(p.rsplit(".", 1)[0]) is not None]
    return (held or parent or [""])[0]


def _reason(built: list, refused: list, approximate: list, asked: dict) -> str:
    out = []
    if built:
        out.append("built from the paper's sentences: " + "; ".join(
            f"{r['terminal']} ({_stated(r)})" for r in built))
    for r in approximate:
        out.append(f"{r['terminal']}: an approximation ({r['approximation']})")
    for r in refused:
        out.append(f"{r['terminal']} not built: {r['reason']}")
    if asked:
        out.append(f"{len(asked)} parameter(s) the paper does not state, asked in equations.yaml: "
                   + ", ".join(sorted(asked)))
    return "; ".join(out)


def _stated(record: dict) -> str:
    stated = [f"{k} {v['value']}" for k, v in record["parameters"].items() if v["source"] in ("paper", "statement",
                                                                                            "correction")]
    return ", ".join(stated) if stated else "stated, no size given"


def revert(plan: Any, result: HoleResult) -> bool:
    """Take a prose-built hole's terminals out of ``plan`` again (what stood at each path is put back)."""
    placed = getattr(result, "placed", None)
    if not placed:
        return False
    for path, before in reversed(placed):
        if before is None:
            plan.delete(path)
        else:
            plan.set(path, copy.deepcopy(before))
    return True
