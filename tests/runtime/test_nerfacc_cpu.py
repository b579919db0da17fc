"""Tests for nerfify_ns.runtime.nerfacc_cpu: the pure-torch stand-in for nerfacc's CUDA ops.

Every op is compared with a plain reference written from its definition (Python loops over rays
or segments), outputs and gradients, including edge cases.  Tolerances are stated per test.
"""

from __future__ import annotations

import copy
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
    for name in ("ray_aabb_intersect", "traverse_grids", "exclusive_sum", "RaySegmentsSpec"):
        assert hasattr(nc.backend, name), name


def test_unreached_ops_raise_a_clear_attribute_error():
    """Ops Nerfstudio 1.1.5 never calls are not served; asking for one names what is served."""
    for name in ("importance_sampling", "inclusive_prod_forward", "searchsorted", "opencv_lens_undistortion"):
        assert not hasattr(nc.backend, name)
        with pytest.raises(AttributeError, match="never calls it"):
            getattr(nc.backend, name)
    with pytest.raises(AttributeError, match="never calls it"):
        nerfacc.inclusive_prod(torch.rand(5), torch.tensor([[0, 5]]))


def test_served_ops_are_the_ones_nerfstudio_reaches():
    """Trace the backend during instant-ngp and instant-ngp-bounded training steps (warm-up and sampled
    occupancy updates) and evaluation: every served op is called, and nothing else is asked for."""
    from nerfstudio.configs.method_configs import all_methods
    from nerfstudio.engine.optimizers import Optimizers

    from nerfify_ns.benchmarks import step_timing

    called: set[str] = set()
    saved = {name: getattr(nc.backend, name) for name in nc.OPS}
    for name, fn in saved.items():
        if callable(fn) and not isinstance(fn, type):
            setattr(nc.backend, name, lambda *a, _fn=fn, _name=name, **k: called.add(_name) or _fn(*a, **k))
    try:
        for method in ("instant-ngp", "instant-ngp-bounded"):
            config = copy.deepcopy(all_methods[method])
            config.pipeline.model.grid_resolution = 16  # a small grid: the same code paths, fast
            model = step_timing.build_model(config)
            optimizers = Optimizers(config.optimizers, model.get_param_groups())
            bundle, batch = step_timing.ray_batch(16)
            model.train()
            for step in (0, 256):
                step_timing.run_before_iteration_callbacks(model, step)
                outputs = model.get_outputs(bundle)
                losses = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))
                sum(losses.values()).backward()
                optimizers.optimizer_step_all()
            model.eval()
            with torch.no_grad():
                model.get_outputs(bundle)
    finally:
        for name, fn in saved.items():
            setattr(nc.backend, name, fn)
    assert called == {"ray_aabb_intersect", "traverse_grids", "exclusive_sum"}


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


def test_exclusive_sum_forward_backward():
    """Forward vs per-chunk torch.cumsum (atol 1e-5, float32); backward equals the reverse scan,
    and gradcheck in float64 through nerfacc's autograd Functions."""
    exclusive = True
    g = torch.Generator().manual_seed(1)
    pi = _packed(CNTS)
    x = torch.randn(sum(CNTS), generator=g)
    fn = nerfacc.exclusive_sum
    ref = _ref_scan(x, pi[:, 0], pi[:, 1], "sum", exclusive)
    torch.testing.assert_close(fn(x, pi), ref, atol=1e-5, rtol=0)
    op = C.exclusive_sum
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


def test_scans_gappy_unordered_chunks_normalize_and_nonfinite():
    """Chunks that are neither contiguous nor ordered; normalize=True; inf inside one chunk must not
    leak into the others (the fast global-cumsum path must hand over to the per-chunk scan)."""
    g = torch.Generator().manual_seed(3)
    x = torch.rand(30, generator=g)
    starts = torch.tensor([20, 0, 9, 14])
    cnts = torch.tensor([6, 5, 3, 0])
    out = C.exclusive_sum(starts, cnts, x, False, False)
    ref = _ref_scan(x, starts, cnts, "sum", True)
    covered = torch.zeros(30, dtype=torch.bool)
    for s, c in zip(starts.tolist(), cnts.tolist(), strict=False):
        covered[s : s + c] = True
    torch.testing.assert_close(out[covered], ref[covered], atol=1e-6, rtol=0)
    assert (out[~covered] == 0).all()
    back = C.exclusive_sum(starts, cnts, x, False, True)  # backward = reverse exclusive scan
    ref_back = _ref_scan(x, starts, cnts, "sum", True, reverse=True)
    torch.testing.assert_close(back[covered], ref_back[covered], atol=1e-6, rtol=0)
    # normalize divides by the chunk total (which includes the last item)
    outn = C.exclusive_sum(starts, cnts, x, True, False)
    for s, c in zip(starts.tolist(), cnts.tolist(), strict=False):
        if c:
            tot = x[s : s + c].sum()
            ref = _ref_scan(x, starts, cnts, "sum", True)[s : s + c] / tot
            torch.testing.assert_close(outn[s : s + c], ref)
    # inf / nan stay within their chunk
    y = torch.rand(12, generator=g)
    y[2] = float("inf")
    y[6] = float("nan")
    pi = _packed([4, 4, 4])
    out = nerfacc.exclusive_sum(y, pi)
    assert torch.isinf(out[3]).all() and torch.isnan(out[7]).all()
    torch.testing.assert_close(out[8:], _ref_scan(y[8:], torch.tensor([0]), torch.tensor([4]), "sum", True))
    torch.testing.assert_close(out[:3], _ref_scan(y[:3], torch.tensor([0]), torch.tensor([3]), "sum", True))


def test_scans_empty_and_single():
    empty = torch.zeros(0)
    assert nerfacc.exclusive_sum(empty, torch.zeros(0, 2, dtype=torch.long)).shape == (0,)
    one = torch.tensor([2.0])
    assert nerfacc.exclusive_sum(one, _packed([1])).tolist() == [0.0]


# ---------------------------------------------------------------------------------------------
# volume rendering
# ---------------------------------------------------------------------------------------------
def test_volrend_weights_transmittance_visibility_and_grads():
    """render_weight_from_density / visibility / accumulate_along_rays vs the per-ray
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
    # visibility = (T >= eps) & (alpha >= thre)
    vis = nerfacc.render_visibility_from_density(
        t0, t1, sig.detach(), packed_info=pi, early_stop_eps=0.2, alpha_thre=0.1
    )
    assert torch.equal(vis, (rT.detach() >= 0.2) & (ra.detach() >= 0.1))
    # accumulate
    rgb = torch.rand(n, 3, generator=g, dtype=torch.float64)
    col = nerfacc.accumulate_along_rays(w.detach(), rgb, ri, n_rays)
    ref = torch.stack([(rw.detach()[ri == r, None] * rgb[ri == r]).sum(0) for r in range(n_rays)])
    torch.testing.assert_close(col, ref)


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
