"""Env steps per second of RedundantIK-v4 and RedundantIK7-v5 for each secondary objective.

    python benchmarks/bench_rik_objectives.py [--episodes 6] [--repeat 2] [--before REF]
                                              [--out results/benchmarks.md]

What an RL agent pays: ``gymnasium.make(id, objective=...)`` (default wrappers) stepped with
uniform random actions in [-1, 1] (seeded), resets included, ``--episodes`` episodes from seeds
0, 1, ...; process CPU time (other jobs' time slices are not counted), best of ``--repeat``
trials. The reset is where the objectives differ: "obstacle" places an obstacle that a motion
along the self-motion can clear over the whole lap (:meth:`clearing_motion`), which carries
every self-motion configuration along the reference by minimum-norm CLIK; "manipulability"
runs that CLIK from the candidate start postures only; "joint_limits" draws a joint window.

``--before REF``: the same measurement on the ``cir_gym`` package of git revision REF
(extracted with ``git archive`` into a temporary directory and run in a subprocess), the two
sides alternating per trial, so the table gives before/after from one run.

Prints markdown and writes it to ``--out`` under ``## RedundantIK objectives``, replacing only
that section.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

from _sections import write_section  # sibling module: the script runs as a file

ROOT = Path(__file__).parents[1]
OUT = ROOT / "results" / "benchmarks.md"
SECTION = "## RedundantIK objectives"
CASES = [
    (env_id, objective)
    for env_id in ("cir_gym/RedundantIK-v4", "cir_gym/RedundantIK7-v5")
    for objective in ("manipulability", "obstacle", "joint_limits")
]


def measure(env_id: str, objective: str, episodes: int) -> dict[str, float | str]:
    """Steps, steps/s, CPU ms per reset and µs per step of ``episodes`` random-action episodes."""
    import gymnasium as gym

    import cir_gym  # registers the ids

    env = gym.make(env_id, objective=objective)
    env.reset(seed=0)  # the passive checker's first reset runs twice: not timed
    env.action_space.seed(0)
    steps, t_reset, t_step = 0, 0.0, 0.0
    for seed in range(episodes):
        t = time.process_time()
        env.reset(seed=seed)
        t_reset += time.process_time() - t
        done = False
        t = time.process_time()
        while not done:
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            steps += 1
            done = terminated or truncated
        t_step += time.process_time() - t
    env.close()
    return {
        "steps": steps,
        "steps_per_s": steps / (t_reset + t_step),
        "reset_ms": 1e3 * t_reset / episodes,
        "step_us": 1e6 * t_step / steps,
        "package": str(Path(cir_gym.__file__).parent),
    }


def measure_at(revision_dir: Path | None, env_id: str, objective: str, episodes: int) -> dict:
    """:func:`measure` in this process, or in a subprocess on the package in ``revision_dir``."""
    if revision_dir is None:
        return measure(env_id, objective, episodes)
    env = {**os.environ, "PYTHONPATH": f"{revision_dir}{os.pathsep}{Path(__file__).parent}"}
    code = (
        "import json, sys; import bench_rik_objectives as b; "
        f"print(json.dumps(b.measure({env_id!r}, {objective!r}, {episodes})))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        cwd=revision_dir,
        check=True,
        capture_output=True,
        text=True,
    )
    result = json.loads(out.stdout.strip().splitlines()[-1])
    if Path(result["package"]) != revision_dir / "cir_gym":
        raise RuntimeError(f"the subprocess imported {result['package']}, not {revision_dir}")
    return result


def extract(revision: str, into: Path) -> Path:
    """``cir_gym`` of git revision ``revision``, extracted under ``into``."""
    archive = into / "rev.tar"
    subprocess.run(
        ["git", "-C", str(ROOT), "archive", "-o", str(archive), revision, "cir_gym"], check=True
    )
    with tarfile.open(archive) as tar:
        tar.extractall(into, filter="data")
    return into


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--before", default=None, help="git revision to compare against")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        old = extract(args.before, Path(tmp)) if args.before else None
        results: dict[tuple[str, str], dict[str, dict]] = {}
        for case in CASES:
            best: dict[str, dict] = {}
            for _ in range(args.repeat):
                for side, where in (("before", old), ("now", None)):
                    if side == "before" and old is None:
                        continue
                    r = measure_at(where, *case, args.episodes)
                    if side not in best or r["steps_per_s"] > best[side]["steps_per_s"]:
                        best[side] = r
            results[case] = best
            print(case, {k: round(v["steps_per_s"]) for k, v in best.items()}, flush=True)

    import mujoco

    head = (
        f"`python benchmarks/bench_rik_objectives.py --episodes {args.episodes} "
        f"--repeat {args.repeat}"
        + (f" --before {args.before}`" if args.before else "`")
        + f" (mujoco {mujoco.__version__}): env steps/s through `gymnasium.make(id, "
        "objective=...)` with uniform random actions, resets included, over seeds "
        f"0-{args.episodes - 1}; process CPU time, best of {args.repeat} trials"
        + (", the two revisions alternating." if args.before else ".")
    )
    rows = []
    if args.before:
        rows.append(
            "| env | objective | steps/episode | steps/s before | steps/s now | now / before "
            "| reset before (ms) | reset now (ms) | step before (µs) | step now (µs) |"
        )
        rows.append("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    else:
        rows.append("| env | objective | steps/episode | steps/s | reset (ms) | step (µs) |")
        rows.append("|---|---|---:|---:|---:|---:|")
    for (env_id, objective), best in results.items():
        now = best["now"]
        per_episode = now["steps"] / args.episodes
        if args.before:
            old_r = best["before"]
            rows.append(
                f"| {env_id} | {objective} | {per_episode:.0f} | {old_r['steps_per_s']:,.0f} "
                f"| {now['steps_per_s']:,.0f} | {now['steps_per_s'] / old_r['steps_per_s']:.2f} "
                f"| {old_r['reset_ms']:.0f} | {now['reset_ms']:.0f} | {old_r['step_us']:.0f} "
                f"| {now['step_us']:.0f} |"
            )
        else:
            rows.append(
                f"| {env_id} | {objective} | {per_episode:.0f} | {now['steps_per_s']:,.0f} "
                f"| {now['reset_ms']:.0f} | {now['step_us']:.0f} |"
            )
    ratios = []
    for env_id in ("cir_gym/RedundantIK-v4", "cir_gym/RedundantIK7-v5"):
        manip = results[(env_id, "manipulability")]["now"]["steps_per_s"]
        obstacle = results[(env_id, "obstacle")]["now"]["steps_per_s"]
        ratios.append(f"{env_id}: manipulability / obstacle steps/s = {manip / obstacle:.2f}")
    body = "\n".join([head, "", *rows, "", *(f"- {r}" for r in ratios)])
    print(body)
    write_section(args.out, SECTION, body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
