"""How a shipped agent's failed episodes end: by termination (which step) or at the time limit,
the largest error it had *while it played* (the scored error of a terminated episode also counts
the reference it no longer follows), and chosen episode metrics.

    python scripts/research/eval_failures.py --env cir_gym/RedundantIK7-v5 \
        --agent ppo_obstacle --set objective=obstacle --seeds 0 --episodes 20 \
        --metric min_clearance
    python scripts/research/eval_failures.py --env cir_gym/CartesianTracking-v1 --agent ppo_100hz

Episodes run on seeds ``--seed`` … (default the leaderboard's 1000-) on the agent's own action
interface (``cir_gym.evaluation.interface_env_kwargs``), played by
:func:`cir_gym.evaluation.evaluate`; the played error is
:func:`cir_gym.agents.shaping.error_norm` of each step's ``info`` (joint, task or flange
position error).
Prints a Markdown table per training seed and a summary line.
"""

from __future__ import annotations

import argparse
from typing import Any

import gymnasium as gym
from cir_gym.agents.shaping import error_norm

import cir_gym  # noqa: F401  (registers the environments)
from cir_gym import agents
from cir_gym.envs.base import make_env
from cir_gym.evaluation import evaluate, interface_env_kwargs
from cir_gym.scoring.policies import parse_value


class PlayedError(gym.Wrapper):
    """The largest :func:`error_norm` of the steps of each episode played (``evaluate`` plays
    them): ``worst[i]`` for the i-th episode since this wrapper was made."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.worst: list[float] = []

    def reset(self, **kwargs: Any) -> tuple[Any, dict]:
        self.worst.append(0.0)
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        result = self.env.step(action)
        self.worst[-1] = max(self.worst[-1], error_norm(result[4]))
        return result


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
        env = PlayedError(make_env(args.env, **interface_env_kwargs(policy, kwargs)))
        print(f"\n`{args.agent}` seed {k} on {args.env} {kwargs or ''}\n")
        print("| " + " | ".join(["episode seed", "success", "ended by", "steps",
                                 "max played error", *args.metric]) + " |")
        print("|---" * (5 + len(args.metric)) + "|")
        result = evaluate(policy, args.env, args.episodes, args.seed, env=env)
        for episode, worst in zip(result.episodes, env.worst, strict=True):
            ok = episode.success
            failed += not ok
            ended += (not ok) and episode.terminated
            cells = [str(episode.seed), str(ok),
                     "termination" if episode.terminated else "time limit", str(episode.length),
                     f"{worst:.3g}", *(f"{episode.metrics[m]:.3g}" for m in args.metric)]
            print("| " + " | ".join(cells) + " |")
        env.close()
    print(f"\nfailed episodes: {failed}, of which ended by termination: {ended}")


if __name__ == "__main__":
    main()
