"""Stable-Baselines3 agents: training, residual RL, and the shipped trained models.

>>> from cir_gym import agents
>>> for name in agents.available("cir_gym/JointTracking-v2"):  # doctest: +SKIP
...     print(name)  # trained on JointTracking-v1, listed on v2 (EARLIER_VERSIONS)
ppo_100hz@JointTracking-v1
ppo_100hz_industrial@JointTracking-v1
residual_ppo_computed_torque@JointTracking-v1
residual_ppo_tuned_computed_torque@JointTracking-v1
>>> policy = agents.load("cir_gym/JointTracking-v2", "ppo_100hz@JointTracking-v1")  # doctest: +SKIP
>>> action, state = policy.predict(obs)  # doctest: +SKIP

Shipped agents live in ``agents/trained/<EnvName-vN>/<agent-name>/``: either one agent
(``config.yml``, ``model.zip``, ...) or, trained over several seeds, one such directory per
training seed, ``<agent-name>/seed_<k>/`` (:func:`seeds`; :mod:`agents.report` aggregates
them). Training is in :mod:`agents.train` (needs the ``train`` extra). This module imports
neither torch nor SB3 until :func:`load` is called.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = [
    "EARLIER_VERSIONS",
    "TRAINED_DIR",
    "agent_dir",
    "available",
    "env_dir_name",
    "load",
    "seeds",
    "trained_for",
]

TRAINED_DIR = Path(__file__).resolve().parent / "trained"

#: Earlier versions of an environment whose shipped agents are also scored on it: the newer
#: version keeps their observation and action spaces (tested) and their dynamics, so an agent
#: trained there runs unchanged. Such an agent is listed as ``<name>@<Env-vK>``: its name says
#: where it was trained, and it is never presented as trained on the newer version (what
#: changed between the versions, the reward or an episode's end, is in each environment's
#: Version History; RedundantIK's ``ppo_obstacle`` agents trained on the wrong capsule axis
#: that v4/v5 corrected). PegInHole-v2 and AdmittanceContact-v1 changed their contact physics and
#: their residual agents' base laws, so their earlier agents are not carried.
EARLIER_VERSIONS: dict[str, tuple[str, ...]] = {
    "JointTracking-v2": ("JointTracking-v1",),
    "ElasticJointTracking-v3": ("ElasticJointTracking-v2",),
    "CartesianTracking-v1": ("CartesianTracking-v0",),
    "VisualServo-v1": ("VisualServo-v0",),
    "RedundantIK-v4": ("RedundantIK-v3",),
    "RedundantIK7-v5": ("RedundantIK7-v4",),
}


def env_dir_name(env_id: str) -> str:
    """'cir_gym:cir_gym/JointTracking-v2' → 'JointTracking-v2' (the version is part of it)."""
    return env_id.split(":")[-1].split("/")[-1]


def _is_agent(p: Path) -> bool:
    return p.is_dir() and (p / "config.yml").is_file() and (p / "model.zip").is_file()


def _seed_dirs(p: Path) -> dict[int, Path]:
    """{k: p/seed_<k>} for the agent directories ``seed_<k>`` inside ``p``."""
    out = {}
    if p.is_dir():
        for d in p.iterdir():
            tail = d.name[len("seed_"):]
            if d.name.startswith("seed_") and tail.isdigit() and _is_agent(d):
                out[int(tail)] = d
    return dict(sorted(out.items()))


def _names_in(root: Path) -> list[str]:
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.iterdir() if _is_agent(p) or _seed_dirs(p))


def available(env_id: str) -> list[str]:
    """Names of the shipped agents for ``env_id``: directories of ``agents/trained/<Env-vN>/``
    holding one agent, or one per training seed in ``seed_<k>/``; then those of the versions
    in :data:`EARLIER_VERSIONS` as ``<name>@<Env-vK>``."""
    own = env_dir_name(env_id)
    names = _names_in(TRAINED_DIR / own)
    for earlier in EARLIER_VERSIONS.get(own, ()):
        names += [f"{n}@{earlier}" for n in _names_in(TRAINED_DIR / earlier)]
    return names


def _trained_dir(env_id: str, name: str) -> Path:
    """agents/trained/<Env-vN>/<name>, or <Env-vK>/<agent> for a name ``<agent>@<Env-vK>``."""
    own = env_dir_name(env_id)
    agent, _, earlier = name.partition("@")
    if earlier and earlier not in EARLIER_VERSIONS.get(own, ()):
        raise ValueError(f"no shipped agent {name!r} for {env_id}: {earlier} is not an earlier "
                         f"version scored on it; available: {available(env_id)}")
    return TRAINED_DIR / (earlier or own) / agent


def seeds(env_id: str, name: str) -> list[int]:
    """Training seeds of shipped agent ``name``: the k of its ``seed_<k>/`` directories, or the
    one seed in ``config.yml`` of a single-seed agent directory."""
    d = _trained_dir(env_id, name)
    found = _seed_dirs(d)
    if found:
        return list(found)
    if _is_agent(d):
        import yaml

        return [int((yaml.safe_load((d / "config.yml").read_text()) or {}).get("seed", 0))]
    raise ValueError(f"no shipped agent {name!r} for {env_id}; available: {available(env_id)}")


def agent_dir(env_id: str, name: str, seed: int | None = None) -> Path:
    """The directory of shipped agent ``name`` (training seed ``seed``; default: its first)."""
    d = _trained_dir(env_id, name)
    found = _seed_dirs(d)
    if not found and not _is_agent(d):
        raise ValueError(f"no shipped agent {name!r} for {env_id}; available: "
                         f"{available(env_id)}")
    if not found:
        if seed is not None and seed not in seeds(env_id, name):
            raise ValueError(f"agent {name!r} for {env_id} has only seed "
                             f"{seeds(env_id, name)}, not {seed}")
        return d
    if seed is None:
        return next(iter(found.values()))
    if seed not in found:
        raise ValueError(f"agent {name!r} for {env_id} has seeds {list(found)}, not {seed}")
    return found[seed]


def trained_for(env_id: str, name: str, env_kwargs: dict[str, Any]) -> bool:
    """Whether shipped agent ``name`` was trained on the task that ``env_kwargs`` asks for.

    An env class may name ``agent_task_keys``: arguments that set what the task asks
    (RedundantIK's ``objective``), not a condition it is asked under (a payload, a drive,
    which an agent may meet unseen). The agent's recorded env arguments, completed with the
    class's defaults, must then agree with ``env_kwargs`` (completed the same way) on those
    keys, so no variant is scored with an agent trained for another. True for an env without
    such keys."""
    from cir_gym.agents.policy import read_config, registered_defaults

    cls, defaults = registered_defaults(env_id)
    keys = getattr(cls, "agent_task_keys", ())
    if not keys:
        return True
    asked = {**defaults, **env_kwargs}
    return all(
        {**defaults, **(read_config(agent_dir(env_id, name, k)).get("env_kwargs") or {})}.get(key)
        == asked.get(key)
        for k in seeds(env_id, name)  # every training seed's task
        for key in keys
    )


def load(env_id: str, name: str, *, path: str | Path | None = None,
         seed: int | None = None) -> Any:
    """A shipped (or given) agent as a policy with SB3's ``predict`` and a ``name``.

    Args:
        env_id: the environment the agent will run on (its id and version must match).
        name: a name from :func:`available` (ignored for lookup when ``path`` is given, but
            used as the policy's name).
        path: an agent directory (e.g. a training run's output) instead of the shipped one.
        seed: the training seed of a multi-seed agent (default: its first, the lowest k of
            ``seed_<k>/``; the leaderboard's main table shows that one, :mod:`agents.report`
            all of them).

    Raises:
        ValueError: unknown agent, or a missing/corrupted/incompatible file (the message names
            it; :class:`agents.policy.AgentFileError` is a ValueError).

    Loading reads weights with ``torch.load(weights_only=True)`` and statistics with
    ``numpy.load(allow_pickle=False)``: no pickle is executed. Still, only load agents from
    sources you trust.
    """
    from cir_gym.agents.policy import load_agent

    if path is None:
        path = agent_dir(env_id, name, seed)
    return load_agent(Path(path), env_id=env_id, name=name,
                      earlier=EARLIER_VERSIONS.get(env_dir_name(env_id), ()))
