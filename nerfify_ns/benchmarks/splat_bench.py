"""Benchmark of the CPU Gaussian rasteriser (``nerfify_ns.runtime.splat_cpu``): one training step's render and
backward for splatfacto-like Gaussians, screening every pixel of each Gaussian's tiles (the baseline) against cutting
them to its alpha >= 1/255 ellipse first (ours), interleaved in one process, medians and the ratio printed. Stock
Nerfstudio cannot run it at all on a CPU (gsplat's rasteriser is CUDA only).

    .venv/bin/python -m nerfify_ns.benchmarks.splat_bench [--gaussians 10000 50000] [--sizes 64 128] [--repeats 5]

The Gaussians follow splatfacto's random initialisation (``random_init``): centres uniform in a cube, scales the
log of the mean distance to the three nearest neighbours, random rotations, opacity 0.1, degree-0 colours; the
camera looks at the cube's centre from 4 units, as the procedural scenes' cameras do.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch

from nerfify_ns.interrupts import run_interruptible


def splatfacto_like(n: int, cube: float, seed: int = 0) -> dict[str, torch.Tensor]:
    """``n`` Gaussians as splatfacto's random initialisation makes them, in a cube of side ``cube``."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) - 0.5) * cube
    nearest = torch.cat([torch.cdist(means[i:i + 2048], means).topk(4, largest=False).values[:, 1:]
                         for i in range(0, n, 2048)])  # the point itself is the first of the four
    scales = torch.log(nearest.mean(-1, keepdim=True)).repeat(1, 3)
    return {"means": means, "quats": torch.randn(n, 4, generator=g), "scales": scales,
            "opacities": torch.full((n,), 0.1), "colors": torch.rand(n, 3, generator=g)}


def camera(size: int, distance: float = 4.0) -> tuple[torch.Tensor, torch.Tensor]:
    """A world-to-camera matrix looking down +z at the origin from ``distance``, and intrinsics of ``size`` px."""
    view = torch.eye(4)
    view[2, 3] = distance
    focal = 1.1 * size
    ks = torch.tensor([[focal, 0.0, size / 2], [0.0, focal, size / 2], [0.0, 0.0, 1.0]])
    return view[None], ks[None]


def step_seconds(params: dict, size: int, alpha_box: bool) -> tuple[float, int]:
    """One render and backward (what a training step costs in the rasteriser), and the pairs composited."""
    from nerfify_ns.runtime.splat_cpu import rasterize

    leaves = {k: v.clone().requires_grad_(k != "quats") for k, v in params.items()}
    view, ks = camera(size)
    start = time.perf_counter()
    img, alpha, info = rasterize(leaves["means"], leaves["quats"], torch.exp(leaves["scales"]),
                                 leaves["opacities"], leaves["colors"], view, ks, size, size, packed=False,
                                 absgrad=True, alpha_box=alpha_box)
    (img.sum() + alpha.sum()).backward()
    return time.perf_counter() - start, int((info["radii"] > 0).sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaussians", type=int, nargs="+", default=[10000, 50000])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--cube", type=float, default=3.0, help="side of the initialisation cube (the scenes': 3)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    rows = []
    for n in args.gaussians:
        params = splatfacto_like(n, args.cube)
        for size in args.sizes:
            times: dict[bool, list[float]] = {False: [], True: []}
            step_seconds(params, size, True)  # warm-up
            for r in range(args.repeats):
                for cut in ((False, True) if r % 2 == 0 else (True, False)):
                    times[cut].append(step_seconds(params, size, cut)[0])
            base, ours = statistics.median(times[False]), statistics.median(times[True])
            rows.append({"gaussians": n, "size": size, "tile_pixels_s": round(base, 4),
                         "alpha_box_s": round(ours, 4), "speedup": round(base / ours, 2)})
            print(f"{n:>7} Gaussians {size:>4} px: every tile pixel {base * 1000:8.1f} ms, cut to the alpha "
                  f"ellipse {ours * 1000:8.1f} ms a step: {base / ours:.2f}x", flush=True)
    print(json.dumps({"threads": torch.get_num_threads(), "repeats": args.repeats, "rows": rows}))


if __name__ == "__main__":
    run_interruptible(main)
