#!/usr/bin/env bash
# Set up (virtual environment, pinned dependencies, pytest, real LPIPS weights) and run the tests.
#
#   scripts/test.sh            the full suite, what CI runs (everything but the benchmark lane)
#   scripts/test.sh --fast     everyday work: no training beyond one smoke-train (`-m "not slow"` + it)
#   scripts/test.sh --bench    the benchmark lane: repeated heavy cases kept out of CI (one of each stays in CI)
# Other arguments go to pytest (e.g. scripts/test.sh --fast tests/grammar).
set -euo pipefail
cd "$(dirname "$0")/.."
lane="full"
args=()
for arg in "$@"; do
  case "$arg" in
    --fast) lane="fast" ;;
    --bench) lane="bench" ;;
    *) args+=("$arg") ;;
  esac
done
scripts/setup.sh --dev --lpips
PYTEST=(.venv/bin/python -m pytest -q -p no:cacheprovider --durations=25)
case "$lane" in
  fast)
    "${PYTEST[@]}" -m "not slow and not bench" "${args[@]}"
    exec "${PYTEST[@]}" "tests/runtime/test_smoke_train.py::test_ci_smoke_train_nerfacto" ;;
  bench) exec "${PYTEST[@]}" -m "bench" "${args[@]}" ;;
  *) exec "${PYTEST[@]}" -m "not bench" "${args[@]}" ;;
esac
