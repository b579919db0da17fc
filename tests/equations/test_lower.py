"""Lowering to a readable nn.Module: its shape, its numerics, its errors; check_lowering's verdicts."""

from __future__ import annotations

import ast
import dataclasses

import numpy as np
import pytest
import torch

from nerfify_ns.equations import (
    CompileError,
    LoweringError,
    ParamSpec,
    ShapeError,
    check_lowering,
    lower,
    lower_module,
    parse_equation,
)
from nerfify_ns.equations import check as check_module

PER_SAMPLE = {"sigma": ("R", "S"), "delta": ("R", "S"), "c": ("R", "S", 3)}


def P(latex: str, number: str | None = None):
    eq = parse_equation(latex, number=number)
    assert eq, str(eq)
    return eq


def build(source: str, class_name: str):
    namespace: dict = {}
    exec(compile(source, "<test>", "exec"), namespace)
    return namespace[class_name]()


def test_the_module_reads_like_the_paper():
    eqs = [P(r"T_i = \exp\left(-\sum_{j=1}^{i-1} \sigma_j \delta_j\right)", "3"),
           P(r"\hat{C}(\mathbf{r}) = \sum_{i=1}^{N} T_i (1 - \exp(-\sigma_i \delta_i)) \mathbf{c}_i", "2")]
    lowered = lower_module(eqs, PER_SAMPLE, ["hat C"], {}, "VolumeRender")
    src = lowered.source
    ast.parse(src)
    lines = src.splitlines()
    forward = lines[[k for k, line in enumerate(lines) if "def forward" in line][0]:]
    assert forward[0].strip() == "def forward(self, v_sigma, v_delta, v_c):"
    assert forward[1].strip().startswith("# (3) T_i = exp(")
    assert forward[2].strip() == "v_t = torch.exp(-_exclusive_cumsum(v_sigma * v_delta, dim=1))"
    assert forward[3].strip().startswith("# (2) hat C(r) = sum_{i=1}^{N}")
    assert "torch.sum(" in forward[4] and forward[4].strip().endswith("dim=1)")
    assert forward[-1].strip() == "return v_hat_c"
    assert lowered.equations == ["3", "2"] and lowered.outputs == [("hat C", "v_hat_c")]
    assert lowered.names["v_t"] == "T"


def test_learned_parameters_are_named_after_their_symbols():
    eqs = [P(r"h = \mathrm{ReLU}(\mathbf{W}_\gamma \cdot \gamma(\mathbf{x}) + \mathbf{b}_\gamma)")]
    sizes = {"W_gamma": (5, 4), "b_gamma": (5,), "B": ParamSpec((2, 2), learned=False)}
    lowered = lower_module(eqs, {"gamma": ("R", 4)}, ["h"], sizes, "Layer")
    assert "self.p_w_gamma = nn.Parameter(torch.empty(5, 4))" in lowered.source
    assert "torch.nn.functional.linear(v_gamma, self.p_w_gamma) + self.p_b_gamma" in lowered.source
    assert "self.register_buffer('p_b', torch.empty(2, 2))" in lowered.source
    module = build(lowered.source, "Layer")
    assert {n for n, _ in module.named_parameters()} == {"p_w_gamma", "p_b_gamma"}
    assert [n for n, _ in module.named_buffers()] == ["p_b"]
    x = torch.randn(7, 4)
    torch.testing.assert_close(module(x), torch.relu(x @ module.p_w_gamma.T + module.p_b_gamma))


def test_products_over_earlier_samples_are_computed_in_log_space_where_they_underflow():
    exp_product = lower([P(r"T_i = \prod_{j<i} \exp(-\sigma_j \delta_j)")], PER_SAMPLE, ["T"], {}, "A")
    assert "torch.exp(_exclusive_cumsum(-(v_sigma * v_delta), dim=1))" in exp_product
    plain = lower([P(r"T_i = \prod_{j=1}^{i-1} (1 - \alpha_j)")], {"alpha": ("R", "S")}, ["T"], {}, "B")
    assert "_exclusive_cumprod(1.0 - v_alpha, dim=1)" in plain
    pairs = lower([P(r"L = \sum_i \sum_{j<i} w_i w_j |t_i - t_j|")], {"w": ("R", "S"), "t": ("R", "S")}, ["L"],
                  {}, "C")
    assert "_before_mask(n_samples, False, v_w)" in pairs and "n_samples = v_w.shape[1]" in pairs
    # float32, 400 samples of exp(-1): the direct product underflows to 0, the log-space one does not
    module = build(exp_product, "A")
    sigma = torch.ones(1, 400)
    out = module(sigma, torch.ones(1, 400), torch.zeros(1, 400, 3))
    assert out[0, -1] == 0.0 and torch.isfinite(out).all()
    torch.testing.assert_close(out[0, 1:50], torch.exp(-torch.arange(1.0, 50.0)))


def test_state_inputs_and_returned_tuples():
    eqs = [P(r"\Psi = \tanh(\mu + f \odot \Psi)", "7"), P(r"h = [\Psi, \mu]", "8")]
    lowered = lower_module(eqs, {"Psi": ("R", 2), "mu": ("R", 2), "f": ("R", 2)}, ["Psi", "h"], {}, "Memory")
    assert "v_psi_2 = torch.tanh(v_mu + v_f * v_psi)" in lowered.source
    assert "return v_psi_2, v_h" in lowered.source
    psi, h = build(lowered.source, "Memory")(torch.ones(3, 2), torch.zeros(3, 2), torch.ones(3, 2))
    assert h.shape == (3, 4) and torch.allclose(psi, torch.tanh(torch.ones(3, 2)))


def test_lowering_errors():
    with pytest.raises(CompileError, match="neither an input"):
        lower([P("y = x + z")], {"x": ("R",)}, ["y"])
    with pytest.raises(CompileError, match="in terms of itself"):
        lower([P(r"\Psi = \tanh(\Psi)")], {}, ["Psi"])
    with pytest.raises(ShapeError, match="matrix"):
        lower([P("h = W x")], {"x": ("R", 3)}, ["h"], {"W": (4, 5)})
    with pytest.raises(ShapeError, match="feature shapes"):
        lower([P("h = a + b")], {"a": ("R", 3), "b": ("R", 4)}, ["h"])
    with pytest.raises(ShapeError, match="layout"):
        lower([P("h = a")], {"a": ("S", "R")}, ["h"])
    with pytest.raises(ShapeError, match="sizes table"):
        lower([P("h = a")], {"a": ("R", "F")}, ["h"])
    with pytest.raises(LoweringError, match="range limit"):
        lower([P(r"y = \sum_{k=0}^{L} x")], {"x": ("R",), "L": ()}, ["y"])  # L must be a size, not a tensor


def test_check_lowering_reports_instead_of_raising():
    report = check_lowering([P("h = W x")], {"x": ("R", 3)}, {"W": (4, 5)})
    assert not report.ok and "matrix" in report.reason
    report = check_lowering([P(r"y = \log(x) + \sqrt{x}")], {"x": ("R", 2)})
    assert report.ok and report.gradcheck == "passed" and report.outputs[0].shape == (3, 2)


def _tampered(monkeypatch, old: str, new: str):
    real = check_module.lower_module

    def fake(*args, **kwargs):
        lowered = real(*args, **kwargs)
        assert old in lowered.source
        return dataclasses.replace(lowered, source=lowered.source.replace(old, new))

    monkeypatch.setattr(check_module, "lower_module", fake)


def test_check_lowering_catches_a_wrong_module(monkeypatch):
    eqs = [P(r"T_i = \exp\left(-\sum_{j<i} \sigma_j \delta_j\right)")]
    _tampered(monkeypatch, "torch.exp(-_exclusive_cumsum(", "torch.exp(-torch.cumsum(")  # inclusive, not exclusive
    report = check_lowering(eqs, PER_SAMPLE)
    assert not report.ok and "differs from the interpreter" in report.reason


def test_check_lowering_catches_a_wrong_gradient(monkeypatch):
    eqs = [P(r"y = \tanh(x) x")]
    _tampered(monkeypatch, "torch.tanh(v_x)", "torch.tanh(v_x).detach()")
    report = check_lowering(eqs, {"x": ("R", 2)})
    assert not report.ok and report.gradcheck.startswith("failed")


def test_float64_agreement_on_many_random_draws():
    eqs = [P(r"\alpha_i = 1 - \exp(-\sigma_i \delta_i)"), P(r"T_i = \prod_{j<i}(1 - \alpha_j)"),
           P(r"\hat{C} = \sum_i T_i \alpha_i \mathbf{c}_i")]
    for seed in range(5):
        report = check_lowering(eqs, PER_SAMPLE, outputs=["hat C"], seed=seed, n_rays=2, n_samples=9,
                                domains={"sigma": (0.0, 5.0)}, gradcheck=seed == 0)
        assert report.ok, str(report)
        assert np.max([o.max_rel for o in report.outputs]) < 1e-6


def test_compile_equations_reads_lowers_and_checks_a_hole():
    from nerfify_ns.equations import compile_equations

    latex = [(r"\alpha_i = 1 - \exp(-\sigma_i \delta_i)", "4"), (r"T_i = \prod_{j<i}(1 - \alpha_j)", "5"),
             (r"\hat{C} = \sum_i T_i \alpha_i \mathbf{c}_i", "6"), (r"y = \nabla x", "7")]
    compiled = compile_equations(latex, PER_SAMPLE, ["hat C"], class_name="Renderer")
    assert compiled.ok and compiled.report.gradcheck == "passed"
    assert [f.number for f in compiled.failures] == ["7"]  # not needed by the outputs: reported, not fatal
    assert "class Renderer(nn.Module)" in compiled.source
    broken = compile_equations(latex[:2] + [(r"\hat{C} = \sum_i T_i \mathcal{F}(\alpha_i + 1)", "6")],
                               PER_SAMPLE, ["hat C"])
    assert not broken.ok and "'hat C' is neither" in broken.reason and "unknown operator" in broken.reason


def test_nested_finite_ranges_with_limits_from_the_outer_range():
    eq = P(r"y = \sum_{\ell=0}^{L}\sum_{m=-\ell}^{\ell} (\ell + m^2) x")
    report = check_lowering([eq], {"x": ("R",)}, {"L": 3})
    assert report.ok and "for k_m in range(-k_ell, k_ell + 1):" in report.source
    want = sum(ell + m * m for ell in range(4) for m in range(-ell, ell + 1))
    module = build(report.source, "CheckedEquations")
    assert float(module(torch.ones(1, dtype=torch.float64))[0]) == want
