"""cir_gym: Gymnasium/MuJoCo environments for an industrial-robot-control course.

``import cir_gym`` registers the environments (ids ``cir_gym/<Name>-v<N>``); they also work as
``gymnasium.make("cir_gym:cir_gym/<Name>-v0")`` in a fresh process.
"""

from __future__ import annotations

import os as _os

# Headless machines: software EGL unless the user chose a backend or has a display.
if "MUJOCO_GL" not in _os.environ and not _os.environ.get("DISPLAY"):
    _os.environ["MUJOCO_GL"] = "egl"
    _os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from cir_gym.envs import ENVIRONMENTS, register_envs
from cir_gym.robot import ModelError, Robot

__all__ = ["ENVIRONMENTS", "ModelError", "Robot", "register_envs"]
__version__ = "0.1.0"

register_envs()
