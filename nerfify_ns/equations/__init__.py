"""Stage 2 (``equations``): the equation compiler: a paper's LaTeX -> IR -> a verified torch ``nn.Module``.

Offline, deterministic, no model. Binding symbols to Nerfstudio quantities and wiring the module into a
plugin's ``components/`` are the caller's (the binder's, ``nerfify_ns.synthesis.novel``) job; this package
reads, evaluates, lowers and checks.

API::

    from nerfify_ns.equations import parse_equation, interpret, lower, check_lowering

    eq = parse_equation(r"T_i = \\exp\\Big(-\\sum_{j=1}^{i-1} \\sigma_j \\delta_j\\Big)", number="3")
    # -> Equation(lhs=Symbol('T', index=Index('i')), rhs=Apply('exp', ...), number='3')
    # or ParseFailure: str(f) == "`\\mathcal{F}` unknown operator at column 12" (never a guess)
    eqs = parse_equations(block)            # every equation of an aligned block / "where" clause

    interpret(eqs, {"sigma": s, "delta": d})                 # numpy float64 -> {"T": [R, S]}
    source = lower(eqs, inputs={"sigma": ("R", "S"), "delta": ("R", "S"), "c": ("R", "S", 3)},
                   outputs=["C"], sizes={"W_gamma": (64, 32), "F": 32}, class_name="VolumeRender")
    lowered = lower_module(...)              # the source + identifier <-> symbol maps, parameters
    report = check_lowering(eqs, {"sigma": ("R", "S"), ...}, sizes)   # report.ok, str(report)

    # all at once, for a hole's equations: read, lower what the outputs need, check; never raises
    compiled = compile_equations([(latex, "1"), (latex2, "2")], inputs, outputs, sizes, "MediumRenderer")
    compiled.ok, compiled.reason, compiled.failures, compiled.source, compiled.lowered.names

Conventions (``shapes.py``): per-ray tensors are ``[R, ...]``, per-sample ``[R, S, ...]``; a sum over
samples sums dim 1; ``\\sum_{j<i}`` / ``\\prod_{j=1}^{i-1}`` are exclusive cumulative reductions along
the samples; learned matrices and vectors (``W``, ``b``) come from the caller's ``sizes``; ``delta``
(``Conventions.step``) is the step between samples, which integrals along the ray use as their
quadrature. Symbols are keyed as ``Symbol.key``: ``sigma``, ``W_Delta^f``, ``hat C``, ``cal L_recon``,
``h'_c``; a sample index is not part of the key (``\\sigma_i`` and ``\\sigma_j`` are both ``sigma``), nor
is the point a field is evaluated at (``C(\\mathbf{r})`` is ``C``).

Persistent state: a symbol that is both an input and defined (BioNeRF's memory
``\\Psi = \\tanh(W_\\Psi(\\mu + f_\\psi \\otimes \\Psi) + b_\\Psi)``) reads the given (previous) value on the right and
is returned as the new value; without it as an input, "defined in terms of itself" is an error.

Components: ``a_k`` inside a sum or product over the range of ``k`` is the k-th component of ``a``'s features
(``\\sum_{k=1}^{K} a_k \\mathbf{m}_k`` with a learned K x 3 ``m`` is ``a @ m``); ``softmax`` is over the features
(a temperature is the paper's division of its argument); a learned parameter may carry the paper's range
(``ParamSpec.clamp``: initialised inside it, projected onto it at every training step). ``\\min_{k=1}^{K} a_k`` and
``\\max_i x_i`` reduce that axis like an indexed sum (components, samples, rays); ``\\min_{\\Theta} L`` (over the
parameters) is the training objective, not a definition. ``q \\propto f`` defines ``q`` up to a constant factor
(relation 'propto'): lowered with the factor 1, which the binder records for the part.

Not supported (each refused with its reason): packed samples (segment sums over ragged rays), shifted
sample indices in evaluation (``t_{i+1}``: bind the quantity they define, e.g. ``delta``), reductions
over sets other than samples/rays/integer ranges, a running max/min (over earlier samples), a symbol indexed by
two range variables (``k_\\ell^m`` in a spherical-harmonics sum: read, but evaluation is refused; the binder binds the
basis), matrix literals, ellipses, factorials.

Modules, in the order of the pipeline:
    normalize.py   noise of converted papers -> clean LaTeX pieces (columns kept)
    grammar.lark   the grammar (LALR: linear time)
    parser.py      parse_equation(s): limits, lark, ParseFailure with reason and column
    reader.py      parse tree -> IR: the reading rules (calls vs products, labels vs powers, big operators)
    resolve.py     sample indices, what each sum/product runs over, integral quadratures
    ir.py          the IR dataclasses; render.py: the IR as one line of text
    shapes.py      layouts, sizes, parameters, the order equations are evaluated in
    interpret.py   numpy float64 interpreter (the oracle)
    naming.py      generated identifiers; lower.py: IR -> nn.Module source
    emit.py        the module's source around the lowered lines (fixed prelude and class text)
    check.py       check_lowering: module vs interpreter (rtol 1e-6) and gradcheck
    compile.py     compile_equations: the three steps for one hole
"""

from .check import CheckReport, check_lowering
from .compile import Compiled, compile_equations
from .interpret import interpret
from .ir import (
                 Apply,
                 BinOp,
                 Cases,
                 Compare,
                 Concat,
                 Conventions,
                 Equation,
                 Expectation,
                 Index,
                 Integral,
                 Neg,
                 Norm,
                 Number,
                 ParseFailure,
                 Reduce,
                 Symbol,
)
from .lower import Lowered, LoweringError, lower, lower_module
from .parser import parse_equation, parse_equations, parse_expression
from .shapes import CompileError, ParamSpec, ShapeError
from .show import show

__all__ = [
    "Apply", "BinOp", "Cases", "CheckReport", "Compare", "CompileError", "Compiled", "Concat", "Conventions",
    "Equation", "Expectation", "Index", "Integral", "Lowered", "LoweringError", "Neg", "Norm", "Number", "ParamSpec",
    "ParseFailure", "Reduce", "ShapeError", "Symbol", "check_lowering", "compile_equations", "interpret", "lower",
    "lower_module", "parse_equation", "parse_equations", "parse_expression", "show",
]
