#!/usr/bin/env bash
# Sets up (if needed) and runs the default test suite (slow tests excluded: add `-m slow`).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# shellcheck disable=SC1091
. .venv/bin/activate
export MUJOCO_GL="${MUJOCO_GL:-egl}"
ruff check .
python -m pytest "$@"
