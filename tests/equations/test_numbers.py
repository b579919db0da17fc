"""Numbers in every notation papers use are read as numbers, in one place (equations/normalize.py: read_numbers),
by the equation reader, the paper's LaTeX normaliser and the hyperparameter reader alike; constants the reader
folds never raise (0^{-2}, overflow, complex powers are ParseFailures with their reason)."""

from __future__ import annotations

import math

import pytest

from nerfify_ns.equations import Equation, Number, ParseFailure, parse_equation, parse_equations, parse_expression
from nerfify_ns.equations.ir import BinOp, walk
from nerfify_ns.equations.normalize import normalize_latex, normalize_numbers
from nerfify_ns.paper.hyperparams import extract_from_sentence, split_sentences


def value(latex: str) -> float:
    """The value of a constant expression as the reader folds it (products of numbers multiplied here)."""
    expr = parse_expression(latex)
    assert not isinstance(expr, ParseFailure), f"{latex!r}: {expr}"

    def ev(e):
        if isinstance(e, Number):
            return e.value
        assert isinstance(e, BinOp) and e.op in ("*", "/"), f"{latex!r} is not a constant: {e}"
        a, b = ev(e.left), ev(e.right)
        return a * b if e.op == "*" else a / b

    return ev(expr)


NOTATIONS = {
    r"1 \times 10^{-2}": 0.01,
    r"1 \times 1 0 ^ { - 2 }": 0.01,          # MinerU: every token spaced
    "5 1 2": 512,
    "0 . 0 0 1": 0.001,
    "1e-2": 0.01,
    "5E-4": 0.0005,
    "1 e - 3": 0.001,                        # MinerU's spaced e-notation
    "10^{-2}": 0.01,
    r"5\cdot10^{-4}": 0.0005,
    "5\u22c510\u207b\u2074": 0.0005,          # 5⋅10⁻⁴: dot operator, unicode superscripts
    "10\u207b\u00b3": 0.001,                  # 10⁻³
    "10^{\u22123}": 0.001,                     # the minus sign U+2212
    r"8\,192": 8192,                          # a thin space between thousands
    "8\u2009192": 8192,                       # the Unicode thin space
    "2^{19}": 524288,
    "2\u00b9\u2079": 524288,                  # 2¹⁹
    "3e-40": 3e-40,                           # past the decimal form: folded as 3 x 10^-40
}


@pytest.mark.parametrize("latex", list(NOTATIONS))
def test_each_notation_reads_as_its_number(latex):
    assert value(latex) == pytest.approx(NOTATIONS[latex], rel=1e-12)


def test_the_number_reader_keeps_what_is_not_one_number():
    assert normalize_numbers(r"x^2 3") == r"x^2 3"            # TeX takes one character as the script
    assert normalize_numbers(r"\frac 1 2") == r"\frac 1 2"    # ... and as \frac's argument
    assert normalize_numbers(r"x_{1 2}") == r"x_{12}"         # a braced script is MinerU's spaced 12
    assert normalize_numbers("x\u00b2\u1d62") == "x^{2}_{i}"  # x²ᵢ
    assert normalize_numbers("2e") == "2e" and normalize_numbers("e-2") == "e-2"
    # prose: only thin spaces join digits; spaced digits in words stay apart
    assert normalize_numbers("batch of 8\u2009192 rays, views 1 2", math=False) == "batch of 8192 rays, views 1 2"


def test_an_equation_with_mineru_numbers_reads():
    eq = parse_equation(r"\mathcal{L} = \mathcal{L}_{c} + 1 \times 1 0 ^ { - 2 } \, \mathcal{L}_{d}")
    assert isinstance(eq, Equation)
    numbers = [n.value for n in walk(eq.rhs) if isinstance(n, Number)]
    assert numbers == [1.0, pytest.approx(0.01)]


@pytest.mark.parametrize("latex, reason", [
    (r"y = 0^{-2}", "divides by zero"),
    (r"y = 1 \times 0 ^ { - 2 }", "divides by zero"),
    (r"y = 10^{400}", "too large"),
    (r"y = 2^{2^{100}}", "too large"),
    (r"y = (-8)^{0.5}", "not a real number"),
    ("y = " + "9" * 60, "digits"),
])
def test_constants_that_cannot_be_folded_are_refused_with_a_reason(latex, reason):
    (result,) = parse_equations(latex)
    assert isinstance(result, ParseFailure) and reason in result.reason
    assert isinstance(parse_expression(latex.split("=", 1)[1]), ParseFailure)


def test_infinity_is_still_read():
    assert math.isinf(parse_expression(r"\infty").value)
    assert isinstance(parse_equation(r"y = \int_{0}^{\infty} x \, dt"), Equation)


@pytest.mark.parametrize("sentence, name, expected", [
    (r"We use a learning rate of $1 \times 1 0 ^ { - 2 }$.", "learning_rate", 0.01),
    (r"We use a batch size of $5 1 2$ rays.", "batch_size", 512),
    (r"The learning rate is $0 . 0 0 1$.", "learning_rate", 0.001),
    ("The learning rate is 1e-2.", "learning_rate", 0.01),
    (r"a learning rate of $10^{-2}$", "learning_rate", 0.01),
    (r"a learning rate of $5\cdot10^{-4}$", "learning_rate", 0.0005),
    ("a learning rate of 5 \u00d7 10\u22124", "learning_rate", 0.0005),      # 5 × 10−4 (a PDF's text layer)
    ("a learning rate of 10\u207b\u00b3", "learning_rate", 0.001),            # 10⁻³
    ("a batch of 8\u2009192 rays", "batch_size", 8192),
    ("a hash table size of 2\u00b9\u2079", "hash_table_size", 524288),        # 2¹⁹
    (r"a hash table of $T = 2^{19}$ entries", "log2_hashmap_size", 19),
])
def test_hyperparameters_in_every_notation(sentence, name, expected):
    found = {h.name: h.value for h in extract_from_sentence(sentence)}
    assert found.get(name) == pytest.approx(expected), found


def test_a_period_inside_inline_math_does_not_end_a_sentence():
    text = r"We decay the learning rate to $0 . 0 0 1$. Next we train. $x$ is a point."
    assert split_sentences(text) == [r"We decay the learning rate to $0 . 0 0 1$.", "Next we train.",
                                     "$x$ is a point."]


def test_the_paper_normaliser_reads_numbers_as_the_equation_reader_does():
    mineru = normalize_latex(r"\lambda = 1 \times 1 0 ^ { - 2 }")
    assert "10^{" in mineru and "1 0" not in mineru and value(mineru.split("=")[1]) == pytest.approx(0.01)
    assert normalize_latex(r"L = \sum_{ i = 1 }^{ 5 1 2 } x_{i}").endswith("^{512} x_{i}")
    assert normalize_latex("y = 10\u207b\u00b3 x") == "y = 10^{-3} x"
