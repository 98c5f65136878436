"""Training-only early termination: end an episode the agent has clearly lost, at its full cost.

A from-scratch torque policy on JointTracking lets the arm fall within ~0.1-0.2 s; the rest of
the 4-s episode is spent far from the reference, where every reward kernel has saturated
(r ≈ −1, no gradient), so ~95 % of the data teaches nothing. :class:`EarlyTermination` ends
the episode when the task error exceeds ``max_error`` and charges the reward the agent would
have collected by staying lost forever, ``penalty = r_lost / (1 − γ)`` (γ the training
discount), so ending early is never a shortcut. It wraps the *training* environments only:
evaluation, the learning curve and the shipped agent's scores use the unmodified environment.
The error is read from ``info["joint_error"]`` or ``info["task_error"]`` (rad or m).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

__all__ = ["EarlyTermination"]

ERROR_KEYS = ("joint_error", "task_error")


class EarlyTermination(gym.Wrapper):
    """Terminate when ‖task error‖ > ``max_error``; add ``penalty`` (≤ 0) on that step.

    Args:
        env: an environment whose ``info`` has ``joint_error`` or ``task_error`` each step.
        max_error: error norm beyond which the episode is lost (task units).
        penalty: reward added on the terminating step, e.g. −1 / (1 − γ) for rewards ≥ −1.
    """

    def __init__(self, env: gym.Env, max_error: float, penalty: float) -> None:
        super().__init__(env)
        if not np.isfinite(max_error) or max_error <= 0:
            raise ValueError(f"max_error must be > 0, got {max_error!r}")
        if not np.isfinite(penalty) or penalty > 0:
            raise ValueError(f"penalty must be <= 0, got {penalty!r}")
        self.max_error = float(max_error)
        self.penalty = float(penalty)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        key = next((k for k in ERROR_KEYS if k in info), None)
        if key is None:
            raise KeyError(f"early termination needs info[{ERROR_KEYS[0]!r}] or "
                           f"info[{ERROR_KEYS[1]!r}]; got {sorted(info)}")
        if not (terminated or truncated) and float(np.linalg.norm(info[key])) > self.max_error:
            terminated = True
            reward = float(reward) + self.penalty
            info["early_termination"] = True
        return obs, reward, terminated, truncated, info
