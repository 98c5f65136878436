"""A residual agent against its own base controller and against the variant's controller.

    python scripts/research/eval_residual_base.py --env cir_gym/AdmittanceContact-v1 \
        --agent residual_ppo_admittance [--seed-agent 1] [--episodes 3] [--seed 1000] [--out FILE]

A residual agent carries its base controller as :func:`agents.load` builds it, from the context
of the env it was trained on. On every leaderboard variant of ``--env`` this scores, on the same
episodes: the residual agent; the agent with its policy's output replaced by zeros (its base
alone, exactly as the agent runs it); and the leaderboard's controller of the same name, built
from the variant's own context. Where the last two differ, the variant tells the controllers
something the agent's base was not told (AdmittanceContact's fixed stiffnesses, for an agent
trained on ``randomize=True``): that gap is not the agent's doing.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np

import cir_gym
from cir_gym import agents, baselines
from cir_gym.evaluation import evaluate


class _ZeroResidual:
    """The policy's ``predict`` replaced by zeros: a residual agent's base alone."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.shape = shape

    def predict(self, x, deterministic: bool = True):
        return np.zeros(self.shape, dtype=np.float32), None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="cir_gym/AdmittanceContact-v1")
    p.add_argument("--agent", default="residual_ppo_admittance")
    p.add_argument("--seed-agent", type=int, default=None, help="training seed (default: first)")
    p.add_argument("--episodes", type=int, default=3)
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    key = args.env.split(":")[-1]
    agent = agents.load(key, args.agent, seed=args.seed_agent)
    if agent.controller is None:
        p.error(f"{args.agent} is not a residual agent")
    base = agents.load(key, args.agent, seed=args.seed_agent)
    base.policy = _ZeroResidual(gym.make(key).action_space.shape)
    name = agent.controller.name
    variants = getattr(cir_gym.ENVIRONMENTS[key][0], "leaderboard_variants", None) or {"": {}}
    lines = [f"# {key}: `{args.agent}` (seed {args.seed_agent or 'first'}) against its base",
             "", f"(`python scripts/research/eval_residual_base.py`; seeds {args.seed}-"
             f"{args.seed + args.episodes - 1}; mean of the primary metric)", "",
             f"| variant | residual agent | its base alone (trained context) | `{name}` built "
             "for the variant |", "|---|---|---|---|"]
    for variant, kwargs in variants.items():
        ctrl = baselines.make(name, key, env=gym.make(key, **kwargs))
        cells = []
        for policy in (agent, base, ctrl):
            r = evaluate(policy, key, args.episodes, args.seed, **kwargs)
            cells.append(f"{np.mean([e.metrics[r.primary_metric] for e in r.episodes]):.4g}")
        lines.append(f"| {variant} | " + " | ".join(cells) + " |")
        print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    if args.out:
        args.out.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
