"""Reading a paper's sentences in context: section roles, prior-work and usage cues (sentences split by
``nerfify_ns.sentence_split``).

Shared by technique detection (``detect.py``) and citation recovery (``citations.py``). The rules
are data (``detect.yaml``). A paper is any object shaped like ``nerfify_ns.paper.Document``
(``title``, ``abstract``, ``sections`` with ``paragraphs``, ``equations``): the knowledge package
imports nothing from the paper package, it only reads those attributes.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns.knowledge.errors import KnowledgeError
from nerfify_ns.sentence_split import split_sentences  # noqa: F401  (the package's one splitter, re-exported)

DETECT_FILE = Path(__file__).resolve().parent / "detect.yaml"

@dataclass(frozen=True)
class Rules:
    """The compiled contents of ``detect.yaml``."""

    section_roles: tuple[tuple[str, re.Pattern], ...]
    context_weights: dict
    signal_weights: dict
    used_threshold: float
    prior: tuple[re.Pattern, ...]
    usage: tuple[re.Pattern, ...]
    own: tuple[re.Pattern, ...]
    contrast: tuple[re.Pattern, ...]
    comparison: tuple[re.Pattern, ...]
    hyperparameter_cards: dict
    metric: tuple[re.Pattern, ...] = ()      # a sentence that measures results (an evaluation metric named)
    objective: tuple[re.Pattern, ...] = ()   # ... unless it speaks of training (a loss, an objective, minimising)
    table: tuple[re.Pattern, ...] = ()       # a table's rows flattened into the text: results wherever they are
    scene_cues: tuple = ()   # (flag, value, (pattern, ...)) per scene fact a paper can state
    experiment_details: re.Pattern | None = None   # a subsection of the experiments that is the method's details


def load_rules(path: str | None = None) -> Rules:
    """The detection rules: the default knowledge base's, or those of the file ``path`` (read now)."""
    if path is not None:
        return read_rules(path)
    from nerfify_ns.knowledge.kb import KnowledgeBase

    return KnowledgeBase.default().rules


def _rules(rules: Rules | None) -> Rules:
    return rules if rules is not None else load_rules()


def read_rules(path: Path | str = DETECT_FILE) -> Rules:
    """The compiled contents of a ``detect.yaml`` (read now: no cache; a ``KnowledgeBase`` keeps them)."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
        cues = data["cues"]

        def comp(items: list) -> tuple[re.Pattern, ...]:
            return tuple(re.compile(p, re.IGNORECASE) for p in items)

        hp_cards = {k: ([v] if isinstance(v, str) else list(v)) for k, v in data["hyperparameter_cards"].items()}
        return Rules(
            section_roles=tuple((r["role"], re.compile(r["pattern"], re.IGNORECASE)) for r in data["section_roles"]),
            context_weights=dict(data["context_weights"]), signal_weights=dict(data["signal_weights"]),
            used_threshold=float(data["used_threshold"]), prior=comp(cues["prior"]), usage=comp(cues["usage"]),
            own=comp(cues["own"]),
            contrast=comp(cues["contrast"]), comparison=comp(cues["comparison"]), hyperparameter_cards=hp_cards,
            metric=comp(cues.get("metric") or []), objective=comp(cues.get("objective") or []),
            table=comp(cues.get("table") or []),
            scene_cues=tuple((str(flag), spec["value"], comp(spec["patterns"]))
                             for flag, spec in (data.get("scene_cues") or {}).items()),
            experiment_details=re.compile(data["experiment_details"], re.IGNORECASE)
            if data.get("experiment_details") else None)
    except (OSError, KeyError, TypeError, re.error, yaml.YAMLError) as exc:
        raise KnowledgeError(f"{path}: cannot read the detection rules ({exc}); fix detect.yaml") from exc


def heading_role(heading: str, rules: Rules | None = None) -> str | None:
    """The role a heading names by itself (``detect.yaml: section_roles``, first rule that matches), or None."""
    heading = heading.strip().lower()
    return next((role for role, pat in _rules(rules).section_roles if pat.search(heading)), None)


def section_roles(doc: Any, rules: Rules | None = None) -> dict[int, str]:
    """The role of every section of ``doc`` (by index): prior, method, experiments, conclusion, ignore."""
    rules = _rules(rules)
    roles: dict[int, str] = {}
    stack: list[tuple[int, str, str]] = []  # (level, number, role)
    flat = ""  # the role of the last unnumbered top-level section (an extraction whose headings carry no numbers)
    for i, s in enumerate(doc.sections):
        heading = (getattr(s, "title", "") or "").strip().lower()
        own = heading_role(heading, rules)
        level = getattr(s, "level", 1) or 1
        number = getattr(s, "number", "") or ""
        while stack and (stack[-1][0] >= level or (number and stack[-1][1] and "." in number
                                                     and not number.startswith(stack[-1][1] + "."))):
            stack.pop()  # "4.1" is not under "3" when the extraction lost the heading "4"
        parent = stack[-1][2] if stack else None
        if parent is None and "." in number:  # "2.1" under "2" even when levels are flat
            prefix = number.rsplit(".", 1)[0]
            parent = next((roles[j] for j in range(i - 1, -1, -1) if doc.sections[j].number == prefix), None)
        if parent is None and not number and level == 1 and own is None and flat == "experiments":
            parent = flat  # "Dehazing Scene Reconstruction" after "Experiments and Results", both unnumbered
        role = own or parent or "method"
        if not number and level == 1:
            flat = role
        if parent == "prior" and role == "method":
            role = "prior"  # a subsection of related work describes others' methods, whatever its heading says
        if parent == "experiments" and role == "method" and not (
                rules.experiment_details is not None and rules.experiment_details.search(heading)):
            role = "experiments"  # "4.1 Rendering" under the experiments reports results, whatever its heading says
        roles[i] = role
        stack.append((level, number, role))
    return roles


def _clause_spans(sentence: str, patterns: tuple[re.Pattern, ...]) -> list[tuple[int, int]]:
    spans = []
    for pat in patterns:
        for m in pat.finditer(sentence):
            end = re.search(r"[,;:.]|\s--\s", sentence[m.end():])
            spans.append((m.start(), m.end() + (end.start() if end else len(sentence) - m.end())))
    return spans


@dataclass(frozen=True)
class SentenceContext:
    """How a sentence speaks about techniques: its section role and cues."""

    role: str
    prior: bool
    usage: bool
    comparison: bool
    contrast_spans: tuple[tuple[int, int], ...]
    own: bool = False
    metric: bool = False
    """The sentence measures results with an evaluation metric and says nothing of training ("we also compute the
    mean absolute error of the intensities"), or is a table's rows flattened into the text: a technique it names is
    a metric or a compared method there, not a part of the method."""
    context_weights: dict = field(default_factory=dict, compare=False, repr=False)

    def in_contrast(self, start: int, end: int) -> bool:
        return any(a <= start and end <= b + 1 for a, b in self.contrast_spans)

    def use_weight(self, start: int = 0, end: int = 0) -> float:
        """How much a mention at [start, end) counts as the paper using the technique (0 = mention only)."""
        weights = self.context_weights or load_rules().context_weights
        if self.role == "ignore" or self.metric or (end > start and self.in_contrast(start, end)):
            return 0.0
        if self.role == "prior":
            return 0.8 if self.own and not self.prior else 0.0
        if self.prior and not self.usage:
            return 0.0
        if self.role == "experiments":
            if self.usage:
                return 0.8
            return 0.0 if self.comparison else weights["experiments"]
        return float(weights.get(self.role, 1.0))


def read_sentence(sentence: str, role: str, rules: Rules | None = None) -> SentenceContext:
    """How ``sentence`` (in a section of ``role``) speaks about techniques, by the cues of ``rules``."""
    rules = _rules(rules)
    return SentenceContext(role=role, prior=any(p.search(sentence) for p in rules.prior),
                           usage=any(p.search(sentence) for p in rules.usage),
                           comparison=any(p.search(sentence) for p in rules.comparison),
                           contrast_spans=tuple(_clause_spans(sentence, rules.contrast)),
                           own=any(p.search(sentence) for p in rules.own),
                           metric=(any(p.search(sentence) for p in rules.metric)
                                   and not any(p.search(sentence) for p in rules.objective))
                           or any(p.search(sentence) for p in rules.table),
                           context_weights=rules.context_weights)


@dataclass(frozen=True)
class Unit:
    """One sentence of the paper with where it is."""

    text: str
    section: str
    role: str
    page: int | None
    line: int | None
    order: int
    context: SentenceContext


def _loc(loc: Any) -> tuple[int | None, int | None, int]:
    if loc is None:
        return None, None, 0
    return getattr(loc, "page", None), getattr(loc, "line", None), getattr(loc, "order", 0) or 0


def sentences(doc: Any, rules: Rules | None = None) -> Iterator[Unit]:
    """Every sentence of the title, abstract, headings and paragraphs, in reading order, with its role."""
    rules = _rules(rules)
    if doc.title:
        page = 1 if getattr(doc, "kind", "") == "pdf" else None
        yield Unit(doc.title, "", "title", page, None if page else 1, 0, read_sentence(doc.title, "title", rules))
    for s in split_sentences(doc.abstract or ""):
        yield Unit(s, "Abstract", "abstract", 1 if getattr(doc, "kind", "") == "pdf" else None, None, 0,
                   read_sentence(s, "abstract", rules))
    roles = section_roles(doc, rules)
    for i, sec in enumerate(doc.sections):
        role = roles[i]
        if role == "ignore":
            continue
        page, line, order = _loc(sec.loc)
        if sec.heading:
            yield Unit(sec.heading, sec.heading, role, page, line, order, read_sentence(sec.heading, role, rules))
        for p in sec.paragraphs:
            page, line, order = _loc(p.loc)
            for s in split_sentences(p.text):
                yield Unit(s, sec.heading, role, page, line, order, read_sentence(s, role, rules))


def role_of_section(doc: Any, heading: str, rules: Rules | None = None) -> str:
    """The role of the section called ``heading`` ("method" when unknown)."""
    roles = section_roles(doc, rules)
    for i, s in enumerate(doc.sections):
        if s.heading == heading:
            return roles[i]
    return "abstract" if heading == "Abstract" else "method"
