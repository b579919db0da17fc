#!/usr/bin/env bash
# Set up (virtual environment, pinned dependencies, pytest, real LPIPS weights) and run the tests.
#
#   scripts/test.sh            the full suite, what CI runs (everything but the benchmark lane)
#   scripts/test.sh --fast     everyday work: no training beyond one smoke-train (`-m "not slow"` + it)
#   scripts/test.sh --bench    the benchmark lane: repeated heavy cases kept out of CI (one of each stays in CI)
# Other arguments go to pytest (e.g. scripts/test.sh --fast tests/grammar).
#
# The full and fast lanes run on every core (pytest-xdist, one worker per core, at most 4), each test's numeric
# libraries and every training it starts on one thread, so two trainings never fight over a core;
# NERFIFY_TEST_WORKERS=0 runs them in one process. The benchmark lane runs one test at a time.
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
workers="${NERFIFY_TEST_WORKERS:-$(.venv/bin/python -c 'import os; print(min(4, len(os.sched_getaffinity(0))))')}"
pin_threads() { export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" MKL_NUM_THREADS="${MKL_NUM_THREADS:-1}"; }
PYTEST=(.venv/bin/python -m pytest -q -p no:cacheprovider --durations=25)
PARALLEL=(-n "$workers" --dist worksteal)
case "$lane" in
  fast)
    pin_threads
    "${PYTEST[@]}" "${PARALLEL[@]}" -m "not slow and not bench" "${args[@]}"
    exec "${PYTEST[@]}" "tests/runtime/test_smoke_train.py::test_ci_smoke_train_nerfacto" ;;
  bench) exec "${PYTEST[@]}" -m "bench" "${args[@]}" ;;
  *) pin_threads; exec "${PYTEST[@]}" "${PARALLEL[@]}" -m "not bench" "${args[@]}" ;;
esac
