"""Which reference plan a derived plan starts from, and why (plan derivation's first step).

1. A paper that says which model it builds on ("our implementation is based on Instant-NGP";
   ``knowledge/bases.py`` finds it, ``bases.yaml`` holds the patterns) gets that base, with the quote.
   A sentence naming several ("backbones: InstantNGP and TensoRF") leaves the choice among those.
2. Otherwise every reference plan is scored by the techniques of the paper it hosts: each counts with its
   weight (the confidence of its detection, or the weight of the citation it was recovered from), a
   technique only one base can host (a ``requires_base`` duty naming one base in the grammar, or a
   technique only one reference plan contains) counts ``exclusive_weight`` times, and every technique
   a plan brings that the paper does not use costs ``extra_penalty`` (generic ones aside).
3. When the top two scores are within ``close_margin`` of the best, the choice is a close call: it is
   decided by, in order, the exclusive techniques hosted, the techniques hosted, fewer techniques the
   paper does not use, then the score, and a sentence naming both candidates with their coverage and
   the criterion that decided goes into the plan's notes.

The weights are data (``bases.yaml``, ``choice``), so a knowledge base can change them.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field

from nerfify_ns.grammar import Grammar
from nerfify_ns.knowledge.bases import BaseStatement
from nerfify_ns.knowledge.patterns import BaseChoice

# tie-breaks of a close call, in order: (what decides, how it reads in the sentence)
TIE_BREAKS = ("exclusive", "covered", "extra", "score")


@dataclass
class BaseScore:
    """How well one reference plan hosts the paper's techniques."""

    name: str
    score: float
    covered: list[str]                 # the paper's techniques it hosts
    exclusive: list[str]               # of those, techniques only this base can host
    missing: list[str]                 # the paper's techniques it cannot host
    extra: list[str]                   # techniques it brings that the paper does not use (generic ones aside)

    @property
    def coverage(self) -> str:
        """"4 of 6" techniques of the paper."""
        return f"{len(self.covered)} of {len(self.covered) + len(self.missing)}"

    def to_dict(self) -> dict:
        return {**asdict(self), "coverage": self.coverage}


@dataclass
class BaseDecision:
    """The base chosen, the scores of every candidate, the statement or close call that decided, and why."""

    base: str
    reason: str
    scores: list[BaseScore]
    statement: BaseStatement | None = None
    close_call: str = ""               # the sentence explaining a close call ("" when it was not one)
    runner_up: str | None = None
    criterion: str = ""                # statement | score | exclusive | covered | extra | order | none
    notes: list[str] = field(default_factory=list)

    def score_of(self, name: str) -> BaseScore | None:
        return next((s for s in self.scores if s.name == name), None)

    def to_dict(self) -> dict:
        return {"base": self.base, "reason": self.reason, "criterion": self.criterion, "close_call": self.close_call,
                "runner_up": self.runner_up, "statement": self.statement.to_dict() if self.statement else None,
                "scores": [s.to_dict() for s in self.scores]}


# ------------------------------------------------------------------------------------------ scoring
def exclusive_cards(hosted: Mapping[str, frozenset], grammar: Grammar) -> set[str]:
    """Techniques only one base can host: a terminal of theirs requires one base (grammar duty ``requires_base``),
    or only one reference plan contains them."""
    counts = Counter(c for cards in hosted.values() for c in cards)
    out = {c for c, n in counts.items() if n == 1}
    for terminal in grammar.terminals.values():
        for duty in terminal.duties:
            bases = duty.get("requires_base") if isinstance(duty, dict) else None
            if terminal.card and bases is not None and len(bases) == 1:
                out.add(terminal.card)
    return out


def score_bases(candidates: Mapping[str, float], hosted: Mapping[str, frozenset], exclusive: set[str],
                choice: BaseChoice, order: Sequence[str]) -> list[BaseScore]:
    """Every reference plan of ``order`` scored against the paper's techniques (``candidates``: card -> weight),
    best first (ties in ``order``)."""
    scores = []
    for name in order:
        covered = hosted.get(name, frozenset())
        hit = sorted(c for c in candidates if c in covered)
        value = sum(candidates[c] * (choice.exclusive_weight if c in exclusive else 1.0) for c in hit)
        extra = sorted(c for c in covered if c not in candidates and c not in choice.generic)
        scores.append(BaseScore(name=name, score=round(value - choice.extra_penalty * len(extra), 4), covered=hit,
                                exclusive=[c for c in hit if c in exclusive],
                                missing=sorted(c for c in candidates if c not in covered), extra=extra))
    rank = {n: i for i, n in enumerate(order)}
    return sorted(scores, key=lambda s: (-s.score, rank[s.name]))


def is_close(a: float, b: float, margin: float) -> bool:
    """Whether two scores are within ``margin`` of the larger one (both positive)."""
    top = max(a, b)
    return top > 0 and abs(a - b) <= margin * top


def _tie_key(s: BaseScore, criterion: str) -> float:
    return {"exclusive": len(s.exclusive), "covered": len(s.covered), "extra": -len(s.extra),
            "score": s.score}[criterion]


def _why(criterion: str, win: BaseScore, other: BaseScore) -> str:
    """The clause saying why ``win`` beat ``other`` on ``criterion``."""
    if criterion == "exclusive":
        return (f"it hosts {len(win.exclusive)} technique(s) only one base can host "
                f"({', '.join(win.exclusive) or 'none'}) against {len(other.exclusive)}"
                f"{' (' + ', '.join(other.exclusive) + ')' if other.exclusive else ''}")
    if criterion == "covered":
        return f"it hosts more of the paper's techniques ({win.coverage} against {other.coverage})"
    if criterion == "extra":
        brought = ", ".join(other.extra) or "nothing"
        return (f"it brings fewer techniques the paper does not use ({len(win.extra)} against {len(other.extra)}: "
                f"{other.name} would add {brought})")
    if criterion == "score":
        return f"its score is higher ({win.score:.2f} against {other.score:.2f})"
    return f"nothing separates them; {win.name} comes first in the order of preference (plainest first)"


def close_call(first: BaseScore, second: BaseScore, margin: float) -> tuple[BaseScore, BaseScore, str, str]:
    """(winner, runner-up, criterion, sentence) of two scores within ``margin`` of each other."""
    for criterion in TIE_BREAKS:
        a, b = _tie_key(first, criterion), _tie_key(second, criterion)
        if a != b:
            win, other = (first, second) if a > b else (second, first)
            break
    else:
        criterion, win, other = "order", first, second
    sentence = (f"close call between {first.name} (score {first.score:.2f}, hosts {first.coverage} of the paper's "
                f"techniques) and {second.name} (score {second.score:.2f}, hosts {second.coverage}), within "
                f"{margin:.0%} of each other: {win.name} is chosen because {_why(criterion, win, other)}")
    return win, other, criterion, sentence


# ------------------------------------------------------------------------------------------ decision
def _reason(best: BaseScore, n_candidates: int, scores: Sequence[BaseScore]) -> str:
    others = ", ".join([f"{s.name} {s.score:.2f}" for s in scores if s.name != best.name][:3])
    miss = f"; not covered: {', '.join(best.missing)}" if best.missing else ""
    return (f"{best.name!r} covers {len(best.covered)} of the {n_candidates} techniques found "
            f"({', '.join(best.covered) or 'none'}){miss} (score {best.score:.2f}; next: {others})")


def _from_statement(statements: Sequence[BaseStatement],
                    available: Iterable[str]) -> tuple[BaseStatement, list[str]] | None:
    """The first statement naming an available base, and the available bases it names."""
    known = set(available)
    for st in statements:
        named = [b for b in st.bases if b in known]
        if named:
            return st, named
    return None


def choose_base(candidates: Mapping[str, float], hosted: Mapping[str, frozenset], exclusive: set[str],
                choice: BaseChoice, order: Sequence[str], statements: Sequence[BaseStatement] = ()) -> BaseDecision:
    """The base of a derived plan (see the module docstring)."""
    scores = score_bases(candidates, hosted, exclusive, choice, order)
    stated = _from_statement(statements, order)
    if stated is not None:
        st, named = stated
        best = next(s for s in scores if s.name in named)
        among = (f" (of {', '.join(named)} it names, {best.name} hosts the most of its techniques)"
                 if len(named) > 1 else "")
        reason = (f"the paper says it builds on {best.name}{among}: \"{st.quote}\" ({st.where}); "
                  + _reason(best, len(candidates), scores))
        return BaseDecision(base=best.name, reason=reason, scores=scores, statement=st, criterion="statement")
    if not candidates:
        name = order[0]
        return BaseDecision(base=name, scores=scores, criterion="none",
                            reason=(f"no technique of the paper was recovered; {name!r}, the plainest NeRF reference "
                                    "plan, stands in for every part"))
    first, second = scores[0], scores[1] if len(scores) > 1 else None
    if second is None or not is_close(first.score, second.score, choice.close_margin):
        return BaseDecision(base=first.name, reason=_reason(first, len(candidates), scores), scores=scores,
                            criterion="score", runner_up=second.name if second else None)
    win, other, criterion, sentence = close_call(first, second, choice.close_margin)
    return BaseDecision(base=win.name, reason=f"{_reason(win, len(candidates), scores)}; {sentence}", scores=scores,
                        close_call=sentence, runner_up=other.name, criterion=criterion)
