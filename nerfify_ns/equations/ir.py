"""The intermediate representation of an equation read from a paper (typed, immutable dataclasses).

Paper notation -> IR:

    \\sigma_i, \\mathbf{W}^f_{\\Delta}, \\hat{C}(\\mathbf{r})   Symbol(name, subscripts, superscript, decorations,
                                                          index, args)
    2, 0.5, 10^{-3}, \\pi                                   Number
    a + b, a - b, a b, a \\cdot b, a / b, a^2              BinOp('+' | '-' | '*' | '/' | '^')
    a \\odot b, a \\otimes b, a \\circ b                     BinOp('odot')   (element-wise, always)
    -a                                                    Neg
    \\exp(x), \\sigma(Wx+b), \\max(a, b), |x|, \\lceil x\\rceil  Apply(func, args)
    \\sum_{i=1}^{N}, \\prod_{j<i}                            Reduce(kind, index, lower, upper, condition, body)
    \\int_{t_n}^{t_f} ... dt                                Integral(var, lower, upper, body, quadrature)
    [a, b], \\left[a ; b\\right]                            Concat
    \\begin{cases} a & x > 0 \\\\ b & \\text{otherwise}       Cases(branches)
    \\mathbb{E}_{\\mathbf{r}} [...]                          Expectation
    \\|x\\|, \\|x\\|_2, \\|x\\|_1                                Norm(arg, order)
    lhs = rhs, lhs := rhs                                  Equation(lhs, rhs, number, relation)

``*`` between a weight matrix and a vector is a matrix-vector product: which one a ``*`` is follows from
the shapes (``interpret`` and ``lower`` decide it), never from the paper's words. The parser fills the
reading; ``resolve`` (run by ``parse_equation``) fills the meaning that depends on the whole equation:
which subscripts are sample indices (``Symbol.index``), what each reduction runs over (``Reduce.axis``,
``Reduce.mode``), and the quadrature of each integral.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

Expr = Union["Symbol", "Number", "BinOp", "Neg", "Apply", "Compare", "Reduce", "Integral", "Concat", "Cases",
             "Expectation", "Norm"]

#: functions ``Apply.func`` may name, with their arity (None: one or more)
FUNCTIONS: dict[str, int | None] = {
    "exp": 1, "log": 1, "sin": 1, "cos": 1, "tan": 1, "tanh": 1, "sigmoid": 1, "relu": 1, "softplus": 1,
    "abs": 1, "sqrt": 1, "ceil": 1, "floor": 1, "stopgrad": 1, "min": 2, "max": 2, "clamp": 3, "mse": 2, "softmax": 1,
}


@dataclass(frozen=True)
class Index:
    """A sample index on a symbol: ``\\sigma_j`` -> Index('j'); ``t_{i+1}`` -> Index('i', 1)."""

    var: str
    offset: int = 0


@dataclass(frozen=True)
class Symbol:
    """A named quantity: ``\\mathbf{W}^{f}_{\\Delta}`` is Symbol('W', ('Delta',), 'f').

    ``subscripts`` are labels that are part of the name (``W_1``, ``h_\\Delta``, ``t_n``); a subscript that
    is a sample index (bound by a sum, product or integral, or free on the left-hand side) is moved to
    ``index`` by ``resolve``. ``args`` holds the point a field is evaluated at (``C(\\mathbf{r})``,
    ``T(t)``, ``\\mathbf{c}(\\mathbf{r}(t), \\mathbf{d})``; parameters after a ';' are dropped): recorded,
    not part of the name. Decorations: hat, bar, tilde, dot, cal, bb, frak, prime.
    """

    name: str
    subscripts: tuple[str, ...] = ()
    superscript: str | None = None
    decorations: tuple[str, ...] = ()
    index: Index | None = None
    args: tuple[Expr, ...] = ()

    @property
    def key(self) -> str:
        """The name bindings use: 'sigma', 'W_Delta^f', 'hat C', 'sigma^obj', "h'_c", 'cal T^obj'."""
        prefix = "".join(f"{d} " for d in self.decorations if d != "prime")
        primes = "'" * sum(1 for d in self.decorations if d == "prime")
        sub = "_" + ",".join(self.subscripts) if self.subscripts else ""
        sup = "^" + self.superscript if self.superscript else ""
        return f"{prefix}{self.name}{primes}{sub}{sup}"


@dataclass(frozen=True)
class Number:
    """A literal (``text`` keeps how the paper wrote it: '\\pi', '10^{-3}')."""

    value: float
    text: str = ""


@dataclass(frozen=True)
class BinOp:
    """``op`` is '+', '-', '*', '/', '^' or 'odot' (element-wise product, written odot/otimes/circ)."""

    op: str
    left: Expr
    right: Expr


@dataclass(frozen=True)
class Neg:
    arg: Expr


@dataclass(frozen=True)
class Apply:
    """A known function applied to arguments (``FUNCTIONS``): ``\\sigma(W x + b)`` -> Apply('sigmoid')."""

    func: str
    args: tuple[Expr, ...]


@dataclass(frozen=True)
class Compare:
    """A condition: op is '<', '<=', '>', '>=', '==' or '!='."""

    op: str
    left: Expr
    right: Expr


@dataclass(frozen=True)
class Reduce:
    """``\\sum`` / ``\\prod`` over an index.

    As read: ``index``, ``lower`` (``i=1`` -> 1), ``upper`` (``^{N}``, ``^{i-1}``), ``condition``
    (``j<i``, ``r \\in \\mathcal{R}``). As resolved: ``axis`` is 'samples' (along each ray), 'rays' (over
    the batch of rays) or 'range' (a finite integer range, ``k = 0 .. L-1``); ``mode`` is 'full',
    'exclusive' (``j<i``, ``j=1..i-1``: over earlier samples) or 'inclusive' (``j<=i``); ``outer`` names
    the index a cumulative reduction is relative to (``i``).
    """

    kind: str
    index: str
    lower: Expr | None
    upper: Expr | None
    condition: Compare | None
    body: Expr
    axis: str = ""
    mode: str = "full"
    outer: str | None = None


@dataclass(frozen=True)
class Integral:
    """``\\int_{lower}^{upper} body \\, d var``; ``quadrature`` (set by ``resolve``) is the sum over
    samples it stands for, the expression ``interpret`` and ``lower`` evaluate."""

    var: str
    lower: Expr | None
    upper: Expr | None
    body: Expr
    quadrature: Expr | None = None
    rule: str = ""


@dataclass(frozen=True)
class Concat:
    """``[a, b]``: concatenation along the feature (last) dimension."""

    items: tuple[Expr, ...]


@dataclass(frozen=True)
class Cases:
    """``\\begin{cases}``: (value, condition) pairs in order; a condition None is 'otherwise'. The first
    branch whose condition holds gives the value; the last branch is the fallback (its condition, when the
    paper writes one, is taken to be the complement of the others)."""

    branches: tuple[tuple[Expr, Compare | None], ...]


@dataclass(frozen=True)
class Expectation:
    """``\\mathbb{E}_{\\mathbf{r}}[body]``: the mean over the batch of rays."""

    index: str
    body: Expr


@dataclass(frozen=True)
class Norm:
    """``\\|x\\|_p`` over the last (feature) dimension; ``order`` 2 unless subscripted."""

    arg: Expr
    order: float = 2.0


@dataclass(frozen=True)
class Equation:
    """``lhs = rhs`` (relation '=', ':=', '~=' for approx, or 'propto': lhs is rhs up to a constant factor);
    ``also``: further right-hand sides of a chain ``a = b = c``; ``number``: the paper's equation number;
    ``source``: the LaTeX as given."""

    lhs: Expr
    rhs: Expr
    number: str | None = None
    relation: str = "="
    source: str = ""
    also: tuple[Expr, ...] = ()
    free_index: str | None = None

    @property
    def defines(self) -> str | None:
        """The key of the symbol this equation defines (None when the left side is not a symbol)."""
        return self.lhs.key if isinstance(self.lhs, Symbol) else None


@dataclass(frozen=True)
class ParseFailure:
    """Why an equation could not be read: ``str(failure)`` is e.g. "`\\mathcal{F}` unknown operator at
    column 12". ``column`` is 1-based in the text as given (None when the reason is not at one place)."""

    reason: str
    column: int | None = None
    fragment: str = ""
    source: str = ""
    number: str | None = None

    def __str__(self) -> str:
        where = f" at column {self.column}" if self.column is not None else ""
        what = f"`{self.fragment}` " if self.fragment else ""
        return f"{what}{self.reason}{where}"

    def __bool__(self) -> bool:  # `if result:` reads as `if it parsed:`
        return False


@dataclass(frozen=True)
class Conventions:
    """Notation NeRF papers share that the reading relies on (never anything paper-specific).

    index_letters: subscripts read as sample indices when not bound by a sum (``T_i``);
    sample_counts: upper limits meaning "every sample on the ray" (``\\sum_{i=1}^{N}``);
    ray_params: bare arguments naming a position along the ray (``T(t)``);
    ray_sets / ray_indices: ``\\sum_{\\mathbf{r} \\in \\mathcal{R}}``, ``\\mathbb{E}_{\\mathbf{r}}``;
    density / transmittance / step: the symbols of the volume-rendering quadrature (``\\sigma``, ``T``,
    ``\\delta``): an integral of T sigma X dt becomes sum_i T_i (1 - exp(-sigma_i delta_i)) X_i.
    """

    index_letters: tuple[str, ...] = ("i", "j", "k")
    sample_counts: tuple[str, ...] = ("N", "N_s", "N_c", "N_f", "N_samples")
    ray_params: tuple[str, ...] = ("t", "s")
    ray_sets: tuple[str, ...] = ("R",)
    ray_indices: tuple[str, ...] = ("r",)
    density: tuple[str, ...] = ("sigma",)
    transmittance: tuple[str, ...] = ("T",)
    step: str = "delta"


DEFAULT_CONVENTIONS = Conventions()


def children(expr: Expr) -> tuple[Expr, ...]:
    """The direct sub-expressions of a node (the quadrature of an integral, not its reading)."""
    if isinstance(expr, Symbol):
        return expr.args
    if isinstance(expr, BinOp | Compare):
        return (expr.left, expr.right)
    if isinstance(expr, Neg | Norm):
        return (expr.arg,)
    if isinstance(expr, Apply):
        return expr.args
    if isinstance(expr, Reduce):
        parts = [p for p in (expr.lower, expr.upper, expr.condition) if p is not None]
        return (*parts, expr.body)
    if isinstance(expr, Integral):
        if expr.quadrature is not None:
            return (expr.quadrature,)
        return tuple(p for p in (expr.lower, expr.upper, expr.body) if p is not None)
    if isinstance(expr, Concat):
        return expr.items
    if isinstance(expr, Cases):
        return tuple(p for branch in expr.branches for p in branch if p is not None)
    if isinstance(expr, Expectation):
        return (expr.body,)
    return ()


def walk(expr: Expr):
    """Every node of an expression, pre-order (iterative: no recursion limit on long chains)."""
    stack = [expr]
    while stack:
        node = stack.pop()
        yield node
        stack.extend(reversed(children(node)))


def depth(expr: Expr) -> int:
    """The nesting depth of an expression tree (iterative)."""
    best, stack = 0, [(expr, 1)]
    while stack:
        node, d = stack.pop()
        best = max(best, d)
        stack.extend((c, d + 1) for c in children(node))
    return best


def symbols(expr: Expr) -> list[Symbol]:
    return [n for n in walk(expr) if isinstance(n, Symbol)]




def map_nodes(expr, fn):
    """``expr`` rebuilt bottom-up with ``fn`` applied to every expression node (a node's fields that are nodes or
    tuples of nodes are rebuilt first; an unchanged node is kept as it is)."""
    import dataclasses

    def go(node):
        if isinstance(node, tuple):
            new = tuple(go(n) for n in node)
            return node if all(a is b for a, b in zip(new, node, strict=True)) else new
        if not dataclasses.is_dataclass(node) or isinstance(node, type | Index):
            return node
        changes = {}
        for f in dataclasses.fields(node):
            value = getattr(node, f.name)
            if isinstance(value, tuple) or dataclasses.is_dataclass(value):
                new = go(value)
                if new is not value:
                    changes[f.name] = new
        return fn(dataclasses.replace(node, **changes) if changes else node)

    return go(expr)


def substitute(expr: Expr, mapping: dict[str, Expr]) -> Expr:
    """``expr`` with every plain occurrence of a key of ``mapping`` (no sample index, no arguments) replaced by its
    expression: a function the paper defines with a dummy argument (``P(x) = ...``) applied to another (``P(T)``)."""
    return map_nodes(expr, lambda n: mapping[n.key] if isinstance(n, Symbol) and n.index is None and not n.args
                     and n.key in mapping else n)


def function_definition(call: Symbol, options: list[Equation]) -> tuple[Equation, tuple[Symbol, ...]] | None:
    """The definition ``f(x) = ...`` (or ``\\propto``) of a function applied as ``f(y)``: its left side takes plain
    dummy arguments, as many as the call, each read on its right side, and the call puts other quantities in."""
    for eq in options:
        lhs = eq.lhs
        if not isinstance(lhs, Symbol) or len(lhs.args) != len(call.args) or not lhs.args:
            continue
        params = lhs.args
        if not all(isinstance(p, Symbol) and not (p.args or p.subscripts or p.superscript or p.index)
                   for p in params):
            continue
        used = {n.key for n in walk(eq.rhs) if isinstance(n, Symbol)}
        if not all(p.key in used for p in params) or any(p.key in _ALONG_RAY for p in params):
            continue  # a field of the position along the ray (T(t)): its quadrature is resolve's, not a function
        if any(isinstance(a, Symbol) and a.key in _POINTS for a in call.args):
            continue  # a field read at a point (c(x), T(s_i), C(r)): the point a field is evaluated at
        if all(isinstance(a, Symbol) and a.key == p.key and a.index is None
               for a, p in zip(call.args, params, strict=True)):
            continue  # applied at its own argument: the definition itself
        return eq, params
    return None


_ALONG_RAY = DEFAULT_CONVENTIONS.ray_params + DEFAULT_CONVENTIONS.ray_indices
_POINTS = _ALONG_RAY + ("x", "d", "p")
"""Arguments that name where a field is evaluated (a position along the ray, a ray, a point, a direction), not a
quantity a function is applied to."""

MAX_INLINE_DEPTH = 4
"""How deep functions defined by functions are put in (a definition that calls itself stops there)."""


def inline_functions(expr: Expr, definitions: dict[str, list[Equation]]):
    """``expr`` with each application ``f(y)`` of a function the equations define with a dummy argument
    (``f(x) = ...``) replaced by that definition with ``y`` put in for ``x``; returns (expr, [(call, definition,
    dummy arguments), ...])."""
    applied: list = []

    def visit(node):
        if isinstance(node, Symbol) and node.args:
            hit = function_definition(node, definitions.get(node.key) or [])
            if hit is not None:
                definition, params = hit
                applied.append((node, definition, params))
                return substitute(definition.rhs, {p.key: a for p, a in zip(params, node.args, strict=True)})
        return node

    for _ in range(MAX_INLINE_DEPTH):
        before = len(applied)
        expr = map_nodes(expr, visit)
        if len(applied) == before:
            break
    return expr, applied
