"""Tests for nerfify_ns.runtime.nerfacc_cpu: the pure-torch stand-in for nerfacc's CUDA ops.

Every op is compared with a plain reference written from its definition (Python loops over rays
or segments), outputs and gradients, including edge cases.  Tolerances are stated per test.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from nerfify_ns.runtime import nerfacc_cpu as nc

# The backend is installed for the whole module (on a CUDA machine too: force=True, so the tests
# exercise the torch backend there as well).
nc.install(force=True)

import nerfacc  # noqa: E402
from nerfacc.data_specs import RayIntervals  # noqa: E402
from nerfacc.grid import _ray_aabb_intersect  # noqa: E402

C = nc.backend
REPO = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
def _packed(cnts):
    cnts = torch.as_tensor(cnts, dtype=torch.long)
    starts = torch.cumsum(cnts, 0) - cnts
    return torch.stack([starts, cnts], -1)


def _ref_scan(x, starts, cnts, op, exclusive=False, reverse=False):
    """Per-chunk torch.cumsum / torch.cumprod in a Python loop (reference only)."""
    out = torch.zeros_like(x)
    ident = 0.0 if op == "sum" else 1.0
    for s, c in zip(starts.tolist(), cnts.tolist(), strict=False):
        if c == 0:
            continue
        seg = x[s : s + c]
        if reverse:
            seg = seg.flip(0)
        if exclusive:
            seg = torch.cat([seg.new_full((1,), ident), seg[:-1]])
        y = torch.cumsum(seg, 0) if op == "sum" else torch.cumprod(seg, 0)
        if reverse:
            y = y.flip(0)
        out[s : s + c] = y
    return out


def _ref_weights(t_starts, t_ends, sigmas, ray_indices, n_rays):
    """T_i = exp(-sum_{j<i} sigma_j delta_j), w_i = T_i (1 - exp(-sigma_i delta_i)), per ray."""
    w = torch.zeros_like(sigmas)
    T = torch.zeros_like(sigmas)
    a = torch.zeros_like(sigmas)
    for r in range(n_rays):
        idx = torch.nonzero(ray_indices == r).squeeze(1)
        acc = sigmas.new_zeros(())
        for i in idx.tolist():
            sd = sigmas[i] * (t_ends[i] - t_starts[i])
            T = T.index_put((torch.tensor([i]),), torch.exp(-acc).reshape(1))
            a = a.index_put((torch.tensor([i]),), (1 - torch.exp(-sd)).reshape(1))
            w = w.index_put((torch.tensor([i]),), (torch.exp(-acc) * (1 - torch.exp(-sd))).reshape(1))
            acc = acc + sd
    return w, T, a


def _random_rays(n, gen, radius=3.0, spread=1.2, dtype=torch.float64):
    o = torch.randn(n, 3, generator=gen, dtype=dtype)
    o = o / o.norm(dim=-1, keepdim=True) * radius
    tgt = (torch.rand(n, 3, generator=gen, dtype=dtype) * 2 - 1) * spread
    d = tgt - o
    return o, d / d.norm(dim=-1, keepdim=True)


# ---------------------------------------------------------------------------------------------
# installation / no JIT build
# ---------------------------------------------------------------------------------------------
def test_install_registers_backend_and_is_idempotent():
    assert nc.install(force=True) is True
    assert nc.install(force=True) is True
    assert nc.is_installed()
    assert sys.modules["nerfacc.cuda._backend"]._C is nc.backend
    assert nc.backend.is_cub_available() is False
    for name in (
        "ray_aabb_intersect", "traverse_grids", "inclusive_sum", "exclusive_sum", "exclusive_sum_by_key",
        "inclusive_prod_forward", "inclusive_prod_backward",
        "exclusive_prod_forward", "exclusive_prod_backward",
        "searchsorted", "importance_sampling", "RaySegmentsSpec", "RaysSpec", "MultiScaleGridSpec",
        "opencv_lens_undistortion", "opencv_lens_undistortion_fisheye",
    ):
        assert hasattr(nc.backend, name), name


def test_install_is_a_noop_when_cuda_is_available(monkeypatch):
    nc.uninstall()
    try:
        monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
        assert nc.install() is False
        assert not nc.is_installed()
        assert getattr(sys.modules.get("nerfacc.cuda._backend"), "_C", None) is not nc.backend
    finally:
        monkeypatch.undo()
        assert nc.install(force=True) is True


def test_no_jit_build_is_ever_attempted(tmp_path):
    """Fresh interpreter: cpp_extension.load raises if called; nerfacc ops must still work."""
    script = textwrap.dedent(
        """
        import sys, torch, torch.utils.cpp_extension as ext
        def boom(*a, **k):
            raise AssertionError("JIT build attempted")
        ext.load = boom
        ext._get_build_directory = boom
        from nerfify_ns.runtime.nerfacc_cpu import install, is_installed
        assert install(force=True) and is_installed()
        import nerfacc
        est = nerfacc.OccGridEstimator(roi_aabb=[-1, -1, -1, 1, 1, 1], resolution=16, levels=2)
        est.binaries[:] = True
        o = torch.tensor([[0.0, 0.0, -3.0]]); d = torch.tensor([[0.0, 0.0, 1.0]])
        ri, t0, t1 = est.sampling(o, d, render_step_size=0.05,
                                  sigma_fn=lambda a, b, r: torch.ones_like(a))
        w, _, _ = nerfacc.render_weight_from_density(t0, t1, torch.ones_like(t0), ray_indices=ri, n_rays=1)
        nerfacc.inclusive_prod(torch.rand(5), torch.tensor([[0, 5]]))
        est.train(); est.update_every_n_steps(0, lambda x: torch.ones_like(x[:, :1]))
        assert t0.numel() > 0 and torch.isfinite(w).all()
        assert "nerfacc.cuda._backend" in sys.modules
        assert sys.modules["nerfacc.cuda._backend"].__file__.endswith("nerfacc_cpu.py")
        print("OK")
        """
    )
    env = dict(os.environ, CUDA_VISIBLE_DEVICES="",
               PYTHONPATH=os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p))
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "OK" in res.stdout


def test_single_thread_scope_restores_thread_count():
    before = torch.get_num_threads()
    with nc._single_thread():
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before


def test_pack_info_cpu():
    ri = torch.tensor([0, 0, 2, 2, 2, 4])
    pi = nerfacc.pack_info(ri, n_rays=6)
    assert pi.tolist() == [[0, 2], [2, 0], [2, 3], [5, 0], [5, 1], [6, 0]]
    assert nerfacc.pack_info(ri).shape == (5, 2)
    assert nerfacc.pack_info(torch.zeros(0, dtype=torch.long), n_rays=3).tolist() == [[0, 0]] * 3


# ---------------------------------------------------------------------------------------------
# ray_aabb_intersect
# ---------------------------------------------------------------------------------------------
def test_ray_aabb_intersect_matches_reference():
    """Exact (float32) agreement with nerfacc's pure-torch _ray_aabb_intersect on random rays,
    rays that miss, start inside, and axis-parallel rays (zero direction components)."""
    g = torch.Generator().manual_seed(0)
    o = torch.randn(2000, 3, generator=g) * 2
    d = torch.randn(2000, 3, generator=g)
    d[:100, 0] = 0.0  # parallel to the yz plane
    d[100:200, :2] = 0.0  # parallel to z
    d[200:220] = torch.tensor([0.0, -1.0, 0.0])
    d = d / d.norm(dim=-1, keepdim=True)
    aabbs = torch.tensor([[-1.0, -1.0, -1.0, 1.0, 1.0, 1.0], [-2.0, -0.5, -3.0, 0.5, 2.5, 1.0]])
    t0, t1, hit = nerfacc.ray_aabb_intersect(o, d, aabbs)
    r0, r1, rhit = _ray_aabb_intersect(o, d, aabbs)
    assert torch.equal(hit, rhit)
    assert hit.any() and (~hit).any()
    torch.testing.assert_close(t0[hit], r0[hit], rtol=0, atol=1e-6)
    torch.testing.assert_close(t1[hit], r1[hit], rtol=0, atol=1e-6)
    assert torch.isinf(t0[~hit]).all()
    inside = (o.abs() < 1).all(-1)
    assert (t0[inside, 0] < 0).all() and hit[inside, 0].all()
    # near / far planes: the kernel clamps tmin from below and tmax from above, misses get miss_value
    n0, n1, nhit = nerfacc.ray_aabb_intersect(o, d, aabbs, near_plane=0.3, far_plane=2.0, miss_value=-7.0)
    assert torch.equal(nhit, hit)
    torch.testing.assert_close(n0[hit], r0[hit].clamp_min(0.3), rtol=0, atol=1e-6)
    torch.testing.assert_close(n1[hit], r1[hit].clamp_max(2.0), rtol=0, atol=1e-6)
    assert (n0[~hit] == -7.0).all()


def test_ray_aabb_intersect_empty_and_single():
    aabbs = torch.tensor([[-1.0, -1.0, -1.0, 1.0, 1.0, 1.0]])
    t0, t1, hit = nerfacc.ray_aabb_intersect(torch.zeros(0, 3), torch.zeros(0, 3), aabbs)
    assert t0.shape == (0, 1) and hit.dtype == torch.bool
    o, d = torch.tensor([[0.0, 0.0, -5.0]]), torch.tensor([[0.0, 0.0, 1.0]])
    t0, t1, hit = nerfacc.ray_aabb_intersect(o, d, aabbs)
    assert hit.item() and t0.item() == pytest.approx(4.0) and t1.item() == pytest.approx(6.0)


# ---------------------------------------------------------------------------------------------
# scans
# ---------------------------------------------------------------------------------------------
CNTS = [3, 0, 1, 7, 2, 0, 40, 5]


@pytest.mark.parametrize("exclusive", [False, True])
def test_sum_scans_forward_backward(exclusive):
    """Forward vs per-chunk torch.cumsum (atol 1e-5, float32); backward equals the reverse scan,
    and gradcheck in float64 through nerfacc's autograd Functions."""
    g = torch.Generator().manual_seed(1)
    pi = _packed(CNTS)
    x = torch.randn(sum(CNTS), generator=g)
    fn = nerfacc.exclusive_sum if exclusive else nerfacc.inclusive_sum
    ref = _ref_scan(x, pi[:, 0], pi[:, 1], "sum", exclusive)
    torch.testing.assert_close(fn(x, pi), ref, atol=1e-5, rtol=0)
    op = C.exclusive_sum if exclusive else C.inclusive_sum
    gy = torch.randn_like(x)
    back = op(pi[:, 0], pi[:, 1], gy, False, True)
    ref_back = _ref_scan(gy, pi[:, 0], pi[:, 1], "sum", exclusive, reverse=True)
    torch.testing.assert_close(back, ref_back, atol=1e-5, rtol=0)
    # gradient of the packed scan equals autograd through the reference
    xd = torch.randn(sum(CNTS), dtype=torch.float64, generator=g, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: fn(v, pi), (xd,), eps=1e-6, atol=1e-8)
    xr = xd.detach().clone().requires_grad_(True)
    (fn(xd, pi) * gy.double()).sum().backward()
    (_ref_scan(xr, pi[:, 0], pi[:, 1], "sum", exclusive) * gy.double()).sum().backward()
    torch.testing.assert_close(xd.grad, xr.grad, atol=1e-12, rtol=0)


@pytest.mark.parametrize("exclusive", [False, True])
def test_prod_scans_forward_backward(exclusive):
    """Products vs per-chunk torch.cumprod (rtol 1e-5) and gradcheck (positive inputs: the kernel's
    backward divides by the input, like nerfacc)."""
    g = torch.Generator().manual_seed(2)
    pi = _packed(CNTS)
    x = torch.rand(sum(CNTS), generator=g) + 0.5
    fn = nerfacc.exclusive_prod if exclusive else nerfacc.inclusive_prod
    ref = _ref_scan(x, pi[:, 0], pi[:, 1], "prod", exclusive)
    torch.testing.assert_close(fn(x, pi), ref, rtol=1e-5, atol=1e-6)
    xd = (torch.rand(sum(CNTS), dtype=torch.float64, generator=g) + 0.5).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda v: fn(v, pi), (xd,), eps=1e-6, atol=1e-7)
    xr = xd.detach().clone().requires_grad_(True)
    gy = torch.randn(sum(CNTS), dtype=torch.float64, generator=g)
    xd.grad = None
    (fn(xd, pi) * gy).sum().backward()
    (_ref_scan(xr, pi[:, 0], pi[:, 1], "prod", exclusive) * gy).sum().backward()
    torch.testing.assert_close(xd.grad, xr.grad, atol=1e-10, rtol=1e-8)


def test_scans_batched_paths_and_zero_in_product():
    x = torch.rand(4, 6) + 0.1
    torch.testing.assert_close(nerfacc.inclusive_prod(x), torch.cumprod(x, -1))
    x0 = torch.tensor([0.5, 0.0, 2.0, 3.0])
    torch.testing.assert_close(nerfacc.exclusive_prod(x0, _packed([4])), torch.tensor([1.0, 0.5, 0.0, 0.0]))


def test_scans_gappy_unordered_chunks_normalize_and_nonfinite():
    """Chunks that are neither contiguous nor ordered; normalize=True; inf inside one chunk must not
    leak into the others (the fast global-cumsum path must hand over to the per-chunk scan)."""
    g = torch.Generator().manual_seed(3)
    x = torch.rand(30, generator=g)
    starts = torch.tensor([20, 0, 9, 14])
    cnts = torch.tensor([6, 5, 3, 0])
    out = C.inclusive_sum(starts, cnts, x, False, False)
    ref = _ref_scan(x, starts, cnts, "sum")
    covered = torch.zeros(30, dtype=torch.bool)
    for s, c in zip(starts.tolist(), cnts.tolist(), strict=False):
        covered[s : s + c] = True
    torch.testing.assert_close(out[covered], ref[covered], atol=1e-6, rtol=0)
    assert (out[~covered] == 0).all()
    back = C.exclusive_sum(starts, cnts, x, False, True)  # backward = reverse exclusive scan
    ref_back = _ref_scan(x, starts, cnts, "sum", True, reverse=True)
    torch.testing.assert_close(back[covered], ref_back[covered], atol=1e-6, rtol=0)
    xp = x + 0.5
    y = C.inclusive_prod_forward(starts, cnts, xp)
    torch.testing.assert_close(y[covered], _ref_scan(xp, starts, cnts, "prod")[covered], rtol=1e-5, atol=0)
    # normalize divides by the chunk total (which includes the last item, also for exclusive)
    for excl in (False, True):
        op = C.exclusive_sum if excl else C.inclusive_sum
        outn = op(starts, cnts, x, True, False)
        for s, c in zip(starts.tolist(), cnts.tolist(), strict=False):
            if c:
                tot = x[s : s + c].sum()
                ref = _ref_scan(x, starts, cnts, "sum", excl)[s : s + c] / tot
                torch.testing.assert_close(outn[s : s + c], ref)
    # inf / nan stay within their chunk
    y = torch.rand(12, generator=g)
    y[2] = float("inf")
    y[6] = float("nan")
    pi = _packed([4, 4, 4])
    out = nerfacc.inclusive_sum(y, pi)
    assert torch.isinf(out[2:4]).all() and torch.isnan(out[6:8]).all()
    torch.testing.assert_close(out[8:], torch.cumsum(y[8:], 0))
    torch.testing.assert_close(out[:2], torch.cumsum(y[:2], 0))


def test_scans_empty_and_single():
    empty = torch.zeros(0)
    assert nerfacc.exclusive_sum(empty, torch.zeros(0, 2, dtype=torch.long)).shape == (0,)
    assert nerfacc.inclusive_prod(empty, _packed([0, 0])).shape == (0,)
    one = torch.tensor([2.0])
    assert nerfacc.exclusive_sum(one, _packed([1])).tolist() == [0.0]
    assert nerfacc.inclusive_prod(one, _packed([1])).tolist() == [2.0]


def test_exclusive_sum_by_key():
    keys = torch.tensor([0, 0, 0, 3, 3, 1, 1, 1, 1, 3])
    x = torch.arange(1.0, 11.0)
    fwd = C.exclusive_sum_by_key(keys, x, False)
    bwd = C.exclusive_sum_by_key(keys, x, True)
    assert fwd.tolist() == [0, 1, 3, 0, 4, 0, 6, 13, 21, 0]
    assert bwd.tolist() == [5, 3, 0, 5, 0, 24, 17, 9, 0, 0]


# ---------------------------------------------------------------------------------------------
# volume rendering
# ---------------------------------------------------------------------------------------------
def test_volrend_weights_transmittance_visibility_and_grads():
    """render_weight_from_density / _from_alpha / visibility / accumulate_along_rays vs the per-ray
    formula; gradients w.r.t. sigmas vs autograd through the per-ray reference (atol 1e-10, float64)."""
    g = torch.Generator().manual_seed(4)
    cnts = [5, 0, 1, 12, 3]
    n_rays = len(cnts)
    ri = torch.repeat_interleave(torch.arange(n_rays), torch.tensor(cnts))
    n = ri.numel()
    t0 = torch.rand(n, generator=g, dtype=torch.float64)
    t1 = t0 + torch.rand(n, generator=g, dtype=torch.float64) * 0.3
    t1[3] = t0[3]  # a zero-length interval
    sig = (torch.rand(n, generator=g, dtype=torch.float64) * 5).requires_grad_(True)
    w, T, a = nerfacc.render_weight_from_density(t0, t1, sig, ray_indices=ri, n_rays=n_rays)
    sig_r = sig.detach().clone().requires_grad_(True)
    rw, rT, ra = _ref_weights(t0, t1, sig_r, ri, n_rays)
    torch.testing.assert_close(w, rw, atol=1e-12, rtol=0)
    torch.testing.assert_close(T, rT, atol=1e-12, rtol=0)
    torch.testing.assert_close(a, ra, atol=1e-12, rtol=0)
    assert a[3].item() == 0.0
    gw = torch.randn(n, generator=g, dtype=torch.float64)
    (w * gw).sum().backward()
    (rw * gw).sum().backward()
    torch.testing.assert_close(sig.grad, sig_r.grad, atol=1e-10, rtol=0)
    # packed_info path gives the same, and gradcheck passes
    pi = nerfacc.pack_info(ri, n_rays)
    assert torch.autograd.gradcheck(
        lambda s: nerfacc.render_weight_from_density(t0, t1, s, packed_info=pi)[0],
        (sig.detach().requires_grad_(True),),
    )
    # alpha based
    alphas = (1 - torch.exp(-sig.detach() * (t1 - t0))).requires_grad_(True)
    wa, Ta = nerfacc.render_weight_from_alpha(alphas, ray_indices=ri, n_rays=n_rays)
    torch.testing.assert_close(wa, rw.detach(), atol=1e-10, rtol=0)
    torch.testing.assert_close(Ta, rT.detach(), atol=1e-10, rtol=0)
    assert torch.autograd.gradcheck(
        lambda al: nerfacc.render_weight_from_alpha(al, packed_info=pi)[0],
        (alphas.detach().clamp(0.05, 0.95).requires_grad_(True),),
    )
    # visibility = (T >= eps) & (alpha >= thre)
    vis = nerfacc.render_visibility_from_density(
        t0, t1, sig.detach(), packed_info=pi, early_stop_eps=0.2, alpha_thre=0.1
    )
    assert torch.equal(vis, (rT.detach() >= 0.2) & (ra.detach() >= 0.1))
    vis_a = nerfacc.render_visibility_from_alpha(
        alphas.detach(), ray_indices=ri, n_rays=n_rays, early_stop_eps=0.2
    )
    assert torch.equal(vis_a, rT.detach() >= 0.2 - 1e-12)
    # accumulate
    rgb = torch.rand(n, 3, generator=g, dtype=torch.float64)
    col = nerfacc.accumulate_along_rays(w.detach(), rgb, ri, n_rays)
    ref = torch.stack([(rw.detach()[ri == r, None] * rgb[ri == r]).sum(0) for r in range(n_rays)])
    torch.testing.assert_close(col, ref)


def test_transmittance_from_alpha_with_zero_rays():
    no_rays = torch.zeros(0, dtype=torch.long)
    w, T = nerfacc.render_weight_from_alpha(torch.zeros(0), ray_indices=no_rays, n_rays=0)
    assert w.shape == (0,) and T.shape == (0,)


# ---------------------------------------------------------------------------------------------
# traverse_grids: per-ray reference marcher written from the definition
# ---------------------------------------------------------------------------------------------
def _slab(o, d, lo, hi):
    """Ray/box entry and exit in plain floats (None when missed; tmax must be > 0)."""
    tmin, tmax = -math.inf, math.inf
    for ax in range(3):
        if d[ax] == 0.0:
            if o[ax] < lo[ax] or o[ax] > hi[ax]:
                return None
            continue
        a = (lo[ax] - o[ax]) / d[ax]
        b = (hi[ax] - o[ax]) / d[ax]
        if a > b:
            a, b = b, a
        tmin, tmax = max(tmin, a), min(tmax, b)
    if tmin > tmax or tmax <= 0:
        return None
    return tmin, tmax


def _ref_march_ray(o, d, binaries, aabbs, near, far, step, cone):
    """Reference marcher for one ray (nested grids).

    t starts at the near plane; dt = clamp(t * cone, step, 1e10), m = t + dt/2.  m is inside the grid
    structure when some hit level's [tmin, tmax) contains it (and near <= m < far); the finest such
    level applies and the cell containing o + m d (binary lookup) decides: occupied -> sample
    [t, t + dt], t += dt; empty -> skip with this fixed dt until the midpoint leaves the cell (or the
    level's span along the ray); before the first box -> skip with fixed dt until m reaches it.
    With step <= 0 every occupied cell crossed is a sample.
    """
    n_lvl, res = binaries.shape[0], binaries.shape[1:]
    spans = []
    for lvl in range(n_lvl):
        s = _slab(o, d, aabbs[lvl][:3], aabbs[lvl][3:])
        spans.append(s)
    hit_spans = [s for s in spans if s is not None]
    if not hit_spans:
        return []
    events = sorted({v for s in hit_spans for v in s})
    t_begin = max(min(s[0] for s in hit_spans), near)
    t_finish = min(max(s[1] for s in hit_spans), far)

    def level_at(m):
        for lvl, s in enumerate(spans):
            if s is not None and s[0] <= m < s[1]:
                return lvl
        return None

    def cell_of(m, lvl):
        lo, hi = aabbs[lvl][:3], aabbs[lvl][3:]
        idx = []
        for ax in range(3):
            u = (o[ax] + d[ax] * m - lo[ax]) / (hi[ax] - lo[ax]) * res[ax]
            idx.append(min(max(int(math.floor(u)), 0), res[ax] - 1))
        return tuple(idx)

    def span_end(m):
        later = [e for e in events if e > m]
        return min(later[0] if later else math.inf, far)

    def cell_exit(m, lvl, idx):
        lo, hi = aabbs[lvl][:3], aabbs[lvl][3:]
        best = math.inf
        for ax in range(3):
            if d[ax] == 0.0:
                continue
            vox = (hi[ax] - lo[ax]) / res[ax]
            plane = lo[ax] + (idx[ax] + (1 if d[ax] > 0 else 0)) * vox
            best = min(best, (plane - o[ax]) / d[ax])
        return min(best, span_end(m))

    out = []
    if t_begin >= t_finish:
        return out
    if step <= 0:
        cuts = {t_begin, t_finish} | {e for e in events if t_begin < e < t_finish}
        for lvl in range(n_lvl):
            lo, hi = aabbs[lvl][:3], aabbs[lvl][3:]
            for ax in range(3):
                if d[ax] == 0.0:
                    continue
                vox = (hi[ax] - lo[ax]) / res[ax]
                for i in range(res[ax] + 1):
                    tc = (lo[ax] + i * vox - o[ax]) / d[ax]
                    # the kernel starts each segment's DDA 1e-6 after its start (and ends it 1e-6
                    # before its end), so crossings that close to a segment end open no cell
                    if t_begin < tc < t_finish and all(abs(tc - e) > 1e-6 for e in events):
                        if level_at(tc) == lvl:  # a level's planes only cut where it applies
                            cuts.add(tc)
        cuts = sorted(cuts)
        for c0, c1 in zip(cuts[:-1], cuts[1:], strict=False):
            m = 0.5 * (c0 + c1)
            lvl = level_at(m)
            if lvl is not None and binaries[(lvl,) + cell_of(m, lvl)]:
                out.append((c0, c1))
        return out
    t = near
    while True:
        dt = min(max(t * cone, step), 1e10)
        m = t + 0.5 * dt
        if m >= t_finish:
            break
        lvl = level_at(m) if m >= t_begin else None
        if lvl is None:  # before the first box: march to it with this dt
            while t + 0.5 * dt < t_begin:
                t += dt
            continue
        idx = cell_of(m, lvl)
        if binaries[(lvl,) + idx]:
            out.append((t, t + dt))
            t += dt
        else:
            ex = cell_exit(m, lvl, idx)
            while t + 0.5 * dt < ex:
                t += dt
    return out


def _check_traversal(o, d, binaries, aabbs, near, far, step, cone, atol=1e-9):
    """Run nerfacc.traverse_grids (our backend) and the reference; compare the sample sets and the
    structure of the packed outputs."""
    intervals, samples = nerfacc.traverse_grids(o, d, binaries, aabbs, near, far, step, cone)
    n_rays = o.shape[0]
    # structure
    assert samples.packed_info.shape == (n_rays, 2) and intervals.packed_info.shape == (n_rays, 2)
    starts = intervals.vals[intervals.is_left]
    ends = intervals.vals[intervals.is_right]
    assert starts.shape == ends.shape == samples.vals.shape
    torch.testing.assert_close(samples.vals, 0.5 * (starts + ends), atol=1e-12, rtol=0)
    assert torch.equal(samples.packed_info[:, 1], torch.bincount(samples.ray_indices, minlength=n_rays))
    assert torch.equal(intervals.ray_indices[intervals.is_left], samples.ray_indices)
    pi = intervals.packed_info
    assert torch.equal(pi[:, 0], torch.cumsum(pi[:, 1], 0) - pi[:, 1])
    for r in range(n_rays):
        got = torch.stack([starts[samples.ray_indices == r], ends[samples.ray_indices == r]], -1).tolist()
        ref = _ref_march_ray(
            o[r].tolist(), d[r].tolist(), binaries.numpy(), aabbs.tolist(),
            float(near[r]), float(far[r]), step, cone,
        )
        assert len(got) == len(ref), (r, len(got), len(ref))
        if ref:
            got_t = torch.tensor(got, dtype=torch.float64)
            torch.testing.assert_close(got_t, torch.tensor(ref, dtype=torch.float64), atol=atol, rtol=0)
        # intervals: one left edge per run of adjacent samples, runs share edges
        e = intervals.vals[intervals.ray_indices == r]
        n_runs = sum(1 for i, s in enumerate(ref) if i == 0 or abs(ref[i - 1][1] - s[0]) > 1e-12)
        assert e.numel() == len(ref) + n_runs
    return samples


def _grid(levels, res, occ, gen):
    return torch.rand(levels, res, res, res, generator=gen) < occ


@pytest.mark.parametrize(
    "levels,res,occ,step,cone",
    [
        (1, 16, 0.3, 0.02, 0.0),  # constant step (instant-ngp-bounded)
        (2, 8, 0.4, 0.03, 0.0),
        (3, 8, 0.35, 0.02, 0.02),  # cone: lattice up to step/cone, then the sequential march
        (2, 8, 0.5, 0.01, 0.2),  # large cone: dt > step almost everywhere
        (2, 8, 0.4, 0.0, 0.0),  # step_size <= 0: one sample per occupied cell
    ],
)
def test_traverse_grids_matches_reference(levels, res, occ, step, cone):
    g = torch.Generator().manual_seed(10 + levels + res)
    o, d = _random_rays(40, g, radius=2.5, spread=1.5)
    # edge cases: inside the box, axis-parallel, missing, sliding along a face of the box
    # (o_y on the plane y = 1 with d_y = 0: the slab gives NaN there, as in the kernel), reversed
    o[0] = torch.tensor([0.05, 0.1, -0.2], dtype=torch.float64)
    o[1] = torch.tensor([0.3, -0.2, -3.0], dtype=torch.float64)
    d[1] = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    o[2] = torch.tensor([5.0, 5.0, 5.0], dtype=torch.float64)
    d[2] = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    o[3] = torch.tensor([-3.0, 1.0, 0.37], dtype=torch.float64)
    d[3] = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    d[4] = -d[4]
    aabb = torch.tensor([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0], dtype=torch.float64)
    aabbs = torch.stack([torch.cat([aabb[:3] * 2**i, aabb[3:] * 2**i]) for i in range(levels)])
    binaries = _grid(levels, res, occ, g)
    near = torch.rand(40, generator=g, dtype=torch.float64) * 0.3
    near[5] = 2.0  # starts inside the box
    far = torch.full((40,), 1e10, dtype=torch.float64)
    far[6] = 2.5  # far plane cuts the ray
    near[7] = far[7] = 2.2  # near == far: nothing
    samples = _check_traversal(o, d, binaries, aabbs, near, far, step, cone)
    assert samples.vals.numel() > 100
    assert samples.packed_info[7, 1] == 0 and samples.packed_info[2, 1] == 0


@pytest.mark.parametrize("step,cone", [(0.03, 0.0), (0.02, 0.05), (0.0, 0.0)])
def test_traverse_grids_non_cubic_grid(step, cone):
    """Resolution (8, 12, 5) and a non-cubic box: lattice, cone and per-cell marching."""
    g = torch.Generator().manual_seed(21)
    o, d = _random_rays(30, g, radius=2.5, spread=1.2)
    aabbs = torch.tensor(
        [[-1.0, -0.5, -1.5, 1.0, 1.5, 1.0], [-2.0, -1.5, -2.75, 2.0, 2.5, 2.25]], dtype=torch.float64
    )
    binaries = torch.rand(2, 8, 12, 5, generator=g) < 0.45
    near = torch.zeros(30, dtype=torch.float64)
    far = torch.full((30,), 1e10, dtype=torch.float64)
    samples = _check_traversal(o, d, binaries, aabbs, near, far, step, cone)
    assert samples.vals.numel() > 50


def test_traverse_grids_float32_close_to_reference():
    """float32 inputs (what nerfstudio passes): same samples up to float32 rounding (atol 1e-4)."""
    g = torch.Generator().manual_seed(5)
    o, d = _random_rays(20, g, radius=2.5)
    binaries = _grid(1, 16, 0.5, g)
    aabbs = torch.tensor([[-1.0, -1.0, -1.0, 1.0, 1.0, 1.0]])
    near = torch.zeros(20, dtype=torch.float64)
    far = torch.full((20,), 1e10, dtype=torch.float64)
    intervals, samples = nerfacc.traverse_grids(
        o.float(), d.float(), binaries, aabbs, near.float(), far.float(), 0.02, 0.0
    )
    assert samples.vals.dtype == torch.float32
    starts = intervals.vals[intervals.is_left].double()
    for r in range(20):
        ref = _ref_march_ray(
            o[r].tolist(), d[r].tolist(), binaries.numpy(), aabbs.double().tolist(), 0.0, 1e10, 0.02, 0.0
        )
        got = starts[samples.ray_indices == r]
        # a midpoint within float32 rounding of a cell face may flip: allow 1 mismatch per ray
        assert abs(len(got) - len(ref)) <= 1
        if ref and len(got) == len(ref):
            ref_starts = torch.tensor([s for s, _ in ref], dtype=torch.float64)
            torch.testing.assert_close(got, ref_starts, atol=1e-4, rtol=0)


def test_traverse_grids_empty_full_zero_rays_single_ray():
    aabbs = torch.tensor([[-1.0, -1.0, -1.0, 1.0, 1.0, 1.0]])
    o = torch.tensor([[0.0, 0.0, -3.0], [0.2, 0.1, -3.0], [4.0, 4.0, 4.0]])
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    # empty grid: no samples, correctly shaped empty packed tensors
    iv, sp = nerfacc.traverse_grids(o, d, torch.zeros(1, 8, 8, 8, dtype=torch.bool), aabbs, step_size=0.1)
    assert sp.vals.shape == (0,) and sp.ray_indices.shape == (0,) and sp.packed_info.shape == (3, 2)
    assert iv.vals.shape == (0,) and iv.is_left.shape == (0,) and iv.packed_info.tolist() == [[0, 0]] * 3
    # full grid: one contiguous run per hit ray covering [2, 4): 20 samples, 21 edges
    iv, sp = nerfacc.traverse_grids(o, d, torch.ones(1, 8, 8, 8, dtype=torch.bool), aabbs, step_size=0.1)
    assert sp.packed_info[:, 1].tolist() == [20, 20, 0]
    assert iv.packed_info[:, 1].tolist() == [21, 21, 0]
    torch.testing.assert_close(iv.vals[:21], torch.arange(21) * 0.1 + 2.0, atol=1e-5, rtol=0)
    s0 = iv.vals[iv.is_left][:20]
    torch.testing.assert_close(s0[1:] - s0[:-1], torch.full((19,), 0.1), atol=1e-5, rtol=0)
    # zero rays
    full = torch.ones(1, 8, 8, 8, dtype=torch.bool)
    iv, sp = nerfacc.traverse_grids(torch.zeros(0, 3), torch.zeros(0, 3), full, aabbs)
    assert sp.vals.shape == (0,) and sp.packed_info.shape == (0, 2) and iv.packed_info.shape == (0, 2)
    # single ray, cone_angle > 0
    iv, sp = nerfacc.traverse_grids(o[:1], d[:1], full, aabbs, step_size=0.01, cone_angle=0.01)
    t = iv.vals
    assert sp.vals.numel() > 0 and bool((t[1:] > t[:-1]).all())
    dt = t[1:] - t[:-1]
    torch.testing.assert_close(dt, (t[:-1] * 0.01).clamp_min(0.01), atol=1e-5, rtol=1e-4)


# ---------------------------------------------------------------------------------------------
# OccGridEstimator end to end
# ---------------------------------------------------------------------------------------------
def test_occgrid_sampling_render_matches_per_ray_reference():
    """OccGridEstimator.sampling(sigma_fn) -> render_weight_from_density -> accumulate_along_rays
    equals the per-ray reference (reference march, visibility filter, compositing), atol 1e-9."""
    g = torch.Generator().manual_seed(6)
    est = nerfacc.OccGridEstimator(roi_aabb=[-1.0, -1.0, -1.0, 1.0, 1.0, 1.0], resolution=16, levels=2)
    centres = (est.grid_coords.double() + 0.5) / 16 * 2 - 1
    est.binaries[0] = (centres.norm(dim=-1) < 0.75).view(16, 16, 16)
    est.binaries[1] = False
    est.occs[: est.cells_per_lvl] = est.binaries[0].flatten().double().float()

    def density(x):
        return 4.0 * torch.exp(-2 * x.norm(dim=-1)) * (x.norm(dim=-1) < 0.7)

    def colour(x):
        return torch.stack([x[:, 0].abs(), x[:, 1].abs(), torch.ones_like(x[:, 0]) * 0.5], -1)

    n = 24
    o, d = _random_rays(n, g, radius=3.0, spread=0.6)
    step, eps = 0.02, 1e-2

    def sigma_fn(t0, t1, ri):
        return density(o[ri] + d[ri] * ((t0 + t1) / 2)[:, None])

    ri, t0, t1 = est.sampling(
        o, d, sigma_fn=sigma_fn, render_step_size=step, early_stop_eps=eps, near_plane=0.0
    )
    x = o[ri] + d[ri] * ((t0 + t1) / 2)[:, None]
    w, _, _ = nerfacc.render_weight_from_density(t0, t1, density(x), ray_indices=ri, n_rays=n)
    rgb = nerfacc.accumulate_along_rays(w, colour(x), ri, n)
    for r in range(n):
        grid, boxes = est.binaries.numpy(), est.aabbs.double().tolist()
        samples = _ref_march_ray(o[r].tolist(), d[r].tolist(), grid, boxes, 0.0, 1e10, step, 0.0)
        acc, col = 0.0, torch.zeros(3, dtype=torch.float64)
        for s0, s1 in samples:
            p = o[r] + d[r] * (s0 + s1) / 2
            sd = float(density(p[None])) * (s1 - s0)
            T = math.exp(-acc)
            acc += sd
            if T < eps:  # the estimator drops samples whose transmittance fell below eps
                continue
            col += T * (1 - math.exp(-sd)) * colour(p[None])[0]
        torch.testing.assert_close(rgb[r], col, atol=1e-9, rtol=0)
    assert (rgb.sum(-1) > 0).sum() > 5


def test_occgrid_update_every_n_steps_runs():
    est = nerfacc.OccGridEstimator(roi_aabb=[-1.0, -1.0, -1.0, 1.0, 1.0, 1.0], resolution=8, levels=2)
    est.train()
    occ_fn = lambda x: (x.norm(dim=-1, keepdim=True) < 0.5).float()  # noqa: E731
    est.update_every_n_steps(step=0, occ_eval_fn=occ_fn, warmup_steps=2, n=1)
    assert est.binaries.any() and not est.binaries.all()
    est.update_every_n_steps(step=5, occ_eval_fn=occ_fn, warmup_steps=2, n=1)  # sampled-cells path
    assert torch.isfinite(est.occs).all()
    o, d = torch.tensor([[0.0, 0.0, -3.0]]), torch.tensor([[0.0, 0.0, 1.0]])
    ri, t0, t1 = est.sampling(o, d, render_step_size=0.05)
    assert t0.numel() > 0 and ((t0 + t1) / 2 > 2.4).all() and ((t0 + t1) / 2 < 3.6).all()


# ---------------------------------------------------------------------------------------------
# pdf: searchsorted, importance_sampling, PropNetEstimator
# ---------------------------------------------------------------------------------------------
def _ref_searchsorted(keys, q):
    """Kernel definition: p = #(keys[:-1] <= q); left = clamp(p - 1), right = clamp(p)."""
    E = len(keys)
    p = sum(1 for k in keys[:-1] if k <= q)
    return min(max(p - 1, 0), E - 1), min(max(p, 0), E - 1)


def test_searchsorted_batched_and_flattened():
    g = torch.Generator().manual_seed(7)
    keys = torch.sort(torch.rand(4, 6, generator=g), -1).values
    q = torch.rand(4, 9, generator=g) * 1.4 - 0.2
    il, ir = nerfacc.searchsorted(RayIntervals(vals=keys), RayIntervals(vals=q))
    for r in range(4):
        for i in range(9):
            assert (il[r, i].item(), ir[r, i].item()) == _ref_searchsorted(keys[r].tolist(), q[r, i].item())
    # flattened keys and queries (absolute indices)
    kc, qc = [3, 5, 1], [2, 4, 3]
    kf = torch.cat([torch.sort(torch.rand(c, generator=g)).values for c in kc])
    qf = torch.rand(sum(qc), generator=g)
    il, ir = nerfacc.searchsorted(
        RayIntervals(vals=kf, packed_info=_packed(kc)), RayIntervals(vals=qf, packed_info=_packed(qc))
    )
    ks = _packed(kc)[:, 0].tolist()
    qi = 0
    for r, c in enumerate(qc):
        for _ in range(c):
            a, b = _ref_searchsorted(kf[ks[r] : ks[r] + kc[r]].tolist(), qf[qi].item())
            assert (il[qi].item(), ir[qi].item()) == (a + ks[r], b + ks[r])
            qi += 1


def _ref_importance(tv, cdf, n):
    """Kernel definition for one ray (non-stratified)."""
    E = len(tv)
    out = []
    for i in range(n):
        u = cdf[0] + (i + 0.5) * (cdf[-1] - cdf[0]) / n
        p = sum(1 for c in cdf[:-1] if c <= u)
        p0, p1 = min(max(p - 1, 0), E - 1), min(max(p, 0), E - 1)
        if cdf[p1] - cdf[p0] < 1e-10:
            out.append(0.5 * (tv[p0] + tv[p1]))
        else:
            out.append(tv[p0] + (u - cdf[p0]) * (tv[p1] - tv[p0]) / (cdf[p1] - cdf[p0]))
    edges = [max(out[0] - (out[1] - out[0]) / 2, tv[0])]
    edges += [(a + b) / 2 for a, b in zip(out[:-1], out[1:], strict=False)]
    edges.append(min(out[-1] + (out[-1] - out[-2]) / 2, tv[-1]))
    return out, edges


def test_importance_sampling_int_and_tensor_counts():
    g = torch.Generator().manual_seed(8)
    tv = torch.sort(torch.rand(3, 7, generator=g, dtype=torch.float64), -1).values
    w = torch.rand(3, 6, generator=g, dtype=torch.float64)
    w[1, 2:4] = 0  # flat CDF pieces
    cdf = torch.cumsum(w, -1) / w.sum(-1, keepdim=True)
    cdf = torch.cat([torch.zeros(3, 1, dtype=torch.float64), cdf], -1)
    iv, sp = nerfacc.importance_sampling(RayIntervals(vals=tv), cdf, 5, stratified=False)
    assert sp.vals.shape == (3, 5) and iv.vals.shape == (3, 6)
    for r in range(3):
        s, e = _ref_importance(tv[r].tolist(), cdf[r].tolist(), 5)
        torch.testing.assert_close(sp.vals[r], torch.tensor(s, dtype=torch.float64), atol=1e-12, rtol=0)
        torch.testing.assert_close(iv.vals[r], torch.tensor(e, dtype=torch.float64), atol=1e-12, rtol=0)
    # per-ray counts -> flattened outputs
    cnt = torch.tensor([4, 0, 3])
    iv, sp = nerfacc.importance_sampling(RayIntervals(vals=tv), cdf, cnt, stratified=False)
    assert sp.packed_info[:, 1].tolist() == [4, 0, 3] and iv.packed_info[:, 1].tolist() == [5, 0, 4]
    for r in (0, 2):
        s, e = _ref_importance(tv[r].tolist(), cdf[r].tolist(), int(cnt[r]))
        s, e = torch.tensor(s, dtype=torch.float64), torch.tensor(e, dtype=torch.float64)
        torch.testing.assert_close(sp.vals[sp.ray_indices == r], s, atol=1e-12, rtol=0)
        torch.testing.assert_close(iv.vals[iv.ray_indices == r], e, atol=1e-12, rtol=0)
    assert iv.is_left.sum() == 7 and iv.is_right.sum() == 7
    # flattened input intervals with an int count -> batched outputs
    ec = [7, 4, 6]
    tv_f = torch.cat([torch.sort(torch.rand(c, generator=g, dtype=torch.float64)).values for c in ec])
    cdf_f = torch.cat([torch.linspace(0, 1, c, dtype=torch.float64) ** 2 for c in ec])
    iv, sp = nerfacc.importance_sampling(RayIntervals(vals=tv_f, packed_info=_packed(ec)), cdf_f, 3)
    assert sp.vals.shape == (3, 3) and iv.vals.shape == (3, 4)
    st = _packed(ec)[:, 0].tolist()
    for r, c in enumerate(ec):
        s, e = _ref_importance(tv_f[st[r] : st[r] + c].tolist(), cdf_f[st[r] : st[r] + c].tolist(), 3)
        torch.testing.assert_close(sp.vals[r], torch.tensor(s, dtype=torch.float64), atol=1e-12, rtol=0)
        torch.testing.assert_close(iv.vals[r], torch.tensor(e, dtype=torch.float64), atol=1e-12, rtol=0)
    # stratified: one jitter per ray, samples stay sorted and inside the ray's range
    iv, sp = nerfacc.importance_sampling(RayIntervals(vals=tv), cdf, 16, stratified=True)
    assert bool((sp.vals[:, 1:] >= sp.vals[:, :-1]).all())
    assert bool((sp.vals >= tv[:, :1]).all()) and bool((sp.vals <= tv[:, -1:]).all())


def test_prop_net_estimator_sampling_runs():
    est = nerfacc.PropNetEstimator()
    fn = lambda t0, t1: torch.exp(-((t0 + t1) / 2 - 3.0) ** 2) * 5  # noqa: E731
    t0, t1 = est.sampling(
        [fn, fn], [32, 16], 8, n_rays=5, near_plane=0.5, far_plane=6.0, stratified=True, requires_grad=True
    )
    assert t0.shape == (5, 8) and bool((t1 >= t0).all())
    trans, _ = nerfacc.render_transmittance_from_density(t0, t1, fn(t0, t1))
    loss = est.compute_loss(trans)
    assert torch.isfinite(loss)


# ---------------------------------------------------------------------------------------------
# lens undistortion
# ---------------------------------------------------------------------------------------------
def test_lens_undistortion_roundtrip():
    from nerfacc.cameras import (
        _opencv_lens_distortion,
        _opencv_lens_distortion_fisheye,
        opencv_lens_undistortion,
        opencv_lens_undistortion_fisheye,
    )

    g = torch.Generator().manual_seed(9)
    uv = (torch.rand(100, 2, generator=g) - 0.5) * 0.8
    params = torch.tensor([0.05, -0.02, 0.001, -0.001, 0.003, 0.0, 0.0, 0.0])
    back = opencv_lens_undistortion(_opencv_lens_distortion(uv, params), params)
    torch.testing.assert_close(back, uv, atol=1e-5, rtol=0)
    fparams = torch.tensor([0.05, 0.01, -0.002, 0.001])
    fback = opencv_lens_undistortion_fisheye(_opencv_lens_distortion_fisheye(uv, fparams), fparams)
    torch.testing.assert_close(fback, uv, atol=1e-5, rtol=0)
