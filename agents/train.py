"""Train an SB3 agent (from scratch or residual) on a cir_gym environment, reproducibly.

    from cir_gym.agents.train import train
    run = train("cir_gym/JointTracking-v2", "ppo", residual="computed_torque",
                env_kwargs={"payload_mass": 3.0})

A run directory ``<out>/<EnvName-vN>/<name>/`` receives:

* ``config.yml``: env id and kwargs, algorithm, resolved hyperparameters, seed, observation
  layout, residual controller and scale, versions (torch, SB3, gymnasium, mujoco, cir_gym), and
  ``retrain``: the ``cir-gym train ...`` command line that trains the same run again
  (:func:`train_command`, rebuilt from the arguments however ``train`` was called, the
  hyperparameter file named even when it is the default; every shipped agent records
  one). Runs from before it record the same line as ``command``;
* ``model.zip`` + ``vecnormalize.pkl`` + ``normalization.npz``: the final model and its frozen
  observation statistics (``best/`` holds the same for the best evaluation);
* ``learning_curve.csv``: timesteps, wall time, mean evaluation return, mean primary metric,
  success rate — one row per evaluation, deterministic actions, on the episodes that
  ``cir_gym.evaluation.evaluate(..., seed=EVAL_SEED)`` runs (the same ones every time);
* ``meta.json``: steps, wall time, CPU time (this process), steps/s, whether it finished or
  was interrupted;
* ``checkpoints/`` (model + VecNormalize every ``checkpoint_freq`` steps, and on Ctrl-C) and
  ``tb/`` (TensorBoard). ``resume=True`` continues from the last checkpoint (or from the
  final model of a finished run, to a larger ``timesteps``), with the
  optimiser keys of ``config.yml`` (:data:`RESUME_KEYS`) as they are in the file then: editing
  ``learning_rate`` there (e.g. ``lin_3.0e-4``) before resuming fine-tunes a run. A linear
  schedule then runs over the steps of the resumed part only from where it would stand at the
  resumed step (SB3's progress counts all steps): from ``start · (1 − k / n)`` at step k of n
  down to 0.

:func:`ship` copies a run's files into ``agents/trained/`` for :func:`agents.load`, with its
``retrain`` line: its final model, its best evaluation, or a checkpoint chosen by a stated
rule (recorded as ``selection``, with the command that chooses it again from a retrained run).
"""

from __future__ import annotations

import ast
import csv
import json
import os
import platform
import re
import shlex
import shutil
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import yaml
from cir_gym.agents import TRAINED_DIR, env_dir_name
from cir_gym.agents.batched import make_batched_vec_env
from cir_gym.agents.hyperparameters import (
    HYPERPARAMS_DIR,
    TRAINING_KEYS,
    HyperparameterError,
    algorithm_class,
    load_hyperparams,
    observation_options,
    resolve_policy_kwargs,
    resolve_schedule,
)
from cir_gym.agents.observation import ObservationLayout, TaskObservation
from cir_gym.agents.residual import ResidualAction, check_scale
from cir_gym.agents.shaping import (
    EarlyTermination,
    LogErrorBonus,
    RewardOffset,
    TaskReplay,
    check_log_error_bonus,
)
from stable_baselines3.common.callbacks import (
    BaseCallback,
    CallbackList,
    CheckpointCallback,
    EvalCallback,
)
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import (
    DummyVecEnv,
    SubprocVecEnv,
    VecEnv,
    VecNormalize,
)

import cir_gym

__all__ = ["EnvFactory", "LearningCurveCallback", "retrain_command", "ship", "train",
           "train_command"]

EVAL_SEED = 100_000  # evaluation episodes during training: seeds EVAL_SEED, EVAL_SEED + 1, …
SHIPPED_FILES = ("model.zip", "vecnormalize.pkl", "normalization.npz", "config.yml",
                 "learning_curve.csv", "meta.json")
#: config.yml keys of the ``cir-gym train`` line that trains a run again: ``retrain``, and
#: ``command``, the same line in runs from before ``retrain`` (a shipped agent's ``command``
#: is the historical record, not always such a line)
RETRAIN_KEYS = ("retrain", "command")


class EnvFactory:
    """Picklable ``() -> env`` for (Subproc|Dummy)VecEnv: env → residual → flat obs → Monitor."""

    def __init__(self, env_id: str, env_kwargs: dict[str, Any], layout: ObservationLayout,
                 residual: str | None = None, scale: Any = None,
                 controller_kwargs: dict[str, Any] | None = None,
                 early_termination: dict[str, float] | None = None,
                 reward_offset: float = 0.0,
                 log_error: dict[str, float] | None = None,
                 task_replay: int = 1) -> None:
        self.env_id = env_id if ":" in env_id else f"cir_gym:{env_id}"  # workers must import
        self.env_kwargs = env_kwargs
        self.layout = layout
        self.residual = residual
        self.scale = scale
        self.controller_kwargs = controller_kwargs or {}
        self.early_termination = early_termination  # training envs only
        self.reward_offset = reward_offset  # training envs only
        self.log_error = log_error  # training envs only
        self.task_replay = task_replay  # training envs only

    def __call__(self) -> gym.Env:
        env = gym.make(self.env_id, **self.env_kwargs)
        if self.task_replay > 1:
            env = TaskReplay(env, self.task_replay)
        if self.early_termination:
            env = EarlyTermination(env, **self.early_termination)
        if self.reward_offset:
            env = RewardOffset(env, self.reward_offset)
        if self.log_error:
            env = LogErrorBonus(env, **self.log_error)
        if self.residual:
            env = ResidualAction(env, self.residual, self.scale, **self.controller_kwargs)
        env = TaskObservation(env, self.layout)
        return Monitor(env)


class LearningCurveCallback(EvalCallback):
    """EvalCallback (success from ``info["is_success"]``) that also records the env's primary
    metric from ``info["episode_metrics"]``, re-seeds the evaluation episodes identically each
    time, appends a row to ``learning_curve.csv`` and saves the normalisation with the best model.
    """

    def __init__(self, eval_env: VecEnv, run_dir: Path, primary: str, eval_freq: int,
                 n_eval_episodes: int, wall_offset: float = 0.0, verbose: int = 1) -> None:
        super().__init__(eval_env, n_eval_episodes=n_eval_episodes, eval_freq=eval_freq,
                         best_model_save_path=str(run_dir / "best"), deterministic=True,
                         verbose=verbose, warn=False)
        self.run_dir = run_dir
        self.primary = primary
        self.csv_path = run_dir / "learning_curve.csv"
        self.wall_start = time.perf_counter() - wall_offset
        self._metric: list[float] = []

    def _log_success_callback(self, locals_: dict[str, Any], globals_: dict[str, Any]) -> None:
        super()._log_success_callback(locals_, globals_)
        if locals_["done"]:
            value = locals_["info"].get("episode_metrics", {}).get(self.primary)
            if value is not None:
                self._metric.append(float(value))

    def _on_step(self) -> bool:
        evaluating = self.eval_freq > 0 and self.n_calls % self.eval_freq == 0
        if evaluating:
            self._metric = []
            # Episode i of every evaluation runs in eval env i with seed EVAL_SEED + i: the
            # episodes cir_gym.evaluation.evaluate(..., seed=EVAL_SEED) scores.
            self.eval_env.seed(EVAL_SEED)
        best_before = self.best_mean_reward
        keep_going = super()._on_step()
        if evaluating:
            metric = float(np.mean(self._metric)) if self._metric else float("nan")
            success = float(np.mean(self._is_success_buffer)) if self._is_success_buffer \
                else float("nan")
            self.logger.record(f"eval/mean_{self.primary}", metric)
            write_curve_row(self.csv_path, self.primary, {
                "timesteps": self.num_timesteps,
                "wall_time_s": round(time.perf_counter() - self.wall_start, 1),
                "mean_return": self.last_mean_reward,
                f"mean_{self.primary}": metric,
                "success_rate": success,
            })
            if self.best_mean_reward > best_before:
                vecnorm = self.model.get_vec_normalize_env()
                if vecnorm is not None:
                    save_normalization(vecnorm, self.run_dir / "best")
        return keep_going


def write_curve_row(path: Path, primary: str, row: dict[str, Any]) -> None:
    fields = ["timesteps", "wall_time_s", "mean_return", f"mean_{primary}", "success_rate"]
    new = not path.exists()
    with path.open("a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        if new:
            w.writeheader()
        w.writerow(row)


def save_normalization(vecnorm: VecNormalize | None, directory: Path) -> None:
    """``vecnormalize.pkl`` (SB3) and ``normalization.npz`` (plain arrays, loaded safely)."""
    directory.mkdir(parents=True, exist_ok=True)
    if vecnorm is not None:
        vecnorm.save(str(directory / "vecnormalize.pkl"))
    write_normalization(vecnorm, directory)


def write_normalization(vecnorm: VecNormalize | None, directory: Path) -> None:
    """``normalization.npz``: VecNormalize's observation statistics as plain arrays (mean and
    variance, shape (n_obs,); clip and epsilon), what :func:`agents.load` reads without
    unpickling; ``norm_obs`` False (empty arrays) for a run without normalisation."""
    if vecnorm is None:
        np.savez(directory / "normalization.npz", norm_obs=False, obs_mean=np.zeros(0),
                 obs_var=np.zeros(0), clip_obs=np.inf, epsilon=0.0)
        return
    np.savez(directory / "normalization.npz", norm_obs=bool(vecnorm.norm_obs),
             obs_mean=vecnorm.obs_rms.mean, obs_var=vecnorm.obs_rms.var,
             clip_obs=float(vecnorm.clip_obs), epsilon=float(vecnorm.epsilon))


def _plain(obj: Any) -> Any:
    """Make ``obj`` safe for yaml.safe_dump (tuples/arrays → lists, numpy scalars → Python)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def versions() -> dict[str, str]:
    import mujoco
    import stable_baselines3

    found = {"cir_gym": cir_gym.__version__, "stable_baselines3": stable_baselines3.__version__,
             "torch": torch.__version__, "gymnasium": gym.__version__,
             "mujoco": mujoco.__version__, "numpy": np.__version__,
             "python": platform.python_version()}
    return {k: str(v) for k, v in found.items()}


def zero_action_layer(model: Any) -> None:
    """Zero the actor's last linear layer so the action mean starts at exactly 0."""
    policy = model.policy
    if hasattr(policy, "action_net"):  # PPO / A2C
        layers = [policy.action_net]
    else:  # SAC (actor.mu Linear), TD3 (actor.mu Sequential ending in Linear, Tanh)
        mu = policy.actor.mu
        layers = [mu] if isinstance(mu, torch.nn.Linear) else \
            [m for m in mu if isinstance(m, torch.nn.Linear)][-1:]
    with torch.no_grad():
        for layer in layers:
            layer.weight.zero_()
            layer.bias.zero_()
    if getattr(policy, "actor_target", None) is not None:
        policy.actor_target.load_state_dict(policy.actor.state_dict())


def _last_checkpoint(run_dir: Path) -> tuple[Path, Path | None] | None:
    """(model, VecNormalize file or None) to resume ``run_dir`` from: its checkpoint of the
    most steps (``checkpoints/model_<k>_steps.zip``), or its final ``model.zip`` when the run
    finished past every checkpoint (``meta.json``'s ``timesteps``; a finished run lengthened
    with ``--timesteps``). None when there is neither."""
    ckpts = []
    for f in (run_dir / "checkpoints").glob("model_*_steps.zip"):
        m = re.fullmatch(r"model_(\d+)_steps\.zip", f.name)
        if m:
            vn = run_dir / "checkpoints" / f"model_vecnormalize_{m.group(1)}_steps.pkl"
            ckpts.append((int(m.group(1)), f, vn))
    meta_path = run_dir / "meta.json"
    if (run_dir / "model.zip").is_file() and meta_path.is_file():
        meta = json.loads(meta_path.read_text())
        if meta.get("finished"):
            ckpts.append((int(meta["timesteps"]), run_dir / "model.zip",
                          run_dir / "vecnormalize.pkl"))
    if not ckpts:
        return None
    _, model, vn = max(ckpts, key=lambda c: c[0])
    return model, (vn if vn.exists() else None)


def replay_buffer_file(run_dir: Path, steps: int) -> Path:
    """The replay buffer an off-policy run saved with its model at ``steps`` (SB3's name)."""
    return run_dir / "checkpoints" / f"model_replay_buffer_{steps}_steps.pkl"


def save_replay_buffer(model: Any, run_dir: Path) -> None:
    """Save an off-policy model's replay buffer beside its checkpoint of the same steps and
    delete the earlier ones (a buffer of 10⁶ transitions is hundreds of MB: only the latest is
    kept, the one a resumed run continues with; SB3's ``CheckpointCallback(save_replay_buffer=
    True)`` would keep every one). Written to a temporary name and renamed, so a
    run killed while writing keeps the previous buffer."""
    path = replay_buffer_file(run_dir, int(model.num_timesteps))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp.pkl")
    model.save_replay_buffer(str(tmp))
    tmp.replace(path)
    for old in path.parent.glob("model_replay_buffer_*_steps.pkl"):
        if old != path:
            old.unlink()


class ReplayBufferCheckpoint(BaseCallback):
    """Every ``save_freq`` calls (the model checkpoints' frequency), :func:`save_replay_buffer`:
    an off-policy run resumes with the transitions it had gathered, not an empty buffer. SB3
    calls the callbacks before it stores a step's transitions, so a buffer saved here lacks the
    ``n_envs`` transitions of its checkpoint's last vector step (harmless for uniform replay)."""

    def __init__(self, save_freq: int, run_dir: Path) -> None:
        super().__init__()
        self.save_freq, self.run_dir = save_freq, run_dir

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            save_replay_buffer(self.model, self.run_dir)
        return True


#: optimiser keys that a resumed run takes from its (possibly edited) config.yml
RESUME_KEYS = ("learning_rate", "clip_range", "ent_coef", "n_epochs", "batch_size")


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _term_raises_interrupt() -> Any:
    """Make SIGTERM act like Ctrl-C (checkpoint, then exit); return the previous handler."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _raise_interrupt)


def _make_vec_env(factory: EnvFactory, n_envs: int, kind: str, seed: int) -> VecEnv:
    fns = [factory] * n_envs
    venv: VecEnv = SubprocVecEnv(fns) if kind == "subproc" and n_envs > 1 else DummyVecEnv(fns)
    venv.seed(seed)
    return venv


def _normalize_kwargs(hp: dict[str, Any], gamma: float) -> dict[str, Any] | None:
    norm = hp.get("normalize", False)
    if norm is False:
        return None
    kw = {"norm_obs": True, "norm_reward": False, "gamma": gamma}
    if isinstance(norm, dict):
        kw.update(norm)
    return kw


def _set_value(value: Any) -> str:
    """A ``--set key=value`` value that the command line reads back as ``value``: the text of
    a string that does not read as a Python literal, else the literal (``3.0``, ``[1, 2]``,
    ``'3'``)."""
    value = _plain(value)
    if isinstance(value, str):
        try:
            ast.literal_eval(value)
        except (ValueError, SyntaxError):
            return value
    return repr(value)


def _path_arg(path: str | Path) -> str:
    """``path`` relative to the working directory when it lies below it (a repository's
    ``agents/hyperparams/...``), else absolute."""
    p = Path(path).resolve()
    try:
        return p.relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return str(p)


def train_command(
    env_id: str,
    algo: str,
    *,
    timesteps: int,
    seed: int,
    name: str,
    out: str | Path,
    residual: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    n_envs: int | None = None,
    residual_scale: float | list[float] | None = None,
    residual_gains: dict[str, Any] | None = None,
    hyperparams_path: str | Path | None = None,
) -> str:
    """The ``cir-gym train`` command line (shell-quoted) that runs :func:`train` with these
    arguments: what ``config.yml`` records as ``retrain``. Environment arguments and the
    residual controller's gains are both ``--set key=value`` (the command line tells them
    apart by name); the hyperparameter file and ``--out`` are relative to the working
    directory when below it."""
    argv = ["cir-gym", "train", "--env", env_id, "--algo", algo, "--timesteps", str(timesteps),
            "--seed", str(seed)]
    if residual:
        argv += ["--residual", residual]
    if residual_scale is not None:
        argv += ["--residual-scale", _set_value(residual_scale)]
    if n_envs is not None:
        argv += ["--n-envs", str(int(n_envs))]
    if hyperparams_path is not None:
        argv += ["--hyperparams", _path_arg(hyperparams_path)]
    argv += ["--out", _path_arg(out), "--name", name]
    for key, value in {**(env_kwargs or {}), **(residual_gains or {})}.items():
        argv += ["--set", f"{key}={_set_value(value)}"]
    return shlex.join(argv)


def _with_timesteps(command: str, timesteps: int) -> str:
    """``command`` (a :func:`train_command`) with ``--timesteps`` set to ``timesteps``."""
    argv = shlex.split(command)
    if "--timesteps" not in argv:
        return command  # a command recorded otherwise: left as it is
    argv[argv.index("--timesteps") + 1] = str(int(timesteps))
    return shlex.join(argv)


def train(
    env_id: str,
    algo: str = "ppo",
    *,
    timesteps: int | None = None,
    seed: int = 0,
    residual: str | None = None,
    resume: bool = False,
    out: str | Path = "runs",
    name: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    n_envs: int | None = None,
    residual_scale: float | list[float] | None = None,
    residual_gains: dict[str, Any] | None = None,
    hyperparams_path: str | Path | None = None,
    progress_bar: bool = True,
    verbose: int = 1,
) -> Path:
    """Train ``algo`` on ``env_id`` and return the run directory (see the module docstring).

    Args:
        env_id: a registered cir_gym id (``cir_gym/JointTracking-v2``).
        algo: "ppo", "sac" or "td3"; hyperparameters from ``agents/hyperparams/<algo>.yml``.
        timesteps: total environment steps (default: the entry's ``n_timesteps``).
        seed: seed of the model and of the training environments (env i gets seed + i).
        residual: a controller name: train a residual on it (:mod:`agents.residual`).
        resume: continue the run in ``<out>/<Env>/<name>`` from its last checkpoint, with its
            saved configuration, up to ``timesteps`` in total.
        out: root of the run directories.
        name: run name (default ``<algo>`` or ``residual_<algo>_<controller>``).
        env_kwargs: environment arguments (e.g. ``{"payload_mass": 3.0}``).
        n_envs: parallel environments (default: the entry's ``n_envs``).
        residual_scale: override the entry's ``residual.scale``.
        residual_gains: the residual controller's gains (``baselines.make`` keywords, e.g. the
            tuned gains of ``scripts/tune_gains.py``), saved as ``residual.controller_kwargs``
            (default: the course's gains).
        hyperparams_path: another hyperparameter YAML file.
        progress_bar: SB3's progress bar (tqdm + rich).

    Raises:
        ValueError: unknown environment, bad hyperparameters, an existing run without
            ``resume``, ``resume`` without a checkpoint.
        KeyboardInterrupt: after saving a checkpoint, when interrupted (Ctrl-C or SIGTERM).
    """
    torch.set_num_threads(1)
    key = env_id.split(":")[-1]
    if key not in cir_gym.ENVIRONMENTS:
        raise ValueError(f"unknown environment {env_id!r}; valid: {sorted(cir_gym.ENVIRONMENTS)}")
    name = name or (f"residual_{algo}_{residual}" if residual else algo)
    run_dir = Path(out) / env_dir_name(key) / name
    config_path = run_dir / "config.yml"

    if resume:
        if not config_path.exists():
            raise ValueError(f"nothing to resume: {config_path} does not exist")
        config = yaml.safe_load(config_path.read_text())
        if config["algo"] != algo or config["env_id"] != key:
            raise ValueError(f"{config_path} is a {config['algo']} run on {config['env_id']}, "
                             f"not {algo} on {key}")
        if timesteps is not None and int(timesteps) != config["n_timesteps"]:
            config["n_timesteps"] = int(timesteps)
            for k in RETRAIN_KEYS:  # the command that trains this run to its new length
                if config.get(k):
                    config[k] = _with_timesteps(config[k], int(timesteps))
            config_path.write_text(yaml.safe_dump(config, sort_keys=False))
    else:
        if config_path.exists():
            raise ValueError(f"{run_dir} already holds a run; pass resume=True (--resume) or "
                             f"another name (--name)")
        hp_file = Path(hyperparams_path or HYPERPARAMS_DIR / f"{algo}.yml")
        hp = load_hyperparams(algo, key, residual=residual is not None, path=hp_file)
        if residual_scale is not None:
            if residual is None:
                raise ValueError("residual_scale needs residual=<controller>")
            hp["residual_scale"] = residual_scale
        if n_envs is not None:
            hp["n_envs"] = int(n_envs)
        probe = gym.make(key, **(env_kwargs or {}))
        opts = observation_options(hp)
        try:
            layout = ObservationLayout.from_space(probe.observation_space, **opts)
            layout.bind(probe)
        except ValueError as exc:
            probe.close()
            raise HyperparameterError(f"observation of {key}: {exc}") from exc
        res_cfg = None
        if residual is not None:
            from cir_gym import baselines

            if residual not in baselines.available(key):
                probe.close()
                raise ValueError(f"controller {residual!r} does not apply to {key}; "
                                 f"available: {baselines.available(key)}")
            scale = check_scale(hp.pop("residual_scale"), probe.action_space)
            res_cfg = {"controller": residual, "scale": scale.tolist()}
            if residual_gains:
                try:  # a bad gain fails here, not in the training envs
                    baselines.make(residual, key, env=probe, **residual_gains)
                except ValueError as exc:
                    probe.close()
                    raise ValueError(f"residual gains {residual_gains}: {exc}") from exc
                res_cfg["controller_kwargs"] = {k: _plain(v) for k, v in residual_gains.items()}
        elif residual_gains:
            probe.close()
            raise ValueError("residual_gains needs residual=<controller>")
        probe.close()
        n_timesteps = int(timesteps if timesteps is not None else hp["n_timesteps"])
        config = {
            "env_id": key,
            "env_kwargs": dict(env_kwargs or {}),
            "algo": algo,
            "seed": int(seed),
            "n_timesteps": n_timesteps,
            "hyperparams": hp,
            "residual": res_cfg,
            "observation": layout.to_dict(),
            "primary_metric": cir_gym.ENVIRONMENTS[key][0].primary_metric,
            "versions": versions(),
            "retrain": train_command(
                key, algo, timesteps=n_timesteps, seed=int(seed), name=name, out=out,
                residual=residual, env_kwargs=env_kwargs, n_envs=n_envs,
                residual_scale=residual_scale, residual_gains=residual_gains,
                hyperparams_path=hp_file),
        }
        text = yaml.safe_dump(_plain(config), sort_keys=False)
        run_dir.mkdir(parents=True, exist_ok=True)
        try:  # created exclusively: of two runs started at once into one directory (the
            # check above passes for both), the second stops here instead of sharing it
            with config_path.open("x") as f:
                f.write(text)
        except FileExistsError:
            raise ValueError(f"{run_dir} already holds a run (started while this one was "
                             f"being set up); pass another name (--name) or --out") from None
        config = yaml.safe_load(config_path.read_text())  # train on exactly what was saved

    return _run(run_dir, config, resume=resume, progress_bar=progress_bar, verbose=verbose)


def _run(run_dir: Path, config: dict[str, Any], *, resume: bool, progress_bar: bool,
         verbose: int) -> Path:
    hp = dict(config["hyperparams"])
    algo_cls = algorithm_class(config["algo"])
    layout = ObservationLayout.from_dict(config["observation"])
    res = config.get("residual") or {}
    gamma = float(hp.get("gamma", 0.99))
    early = hp.get("early_termination")
    if early:  # default penalty: staying lost forever at r = -1 per step
        early = {"max_error": float(early["max_error"]),
                 "penalty": float(early.get("penalty", -1.0 / (1.0 - gamma))),
                 "orientation_scale": float(early.get("orientation_scale", 0.0))}
    log_error = (check_log_error_bonus(hp["log_error_bonus"])
                 if hp.get("log_error_bonus") is not None else None)
    factory = EnvFactory(config["env_id"], config.get("env_kwargs") or {}, layout,
                         res.get("controller"), res.get("scale"), res.get("controller_kwargs"))
    train_factory = EnvFactory(factory.env_id, factory.env_kwargs, layout, factory.residual,
                               factory.scale, factory.controller_kwargs, early or None,
                               float(hp.get("reward_offset", 0.0)), log_error,
                               int(hp.get("task_replay", 1)))
    n_envs = int(hp.get("n_envs", 1))
    seed = int(config["seed"])
    total = int(config["n_timesteps"])
    primary = config["primary_metric"]

    algo_kwargs = {k: v for k, v in hp.items() if k not in TRAINING_KEYS}
    for k in ("learning_rate", "clip_range", "clip_range_vf"):
        if k in algo_kwargs and algo_kwargs[k] is not None:
            algo_kwargs[k] = resolve_schedule(algo_kwargs[k], where=k)
    noise_type, noise_std = algo_kwargs.pop("noise_type", None), algo_kwargs.pop("noise_std", 0.1)

    kind = hp.get("vec_env", "dummy")
    if kind == "batched":  # one mujoco.batch for all training copies (agents/batched.py)
        if early or int(hp.get("task_replay", 1)) > 1:
            raise HyperparameterError("vec_env 'batched' trains without early_termination or "
                                      "task_replay; use vec_env 'dummy'")
        venv = make_batched_vec_env(config["env_id"], config.get("env_kwargs") or {}, layout,
                                    n_envs, seed, float(hp.get("reward_offset", 0.0)),
                                    log_error, factory.residual, factory.scale,
                                    factory.controller_kwargs)
    else:
        venv = _make_vec_env(train_factory, n_envs, kind, seed)
    n_eval = int(hp.get("n_eval_episodes", 5))
    eval_env: VecEnv = DummyVecEnv([factory] * n_eval)  # one episode each: seeds EVAL_SEED + i
    norm_kwargs = _normalize_kwargs(hp, gamma)
    meta_path = run_dir / "meta.json"
    meta = json.loads(meta_path.read_text()) if (resume and meta_path.exists()) else {}
    wall_before = float(meta.get("wall_time_s", 0.0))
    cpu_before = float(meta.get("cpu_time_s", 0.0))

    if resume:
        last = _last_checkpoint(run_dir)
        if last is None:
            raise ValueError(f"no checkpoint to resume from in {run_dir / 'checkpoints'} "
                             "and no finished model.zip")
        model_file, vn_file = last
        if norm_kwargs is not None:
            if vn_file is None:
                raise ValueError(f"checkpoint {model_file} has no VecNormalize statistics")
            venv = VecNormalize.load(str(vn_file), venv)  # our own checkpoint: trusted pickle
            venv.training = True
        custom = {k: algo_kwargs[k] for k in RESUME_KEYS if k in algo_kwargs}
        model = algo_cls.load(str(model_file), env=venv, device="cpu",
                              tensorboard_log=str(run_dir / "tb"), custom_objects=custom)
        print(f"resuming {run_dir} from {model_file.name} ({model.num_timesteps} steps)",
              file=sys.stderr)
        if isinstance(model, OffPolicyAlgorithm):
            buffer = replay_buffer_file(run_dir, model.num_timesteps)
            if buffer.is_file():
                model.load_replay_buffer(str(buffer))
            else:
                print(f"no replay buffer saved at {model.num_timesteps} steps: the run "
                      f"continues with an empty one", file=sys.stderr)
    else:
        if norm_kwargs is not None:
            venv = VecNormalize(venv, **norm_kwargs)
        if noise_type is not None:
            if noise_type != "normal":
                raise HyperparameterError(f"noise_type must be 'normal', got {noise_type!r}")
            m = venv.action_space.shape[0]
            algo_kwargs["action_noise"] = NormalActionNoise(np.zeros(m), noise_std * np.ones(m))
        policy_kwargs = resolve_policy_kwargs(hp.get("policy_kwargs") or {})
        model = algo_cls(hp.get("policy", "MlpPolicy"), venv, seed=seed, device="cpu",
                         verbose=verbose, tensorboard_log=str(run_dir / "tb"),
                         policy_kwargs=policy_kwargs, **algo_kwargs)
        if hp.get("zero_init_action", False):
            zero_action_layer(model)
    if norm_kwargs is not None:
        eval_env = VecNormalize(eval_env, training=False, norm_obs=True, norm_reward=False)

    eval_freq = max(1, int(hp.get("eval_freq", 50_000)) // n_envs)
    ckpt_freq = max(1, int(hp.get("checkpoint_freq", 200_000)) // n_envs)
    curve = LearningCurveCallback(eval_env, run_dir, primary, eval_freq, n_eval,
                                  wall_offset=wall_before, verbose=verbose)
    if resume and curve.csv_path.exists():  # keep the best model of the earlier sessions
        with curve.csv_path.open() as f:
            returns = [float(r["mean_return"]) for r in csv.DictReader(f)]
        curve.best_mean_reward = max(returns, default=-np.inf)
    ckpt = CheckpointCallback(ckpt_freq, str(run_dir / "checkpoints"), name_prefix="model",
                              save_vecnormalize=True, verbose=0)
    off_policy = isinstance(model, OffPolicyAlgorithm)
    callbacks = [ckpt, curve] + ([ReplayBufferCheckpoint(ckpt_freq, run_dir)] if off_policy
                                 else [])
    remaining = max(0, total - model.num_timesteps)
    steps_before = model.num_timesteps
    t0, cpu0 = time.perf_counter(), time.process_time()
    interrupted = False
    previous_term = _term_raises_interrupt()
    try:
        model.learn(remaining, callback=CallbackList(callbacks), tb_log_name="run",
                    reset_num_timesteps=not resume, progress_bar=progress_bar)
    except KeyboardInterrupt:
        interrupted = True
        ckpt_dir = run_dir / "checkpoints"
        stem = ckpt_dir / f"model_{model.num_timesteps}_steps"
        ckpt_dir.mkdir(parents=True, exist_ok=True)
        model.save(str(stem) + ".zip")
        vecnorm = model.get_vec_normalize_env()
        if vecnorm is not None:
            vecnorm.save(str(ckpt_dir / f"model_vecnormalize_{model.num_timesteps}_steps.pkl"))
        if off_policy:
            save_replay_buffer(model, run_dir)
        print(f"\ninterrupted: checkpoint {stem}.zip saved; continue with resume=True "
              f"(cir-gym train ... --resume)", file=sys.stderr)
    finally:
        if previous_term is not None:
            signal.signal(signal.SIGTERM, previous_term)
        wall = time.perf_counter() - t0
        meta = {
            "timesteps": int(model.num_timesteps),
            "wall_time_s": round(wall_before + wall, 1),
            # this process's CPU time over every session (the batched physics' threads
            # included; SubprocVecEnv workers are other processes, not counted)
            "cpu_time_s": round(cpu_before + time.process_time() - cpu0, 1),
            "steps_per_s": round((model.num_timesteps - steps_before) / max(wall, 1e-9), 1),
            "finished": not interrupted and model.num_timesteps >= total,
            "interrupted": interrupted,
            "n_envs": n_envs,
            "cpu_count": os.cpu_count(),
            "sessions": int(meta.get("sessions", 0)) + 1,
        }
        meta_path.write_text(json.dumps(meta, indent=2) + "\n")
        if not interrupted:
            model.save(str(run_dir / "model.zip"))
            save_normalization(model.get_vec_normalize_env(), run_dir)
            # a finished run lengthened with --timesteps resumes from model.zip and this buffer,
            # complete (a checkpoint's lacks its last vector step); a crash keeps the last
            # checkpoint's, which its resume starts from
            if off_policy and meta["finished"]:
                save_replay_buffer(model, run_dir)
        for e in (venv, eval_env):
            try:
                e.close()
            except (EOFError, BrokenPipeError, ConnectionError):  # workers killed by Ctrl-C
                pass
    if interrupted:
        raise KeyboardInterrupt
    return run_dir


def retrain_command(config: dict[str, Any]) -> str | None:
    """The ``cir-gym train`` line a run's ``config.yml`` records to train it again: its
    ``retrain``, or in a run from before that key its ``command`` when that is such a line;
    None when it records none."""
    for key in RETRAIN_KEYS:
        command = config.get(key)
        if isinstance(command, str) and shlex.split(command)[:2] == ["cir-gym", "train"]:
            return command
    return None


#: models :func:`ship` copies: the final model, SB3's best evaluation (``best/``), or a saved
#: checkpoint (``checkpoints/model_<N>_steps.zip``) chosen by a stated rule
SHIPPABLE = ("final", "best", "checkpoint")


def _checkpoint_files(run_dir: Path, steps: int) -> tuple[Path, Path]:
    """(model, VecNormalize statistics) of checkpoint ``steps`` of ``run_dir``; ValueError
    naming the saved step counts when the model is not there."""
    folder = run_dir / "checkpoints"
    model = folder / f"model_{steps}_steps.zip"
    if not model.is_file():
        saved = sorted(int(m.group(1)) for f in folder.glob("model_*_steps.zip")
                       if (m := re.fullmatch(r"model_(\d+)_steps\.zip", f.name)))
        raise ValueError(f"steps={steps}: {run_dir} has no checkpoint {model.name}; "
                         f"saved: {saved}")
    return model, folder / f"model_vecnormalize_{steps}_steps.pkl"


def _ship_checkpoint(run_dir: Path, config: dict[str, Any], steps: int, target: Path) -> None:
    """Checkpoint ``steps`` into ``target``: its model as ``model.zip``, its VecNormalize
    statistics as ``vecnormalize.pkl`` and, through :func:`write_normalization`,
    ``normalization.npz`` (for a run without normalisation, ``norm_obs`` False)."""
    import pickle

    model, stats = _checkpoint_files(run_dir, steps)
    normalizes = config["hyperparams"].get("normalize", False) is not False
    if normalizes and not stats.is_file():
        raise ValueError(f"steps={steps}: {run_dir} normalises observations but has no "
                         f"{stats.name} for its checkpoint")
    shutil.copy2(model, target / "model.zip")
    vecnorm = None
    if normalizes:
        shutil.copy2(stats, target / "vecnormalize.pkl")
        with stats.open("rb") as f:
            vecnorm = pickle.load(f)  # this run's own checkpoint (as resume reads it): trusted
    write_normalization(vecnorm, target)


def _check_ship_arguments(which: str, steps: int | None, selection: dict[str, Any] | None
                          ) -> None:
    if which not in SHIPPABLE:
        raise ValueError(f"which must be one of {list(SHIPPABLE)}, got {which!r}")
    if which == "checkpoint":
        if not isinstance(steps, int) or isinstance(steps, bool) or steps <= 0:
            raise ValueError(f"which='checkpoint' needs steps=<N>, the step count of "
                             f"checkpoints/model_<N>_steps.zip (a positive int), got {steps!r}")
        if not isinstance(selection, dict) or not {"command", "rule"} <= set(selection):
            raise ValueError("which='checkpoint' needs selection={'command': <the line that "
                             "chooses it again>, 'rule': <how it was chosen>, ...}: a "
                             f"checkpoint ships with why it was chosen, got {selection!r}")
    elif steps is not None:
        raise ValueError(f"steps is for which='checkpoint' only, got steps={steps!r} with "
                         f"which={which!r}")


def ship(run_dir: str | Path, *, which: str = "final", dest: str | Path | None = None,
         steps: int | None = None, selection: dict[str, Any] | None = None) -> Path:
    """Copy a run's model, statistics, config, curve and meta into
    ``agents/trained/<EnvName-vN>/<name>/`` (or ``dest``); return that directory.

    A run named ``<name>/seed_<k>`` (``train(..., seed=k, name="ppo/seed_k")``) goes to
    ``agents/trained/<EnvName-vN>/<name>/seed_<k>/``: one seed of a multi-seed agent. The
    shipped ``config.yml`` records the run's ``retrain`` line (:func:`retrain_command`; an
    older run's ``command`` is recorded as ``retrain``).

    Args:
        run_dir: a run directory of :func:`train`.
        which: "final" (``model.zip``), "best" (``best/best_model.zip``) or "checkpoint"
            (``checkpoints/model_<steps>_steps.zip`` with the VecNormalize statistics saved
            beside it, written as ``vecnormalize.pkl`` and ``normalization.npz``).
        dest: the agent directory to write (default: under ``agents/trained/``).
        steps: the checkpoint's step count (``which="checkpoint"`` only).
        selection: how the model was chosen, recorded as ``config.yml``'s ``selection``
            (with ``model`` and, for a checkpoint, ``steps``): at least ``command``, the line
            that chooses it again from the retrained run's saved models, and ``rule``; e.g.
            the validation seeds and the chosen model's scores. Needed for a checkpoint.

    The shipped ``meta.json`` is the run's (its ``timesteps`` are the whole run's, which the
    ``retrain`` line trains again) with ``shipped_model`` and, for a checkpoint,
    ``shipped_steps``.

    Raises:
        ValueError: ``which`` is not one of :data:`SHIPPABLE`; a checkpoint without
            ``steps`` or ``selection``, or one the run did not save; the run records no
            ``cir-gym train`` line that trains it again (no agent ships without one).
    """
    run_dir = Path(run_dir)
    _check_ship_arguments(which, steps, selection)
    config = yaml.safe_load((run_dir / "config.yml").read_text())
    retrain = retrain_command(config)
    if retrain is None:
        raise ValueError(f"{run_dir / 'config.yml'} records no 'cir-gym train' line that "
                         f"trains the run again ('retrain'); train it with agents.train.train "
                         f"or cir-gym train to ship it")
    name = run_dir.name
    if re.fullmatch(r"seed_\d+", name):
        name = f"{run_dir.parent.name}/{name}"
    target = Path(dest) if dest is not None else \
        TRAINED_DIR / env_dir_name(config["env_id"]) / name
    if which == "checkpoint":
        _checkpoint_files(run_dir, steps)  # refused before anything is written
    target.mkdir(parents=True, exist_ok=True)
    if which == "checkpoint":
        _ship_checkpoint(run_dir, config, steps, target)
    else:
        src = run_dir if which == "final" else run_dir / "best"
        model = src / ("model.zip" if which == "final" else "best_model.zip")
        shutil.copy2(model, target / "model.zip")
        for f in ("vecnormalize.pkl", "normalization.npz"):
            if (src / f).exists():
                shutil.copy2(src / f, target / f)
    for f in ("config.yml", "learning_curve.csv", "meta.json"):
        shutil.copy2(run_dir / f, target / f)
    if config.get("retrain") != retrain or selection is not None:
        config["retrain"] = retrain  # a run from before 'retrain': its 'command' is it
        if selection is not None:
            shipped = {"model": which, **({"steps": steps} if which == "checkpoint" else {})}
            config["selection"] = _plain({**selection, **shipped})
        (target / "config.yml").write_text(yaml.safe_dump(config, sort_keys=False))
    meta = json.loads((target / "meta.json").read_text())
    meta["shipped_model"] = which
    if which == "checkpoint":
        meta["shipped_steps"] = steps
    (target / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")
    return target
