"""The main job: every applicable controller and shipped agent on every environment variant.

Each environment class declares ``leaderboard_variants`` (name → constructor kwargs, e.g. a
3 kg unknown payload) and, optionally, ``leaderboard_primary_metrics`` (variant → the metric
it is ranked on, e.g. RedundantIK's "manipulability" variant on ``min_manipulability``; the
class's ``primary_metric`` otherwise). Every (variant, policy) pair runs on the same seeds in a
pool of worker processes (one per core); the tables in ``<out>/leaderboard.md`` rank by success
rate, then by the variant's primary metric (:func:`cir_gym.evaluation.rank`), and a PNG per
variant is written beside them. The output is
deterministic for a given seed (no timings in the tables).
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

import cir_gym
from cir_gym.evaluation import EvaluationResult, evaluate, variant_primary_metric
from cir_gym.scoring.page import write_page
from cir_gym.scoring.tables import ranked_table, rl_summary, slug


def jobs_for(
    env_id: str, overrides: dict[str, Any] | None = None
) -> list[tuple[str, str, dict[str, Any], str]]:
    """(env_id, variant name, env kwargs, policy name) for every pair to evaluate: every
    controller on every variant, at its course gains and, where ``scripts/tune_gains.py``
    tuned it for exactly the variant's arguments, at those gains (``tuned:<controller>``,
    :func:`cir_gym.cli.tuned_gains`); a shipped agent only on the variants of the task it was
    trained for (:func:`agents.trained_for`: RedundantIK's objective)."""
    from cir_gym.scoring.policies import has_tuned_gains, policy_names, trained_for

    cls = cir_gym.ENVIRONMENTS[env_id][0]
    variants = getattr(cls, "leaderboard_variants", {"default": {}})
    return [
        (env_id, v, {**kw, **(overrides or {})}, p)
        for v, kw in variants.items()
        for p in policy_names(env_id)
        if trained_for(env_id, p, {**kw, **(overrides or {})})
        and has_tuned_gains(env_id, p, {**kw, **(overrides or {})})
    ]


def run_job(
    job: tuple[str, str, dict[str, Any], str], episodes: int, seed: int
) -> tuple[tuple[str, str, str], EvaluationResult, float]:
    from cir_gym.scoring.policies import make_policy

    env_id, variant, env_kwargs, policy_name = job
    t0 = time.perf_counter()
    policy = make_policy(env_id, policy_name, env_kwargs, {})
    result = evaluate(policy, env_id, episodes, seed, policy_name=policy_name, **env_kwargs)
    result = result.ranked_on(variant_primary_metric(cir_gym.ENVIRONMENTS[env_id][0], variant))
    return (env_id, variant, policy_name), result, time.perf_counter() - t0


def _progress(total: int) -> Any:
    try:
        from tqdm import tqdm

        return tqdm(total=total, desc="leaderboard", unit="run", file=sys.stderr)
    except ImportError:  # pragma: no cover
        return None


def run_leaderboard(
    out: Path,
    episodes: int = 10,
    seed: int = 1000,
    envs: list[str] | None = None,
    workers: int | None = None,
    env_overrides: dict[str, Any] | None = None,
) -> Path:
    """Evaluate everything, write ``out/leaderboard.md`` and the figures; return the md path.

    ``env_overrides`` are added to every environment's kwargs (e.g. a short
    ``episode_duration`` for tests).
    """
    from cir_gym.scoring.plotting import plot_comparison

    env_ids = envs or list(cir_gym.ENVIRONMENTS)
    jobs = [j for e in env_ids for j in jobs_for(e, env_overrides)]
    workers = workers or min(len(jobs), os.cpu_count() or 1)
    results: dict[tuple[str, str, str], EvaluationResult] = {}
    seconds: dict[tuple[str, str, str], float] = {}
    bar = _progress(len(jobs))
    t0 = time.perf_counter()
    # spawn, not fork: a child forked from a parent that has already run torch (an agent's
    # policy, a test that trained one) can deadlock in torch's thread pool at its first op.
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=spawn) as pool:
        futures = [pool.submit(run_job, j, episodes, seed) for j in jobs]
        for fut in as_completed(futures):
            key, result, sec = fut.result()
            results[key], seconds[key] = result, sec
            if bar is not None:
                bar.set_postfix_str(f"{key[0].split('/')[-1]} {key[1]} {key[2]}")
                bar.update(1)
    if bar is not None:
        bar.close()
    out.mkdir(parents=True, exist_ok=True)
    lines = [
        "# cir_gym leaderboard",
        "",
        f"{episodes} episodes per policy, seeds {seed}…{seed + episodes - 1} (the same for every "
        "policy). Ranked by success rate, then by each variant's primary metric (mean over "
        "episodes; the environment's, or the variant's own, e.g. the manipulability of "
        "RedundantIK's manipulability variant); *worst* is the worst episode, CVaR20% the mean "
        "of the worst 20 %. Generated by `cir-gym leaderboard`.",
        "",
    ]
    seed_tables: dict[tuple[str, str], str] = {}
    for env_id in env_ids:
        cls, description = cir_gym.ENVIRONMENTS[env_id]
        lines += [f"## {env_id}", "", description, ""]
        variants = getattr(cls, "leaderboard_variants", {"default": {}})
        by_variant = {
            v: [r for (e, vv, _), r in sorted(results.items()) if e == env_id and vv == v]
            for v in variants
        }
        lines += [rl_summary(by_variant), ""]
        for variant, kwargs in variants.items():
            rows = by_variant[variant]
            setting = ", ".join(f"{k}={v}" for k, v in kwargs.items()) or "default arguments"
            lines += [f"### {variant} ({setting})", "", ranked_table(rows), ""]
            seeds_md = multi_seed_table(env_id, {**kwargs, **(env_overrides or {})}, episodes, seed)
            if seeds_md:
                seed_tables[(env_id, variant)] = seeds_md
                lines += [seeds_md, ""]
            fig = out / f"{env_id.split('/')[-1]}_{slug(variant)}.png"
            plot_comparison(rows, fig, title=f"{env_id} — {variant}")
            lines += [f"![{env_id} {variant}]({fig.name})", ""]
    md = out / "leaderboard.md"
    md.write_text("\n".join(lines))
    write_page(
        out,
        results,
        env_ids,
        episodes,
        seed,
        env_overrides,
        workers,  # index.html
        extra=seed_tables,
    )
    print(
        f"wrote {md} in {time.perf_counter() - t0:.0f} s "
        f"(slowest run {max(seconds.values()):.0f} s)",
        file=sys.stderr,
    )
    print(md.read_text())
    return md


def multi_seed_table(env_id: str, env_kwargs: dict[str, Any], episodes: int, seed: int) -> str:
    """The shipped agents of ``env_id`` trained over >= 2 seeds (``<name>/seed_<k>/``) on one
    variant, over all their seeds: :func:`agents.report.seed_table` (IQM of the primary metric
    with its stratified-bootstrap CI over seeds). "" when there is none (or no train extra).
    The ranked table above it shows such an agent's first seed only."""
    from cir_gym.scoring.policies import agents_module

    ag = agents_module()
    if ag is None:
        return ""
    names = [n for n in ag.available(env_id)
             if len(ag.seeds(env_id, n)) >= 2 and ag.trained_for(env_id, n, env_kwargs)]
    if not names:
        return ""
    from cir_gym.agents.report import seed_table

    return seed_table(env_id, env_kwargs, episodes=episodes, seed=seed, names=names)


# ---------------------------------------------------------------------- a sweep's table
def _label(row: dict[str, Any]) -> str:
    """A policy's name in a sweep's tables: the policy, its gains, its training seed."""
    gains = ", ".join(
        f"{k[5:]}={row[k]}" for k in sorted(row) if k.startswith("gain.") and row[k] is not None
    )
    label = f"{row['policy']} ({gains})" if gains else str(row["policy"])
    if row.get("train_seed") is not None:
        label += f" seed {row['train_seed']}"
    return label


def sweep_results(rows: list[dict[str, Any]]) -> dict[tuple[str, str], dict[str, EvaluationResult]]:
    """A sweep's finished episodes as (env_id, variant) → {policy label: EvaluationResult},
    ranked on the variant's primary metric; nothing is re-run."""
    from cir_gym.evaluation import EpisodeResult

    groups: dict[tuple[str, str], dict[str, list[dict[str, Any]]]] = {}
    for r in rows:
        if r.get("status") == "ok" and r.get("episode_seed") is not None:
            groups.setdefault((r["env_id"], r["variant"]), {}).setdefault(_label(r), []).append(r)
    out: dict[tuple[str, str], dict[str, EvaluationResult]] = {}
    for (env_id, variant), by_label in sorted(groups.items()):
        cls = cir_gym.ENVIRONMENTS[env_id][0]
        specs = tuple(cls.metric_specs)
        primary = variant_primary_metric(cls, variant)
        out[(env_id, variant)] = {}
        for label, eps in sorted(by_label.items()):
            episodes = [
                EpisodeResult(
                    seed=int(e["episode_seed"]),
                    episode_return=float(e["return"]),
                    length=int(e["length"]),
                    success=bool(e["success"]),
                    diverged=bool(e["diverged"]),
                    terminated=bool(e["terminated"]),
                    metrics={
                        s.name: float(e[f"metric.{s.name}"])
                        for s in specs
                        if e.get(f"metric.{s.name}") is not None
                    },
                )
                for e in sorted(eps, key=lambda e: e["episode_seed"])
            ]
            out[(env_id, variant)][label] = EvaluationResult(
                env_id, label, episodes, specs, primary
            )
    return out


def training_seed_table(results: dict[str, EvaluationResult]) -> str:
    """Training runs of one variant with >= 2 seeds: IQM of the primary metric over (seeds ×
    episodes) with its 95 % stratified-bootstrap CI (:func:`agents.report.interval`, the
    statistics of :func:`agents.report.seed_table`), mean success rate, each seed's mean."""
    from cir_gym.agents.report import interval

    runs: dict[str, list[EvaluationResult]] = {}
    for label, r in results.items():
        if label.startswith("train:") and " seed " in label:
            runs.setdefault(label.rsplit(" seed ", 1)[0], []).append(r)
    runs = {k: v for k, v in runs.items() if len(v) >= 2}
    if not runs:
        return ""
    primary = next(iter(results.values())).primary_metric
    lines = [
        f"Training runs over seeds: IQM of `{primary}` over (seeds × episodes), 95 % "
        "stratified-bootstrap CI over seeds (agents/report.py).",
        "",
        f"| run | seeds | IQM {primary} | 95 % CI | success (mean) | per seed |",
        "|---|---|---|---|---|---|",
    ]
    for name, group in sorted(runs.items()):
        common = sorted(set.intersection(*({e.seed for e in r.episodes} for r in group)))
        scores = np.array(
            [
                [
                    next(e.metrics.get(primary, np.nan) for e in r.episodes if e.seed == s)
                    for s in common
                ]
                for r in group
            ]
        )
        success = np.array(
            [
                [float(next(e.success for e in r.episodes if e.seed == s)) for s in common]
                for r in group
            ]
        )
        point, lo, hi = interval(scores)
        per_seed = ", ".join(f"{m:.3g}" for m in scores.mean(axis=1))
        lines.append(
            f"| {name} | {len(group)} | {point:.3g} | [{lo:.3g}, {hi:.3g}] | "
            f"{interval(success, statistic='mean')[0]:.3g} | {per_seed} |"
        )
    return "\n".join(lines)


def _swept_axis(rows: list[dict[str, Any]]) -> str | None:
    """The one numeric environment argument (``env.<name>``) that varies across ``rows``."""
    varying = []
    for k in sorted({k for r in rows for k in r if k.startswith("env.")}):
        values = {r.get(k) for r in rows}
        if len(values) > 1 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in values
        ):
            varying.append(k)
    return varying[0] if len(varying) == 1 else None


def plot_sweep_axis(rows: list[dict[str, Any]], env_id: str, axis: str, path: Path) -> Path:
    """The primary metric (mean over each policy's episodes) against a swept numeric
    environment argument, one line per policy: where each controller stops coping."""
    from cir_gym.scoring.plotting import _plt

    plt = _plt()
    cls = cir_gym.ENVIRONMENTS[env_id][0]
    primary = cls.primary_metric
    spec = next(s for s in cls.metric_specs if s.name == primary)
    fig, ax = plt.subplots(figsize=(7, 4))
    lines: dict[str, dict[float, list[float]]] = {}
    for r in rows:
        lines.setdefault(_label(r), {}).setdefault(float(r[axis]), []).append(
            float(r.get(f"metric.{primary}") if r.get(f"metric.{primary}") is not None else np.nan)
        )
    positive = True
    for label, points in sorted(lines.items()):
        x = np.array(sorted(points))
        mean = np.array([np.nanmean(points[v]) for v in x])
        positive &= bool(np.all(mean[np.isfinite(mean)] > 0))
        ax.plot(x, mean, marker="o", label=label)
    if positive:
        ax.set_yscale("log")
    ax.set_xlabel(axis[4:])
    ax.set_ylabel(f"{primary} ({spec.unit}), mean" if spec.unit else f"{primary}, mean")
    ax.set_title(f"{env_id}: {primary} against {axis[4:]}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def leaderboard_from(directory: Path, out: Path | None = None) -> Path:
    """``cir-gym leaderboard --from DIR``: a sweep's table (``DIR/results.parquet`` or
    ``.csv``) as ``leaderboard.md``, one figure per (environment, variant), a figure against
    the swept environment argument where one numeric argument varies, and ``index.html``, all
    in ``out`` (default ``DIR``). Ranked as the leaderboard ranks (:func:`ranked_table`);
    training runs over >= 2 seeds also get :func:`training_seed_table`; failed tasks are listed
    with their errors. Returns the markdown's path."""
    from cir_gym.scoring.page import html_page, markdown_to_html
    from cir_gym.scoring.plotting import plot_comparison
    from cir_gym.scoring.sweep import read_table

    directory = Path(directory)
    out = Path(out) if out is not None else directory
    out.mkdir(parents=True, exist_ok=True)
    rows = read_table(directory)
    results = sweep_results(rows)
    ok = [r for r in rows if r.get("status") == "ok" and r.get("episode_seed") is not None]
    failed = [r for r in rows if r.get("status") != "ok"]
    tasks = {r["task_id"] for r in rows}
    lines = [
        "# Sweep leaderboard",
        "",
        f"{len(ok)} episodes of {len(tasks)} tasks ({len(failed)} failed) from the sweep "
        f"in `{directory}`. Ranked by success rate, then by each variant's primary metric "
        "(mean over episodes); *worst* is the worst episode, CVaR20% the mean of the worst "
        "20 %. Generated by `cir-gym leaderboard --from`.",
        "",
    ]
    for env_id in sorted({e for e, _ in results}):
        lines += [f"## {env_id}", ""]
        env_rows = [r for r in ok if r["env_id"] == env_id]
        axis = _swept_axis(env_rows)
        if axis is not None:
            fig = plot_sweep_axis(
                env_rows, env_id, axis, out / f"{env_id.split('/')[-1]}_vs_{slug(axis[4:])}.png"
            )
            lines += [f"![{env_id} against {axis[4:]}]({fig.name})", ""]
        for (e, variant), by_label in results.items():
            if e != env_id:
                continue
            group = list(by_label.values())
            first = next(r for r in env_rows if r["variant"] == variant)
            setting = ", ".join(
                f"{k[4:]}={first[k]}"
                for k in sorted(first)
                if k.startswith("env.") and first[k] is not None
            )
            lines += [
                f"### {variant} ({setting or 'default arguments'})",
                "",
                ranked_table(group),
                "",
            ]
            seeds_md = training_seed_table(by_label)
            if seeds_md:
                lines += [seeds_md, ""]
            fig = out / f"{env_id.split('/')[-1]}_{slug(variant)}.png"
            plot_comparison(group, fig, title=f"{env_id} — {variant}")
            lines += [f"![{env_id} {variant}]({fig.name})", ""]
    if failed:
        lines += [
            "## Failed tasks",
            "",
            "| task | environment | variant | policy | error |",
            "|---|---|---|---|---|",
        ]
        lines += [
            f"| {r['task_id']} | {r['env_id']} | {r['variant']} | {_label(r)} | "
            f"{str(r['error']).replace('|', '/')} |"
            for r in failed
        ]
        lines.append("")
    md = out / "leaderboard.md"
    md.write_text("\n".join(lines))
    (out / "index.html").write_text(
        html_page("cir_gym sweep leaderboard", markdown_to_html("\n".join(lines))), encoding="utf-8"
    )
    return md
