"""Native batched AdmittanceContact on ``mujoco.batch.Batch``: ``num_envs`` copies of
``cir_gym/AdmittanceContact-v1`` in one vector env.

>>> import cir_gym
>>> envs = cir_gym.make_vec("cir_gym/AdmittanceContact-v1", num_envs=32)   # doctest: +SKIP
>>> obs, infos = envs.reset(seed=0)          # copy i is AdmittanceContact reset(seed=i)
>>> obs, rew, term, trunc, infos = envs.step(envs.action_space.sample())

What is batched and how (the single env's ``step`` is the specification; each copy equals it
to the tolerance tests/test_vector_admittance.py states):

* **Physics.** A control period is ``substeps`` physics steps of every copy, one
  ``Batch.step`` each (:meth:`BatchedTaskEnv._simulate`: per-copy divergence and restore).
  The contact forces are MuJoCo contact sensors (the scene's ``tool_contact``: the
  tool-plate net force; ``peak_contact``: the largest single contact on the plate), so each
  step's ``sensordata`` row (N, nsensordata) is the whole per-step measurement; the period's
  record (N, substeps, nsensordata) feeds the batched wrist-sensor model
  (:class:`~cir_gym.ft_sensor.WrenchSensor` with ``num_envs``) and
  :func:`~cir_gym.envs.admittance_task.period_forces`, as the single env feeds its own. The
  torque interface holds τ = a ⊙ τ_max over the period; the position interface's torque law
  (:class:`~cir_gym.motion_interface.CartesianMotionInterface` on (N, 7) arrays) runs at
  every physics step. After the period ``Batch.forward`` (to the velocity stage) makes the
  poses and velocities of the reached state current, as the single env's kinematics calls.
* **Per-episode surfaces.** Every reset draws a surface height, tilt (and with
  ``randomize=True`` the stiffness, damping and sensor bias): the plate's ``jnt_stiffness``,
  ``dof_damping`` and its mount's ``body_pos``, ``body_quat`` are per-copy model fields
  (``Batch.expand``), written from the template after each copy's reset.
* **Task.** The reward (:class:`~cir_gym.envs.admittance_task.AdmittanceReward`), the contact
  flags, the force limit and the episode metrics
  (:func:`~cir_gym.envs.admittance_task.episode_metrics`) are the single env's own functions
  on (N, ...) arrays; resets are the template single env's (``BatchedTaskEnv``).

Driving the task by torques: :meth:`AdmittanceContactVectorEnv._task_step` is one 2-ms task
step of every copy with (N, 7) normalised torques (``control="torque"``), without autoreset: a
wrapper (the agent-ready impedance loop) can call it for each of its inner steps.

Supported: every argument of the single env except ``render_mode``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np

from cir_gym.envs import admittance_scene as scene
from cir_gym.envs.admittance_contact import START_Q, AdmittanceContactEnv
from cir_gym.envs.admittance_task import CONTACT_THRESHOLD, REWARD_TERMS, period_forces
from cir_gym.envs.base import MAX_JOINT_SPEED
from cir_gym.envs.vector_base import BatchedTaskEnv
from cir_gym.ft_sensor import WrenchSensor
from cir_gym.motion_interface import CartesianMotionInterface
from cir_gym.numeric import CLIP

__all__ = ["AdmittanceContactVectorEnv"]

_VELOCITY_STAGE = int(mujoco.mjtStage.mjSTAGE_VEL)
#: what a period records of each physics step
_RECORD = ("sensordata", "qpos", "qvel")
#: the per-copy model fields an episode's surface sets (AdmittanceContactEnv.reset)
_SURFACE_FIELDS = ("jnt_stiffness", "dof_damping", "body_pos", "body_quat")


class AdmittanceContactVectorEnv(BatchedTaskEnv):
    """``num_envs`` copies of ``cir_gym/AdmittanceContact-v1`` on one ``mujoco.batch.Batch``
    (see the module docstring).

    Args:
        num_envs: number of copies (≥ 1).
        nthread: MuJoCo threads (0: all CPUs).
        **kwargs: the single env's arguments, except ``render_mode``.
    """

    env_class: ClassVar[type[AdmittanceContactEnv]] = AdmittanceContactEnv
    env_id: ClassVar[str] = "cir_gym/AdmittanceContact-v1"
    template: AdmittanceContactEnv

    episode_state: ClassVar[tuple[str, ...]] = (
        "_normal", "_f_ref", "_pos_ref", "_vel_ref", "_a_prev",
    )
    episode_history: ClassVar[tuple[str, ...]] = ("_force", "_touch", "_peak", "_path")

    # ------------------------------------------------------------------ allocation, resets
    def _allocate(self) -> None:
        t, N, m, n = self.template, self.num_envs, self.template.model, self.template.substeps
        self._model_rows = {name: self.batch.expand(name) for name in _SURFACE_FIELDS}
        self._site_xpos = self.batch.bind("site_xpos")
        self._site_xmat = self.batch.bind("site_xmat")
        self._cvel = self.batch.bind("cvel")
        self._subtree_com = self.batch.bind("subtree_com")
        self._site_body = int(m.site_bodyid[t._site])
        self._site_root = int(m.body_rootid[self._site_body])
        self.sensor = WrenchSensor(t.sensor_spec, m.opt.timestep, num_envs=N)
        self.interface = (
            CartesianMotionInterface(scene.tool_robot(), scene.SITE)
            if t.control == "position" else None
        )
        if self.interface is not None:
            self.interface.reset(np.tile(START_Q, (N, 1)))
        # a period's records, (N, n, ...) per item of _RECORD, and those of one physics step
        # (the position interface's torque law runs between them)
        self._record = {key: np.zeros((N, n, size)) for key, size in
                        (("sensordata", m.nsensordata), ("qpos", m.nq), ("qvel", m.nv))}
        self._one_step = {key: np.zeros((N, 1, v.shape[2])) for key, v in self._record.items()}
        self._start_q = np.zeros((N, m.nq))  # the state a period starts from
        self._start_qd = np.zeros((N, m.nv))
        self._last_safe_q = np.zeros((N, m.nq))  # see _advance
        self._last_safe_qd = np.zeros((N, m.nv))
        self._first_contact = np.full(N, -1)  # the step of the first contact; -1: none yet

    def _start_episode(self, i: int) -> None:
        t = self.template
        for name, rows in self._model_rows.items():
            rows[i] = getattr(t.model, name)
        self.sensor.load_row(i, t.sensor)
        if self.interface is not None:
            self.interface.reset(START_Q, rows=[i])
        self._first_contact[i] = -1
        self._last_safe_q[i] = self._qpos[i]
        self._last_safe_qd[i] = self._qvel[i]

    # ------------------------------------------------------------------ step
    def _advance(self, a: np.ndarray) -> np.ndarray:
        """One control period of every copy (AdmittanceContactEnv._advance on the rows); return
        the (N,) copies that diverged.

        The torque interface's period is one ``Batch.rollout`` of ``substeps`` physics steps
        at the held torque; the position interface's, one rollout per physics step with its
        torque law in between. Each step's sensordata, qpos and qvel go to ``_record``. A
        copy diverged at step j if MuJoCo raised an instability warning there (the rollout
        stops that copy: its later records repeat step j's) or if step j left q or q̇
        non-finite or |q̇| > MAX_JOINT_SPEED (RobotEnv._simulate's rule, at each physics
        step): it is put back to its state after step j − 1 (the period's start for j = 0)
        and its records from step j on are zeroed, as the single env stops there. Then the
        records feed the wrist sensors, and ``Batch.forward`` makes the poses and velocities
        of the reached state current."""
        t, n, N = self.template, self.template.substeps, self.num_envs
        q, qd, record = self._qpos, self._qvel, self._record
        self._start_q[:] = q
        self._start_qd[:] = qd
        played = np.full(N, n)
        held = self.interface is None
        for j in range(0, n, n if held else 1):
            if held:
                self._ctrl[:] = a * t.torque_limit
            else:
                tau = self.interface.torque(q[:, t._qa], qd[:, t._da], (j + 1) / n)
                self._ctrl[:] = np.clip(tau, -t.torque_limit, t.torque_limit)
            before = self._warning_counts().copy()
            out = self.batch.rollout(n if held else 1, record=_RECORD,
                                     out=record if held else self._one_step)
            if not held:
                for key, value in out.items():
                    record[key][:, j] = value[:, 0]
            for i in np.flatnonzero(np.any(self._warning_counts() != before, axis=1)):
                played[i] = min(played[i], j + _stopped_at(out["qpos"][i], out["qvel"][i]))
        qpos, qvel = record["qpos"], record["qvel"]
        if np.max(np.abs(qvel)) > MAX_JOINT_SPEED or not np.isfinite(np.sum(qpos)):
            with np.errstate(all="ignore"):  # NaN fails the comparison
                bad = ~np.all(np.isfinite(qpos), axis=2) | ~(
                    np.max(np.abs(qvel), axis=2) <= MAX_JOINT_SPEED
                )
            played = np.minimum(played, np.where(bad.any(axis=1), bad.argmax(axis=1), n))
        stopped = played < n
        if stopped.any():
            for i in np.flatnonzero(stopped):  # back to the last finite state before the step
                j = played[i] - 1
                start_finite = np.isfinite(self._start_q[i].sum() + self._start_qd[i].sum())
                q[i], qd[i] = (
                    (qpos[i, j], qvel[i, j]) if j >= 0
                    else (self._start_q[i], self._start_qd[i]) if start_finite
                    else (self._last_safe_q[i], self._last_safe_qd[i])
                )
            for value in record.values():
                value[np.arange(n)[None, :] >= played[:, None]] = 0.0
        # the state before this period's last step: the last finite state of a period that
        # starts from a non-finite one (RobotEnv._simulate keeps it for that case)
        self._last_safe_q[:] = qpos[:, n - 2] if n > 1 else self._start_q
        self._last_safe_qd[:] = qvel[:, n - 2] if n > 1 else self._start_qd
        self.sensor.advance_many(record["sensordata"][:, :, t._wrench_at])
        self.batch.forward(stage=_VELOCITY_STAGE)  # poses and velocities of the reached state
        return stopped

    def _task_step(
        self, a: np.ndarray, peak: np.ndarray, k: np.ndarray
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, dict[str, Any]]:
        t, rows = self.template, self._rows
        if self.interface is not None:
            self.interface.command(a * t.increment_scale, t.dt)
        diverged = self._advance(a)
        tool, peak_steps = period_forces(
            self._record["sensordata"], self._normal, t._tool_at, t._peak_at
        )
        force = tool.mean(axis=1)
        touch = (tool > CONTACT_THRESHOLD).mean(axis=1)
        largest = peak_steps.max(axis=1)
        load = self._plate_load()
        k1 = self._k
        e = self._pos_ref[rows, np.minimum(k1, t.max_steps)] - self._site_xpos[:, t._site]
        e_t = e - (e @ scene.SURFACE_NORMAL)[:, None] * scene.SURFACE_NORMAL
        e_t_sq = np.sum(e_t * e_t, axis=1)
        self._force[rows, k], self._touch[rows, k], self._peak[rows, k] = force, touch, largest
        self._path[rows, k] = np.sqrt(e_t_sq)
        first = (self._first_contact < 0) & (touch > 0.0)
        self._first_contact[first] = k[first]
        over = ~diverged & (np.maximum(largest, load) > t.force_limit)
        err = force - self._f_ref
        terms = t.reward_model.terms(
            err, e_t_sq, np.sum((a - self._a_prev) ** 2, axis=1), over, diverged, k1
        )
        reward = sum(terms[name] for name in REWARD_TERMS)  # the single env's order
        self._a_prev[:] = a
        terminated = diverged | over
        infos = self._step_infos({
            **terms,
            "contact_force": force,
            "in_contact": touch == 1.0,
            "contact_steps": touch,
            "peak_contact_force": largest,
            "plate_load": load,
            "force_error": err,
            "path_error": self._path[rows, k],
            "force_limit_exceeded": over,
            "diverged": diverged,
        })
        return self._observation(), reward, terminated, infos

    def _plate_load(self) -> np.ndarray:
        """k x + c ẋ of every copy's plate (N,) (AdmittanceContactEnv.normal_force)."""
        t, fields = self.template, self._model_rows
        x = -self._qpos[:, t._slide_qpos]
        return (
            fields["jnt_stiffness"][:, t._slide_jnt] * x
            - fields["dof_damping"][:, t._slide_dof] * self._qvel[:, t._slide_dof]
        )

    def _observation(self) -> dict[str, np.ndarray]:
        """The single env's observation of every copy (AdmittanceContactEnv._obs), clipped."""
        t, rows = self.template, self._rows
        kk = np.minimum(self._k, t.max_steps)
        tool_pos = self._site_xpos[:, t._site]
        tool_quat = scene.quat_of(self._site_xmat[:, t._site].reshape(-1, 3, 3))
        # the tcp's velocity (mj_objectVelocity, world frame): the body's spatial velocity
        # [ω; v] about its subtree's centre of mass, moved to the site: v + ω × (p − c)
        cvel = self._cvel[:, self._site_body]
        omega = cvel[:, :3]
        lever = tool_pos - self._subtree_com[:, self._site_root]
        velocity = cvel[:, 3:] + np.cross(omega, lever)
        if self.interface is not None:
            robot, site = self.interface.robot, self.interface.site
            poses = [robot.site_pose(site, q_c) for q_c in self.interface.q_c]
            setpoint_pos = np.array([p for p, _ in poses])
            setpoint_quat = scene.quat_of(np.array([R for _, R in poses]))
        else:
            setpoint_pos, setpoint_quat = tool_pos, tool_quat
        obs = {
            "q": self._qpos[:, t._qa],
            "qd": self._qvel[:, t._da],
            "tool_pos": tool_pos,
            "tool_quat": tool_quat,
            "tool_vel": velocity,
            "tool_angvel": omega,
            "wrench": self.sensor.reading,
            "f_ref": self._f_ref[:, None],
            "tool_pos_ref": self._pos_ref[rows, kk],
            "tool_vel_ref": self._vel_ref[rows, kk],
            "setpoint_pos": setpoint_pos,
            "setpoint_quat": setpoint_quat,
        }
        return {key: CLIP(v, *t.observation_bounds[key]) for key, v in obs.items()}

    def _episode_end(
        self, i: int, infos: dict[str, Any], terminated: bool, truncated: bool
    ) -> dict[str, Any]:
        t = self.template
        self._load_template(i)  # its histories, f̄ and steps played: its own metrics score it
        first = int(self._first_contact[i])
        t._first_contact = None if first < 0 else first
        t._stopped_at = t._k if terminated else None
        metrics = t.episode_metrics()
        return {
            **self._row_info(infos, i),
            "episode_metrics": metrics,
            "is_success": t.succeeded(metrics, terminated),
        }


def _stopped_at(qpos: np.ndarray, qvel: np.ndarray) -> int:
    """The step (0-based) of a rollout's records (steps, nq) and (steps, nv) at which MuJoCo
    stopped the simulation for an instability warning: the first record the next ones
    repeat (the last step if none does)."""
    same = np.all(qpos[1:] == qpos[:-1], axis=1) & np.all(qvel[1:] == qvel[:-1], axis=1)
    return int(same.argmax()) if same.any() else len(qpos) - 1
