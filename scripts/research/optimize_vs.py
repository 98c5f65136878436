"""Optuna study of PPO's hyperparameters on VisualServo-v1, through the project's own trainer.

    python scripts/research/optimize_vs.py run [--trials 12] [--timesteps 100000] [--wall 2400]
        [--worker 0]
    python scripts/research/optimize_vs.py trials      # markdown table of every trial
    python scripts/research/optimize_vs.py best [--write agents/hyperparams/vs/ppo_study.yml]

Why not rl-zoo3's ``-optimize`` (``scripts/zoo_optimize.sh``): it scores a trial by the mean
evaluation return, and its PPO sampler draws batches of 4–1024 at up to 20 epochs (the
JointTracking study spent most of its 40 min in gradient steps of batch 4–16,
results/tuning/zoo_optuna/README.md). Here every trial is an ordinary
:func:`cir_gym.agents.train.train` run (its ``config.yml`` retrains it), on a narrow space
around the hand recipe (``agents/hyperparams/vs/ppo.yml``'s ``default``), scored on the primary
metric: the mean over ``VALIDATION_EPISODES`` episodes (seeds ``VALIDATION_SEED`` …, used by
no training, leaderboard or test run) of log10 of the final feature error (px, clipped to
[0.01, 1000]), an episode that ends early (feature lost, joint limit) scoring 3 (1000 px).
Lower is better; 0 is the 1-px success bar, IBVS scores about −1.5 (0.035 px).

Multivariate TPE (seeded per worker, the first ``STARTUP`` trials random), no pruner: the
trainer has no hook for one. Several workers (``--worker k``, one process each) share the
sqlite study. ``--wall`` stops a worker: no new trial after it, and SIGTERM (``timeout``) ends
the running one (checkpointed, marked FAIL). Re-running continues the study.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ENV_ID = "cir_gym/VisualServo-v1"
BASE = Path("agents/hyperparams/vs/ppo.yml")
STORAGE = Path("results/visual_servo/agents_study/ppo_vs.db")
ADOPTED = Path("agents/hyperparams/vs/ppo_study.yml")  # the best trial, for the full runs
STUDY = "ppo_visualservo_v1"
RUNS = Path("/work/main/runs/rl/study")
VALIDATION_SEED = 60_000
VALIDATION_EPISODES = 20
FAILED_SCORE = 3.0  # log10 px of an episode that ends early
STARTUP = 4
#: the sampled hyperparameters and their choices (the rest is the hand recipe's)
CHOICES: dict[str, tuple[Any, ...]] = {
    "n_steps": (128, 256, 512),
    "batch_size": (256, 512, 1024),
    "n_epochs": (5, 10),
    "gamma": (0.98, 0.99, 0.995),
    "gae_lambda": (0.9, 0.95, 0.98),
    "clip_range": (0.1, 0.2, 0.3),
    "width": (64, 128, 256),
}
LEARNING_RATE = (1.0e-4, 1.0e-3)  # log-uniform
LOG_STD_INIT = (-2.0, -0.5)  # uniform; the std of a (−1, 1) action


def episode_score(final_error: float, terminated: bool) -> float:
    """log10 of the final feature error (px) clipped to [0.01, 1000]; ``FAILED_SCORE`` when the
    episode ended early."""
    if terminated:
        return FAILED_SCORE
    return math.log10(min(max(final_error, 0.01), 1000.0))


def base_entry() -> dict[str, Any]:
    """The hand recipe: the ``default`` entry and the ``training`` section of ``BASE``."""
    data = yaml.safe_load(BASE.read_text())
    return {"default": dict(data["default"]), "training": data.get("training", {})}


def trial_entry(params: dict[str, Any], timesteps: int) -> dict[str, Any]:
    """A hyperparameter file (``default`` + ``training``) for a trial's sampled ``params``."""
    data = base_entry()
    entry = data["default"]
    for key in ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda", "clip_range",
                "learning_rate"):
        entry[key] = params[key]
    width = int(params["width"])
    entry["policy_kwargs"] = (f"dict(net_arch=[{width}, {width}], activation_fn=nn.Tanh, "
                              f"log_std_init={params['log_std_init']:.3f})")
    entry["n_timesteps"] = float(timesteps)
    data["training"] = {"default": {"vec_env": "dummy", "eval_freq": timesteps // 2,
                                    "n_eval_episodes": 3, "checkpoint_freq": timesteps}}
    return data


def sample(trial: Any) -> dict[str, Any]:
    params = {k: trial.suggest_categorical(k, list(v)) for k, v in CHOICES.items()}
    params["learning_rate"] = trial.suggest_float("learning_rate", *LEARNING_RATE, log=True)
    params["log_std_init"] = trial.suggest_float("log_std_init", *LOG_STD_INIT)
    return params


def score_agent(run_dir: Path) -> dict[str, float]:
    """The study's objective and its parts for the agent in ``run_dir`` (final model)."""
    from cir_gym.agents.policy import load_agent

    from cir_gym.evaluation import evaluate

    agent = load_agent(run_dir, ENV_ID)
    res = evaluate(agent, ENV_ID, VALIDATION_EPISODES, VALIDATION_SEED)
    scores = [episode_score(ep.metrics["final_feature_error"], ep.terminated)
              for ep in res.episodes]
    finals = [ep.metrics["final_feature_error"] for ep in res.episodes]
    return {"objective": float(np.mean(scores)), "success": float(res.success_rate),
            "median_final_error": float(np.median(finals)),
            "terminated": float(sum(ep.terminated for ep in res.episodes))}


def objective_factory(timesteps: int) -> Any:
    def objective(trial: Any) -> float:
        from cir_gym.agents.train import train

        params = sample(trial)
        name = f"ppo_trial_{trial.number:03d}"
        hp_dir = RUNS / "hyperparams"
        hp_dir.mkdir(parents=True, exist_ok=True)
        hp_file = hp_dir / f"{name}.yml"
        hp_file.write_text(yaml.safe_dump(trial_entry(params, timesteps), sort_keys=False))
        t0 = time.perf_counter()
        run_dir = train(ENV_ID, "ppo", timesteps=timesteps, seed=0, out=RUNS, name=name,
                        hyperparams_path=hp_file, progress_bar=False, verbose=0)
        trial.set_user_attr("train_wall_s", round(time.perf_counter() - t0, 1))
        trial.set_user_attr("run_dir", str(run_dir))
        parts = score_agent(run_dir)
        for k, v in parts.items():
            trial.set_user_attr(k, v)
        print(f"trial {trial.number}: {parts} {params}", flush=True)
        return parts["objective"]
    return objective


def load_study(create: bool = False, worker: int = 0) -> Any:
    import optuna

    sampler = optuna.samplers.TPESampler(seed=worker, multivariate=True,
                                         n_startup_trials=STARTUP)
    storage = f"sqlite:///{STORAGE}"
    if create:
        STORAGE.parent.mkdir(parents=True, exist_ok=True)
        return optuna.create_study(study_name=STUDY, storage=storage, direction="minimize",
                                   sampler=sampler, load_if_exists=True)
    return optuna.load_study(study_name=STUDY, storage=storage, sampler=sampler)


def adopted_file(study: Any, timesteps: int) -> str:
    """The hyperparameter file of the study's best complete trial for a full run of
    ``timesteps`` steps (the hand recipe's ``training`` section: evaluations and checkpoints
    every 100k steps), with a header naming the trial."""
    best = study.best_trial
    data = trial_entry(best.params, timesteps)
    data["training"] = base_entry()["training"]
    done = [t for t in study.trials if t.state.name == "COMPLETE"]
    attrs = {k: best.user_attrs[k] for k in ("success", "median_final_error", "terminated")
             if k in best.user_attrs}
    header = (
        f"# Written by `python scripts/research/optimize_vs.py best --write {ADOPTED}`: the best\n"
        f"# of {len(done)} complete trials of the Optuna study {STUDY!r} ({STORAGE}), trial "
        f"{best.number}:\n# objective {best.value:.4g} (mean log10 final feature error, px, on "
        f"{VALIDATION_EPISODES} validation episodes\n# after the trial's steps; {attrs}).\n"
        "# Used for both visual-servoing envs by scripts/research/train_vs.sh (the study ran on "
        "VisualServo-v1).\n")
    return header + yaml.safe_dump(data, sort_keys=False)


def _fmt(x: Any) -> str:
    if isinstance(x, float):
        return f"{x:.4g}"
    return "" if x is None else str(x)


def trials_table(study: Any) -> str:
    keys = [*CHOICES, "learning_rate", "log_std_init"]
    head = ["trial", "state", "objective", "success", "median final error (px)", "ended early",
            "train wall (min)", *keys]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for t in study.trials:
        a = t.user_attrs
        wall = a.get("train_wall_s")
        cells = [str(t.number), t.state.name, _fmt(t.value), _fmt(a.get("success")),
                 _fmt(a.get("median_final_error")), _fmt(a.get("terminated")),
                 _fmt(wall / 60.0 if wall else None), *(_fmt(t.params.get(k)) for k in keys)]
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run trials (one worker)")
    r.add_argument("--trials", type=int, default=12)
    r.add_argument("--timesteps", type=int, default=100_000)
    r.add_argument("--wall", type=float, default=2400.0, help="s: no new trial after this")
    r.add_argument("--worker", type=int, default=0, help="seeds this worker's sampler")
    r.add_argument("--total", type=int, help="stop when the study has this many complete "
                   "trials (all workers together)")
    sub.add_parser("trials", help="every trial as a markdown table")
    b = sub.add_parser("best", help="the best trial as a hyperparameter file (YAML)")
    b.add_argument("--timesteps", type=int, default=3_000_000)
    b.add_argument("--write", type=Path, help=f"write it here (e.g. {ADOPTED})")
    args = ap.parse_args(argv)
    if args.cmd == "run":
        import optuna

        study = load_study(create=True, worker=args.worker)
        study = load_study(worker=args.worker + 100 * len(study.trials))  # a resumed study's
        # random start-up trials must not repeat the first session's draws
        stop = [] if args.total is None else [optuna.study.MaxTrialsCallback(
            args.total, states=(optuna.trial.TrialState.COMPLETE,))]
        study.optimize(objective_factory(args.timesteps), n_trials=args.trials,
                       timeout=args.wall, catch=(ValueError, RuntimeError), callbacks=stop)
        return 0
    study = load_study()
    if args.cmd == "trials":
        print(f"study {STUDY!r} ({STORAGE}): {len(study.trials)} trials")
        print(trials_table(study))
        return 0
    text = adopted_file(study, args.timesteps)
    if args.write:
        args.write.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
