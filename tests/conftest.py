"""Test-session setup: let cir_gym choose the headless GL backend before anything imports mujoco
(EGL if libEGL is installed, else OSMesa, else rendering disabled with a clear error)."""

from __future__ import annotations

import cir_gym  # noqa: F401  (sets MUJOCO_GL when the user has not)
