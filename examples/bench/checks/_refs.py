"""Reference functions shared by the checks (written from the papers' equations; not a check file of a paper)."""

import numpy as np
import torch


def load(name: str):
    """A sibling module of the checks folder (check files are loaded by path, not as a package)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).with_name(f"{name}.py")
    spec = importlib.util.spec_from_file_location(f"nerfify_bench_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def rays(n: int = 3):
    from nerfstudio.cameras.rays import RayBundle

    g = torch.Generator().manual_seed(0)
    dirs = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    return RayBundle(origins=torch.zeros(n, 3), directions=dirs, pixel_area=torch.ones(n, 1),
                     nears=torch.full((n, 1), 2.0), fars=torch.full((n, 1), 6.0))


def inverse_transform_sampling(num_samples: int) -> None:
    """NeRF Eq. 5 / Sec. 5.2 (and every hierarchical sampler after it): normalised weights w_i / sum_j w_j are a
    piecewise-constant PDF over the coarse bins; the fine samples are u_k mapped through the inverse of its
    (piecewise-linear) CDF. Nerfstudio's PDFSampler, the sampler the plans use, against numpy's interpolation."""
    from nerfstudio.model_components.ray_samplers import PDFSampler, UniformSampler

    bundle = rays()
    coarse = UniformSampler(num_samples=16, train_stratified=False)(bundle)
    g = torch.Generator().manual_seed(1)
    w = torch.rand(3, 16, 1, generator=g) ** 3
    sampler = PDFSampler(num_samples=num_samples, train_stratified=False, include_original=False,
                         histogram_padding=0.0).eval()
    fine = sampler.generate_ray_samples(bundle, coarse, w, num_samples)
    got = torch.cat([fine.spacing_starts[..., 0], fine.spacing_ends[..., -1:, 0]], -1).numpy()
    edges = torch.cat([coarse.spacing_starts[..., 0], coarse.spacing_ends[..., -1:, 0]], -1).numpy()
    pdf = w[..., 0].numpy() / w[..., 0].numpy().sum(-1, keepdims=True)
    cdf = np.concatenate([np.zeros((3, 1)), np.cumsum(pdf, -1)], -1)
    k = num_samples + 1
    u = np.linspace(0.0, 1.0 - 1.0 / k, k) + 1.0 / (2 * k)
    want = np.stack([np.interp(u, cdf[r], edges[r]) for r in range(3)])
    np.testing.assert_allclose(got, want, atol=2e-4)


def mse(loss_module) -> None:
    """L = mean over rays of ||C_hat(r) - C(r)||^2 (up to the constant factor of a mean over the channels)."""
    g = torch.Generator().manual_seed(0)
    pred, gt = torch.rand(64, 3, generator=g), torch.rand(64, 3, generator=g)
    got = float(loss_module(pred, gt))
    want = float(((pred - gt) ** 2).mean())
    assert abs(got - want) < 1e-6, f"the plan's colour loss gives {got}, the squared error {want}"


def plane_tv() -> None:
    """Total variation of a feature plane P [C, H, W]: the mean squared difference of neighbouring cells along both
    axes (K-Planes Eq. 5, HexPlane's TV on its planes): the regulariser the plans use against it."""
    from nerfify_ns.components import regularizers as reg

    g = torch.Generator().manual_seed(0)
    plane = torch.randn(1, 4, 6, 5, generator=g)
    got = float(reg.plane_tv([plane]))
    p = plane.numpy()
    want = np.mean((p[..., 1:, :] - p[..., :-1, :]) ** 2) + np.mean((p[..., 1:] - p[..., :-1]) ** 2)
    assert np.isclose(got, want, rtol=1e-5), f"the plan's plane TV gives {got}, Eq. {want}"


def as_derived(target):
    """The item's plan value as the pipeline derived it from the paper: a value the scene's pruning changed (the
    plan's ``pruned`` records: path, from, to) is read as it was before (the sizes a 32 px CPU scene clamps are
    not the paper's method)."""
    import copy

    value = copy.deepcopy(target.value)
    for record in target.plan.get("pruned") or []:
        path = str(record.get("path") or "")
        if "from" not in record or record.get("action") in ("removed", "kept"):
            continue
        if path == target.path:
            return copy.deepcopy(record["from"])
        if path.startswith(target.path + ".") and isinstance(value, dict):
            node = value
            keys = path[len(target.path) + 1:].split(".")
            for key in keys[:-1]:
                node = node.setdefault(key, {}) if isinstance(node, dict) else {}
            if isinstance(node, dict):
                node[keys[-1]] = copy.deepcopy(record["from"])
    return value
