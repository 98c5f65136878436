#!/usr/bin/env bash
# Sets up (if needed) and runs the main job: the leaderboard of every policy on every environment.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# shellcheck disable=SC1091
. .venv/bin/activate
export MUJOCO_GL="${MUJOCO_GL:-egl}"
cir-gym list
cir-gym leaderboard "$@"
