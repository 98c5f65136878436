"""Residual RL: the agent adds a bounded correction to a course controller's action.

    a = clip(a_ctrl + scale ⊙ a_agent, −1, 1),   a_agent ∈ [−1, 1]^m

``a_ctrl`` comes from the controller's own ``predict`` on the env's observation, with its state
(integrators, adaptive estimates) kept across steps and re-initialised at each episode start,
exactly as :func:`cir_gym.evaluation.evaluate` runs it. With ``a_agent = 0`` the wrapped env
behaves exactly like the controller alone, so a residual policy whose mean starts at zero starts
at the controller's performance. :class:`agents.batched.BatchedResidualAction` is the same
layer on a native batched env (one ``predict`` on all copies' observations per step).

Choosing ``scale`` (in units of the action, i.e. of τ_max for torque actions): the residual's
range must cover the error it corrects, with margin, or it saturates. For JointTracking with an
unknown 3 kg payload, the nominal model's torque error along the references (B, n with and
without payload, 20 episodes) peaks at (0.02, 0.08, 0.03, 0.11, 0.02, 0.12, 0) τ_max on joints
1…7 — joint 6's ~5 N m gravity error is 0.12 × 40 N m — so ``scale = 0.1`` cannot cancel it;
the shipped agents use 0.25 (twice the largest error). A larger scale only multiplies the
exploration noise in N m, which the controller's feedback rejects easily at 500 Hz (σ = 0.135
on a_agent at scale 0.25 changes the controller's RMS error by 2 %).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

__all__ = ["ResidualAction", "agent_action", "base_controller", "check_scale", "combine"]


def check_scale(scale: Any, action_space: gym.spaces.Box) -> np.ndarray:
    """``scale`` (scalar or per action dimension) as an array of the action's shape."""
    arr = np.asarray(scale, dtype=np.float64)
    try:
        arr = np.broadcast_to(arr, action_space.shape).copy()
    except ValueError as exc:
        raise ValueError(f"residual scale must be a scalar or shape {action_space.shape}, "
                         f"got {scale!r}") from exc
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0) or np.any(arr > 2):
        raise ValueError(f"residual scale must be in (0, 2], got {scale!r}")
    return arr


def base_controller(controller: Any, env: gym.Env, env_id: str | None,
                    **controller_kwargs: Any) -> Any:
    """The residual's base: ``controller`` itself (an object with SB3's ``predict``) or, for a
    name of ``baselines.available(env_id)``, ``baselines.make(controller, env_id, env=env,
    **controller_kwargs)`` (its context read from ``env``, a single env of ``env_id``).

    Raises:
        ValueError: a name without ``env_id``; ``controller_kwargs`` with an object.
        TypeError: an object without ``predict``.
    """
    if isinstance(controller, str):
        from cir_gym import baselines

        if env_id is None:
            raise ValueError("a controller name needs an env made with gymnasium.make")
        controller = baselines.make(controller, env_id, env=env, **controller_kwargs)
    elif controller_kwargs:
        raise ValueError("controller_kwargs only apply to a controller given by name")
    if not hasattr(controller, "predict"):
        raise TypeError(f"controller must have SB3's predict(), got {controller!r}")
    return controller


def agent_action(action: Any, shape: tuple[int, ...]) -> np.ndarray:
    """The agent's action a_agent as float64 of ``shape`` ((m,) or (n_envs, m)).

    Raises:
        ValueError: a NaN or inf in it (or it does not reshape to ``shape``).
    """
    a_agent = np.asarray(action, dtype=np.float64).reshape(shape)
    if not np.all(np.isfinite(a_agent)):
        raise ValueError(f"residual action contains NaN or inf: {a_agent}")
    return a_agent


def combine(a_ctrl: np.ndarray, a_agent: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """a = clip(a_ctrl + scale ⊙ clip(a_agent, −1, 1), −1, 1) (float32, any leading batch)."""
    a = np.asarray(a_ctrl, dtype=np.float64) + scale * np.clip(a_agent, -1.0, 1.0)
    return np.clip(a, -1.0, 1.0).astype(np.float32)


class ResidualAction(gym.Wrapper):
    """Run ``controller`` inside the env; the agent's action is the scaled residual.

    Args:
        env: an environment with a ``Box(-1, 1)`` action space.
        controller: a name from ``baselines.available(env_id)`` or an object with SB3's
            ``predict`` protocol (a :class:`baselines.Controller`).
        scale: residual range per action dimension (scalar or (m,)), see the module docstring.
        controller_kwargs: gains passed to ``baselines.make`` when ``controller`` is a name.

    ``info["controller_action"]`` and ``info["residual_action"]`` hold a_ctrl and
    scale ⊙ a_agent of the step.
    """

    def __init__(self, env: gym.Env, controller: Any, scale: Any = 0.25,
                 **controller_kwargs: Any) -> None:
        super().__init__(env)
        env_id = env.spec.id if env.spec is not None else None
        self.controller = base_controller(controller, env, env_id, **controller_kwargs)
        self.scale = check_scale(scale, env.action_space)
        self._obs: Any = None
        self._state: Any = None
        self._start = True

    def reset(self, **kwargs: Any) -> tuple[Any, dict]:
        obs, info = self.env.reset(**kwargs)
        self._obs, self._state, self._start = obs, None, True
        return obs, info

    def controller_action(self) -> np.ndarray:
        """a_ctrl for the current observation (advances the controller's state once)."""
        if self._obs is None:
            raise RuntimeError("call reset() before step()")
        a_ctrl, self._state = self.controller.predict(
            self._obs, state=self._state, episode_start=np.array([self._start]),
            deterministic=True)
        self._start = False
        return np.asarray(a_ctrl, dtype=np.float64)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        a_agent = agent_action(action, self.scale.shape)
        a_ctrl = self.controller_action()
        a = combine(a_ctrl, a_agent, self.scale)
        obs, reward, terminated, truncated, info = self.env.step(a)
        self._obs = obs
        info["controller_action"] = a_ctrl
        info["residual_action"] = self.scale * np.clip(a_agent, -1.0, 1.0)
        return obs, reward, terminated, truncated, info
