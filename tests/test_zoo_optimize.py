"""scripts/zoo_optimize.py: the study table and loading an rl-zoo3 run for the evaluator."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rl_zoo3")
optuna = pytest.importorskip("optuna")

from scripts.zoo_optimize import load_zoo_run, trial_hyperparameters, trials_table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ENV = "cir_gym/JointTracking-v2"


def test_trial_hyperparameters_match_rl_zoo3s_conversion():
    """The table shows what rl-zoo3 trains with: its sampler's powers of two and 1 - gamma
    converted as rl_zoo3.hyperparams_opt.convert_onpolicy_params does."""
    from rl_zoo3.hyperparams_opt import sample_ppo_params

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0),
                                direction="maximize")
    used = {}

    def objective(trial):
        used[trial.number] = sample_ppo_params(trial, 7, 16, {})
        trial.report(-1.0, 1)
        return -1.0 - trial.number

    study.optimize(objective, n_trials=3)
    for t in study.trials:
        hp, zoo = trial_hyperparameters(t.params), used[t.number]
        for k in ("n_steps", "batch_size", "gamma", "gae_lambda", "learning_rate", "n_epochs"):
            assert hp[k] == pytest.approx(zoo[k]), k
    table = trials_table(study).splitlines()
    assert len(table) == 2 + 3
    assert table[2].startswith("| 0 | COMPLETE | -1 | -1 |")


def test_a_zoo_run_loads_as_a_policy_on_raw_observations(tmp_path):
    """A short rl-zoo3 run on the study's file (agent at 100 Hz, gravity feature) loads with
    the run's wrapper and VecNormalize statistics, acts on the env's raw Dict observation as
    the network does on the normalised flat one, and runs in the project's evaluator."""
    import gymnasium as gym
    from cir_gym.agents.observation import TaskObservation

    from cir_gym.evaluation import evaluate

    cmd = [sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", ENV,
           "--gym-packages", "cir_gym", "--conf-file",
           str(ROOT / "agents/hyperparams/zoo/ppo_100hz.yml"), "-n", "256",
           "--log-folder", str(tmp_path), "--eval-freq", "-1", "--seed", "0", "--vec-env",
           "dummy", "--env-kwargs", "control_freq:100.0", "episode_duration:0.2",
           "--hyperparams", "n_envs:2", "n_steps:64", "batch_size:64", "n_epochs:1"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr[-2000:]
    agent, env_kwargs, wrapper = load_zoo_run(tmp_path / "ppo" / "cir_gym-JointTracking-v2_1")
    assert wrapper is TaskObservation
    assert env_kwargs == {"control_freq": 100.0, "episode_duration": 0.2}
    assert agent.interface_kwargs == {"control_freq": 100.0}
    assert agent.vecnormalize is not None and agent.vecnormalize.obs_rms.count > 1

    env = gym.make(ENV, **env_kwargs)
    obs, _ = env.reset(seed=3)
    flat = TaskObservation(gym.make(ENV, **env_kwargs), features=["gravity"]).observation(obs)
    expected, _ = agent.model.predict(agent.vecnormalize.normalize_obs(flat), deterministic=True)
    action, _ = agent.predict(obs)
    np.testing.assert_allclose(action, expected, rtol=1e-6)
    result = evaluate(agent, ENV, 1, 1000, **env_kwargs)
    assert np.isfinite(result.episodes[0].metrics["rms_error"])
