#!/usr/bin/env bash
# Sets up cir_gym on a fresh Debian machine with Python 3.11; reuses what exists on a second run.
#   bash scripts/setup.sh            # venv in .venv, CPU torch, the package with all extras, Mesa
# A second run installs nothing when .venv/.cir_gym-installed holds the sha256 of the current
# pyproject.toml (written after a successful install; delete it to force a reinstall).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
STAMP=.venv/.cir_gym-installed

# shellcheck source=scripts/apt.sh
. scripts/apt.sh

# Headless rendering: Mesa's EGL/OSMesa (software llvmpipe). Skipped when already present.
apt_need libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6

if [ ! -x .venv/bin/python ]; then
  # Debian ships ensurepip (which `python3 -m venv` needs) in the separate python3-venv package.
  if ! "$PY" -c 'import ensurepip' >/dev/null 2>&1; then
    apt_need python3-venv
  fi
  "$PY" -m venv .venv
fi
# shellcheck disable=SC1091
. .venv/bin/activate

stamp=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$stamp" ]; then
  echo "cir_gym already installed in .venv for this pyproject.toml (remove $STAMP to reinstall)"
  exit 0
fi
rm -f "$STAMP"
python -m pip install -q --upgrade pip >/dev/null
# CPU torch first: a bare 'torch' requirement would pull a multi-GB CUDA build.
python -c "import torch" 2>/dev/null || python -m pip install -q "torch==2.13.0"
python -m pip install -q -e ".[all]"
echo "$stamp" >"$STAMP"
