"""The reward of the torque-driven tracking tasks (JointTracking, ElasticJointTracking,
CartesianTracking), one function for a single env and for a batch of copies (envs/vector.py).

r = r_tracking + r_torque + r_action_rate + r_following_error + r_diverged:

- r_tracking = −(1 − (1/S) Σ_s exp(−e² / s²)) over the S kernel widths s ∈ ``error_scales``
  (wide and narrow kernels), in [−1, 0]; e² is the task's squared error (joint error ‖q̃‖²,
  or the pose error of CartesianTracking);
- r_torque = −``torque_weight`` ‖a‖² / n;
- r_action_rate = −``action_rate_weight`` ‖a_k − a_{k−1}‖² / n (against chattering);
- r_following_error = −``following_error_penalty`` on the step the following-error monitor
  stops the episode, else 0;
- r_diverged = −``divergence_penalty`` on the step the physics diverged, else 0.

With ``charge_unplayed_steps`` a stopped or diverged episode also loses, on its last step, the
worst reward of every step it did not play, (T − k)(1 + ``torque_weight`` +
4 ``action_rate_weight``) (the worst step: r_tracking = −1, ‖a‖² = n, ‖Δa‖² = 4n with a in
[−1, 1]ⁿ). Playing on then never loses more than stopping: ending early never raises the
return, at any discount γ ≤ 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from cir_gym.validation import InvalidArgument, as_float_array, check_flag, check_number

#: the reward terms, in the order they are summed (each is ``info["reward_<name>"]``)
TERMS = (
    "reward_tracking",
    "reward_torque",
    "reward_action_rate",
    "reward_following_error",
    "reward_diverged",
)


def squared_norm(x: np.ndarray) -> np.ndarray:
    """‖x‖² over the last axis: (..., n) → (...)."""
    return (x * x).sum(axis=-1)


def check_error_scales(value: Any, unit: str) -> np.ndarray:
    """Kernel widths (S,) in [1e-9, 1e3] ``unit``; else InvalidArgument naming error_scales."""
    scales = np.atleast_1d(as_float_array("error_scales", value))
    if scales.ndim != 1 or scales.size == 0 or not np.all((scales >= 1e-9) & (scales <= 1e3)):
        raise InvalidArgument(f"error_scales must be numbers in [1e-9, 1e3] {unit}, got {value!r}")
    return scales


@dataclass(frozen=True)
class TrackingReward:
    """The weights of the tracking reward (see the module docstring); call it on a step.

    Attributes:
        error_scales: kernel widths s (S,), in the unit of the task's error.
        torque_weight: weight of r_torque.
        action_rate_weight: weight of r_action_rate.
        divergence_penalty: reward lost on the step the physics diverged.
        following_error_penalty: reward lost on the step the following-error monitor stops.
        charge_unplayed_steps: also charge a stopped or diverged episode the worst reward of
            each step it did not play.
    """

    error_scales: np.ndarray
    torque_weight: float = 0.01
    action_rate_weight: float = 0.01
    divergence_penalty: float = 100.0
    following_error_penalty: float = 50.0
    charge_unplayed_steps: bool = True

    @classmethod
    def from_arguments(
        cls,
        error_scales: Any,
        unit: str,
        torque_weight: Any,
        action_rate_weight: Any,
        divergence_penalty: Any,
        following_error_penalty: Any,
        charge_unplayed_steps: Any,
    ) -> TrackingReward:
        """The reward of an env's constructor arguments, each checked (InvalidArgument names
        the argument and its allowed range); ``unit`` is that of the error (rad, m)."""
        return cls(
            error_scales=check_error_scales(error_scales, unit),
            torque_weight=check_number("torque_weight", torque_weight, 0.0, 10.0),
            action_rate_weight=check_number("action_rate_weight", action_rate_weight, 0.0, 10.0),
            divergence_penalty=check_number("divergence_penalty", divergence_penalty, 0.0, 1e6),
            following_error_penalty=check_number(
                "following_error_penalty", following_error_penalty, 0.0, 1e6
            ),
            charge_unplayed_steps=check_flag("charge_unplayed_steps", charge_unplayed_steps),
        )

    @cached_property
    def _scales_sq(self) -> tuple[float, ...]:
        """s² of each kernel."""
        return tuple((self.error_scales**2).tolist())

    @property
    def worst_step(self) -> float:
        """The lowest reward of one played step: r_tracking = −1, ‖a‖²/n = 1, ‖Δa‖²/n = 4."""
        return 1.0 + self.torque_weight + 4.0 * self.action_rate_weight

    def __call__(
        self,
        error_sq: Any,
        action: np.ndarray,
        previous_action: np.ndarray,
        diverged: Any,
        stopped: Any,
        unplayed_steps: Any,
    ) -> dict[str, np.ndarray]:
        """The reward terms of one step, or of a batch of copies (leading axes ``...``).

        Args:
            error_sq: the task's squared error e² (...).
            action: the applied action a (..., n), in [−1, 1].
            previous_action: a_{k−1} (..., n).
            diverged: the physics diverged on this step (...) bool.
            stopped: the following-error monitor stopped the episode on this step (...) bool.
            unplayed_steps: steps of the horizon left after this one, T − k (...).

        Returns:
            ``TERMS`` → array (...): the five terms (0-d arrays for one step).
        """
        n = action.shape[-1]
        kernels = [np.exp(-error_sq / s_sq) for s_sq in self._scales_sq]  # S of them, each (...)
        unplayed = unplayed_steps * self.worst_step if self.charge_unplayed_steps else 0.0
        return {
            "reward_tracking": sum(kernels) / len(kernels) - 1.0,
            "reward_torque": (-self.torque_weight / n) * squared_norm(action),
            "reward_action_rate": (
                (-self.action_rate_weight / n) * squared_norm(action - previous_action)
            ),
            "reward_following_error": np.where(
                stopped, -(self.following_error_penalty + unplayed), 0.0
            ),
            "reward_diverged": np.where(diverged, -(self.divergence_penalty + unplayed), 0.0),
        }
