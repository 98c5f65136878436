"""The normalized score's scale: a metric value between two anchors → a number, 0 at the first
anchor (a hold-still policy), 1 at the second (the best tuned controller).

For a mean m, with the anchors' means m_hold and m_best:

* linear: score = (m_hold − m) / (m_hold − m_best);
* log, where the metric spans decades: score = log(m_hold / m) / log(m_hold / m_best).

Both formulas hold whichever way the metric is better (lower or higher): the score grows as m
moves from m_hold towards m_best and beyond. It is not clipped: < 0 is worse than holding
still, > 1 better than the best controller. The log scale is used when m_hold and m_best are
both > 0 and at least ``LOG_DECADES`` (one) decade apart: a tracking error going from 1e-1 to
1e-4 rad counts each decade alike, instead of scoring 0.9 for 1e-2 rad. On the log scale a value
m ≤ 0 or below m_best / 1000 is floored at m_best / 1000 when lower is better, so that a perfect
episode scores finitely, 1 + 3 / log10(m_hold / m_best); when higher is better m is clamped to
[m_hold / 1000, 1000 m_best].

Only numbers here (no environment, no policy), so every layer can score: the anchors are
measured by the leaderboard (:mod:`cir_gym.scoring.normalized`) and travel as :class:`Anchors`
(to the agents' seed tables, and as JSON in ``<leaderboard>/normalized.json``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = ["LOG_DECADES", "LOG_FLOOR", "Anchors", "normalized_score", "uses_log_scale"]

#: decades between m_hold and m_best from which the score is on a log scale
LOG_DECADES = 1.0
#: on the log scale, values are floored at m_best × LOG_FLOOR (lower is better; module docstring)
LOG_FLOOR = 1e-3


def uses_log_scale(hold: float, best: float) -> bool:
    """True when m_hold and m_best are both > 0 and at least ``LOG_DECADES`` decades apart."""
    if not (hold > 0 and best > 0 and math.isfinite(hold) and math.isfinite(best)):
        return False
    return abs(math.log10(hold / best)) >= LOG_DECADES


def normalized_score(value: float, hold: float, best: float, *, log: bool | None = None) -> float:
    """The score of a metric value between the anchors (module docstring).

    Args:
        value: the policy's metric value m.
        hold: m_hold, the hold-still policy's value (score 0).
        best: m_best, the best tuned controller's value (score 1).
        log: the scale; None: :func:`uses_log_scale`.

    Returns:
        The score (NaN if ``value`` is NaN).

    Raises:
        ValueError: the anchors are equal or not finite (no scale), or ``log`` is True with an
            anchor ≤ 0.
    """
    if not (math.isfinite(hold) and math.isfinite(best)) or hold == best:
        raise ValueError(
            f"the anchors must be finite and differ: hold-still {hold!r}, best {best!r}"
        )
    if log is None:
        log = uses_log_scale(hold, best)
    if math.isnan(value):
        return float("nan")
    if not log:
        return (hold - value) / (hold - best)
    if hold <= 0 or best <= 0:
        raise ValueError(f"a log scale needs anchors > 0: hold-still {hold!r}, best {best!r}")
    if best < hold:  # lower is better
        value = max(value, best * LOG_FLOOR)
    else:
        value = min(max(value, hold * LOG_FLOOR), best / LOG_FLOOR)
    return math.log(hold / value) / math.log(hold / best)


@dataclass(frozen=True)
class Anchors:
    """The two anchors of one leaderboard variant's score, on its primary metric.

    Attributes:
        metric: the metric scored.
        hold: m_hold, the hold-still policy's mean (score 0).
        best: m_best, the best tuned controller's mean (score 1).
        best_policy: the policy whose mean is m_best.
        log: whether the log formula is used (:func:`uses_log_scale` of the anchors).
        unit: the metric's unit ("" for none), for :meth:`describe`.

    Raises:
        ValueError: the anchors are equal or not finite (there is no scale).
    """

    metric: str
    hold: float
    best: float
    best_policy: str
    log: bool
    unit: str = ""

    def __post_init__(self) -> None:
        normalized_score(self.hold, self.hold, self.best, log=self.log)  # a clear error

    @classmethod
    def of(cls, metric: str, hold: float, best: float, best_policy: str,
           unit: str = "") -> Anchors:
        """The anchors with the scale :func:`uses_log_scale` chooses for them."""
        return cls(metric, float(hold), float(best), best_policy, uses_log_scale(hold, best),
                   unit)

    def score(self, value: float) -> float:
        """The normalized score of one metric value (a mean, or one episode's value)."""
        return normalized_score(float(value), self.hold, self.best, log=self.log)

    def scores(self, values: Any) -> np.ndarray:
        """Element-wise :meth:`score` of an array of any shape (NaN stays NaN)."""
        x = np.asarray(values, dtype=np.float64)
        return np.vectorize(self.score, otypes=[np.float64])(x) if x.size else x.copy()

    def describe(self) -> str:
        """One line: what 0 and 1 are and the scale."""
        unit = f" {self.unit}" if self.unit else ""
        scale = "log scale (the anchors are a decade or more apart)" if self.log else "linear"
        return (f"score on `{self.metric}`: 0 = hold still ({self.hold:.3g}{unit}), 1 = "
                f"{self.best_policy} ({self.best:.3g}{unit}), {scale}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Anchors:
        """The anchors :meth:`to_dict` wrote (unknown keys are an error)."""
        return cls(**data)
