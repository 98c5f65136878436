"""The main job: every applicable controller and shipped agent on every environment variant.

Each environment class declares ``leaderboard_variants`` (name → constructor kwargs, e.g. a
3 kg unknown payload) and, optionally, ``leaderboard_primary_metrics`` (variant → the metric
it is ranked on, e.g. RedundantIK's "manipulability" variant on ``min_manipulability``; the
class's ``primary_metric`` otherwise). Every (variant, policy) pair runs on the same seeds in a
pool of worker processes (one per core); the tables in ``<out>/leaderboard.md`` rank by success
rate, then by the variant's primary metric (:func:`cir_gym.evaluation.rank`), a PNG per
variant is written beside them and ``<out>/index.html`` (:mod:`cir_gym.scoring.page`) shows
it all with a video per variant. A task's tables hold every interface that plays it: the
policies of an agent-ready variant (``cir_gym/PegInHoleImpedance-v0`` plays
``cir_gym/PegInHole-v2``, :func:`cir_gym.scoring.policies.task_id`) run on the task's
variants with the same kwargs and seeds, and their rows are labelled with the interface
(``impedance_insertion [PegInHoleImpedance-v0]``, :func:`row_key`). Every variant also runs
the hold-still policy
(:func:`cir_gym.scoring.normalized.hold_still_policy`) on the same seeds: with the best
controller it anchors each policy's normalized score on the variant's primary metric (0 = hold
still, 1 = the best controller; :mod:`cir_gym.score_scale`), a column of every table, and the
anchors go to ``<out>/normalized.json``. The tables are deterministic for a given seed (no
timings in them); the time per episode of each policy goes to ``<out>/timings.json``, the next run's
estimate. ``cir-gym leaderboard`` writes into ``runs/leaderboard/`` (untracked) unless
``--out`` names another folder (``--out results/`` regenerates the repository's results).
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
import shutil
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import cir_gym
from cir_gym.evaluation import EvaluationResult, batchable, evaluate, variant_primary_metric
from cir_gym.score_scale import Anchors
from cir_gym.scoring.normalized import HoldStill, hold_still_policy, variant_anchors
from cir_gym.scoring.page import write_page
from cir_gym.scoring.tables import (
    MEAN_MEANING,
    SCORE_MEANING,
    SUCCESS_MEANING,
    ranked_table,
    rl_summary,
    score_cell,
    slug,
)

#: the policy name of a variant's hold-still run (the normalized score's 0)
HOLD_STILL = HoldStill.name
#: ids on which the shipped agents' episodes run batched (``evaluate(..., batched=True)``, where
#: :func:`cir_gym.evaluation.batchable` allows it: not a ``randomize`` model), in the ranked tables
#: and the seed tables alike. A torch network rounds a batch of rows differently from one row
#: (~1e-7 in the actions); the closed loop carries that into the metrics, measured on 4–8 episodes
#: of every shipped agent: ≤ 3e-6 relative for most; for the tuned residual agents, in some
#: episodes, up to 4e-3 in the primary metric (CartesianTracking's position_rms; 2e-4
#: JointTracking's rms_error; 7e-3 on its industrial drive, whose 20-bit encoder quantises the
#: difference into a whole count, 2e-3 in a seed's mean there) and 3e-3 in the return, 5e-4 in
#: an 8-episode mean elsewhere, and more in a final error (one sample of a trajectory, a few
#: 1e-5 rad); never a changed length or success (``tests/test_batched_agents.py`` holds two
#: agents to a stated tolerance). The rounding depends
#: on the batch's size, so an agent's episode can differ by as much between runs of another
#: ``--episodes``; a run is deterministic. Evaluating the network row by row would be exact but
#: costs most of the gain (measured, 8 episodes of JointTracking's residual agent: 8.1 s CPU
#: against 10.2 s one by one, 2.5 s batched). The contact ids (AdmittanceContact-v2, PegInHole-v2)
#: are left out until an agent of theirs is measured: contact switching can amplify a last-bit
#: difference without bound.
AGENT_BATCH_IDS = frozenset({
    "cir_gym/JointTracking-v2", "cir_gym/ElasticJointTracking-v3", "cir_gym/CartesianTracking-v1",
})
#: the anchors of every variant's normalized score, in the output folder
ANCHORS_FILE = "normalized.json"


def jobs_for(
    env_id: str, overrides: dict[str, Any] | None = None
) -> list[tuple[str, str, dict[str, Any], str]]:
    """(env_id, variant name, env kwargs, policy name) for every pair to evaluate: every
    controller on every variant, at its course gains and, where ``scripts/tune_gains.py``
    tuned it for exactly the variant's arguments, at those gains (``tuned:<controller>``,
    :func:`cir_gym.scoring.policies.tuned_gains`); a shipped agent (with the ``train`` extra)
    only on the variants of the task it was trained for (:func:`agents.trained_for`:
    RedundantIK's objective); every installed plugin policy (``plugin:<name>``) that applies.
    The variants are those of the task ``env_id`` plays (an agent-ready variant's task,
    :func:`cir_gym.scoring.policies.task_id`): its rows go into the task's tables."""
    from cir_gym.scoring.policies import has_tuned_gains, policy_names, task_id, trained_for

    cls = cir_gym.ENVIRONMENTS[task_id(env_id)][0]
    variants = getattr(cls, "leaderboard_variants", {"default": {}})
    return [
        (env_id, v, {**kw, **(overrides or {})}, p)
        for v, kw in variants.items()
        for p in policy_names(env_id)
        if trained_for(env_id, p, {**kw, **(overrides or {})})
        and has_tuned_gains(env_id, p, {**kw, **(overrides or {})})
    ]


def row_key(job: tuple[str, str, dict[str, Any], str]) -> tuple[str, str, str]:
    """Where a job's result goes: (the id of the task whose table it is a row of, variant,
    the row's label), :func:`cir_gym.scoring.policies.task_id` and
    :func:`~cir_gym.scoring.policies.row_label`."""
    from cir_gym.scoring.policies import row_label, task_id

    env_id, variant, _, policy = job
    return task_id(env_id), variant, row_label(env_id, policy)


def anchor_job(env_id: str, variant: str,
               env_kwargs: dict[str, Any]) -> tuple[str, str, dict[str, Any], str]:
    """The hold-still run of one variant (:data:`HOLD_STILL`), a :func:`run_job` job."""
    return (env_id, variant, env_kwargs, HOLD_STILL)


def run_job(
    job: tuple[str, str, dict[str, Any], str], episodes: int, seed: int
) -> tuple[tuple[str, str, str], EvaluationResult, float]:
    """One (environment, variant, policy) of the leaderboard: its :func:`row_key`, its
    episodes (labelled with the row's label), ranked on the variant's primary metric, and the
    CPU time (s) it took (its process's: the time it takes one free core, whatever else the
    machine runs). The policy :data:`HOLD_STILL` is the
    variant's hold-still policy (:func:`anchor_job`). The episodes run batched where
    :func:`cir_gym.evaluation.evaluate` batches by itself (a course controller: bit for bit)
    and, for a shipped agent on :data:`AGENT_BATCH_IDS`, where the env allows it (to float
    rounding)."""
    from cir_gym.scoring.policies import make_policy

    env_id, variant, env_kwargs, policy_name = job
    key = row_key(job)
    t0 = time.process_time()
    if policy_name == HOLD_STILL:
        env = gym.make(env_id, **env_kwargs)
        policy = hold_still_policy(env)
        env.close()
    else:
        policy = make_policy(env_id, policy_name, env_kwargs, {})
    at_once = (policy_name.startswith("agent:") and env_id in AGENT_BATCH_IDS
               and batchable(policy, env_id, **env_kwargs))
    result = evaluate(policy, env_id, episodes, seed, policy_name=key[2],
                      batched=True if at_once else None, **env_kwargs)
    result = result.ranked_on(variant_primary_metric(cir_gym.ENVIRONMENTS[key[0]][0], variant))
    return key, result, time.process_time() - t0


def run_seed_table(
    env_id: str, variant: str, env_kwargs: dict[str, Any], episodes: int, seed: int
) -> tuple[tuple[str, str], list[Any], float]:
    """One variant's multi-seed agents of ``env_id`` evaluated over all their seeds
    (:func:`agents.report.seed_reports` on the variant's primary metric, batched on
    :data:`AGENT_BATCH_IDS`; their table is written once the variant's anchors are known,
    :func:`agents.report.seed_markdown`) and the CPU time (s) it took."""
    from cir_gym.agents.report import seed_reports
    from cir_gym.scoring.policies import row_label, task_id

    t0 = time.process_time()
    names = _multi_seed_agents(env_id, env_kwargs)
    metric = variant_primary_metric(cir_gym.ENVIRONMENTS[task_id(env_id)][0], variant)
    reports = seed_reports(env_id, env_kwargs, episodes=episodes, seed=seed, names=names,
                           metric=metric, batched=env_id in AGENT_BATCH_IDS) if names else []
    reports = [dataclasses.replace(r, name=row_label(env_id, r.name)) for r in reports]
    return (env_id, variant), reports, time.process_time() - t0


# ---------------------------------------------------------------------- progress and estimates
#: CPU seconds of one episode (one core), the mean over a few policies of the environment
#: (two controllers and an agent, 2 episodes each, on the shared 2-core machine the defaults
#: were chosen on): the estimate before a first run; a run's own timings
#: (``<out>/timings.json``, per policy) replace them for the next run into the same folder
EPISODE_SECONDS: dict[str, float] = {
    "JointTracking-v2": 0.45,
    "ElasticJointTracking-v3": 0.5,
    "RedundantIK-v4": 0.45,
    "RedundantIK7-v5": 0.45,
    "VisualServo-v1": 0.6,
    "VisualServoEyeToHand-v1": 0.5,
    "AdmittanceContact-v2": 2.5,
    "PegInHole-v2": 5.0,
    "CartesianTracking-v1": 0.9,
}
#: CPU seconds to build a policy (an agent loads torch and its network) before its episodes
JOB_SECONDS = {"agent": 1.5, "other": 0.2}
#: wall seconds of one comparison figure and of one variant's GIF (two episodes rendered)
FIGURE_SECONDS = 0.8
VIDEO_SECONDS = 20.0
#: a seed table's cost against its agents' seeds run as leaderboard jobs (its bootstrap CIs)
SEED_TABLE_FACTOR = 1.5
#: CPU seconds a seed table spends per training seed whatever the episodes (loading the agent,
#: building its env): fitted on CartesianTracking's and JointTracking's tables run at 3 and 12
#: episodes (0.7–1.2 s); kept out of the per-episode timing so a run of another --episodes is
#: estimated right
SEED_LOAD_SECONDS = 1.0
TIMINGS = "timings.json"
#: the fewest episodes per policy behind a number worth quoting (the summary says so below)
HEADLINE_EPISODES = 30
#: the heading of the failed runs in leaderboard.md (the command line exits 1 when present)
FAILED_HEADING = "## Failed runs"


def _name(env_id: str) -> str:
    return env_id.split("/")[-1]


class Progress:
    """One phase's progress on stderr: the count done, the time spent and the time left.

    The time left is the planned cost of what remains (s of one worker, from the estimates)
    scaled by how fast the phase has gone so far (wall time per planned second), so it is
    honest from the first finished item on; before that it is the plan divided by the workers.
    On a terminal the line is rewritten in place every second; otherwise a line is written
    every ``every`` seconds (from a thread, so a long item shows the phase alive), and at
    the end.
    """

    def __init__(self, phase: str, total: int, planned: float, workers: int = 1,
                 unit: str = "", every: float = 20.0) -> None:
        self.phase, self.total, self.unit = phase, total, unit
        self.planned, self.workers = max(planned, 1e-9), max(1, workers)
        self.done, self.done_cost = 0, 0.0
        self.t0 = time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.label = ""
        self.lock = threading.Lock()
        self.halt = threading.Event()
        self.every = 1.0 if self.tty else every
        self.ticker = threading.Thread(target=self._tick, daemon=True)
        self.ticker.start()

    def _tick(self) -> None:
        while not self.halt.wait(self.every):
            self._write(final=False)

    def left(self) -> float:
        """Estimated wall seconds left."""
        elapsed = time.perf_counter() - self.t0
        if self.done_cost <= 0.0:
            return max(0.0, self.planned / self.workers - elapsed)
        return max(0.0, (self.planned - self.done_cost) * elapsed / self.done_cost)

    def update(self, cost: float, label: str = "") -> None:
        """One more item done, of planned cost ``cost`` (s)."""
        with self.lock:
            self.done += 1
            self.done_cost += cost
            self.label = label
        if self.tty:
            self._write(final=False)

    def _write(self, final: bool) -> None:
        with self.lock:
            elapsed = time.perf_counter() - self.t0
            what = f"{self.done}/{self.total} {self.unit}".rstrip()
            tail = f"done in {_clock(elapsed)}" if final else (
                f"{_clock(elapsed)} spent, ~{_clock(self.left())} left"
            )
            label = f"  ({self.label})" if self.label and not final else ""
            line = f"  {self.phase}: {what}, {tail}{label}"
            if self.tty:
                width = shutil.get_terminal_size((100, 20)).columns - 1
                sys.stderr.write("\r\x1b[2K" + line[:width] + ("\n" if final else ""))
            else:
                sys.stderr.write(line + "\n")
            sys.stderr.flush()

    def close(self) -> float:
        """End the phase (its last line); return its wall time (s)."""
        self.halt.set()
        self.ticker.join()
        self._write(final=True)
        return time.perf_counter() - self.t0


def _clock(seconds: float) -> str:
    seconds = round(max(0.0, seconds))
    return f"{seconds // 60}:{seconds % 60:02d}" if seconds >= 60 else f"{seconds} s"


def _load_timings(out: Path) -> dict[str, Any]:
    try:
        return json.loads((out / TIMINGS).read_text())
    except (OSError, ValueError):
        return {}


def job_cost(job: tuple[str, str, dict[str, Any], str], episodes: int,
             timings: dict[str, Any] | None = None) -> float:
    """Planned seconds of one worker for a leaderboard job: the previous run's time per
    episode of this (environment, policy) where ``<out>/timings.json`` has it, else the
    environment's :data:`EPISODE_SECONDS`, plus building the policy."""
    env_id, _, _, policy = job
    kind = "agent" if policy.startswith("agent:") else "other"
    per_episode = (timings or {}).get("episode", {}).get(f"{_name(env_id)} {policy}")
    if per_episode is None:
        per_episode = EPISODE_SECONDS.get(_name(env_id), 1.0)
    return JOB_SECONDS[kind] + episodes * float(per_episode)


def seed_table_cost(env_id: str, variant: str, env_kwargs: dict[str, Any], episodes: int,
                    timings: dict[str, Any] | None = None) -> float:
    """Planned seconds of one worker for a variant's :func:`multi_seed_table`: the previous
    run's where ``<out>/timings.json`` has it, else every seed of every agent as a job."""
    per_episode = (timings or {}).get("seed_table", {}).get(f"{_name(env_id)} {variant}")
    if per_episode is not None:
        return SEED_LOAD_SECONDS * _seed_count(env_id, env_kwargs) + episodes * float(per_episode)
    return sum(
        SEED_TABLE_FACTOR * len(_seeds(env_id, n))
        * job_cost((env_id, variant, env_kwargs, f"agent:{n}"), episodes, timings)
        for n in _multi_seed_agents(env_id, env_kwargs)
    )


def missing_extras(figures: bool, videos: bool) -> list[str]:
    """What the figures (matplotlib) and the videos (Pillow) need but cannot import."""
    from cir_gym.scoring.policies import module_missing

    need = (["matplotlib"] if figures else []) + (["PIL"] if videos else [])
    return [m for m in need if module_missing(m)]


def run_leaderboard(
    out: Path,
    episodes: int = 10,
    seed: int = 1000,
    envs: list[str] | None = None,
    workers: int | None = None,
    env_overrides: dict[str, Any] | None = None,
    figures: bool = True,
    videos: bool = True,
) -> Path:
    """Evaluate everything, write ``out/leaderboard.md``, the figures and ``out/index.html``
    (:func:`cir_gym.scoring.page.write_page`, with a GIF per variant); return the md path.

    Progress goes to stderr, phase by phase (episodes and the agents' seed tables, figures,
    videos and the page), with the estimate of each phase at the start and the time left as it
    runs; at the end a summary (:func:`summary`: the best controller and agent of each
    environment) and where the page is. The time per episode of each (environment, policy)
    is kept in ``out/timings.json`` for the next run's estimate.

    Args:
        out: the output folder (created).
        episodes: episodes per (variant, policy), seeds ``seed`` … ``seed + episodes - 1``.
        envs: environment ids (default: every registered one); each names its task's tables,
            which hold every interface that plays the task
            (:func:`cir_gym.scoring.policies.interface_ids`).
        workers: processes (default: one per core).
        env_overrides: added to every environment's kwargs (e.g. a short
            ``episode_duration`` for tests).
        figures, videos: False leaves out the PNG figures (matplotlib) or the GIFs (Pillow);
            they are left out, with a line saying so, when those packages are missing.
    """
    out = Path(out)
    missing = missing_extras(figures, videos)
    if missing:
        print(
            f"cir-gym leaderboard: {' and '.join(missing)} not installed: no "
            f"{'figures' if 'matplotlib' in missing else ''}"
            f"{' or ' if len(missing) == 2 else ''}{'videos' if 'PIL' in missing else ''}"
            " (pip install 'cir-gym[plots]' adds them)",
            file=sys.stderr,
        )
        figures = figures and "matplotlib" not in missing
        videos = videos and "PIL" not in missing
    from cir_gym.scoring.policies import interface_ids, task_id

    # one table per task, with the rows of every interface that plays it (an id given names
    # its task's tables); a task with no policy to score has none
    tasks = dict.fromkeys(task_id(e) for e in envs or list(cir_gym.ENVIRONMENTS))
    jobs_of = {t: [j for e in interface_ids(t) for j in jobs_for(e, env_overrides)]
               for t in tasks}
    env_ids = [e for e, env_jobs in jobs_of.items() if env_jobs]
    variants = [
        (e, v, {**kw, **(env_overrides or {})})
        for e in env_ids
        for v, kw in getattr(cir_gym.ENVIRONMENTS[e][0], "leaderboard_variants",
                             {"default": {}}).items()
    ]
    # each variant's hold-still run (the normalized score's 0) on the same seeds
    jobs = [j for e in env_ids for j in jobs_of[e]] + [anchor_job(*v) for v in variants]
    seed_jobs = [(i, v, kw) for e, v, kw in variants for i in interface_ids(e)
                 if _multi_seed_agents(i, kw)]
    workers = max(1, workers or min(len(jobs), os.cpu_count() or 1))
    timings = _load_timings(out)

    cost = [job_cost(j, episodes, timings) for j in jobs]
    seed_cost = {(e, v): seed_table_cost(e, v, kw, episodes, timings) for e, v, kw in seed_jobs}
    plan = {
        "episodes": (sum(cost) + sum(seed_cost.values())) / workers,
        "figures": FIGURE_SECONDS * len(variants) * figures,
        "videos": VIDEO_SECONDS * len(variants) * videos / min(workers, len(variants)),
    }
    print(
        f"cir-gym leaderboard: {len(env_ids)} environment(s), {len(variants)} variants, "
        f"{len(jobs)} runs × {episodes} episode(s) (seeds {seed}…{seed + episodes - 1}; "
        f"{len(variants)} of them hold still, the scores' 0)"
        + (f" and the agents' seed tables of {len(seed_jobs)} variant(s)" if seed_jobs else "")
        + f" on {workers} worker(s) → {out}/\n  estimate with {workers} free core(s): "
        + f"~{_clock(sum(plan.values()))} ("
        + ", ".join(f"{k} ~{_clock(v)}" for k, v in plan.items() if v > 0)
        + ")",
        file=sys.stderr,
    )
    t_start = time.perf_counter()
    results: dict[tuple[str, str, str], EvaluationResult] = {}
    seconds: dict[tuple[str, str, str], float] = {}
    seed_tables: dict[tuple[str, str], list[Any]] = {}
    seed_seconds: dict[tuple[str, str], float] = {}
    failed: dict[str, str] = {}
    bar = Progress("episodes", len(jobs) + len(seed_jobs),
                   sum(cost) + sum(seed_cost.values()), workers, "runs")
    # spawn, not fork: a child forked from a parent that has already run torch (an agent's
    # policy, a test that trained one) can deadlock in torch's thread pool at its first op.
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=spawn) as pool:
        # the runs first, so the count moves from the start; then the seed tables (each one
        # evaluates every training seed of a variant's agents: the longest items)
        futures = {pool.submit(run_job, j, episodes, seed): ("run", i) for i, j in enumerate(jobs)}
        futures.update({
            pool.submit(run_seed_table, e, v, kw, episodes, seed): ("seeds", (e, v))
            for e, v, kw in seed_jobs
        })
        for fut in as_completed(futures):
            kind, what = futures[fut]
            label = (f"seed table {_name(what[0])} {what[1]}" if kind == "seeds"
                     else f"{_name(jobs[what][0])} {jobs[what][1]} {jobs[what][3]}")
            try:
                if kind == "seeds":
                    key2, reports, sec = fut.result()
                    seed_tables[key2], seed_seconds[key2] = reports, sec
                else:
                    key, result, sec = fut.result()
                    results[key], seconds[key] = result, sec
            except Exception as exc:  # a plugin's bug, a missing file: the others go on
                failed[label] = f"{type(exc).__name__}: {exc}".split("\n")[0]
            bar.update(seed_cost[what] if kind == "seeds" else cost[what], label)
    bar.close()
    out.mkdir(parents=True, exist_ok=True)
    loads = {(e, v): _seed_count(e, kw) for e, v, kw in seed_jobs}
    _save_timings(out, timings, jobs, seconds, seed_seconds, loads, episodes)
    holds = {(e, v): results.pop((e, v, p)) for (e, v, p) in list(results) if p == HOLD_STILL}
    anchors, no_score = score_anchors(results, holds, env_ids)
    write_anchors(out / ANCHORS_FILE, anchors, episodes, seed)

    lines = [
        "# cir_gym leaderboard",
        "",
        f"{episodes} episodes per policy, seeds {seed}…{seed + episodes - 1} (the same for every "
        "policy). Ranked by success rate, then by each variant's primary metric (mean over "
        "episodes; the environment's, or the variant's own, e.g. the manipulability of "
        "RedundantIK's manipulability variant), shown as *mean [95 % CI]* (" + MEAN_MEANING
        + "); *success (95 % Wilson)*: the " + SUCCESS_MEANING + "; *worst* is the worst "
        "episode, CVaR20% the mean of the worst 20 %. A task's tables also rank the policies of "
        "the ids that play it at another interface, labelled `<policy> [<id>]` (an "
        "agent-ready variant's 20-Hz setpoint of an impedance loop: the same variants, env "
        "arguments, seeds, metrics and success). *score*: the " + SCORE_MEANING
        + " (every variant's hold-still policy runs on the same seeds; a log scale where the "
        "two are a decade or more apart: "
        f"cir_gym/score_scale.py; the anchors are in {ANCHORS_FILE}). Episodes run batched "
        "where a native batched env exists: a course controller's equal the one-by-one "
        "episodes bit for bit, a shipped agent's (on "
        + ", ".join(_name(e) for e in sorted(AGENT_BATCH_IDS))
        + ") to float rounding (its network rounds a batch differently from one row, ~1e-7 "
        "in the actions, which the closed loop carries into the metrics: measured ≤ 3e-6 "
        "relative for most agents, up to 4e-3 in the primary metric and the return of an "
        "episode of a tuned residual agent; tests/test_batched_agents.py). "
        "Generated by "
        "`cir-gym leaderboard`.",
        "",
    ]
    seed_md: dict[tuple[str, str], str] = {}
    figure_bar = (
        Progress("figures", len(variants), FIGURE_SECONDS * len(variants), 1, "figures")
        if figures else None
    )
    for env_id in env_ids:
        cls, description = cir_gym.ENVIRONMENTS[env_id]
        lines += [f"## {env_id}", "", description, ""]
        by_variant = _by_variant(results, env_id)
        env_anchors = {v: anchors.get((env_id, v)) for v in by_variant}
        lines += [rl_summary(by_variant, env_anchors), ""]
        for variant, kwargs in getattr(cls, "leaderboard_variants", {"default": {}}).items():
            rows = by_variant[variant]
            setting = ", ".join(f"{k}={v}" for k, v in kwargs.items()) or "default arguments"
            a = anchors.get((env_id, variant))
            lines += [f"### {variant} ({setting})", "", ranked_table(rows, a), ""]
            if rows:
                lines += [anchor_line(a, no_score.get((env_id, variant), "")), ""]
            reports = [r for i in interface_ids(env_id) for r in seed_tables.get((i, variant), [])]
            if reports:
                from cir_gym.agents.report import seed_markdown

                seed_md[(env_id, variant)] = seed_markdown(reports, a)
                lines += [seed_md[(env_id, variant)], ""]
            if figures and rows:
                from cir_gym.scoring.plotting import plot_comparison

                fig = out / f"{_name(env_id)}_{slug(variant)}.png"
                plot_comparison(rows, fig, title=f"{env_id} — {variant}")
                lines += [f"![{env_id} {variant}]({fig.name})", ""]
                if figure_bar is not None:
                    figure_bar.update(FIGURE_SECONDS, fig.name)
    if figure_bar is not None:
        figure_bar.close()
    if failed:
        lines += [FAILED_HEADING, "", "| run | error |", "|---|---|"]
        lines += [f"| {k} | {v.replace('|', '/')} |" for k, v in sorted(failed.items())]
        lines.append("")
    md = out / "leaderboard.md"
    md.write_text("\n".join(lines))

    shown = sum(1 for e, v, _ in variants if _by_variant(results, e)[v]) if videos else 0
    watch = _VideoWatch(out, shown, workers) if shown else None
    write_page(
        out,
        results,
        env_ids,
        episodes,
        seed,
        env_overrides,
        workers,
        videos=videos,
        extra={k: v for k, v in seed_md.items() if v},
        anchors=anchors,
    )
    if watch is not None:
        watch.stop()
    total = time.perf_counter() - t_start
    print(summary(results, env_ids, anchors), file=sys.stderr)
    if episodes < HEADLINE_EPISODES:
        print(
            f"({episodes} episodes per policy: a first look; numbers to quote need "
            f"--episodes {HEADLINE_EPISODES} or more, with the 95 % intervals of the tables)",
            file=sys.stderr,
        )
    if failed:
        print(f"{len(failed)} run(s) failed (listed in {md}):", file=sys.stderr)
        for k, v in sorted(failed.items()):
            print(f"  {k}: {v}", file=sys.stderr)
    print(
        f"done in {_clock(total)} (slowest run {max(seconds.values(), default=0):.0f} CPU s)\n"
        f"page: {(out / 'index.html').resolve()}\ntables: {md.resolve()}",
        file=sys.stderr,
    )
    return md


def score_anchors(
    results: dict[tuple[str, str, str], EvaluationResult],
    holds: dict[tuple[str, str], EvaluationResult],
    env_ids: list[str],
) -> tuple[dict[tuple[str, str], Anchors], dict[tuple[str, str], str]]:
    """Each variant's anchors (:func:`cir_gym.scoring.normalized.variant_anchors`: its
    hold-still run at 0, its best controller at 1, on the variant's primary metric), and for a
    variant without them the reason (no hold-still run, no controller with a finite mean,
    anchors equal, holding still better than the first-ranked controller: no scale)."""
    anchors: dict[tuple[str, str], Anchors] = {}
    why: dict[tuple[str, str], str] = {}
    for env_id in env_ids:
        for variant, rows in _by_variant(results, env_id).items():
            key = (env_id, variant)
            if not rows:
                continue
            if key not in holds:
                why[key] = "its hold-still run failed"
                continue
            try:
                anchors[key] = variant_anchors(rows, holds[key])
            except ValueError as exc:
                why[key] = str(exc)
    return anchors, why


def write_anchors(path: Path, anchors: dict[tuple[str, str], Anchors], episodes: int,
                  seed: int) -> Path:
    """``normalized.json``: the episodes and first seed the anchors were measured on and, per
    ``"<env id> <variant>"``, the anchors (:meth:`Anchors.to_dict`), for whoever scores the
    same episodes later (``python -m agents.report --anchors``)."""
    data = {
        "episodes": episodes,
        "seed": seed,
        "variants": {f"{e} {v}": a.to_dict() for (e, v), a in sorted(anchors.items())},
    }
    path.write_text(json.dumps(data, indent=1) + "\n")
    return path


def anchor_line(anchors: Anchors | None, why: str = "") -> str:
    """The line under a ranked table: what its score column's 0 and 1 are, or why it has
    none."""
    if anchors is None:
        return f"No normalized score on this variant ({why or 'no anchors'})."
    return f"Normalized {anchors.describe()}."


def _multi_seed_agents(env_id: str, env_kwargs: dict[str, Any]) -> list[str]:
    """The shipped agents of ``env_id`` trained over >= 2 seeds for the variant's task."""
    from cir_gym.scoring.policies import agents_module

    ag = agents_module()
    if ag is None:
        return []
    return [n for n in ag.available(env_id)
            if len(ag.seeds(env_id, n)) >= 2 and ag.trained_for(env_id, n, env_kwargs)]


def _seed_count(env_id: str, env_kwargs: dict[str, Any]) -> int:
    """How many trained agents (training seeds) a variant's seed table loads."""
    return sum(len(_seeds(env_id, n)) for n in _multi_seed_agents(env_id, env_kwargs))


def _seeds(env_id: str, name: str) -> list[int]:
    from cir_gym.scoring.policies import agents_module

    ag = agents_module()
    return ag.seeds(env_id, name) if ag is not None else []


def _by_variant(
    results: dict[tuple[str, str, str], EvaluationResult], env_id: str
) -> dict[str, list[EvaluationResult]]:
    """One environment's results, variant → its rows (every variant, in the class's order)."""
    variants = getattr(cir_gym.ENVIRONMENTS[env_id][0], "leaderboard_variants", {"default": {}})
    return {
        v: [r for (e, vv, _), r in sorted(results.items()) if e == env_id and vv == v]
        for v in variants
    }


def _save_timings(out: Path, timings: dict[str, Any], jobs: list[Any],
                  seconds: dict[tuple[str, str, str], float],
                  seed_seconds: dict[tuple[str, str], float],
                  loads: dict[tuple[str, str], int], episodes: int) -> None:
    """Merge this run's CPU time per episode of each (environment, policy) (the mean over
    its variants, building the policy left out) and of each seed table (loading its
    ``loads[(env, variant)]`` agents left out) into ``out/timings.json``: the next run's
    estimate (:func:`job_cost`, :func:`seed_table_cost`)."""
    per: dict[str, list[float]] = {}
    for job in jobs:
        env_id, _, _, policy = job
        sec = seconds.get(row_key(job))
        if sec is not None:
            kind = "agent" if policy.startswith("agent:") else "other"
            per.setdefault(f"{_name(env_id)} {policy}", []).append(
                max(0.0, sec - JOB_SECONDS[kind]) / episodes
            )
    episode = {**timings.get("episode", {}),
               **{k: round(float(np.mean(v)), 4) for k, v in per.items()}}
    seeds = {**timings.get("seed_table", {}),
             **{f"{_name(e)} {v}": round(
                 max(0.0, sec - SEED_LOAD_SECONDS * loads.get((e, v), 0)) / episodes, 4)
                for (e, v), sec in seed_seconds.items()}}
    (out / TIMINGS).write_text(
        json.dumps({"episode": episode, "seed_table": seeds}, indent=1, sort_keys=True) + "\n"
    )


class _VideoWatch:
    """Progress of :func:`write_page`'s videos, read from the GIFs it writes into
    ``out/videos`` (a file newer than the phase's start is a finished video), on a thread."""

    def __init__(self, out: Path, total: int, workers: int) -> None:
        self.folder, self.total = out / "videos", total
        self.t0 = time.time()
        self.bar = Progress("videos", total, VIDEO_SECONDS * total,
                            min(workers, total), "videos")
        self.halt = threading.Event()
        self.thread = threading.Thread(target=self._watch, daemon=True)
        self.thread.start()

    def _finished(self) -> int:
        if not self.folder.is_dir():
            return 0
        return sum(1 for g in self.folder.glob("*.gif") if g.stat().st_mtime >= self.t0)

    def _watch(self) -> None:
        while not self.halt.wait(2.0):
            while self.bar.done < min(self._finished(), self.total):
                self.bar.update(VIDEO_SECONDS)

    def stop(self) -> None:
        self.halt.set()
        self.thread.join()
        self.bar.close()


def summary(results: dict[tuple[str, str, str], EvaluationResult], env_ids: list[str],
            anchors: dict[tuple[str, str], Anchors] | None = None) -> str:
    """A few lines: per environment, on its first leaderboard variant, the best controller
    (a course law, at course or tuned gains, or a plugin policy) and the best shipped agent
    (:func:`cir_gym.scoring.tables.best`: success rate first, then the primary metric), with
    their normalized scores where ``anchors`` has the variant's."""
    from cir_gym.scoring.tables import best, score_of

    def cell(r: EvaluationResult | None, a: Anchors | None) -> str:
        if r is None:
            return "—"
        spec = r.spec(r.primary_metric)
        unit = f" {spec.unit}" if spec.unit else ""
        score = f", score {score_cell(score_of(r, a))}" if a is not None else ""
        return (f"{r.policy_name} {r.summary[r.primary_metric]['mean']:.3g}{unit} "
                f"({100 * r.success_rate:.0f} % success{score})")

    lines = ["best per environment (its first variant; success first, then the metric; "
             "score: 0 = hold still, 1 = the best controller):"]
    width = max((len(_name(e)) for e in env_ids), default=0)
    for env_id in env_ids:
        variant, rows = next(iter(_by_variant(results, env_id).items()))
        if not rows:
            continue
        a = (anchors or {}).get((env_id, variant))
        ctrl = best([r for r in rows if not r.policy_name.startswith("agent:")])
        agent = best([r for r in rows if r.policy_name.startswith("agent:")])
        lines.append(
            f"  {_name(env_id):<{width}}  {variant} [{rows[0].primary_metric}]: controller "
            f"{cell(ctrl, a)}; agent {cell(agent, a)}"
        )
    return "\n".join(lines)


def multi_seed_table(env_id: str, env_kwargs: dict[str, Any], episodes: int, seed: int,
                     anchors: Anchors | None = None) -> str:
    """The shipped agents of ``env_id`` trained over >= 2 seeds (``<name>/seed_<k>/``) on one
    variant, over all their seeds: :func:`agents.report.seed_table` (IQM of the primary metric
    with its stratified-bootstrap CI over seeds; and of the normalized score given the
    variant's ``anchors``). "" when there is none (or no train extra). The ranked table above
    it shows such an agent's first seed only."""
    names = _multi_seed_agents(env_id, env_kwargs)
    if not names:
        return ""
    from cir_gym.agents.report import seed_table

    return seed_table(env_id, env_kwargs, episodes=episodes, seed=seed, names=names,
                      anchors=anchors, batched=env_id in AGENT_BATCH_IDS)


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


def leaderboard_from(directory: Path, out: Path | None = None) -> Path:
    """``cir-gym leaderboard --from DIR``: a sweep's table (``DIR/results.parquet`` or
    ``.csv``) as ``leaderboard.md``, one figure per (environment, variant), a figure against
    the swept environment argument where one numeric argument varies, and ``index.html``, all
    in ``out`` (default ``DIR``). Ranked as the leaderboard ranks (:func:`ranked_table`);
    training runs over >= 2 seeds also get :func:`training_seed_table`; failed tasks are listed
    with their errors. Returns the markdown's path."""
    from cir_gym.scoring.page import html_page, markdown_to_html
    from cir_gym.scoring.plotting import plot_comparison, plot_sweep_axis
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
