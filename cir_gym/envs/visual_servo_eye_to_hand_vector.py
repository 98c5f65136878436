"""Native batched VisualServoEyeToHand (a fixed camera, markers on the flange) on
``mujoco.batch.Batch``.

>>> import cir_gym
>>> envs = cir_gym.make_vec("cir_gym/VisualServoEyeToHand-v1", num_envs=16)  # doctest: +SKIP
>>> obs, infos = envs.reset(seed=0)      # copy i is the single env reset(seed=i)

The eye-in-hand batched env (:mod:`cir_gym.envs.visual_servo_vector`: one ``Batch.step`` for
the physics, batched ray casts for the line of sight, each copy's noise from its own
generator, the single env's reward and metrics on rows) with the eye-to-hand geometry of
:class:`~cir_gym.envs.visual_servo_eye_to_hand.VisualServoEyeToHandEnv`, the specification
(each copy equals it to the tolerance tests/test_visual_servo_eye_to_hand_vector.py states):

* **The twist's frame** is the fixed camera's nominal optical frame (the single env's
  ``_twist_rotation``, the same rotation at any joints), not the flange's.
* **The moving frame** is the marker plate's centre, ``moving_offset`` = 0.03 m beyond the
  flange along its z axis: the resolved-rate Jacobian's linear rows and the recorded path are
  that point's (the shared batched env's :meth:`_moving_jacobians` and ``_record`` follow
  ``moving_offset``, 0 on the eye-in-hand task).
* **The camera** is on the world body: its true pose per copy (the calibration error's
  extrinsic terms) is the copy's ``cam_pos`` / ``cam_quat`` row, and the static geoms rigid
  with it (its weld group, the world's) keep their "encloses the camera centre" test for the
  episode, as in the eye-in-hand env.

Supported: what the eye-in-hand batched env supports (``features="projected"`` without
``obs_image``, both actions, every other argument); ``features="detected"``,
``obs_image=True`` and ``render_mode`` fall back to a ``SyncVectorEnv`` in
``cir_gym.make_vec``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from cir_gym.envs.visual_servo_eye_to_hand import VisualServoEyeToHandEnv
from cir_gym.envs.visual_servo_vector import VisualServoVectorEnv

__all__ = ["VisualServoEyeToHandVectorEnv"]


class VisualServoEyeToHandVectorEnv(VisualServoVectorEnv):
    """``num_envs`` copies of ``cir_gym/VisualServoEyeToHand-v1`` stepped by one
    ``mujoco.batch.Batch``; copy i of ``reset(seed=s)`` is the single env reset with s + i
    (module docstring).

    Args:
        num_envs: number of copies (≥ 1).
        nthread: MuJoCo threads (0: all CPUs).
        **kwargs: :class:`~cir_gym.envs.visual_servo_eye_to_hand.VisualServoEyeToHandEnv`'s
            arguments, except ``features="detected"``, ``obs_image=True`` and
            ``render_mode``.

    Raises:
        InvalidArgument: ``num_envs`` < 1, an unsupported argument, or one the single env
            rejects.
    """

    env_class: ClassVar[type[VisualServoEyeToHandEnv]] = VisualServoEyeToHandEnv
    env_id: ClassVar[str] = "cir_gym/VisualServoEyeToHand-v1"
    template: VisualServoEyeToHandEnv

    def _allocate(self) -> None:
        super()._allocate()
        t = self.template
        R = t._twist_rotation(t.q_goal)  # the fixed camera's: the same at any joints
        self._camera_rotation = np.ascontiguousarray(np.broadcast_to(R, (self.num_envs, 3, 3)))

    def _twist_rotations(self) -> np.ndarray:
        """R (N, 3, 3): the nominal camera's rotation, optical → world, for every copy
        (VisualServoEyeToHandEnv._twist_rotation: the twist is in its optical frame)."""
        return self._camera_rotation
