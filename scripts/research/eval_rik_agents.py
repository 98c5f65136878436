"""RedundantIK agents on many seeds, and where their laps are lost (the 90 % target).

    python scripts/research/eval_rik_agents.py [--env cir_gym/RedundantIK-v4] [--episodes 100]
        [--seed 1000] [--laps 60] [--out results/agents/RedundantIK-v3_agents.md]
        [--agent NAME[:OBJECTIVE] ...] [--path DIR[:OBJECTIVE] ...]

For every training seed of each shipped agent (default: all, each on the objective it was
trained for) and every agent directory given by ``--path`` (a lever's model), the success rate
and the median RMS task error over ``--episodes`` episodes from ``--seed``
(:func:`cir_gym.evaluation.evaluate`, the leaderboard's scorer, which plays every episode here).
Then, for the first agent's
seed 0 on its first ``--laps`` episodes, each lap is sorted into succeeded (max error < the
success threshold), near miss (< 10 mm) or lost, with the control step of its largest error and
its minimum manipulability and joint-limit margin, beside ``clik``'s minimum manipulability on
the same episodes (does the agent lose its laps where the arm is badly conditioned?), and the
error at that step split along the reference's direction of motion and across it, with the
reference speed there (does it lag behind a fast reference, or leave the path sideways?).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np

import cir_gym  # noqa: F401  (registers the ids)
from cir_gym import agents, baselines
from cir_gym.envs.base import make_env
from cir_gym.evaluation import evaluate, interface_env_kwargs

NEAR_MISS = 0.01  # m: a lap whose max error stays below this is a near miss, above it lost


def _objective(config: dict) -> str:
    return (config.get("env_kwargs") or {}).get("objective", "manipulability")


def _score(policy, env_id: str, objective: str, episodes: int, seed: int) -> tuple[float, float]:
    r = evaluate(policy, env_id, episodes, seed, objective=objective)
    rms = [e.metrics["rms_task_error"] for e in r.episodes]
    return float(np.mean([e.success for e in r.episodes])), float(np.median(rms))


class StepObservations(gym.Wrapper):
    """Keeps the observation after each step of the current episode (``evaluate`` plays it)."""

    def reset(self, **kwargs):
        self.after: list[dict] = []
        return self.env.reset(**kwargs)

    def step(self, action):
        result = self.env.step(action)
        self.after.append(result[0])
        return result


def _lap(policy, env_id: str, objective: str, seed: int) -> tuple[np.ndarray, dict]:
    """Per control step: the task-position error norm, its components along the reference's
    direction of motion (positive: behind the reference) and across it, and the reference
    speed (rows of a (steps, 4) array); and the episode's metrics."""
    kwargs = interface_env_kwargs(policy, {"objective": objective})
    env = StepObservations(make_env(env_id, **kwargs))
    episode = evaluate(policy, env_id, 1, seed, env=env).episodes[0]
    rows = []
    for obs in env.after:
        e, v = obs["x_ref"] - obs["x"], obs["xd_ref"]
        speed = float(np.linalg.norm(v))
        along = float(e @ v) / speed if speed > 1e-9 else 0.0
        across = float(np.sqrt(max(e @ e - along**2, 0.0)))
        rows.append((float(np.linalg.norm(e)), along, across, speed))
    env.close()
    return np.array(rows), episode.metrics


def laps_table(policy, env_id: str, objective: str, laps: int, seed: int) -> list[str]:
    threshold = gym.make(env_id).unwrapped.success_threshold
    clik = baselines.make("clik", env_id)
    rows: dict[str, list] = {"succeeded": [], "near miss": [], "lost": []}
    for s in range(seed, seed + laps):
        steps, m = _lap(policy, env_id, objective, s)
        e = steps[:, 0]
        at = int(np.argmax(e))
        kind = ("succeeded" if e.max() < threshold else
                "near miss" if e.max() < NEAR_MISS else "lost")
        _, mc = _lap(clik, env_id, objective, s)
        rows[kind].append((e.max(), at, len(e), m["min_manipulability"],
                           m["min_joint_limit_margin"], mc["min_manipulability"],
                           mc["max_task_error"], *steps[at, 1:]))
    out = [f"Laps of seeds {seed}-{seed + laps - 1} (one episode each):", "",
           "| laps | n | max error median (mm) | step of the max error (median, range) | "
           "min manipulability (agent, median) | joint-limit margin (rad, median) | "
           "clik's min manipulability, same episodes | clik's max error (mm, median / worst) | "
           "clik's laps under the threshold | at the max error: along the path / across it "
           "(mm, median; along > 0: behind) | reference speed there (m/s, median) |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    for kind, r in rows.items():
        if not r:
            out.append(f"| {kind} | 0 | | | | | | | | | |")
            continue
        a = np.array(r, dtype=float)
        out.append(
            f"| {kind} | {len(r)} | {1e3 * np.median(a[:, 0]):.3g} | {np.median(a[:, 1]):.0f} "
            f"({a[:, 1].min():.0f}-{a[:, 1].max():.0f} of {a[:, 2].max():.0f}) | "
            f"{np.median(a[:, 3]):.3g} | {np.median(a[:, 4]):.3g} | {np.median(a[:, 5]):.3g} | "
            f"{1e3 * np.median(a[:, 6]):.3g} / {1e3 * a[:, 6].max():.3g} | "
            f"{int(np.sum(a[:, 6] < threshold))} of {len(r)} | "
            f"{1e3 * np.median(a[:, 7]):.3g} / {1e3 * np.median(a[:, 8]):.3g} | "
            f"{np.median(a[:, 9]):.3g} |")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="cir_gym/RedundantIK-v4")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--laps", type=int, default=60, help="episodes of the lap diagnosis (0: none)")
    p.add_argument("--agent", action="append", default=[], help="NAME[:OBJECTIVE]")
    p.add_argument("--path", action="append", default=[], help="agent directory[:OBJECTIVE]")
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    env_id = args.env
    runs = []  # (label, policy, objective)
    for spec in args.agent or agents.available(env_id):
        name, _, objective = spec.partition(":")
        for k in agents.seeds(env_id, name):
            policy = agents.load(env_id, name, seed=k)
            runs.append((f"`{name}` seed {k}", policy, objective or _objective(policy.config)))
    for spec in args.path:
        path, _, objective = spec.partition(":")
        policy = agents.load(env_id, Path(path).name, path=path)
        runs.append((f"`{path}`", policy, objective or _objective(policy.config)))
    lines = [f"# {env_id}: agents on seeds {args.seed}-{args.seed + args.episodes - 1}", "",
             "(`python scripts/research/eval_rik_agents.py`; each agent on its objective)", "",
             "| agent | objective | success | median RMS task error (mm) |", "|---|---|---|---|"]
    for label, policy, objective in runs:
        ok, rms = _score(policy, env_id, objective, args.episodes, args.seed)
        lines.append(f"| {label} | {objective} | {100 * ok:.0f} % | {1e3 * rms:.3g} |")
        print(lines[-1], flush=True)
    if args.laps and runs:
        label, policy, objective = runs[0]
        lines += ["", f"## Where {label} loses its laps ({objective})", ""]
        lines += laps_table(policy, env_id, objective, args.laps, args.seed)
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
