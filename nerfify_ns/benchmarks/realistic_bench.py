"""Realistic scenes benchmark: what pruning does on scenes we did not draw (Mitsuba 3 renders of pybullet's
textured meshes, :mod:`nerfify_ns.scenes.realistic`).

    python -m nerfify_ns.benchmarks.realistic_bench [--out bench-results/realistic] [--seed 42]

* ``garden-360``, an unbounded 360-degree capture with per-image exposure and white balance, poses estimated by
  COLMAP (pycolmap) from the images alone, as ns-process-data does: the COLMAP poses against the renderer's
  (after a similarity alignment), the scene facts the probe measures, what the nerfacto reference plan keeps
  (contraction, appearance codes, camera optimiser: the ``kept`` records and their reasons), the same probe on a
  copy with the true gains divided out (the appearance fact must flip), and the held-out PSNR the plan reaches.
* ``duck-white``, a bounded object on a transparent background (Blender format): the nerfacto reference plan kept
  whole against the plan pruned for the scene, same budget, PSNR at equal wall-clock time
  (:func:`nerfify_ns.benchmarks.parity_bench.pruning`).

One training process at a time; the scenes come from the scene cache (rendered on the first run).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
from PIL import Image

from nerfify_ns.benchmarks.parity_bench import BUDGET, _args, _run, pruning
from nerfify_ns.evaluate.smoke_train import generated_env
from nerfify_ns.interrupts import run_interruptible
from nerfify_ns.runtime.launch import GENERATED_METHOD
from nerfify_ns.scenes.pbr import srgb
from nerfify_ns.scenes.realistic import RealisticSettings, dataset_pose_accuracy, load_ground_truth, write_realistic
from nerfify_ns.synthesis.compose import compose
from nerfify_ns.synthesis.prune import prune_plan
from nerfify_ns.synthesis.resources import load_reference_plan
from nerfify_ns.synthesis.scene_probe import probe_scene

GARDEN = RealisticSettings("garden-360", resolution=64, n_train=36, n_val=0, n_test=4, spp=16)
"""40 views; COLMAP sees them at 256 px (sfm_factor 4), training at 64 px."""
DUCK = RealisticSettings("duck-white", resolution=64, n_train=24, n_val=4, n_test=8, spp=32)


def neutralised_copy(folder: Path, out: Path) -> Path:
    """A copy of a realistic capture with each image's true exposure and white balance divided out (in linear
    RGB), so that its appearance is constant: the probe must then find no variation."""
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(folder, out)
    for frame in load_ground_truth(folder)["frames"]:
        gains = 2.0 ** frame["exposure_ev"] * np.asarray(frame["white_balance"])
        path = out / frame["file_path"]
        with Image.open(path) as im:
            value = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
        linear = np.where(value <= 0.04045, value / 12.92, ((value + 0.055) / 1.055) ** 2.4) / gains
        Image.fromarray(np.round(srgb(linear) * 255.0).astype(np.uint8)).save(path)
    return out


def garden(out: Path, seed: int) -> dict:
    data = write_realistic(GARDEN, out / "data", overwrite=True)
    truth = load_ground_truth(data)
    accuracy = dataset_pose_accuracy(data)
    facts = probe_scene(data)
    plan = prune_plan(load_reference_plan("nerfacto"), facts)
    kept = {r["path"]: r["reason"] for r in plan["pruned"] if r["action"] == "kept"}
    neutral = probe_scene(neutralised_copy(data, out / "data-constant-appearance"))
    iterations, rays = BUDGET["nerfacto"]
    plugin = compose(plan, out / "plugin", overwrite=True, record=False)
    run = _run(GENERATED_METHOD, "nerfacto (garden-360, COLMAP poses)", data, out / "train", iterations,
               iterations // 3, _args("nerfacto", rays, seed), env=generated_env(plugin.out))
    return {"sfm": truth["sfm"], "pose_accuracy": accuracy.__dict__, "facts": facts.flags(),
            "evidence": facts.evidence, "kept": kept,
            "constant_appearance_copy": {"appearance_variation": neutral.appearance_variation,
                                         "evidence": neutral.evidence["appearance_variation"]},
            "iterations": iterations, "psnr": run["psnr"], "seconds": run["curve"].points[-1].train_seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("bench-results/realistic"))
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument("--skip-duck", action="store_true")
    parser.add_argument("--skip-garden", action="store_true")
    ns = parser.parse_args()
    ns.out.mkdir(parents=True, exist_ok=True)
    results: dict = {}
    if not ns.skip_garden:
        g = results["garden"] = garden(ns.out / "garden", ns.seed)
        a = g["pose_accuracy"]
        print(f"garden-360: COLMAP registered {g['sfm']['registered']}/{g['sfm']['images']} images, "
              f"{g['sfm']['points']} points, {g['sfm']['mean_reprojection_error']:.2f} px; against the renderer: "
              f"rotation {a['rotation_deg_median']:.2f} deg median ({a['rotation_deg_max']:.2f} max), position "
              f"{100 * a['position_median']:.1f}% of the rig radius median ({100 * a['position_max']:.1f}% max)")
        print(f"garden-360 facts: {g['facts']}")
        for path, reason in g["kept"].items():
            print(f"  kept {path}: {reason}")
        c = g["constant_appearance_copy"]
        print(f"  the same images with the true gains divided out: appearance_variation={c['appearance_variation']} "
              f"({c['evidence']})")
        print(f"garden-360 nerfacto plan, {g['iterations']} iterations ({g['seconds']:.0f} s): held-out PSNR "
              f"{g['psnr']:.2f} dB")
    if not ns.skip_duck:
        duck = write_realistic(DUCK, ns.out / "duck" / "data", overwrite=True)
        p = results["duck_pruning"] = pruning(duck, ns.out / "duck", BUDGET["nerfacto"][0] // 3, ns.seed)
        print(f"duck-white pruning (nerfacto): {p['speedup_sec_per_iter']:.2f}x faster per iteration; PSNR at "
              f"{p['equal_time_seconds']:.0f} s: pruned {p['psnr_at_equal_time_pruned']:.2f} dB vs kept "
              f"{p['psnr_at_equal_time_kept']:.2f} dB (final: pruned {p['psnr_final_pruned']:.2f}, kept "
              f"{p['psnr_final_kept']:.2f})")
    (ns.out / "summary.json").write_text(json.dumps(results, indent=2, default=str))
    print(f"wrote {ns.out / 'summary.json'}")


if __name__ == "__main__":
    run_interruptible(main)
