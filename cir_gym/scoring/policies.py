"""Policy resolution: a policy name on an environment → an object with SB3's ``predict``.

Names: a controller of :mod:`cir_gym.baselines` (``computed_torque``), a controller at the
gains tuned for a variant (``tuned:computed_torque``, :func:`tuned_gains`), a shipped agent
(``agent:ppo``, :mod:`cir_gym.agents`). ``--set key=value`` settings are split into
environment arguments and gains by :func:`split_settings`.
"""

from __future__ import annotations

import ast
import dataclasses
import json
from pathlib import Path
from typing import Any

import cir_gym
from cir_gym import baselines
from cir_gym.envs.base import constructor_arguments


class PolicyError(ValueError):
    """A policy that cannot be resolved: an unknown name, a gain or setting it does not take, or
    ``tuned:<controller>`` without a study for the asked arguments. The message says what is
    allowed."""


def parse_value(text: str) -> Any:
    """A ``--set`` value: a Python literal (``3.0``, ``True``, ``[1, 2]``) or else the text."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def check_env_id(env_id: str) -> str:
    """The registered id of ``env_id`` (``cir_gym:`` module prefix allowed)."""
    key = env_id.split(":")[-1]
    if key not in cir_gym.ENVIRONMENTS:
        raise PolicyError(f"unknown environment {env_id!r}; valid: {sorted(cir_gym.ENVIRONMENTS)}")
    return key


def agents_module() -> Any | None:
    """:mod:`cir_gym.agents`, or None when the ``train`` extra (SB3, torch) is not installed."""
    try:
        from cir_gym import agents
    except ImportError:  # the train extra (SB3, torch) is not installed
        return None
    return agents if hasattr(agents, "available") else None


def policy_names(env_id: str) -> list[str]:
    """Controllers, controllers at tuned gains (``tuned:<controller>``, :func:`tuned_gains`)
    and shipped agents (``agent:<name>``) that apply to an environment."""
    names = baselines.available(env_id)
    names += [f"tuned:{c}" for c in sorted({r["controller"] for r in _tuning_rows(env_id)})]
    ag = agents_module()
    if ag is not None:
        names += [f"agent:{a}" for a in ag.available(env_id)]
    return names


#: the gains ``scripts/tune_gains.py`` found, shipped with the package: ``<Env-vN>.json`` per
#: environment (the studies' reports are in the repository's ``results/tuning/``)
TUNED_GAINS_DIR = Path(__file__).resolve().parent / "tuned_gains"


def _tuning_rows(env_id: str) -> list[dict[str, Any]]:
    path = TUNED_GAINS_DIR / f"{env_id.split('/')[-1]}.json"
    return json.loads(path.read_text()) if path.is_file() else []


def _as_json(value: Any) -> Any:
    return json.loads(json.dumps(value))  # tuples as lists, as a JSON file holds them


def _tuned_row(env_id: str, controller: str, env_kwargs: dict[str, Any]) -> dict[str, Any] | None:
    """The study of ``controller`` on ``env_id`` with ``env_kwargs``, or None: the arguments
    must be the study's but for the env's ``reward_arguments`` (the controller's episodes do
    not depend on them)."""
    cls = cir_gym.ENVIRONMENTS.get(env_id, (None,))[0]
    reward_only = cls.reward_arguments if cls is not None else frozenset()

    def task(kwargs: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in kwargs.items() if k not in reward_only}

    asked = task(_as_json(env_kwargs))
    return next((r for r in _tuning_rows(env_id)
                 if r["controller"] == controller and task(r["env_kwargs"]) == asked), None)


def tuned_gains(env_id: str, controller: str, env_kwargs: dict[str, Any]) -> dict[str, float]:
    """The gains ``scripts/tune_gains.py`` found for ``controller`` on ``env_id`` with
    ``env_kwargs`` (a leaderboard variant's arguments; the env's ``reward_arguments`` may differ
    from the study's: they change the reward, not the episodes), from
    ``cir_gym/scoring/tuned_gains/<Env-vN>.json`` (Optuna on training seeds, never the
    leaderboard's; each file's header says which).

    Raises:
        PolicyError: no study of that controller with these arguments (the message lists the
            arguments it was tuned with).
    """
    row = _tuned_row(env_id, controller, env_kwargs)
    if row is not None:
        return dict(row["tuned"])
    tuned_with = [r["env_kwargs"] for r in _tuning_rows(env_id) if r["controller"] == controller]
    raise PolicyError(
        f"{controller} was not tuned for {env_id} with {env_kwargs or 'its default arguments'}; "
        f"tuned with: {tuned_with or 'nothing'} "
        f"({TUNED_GAINS_DIR / (env_id.split('/')[-1] + '.json')}, scripts/tune_gains.py)"
    )


def resolve_tuned(env_id: str, policy: str, env_kwargs: dict[str, Any],
                  gains: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """(controller, gains) of a policy name: ``tuned:<controller>`` is the controller at the
    gains tuned for ``env_kwargs`` (:func:`tuned_gains`) with ``gains`` (``--set``) over them;
    any other name is returned with ``gains`` as they are."""
    if not policy.startswith("tuned:"):
        return policy, gains
    controller = policy.removeprefix("tuned:")
    return controller, {**tuned_gains(env_id, controller, env_kwargs), **gains}


def has_tuned_gains(env_id: str, policy: str, env_kwargs: dict[str, Any]) -> bool:
    """False for ``tuned:<controller>`` without a study for ``env_kwargs``; True otherwise."""
    return (not policy.startswith("tuned:")
            or _tuned_row(env_id, policy.removeprefix("tuned:"), env_kwargs) is not None)


def trained_for(env_id: str, policy: str, env_kwargs: dict[str, Any]) -> bool:
    """False for a shipped agent (``agent:<name>``) trained for another task than
    ``env_kwargs`` asks (:func:`agents.trained_for`: RedundantIK's objective); True for a
    controller or a factory."""
    if not policy.startswith("agent:"):
        return True
    ag = agents_module()
    return ag is None or ag.trained_for(env_id, policy.removeprefix("agent:"), env_kwargs)


def split_settings(
    env_id: str, policy: str, settings: list[str]
) -> tuple[dict[str, Any], dict[str, Any]]:
    """``--set key=value`` → (environment kwargs, controller gains); unknown keys are errors."""
    env_cls = cir_gym.ENVIRONMENTS[env_id][0]
    env_keys = constructor_arguments(env_cls)
    gain_keys: list[str] = []
    controller = policy.removeprefix("tuned:")
    if controller in baselines.CONTROLLERS:
        gain_keys = [
            f.name
            for f in dataclasses.fields(baselines.controller_class(controller, env_id).Gains)
        ]
    env_kwargs: dict[str, Any] = {}
    gains: dict[str, Any] = {}
    for item in settings:
        if "=" not in item:
            raise PolicyError(f"--set expects key=value, got {item!r}")
        key, value = item.split("=", 1)
        if key in env_keys:
            env_kwargs[key] = parse_value(value)
        elif key in gain_keys:
            gains[key] = parse_value(value)
        else:
            raise PolicyError(
                f"unknown --set key {key!r}; environment arguments: {env_keys}; "
                f"gains of {policy!r}: {gain_keys}"
            )
    return env_kwargs, gains


def make_policy(env_id: str, policy: str, env_kwargs: dict[str, Any], gains: dict[str, Any]) -> Any:
    valid = policy_names(env_id)
    if policy not in valid:
        raise PolicyError(f"unknown policy {policy!r} for {env_id}; valid: {valid}")
    if policy.startswith("agent:"):
        ag = agents_module()
        assert ag is not None
        return ag.load(env_id, policy.split(":", 1)[1])
    policy, gains = resolve_tuned(env_id, policy, env_kwargs, gains)
    try:
        return baselines.make(policy, env_id, env_kwargs=env_kwargs, **gains)
    except (ValueError, TypeError) as exc:  # bad gain (InvalidGain) or environment argument
        raise PolicyError(str(exc)) from exc
