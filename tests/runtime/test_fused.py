"""The runtime's CPU fast paths (nerfify_ns.runtime.fused) give Nerfstudio's results: each is compared
with the stock implementation on random inputs, values and gradients."""

import os
import subprocess
import sys

import pytest
import torch
from nerfacc.estimators.occ_grid import OccGridEstimator
from nerfstudio.engine.optimizers import AdamOptimizerConfig, OptimizerConfig, RAdamOptimizerConfig
from nerfstudio.field_components.spatial_distortions import SceneContraction

from nerfify_ns.runtime import fused, hashgrid_ext

STOCK_SETUP = OptimizerConfig.__dict__["setup"]
if STOCK_SETUP is fused.fused_optimizer_setup:  # the runtime was activated before this module was imported

    def STOCK_SETUP(self, params):  # noqa: N802 - Nerfstudio 1.1.5's OptimizerConfig.setup, verbatim
        kwargs = vars(self).copy()
        kwargs.pop("_target")
        kwargs.pop("max_norm")
        return self._target(params, **kwargs)


STOCK_CONTRACTION = getattr(SceneContraction.forward, "_nerfify_stock", SceneContraction.forward)
STOCK_OCC_UPDATE = getattr(OccGridEstimator._update, "_nerfify_stock", OccGridEstimator._update)


def _tables(seed: int):
    g = torch.Generator().manual_seed(seed)
    return [torch.nn.Parameter(torch.randn(4096, 2, generator=g) * 1e-4),
            torch.nn.Parameter(torch.randn(64, 32, generator=g)), torch.nn.Parameter(torch.randn(32, generator=g))]


@pytest.mark.parametrize("config", [AdamOptimizerConfig(lr=1e-2, eps=1e-15),
                                    AdamOptimizerConfig(lr=5e-3, eps=1e-8, weight_decay=1e-3)],
                         ids=["adam", "adam-weight-decay"])
def test_fused_optimizer_steps_like_nerfstudios(config):
    ours_params, stock_params = _tables(0), _tables(0)
    ours, stock = fused.fused_optimizer_setup(config, ours_params), STOCK_SETUP(config, stock_params)
    assert ours.defaults["fused"] is True and not stock.defaults.get("fused")
    g = torch.Generator().manual_seed(1)
    for step in range(6):
        for a, b in zip(ours_params, stock_params, strict=False):
            grad = torch.randn(a.shape, generator=g)
            if step % 2:  # hash-grid style: most rows of a table untouched this step
                grad[torch.rand(a.shape[0], generator=g) < 0.9] = 0
            a.grad, b.grad = grad.clone(), grad.clone()
        ours.step()
        stock.step()
    for a, b in zip(ours_params, stock_params, strict=False):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-7)
        torch.testing.assert_close(ours.state[a]["exp_avg_sq"], stock.state[b]["exp_avg_sq"], rtol=1e-5, atol=1e-12)


def test_optimizers_without_a_fused_cpu_kernel_are_built_as_nerfstudio_does():
    optimizer = fused.fused_optimizer_setup(RAdamOptimizerConfig(lr=1e-3), _tables(0))
    assert isinstance(optimizer, torch.optim.RAdam) and not optimizer.defaults.get("fused")
    config = AdamOptimizerConfig(lr=1e-3)
    config.foreach = True  # a config that chooses its implementation keeps it
    assert fused.fused_optimizer_setup(config, _tables(0)).defaults["fused"] is None


@pytest.mark.parametrize("order", [float("inf"), None, 2])
def test_contraction_matches_nerfstudio_values_and_gradients(order):
    g = torch.Generator().manual_seed(3)
    x = torch.randn(4096, 3, generator=g, dtype=torch.float64) * 2.0
    x[:8] = torch.tensor([[2.0, 2.0, 1.0], [-3.0, 3.0, 0.5], [0.5, -0.5, 0.5], [1.0, 0.0, 0.0],
                          [4.0, -4.0, 4.0], [0.0, 0.0, 0.0], [-1.5, 0.2, 1.5], [0.9, 0.9, -0.9]],
                         dtype=torch.float64)  # ties of the L-inf norm, the unit boundary, the origin
    module = SceneContraction(order=order)
    xa, xb = x.clone().requires_grad_(), x.clone().requires_grad_()
    ours, stock = fused.make_contraction_forward(STOCK_CONTRACTION)(module, xa), STOCK_CONTRACTION(module, xb)
    torch.testing.assert_close(ours, stock, rtol=0, atol=1e-15)
    weights = torch.randn(ours.shape, generator=g, dtype=torch.float64)
    (ours * weights).sum().backward()
    (stock * weights).sum().backward()
    torch.testing.assert_close(xa.grad, xb.grad, rtol=1e-12, atol=1e-12, equal_nan=True)  # the origin: NaN in both


def test_contraction_keeps_the_stock_path_for_gaussians():
    from nerfstudio.utils.math import Gaussians

    forward = fused.make_contraction_forward(STOCK_CONTRACTION)
    mean = torch.tensor([[0.2, 0.1, -0.3], [2.0, -1.0, 0.5]])
    cov = torch.eye(3).expand(2, 3, 3).clone() * 0.01
    ours = forward(SceneContraction(), Gaussians(mean=mean, cov=cov))
    stock = STOCK_CONTRACTION(SceneContraction(), Gaussians(mean=mean, cov=cov))
    torch.testing.assert_close(ours.mean, stock.mean)
    torch.testing.assert_close(ours.cov, stock.cov)


def test_chunked_occupancy_update_gives_the_stock_grid(monkeypatch):
    torch.manual_seed(0)
    field = torch.nn.Sequential(torch.nn.Linear(3, 32), torch.nn.ReLU(), torch.nn.Linear(32, 1))

    def occ_eval_fn(x):  # a density field: one value per point
        return torch.nn.functional.softplus(field(x)) * 0.01

    monkeypatch.setattr(fused, "OCC_CHUNK", 1000)  # 2 levels x 16^3 cells: several chunks per level
    grids = []
    for update in (STOCK_OCC_UPDATE, fused.make_chunked_occupancy_update(STOCK_OCC_UPDATE)):
        grid = OccGridEstimator(roi_aabb=[-1.0, -1.0, -1.0, 1.0, 1.0, 1.0], resolution=16, levels=2)
        torch.manual_seed(7)  # the update jitters the cell centres and samples cells at random
        with torch.no_grad():
            for step in (0, 16, 300):  # warm-up (all cells) and afterwards (sampled and occupied cells)
                update(grid, step, occ_eval_fn)
        grids.append(grid)
    torch.testing.assert_close(grids[0].occs, grids[1].occs, rtol=1e-6, atol=1e-9)
    assert torch.equal(grids[0].binaries, grids[1].binaries)
    assert grids[0].binaries.any() and not grids[0].binaries.all()  # the test grid is not trivial


def test_chunked_applies_a_pointwise_function_in_parts():
    calls = []

    def fn(x):
        calls.append(x.shape[0])
        return x.sum(-1, keepdim=True)

    x = torch.randn(2500, 3)
    torch.testing.assert_close(fused.chunked(fn, 1000)(x), x.sum(-1, keepdim=True))
    assert calls == [1000, 1000, 500]


@pytest.mark.skipif(hashgrid_ext.load() is None,
                    reason="the C++ extension is not built (scripts/setup.sh builds it); only the calling "
                           "thread can be set without it")
def test_denormals_are_flushed_in_every_pool_thread():
    """A two-thread elementwise op over denormals: both threads' halves come out zero."""
    code = ("import torch; torch.set_num_threads(2);"
            "x = torch.full((1 << 22,), 1e-39); before = int((x * 1.0 != 0).sum());"
            "from nerfify_ns.runtime.fused import flush_denormals; n = flush_denormals();"
            "print(before, int((x * 1.0 != 0).sum()), n)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "OMP_NUM_THREADS": "2"})
    assert out.returncode == 0, out.stderr[-2000:]
    before, after, threads = map(int, out.stdout.split())
    assert before == 1 << 22 and after == 0 and threads == 2

