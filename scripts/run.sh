#!/usr/bin/env bash
# Sets up (if needed) and runs the main job: the leaderboard of every policy on every environment,
# written into runs/leaderboard/ (untracked): index.html (the page), leaderboard.md, figures,
# videos. Progress and estimates go to stderr; a summary and the page's path at the end.
#   bash scripts/run.sh                       # 3 episodes per policy: a first look
#   bash scripts/run.sh --episodes 30         # more episodes per policy (longer)
#   bash scripts/run.sh --out results/        # regenerate the repository's results/ on purpose
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# shellcheck disable=SC1091
. .venv/bin/activate
export MUJOCO_GL="${MUJOCO_GL:-egl}"
cir-gym leaderboard "$@"
