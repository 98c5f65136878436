"""The learners the trainer can build (SB3's, sb3-contrib's TQC and CrossQ) and the errors its
shaping wrappers read."""

from __future__ import annotations

import pytest
from cir_gym.agents.hyperparameters import ALGORITHMS, HyperparameterError, algorithm_class


def test_every_named_algorithm_is_a_learner_class() -> None:
    sb3_contrib = pytest.importorskip("sb3_contrib")
    import stable_baselines3 as sb3

    classes = {a: algorithm_class(a) for a in ALGORITHMS}
    assert classes["tqc"] is sb3_contrib.TQC and classes["crossq"] is sb3_contrib.CrossQ
    assert classes["ppo"] is sb3.PPO and classes["sac"] is sb3.SAC
    with pytest.raises(HyperparameterError, match=r"unknown algorithm 'a2c'.*crossq"):
        algorithm_class("a2c")


def test_shaping_reads_the_visual_servo_feature_error() -> None:
    """Early termination and the log-error bonus work on visual servoing (error in px)."""
    import gymnasium as gym
    import numpy as np
    from cir_gym.agents.shaping import error_norm

    import cir_gym  # noqa: F401

    env = gym.make("cir_gym/VisualServo-v1")
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(env.action_space.shape))
    assert error_norm(info) == pytest.approx(info["feature_error"]) and info["feature_error"] > 1
