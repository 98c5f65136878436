"""cir_gym: Gymnasium/MuJoCo environments for an industrial-robot-control course.

``import cir_gym`` registers the environments (ids ``cir_gym/<Name>-v<N>``, the keys of
``cir_gym.ENVIRONMENTS``); they also work as ``gymnasium.make("cir_gym:cir_gym/<Name>-v<N>")``
in a fresh process.
"""

from __future__ import annotations

import ctypes.util as _ctypes_util
import os as _os

# MuJoCo's GL backend on a machine without a display (before mujoco is imported): EGL if
# libEGL is installed, else OSMesa if libOSMesa is, else none. Forcing a backend whose library
# is missing makes `import mujoco` crash inside PyOpenGL; with MUJOCO_GL=disable only
# `render()` fails, with a RuntimeError naming the Debian packages to install (envs/base.py
# GL_HELP). A backend chosen by the user (MUJOCO_GL) or a display (DISPLAY: GLFW) is kept.
if "MUJOCO_GL" not in _os.environ and not _os.environ.get("DISPLAY"):
    for _gl, _library in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if _ctypes_util.find_library(_library):
            _os.environ["MUJOCO_GL"] = _gl
            _os.environ.setdefault("PYOPENGL_PLATFORM", _gl)
            break
    else:
        _os.environ["MUJOCO_GL"] = "disable"

from typing import Any as _Any

from cir_gym.envs import ENVIRONMENTS, register_envs
from cir_gym.robot import ModelError, Robot

__all__ = ["ENVIRONMENTS", "ModelError", "Robot", "make_vec", "register_envs"]


def make_vec(env_id: str, num_envs: int = 1, **kwargs: _Any) -> _Any:
    """``num_envs`` copies of ``env_id`` as a Gymnasium vector env: natively batched on
    ``mujoco.batch`` where :mod:`cir_gym.envs.vector` has it, else a SyncVectorEnv (same autoreset
    mode and seeding); see :func:`cir_gym.envs.vector.make_vec` (imported on first use)."""
    from cir_gym.envs.vector import make_vec as _make_vec

    return _make_vec(env_id, num_envs, **kwargs)


__version__ = "0.1.0"

register_envs()
