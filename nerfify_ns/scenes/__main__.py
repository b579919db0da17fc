"""Command line: ``python -m nerfify_ns.scenes [NAME OUT] [--resolution 64 ...]``; no NAME lists them."""

from __future__ import annotations

import argparse
from pathlib import Path

from nerfify_ns.interrupts import run_interruptible

from . import list_scenes, scene_spec, write_scene


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m nerfify_ns.scenes", description=__doc__)
    parser.add_argument("name", nargs="?", help="catalog scene to write; omit to list the scenes")
    parser.add_argument("out", nargs="?", type=Path, help="output folder")
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--n-train", type=int, default=24)
    parser.add_argument("--n-val", type=int, default=8)
    parser.add_argument("--n-test", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--supersample", type=int, default=2)
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)
    if args.name is None:
        for name in list_scenes():
            print(f"{name:14s} {' '.join(scene_spec(name)['description'].split())}")
        return 0
    if args.out is None:
        parser.error("OUT is required when NAME is given")
    root = write_scene(
        args.name,
        args.out,
        resolution=args.resolution,
        n_train=args.n_train,
        n_val=args.n_val,
        n_test=args.n_test,
        seed=args.seed,
        supersample=args.supersample,
        overwrite=args.overwrite,
    )
    print(root)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_interruptible(main))
