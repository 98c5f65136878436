#!/usr/bin/env bash
# Builds the documentation site into docs/_build/html/ (open docs/_build/html/index.html).
#   bash scripts/docs.sh                 # the site in docs/_build/html/
#   bash scripts/docs.sh --out DIR       # the site in DIR (its sources staged in DIR/../src)
# Sets up .venv first (bash scripts/setup.sh) unless it already has the package and the docs
# extra. Pages are generated from the code at build time (docs/_gen/site.py): one per
# registered environment, the controller tables, the API reference.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! .venv/bin/python -c "import cir_gym, sphinx, furo, myst_parser" >/dev/null 2>&1; then
  bash scripts/setup.sh
fi
# shellcheck disable=SC1091
. .venv/bin/activate
export MUJOCO_GL="${MUJOCO_GL:-egl}"
python docs/_gen/site.py "$@"
