"""Native batched AdmittanceContact on ``mujoco.batch.Batch``: ``num_envs`` copies of
``cir_gym/AdmittanceContact-v2`` in one vector env.

>>> import cir_gym
>>> envs = cir_gym.make_vec("cir_gym/AdmittanceContact-v2", num_envs=32)   # doctest: +SKIP
>>> obs, infos = envs.reset(seed=0)          # copy i is AdmittanceContact reset(seed=i)
>>> obs, rew, term, trunc, infos = envs.step(envs.action_space.sample())

What is batched and how (the single env's ``step`` is the specification; each copy equals it
to the tolerance tests/test_vector_admittance.py states):

* **Physics.** The torque interface holds τ = a ⊙ τ_max over a control period: one
  ``Batch.step(nstep=substeps)`` for all copies (:meth:`BatchedTaskEnv._simulate`: per-copy
  divergence and restore); the position interface's torque law
  (:class:`~cir_gym.motion_interface.CartesianMotionInterface` on (N, 7) arrays) runs at
  every physics step, one ``Batch.step`` each. The contact forces are MuJoCo contact sensors
  (the scene's ``tool_contact``: the tool-plate net force; ``peak_contact``: the largest
  single contact on the plate) whose every physics step MuJoCo keeps in its sensor history
  (``Batch.bind("history")``, read by
  :class:`~cir_gym.envs.admittance_scene.PeriodRecord`): the period's record (N, substeps,
  nsensordata) feeds the batched wrist-sensor model (:class:`~cir_gym.ft_sensor.WrenchSensor`
  with ``num_envs``) and :func:`~cir_gym.envs.admittance_task.period_forces`, as the single
  env feeds its own. After the period ``Batch.forward`` (to the velocity stage) makes the
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
from cir_gym.envs.vector_base import BatchedTaskEnv
from cir_gym.ft_sensor import WrenchSensor
from cir_gym.motion_interface import CartesianMotionInterface
from cir_gym.numeric import CLIP

__all__ = ["AdmittanceContactVectorEnv"]


def cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """u × v of rows (N, 3) (np.cross's values, without its generic machinery)."""
    return np.stack((
        u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1],
        u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
        u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0],
    ), axis=1)


_VELOCITY_STAGE = int(mujoco.mjtStage.mjSTAGE_VEL)
#: the per-copy model fields an episode's surface sets (AdmittanceContactEnv.reset)
_SURFACE_FIELDS = ("jnt_stiffness", "dof_damping", "body_pos", "body_quat")


class AdmittanceContactVectorEnv(BatchedTaskEnv):
    """``num_envs`` copies of ``cir_gym/AdmittanceContact-v2`` on one ``mujoco.batch.Batch``
    (see the module docstring).

    Args:
        num_envs: number of copies (≥ 1).
        nthread: MuJoCo threads (0: all CPUs).
        **kwargs: the single env's arguments, except ``render_mode``.
    """

    env_class: ClassVar[type[AdmittanceContactEnv]] = AdmittanceContactEnv
    env_id: ClassVar[str] = "cir_gym/AdmittanceContact-v2"
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
        self._xquat = self.batch.bind("xquat")
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
        self._history = self.batch.bind("history")  # MuJoCo's sensor history of every copy
        self.period_record = scene.PeriodRecord(m)
        self._record = np.zeros((N, n, m.nsensordata))  # the period's sensordata, step by step
        self._held_q = np.zeros((N, m.nq))  # where a copy diverged mid-period is held
        self._held_qd = np.zeros((N, m.nv))
        self._first_contact = np.full(N, -1)  # the step of the first contact; -1: none yet

    def _start_episode(self, i: int) -> None:
        t = self.template
        for name, rows in self._model_rows.items():
            rows[i] = getattr(t.model, name)
        self.sensor.load_row(i, t.sensor)
        if self.interface is not None:
            self.interface.reset(START_Q, rows=[i])
        self._first_contact[i] = -1

    # ------------------------------------------------------------------ step
    def _advance(self, a: np.ndarray) -> np.ndarray:
        """One control period of every copy (AdmittanceContactEnv._advance on the rows); return
        the (N,) copies that diverged.

        The torque interface holds τ = a ⊙ τ_max: one ``_simulate`` (``Batch.step``) of
        ``substeps`` physics steps; the position interface's torque law runs at every physics
        step, one ``_simulate`` each, and a copy that diverged at one of them is held where
        ``_simulate`` put it back for the rest of the period, as the single env stops there.
        Then ``_record`` is the period's sensordata, step by step, from MuJoCo's sensor
        history (:class:`~cir_gym.envs.admittance_scene.PeriodRecord`; 0 for a diverged
        copy, whose period is not played), the wrist sensors of the copies that did not
        diverge take their wrenches, and ``Batch.forward`` makes the poses and velocities of
        the reached state current."""
        t, n = self.template, self.template.substeps
        q, qd = self._qpos, self._qvel
        if self.interface is None:
            diverged = self._simulate(a * t.torque_limit)
        else:
            diverged = np.zeros(self.num_envs, dtype=bool)
            for i in range(n):
                tau = self.interface.torque(q[:, t._qa], qd[:, t._da], (i + 1) / n)
                new = self._simulate(np.clip(tau, -t.torque_limit, t.torque_limit), 1)
                new &= ~diverged
                if new.any():
                    self._held_q[new], self._held_qd[new] = q[new], qd[new]
                    diverged |= new
            if diverged.any():
                q[diverged], qd[diverged] = self._held_q[diverged], self._held_qd[diverged]
        self._record = self.period_record(self._history)
        self._record[diverged] = 0.0
        wrenches = self._record[:, :, t._wrench_at]
        if diverged.any():
            self.sensor.advance_many(wrenches[~diverged], rows=~diverged)
        else:
            self.sensor.advance_many(wrenches)
        self.batch.forward(stage=_VELOCITY_STAGE)  # poses and velocities of the reached state
        return diverged

    def _task_step(
        self, a: np.ndarray, peak: np.ndarray, k: np.ndarray
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, dict[str, Any]]:
        t, rows = self.template, self._rows
        if self.interface is not None:
            self.interface.command(a * t.increment_scale, t.dt)
        diverged = self._advance(a)
        tool, peak_steps = period_forces(self._record, self._normal, t._tool_at, t._peak_at)
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
        tool_quat = scene.positive_w(self._xquat[:, t._tool_body])
        # the tcp's velocity (mj_objectVelocity, world frame): the body's spatial velocity
        # [ω; v] about its subtree's centre of mass, moved to the site: v + ω × (p − c)
        cvel = self._cvel[:, self._site_body]
        omega = cvel[:, :3]
        lever = tool_pos - self._subtree_com[:, self._site_root]
        velocity = cvel[:, 3:] + cross(omega, lever)
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

