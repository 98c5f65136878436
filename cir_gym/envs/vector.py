"""Native batched envs on ``mujoco.batch.Batch`` (one C thread pool, no env per process): the
registry, :func:`make_vec`, the SB3 adapter, and joint tracking's batched envs.

>>> import cir_gym, gymnasium as gym
>>> envs = cir_gym.make_vec("cir_gym/JointTracking-v2", num_envs=64)    # doctest: +SKIP
>>> envs = gym.make_vec("cir_gym/JointTracking-v2", num_envs=64,
...                     vectorization_mode="vector_entry_point")        # doctest: +SKIP
>>> obs, infos = envs.reset(seed=0)                # env i is JointTracking reset(seed=i)
>>> obs, rew, term, trunc, infos = envs.step(envs.action_space.sample())

Native batched envs (``VECTOR_ENVS``, id → class, filled from
``cir_gym.envs.BATCHED_ENVIRONMENTS``'s ``"module:Class"`` table and imported on first
lookup): here ``cir_gym/JointTracking-v2`` (:class:`JointTrackingVectorEnv`) and
``cir_gym/ElasticJointTracking-v3`` (:class:`ElasticJointTrackingVectorEnv`: the same step on
the elastic model, plus the motor keys of the observation); the other tasks' classes live in
their own modules, each a :class:`~cir_gym.envs.vector_base.BatchedTaskEnv` (the shared
plumbing: resets, seeding, autoreset, physics and divergence; its docstring is the contract a
new class implements). Every id of the table has a ``vector_entry_point``
(:func:`vector_entry_point`), so ``gymnasium.make_vec`` builds them by default. Every other id,
and these with an unsupported argument (below), get :func:`make_vec`'s fallback: Gymnasium's
``SyncVectorEnv`` of the single env with the same autoreset mode (``SAME_STEP``) and seeding,
so code written for one works on the other.

What is batched and what is not:

* the physics of all ``num_envs`` copies is one ``Batch.step(nstep=frame_skip)`` call (MuJoCo's
  threads; the same computation as ``mj_step`` on one MjData per copy);
* the task's step (action check, torques, divergence check, tracking error, following-error
  stop, observation) is the single env's arithmetic on ``(num_envs, n)`` arrays
  (``JointTrackingEnv.step`` is the specification; the test compares the two env by env); the
  reward is the single env's own function (:class:`~cir_gym.envs.tracking_reward.TrackingReward`,
  batched over the copies);
* resets are the single env's own: one ``JointTrackingEnv`` (the template) draws each copy's
  reference and initial state with that copy's random generator, and its MjData's integration
  state is written into the copy's row; episode metrics are the template's ``episode_metrics``
  on the copy's history.

Supported: every argument (reference, episode length, payload, friction, reward weights,
stiffness, the sensing and actuation: ``drive``, ``torque_noise``, ``encoder_resolution``) as in
the single env, except a per-episode ``randomize`` (each copy would need its own model: the
classes raise InvalidArgument, :func:`make_vec` falls back to ``SyncVectorEnv``). A ``drive``
is one :class:`cir_gym.drives.DriveState` over the copies' rows (the single env's, with a row
axis; a reset copy takes the template's); ``torque_noise`` is drawn from each copy's own
generator, as the single env draws it from its ``np_random``.

Autoreset is Gymnasium's ``SAME_STEP`` mode: a finished copy is reset in the same ``step``; its
last observation and info are in ``infos["final_obs"]`` / ``infos["final_info"]`` (masks
``"_final_obs"``, ``"_final_info"``). Copy ``i`` of ``reset(seed=s)`` is the single env after
``reset(seed=s + i)``, and its later episodes those of ``reset()`` (the same generator).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from importlib import import_module
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from cir_gym.drives import DriveState
from cir_gym.envs import BATCHED_ENVIRONMENTS
from cir_gym.envs.elastic_joint_tracking import ElasticJointTrackingEnv
from cir_gym.envs.joint_tracking import JointTrackingEnv, held_error
from cir_gym.envs.tracking_reward import TERMS, squared_norm
from cir_gym.envs.vector_base import BatchedTaskEnv, TaskStep
from cir_gym.validation import InvalidArgument, check_number

__all__ = [
    "VECTOR_ENVS",
    "BatchedTaskEnv",
    "ElasticJointTrackingVectorEnv",
    "JointTrackingVectorEnv",
    "make_vec",
    "native_vector_env",
    "sb3_vec_env",
    "vector_entry_point",
]


class JointTrackingVectorEnv(BatchedTaskEnv):
    """``num_envs`` copies of ``cir_gym/JointTracking-v2`` stepped by one ``mujoco.batch.Batch``.

    Args:
        num_envs: number of copies (≥ 1).
        nthread: MuJoCo threads (0: all CPUs).
        **kwargs: the single env's arguments (see ``env_class``), except ``randomize`` and
            ``render_mode``.

    Raises:
        InvalidArgument: ``num_envs`` < 1, an unsupported argument, or one the single env
            rejects.
    """

    env_class: ClassVar[type[JointTrackingEnv]] = JointTrackingEnv
    env_id: ClassVar[str] = "cir_gym/JointTracking-v2"
    fixed_arguments: ClassVar[dict[str, Any]] = {"randomize": False}
    template: JointTrackingEnv
    episode_state: ClassVar[tuple[str, ...]] = (
        "_ref",  # q̄, q̄̇, q̄̈ (3, T + 1, n) at every control instant
        "_following_error_limit",  # ‖q̃‖ that stops the episode (rad)
        "_judged_from",  # first step judged for success
        "_a_prev",  # the previous action (n,)
        "_k_scored",  # steps the metrics cover
    )
    episode_history: ClassVar[tuple[str, ...]] = (
        "_err",  # q̃ (T, n) rad
        "_tau",  # commanded torque (T, n) N m
        "_sat",  # (T,) bool: a clipped or saturated joint
    )

    def _allocate(self) -> None:
        t = self.template
        self._q_err = np.zeros((self.num_envs, t.n))  # q̃ = q̄ − q of the last step
        self._bounds = {k: t._obs_bounds[k] for k in t.observation_space.spaces}
        # the joints' drives (N, n): the template's DriveState with a row per copy
        self._drive = None if t.drive is None else DriveState(t.drive, t.n, rows=self.num_envs)

    def _start_episode(self, i: int) -> None:
        if self._drive is not None:  # the template's drive after its reset (and first reading)
            self._drive.load_row(i, self.template._drive_state)

    def _motor_angle(self, q: np.ndarray) -> np.ndarray:
        """Motor positions in link units θ (N, n) from the batch's qpos (N, nq) (the joints
        here), the torque ripple's angle."""
        return q[:, self.template._qa]

    def _applied_torque(self, tau: np.ndarray) -> np.ndarray:
        """The torque (N, n) the drives apply for the commanded τ (N, n) (N m), as the single
        env's step: one period late with the ripple of the present motor angle (a ``drive``),
        plus ``torque_noise`` · 𝒩(0, 1) from each copy's generator."""
        t = self.template
        if self._drive is not None:
            tau = self._drive.actuate(tau)
            tau = t.drive.ripple(tau, self._motor_angle(self._qpos), t.gear_ratio)
        if t.torque_noise > 0:
            noise = np.stack([rng.standard_normal(t.n) for rng in self._rngs])
            tau = tau + t.torque_noise * noise
        return tau

    def _measured(
        self, q: np.ndarray, qd: np.ndarray, q_meas_prev: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The observation's q, q̇ (N, n) from the joints' q, q̇ (N, n) after a step: the
        drive's encoder and difference, or the ``encoder_resolution`` quantum's reading and its
        difference from the reading before the step ``q_meas_prev``, or exact."""
        t = self.template
        if self._drive is not None:
            return self._drive.measure(q, qd, t.dt)
        if q_meas_prev is not None:
            q_meas = t._quantize(q)
            return q_meas, (q_meas - q_meas_prev) / t.dt
        return q, qd

    def _task_step(self, a: np.ndarray, peak: np.ndarray, k: np.ndarray) -> TaskStep:
        t = self.template
        tau = a * t.torque_limit  # commanded: the metrics' τ (drive and noise act on it)
        applied = self._applied_torque(tau)
        q, qd = self._qpos, self._qvel
        # the encoder's reading before the step, for q̇ by differences
        q_meas_prev = t._quantize(q[:, t._qa]) if t.encoder_resolution > 0 else None
        diverged = self._simulate(applied)
        qj, qdj = q[:, t._qa], qd[:, t._da]
        q_meas, qd_meas = self._measured(qj, qdj, q_meas_prev)
        rows, k1 = self._rows, self._k
        q_err = self._ref[rows, 0, k1] - qj
        self._err[rows, k] = q_err
        self._tau[rows, k] = tau
        self._sat[rows, k] = peak >= 1.0  # clipped or at the limit, as the single env

        err_sq = squared_norm(q_err)
        joint_error = np.sqrt(err_sq)
        stopped = (
            ~diverged & (joint_error > self._following_error_limit)
            if t.max_following_error is not None
            else np.zeros_like(diverged)
        )
        terms = t.reward_model(err_sq, a, self._a_prev, diverged, stopped, t.max_steps - k1)
        reward = sum(terms[name] for name in TERMS)  # the single env's order of the terms
        self._a_prev[:] = a
        kk = np.minimum(k1, t.max_steps)
        raw_obs = {
            "q": q_meas,
            "qd": qd_meas,
            "q_ref": self._ref[rows, 0, kk],
            "qd_ref": self._ref[rows, 1, kk],
            "qdd_ref": self._ref[rows, 2, kk],
            **self._extra_obs(q, qd),
        }
        obs = {key: np.clip(v, -self._bounds[key], self._bounds[key]) for key, v in raw_obs.items()}
        infos = self._step_infos(
            {
                **terms,
                "joint_error": joint_error,
                "following_error_exceeded": stopped,
                "diverged": diverged,
            }
        )
        self._q_err[:] = q_err  # held over a stopped or diverged copy's unplayed steps
        return obs, reward, diverged | stopped, infos

    def _extra_obs(self, q: np.ndarray, qd: np.ndarray) -> dict[str, np.ndarray]:
        """Observation keys beyond JointTracking's, from the batch's qpos (N, nq) and qvel
        (N, nv) (none here)."""
        return {}

    def _episode_end(
        self, i: int, infos: dict[str, Any], terminated: bool, truncated: bool
    ) -> dict[str, Any]:
        """Metrics and success of copy ``i`` as the single env scores them."""
        t = self.template
        info = self._row_info(infos, i)
        diverged, stopped = info["diverged"], info["following_error_exceeded"]
        if stopped or diverged:  # scored over the whole horizon, as the single env
            q_err, limit = self._q_err[i], self._following_error_limit[i]
            self._err[i, self._k[i] :] = held_error(q_err, limit) if diverged else q_err
            self._k_scored[i] = t.max_steps
        self._load_template(i)
        info["episode_metrics"] = t.episode_metrics()
        info["is_success"] = not terminated and t._settled()
        return info


class ElasticJointTrackingVectorEnv(JointTrackingVectorEnv):
    """``num_envs`` copies of ``cir_gym/ElasticJointTracking-v3`` on one ``mujoco.batch.Batch``.

    ElasticJointTracking inherits JointTracking's ``step`` (actuators on the motor hinges,
    0.5-ms physics: ``frame_skip`` 4, ``charge_unplayed_steps`` on by default); its observation
    adds the motor positions and velocities ``q_motor``, ``qd_motor`` (7,) (rad and rad/s, link
    units), read here from the batch's rows as the single env reads them (with a ``drive``,
    through the motor encoders' own DriveState, as the single env's). Arguments and
    limits as :class:`JointTrackingVectorEnv` (``stiffness``, ``stiffness_scale`` supported).
    """

    env_class: ClassVar[type[JointTrackingEnv]] = ElasticJointTrackingEnv
    env_id: ClassVar[str] = "cir_gym/ElasticJointTracking-v3"

    def _allocate(self) -> None:
        super()._allocate()
        t = self.template
        # the motors' encoders (a drive's second DriveState, on the motor side)
        self._motor_drive = (
            None if t.drive is None else DriveState(t.drive, t.n, rows=self.num_envs)
        )

    def _start_episode(self, i: int) -> None:
        super()._start_episode(i)
        if self._motor_drive is not None:
            self._motor_drive.load_row(i, self.template._motor_drive)

    def _motor_angle(self, q: np.ndarray) -> np.ndarray:
        return q[:, self.template._ma]

    def _extra_obs(self, q: np.ndarray, qd: np.ndarray) -> dict[str, np.ndarray]:
        t = self.template
        theta, theta_d = q[:, t._ma], qd[:, t._md]
        if self._motor_drive is not None:
            theta, theta_d = self._motor_drive.measure(theta, theta_d, t.dt)
        return {"q_motor": theta, "qd_motor": theta_d}


class _LazyClasses(Mapping[str, type[BatchedTaskEnv]]):
    """Env id → batched class, from ``cir_gym.envs.BATCHED_ENVIRONMENTS``'s ``"module:Class"``
    names: a class's module is imported when the class is first looked up, so listing the
    ids (``sorted(VECTOR_ENVS)``, ``id in VECTOR_ENVS``) imports nothing."""

    def __init__(self, table: Mapping[str, str]) -> None:
        self._table = table
        self._classes: dict[str, type[BatchedTaskEnv]] = {}

    def __getitem__(self, env_id: str) -> type[BatchedTaskEnv]:
        if env_id not in self._classes:
            module, name = self._table[env_id].split(":")
            self._classes[env_id] = getattr(import_module(module), name)
        return self._classes[env_id]

    def __iter__(self) -> Iterator[str]:
        return iter(self._table)

    def __len__(self) -> int:
        return len(self._table)


#: env id → its native batched class (imported on first lookup; the table is
#: ``cir_gym.envs.BATCHED_ENVIRONMENTS``)
VECTOR_ENVS: Mapping[str, type[BatchedTaskEnv]] = _LazyClasses(BATCHED_ENVIRONMENTS)


def _env_key(env_id: str) -> str:
    """``"cir_gym:cir_gym/X-v1"`` → ``"cir_gym/X-v1"`` (the module prefix gym.make accepts)."""
    return env_id.split(":")[-1]


def native_vector_env(
    env_id: str, env_kwargs: dict[str, Any]
) -> type[BatchedTaskEnv] | None:
    """The native batched class for ``env_id`` with ``env_kwargs``, or None when there is none
    (another id, or an argument it does not batch: see ``unsupported``)."""
    cls = VECTOR_ENVS.get(_env_key(env_id))
    if cls is None or cls.unsupported(env_kwargs) is not None:
        return None
    return cls


def make_vec(
    env_id: str,
    num_envs: int = 1,
    *,
    nthread: int = 0,
    max_episode_steps: int | None = None,
    **kwargs: Any,
) -> gym.vector.VectorEnv:
    """``num_envs`` copies of ``env_id``: natively batched where possible, else SyncVectorEnv.

    Args:
        env_id: a registered cir_gym id.
        num_envs: number of copies (≥ 1).
        nthread: MuJoCo threads of a native batched env (0: all CPUs); unused otherwise.
        max_episode_steps: as in ``gymnasium.make``. A native env truncates at its own episode
            end, so it accepts only None, -1 or at least that many steps; a smaller value
            raises InvalidArgument (use ``gymnasium.make_vec(..., vectorization_mode="sync")``
            for a TimeLimit shorter than the episode).
        **kwargs: the environment's arguments.

    Returns:
        The id's native batched env (a :class:`BatchedTaskEnv` of ``VECTOR_ENVS``) when
        there is one and it batches ``kwargs``; otherwise Gymnasium's
        ``SyncVectorEnv`` of ``gymnasium.make(env_id, ...)`` with ``SAME_STEP`` autoreset.
        Either way copy i of ``reset(seed=s)`` is the single env reset with seed s + i.
    """
    cls = native_vector_env(env_id, kwargs)
    if cls is None:
        make_kw = {} if max_episode_steps is None else {"max_episode_steps": max_episode_steps}
        num = int(check_number("num_envs", num_envs, 1, 1e6))
        spec = gym.spec(_env_key(env_id))
        return gym.vector.SyncVectorEnv(
            [lambda: gym.make(spec, **make_kw, **kwargs) for _ in range(num)],
            autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
        )
    venv = cls(num_envs=num_envs, nthread=nthread, **kwargs)
    steps = venv.template.max_steps
    if max_episode_steps is not None and max_episode_steps != -1 and max_episode_steps < steps:
        venv.close()
        raise InvalidArgument(
            f"max_episode_steps={max_episode_steps} would cut this {steps}-step episode; the "
            f"batched {env_id} truncates at its own end: pass max_episode_steps=-1 (or ≥ "
            f"{steps}), or gymnasium.make_vec(..., vectorization_mode='sync') for a TimeLimit"
        )
    return venv


def vector_entry_point(env_id: str, num_envs: int = 1, **kwargs: Any) -> BatchedTaskEnv:
    """What ``gymnasium.make_vec`` calls for an id of ``VECTOR_ENVS`` (registered by
    ``cir_gym.envs.register_envs`` as its ``vector_entry_point``): the native batched env.

    Raises:
        InvalidArgument: an argument the native env does not batch (``unsupported``): with
            ``vectorization_mode="sync"`` gymnasium builds a SyncVectorEnv instead, and
            :func:`make_vec` falls back to one by itself.
    """
    max_episode_steps = kwargs.pop("max_episode_steps", None)
    cls = VECTOR_ENVS[_env_key(env_id)]
    reason = cls.unsupported(kwargs)
    if reason is not None:
        raise InvalidArgument(
            f"{env_id}'s batched env cannot batch {reason}; use gymnasium.make_vec(..., "
            f"vectorization_mode='sync') or cir_gym.make_vec (which falls back to it)"
        )
    venv = make_vec(env_id, num_envs, max_episode_steps=max_episode_steps, **kwargs)
    assert isinstance(venv, BatchedTaskEnv)
    return venv


def sb3_vec_env(venv: BatchedTaskEnv) -> Any:
    """``venv`` as a Stable-Baselines3 ``VecEnv`` (imports SB3 only when called).

    Episode ends follow SB3's conventions: ``dones = terminated | truncated``, the last
    observation in ``infos[i]["terminal_observation"]``, ``infos[i]["TimeLimit.truncated"]``;
    ``is_success`` and ``episode_metrics`` of the finished episode are in ``infos[i]`` too.
    ``seed(s)`` makes the next ``reset()`` seed copy i with s + i, as the vector env does.
    """
    return _sb3_class()(venv)


def _sb3_class() -> type:
    from stable_baselines3.common.vec_env import VecEnv

    class BatchedSB3VecEnv(VecEnv):
        """SB3 ``VecEnv`` over a :class:`BatchedTaskEnv` (see :func:`sb3_vec_env`)."""

        def __init__(self, venv: BatchedTaskEnv) -> None:
            self.venv = venv
            self.render_mode = None
            super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
            self._actions: np.ndarray | None = None

        def reset(self) -> dict[str, np.ndarray]:
            seeds = None if all(s is None for s in self._seeds) else list(self._seeds)
            obs, _ = self.venv.reset(seed=seeds)
            self._reset_seeds()
            self._reset_options()
            return obs

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = actions

        def step_wait(self) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, list]:
            obs, rew, term, trunc, infos = self.venv.step(self._actions)
            dones = term | trunc
            out: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
            for i in np.flatnonzero(dones):
                final = infos["final_info"]
                out[i] = {
                    "terminal_observation": infos["final_obs"][i],
                    "TimeLimit.truncated": bool(trunc[i] and not term[i]),
                    "is_success": bool(final["is_success"][i]),
                    "episode_metrics": {
                        k: float(v[i]) for k, v in final["episode_metrics"].items()
                    },
                }
            return obs, rew.astype(np.float32), dones, out

        def close(self) -> None:
            self.venv.close()

        def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
            """The template env's attribute (every copy shares its arguments)."""
            return [getattr(self.venv.template, attr_name)] * len(self._get_indices(indices))

        def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
            raise NotImplementedError("the copies of a batched env share one template")

        def env_method(
            self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any
        ) -> list[Any]:
            raise NotImplementedError("the copies of a batched env are array rows")

        def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
            return [False] * len(self._get_indices(indices))

    return BatchedSB3VecEnv
