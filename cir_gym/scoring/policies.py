"""Policy resolution: a policy name on an environment → an object with SB3's ``predict``.

Names: a controller of :mod:`cir_gym.baselines` (``computed_torque``), a controller at the
gains tuned for a variant (``tuned:computed_torque``, :func:`tuned_gains`), a shipped agent
(``agent:ppo``, :mod:`cir_gym.agents`; needs the ``train`` extra) and a third party's policy
installed under the entry-point group ``cir_gym.policies`` (``plugin:<name>``,
:func:`plugin_factories`; docs/policies.md). ``--set key=value`` settings are split into
environment arguments and gains by :func:`split_settings`.
"""

from __future__ import annotations

import ast
import dataclasses
import difflib
import importlib.metadata
import importlib.util
import json
import sys
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import cir_gym
from cir_gym import baselines
from cir_gym.envs.base import constructor_arguments, default_arguments

#: the prefixes of policy names that are not a plain controller
PREFIXES = ("tuned:", "agent:", "plugin:")
#: the entry-point group of third-party policies: ``name = "module:factory"``, where
#: ``factory(env_id, env_kwargs)`` returns an object with SB3's ``predict``
ENTRY_POINT_GROUP = "cir_gym.policies"
#: what a user installs to run the shipped agents
TRAIN_EXTRA = "pip install 'cir-gym[train]'"
#: arguments that set only how long an episode lasts: a tuned controller's study holds for
#: any value of them (:func:`tuned_gains`)
LENGTH_ARGUMENTS = frozenset({"episode_duration"})
#: the modules a shipped agent needs (the train extra)
TRAIN_MODULES = ("yaml", "torch", "stable_baselines3")


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


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``choices`` to ``word`` (difflib), or ""."""
    close = difflib.get_close_matches(word, list(choices), n=2, cutoff=0.6)
    return f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ""


def check_env_id(env_id: str) -> str:
    """The registered id of ``env_id``: ``cir_gym/JointTracking-v2``, ``JointTracking-v2``
    (the ``cir_gym/`` namespace is optional) or ``cir_gym:cir_gym/JointTracking-v2`` (with
    Gymnasium's module prefix).

    Raises:
        PolicyError: no such environment (the message suggests the closest id, lists them all).
    """
    key = env_id.split(":")[-1]
    if key not in cir_gym.ENVIRONMENTS and f"cir_gym/{key}" in cir_gym.ENVIRONMENTS:
        key = f"cir_gym/{key}"
    if key not in cir_gym.ENVIRONMENTS:
        names = {e.split("/")[-1]: e for e in cir_gym.ENVIRONMENTS}
        close = difflib.get_close_matches(key.split("/")[-1], list(names), n=2, cutoff=0.6)
        hint = f" (did you mean {' or '.join(repr(names[c]) for c in close)}?)" if close else ""
        raise PolicyError(
            f"unknown environment {env_id!r}{hint}; valid: {sorted(cir_gym.ENVIRONMENTS)} "
            "(the 'cir_gym/' prefix may be left out)"
        )
    return key


def task_id(env_id: str) -> str:
    """The id of the task ``env_id`` plays: an agent-ready variant's task (its class's
    ``task_class`` registered under its own id: ``cir_gym/PegInHoleImpedance-v0`` →
    ``cir_gym/PegInHole-v2``), else ``env_id`` itself. Same seeds, metrics and success: the
    leaderboard ranks every interface of a task in the task's tables. An id that is not
    registered is its own task."""
    task = getattr(cir_gym.ENVIRONMENTS.get(env_id, (None,))[0], "task_class", None)
    return next((e for e, (cls, _) in cir_gym.ENVIRONMENTS.items() if cls is task), env_id)


def interface_ids(task: str) -> list[str]:
    """``task`` and the ids that play it at another interface (:func:`task_id`), in
    ``cir_gym.ENVIRONMENTS``' order."""
    return [task] + [e for e in cir_gym.ENVIRONMENTS if e != task and task_id(e) == task]


def row_label(env_id: str, policy: str) -> str:
    """A policy's row in its task's tables: ``policy`` on the task's own id, ``policy
    [<Interface-vN>]`` on another interface (``impedance_insertion [PegInHoleImpedance-v0]``).
    The prefixes of :data:`PREFIXES` stay in front (an agent's row is still ``agent:…``)."""
    return policy if task_id(env_id) == env_id else f"{policy} [{env_id.split('/')[-1]}]"


def policy_of_row(label: str) -> str:
    """The policy name of a row label (:func:`row_label` undone; the interface's id is the
    result's ``env_id``)."""
    return label.split(" [", 1)[0]


def module_missing(name: str) -> bool:
    """Whether top-level module ``name`` cannot be imported, looked up without importing it
    (torch takes seconds)."""
    if name in sys.modules:
        return sys.modules[name] is None
    try:
        return importlib.util.find_spec(name) is None
    except (ImportError, ValueError):  # a finder that refuses it, a broken parent module
        return True


def train_extra_missing() -> list[str]:
    """The modules of the ``train`` extra that cannot be imported (none: agents can run)."""
    return [name for name in TRAIN_MODULES if module_missing(name)]


def agents_module() -> Any | None:
    """:mod:`cir_gym.agents`, or None when the ``train`` extra (SB3, torch, PyYAML) is not
    installed: a shipped agent cannot be loaded then."""
    if train_extra_missing():
        return None
    try:
        from cir_gym import agents
    except ImportError:
        return None
    return agents if hasattr(agents, "available") else None


def shipped_agents(env_id: str) -> list[str]:
    """``agent:<name>`` of every agent shipped for ``env_id``, whether or not the ``train``
    extra is installed to run them (the directories are package data)."""
    from cir_gym import agents  # imports neither torch, SB3 nor yaml

    return [f"agent:{a}" for a in agents.available(env_id)]


_PLUGINS: dict[str, Any] | None = None


def plugin_factories(refresh: bool = False) -> dict[str, Any]:
    """The installed distributions' policies: ``plugin:<name>`` → its entry point (group
    ``cir_gym.policies``, :data:`ENTRY_POINT_GROUP`), read once per process (``refresh``
    reads the installed distributions again)."""
    global _PLUGINS
    if _PLUGINS is None or refresh:
        eps = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
        _PLUGINS = {f"plugin:{ep.name}": ep for ep in sorted(eps, key=lambda e: e.name)}
    return _PLUGINS


_LOADED: dict[str, Callable[..., Any] | Exception] = {}


def plugin_factory(name: str) -> Callable[..., Any]:
    """The factory of plugin policy ``name`` (``plugin:<name>``), imported once.

    Raises:
        PolicyError: no such entry point, or it failed to import (the message says which).
    """
    ep = plugin_factories().get(name)
    if ep is None:
        raise PolicyError(
            f"no installed policy {name!r}{did_you_mean(name, plugin_factories())}; "
            f"installed ({ENTRY_POINT_GROUP} entry points): {sorted(plugin_factories())}"
        )
    if name not in _LOADED:
        try:
            _LOADED[name] = ep.load()
        except Exception as exc:  # a third party's import error: name it, never crash a list
            _LOADED[name] = exc
    loaded = _LOADED[name]
    if isinstance(loaded, Exception):
        raise PolicyError(
            f"{name} ({ep.value}, entry point of {ENTRY_POINT_GROUP}) failed to load: "
            f"{type(loaded).__name__}: {loaded}"
        )
    return loaded


def plugin_applies(name: str, env_id: str) -> bool:
    """Whether plugin policy ``name`` applies to ``env_id``: its factory's optional
    ``env_ids`` attribute (ids, with or without ``cir_gym/``) holds the id, or it has none.
    A plugin that fails to load applies nowhere (a warning names it)."""
    try:
        factory = plugin_factory(name)
    except PolicyError as exc:
        warnings.warn(str(exc), stacklevel=2)
        return False
    ids = getattr(factory, "env_ids", None)
    return ids is None or env_id in ids or env_id.split("/")[-1] in ids


def policy_names(env_id: str) -> list[str]:
    """Controllers, controllers at tuned gains (``tuned:<controller>``, :func:`tuned_gains`),
    shipped agents (``agent:<name>``; only with the ``train`` extra installed) and installed
    plugin policies (``plugin:<name>``) that apply to an environment."""
    names = baselines.available(env_id)
    names += [f"tuned:{c}" for c in sorted({r["controller"] for r in _tuning_rows(env_id)})]
    if agents_module() is not None:
        names += shipped_agents(env_id)
    names += [p for p in plugin_factories() if plugin_applies(p, env_id)]
    return names


def is_policy_name(policy: str) -> bool:
    """Whether ``policy`` has the form of a policy name (a controller, or one of
    :data:`PREFIXES`), as opposed to a sweep's ``module:callable`` factory."""
    return ":" not in policy or policy.startswith(PREFIXES)


#: the gains ``scripts/tune_gains.py`` found, shipped with the package: ``<Env-vN>.json`` per
#: environment (the studies' reports are in the repository's ``results/tuning/``)
TUNED_GAINS_DIR = Path(__file__).resolve().parent / "tuned_gains"


def _tuning_rows(env_id: str) -> list[dict[str, Any]]:
    path = TUNED_GAINS_DIR / f"{env_id.split('/')[-1]}.json"
    return json.loads(path.read_text()) if path.is_file() else []


def _as_json(value: Any) -> Any:
    """``value`` as a JSON file holds it (tuples as lists; an object as its ``str``)."""
    return json.loads(json.dumps(value, default=str))


def _tuned_row(env_id: str, controller: str, env_kwargs: dict[str, Any]) -> dict[str, Any] | None:
    """The study of ``controller`` on ``env_id`` with ``env_kwargs``, or None: the arguments
    (an argument left out is its default: ``payload_mass=0.0`` is the default study) must be
    the study's but for the env's ``reward_arguments`` (the controller's episodes do not depend
    on them) and the episode's length (:data:`LENGTH_ARGUMENTS`: a shorter episode is the
    start of the same one, so the gains are those tuned for the task)."""
    cls = cir_gym.ENVIRONMENTS.get(env_id, (None,))[0]
    ignored = frozenset(cls.reward_arguments if cls is not None else ()) | LENGTH_ARGUMENTS
    defaults = default_arguments(cls) if cls is not None else {}

    def same_task(study: dict[str, Any], asked: dict[str, Any]) -> bool:
        for key in (set(study) | set(asked)) - ignored:
            a = study[key] if key in study else _as_json(defaults.get(key))
            b = asked[key] if key in asked else _as_json(defaults.get(key))
            if a != b:
                return False
        return True

    asked = _as_json(env_kwargs)
    return next((r for r in _tuning_rows(env_id)
                 if r["controller"] == controller and same_task(r["env_kwargs"], asked)), None)


def tuned_gains(env_id: str, controller: str, env_kwargs: dict[str, Any]) -> dict[str, float]:
    """The gains ``scripts/tune_gains.py`` found for ``controller`` on ``env_id`` with
    ``env_kwargs`` (a leaderboard variant's arguments; the env's ``reward_arguments`` and the
    episode's duration may differ from the study's: they change the reward or how long the same
    episode runs, not the task), from
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
                f"unknown --set key {key!r}{did_you_mean(key, env_keys + gain_keys)}; "
                f"environment arguments: {env_keys}; "
                f"gains of {policy!r}: {gain_keys}"
            )
    return env_kwargs, gains


def check_policy(env_id: str, policy: str) -> str:
    """``policy`` if it is one of :func:`policy_names` of ``env_id``.

    Raises:
        PolicyError: a shipped agent without the ``train`` extra (the message names the
            install command), or an unknown name (with the closest valid one).
    """
    valid = policy_names(env_id)
    if policy in valid:
        return policy
    if policy in shipped_agents(env_id):
        raise PolicyError(
            f"{policy} is a trained agent: running it needs the train extra (missing: "
            f"{', '.join(train_extra_missing())}): {TRAIN_EXTRA}"
        )
    if policy.startswith("plugin:") and policy in plugin_factories():
        plugin_factory(policy)  # a load error says why
        raise PolicyError(
            f"{policy} does not apply to {env_id}: its factory's env_ids are "
            f"{list(getattr(plugin_factory(policy), 'env_ids', []))}"
        )
    candidates = list(dict.fromkeys(valid + shipped_agents(env_id)))
    hint = did_you_mean(policy, candidates)
    if not hint and ":" not in policy:  # 'ppo_100hz' for 'agent:ppo_100hz'
        bare = {c.split(":", 1)[-1]: c for c in candidates}
        close = difflib.get_close_matches(policy, list(bare), n=1, cutoff=0.6)
        hint = f" (did you mean {bare[close[0]]!r}?)" if close else ""
    raise PolicyError(f"unknown policy {policy!r} for {env_id}{hint}; valid: {valid}")


def check_env_kwargs(env_id: str, env_kwargs: dict[str, Any], option: str = "--set") -> None:
    """Build ``env_id``'s class with ``env_kwargs`` once, so a bad value is reported before any
    work, in our words: the option, the argument, the value and what is allowed.

    Raises:
        PolicyError: the constructor refused a value (InvalidArgument, ValueError, TypeError).
    """
    cls = cir_gym.ENVIRONMENTS[env_id][0]
    try:
        env = cls(**env_kwargs)
    except (ValueError, TypeError) as exc:
        bad = [k for k in env_kwargs if k in str(exc)] or list(env_kwargs)
        defaults = default_arguments(cls)
        given = ", ".join(f"{option} {k}={env_kwargs[k]}" for k in bad)
        default = "; ".join(f"{k} defaults to {defaults[k]!r}" for k in bad if k in defaults)
        raise PolicyError(f"{given}: {exc}" + (f" ({default})" if default else "")) from None
    env.close()


def make_policy(env_id: str, policy: str, env_kwargs: dict[str, Any], gains: dict[str, Any]) -> Any:
    """The policy named ``policy`` for ``env_id`` with ``env_kwargs``, at ``gains`` (a
    controller's; a tuned controller's over its tuned gains).

    Raises:
        PolicyError: an unknown name, a bad gain, a missing extra or a failing plugin.
    """
    check_policy(env_id, policy)
    if policy.startswith("agent:"):
        ag = agents_module()
        assert ag is not None
        return ag.load(env_id, policy.split(":", 1)[1])
    if policy.startswith("plugin:"):
        if gains:
            raise PolicyError(f"{policy} takes no gains (--set {', '.join(gains)})")
        made = plugin_factory(policy)(env_id, dict(env_kwargs))
        if not callable(getattr(made, "predict", None)):
            raise PolicyError(
                f"{policy}'s factory returned {type(made).__name__}, which has no predict("
                "observation, state=None, episode_start=None, deterministic=True) method"
            )
        return made
    policy, gains = resolve_tuned(env_id, policy, env_kwargs, gains)
    try:
        return baselines.make(policy, env_id, env_kwargs=env_kwargs, **gains)
    except (ValueError, TypeError) as exc:  # bad gain (InvalidGain) or environment argument
        raise PolicyError(str(exc)) from exc
