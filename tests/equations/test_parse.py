"""The reading: LaTeX of NeRF papers -> IR, the noise of converted papers, and typed failures with columns."""

from __future__ import annotations

import pytest

from nerfify_ns.equations import (
    Apply,
    BinOp,
    Cases,
    Concat,
    Equation,
    Expectation,
    Index,
    Integral,
    Norm,
    Number,
    ParseFailure,
    Reduce,
    Symbol,
    parse_equation,
    parse_equations,
    parse_expression,
    show,
)


def read(latex: str, **kw) -> Equation:
    eq = parse_equation(latex, **kw)
    assert isinstance(eq, Equation), f"{latex!r}: {eq}"
    return eq


def fails(latex: str) -> ParseFailure:
    result = parse_equation(latex)
    assert isinstance(result, ParseFailure), f"{latex!r} was read as {show(result)}"
    assert not result  # a failure is falsy
    return result


@pytest.mark.parametrize("latex, shown", [
    # arithmetic, fractions, powers
    (r"y = \frac{a}{b} + \dfrac12 - \tfrac{x}{2} + a/b", "y = a/b + 1/2 - x/2 + a/b"),
    (r"y = x^2 + \sigma^{-1} + 2^{k} + x^{1/2}", "y = x^2 + sigma^-1 + 2^k + x^(1/2)"),
    (r"y = e^{-\sigma\delta}", "y = exp(-(sigma delta))"),
    (r"\epsilon = 10^{-3}", "epsilon = 0.001"),
    (r"y = \sqrt{x} + \sqrt[3]{x}", "y = sqrt(x) + x^(1/3)"),
    # sub- and superscript labels
    (r"y = \mathbf{W}_{1} x^{(k)} + W^f_\Delta + c^{\mathrm{med}} + h'_c + C^*",
     "y = W_1 x^{(k)} + W_{Delta}^f + c^{med} + h'_c + C^*"),
    (r"y = \mathrm{MLP}_{\theta}", "y = MLP_{theta}"),
    # functions
    (r"y = \exp(x) \log x + \ln(x) + \sin x \cos(x) + \tanh(x)",
     "y = exp(x) log(x) + log(x) + sin(x) cos(x) + tanh(x)"),
    (r"y = \mathrm{ReLU}(x) + \operatorname{softplus}(x) + \text{sigmoid}(x) + ReLU(x)",
     "y = relu(x) + softplus(x) + sigmoid(x) + relu(x)"),
    (r"y = \min(a, b) + \max(0, x) + \operatorname{clamp}(x, 0, 1) + \lceil x \rceil + \lfloor x \rfloor",
     "y = min(a, b) + max(0, x) + clamp(x, 0, 1) + ceil(x) + floor(x)"),
    (r"y = \sigma(\mathbf{W} x + b)", "y = sigmoid(W x + b)"),
    (r"y = \sigma(\mathbf{x})", "y = sigma(x)"),
    (r"y = \mathrm{sg}(x) + \mathrm{MSE}(a, b)", "y = stopgrad(x) + mse(a, b)"),
    # norms and absolute values
    (r"y = \|x\| + \|x\|_1 + \left\| x \right\|_2 + \lVert x \rVert_\infty", "y = ||x|| + ||x||_1 + ||x|| + ||x||_inf"),
    (r"y = |x| + \lvert x \rvert + |a - |b||", "y = |x| + |x| + |a - |b||"),
    (r"y = |x|_2^2", "y = ||x||^2"),
    # products
    (r"y = a \cdot b \times c \ast d", "y = a b c d"),
    (r"y = a \odot b + a \otimes b + a \circ b", "y = a (.) b + a (.) b + a (.) b"),
    (r"y = T_i (1 - \alpha_i)", "y_i = T_i (1 - alpha_i)"),
    (r"y = td_z", "y = t d_z"),
    # concatenation
    (r"y = [a, b]", "y = [a, b]"),
    (r"y = \left[a ; b\right]", "y = [a, b]"),
    (r"y = \begin{pmatrix} a \\ b \end{pmatrix}", "y = [a, b]"),
    # relations
    (r"y := x", "y := x"),
    (r"y \triangleq x", "y := x"),
    (r"y \approx x", "y ~= x"),
])
def test_readings(latex, shown):
    assert show(read(latex)) == shown


def test_symbols_keep_labels_decorations_and_sample_indices():
    eq = read(r"\hat{\mathbf{C}}_i^{\mathrm{obj}}(\mathbf{r}) = \mathbf{W}^{f}_{\Delta} \mathbf{c}_i")
    lhs = eq.lhs
    assert (lhs.name, lhs.superscript, lhs.decorations, lhs.index) == ("C", "obj", ("hat",), Index("i"))
    assert lhs.key == "hat C^obj" and lhs.args == (Symbol("r"),)
    w, c = eq.rhs.left, eq.rhs.right
    assert (w.key, w.index) == ("W_Delta^f", None)
    assert (c.key, c.index) == ("c", Index("i"))
    assert eq.free_index == "i"


def test_sums_and_products_over_samples():
    full = read(r"C = \sum_{i=1}^{N} T_i \alpha_i c_i").rhs
    assert isinstance(full, Reduce) and (full.kind, full.index, full.axis, full.mode) == ("sum", "i", "samples", "full")
    for latex in (r"T_i = \prod_{j<i} (1 - \alpha_j)", r"T_i = \prod_{j=1}^{i-1} (1 - \alpha_j)",
                  r"T_i = \prod_{j=0}^{i-1} (1 - \alpha_j)"):
        red = read(latex).rhs
        assert (red.kind, red.axis, red.mode, red.outer) == ("prod", "samples", "exclusive", "i"), latex
        assert red.body.right.index == Index("j")
    inclusive = read(r"S_i = \sum_{j \le i} x_j").rhs
    assert (inclusive.mode, inclusive.outer) == ("inclusive", "i")
    inclusive = read(r"S_i = \sum_{j=1}^{i} x_j").rhs
    assert (inclusive.mode, inclusive.outer) == ("inclusive", "i")
    rays = read(r"L = \sum_{\mathbf{r} \in \mathcal{R}} \|C(\mathbf{r})\|^2").rhs
    assert rays.axis == "rays"
    finite = read(r"y = \sum_{k=0}^{L-1} 2^k x").rhs
    assert finite.axis == "range" and finite.lower == Number(0.0, "0")
    double = read(r"L = \sum_{i,j} w_i w_j").rhs
    assert isinstance(double.body, Reduce) and (double.index, double.body.index) == ("i", "j")


def test_a_sum_takes_the_rest_of_its_term():
    eq = read(r"y = a \sum_i b_i c_i + d")
    assert isinstance(eq.rhs, BinOp) and eq.rhs.op == "+"
    product = eq.rhs.left
    assert product.left == Symbol("a") and isinstance(product.right, Reduce)
    assert show(product.right.body) == "b_i c_i"


def test_the_volume_rendering_integral_is_read_as_its_quadrature():
    eq = read(r"C(\mathbf{r}) = \int_{t_n}^{t_f} T(t)\sigma(\mathbf{r}(t))\mathbf{c}(\mathbf{r}(t),\mathbf{d})\,dt")
    integral = eq.rhs
    assert isinstance(integral, Integral) and integral.var == "t"
    assert integral.lower.key == "t_n" and integral.upper.key == "t_f"
    assert "volume-rendering" in integral.rule
    assert show(integral.quadrature) == "sum_t T_t(t) (1 - exp(-(sigma_t(r_t(t)) delta_t))) c_t(r_t(t), d)"
    inner = read(r"T(t) = \exp\left(-\int_{t_n}^{t} \sigma(\mathbf{r}(s))\, ds\right)").rhs.args[0].arg
    assert (inner.quadrature.mode, inner.quadrature.outer) == ("exclusive", "t")
    riemann = read(r"D = \int_{t_n}^{t_f} w(t) \, t \, dt").rhs
    assert riemann.rule.startswith("Riemann") and show(riemann.quadrature) == "sum_t w_t(t) t delta_t"
    assert "differential" in str(fails(r"y = \int_0^1 x"))


def test_cases_and_expectations():
    eq = read(r"f(x) = \begin{cases} x^2 & x < 1 \\ 2x - 1 & \text{otherwise} \end{cases}")
    assert isinstance(eq.rhs, Cases) and len(eq.rhs.branches) == 2
    assert eq.rhs.branches[0][1].op == "<" and eq.rhs.branches[1][1] is None
    eq = read(r"f = \begin{cases} a, & \text{if } x \geq 0 \\ b, & \text{else} \end{cases}")
    assert eq.rhs.branches[0][1].op == ">="
    loss = read(r"\mathcal{L} = \mathbb{E}_{\mathbf{r}} \|C(\mathbf{r}) - \hat{C}(\mathbf{r})\|_2^2").rhs
    assert isinstance(loss, Expectation) and loss.index == "r"
    assert isinstance(loss.body, BinOp) and isinstance(loss.body.left, Norm)
    assert "only expectations over rays" in str(fails(r"y = \mathbb{E}_{t}[x]"))


def test_matrix_vector_products_and_concatenations():
    eq = read(r"f_\psi = \sigma\left(\mathbf{W}^f_\psi[h_\Delta, h_c] + b^f_\psi\right)")
    assert isinstance(eq.rhs, Apply) and eq.rhs.func == "sigmoid"
    wx = eq.rhs.args[0].left
    assert wx.op == "*" and wx.left.key == "W_psi^f" and isinstance(wx.right, Concat)
    eq = read(r"\Psi = \tanh(W_\Psi(\mu + (f_\psi \otimes \Psi)) + b_\Psi)")  # W(...) is a product, not a call
    assert eq.rhs.args[0].left.left.key == "W_Psi"


@pytest.mark.parametrize("latex, shown", [
    # markdown/PDF conversion noise
    (r"$$ C(\pmb{r}) = \boldsymbol{\sigma} \bm{x} \mathbf{c} $$", "C(r) = sigma x c"),
    (r"{\cal L}*{\mathrm{reg}}=\alpha ,\overline{P*{\mathrm{deform}}}+\overline{P_{\mathrm{new}}} ,",
     "cal L_{reg} = alpha bar P_{deform} + bar P_{new}"),
    (r"L _ { \mathrm { r e c } } = \sum _ { \pmb { r } \in \mathcal { R } } | \pmb { C } ( \pmb { r } ) - "
     r"\pmb { C } _ { \mathrm { g t } } ( \pmb { r } ) | _ { 2 } ^ { 2 } ,",
     "L_{rec} = sum_{r in cal R} ||C(r) - C_{gt}(r)||^2"),
    (r"T(s_i)=\exp!\Big(-\sum_{j=0}^{i-1}\sigma_j\delta_j\Big).",
     "T_i(s_i) = exp(-(sum_{j=0}^{i - 1} sigma_j delta_j))"),
    (r"\begin{equation} y = x \label{eq:y} \end{equation}", "y = x"),
    (r"\begin{array}{rl} y &= \displaystyle\frac{a}{b} \end{array}", "y = a/b"),
    (r"y = a\,b\;c\!d\quad", "y = a b c d"),
    (r"y = \left( a + b \right) \bigl[c\bigr] \Big( d \Big)", "y = (a + b) c d"),
    ("y = \u03c3(x + 1) \u2299 \u03b4 \u2212 \U0001d431", "y = sigmoid(x + 1) (.) delta - x"),
    (r"y = \sum\limits_{i=1}^{N} x_i", "y = sum_{i=1}^{N} x_i"),
])
def test_noise_of_converted_papers_is_normalised(latex, shown):
    assert show(read(latex)) == shown


def test_equation_numbers_rows_and_where_clauses():
    assert read(r"y = x \tag{7}").number == "7"
    assert read(r"y = x", number="3").number == "3"
    rows = parse_equations(r"\begin{aligned} a &= b + c \\ d &= e \end{aligned}")
    assert [show(r) for r in rows] == ["a = b + c", "d = e"]
    chain = read(r"\begin{aligned} a &= b + c \\ &= d \end{aligned}")
    assert show(chain) == "a = b + c" and chain.also == (Symbol("d"),)
    where = parse_equations(r"\mathcal L = (a - b)^2,\quad \epsilon=10^{-3}")
    assert [show(r) for r in where] == ["cal L = (a - b)^2", "epsilon = 0.001"]
    assert "2 equations" in str(parse_equation(r"a = b, c = d"))
    lost_rows = parse_equations("\\begin{array}{l} a = b[2pt]\nc = d \\\\[6pt] e = f \\end{array}")
    assert [show(r) for r in lost_rows] == ["a = b", "c = d", "e = f"]


@pytest.mark.parametrize("latex, fragment, reason", [
    (r"y = x + \mathcal{F}(x + 1)", r"\mathcal{F}", "unknown operator"),
    (r"y = \nabla x", r"\nabla", "unknown operator"),
    (r"y = \operatorname{__import__('os').system}(x)", "__import__('os').system", "unreadable name"),
    (r"y = x_1 + \cdots + x_N", r"\cdots", "an ellipsis"),
    (r"y = \max(a) + \max_{i} x_i", r"\max", "of one argument"),
    (r"y = (a, b)", "(", "a tuple"),
    (r"y = \hat{a+b}", r"\hat", "over an expression"),
    (r"y = x + ", "", "ends too early"),
    (r"y = x \propto z", r"\propto", "a chain with a proportionality"),
    (r"y \to x", r"\to", "not an equality"),
    (r"y < x", "<", "an inequality"),
])
def test_failures_name_the_reason_and_the_column_in_the_text_as_given(latex, fragment, reason):
    failure = fails(latex)
    assert failure.fragment == fragment and reason in failure.reason
    if fragment:
        start = latex.index(fragment if not fragment.startswith("__") else r"\operatorname")
        assert failure.column == start + 1
        assert str(failure) == f"`{fragment}` {failure.reason} at column {start + 1}"


def test_the_column_counts_in_the_original_text_after_normalisation():
    latex = r"$$ y = \left( \mathbf{x} \right) + \boldsymbol{\sigma} + \nabla z $$"
    failure = fails(latex)
    assert failure.column == latex.index(r"\nabla") + 1
    assert str(fails(r"y = \mathcal{F}(x+1)")) == r"`\mathcal{F}` unknown operator at column 5"
    assert fails("y = x + \u2603").reason == "unknown character"


def test_failures_of_meaning():
    assert "free index" in str(fails(r"T_i = x_j"))
    assert "nothing binds" in str(fails(r"y = \sum_{j=1}^{i} x_j"))
    assert "the batch of rays" in str(fails(r"y = \sum_{\mathbf{r}\in\mathcal{R}_p} x"))
    assert "not an equation" in str(fails(r"x + 1")) or "an expression" in str(fails(r"x + 1"))
    assert "left side" in str(fails(r"x + 1 = y"))


def test_parse_expression_reads_a_right_hand_side_alone():
    expr = parse_expression(r"\exp(-\sigma \delta)")
    assert isinstance(expr, Apply) and expr.func == "exp"
    assert isinstance(parse_expression(r"a = b"), ParseFailure)


def test_notation_of_gh_nerf_and_mip_nerf():
    # spherical-harmonics colour head (GH-NeRF Eq. 7): read; evaluating k_l^m is refused with its reason
    eq = read(r"c(\mathbf{d};\mathbf{k})=\sigma(\sum_{\ell=0}^{\ell_{\max}}\sum_{m=-\ell}^{\ell}k_{\ell}^{m}"
              r"Y_{\ell}^{m}(\mathbf{d}))")
    assert show(eq) == "c(d) = sigmoid(sum_{ell=0}^{ell_{max}} (sum_{m=-ell}^{ell} k_{ell}^m Y_{ell}^m(d)))"
    outer = eq.rhs.args[0]
    assert (outer.axis, outer.body.axis) == ("range", "range")
    from nerfify_ns.equations import CompileError, lower

    with pytest.raises(CompileError, match="range variable 'ell'"):
        lower([eq], {"k_ell^m": ("R",), "Y_ell^m": ("R",)}, ["c"], {"ell_max": 2})
    # a field's parameters after ';' are not its point; a primed index is its own index; "with" is a word
    rows = parse_equations(r"\mathbf{C}(\mathbf{r};\Theta,\mathbf{t})=\sum_{k}T_{k}\mathbf{c}_{k} \\ \text{with} "
                           r"T_{k}=\exp(-\sum_{k'<k}\tau_{k'}\delta_{k'})")
    assert [show(r) for r in rows] == ["C(r) = sum_k T_k c_k", "T_k = exp(-(sum_{k' < k} tau_{k'} delta_{k'}))"]
    assert rows[0].free_index is None and rows[1].rhs.args[0].arg.mode == "exclusive"


def test_reasons_for_what_is_not_read():
    assert fails(r"Y = \frac{(\ell-m)!}{(\ell+m)!}").reason == "a factorial (!) is not read"
    assert "ellipsis" in fails(r"\gamma(x) = [\sin(x), \cos(x), ..., \sin(2^{L-1} x)]").reason
    assert "unknown operator" in fails(r"y = \Im[z]").reason
    assert "double superscript" in fails(r"y = x^2^2").reason
    eq = read(r"f = \begin{cases} a & m < 0, \\ b & m > 0. \end{cases}")  # trailing punctuation in rows
    assert len(eq.rhs.branches) == 2
