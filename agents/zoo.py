"""A shipped agent in rl-zoo3's folder layout, so that ``rl_zoo3.enjoy`` and
``rl_zoo3.record_video`` run it.

rl-zoo3 finds a trained agent by ``--algo``, ``--env`` and ``--exp-id`` in a log folder::

    <folder>/<algo>/<EnvName>_<k>/<EnvName>.zip          the SB3 model (PPO.load)
    <folder>/<algo>/<EnvName>_<k>/<EnvName>/config.yml   hyperparameters: env_wrapper, normalize
    <folder>/<algo>/<EnvName>_<k>/<EnvName>/vecnormalize.pkl   observation statistics
    <folder>/<algo>/<EnvName>_<k>/<EnvName>/args.yml     env_kwargs of the environment

where ``<EnvName>`` is the id with ``/`` replaced by ``-`` (``cir_gym-JointTracking-v2``;
huggingface_sb3's ``EnvironmentName``). :func:`export_zoo` writes that for one shipped agent
(:func:`cir_gym.agents.load` checks it runs on the id first): the model zip as trained; the
wrappers that turn the env into what the network saw (``env_wrapper``: the residual agent's
:class:`~cir_gym.agents.residual.ResidualAction` with its base controller and scale, then
:class:`~cir_gym.agents.observation.TaskObservation` with the agent's observation layout); a
``vecnormalize.pkl`` written from the agent's ``normalization.npz`` (the statistics
:func:`cir_gym.agents.load` uses) and the agent's recorded env arguments.

An agent trained on an earlier version (``<name>@<Env-vK>``,
:data:`cir_gym.agents.EARLIER_VERSIONS`) is exported under today's id, which keeps its spaces
and dynamics: rl-zoo3 then makes the registered version. Then, with ``--gym-packages cir_gym``
registering the ids::

    cir-gym export-zoo --env cir_gym/JointTracking-v2 --agent ppo_100hz@JointTracking-v1 \\
        --out logs
    python -m rl_zoo3.enjoy --algo ppo --env cir_gym/JointTracking-v2 --gym-packages cir_gym \\
        -f logs --exp-id 1 --deterministic --no-render -n 1000

``rl_zoo3.record_video`` has no ``--gym-packages``: :func:`record_video_command` starts it
through ``python -c`` after ``import cir_gym`` (the ``cir_gym:``-prefixed id does not do it:
rl-zoo3 looks the id up in Gymnasium's registry, where ``cir_gym:cir_gym/...`` is no key,
before it makes the env). rl-zoo3 unpickles ``vecnormalize.pkl`` and the model zip's data
(``PPO.load``): run it on exports you made.
"""

from __future__ import annotations

import re
import shlex
import shutil
import sys
from pathlib import Path
from typing import Any

import yaml

__all__ = ["enjoy_command", "export_zoo", "record_video_command", "zoo_env_name"]

OBSERVATION_WRAPPER = "cir_gym.agents.observation.TaskObservation"
RESIDUAL_WRAPPER = "cir_gym.agents.residual.ResidualAction"


def zoo_env_name(env_id: str) -> str:
    """rl-zoo3's folder name of an env id: 'cir_gym/JointTracking-v2' →
    'cir_gym-JointTracking-v2' (a ``module:`` prefix dropped)."""
    return env_id.split(":")[-1].replace("/", "-")


def _next_exp_id(algo_dir: Path, env_name: str) -> int:
    found = [int(m.group(1)) for p in algo_dir.glob(f"{env_name}_*")
             if (m := re.fullmatch(re.escape(env_name) + r"_(\d+)", p.name))]
    return max(found, default=0) + 1


def _wrappers(agent: Any) -> list[dict[str, dict[str, Any]]]:
    """rl-zoo3's ``env_wrapper`` list (innermost first) that rebuilds the agent's observation
    and action: ResidualAction (residual agents), then TaskObservation with the layout's
    ``task_errors`` and ``features``.

    Raises:
        ValueError: the agent's layout is not one TaskObservation makes from the env's space.
    """
    import gymnasium as gym
    from cir_gym.agents.observation import ObservationLayout

    out: list[dict[str, dict[str, Any]]] = []
    residual = agent.config.get("residual")
    if residual:
        kwargs = {"controller": residual["controller"], "scale": list(residual["scale"])}
        out.append({RESIDUAL_WRAPPER: {**kwargs, **(residual.get("controller_kwargs") or {})}})
    env = gym.make(agent.env_id, **(agent.config.get("env_kwargs") or {}))
    space = env.observation_space
    env.close()
    features = list(agent.layout.features)
    for task_errors in (True, False):
        if ObservationLayout.from_space(space, task_errors, features) == agent.layout:
            out.append({OBSERVATION_WRAPPER: {"task_errors": task_errors, "features": features}})
            return out
    raise ValueError(f"the observation layout of {agent.name} ({agent.layout}) is not one "
                     f"{OBSERVATION_WRAPPER} makes from {agent.env_id}'s observation space")


def _write_vecnormalize(agent: Any, wrappers: list[dict[str, dict[str, Any]]],
                        path: Path) -> None:
    """``vecnormalize.pkl`` with the agent's frozen observation statistics (training off, no
    reward normalisation), over the env the wrappers make."""
    import gymnasium as gym
    import numpy as np
    from cir_gym.agents.observation import TaskObservation
    from cir_gym.agents.residual import ResidualAction
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    def make() -> gym.Env:
        env = gym.make(agent.env_id, **(agent.config.get("env_kwargs") or {}))
        for entry in wrappers:
            (name, kwargs), = entry.items()
            cls = ResidualAction if name == RESIDUAL_WRAPPER else TaskObservation
            env = cls(env, **kwargs)
        return env

    norm = agent.norm
    venv = VecNormalize(DummyVecEnv([make]), training=False, norm_obs=True, norm_reward=False,
                        clip_obs=float(norm["clip_obs"]), epsilon=float(norm["epsilon"]))
    venv.obs_rms.mean = np.asarray(norm["obs_mean"], dtype=np.float64)
    venv.obs_rms.var = np.asarray(norm["obs_var"], dtype=np.float64)
    venv.save(str(path))
    venv.close()


def export_zoo(env_id: str, name: str, folder: str | Path, *, seed: int | None = None,
               exp_id: int | None = None) -> Path:
    """Write shipped agent ``name`` of ``env_id`` into ``folder`` in rl-zoo3's layout (module
    docstring); return the experiment folder ``<folder>/<algo>/<EnvName>_<exp_id>``.

    Args:
        env_id: a registered id the agent runs on (today's version: an earlier version's agent
            is named ``<agent>@<Env-vK>``).
        name: a name from :func:`cir_gym.agents.available`.
        folder: rl-zoo3's log folder (``-f``).
        seed: the training seed of a multi-seed agent (default: its first).
        exp_id: rl-zoo3's experiment id (``--exp-id``); default: one more than the highest in
            the folder, which is the one ``--exp-id 0`` (latest) loads.

    Raises:
        ValueError: an unknown agent, one that does not run on ``env_id``, an existing
            experiment folder, or a layout rl-zoo3's wrappers cannot rebuild.
    """
    from cir_gym.agents.train import retrain_command

    from cir_gym import agents

    key = env_id.split(":")[-1]
    agent = agents.load(key, name, seed=seed)  # checks the files and the spaces on env_id
    source = agents.agent_dir(key, name, seed)
    algo = str(agent.config["algo"])
    env_name = zoo_env_name(key)
    algo_dir = Path(folder) / algo
    k = exp_id if exp_id is not None else _next_exp_id(algo_dir, env_name)
    run = algo_dir / f"{env_name}_{k}"
    if run.exists():
        raise ValueError(f"{run} exists; pass another exp_id (--exp-id) or folder")
    wrappers = _wrappers(agent)
    stats = run / env_name
    stats.mkdir(parents=True)
    shutil.copy2(source / "model.zip", run / f"{env_name}.zip")
    normalize = bool(agent.norm["norm_obs"])
    if normalize:
        _write_vecnormalize(agent, wrappers, stats / "vecnormalize.pkl")
    hp = agent.config["hyperparams"]
    config = {
        "policy": hp.get("policy", "MlpPolicy"),
        "n_timesteps": int(agent.config.get("n_timesteps", 0)),
        "normalize": {"norm_obs": True, "norm_reward": False} if normalize else False,
        "env_wrapper": wrappers,
    }
    (stats / "config.yml").write_text(yaml.safe_dump(config, sort_keys=False))
    args = {
        "algo": algo,
        "env": key,
        "env_kwargs": dict(agent.config.get("env_kwargs") or {}),
        "seed": int(agent.config.get("seed", 0)),
        "gym_packages": ["cir_gym"],
        "cir_gym_agent": name,
        "trained_on": str(agent.config["env_id"]),
        "source": str(source),
        "retrain": retrain_command(agent.config),
    }
    (stats / "args.yml").write_text(yaml.safe_dump(args, sort_keys=False))
    return run


def _exp(run: Path) -> tuple[str, str, str, int]:
    """(folder, algo, env id, exp id) of an experiment folder :func:`export_zoo` wrote."""
    run = Path(run)
    args = yaml.safe_load(next(run.glob("*/args.yml")).read_text())
    return str(run.parent.parent), args["algo"], args["env"], int(run.name.rsplit("_", 1)[1])


def enjoy_command(run: str | Path, n_timesteps: int = 1000) -> str:
    """``python -m rl_zoo3.enjoy ...`` that runs the exported agent in ``run`` (deterministic
    actions, no window)."""
    folder, algo, env, k = _exp(Path(run))
    return shlex.join([sys.executable, "-m", "rl_zoo3.enjoy", "--algo", algo, "--env", env,
                       "--gym-packages", "cir_gym", "-f", folder, "--exp-id", str(k),
                       "--deterministic", "--no-render", "-n", str(n_timesteps)])


def record_video_command(run: str | Path, video_folder: str | Path,
                         n_timesteps: int = 500) -> str:
    """The ``rl_zoo3.record_video`` command for the exported agent in ``run``, started as
    ``python -c "import cir_gym; ..."`` since record_video has no ``--gym-packages``."""
    folder, algo, env, k = _exp(Path(run))
    code = ("import sys, runpy, cir_gym; sys.argv[0] = 'record_video'; "
            "runpy.run_module('rl_zoo3.record_video', run_name='__main__')")
    return shlex.join([sys.executable, "-c", code, "--algo", algo, "--env", env, "-f", folder,
                       "--exp-id", str(k), "--deterministic", "-n", str(n_timesteps),
                       "-o", str(video_folder)])
