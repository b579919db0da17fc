"""A corpus of real NeRF equations: each is read, lowered, checked against the interpreter (rtol 1e-6) and
gradchecked; for most, a reference written by hand from the equation tests the reading itself."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pytest

from nerfify_ns.equations import Equation, ParamSpec, check_lowering, interpret, parse_equation


@dataclass
class Case:
    name: str
    latex: list[str]
    inputs: dict
    outputs: list[str]
    sizes: dict = field(default_factory=dict)
    domains: dict = field(default_factory=dict)
    reference: Callable | None = None   # values -> {output: array}, written by hand from the equations


def _exclusive_cumsum(x):
    return np.concatenate([np.zeros_like(x[:, :1]), np.cumsum(x, axis=1)[:, :-1]], axis=1)


def _render_reference(v):
    tau = v["sigma"] * v["delta"]
    trans = np.exp(-_exclusive_cumsum(tau))
    weights = trans * (1.0 - np.exp(-tau))
    colour = np.einsum("rs,rsk->rk", weights, v["c"])
    return {"T": trans, "hat C": colour, "C": colour}


def _alpha_reference(v):
    alpha = 1.0 - np.exp(-v["sigma"] * v["delta"])
    trans = np.concatenate([np.ones_like(alpha[:, :1]), np.cumprod(1.0 - alpha, axis=1)[:, :-1]], axis=1)
    w = trans * alpha
    return {"alpha": alpha, "T": trans, "w": w, "hat C": np.einsum("rs,rsk->rk", w, v["c"]),
            "hat D": (w * v["t"]).sum(1), "A": w.sum(1)}


def _pe_reference(v):
    p = v["p"]
    return {"gamma": np.concatenate([np.sin(np.pi * p), np.cos(np.pi * p), np.sin(2 * np.pi * p),
                                     np.cos(2 * np.pi * p)], axis=-1)}


def _mlp_reference(v):
    h1 = np.maximum(v["x"] @ v["W_1"].T + v["b_1"], 0.0)
    return {"h_1": h1, "h_2": np.maximum(h1 @ v["W_2"].T + v["b_2"], 0.0)}


def _distortion_reference(v):
    w, m, d = v["w"], v["m"], v["delta"]
    pair = (w[:, :, None] * w[:, None, :] * np.abs(m[:, :, None] - m[:, None, :])).sum((1, 2))
    return {"cal L_dist": pair + (w ** 2 * d).sum(1) / 3.0}


def _huber_reference(v):
    x, eps = v["x"], 0.5
    return {"rho": np.where(np.abs(x) <= eps, 0.5 * x ** 2, eps * (np.abs(x) - 0.5 * eps)), "epsilon": eps}


def _contract_reference(v):
    x = v["x"]
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    return {"contract": np.where(n <= 1.0, x, (2.0 - 1.0 / n) * x / n)}


def _expectation_reference(v):
    return {"cal L": ((v["C"] - v["hat C"]) ** 2).sum(-1).mean()}


def _nerf_loss_reference(v):
    return {"cal L": (((v["hat C_c"] - v["C"]) ** 2).sum(-1) + ((v["hat C_f"] - v["C"]) ** 2).sum(-1)).sum()}


def _fourier_reference(v):
    proj = 2.0 * np.pi * v["x"] @ v["B"].T
    return {"gamma": np.concatenate([np.cos(proj), np.sin(proj)], axis=-1)}


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


def _bionerf_reference(v):
    """BioNeRF Eqs. 1-9 (cognitive filtering, pre-modulation, modulation, memory, contextual embeddings)."""
    hd, hc = v["h_Delta"], v["h_c"]
    cat = np.concatenate([hd, hc], axis=-1)
    f_d = _sigmoid(hd @ v["W_Delta^f"].T + v["b_Delta^f"])
    f_c = _sigmoid(hc @ v["W_c^f"].T + v["b_c^f"])
    f_psi = _sigmoid(cat @ v["W_psi^f"].T + v["b_psi^f"])
    f_mu = _sigmoid(cat @ v["W_mu^f"].T + v["b_mu^f"])
    gamma = np.tanh(cat @ v["W_gamma"].T + v["b_gamma"])
    mu = f_mu * gamma
    psi = np.tanh((mu + f_psi * v["Psi"]) @ v["W_Psi"].T + v["b_Psi"])
    return {"f_Delta": f_d, "f_c": f_c, "mu": mu, "Psi": psi,
            "h'_Delta": np.concatenate([psi * f_d, v["l"]], axis=-1),
            "h'_c": np.concatenate([psi * f_c, v["d"]], axis=-1)}


def _seathru_reference(v):
    """SeaThru-NeRF's final model (separate direct and backscatter attenuation), from its equations."""
    s_obj, d, s = v["sigma^obj"], v["delta"], v["s"]
    trans = np.exp(-_exclusive_cumsum(s_obj * d))
    a_attn, a_bs = v["a^attn"][:, None, :], v["a^bs"][:, None, :]
    c_obj = trans[..., None] * np.exp(-a_attn * s[..., None]) * (1 - np.exp(-s_obj * d))[..., None] * v["c^obj"]
    c_med = trans[..., None] * np.exp(-a_bs * s[..., None]) * (1 - np.exp(-a_bs * d[..., None])) \
        * v["c^med"][:, None, :]
    return {"hat C": (c_obj + c_med).sum(1), "cal T^obj": trans}


def _recon_reference(v):
    return {"cal L_recon": ((v["hat C"] - v["C^*"]) / (v["hat C"] + 1e-3)) ** 2}


def _heads_reference(v):
    h, dirs = v["h"], v["d"]
    sigma = np.logaddexp(0.0, h @ v["W_sigma"].T + v["b_sigma"])
    color = _sigmoid(np.concatenate([h, dirs], axis=-1) @ v["W_c"].T + v["b_c"])
    return {"sigma": sigma, "c": color}


def _entropy_reference(v):
    w = v["w"]
    return {"cal L_ent": (-(w * np.log(w)).sum(1)).mean()}


RENDER = [r"\hat{C}(\mathbf{r}) = \sum_{i=1}^{N} T_i \left(1-\exp(-\sigma_i \delta_i)\right) \mathbf{c}_i",
          r"T_i = \exp\left(-\sum_{j=1}^{i-1} \sigma_j \delta_j\right)"]
PER_SAMPLE = {"sigma": ("R", "S"), "delta": ("R", "S"), "c": ("R", "S", 3)}

CORPUS = [
    Case("nerf volume rendering (discrete, NeRF Eq. 3)", RENDER, PER_SAMPLE, ["hat C", "T"],
         domains={"sigma": (0.1, 3.0)}, reference=_render_reference),
    Case("nerf volume rendering (the integral, NeRF Eq. 1)",
         [r"C(\mathbf{r}) = \int_{t_n}^{t_f} T(t)\sigma(\mathbf{r}(t))\mathbf{c}(\mathbf{r}(t),\mathbf{d})\,dt",
          r"T(t) = \exp\left(-\int_{t_n}^{t}\sigma(\mathbf{r}(s))\,ds\right)"], PER_SAMPLE, ["C"],
         reference=_render_reference),
    Case("nerfplayer rendering integral (noisy conversion)",
         [r"C ( \pmb { r } ) = \int_{ i_n }^{ i_f } e^{ - \int_{ i_n }^{ i } \sigma ( \pmb { p } _ { j } ) d j } , "
          r"\sigma !\big( \pmb { p } _ { i } \big) , c !\big( \pmb { p } _ { i } , d \big) , d i ,"],
         PER_SAMPLE, ["C"], reference=_render_reference),
    Case("alpha compositing with prod_{j<i}(1 - alpha_j), depth and accumulation",
         [r"\alpha_i = 1 - \exp(-\sigma_i \delta_i)", r"T_i = \prod_{j<i}(1-\alpha_j)", r"w_i = T_i \alpha_i",
          r"\hat{C} = \sum_{i} w_i \mathbf{c}_i", r"\hat{D} = \sum_{i=1}^{N} w_i t_i", r"A = \sum_i w_i"],
         {**PER_SAMPLE, "t": ("R", "S")}, ["alpha", "T", "w", "hat C", "hat D", "A"], reference=_alpha_reference),
    Case("positional encoding (sin/cos, two frequencies)",
         [r"\gamma(p) = \left[\sin(2^{0}\pi p), \cos(2^{0}\pi p), \sin(2^{1}\pi p), \cos(2^{1}\pi p)\right]"],
         {"p": ("R", 3)}, ["gamma"], reference=_pe_reference),
    Case("MLP layers h = ReLU(W x + b)",
         [r"\mathbf{h}_1 = \mathrm{ReLU}(\mathbf{W}_1 \mathbf{x} + \mathbf{b}_1)",
          r"\mathbf{h}_2 = \operatorname{ReLU}\left(\mathbf{W}_{2}\mathbf{h}_1 + \mathbf{b}_{2}\right)"],
         {"x": ("R", 3)}, ["h_1", "h_2"], sizes={"W_1": (8, 3), "b_1": (8,), "W_2": (4, 8), "b_2": (4,)},
         domains={"x": (-1.0, 1.0)}, reference=_mlp_reference),
    Case("distortion loss (Mip-NeRF 360, double sum)",
         [r"\mathcal{L}_{\mathrm{dist}} = \sum_{i,j} w_i w_j \left|m_i - m_j\right| + \frac{1}{3}\sum_{i=1}^{N} w_i^2 "
          r"\delta_i"], {"w": ("R", "S"), "m": ("R", "S"), "delta": ("R", "S")}, ["cal L_dist"],
         reference=_distortion_reference),
    Case("a cases expression (Huber)",
         [r"\rho(x) = \begin{cases} \frac{1}{2}x^2 & |x| \le \epsilon \\ \epsilon\left(|x| - \frac{1}{2}\epsilon"
          r"\right) & \text{otherwise} \end{cases}", r"\epsilon = 0.5"],
         {"x": ("R", 3)}, ["rho", "epsilon"], domains={"x": (-2.0, 2.0)}, reference=_huber_reference),
    Case("scene contraction (Mip-NeRF 360, cases with both conditions)",
         [r"\operatorname{contract}(\mathbf{x}) = \begin{cases} \mathbf{x} & \|\mathbf{x}\| \leq 1 \\ "
          r"\left(2 - \frac{1}{\|\mathbf{x}\|}\right)\left(\frac{\mathbf{x}}{\|\mathbf{x}\|}\right) & "
          r"\|\mathbf{x}\| > 1 \end{cases}"], {"x": ("R", 3)}, ["contract"], domains={"x": (-2.0, 2.0)},
         reference=_contract_reference),
    Case("expectation loss over rays",
         [r"\mathcal{L} = \mathbb{E}_{\mathbf{r}} \|C(\mathbf{r}) - \hat{C}(\mathbf{r})\|_2^2"],
         {"C": ("R", 3), "hat C": ("R", 3)}, ["cal L"], reference=_expectation_reference),
    Case("NeRF loss: a sum over the batch of rays",
         [r"\mathcal{L} = \sum_{\mathbf{r} \in \mathcal{R}} \left[\left\|\hat{C}_c(\mathbf{r}) - C(\mathbf{r})"
          r"\right\|_2^2 + \left\|\hat{C}_f(\mathbf{r}) - C(\mathbf{r})\right\|_2^2\right]"],
         {"hat C_c": ("R", 3), "hat C_f": ("R", 3), "C": ("R", 3)}, ["cal L"], reference=_nerf_loss_reference),
    Case("Fourier features (Tancik et al.)",
         [r"\gamma(\mathbf{v}) = \left[\cos(2\pi\mathbf{B}\mathbf{v}), \sin(2\pi\mathbf{B}\mathbf{v})\right]^{T}"],
         {"v": ("R", 3)}, ["gamma"], sizes={"B": ParamSpec((8, 3), learned=False, init="normal", std=10.0)},
         domains={"v": (-1.0, 1.0)}, reference=lambda v: _fourier_reference({"x": v["v"], "B": v["B"]})),
    Case("BioNeRF filters, modulation, memory, embeddings (element-wise products)",
         [r"f_\Delta = \sigma\left(W^f_\Delta h_\Delta + b^f_\Delta\right)",
          r"f_c = \sigma\left(W^f_c h_c + b^f_c\right)",
          r"f_\psi = \sigma\left(W^f_\psi [h_\Delta, h_c] + b^f_\psi\right)",
          r"f_\mu = \sigma\left(W^f_\mu [h_\Delta, h_c] + b^f_\mu\right)",
          r"\gamma = \tanh\left(W_\gamma [h_\Delta, h_c] + b_\gamma\right)",
          r"\mu = f_\mu \otimes \gamma",
          r"\Psi = \tanh\left(W_\Psi\left(\mu + (f_\psi \otimes \Psi)\right) + b_\Psi\right)",
          r"h'_\Delta = [\Psi \otimes f_\Delta, l]",
          r"h'_c = [\Psi \odot f_c, d]"],
         {"h_Delta": ("R", "F"), "h_c": ("R", "F"), "Psi": ("R", "F"), "l": ("R", 3), "d": ("R", 3)},
         ["f_Delta", "f_c", "mu", "Psi", "h'_Delta", "h'_c"],
         sizes={"F": 4, "W_Delta^f": (4, 4), "b_Delta^f": (4,), "W_c^f": (4, 4), "b_c^f": (4,),
                "W_psi^f": (4, 8), "b_psi^f": (4,), "W_mu^f": (4, 8), "b_mu^f": (4,), "W_gamma": (4, 8),
                "b_gamma": (4,), "W_Psi": (4, 4), "b_Psi": (4,)},
         domains={"h_Delta": (-1, 1), "h_c": (-1, 1), "Psi": (-1, 1)}, reference=_bionerf_reference),
    Case("SeaThru-NeRF object and medium rendering (final model)",
         [r"\hat C_i^{\mathrm{obj}}(\mathbf r)=\mathcal T_i^{\mathrm{obj}}\cdot \exp!\big(-\mathbf a^{\mathrm{attn}} "
          r"s_i\big)\cdot\big(1-\exp(-\sigma_i^{\mathrm{obj}}\delta_i)\big)\cdot\mathbf c_i^{\mathrm{obj}}",
          r"\hat C_i^{\mathrm{med}}(\mathbf r)=\mathcal T_i^{\mathrm{obj}}\cdot \exp!\big(-\mathbf a^{\mathrm{bs}} "
          r"s_i\big)\cdot\big(1-\exp(-\mathbf a^{\mathrm{bs}}\delta_i)\big)\cdot\mathbf c^{\mathrm{med}}",
          r"\mathcal T_i^{\mathrm{obj}}=\exp!\Big(-\sum_{j=0}^{i-1}\sigma_j^{\mathrm{obj}}\delta_j\Big)",
          r"\hat{C}(\mathbf{r}) = \sum_{i=1}^{N} \left(\hat C_i^{\mathrm{obj}}(\mathbf r) + "
          r"\hat C_i^{\mathrm{med}}(\mathbf r)\right)"],
         {"sigma^obj": ("R", "S"), "delta": ("R", "S"), "s": ("R", "S"), "c^obj": ("R", "S", 3),
          "a^attn": ("R", 3), "a^bs": ("R", 3), "c^med": ("R", 3)}, ["hat C", "cal T^obj"],
         reference=_seathru_reference),
    Case("SeaThru-NeRF reconstruction loss (stop-gradient, a 'where' clause)",
         [r"\mathcal L_{\mathrm{recon}}(\hat C,C^*)=\left(\frac{\hat C-C^*}{\mathrm{sg}(\hat C)+\epsilon}\right)^2",
          r"\epsilon=10^{-3}"], {"hat C": ("R", 3), "C^*": ("R", 3)}, ["cal L_recon"],
         reference=_recon_reference),
    Case("density and colour heads (softplus, sigmoid of a concatenation)",
         [r"\sigma = \mathrm{softplus}(\mathbf{W}_\sigma \mathbf{h} + b_\sigma)",
          r"\mathbf{c} = \sigma(\mathbf{W}_c [\mathbf{h}, \mathbf{d}] + \mathbf{b}_c)"],
         {"h": ("R", 6), "d": ("R", 3)}, ["sigma", "c"],
         sizes={"W_sigma": (1, 6), "b_sigma": (1,), "W_c": (3, 9), "b_c": (3,)}, domains={"h": (-1, 1)},
         reference=_heads_reference),
    Case("ray entropy regulariser",
         [r"\mathcal{L}_{ent} = \mathbb{E}_{\mathbf{r}}\left[-\sum_{i} w_i \log(w_i)\right]"],
         {"w": ("R", "S")}, ["cal L_ent"], reference=_entropy_reference),
    Case("a finite sum over frequencies", [r"y = \sum_{k=0}^{L-1} \frac{\sin(2^{k}\pi x)}{2^{k}}"],
         {"x": ("R", 2)}, ["y"], sizes={"L": 4},
         reference=lambda v: {"y": sum(np.sin(2 ** k * np.pi * v["x"]) / 2 ** k for k in range(4))}),
]


def _parse(case: Case) -> list[Equation]:
    equations = []
    for k, latex in enumerate(case.latex, start=1):
        eq = parse_equation(latex, number=str(k))
        assert isinstance(eq, Equation), f"{case.name}: {latex!r}: {eq}"
        equations.append(eq)
    return equations


@pytest.mark.parametrize("case", CORPUS, ids=[c.name for c in CORPUS])
def test_lowering_agrees_with_the_interpreter_and_gradchecks(case: Case):
    report = check_lowering(_parse(case), case.inputs, case.sizes, case.outputs, domains=case.domains)
    assert report.ok, f"{case.name}: {report}\n{report.source}"
    assert all(o.max_rel <= 1e-6 for o in report.outputs)
    expected_grad = "skipped" if "stop-gradient" in case.name else "passed"
    assert report.gradcheck.startswith(expected_grad), report.gradcheck


@pytest.mark.parametrize("case", [c for c in CORPUS if c.reference is not None],
                         ids=[c.name for c in CORPUS if c.reference is not None])
def test_the_reading_matches_a_reference_written_by_hand(case: Case):
    rng = np.random.default_rng(1)
    sizes = {"R": 4, "S": 7, **{k: v for k, v in case.sizes.items() if isinstance(v, int)}}
    values = {}
    for key, dims in case.inputs.items():
        shape = tuple(sizes[d] if isinstance(d, str) else d for d in dims)
        lo, hi = case.domains.get(key, (0.1, 0.9))
        values[key] = rng.uniform(lo, hi, size=shape)
    for key, spec in case.sizes.items():
        shape = spec.shape if isinstance(spec, ParamSpec) else spec
        if isinstance(shape, tuple):
            values[key] = rng.normal(0.0, 0.7, size=shape)
    layout = {key: dims for key, dims in case.inputs.items()}
    got = interpret(_parse(case), values, layout, case.sizes, case.outputs)
    want = case.reference(values)
    for key in case.outputs:
        np.testing.assert_allclose(got[key], want[key], rtol=1e-10, atol=1e-12, err_msg=f"{case.name}: {key}")


def test_the_generated_sources_are_clean_python():
    import subprocess
    import sys
    from pathlib import Path

    from nerfify_ns.equations import lower

    ruff = Path(sys.executable).with_name("ruff")
    for case in CORPUS:
        source = lower(_parse(case), case.inputs, case.outputs, case.sizes, "Compiled")
        result = subprocess.run([str(ruff), "check", "--no-cache", "--select", "F,E9,E7", "--stdin-filename",
                                 "compiled.py", "-"], input=source, capture_output=True, text=True)
        assert result.returncode == 0, f"{case.name}: {result.stdout}"
