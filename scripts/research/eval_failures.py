"""How a shipped agent's failed episodes end: by termination (which step) or at the time limit,
the largest error it had *while it played* (the scored error of a terminated episode also counts
the reference it no longer follows), and chosen episode metrics.

    python scripts/eval_failures.py --env cir_gym/RedundantIK7-v4 --agent ppo_obstacle \
        --set objective=obstacle --seeds 0 --episodes 20 --metric min_clearance
    python scripts/eval_failures.py --env cir_gym/CartesianTracking-v0 --agent ppo_100hz

Episodes run on seeds ``--seed`` … (default the leaderboard's 1000-) on the agent's own action
interface (``cir_gym.evaluation.interface_env_kwargs``); the played error is
:func:`agents.shaping.error_norm` of each step's ``info`` (joint, task or flange position error).
Prints a Markdown table per training seed and a summary line.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
from cir_gym.agents.shaping import error_norm

import cir_gym  # noqa: F401  (registers the environments)
from cir_gym import agents
from cir_gym.evaluation import interface_env_kwargs
from cir_gym.scoring.policies import parse_value


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", required=True)
    ap.add_argument("--agent", required=True)
    ap.add_argument("--seeds", type=int, nargs="*", help="training seeds (default: all)")
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--metric", action="append", default=[], help="episode metric to list")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="environment argument (a Python literal or a bare string)")
    args = ap.parse_args(argv)

    kwargs = {key: parse_value(value)
              for key, _, value in (item.partition("=") for item in args.set)}
    failed = ended = 0
    for k in args.seeds if args.seeds is not None else agents.seeds(args.env, args.agent):
        policy = agents.load(args.env, args.agent, seed=k)
        env = gym.make(args.env, **interface_env_kwargs(policy, kwargs))
        print(f"\n`{args.agent}` seed {k} on {args.env} {kwargs or ''}\n")
        print("| " + " | ".join(["episode seed", "success", "ended by", "steps",
                                 "max played error", *args.metric]) + " |")
        print("|---" * (5 + len(args.metric)) + "|")
        for s in range(args.seed, args.seed + args.episodes):
            obs, _ = env.reset(seed=s)
            steps, worst, done = 0, 0.0, False
            while not done:
                obs, _, terminated, truncated, info = env.step(policy.predict(obs)[0])
                steps += 1
                worst = max(worst, error_norm(info))
                done = terminated or truncated
            ok = bool(info.get("is_success"))
            failed += not ok
            ended += (not ok) and terminated
            cells = [str(s), str(ok), "termination" if terminated else "time limit", str(steps),
                     f"{worst:.3g}", *(f"{info['episode_metrics'][m]:.3g}" for m in args.metric)]
            print("| " + " | ".join(cells) + " |")
        env.close()
    print(f"\nfailed episodes: {failed}, of which ended by termination: {ended}")


if __name__ == "__main__":
    main()
