"""The parse tree of an equation -> IR: the reading rules of NeRF papers' notation (see ``parser.py``).

A term is a list of pieces (symbols, numbers, function names, parenthesised groups) combined in three passes:
``X(...)`` calls (a field at a point, the sigmoid, or a product), function application (``\\exp x``,
``\\max(a, b)``), then the product (juxtaposition, ``\\cdot``, ``/``, ``\\odot``). Scripts decide labels against
powers (``W^f`` against ``x^2``). Every refusal is a ``ReadError`` with its position.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from lark import Token, Transformer, v_args

from .ir import (
    FUNCTIONS,
    Apply,
    BinOp,
    Cases,
    Compare,
    Concat,
    Expectation,
    Expr,
    Integral,
    Neg,
    Norm,
    Number,
    Reduce,
    Symbol,
)

FUNCTION_WORDS = {
    "exp": "exp", "log": "log", "ln": "log", "sin": "sin", "cos": "cos", "tan": "tan", "tanh": "tanh",
    "sigmoid": "sigmoid", "relu": "relu", "softplus": "softplus", "abs": "abs", "sqrt": "sqrt", "ceil": "ceil",
    "floor": "floor", "min": "min", "max": "max", "clamp": "clamp", "clip": "clamp", "sg": "stopgrad",
    "stopgrad": "stopgrad", "mse": "mse", "softmax": "softmax",
}
_CASE_WORDS = {"if", "otherwise", "else", "when", "for", "where"}
_DECORATIONS = {"hat": "hat", "widehat": "hat", "bar": "bar", "overline": "bar", "underline": "bar",
                "tilde": "tilde", "widetilde": "tilde", "dot": "dot", "ddot": "ddot", "mathcal": "cal",
                "mathscr": "cal", "mathbb": "bb", "mathfrak": "frak", "check": "check", "breve": "breve",
                "acute": "acute"}
_OPERATOR_DECORATIONS = {"cal", "bb", "frak"}
_GREEK_ALIASES = {"varepsilon": "epsilon", "varphi": "phi", "vartheta": "theta", "varrho": "rho",
                  "varsigma": "sigma"}
_COMPARE = {"<": "<", ">": ">", r"\lt": "<", r"\gt": ">", r"\le": "<=", r"\leq": "<=", r"\leqslant": "<=",
            r"\ge": ">=", r"\geq": ">=", r"\geqslant": ">=", r"\ne": "!=", r"\neq": "!=", "=": "=="}
DEFINE_RELATIONS = {":=", r"\coloneqq", r"\triangleq", r"\doteq", r"\equiv"}
APPROX_RELATIONS = {r"\approx", r"\simeq"}
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9]{0,31}")
_LABEL = re.compile(r"[A-Za-z0-9'*+\-(),]{1,32}")
_LABEL_SUP = re.compile(r"\([A-Za-z0-9+\-]{1,12}\)|[A-Za-z]+|\(?\\[A-Za-z]+\)?"
                        r"|\\(?:mathrm|text|textrm|mathsf|operatorname|mbox)\{[^{}]*\}|\*|'+|\\prime|\\top")
"""A superscript that labels rather than raises to a power (``x^{(k)}``, ``c^{\\mathrm{obj}}``, ``W^{\\top}``)."""
_OPERAND_TYPES = (Symbol, Number, BinOp, Neg, Apply, Reduce, Integral, Concat, Cases, Expectation, Norm)
"""What may stand after a binary operator."""


class ReadError(Exception):
    """A reason not to read, at a position of the normalised text."""

    def __init__(self, reason: str, pos: int | None = None, fragment: str = ""):
        super().__init__(reason)
        self.reason, self.pos, self.fragment = reason, pos, fragment


# --- pieces of a term before it is a product -------------------------------------------------------------

@dataclass
class _Func:
    name: str
    pos: int
    text: str
    power: Expr | None = None


@dataclass
class _Paren:
    items: tuple
    seps: tuple
    kind: str
    pos: int
    power: Expr | None = None


@dataclass
class Word:
    text: str
    pos: int


@dataclass
class _SArg:
    items: list            # Expr or _Rel per comma-separated item
    raw: str               # the script's text, for labels
    pos: int
    token: Token | None = None


@dataclass
class _Rel:
    items: list
    ops: list


def _pos(node) -> int:
    if isinstance(node, Token):
        return node.start_pos or 0
    return getattr(node, "start_pos", 0) or 0


def _label(raw: str, pos: int) -> str:
    """A subscript/superscript as a label: '\\mathrm{obj}' -> 'obj', '\\Delta' -> 'Delta', '(k)' -> '(k)'."""
    text = re.sub(r"\\(?:mathrm|text|textrm|textit|mathsf|operatorname|mbox|rm|mathit)\s*\{([^{}]*)\}", r"\1", raw)
    text = text.replace(r"\prime", "'").replace(r"\top", "T").replace(r"\intercal", "T")
    text = re.sub(r"\\([A-Za-z]+)", lambda m: _GREEK_ALIASES.get(m.group(1), m.group(1)), text)
    text = re.sub(r"[\s{}]", "", text)
    if not _LABEL.fullmatch(text):
        raise ReadError("unreadable subscript or superscript", pos, raw[:40])
    return text


def _is_label_sup(sarg: _SArg) -> bool:
    """A superscript that labels a symbol (W^f, c^{med}, x^{(k)}, h', C^*) rather than raises it."""
    raw = re.sub(r"\s", "", sarg.raw)
    if sarg.token is not None:
        return sarg.token.type in ("LETTERS", "GREEK", "ROMAN", "STAR", "PRIMECMD", "TOP")
    return bool(_LABEL_SUP.fullmatch(raw)) and raw not in (r"\pi", r"\infty")


def _as_point(expr) -> bool:
    """Is an argument a point (a symbol, a field at a point, a number) rather than an expression?"""
    return isinstance(expr, Symbol | Number)


def _product(items: list[tuple[str | None, object, int]]) -> Expr:
    ops = {None: "*", "*": "*", r"\cdot": "*", r"\times": "*", r"\ast": "*", r"\bullet": "*", "/": "/",
           r"\odot": "odot", r"\otimes": "odot", r"\circ": "odot"}
    first_op, result, pos = items[0]
    if first_op is not None:
        raise ReadError("an operator without a left operand", pos, first_op)
    for op, value, pos in items[1:]:
        if not isinstance(value, _OPERAND_TYPES):
            raise ReadError("cannot be read here", pos, type(value).__name__)
        result = BinOp(ops[op], result, value)
    return result


MAX_NUMBER_DIGITS = 40
"""A number literal of more digits is refused (a paper's constants have a few; a long run is noise)."""


def fold_power(base: float, exponent: float) -> float:
    """``base ** exponent`` for constants the paper writes (``10^{-2}``, ``2^{19}``), or a ReadError that says
    why not: a division by zero (``0^{-2}``), a result too large for a float, or not a real number
    (``(-8)^{1/2}``). Never raises anything else."""
    text = f"{base:g}^{exponent:g}"
    if base == 0 and exponent < 0:
        raise ReadError("a constant that divides by zero", None, text)
    try:
        value = float(base) ** float(exponent)
    except ZeroDivisionError:
        raise ReadError("a constant that divides by zero", None, text) from None
    except OverflowError:
        raise ReadError("a constant too large for a float", None, text) from None
    if isinstance(value, complex):
        raise ReadError("a constant that is not a real number", None, text)
    if math.isnan(value) or (math.isinf(value) and not (math.isinf(base) or math.isinf(exponent))):
        raise ReadError("a constant too large for a float", None, text)
    return value


def _literal(text: str, pos: int | None = None) -> float:
    """A number token's value, refused when it is too long to be a paper's constant."""
    digits = sum(ch.isdigit() for ch in text)
    if digits > MAX_NUMBER_DIGITS:
        raise ReadError(f"a number of more than {MAX_NUMBER_DIGITS} digits", pos, text[:20] + "...")
    return float(text)


def _power(base: Expr, exponent: Expr) -> Expr:
    if isinstance(base, Number) and isinstance(exponent, Number):
        value = fold_power(float(base.value), float(exponent.value))
        return Number(value, f"{base.text or base.value}^{exponent.value:g}")
    return BinOp("^", base, exponent)


@v_args(meta=True)
class Reader(Transformer):
    """Parse tree -> IR (with the conventions of the module docstring)."""

    def __init__(self, text: str):
        super().__init__()
        self.text = text

    # --- relations and sums --------------------------------------------------------------------------------
    def start(self, meta, children):
        return children

    def relop(self, meta, children):
        return children[0]

    def sitem(self, meta, children):
        if len(children) == 1:
            return children[0]
        return _Rel([c for c in children if not isinstance(c, Token)],
                    [str(c) for c in children if isinstance(c, Token)])

    def sum(self, meta, children):
        sign = None
        if isinstance(children[0], Token):
            sign, children = str(children[0]), children[1:]
        result = children[0]
        if isinstance(result, Word) and len(children) == 1 and sign is None:
            return result
        result = self._expr(result)
        if sign == "-":
            result = Number(-result.value, result.text and "-" + result.text) if isinstance(result, Number) \
                else Neg(result)
        for op, term in zip(children[1::2], children[2::2], strict=False):
            result = BinOp(str(op), result, self._expr(term))
        return result

    def _expr(self, value):
        if isinstance(value, Word):
            return _product([(None, Symbol(value.text[0]), value.pos)]
                            + [(None, Symbol(ch), value.pos) for ch in value.text[1:]])
        return value

    # --- terms: products, calls, functions -----------------------------------------------------------------
    def term(self, meta, children):
        seq: list[list] = []  # [op, value, pos]
        pending_op = None
        for child in children:
            if isinstance(child, Token):  # MULOP / STAR
                if pending_op is not None:
                    raise ReadError("two operators in a row", _pos(child), str(child))
                pending_op = str(child)
                continue
            pieces = child if isinstance(child, list) else [(child, meta.end_pos if meta else 0)]
            for k, (value, pos) in enumerate(pieces):
                seq.append([pending_op if k == 0 else None, value, pos])
            pending_op = None
        if pending_op is not None:
            raise ReadError("an operator without a right operand", None, pending_op)
        if len(seq) == 1 and isinstance(seq[0][1], Word):
            return seq[0][1]
        for item in seq:
            if isinstance(item[1], Word):
                item[1] = self._expr(item[1])
        seq = self._calls(seq)
        seq = self._functions(seq)
        for item in seq:
            value, pos = item[1], item[2]
            if isinstance(value, _Paren):
                item[1] = self._group(value)
        return _product([tuple(item) for item in seq])

    def _calls(self, seq):
        out = []
        i = 0
        while i < len(seq):
            op, value, pos = seq[i]
            nxt = seq[i + 1] if i + 1 < len(seq) else None
            if (isinstance(value, Symbol) and nxt is not None and nxt[0] is None and isinstance(nxt[1], _Paren)
                    and nxt[1].kind == "("):
                paren: _Paren = nxt[1]
                merged = self._call(value, paren, pos)
                if merged is not None:
                    if paren.power is not None:
                        merged = _power(merged, paren.power)
                    out.append([op, merged, pos])
                    i += 2
                    continue
            out.append([op, value, pos])
            i += 1
        return out

    def _call(self, symbol: Symbol, paren: _Paren, pos: int):
        items = paren.items
        if ";" in paren.seps:  # C(r; Theta, t): the point, then the parameters (dropped: not a point)
            items = items[:paren.seps.index(";") + 1]
        point = len(items) > 1 or _as_point(items[0])
        if symbol.args:
            return None  # C(r)(...) : a product
        plain = not (symbol.subscripts or symbol.superscript or symbol.decorations)
        if symbol.name == "sigma" and plain and not point:
            return Apply("sigmoid", items)
        if point:
            if len(items) > 8:
                raise ReadError("a field evaluated at more than 8 arguments", paren.pos, "(")
            return Symbol(symbol.name, symbol.subscripts, symbol.superscript, symbol.decorations, None,
                          tuple(items))
        bare = not (symbol.subscripts or symbol.superscript)
        operator_like = bool(set(symbol.decorations) & _OPERATOR_DECORATIONS) or (
            len(symbol.name) > 1 and symbol.name not in _GREEK_NAMES)
        if bare and operator_like:
            raise ReadError("unknown operator", pos, _latex_name(symbol))
        return None  # a product: T_i (1 - alpha_i)

    def _functions(self, seq):
        if len(seq) == 1 and isinstance(seq[0][1], _Func) and seq[0][1].power is None:
            return [[seq[0][0], Symbol(seq[0][1].name), seq[0][2]]]  # \ell_{\max}: a name, not a call
        out: list = []
        for op, value, pos in reversed(seq):
            if isinstance(value, _Func):
                if not out or out[-1][0] is not None:
                    raise ReadError("a function without an argument", pos, value.text)
                _, arg, _ = out.pop()
                post_power = None
                if isinstance(arg, _Paren) and arg.kind == "(":
                    args, post_power = arg.items, arg.power
                    if any(sep == ";" for sep in arg.seps):
                        raise ReadError("arguments separated by ';'", arg.pos, ";")
                elif isinstance(arg, _Paren):
                    args = (self._group(arg),)
                else:
                    args = (arg,)
                arity = FUNCTIONS[value.name]
                if arity is not None and len(args) != arity:
                    if value.name in ("min", "max") and len(args) == 1:
                        raise ReadError(f"{value.name} of one argument (a reduction) is not read", pos, value.text)
                    raise ReadError(f"{value.name} takes {arity} argument(s), got {len(args)}", pos, value.text)
                result: Expr = Apply(value.name, tuple(args))
                if value.power is not None:
                    result = _power(result, value.power)
                if post_power is not None:
                    result = _power(result, post_power)
                out.append([op, result, pos])
            else:
                out.append([op, value, pos])
        out.reverse()
        return out

    def _group(self, paren: _Paren) -> Expr:
        if paren.kind == "[" and len(paren.items) > 1:
            if paren.power is not None:
                raise ReadError("a power of a concatenation", paren.pos, "]^")
            return Concat(tuple(paren.items))
        if len(paren.items) > 1:
            raise ReadError("a tuple is not read as a value", paren.pos, "(")
        inner = paren.items[0]
        return _power(inner, paren.power) if paren.power is not None else inner

    # --- factors and scripts -------------------------------------------------------------------------------
    def factor(self, meta, children):
        primary, scripts = children[0], children[1:]
        pieces = primary if isinstance(primary, list) else [(primary, meta.start_pos)]
        if scripts:
            value, pos = pieces[-1]
            pieces = pieces[:-1] + [(self._scripts(value, pos, scripts), pos)]
        return pieces

    def sub(self, meta, children):
        return ("sub", children[-1])

    def sup(self, meta, children):
        return ("sup", children[-1])

    def prime(self, meta, children):
        return ("prime", len(str(children[0])))

    def _scripts(self, value, pos, scripts):
        sups = [arg for kind, arg in scripts if kind == "sup"]
        subs = [arg for kind, arg in scripts if kind == "sub"]
        for extra in (sups[1:2] or subs[1:2]):
            raise ReadError("a double superscript or subscript (x^a^b)", extra.pos, "^" if sups[1:2] else "_")
        for kind, arg in scripts:
            if kind == "prime":
                if not isinstance(value, Symbol):
                    raise ReadError("a prime on an expression", pos, "'")
                value = Symbol(value.name, value.subscripts, value.superscript,
                               value.decorations + ("prime",) * arg, value.index, value.args)
            elif isinstance(value, Symbol) and not value.args:
                value = self._symbol_script(value, kind, arg, pos)
            elif kind == "sup" and re.sub(r"[\s{}]", "", arg.raw) in (r"\top", r"\intercal", "T"):
                pass  # the transpose of a vector: features are last either way
            elif isinstance(value, _Func):
                if kind == "sub":
                    raise ReadError(f"a {value.name} over an index is not read", pos, value.text + "_")
                value.power = self._sarg_expr(arg)
            elif isinstance(value, _Paren):
                if kind == "sub":
                    raise ReadError("a subscript on a parenthesised expression", arg.pos, "_")
                value.power = self._sarg_expr(arg)
            elif isinstance(value, Norm) and kind == "sub":
                value = Norm(value.arg, self._norm_order(arg))
            elif isinstance(value, Apply) and value.func == "abs" and kind == "sub":
                value = Norm(value.args[0], self._norm_order(arg))  # |x|_2: a norm written with single bars

            elif kind == "sup":
                value = _power(value, self._sarg_expr(arg))
            else:
                raise ReadError("a subscript on an expression", arg.pos, "_")
        return value

    def _norm_order(self, arg: _SArg) -> float:
        raw = re.sub(r"[\s{}]", "", arg.raw)
        if raw in ("1", "2"):
            return float(raw)
        if raw in (r"\infty", "inf"):
            return math.inf
        raise ReadError("a norm order other than 1, 2 or infinity", arg.pos, raw[:20])

    def _symbol_script(self, symbol: Symbol, kind: str, arg: _SArg, pos: int):
        if kind == "sub":
            label = _label(arg.raw, arg.pos)
            return Symbol(symbol.name, symbol.subscripts + (label,), symbol.superscript, symbol.decorations)
        plain_e = symbol.name == "e" and not (symbol.subscripts or symbol.superscript or symbol.decorations)
        if plain_e:
            return Apply("exp", (self._sarg_expr(arg),))
        if _is_label_sup(arg):
            label = _label(arg.raw, arg.pos)
            if label == "'" * len(label):
                return Symbol(symbol.name, symbol.subscripts, symbol.superscript,
                              symbol.decorations + ("prime",) * len(label))
            if symbol.superscript:
                raise ReadError("two superscript labels", arg.pos, label)
            return Symbol(symbol.name, symbol.subscripts, label, symbol.decorations)
        return _power(symbol, self._sarg_expr(arg))

    def _sarg_expr(self, arg: _SArg) -> Expr:
        if len(arg.items) != 1 or isinstance(arg.items[0], _Rel):
            raise ReadError("expected one expression", arg.pos, arg.raw[:20])
        return self._expr(arg.items[0])

    def sarg(self, meta, children):
        if len(children) == 2:  # SIGN NUMBER
            sign, num = children
            value = _literal(str(num), _pos(num)) * (-1 if str(sign) == "-" else 1)
            return _SArg([Number(value, str(sign) + str(num))], str(sign) + str(num), _pos(sign))
        child = children[0]
        if isinstance(child, Token):
            pieces = self._token_primary(child)
            expr = self._expr(pieces[0][0]) if len(pieces) == 1 and not isinstance(pieces[0][0], _Func) \
                else None
            if len(pieces) > 1:
                expr = _product([(None, v, p) for v, p in pieces])
            return _SArg([expr] if expr is not None else [], str(child), _pos(child), child)
        items, raw_pos = child
        return _SArg(items, self.text[raw_pos[0]:raw_pos[1]], raw_pos[0])

    def sempty(self, meta, children):
        return _SArg([], "", meta.start_pos if meta and not meta.empty else 0)

    def sbody(self, meta, children):
        span = (meta.start_pos, meta.end_pos)
        if len(children) == 1 and isinstance(children[0], Token):  # * \prime \top
            return [], span
        return [c for c in children if not isinstance(c, Token)], span

    def _token_primary(self, tok: Token) -> list:
        kind = tok.type
        if kind == "NUMBER":
            return [(Number(_literal(str(tok), _pos(tok)), str(tok)), _pos(tok))]
        if kind == "LETTERS":
            return self._letters(tok)
        if kind == "GREEK":
            return [(self._greek(tok), _pos(tok))]
        if kind == "CONST":
            return [(self._const(tok), _pos(tok))]
        if kind == "ROMAN":
            return self._roman(tok)
        return [(Symbol(str(tok)), _pos(tok))]

    # --- primaries -----------------------------------------------------------------------------------------
    def number(self, meta, children):
        return Number(_literal(str(children[0]), _pos(children[0])), str(children[0]))

    def letters(self, meta, children):
        return self._letters(children[0])

    def _letters(self, tok):
        word, pos = str(tok), _pos(tok)
        if len(word) > 1 and word.lower() in FUNCTION_WORDS:
            return [(_Func(FUNCTION_WORDS[word.lower()], pos, word), pos)]
        if word.lower() in _CASE_WORDS:
            return [(Word(word, pos), pos)]
        return [(Symbol(ch), pos + k) for k, ch in enumerate(word)]

    def greek(self, meta, children):
        return self._greek(children[0])

    def _greek(self, tok):
        name = str(tok)[1:]
        return Symbol(_GREEK_ALIASES.get(name, name))

    def const(self, meta, children):
        return self._const(children[0])

    def _const(self, tok):
        name = str(tok)
        return Number(math.pi, r"\pi") if name == r"\pi" else Number(math.inf, r"\infty")

    def roman(self, meta, children):
        return self._roman(children[0])

    def _roman(self, tok):
        content = re.sub(r"\s", "", str(tok)[str(tok).index("{") + 1:-1])
        pos = _pos(tok)
        if content.lower() in FUNCTION_WORDS:
            return [(_Func(FUNCTION_WORDS[content.lower()], pos, str(tok)), pos)]
        if not _NAME.fullmatch(content):
            raise ReadError("unreadable name", pos, content[:40])
        return [(Symbol(content), pos)]

    def func(self, meta, children):
        tok = children[0]
        name = str(tok)[1:]
        return [(_Func(FUNCTION_WORDS.get(name, name), _pos(tok), str(tok)), _pos(tok))]

    def decorated(self, meta, children):
        tok, arg = children
        decoration = _DECORATIONS[str(tok)[1:]]
        if arg.token is not None and arg.token.type == "LETTERS":
            word = str(arg.token)
            first = Symbol(word[0], decorations=(decoration,))
            return [(first, _pos(tok))] + [(Symbol(ch), _pos(arg.token) + k + 1) for k, ch in enumerate(word[1:])]
        if len(arg.items) != 1 or not isinstance(arg.items[0], Symbol) or arg.items[0].args:
            raise ReadError(f"\\{str(tok)[1:]} over an expression is not read", _pos(tok), str(tok))
        inner: Symbol = arg.items[0]
        return [(Symbol(inner.name, inner.subscripts, inner.superscript, (decoration,) + inner.decorations),
                 _pos(tok))]

    def args(self, meta, children):
        items = tuple(self._expr(c) for c in children if not isinstance(c, Token))
        seps = tuple(str(c) for c in children if isinstance(c, Token))
        return items, seps, meta.start_pos

    def paren(self, meta, children):
        items, seps, _ = [c for c in children if isinstance(c, tuple)][0]
        return [(_Paren(items, seps, "(", meta.start_pos), meta.start_pos)]

    def bracket(self, meta, children):
        items, seps, _ = children[0]
        return [(_Paren(items, seps, "[", meta.start_pos), meta.start_pos)]

    def brace(self, meta, children):
        items, seps, pos = children[0]
        if len(items) != 1:
            raise ReadError("a set {a, b} is not read as a value", pos, "{")
        return [(items[0], pos)]

    def frac(self, meta, children):
        _, num, den = children
        return BinOp("/", self._sarg_expr(num), self._sarg_expr(den))

    def sqrt(self, meta, children):
        degree = children[1] if len(children) == 3 else None
        arg = self._sarg_expr(children[-1])
        if degree is None:
            return Apply("sqrt", (arg,))
        return BinOp("^", arg, BinOp("/", Number(1.0, "1"), degree))

    def norm(self, meta, children):
        return Norm(children[1])

    def abs(self, meta, children):
        return Apply("abs", (children[1],))

    def ceil(self, meta, children):
        return Apply("ceil", (children[1],))

    def floor(self, meta, children):
        return Apply("floor", (children[1],))

    def case_rows(self, meta, children):
        return [c for c in children if not isinstance(c, Token)]

    def case_row(self, meta, children):
        value = children[0]
        if isinstance(value, _Rel):
            raise ReadError("a case value that is a relation", meta.start_pos, "&")
        rest = [c for c in children[1:] if not (isinstance(c, Token) and c.type in ("AMP", "SEP"))]
        words = [str(c) for c in rest if isinstance(c, Token)]
        conds = [c for c in rest if not isinstance(c, Token)]
        if not conds or all(isinstance(c, Word) for c in conds):
            spoken = " ".join(words + [c.text for c in conds if isinstance(c, Word)]).lower()
            if not conds and not words:
                return (self._expr(value), None)
            if any(w in spoken for w in ("otherwise", "else")):
                return (self._expr(value), None)
            raise ReadError("a case condition that is not a comparison", meta.start_pos, spoken[:30])
        cond = conds[0]
        if not isinstance(cond, _Rel) or len(cond.ops) != 1 or cond.ops[0] not in _COMPARE:
            raise ReadError("a case condition that is not one comparison", meta.start_pos, "&")
        return (self._expr(value), Compare(_COMPARE[cond.ops[0]], cond.items[0], cond.items[1]))

    def cases(self, meta, children):
        rows = children[1]
        if sum(1 for _, cond in rows if cond is None) > 1 or any(c is None for _, c in rows[:-1]):
            raise ReadError("'otherwise' must be the last case, once", meta.start_pos, r"\begin{cases}")
        return Cases(tuple(rows))

    def matrix_rows(self, meta, children):
        return [c for c in children if not isinstance(c, Token)]

    def matrix_row(self, meta, children):
        items = [c for c in children if not isinstance(c, Token)]
        if len(items) != 1 or isinstance(items[0], _Rel):
            raise ReadError("matrix literals are not read (only column vectors)", meta.start_pos, "&")
        return self._expr(items[0])

    def matrix(self, meta, children):
        return Concat(tuple(children[1]))

    def ellipsis(self, meta, children):
        raise ReadError("an ellipsis is not a finite expression", _pos(children[0]), str(children[0]))

    def unknown_cmd(self, meta, children):
        raise ReadError("unknown operator", _pos(children[0]), str(children[0]))

    # --- big operators -------------------------------------------------------------------------------------
    def bigop(self, meta, children):
        op, scripts, body = str(children[0]), children[1:-1], children[-1]
        body = self._expr(body)
        subs = [arg for kind, arg in scripts if kind == "sub"]
        sups = [arg for kind, arg in scripts if kind == "sup"]
        if any(kind == "prime" for kind, _ in scripts) or len(subs) > 1 or len(sups) > 1:
            raise ReadError("unreadable limits", meta.start_pos, op)
        sub, sup = (subs[0] if subs else None), (sups[0] if sups else None)
        if op in (r"\int", r"\oint"):
            return self._integral(body, sub, sup, meta.start_pos)
        if op == r"\mathbb{E}":
            if sup is not None:
                raise ReadError("a superscript on an expectation", sup.pos, "^")
            index = "r"
            if sub is not None:
                item = sub.items[0] if len(sub.items) == 1 else None
                var = item.items[0] if isinstance(item, _Rel) and item.ops[0] in (r"\sim", r"\in") else item
                index = self._index_name(var, sub.pos)
            return Expectation(index, body)
        kind = {r"\sum": "sum", r"\prod": "prod", r"\min": "min", r"\max": "max"}[op]
        upper = self._sarg_expr(sup) if sup is not None else None
        if sub is None:
            return Reduce(kind, "", None, upper, None, body)
        specs = []
        if kind in ("min", "max") and not all(isinstance(i, _Rel) or _is_index(i) for i in sub.items):
            raise ReadError(f"{OBJECTIVE} ({kind} over the parameters {sub.raw[:30]}), not an equation",
                            meta.start_pos, op + "_")
        for item in sub.items:
            if isinstance(item, _Rel):
                if len(item.ops) != 1:
                    raise ReadError("a chained range is not read", sub.pos, sub.raw[:30])
                var, rel, rhs = item.items[0], item.ops[0], item.items[1]
                name = self._index_name(var, sub.pos)
                if rel == "=":
                    specs.append((name, self._expr(rhs), None))
                elif rel in _COMPARE:
                    specs.append((name, None, Compare(_COMPARE[rel], Symbol(name), self._expr(rhs))))
                elif rel in (r"\in", r"\sim"):
                    specs.append((name, None, Compare("in", Symbol(name), self._expr(rhs))))
                else:
                    raise ReadError("unreadable range", sub.pos, sub.raw[:30])
            else:
                specs.append((self._index_name(item, sub.pos), None, None))
        if not specs:
            raise ReadError("a range that is not an index", sub.pos, op + "_{" + sub.raw[:20] + "}")
        # \sum_{i,j=1}^{N}: the bound of the last applies to every bare index before it
        last_lower = specs[-1][1]
        result = body
        for name, lower, cond in reversed(specs):
            result = Reduce(kind, name, lower if lower is not None or cond is not None else last_lower,
                            upper, cond, result)
        return result

    def _index_name(self, var, pos) -> str:
        if _is_index(var):
            return var.name + "'" * len(var.decorations)  # k' is its own index
        raise ReadError("an index that is not a single variable", pos, "_")

    def _integral(self, body, sub, sup, pos) -> Integral:
        factors = []
        node = body
        while isinstance(node, BinOp) and node.op == "*":
            factors.insert(0, node.right)
            node = node.left
        factors.insert(0, node)
        var, rest = None, factors
        for at in (len(factors) - 2, 0):
            if 0 <= at and at + 1 < len(factors):
                d, v = factors[at], factors[at + 1]
                if (isinstance(d, Symbol) and d.name == "d" and not (d.subscripts or d.superscript or d.args)
                        and isinstance(v, Symbol) and not (v.subscripts or v.superscript or v.args)):
                    var, rest = v.name, factors[:at] + factors[at + 2:]
                    break
        if var is None:
            raise ReadError("an integral without its differential (d t)", pos, r"\int")
        integrand: Expr = Number(1.0, "1")
        if rest:
            integrand = rest[0]
            for f in rest[1:]:
                integrand = BinOp("*", integrand, f)
        lower = self._sarg_expr(sub) if sub is not None else None
        upper = self._sarg_expr(sup) if sup is not None else None
        return Integral(var, lower, upper, integrand)


def _is_index(var) -> bool:
    return (isinstance(var, Symbol) and not var.subscripts and not var.superscript and not var.args
            and set(var.decorations) <= {"prime"})


OBJECTIVE = "a training objective"
"""The reason for ``\\min_{\\Theta} L`` (what training minimises over the parameters): read as no definition."""

_GREEK_NAMES = {
    "alpha", "beta", "gamma", "delta", "epsilon", "zeta", "eta", "theta", "iota", "kappa", "lambda", "mu", "nu",
    "xi", "rho", "sigma", "tau", "upsilon", "phi", "chi", "psi", "omega", "Gamma", "Delta", "Theta", "Lambda",
    "Xi", "Pi", "Sigma", "Upsilon", "Phi", "Psi", "Omega", "ell",
}


def _latex_name(symbol: Symbol) -> str:
    name = "\\" + symbol.name if symbol.name in _GREEK_NAMES else symbol.name
    for d in symbol.decorations:
        command = {"cal": "mathcal", "bb": "mathbb", "frak": "mathfrak"}.get(d, d)
        if d != "prime":
            name = f"\\{command}{{{name}}}"
    return name
