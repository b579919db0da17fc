"""The parser is bounded: input length, nesting depth, big operators, IR depth; linear time on hostile input."""

from __future__ import annotations

import random
import time

import pytest

from nerfify_ns.equations import Equation, ParseFailure, parse_equation, parse_equations
from nerfify_ns.equations.normalize import MAX_BIG_OPERATORS, MAX_CHARS, MAX_DEPTH
from nerfify_ns.equations.parser import MAX_IR_DEPTH


def test_inputs_longer_than_the_limit_are_refused_at_once():
    failure = parse_equation("y = " + "x + " * (MAX_CHARS // 4) + "x")
    assert isinstance(failure, ParseFailure) and "longer than" in failure.reason


def test_nesting_deeper_than_the_limit_is_refused_with_its_column():
    deep = "y = " + "(" * (MAX_DEPTH + 1) + "x" + ")" * (MAX_DEPTH + 1)
    failure = parse_equation(deep)
    assert isinstance(failure, ParseFailure) and "nested deeper" in failure.reason
    assert failure.column == 4 + MAX_DEPTH + 1
    ok = "y = " + "(" * (MAX_DEPTH - 1) + "x" + ")" * (MAX_DEPTH - 1)
    assert isinstance(parse_equation(ok), Equation)
    bars = parse_equation("y = " + "|" * 200)
    assert isinstance(bars, ParseFailure)


def test_big_operators_and_deep_expression_trees_are_bounded():
    many = parse_equation("y = " + r"\sum_i " * (MAX_BIG_OPERATORS + 1) + "x_i")
    assert isinstance(many, ParseFailure) and "sums, products or integrals" in many.reason
    chain = parse_equation("y = " + r"\exp " * (MAX_IR_DEPTH + 5) + "x")
    assert isinstance(chain, ParseFailure) and f"more than {MAX_IR_DEPTH} levels" in chain.reason
    long_sum = parse_equation("y = " + "+".join(["x"] * (MAX_IR_DEPTH + 5)))
    assert isinstance(long_sum, ParseFailure)


def _hostile(n: int, seed: int = 0) -> dict[str, str]:
    rng = random.Random(seed)
    alphabet = list("{}()[]|^_,;&=+-*/\\ab12 ") + [r"\frac", r"\sum", r"\left(", r"\|", r"\mathrm{", r"\text{if}"]
    return {
        "long product": "y = " + "a" * n,
        "long chain": "y = " + "x_1 " * (n // 4),
        "bars": "y = " + "|a" * (n // 2),
        "norm bars": "y = " + r"\|" * (n // 2),
        "open braces": "y = " + "{" * n,
        "scripts": "y = x" + "_1" * (n // 2),
        "unclosed labels": r"\label{" * (n // 7),
        "unclosed tags": (r"\tag{" + "a" * 30) * (n // 40),
        "fractions": "y = " + r"\frac" * (n // 5),
        "commas": "y = " + "a," * (n // 2),
        "rows": "y = " + r"a \\" * (n // 4),
        "random": "".join(rng.choice(alphabet) for _ in range(n // 3)),
    }


@pytest.mark.parametrize("name", list(_hostile(100)))
def test_hostile_input_is_answered_quickly_and_in_linear_time(name):
    def timed(text: str) -> float:
        start = time.perf_counter()
        results = parse_equations(text)
        elapsed = time.perf_counter() - start
        assert results and all(isinstance(r, Equation | ParseFailure) for r in results)
        return elapsed

    small, large = _hostile(MAX_CHARS // 8)[name], _hostile(MAX_CHARS - 100)[name]
    assert len(large) <= MAX_CHARS
    t_small = min(timed(small) for _ in range(2))
    t_large = min(timed(large) for _ in range(2))
    assert t_large < 2.5, f"{name}: {t_large:.3f} s"  # generous: CI machines are shared
    # linear: 8x the input takes about 8x the time (quadratic would be 64x)
    assert t_large < 20 * t_small + 0.1, f"{name}: {t_small:.4f} s -> {t_large:.4f} s for 8x the input"
