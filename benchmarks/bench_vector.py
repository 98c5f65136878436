"""Batched envs, the batched evaluator, a 100-seed leaderboard estimate and PPO throughput.

    python benchmarks/bench_vector.py [--num-envs 16 64] [--envs ID ...] [--episodes 100]
                                      [--seq-episodes 10] [--other-episodes 1]
                                      [--ppo-steps 16384] [--skip ...] [--out results/benchmarks.md]

Four parts, written under the heading ``## Vector env`` of ``--out`` (only that section is
replaced; the other sections belong to other scripts):

1. ``throughput``: env-steps/s of each ``--num-envs`` count of copies of every id of
   ``cir_gym.envs.vector.VECTOR_ENVS`` (or ``--envs``) in its native batched env, of the same
   model's raw ``mujoco.batch.Batch.step`` and of Gymnasium's ``SyncVectorEnv`` of the single
   env; zero actions, ``max_following_error=None`` where the env has it (resets are not what
   this times). The loops are timed alternately, best of ``--repeat``: in process CPU time
   with one MuJoCo thread (other jobs' time slices on this shared machine are not counted),
   and in wall-clock time the batched env with 2 threads against the SyncVectorEnv (both
   inflated by the machine's load).
2. ``evaluator``: ``cir_gym.evaluation.evaluate`` on every JointTracking-v2 and
   ElasticJointTracking-v3 leaderboard (variant, policy) pair, as ``scripts/leaderboard.py``
   runs them (seed 1000 on): batched on ``--episodes`` seeds where it batches (controllers,
   ideal drive), sequential on ``--seq-episodes`` seeds, scaled linearly to ``--episodes``
   (each episode is one independent rollout of the same length: the scaling is the
   measurement's only assumption). The batched run's first ``--seq-episodes`` EpisodeResults
   are checked equal to the sequential ones.
3. ``leaderboard``: every other environment's pairs, ``--other-episodes`` episodes each
   (sequential: they have no batched env), scaled to ``--episodes``; with part 2 this gives
   the CPU time of a full leaderboard at ``--episodes`` seeds per variant, and that time over
   2 workers (the leaderboard's process pool on 2 cores, perfectly balanced: a lower bound on
   its wall time). Not counted: the leaderboard's figures and its page's videos.
4. ``ppo``: PPO training throughput (env-steps/s over ``--ppo-steps`` steps of ``learn``,
   rollouts and updates) with agents/hyperparams/ppo.yml's JointTracking-v2 entry (n_steps
   512 per env for 16 envs, batch 1024, 10 epochs, γ 0.98, λ 1, [128, 128] tanh,
   log σ −2, VecNormalize on observations and rewards; one torch thread) on a DummyVecEnv
   of 16 single envs against ``sb3_vec_env`` of the batched env with 16 copies and with 64
   (n_steps 128: the same 8192-step rollout). Both sides use SB3's MultiInputPolicy on the raw
   Dict observation (the shipped agents' flattening wrapper is left out on both).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import mujoco.batch
import numpy as np
from _sections import write_section  # sibling module: the scripts run as files

import cir_gym
from cir_gym.envs.base import constructor_arguments, make_env
from cir_gym.envs.vector import VECTOR_ENVS, native_vector_env, sb3_vec_env
from cir_gym.evaluation import evaluate

SECTION = "## Vector env"
OUT = Path(__file__).parents[1] / "results" / "benchmarks.md"
SEED = 1000  # scripts/leaderboard.py's
PARTS = ("throughput", "evaluator", "leaderboard", "ppo")


def _cpu() -> float:
    return time.process_time()


# ---------------------------------------------------------------------- 1. throughput
def _per_env_step(
    step: Callable[[], Any], n: int, num_envs: int, clock: Callable[[], float] = _cpu
) -> Callable[[], float]:
    """A trial: ``n`` calls of ``step``, returning seconds per env-step (per copy)."""

    def run() -> float:
        t0 = clock()
        for _ in range(n):
            step()
        return (clock() - t0) / (n * num_envs)

    return run


def bench_throughput(
    counts: list[int], steps: int, repeat: int, env_ids: list[str] | None = None
) -> list[str]:
    """Rows of env-steps/s per (env, copies): the batched env (1 thread CPU, 2 threads wall)
    vs its raw batch physics and vs SyncVectorEnv (CPU and wall)."""
    rows = [
        "Zero actions, `max_following_error=None` where the env has it; best of the trials, "
        "the loops timed alternately. CPU: process time, 1 MuJoCo thread. Wall: the batched "
        "env with 2 threads against the SyncVectorEnv, in the same run (the machine's load "
        "inflates both).",
        "",
        "| env | copies | SyncVectorEnv (CPU) | batched, 1 thread (CPU) | batched / Sync "
        "| raw Batch.step (CPU) | batched / raw | SyncVectorEnv (wall) | batched, 2 threads "
        "(wall) | batched 2 threads / Sync (wall) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for env_id in env_ids or list(VECTOR_ENVS):
        cls = VECTOR_ENVS[env_id]
        kw = (
            {"max_following_error": None}
            if "max_following_error" in constructor_arguments(cls.env_class)
            else {}
        )
        for num_envs in counts:
            vec = cls(num_envs, nthread=1, **kw)
            vec2 = cls(num_envs, nthread=2, **kw)
            sync = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="sync", **kw)
            for env in (vec, vec2, sync):
                env.reset(seed=0)
            raw = mujoco.batch.Batch(vec.template.model, nsim=num_envs, nthread=1)
            raw.state[:] = vec.batch.state
            skip = vec.template.frame_skip
            zeros = np.zeros(vec.action_space.shape, dtype=np.float32)
            n_sync = max(1, steps // 8)
            loops = {
                "vec": _per_env_step(lambda v=vec, z=zeros: v.step(z), steps, num_envs),
                "raw": _per_env_step(lambda r=raw, s=skip: r.step(nstep=s), steps, num_envs),
                "sync": _per_env_step(lambda v=sync, z=zeros: v.step(z), n_sync, num_envs),
                "wall2": _per_env_step(
                    lambda v=vec2, z=zeros: v.step(z), steps, num_envs, time.perf_counter
                ),
                "sync_wall": _per_env_step(
                    lambda v=sync, z=zeros: v.step(z), n_sync, num_envs, time.perf_counter
                ),
            }
            best = {k: float("inf") for k in loops}
            for _ in range(repeat):
                for key, run in loops.items():
                    best[key] = min(best[key], run())
            rate = {k: 1.0 / v for k, v in best.items()}
            print(
                f"  {env_id} x{num_envs}: " + ", ".join(f"{k} {v:,.0f}/s" for k, v in rate.items()),
                flush=True,
            )
            rows.append(
                f"| {env_id} | {num_envs} | {rate['sync']:,.0f} | {rate['vec']:,.0f} | "
                f"{rate['vec'] / rate['sync']:.1f} | {rate['raw']:,.0f} | "
                f"{rate['vec'] / rate['raw']:.2f} | {rate['sync_wall']:,.0f} | "
                f"{rate['wall2']:,.0f} | {rate['wall2'] / rate['sync_wall']:.1f} |"
            )
            for env in (vec, vec2, sync):
                env.close()
    return rows


# ---------------------------------------------------------------------- 2./3. evaluation
def _episode_fields(result: Any) -> list[tuple]:
    return [
        (e.seed, e.length, e.success, e.diverged, e.terminated, e.metrics, e.episode_return)
        for e in result.episodes
    ]


def _timed_evaluate(
    env_id: str, kwargs: dict, policy_name: str, episodes: int, batched: bool
) -> tuple[Any, float]:
    """(result, CPU seconds) of one leaderboard job: the policy built, then evaluated."""
    from cir_gym.scoring.policies import make_policy

    t0 = _cpu()
    policy = make_policy(env_id, policy_name, kwargs, {})
    result = evaluate(
        policy,
        env_id,
        episodes,
        SEED,
        policy_name=policy_name,
        batched=None if batched else False,
        **kwargs,
    )
    return result, _cpu() - t0


def bench_evaluator(episodes: int, seq_episodes: int) -> tuple[list[str], float, float]:
    """Per (variant, policy) of the batched envs: batched vs sequential CPU time at
    ``episodes`` seeds. Returns (rows, CPU s of these jobs now, CPU s sequentially)."""
    from cir_gym.evaluation import batches_exactly
    from cir_gym.scoring.leaderboard import jobs_for
    from cir_gym.scoring.policies import make_policy

    scale = episodes / seq_episodes
    rows = [
        f"`evaluate` per leaderboard job at {episodes} seeds ({SEED}…), process CPU time. "
        f"Sequential: {seq_episodes} seeds timed, ×{scale:g}. Batched: all {episodes} seeds "
        "timed, one group (one `mujoco.batch.Batch`, 1 thread); its first "
        f"{seq_episodes} EpisodeResults checked equal to the sequential ones.",
        "",
        "| env | variant | policy | sequential (s, scaled) | batched (s) | speed-up | identical |",
        "|---|---|---|---:|---:|---:|---|",
    ]
    total_now = total_seq = 0.0
    by_kind: dict[str, list[float]] = {}  # kind of job → [sequential s, now s, jobs]
    for env_id in VECTOR_ENVS:
        for _, variant, kwargs, name in jobs_for(env_id):
            seq, t_seq = _timed_evaluate(env_id, kwargs, name, seq_episodes, batched=False)
            t_seq *= scale
            policy = make_policy(env_id, name, kwargs, {})
            can = native_vector_env(env_id, kwargs) is not None and batches_exactly(policy)
            if can:
                fast, t_fast = _timed_evaluate(env_id, kwargs, name, episodes, batched=True)
                fast.episodes = fast.episodes[:seq_episodes]
                same = "yes" if _episode_fields(fast) == _episode_fields(seq) else "**NO**"
                cells = f"{t_fast:.1f} | {t_seq / t_fast:.1f} | {same}"
            else:
                t_fast = t_seq
                why = "drive" if native_vector_env(env_id, kwargs) is None else "agent"
                cells = f"– (sequential: {why}) | 1.0 | –"
            total_now += t_fast
            total_seq += t_seq
            kind = (
                "batched controllers"
                if can
                else "agents (sequential)"
                if name.startswith("agent:")
                else "industrial-drive controllers (sequential)"
            )
            acc = by_kind.setdefault(kind, [0.0, 0.0, 0])
            acc[0], acc[1], acc[2] = acc[0] + t_seq, acc[1] + t_fast, acc[2] + 1
            print(f"  {env_id} {variant} {name}: seq {t_seq:.1f} s, now {t_fast:.1f} s", flush=True)
            rows.append(f"| {env_id.split('/')[-1]} | {variant} | {name} | {t_seq:.1f} | {cells} |")
    rows += [
        "",
        f"These {len(rows) - 4} jobs: {total_seq:.0f} CPU s sequential → "
        f"{total_now:.0f} CPU s with the batched evaluator ({total_seq / total_now:.1f}×): "
        + "; ".join(
            f"{kind} ({int(n)} jobs) {seq:.0f} → {now:.0f} s"
            for kind, (seq, now, n) in by_kind.items()
        )
        + ".",
    ]
    return rows, total_now, total_seq


def bench_other_envs(episodes: int, other_episodes: int) -> tuple[list[str], float]:
    """CPU seconds of every other env's leaderboard jobs, scaled to ``episodes``."""
    from cir_gym.scoring.leaderboard import jobs_for

    scale = episodes / other_episodes
    per_env: dict[str, float] = {}
    for env_id in cir_gym.ENVIRONMENTS:
        if env_id in VECTOR_ENVS:
            continue
        for _, variant, kwargs, name in jobs_for(env_id):
            _, t = _timed_evaluate(env_id, kwargs, name, other_episodes, batched=False)
            per_env[env_id] = per_env.get(env_id, 0.0) + t * scale
            print(f"  {env_id} {variant} {name}: {t:.1f} s for {other_episodes}", flush=True)
    rows = [
        f"| {env_id.split('/')[-1]} | {len(jobs_for(env_id))} | {sec:.0f} |"
        for env_id, sec in per_env.items()
    ]
    return rows, sum(per_env.values())


# ---------------------------------------------------------------------- 4. PPO
def _ppo_hyperparams(n_envs: int) -> dict[str, Any]:
    """ppo.yml's JointTracking-v2 entry, n_steps scaled to keep its 8192-step rollout."""
    import torch

    return {
        "n_steps": 8192 // n_envs,
        "batch_size": 1024,
        "n_epochs": 10,
        "gamma": 0.98,
        "gae_lambda": 1.0,
        "learning_rate": 3.0e-4,
        "clip_range": 0.2,
        "ent_coef": 0.0,
        "vf_coef": 0.5,
        "max_grad_norm": 0.5,
        "policy_kwargs": {
            "net_arch": [128, 128],
            "activation_fn": torch.nn.Tanh,
            "log_std_init": -2.0,
        },
    }


def bench_ppo(steps: int) -> list[str]:
    """PPO env-steps/s (wall and CPU) on DummyVecEnv(16) vs the batched env (16, 64)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from cir_gym.envs.vector import JointTrackingVectorEnv

    torch.set_num_threads(1)
    env_id = "cir_gym/JointTracking-v2"

    def dummy(n: int) -> Any:
        return DummyVecEnv([lambda: make_env(env_id) for _ in range(n)])

    def batched(n: int) -> Any:
        return sb3_vec_env(JointTrackingVectorEnv(n, nthread=1))

    sides = [
        ("SB3 DummyVecEnv of 16 single envs", dummy, 16),
        ("sb3_vec_env(JointTrackingVectorEnv(16))", batched, 16),
        ("sb3_vec_env(JointTrackingVectorEnv(64))", batched, 64),
    ]
    rates = []
    for label, make, n in sides:
        venv = VecNormalize(make(n), norm_obs=True, norm_reward=True, gamma=0.98)
        venv.seed(0)
        model = PPO(
            "MultiInputPolicy", venv, seed=0, device="cpu", verbose=0, **_ppo_hyperparams(n)
        )
        t0, c0 = time.perf_counter(), _cpu()
        model.learn(total_timesteps=steps)
        wall, cpu = time.perf_counter() - t0, _cpu() - c0
        done = model.num_timesteps
        rates.append((label, n, done / wall, done / cpu, done))
        print(
            f"  {label}: {done / wall:,.0f} steps/s wall, {done / cpu:,.0f} per CPU s", flush=True
        )
        venv.close()
    base_cpu = rates[0][3]
    rows = [
        f"PPO `learn` for {rates[0][4]:,} steps per side (rollouts of 8192 steps and their 10 "
        "epochs of updates; one torch thread, one MuJoCo thread), run one after the other:",
        "",
        "| vec env | n_envs × n_steps | env-steps/s (wall) | env-steps per CPU s | vs Dummy "
        "(CPU) |",
        "|---|---|---:|---:|---:|",
    ]
    rows += [
        f"| {label} | {n} × {8192 // n} | {wall:,.0f} | {cpu:,.0f} | {cpu / base_cpu:.2f} |"
        for label, n, wall, cpu, _ in rates
    ]
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument(
        "--num-envs", type=int, nargs="+", default=[16, 64], help="copies (throughput part)"
    )
    p.add_argument(
        "--envs", nargs="*", default=None, help="ids of the throughput part (default: all)"
    )
    p.add_argument("--steps", type=int, default=200, help="vector steps per timed trial")
    p.add_argument("--repeat", type=int, default=5, help="trials; the best is kept")
    p.add_argument("--episodes", type=int, default=100, help="seeds per leaderboard variant")
    p.add_argument("--seq-episodes", type=int, default=10, help="seeds timed sequentially")
    p.add_argument(
        "--other-episodes",
        type=int,
        default=1,
        help="seeds timed per job of the envs without a batched env",
    )
    p.add_argument("--ppo-steps", type=int, default=16384, help="PPO steps per side")
    p.add_argument("--skip", nargs="*", default=[], choices=PARTS, help="parts to leave out")
    p.add_argument("--out", type=Path, default=OUT, help="markdown file ('-' for none)")
    args = p.parse_args(argv)
    warnings.filterwarnings("ignore")
    body = [
        f"`python benchmarks/bench_vector.py{''.join(' ' + a for a in argv or sys.argv[1:])}` "
        f"(mujoco {mujoco.__version__}, gymnasium "
        f"{gym.__version__}; 2 cores shared with other jobs: only ratios measured side by "
        "side mean something; CPU time counts this process only).",
        "",
    ]
    t_batched_envs = t_seq_envs = t_other = None
    if "throughput" not in args.skip:
        print("throughput:", flush=True)
        body += [
            "### Batched env throughput",
            "",
            *bench_throughput(args.num_envs, args.steps, args.repeat, args.envs),
            "",
        ]
    if "evaluator" not in args.skip:
        print("evaluator:", flush=True)
        rows, t_batched_envs, t_seq_envs = bench_evaluator(args.episodes, args.seq_episodes)
        body += ["### Batched evaluator", "", *rows, ""]
    if "leaderboard" not in args.skip:
        print("leaderboard (other envs):", flush=True)
        rows, t_other = bench_other_envs(args.episodes, args.other_episodes)
        body += [
            f"### Full leaderboard at {args.episodes} seeds per variant (estimate)",
            "",
            f"The envs without a batched env, sequential: {args.other_episodes} episode(s) per "
            f"job timed (policy and env construction included, so scaled ×"
            f"{args.episodes / args.other_episodes:g} with the episodes: an overestimate by "
            "the construction time, ≲ 1 s per job).",
            "",
            f"| env | jobs | CPU s at {args.episodes} seeds |",
            "|---|---:|---:|",
            *rows,
            "",
        ]
        if t_batched_envs is not None:
            now = t_batched_envs + t_other
            before = t_seq_envs + t_other
            body += [
                f"All {len(cir_gym.ENVIRONMENTS)} envs at {args.episodes} seeds per variant: "
                f"{now / 60:.0f} CPU min with the batched evaluator (the envs of "
                f"VECTOR_ENVS {t_batched_envs / 60:.0f}, the others "
                f"{t_other / 60:.0f}), {before / 60:.0f} CPU min all sequential; on the "
                f"leaderboard's 2 workers at best {now / 120:.0f} min of wall time "
                f"(perfect balance, an unloaded machine; figures and videos not counted). "
                f"Target: 10 min.",
                "",
            ]
    if "ppo" not in args.skip:
        print("ppo:", flush=True)
        body += ["### PPO training throughput", "", *bench_ppo(args.ppo_steps), ""]
    text = "\n".join(body)
    print()
    print(text)
    if str(args.out) != "-":
        write_section(args.out, SECTION, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
