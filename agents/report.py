"""Agents reported the way the field reports them: over training seeds, IQM with bootstrap CIs.

An agent trained with several seeds lives in ``agents/trained/<Env-vN>/<name>/seed_<k>/`` (each
seed directory a complete agent: config, model, statistics, learning curve, meta); an older
single-seed agent directory counts as one seed (:func:`agents.seeds`).

Scores (Agarwal et al., "Deep RL at the edge of the statistical precipice", NeurIPS 2021, the
method of the ``rliable`` library):

* every seed's agent is evaluated on the same episodes (seeds ``seed … seed + n − 1``, as the
  leaderboard runs them); the score matrix is (training seeds × evaluation episodes) of the
  primary metric, each evaluation episode (a fixed reference and start) playing the part of a
  task;
* the point estimate is the **interquartile mean** (IQM, the mean of the middle 50 % of all
  seed-episode scores; ``scipy.stats.trim_mean(x, 0.25)``);
* its 95 % confidence interval is the percentile interval of a **stratified bootstrap**: each
  replicate resamples the training seeds with replacement within every episode column
  (``rliable.library.get_interval_estimates`` when rliable is installed — the ``report``
  extra; the same procedure in numpy otherwise, :func:`stratified_bootstrap_ci`). With one seed
  there is no interval (reported as such).

Learning curves are aggregated the same way per evaluation point (:func:`curve_band`): the IQM
over seeds of each seed's mean evaluation metric, with the bootstrap band over seeds.

Normalized score (:mod:`cir_gym.score_scale`): given a variant's anchors (the hold-still
policy's mean at 0 and the best controller's at 1, measured by the leaderboard on the same
episodes), every (seed, episode) value is scored and the table adds the score's IQM and CI.

For the leaderboard, :func:`seed_reports` evaluates every seed of every shipped agent of an
environment on one variant and :func:`seed_markdown` writes its table once the anchors are
known; ``python -m agents.report --env ID`` writes those tables for every leaderboard variant of
the env to ``results/agents/<Env>_seeds.md``, scored with the anchors of a leaderboard's
``normalized.json`` measured on the same seeds (``--anchors``, default
``results/normalized.json``).
"""

from __future__ import annotations

import csv
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cir_gym.score_scale import Anchors

__all__ = [
    "SeedReport",
    "curve_band",
    "interval",
    "iqm",
    "mean",
    "read_anchors",
    "read_curve",
    "seed_markdown",
    "seed_report",
    "seed_reports",
    "seed_table",
    "stratified_bootstrap_ci",
]

REPS = 2000  # bootstrap replicates
CONFIDENCE = 0.95


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean of all entries: ``scipy.stats.trim_mean(x.ravel(), 0.25)``, written
    out (sort, drop ⌊n/4⌋ at each end, mean of the rest)."""
    x = np.sort(np.asarray(scores, dtype=np.float64).ravel())
    if x.size == 0:
        raise ValueError("iqm of an empty score array")
    cut = int(0.25 * x.size)
    return float(np.mean(x[cut:x.size - cut]))


def stratified_bootstrap_ci(scores: np.ndarray, statistic: Callable[[np.ndarray], float] = iqm,
                            reps: int = REPS, confidence: float = CONFIDENCE,
                            seed: int = 0) -> tuple[float, float]:
    """Percentile CI of ``statistic`` over a stratified bootstrap of the runs (rows), resampled
    with replacement independently in every task column — rliable's ``StratifiedBootstrap``.

    Args:
        scores: (n_runs, n_tasks) or (n_runs,).
    """
    x = np.asarray(scores, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    n_runs, n_tasks = x.shape
    if n_runs < 2:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n_runs, size=(reps, n_runs, n_tasks))
    cols = np.arange(n_tasks)
    stats = np.array([statistic(x[i, cols]) for i in idx])
    alpha = (1.0 - confidence) / 2.0
    lo, hi = np.percentile(stats, [100 * alpha, 100 * (1 - alpha)])
    return float(lo), float(hi)


def mean(scores: np.ndarray) -> float:
    """Mean of all entries: the statistic for a 0/1 outcome such as success, whose IQM is 0
    or 1 whenever the rate is below 25 % or above 75 % (rliable's ``aggregate_mean``)."""
    x = np.asarray(scores, dtype=np.float64)
    if x.size == 0:
        raise ValueError("mean of an empty score array")
    return float(np.mean(x))


def interval(scores: np.ndarray, reps: int = REPS, seed: int = 0, *,
             statistic: str = "iqm") -> tuple[float, float, float]:
    """(statistic, CI low, CI high) of a (runs × tasks) score matrix, with rliable when
    installed; ``statistic`` is ``"iqm"`` (a metric) or ``"mean"`` (a 0/1 success rate)."""
    functions = {"iqm": iqm, "mean": mean}
    if statistic not in functions:
        raise ValueError(f"statistic {statistic!r}: allowed {sorted(functions)}")
    x = np.asarray(scores, dtype=np.float64)
    x = x[:, None] if x.ndim == 1 else x
    point = functions[statistic](x)
    if x.shape[0] < 2:
        return point, float("nan"), float("nan")
    try:
        from rliable import library as rly
        from rliable import metrics
    except ImportError:
        lo, hi = stratified_bootstrap_ci(x, functions[statistic], reps, seed=seed)
        return point, lo, hi
    aggregate = {"iqm": metrics.aggregate_iqm, "mean": metrics.aggregate_mean}[statistic]
    # rliable's StratifiedBootstrap draws its resamples from numpy's global generator
    # (np.random.choice in update_indices), not from the random_state it is given: seed the
    # global one for the call and put its state back, so the same scores give the same CI
    outer = np.random.get_state()  # noqa: NPY002 (the global generator is rliable's)
    np.random.seed(seed)  # noqa: NPY002
    try:
        with warnings.catch_warnings():  # arch: "random_state is deprecated" (rliable's call)
            warnings.simplefilter("ignore", FutureWarning)
            _, cis = rly.get_interval_estimates(
                {"agent": x}, lambda s: np.array([aggregate(s)]), reps=reps,
                random_state=np.random.RandomState(seed))  # rliable takes a RandomState
    finally:
        np.random.set_state(outer)  # noqa: NPY002
    return point, float(cis["agent"][0, 0]), float(cis["agent"][1, 0])


@dataclass
class SeedReport:
    """One agent on one variant over its training seeds.

    Attributes:
        name: the agent's name.
        seeds: training seeds (one row of ``scores`` each).
        scores: (n_seeds, n_episodes) primary metric.
        success: (n_seeds, n_episodes) 0/1.
        primary: the metric's name.
        iqm, ci_low, ci_high: IQM of ``scores`` and its 95 % stratified-bootstrap CI (NaN with
            one seed).
    """

    name: str
    seeds: list[int]
    scores: np.ndarray
    success: np.ndarray
    primary: str
    iqm: float
    ci_low: float
    ci_high: float

    @property
    def seed_means(self) -> np.ndarray:
        return self.scores.mean(axis=1)


def seed_report(env_id: str, name: str, env_kwargs: dict[str, Any] | None = None, *,
                episodes: int = 10, seed: int = 1000, metric: str | None = None,
                batched: bool = False) -> SeedReport:
    """Evaluate every training seed of shipped agent ``name`` on ``episodes`` episodes, scored
    on ``metric`` (default: the environment's primary metric; a leaderboard variant passes its
    own, :func:`cir_gym.evaluation.variant_primary_metric`). ``batched``: each seed's episodes
    run at once where :func:`cir_gym.evaluation.batchable` allows it (equal to the sequential
    ones to float rounding amplified by the closed loop, not bit for bit: the leaderboard's
    tolerance, ``tests/test_batched_agents.py``), else one after the other."""
    import cir_gym
    from cir_gym import agents
    from cir_gym.evaluation import batchable, evaluate

    primary = metric or cir_gym.ENVIRONMENTS[env_id.split(":")[-1]][0].primary_metric
    train_seeds = agents.seeds(env_id, name)
    scores, success = [], []
    for k in train_seeds:
        policy = agents.load(env_id, name, seed=k)
        at_once = batched and batchable(policy, env_id, **(env_kwargs or {}))
        result = evaluate(policy, env_id, episodes, seed, policy_name=name,
                          batched=True if at_once else None, **(env_kwargs or {}))
        scores.append([ep.metrics.get(primary, np.nan) for ep in result.episodes])
        success.append([float(ep.success) for ep in result.episodes])
    s = np.array(scores, dtype=np.float64)
    point, lo, hi = interval(s)
    return SeedReport(name, train_seeds, s, np.array(success), primary, point, lo, hi)


def _fmt(x: float) -> str:
    return "—" if not np.isfinite(x) else f"{x:.3g}"


def seed_reports(env_id: str, env_kwargs: dict[str, Any] | None = None, *, episodes: int = 10,
                 seed: int = 1000, names: list[str] | None = None,
                 metric: str | None = None, batched: bool = False) -> list[SeedReport]:
    """:func:`seed_report` of every shipped agent of ``env_id`` trained for the variant's task
    (``env_kwargs``, :func:`agents.trained_for`), or of ``names`` (``batched``: as there)."""
    from cir_gym import agents

    if names is None:  # every agent trained for this variant's task (agents.trained_for)
        names = [n for n in agents.available(env_id)
                 if agents.trained_for(env_id, n, env_kwargs or {})]
    return [seed_report(env_id, n, env_kwargs, episodes=episodes, seed=seed, metric=metric,
                        batched=batched)
            for n in names]


def seed_markdown(reports: list[SeedReport], anchors: Anchors | None = None) -> str:
    """Markdown table of :func:`seed_reports`: seeds, IQM of the metric [95 % CI], mean success
    rate [CI], each seed's mean and, given the variant's ``anchors`` (the leaderboard's
    hold-still policy and best controller on the same episodes, :mod:`cir_gym.score_scale`),
    the IQM of the normalized score over (seeds × episodes) [CI]. "" without reports."""
    if not reports:
        return ""
    primary, episodes = reports[0].primary, reports[0].scores.shape[1]
    if anchors is not None and anchors.metric != primary:
        raise ValueError(f"the anchors are on {anchors.metric!r}, the reports on {primary!r}")
    score_head = " | IQM score | score CI" if anchors is not None else ""
    lines = [
        f"Agents over training seeds: IQM of `{primary}` over (seeds × {episodes} episodes), "
        f"95 % stratified-bootstrap CI over seeds ({REPS} replicates; agents/report.py); "
        "success: the mean rate over (seeds × episodes), same CI (an IQM of a 0/1 outcome "
        "trims any rate below 25 % to 0)"
        + (f"; normalized {anchors.describe()}, each episode scored, IQM and CI as above"
           if anchors is not None else "") + ".",
        "",
        f"| agent | seeds | IQM {primary} | 95 % CI | success (mean) | success CI | per seed"
        f"{score_head} |",
        "|---|---|---|---|---|---|---|" + ("---|---|" if anchors is not None else ""),
    ]
    for r in reports:
        s_point, s_lo, s_hi = interval(r.success, statistic="mean")
        per_seed = ", ".join(f"{m:.3g}" for m in r.seed_means)
        one = len(r.seeds) < 2
        ci = "one seed: none" if one else f"[{_fmt(r.ci_low)}, {_fmt(r.ci_high)}]"
        s_ci = "—" if one else f"[{_fmt(s_lo)}, {_fmt(s_hi)}]"
        score = ""
        if anchors is not None:
            n_point, n_lo, n_hi = interval(anchors.scores(r.scores))
            score = f" | {_fmt(n_point)} | " + ("—" if one else f"[{_fmt(n_lo)}, {_fmt(n_hi)}]")
        lines.append(f"| {r.name} | {len(r.seeds)} | {_fmt(r.iqm)} | {ci} | {_fmt(s_point)} | "
                     f"{s_ci} | {per_seed}{score} |")
    return "\n".join(lines)


def seed_table(env_id: str, env_kwargs: dict[str, Any] | None = None, *, episodes: int = 10,
               seed: int = 1000, names: list[str] | None = None, metric: str | None = None,
               anchors: Anchors | None = None, batched: bool = False) -> str:
    """Markdown table: every shipped agent of ``env_id`` trained for the variant's task (or
    ``names``) over its training seeds on one variant (``env_kwargs``):
    :func:`seed_markdown` of :func:`seed_reports` (with the normalized score given the
    variant's ``anchors``; ``metric`` defaults to theirs; ``batched``: as there)."""
    metric = metric or (anchors.metric if anchors is not None else None)
    return seed_markdown(seed_reports(env_id, env_kwargs, episodes=episodes, seed=seed,
                                      names=names, metric=metric, batched=batched), anchors)


def read_anchors(path: Path, env_id: str, variant: str, episodes: int,
                 seed: int) -> Anchors | None:
    """The anchors of one variant from a leaderboard's ``normalized.json``
    (:func:`cir_gym.scoring.leaderboard.run_leaderboard` writes it), or None when the file is
    missing, lacks the variant or was measured on other episodes than ``episodes`` from
    ``seed`` (a score needs its anchors on the same seeds)."""
    import json

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    if (data.get("episodes"), data.get("seed")) != (episodes, seed):
        return None
    entry = data.get("variants", {}).get(f"{env_id} {variant}")
    return Anchors.from_dict(entry) if entry else None


def read_curve(path: Path, primary: str) -> tuple[np.ndarray, np.ndarray]:
    """(timesteps, column ``mean_<primary>``) of an agent directory's ``learning_curve.csv``
    (or of that CSV file itself); ``primary="return"`` reads the mean evaluation return."""
    path = Path(path)
    with (path / "learning_curve.csv" if path.is_dir() else path).open() as f:
        rows = list(csv.DictReader(f))
    return (np.array([int(r["timesteps"]) for r in rows]),
            np.array([float(r[f"mean_{primary}"]) for r in rows]))


def curve_band(curves: list[tuple[np.ndarray, np.ndarray]], reps: int = REPS
               ) -> dict[str, np.ndarray]:
    """Aggregate seeds' learning curves at the evaluation steps they all have.

    Where the seeds were evaluated at different steps (a run resumed with another evaluation
    period, say) and share fewer steps than the sparsest seed has inside their common range,
    each seed is interpolated linearly onto the sparsest seed's steps in that range
    (``interpolated`` is then True), instead of aggregating the few coinciding points, or
    none.

    Returns ``steps``, ``iqm``, ``low``, ``high`` (the stratified-bootstrap band over seeds,
    NaN with one seed), ``seeds`` (n_seeds, n_steps) and ``interpolated``."""
    if not curves:
        raise ValueError("no learning curves")
    common = sorted(set.intersection(*(set(t.tolist()) for t, _ in curves)))
    start = max(int(t[0]) for t, _ in curves)
    stop = min(int(t[-1]) for t, _ in curves)
    inside = [t[(t >= start) & (t <= stop)] for t, _ in curves]
    sparsest = min(inside, key=len)
    interpolated = len(common) < len(sparsest)
    if interpolated:
        common = sparsest.tolist()
        values = np.array([np.interp(common, t, v) for t, v in curves])
    else:
        values = np.array([[v[list(t).index(s)] for s in common] for t, v in curves])
    if not common:
        raise ValueError("the learning curves share no range of training steps")
    out = {"steps": np.array(common), "seeds": values, "interpolated": interpolated,
           "iqm": np.array([iqm(values[:, j]) for j in range(len(common))])}
    bands = [interval(values[:, j], reps=reps)[1:] for j in range(len(common))]
    out["low"] = np.array([b[0] for b in bands])
    out["high"] = np.array([b[1] for b in bands])
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m agents.report --env ID [--agent NAME ...] [--episodes 10] [--seed 1000]``:
    :func:`seed_table` for every leaderboard variant of ``ID``, to ``--out``."""
    import argparse
    import sys

    import cir_gym

    p = argparse.ArgumentParser(description="shipped agents over training seeds (IQM, CIs)")
    p.add_argument("--env", required=True, help="environment id, e.g. cir_gym/JointTracking-v2")
    p.add_argument("--agent", action="append", help="agent name (repeatable; default: all)")
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--seed", type=int, default=1000, help="first evaluation seed (leaderboard)")
    p.add_argument("--out", help="markdown file (default results/agents/<Env>_seeds.md)")
    p.add_argument("--anchors", default="results/normalized.json",
                   help="a leaderboard's normalized.json: the hold-still and best-controller "
                   "means of each variant, for the normalized score (used when measured on the "
                   "same --episodes and --seed; default: %(default)s)")
    args = p.parse_args(argv)
    key = args.env.split(":")[-1]
    if key not in cir_gym.ENVIRONMENTS:
        p.error(f"unknown environment {args.env!r}; valid: {sorted(cir_gym.ENVIRONMENTS)}")
    from cir_gym.agents import env_dir_name

    from cir_gym.evaluation import variant_primary_metric

    cls = cir_gym.ENVIRONMENTS[key][0]
    out = Path(args.out or f"results/agents/{env_dir_name(key)}_seeds.md")
    parts = [f"# {key}: shipped agents over training seeds (`python -m agents.report`)", "",
             f"Evaluation seeds {args.seed}–{args.seed + args.episodes - 1} (the leaderboard's), "
             f"deterministic actions; every training seed's agent on the same episodes.", ""]
    variants = getattr(cls, "leaderboard_variants", None) or {"default": {}}
    for variant, kwargs in variants.items():
        print(f"{key} {variant}", file=sys.stderr)
        anchors = read_anchors(Path(args.anchors), key, variant, args.episodes, args.seed)
        parts += [f"## {variant} `{kwargs}`", "",
                  seed_table(key, kwargs, episodes=args.episodes, seed=args.seed,
                             names=args.agent, metric=variant_primary_metric(cls, variant),
                             anchors=anchors),
                  "" if anchors is not None else
                  f"\n(no normalized score: {args.anchors} has no anchors of this variant "
                  f"measured on these {args.episodes} episodes from seed {args.seed}; "
                  "`cir-gym leaderboard` writes them)\n"]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(parts))
    print(out, file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
