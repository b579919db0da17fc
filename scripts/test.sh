#!/usr/bin/env bash
# Set up (virtual environment, pinned dependencies, pytest, real LPIPS weights) and run the tests.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh --dev --lpips
exec .venv/bin/python -m pytest -q -p no:cacheprovider --durations=25 "$@"
