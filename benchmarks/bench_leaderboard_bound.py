"""The physics floor of the leaderboard at 100 seeds: what ``mj_step`` alone costs.

    python benchmarks/bench_leaderboard_bound.py [--episodes 2] [--seeds 100] [--repeat 3]
                                                 [--budget-min 20] [--env ID ...]
                                                 [--out results/benchmarks.md]

For every leaderboard job (each environment's ``leaderboard_variants`` × every controller and
shipped agent, :func:`cir_gym.scoring.leaderboard.jobs_for`), ``--episodes`` episodes on the
leaderboard's seeds (1000, 1001, ...) run one after the other through
:func:`cir_gym.evaluation.evaluate` while every ``mj_step`` call is recorded (MuJoCo's full
integration state before it, and its ``nstep``). The recorded calls are then replayed (each
state restored with ``mj_setState`` and stepped, minus the ``mj_setState`` loop alone; best of
``--repeat``): the CPU time of the physics of those very episodes, contacts included, with no
Python around it. Scaled to ``--seeds`` episodes per job and summed, it is a lower bound on the
CPU time of ``cir-gym leaderboard --episodes <seeds>`` for any implementation that steps
MuJoCo's physics at the environments' own time steps (batched threads share the cores, they do
not remove work). The kinematic environments (RedundantIK: no ``mj_step``) count their
episodes' ``mj_kinematics + mj_comPos + mj_jacSite`` once per step instead.

The same runs give the sequential evaluator's whole CPU time per job (``evaluate`` with
``batched=False``, process time, scaled the same way): the part of it that is not physics is
what faster Python could remove.

Prints markdown and writes it to ``--out`` under ``## Leaderboard at 100 seeds: the physics
floor`` (the other sections are kept).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from _sections import write_section  # sibling modules: the scripts run as files
from _tape import PhysicsTape, replay_seconds

sys.path.insert(0, str(Path(__file__).parents[1]))  # cir_gym.scoring.leaderboard, run as a file

import cir_gym
from cir_gym.evaluation import evaluate

SECTION = "## Leaderboard at 100 seeds: the physics floor"
OUT = Path(__file__).parents[1] / "results" / "benchmarks.md"
KINEMATIC = ("cir_gym/RedundantIK-v4", "cir_gym/RedundantIK7-v5")


def kinematics_seconds(env_id: str, env_kwargs: dict[str, Any], steps: int, repeat: int) -> float:
    """CPU seconds of ``steps`` × (mj_kinematics + mj_comPos + mj_jacSite) of the env's model."""
    from cir_gym.envs.base import make_env

    env = make_env(env_id, **env_kwargs)
    u = env.unwrapped
    m, d = u.model, mujoco.MjData(u.model)
    site = m.nsite - 1
    if u.controller_context().site is not None:
        site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, u.controller_context().site)
    env.close()
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        for _ in range(steps):
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, jacp, jacr, site)
        best = min(best, time.process_time() - t0)
    return float(best)


def run_job(
    job: tuple[str, str, dict[str, Any], str], episodes: int, seed: int, repeat: int
) -> dict[str, Any]:
    """One leaderboard job's ``episodes``: env steps, physics steps, physics and total CPU s."""
    from cir_gym.scoring.policies import make_policy

    env_id, _, env_kwargs, policy_name = job
    policy = make_policy(env_id, policy_name, env_kwargs, {})
    # an agent runs on the action interface it was trained on (agents.policy.TrainedAgent)
    env_kwargs = {**env_kwargs, **getattr(policy, "interface_kwargs", {})}
    recorder = PhysicsTape()  # every model's calls, an episode per segment (model copied)
    with recorder:  # the recording is left out of the evaluator's time below
        result = evaluate(
            policy, env_id, episodes, seed, policy_name=policy_name, batched=False, **env_kwargs
        )
    steps = sum(e.length for e in result.episodes)
    t0 = time.process_time()
    evaluate(policy, env_id, episodes, seed, policy_name=policy_name, batched=False, **env_kwargs)
    total = time.process_time() - t0
    if env_id in KINEMATIC:
        physics = kinematics_seconds(env_id, env_kwargs, steps, repeat)
    else:
        physics = min(
            sum(replay_seconds(segment) for segment in recorder.segments) for _ in range(repeat)
        )
    return {
        "env_steps": steps,
        "physics_steps": recorder.physics_steps(),
        "physics_s": physics,
        "total_s": total,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=2, help="episodes run per job")
    parser.add_argument("--seed", type=int, default=1000, help="the leaderboard's first seed")
    parser.add_argument("--seeds", type=int, default=100, help="episodes per job to scale to")
    parser.add_argument("--repeat", type=int, default=3, help="replays; the best is kept")
    parser.add_argument("--budget-min", type=float, default=20.0, help="CPU minutes allowed")
    parser.add_argument("--env", nargs="*", default=None, help="env ids (default: all)")
    parser.add_argument("--out", type=Path, default=OUT, help="markdown file ('-' for none)")
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore")
    from cir_gym.scoring.leaderboard import jobs_for

    ids = args.env or list(cir_gym.ENVIRONMENTS)
    scale = args.seeds / args.episodes
    rows: dict[tuple[str, str], dict[str, Any]] = {}
    failed: list[str] = []
    t_start = time.perf_counter()
    for env_id in ids:
        for job in jobs_for(env_id):
            _, variant, _, policy_name = job
            try:
                r = run_job(job, args.episodes, args.seed, args.repeat)
            except Exception as exc:  # a job the leaderboard cannot run either: named, left out
                failed.append(f"{env_id} {variant} {policy_name} ({type(exc).__name__}: {exc})")
                print(f"  {env_id} {variant} {policy_name}: FAILED {exc}", flush=True)
                continue
            row = rows.setdefault(
                (env_id, variant),
                {"jobs": 0, "env_steps": 0, "physics_steps": 0, "physics_s": 0.0, "total_s": 0.0},
            )
            row["jobs"] += 1
            for key in ("env_steps", "physics_steps", "physics_s", "total_s"):
                row[key] += r[key]
            print(
                f"  {env_id} {variant} {policy_name}: {r['env_steps']} steps, physics "
                f"{r['physics_s']:.2f} s of {r['total_s']:.2f} s",
                flush=True,
            )
    wall = time.perf_counter() - t_start
    lines = [
        "| env | variant | jobs | env steps / episode | physics steps / episode | "
        "µs per physics step (visited states) | physics at 100 seeds (CPU min) | "
        "sequential evaluator at 100 seeds (CPU min) | physics share |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    by_env: dict[str, list[float]] = {}
    for (env_id, variant), row in rows.items():
        episodes = row["jobs"] * args.episodes
        phys_min = row["physics_s"] * scale / 60
        total_min = row["total_s"] * scale / 60
        unit = "kinematics" if env_id in KINEMATIC else "mj_step"
        per_step = (
            row["physics_s"] / row["env_steps"]
            if env_id in KINEMATIC
            else row["physics_s"] / max(1, row["physics_steps"])
        )
        acc = by_env.setdefault(env_id, [0.0, 0.0])
        acc[0] += phys_min
        acc[1] += total_min
        lines.append(
            f"| {env_id} | {variant} | {row['jobs']} | {row['env_steps'] / episodes:,.0f} | "
            f"{row['physics_steps'] / episodes:,.0f} | {1e6 * per_step:.2f} ({unit}) | "
            f"{phys_min:.2f} | {total_min:.1f} | {phys_min / total_min:.0%} |"
        )
    phys_total = sum(v[0] for v in by_env.values())
    eval_total = sum(v[1] for v in by_env.values())
    lines.append(
        f"| **all** | | {sum(r['jobs'] for r in rows.values())} | | | | **{phys_total:.1f}** | "
        f"**{eval_total:.1f}** | {phys_total / eval_total:.0%} |"
    )
    per_env = "; ".join(
        f"{e.split('/')[-1]} {v[0]:.1f}" for e, v in sorted(by_env.items(), key=lambda x: -x[1][0])
    )
    env_steps = sum(r["env_steps"] for r in rows.values()) * scale
    physics_steps = sum(r["physics_steps"] for r in rows.values()) * scale
    left_us = (args.budget_min - phys_total) * 60 / env_steps * 1e6
    now_us = (eval_total - phys_total) * 60 / env_steps * 1e6
    verdict = (
        "the physics alone exceeds the budget: the target cannot be met on this machine at "
        "these time steps, whatever the Python costs"
        if phys_total > args.budget_min
        else f"the physics fits: {args.budget_min - phys_total:.1f} CPU min are left for "
        f"everything else (envs' Python, policies, evaluator, start-up), {left_us:.1f} µs per "
        f"env step over the {env_steps / 1e6:.1f} M env steps ({physics_steps / 1e6:.1f} M "
        f"physics steps) of the {args.seeds}-seed leaderboard; the sequential evaluator "
        f"spends {now_us:.0f} µs per env step on them today ({now_us / max(left_us, 1e-9):.1f}×)"
    )
    body = "\n".join(
        [
            f"`python benchmarks/bench_leaderboard_bound.py --episodes {args.episodes} "
            f"--repeat {args.repeat}` (mujoco {mujoco.__version__}; {wall / 60:.0f} min here). "
            f"Every leaderboard job (variant × controller or shipped agent) ran "
            f"{args.episodes} episodes (seeds {args.seed}…) one after the other with every "
            "`mj_step` call recorded; the physics column replays those calls (MuJoCo's full "
            "state restored, `mj_setState` cost subtracted, best of the replays) and scales "
            f"them to {args.seeds} episodes per job: the CPU time of `mj_step` alone on the "
            "states the leaderboard visits, contacts included. RedundantIK has no dynamics: "
            "its row counts mj_kinematics + mj_comPos + mj_jacSite per step. The sequential "
            "column is the whole `evaluate(..., batched=False)` of the same episodes (process "
            "CPU time, same scaling; policies and agents included; the batched evaluator cuts "
            "the JointTracking and ElasticJointTracking controller jobs 2-3×, "
            "`## Vector env`).",
            "",
            *lines,
            "",
            f"Budget: 10 min on 2 cores = {args.budget_min:g} CPU min. Physics floor at "
            f"{args.seeds} seeds: **{phys_total:.1f} CPU min** ({per_env}); {verdict}.",
            *(
                ["", "Jobs that failed (left out of the sums): " + "; ".join(failed) + "."]
                if failed
                else []
            ),
        ]
    )
    print()
    print(body)
    if str(args.out) != "-":
        write_section(args.out, SECTION, body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
