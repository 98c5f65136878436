"""Metric declarations: what each environment measures, in which unit, and which way is better.

Every environment declares its metrics once, as a tuple of :class:`MetricSpec` in the class
attribute ``metric_specs`` and the name of its primary metric in ``primary_metric``; at the
last step of an episode it puts the episode's values in ``info["episode_metrics"]`` (a dict
name → float). The evaluator and the leaderboard read nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = ["MetricSpec", "aggregate", "cvar"]


@dataclass(frozen=True)
class MetricSpec:
    """One episode metric.

    Attributes:
        name: key in ``info["episode_metrics"]``.
        unit: SI unit ("rad", "m", "N m", "" for ratios).
        better: "lower" or "higher".
        description: one line for tables and docstrings.
        failure_scores_limit: a failed episode scores a fixed limit rather than a measured
            value (PegInHole's ``insertion_time`` is the time limit when the peg never
            reaches the goal depth): the value is censored, so a mean over episodes that
            include failures, or a ratio of two such means, measures the failures, not the
            metric. The leaderboard leaves such ratios out.
    """

    name: str
    unit: str
    better: Literal["lower", "higher"]
    description: str
    failure_scores_limit: bool = False

    def worst(self, values: np.ndarray) -> float:
        """Worst value over episodes (max if lower is better, min otherwise)."""
        return float(np.max(values) if self.better == "lower" else np.min(values))


def cvar(values: np.ndarray, better: str, alpha: float = 0.2) -> float:
    """Conditional value at risk: mean of the worst ``alpha`` fraction of episodes (≥ 1)."""
    v = np.sort(np.asarray(values, dtype=float))
    if better == "lower":
        v = v[::-1]
    k = max(1, int(np.ceil(alpha * v.size)))
    return float(np.mean(v[:k]))


def aggregate(spec: MetricSpec, values: np.ndarray) -> dict[str, float]:
    """mean, std, median, worst and CVaR(20 %) of one metric over episodes (NaNs ignored)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {k: float("nan") for k in ("mean", "std", "median", "worst", "cvar")}
    return {
        "mean": float(np.mean(v)),
        "std": float(np.std(v)),
        "median": float(np.median(v)),
        "worst": spec.worst(v),
        "cvar": cvar(v, spec.better),
    }
