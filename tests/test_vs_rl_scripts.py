"""scripts/research/optimize_vs.py: the study's objective and the hyperparameter files it writes."""

from __future__ import annotations

import math

import pytest
import yaml

optuna = pytest.importorskip("optuna")

from cir_gym.agents.hyperparameters import load_hyperparams  # noqa: E402

from scripts.research import optimize_vs as study_script  # noqa: E402

ENVS = ("cir_gym/VisualServo-v1", "cir_gym/VisualServoEyeToHand-v1")


def test_episode_score_is_log10_px_clipped_and_failures_score_the_worst():
    assert study_script.episode_score(1.0, False) == 0.0  # the success bar
    assert study_script.episode_score(0.1, False) == pytest.approx(-1.0)
    assert study_script.episode_score(1e-5, False) == pytest.approx(-2.0)  # clipped at 0.01 px
    assert study_script.episode_score(1e6, False) == pytest.approx(3.0)  # clipped at 1000 px
    assert study_script.episode_score(0.05, True) == study_script.FAILED_SCORE == 3.0
    assert study_script.episode_score(50.0, False) == pytest.approx(math.log10(50.0))


def _study(n: int) -> optuna.Study:
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=1))
    study.optimize(lambda t: sum(len(str(v)) for v in study_script.sample(t).values()),
                   n_trials=n)
    return study


def test_every_sampled_trial_is_a_valid_ppo_entry_with_its_values(tmp_path):
    """A trial's file passes the trainer's validation (keys and SB3 arguments) and trains with
    exactly the sampled values."""
    for t in _study(5).trials:
        file = tmp_path / f"t{t.number}.yml"
        file.write_text(yaml.safe_dump(study_script.trial_entry(t.params, 120_000)))
        hp = load_hyperparams("ppo", ENVS[0], path=file)
        for k in ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda", "clip_range"):
            assert hp[k] == t.params[k]
        assert hp["learning_rate"] == pytest.approx(t.params["learning_rate"])
        assert hp["policy_kwargs"]["net_arch"] == [t.params["width"]] * 2
        assert hp["policy_kwargs"]["log_std_init"] == pytest.approx(t.params["log_std_init"],
                                                                    abs=1e-3)
        assert hp["n_timesteps"] == 120_000
        assert hp["checkpoint_freq"] == 120_000


def test_the_adopted_file_is_the_best_trial_for_both_envs_with_100k_checkpoints(tmp_path):
    study = _study(4)
    file = tmp_path / "ppo_study.yml"
    file.write_text(study_script.adopted_file(study, 3_000_000))
    assert f"trial {study.best_trial.number}" in file.read_text()
    for env_id in ENVS:
        hp = load_hyperparams("ppo", env_id, path=file)
        assert hp["n_steps"] == study.best_trial.params["n_steps"]
        assert hp["n_timesteps"] == 3_000_000
        assert hp["checkpoint_freq"] == 100_000
