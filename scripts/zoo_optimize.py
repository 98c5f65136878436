"""Read rl-zoo3's Optuna study (scripts/zoo_optimize.sh) and score rl-zoo3 runs on the leaderboard.

    python scripts/zoo_optimize.py trials results/tuning/zoo_optuna/jointtracking_100hz_ppo.db \
        [--study jointtracking_100hz_ppo] [--csv FILE]
    python scripts/zoo_optimize.py evaluate LOG_FOLDER/ppo/cir_gym-JointTracking-v2_1 [...] \
        [--episodes 10] [--seed 1000] [--controller pd_gravity]

``trials`` prints every trial of the study (state, value = rl-zoo3's objective: the mean return
of the last evaluation, the pruner's evaluations, the sampled hyperparameters as rl-zoo3 uses
them) as a markdown table, through Optuna's API; ``--csv`` also writes Optuna's
``trials_dataframe``.

``evaluate`` loads a run that ``python -m rl_zoo3.train`` saved (``<env>.zip`` with SB3's
``PPO.load``, ``<env>/vecnormalize.pkl`` with ``VecNormalize.load``: both unpickle, so trusted
files only), rebuilds the observation wrapper its ``config.yml`` names (``env_wrapper``, through
rl-zoo3's ``get_wrapper_class``) on an env with the run's ``env_kwargs`` (``args.yml``), and
scores it with the project's evaluator (``cir_gym.evaluation.evaluate``, deterministic
actions) on the episodes ``seed … seed + episodes − 1`` with the run's env kwargs, beside
``--controller`` at its default gains at the same control rate.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np

ENV_ID = "cir_gym/JointTracking-v2"
#: the hyperparameters rl-zoo3's PPO sampler sets, in the order of the table
SAMPLED = ("n_steps", "batch_size", "gamma", "gae_lambda", "learning_rate", "ent_coef",
           "clip_range", "n_epochs", "max_grad_norm", "net_arch", "activation_fn")


def trial_hyperparameters(params: dict[str, Any]) -> dict[str, Any]:
    """The hyperparameters rl-zoo3 trains with, from a trial's sampled ``params``
    (``rl_zoo3.hyperparams_opt.sample_ppo_params``: powers of two and 1 − gamma)."""
    out = dict(params)
    for name in ("n_steps", "batch_size"):
        if f"{name}_pow" in out:
            out[name] = 2 ** out.pop(f"{name}_pow")
    for name in ("gamma", "gae_lambda"):
        if f"one_minus_{name}" in out:
            out[name] = 1.0 - out.pop(f"one_minus_{name}")
    return out


def _fmt(x: Any) -> str:
    if isinstance(x, float):
        return f"{x:.4g}" if math.isfinite(x) else str(x)
    return "" if x is None else str(x)


def trials_table(study: Any) -> str:
    """Markdown table of every trial of an Optuna ``study`` (any state)."""
    head = ["trial", "state", "value", "evaluations (mean return)", "minutes", *SAMPLED]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for t in study.trials:
        hp = trial_hyperparameters(t.params)
        minutes = (t.duration.total_seconds() / 60.0) if t.duration is not None else None
        inter = ", ".join(f"{t.intermediate_values[k]:.4g}" for k in sorted(t.intermediate_values))
        cells = [str(t.number), t.state.name, _fmt(t.value), inter, _fmt(minutes),
                 *(_fmt(hp.get(k)) for k in SAMPLED)]
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)


def _read_run_yaml(file: Path) -> Any:
    """A yml file rl-zoo3 saved (config.yml holds a python/object/apply OrderedDict tag)."""
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    Loader.add_constructor(
        "tag:yaml.org,2002:python/object/apply:collections.OrderedDict",
        lambda loader, node: dict(map(tuple, loader.construct_sequence(node.value[0], True))))
    # a trial's policy_kwargs (--trial-id) holds classes (python/name:torch.nn...): their names
    Loader.add_multi_constructor("tag:yaml.org,2002:python/name:",
                                 lambda loader, suffix, node: suffix)
    data = yaml.load(file.read_text(), Loader=Loader)
    return dict(data) if isinstance(data, list) else data


class ZooAgent:
    """An rl-zoo3 run as a policy with SB3's ``predict`` on the env's raw Dict observation:
    the run's observation wrapper, its frozen VecNormalize statistics, the network."""

    def __init__(self, model: Any, transform: Any, vecnormalize: Any,
                 env_kwargs: dict[str, Any], name: str) -> None:
        self.model = model
        self.transform = transform
        self.vecnormalize = vecnormalize
        self.name = name
        from cir_gym.agents.policy import INTERFACE_KEYS, interface_defaults

        # as a shipped agent's: the recorded interface, else the env's default (500 Hz)
        self.interface_kwargs = {**interface_defaults(ENV_ID),
                                 **{k: env_kwargs[k] for k in INTERFACE_KEYS if k in env_kwargs}}

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        x = np.asarray(self.transform(observation), dtype=np.float32)
        if self.vecnormalize is not None:
            x = self.vecnormalize.normalize_obs(x)
        action, _ = self.model.predict(x, deterministic=deterministic)
        return np.asarray(action, dtype=np.float32), None


def load_zoo_run(run: Path, env_id: str = ENV_ID) -> tuple[ZooAgent, dict[str, Any], Any]:
    """(agent, env_kwargs, the outermost observation wrapper's class or None) of an rl-zoo3
    run directory."""
    import gymnasium as gym
    from rl_zoo3.utils import get_wrapper_class
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import cir_gym  # noqa: F401  (registers the env ids)

    run = Path(run)
    name = env_id.replace("/", "-")
    sub = run / name
    config = _read_run_yaml(sub / "config.yml")
    env_kwargs = dict(_read_run_yaml(sub / "args.yml").get("env_kwargs") or {})
    wrap = get_wrapper_class({"env_wrapper": config.get("env_wrapper")}) \
        if config.get("env_wrapper") else None
    env = gym.make(env_id, **env_kwargs)
    if wrap is not None:
        env = wrap(env)
    wrapper = type(env) if isinstance(env, gym.ObservationWrapper) else None
    transform = env.observation if wrapper is not None else (lambda obs: obs)
    vecnormalize = None
    if (sub / "vecnormalize.pkl").is_file():
        vecnormalize = VecNormalize.load(str(sub / "vecnormalize.pkl"),
                                         DummyVecEnv([lambda: env]))
        vecnormalize.training = False
        vecnormalize.norm_reward = False
    model = PPO.load(str(run / f"{name}.zip"), device="cpu")
    return ZooAgent(model, transform, vecnormalize, env_kwargs, run.name), env_kwargs, wrapper


def _cmd_trials(args: argparse.Namespace) -> int:
    import optuna

    storage = f"sqlite:///{args.db}"
    name = args.study or optuna.get_all_study_names(storage)[0]
    study = optuna.load_study(study_name=name, storage=storage)
    print(f"study {name!r}: {len(study.trials)} trials")
    for k, v in sorted(study.user_attrs.items()):
        print(f"  {k}: {v}")
    print(trials_table(study))
    done = [t for t in study.trials if t.value is not None and t.state.name == "COMPLETE"]
    if done:
        best = study.best_trial
        print(f"best: trial {best.number}, value {best.value:.4g}, "
              f"{trial_hyperparameters(best.params)}")
    if args.csv:
        study.trials_dataframe().to_csv(args.csv, index=False)
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from cir_gym import baselines
    from cir_gym.evaluation import evaluate

    print("| policy | observation wrapper | RMS error (rad), mean | median | success | "
          "mean return |")
    print("|---|---|---:|---:|---:|---:|")
    env_kwargs: dict[str, Any] = {}
    for run in args.runs:
        agent, env_kwargs, wrapper = load_zoo_run(Path(run), args.env)
        res = evaluate(agent, args.env, args.episodes, args.seed, policy_name=agent.name,
                       **env_kwargs)
        x = np.array([ep.metrics["rms_error"] for ep in res.episodes])
        w = f"{wrapper.__module__}.{wrapper.__qualname__}" if wrapper else "none"
        print(f"| {run} | {w} | {x.mean():.4g} | {np.median(x):.4g} | {res.success_rate:.0%} | "
              f"{res.returns.mean():.4g} |", flush=True)
    if args.controller:
        policy = baselines.make(args.controller, args.env, env_kwargs=env_kwargs)
        res = evaluate(policy, args.env, args.episodes, args.seed, policy_name=args.controller,
                       **env_kwargs)
        x = np.array([ep.metrics["rms_error"] for ep in res.episodes])
        print(f"| {args.controller} (default gains, {env_kwargs}) | — | {x.mean():.4g} | "
              f"{np.median(x):.4g} | {res.success_rate:.0%} | {res.returns.mean():.4g} |")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("trials", help="the study's trials as a markdown table")
    t.add_argument("db", help="the study's sqlite file")
    t.add_argument("--study", help="study name (default: the file's first study)")
    t.add_argument("--csv", help="also write Optuna's trials_dataframe here")
    e = sub.add_parser("evaluate", help="score rl-zoo3 runs with the project's evaluator")
    e.add_argument("runs", nargs="+", help="rl-zoo3 run directories (LOG/ppo/<env>_N)")
    e.add_argument("--env", default=ENV_ID)
    e.add_argument("--episodes", type=int, default=10)
    e.add_argument("--seed", type=int, default=1000)
    e.add_argument("--controller", default="pd_gravity", help="'' for none")
    args = ap.parse_args(argv)
    return _cmd_trials(args) if args.cmd == "trials" else _cmd_evaluate(args)


if __name__ == "__main__":
    raise SystemExit(main())
