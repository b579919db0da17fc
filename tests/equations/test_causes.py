"""Operators and constraints the compiler reads, one per cause, each with an equation written for this test and
checked against torch code written by hand (values and gradients), through the one compile path."""

from __future__ import annotations

import pytest
import torch

from nerfify_ns.equations import Equation, ParseFailure, compile_equations, parse_equation, parse_equations


def _run(compiled, *args, params: dict | None = None):
    namespace: dict = {}
    exec(compile(compiled.source, "<compiled>", "exec"), namespace)  # noqa: S102 - our own generated source
    module = namespace[compiled.lowered.class_name]().double()
    with torch.no_grad():
        for key, value in (params or {}).items():
            attr, _ = compiled.lowered.params[key]
            getattr(module, attr).copy_(value)
    return module, module(*args)


def _grads_match(got, want, inputs):
    g1 = torch.autograd.grad(got.sum(), inputs, retain_graph=True)
    g2 = torch.autograd.grad(want.sum(), inputs, retain_graph=True)
    for a, b in zip(g1, g2, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)


def test_softmax_with_a_temperature_over_the_components():
    compiled = compile_equations([(r"\mathbf{a} = \operatorname{softmax}(\mathbf{z} / \tau)", "1")],
                                 {"z": ("R", 5), "tau": ("R",)}, ["a"])
    assert compiled.ok, compiled.reason
    z = torch.randn(4, 5, dtype=torch.float64, requires_grad=True)
    tau = torch.rand(4, dtype=torch.float64, requires_grad=True) + 0.5
    _, got = _run(compiled, z, tau)
    want = torch.exp(z / tau[:, None]) / torch.exp(z / tau[:, None]).sum(dim=-1, keepdim=True)
    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    _grads_match(got, want, (z, tau))


def test_a_softmax_of_one_number_per_element_is_refused_with_its_reason():
    compiled = compile_equations([r"a = \mathrm{softmax}(x)"], {"x": ("R",)}, ["a"])
    assert not compiled.ok and "softmax over a quantity without features" in compiled.reason


def test_constraints_sigmoid_softplus_exp_clamp_and_normalise():
    latex = [(r"\mathbf{g} = \mathrm{sigmoid}(\mathbf{x}) \odot \mathrm{softplus}(\mathbf{x}) "
              r"+ \exp(-\mathbf{x})", "1"),
             (r"\mathbf{y} = \mathrm{clamp}(\mathbf{g}, 0, 1)", "2"),
             (r"\mathbf{n} = \frac{\mathbf{x}}{\lVert \mathbf{x} \rVert_2}", "3")]
    compiled = compile_equations(latex, {"x": ("R", 3)}, ["y", "n"])
    assert compiled.ok, compiled.reason
    x = torch.randn(6, 3, dtype=torch.float64, requires_grad=True)
    _, (y, n) = _run(compiled, x)
    g = torch.sigmoid(x) * torch.nn.functional.softplus(x) + torch.exp(-x)
    torch.testing.assert_close(y, torch.clamp(g, 0.0, 1.0), rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(n, x / x.norm(dim=-1, keepdim=True), rtol=1e-10, atol=1e-12)
    _grads_match(n, x / x.norm(dim=-1, keepdim=True), (x,))


def test_a_learned_dictionary_mixes_its_signatures_by_softmax_abundances():
    """K learned signatures (a matrix) mixed by abundances a softmax with a temperature gives."""
    latex = [(r"\mathbf{a} = \operatorname{softmax}(\mathbf{z} / \tau)", "1"),
             (r"\mathbf{c} = \mathrm{clamp}(\mathbf{M} \mathbf{a}, 0, 1)", "2")]
    compiled = compile_equations(latex, {"z": ("R", 4), "tau": ("R",)}, ["c"], {"M": (3, 4)})
    assert compiled.ok, compiled.reason
    m = torch.rand(3, 4, dtype=torch.float64)
    z = torch.randn(5, 4, dtype=torch.float64, requires_grad=True)
    tau = torch.full((5,), 0.7, dtype=torch.float64)
    module, got = _run(compiled, z, tau, params={"M": m})
    want = torch.clamp(torch.softmax(z / 0.7, dim=-1) @ m.T, 0.0, 1.0)
    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    got.sum().backward()
    assert all(p.grad is not None for p in module.parameters())


@pytest.mark.parametrize("text,value", [(r"1.5\times10^{-2}", 0.015), (r"5 \cdot 10^{-4}", 5e-4),
                                        (r"\frac{1}{3}", 1 / 3), (r"10^{3}", 1000.0), (r"0.25", 0.25),
                                        (r"2^{-1}", 0.5)])
def test_numbers_in_every_notation(text, value):
    compiled = compile_equations([rf"y = {text} x"], {"x": ("R",)}, ["y"])
    assert compiled.ok, compiled.reason
    x = torch.rand(3, dtype=torch.float64)
    _, got = _run(compiled, x)
    torch.testing.assert_close(got, value * x, rtol=1e-12, atol=0.0)


def test_equations_already_read_compile_through_the_same_path():
    eq = parse_equation(r"y = \exp(\beta x)", number="4")
    assert isinstance(eq, Equation)
    compiled = compile_equations([eq], {"x": ("R",)}, ["y"], {"beta": ()})
    assert compiled.ok, compiled.reason
    x = torch.rand(3, dtype=torch.float64)
    _, got = _run(compiled, x, params={"beta": torch.tensor(0.5, dtype=torch.float64)})
    torch.testing.assert_close(got, torch.exp(0.5 * x))


def test_indexed_sums_and_products_over_components_and_levels():
    """a_k inside a sum over k is the k-th component of a's features; m_k of a learned K x 3 dictionary its k-th
    signature; a product over levels multiplies the components."""
    latex = [(r"y = \sum_{k=1}^{K} a_k s_k", "1"), (r"\mathbf{c} = \sum_{k=1}^{K} a_k \mathbf{m}_k", "2"),
             (r"p = \prod_{l=0}^{K-1} s_l", "3")]
    compiled = compile_equations(latex, {"a": ("R", 4), "s": ("R", 4)}, ["y", "c", "p"], {"K": 4, "m": (4, 3)})
    assert compiled.ok, compiled.reason
    a = torch.rand(5, 4, dtype=torch.float64, requires_grad=True)
    s = torch.rand(5, 4, dtype=torch.float64, requires_grad=True)
    m = torch.rand(4, 3, dtype=torch.float64)
    module, (y, c, p) = _run(compiled, a, s, params={"m": m})
    torch.testing.assert_close(y, (a * s).sum(dim=-1), rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(c, a @ m, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(p, s.prod(dim=-1), rtol=1e-10, atol=1e-12)
    _grads_match(y + p, (a * s).sum(dim=-1) + s.prod(dim=-1), (a, s))
    c.sum().backward()
    assert all(q.grad is not None and torch.isfinite(q.grad).all() for q in module.parameters())


def test_a_component_past_the_features_is_refused():
    compiled = compile_equations([r"y = \sum_{k=1}^{K} a_k"], {"a": ("R", 3)}, ["y"], {"K": 5})
    assert not compiled.ok and ("past its 3 features" in compiled.reason or "out of range" in compiled.reason)


def test_a_min_and_a_max_over_a_range_of_components_reduce_that_axis():
    """``\\min_{k=1}^{K} a_k``: the elementwise min over the k-th components, like an indexed sum; gradients flow to
    the component each min (max) picks."""
    latex = [(r"m = \min_{k=1}^{K} a_k", "1"), (r"y = \max_{k=1}^{K} (a_k s_k) - m", "2")]
    compiled = compile_equations(latex, {"a": ("R", 4), "s": ("R", 4)}, ["y"], {"K": 4})
    assert compiled.ok, compiled.reason
    a = torch.randn(6, 4, dtype=torch.float64, requires_grad=True)
    s = torch.randn(6, 4, dtype=torch.float64, requires_grad=True)
    _, got = _run(compiled, a, s)
    want = (a * s).amax(dim=-1) - a.amin(dim=-1)
    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    _grads_match(got, want, (a, s))


def test_a_max_over_the_samples_of_a_ray_is_a_reduction_over_the_sample_axis():
    compiled = compile_equations([(r"D(\mathbf{r}) = \max_{i} \sigma_i t_i", "1")],
                                 {"sigma": ("R", "S"), "t": ("R", "S")}, ["D"])
    assert compiled.ok, compiled.reason
    sigma = torch.rand(5, 7, dtype=torch.float64, requires_grad=True)
    t = torch.rand(5, 7, dtype=torch.float64, requires_grad=True)
    _, got = _run(compiled, sigma, t)
    want = (sigma * t).amax(dim=1)
    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    _grads_match(got, want, (sigma, t))


def test_a_min_over_the_parameters_is_a_training_objective_not_a_definition():
    """``\\min_{\\Theta}`` over a body the reader would refuse (``;`` arguments, ``\\cup``): still the objective."""
    (failure,) = parse_equations(r"\min_{\Theta} \sum_{r} \lVert C(r; \Theta, t^c \cup t^f) \rVert_2^2")
    assert isinstance(failure, ParseFailure) and "a training objective" in failure.reason
    (failure,) = parse_equations(r"\min_{\Theta} \sum_{\mathbf{r}} \lVert C(\mathbf{r}) - C^*(\mathbf{r}) \rVert_2^2")
    assert isinstance(failure, ParseFailure) and "a training objective" in failure.reason
    (failure,) = parse_equations(r"\min_{\Theta^{c}, \Theta^{f}} \mathcal{L}")
    assert isinstance(failure, ParseFailure) and "a training objective" in failure.reason


def test_a_proportionality_defines_its_left_side_with_the_factor_one_and_says_so():
    """``q(x) \\propto ...`` then ``-log q``: the definition up to a constant factor; the factor is taken as 1 (a
    constant under the logarithm shifts the loss, not its gradient), and the binder's record says so."""
    eqs = parse_equations(r"q(u) \propto e^{-u^2/0.5} + e^{-|2-u|/0.25}, \quad \mathcal{L}_q = -\log q(u)")
    assert [type(e).__name__ for e in eqs] == ["Equation", "Equation"] and eqs[0].relation == "propto"
    compiled = compile_equations(eqs, {"u": ("R",)}, ["cal L_q"])
    assert compiled.ok, compiled.reason
    u = torch.rand(8, dtype=torch.float64, requires_grad=True)
    _, got = _run(compiled, u)
    want = -torch.log(torch.exp(-u**2 / 0.5) + torch.exp(-(2 - u).abs() / 0.25))
    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    _grads_match(got, want, (u,))
    assert not isinstance(parse_equations(r"a \propto b = c")[0], Equation)  # a chain: refused with its reason


def test_a_function_defined_with_a_dummy_argument_is_applied_to_the_quantity_the_paper_puts_in():
    """``q(u) \\propto ...`` read at ``q(v_i)`` and ``q(w_i)``: the definition with each put in for ``u``
    (per sample), never ``q`` evaluated at an input named ``u``."""
    latex = [(r"q(u) \propto e^{-u^2/0.5} + e^{-|2-u|/0.25}, \quad \mathcal{L}_q = -\log q(v_i) + q(w_i)", "3")]
    compiled = compile_equations(latex, {"v": ("R", "S"), "w": ("R", "S")}, ["cal L_q"])
    assert compiled.ok, compiled.reason

    def q(u):
        return torch.exp(-u**2 / 0.5) + torch.exp(-(2 - u).abs() / 0.25)

    v = torch.rand(4, 6, dtype=torch.float64, requires_grad=True)
    w = torch.rand(4, 6, dtype=torch.float64, requires_grad=True)
    _, got = _run(compiled, v, w)
    want = -torch.log(q(v)) + q(w)
    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    _grads_match(got, want, (v, w))


@pytest.mark.parametrize("text,value", [(r"1{,}000", 1000.0), (r"1\,000", 1000.0), (r"12{,}345{,}678", 12345678.0),
                                        (r"2\,048", 2048.0), (r"\frac{1}{1{,}000}", 1e-3)])
def test_numbers_with_a_thousands_separator(text, value):
    compiled = compile_equations([rf"y = {text} x"], {"x": ("R",)}, ["y"])
    assert compiled.ok, compiled.reason
    x = torch.rand(3, dtype=torch.float64)
    _, got = _run(compiled, x)
    torch.testing.assert_close(got, value * x, rtol=1e-12, atol=0.0)


def test_a_decimal_comma_is_not_read_as_a_thousands_separator():
    compiled = compile_equations([r"y = 0{,}5 x"], {"x": ("R",)}, ["y"])
    assert not compiled.ok


BIMODAL = r"""# BimodalNeRF: A Density Prior

## Abstract

We use positional encoding, hierarchical sampling and volume rendering as NeRF does, and regularise the density.

## 3 Method

### 3.1 Bimodal density prior

We add a regulariser that pushes each sample's density towards empty or solid space, with a prior that is a mixture
of two Laplacians:

$$Q(u) \propto e^{-|u|/0.5} + e^{-|1-u|/0.5}, \quad \mathcal{L}_{bi} = -\log Q(\sigma_i) \tag{2}$$

## 4 Experiments

We train for 200k iterations with a learning rate of 5e-4.
"""


def test_the_binder_records_the_factor_of_a_proportionality_and_the_function_it_applies(tmp_path):
    """A test paper's prior written with ``\\propto`` and applied to the density: the part is built, its record says
    the factor is taken as 1 and why, and the regulariser is the mean of -log Q(sigma) written by hand."""
    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.novel import IMPLEMENTED, implement_holes
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    path = tmp_path / "bimodal.md"
    path.write_text(BIMODAL)
    doc = ingest(path)
    (record,) = [r for r in implement_holes(doc, plan_from_paper(doc).plan).records if r.production == "Regularizers"]
    assert record.status == IMPLEMENTED, record.reason
    assert any("taken as 1" in n and "propto" in n for n in record.notes), record.notes
    assert any("argument u replaced by sigma" in n for n in record.notes), record.notes
    namespace = {"__name__": "compiled_for_test"}
    exec(compile(record.source, "<component>", "exec"), namespace)  # noqa: S102 - our own generated source
    module = namespace[record.component["class"]]().double()
    sigma = torch.rand(4, 6, 1, dtype=torch.float64, requires_grad=True) * 2
    got = module(sigma)
    want = -torch.log(torch.exp(-sigma.abs() / 0.5) + torch.exp(-(1 - sigma).abs() / 0.5)).mean()
    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    _grads_match(got, want, (sigma,))


OPAQUE = r"""# OpaqueNeRF: A Transmittance Prior

## Abstract

We use positional encoding, hierarchical sampling and volume rendering as NeRF does, and add a prior that makes
surfaces opaque.

## 3 Method

### 3.1 Opacity prior

We add a regulariser that pushes the visibility of each sample towards empty or solid space, where $\delta_i$ is
the distance between adjacent samples:

$$\mathcal{L}_{op} = \big(o_i (1 - o_i)\big)^{2}, \quad o_i = 1 - \exp(-\sigma_i \delta_i) \tag{3}$$

### 3.2 Training objective

We train with the sum of the photometric loss and the prior, where $\beta = 0.05$:

$$\mathcal{L} = \mathcal{L}_{rgb} + \beta \mathcal{L}_{op} \tag{4}$$

## 4 Experiments

We train for 200k iterations with a learning rate of 5e-4.
"""


def test_a_regulariser_reads_the_steps_between_samples(tmp_path):
    """A test paper's prior on each sample's opacity, whose equation reads the steps between samples (delta): the
    Regularizers interface gives them, the part is built, and it is the hand-written prior, gradients included;
    without the steps it says so instead of guessing. Its weight is its coefficient in the paper's objective."""
    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.novel import IMPLEMENTED, implement_holes
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    path = tmp_path / "opaque.md"
    path.write_text(OPAQUE)
    doc = ingest(path)
    (record,) = [r for r in implement_holes(doc, plan_from_paper(doc).plan).records if r.production == "Regularizers"]
    assert record.status == IMPLEMENTED, record.reason
    assert record.bindings["delta"]["role"] == "step"
    assert record.component["weight"] == 0.05  # its coefficient in the objective, Eq. 4, set in a sentence
    assert any(n.startswith("weight 0.05: cal L_op's coefficient beta") for n in record.notes), record.notes
    namespace = {"__name__": "compiled_for_test"}
    exec(compile(record.source, "<component>", "exec"), namespace)  # noqa: S102 - our own generated source
    module = namespace[record.component["class"]]().double()
    sigma = (torch.rand(4, 6, 1, dtype=torch.float64) * 2).requires_grad_()
    delta = torch.rand(4, 6, 1, dtype=torch.float64) * 0.2 + 0.01
    got = module(sigma, delta)
    o = 1 - torch.exp(-sigma * delta)
    want = ((o * (1 - o)) ** 2).mean()
    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    _grads_match(got, want, (sigma,))
    with pytest.raises(ValueError, match="steps between samples"):
        module(sigma)


@pytest.mark.parametrize("latex, words, want", [
    (r"\mathcal{L} = \mathcal{L}_{c} + 0.01 \mathcal{L}_{s}", {}, 0.01),
    (r"\mathcal{L} = \mathcal{L}_{c} + \mathcal{L}_{s} \lambda, \quad \lambda = 2", {}, 2.0),
    (r"\mathcal{L} = \mathcal{L}_{c} + \mathcal{L}_{s}", {}, 1.0),
    (r"\mathcal{L} = \mathcal{L}_{c} + \gamma \mathcal{L}_{s}", {}, None),
])
def test_a_loss_terms_weight_is_its_coefficient_in_the_objective(latex, words, want):
    """The coefficient of a part's output in a sum another equation defines: a number, a symbol the block sets,
    an unweighted term (1), or a symbol the paper gives no value (None: said, the weight stays 1)."""
    from types import SimpleNamespace

    from nerfify_ns.synthesis.novel.items import Item, _parse
    from nerfify_ns.synthesis.novel.objective import objective_weight

    item = Item(number="5", latex=latex, section="3", order=0, where="Sec. 3", in_hole=False)
    _parse(item)
    got = objective_weight(["cal L_s"], [item], SimpleNamespace(constants=words))
    assert got is not None and got.value == want, got
    assert "cal L_s" in got.note
    assert objective_weight(["cal L_x"], [item], SimpleNamespace(constants=words)) is None


SHARED = r"""# ShareNeRF: Two Fields and a Prior on How They Share Space

## Abstract

We use positional encoding, hierarchical sampling and volume rendering as NeRF does. A second field models what
moves; a small network blends the two fields per sample, and a prior keeps the moving field's share small.

## 3 Method

### 3.1 Two fields

A **sharing field** $m:(\mathbf{x},t)\mapsto(P_{\text{still}},P_{\text{moving}})$ gives, for every sample, the
probability that each field explains it; the colour and density are the two fields' outputs weighted by them.

### 3.2 Sharing prior

We add a regulariser that penalises samples the moving field explains, where $\gamma = 0.5$:

$$\mathcal{L}_{sh} = \gamma \, P_{\text{moving}} \left(2 - P_{\text{moving}}\right) \tag{3}$$

### 3.3 Training objective

$$\mathcal{L} = \mathcal{L}_{rgb} + 0.01 \, \mathcal{L}_{sh} \tag{4}$$

## 4 Experiments

We train for 200k iterations with a learning rate of 5e-4.
"""


def test_a_regulariser_reads_a_blended_fields_share_by_its_place_in_the_decomposition(tmp_path):
    """A test paper's prior on the share of its second field: the symbol is the second output of the tuple the
    paper writes its decomposition as, so it reads the second column of the blended fields' shares (the Regularizers
    interface's weights); the part is the hand-written prior, gradients included, and it refuses a blend of another
    number of fields or none instead of reading the wrong column."""
    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.novel import IMPLEMENTED, implement_holes
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    path = tmp_path / "shared.md"
    path.write_text(SHARED)
    doc = ingest(path)
    (record,) = [r for r in implement_holes(doc, plan_from_paper(doc).plan).records if r.production == "Regularizers"]
    assert record.status == IMPLEMENTED, record.reason
    (binding,) = [b for b in record.bindings.values() if b.get("role") == "probability"]
    assert "mapsto" in binding["evidence"] and binding["note"].startswith("output 2 of the 2")
    assert record.bindings["gamma"]["value"] == 0.5 and record.component["weight"] == 0.01
    namespace = {"__name__": "compiled_for_test"}
    exec(compile(record.source, "<component>", "exec"), namespace)  # noqa: S102 - our own generated source
    module = namespace[record.component["class"]]().double()
    sigma = torch.rand(4, 6, 1, dtype=torch.float64)
    shares = torch.softmax(torch.randn(4, 6, 2, dtype=torch.float64), dim=-1).requires_grad_()
    got = module(sigma, None, shares)
    p = shares[..., 1]
    want = (0.5 * p * (2 - p)).mean()
    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    _grads_match(got, want, (shares,))
    assert float(module(sigma[:0], None, shares[:0])) == 0.0  # an empty batch
    with pytest.raises(ValueError, match="blends none"):
        module(sigma, None, None)
    with pytest.raises(ValueError, match="shares of 2 blended fields; the field blends 3"):
        module(sigma, None, torch.softmax(torch.randn(4, 6, 3, dtype=torch.float64), dim=-1))


RELATIVE = r"""# RelNeRF: A Relative Photometric Loss

## Abstract

We use positional encoding, hierarchical sampling and volume rendering as NeRF does, and replace the photometric
loss with a relative one that weighs dark pixels as much as bright ones.

## 3 Method

### 3.1 Relative loss

We train with the squared error relative to the rendered colour, where $\mathrm{sg}$ stops the gradient:

$$\mathcal{L}_{rel}(\hat{C}, C^*) = \left(\frac{\hat{C} - C^*}{\mathrm{sg}(\hat{C}) + \epsilon}\right)^2,
\quad \epsilon = 10^{-3} \tag{3}$$

## 4 Experiments

We train for 200k iterations with a learning rate of 5e-4.
"""


def test_a_compiled_loss_is_computed_in_float32_whatever_its_inputs_precision(tmp_path):
    """A test paper's relative loss divides by the rendered colour plus 1e-3: on float16 inputs (the stability
    rung's ``half`` case) the squared ratio overflows float16 where a rendered colour is near 0, so the compiled
    loss computes in float32 (as autocast computes losses) and stays finite; on float32 inputs it is the paper's."""
    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.novel import IMPLEMENTED, implement_holes
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    path = tmp_path / "relative.md"
    path.write_text(RELATIVE)
    doc = ingest(path)
    (record,) = [r for r in implement_holes(doc, plan_from_paper(doc).plan).records if r.production == "RGBLoss"]
    assert record.status == IMPLEMENTED, record.reason
    namespace = {"__name__": "compiled_for_test"}
    exec(compile(record.source, "<component>", "exec"), namespace)  # noqa: S102 - our own generated source
    module = namespace[record.component["class"]]()
    pred = torch.tensor([[0.0005, 0.5, 0.9], [0.2, 0.0001, 0.7]])
    target = torch.tensor([[1.0, 0.4, 0.1], [0.3, 0.9, 0.7]])
    want = (((pred - target) / (pred + 1e-3)) ** 2).mean()
    torch.testing.assert_close(module(pred, target), want)
    assert not torch.isfinite((((pred.half() - target.half()) / (pred.half() + 1e-3)) ** 2).mean())  # float16 overflows
    got = module.half()(pred.half(), target.half())
    assert torch.isfinite(got) and got.dtype == torch.float32
    torch.testing.assert_close(got, want, rtol=2e-3, atol=0)


# a saturating prior of our own (not SNeRG's Cauchy prior, which the knowledge base's card holds: the plan takes the
# card's terminal for that one, whatever weight and scale it is written with)
SATURATING = r"""# SatNeRF: A Sparsity Prior

## Abstract

We use positional encoding, hierarchical sampling and volume rendering as NeRF does, and add a sparsity prior on
the density.

## 3 Method

### 3.1 Sparsity prior

We add a saturating prior over the density at every sample $t_k$ of every ray $\mathbf{r}_i$ of the batch:

$$\mathcal{L}_{s} = \lambda_{s} \sum_{i, k} \left(1 - \exp(-2\sigma(\mathbf{r}_{i}(t_{k}))^{2})\right) \tag{2}$$

## 4 Experiments

We train for 200k iterations with a learning rate of 5e-4 and set $\lambda_s = WEIGHT$.
"""


@pytest.mark.parametrize("stated, want", [(r"10^{-4}", 1e-4), (r"5 \times 10^{-3}", 5e-3), ("", None)])
def test_a_regulariser_with_its_own_weight_summed_over_rays_and_samples(tmp_path, stated, want):
    """A test paper's prior written with its own weight (L_s = lambda_s sum_{i,k} ...) over the rays r_i and their
    samples t_k: the weight is taken out of the component and becomes the regulariser's weight, its value read from
    the sentence in whatever notation it is written (or left at 1 and said); i numbers the rays because it
    subscripts a ray. The component is the hand-written sum over rays and samples, gradients included."""
    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.novel import IMPLEMENTED, implement_holes
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    path = tmp_path / "cauchy.md"
    text = SATURATING.replace("WEIGHT", stated) if stated else SATURATING.replace(" and set $\\lambda_s = WEIGHT$", "")
    path.write_text(text)
    doc = ingest(path)
    (record,) = [r for r in implement_holes(doc, plan_from_paper(doc).plan).records if r.production == "Regularizers"]
    assert record.status == IMPLEMENTED, record.reason
    assert any("own weight in the paper's equation" in n for n in record.notes), record.notes
    assert record.component.get("weight") == (pytest.approx(want) if want is not None else None)
    if want is None:
        assert any("has no value in the paper: the weight stays 1" in n for n in record.notes), record.notes
    namespace = {"__name__": "compiled_for_test"}
    exec(compile(record.source, "<component>", "exec"), namespace)  # noqa: S102 - our own generated source
    module = namespace[record.component["class"]]().double()
    sigma = (torch.rand(4, 6, 1, dtype=torch.float64) * 2).requires_grad_()
    got = module(sigma)
    want_value = (1 - torch.exp(-2 * sigma[..., 0] ** 2)).sum()  # the paper's sum over i and k, without lambda_s
    torch.testing.assert_close(got, want_value, rtol=1e-10, atol=1e-12)
    _grads_match(got, want_value, (sigma,))


BATCH_MEAN = r"""# MeanNeRF: A Relative Loss

## Abstract

We use positional encoding, hierarchical sampling and volume rendering as NeRF does, with a relative photometric
loss.

## 3 Method

### 3.1 Relative photometric loss

We optimise the rendered colours with respect to a relative squared error over a batch of rays $\mathcal{R}$:

LOSS

## 4 Experiments

We train for 200k iterations with a learning rate of 5e-4.
"""

OWN_EQUATION = r"""$$\mathcal{L}_{rel} = \frac{1}{|\mathcal{R}|} \sum_{\mathbf{r} \in \mathcal{R}}
\frac{\| C(\mathbf{r})-\hat{C}(\mathbf{r}) \|_{2}^{2}}{\hat{C}(\mathbf{r})^2 + 0.01} \tag{2}$$"""

OBJECTIVE_TERM = r"""$$\mathcal{L} = \mathcal{L}_{rel} + \lambda_{TV} \mathcal{L}_{TV} \tag{2}$$

where the relative error and the total variation over the voxels $\mathcal{V}$ are:

$$&{\mathcal{L}_{rel} = \frac{1}{|\mathcal{R}|} \sum_{\mathbf{r} \in \mathcal{R}}
\frac{\| C(\mathbf{r})-\hat{C}(\mathbf{r}) \|_{2}^{2}}{\hat{C}(\mathbf{r})^2 + 0.01}} \\
&{\quad \mathcal{L}_{TV} = \frac{1}{|\mathcal{V}|} \sum_{\mathbf{v} \in \mathcal{V}}
\sqrt{\Delta_{x}^{2}(\mathbf{v}, d)}}$$"""


@pytest.mark.parametrize("loss", [OWN_EQUATION, OBJECTIVE_TERM], ids=["its-own-equation", "a-term-of-the-objective"])
def test_a_loss_averaged_over_the_batch_compares_the_estimate_with_the_observation(tmp_path, loss):
    """A test paper's loss written as a mean over the batch's rays (1/|R| sum over r in R) between C and its hat,
    with no sentence naming the ground truth: the sum over the rays divided by their number is the loss's own mean,
    the hat marks the estimate (the render) and the plain C the observation. The component is the hand-written loss,
    which is not symmetric in the two (the estimate is in the denominator), gradients included. Written as a term of
    a numbered objective and defined in the unnumbered block after it (each row one brace group, as some LaTeX
    converters write aligned rows; the other row unreadable), it is the same part."""
    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.novel import IMPLEMENTED, implement_holes
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    path = tmp_path / "relative.md"
    path.write_text(BATCH_MEAN.replace("LOSS", loss))
    doc = ingest(path)
    (record,) = [r for r in implement_holes(doc, plan_from_paper(doc).plan).records if r.production == "RGBLoss"]
    assert record.status == IMPLEMENTED, record.reason
    assert record.bindings["C"]["role"] == "target_colour" and record.bindings["hat C"]["role"] == "ray_colour"
    assert any("is the mean over the batch" in n for n in record.notes), record.notes
    namespace = {"__name__": "compiled_for_test"}
    exec(compile(record.source, "<component>", "exec"), namespace)  # noqa: S102 - our own generated source
    module = namespace[record.component["class"]]().double()
    pred = torch.rand(5, 3, dtype=torch.float64, requires_grad=True)
    target = torch.rand(5, 3, dtype=torch.float64)
    got = module(pred, target)
    want = (((target - pred) ** 2).sum(-1, keepdim=True) / (pred**2 + 0.01)).mean()
    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    _grads_match(got, want, (pred,))


@pytest.mark.parametrize("stated, want", [(0.1, 0.5 * 0.1), (None, 0.5)])
def test_a_loss_terms_own_weight_and_its_coefficient_in_the_objective_multiply(stated, want):
    """A term weighted in its own equation and again in the objective: the plugin's weight is the product; an own
    weight the paper gives no number counts 1 (said), and the objective's coefficient still applies."""
    from types import SimpleNamespace

    from nerfify_ns.equations import Symbol
    from nerfify_ns.synthesis.novel.items import Item, _parse
    from nerfify_ns.synthesis.novel.notation import symbol_loose_key
    from nerfify_ns.synthesis.novel.objective import term_weight

    own = Symbol("lambda", ("s",))
    words = {symbol_loose_key(own): (stated, "we set lambda_s", "Sec. 4")} if stated is not None else {}
    item = Item(number="5", latex=r"\mathcal{L} = \mathcal{L}_{c} + 0.5 \mathcal{L}_{s}", section="3", order=0,
                where="Sec. 3", in_hole=False)
    _parse(item)
    got = term_weight(["cal L_s"], own, [item], SimpleNamespace(constants=words))
    assert got is not None and got.value == pytest.approx(want), got
    assert "own weight lambda_s" in got.note and "coefficient in the objective" in got.note
    assert ("has no value in the paper" in got.note) == (stated is None)
