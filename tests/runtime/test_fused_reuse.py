"""The hash encodings of nerfacc's alpha test reused by Instant-NGP's field, and the heap that keeps freed
memory (nerfify_ns.runtime.fused, nerfify_ns.runtime.hashgrid): the same values and gradients as computing
everything afresh, checked on random inputs and on a real Nerfstudio model's training step."""

import copy
import subprocess
import sys
import textwrap

import pytest
import torch

from nerfify_ns.runtime import fused, hashgrid, hashgrid_ext

needs_kernel = pytest.mark.skipif(hashgrid_ext.load() is None, reason="the C++ hash-grid kernel is not built here")


def _table(seed: int = 0, levels: int = 4, log2: int = 10) -> tuple[torch.nn.Parameter, torch.Tensor, int]:
    g = torch.Generator().manual_seed(seed)
    table = torch.nn.Parameter(torch.randn(levels << log2, 2, generator=g) * 0.1)
    return table, torch.tensor([4.0, 9.0, 20.0, 45.0][:levels]), 1 << log2


@pytest.fixture
def count_reuse(monkeypatch):
    calls = []
    apply = hashgrid_ext.HashGridReusedFunction.apply
    monkeypatch.setattr(hashgrid_ext.HashGridReusedFunction, "apply",
                        lambda *args: calls.append(args[0].shape[0]) or apply(*args))
    return calls


@needs_kernel
def test_recorded_rows_are_reused_with_the_same_values_and_table_gradient(count_reuse):
    table, scalings, size = _table()
    g = torch.Generator().manual_seed(1)
    x = torch.rand(5000, 3, generator=g)
    mask = torch.rand(5000, generator=g) < 0.6
    with torch.no_grad(), hashgrid.recording_encodings():
        hashgrid.hash_encode(x, table, scalings, size)
    hashgrid.keep_recorded_rows(mask)
    kept = x[mask].requires_grad_(True)  # Nerfstudio's field asks for gradients w.r.t. its sample positions
    reused = hashgrid.hash_encode(kept, table, scalings, size)
    assert count_reuse == [int(mask.sum())]
    weights = torch.randn(reused.shape, generator=g)
    (reused * weights).sum().backward()
    grad_reused, table.grad = table.grad.clone(), None
    fresh_kept = x[mask].requires_grad_(True)
    fresh = hashgrid.hash_encode(fresh_kept, table, scalings, size)
    (fresh * weights).sum().backward()
    assert count_reuse == [int(mask.sum())]  # a record is used once
    assert torch.equal(reused, fresh)
    torch.testing.assert_close(grad_reused, table.grad, rtol=0, atol=0)
    torch.testing.assert_close(kept.grad, fresh_kept.grad, rtol=0, atol=0)


@needs_kernel
def test_no_reuse_for_other_positions_an_updated_table_or_outside_the_alpha_test(count_reuse):
    table, scalings, size = _table()
    x = torch.rand(300, 3, generator=torch.Generator().manual_seed(2))
    keep = torch.ones(300, dtype=torch.bool)

    def record() -> None:
        with torch.no_grad(), hashgrid.recording_encodings():
            hashgrid.hash_encode(x, table, scalings, size)
        hashgrid.keep_recorded_rows(keep)

    record()
    moved = x.clone()
    moved[7, 0] = torch.nextafter(moved[7, 0], torch.tensor(2.0))  # one position one ulp away
    torch.testing.assert_close(hashgrid.hash_encode(moved, table, scalings, size),
                               hashgrid.hash_encode(moved, table, scalings, size))
    record()
    with torch.no_grad():
        table.add_(0.5)  # an optimiser step between the alpha test and the field
    out = hashgrid.hash_encode(x, table, scalings, size)
    with torch.no_grad():
        hashgrid.hash_encode(x, table, scalings, size)  # outside recording_encodings: nothing recorded
    hashgrid.keep_recorded_rows(keep)
    assert torch.equal(out, hashgrid.hash_encode(x, table, scalings, size))
    assert count_reuse == []


def _instant_ngp_step(model, seed: int):
    """Forward and backward of one training step on fixed random rays (stratified marching seeded)."""
    from nerfify_ns.benchmarks import step_timing

    bundle, batch = step_timing.ray_batch(96, seed=3)
    model.train()
    model.zero_grad(set_to_none=True)
    torch.manual_seed(seed)
    outputs = model.get_outputs(bundle)
    losses = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))
    sum(losses.values()).backward()
    grads = {name: p.grad.clone() for name, p in model.named_parameters() if p.grad is not None}
    return {k: v.detach().clone() for k, v in outputs.items() if isinstance(v, torch.Tensor)}, grads


@needs_kernel
def test_instant_ngp_step_is_unchanged_by_the_reuse(monkeypatch, count_reuse):
    """A real Instant-NGP model (Nerfstudio's config, a small occupancy grid): its step with the alpha test's
    encodings reused gives the outputs and parameter gradients of the stock sampler's step."""
    import nerfacc.estimators.occ_grid as occ_grid
    from nerfstudio.configs.method_configs import all_methods
    from nerfstudio.model_components.ray_samplers import VolumetricSampler

    from nerfify_ns.benchmarks import step_timing

    stock_sigma = getattr(VolumetricSampler.get_sigma_fn, "_nerfify_stock", VolumetricSampler.get_sigma_fn)
    stock_vis = getattr(occ_grid.render_visibility_from_density, "_nerfify_stock",
                        occ_grid.render_visibility_from_density)
    config = copy.deepcopy(all_methods["instant-ngp"])
    config.pipeline.model.grid_resolution = 16
    model = step_timing.build_model(config)
    step_timing.run_before_iteration_callbacks(model, 0)  # the warm-up grid update: every cell
    monkeypatch.setattr(VolumetricSampler, "get_sigma_fn", stock_sigma)
    monkeypatch.setattr(occ_grid, "render_visibility_from_density", stock_vis)
    stock_out, stock_grads = _instant_ngp_step(model, seed=5)
    assert count_reuse == []
    monkeypatch.setattr(VolumetricSampler, "get_sigma_fn", fused.make_recording_sigma_fn(stock_sigma))
    monkeypatch.setattr(occ_grid, "render_visibility_from_density", fused.make_visibility_recorder(stock_vis))
    ours_out, ours_grads = _instant_ngp_step(model, seed=5)
    assert len(count_reuse) == 1 and count_reuse[0] == int(ours_out["num_samples_per_ray"].sum()) > 0
    assert stock_out.keys() == ours_out.keys() and stock_grads.keys() == ours_grads.keys()
    for name in stock_out:
        torch.testing.assert_close(ours_out[name], stock_out[name], rtol=1e-6, atol=1e-7, msg=name)
    for name in stock_grads:
        torch.testing.assert_close(ours_grads[name], stock_grads[name], rtol=1e-5, atol=1e-7, msg=name)


def test_freed_memory_is_reused_without_page_faults():
    """With the patch a freed 64 MB block is reused as it is (no new pages); with glibc's defaults each such
    block is a fresh mapping whose pages fault in again. Counted as minor page faults, in a fresh process."""
    code = textwrap.dedent("""
        import resource, torch
        from nerfify_ns.runtime.fused import reuse_freed_memory

        def faults():
            for _ in range(24):  # torch's aligned blocks settle into reusable heap chunks after a few rounds
                torch.empty(16 << 20).fill_(1.0)  # 64 MB, freed at once
            before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            for _ in range(4):
                torch.empty(16 << 20).fill_(1.0)
            return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

        assert reuse_freed_memory(False)
        off = faults()
        assert reuse_freed_memory(True)
        print(off, faults())
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    if proc.returncode != 0 and "mallopt" in proc.stderr:
        pytest.skip("not glibc")
    assert proc.returncode == 0, proc.stderr[-2000:]
    off, on = map(int, proc.stdout.split())
    assert off > 4 * 8000  # each block's 16,384 pages of 4 KiB fault in again
    assert on < 1000
