"""Soak test: millions of random steps of one environment, checking speed, memory and warnings.

    python benchmarks/soak.py --steps 1000000 --env cir_gym/ElasticJointTracking-v3

Without ``--env`` the slowest registered environment (measured on a few hundred steps) is used.
Actions are uniform in [-1, 1]; the env is reset at every episode end and, to exercise resets
mid-episode too, after a random number of steps drawn uniformly in [1, 2 ``--reset-every``].
Reported: steps/s, resident memory (VmRSS) growth between 10 % and 100 % of the run (target
< ``--max-growth-mb``), Python warnings (target 0), MuJoCo's own warnings (target 0: the
messages of its ``mju_user_warning`` hook, which also keeps them out of MUJOCO_LOG.TXT, and the
``MjData.warning`` counters, read before every reset), episodes and divergences. Exits with
status 1 when a target is missed, 2 on bad arguments. From Python::

    from benchmarks.soak import main
    main(["--steps", "5000", "--env", "cir_gym/JointTracking-v2"])  # -> exit status
"""

from __future__ import annotations

import argparse
import gc
import resource
import sys
import time
import warnings
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

import cir_gym

CHUNK = 10_000  # actions drawn per batch


def rss_mb() -> float:
    """Current resident set size (MB) from /proc, else the peak from getrusage."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def step_cost(env_id: str, steps: int = 300) -> float:
    """Seconds per ``step`` of ``env_id`` with random actions (after a short warm-up)."""
    env = gym.make(env_id)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    shape = env.action_space.shape
    elapsed = 0.0
    for k in range(steps + 20):
        a = rng.uniform(-1, 1, shape)
        t0 = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(a)
        if k >= 20:
            elapsed += time.perf_counter() - t0
        if terminated or truncated:
            env.reset()
    env.close()
    return elapsed / steps


def slowest_env() -> str:
    costs = {env_id: step_cost(env_id) for env_id in cir_gym.ENVIRONMENTS}
    for env_id, cost in sorted(costs.items(), key=lambda kv: -kv[1]):
        print(f"  {env_id:45s} {cost * 1e6:8.1f} µs/step")
    return max(costs, key=costs.__getitem__)


def mujoco_warning_counts(data: mujoco.MjData) -> dict[str, int]:
    """Non-zero ``data.warning`` counters by name (``mjWARN_*``); mj_resetData clears them."""
    return {mujoco.mjtWarning(i).name: int(w.number)
            for i, w in enumerate(data.warning) if w.number}


def soak(env_id: str, steps: int, reset_every: int, seed: int) -> dict[str, Any]:
    """Run the soak; return the measurements."""
    caught: list[str] = []
    n_warnings = 0
    mj_messages: list[str] = []
    mj_counts: dict[str, int] = {}

    def record(message: Any, category: type, filename: str, lineno: int, *_: Any) -> None:
        nonlocal n_warnings
        n_warnings += 1
        if len(caught) < 5:
            caught.append(f"{category.__name__}: {message} ({filename}:{lineno})")

    def count_mujoco(data: mujoco.MjData) -> None:
        for name, number in mujoco_warning_counts(data).items():
            mj_counts[name] = mj_counts.get(name, 0) + number

    rng = np.random.default_rng(seed)
    previous_hook = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(mj_messages.append)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.showwarning = record
            r = _run(env_id, steps, reset_every, seed, rng, count_mujoco)
    finally:
        mujoco.set_mju_user_warning(previous_hook)
    return {
        **r,
        "warnings": n_warnings,
        "first_warnings": caught,
        "mujoco_messages": len(mj_messages),
        "first_mujoco_messages": [m.strip() for m in mj_messages[:5]],
        "mujoco_counters": mj_counts,
    }


def _run(env_id: str, steps: int, reset_every: int, seed: int, rng: np.random.Generator,
         count_mujoco: Any) -> dict[str, Any]:
    """The stepping loop of :func:`soak`; ``count_mujoco(base.data)`` before every reset."""
    env = gym.make(env_id)
    base = env.unwrapped
    shape = env.action_space.shape
    env.reset(seed=seed)
    ended = forced = diverged = since_reset = 0
    cap = int(rng.integers(1, 2 * reset_every + 1))
    rss_10 = rss_start = rss_mb()
    t_start = time.perf_counter()
    t_10 = t_start
    mark = max(1, steps // 10)
    actions = rng.uniform(-1, 1, (CHUNK, *shape)).astype(np.float32)
    for k in range(steps):
        if k % CHUNK == 0 and k:
            actions = rng.uniform(-1, 1, (CHUNK, *shape)).astype(np.float32)
        _, _, terminated, truncated, info = env.step(actions[k % CHUNK])
        since_reset += 1
        if terminated or truncated or since_reset >= cap:
            if terminated or truncated:
                ended += 1
                diverged += bool(info.get("diverged", False))
                assert "episode_metrics" in info, "episode end without episode_metrics"
            else:
                forced += 1
            count_mujoco(base.data)
            env.reset()
            since_reset = 0
            cap = int(rng.integers(1, 2 * reset_every + 1))
        if (k + 1) % mark == 0:
            gc.collect()
            now, rss = time.perf_counter(), rss_mb()
            if k + 1 == mark:
                rss_10, t_10 = rss, now
            print(f"  {100 * (k + 1) // steps:3d} %  {k + 1:>9d} steps  "
                  f"{(k + 1) / (now - t_start):8.0f} steps/s  RSS {rss:7.1f} MB", flush=True)
    t_end = time.perf_counter()
    count_mujoco(base.data)
    gc.collect()
    rss_end = rss_mb()
    env.close()
    return {
        "env_id": env_id,
        "steps": steps,
        "seconds": t_end - t_start,
        "steps_per_s": steps / (t_end - t_start),
        "steps_per_s_after_10pct": (steps - mark) / max(t_end - t_10, 1e-9),
        "rss_start_mb": rss_start,
        "rss_10_mb": rss_10,
        "rss_end_mb": rss_end,
        "growth_mb": rss_end - rss_10,
        "episodes_ended": ended,
        "forced_resets": forced,
        "diverged": diverged,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--env", default=None, help="env id (default: the slowest registered)")
    parser.add_argument("--reset-every", type=int, default=1_500,
                        help="mean number of steps before a forced mid-episode reset")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-growth-mb", type=float, default=10.0)
    try:
        args = parser.parse_args(argv)
        if args.steps < 10:
            parser.error("--steps must be >= 10")
        env_id = args.env
        if env_id is None:
            print("measuring the step cost of every registered environment:")
            env_id = slowest_env()
        env_id = env_id.split(":")[-1]
        if env_id not in cir_gym.ENVIRONMENTS:
            parser.error(f"unknown env {env_id!r}; registered: {sorted(cir_gym.ENVIRONMENTS)}")
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return exc.code if isinstance(exc.code, int) else 2

    print(f"soak: {args.steps} random steps of {env_id} (reset at episode end or after "
          f"U[1, {2 * args.reset_every}] steps), seed {args.seed}")
    r = soak(env_id, args.steps, args.reset_every, args.seed)

    ok_mem = r["growth_mb"] < args.max_growth_mb
    ok_warn = r["warnings"] == 0
    ok_mj = r["mujoco_messages"] == 0 and not r["mujoco_counters"]
    print()
    print("| quantity | value | target |")
    print("|---|---|---|")
    print(f"| env | {r['env_id']} | |")
    print(f"| steps | {r['steps']} | |")
    print(f"| wall time | {r['seconds']:.1f} s | |")
    print(f"| steps/s | {r['steps_per_s']:.0f} (after 10 %: {r['steps_per_s_after_10pct']:.0f}) "
          f"| |")
    print(f"| RSS start / 10 % / end | {r['rss_start_mb']:.1f} / {r['rss_10_mb']:.1f} / "
          f"{r['rss_end_mb']:.1f} MB | |")
    print(f"| RSS growth 10 % → 100 % | {r['growth_mb']:+.2f} MB | < {args.max_growth_mb} MB "
          f"{'ok' if ok_mem else 'MISSED'} |")
    print(f"| Python warnings | {r['warnings']} | 0 {'ok' if ok_warn else 'MISSED'} |")
    counters = ", ".join(f"{k} {v}" for k, v in r["mujoco_counters"].items()) or "none"
    print(f"| MuJoCo warnings (messages; counters) | {r['mujoco_messages']}; {counters} | 0 "
          f"{'ok' if ok_mj else 'MISSED'} |")
    print(f"| episodes ended / forced resets | {r['episodes_ended']} / {r['forced_resets']} | |")
    print(f"| diverged episodes | {r['diverged']} | |")
    for w in r["first_warnings"]:
        print(f"warning: {w}")
    for w in r["first_mujoco_messages"]:
        print(f"MuJoCo warning: {w}")
    return 0 if ok_mem and ok_warn and ok_mj else 1


if __name__ == "__main__":
    sys.exit(main())
