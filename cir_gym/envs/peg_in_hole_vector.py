"""Native batched PegInHole on ``mujoco.batch.Batch``.

>>> import cir_gym
>>> envs = cir_gym.make_vec("cir_gym/PegInHole-v2", num_envs=64)  # doctest: +SKIP

What is batched: the physics of all copies in MuJoCo's threads, as the single env's
``_advance`` runs it: the torque interface holds each copy's torques for the control period,
one ``Batch.step(nstep=frame_skip)``; the position interface computes its torque law at every
physics step, one ``Batch.step(nstep=1)`` each. The contacts are the scene's MuJoCo contact
sensors, each physics step's values read from MuJoCo's history buffer for all copies at once
(:class:`~cir_gym.envs.peg_in_hole_contacts.ContactSensors`); the F/T sensor is one batched
:class:`~cir_gym.ft_sensor.WrenchSensor`; the position interface one
:class:`~cir_gym.motion_interface.CartesianMotionInterface` on (N, 7) arrays. The task's
step (insertion, flags, reward, observation) is the single env's arithmetic on (N, ...)
arrays (its ``_reward_terms``, ``_step_info``, :func:`~cir_gym.envs.peg_in_hole.tip_twist`,
:func:`~cir_gym.envs.peg_in_hole_contacts.contact_flags`); each copy has its own hole pose
(the block's ``body_pos``/``body_quat`` expanded per simulation). Resets, seeding, autoreset
and divergence are :class:`~cir_gym.envs.vector_base.BatchedTaskEnv`'s; the episode metrics
are the template's ``episode_metrics`` on a copy's history.

A copy whose period a single contact stops is set back to the period's start and simulated
again up to that physics step (the same computation), then ``Batch.forward`` as the single
env's ``mj_forward``; its F/T sensor feels the stopped state for the rest of the period, as
the single env's does. A copy that diverges is restored and counts no contact, as there.

Supported: every argument of the single env except ``render_mode``; both control interfaces.
A wrapper may drive it with (N, 7) torques per control step (``control="torque"``).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from cir_gym import trajectories as traj
from cir_gym.envs.peg_in_hole import (
    ALIGNED,
    BOTTOM_TOLERANCE,
    ENTRY_DEPTH,
    PegInHoleEnv,
    tip_twist,
)
from cir_gym.envs.peg_in_hole_contacts import ContactFlags, contact_flags
from cir_gym.envs.vector_base import BatchedTaskEnv
from cir_gym.ft_sensor import WrenchSensor
from cir_gym.motion_interface import CartesianMotionInterface

__all__ = ["PegInHoleVectorEnv"]


class PegInHoleVectorEnv(BatchedTaskEnv):
    """``num_envs`` copies of ``cir_gym/PegInHole-v2`` stepped by one ``mujoco.batch.Batch``;
    copy i of ``reset(seed=s)`` is the single env reset with s + i.

    Args:
        num_envs: number of copies (≥ 1).
        nthread: MuJoCo threads (0: all CPUs).
        **kwargs: :class:`~cir_gym.envs.peg_in_hole.PegInHoleEnv`'s arguments, except
            ``render_mode``.

    Raises:
        InvalidArgument: ``num_envs`` < 1, an unsupported argument, or one the single env
            rejects.
    """

    env_class: ClassVar[type[PegInHoleEnv]] = PegInHoleEnv
    env_id: ClassVar[str] = "cir_gym/PegInHole-v2"
    template: PegInHoleEnv

    def _allocate(self) -> None:
        t, N = self.template, self.num_envs
        m, steps = t.model, t.max_steps
        b = self.batch
        self._body_pos = b.expand("body_pos")  # (N, nbody, 3): each copy's hole pose
        self._body_quat = b.expand("body_quat")
        self._sensordata = b.bind("sensordata")
        self._history = b.bind("history")
        self._site_xpos = b.bind("site_xpos")
        self._site_xmat = b.bind("site_xmat")
        self._cdof = b.bind("cdof")
        self._subtree_com = b.bind("subtree_com")
        self._held = np.zeros_like(b.state)  # states of copies that diverged within a period
        self._period = np.zeros((N, t.frame_skip, m.nsensordata))
        self._hole_pos = np.zeros((N, 3))  # the true hole pose of each copy
        self._hole_R = np.zeros((N, 3, 3))
        self._goal = np.zeros((N, 3))
        self._force = np.zeros((N, steps))
        self._net_peak = np.zeros((N, steps))
        self._net_sum = np.zeros((N, steps))
        self._jammed_steps = np.zeros(N, dtype=np.int64)
        self._inserted_at = np.full(N, -1)  # step of the insertion, −1: not inserted
        self._inserted = np.zeros(N, dtype=bool)  # inserted at the last step
        self._entered = np.zeros(N, dtype=bool)
        self._tip_z = np.zeros(N)  # tip height in the true hole frame after the last step
        self._depth = np.zeros(N)
        self.ft_sensor = WrenchSensor(t.ft_sensor.spec, m.opt.timestep, num_envs=N)
        self.motion: CartesianMotionInterface | None = None
        if t.control == "position":
            self.motion = CartesianMotionInterface(t.motion.robot, "peg_tip")
            self.motion.reset(np.tile(t._q0, (N, 1)))
        self._bounds = {key: t._obs_bounds[key] for key in t.observation_space.spaces}
        self._low = {key: -b for key, b in self._bounds.items()}
        # the nominal hole's pose: the same in every copy and step (within its bounds)
        hole = {key: np.clip(getattr(t, key), self._low[key], self._bounds[key])
                for key in ("hole_pos", "hole_quat")}
        self._hole_pos_obs = np.tile(hole["hole_pos"], (N, 1))
        self._hole_quat_obs = np.tile(hole["hole_quat"], (N, 1))

    def _start_episode(self, i: int) -> None:
        t = self.template
        self._body_pos[i, t._block] = t.model.body_pos[t._block]
        self._body_quat[i, t._block] = t.model.body_quat[t._block]
        self._hole_pos[i] = t.true_hole_pos
        self._hole_R[i] = t.true_hole_R
        self._goal[i] = t._goal
        self._force[i] = 0.0
        self._net_peak[i] = 0.0
        self._net_sum[i] = 0.0
        self._jammed_steps[i] = 0
        self._inserted_at[i] = -1
        self._entered[i] = False
        self._tip_z[i] = -t._final_depth
        self._depth[i] = t._final_depth
        self.ft_sensor.load_row(i, t.ft_sensor)
        if self.motion is not None:
            self.motion.reset(t._q0, rows=[i])

    # ------------------------------------------------------------------ physics
    def _advance(self, a: np.ndarray) -> tuple[np.ndarray, ...]:
        """One control period of every copy (PegInHoleEnv._advance on (N, ...) arrays): the
        physics, the contact sensors of each physics step from the history buffer, and the
        copies stopped by the force limit simulated again from the period's start up to
        their stop.

        Returns:
            (diverged, largest single contact force, largest net force, sum of the net force
            over the physics steps played), each (N,).
        """
        t, steps = self.template, self.template.frame_skip
        if self.motion is not None:
            dx = a * t.increment_scale  # in the nominal hole frame
            R_h = t._R_hole
            self.motion.command(np.concatenate((dx[:, :3] @ R_h.T, dx[:, 3:] @ R_h.T), axis=1), t.dt)
            tau = None
        else:
            tau = a * t.torque_limit
        period, sensors = self._period, t.sensors
        start = self.batch.state.copy()
        diverged = self._physics(tau, steps)
        sensors.period(self._history, period)
        over = (sensors.largest(period) > t.force_limit) & ~diverged[:, None]  # (N, steps)
        stopping = np.any(over, axis=1)
        played = np.where(stopping, np.argmax(over, axis=1) + 1, steps)
        played[diverged] = 0
        again = np.flatnonzero(stopping & (played < steps))
        if again.size:  # the same computation from the period's start, up to the stop
            self.batch.state[again] = start[again]
            self._replay(again, tau, played[again])
        stopped = np.flatnonzero(stopping | diverged)
        done = np.arange(steps) < played[:, None]  # (N, steps): the physics steps played
        if stopped.size:
            self.batch.forward(ids=np.flatnonzero(stopping))  # the stopped state
            # the rest of a stopped period: the sensor feels the stopped state
            period[stopped] = np.where(
                done[stopped, :, None], period[stopped], self._sensordata[stopped, None]
            )
        self.ft_sensor.advance_many(sensors.wrist(period))
        net = np.where(done, np.linalg.norm(sensors.net(period), axis=-1), 0.0)
        largest = np.max(np.where(done, sensors.largest(period), 0.0), axis=1)
        return diverged, largest, np.max(net, axis=1), np.sum(net, axis=1)

    def _physics(self, tau: np.ndarray | None, steps: int) -> np.ndarray:
        """A control period's physics of every copy (PegInHoleEnv._physics): the torques
        ``tau`` (N, 7) held, one ``Batch.step``, or the position interface's torques at each
        physics step (``tau`` None). A copy that diverges is restored (``_simulate``) and
        held there for the rest of the period. Returns the (N,) diverged copies."""
        if tau is not None:
            return self._simulate(tau, nstep=steps)
        t, qa, da = self.template, self.template.robot.qpos_adr, self.template.robot.dof_adr
        diverged = np.zeros(self.num_envs, dtype=bool)
        for i in range(steps):
            tau_i = self.motion.torque(self._qpos[:, qa], self._qvel[:, da], (i + 1) / steps)
            new = self._simulate(np.clip(tau_i, -t.torque_limit, t.torque_limit), nstep=1)
            new &= ~diverged
            if new.any():
                self._held[new] = self.batch.state[new]
                diverged |= new
        if diverged.any():  # held at their restored state
            ids = np.flatnonzero(diverged)
            self.batch.state[ids] = self._held[ids]
            self.batch.forward(ids=ids)
        return diverged

    def _replay(self, ids: np.ndarray, tau: np.ndarray | None, counts: np.ndarray) -> None:
        """Copies ``ids``, set back to their period's start, run their first ``counts``
        physics steps again (none diverged there in the first pass)."""
        ctrl = self._ctrl
        if tau is not None:
            for count in np.unique(counts):
                group = ids[counts == count]
                ctrl[group] = tau[group]
                self.batch.step(ids=group, nstep=int(count))
            return
        t, qa, da = self.template, self.template.robot.qpos_adr, self.template.robot.dof_adr
        steps = t.frame_skip
        for i in range(int(np.max(counts))):
            group = ids[counts > i]
            tau_i = self.motion.torque(self._qpos[:, qa], self._qvel[:, da], (i + 1) / steps)
            ctrl[group] = np.clip(tau_i[group], -t.torque_limit, t.torque_limit)
            self.batch.step(ids=group, nstep=1)

    # ------------------------------------------------------------------ task
    def _task_step(
        self, a: np.ndarray, peak: np.ndarray, k: np.ndarray
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, dict[str, Any]]:
        t, rows = self.template, self._rows
        z_before = self._tip_z.copy()
        diverged, force, net_peak, net_sum = self._advance(a)
        self._force[rows, k], self._net_peak[rows, k], self._net_sum[rows, k] = (
            force, net_peak, net_sum
        )
        p_tip = self._site_xpos[:, t._tip]
        tip = np.einsum("nji,nj->ni", self._hole_R, p_tip - self._hole_pos)  # Rᵀ (p − p_h)
        depth = -tip[:, 2]
        self._tip_z[:], self._depth[:] = tip[:, 2], depth
        twist = tip_twist(self._cdof, self._qvel, p_tip, self._subtree_com[:, t._arm_root])
        axis = self._hole_R[:, :, 2]
        flags = self._contact_flags(depth, np.einsum("ni,ni->n", axis, twist[:, :3]))
        self._jammed_steps += flags.jammed
        radial = np.hypot(tip[:, 0], tip[:, 1])
        g = t.geometry
        above = tip[:, 2] > -ENTRY_DEPTH  # at or above the top face: not in the bore
        went_in = ~above & (z_before > -ENTRY_DEPTH)  # through the opening?
        self._entered = ~above & np.where(went_in, radial < g.hole_radius + g.chamfer, self._entered)
        inserted = (
            ~diverged
            & self._entered
            & (t.goal_depth <= depth)
            & (depth <= g.depth + BOTTOM_TOLERANCE)
            & (radial < g.hole_radius)
        )
        self._inserted = inserted
        first = inserted & (self._inserted_at < 0)
        self._inserted_at[first] = self._k[first]
        over = ~diverged & (force > t.force_limit)

        dist = np.linalg.norm(p_tip - self._goal, axis=1)
        terms = t._reward_terms(dist, force, inserted, over, diverged, self._k)
        reward = sum(terms.values())
        infos = self._step_infos(
            t._step_info(terms, force, net_peak, depth, flags, over, diverged)
        )
        return self._observe(twist), reward, diverged | inserted | over, infos

    def _contact_flags(self, depth: np.ndarray, axial_speed: np.ndarray) -> ContactFlags:
        """The single env's flags of every copy, from the peg's contact sensor."""
        t, N = self.template, self.num_envs
        flags = [np.zeros(N, dtype=bool) for _ in range(3)]
        rows = np.flatnonzero(t.sensors.peg_count(self._sensordata) >= 2)  # two contacts
        if rows.size:
            normal, pressing = t.sensors.peg(self._sensordata[rows])
            found = contact_flags(
                normal, pressing, self._hole_R[rows, :, 2], depth[rows], axial_speed[rows],
                t._mu_diameter,
            )
            for flag, value in zip(flags, (found.two_point, found.wedged, found.jammed),
                                   strict=True):
                flag[rows] = value
        return ContactFlags(*flags)

    def _observe(self, twist: np.ndarray) -> dict[str, np.ndarray]:
        """PegInHoleEnv._obs of every copy; ``twist`` (N, 6) the tips' [v; ω], world frame."""
        t, N = self.template, self.num_envs
        R_h = t._R_hole
        R_tip = self._site_xmat[:, t._tip].reshape(N, 3, 3)
        raw = {
            "q": self._qpos[:, t.robot.qpos_adr],
            "qd": self._qvel[:, t.robot.dof_adr],
            "peg_pos": (self._site_xpos[:, t._tip] - t.hole_pos) @ R_h,
            "peg_quat": traj.quat_from_matrix(R_h.T @ R_tip @ ALIGNED.T),
            "peg_twist": np.concatenate((twist[:, :3] @ R_h, twist[:, 3:] @ R_h), axis=1),
            "wrench": self.ft_sensor.reading.copy(),
        }
        obs = {key: np.clip(x, self._low[key], self._bounds[key]) for key, x in raw.items()}
        return {**obs, "hole_pos": self._hole_pos_obs.copy(), "hole_quat": self._hole_quat_obs.copy()}

    def _episode_end(
        self, i: int, infos: dict[str, Any], terminated: bool, truncated: bool
    ) -> dict[str, Any]:
        """Metrics and success of copy ``i`` as the single env scores them."""
        t = self.template
        info = self._row_info(infos, i)
        t._force[:] = self._force[i]
        t._net_peak[:] = self._net_peak[i]
        t._net_sum[:] = self._net_sum[i]
        t._jammed_steps = int(self._jammed_steps[i])
        t._k = int(self._k[i])
        t._inserted_at = int(self._inserted_at[i]) if self._inserted_at[i] >= 0 else None
        t._final_depth = float(self._depth[i])
        info["episode_metrics"] = t.episode_metrics()
        info["is_success"] = bool(self._inserted[i])
        return info

