"""A trained agent as a policy with SB3's ``predict``, loaded from its directory without unpickling.

An agent directory holds ``config.yml`` (env id, env kwargs, algorithm, hyperparameters,
observation layout, residual controller and scale), ``model.zip`` (SB3's format),
``normalization.npz`` (the frozen VecNormalize observation statistics) and, for SB3 users,
``vecnormalize.pkl``. :func:`load_agent` rebuilds the SB3 policy network from the config and
reads only the weights (``policy.pth``, through ``torch.load(weights_only=True)``) from the zip
and plain arrays from the npz (``allow_pickle=False``): nothing is unpickled. SB3's own
``PPO.load`` and ``VecNormalize.load`` do unpickle (``model.zip``'s data, ``vecnormalize.pkl``)
— use those on trusted files only.

The agent accepts the environment's raw Dict observation, single or batched, and applies in
order: the observation layout (flatten + task errors), the frozen normalisation, the network,
and for residual agents ``clip(a_ctrl + scale ⊙ a_agent, −1, 1)`` with the controller's state
carried in ``state`` (reset where ``episode_start`` is true).
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from cir_gym.agents.hyperparameters import algorithm_class, resolve_policy_kwargs
from cir_gym.agents.observation import ObservationLayout
from cir_gym.agents.residual import check_scale, combine

__all__ = ["INTERFACE_KEYS", "AgentFileError", "TrainedAgent", "interface_defaults", "load_agent",
           "read_config"]

#: env arguments that set the action interface (what an action means and how often one is
#: taken): an agent acts only on the interface it was trained on, whatever the task's other
#: arguments. The other recorded env arguments (payload_mass, randomize, ...) are training
#: conditions; an evaluation chooses those.
INTERFACE_KEYS = ("control", "control_freq")

CONFIG = "config.yml"


def registered_defaults(env_id: str) -> tuple[type | None, dict[str, Any]]:
    """``env_id``'s cir_gym env class and the defaults of its arguments (the class's,
    overridden by the registered kwargs); ``(None, {})`` for an env id registered without
    cir_gym's entry point."""
    import gymnasium as gym

    from cir_gym.envs.base import default_arguments

    spec = gym.spec(env_id)
    cls = getattr(spec.entry_point, "cls", None)
    if cls is None:
        return None, {}
    return cls, {**default_arguments(cls), **(spec.kwargs or {})}


def interface_defaults(env_id: str) -> dict[str, Any]:
    """The defaults of ``env_id``'s :data:`INTERFACE_KEYS` arguments
    (:func:`registered_defaults`; e.g. ``{"control_freq": 500.0}`` for JointTracking-v2): the
    interface of an agent whose ``config.yml`` does not record them. Empty for an env id
    registered without cir_gym's entry point."""
    defaults = registered_defaults(env_id)[1]
    return {k: defaults[k] for k in INTERFACE_KEYS if defaults.get(k) is not None}


MODEL = "model.zip"
NORMALIZATION = "normalization.npz"


class AgentFileError(ValueError):
    """A missing, corrupted or incompatible agent file (the message names the file)."""


class TrainedAgent:
    """A trained SB3 policy behind SB3's ``predict`` protocol (see the module docstring).

    Attributes:
        name: agent name (its directory name).
        env_id: the environment id it was trained on.
        config: the agent's ``config.yml`` as a dict.
        controller: the residual's base controller, or None.
        interface_kwargs: the env arguments of its action interface at training
            (:data:`INTERFACE_KEYS`, e.g. PegInHole's ``{"control": "position",
            "control_freq": 100.0}``): the recorded ones, and for an argument not recorded
            the env's default that training then used (:func:`interface_defaults`), so an
            agent trained at the default 500 Hz refuses a 100-Hz env too. Evaluate it on
            ``gym.make(env_id, **task_kwargs, **agent.interface_kwargs)``.
    """

    def __init__(self, name: str, env_id: str, config: dict[str, Any], policy: Any,
                 layout: ObservationLayout, normalization: dict[str, Any],
                 controller: Any = None, scale: np.ndarray | None = None,
                 flatten: Any = None) -> None:
        self.name = name
        self.env_id = env_id
        self.config = config
        self.policy = policy
        self.layout = layout
        self.norm = normalization
        self.controller = controller
        self.scale = scale
        self.flatten = flatten or layout.flatten  # layout.bind(env) when it has features
        recorded = config.get("env_kwargs") or {}
        self.interface_kwargs = {**interface_defaults(env_id),
                                 **{k: recorded[k] for k in INTERFACE_KEYS if k in recorded}}

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """VecNormalize's observation transform with the frozen training statistics."""
        n = self.norm
        if not n["norm_obs"]:
            return x
        return np.clip((x - n["obs_mean"]) / np.sqrt(n["obs_var"] + n["epsilon"]),
                       -n["clip_obs"], n["clip_obs"]).astype(np.float32)

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """SB3's protocol: (action in [-1, 1] of the env's shape, state); single or batched."""
        x = self.normalize(self.flatten(observation))
        a_agent, _ = self.policy.predict(x, deterministic=deterministic)
        if self.controller is None:
            return np.asarray(a_agent, dtype=np.float32), None
        a_ctrl, state = self.controller.predict(observation, state=state,
                                                episode_start=episode_start, deterministic=True)
        return combine(a_ctrl, a_agent, self.scale), state

    def __repr__(self) -> str:
        res = (f", residual on {self.controller.name!r}" if self.controller is not None else "")
        return f"TrainedAgent({self.name!r}, {self.env_id}, {self.config['algo']}{res})"


def read_config(path: Path) -> dict[str, Any]:
    """``config.yml`` of an agent directory (plain YAML); AgentFileError if unreadable."""
    import yaml

    file = Path(path) / CONFIG
    try:
        config = yaml.safe_load(file.read_text())
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise AgentFileError(f"cannot read agent config {file}: {exc}") from exc
    required = ("env_id", "algo", "hyperparams", "observation")
    if not isinstance(config, dict) or any(k not in config for k in required):
        raise AgentFileError(f"{file} is not an agent config (needs keys {list(required)})")
    return config


def _read_weights(file: Path) -> dict[str, Any]:
    import torch

    try:
        with zipfile.ZipFile(file) as z:
            raw = z.read("policy.pth")
        return torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except FileNotFoundError as exc:
        raise AgentFileError(f"missing model file {file}") from exc
    except KeyError as exc:
        raise AgentFileError(f"{file} has no policy.pth: not an SB3 model zip") from exc
    except Exception as exc:  # BadZipFile, truncated data, torch unpickling refusals, ...
        raise AgentFileError(f"corrupted or unsupported model file {file}: "
                             f"{type(exc).__name__}: {exc}") from exc


def _read_normalization(file: Path) -> dict[str, Any]:
    if not file.exists():
        return {"norm_obs": False}
    try:
        with np.load(file, allow_pickle=False) as z:
            norm = {k: z[k] for k in z.files}
        out = {"norm_obs": bool(norm["norm_obs"]),
               "obs_mean": norm["obs_mean"].astype(np.float64),
               "obs_var": norm["obs_var"].astype(np.float64),
               "clip_obs": float(norm["clip_obs"]), "epsilon": float(norm["epsilon"])}
    except Exception as exc:
        raise AgentFileError(f"corrupted normalization file {file}: "
                             f"{type(exc).__name__}: {exc}") from exc
    return out


def load_agent(path: Path | str, env_id: str | None = None, name: str | None = None,
               earlier: tuple[str, ...] = ()) -> TrainedAgent:
    """Load the agent in directory ``path`` (see the module docstring).

    Args:
        path: agent directory (config.yml, model.zip, normalization.npz).
        env_id: the environment it will run on; must equal the trained id, version included,
            or the trained id must be one of ``earlier``.
        name: the agent's name (default: the directory name).
        earlier: earlier versions (``"JointTracking-v1"``) whose agents may run on ``env_id``
            (:data:`cir_gym.agents.EARLIER_VERSIONS`); the spaces are checked on ``env_id``.

    Raises:
        AgentFileError (a ValueError): missing/corrupted files, a different env id or version,
            observation/action spaces that no longer match the environment's.

    Side effect: ``torch.set_num_threads(1)`` in the calling process.
    """
    import gymnasium as gym

    import cir_gym  # noqa: F401  (registers the ids)

    path = Path(path)
    config = read_config(path)
    trained_id = str(config["env_id"])
    run_id = trained_id
    if env_id is not None and env_id.split(":")[-1] != trained_id:
        if trained_id.split("/")[-1] not in earlier:
            raise AgentFileError(f"agent {path} was trained on {trained_id}, not "
                                 f"{env_id.split(':')[-1]} (different environment or version)")
        run_id = env_id.split(":")[-1]
    if run_id not in gym.registry:
        raise AgentFileError(f"agent {path} needs environment {run_id}, which is not "
                             f"registered (removed or renamed version?)")
    try:
        layout = ObservationLayout.from_dict(config["observation"])
    except (KeyError, TypeError, ValueError) as exc:
        raise AgentFileError(f"{path / CONFIG}: bad observation layout ({exc})") from exc
    hp = config["hyperparams"]
    env_kwargs = config.get("env_kwargs") or {}
    env = gym.make(run_id, **env_kwargs)
    try:
        try:
            layout.check_space(env.observation_space)
        except ValueError as exc:
            raise AgentFileError(f"agent {path} no longer matches {run_id}: {exc}") from exc
        try:
            flatten = layout.bind(env)
        except ValueError as exc:
            raise AgentFileError(f"{path / CONFIG}: {exc}") from exc
        action_space = env.action_space
        residual = config.get("residual")
        controller, scale = None, None
        if residual:
            from cir_gym import baselines

            try:
                controller = baselines.make(residual["controller"], run_id, env=env,
                                            **(residual.get("controller_kwargs") or {}))
                scale = check_scale(residual["scale"], action_space)
            except (ValueError, TypeError, KeyError) as exc:
                raise AgentFileError(f"{path / CONFIG}: bad residual section ({exc})") from exc
    finally:
        env.close()
    try:
        cls = algorithm_class(config["algo"])
        policy_cls = cls.policy_aliases[hp.get("policy", "MlpPolicy")]
        kwargs = resolve_policy_kwargs(hp.get("policy_kwargs") or {})
        if hp.get("use_sde"):
            kwargs["use_sde"] = True
        policy = policy_cls(layout.space(), action_space, lambda _: 0.0, **kwargs)
    except (ValueError, TypeError, KeyError) as exc:
        raise AgentFileError(f"{path / CONFIG}: cannot build the policy ({exc})") from exc
    import torch

    torch.set_num_threads(1)  # small MLP: one thread is fastest; leaderboard workers share cores
    weights = _read_weights(path / MODEL)
    try:
        policy.load_state_dict(weights)
    except (RuntimeError, TypeError) as exc:
        raise AgentFileError(f"{path / MODEL} does not fit the policy in {path / CONFIG}: "
                             f"{exc}") from exc
    policy.set_training_mode(False)
    norm = _read_normalization(path / NORMALIZATION)
    if norm["norm_obs"] and norm["obs_mean"].shape != (layout.size,):
        raise AgentFileError(f"{path / NORMALIZATION}: statistics of size "
                             f"{norm['obs_mean'].shape} for an observation of size {layout.size}")
    return TrainedAgent(name or path.name, run_id, config, policy, layout, norm,
                        controller, scale, flatten)
