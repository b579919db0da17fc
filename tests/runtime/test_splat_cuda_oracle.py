"""The CPU rasteriser against gsplat's own CUDA kernels (the code it stands in for), on a machine with CUDA.

On such a machine gsplat builds its CUDA extension (a few minutes the first time) and renders random Gaussians;
``nerfify_ns.runtime.splat_cpu.rasterize`` renders the same Gaussians on the CPU. Images, alphas, the projected
means, radii and depths, the gradients of every input, and the densification signal (``absgrad``) must agree, for
RGB colours and degree-3 spherical harmonics, packed and unpacked (radii exactly where gsplat's unpacked kernel
computes them; its packed kernel reported other radii for about a tenth of the pairs on an H200, images and
gradients unchanged). Both run in a fresh process: the suite forces our runtime on with CUDA (``conftest.py``), and
its ``splatting`` patch would put this rasteriser in gsplat's place. Without CUDA the test skips: there is no oracle
to run (``test_splat_cpu.py`` checks a reference written from the paper instead)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import torch

ORACLE = r"""
import json, torch
from gsplat.rendering import rasterization
from nerfify_ns.runtime.splat_cpu import rasterize

assert rasterization.__module__ == "gsplat.rendering", rasterization.__module__
torch.manual_seed(0)
N, C, W, H = 4000, 2, 96, 64
means = (torch.rand(N, 3) - 0.5) * torch.tensor([3.0, 2.0, 2.0])
means[:, 2] += 4.0
quats = torch.randn(N, 4)
scales = torch.rand(N, 3) * 0.08 + 0.01
opacities = torch.rand(N) * 0.95 + 0.02
viewmats = torch.eye(4).repeat(C, 1, 1)
viewmats[1, 0, 3] = 0.3  # a second camera, shifted
Ks = torch.tensor([[60.0, 0.0, W / 2], [0.0, 60.0, H / 2], [0.0, 0.0, 1.0]]).repeat(C, 1, 1)
backgrounds = torch.rand(C, 3)
weights = torch.rand(C, H, W, 3)


def rel(a, b):
    return float((a - b).norm() / b.norm().clamp(min=1e-12))


def run(fn, device, colors, sh_degree, packed):
    leaves = [t.detach().to(device).requires_grad_(True) for t in (means, quats, scales, opacities, colors)]
    img, alpha, info = fn(*leaves, viewmats.to(device), Ks.to(device), W, H, sh_degree=sh_degree, packed=packed,
                          absgrad=True, backgrounds=backgrounds.to(device))
    info["means2d"].retain_grad()
    ((img * weights.to(device)).sum() + alpha.sum()).backward()
    out = {k: v.detach().cpu() for k, v in info.items() if torch.is_tensor(v) and k != "means2d"}
    out.update(img=img.detach().cpu(), alpha=alpha.detach().cpu(), means2d=info["means2d"].detach().cpu(),
               absgrad=info["means2d"].absgrad.detach().cpu(), grads=[t.grad.cpu() for t in leaves])
    return out


cases = {}
for name, colors, sh_degree in (("rgb", torch.rand(N, 3), None), ("sh3", torch.randn(N, 16, 3) * 0.3, 3)):
    for packed in (False, True):
        ours = run(rasterize, "cpu", colors, sh_degree, packed)
        theirs = run(rasterization, "cuda", colors, sh_degree, packed)
        diff = (ours["img"] - theirs["img"]).abs()
        visible = theirs["radii"] > 0
        same_visible = ours["radii"].shape == theirs["radii"].shape and bool(torch.equal(ours["radii"] > 0, visible))
        if packed:  # the same (camera, Gaussian) pairs, in the same order
            same_visible = same_visible and all(torch.equal(ours[k], theirs[k]) for k in ("camera_ids", "gaussian_ids"))
        cases[f"{name}, {'packed' if packed else 'unpacked'}"] = {
            "visible": int(visible.sum()),
            "same_visible": same_visible,
            "radii_differ": int((ours["radii"] != theirs["radii"]).sum()) if same_visible else None,
            "means2d_max_abs": float((ours["means2d"] - theirs["means2d"]).abs().max()) if same_visible else None,
            "depths_max_abs": float((ours["depths"] - theirs["depths"]).abs().max()) if same_visible else None,
            "img_mean_abs": float(diff.mean()), "img_p999_abs": float(diff.flatten().quantile(0.999)),
            "img_max_abs": float(diff.max()),
            "alpha_max_abs": float((ours["alpha"] - theirs["alpha"]).abs().max()),
            "grad_rel": {k: rel(a, b) for k, a, b in zip(("means", "quats", "scales", "opacities", "colors"),
                                                         ours["grads"], theirs["grads"])},
            "absgrad_rel": rel(ours["absgrad"], theirs["absgrad"]) if same_visible else None,
            "image_spread": float(theirs["img"].std()),
        }
print("ORACLE " + json.dumps(cases))
"""


def test_matches_gsplats_cuda_kernels():
    if not torch.cuda.is_available():
        pytest.skip("no CUDA: gsplat's own kernels, the oracle, run only on a GPU (test_splat_cpu.py checks the "
                    "rasteriser against a reference written from the paper)")
    env = {k: v for k, v in os.environ.items() if k != "NERFIFY_RUNTIME"}
    env.setdefault("MAX_JOBS", str(os.cpu_count() or 4))
    props = torch.cuda.get_device_properties(0)
    env.setdefault("TORCH_CUDA_ARCH_LIST", f"{props.major}.{props.minor}")  # gsplat's build: this GPU's only
    proc = subprocess.run([sys.executable, "-c", ORACLE], capture_output=True, text=True, env=env, timeout=1500)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("ORACLE ")]
    assert proc.returncode == 0 and lines, proc.stderr[-4000:]
    cases = json.loads(lines[-1][len("ORACLE "):])
    print(json.dumps(cases, indent=1))  # the figures, for the check's log
    for name, case in cases.items():
        assert case["visible"] > 1000 and case["image_spread"] > 0.05, (name, "the scene should be seen")
        assert case["same_visible"], (name, "the same Gaussians on screen (packed: the same pairs, same order)")
        if "unpacked" in name:  # gsplat's packed projection kernel rounds some radii otherwise than its unpacked one
            assert case["radii_differ"] == 0, (name, case)
        assert case["means2d_max_abs"] < 1e-3 and case["depths_max_abs"] < 1e-4, (name, case)
        assert case["img_mean_abs"] < 1e-4 and case["img_p999_abs"] < 1e-3, (name, case)
        assert case["alpha_max_abs"] < 0.02, (name, case)
        assert all(r < 5e-3 for r in case["grad_rel"].values()), (name, case["grad_rel"])
        assert case["absgrad_rel"] < 5e-3, (name, case)
