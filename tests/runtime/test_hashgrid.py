"""The fast hash encoding against Nerfstudio's own torch fallback (the oracle), values and gradients."""

import copy

import pytest
import torch
from hashgrid_oracle import STOCK, make_encoding, off_grid, run

from nerfify_ns.runtime.hashgrid import corner_indices, corner_weights, fast_pytorch_fwd, hash_encode


@pytest.fixture(autouse=True)
def torch_path(monkeypatch):
    """These tests cover the pure-torch path; tests/test_hashgrid_ext.py covers the C++ kernel."""
    monkeypatch.setenv("NERFIFY_HASHGRID_IMPL", "torch")








@pytest.mark.parametrize("features", [1, 2, 4])
@pytest.mark.parametrize("levels,log2_size", [(1, 8), (4, 12), (16, 19)])
def test_matches_stock_float64(features, levels, log2_size):
    enc = make_encoding(levels, log2_size, features, dtype=torch.float64)
    x = torch.rand(500, 3, dtype=torch.float64)
    g = torch.randn(500, levels * features, dtype=torch.float64)
    ref = run(STOCK, enc, x, g)
    ours = run(fast_pytorch_fwd, enc, x, g)
    keep = off_grid(x, enc)
    assert torch.allclose(ours[0], ref[0], atol=1e-12)
    assert torch.allclose(ours[1], ref[1], atol=1e-10)
    assert torch.allclose(ours[2][keep], ref[2][keep], rtol=1e-9, atol=1e-8)


def test_matches_stock_float32_nerfacto_size():
    enc = make_encoding()
    x = torch.rand(4000, 3)
    g = torch.randn(4000, 32)
    ref, ours = run(STOCK, enc, x, g), run(fast_pytorch_fwd, enc, x, g)
    keep = off_grid(x, enc)
    assert torch.allclose(ours[0], ref[0], atol=1e-5)
    assert torch.allclose(ours[1], ref[1], atol=1e-4)
    scale = ref[2].abs().max()
    assert ((ours[2] - ref[2])[keep].abs().max() / scale) < 1e-4


def test_outside_unit_cube_and_negative_coordinates():
    enc = make_encoding(4, 12, dtype=torch.float64)
    x = torch.rand(300, 3, dtype=torch.float64) * 6 - 3  # hashes negative cell indices
    g = torch.randn(300, 8, dtype=torch.float64)
    ref, ours = run(STOCK, enc, x, g), run(fast_pytorch_fwd, enc, x, g)
    assert torch.allclose(ours[0], ref[0], atol=1e-12)
    assert torch.allclose(ours[1], ref[1], atol=1e-10)


def test_on_grid_points_value_matches_and_gradient_is_right_sided():
    enc = make_encoding(2, 10, dtype=torch.float64, max_res=32)
    x = torch.tensor([[0.5, 0.25, 0.125]], dtype=torch.float64)  # integer at every level
    out = fast_pytorch_fwd(enc, x)
    assert torch.allclose(out, STOCK(enc, x), atol=1e-12)
    h = 1e-7
    xx = x.clone().requires_grad_(True)
    grad, = torch.autograd.grad(fast_pytorch_fwd(enc, xx)[0, 0], xx)
    for axis in range(3):
        step = torch.zeros_like(x)
        step[0, axis] = h
        right = (fast_pytorch_fwd(enc, x + step)[0, 0] - out[0, 0]) / h
        assert abs(float(right - grad[0, axis])) < 1e-5


def test_gradcheck_small():
    enc = make_encoding(3, 6, 2, dtype=torch.float64, max_res=16)
    x = (torch.rand(20, 3, dtype=torch.float64) * 0.9 + 0.05).requires_grad_(True)
    table = enc.hash_table.detach().clone().requires_grad_(True)
    scalings = enc.scalings.double()
    assert torch.autograd.gradcheck(lambda p, t: hash_encode(p, t, scalings, 2**6), (x, table))


def test_empty_and_batched_shapes():
    enc = make_encoding(4, 10)
    assert fast_pytorch_fwd(enc, torch.zeros(0, 3)).shape == (0, 8)
    x = torch.rand(2, 5, 7, 3)
    out = fast_pytorch_fwd(enc, x)
    assert out.shape == (2, 5, 7, 8)
    assert torch.allclose(out, STOCK(enc, x), atol=1e-6)


def test_weights_partition_unity_and_indices_in_range():
    x = torch.rand(100, 3)
    scalings = torch.tensor([16.0, 37.0, 512.0])
    idx, frac = corner_indices(x, scalings, 2**10)
    weights = corner_weights(frac)
    assert idx.shape == weights.shape == (3, 100, 8)
    assert torch.allclose(weights.sum(-1), torch.ones(3, 100))
    for level in range(3):  # each level addresses its own slice of the flat table
        assert int(idx[level].min()) >= level * 2**10 and int(idx[level].max()) < (level + 1) * 2**10


def test_checkpoint_interchangeable_with_stock_layout():
    enc = make_encoding(4, 10)
    clone = copy.deepcopy(enc)
    clone.load_state_dict(enc.state_dict())
    x = torch.rand(50, 3)
    assert torch.allclose(fast_pytorch_fwd(clone, x), STOCK(enc, x), atol=1e-6)
    assert list(enc.state_dict()) == ["hash_table"]
