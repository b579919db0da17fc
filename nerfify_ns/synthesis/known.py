"""Known or new, by meaning: a paper's equation is *known* when it matches a technique card's equation by
structure, in the equation compiler's own IR, not when a card's name is nearby.

    index = CardEquations.of(kb)                 # every card's canonical equation(s), parsed once
    match = index.match(latex_or_text)           # Match(card='hierarchical_sampling', how='same equation')

Structure means: the IR with every symbol renamed by its first appearance (``\\sigma_i \\delta_i`` and
``\\tau_k s_k`` are the same), operands of ``+`` and ``*`` sorted (commutativity), scale factors dropped (a
constant, a Greek weight ``\\lambda``, a mean's ``1/N`` or a divisor ``c`` next to something computed does not make
a new technique), decorations and sample indices ignored, and both sides of
``=`` compared as well as the right-hand side alone (``\\hat C`` or ``C``, ``:=`` or ``=``). A card equation found
whole inside a larger paper equation (of a few operations at least) also counts: the paper builds on it.
An equation the parser cannot read is compared by the sequence of its operators (sum, exp, product, sin, ...),
only when that sequence is long enough to mean something.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from nerfify_ns.equations import ParseFailure, ir, parse_equations

COMMUTATIVE = {"+", "*", "odot"}
MIN_CONTAINED = 6
"""A card equation found inside a paper equation counts only with at least this many IR nodes."""
MIN_OPERATORS = 5
"""Operator sequences (unreadable equations) are compared only with at least this many operators."""


@dataclass(frozen=True)
class Match:
    card: str
    how: str
    """'same equation' | 'contains the card's equation' | 'same operators' (unreadable equations)."""
    card_equation: str

    def to_dict(self) -> dict:
        return {"card": self.card, "how": self.how, "card_equation": self.card_equation}


def _applied(e: Any) -> list:
    """The arguments of a symbol applied to expressions (``\\sigma(\\sum_k ...)``, ``S(...)``): a named function of
    something computed. The point a field is evaluated at (``c(\\mathbf{r}(t), \\mathbf{d})``) is notation: left out."""
    return [a for a in e.args if not isinstance(a, ir.Symbol)]


def _children(e: Any) -> list:
    if isinstance(e, ir.Symbol):
        return _applied(e)
    if isinstance(e, ir.BinOp):
        return [e.left, e.right]
    if isinstance(e, ir.Neg):
        return [e.arg]
    if isinstance(e, ir.Apply):
        return list(e.args)
    if isinstance(e, ir.Reduce | ir.Integral | ir.Expectation):
        return [e.body]
    if isinstance(e, ir.Norm):
        return [e.arg]
    if isinstance(e, ir.Concat):
        return list(e.items)
    if isinstance(e, ir.Cases):
        return [x for branch in e.branches for x in branch if x is not None]
    if isinstance(e, ir.Compare):
        return [e.left, e.right]
    return []


def _constant(e: Any) -> bool:
    """An expression without symbols (2, 1/2, \\pi is a symbol and stays)."""
    return not any(isinstance(t, ir.Symbol) for t in _subtrees(e))


GREEK = {"alpha", "beta", "gamma", "delta", "epsilon", "varepsilon", "zeta", "eta", "theta", "kappa", "lambda", "mu",
         "nu", "xi", "rho", "sigma", "tau", "phi", "varphi", "chi", "psi", "omega"}
"""Names of Greek letters: a Greek symbol that is neither indexed nor evaluated at a point is a weight or a scale
(``\\lambda_s``, ``\\beta``); a Latin letter next to a parenthesis may be a function's name the parser read as a
product (``BCE(x)``, ``S(x)``), so it is kept."""


def _bare(e: Any) -> bool:
    return isinstance(e, ir.Symbol) and e.index is None and not e.args


def _scale(e: Any) -> bool:
    """A scale: a constant, a bare Greek symbol (``\\lambda_s``), or such a scale divided by a bare symbol or a
    constant (``\\lambda_s / N``), or a product of scales. Next to something computed it only weights it (a loss
    weight, a mean's 1/N), so it does not make a new technique either."""
    if _constant(e):
        return True
    if _bare(e):
        return e.name in GREEK
    if isinstance(e, ir.BinOp) and e.op == "/":
        return _scale(e.left) and (_bare(e.right) or _constant(e.right))
    if isinstance(e, ir.BinOp) and e.op == "*":
        return _scale(e.left) and _scale(e.right)
    return False


def _divisor(e: Any) -> bool:
    """A divisor that only scales: a constant or a bare symbol (a Cauchy scale ``c``, a count ``N``)."""
    return _constant(e) or _bare(e)


def _factors(e: Any) -> list:
    """The operands of a product that are not scales (all of them when every one is)."""
    parts = _flatten(e, "*")
    kept = [p for p in parts if not _scale(p)]
    return kept or [p for p in parts if not _constant(p)] or parts[:1]


def _flatten(e: Any, op: str) -> list:
    if isinstance(e, ir.BinOp) and e.op == op:
        return _flatten(e.left, op) + _flatten(e.right, op)
    return [e]


def _label(e: Any) -> str:
    """The node's own label, without its children and without symbol names."""
    if isinstance(e, ir.Symbol):
        return "S"
    if isinstance(e, ir.Number):
        return "N"
    if isinstance(e, ir.BinOp):
        return e.op
    if isinstance(e, ir.Neg):
        return "neg"
    if isinstance(e, ir.Apply):
        return f"f:{e.func}"
    if isinstance(e, ir.Reduce):
        return f"red:{e.kind}"
    if isinstance(e, ir.Integral):
        return "int"
    if isinstance(e, ir.Norm):
        return "norm"
    return type(e).__name__.lower()


class _Canon:
    """Canonical strings of IR trees: anonymous shapes first (to order commutative operands), then symbols
    numbered in that order."""

    def __init__(self) -> None:
        self.names: dict[str, str] = {}

    @staticmethod
    def shape(e: Any) -> str:
        if isinstance(e, ir.BinOp) and e.op in COMMUTATIVE:
            parts = _factors(e) if e.op == "*" else _flatten(e, e.op)
            if len(parts) == 1:
                return _Canon.shape(parts[0])
            return f"{e.op}({','.join(sorted(_Canon.shape(p) for p in parts))})"
        if isinstance(e, ir.BinOp) and e.op == "/" and _divisor(e.right) and not _scale(e.left):
            return _Canon.shape(e.left)  # a scale factor
        kids = [k for k in _children(e) if k is not None]
        return _label(e) + (f"({','.join(_Canon.shape(k) for k in kids)})" if kids else "")

    def full(self, e: Any) -> str:
        if isinstance(e, ir.Symbol):
            key = "|".join([e.name, ",".join(e.subscripts), e.superscript or "", ",".join(e.decorations)])
            self.names.setdefault(key, f"v{len(self.names)}")
            applied = _applied(e)
            return self.names[key] + (f"({','.join(self.full(a) for a in applied)})" if applied else "")
        if isinstance(e, ir.BinOp) and e.op in COMMUTATIVE:
            parts = _factors(e) if e.op == "*" else _flatten(e, e.op)
            if len(parts) == 1:
                return self.full(parts[0])
            ordered = sorted(parts, key=_Canon.shape)
            return f"{e.op}({','.join(self.full(p) for p in ordered)})"
        if isinstance(e, ir.BinOp) and e.op == "/" and _divisor(e.right) and not _scale(e.left):
            return self.full(e.left)
        kids = [k for k in _children(e) if k is not None]
        return _label(e) + (f"({','.join(self.full(k) for k in kids)})" if kids else "")


def canonical(e: Any) -> str:
    """The canonical string of an IR expression (see the module docstring)."""
    return _Canon().full(e)


def _subtrees(e: Any) -> Iterable[Any]:
    yield e
    for k in _children(e):
        if k is not None:
            yield from _subtrees(k)


def _size(e: Any) -> int:
    return sum(1 for _ in _subtrees(e))


_OPERATOR_TOKENS = [
    (r"\\sum|∑|Σ(?=\s*[_a-zij=])", "sum"), (r"\\prod|∏", "prod"), (r"\\int|∫", "int"), (r"\\exp|\bexp\b", "exp"),
    (r"\\log|\blog\b", "log"), (r"\\sin|\bsin\b", "sin"), (r"\\cos|\bcos\b", "cos"), (r"\\sqrt|√", "sqrt"),
    (r"\\frac", "/"), (r"\\tanh|\btanh\b", "tanh"), (r"\\max|\bmax\b", "max"), (r"\\min|\bmin\b", "min"),
    (r"\\\||‖|∥", "norm"), (r"\\odot|⊙", "odot"), (r"=", "="), (r"\+", "+"), (r"−|-", "-"), (r"\^", "^"), (r"/", "/"),
]
_TOKEN_RE = re.compile("|".join(f"(?:{p})" for p, _ in _OPERATOR_TOKENS))


def operators(text: str) -> tuple[str, ...]:
    """The sequence of operators of an equation's text or LaTeX (for equations the parser cannot read)."""
    out = []
    for m in _TOKEN_RE.finditer(text or ""):
        tok = m.group(0)
        for pattern, name in _OPERATOR_TOKENS:
            if re.fullmatch(pattern, tok):
                out.append(name)
                break
    return tuple(out)


def _parsed(latex: str) -> list:
    try:
        found = parse_equations(latex)
    except Exception:  # noqa: BLE001 - an equation the parser cannot read is compared by its operators
        return []
    return [e for e in (found if isinstance(found, list) else [found]) if not isinstance(e, ParseFailure)]


@dataclass(frozen=True)
class _CardForm:
    card: str
    latex: str
    whole: str
    rhs: str
    rhs_tree: Any
    size: int


class CardEquations:
    """Every card's equation(s) in canonical form (the card's LaTeX and its ``canonical`` forms), parsed once."""

    def __init__(self, forms: list[_CardForm], ops: list[tuple[str, str, tuple[str, ...]]]):
        self.forms = forms
        self.ops = ops

    @classmethod
    def of(cls, kb: Any) -> CardEquations:
        cached = getattr(kb, "_card_equations", None)
        if cached is not None:
            return cached
        forms, ops = [], []
        for name, card in kb.cards.items():
            sources = [s for s in (card.equation.latex, *getattr(card.equation, "canonical", ())) if s]
            for latex in sources:
                for eq in _parsed(latex):
                    rhs = eq.rhs
                    forms.append(_CardForm(name, latex, f"{canonical(eq.lhs)}={canonical(rhs)}", canonical(rhs), rhs,
                                           _size(rhs)))
                seq = operators(latex)
                if len(seq) >= MIN_OPERATORS:
                    ops.append((name, latex, seq))
        index = cls(forms, ops)
        try:
            kb._card_equations = index
        except AttributeError:
            pass
        return index

    def match(self, latex: str, text: str = "") -> Match | None:
        """The card whose equation ``latex`` (or, unreadable, ``text``) is, by structure; None when it is new."""
        return self.read_and_match(latex, text)[1]

    def read_and_match(self, latex: str, text: str = "") -> tuple[bool, Match | None]:
        """Whether the parser read the equation (its LaTeX, else its text), and the card it matches (see ``match``):
        both from one parse."""
        parsed = _parsed(latex) if latex else []
        if not parsed and text:
            parsed = _parsed(text)
        return bool(parsed), self._match(parsed, latex or text)

    def _match(self, parsed: list, source: str) -> Match | None:
        for eq in parsed:
            rhs_c = canonical(eq.rhs)
            for f in self.forms:
                if f.rhs == rhs_c and f.size >= 3:
                    return Match(f.card, "same equation", f.latex)
            subtrees = {canonical(t) for t in _subtrees(eq.rhs) if _size(t) >= MIN_CONTAINED}
            for f in self.forms:
                if f.size >= MIN_CONTAINED and f.rhs in subtrees:
                    return Match(f.card, "contains the card's equation", f.latex)
        if parsed:
            return None
        seq = operators(source)
        if len(seq) < MIN_OPERATORS:
            return None
        for name, card_latex, card_seq in self.ops:
            if card_seq == seq:
                return Match(name, "same operators", card_latex)
        return None
