"""Tables of evaluation results: a ranked table per variant, the controllers-vs-RL summary,
each with the normalized score (0 = hold still, 1 = the best controller) where the variant's
anchors are given (:mod:`cir_gym.score_scale`, :mod:`cir_gym.scoring.normalized`)."""

from __future__ import annotations

import math

import numpy as np

from cir_gym.evaluation import EvaluationResult, rank
from cir_gym.metrics import BOOTSTRAP_RESAMPLES, wilson_interval
from cir_gym.score_scale import Anchors

#: the normalized score's column header and what it means
SCORE_HEADER = "score"
SCORE_MEANING = "normalized score: 0 = hold still, 1 = the best controller"
#: the primary metric's and the success rate's column headers (after the metric's name and
#: unit, and "success") and what their intervals are
MEAN_HEADER = "mean [95 % CI]"
#: fewest episodes whose mean a table shows with its interval: a percentile bootstrap of the
#: mean covers ~74 % at 3 episodes, ~83 % at 5, ~90 % at 10 and ~93 % at 30 instead of 95 %
#: (2000 normal samples of each size, 2000 resamples each)
MIN_INTERVAL_EPISODES = 10
MEAN_MEANING = (
    "95 % CI: percentile bootstrap of the mean over the episodes' seeds "
    f"({BOOTSTRAP_RESAMPLES:,} resamples, a fixed generator seed: the same episodes give the "
    f"same interval); below {MIN_INTERVAL_EPISODES} episodes the mean alone (there the "
    "bootstrap covers far less than 95 %: ~74 % at 3 episodes)"
)
SUCCESS_HEADER = "(95 % Wilson)"
SUCCESS_MEANING = "success rate (low–high): its 95 % Wilson interval, in %"


def score_of(r: EvaluationResult, anchors: Anchors | None) -> float | None:
    """The normalized score of ``r``'s mean on the anchors' metric, None without anchors."""
    if anchors is None:
        return None
    return anchors.score(r.summary[anchors.metric]["mean"])


def score_cell(score: float | None) -> str:
    """A score as a table shows it: two decimals, "–" for none or NaN."""
    return "–" if score is None or not np.isfinite(score) else f"{score:.2f}"


def interval_cell(mean: float, low: float, high: float) -> str:
    """A mean and its interval at one precision: three significant digits of the largest of
    the three, ``6.98 [6.41, 7.60]``; the mean alone (``.3g``) without an interval (NaN)."""
    if not (np.isfinite(low) and np.isfinite(high) and np.isfinite(mean)):
        return f"{mean:.3g}"
    largest = max(abs(mean), abs(low), abs(high))
    if largest == 0.0:
        return "0 [0, 0]"
    if not 1e-4 <= largest < 1e5:
        return f"{mean:.3g} [{low:.3g}, {high:.3g}]"
    decimals = max(0, 2 - math.floor(math.log10(largest)))
    return f"{mean:.{decimals}f} [{low:.{decimals}f}, {high:.{decimals}f}]"


def mean_cell(r: EvaluationResult, metric: str) -> str:
    """``metric``'s mean over ``r``'s episodes with its 95 % interval (:func:`interval_cell`);
    the mean alone from fewer than :data:`MIN_INTERVAL_EPISODES` episodes or a summary
    without ``ci_low``/``ci_high``."""
    s = r.summary[metric]
    nan = float("nan")
    if len(r.episodes) < MIN_INTERVAL_EPISODES:
        return interval_cell(s["mean"], nan, nan)
    return interval_cell(s["mean"], s.get("ci_low", nan), s.get("ci_high", nan))


def success_cell(r: EvaluationResult) -> str:
    """The success rate with its 95 % Wilson interval in %: ``87 % (70–95)``."""
    n = len(r.episodes)
    if n == 0:
        return "–"
    low, high = wilson_interval(sum(bool(ep.success) for ep in r.episodes), n)
    return f"{100 * r.success_rate:.0f} % ({100 * low:.0f}–{100 * high:.0f})"


def format_table(results: list[EvaluationResult], markdown: bool = True,
                 anchors: Anchors | None = None) -> str:
    """A table ranked on the primary metric: its mean with the 95 % bootstrap interval
    (:data:`MEAN_MEANING`), worst, CVaR, success with its 95 % Wilson interval, the normalized
    score on the variant's ``anchors`` (a column only when given), the other metrics' means,
    return."""
    if not results:
        return "(no results)"
    primary = results[0].primary_metric
    spec = results[0].spec(primary)
    reverse = spec.better == "higher"
    ranked = sorted(results, key=lambda r: _nan_last(r.summary[primary]["mean"], reverse))
    other = [s for s in results[0].specs if s.name != primary]
    unit = f" ({spec.unit})" if spec.unit else ""
    head = (
        ["rank", "policy", f"{primary}{unit} {MEAN_HEADER}", f"worst{unit}", f"CVaR 20 %{unit}",
         f"success {SUCCESS_HEADER}"]
        + ([SCORE_HEADER] if anchors is not None else [])
        + [f"{s.name} ({s.unit})" if s.unit else s.name for s in other]
        + ["return", "diverged"]
    )
    rows = []
    for i, r in enumerate(ranked, 1):
        s = r.summary[primary]
        rows.append(
            [
                str(i),
                r.policy_name,
                mean_cell(r, primary),
                f"{s['worst']:.3g}",
                f"{s['cvar']:.3g}",
                success_cell(r),
            ]
            + ([score_cell(score_of(r, anchors))] if anchors is not None else [])
            + [f"{r.summary[o.name]['mean']:.3g}" for o in other]
            + [f"{r.summary['return']['mean']:.1f}", f"{100 * r.divergence_rate:.0f}%"]
        )
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(row) + " |" for row in rows]
        return "\n".join(lines)
    widths = [max(len(x) for x in col) for col in zip(head, *rows, strict=True)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    return "\n".join(fmt.format(*row) for row in [head, *rows])


def _nan_last(value: float, reverse: bool) -> float:
    if value != value:  # NaN
        return float("inf")
    return -value if reverse else value


def ranked_table(rows: list[EvaluationResult], anchors: Anchors | None = None) -> str:
    """:func:`format_table`'s markdown table (with the score column given the variant's
    ``anchors``), rows in :func:`rank`'s order (success rate, then the primary metric) instead
    of the primary metric alone."""
    if not rows:
        return format_table(rows)
    tables = [format_table([r], anchors=anchors).split("\n") for r in rank(rows)]
    return "\n".join(
        [
            *tables[0][:2],
            *(f"| {i} |" + table[2].split("|", 2)[2] for i, table in enumerate(tables, 1)),
        ]
    )


def best(group: list[EvaluationResult]) -> EvaluationResult | None:
    """The best result of ``group`` (:func:`rank`: the highest success rate, then the best
    primary-metric mean; NaN never wins). Success first, because an episode that ends early —
    at a joint limit, on an obstacle — can still show a small tracking error."""
    finite = [r for r in group if np.isfinite(r.summary[r.primary_metric]["mean"])]
    return rank(finite)[0] if finite else None


#: in a summary cell, the factor to the best controller left out (:func:`censored_ratio`)
NO_FACTOR = "–†"


def censored_ratio(r: EvaluationResult, reference: EvaluationResult) -> bool:
    """Whether the factor of ``r`` to ``reference`` on their primary metric would compare
    censored values: the metric scores a failed episode at a fixed limit
    (``MetricSpec.failure_scores_limit``, PegInHole's ``insertion_time``: the time limit) and
    either mean includes a failed episode. A 0 %-success agent's mean is then the limit
    itself, and a partly successful one's is pulled towards it: the ratio would measure the
    failures, not the metric. Other metrics are measured in every episode, so their ratios
    stand (the success rate is printed beside them)."""
    spec = r.spec(r.primary_metric)
    return spec.failure_scores_limit and min(r.success_rate, reference.success_rate) < 1.0


def _metric_cell(r: EvaluationResult) -> str:
    """The primary metric's name and unit: `insertion_time` (s)."""
    unit = r.spec(r.primary_metric).unit
    return f"`{r.primary_metric}`" + (f" ({unit})" if unit else "")


def _summary_cell(r: EvaluationResult | None, reference: EvaluationResult | None,
                  anchors: Anchors | None = None) -> str:
    """'name: mean [95 % CI] (worst, success (95 % Wilson)[, score])' and, given a reference,
    the factor to it (> 1: worse); :data:`NO_FACTOR` instead of a factor of censored values
    (:func:`censored_ratio`); the normalized score given the variant's ``anchors``."""
    if r is None:
        return "–"
    primary = r.primary_metric
    s = r.summary[primary]
    score = f", score {score_cell(score_of(r, anchors))}" if anchors is not None else ""
    text = (
        f"{r.policy_name}: {mean_cell(r, primary)} (worst {s['worst']:.3g}, "
        f"{success_cell(r)} success{score})"
    )
    if reference is not None:
        c = reference.summary[primary]["mean"]
        if censored_ratio(r, reference):
            text += f", {NO_FACTOR}"
        elif np.isfinite(c) and c > 0 and s["mean"] > 0:  # a ratio of clearances < 0 says nothing
            higher = r.spec(primary).better == "higher"
            factor = c / s["mean"] if higher else s["mean"] / c
            text += f", **{factor:.3g}×** the best controller's"
    return text


def rl_summary(by_variant: dict[str, list[EvaluationResult]],
               anchors: dict[str, Anchors | None] | None = None) -> str:
    """Per variant: the best controller, the best from-scratch agent and the best residual
    agent on the primary metric (mean), with success, worst episode, the normalized score
    where ``anchors`` (variant → its anchors) has the variant's, and the factor to the best
    controller (> 1: worse than it, in the metric's own direction); a footnote under the
    table when a factor is left out (:func:`censored_ratio`)."""
    lines = [
        "| variant | ranked on | best controller, course gains | best controller, tuned gains "
        "| best from-scratch RL | best residual RL |",
        "|---|---|---|---|---|---|",
    ]
    censored: set[str] = set()
    for variant, rows in by_variant.items():
        if not rows:
            continue
        course = best([r for r in rows if not r.policy_name.startswith(("agent:", "tuned:"))])
        tuned = best([r for r in rows if r.policy_name.startswith("tuned:")])
        ctrl = best([r for r in (course, tuned) if r is not None])  # the bar for RL
        agents_ = [r for r in rows if r.policy_name.startswith("agent:")]
        scratch = best([r for r in agents_ if "residual" not in r.policy_name])
        residual = best([r for r in agents_ if "residual" in r.policy_name])
        for r in (scratch, residual):
            if r is not None and ctrl is not None and censored_ratio(r, ctrl):
                censored.add(r.primary_metric)
        a = (anchors or {}).get(variant)
        lines.append(
            f"| {variant} | {_metric_cell(rows[0])} | {_summary_cell(course, None, a)} | "
            f"{_summary_cell(tuned, None, a)} | "
            f"{_summary_cell(scratch, ctrl, a)} | {_summary_cell(residual, ctrl, a)} |"
        )
    notes = []
    if any(r.policy_name.startswith("agent:residual") for rows in by_variant.values()
           for r in rows):
        notes += [
            "",
            "A residual agent carries its base controller as designed from the context of the "
            "env it was trained on (`agents.load`), on every variant: where a variant tells the "
            "controllers more than training did (AdmittanceContact's fixed stiffnesses, against "
            "an agent trained on `randomize=True`, whose `admittance` designs for the worst "
            "case), the gap to the best controller includes that information "
            "(docs/research/agents.md).",
        ]
    if censored:
        names = ", ".join(f"`{m}`" for m in sorted(censored))
        notes += [
            "",
            f"{NO_FACTOR[-1]} No factor to the best controller: a failed episode scores {names} "
            "at a fixed limit (a time: the time limit), not a measured value, and a mean here "
            "includes failed episodes (at 0 % success it is the limit itself), so the ratio would "
            "compare the limit with measured values.",
        ]
    return "\n".join(
        [
            "Controllers vs RL on each variant's primary metric (mean over the same "
            "seeds [its 95 % bootstrap interval], the success rate (its 95 % Wilson interval); "
            "best = highest success rate, then the best mean). A controller runs at the "
            "course's gains and, as `tuned:<controller>`, at the gains `scripts/tune_gains.py` "
            "found for the variant (Optuna on training seeds; results/tuning/); an agent's "
            "factor is to the better of the two best controllers"
            + (f"; *score* is the {SCORE_MEANING} on the variant's metric (its anchors under "
               "each ranked table)" if any((anchors or {}).values()) else "") + ":",
            "",
            *lines,
            *notes,
        ]
    )


def slug(text: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in text).strip("_").lower()
