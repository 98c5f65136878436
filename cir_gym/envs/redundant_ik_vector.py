"""Native batched RedundantIK (planar 3R and iiwa14) on ``mujoco.batch.Batch``.

>>> from cir_gym.envs.redundant_ik_vector import RedundantIK7VectorEnv
>>> envs = RedundantIK7VectorEnv(num_envs=64, objective="obstacle")   # doctest: +SKIP

RedundantIK is kinematic: a step integrates the joint-velocity command exactly
(q ← q + Δt a ⊙ q̇_max, clipped at the joint limits) and has no ``mj_step``. Its per-step cost
is the forward kinematics of the new q and what is read from it: the site pose, the task
Jacobian (manipulability) and the link capsules' poses (clearance to the obstacle). That is
what is batched: the new q of every copy goes into the batch's ``qpos`` rows, one
``Batch.forward`` to the position stage (``mj_kinematics`` of every copy in C, as the single
env's ``Robot.site_pose``) gives the site and capsule poses, one ``Batch.jac`` at the site (as
``mj_jacSite``) the Jacobians. The rest of the single env's step (joint-limit stop, task and
orientation errors, manipulability, clearance, reward terms, ends, observation) is its
arithmetic on (N, ...) arrays; the orientation error runs MuJoCo's quaternion helpers row by
row, as the single env. Resets are the template single env's (every draw: path, obstacle,
"manipulability" start, joint window); episode metrics, the stopped arm's scoring of a
terminated episode and success are the template's own methods on a copy's trace.

Supported: every argument of the single env except ``render_mode``; ``reset``'s replay option
is not (each copy draws its tasks).
"""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np

from cir_gym import trajectories as traj
from cir_gym.envs.redundant_ik import RedundantIK7Env, RedundantIKEnv
from cir_gym.envs.redundant_ik_base import STEP_INFO_KEYS, RedundantIKBase
from cir_gym.envs.vector_base import BatchedTaskEnv, TaskStep
from cir_gym.operational_space import align_quat
from cir_gym.redundancy import orientation_error

__all__ = ["RedundantIK7VectorEnv", "RedundantIKVectorEnv"]

_POSITION_STAGE = int(mujoco.mjtStage.mjSTAGE_POS)


class _RedundantIKBatch(BatchedTaskEnv):
    """What the two arms' batched envs share (a subclass sets ``env_class`` and ``env_id``)."""

    template: RedundantIKBase
    episode_state: ClassVar[tuple[str, ...]] = (
        "_q",  # q (n,) rad: the copy's joint positions (the step integrates them)
        "_q0",  # q(0) (n,) rad
        "lower",  # this episode's joint limits (n,) rad
        "upper",
        "obstacle_centre",  # (3,) m
        "obstacle_radius",  # m (0: none)
        "_obstacle",  # the observation's obstacle (p + 1,)
        "_scored",  # trace rows holding scores
    )
    episode_history: ClassVar[tuple[str, ...]] = ("trace",)  # (T,) TRACE_FIELDS per step

    def _allocate(self) -> None:
        t, N = self.template, self.num_envs
        K1, p = t.max_steps + 1, t.pos_dim
        self._x_ref = np.zeros((N, K1, p))  # x̄ m
        self._xd_ref = np.zeros((N, K1, p))  # x̄̇ m/s
        self._R_ref = np.zeros((N, K1, 3, 3))  # R̄
        self._quat_ref = np.zeros((N, K1, 4))
        self._omega_ref = np.zeros((N, K1, 3))  # ω̄ rad/s
        self._references = [t.reference] * N  # each copy's Reference (stopped-arm scoring)
        self._p = np.zeros((N, p))  # the site pose at the copy's last step
        self._R = np.zeros((N, 3, 3))
        self._site = t.kin.site_id
        self._body = int(t.model.site_bodyid[self._site])
        self._qa = t.robot.qpos_adr
        self._da = t.robot.dof_adr
        self._capsules = t.kin.capsules
        self._site_xpos = self.batch.bind("site_xpos")  # (N, nsite, 3)
        self._site_xmat = self.batch.bind("site_xmat")  # (N, nsite, 9)
        self._geom_xpos = self.batch.bind("geom_xpos")  # (N, ngeom, 3)
        self._geom_xmat = self.batch.bind("geom_xmat")  # (N, ngeom, 9)

    def _start_episode(self, i: int) -> None:
        ref = self.template.reference
        self._references[i] = ref
        self._x_ref[i] = ref.x
        self._xd_ref[i] = ref.xd
        self._R_ref[i] = ref.R
        self._quat_ref[i] = ref.quat
        self._omega_ref[i] = ref.omega

    # ------------------------------------------------------------------ kinematics
    def _kinematics(self, q: np.ndarray) -> tuple[np.ndarray, ...]:
        """Site position (N, p) m and rotation (N, 3, 3), task Jacobian (N, m, n) and capsule
        end points a, b (N, c, 3) m of every copy at q (N, n): one ``Batch.forward`` to the
        position stage and one ``Batch.jac``."""
        t = self.template
        self._qpos[:, self._qa] = q
        self.batch.forward(stage=_POSITION_STAGE)
        x = self._site_xpos[:, self._site]
        R = self._site_xmat[:, self._site].reshape(-1, 3, 3)
        jacp, jacr = self.batch.jac(self._body, x)
        J = jacp[:, :2] if t.task_dim == 2 else np.concatenate((jacp, jacr), axis=1)
        ids = self._capsules.geom_ids
        a, b = self._capsules.ends(self._geom_xpos[:, ids], self._geom_xmat[:, ids])
        return x[:, : t.pos_dim], R, J[:, :, self._da], a, b

    def _orientation_errors(self, R_ref: np.ndarray, R: np.ndarray) -> np.ndarray:
        """‖θ r‖ (N,) rad of R̄ Rᵀ per copy (the single env's ``orientation_error``)."""
        return np.array([np.linalg.norm(orientation_error(Rr, Ri))
                         for Rr, Ri in zip(R_ref, R, strict=True)])

    # ------------------------------------------------------------------ step
    def _task_step(self, a: np.ndarray, peak: np.ndarray, k: np.ndarray) -> TaskStep:
        t, rows, k1 = self.template, self._rows, self._k
        q = self._q + t.dt * (a * t.velocity_limit)  # q̇ = a ⊙ q̇_max, held over Δt
        margin = np.minimum((q - self.lower).min(axis=1), (self.upper - q).min(axis=1))
        violation = margin < 0.0
        if violation.any():  # the joint stops at its limit
            q[violation] = np.clip(q[violation], self.lower[violation], self.upper[violation])
            margin[violation] = 0.0
        self._q[:] = q
        p, R, J, seg_a, seg_b = self._kinematics(q)
        self._p[:] = p
        self._R[:] = R
        e_pos = np.linalg.norm(self._x_ref[rows, k1] - p, axis=1)
        e_rot = np.zeros(self.num_envs)
        if t.task_dim == 6:
            e_rot = self._orientation_errors(self._R_ref[rows, k1], R)
        w = np.sqrt(np.maximum(np.linalg.det(J @ J.transpose(0, 2, 1)), 0.0))
        clear = self._capsules.segment_clearance(
            seg_a, seg_b, self.obstacle_centre[:, None, :], self.obstacle_radius
        )
        collision = clear < 0.0
        trace = self.trace
        for name, value in zip(trace.dtype.names, (e_pos, e_rot, w, margin, clear), strict=True):
            trace[name][rows, k] = value
        self._scored[:] = k1

        r_track = -(1.0 - np.exp(-(e_pos[:, None] ** 2) / t.error_scales**2).mean(axis=1))
        r_orient = np.zeros(self.num_envs)
        if t.task_dim == 6:
            r_orient = -(
                1.0 - np.exp(-(e_rot[:, None] ** 2) / t.orientation_scales**2).mean(axis=1)
            )
        r_secondary = -t.secondary_weight * self._secondary_cost(q, w, clear)
        r_velocity = -t.velocity_weight * np.einsum("ij,ij->i", a, a) / t.n
        terminated = violation | collision
        charge = (t.max_steps - k1) * t.worst_step_reward() if t.charge_unplayed_steps else 0.0
        r_term = np.where(terminated, -(t.termination_penalty + charge), 0.0)
        reward = r_track + r_orient + r_secondary + r_velocity + r_term
        values = dict(zip(STEP_INFO_KEYS, (
            r_track, r_orient, r_secondary, r_velocity, r_term, e_pos, w, margin, clear,
            violation, collision, np.zeros(self.num_envs, dtype=bool)), strict=True))
        if t.task_dim == 6:
            values["orientation_error"] = e_rot
        return self._observe(p, R), reward, terminated, self._step_infos(values)

    def _secondary_cost(self, q: np.ndarray, w: np.ndarray, clear: np.ndarray) -> np.ndarray:
        """The single env's objective cost in [0, 1] per copy (N,)."""
        t = self.template
        if t.objective == "manipulability":
            return np.exp(-w / t.arm.manipulability_scale)
        if t.objective == "joint_limits":  # −8 w_jl(q) = (4/n) Σ ((q − q̄)/(q_M − q_m))²
            u = (q - 0.5 * (self.lower + self.upper)) / (self.upper - self.lower)
            return 4.0 * np.einsum("ij,ij->i", u, u) / t.n
        return np.exp(-np.maximum(clear, 0.0) / 0.05)

    def _observe(self, p: np.ndarray, R: np.ndarray) -> dict[str, np.ndarray]:
        """The observation rows (N, ...) at the site poses (p, R) and the current step."""
        t, rows, k = self.template, self._rows, self._k
        parts = [self._q, p, self._x_ref[rows, k], self._xd_ref[rows, k]]
        if t.task_dim == 6:
            quat = align_quat(traj.quat_from_matrix(R), t._quat_home)
            parts += [quat, self._quat_ref[rows, k], self._omega_ref[rows, k]]
        parts += [self.lower, self.upper, self._obstacle]
        return t.observation_of(parts)

    def _episode_end(
        self, i: int, infos: dict[str, Any], terminated: bool, truncated: bool
    ) -> dict[str, Any]:
        """Copy ``i``'s last info: its metrics are the template's on the copy's trace (a
        terminated episode's trace completed by the template's stopped-arm scoring)."""
        t = self.template
        self._load_template(i)
        if terminated:
            t.reference = self._references[i]
            t._score_stopped_arm(int(self._k[i]) - 1, self._p[i], self._R[i])
        info = self._row_info(infos, i)
        info["episode_metrics"] = metrics = t.episode_metrics()
        info["is_success"] = t.is_success(metrics, terminated)
        return info


class RedundantIKVectorEnv(_RedundantIKBatch):
    """``num_envs`` copies of ``cir_gym/RedundantIK-v4`` (planar 3R, ``kwargs``: the single
    env's but ``render_mode``); copy i of ``reset(seed=s)`` is the single env reset with s + i."""

    env_class: ClassVar[type[RedundantIKEnv]] = RedundantIKEnv
    env_id: ClassVar[str] = "cir_gym/RedundantIK-v4"


class RedundantIK7VectorEnv(_RedundantIKBatch):
    """``num_envs`` copies of ``cir_gym/RedundantIK7-v5`` (iiwa14), as
    :class:`RedundantIKVectorEnv`."""

    env_class: ClassVar[type[RedundantIK7Env]] = RedundantIK7Env
    env_id: ClassVar[str] = "cir_gym/RedundantIK7-v5"
