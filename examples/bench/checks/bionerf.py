"""Checks of BioNeRF (Passos et al. 2024) items: reference functions written from the paper's equations."""

import numpy as np
import torch


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


def filters_and_memory(target):
    """Eqs. 1-9 (Sec. 3): the filters f_Delta, f_c, f_psi, f_mu (sigmoid), gamma (tanh), mu = f_mu * gamma, the
    memory Psi = tanh(W_Psi (mu + f_psi * Psi) + b_Psi), and the outputs [Psi * f_Delta, l] and Psi * f_c, against
    the generated backbone in float64 on random inputs (its own weights)."""
    assert target.cls is not None, "no compiled component implements Eqs. 1-9"
    module = target.cls(in_dim=7).double()
    eq = module.equations
    p = {name: t.detach().numpy() for name, t in eq.named_parameters()}
    rng = np.random.default_rng(1)
    h_d, h_c, psi = (rng.normal(size=(5, 256)) for _ in range(3))
    l_in = rng.normal(size=(5, 7))
    hdc = np.concatenate([h_d, h_c], -1)
    f_d = _sigmoid(h_d @ p["p_w_delta_f"].T + p["p_b_delta_f"])                       # (1)
    f_c = _sigmoid(h_c @ p["p_w_c_f"].T + p["p_b_c_f"])                               # (2)
    f_psi = _sigmoid(hdc @ p["p_w_psi_f"].T + p["p_b_psi_f"])                         # (3)
    f_mu = _sigmoid(hdc @ p["p_w_mu_f"].T + p["p_b_mu_f"])                            # (4)
    gamma = np.tanh(hdc @ p["p_w_gamma"].T + p["p_b_gamma"])                          # (5)
    mu = f_mu * gamma                                                                 # (6)
    psi_new = np.tanh((mu + f_psi * psi) @ p["p_w_psi"].T + p["p_b_psi"])             # (7)
    want = (np.concatenate([psi_new * f_d, l_in], -1), psi_new * f_c, psi_new)        # (8), (9)
    got = eq(*(torch.from_numpy(a) for a in (h_d, h_c, l_in, psi)))
    for value, ref in zip(got, want, strict=False):
        np.testing.assert_allclose(value.detach().numpy(), ref, rtol=1e-9, atol=1e-12)


def memory_size(target):
    """Sec. 3: the memory Psi holds z = 8,192 rows (persistent state of the backbone)."""
    assert target.record is not None, "no equations.yaml record for the backbone"
    rows = (target.record.get("state") or {}).get("Psi", {}).get("rows")
    assert rows == 8192, f"memory rows {rows}, the paper's z is 8,192"


def loss(target):
    """Eq. 10: L = MSE(r(Delta, c), g), the mean squared error between the rendered and the true pixel colour."""
    import importlib.util
    from pathlib import Path

    assert "l2" in (target.value or {}), f"the plan's colour loss is {target.value}, Eq. 10 is a mean squared error"
    spec = importlib.util.spec_from_file_location("nerfify_bench_refs", Path(__file__).with_name("_refs.py"))
    refs = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(refs)
    refs.mse(torch.nn.MSELoss())
