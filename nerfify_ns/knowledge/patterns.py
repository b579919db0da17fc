"""The pattern files of the knowledge base, compiled: citation patterns (``citation_patterns.yaml``) and
base-model statements with the base-choice weights (``bases.yaml``).

Only parsing lives here (no cache: a ``KnowledgeBase`` reads each file once and keeps the result);
``citations.py`` and ``bases.py`` apply the patterns to a paper.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns.knowledge.errors import KnowledgeError
from nerfify_ns.knowledge.text import alias_pattern

PATTERNS_FILE = Path(__file__).resolve().parent / "citation_patterns.yaml"
BASES_FILE = Path(__file__).resolve().parent / "bases.yaml"
RELATIONS = ("adopts", "follows", "builds_on")

# one or more citation targets in a row, each replaced by a token before matching (citations.py)
CITE_GROUP = r"(?P<cite>\u27e6\d+\u27e7(?:\s*(?:,|and)?\s*\u27e6\d+\u27e7)*)"
# one or more named base models in a row ("InstantNGP [52] and TensoRF [11]"; markdown emphasis allowed),
# after an optional possessive ("Nerfstudio's nerfacto") and not followed by a possessive naming a part
# ("Instant-NGP's hash encoding" is a component, "Instant-NGP's implementation" the code)
BASE_GROUP = (r"(?:\u27e6\d+\u27e7['\u2019]s\s+)?[*_]*"
              r"(?P<base>\u27e6\d+\u27e7(?:[\s*_]*(?:,|and|or|/|\+)?[\s*_]*\u27e6\d+\u27e7)*)"
              r"(?!['\u2019]s\s+(?!(?:official\s+|public\s+|open[- ]source\s+|original\s+)?"
              r"(?:implementation|code|codebase|framework|model|pipeline|architecture)\b))")


# ------------------------------------------------------------------------------------------ citations
@dataclass(frozen=True)
class CitationPattern:
    name: str
    relation: str
    regex: re.Pattern


@dataclass(frozen=True)
class PatternSet:
    patterns: tuple[CitationPattern, ...]
    terminal_productions: dict
    needed_productions: tuple[str, ...]
    bare_names: tuple[tuple[str, re.Pattern], ...] = ()


def read_patterns(path: Path | str = PATTERNS_FILE) -> PatternSet:
    """The compositional citation patterns of a ``citation_patterns.yaml``."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
        patterns = tuple(CitationPattern(p["name"], p["relation"],
                                         re.compile(p["regex"].replace("{cite}", CITE_GROUP), re.IGNORECASE))
                         for p in data["patterns"])
        for p in patterns:
            if p.relation not in RELATIONS:
                raise KnowledgeError(f"{path}: pattern {p.name!r} has unknown relation {p.relation!r}")
        bare = tuple((k, re.compile(v)) for k, v in (data.get("bare_names") or {}).items())
        return PatternSet(patterns, dict(data.get("terminal_productions") or {}),
                          tuple(data.get("needed_productions") or ()), bare)
    except (OSError, KeyError, TypeError, re.error, yaml.YAMLError) as exc:
        raise KnowledgeError(f"{path}: cannot read the citation patterns ({exc}); fix citation_patterns.yaml") from exc


# ------------------------------------------------------------------------------------------ base models
@dataclass(frozen=True)
class BaseModel:
    """A Nerfstudio model a paper may build on: the reference plan's name and how papers name it."""

    name: str
    names: tuple[str, ...]
    papers: tuple[str, ...]


@dataclass(frozen=True)
class BaseChoice:
    """How plan derivation weighs techniques when it chooses a base (see bases.yaml)."""

    exclusive_weight: float
    extra_penalty: float
    close_margin: float
    generic: frozenset
    citation_weights: dict = field(default_factory=dict)

    def citation_weight(self, relation: str) -> float:
        """The weight of a technique taken from cited work through ``relation``."""
        return float(self.citation_weights.get(relation, self.citation_weights.get("other", 0.3)))


@dataclass(frozen=True)
class BaseRules:
    """The compiled contents of ``bases.yaml``: models in order of preference, statements, choice weights."""

    models: tuple[BaseModel, ...]
    statements: tuple[tuple[str, re.Pattern], ...]
    choice: BaseChoice

    def model(self, name: str) -> BaseModel | None:
        return next((m for m in self.models if m.name == name), None)

    @property
    def order(self) -> tuple[str, ...]:
        """Model names, plainest first (ties are broken in this order)."""
        return tuple(m.name for m in self.models)


def _model(name: str, raw: Any, path: Path) -> BaseModel:
    if not isinstance(raw, dict):
        raise KnowledgeError(f"{path}: models.{name} must be a mapping with names and papers; fix bases.yaml")
    names = tuple(str(n) for n in raw.get("names") or ())
    for n in names:
        if n != n.lower():
            raise KnowledgeError(f"{path}: models.{name}: names must be lower-case ({n!r}); fix bases.yaml")
        alias_pattern(n)
    return BaseModel(name=name, names=names, papers=tuple(str(p) for p in raw.get("papers") or ()))


BASE_DEFINITIONS = Path(__file__).resolve().parents[1] / "registry" / "bases.yaml"
"""The base models' one definition (read as data: the knowledge base imports no other package of the project)."""


def _models(data: dict) -> dict[str, Any]:
    """The reference models of a ``bases.yaml`` (``models``), else those of the base models' one definition: each
    base's ``reference_plans`` (name -> names, papers, base), by ``preference`` (plainest first)."""
    if "models" in data:
        return data["models"]
    bases = yaml.safe_load(BASE_DEFINITIONS.read_text(encoding="utf-8"))
    plans = [(plan, {**entry, "base": name}) for name, base in bases.items()
             for plan, entry in (base.get("reference_plans") or {}).items()]
    return dict(sorted(plans, key=lambda p: p[1].get("preference", 0)))


def read_bases(path: Path | str = BASES_FILE) -> BaseRules:
    """The base models, statement patterns and choice weights of a ``bases.yaml``."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
        prefix = data.get("prefix") or ""
        models = tuple(_model(str(k), v, path) for k, v in _models(data).items())
        statements = tuple((s["name"], re.compile(s["regex"].replace("{base}", prefix + BASE_GROUP), re.IGNORECASE))
                           for s in data["statements"])
        for name, regex in statements:
            if "base" not in regex.groupindex:
                raise KnowledgeError(f"{path}: statement {name!r} has no {{base}}; fix bases.yaml")
        raw = data["choice"]
        choice = BaseChoice(exclusive_weight=float(raw["exclusive_weight"]), extra_penalty=float(raw["extra_penalty"]),
                            close_margin=float(raw["close_margin"]), generic=frozenset(raw.get("generic") or ()),
                            citation_weights={str(k): float(v) for k, v in (raw.get("citation_weights") or {}).items()})
        return BaseRules(models=models, statements=statements, choice=choice)
    except (OSError, KeyError, TypeError, ValueError, AttributeError, re.error, yaml.YAMLError) as exc:
        raise KnowledgeError(f"{path}: cannot read the base models ({exc}); fix bases.yaml") from exc
