"""Read one displayed equation of a NeRF paper into the IR (``ir.py``), or say why not.

``parse_equation(latex)`` -> Equation | ParseFailure. The reading, in the paper's notation:

* juxtaposition is a product (``T_i \\alpha_i c_i``); a run of letters is a product of one-letter symbols
  (``td_z`` = t d_z) unless it is a function word (``exp``, ``ReLU``, ``softplus``, ``MSE``, ``sg``);
* ``X(...)`` after a symbol is the field X evaluated at a point when the argument is a point (a symbol
  such as ``\\mathbf{r}``, ``t``, ``s_i``, ``\\mathbf{r}(t)``, or several arguments): ``C(\\mathbf{r})``,
  ``T(t)``, ``\\mathbf{c}(\\mathbf{r}(t), \\mathbf{d})``; a product when the argument is an expression
  (``T_i(1 - \\alpha_i)``); ``\\sigma(\\cdot)`` of an expression is the logistic sigmoid
  (``\\sigma(\\mathbf{W} x + b)``) and of a point the density there (``\\sigma(\\mathbf{r}(t))``); a
  calligraphic, blackboard or multi-letter name applied to an expression is an unknown operator;
* superscripts: a number or an expression is a power (``x^2``, ``x^{-1}``, ``2^{k}``, ``e^{-x}`` is
  exp); letters, ``(k)``, ``\\prime``, ``*``, ``\\top`` on a symbol are labels (``W^f``, ``c^{med}``,
  ``x^{(k)}``); subscripts on a symbol are labels (``W_1``, ``h_\\Delta``) until ``resolve`` makes the
  sample indices among them indices;
* a sum, product, integral or expectation takes the rest of its term (``\\sum_i w_i c_i + b``).

Limits: ``normalize.MAX_CHARS`` characters, ``normalize.MAX_DEPTH`` nested groups, ``MAX_IR_DEPTH`` levels
of the IR; the LALR parser and every pass are linear in the input.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from lark import Lark, Token, Tree
from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken, VisitError

from .ir import DEFAULT_CONVENTIONS, Conventions, Equation, Expr, ParseFailure, Reduce, depth
from .normalize import MAX_CHARS, Mapped, NormalizeError, normalize
from .reader import APPROX_RELATIONS, DEFINE_RELATIONS, OBJECTIVE, Reader, ReadError, Word

MAX_IR_DEPTH = 120
MAX_EQUATIONS = 64


@lru_cache(maxsize=1)
def _lark() -> Lark:
    grammar = Path(__file__).with_name("grammar.lark").read_text()
    return Lark(grammar, parser="lalr", propagate_positions=True, maybe_placeholders=False)


# --- entry points ----------------------------------------------------------------------------------------

def _failure(reason: str, piece: Mapped | None, pos: int | None, fragment: str, latex: str,
             number: str | None) -> ParseFailure:
    column = piece.column(pos) if (piece is not None and pos is not None) else None
    return ParseFailure(reason, column, fragment, latex, number)


def _read_piece(piece: Mapped, latex: str, number: str | None):
    """The parse of one normalised piece: a list [expr, relop, expr, ...] or a ParseFailure."""
    try:
        tree = _lark().parse(piece.text)
    except UnexpectedCharacters as err:
        ch = piece.text[err.pos_in_stream] if err.pos_in_stream < len(piece.text) else ""
        reason = "unknown character" if not ch.isascii() else (
            "a factorial (!) is not read" if ch == "!" else "unexpected character")
        return _failure(reason, piece, err.pos_in_stream, ch, latex, number)
    except UnexpectedEOF:
        return _failure("the equation ends too early (an unclosed group?)", piece, len(piece.text) - 1, "",
                        latex, number)
    except UnexpectedToken as err:
        tok = err.token
        if tok.type == "$END":
            return _failure("the equation ends too early (an unclosed group?)", piece, len(piece.text) - 1, "",
                            latex, number)
        return _failure("unexpected here", piece, tok.start_pos, str(tok)[:40], latex, number)
    except UnexpectedInput as err:  # pragma: no cover - other lark input errors
        return _failure("unreadable", piece, getattr(err, "pos_in_stream", None), "", latex, number)
    objective = _objective(tree)
    if objective is not None:  # \min_{\Theta} (...): what training minimises, whatever its body holds
        return _failure(f"{OBJECTIVE} ({str(objective)[1:]} over the parameters), not an equation", piece,
                        objective.start_pos, str(objective) + "_", latex, number)
    try:
        return Reader(piece.text).transform(tree)
    except VisitError as err:
        inner = err.orig_exc
        if isinstance(inner, ReadError):
            return _failure(inner.reason, piece, inner.pos, inner.fragment, latex, number)
        if isinstance(inner, RecursionError):
            return _failure("nested too deeply", piece, None, "", latex, number)
        return _failure(f"could not read: {_describe(inner)}", piece, None, "", latex, number)
    except ReadError as err:
        return _failure(err.reason, piece, err.pos, err.fragment, latex, number)
    except RecursionError:
        return _failure("nested too deeply", piece, None, "", latex, number)


def _objective(tree) -> Token | None:
    """The ``\\min``/``\\max`` token of a block that is one min (max) over something and no relation: a training
    objective (``\\min_{\\Theta} \\sum_r ...``), not a definition."""
    if len(tree.children) != 1 or not isinstance(tree.children[0], Tree) or tree.children[0].data != "sum":
        return None
    terms = tree.children[0].children
    if len(terms) != 1 or not isinstance(terms[0], Tree) or len(terms[0].children) != 1:
        return None
    big = terms[0].children[0]
    if not isinstance(big, Tree) or big.data != "bigop" or not big.children:
        return None
    op = big.children[0]
    has_sub = any(isinstance(c, Tree) and c.data == "sub" for c in big.children[1:-1])
    return op if isinstance(op, Token) and str(op) in (r"\min", r"\max") and has_sub else None


def _equation(parts, piece: Mapped, latex: str, number: str | None, conventions: Conventions):
    if isinstance(parts, ParseFailure):
        return parts
    exprs = [p for p in parts if not isinstance(p, Token)]
    ops = [p for p in parts if isinstance(p, Token)]
    for e in exprs:
        if isinstance(e, Word):
            return _failure("a word where an expression should be", piece, e.pos, e.text, latex, number)
    if not ops:
        if isinstance(exprs[0], Reduce) and exprs[0].kind in ("min", "max"):  # \min_{\Theta} L: what training does
            return _failure(f"{OBJECTIVE} ({exprs[0].kind} over {exprs[0].index}), not an equation", piece, None,
                            "", latex, number)
        return _failure("no '=': an expression, not an equation", piece, None, "", latex, number)
    first = str(ops[0])
    bad = [op for op in ops if op.type != "REL" or str(op) in (r"\to", r"\rightarrow", r"\mapsto",
                                                               r"\leftarrow", r"\Rightarrow", r"\leftrightarrow")]
    if bad:
        op = bad[0]
        what = "an inequality or membership" if op.type in ("CMP", "IN") else "not an equality"
        return _failure(f"{what}, not an equation", piece, op.start_pos, str(op), latex, number)
    prop = next((op for op in ops if str(op) == r"\propto"), None)
    if prop is not None and len(ops) > 1:
        return _failure("a chain with a proportionality", piece, prop.start_pos, str(prop), latex, number)
    # a \propto b: a definition up to a constant factor; the binder takes the factor as 1 and says so
    relation = "propto" if first == r"\propto" else \
        (":=" if first in DEFINE_RELATIONS else ("~=" if first in APPROX_RELATIONS else "="))
    for e in exprs:
        if depth(e) > MAX_IR_DEPTH:
            return _failure(f"nested more than {MAX_IR_DEPTH} levels deep", piece, None, "", latex, number)
    equation = Equation(exprs[0], exprs[1], number, relation, latex, tuple(exprs[2:]))
    from .resolve import ResolveError, resolve

    try:
        return resolve(equation, conventions)
    except ResolveError as err:
        return ParseFailure(err.reason, None, err.fragment, latex, number)
    except RecursionError:
        return ParseFailure("nested too deeply", None, "", latex, number)


def _describe(err: BaseException) -> str:
    """An exception as a reason: its type and its message's first line (``ZeroDivisionError: ...``)."""
    message = " ".join(str(err).split())[:200]
    return f"{type(err).__name__}: {message}" if message else type(err).__name__


def parse_equations(latex: str, *, number: str | None = None,
                    conventions: Conventions = DEFAULT_CONVENTIONS) -> list[Equation | ParseFailure]:
    """Every equation of a displayed block (aligned rows, ``\\quad``-separated "where" clauses). Never raises
    for what a paper holds: anything the reader cannot take, an error of the reader itself included, is a
    ParseFailure with its reason (``could not read: ZeroDivisionError: ...``)."""
    try:
        return _parse_equations(str(latex or ""), number, conventions)
    except Exception as err:  # noqa: BLE001 - the per-equation boundary: the block's failure, the run goes on
        return [ParseFailure(f"could not read: {_describe(err)}", None, "", str(latex or "")[:MAX_CHARS], number)]


def _parse_equations(latex: str, number: str | None, conventions: Conventions) -> list[Equation | ParseFailure]:
    try:
        normalized = normalize(latex)
    except NormalizeError as err:
        return [ParseFailure(err.reason, err.column, err.fragment, latex, number)]
    number = number if number is not None else normalized.number
    if not normalized.pieces:
        return [ParseFailure("empty", None, "", latex, number)]
    if len(normalized.pieces) > MAX_EQUATIONS:
        return [ParseFailure(f"more than {MAX_EQUATIONS} equations in one block", None, "", latex, number)]
    return [_equation(_read_piece(piece, latex, number), piece, latex, number, conventions)
            for piece in normalized.pieces]


def parse_equation(latex: str, *, number: str | None = None,
                   conventions: Conventions = DEFAULT_CONVENTIONS) -> Equation | ParseFailure:
    """One equation -> Equation, or ParseFailure with the reason and the column (never a guess)."""
    results = parse_equations(latex, number=number, conventions=conventions)
    if len(results) > 1:
        first_failure = next((r for r in results if isinstance(r, ParseFailure)), None)
        if first_failure is not None:
            return first_failure
        return ParseFailure(f"{len(results)} equations in one block; parse_equations reads each", None, "",
                            latex, results[0].number)
    return results[0]


def parse_expression(latex: str) -> Expr | ParseFailure:
    """An expression without '=' (a symbol table entry, a right-hand side given alone); not resolved. Never
    raises for what a paper holds (as ``parse_equations``)."""
    try:
        return _parse_expression(str(latex or ""))
    except Exception as err:  # noqa: BLE001 - the per-expression boundary
        return ParseFailure(f"could not read: {_describe(err)}", None, "", str(latex or "")[:MAX_CHARS])


def _parse_expression(latex: str) -> Expr | ParseFailure:
    try:
        normalized = normalize(latex)
    except NormalizeError as err:
        return ParseFailure(err.reason, err.column, err.fragment, latex)
    if len(normalized.pieces) != 1:
        return ParseFailure("not one expression", None, "", latex)
    piece = normalized.pieces[0]
    parts = _read_piece(piece, latex, None)
    if isinstance(parts, ParseFailure):
        return parts
    if len(parts) != 1 or isinstance(parts[0], Word):
        return ParseFailure("a relation, not one expression", None, "", latex)
    if depth(parts[0]) > MAX_IR_DEPTH:
        return ParseFailure(f"nested more than {MAX_IR_DEPTH} levels deep", None, "", latex)
    return parts[0]
