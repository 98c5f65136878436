"""Training on a native batched env (``cir_gym.envs.vector.VECTOR_ENVS``): the batched env as
an agent's VecEnv.

``vec_env: batched`` in a hyperparameter entry (``training`` section) makes :mod:`agents.train`
step all ``n_envs`` training copies on the env id's native batched env (the registry's
:func:`~cir_gym.envs.vector.native_vector_env`: every id of ``cir_gym.envs.
BATCHED_ENVIRONMENTS`` whose batched class takes the entry's ``env_kwargs``), its physics one
``mujoco.batch.Batch`` (JointTracking-v2: ~54 k env-steps per CPU second for 64 copies against
~9 k for Gymnasium's ``SyncVectorEnv`` of single envs; PPO on the agent-ready contact variants
~5x the env steps of a ``DummyVecEnv``: results/benchmarks.md, "## Vector env"). Each copy is the
single env step for step (each batched env's own test), so an agent trained here is
evaluated, shipped and loaded exactly as one trained on ``DummyVecEnv``; evaluations during
training still run the single env.

:class:`BatchedTaskObservation` is the batched counterpart of the single-env wrapper stack of
``agents.train.EnvFactory``: the observation layout (:class:`agents.observation.
ObservationLayout`, with its features), the training-only shaping of :mod:`agents.shaping`
(``reward_offset``; ``log_error_bonus`` on the error of every copy's last step: the batched
env's ``error_norms()`` where it has one (VisualServo-v1: ``info["feature_error"]``), else, on
the joint-tracking envs, ‖q̄ − q‖ read from the observation, the value ``info["joint_error"]``
holds in the single env), and the
episode statistics SB3's ``Monitor`` would report (``info["episode"]``). Under it, for a residual
agent, :class:`BatchedResidualAction` runs the base controller once per vector step on every
copy's Dict observation (the single stack's :class:`agents.residual.ResidualAction`); its
training throughput against a ``DummyVecEnv`` of single envs under ``ResidualAction`` is
measured by ``benchmarks/bench_vector.py --only residual`` (residual PPO over impedance_spiral
on PegInHoleImpedance-v0, 16 envs).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from cir_gym.agents.observation import ObservationLayout
from cir_gym.agents.residual import agent_action, base_controller, check_scale, combine
from cir_gym.agents.shaping import check_log_error_bonus, log_error_bonus
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

__all__ = ["BatchedResidualAction", "BatchedTaskObservation", "make_batched_vec_env"]


class BatchedResidualAction(VecEnvWrapper):
    """:class:`agents.residual.ResidualAction` on all copies at once: the agent's action is
    the scaled residual on the controller's, a = clip(a_ctrl + scale ⊙ a_agent, −1, 1) (N, m).

    One ``controller.predict`` per vector step on every copy's Dict observation (N rows), its
    state (N, state_size) kept across steps; a row's state is re-initialised at its episode's
    start (``episode_start``): every row after :meth:`reset`, and row i after a step whose
    ``dones[i]`` (the batched env has then already reset copy i, SAME_STEP autoreset: its
    observation is the new episode's first), as the single wrapper after ``reset()``. A course
    controller gives each row the action it gives that observation alone (``baselines.RowLaw``;
    the others run row by row), so copy i is the single env under ``ResidualAction``.

    Args:
        venv: an SB3 VecEnv with Dict observations (``cir_gym.envs.vector.sb3_vec_env``).
        controller: an object with SB3's ``predict`` (e.g. :func:`agents.residual.
            base_controller` of the batched env's template).
        scale: residual range per action dimension (scalar or (m,)).

    ``infos[i]["controller_action"]`` (m,) and ``infos[i]["residual_action"]`` (m,) hold copy
    i's a_ctrl and scale ⊙ a_agent of the step, as the single wrapper's info.
    """

    def __init__(self, venv: VecEnv, controller: Any, scale: Any) -> None:
        super().__init__(venv)
        if not hasattr(controller, "predict"):
            raise TypeError(f"controller must have SB3's predict(), got {controller!r}")
        self.controller = controller
        self.scale = check_scale(scale, venv.action_space)
        self._obs: dict[str, np.ndarray] | None = None
        self._state: Any = None
        self._starts = np.ones(self.num_envs, dtype=bool)
        self._a_ctrl = np.zeros((self.num_envs, *self.scale.shape))
        self._residual = np.zeros_like(self._a_ctrl)

    def reset(self) -> dict[str, np.ndarray]:
        self._obs = self.venv.reset()
        self._state = None
        self._starts[:] = True
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        if self._obs is None:
            raise RuntimeError("call reset() before step()")
        a_agent = agent_action(actions, self._a_ctrl.shape)
        a_ctrl, self._state = self.controller.predict(
            self._obs, state=self._state, episode_start=self._starts, deterministic=True)
        self._a_ctrl = np.asarray(a_ctrl, dtype=np.float64)
        self._residual = self.scale * np.clip(a_agent, -1.0, 1.0)
        self.venv.step_async(combine(self._a_ctrl, a_agent, self.scale))

    def step_wait(self) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, list[dict]]:
        obs, rew, dones, infos = self.venv.step_wait()
        self._obs = obs  # ended copies: their next episode's first observation
        self._starts = np.asarray(dones, dtype=bool).copy()
        for i, info in enumerate(infos):
            info["controller_action"] = self._a_ctrl[i]
            info["residual_action"] = self._residual[i]
        return obs, rew, dones, infos


class BatchedTaskObservation(VecEnv):
    """Flatten a batched Dict observation by ``layout``; add ``reward_offset``; Monitor stats.

    A plain ``VecEnv`` holding ``venv`` rather than a ``VecEnvWrapper``: SB3's
    ``sync_envs_normalization`` walks the training and evaluation wrapper chains in step, and
    the evaluation env (a ``DummyVecEnv`` under ``VecNormalize``) has no such layer.

    Args:
        venv: an SB3 VecEnv with Dict observations (``cir_gym.envs.vector.sb3_vec_env``).
        layout: the agent's observation layout.
        flatten: ``obs ↦ (n_envs, size)``, ``layout.bind(template_env)``.
        reward_offset: added to every step's reward (training only, as
            :class:`agents.shaping.RewardOffset`).
        log_error: ``{weight, max_error, floor[, orientation_scale = 0]}`` of
            :class:`agents.shaping.LogErrorBonus` (training only), or None.
        error_norms: ``() ↦ (n_envs,)``, the error norm of every copy's last step (the
            value the single env's info holds under one of ``agents.shaping.ERROR_KEYS``):
            the bonus's error; None: ‖q̄ − q‖ from the observation (joint tracking).
    """

    def __init__(
        self,
        venv: VecEnv,
        layout: ObservationLayout,
        flatten: Any,
        reward_offset: float = 0.0,
        log_error: dict[str, float] | None = None,
        error_norms: Callable[[], np.ndarray] | None = None,
    ) -> None:
        self.render_mode = None
        self.venv = venv  # before VecEnv.__init__, which asks it for render_mode
        super().__init__(venv.num_envs, layout.space(), venv.action_space)
        if not np.isfinite(reward_offset):
            raise ValueError(f"reward offset must be finite, got {reward_offset!r}")
        self.layout = layout
        self._flatten = flatten
        self.reward_offset = float(reward_offset)
        self.log_error = check_log_error_bonus(log_error) if log_error else None
        self._error_norms = error_norms
        if self.log_error:  # the env's error of each copy, or ‖q̄ − q‖ (joint tracking)
            if error_norms is None and "q_ref" not in layout.keys:
                raise ValueError("log_error_bonus with vec_env 'batched' needs the batched "
                                 "env's error_norms() (VisualServo-v1) or the joint reference "
                                 "q_ref in the observation (the joint-tracking envs); use "
                                 "vec_env 'dummy'")
            if self.log_error.pop("orientation_scale") > 0:
                raise ValueError("log_error_bonus orientation_scale > 0 needs an orientation "
                                 "error; the batched envs have none (use 0 or vec_env 'dummy')")
        self._ret = np.zeros(self.num_envs)
        self._len = np.zeros(self.num_envs, dtype=np.int64)

    def reset(self) -> np.ndarray:
        self._ret[:] = 0.0
        self._len[:] = 0
        return self._flatten(self.venv.reset())

    def step_async(self, actions: np.ndarray) -> None:
        self.venv.step_async(actions)

    def seed(self, seed: int | None = None) -> list[None]:
        return self.venv.seed(seed)

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return self.venv.get_attr(attr_name, indices)

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        self.venv.set_attr(attr_name, value, indices)

    def env_method(
        self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any
    ) -> list[Any]:
        return self.venv.env_method(method_name, *args, indices=indices, **kwargs)

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return self.venv.env_is_wrapped(wrapper_class, indices)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        obs, rew, dones, infos = self.venv.step_wait()
        rew = rew.astype(np.float64) + self.reward_offset
        if self.log_error:
            rew += log_error_bonus(self._step_error(obs, dones, infos), **self.log_error)
        self._ret += rew
        self._len += 1
        for i in np.flatnonzero(dones):
            info = infos[i]
            term = info.get("terminal_observation")
            if term is not None:
                info["terminal_observation"] = self._flatten(term)
            # as Monitor records it: the reward the agent was trained on
            info["episode"] = {"r": float(self._ret[i]), "l": int(self._len[i]), "t": 0.0}
            self._ret[i] = 0.0
            self._len[i] = 0
        return self._flatten(obs), rew.astype(np.float32), dones, infos

    def _step_error(self, obs: dict[str, np.ndarray], dones: np.ndarray,
                    infos: list[dict[str, Any]]) -> np.ndarray:
        """The error norm (n_envs,) of every copy's last step, as ``agents.shaping.
        error_norm`` reads it from the single env's info: the env's ``error_norms()``, else
        ‖q̄(k+1) − q(k+1)‖ = info["joint_error"] (an ended copy's from its final observation)."""
        if self._error_norms is not None:
            return np.abs(self._error_norms())
        err = obs["q_ref"] - obs["q"]
        for i in np.flatnonzero(dones):  # obs holds the next episode's first observation
            last = infos[i]["terminal_observation"]
            err[i] = last["q_ref"] - last["q"]
        return np.linalg.norm(err, axis=1)


def make_batched_vec_env(
    env_id: str,
    env_kwargs: dict[str, Any],
    layout: ObservationLayout,
    n_envs: int,
    seed: int,
    reward_offset: float = 0.0,
    log_error: dict[str, float] | None = None,
    residual: str | None = None,
    scale: Any = None,
    controller_kwargs: dict[str, Any] | None = None,
) -> VecEnv:
    """``n_envs`` batched training copies of ``env_id`` as an SB3 VecEnv (copy i: seed + i), on
    the id's native batched env (:func:`cir_gym.envs.vector.native_vector_env`).

    ``residual`` (a controller name of ``baselines.available(env_id)``, built with
    ``controller_kwargs`` on the batched env's template) makes the agent's action the residual
    on it (:class:`BatchedResidualAction`, scale ``scale``): the stack of ``agents.train.
    EnvFactory`` with ``residual``.

    Raises:
        ValueError: ``env_id`` has no native batched env, or it does not batch ``env_kwargs``;
            a controller that does not apply, bad gains or scale.
    """
    from cir_gym.envs.vector import VECTOR_ENVS, native_vector_env, sb3_vec_env

    cls = native_vector_env(env_id, env_kwargs)
    if cls is None:
        key = env_id.split(":")[-1]
        why = (VECTOR_ENVS[key].unsupported(env_kwargs) if key in VECTOR_ENVS
               else "no native batched env")
        raise ValueError(
            f"vec_env 'batched' needs a native batched env; {key!r}: {why} (batched ids: "
            f"{sorted(VECTOR_ENVS)}); use vec_env 'dummy'"
        )
    venv = cls(num_envs=n_envs, nthread=1, **env_kwargs)
    layout.check_space(venv.single_observation_space)
    flatten = layout.bind(venv.template)
    sb3: VecEnv = sb3_vec_env(venv)
    sb3.seed(seed)
    if residual is not None:
        try:
            controller = base_controller(residual, venv.template, cls.env_id,
                                         **(controller_kwargs or {}))
            sb3 = BatchedResidualAction(sb3, controller, scale)
        except (ValueError, TypeError):
            sb3.close()
            raise
    elif scale is not None or controller_kwargs:
        sb3.close()
        raise ValueError("scale and controller_kwargs need residual=<controller>")
    return BatchedTaskObservation(sb3, layout, flatten, reward_offset, log_error,
                                  getattr(venv, "error_norms", None))
