"""Metric declarations: what each environment measures, in which unit, and which way is better.

Every environment declares its metrics once, as a tuple of :class:`MetricSpec` in the class
attribute ``metric_specs`` and the name of its primary metric in ``primary_metric``; at the
last step of an episode it puts the episode's values in ``info["episode_metrics"]`` (a dict
name → float). The evaluator and the leaderboard read nothing else.

Over episodes, :func:`aggregate` summarises a metric (with :func:`mean_interval`, the 95 %
confidence interval of its mean) and :func:`wilson_interval` gives a success rate's: the
project quotes no headline without one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = [
    "BOOTSTRAP_RESAMPLES",
    "BOOTSTRAP_SEED",
    "SUMMARY_KEYS",
    "Z95",
    "MetricSpec",
    "aggregate",
    "cvar",
    "mean_interval",
    "wilson_interval",
]

#: Φ⁻¹(0.975): the standard normal quantile of a two-sided 95 % interval
Z95 = 1.959963984540054
#: resamples of :func:`mean_interval`'s bootstrap (its percentiles settle to ~1 % of the width)
BOOTSTRAP_RESAMPLES = 10_000
#: the bootstrap generator's seed: the same episodes give the same interval (on one numpy)
BOOTSTRAP_SEED = 0
#: resampled values drawn at a time (bounds the memory at 8 MB whatever the episodes)
_BOOTSTRAP_BLOCK = 1 << 20


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


def mean_interval(values: np.ndarray, confidence: float = 0.95,
                  resamples: int = BOOTSTRAP_RESAMPLES,
                  seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """Percentile-bootstrap confidence interval (low, high) of the mean of ``values``.

    The n values (one per episode, i.e. per seed) are resampled n at a time with
    replacement ``resamples`` times; the interval holds the middle ``confidence`` of the
    resamples' means (``np.percentile``, linear). The generator is
    ``np.random.default_rng(seed)``, so a regenerated table reproduces its intervals.

    Why the bootstrap rather than Student's t (x̄ ± t₀.₉₇₅,ₙ₋₁ s/√n): it assumes no shape
    of the episodes' distribution, and the metrics here are skewed or censored (an insertion
    time stops at the time limit, an error is ≥ 0), where a symmetric interval would run
    past what an episode can score; it needs no t quantile (no scipy in the core). Its cost:
    on normal data it is a little narrow at small n (it uses the plug-in s·√((n−1)/n) and,
    in effect, the normal quantile: at n = 30, 0.94 of the t interval's width; coverage
    measured 94 % instead of 95 % on 2000 normal samples): one more reason for ≥ 30
    episodes behind a headline.

    Args:
        values: (n,) finite values (one per episode).
        confidence: in (0, 1).
        resamples: number of bootstrap resamples, an integer ≥ 1.
        seed: the generator's seed, an integer ≥ 0.

    Returns:
        (low, high), with low ≤ mean ≤ high; (NaN, NaN) for n < 2 (one value has no
        spread to resample).

    Raises:
        ValueError: confidence outside (0, 1), resamples or seed not such an integer (a bool
            is not one), values not finite.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    if not _is_integer(resamples) or resamples < 1:
        raise ValueError(f"resamples must be an integer >= 1, got {resamples!r}")
    if not _is_integer(seed) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0 (np.random.default_rng's), got {seed!r}")
    v = np.asarray(values, dtype=float).ravel()
    if not np.all(np.isfinite(v)):
        raise ValueError("values must be finite (aggregate drops NaN episodes first)")
    if v.size < 2:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    per_block = max(1, _BOOTSTRAP_BLOCK // v.size)
    means = np.concatenate([
        v[rng.integers(0, v.size, size=(min(per_block, resamples - start), v.size))].mean(axis=1)
        for start in range(0, resamples, per_block)
    ])
    tail = 50.0 * (1.0 - confidence)
    low, high = np.percentile(means, [tail, 100.0 - tail])
    mean = float(np.mean(v))  # the interval holds it also when rounding says otherwise
    return min(float(low), mean), max(float(high), mean)


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval (low, high) of a success rate from ``successes`` of ``n`` trials.

    With p̂ = k/n: centre (p̂ + z²/2n)/(1 + z²/n), half-width
    z √(p̂(1 − p̂)/n + z²/4n²)/(1 + z²/n). Unlike p̂ ± z √(p̂(1 − p̂)/n) it is not degenerate at
    0/n or n/n (0/30 → 0–0.114) and stays in [0, 1]: exactly 0 at 0/n, exactly 1 at n/n.
    ``z`` = :data:`Z95` gives 95 %.

    Raises:
        ValueError: n < 1 or successes not in 0…n.
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n!r}")
    if not 0 <= successes <= n:
        raise ValueError(f"successes must be in 0..n = 0..{n}, got {successes!r}")
    p = successes / n
    scale = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / scale
    half = z * np.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n)) / scale
    # at 0/n and n/n the closed form's bound is 0 and 1 exactly (centre = half), up to rounding
    low = 0.0 if successes == 0 else max(0.0, float(centre - half))
    high = 1.0 if successes == n else min(1.0, float(centre + half))
    return low, high


def _is_integer(x: object) -> bool:
    """An int or numpy integer, not a bool."""
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


#: the keys of :func:`aggregate`'s summary of a metric
SUMMARY_KEYS = ("mean", "std", "ci_low", "ci_high", "median", "worst", "cvar")


def aggregate(spec: MetricSpec, values: np.ndarray) -> dict[str, float]:
    """mean, std, the mean's 95 % interval (ci_low, ci_high: :func:`mean_interval`, NaN for
    fewer than two episodes), median, worst and CVaR(20 %) of one metric over episodes (NaNs
    ignored)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return dict.fromkeys(SUMMARY_KEYS, float("nan"))
    low, high = mean_interval(v)
    return {
        "mean": float(np.mean(v)),
        "std": float(np.std(v)),
        "ci_low": low,
        "ci_high": high,
        "median": float(np.median(v)),
        "worst": spec.worst(v),
        "cvar": cvar(v, spec.better),
    }
