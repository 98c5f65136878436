"""AdmittanceContact's task arithmetic, one function for a single env and for a batch of copies
(``cir_gym.envs.admittance_vector``): a control period's contact forces from its sensordata,
the reward of a step, and the metrics of an episode.

r = r_force + r_path + r_action_rate + r_force_limit + r_diverged (:data:`REWARD_TERMS`):

- r_force = −(1 − ½ Σ_s exp(−(f − f̄)² / s²)), s ∈ (``force_scale``, ``force_scale``/5) N;
- r_path = −``path_weight`` (1 − exp(−‖e_t‖² / σ²)), σ = ``path_scale``;
- r_action_rate = −``action_rate_weight`` ‖a_k − a_{k−1}‖² / dim(a);
- r_force_limit = −``force_limit_penalty`` on the step the force limit stops the episode;
- r_diverged = −``divergence_penalty`` on the step the physics diverged;

with ``charge_unplayed_steps`` a stop also loses (T − k)(1 + ``path_weight`` +
4 ``action_rate_weight``), the worst reward of every step it did not play.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from cir_gym.envs.contact_force import largest_contact_force

__all__ = [
    "CONTACT_THRESHOLD",
    "REWARD_TERMS",
    "AdmittanceReward",
    "episode_metrics",
    "period_forces",
]

CONTACT_THRESHOLD = 0.5  # N: the tool's normal contact force above which it touches the plate
#: the reward's terms, in the order they are summed (``info["<term>"]``)
REWARD_TERMS = (
    "reward_force", "reward_path", "reward_action_rate", "reward_force_limit", "reward_diverged",
)


def period_forces(
    record: np.ndarray, normal: np.ndarray, tool_at: slice, peak_at: slice
) -> tuple[np.ndarray, np.ndarray]:
    """A control period's contact forces at each physics step, from its sensordata record
    (..., n, nsensordata) (n physics steps, a leading copy axis or none) and the true surface
    normal (..., 3): the tool's normal contact force (..., n) (N), n̂ · the plate's force on
    the tip (the ``tool_contact`` sensor at ``tool_at``), and the largest single contact force
    on the plate (..., n) (N), max_i ‖f_i‖ over the plate's contacts (the tool's and the
    links'): the whole force, normal and friction, of ``peak_contact`` (at ``peak_at``), as
    PegInHole measures its largest contact
    (:func:`~cir_gym.envs.contact_force.largest_contact_force`)."""
    tool = np.sum(record[..., tool_at] * normal[..., None, :], axis=-1)
    return tool, largest_contact_force(record[..., peak_at])


@dataclass(frozen=True)
class AdmittanceReward:
    """The reward's weights (module docstring; the env checks them) and the episode's length.

    Attributes:
        force_scale: force kernel width (N).
        path_scale: path kernel width (m).
        path_weight, action_rate_weight: weights of r_path and r_action_rate.
        force_limit_penalty, divergence_penalty: reward lost at a stop.
        charge_unplayed_steps: a stop also loses the worst reward of each unplayed step.
        max_steps: T, control steps of an episode.
        action_dim: dim(a).
    """

    force_scale: float
    path_scale: float
    path_weight: float
    action_rate_weight: float
    force_limit_penalty: float
    divergence_penalty: float
    charge_unplayed_steps: bool
    max_steps: int
    action_dim: int

    def worst_step(self) -> float:
        """The magnitude of the worst reward of one step (r_force = −1, e_t large, ‖Δa‖² =
        4 dim(a)): what ``charge_unplayed_steps`` charges per unplayed step."""
        return 1.0 + self.path_weight + 4.0 * self.action_rate_weight

    def terms(
        self,
        force_error: Any,
        path_error_sq: Any,
        action_change_sq: Any,
        over: Any,
        diverged: Any,
        played: Any,
    ) -> dict[str, Any]:
        """The terms of one step by name (:data:`REWARD_TERMS`), for one env (numbers: 0-d
        results) or for copies (arrays (N,) of each argument: (N,) terms).

        Args:
            force_error: f − f̄ (N).
            path_error_sq: ‖e_t‖² (m²).
            action_change_sq: ‖a_k − a_{k−1}‖².
            over: the force limit stopped the episode at this step.
            diverged: the physics diverged at this step.
            played: steps played with this one (k + 1).
        """
        s = self.force_scale
        kernel = np.exp(-((force_error / s) ** 2)) + np.exp(-((5 * force_error / s) ** 2))
        unplayed = (self.max_steps - np.asarray(played)) * self.worst_step()
        charge = unplayed if self.charge_unplayed_steps else 0.0 * unplayed
        return {
            "reward_force": -(1.0 - 0.5 * kernel),
            "reward_path": -self.path_weight
            * (1.0 - np.exp(-np.asarray(path_error_sq) / self.path_scale**2)),
            "reward_action_rate": -self.action_rate_weight
            * np.asarray(action_change_sq) / self.action_dim,
            "reward_force_limit": np.where(over, -(self.force_limit_penalty + charge), 0.0),
            "reward_diverged": np.where(diverged, -(self.divergence_penalty + charge), 0.0),
        }


def episode_metrics(
    force: np.ndarray,
    touch: np.ndarray,
    peak: np.ndarray,
    path: np.ndarray,
    played: int,
    stopped: bool,
    first_contact: int | None,
    f_ref: float,
    settle_steps: int,
    max_steps: int,
) -> dict[str, float]:
    """The metrics (AdmittanceContactEnv's Metrics section) of one episode's histories.

    Args:
        force, touch, peak, path: per control step (≥ ``played`` entries): the tool's mean
            normal force (N), the fraction of physics steps in contact, the largest single
            contact force (N), the path error (m).
        played: steps played.
        stopped: the episode was stopped (force limit or divergence): scored over the whole
            horizon, the unplayed steps with f = 0, no contact and the last path error.
        first_contact: the step of the first contact, or None.
        f_ref: f̄ (N).
        settle_steps: steps after the first contact before the force error is scored.
        max_steps: T.
    """
    end = max_steps if stopped else max(played, 1)
    f = np.zeros(end)  # steps not played: no contact (f = 0)
    t = np.zeros(end)
    f[:played] = force[:played]
    t[:played] = touch[:played]
    e = np.full(end, path[played - 1] if played else 0.0)
    e[:played] = path[:played]
    if first_contact is None:
        rms, loss, path_rms, overshoot = f_ref, 1.0, math.sqrt(np.mean(e**2)), 0.0
    else:
        start = min(first_contact + settle_steps, end - 1)
        rms = math.sqrt(np.mean((f[start:] - f_ref) ** 2))
        loss = 1.0 - float(np.mean(t[start:]))
        path_rms = math.sqrt(np.mean(e[start:] ** 2))
        overshoot = max(float(np.max(force[first_contact:played])) - f_ref, 0.0)
    return {
        "force_rms_error": float(rms),
        "peak_overshoot": overshoot,
        "contact_loss": loss,
        "path_error": float(path_rms),
        "max_force": float(np.max(peak[:played])) if played else 0.0,
    }
