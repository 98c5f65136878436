#!/usr/bin/env bash
# Sets up cir_gym on a fresh Debian machine with Python 3.11; reuses what exists on a second run.
#   bash scripts/setup.sh            # venv in .venv, CPU torch, the package with all extras, Mesa
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}

# Headless rendering: Mesa's EGL/OSMesa (software llvmpipe). Skipped when already present.
need=()
for p in libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6; do
  dpkg -s "$p" >/dev/null 2>&1 || need+=("$p")
done
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
  $SUDO apt-get update -qq && $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
fi

[ -x .venv/bin/python ] || "$PY" -m venv .venv
# shellcheck disable=SC1091
. .venv/bin/activate
python -m pip install -q --upgrade pip >/dev/null
# CPU torch first: a bare 'torch' requirement would pull a multi-GB CUDA build.
python -c "import torch" 2>/dev/null || python -m pip install -q "torch==2.13.0"
python -m pip install -q -e ".[all]"
