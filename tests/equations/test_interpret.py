"""The numpy interpreter: the conventions of layouts and sample axes, and its errors."""

from __future__ import annotations

import numpy as np
import pytest

from nerfify_ns.equations import CompileError, ShapeError, interpret, parse_equation

rng = np.random.default_rng(0)
R, S = 3, 6


def P(latex: str):
    eq = parse_equation(latex)
    assert eq, str(eq)
    return eq


def test_layouts_are_inferred_from_the_equations():
    sigma, delta = rng.uniform(0.1, 1, (R, S)), rng.uniform(0.1, 1, (R, S))
    c_med = rng.uniform(0, 1, (R, 3))
    out = interpret([P(r"w_i = \sigma_i \delta_i c^{med}")], {"sigma": sigma, "delta": delta, "c^med": c_med})
    np.testing.assert_allclose(out["w"], (sigma * delta)[..., None] * c_med[:, None, :])  # per ray -> [R, 1, 3]
    out = interpret([P(r"y = 2 \lambda x")], {"lambda": np.float64(0.5), "x": np.ones((R, 2))})
    np.testing.assert_allclose(out["y"], np.ones((R, 2)))  # a 0-d binding is a scalar


def test_sums_over_samples_rays_and_ranges():
    x = rng.normal(size=(R, S))
    out = interpret([P(r"y = \sum_i x_i"), P(r"z = \sum_{i=1}^{N} 2"), P(r"a = \sum_{\mathbf{r}\in\mathcal{R}} y"),
                     P(r"m = \mathbb{E}_{\mathbf{r}} [y]"), P(r"q = \prod_{k=1}^{K} k")],
                    {"x": x}, sizes={"K": 4})
    np.testing.assert_allclose(out["y"], x.sum(1))
    assert out["z"] == 2 * S
    np.testing.assert_allclose(out["a"], x.sum())
    np.testing.assert_allclose(out["m"], x.sum(1).mean())
    assert out["q"] == 24.0


def test_exclusive_and_inclusive_cumulative_reductions_follow_their_definition():
    x = rng.uniform(0.1, 0.9, (R, S))
    out = interpret([P(r"a_i = \sum_{j<i} x_j"), P(r"b_i = \sum_{j=1}^{i} x_j"), P(r"c_i = \prod_{j=1}^{i-1} x_j"),
                     P(r"d_i = \prod_{j \le i} x_j")], {"x": x})
    np.testing.assert_allclose(out["a"], np.cumsum(x, 1) - x)
    np.testing.assert_allclose(out["b"], np.cumsum(x, 1))
    np.testing.assert_allclose(out["c"], np.cumprod(x, 1) / x)
    np.testing.assert_allclose(out["d"], np.cumprod(x, 1))


def test_a_bare_per_sample_symbol_takes_the_index_in_scope():
    x = rng.uniform(size=(R, S))
    out = interpret([P(r"y = \sum_i x"), P(r"\alpha = 1 - \exp(-x)")], {"x": x}, layout={"x": ("R", "S")})
    np.testing.assert_allclose(out["y"], x.sum(1))
    np.testing.assert_allclose(out["alpha"], 1 - np.exp(-x))  # per-sample result, no index written


def test_persistent_state_reads_the_previous_value():
    psi, mu = rng.normal(size=(R, 4)), rng.normal(size=(R, 4))
    out = interpret([P(r"\Psi = \tanh(\mu + \Psi)")], {"Psi": psi, "mu": mu})
    np.testing.assert_allclose(out["Psi"], np.tanh(mu + psi))
    with pytest.raises(CompileError, match="in terms of itself"):
        interpret([P(r"\Psi = \tanh(\mu + \Psi)")], {"mu": mu})


def test_errors_name_the_equation_and_the_cause():
    with pytest.raises(CompileError, match="neither an input"):
        interpret([P(r"y = x + z")], {"x": np.ones((R, 1))})
    with pytest.raises(CompileError, match="shifted"):
        interpret([P(r"\delta_i = t_{i+1} - t_i")], {"t": np.ones((R, S))})
    with pytest.raises(ShapeError, match="matrix"):
        interpret([P(r"h = W x")], {"W": np.ones((4, 5)), "x": np.ones((R, 3))}, sizes={"W": (4, 5)})
    with pytest.raises(ShapeError, match="disagree"):
        interpret([P(r"y = \sum_i a_i b_i")], {"a": np.ones((R, S)), "b": np.ones((R, S + 1))})
    with pytest.raises(ShapeError, match="per sample"):
        interpret([P(r"y = \sum_i a_i")], {"a": np.ones(R)})
    with pytest.raises(CompileError, match="defined twice"):
        interpret([P("y = x"), P("y = 2 x")], {"x": np.ones((R,))})
    with pytest.raises(CompileError, match="cycle"):
        interpret([P("y = z"), P("z = y")], {})
