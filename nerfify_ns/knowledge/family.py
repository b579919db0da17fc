"""A paper's family: static scene, dynamic scene, Gaussian splatting, surface reconstruction, or not a
view-synthesis training method at all, decided from what its title, abstract and method sections describe.

    family = detect_family(doc, kb)      # Family(name='dynamic', buildable=True, scene={'timestamps': True}, ...)
    family.evidence                      # the sentences that decided it, with their sections

The cues, weights and thresholds are data (``families.yaml``). Each cue counts once per sentence, weighted by where
the sentence is: the title and abstract say what the paper is about, the method sections what it does; the
introduction and related work describe other people's methods and count little. The family whose score passes its
threshold and comes first in ``precedence`` wins, among the families whose score is at least ``dominance`` times the
best score that passed (a surface paper that mentions Gaussian splatting and covariance matrices in passing is not
a splatting paper); a paper that passes none is ``static``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns.knowledge.errors import KnowledgeError
from nerfify_ns.knowledge.sentences import Rules, sentences

FAMILIES_FILE = Path(__file__).resolve().parent / "families.yaml"
STATIC = "static"
UP_FRONT = ("title", "abstract")
"""The roles of the sentences where a paper says what it is."""


@dataclass(frozen=True)
class FamilySpec:
    name: str
    buildable: bool
    threshold: float
    why: str
    scene: dict
    cues: tuple[tuple[re.Pattern, float], ...]
    against: tuple[tuple[re.Pattern, float], ...] = ()
    method: str = ""
    base: str = ""
    named_up_front: bool = False
    """The family passes only when one of its cues is in the title or the abstract (where a paper says what it is):
    a paper that only discusses such methods elsewhere is not one."""


@dataclass(frozen=True)
class FamilyRules:
    weights: dict
    precedence: tuple[str, ...]
    families: dict[str, FamilySpec]
    dominance: float = 0.0


@dataclass
class Family:
    """What kind of method the paper describes, and why."""

    name: str
    """static | dynamic | splatting | surface | not-training"""
    buildable: bool
    """Whether the grammar of Nerfstudio methods can build it."""
    why: str = ""
    """For a family that cannot be built: what cannot be built, in one sentence."""
    scene: dict = field(default_factory=dict)
    """Scene facts the family implies (``{"timestamps": True}`` for a dynamic scene), and those of the families that
    also passed (a dynamic splatting paper's timestamps)."""
    scores: dict = field(default_factory=dict)
    """Every family's score (and its threshold), for the record."""
    evidence: list = field(default_factory=list)
    """The sentences that decided it: {quote, section, page, line, cue}."""
    also: list = field(default_factory=list)
    """Other families that passed their threshold (a dynamic splatting paper: ["dynamic"])."""
    method: str = ""
    """For a family that cannot be built: Nerfstudio's own method of its kind (``splatfacto``), or empty."""
    base: str = ""
    """The base every paper of the family stands on (a splatting paper: ``splatfacto``, 3D Gaussians), or empty:
    the base is chosen among the reference plans (and never one that another family reserves)."""

    def to_dict(self) -> dict:
        return {"name": self.name, "buildable": self.buildable, "why": self.why, "scene": dict(self.scene),
                "also": list(self.also), "scores": dict(self.scores), "evidence": list(self.evidence),
                **({"method": self.method} if self.method else {}), **({"base": self.base} if self.base else {})}

    def method_line(self) -> str:
        """Where a researcher can train the family's own kind of model here, or empty."""
        return (f"Nerfstudio's method of this kind is {self.method} (`ns-train {self.method}` trains it on this "
                f"machine, the CPU included), but no plugin is derived from it") if self.method else ""

    def headline(self) -> str:
        extra = f" (also {', '.join(self.also)})" if self.also else ""
        return f"{self.name}{extra}"


def stands_on(plan: dict) -> str:
    """The Nerfstudio method a plan stands on, as a researcher would name it: its family's own method when the grammar
    cannot build the family (a splatting paper's ``splatfacto``, not the ray-marched base the chooser fell back on),
    else its base."""
    family = plan.get("family") if isinstance(plan.get("family"), dict) else {}
    if family.get("buildable") is False and family.get("method"):
        return str(family["method"])
    return str(plan.get("base") or "")


def _patterns(items: Any, where: str) -> tuple[tuple[re.Pattern, float], ...]:
    out = []
    for item in items or ():
        pattern, weight = item
        out.append((re.compile(pattern, re.IGNORECASE), float(weight)))
    return tuple(out)


def read_family_rules(path: Path | str = FAMILIES_FILE) -> FamilyRules:
    """The compiled contents of ``families.yaml``."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
        families = {}
        for name, spec in data["families"].items():
            families[name] = FamilySpec(
                name=name, buildable=bool(spec["buildable"]), threshold=float(spec["threshold"]),
                why=str(spec.get("why", "")), scene=dict(spec.get("scene") or {}),
                cues=_patterns(spec["cues"], name), against=_patterns(spec.get("against"), name),
                method=str(spec.get("method") or "") if not spec["buildable"] else "",
                base=str(spec.get("base") or ""), named_up_front=bool(spec.get("named_up_front", False)))
        precedence = tuple(data["precedence"])
        unknown = [p for p in precedence if p not in families]
        if unknown:
            raise KeyError(f"precedence names unknown families {unknown}")
        return FamilyRules(weights=dict(data["weights"]), precedence=precedence, families=families,
                           dominance=float(data.get("dominance", 0.0)))
    except (OSError, KeyError, TypeError, ValueError, re.error, yaml.YAMLError) as exc:
        raise KnowledgeError(f"{path}: cannot read the paper families ({exc}); fix families.yaml") from exc


_DEFAULT: FamilyRules | None = None


def family_rules() -> FamilyRules:
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = read_family_rules()
    return _DEFAULT


def _score(units: list, cues: tuple, weights: dict, evidence: list | None = None) -> float:
    """Sum over sentences of each matching cue's weight times the sentence's place weight, sub-linear in the
    number of sentences per cue (one cue repeated fifty times is not fifty cues)."""
    total = 0.0
    for pattern, weight in cues:
        hits = 0.0
        for u in units:
            place = weights.get(u.role, 0.0)
            if place <= 0 or not pattern.search(u.text):
                continue
            hits += place
            if evidence is not None and place >= 1.0 and len(evidence) < 40:
                evidence.append((place * weight, u, pattern.pattern))
        total += weight * math.sqrt(hits) * 2 if hits else 0.0
    return total


def detect_family(doc: Any, rules: Rules | None = None, family: FamilyRules | None = None) -> Family:
    """The family of ``doc`` (see the module docstring)."""
    fr = family or family_rules()
    units = list(sentences(doc, rules))
    scores: dict[str, float] = {}
    found: dict[str, list] = {}
    for name, spec in fr.families.items():
        ev: list = []
        score = _score(units, spec.cues, fr.weights, ev)
        if spec.against:
            score -= _score(units, spec.against, fr.weights)
        scores[name] = round(score, 2)
        found[name] = ev
    up_front = [u for u in units if u.role in UP_FRONT]
    passed = [n for n in fr.precedence if scores.get(n, 0.0) >= fr.families[n].threshold
              and (not fr.families[n].named_up_front or _score(up_front, fr.families[n].cues, fr.weights) > 0)]
    best = max((scores[n] for n in passed), default=0.0)
    passed = [n for n in passed if scores[n] >= fr.dominance * best]
    name = passed[0] if passed else STATIC
    spec = fr.families.get(name)
    evidence = []
    for _w, u, cue in sorted(found.get(name, []), key=lambda e: -e[0])[:3]:
        evidence.append({"quote": u.text[:300], "section": u.section, "page": u.page, "line": u.line, "cue": cue})
    record = {n: {"score": s, "threshold": fr.families[n].threshold} for n, s in scores.items()}
    if spec is None:
        return Family(STATIC, True, scores=record, evidence=[], also=[])
    also = [p for p in passed[1:]]
    scene = {k: v for other in also for k, v in fr.families[other].scene.items()}  # a dynamic splatting paper
    scene.update(spec.scene)
    return Family(name, spec.buildable, spec.why if not spec.buildable else "", scene, record, evidence,
                  also=also, method=spec.method, base=spec.base)
