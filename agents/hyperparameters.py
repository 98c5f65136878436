"""Hyperparameters from ``agents/hyperparams/<algo>.yml``: rl-zoo3's own format, plus two
project sections rl-zoo3 never reads. Plain YAML, nothing evaluated here.

rl-zoo3 reads one entry of the file, the env id's (or ``default``), and passes every key it
does not know to the algorithm. So every entry is complete by itself (YAML merge keys,
``<<: *default``, copy ``default`` into it) and holds only keys rl-zoo3 understands::

    default: &default
      policy: MlpPolicy
      n_timesteps: 1000000            # an int or 1.0e+6 (YAML 1.1 reads 1.0e6 as a string)
      n_envs: 16
      normalize: {norm_obs: true, norm_reward: true}
      env_wrapper: cir_gym.agents.observation.TaskObservation  # Dict -> flat vector (+ k_ref - k)
      policy_kwargs: "dict(net_arch=[64, 64], activation_fn=nn.Tanh, log_std_init=-1.0)"
      learning_rate: 3.0e-4           # or "lin_3.0e-4" (linear decay to 0)
      ...                             # any other keyword of the SB3 algorithm
    cir_gym/JointTracking-v2:
      <<: *default
      n_timesteps: 5000000

    training:                         # agents.train only: evaluation, checkpoints, vec env
      default: {vec_env: dummy, eval_freq: 50000, n_eval_episodes: 5, checkpoint_freq: 250000}
      cir_gym/JointTracking-v2: {eval_freq: 150000}
    residual:                         # agents.train only: overrides for --residual CONTROLLER
      default: {scale: 0.25, zero_init_action: true}

``python -m rl_zoo3.train --algo ppo --env cir_gym/JointTracking-v2 --gym-packages cir_gym
--conf-file agents/hyperparams/ppo.yml`` trains from the file as it is.

For the project an entry is merged over ``default`` key by key (``policy_kwargs``,
``normalize`` and ``residual`` one level deeper), then the ``training`` section's ``default``
and id entries, then (residual agents) the ``residual`` section's. The older layout — the
training keys and a ``residual:`` mapping inside the entries, ``policy_kwargs`` as a mapping
with ``activation_fn: tanh`` — is still read. ``policy_kwargs`` strings are parsed, never
evaluated: only ``dict(...)`` with literal values and ``nn.<activation>`` from
:data:`ACTIVATIONS`. Unknown keys, algorithm arguments, wrappers or activation names raise
:class:`HyperparameterError` naming the file and the allowed values.
"""

from __future__ import annotations

import ast
import copy
import inspect
from pathlib import Path
from typing import Any

__all__ = [
    "ACTIVATIONS",
    "ALGORITHMS",
    "HYPERPARAMS_DIR",
    "HyperparameterError",
    "algorithm_class",
    "load_hyperparams",
    "observation_options",
    "parse_policy_kwargs",
    "resolve_policy_kwargs",
    "resolve_schedule",
]

HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"
#: SB3's on- and off-policy learners, and sb3-contrib's TQC and CrossQ (the ``zoo`` extra)
ALGORITHMS = ("ppo", "sac", "td3", "tqc", "crossq")

#: activation names usable in ``policy_kwargs.activation_fn`` → torch.nn class name
ACTIVATIONS = {
    "tanh": "Tanh",
    "relu": "ReLU",
    "elu": "ELU",
    "leaky_relu": "LeakyReLU",
    "gelu": "GELU",
    "silu": "SiLU",
}

#: keys handled here (not passed to the SB3 algorithm's constructor)
TRAINING_KEYS = {
    "policy": "SB3 policy name; observations are flattened, so MlpPolicy",
    "n_timesteps": "total environment steps",
    "n_envs": "parallel environments (DummyVecEnv, or SubprocVecEnv with vec_env: subproc)",
    "vec_env": "'dummy' (one process), 'subproc' (one process per env) or 'batched' (one "
               "mujoco.batch for all envs: JointTracking-v2, agents/batched.py)",
    "normalize": "VecNormalize: true/false or {norm_obs, norm_reward, clip_obs, gamma}",
    "policy_kwargs": "SB3 policy keywords (activation_fn by name)",
    "eval_freq": "environment steps between evaluations",
    "n_eval_episodes": "episodes per evaluation",
    "checkpoint_freq": "environment steps between checkpoints",
    "task_errors": "add k_ref - k features to the observation (true/false)",
    "zero_init_action": "zero the last layer of the actor (the action mean starts at 0)",
    "early_termination": "training only: {max_error, penalty, orientation_scale} "
                         "(agents/shaping.py)",
    "reward_offset": "training only: added to every step's reward (agents/shaping.py)",
    "log_error_bonus": "training only: {weight, max_error, floor, orientation_scale}: + weight "
                       "* ln(max_error / max(|error|, floor)) per step (agents/shaping.py)",
    "task_replay": "training only: plays per drawn task (RedundantIK's reset can replay its "
                   "task; agents/shaping.py TaskReplay), default 1",
    "noise_type": "off-policy exploration noise added to actions: 'normal' (TD3)",
    "noise_std": "std of that noise (action units)",
    "residual": "overrides used when training a residual agent",
    "env_wrapper": "rl-zoo3's observation wrapper: cir_gym.agents.observation.TaskObservation, "
                   "with optional {task_errors, features} (the project applies it itself)",
}
#: the observation wrapper rl-zoo3 must apply (the project's own EnvFactory applies it too)
ENV_WRAPPER = "cir_gym.agents.observation.TaskObservation"
WRAPPER_KEYS = {"task_errors", "features"}
#: top-level sections of a file that rl-zoo3 never reads (not environment ids)
SECTIONS = ("training", "residual")
RESIDUAL_KEYS = {"scale"}  # besides any top-level key
NORMALIZE_KEYS = {"norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon"}
POLICIES = ("MlpPolicy",)
VEC_ENVS = ("dummy", "subproc", "batched")
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")


class HyperparameterError(ValueError):
    """A malformed hyperparameter file or entry (names the file and the offending key)."""


def algorithm_class(algo: str) -> type:
    """The SB3 class of ``algo``, one of :data:`ALGORITHMS` ("tqc" and "crossq" from
    sb3-contrib)."""
    if algo not in ALGORITHMS:
        raise HyperparameterError(f"unknown algorithm {algo!r}; available: {list(ALGORITHMS)}")
    if algo in ("tqc", "crossq"):
        try:
            import sb3_contrib
        except ImportError as exc:
            raise HyperparameterError(
                f"{algo} is sb3-contrib's: pip install 'cir-gym[zoo]'"
            ) from exc
        return {"tqc": sb3_contrib.TQC, "crossq": sb3_contrib.CrossQ}[algo]
    import stable_baselines3 as sb3

    return {"ppo": sb3.PPO, "sac": sb3.SAC, "td3": sb3.TD3}[algo]


def _yaml_loader() -> type:
    """yaml.SafeLoader that also reads ``1e6`` / ``3.0e6`` as floats (YAML 1.2 style)."""
    import re

    import yaml

    class Loader(yaml.SafeLoader):
        pass

    Loader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
        list("-+0123456789"),
    )
    return Loader


def _read_yaml(path: Path) -> dict[str, Any]:
    import yaml

    if not path.is_file():
        raise HyperparameterError(f"no hyperparameter file {path}")
    try:
        data = yaml.load(path.read_text(), Loader=_yaml_loader())  # safe: SafeLoader subclass
    except yaml.YAMLError as exc:
        raise HyperparameterError(f"{path}: invalid YAML ({exc})") from exc
    if not isinstance(data, dict) or "default" not in data:
        raise HyperparameterError(f"{path}: expected a mapping of env ids with a 'default' entry")
    return data


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if k == "policy_kwargs" and isinstance(v, str):
            v = parse_policy_kwargs(v)
        if k in ("policy_kwargs", "residual", "normalize") and isinstance(v, dict) \
                and isinstance(out.get(k), dict):
            out[k] = {**out[k], **v}
        else:
            out[k] = copy.deepcopy(v)
    return out


def load_hyperparams(algo: str, env_id: str, *, residual: bool = False,
                     path: Path | str | None = None) -> dict[str, Any]:
    """Resolved hyperparameters of ``algo`` for ``env_id`` (plain data, as saved in config.yml).

    Args:
        algo: one of :data:`ALGORITHMS`.
        env_id: the environment id (a ``cir_gym:`` module prefix is ignored).
        residual: apply the entry's ``residual`` overrides (and keep ``residual_scale``).
        path: another YAML file (default ``agents/hyperparams/<algo>.yml``).

    Returns:
        The merged entry without the ``residual`` section; for residual agents ``scale`` is
        moved to ``residual_scale``.

    Raises:
        HyperparameterError: unknown keys, algorithm arguments, policy or activation names.
    """
    cls = algorithm_class(algo)
    file = Path(path) if path is not None else HYPERPARAMS_DIR / f"{algo}.yml"
    data = _read_yaml(file)
    key = env_id.split(":")[-1]
    try:
        entry = _merge(_parsed(data["default"]), _parsed(data.get(key)))
        training = _section(data, "training", file)
        entry = _merge(_merge(entry, _parsed(training.get("default"))),
                       _parsed(training.get(key)))
        res = entry.pop("residual", {}) or {}
        if not isinstance(res, dict):
            raise HyperparameterError(f"{file}: 'residual' must be a mapping, got {res!r}")
        section = _section(data, "residual", file)
        res = _merge(_merge(_parsed(res), _parsed(section.get("default"))),
                     _parsed(section.get(key)))
    except HyperparameterError as exc:
        raise HyperparameterError(f"{file} [{key}]: {exc}") from exc
    if residual:
        scale = res.get("scale")
        entry = _merge(entry, {k: v for k, v in res.items() if k != "scale"})
        if scale is None:
            raise HyperparameterError(f"{file}: residual training needs residual.scale "
                                      f"(in {key!r} or 'default')")
        entry["residual_scale"] = scale
    _validate(entry, cls, file, key)
    return entry


def _parsed(entry: Any) -> dict[str, Any]:
    """An entry (or None) with a ``policy_kwargs`` string parsed into a mapping."""
    if entry is None:
        return {}
    if not isinstance(entry, dict):
        raise HyperparameterError(f"expected a mapping, got {entry!r}")
    out = dict(entry)
    if isinstance(out.get("policy_kwargs"), str):
        out["policy_kwargs"] = parse_policy_kwargs(out["policy_kwargs"])
    return out


def _section(data: dict[str, Any], name: str, file: Path) -> dict[str, Any]:
    """A top-level project section ({default, <env id>: {...}}), or {} if absent."""
    section = data.get(name) or {}
    if not isinstance(section, dict) or not all(isinstance(v, dict) or v is None
                                                for v in section.values()):
        raise HyperparameterError(f"{file}: top-level {name!r} must map 'default' and env ids "
                                  f"to mappings")
    return section


def parse_policy_kwargs(text: str) -> dict[str, Any]:
    """rl-zoo3's ``policy_kwargs`` string, parsed without evaluation.

    Only ``dict(key=value, ...)`` is accepted, with literal values (numbers, strings, lists,
    nested ``dict(...)``) and activations ``nn.<Name>`` of :data:`ACTIVATIONS`, which come
    back by their short name: ``"dict(net_arch=[64], activation_fn=nn.Tanh)"`` →
    ``{"net_arch": [64], "activation_fn": "tanh"}``.
    """
    by_class = {v: k for k, v in ACTIVATIONS.items()}

    def value(node: ast.AST) -> Any:
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id == "dict" and not node.args:
            return {kw.arg: value(kw.value) for kw in node.keywords if kw.arg is not None}
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id == "nn":
            if node.attr not in by_class:
                raise HyperparameterError(f"policy_kwargs: activation nn.{node.attr} not "
                                          f"allowed; allowed: {sorted(by_class)}")
            return by_class[node.attr]
        if isinstance(node, (ast.List, ast.Tuple)):
            return [value(e) for e in node.elts]
        if isinstance(node, ast.Dict):
            return {value(k): value(v) for k, v in zip(node.keys, node.values, strict=True)}
        try:
            return ast.literal_eval(node)
        except ValueError as exc:
            raise HyperparameterError(f"policy_kwargs: {ast.unparse(node)!r} is not a literal, "
                                      f"dict(...) or nn.<activation>") from exc

    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise HyperparameterError(f"policy_kwargs: not a Python expression: {text!r}") from exc
    out = value(tree.body)
    if not isinstance(out, dict):
        raise HyperparameterError(f"policy_kwargs must be dict(...), got {text!r}")
    return out


def observation_options(hp: dict[str, Any], where: str = "hyperparameters"
                        ) -> dict[str, Any]:
    """{task_errors, features} of the observation, from ``env_wrapper`` (rl-zoo3's key) and
    the older ``task_errors`` training key."""
    opts: dict[str, Any] = {"task_errors": hp.get("task_errors", True), "features": []}
    wrapper = hp.get("env_wrapper")
    if wrapper is None:
        return opts
    if isinstance(wrapper, list) and len(wrapper) == 1:
        wrapper = wrapper[0]
    name, kwargs = (wrapper, {}) if isinstance(wrapper, str) else \
        (next(iter(wrapper)), next(iter(wrapper.values())) or {}) \
        if isinstance(wrapper, dict) and len(wrapper) == 1 else (None, None)
    if name != ENV_WRAPPER or not isinstance(kwargs, dict) or set(kwargs) - WRAPPER_KEYS:
        raise HyperparameterError(f"{where}: env_wrapper must be {ENV_WRAPPER!r} or "
                                  f"{{{ENV_WRAPPER}: {{task_errors, features}}}}, got {wrapper!r}")
    opts.update(kwargs)
    opts["features"] = list(opts.get("features") or [])
    return opts


def _validate(entry: dict[str, Any], cls: type, file: Path, key: str) -> None:
    where = f"{file} [{key}]"
    reserved = {"self", "policy", "env", "seed", "device", "verbose", "tensorboard_log",
                "_init_setup_model"}  # set by agents.train, not by the file
    algo_args = set(inspect.signature(cls.__init__).parameters) - reserved
    allowed = set(TRAINING_KEYS) | algo_args | {"residual_scale"}
    unknown = sorted(set(entry) - allowed)
    if unknown:
        raise HyperparameterError(
            f"{where}: unknown key(s) {unknown}; training keys: {sorted(TRAINING_KEYS)}; "
            f"{cls.__name__} arguments: {sorted(algo_args)}"
        )
    if entry.get("policy", "MlpPolicy") not in POLICIES:
        raise HyperparameterError(f"{where}: policy must be one of {POLICIES} (observations are "
                                  f"flattened by agents.observation), got {entry['policy']!r}")
    norm = entry.get("normalize", False)
    if isinstance(norm, dict):
        bad = sorted(set(norm) - NORMALIZE_KEYS)
        if bad:
            raise HyperparameterError(f"{where}: unknown normalize key(s) {bad}; allowed: "
                                      f"{sorted(NORMALIZE_KEYS)}")
    elif not isinstance(norm, bool):
        raise HyperparameterError(f"{where}: normalize must be true/false or a mapping")
    early = entry.get("early_termination")
    if early is not None and (not isinstance(early, dict) or "max_error" not in early
                              or set(early) - {"max_error", "penalty", "orientation_scale"}):
        raise HyperparameterError(f"{where}: early_termination must be "
                                  f"{{max_error: <float>, penalty: <float, optional>, "
                                  f"orientation_scale: <float >= 0, optional>}}")
    replay = entry.get("task_replay", 1)
    if isinstance(replay, bool) or not isinstance(replay, int) or replay < 1:
        raise HyperparameterError(f"{where}: task_replay must be an integer >= 1 (plays per "
                                  f"drawn task), got {replay!r}")
    if entry.get("log_error_bonus") is not None:
        from cir_gym.agents.shaping import check_log_error_bonus

        try:
            check_log_error_bonus(entry["log_error_bonus"])
        except ValueError as exc:
            raise HyperparameterError(f"{where}: {exc}") from exc
    from cir_gym.agents.observation import FEATURES

    features = observation_options(entry, where)["features"]
    if set(features) - set(FEATURES):
        raise HyperparameterError(f"{where}: unknown observation feature(s) "
                                  f"{sorted(set(features) - set(FEATURES))}; allowed: "
                                  f"{sorted(FEATURES)}")
    if entry.get("vec_env", "dummy") not in VEC_ENVS:
        raise HyperparameterError(f"{where}: vec_env must be one of {VEC_ENVS}, got "
                                  f"{entry['vec_env']!r}")
    resolve_policy_kwargs(entry.get("policy_kwargs") or {}, where=where)
    for k in SCHEDULE_KEYS:
        if k in entry:
            resolve_schedule(entry[k], where=f"{where} {k}")


def resolve_policy_kwargs(kwargs: dict[str, Any], *, where: str = "policy_kwargs"
                          ) -> dict[str, Any]:
    """Plain policy_kwargs → SB3's: ``activation_fn`` name → torch class (whitelist only)."""
    import torch.nn as nn

    if not isinstance(kwargs, dict):
        raise HyperparameterError(f"{where}: policy_kwargs must be a mapping, got {kwargs!r}")
    out = dict(kwargs)
    if "activation_fn" in out:
        name = out["activation_fn"]
        if not isinstance(name, str) or name not in ACTIVATIONS:
            raise HyperparameterError(
                f"{where}: unknown activation_fn {name!r}; allowed: {sorted(ACTIVATIONS)}"
            )
        out["activation_fn"] = getattr(nn, ACTIVATIONS[name])
    return out


def resolve_schedule(value: Any, *, where: str = "schedule") -> Any:
    """A float, or ``"lin_<float>"`` → a linear schedule from that value to 0."""
    if isinstance(value, bool):
        raise HyperparameterError(f"{where}: expected a number or 'lin_<float>', got {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str) and value.startswith("lin_"):
        try:
            start = float(value[4:])
        except ValueError as exc:
            raise HyperparameterError(f"{where}: bad schedule {value!r}") from exc
        return LinearSchedule(start)
    raise HyperparameterError(f"{where}: expected a number or 'lin_<float>', got {value!r}")


class LinearSchedule:
    """progress_remaining (1 → 0) ↦ start · progress_remaining (picklable, unlike a lambda)."""

    def __init__(self, start: float) -> None:
        self.start = start

    def __call__(self, progress_remaining: float) -> float:
        return self.start * progress_remaining

    def __repr__(self) -> str:
        return f"lin_{self.start}"
