"""Training-only early termination: end an episode the agent has clearly lost, at its full cost.

A from-scratch torque policy on JointTracking lets the arm fall within ~0.1-0.2 s; the rest of
the 4-s episode is spent far from the reference, where every reward kernel has saturated
(r ≈ −1, no gradient), so ~95 % of the data teaches nothing. :class:`EarlyTermination` ends
the episode when the task error exceeds ``max_error`` and charges the reward the agent would
have collected by staying lost forever, ``penalty = r_lost / (1 − γ)`` (γ the training
discount), so ending early is never a shortcut. It wraps the *training* environments only:
evaluation, the learning curve and the shipped agent's scores use the unmodified environment.
The error is read from ``info["joint_error"]``, ``info["task_error"]`` or
``info["position_error"]`` (CartesianTracking; rad or m); with
``orientation_scale`` s > 0 (both wrappers) the error norm is max(‖e‖, s · θ), θ =
``info["orientation_error"]`` (rad; RedundantIK7-v5's pose tracking): s = 0.1 m/rad makes
10 mrad count as 1 mm, the env's success ratio. s = 0 (the default) reads ‖e‖ alone.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

__all__ = ["EarlyTermination", "LogErrorBonus", "RewardOffset", "TaskReplay",
           "check_log_error_bonus", "error_norm", "log_error_bonus"]

#: the error an episode is shaped on: rad or m (tracking), px (visual servoing, RMS over features)
ERROR_KEYS = ("joint_error", "task_error", "position_error", "feature_error")
ORIENTATION_KEY = "orientation_error"


def _check_scale(orientation_scale: float) -> float:
    if not np.isfinite(orientation_scale) or orientation_scale < 0:
        raise ValueError(f"orientation_scale must be finite and >= 0, got {orientation_scale!r}")
    return float(orientation_scale)


def error_norm(info: dict, orientation_scale: float = 0.0, who: str = "shaping") -> float:
    """‖info[joint_error | task_error]‖, or max(that, s · ‖info["orientation_error"]‖) for
    ``orientation_scale`` s > 0 (task units: s in m/rad turns radians into metres).

    Raises:
        KeyError: no error key in ``info`` (or no orientation error while s > 0).
    """
    key = next((k for k in ERROR_KEYS if k in info), None)
    if key is None:
        keys = ", ".join(f"info[{k!r}]" for k in ERROR_KEYS)
        raise KeyError(f"{who} needs one of {keys}; got "
                       f"{sorted(info)}")
    e = float(np.linalg.norm(info[key]))
    if orientation_scale > 0:
        if ORIENTATION_KEY not in info:
            raise KeyError(f"{who} with orientation_scale > 0 needs info[{ORIENTATION_KEY!r}]; "
                           f"got {sorted(info)}")
        e = max(e, orientation_scale * float(np.linalg.norm(info[ORIENTATION_KEY])))
    return e


class EarlyTermination(gym.Wrapper):
    """Terminate when ‖task error‖ > ``max_error``; add ``penalty`` (≤ 0) on that step.

    Args:
        env: an environment whose ``info`` has ``joint_error`` or ``task_error`` each step.
        max_error: error norm beyond which the episode is lost (task units).
        penalty: reward added on the terminating step, e.g. −1 / (1 − γ) for rewards ≥ −1.
        orientation_scale: s ≥ 0; s > 0: the error is max(‖e‖, s · θ) (:func:`error_norm`).
    """

    def __init__(self, env: gym.Env, max_error: float, penalty: float,
                 orientation_scale: float = 0.0) -> None:
        super().__init__(env)
        if not np.isfinite(max_error) or max_error <= 0:
            raise ValueError(f"max_error must be > 0, got {max_error!r}")
        if not np.isfinite(penalty) or penalty > 0:
            raise ValueError(f"penalty must be <= 0, got {penalty!r}")
        self.max_error = float(max_error)
        self.penalty = float(penalty)
        self.orientation_scale = _check_scale(orientation_scale)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        e = error_norm(info, self.orientation_scale, "early termination")
        if not (terminated or truncated) and e > self.max_error:
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
    penalty *plus* the bonuses it ends, so holding the arm up is what pays. The evaluation,
    the learning curve and the shipped scores use the env's reward.
    """

    def __init__(self, env: gym.Env, offset: float) -> None:
        super().__init__(env)
        if not np.isfinite(offset):
            raise ValueError(f"reward offset must be finite, got {offset!r}")
        self.offset = float(offset)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, float(reward) + self.offset, terminated, truncated, info


#: ``log_error_bonus`` keys → defaults (JointTracking's following-error limit, 1 mm/1 mrad;
#: orientation_scale 0: the position/joint error alone)
LOG_ERROR_DEFAULTS = {"weight": 1.0, "max_error": 0.5, "floor": 1e-3, "orientation_scale": 0.0}


def check_log_error_bonus(spec: Any) -> dict[str, float]:
    """``{weight, max_error, floor, orientation_scale}`` with defaults filled in, or ValueError
    saying what is allowed (weight ≥ 0, 0 < floor < max_error, orientation_scale ≥ 0, all
    finite)."""
    if not isinstance(spec, dict) or set(spec) - set(LOG_ERROR_DEFAULTS):
        raise ValueError(f"log_error_bonus must be a mapping with keys from "
                         f"{sorted(LOG_ERROR_DEFAULTS)}, got {spec!r}")
    out = {k: float(spec.get(k, v)) for k, v in LOG_ERROR_DEFAULTS.items()}
    if not all(np.isfinite(v) for v in out.values()) or out["weight"] < 0 \
            or not 0 < out["floor"] < out["max_error"] or out["orientation_scale"] < 0:
        raise ValueError(f"log_error_bonus needs finite weight >= 0, 0 < floor < max_error and "
                         f"orientation_scale >= 0, got {out}")
    return out


def log_error_bonus(error_norm: Any, weight: float, max_error: float,
                    floor: float) -> np.ndarray:
    """w · ln(max_error / max(‖e‖, floor)): ≥ 0 while ‖e‖ ≤ max_error, the same reward for
    halving the error at any scale (0.4 → 0.2 rad as 0.02 → 0.01), at most w · ln(max_error /
    floor)."""
    return weight * np.log(max_error / np.maximum(np.asarray(error_norm, dtype=np.float64),
                                                  floor))


class LogErrorBonus(gym.Wrapper):
    """Training only: r + w · ln(max_error / max(‖task error‖, floor)) on every step.

    JointTracking's reward kernels (1, 0.1, 0.01 rad) pay almost nothing for improving an
    error of 0.4 rad and saturate below ~3 mrad; the log bonus pays the same for every halving
    of the error, and, being ≥ 0 up to the following-error limit (``max_error`` = 0.5 rad),
    it is also an alive bonus: a stopped episode loses every bonus it does not play. The error
    norm is read from ``info["joint_error"]`` or ``info["task_error"]`` (with
    ``orientation_scale`` s > 0: max(‖e‖, s · θ), :func:`error_norm`); evaluation, learning
    curves and shipped scores use the env's reward.
    """

    def __init__(self, env: gym.Env, weight: float = 1.0, max_error: float = 0.5,
                 floor: float = 1e-3, orientation_scale: float = 0.0) -> None:
        super().__init__(env)
        self.spec_ = check_log_error_bonus({"weight": weight, "max_error": max_error,
                                            "floor": floor,
                                            "orientation_scale": orientation_scale})
        self.orientation_scale = self.spec_["orientation_scale"]

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        e = error_norm(info, self.orientation_scale, "the log-error bonus")
        bonus = log_error_bonus(e, self.spec_["weight"], self.spec_["max_error"],
                                self.spec_["floor"])
        return obs, float(reward) + float(bonus), terminated, truncated, info


class TaskReplay(gym.Wrapper):
    """Training only: play each drawn task ``repeats`` times before drawing the next.

    RedundantIK7-v5's "obstacle" reset draws a lap and searches for an obstacle that a
    self-motion can clear: ~0.2 s of CPU, while a step costs ~0.1 ms. Under early termination
    an untrained policy loses its lap within a few steps, so training is almost all resets
    (43 env steps/s measured, docs/research/agents.md). This wrapper resets with
    ``options={"replay": True}`` (the env restores the last task exactly, ~0.1 ms) on all but
    every ``repeats``-th reset, cutting the draw cost ``repeats``-fold. Every drawn task is
    played the same number of times, so the task distribution is unchanged (only correlated);
    a reset with a seed always draws. Evaluation and the shipped scores draw every episode.

    Raises:
        ValueError: ``repeats`` < 1, or an env whose reset cannot replay a task (its class has
            no ``replayable_tasks = True``: RedundantIK's envs have it).
    """

    def __init__(self, env: gym.Env, repeats: int) -> None:
        super().__init__(env)
        if isinstance(repeats, bool) or not isinstance(repeats, int | np.integer) or repeats < 1:
            raise ValueError(f"task_replay must be an integer >= 1 (plays per drawn task), "
                             f"got {repeats!r}")
        if not getattr(env.unwrapped, "replayable_tasks", False):
            raise ValueError(f"task_replay needs an env whose reset can replay its task "
                             f"(RedundantIK's); {type(env.unwrapped).__name__} cannot")
        self.repeats = int(repeats)
        self._plays = 0  # plays of the current task so far; 0: none drawn yet

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        if seed is None and not options and 0 < self._plays < self.repeats:
            self._plays += 1
            return self.env.reset(options={"replay": True})
        self._plays = 1
        return self.env.reset(seed=seed, options=options)
