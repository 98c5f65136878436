"""Native batched CartesianTracking on ``mujoco.batch.Batch``.

>>> import cir_gym
>>> envs = cir_gym.make_vec("cir_gym/CartesianTracking-v1", num_envs=64)  # doctest: +SKIP

What is batched: the physics of all copies is one ``Batch.step(nstep=frame_skip)`` call; the
flange poses of the new joint positions one ``Batch.forward`` to the position stage (the
single env's forward kinematics, ``mj_kinematics``, in MuJoCo's threads), their Jacobians one
``Batch.jac`` (``mj_jac`` at the flange site, as ``mj_jacSite``); the task's step is the
single env's own functions of :mod:`cir_gym.envs.cartesian_tracking` (pose errors, the reward's
e², the following-error monitor, the held errors, the observation) on (N, ...) arrays, and
its reward :class:`~cir_gym.envs.tracking_reward.TrackingReward` on (N,) rows. Resets, seeding,
autoreset and divergence are :class:`~cir_gym.envs.vector_base.BatchedTaskEnv`'s; the episode
metrics and success are the template's ``episode_metrics`` on a copy's history.

Supported: exact sensing and actuation (no ``torque_noise``, no ``encoder_resolution``) and no
per-episode ``randomize``; every other argument (path, episode length, payload, friction,
reward weights, limits...) as in the single env. Otherwise :meth:`unsupported` names the
argument and ``cir_gym.make_vec`` falls back to a ``SyncVectorEnv``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np

from cir_gym.envs.cartesian_reference import quat_of
from cir_gym.envs.cartesian_tracking import (
    CartesianTrackingEnv,
    flange_pose_errors,
    following_error_exceeded,
    held_errors,
    observe,
    pose_error_sq,
)
from cir_gym.envs.tracking_reward import TERMS
from cir_gym.envs.vector_base import BatchedTaskEnv, TaskStep

__all__ = ["CartesianTrackingVectorEnv"]

_POSITION_STAGE = int(mujoco.mjtStage.mjSTAGE_POS)


class CartesianTrackingVectorEnv(BatchedTaskEnv):
    """``num_envs`` copies of ``cir_gym/CartesianTracking-v1`` stepped by one
    ``mujoco.batch.Batch``; copy i of ``reset(seed=s)`` is the single env reset with s + i.

    Arguments and errors as :class:`~cir_gym.envs.vector_base.BatchedTaskEnv`'s; ``kwargs``
    are :class:`~cir_gym.envs.cartesian_tracking.CartesianTrackingEnv`'s, except
    ``torque_noise``, ``encoder_resolution``, ``randomize`` and ``render_mode``.
    """

    env_class: ClassVar[type[CartesianTrackingEnv]] = CartesianTrackingEnv
    env_id: ClassVar[str] = "cir_gym/CartesianTracking-v1"
    fixed_arguments: ClassVar[dict[str, Any]] = {
        "torque_noise": 0.0,
        "encoder_resolution": 0.0,
        "randomize": False,
    }
    template: CartesianTrackingEnv

    episode_state: ClassVar[tuple[str, ...]] = (
        "_x_ref",  # p̄ (T + 1, 3) m at every control instant
        "_quat_ref",  # Q̄ (T + 1, 4) (w, x, y, z)
        "_twist_ref",  # [ṗ̄; ω̄] (T + 1, 6)
        "_acc_ref",  # [p̈̄; ω̄̇] (T + 1, 6)
        "_limits",  # (2,) position (m) and angle (rad) errors that stop the episode
        "_q_start",  # q(0) (n,) rad
        "_a_prev",  # the previous action (n,)
        "_k_scored",  # steps the metrics cover
    )
    episode_history: ClassVar[tuple[str, ...]] = (
        "_pos_err",  # ‖p̄ − p‖ (T,) m
        "_ang_err",  # θ̃ (T,) rad
        "_tau",  # commanded torque (T, n) N m
        "_qd_true",  # q̇ (T, n) rad/s
        "_sat",  # (T,) bool: a clipped or saturated joint
    )

    def _allocate(self) -> None:
        # the flange: its site's pose rows of the batch, its body for Batch.jac
        t = self.template
        self._site = t._site
        self._body = int(t.model.site_bodyid[t._site])
        self._site_xpos = self.batch.bind("site_xpos")  # (N, nsite, 3)
        self._site_xmat = self.batch.bind("site_xmat")  # (N, nsite, 9)

    def _task_step(self, a: np.ndarray, peak: np.ndarray, k: np.ndarray) -> TaskStep:
        t = self.template
        tau = a * t.torque_limit
        diverged = self._simulate(tau)
        self.batch.forward(stage=_POSITION_STAGE)  # the flange pose at the new q
        x = self._site_xpos[:, self._site]
        quat = quat_of(self._site_xmat[:, self._site])
        q, qd = self._qpos[:, t._qa], self._qvel[:, t._da]
        rows, k1 = self._rows, self._k
        reference = (
            self._x_ref[rows, k1],
            self._quat_ref[rows, k1],
            self._twist_ref[rows, k1],
            self._acc_ref[rows, k1],
        )

        e_pos, e_ang = flange_pose_errors(reference[0], reference[1], x, quat)
        self._pos_err[rows, k] = e_pos
        self._ang_err[rows, k] = e_ang
        self._tau[rows, k] = tau
        self._qd_true[rows, k] = qd
        self._sat[rows, k] = peak >= 1.0  # clipped or at the limit, as the single env
        stopped = following_error_exceeded(e_pos, e_ang, self._limits, diverged)
        error_sq = pose_error_sq(e_pos, e_ang, t.orientation_scale)
        terms = t.reward_model(error_sq, a, self._a_prev, diverged, stopped, t.max_steps - k1)
        reward = sum(terms[name] for name in TERMS)  # the single env's order of the terms
        self._a_prev[:] = a
        ended = np.flatnonzero(stopped | diverged)
        if ended.size:  # scored over the whole horizon (the single env's Episode End)
            held_pos, held_ang = held_errors(
                e_pos[ended], e_ang[ended], self._limits[ended], diverged[ended]
            )
            for i, pos, ang in zip(ended, held_pos, held_ang, strict=True):
                self._pos_err[i, k1[i] :] = pos
                self._ang_err[i, k1[i] :] = ang
                self._k_scored[i] = t.max_steps

        jacp, jacr = self.batch.jac(self._body, x)  # (N, 3, nv) each, at the flange site
        J = np.concatenate((jacp, jacr), axis=1)[:, :, t._da]  # (N, 6, n)
        flat = observe((q, qd, x, quat), J, reference, t._obs_low, t._obs_high)
        obs = {key: flat[:, at] for key, at in t._obs_slices.items()}
        infos = self._step_infos(
            {
                **terms,
                "position_error": e_pos,
                "orientation_error": e_ang,
                "following_error_exceeded": stopped,
                "diverged": diverged,
            }
        )
        return obs, reward, diverged | stopped, infos

    def _episode_end(
        self, i: int, infos: dict[str, Any], terminated: bool, truncated: bool
    ) -> dict[str, Any]:
        """Metrics and success of copy ``i``: the template's, on the copy's history and its
        last state."""
        t = self.template
        self._load_template(i)
        t.data.qpos[:] = self._qpos[i]  # the last configuration (joint_drift)
        info = self._row_info(infos, i)
        info["episode_metrics"] = t.episode_metrics()
        info["is_success"] = not terminated and t._settled()
        return info
