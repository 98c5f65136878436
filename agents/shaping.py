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

__all__ = ["EarlyTermination", "RewardOffset"]

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


class RewardOffset(gym.Wrapper):
    """Training only: r + ``offset`` on every step (an "alive bonus").

    JointTracking's tracking reward lies in [−1, 0], so a lost arm that keeps playing earns
    about as little as one the following-error monitor stops (−50 = −1/(1 − γ) at γ = 0.98):
    at 0.3 rad of error r ≈ −0.7 per step, and holding on is worth only ~15 more than falling.
    With ``offset = 1`` every played step is worth ≥ 0 and the monitor's stop costs its
    penalty *plus* the bonuses it ends, so holding the arm up is what pays (issue 20's reward
    review). The evaluation, the learning curve and the shipped scores use the env's reward.
    """

    def __init__(self, env: gym.Env, offset: float) -> None:
        super().__init__(env)
        if not np.isfinite(offset):
            raise ValueError(f"reward offset must be finite, got {offset!r}")
        self.offset = float(offset)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, float(reward) + self.offset, terminated, truncated, info
