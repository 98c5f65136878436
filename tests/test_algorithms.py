"""The learners the trainer can build: SB3's, and sb3-contrib's TQC and CrossQ."""

from __future__ import annotations

import pytest

from cir_gym.agents.hyperparameters import ALGORITHMS, HyperparameterError, algorithm_class


def test_every_named_algorithm_is_a_learner_class() -> None:
    sb3_contrib = pytest.importorskip("sb3_contrib")
    import stable_baselines3 as sb3

    classes = {a: algorithm_class(a) for a in ALGORITHMS}
    assert classes["tqc"] is sb3_contrib.TQC and classes["crossq"] is sb3_contrib.CrossQ
    assert classes["ppo"] is sb3.PPO and classes["sac"] is sb3.SAC
    with pytest.raises(HyperparameterError, match="unknown algorithm 'a2c'.*crossq"):
        algorithm_class("a2c")
