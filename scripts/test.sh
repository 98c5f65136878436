#!/usr/bin/env bash
# Sets up (if needed) and runs the default test suite (slow tests excluded: add `-m slow`).
# Also installs Debian's chromium when it is missing: tests/test_leaderboard_page.py loads the
# leaderboard page in it, headless (25 packages, ~350 MB, ~35 s here the first time).
# CIR_GYM_NO_BROWSER=1 skips the install; that test then skips with a message (fails under CI).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
if [ -z "${CIR_GYM_NO_BROWSER:-}" ] && [ ! -x /usr/bin/chromium ]; then
  # shellcheck source=scripts/apt.sh
  . scripts/apt.sh
  echo "installing Debian's chromium (headless browser for tests/test_leaderboard_page.py)" >&2
  apt_install --no-install-recommends chromium
fi
# shellcheck disable=SC1091
. .venv/bin/activate
export MUJOCO_GL="${MUJOCO_GL:-egl}"
ruff check .
python -m pytest "$@"
