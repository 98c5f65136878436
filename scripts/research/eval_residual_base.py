"""A residual agent against its own base controller and against the variant's controller.

    python scripts/research/eval_residual_base.py --env cir_gym/JointTracking-v2 \
        --agent residual_ppo_computed_torque@JointTracking-v1 [--seed-agent 1] [--episodes 3] \
        [--seed 1000] [--out FILE]

``--env`` and ``--agent`` are required: ``--agent`` is a shipped residual agent of ``--env``
(:func:`residual_agents`; an unknown name's error lists them).

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
import yaml

import cir_gym
from cir_gym import agents, baselines
from cir_gym.evaluation import evaluate


class _ZeroResidual:
    """The policy's ``predict`` replaced by zeros: a residual agent's base alone."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.shape = shape

    def predict(self, x, deterministic: bool = True):
        return np.zeros(self.shape, dtype=np.float32), None


def residual_agents(env_id: str) -> list[str]:
    """Names of the shipped agents of ``env_id`` (:func:`agents.available`) that are residual
    agents: their config.yml records a base controller."""
    def is_residual(name: str) -> bool:
        config = yaml.safe_load((agents.agent_dir(env_id, name) / "config.yml").read_text())
        return bool((config.get("residual") or {}).get("controller"))

    return [n for n in agents.available(env_id) if is_residual(n)]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", required=True, help="a registered id, e.g. cir_gym/JointTracking-v2")
    p.add_argument("--agent", required=True,
                   help="a shipped residual agent of --env, e.g. "
                        "residual_ppo_computed_torque@JointTracking-v1")
    p.add_argument("--seed-agent", type=int, default=None, help="training seed (default: first)")
    p.add_argument("--episodes", type=int, default=3)
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    key = args.env.split(":")[-1]
    if key not in cir_gym.ENVIRONMENTS:
        p.error(f"--env {args.env!r} is not registered; valid: {sorted(cir_gym.ENVIRONMENTS)}")
    if args.agent not in (names := residual_agents(key)):
        p.error(f"--agent {args.agent!r} is not a shipped residual agent of {key}; "
                f"its residual agents: {names or 'none'}")
    agent = agents.load(key, args.agent, seed=args.seed_agent)
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
