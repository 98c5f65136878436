"""Stable-Baselines3 agents: training, residual RL, and the shipped trained models.

>>> import agents
>>> agents.available("cir_gym/JointTracking-v1")          # doctest: +SKIP
['ppo', 'residual_ppo_computed_torque']
>>> policy = agents.load("cir_gym/JointTracking-v1", "ppo")  # doctest: +SKIP
>>> action, state = policy.predict(obs)                      # doctest: +SKIP

Shipped agents live in ``agents/trained/<EnvName-vN>/<agent-name>/``; training is in
:mod:`agents.train` (needs the ``train`` extra). This module imports neither torch nor SB3
until :func:`load` is called.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["TRAINED_DIR", "available", "env_dir_name", "load"]

TRAINED_DIR = Path(__file__).resolve().parent / "trained"


def env_dir_name(env_id: str) -> str:
    """'cir_gym:cir_gym/JointTracking-v1' → 'JointTracking-v1' (the version is part of it)."""
    return env_id.split(":")[-1].split("/")[-1]


def available(env_id: str) -> list[str]:
    """Names of the shipped agents for ``env_id`` (directories of ``agents/trained/<Env-vN>/``)."""
    root = TRAINED_DIR / env_dir_name(env_id)
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.iterdir()
                  if p.is_dir() and (p / "config.yml").is_file() and (p / "model.zip").is_file())


def load(env_id: str, name: str, *, path: str | Path | None = None) -> Any:
    """A shipped (or given) agent as a policy with SB3's ``predict`` and a ``name``.

    Args:
        env_id: the environment the agent will run on (its id and version must match).
        name: a name from :func:`available` (ignored for lookup when ``path`` is given, but
            used as the policy's name).
        path: an agent directory (e.g. a training run's output) instead of the shipped one.

    Raises:
        ValueError: unknown agent, or a missing/corrupted/incompatible file (the message names
            it; :class:`agents.policy.AgentFileError` is a ValueError).

    Loading reads weights with ``torch.load(weights_only=True)`` and statistics with
    ``numpy.load(allow_pickle=False)``: no pickle is executed. Still, only load agents from
    sources you trust (see docs/agents.md).
    """
    from agents.policy import load_agent

    if path is None:
        names = available(env_id)
        if name not in names:
            raise ValueError(f"no shipped agent {name!r} for {env_id}; available: {names}")
        path = TRAINED_DIR / env_dir_name(env_id) / name
    return load_agent(Path(path), env_id=env_id, name=name)
