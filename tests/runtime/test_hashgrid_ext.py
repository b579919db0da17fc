"""The fused C++ hash-grid kernel against Nerfstudio's own torch fallback (the oracle), and its loading rules.

The kernel is built once per session: the installed build is used when ``load()`` finds one,
otherwise it is compiled into a temporary cache (about a minute).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
import torch
from hashgrid_oracle import STOCK, make_encoding, off_grid, run
from nerfstudio.field_components.encodings import HashEncoding

from nerfify_ns.runtime import hashgrid, hashgrid_ext
from nerfify_ns.runtime.hashgrid import fast_pytorch_fwd, hash_encode
from nerfify_ns.runtime.paths import ENV_CACHE


@pytest.fixture(scope="session")
def ext_cache(tmp_path_factory) -> Path:
    """A ``NERFIFY_CACHE`` holding a built kernel: the configured one if built, else a fresh temporary one."""
    configured = os.environ.get(ENV_CACHE)
    if hashgrid_ext.load() is not None:
        return Path(configured) if configured else Path.home() / ".cache" / "nerfify"
    if shutil.which(os.environ.get("CXX", "c++")) is None:
        pytest.skip("no C++ compiler to build the hash-grid kernel")
    cache = tmp_path_factory.mktemp("nerfify_cache")
    with pytest.MonkeyPatch.context() as mp:  # only while building: other tests keep their cache
        mp.setenv(ENV_CACHE, str(cache))
        hashgrid_ext.build()
        assert hashgrid_ext.load() is not None
    return cache


@pytest.fixture()
def cpp(ext_cache, monkeypatch):
    """The kernel module, with ``hash_encode`` forced onto it for the test."""
    monkeypatch.setenv(ENV_CACHE, str(ext_cache))
    monkeypatch.setenv(hashgrid.ENV_IMPL, "cpp")
    module = hashgrid_ext.load()
    assert module is not None
    return module




def cpp_fwd(enc: HashEncoding, x: torch.Tensor) -> torch.Tensor:
    """The C++ op called directly (not through the dispatcher)."""
    flat = x.reshape(-1, 3)
    fn = hashgrid_ext.HashGridCppFunction.apply
    out = fn(flat, enc.hash_table, enc.scalings.to(x), enc.hash_table_size)
    return out.reshape(*x.shape[:-1], out.shape[-1])






@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("features", [1, 2, 4])
@pytest.mark.parametrize("levels,log2_size", [(1, 8), (4, 12), (16, 19)])
def test_matches_stock_float64(cpp, features, levels, log2_size, threads):
    enc = make_encoding(levels, log2_size, features, dtype=torch.float64)
    x = torch.rand(500, 3, dtype=torch.float64)
    g = torch.randn(500, levels * features, dtype=torch.float64)
    ref = run(STOCK, enc, x, g)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        ours = run(cpp_fwd, enc, x, g)
    finally:
        torch.set_num_threads(before)
    keep = off_grid(x, enc)
    assert torch.allclose(ours[0], ref[0], atol=1e-12)
    assert torch.allclose(ours[1], ref[1], atol=1e-10)
    assert torch.allclose(ours[2][keep], ref[2][keep], rtol=1e-9, atol=1e-8)


@pytest.mark.parametrize("features", [1, 2, 4])
def test_matches_stock_float32_nerfacto_size(cpp, features):
    enc = make_encoding(features=features)
    x = torch.rand(4000, 3)
    g = torch.randn(4000, 16 * features)
    ref, ours = run(STOCK, enc, x, g), run(cpp_fwd, enc, x, g)
    keep = off_grid(x, enc)
    assert all(t.dtype == torch.float32 for t in ours)
    assert torch.allclose(ours[0], ref[0], atol=1e-5)
    assert torch.allclose(ours[1], ref[1], atol=1e-4)
    scale = ref[2].abs().max()
    assert ((ours[2] - ref[2])[keep].abs().max() / scale) < 1e-4


@pytest.mark.parametrize("schedule", [1, 2])
@pytest.mark.parametrize("threads", [1, 2, 3])
def test_backward_schedules_agree(cpp, schedule, threads):
    """Both table-gradient schedules (by level, by point with per-task copies) give the same gradients."""
    enc = make_encoding(5, 10, 2, dtype=torch.float64, max_res=128)
    x = torch.rand(3000, 3, dtype=torch.float64)
    g = torch.randn(3000, 10, dtype=torch.float64)
    ref = run(STOCK, enc, x, g)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        g_table, g_pos = cpp.backward(g, x, enc.hash_table.detach(), enc.scalings.double(), 2**10, True, True,
                                      schedule)
    finally:
        torch.set_num_threads(before)
    keep = off_grid(x, enc)
    assert torch.allclose(g_table, ref[1], atol=1e-10)
    assert torch.allclose(g_pos[keep], ref[2][keep], rtol=1e-9, atol=1e-8)


def test_only_requested_gradients(cpp):
    enc = make_encoding(4, 10, 2, dtype=torch.float64)
    x = torch.rand(100, 3, dtype=torch.float64)
    g = torch.randn(100, 8, dtype=torch.float64)
    g_table, g_pos = cpp.backward(g, x, enc.hash_table.detach(), enc.scalings.double(), 2**10, True, False)
    assert g_table.shape == enc.hash_table.shape and g_pos.numel() == 0
    g_table, g_pos = cpp.backward(g, x, enc.hash_table.detach(), enc.scalings.double(), 2**10, False, True)
    assert g_table.numel() == 0 and g_pos.shape == (100, 3)
    out = cpp_fwd(enc, x)  # positions without grad: only the table gradient flows
    (g_table2,) = torch.autograd.grad(out, [enc.hash_table], g)
    assert torch.allclose(g_table2, run(STOCK, enc, x, g)[1], atol=1e-10)


def test_outside_unit_cube_and_negative_coordinates(cpp):
    enc = make_encoding(4, 12, dtype=torch.float64)
    x = torch.rand(300, 3, dtype=torch.float64) * 6 - 3  # hashes negative cell indices
    g = torch.randn(300, 8, dtype=torch.float64)
    ref, ours = run(STOCK, enc, x, g), run(cpp_fwd, enc, x, g)
    keep = off_grid(x, enc)
    assert torch.allclose(ours[0], ref[0], atol=1e-12)
    assert torch.allclose(ours[1], ref[1], atol=1e-10)
    assert torch.allclose(ours[2][keep], ref[2][keep], rtol=1e-9, atol=1e-8)


def test_on_grid_points_value_matches_and_gradient_is_right_sided(cpp):
    enc = make_encoding(2, 10, dtype=torch.float64, max_res=32)
    x = torch.tensor([[0.5, 0.25, 0.125]], dtype=torch.float64)  # integer at every level
    out = cpp_fwd(enc, x).detach()
    assert torch.allclose(out, STOCK(enc, x), atol=1e-12)
    xx = x.clone().requires_grad_(True)
    grad, = torch.autograd.grad(cpp_fwd(enc, xx)[0, 0], xx)
    h = 1e-7
    for axis in range(3):
        step = torch.zeros_like(x)
        step[0, axis] = h
        right = (cpp_fwd(enc, x + step)[0, 0] - out[0, 0]).detach() / h
        assert abs(float(right - grad[0, axis])) < 1e-5


def test_gradcheck_small(cpp):
    enc = make_encoding(3, 6, 2, dtype=torch.float64, max_res=16)
    x = (torch.rand(20, 3, dtype=torch.float64) * 0.9 + 0.05).requires_grad_(True)
    table = enc.hash_table.detach().clone().requires_grad_(True)
    scalings = enc.scalings.double()
    fn = hashgrid_ext.HashGridCppFunction.apply
    assert torch.autograd.gradcheck(lambda p, t: fn(p, t, scalings, 2**6), (x, table))


def test_empty_and_batched_shapes_through_hash_encode(cpp):
    enc = make_encoding(4, 10)
    empty = torch.zeros(0, 3, requires_grad=True)
    out = fast_pytorch_fwd(enc, empty)
    assert out.shape == (0, 8)
    g_table, g_pos = torch.autograd.grad(out.sum(), [enc.hash_table, empty])
    assert g_pos.shape == (0, 3) and float(g_table.abs().sum()) == 0.0
    x = torch.rand(2, 5, 7, 3)
    out = fast_pytorch_fwd(enc, x)
    assert out.shape == (2, 5, 7, 8)
    assert torch.allclose(out, STOCK(enc, x), atol=1e-6)
    strided = torch.rand(40, 6)[:, ::2]  # non-contiguous positions
    assert torch.allclose(fast_pytorch_fwd(enc, strided), STOCK(enc, strided), atol=1e-6)


def test_dispatch_follows_env(ext_cache, monkeypatch):
    """auto and cpp take the kernel, torch the torch path; both agree."""
    monkeypatch.setenv(ENV_CACHE, str(ext_cache))
    enc = make_encoding(4, 10)
    x = torch.rand(64, 3)
    calls = []
    original = hashgrid_ext.HashGridCppFunction.apply
    monkeypatch.setattr(hashgrid_ext.HashGridCppFunction, "apply", lambda *a: calls.append(1) or original(*a))
    results = {}
    for impl in ("auto", "cpp", "torch"):
        monkeypatch.setenv(hashgrid.ENV_IMPL, impl)
        before = len(calls)
        results[impl] = fast_pytorch_fwd(enc, x)
        assert (len(calls) > before) == (impl != "torch")
    assert torch.allclose(results["cpp"], results["torch"], atol=1e-6)
    monkeypatch.setenv(hashgrid.ENV_IMPL, "cpp")
    with pytest.raises(RuntimeError, match="float32/float64"):  # forced, but the kernel cannot take it
        hash_encode(x.half(), enc.hash_table.detach().half(), enc.scalings, 2**10)
    monkeypatch.setenv(hashgrid.ENV_IMPL, "bogus")
    with pytest.raises(ValueError, match="NERFIFY_HASHGRID_IMPL"):
        fast_pytorch_fwd(enc, x)


def test_load_never_compiles(tmp_path, monkeypatch):
    """An empty cache means "not available" (None), never a build; forcing cpp then says how to build."""
    from torch.utils import cpp_extension

    def no_build(*args, **kwargs):
        raise AssertionError("load() must not compile")

    monkeypatch.setattr(cpp_extension, "load", no_build)
    monkeypatch.setattr(cpp_extension, "load_inline", no_build)
    monkeypatch.setenv(ENV_CACHE, str(tmp_path / "empty"))
    assert hashgrid_ext.load() is None
    assert not (tmp_path / "empty").exists()
    enc = make_encoding(2, 8)
    x = torch.rand(10, 3)
    monkeypatch.setenv(hashgrid.ENV_IMPL, "auto")
    assert torch.allclose(fast_pytorch_fwd(enc, x), STOCK(enc, x), atol=1e-6)  # falls back to torch
    monkeypatch.setenv(hashgrid.ENV_IMPL, "cpp")
    with pytest.raises(RuntimeError, match="hashgrid_ext build"):
        fast_pytorch_fwd(enc, x)


def test_stale_or_broken_library_is_not_loaded(ext_cache, tmp_path, monkeypatch):
    """A library whose stamp does not match the source, or that cannot be imported, gives None."""
    monkeypatch.setenv(ENV_CACHE, str(ext_cache))
    built = hashgrid_ext.library_path()
    stamp = built.parent / f"{hashgrid_ext.EXT_NAME}{hashgrid_ext.STAMP_SUFFIX}"
    copy_dir = tmp_path / "ext" / torch.__version__
    copy_dir.mkdir(parents=True)
    shutil.copy(built, copy_dir / built.name)
    monkeypatch.setenv(ENV_CACHE, str(tmp_path))
    with pytest.warns(RuntimeWarning, match="stale"):
        assert hashgrid_ext.load() is None  # no stamp
    broken = tmp_path / "broken"
    broken_dir = broken / "ext" / torch.__version__
    broken_dir.mkdir(parents=True)
    (broken_dir / built.name).write_bytes(b"not a shared library")
    shutil.copy(stamp, broken_dir / stamp.name)
    monkeypatch.setenv(ENV_CACHE, str(broken))
    with pytest.warns(RuntimeWarning, match="failed to load"):
        assert hashgrid_ext.load() is None


def test_cli_status(ext_cache, monkeypatch, capsys, tmp_path):
    monkeypatch.setenv(ENV_CACHE, str(ext_cache))
    assert hashgrid_ext.main(["status"]) == 0
    assert capsys.readouterr().out.strip() == str(hashgrid_ext.library_path())
    monkeypatch.setenv(ENV_CACHE, str(tmp_path / "none"))
    assert hashgrid_ext.main(["status"]) == 1
