"""The weight of a loss term in the paper's training objective.

A paper defines a regulariser (``\\mathcal L_{acc} = -\\log P(T_i)``) in one place and weights it in another, the
line that adds up the training objective (``\\mathcal L = \\mathcal L_{recon} + \\lambda \\mathcal L_{acc},\\ \\lambda
= 10^{-4}``; SeaThru-NeRF's Losses, NeRF-W Eq. 13, Mip-NeRF 360 Eq. 16). The term's coefficient there is the weight
the plugin adds the compiled part to the loss with: a number written in the sum, or a symbol the same block, another
displayed equation or a sentence of the paper sets to a number. The record quotes where it comes from; a
coefficient the paper does not give is left at 1 and said.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from nerfify_ns.equations import Equation
from nerfify_ns.equations.ir import BinOp, Number, Symbol
from nerfify_ns.synthesis.novel.notation import symbol_loose_key


@dataclass
class ObjectiveWeight:
    """A loss term's coefficient in the paper's objective: its value (None when the paper gives no number for a
    coefficient it writes) and the record's sentence."""

    value: float | None
    note: str


def terms(expr: Any) -> list[Any]:
    """The summands of ``expr`` (a '+' chain flattened; a difference's right side is not a term of the sum)."""
    if isinstance(expr, BinOp) and expr.op == "+":
        return terms(expr.left) + terms(expr.right)
    return [expr]


def coefficient(term: Any, output: str) -> Any | None:
    """The coefficient of ``output`` in ``term``: 1.0 for the bare symbol, the other factor of a product with it
    (a number or a symbol), None when the term is not ``output`` weighted."""
    if isinstance(term, Symbol) and term.key == output:
        return 1.0
    if isinstance(term, BinOp) and term.op == "*":
        for mine, other in ((term.right, term.left), (term.left, term.right)):
            if isinstance(mine, Symbol) and mine.key == output and isinstance(other, Number | Symbol):
                return other
    return None


def sums_over(eq: Equation, keys: set[str]) -> bool:
    """Whether ``eq`` adds up weighted terms of which one is another of ``keys`` (an objective over that part,
    not a form of it)."""
    summands = terms(eq.rhs)
    return len(summands) >= 2 and any(coefficient(t, k) is not None for t in summands for k in keys - {eq.defines})


def _stated_numbers(items: list) -> dict[str, tuple[float, str]]:
    """Every symbol an equation of the paper sets to a number (``\\lambda = 10^{-4}``), with where."""
    numbers: dict[str, tuple[float, str]] = {}
    for it in items:
        for e in it.equations():
            if e.defines and isinstance(e.rhs, Number):
                numbers.setdefault(e.defines, (float(e.rhs.value), it.where))
    return numbers


def _stated(coef: Symbol, numbers: dict, words: Any) -> tuple[float, str] | None:
    """The number an equation or a sentence of the paper sets the symbol to, with where; None if none does."""
    stated = numbers.get(coef.key)
    if stated is None and words is not None and symbol_loose_key(coef) in words.constants:
        value, _quote, where = words.constants[symbol_loose_key(coef)]
        stated = (float(value), where)
    return stated


def _resolved(coef: Symbol, label: str, numbers: dict, words: Any) -> ObjectiveWeight:
    """A loss term's weight written as a symbol (``label`` says which and where), resolved to the number the paper
    sets it to, or left at 1 and said."""
    stated = _stated(coef, numbers, words)
    if stated is None:
        return ObjectiveWeight(None, f"{label} has no value in the paper: the weight stays 1 (set it in the plan's "
                                     "weight)")
    value, where = stated
    return ObjectiveWeight(value, f"weight {value:g}: {label}, {coef.key} = {value:g} at {where}")


def term_weight(outputs: list[str], own: Symbol | None, items: list, words: Any) -> ObjectiveWeight | None:
    """The weight the plugin adds a loss term with: its own factor in its equation (``L_s = lambda_s sum ...``;
    ``own``), times its coefficient in the objective; a factor the paper gives no number counts 1 and is said. None
    when the paper weights the term nowhere."""
    weighted = objective_weight(outputs, items, words)
    if own is None:
        return weighted
    mine = _resolved(own, f"{outputs[0]}'s own weight {own.key} in its equation", _stated_numbers(items), words)
    if weighted is None:
        return mine
    known = [w.value for w in (mine, weighted) if w.value is not None]
    value = known[0] * known[1] if len(known) == 2 else (known[0] if known else None)
    return ObjectiveWeight(value, f"{mine.note}; {weighted.note}")


def objective_weight(outputs: list[str], items: list, words: Any) -> ObjectiveWeight | None:
    """The coefficient of the part's output (one of ``outputs``) in a sum of two or more terms that another
    equation of the paper defines (its objective), resolved to a number; None when no such sum names it."""
    numbers = _stated_numbers(items)
    for it in items:
        for e in it.equations():
            summands = terms(e.rhs)
            if e.defines in outputs or len(summands) < 2:
                continue
            for output in outputs:
                coef = next((c for c in (coefficient(t, output) for t in summands) if c is not None), None)
                if coef is None:
                    continue
                objective = f"the objective {e.defines or ''} = ... at {it.where or 'its equation'}"
                if not isinstance(coef, Symbol):  # written in the sum (1 for a bare term)
                    value = float(coef.value if isinstance(coef, Number) else coef)
                    return ObjectiveWeight(value, f"weight {value:g}: {output}'s coefficient in {objective}")
                return _resolved(coef, f"{output}'s coefficient {coef.key} in {objective}", numbers, words)
    return None
