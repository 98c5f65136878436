"""Native batched joint tracking on ``mujoco.batch.Batch``: one C thread pool, no env per process.

>>> import cir_gym, gymnasium as gym
>>> envs = cir_gym.make_vec("cir_gym/JointTracking-v2", num_envs=64)    # doctest: +SKIP
>>> envs = gym.make_vec("cir_gym/JointTracking-v2", num_envs=64,
...                     vectorization_mode="vector_entry_point")        # doctest: +SKIP
>>> obs, infos = envs.reset(seed=0)                # env i is JointTracking reset(seed=i)
>>> obs, rew, term, trunc, infos = envs.step(envs.action_space.sample())

Native batched envs (``VECTOR_ENVS``): ``cir_gym/JointTracking-v2``
(:class:`JointTrackingVectorEnv`) and ``cir_gym/ElasticJointTracking-v3``
(:class:`ElasticJointTrackingVectorEnv`: the same step on the elastic model, plus the motor
keys of the observation). Both ids have a ``vector_entry_point`` (:func:`vector_entry_point`),
so ``gymnasium.make_vec`` builds them by default. Every other id, and these two with an
unsupported argument (below), get :func:`make_vec`'s fallback: Gymnasium's ``SyncVectorEnv``
of the single env with the same autoreset mode (``SAME_STEP``) and seeding, so code written
for one works on the other. The other torque envs (CartesianTracking, AdmittanceContact,
PegInHole) have task steps of their own (operational-space errors, contact forces) that are
not written in array form here: they use the fallback.

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

Supported: the default sensing and actuation (no ``drive``, ``torque_noise``,
``encoder_resolution``; no per-episode ``randomize``: the classes raise InvalidArgument,
:func:`make_vec` falls back to ``SyncVectorEnv``); every other argument (reference, episode
length, payload, friction, reward weights, stiffness...) as in the single env.

Autoreset is Gymnasium's ``SAME_STEP`` mode: a finished copy is reset in the same ``step``; its
last observation and info are in ``infos["final_obs"]`` / ``infos["final_info"]`` (masks
``"_final_obs"``, ``"_final_info"``). Copy ``i`` of ``reset(seed=s)`` is the single env after
``reset(seed=s + i)``, and its later episodes those of ``reset()`` (the same generator).
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import mujoco.batch
import numpy as np
from gymnasium.vector.utils import batch_space

from cir_gym.envs.base import (
    _UNSTABLE_WARNINGS as _UNSTABLE,  # MuJoCo's instability warnings, as RobotEnv counts them
)
from cir_gym.envs.base import MAX_JOINT_SPEED, check_kwargs
from cir_gym.envs.elastic_joint_tracking import ElasticJointTrackingEnv
from cir_gym.envs.joint_tracking import JointTrackingEnv, held_error
from cir_gym.envs.tracking_reward import TERMS, squared_norm
from cir_gym.validation import InvalidArgument, check_number

__all__ = [
    "VECTOR_ENVS",
    "ElasticJointTrackingVectorEnv",
    "JointTrackingVectorEnv",
    "make_vec",
    "native_vector_env",
    "sb3_vec_env",
    "vector_entry_point",
]

_INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
_WARNINGS: slice | list[int] = (
    slice(_UNSTABLE[0], _UNSTABLE[-1] + 1)
    if _UNSTABLE[-1] - _UNSTABLE[0] + 1 == len(_UNSTABLE)
    else list(_UNSTABLE)
)
_UNSUPPORTED = {"drive": None, "torque_noise": 0.0, "encoder_resolution": 0.0, "randomize": False}


class JointTrackingVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` copies of ``cir_gym/JointTracking-v2`` stepped by one ``mujoco.batch.Batch``.

    Args:
        num_envs: number of copies (≥ 1).
        nthread: MuJoCo threads (0: all CPUs).
        **kwargs: the single env's arguments (see ``env_class``), except ``drive``,
            ``torque_noise``, ``encoder_resolution``, ``randomize`` and ``render_mode``.

    Raises:
        InvalidArgument: ``num_envs`` < 1, an unsupported argument, or one the single env
            rejects.
    """

    metadata: ClassVar[dict[str, Any]] = {"autoreset_mode": gym.vector.AutoresetMode.SAME_STEP}
    #: the single env whose step this class batches (its ``step`` is the specification)
    env_class: ClassVar[type[JointTrackingEnv]] = JointTrackingEnv
    env_id: ClassVar[str] = "cir_gym/JointTracking-v2"

    @classmethod
    def unsupported(cls, kwargs: dict[str, Any]) -> str | None:
        """Why ``kwargs`` cannot be batched here (the first unsupported argument), or None."""
        for name, default in _UNSUPPORTED.items():
            if name in kwargs and kwargs[name] != default:
                return f"{name}={kwargs[name]!r} (supported: {name}={default!r} only)"
        if kwargs.get("render_mode") is not None:
            return f"render_mode={kwargs['render_mode']!r} (the batched env does not render)"
        return None

    def __init__(self, num_envs: int = 64, nthread: int = 0, **kwargs: Any) -> None:
        num_envs = int(check_number("num_envs", num_envs, 1, 1e6))
        nthread = int(check_number("nthread", nthread, 0, 1024))
        reason = self.unsupported(kwargs)
        if reason is not None:
            raise InvalidArgument(
                f"{type(self).__name__} cannot batch {reason}; cir_gym.make_vec("
                f"{self.env_id!r}, ...) falls back to a SyncVectorEnv of the single env"
            )
        check_kwargs(self.env_class, kwargs)  # an unknown argument: named, as gymnasium.make
        self.template = self.env_class(**kwargs)  # validates every other argument
        t = self.template
        self.num_envs = num_envs
        self.single_observation_space = t.observation_space
        self.single_action_space = t.action_space
        self.observation_space = batch_space(t.observation_space, num_envs)
        self.action_space = batch_space(t.action_space, num_envs)
        self.metadata = {**self.metadata, "render_fps": t.metadata["render_fps"]}
        self.spec = None
        self.render_mode = None

        self.batch = mujoco.batch.Batch(t.model, nsim=num_envs, nthread=nthread)
        self._qpos = self.batch.bind("qpos")
        self._qvel = self.batch.bind("qvel")
        self._ctrl = self.batch.bind("ctrl")
        self._no_divergence = np.zeros(num_envs, dtype=bool)
        self._state_row = np.zeros(mujoco.mj_stateSize(t.model, _INTEGRATION))

        N, n, steps = num_envs, t.n, t.max_steps
        # an own generator per copy (unseeded until reset(seed=...))
        self._rngs = [gym.utils.seeding.np_random()[0] for _ in range(N)]
        self._ref = np.zeros((N, 3, steps + 1, n))
        self._err = np.zeros((N, steps, n))
        self._tau = np.zeros((N, steps, n))
        self._sat = np.zeros((N, steps), dtype=bool)
        self._k = np.zeros(N, dtype=np.int64)
        self._k_scored = np.zeros(N, dtype=np.int64)
        self._limit = np.zeros(N)
        self._judged_from = np.zeros(N, dtype=np.int64)
        self._a_prev = np.zeros((N, n))
        self._safe_q = np.zeros((N, t.model.nq))
        self._safe_qd = np.zeros((N, t.model.nv))
        self._rows = np.arange(N)
        self._bounds = {k: t._obs_bounds[k] for k in t.observation_space.spaces}

    # ------------------------------------------------------------------ resets
    def _reset_copy(self, i: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Reset copy ``i`` with the template and its generator; write its state into row i."""
        t = self.template
        t._np_random = self._rngs[i]
        obs, info = t.reset()
        self.batch.reset(ids=[i], stage=int(mujoco.mjtStage.mjSTAGE_NONE))
        mujoco.mj_getState(t.model, t.data, self._state_row, _INTEGRATION)
        self.batch.state[i] = self._state_row
        self._safe_q[i] = t.data.qpos
        self._safe_qd[i] = t.data.qvel
        self._ref[i] = t._ref
        self._limit[i] = t._following_error_limit
        self._judged_from[i] = t._judged_from
        self._k[i] = 0
        self._k_scored[i] = 0
        self._a_prev[i] = 0.0
        return obs, info

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed if isinstance(seed, int) else None)
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be an int or {self.num_envs} seeds, got {seed!r}")
        for i, s in enumerate(seeds):
            if s is not None:
                self._rngs[i], _ = gym.utils.seeding.np_random(s)
        obs_list, infos = [], {}
        for i in range(self.num_envs):
            obs, info = self._reset_copy(i)
            obs_list.append(obs)
            infos = self._add_info(infos, info, i)
        return {k: np.stack([o[k] for o in obs_list]) for k in self._bounds}, infos

    # ------------------------------------------------------------------ step
    def _check_actions(self, actions: Any) -> tuple[np.ndarray, np.ndarray]:
        """(actions clipped to [-1, 1] as float64 (N, m), max |action| of each row (N,))."""
        shape = self.action_space.shape
        try:
            raw = np.asarray(actions)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"actions must be a numeric array of shape {shape}") from exc
        if raw.dtype.kind not in "biuf" or raw.shape != shape:
            raise ValueError(
                f"actions must be a numeric array of shape {shape} with values in [-1, 1], "
                f"got shape {raw.shape} dtype {raw.dtype}"
            )
        a = raw.astype(np.float64)
        mag = np.max(np.abs(a), axis=1)  # NaN propagates, inf stays: one reduction checks both
        if not np.all(np.isfinite(mag)):
            bad = np.flatnonzero(~np.isfinite(mag))
            raise ValueError(f"actions of envs {bad.tolist()} contain NaN or inf")
        if np.any(mag > 1.0):
            np.clip(a, -1.0, 1.0, out=a)
        return a, mag

    def _warning_counts(self) -> np.ndarray:
        """MuJoCo's instability-warning counters of every copy (N, 4): a view of the batch's
        while the four are neighbours in mjtWarning (as in MuJoCo 4), else a copy."""
        return self.batch.warning[:, _WARNINGS, 1]

    def _diverged(self, warnings_before: np.ndarray) -> np.ndarray:
        """(N,) bool: a new MuJoCo instability warning, a non-finite q or q̇, or |q̇| above
        MAX_JOINT_SPEED, per copy, as RobotEnv._simulate judges one env. Two whole-batch
        reductions decide; the per-row checks run only when they flag something."""
        q, qd = self._qpos, self._qvel
        new_warning = self._warning_counts() != warnings_before  # the counters only grow
        if (
            not new_warning.any()
            and np.max(np.abs(qd)) <= MAX_JOINT_SPEED
            and np.isfinite(np.sum(q))
        ):  # NaN fails the comparison and the finite sum
            return self._no_divergence
        with np.errstate(all="ignore"):
            return (
                np.any(new_warning, axis=1)
                | ~np.all(np.isfinite(q), axis=1)
                | ~np.all(np.isfinite(qd), axis=1)
                | (np.max(np.abs(qd), axis=1) > MAX_JOINT_SPEED)
            )

    def step(
        self, actions: Any
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        t = self.template
        a, mag = self._check_actions(actions)
        if np.any(self._k >= t.max_steps):
            raise RuntimeError("step() on a finished copy; the vector env resets them itself")
        q, qd = self._qpos, self._qvel
        # the last finite state, restored on divergence (a finite sum: every row is finite)
        if np.isfinite(np.sum(q)) and np.isfinite(np.sum(qd)):
            self._safe_q[:] = q
            self._safe_qd[:] = qd
        else:
            finite = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(qd), axis=1)
            self._safe_q[finite] = q[finite]
            self._safe_qd[finite] = qd[finite]
        warnings_before = self._warning_counts().copy()
        tau = a * t.torque_limit
        self._ctrl[:] = tau
        self.batch.step(nstep=t.frame_skip)
        diverged = self._diverged(warnings_before)
        if np.any(diverged):  # the last finite state, as RobotEnv._simulate restores it
            q[diverged] = self._safe_q[diverged]
            qd[diverged] = self._safe_qd[diverged]
        qa, da = t._qa, t._da
        qj, qdj = q[:, qa], qd[:, da]
        rows, k = self._rows, self._k.copy()
        self._k += 1
        k1 = self._k
        q_err = self._ref[rows, 0, k1] - qj
        self._err[rows, k] = q_err
        self._tau[rows, k] = tau
        self._sat[rows, k] = mag >= 1.0  # clipped or at the limit, as the single env

        err_sq = squared_norm(q_err)
        joint_error = np.sqrt(err_sq)
        stopped = (
            ~diverged & (joint_error > self._limit)
            if t.max_following_error is not None
            else np.zeros_like(diverged)
        )
        terms = t.reward_model(err_sq, a, self._a_prev, diverged, stopped, t.max_steps - k1)
        reward = sum(terms[name] for name in TERMS)  # the single env's order of the terms
        self._a_prev[:] = a
        terminated = diverged | stopped
        truncated = (k1 >= t.max_steps) & ~terminated
        kk = np.minimum(k1, t.max_steps)
        raw_obs = {
            "q": qj,
            "qd": qdj,
            "q_ref": self._ref[rows, 0, kk],
            "qd_ref": self._ref[rows, 1, kk],
            "qdd_ref": self._ref[rows, 2, kk],
            **self._extra_obs(q, qd),
        }
        obs = {key: np.clip(v, -self._bounds[key], self._bounds[key]) for key, v in raw_obs.items()}
        terms["joint_error"] = joint_error
        ones = np.ones(self.num_envs, dtype=bool)
        infos: dict[str, Any] = {}
        for key, value in (
            *terms.items(),
            ("following_error_exceeded", stopped),
            ("diverged", diverged),
        ):
            infos[key] = value
            infos["_" + key] = ones
        for i in np.flatnonzero(terminated | truncated):
            i = int(i)
            infos = self._finish_copy(
                i,
                obs,
                infos,
                bool(diverged[i]),
                bool(stopped[i]),
                q_err[i],
                {key: float(v[i]) for key, v in terms.items()},
            )
        return obs, reward, terminated, truncated, infos

    def _extra_obs(self, q: np.ndarray, qd: np.ndarray) -> dict[str, np.ndarray]:
        """Observation keys beyond JointTracking's, from the batch's qpos (N, nq) and qvel
        (N, nv) (none here)."""
        return {}

    def _finish_copy(
        self,
        i: int,
        obs: dict[str, np.ndarray],
        infos: dict[str, Any],
        diverged: bool,
        stopped: bool,
        q_err: np.ndarray,
        terms: dict[str, float],
    ) -> dict[str, Any]:
        """Episode end of copy ``i``: metrics and success as the single env, then its reset."""
        t = self.template
        if stopped or diverged:  # scored over the whole horizon, as the single env
            self._err[i, self._k[i] :] = held_error(q_err, self._limit[i]) if diverged else q_err
            self._k_scored[i] = t.max_steps
        t._err[:] = self._err[i]
        t._tau[:] = self._tau[i]
        t._sat[:] = self._sat[i]
        t._k, t._k_scored = int(self._k[i]), int(self._k_scored[i])
        t._judged_from = int(self._judged_from[i])
        final_info = {
            **terms,
            "following_error_exceeded": stopped,
            "diverged": diverged,
            "episode_metrics": t.episode_metrics(),
            "is_success": not diverged and not stopped and t._settled(),
        }
        final_obs = {key: v[i].copy() for key, v in obs.items()}
        new_obs, reset_info = self._reset_copy(i)
        for key in obs:
            obs[key][i] = new_obs[key]
        infos = self._add_info(infos, {"final_obs": final_obs, "final_info": final_info}, i)
        return self._add_info(infos, reset_info, i)

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()


class ElasticJointTrackingVectorEnv(JointTrackingVectorEnv):
    """``num_envs`` copies of ``cir_gym/ElasticJointTracking-v3`` on one ``mujoco.batch.Batch``.

    ElasticJointTracking inherits JointTracking's ``step`` (actuators on the motor hinges,
    0.5-ms physics: ``frame_skip`` 4, ``charge_unplayed_steps`` on by default); its observation
    adds the motor positions and velocities ``q_motor``, ``qd_motor`` (7,) (rad and rad/s, link
    units), read here from the batch's rows as the single env reads them. Arguments and
    limits as :class:`JointTrackingVectorEnv` (``stiffness``, ``stiffness_scale`` supported).
    """

    env_class: ClassVar[type[JointTrackingEnv]] = ElasticJointTrackingEnv
    env_id: ClassVar[str] = "cir_gym/ElasticJointTracking-v3"

    def _extra_obs(self, q: np.ndarray, qd: np.ndarray) -> dict[str, np.ndarray]:
        t = self.template
        return {"q_motor": q[:, t._ma], "qd_motor": qd[:, t._md]}


#: env id → its native batched class
VECTOR_ENVS: dict[str, type[JointTrackingVectorEnv]] = {
    cls.env_id: cls for cls in (JointTrackingVectorEnv, ElasticJointTrackingVectorEnv)
}


def _env_key(env_id: str) -> str:
    """``"cir_gym:cir_gym/X-v1"`` → ``"cir_gym/X-v1"`` (the module prefix gym.make accepts)."""
    return env_id.split(":")[-1]


def native_vector_env(
    env_id: str, env_kwargs: dict[str, Any]
) -> type[JointTrackingVectorEnv] | None:
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
        A :class:`JointTrackingVectorEnv` / :class:`ElasticJointTrackingVectorEnv` when
        ``VECTOR_ENVS`` has ``env_id`` and it batches ``kwargs``; otherwise Gymnasium's
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


def vector_entry_point(env_id: str, num_envs: int = 1, **kwargs: Any) -> JointTrackingVectorEnv:
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
    assert isinstance(venv, JointTrackingVectorEnv)
    return venv


def sb3_vec_env(venv: JointTrackingVectorEnv) -> Any:
    """``venv`` as a Stable-Baselines3 ``VecEnv`` (imports SB3 only when called).

    Episode ends follow SB3's conventions: ``dones = terminated | truncated``, the last
    observation in ``infos[i]["terminal_observation"]``, ``infos[i]["TimeLimit.truncated"]``;
    ``is_success`` and ``episode_metrics`` of the finished episode are in ``infos[i]`` too.
    ``seed(s)`` makes the next ``reset()`` seed copy i with s + i, as the vector env does.
    """
    return _sb3_class()(venv)


def _sb3_class() -> type:
    from stable_baselines3.common.vec_env import VecEnv

    class JointTrackingSB3VecEnv(VecEnv):
        """SB3 ``VecEnv`` over a :class:`JointTrackingVectorEnv` (see :func:`sb3_vec_env`)."""

        def __init__(self, venv: JointTrackingVectorEnv) -> None:
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
            raise NotImplementedError("the copies of a JointTrackingVectorEnv share one template")

        def env_method(
            self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any
        ) -> list[Any]:
            raise NotImplementedError("the copies of a JointTrackingVectorEnv are array rows")

        def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
            return [False] * len(self._get_indices(indices))

    return JointTrackingSB3VecEnv
