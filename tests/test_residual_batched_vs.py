"""Residual RL over IBVS on the batched VisualServo-v1 (agents.batched: BatchedResidualAction
and the log-error bonus on every copy's feature error) against the single env stack of
agents.train.EnvFactory.

Tolerance as tests/test_residual_batched.py: what the agent sees is float32 (the flat
observation, SB3's rewards), compared to 1e-6 relative; float64 episode metrics to 1e-9; ends,
lengths and success exactly (measured: bit for bit: the batched env, the row-vectorised IBVS
and the bonus are each the single stack's computation).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from cir_gym.agents.batched import BatchedTaskObservation, make_batched_vec_env
from cir_gym.agents.observation import ObservationLayout
from cir_gym.agents.train import EnvFactory
from lockstep import SB3_RTOL as RTOL
from lockstep import sb3_step

ENV = "cir_gym/VisualServo-v1"
SCALE = 0.25
GAIN = {"gain": 0.6058598995030436}  # the lever's IBVS gain
LOG_ERROR = {"weight": 0.1, "max_error": 100.0, "floor": 0.01}


def _layout(kwargs: dict) -> ObservationLayout:
    probe = gym.make(ENV, **kwargs)
    layout = ObservationLayout.from_space(probe.observation_space)
    probe.close()
    return layout


def test_each_copy_is_the_single_residual_stack_with_the_log_error_bonus():
    """Three batched copies and three single envs (ResidualAction over IBVS, LogErrorBonus on
    info["feature_error"]) on the rotation family (where IBVS's camera retreat ends many
    starts at a joint limit), same seeds and random agent actions, through terminations and
    truncations at different steps: every reward carries the bonus of the copy's own error,
    ended copies included."""
    kwargs = {"start_rotation": (0.3, np.pi), "episode_duration": 2.0}
    layout = _layout(kwargs)
    n, seed = 3, 10  # IBVS alone ends seeds 10, 11, 12 at 1.3, 1.3, 0.6 s
    venv = make_batched_vec_env(ENV, kwargs, layout, n, seed, log_error=LOG_ERROR,
                                residual="ibvs", scale=SCALE, controller_kwargs=GAIN)
    singles = [EnvFactory(ENV, kwargs, layout, "ibvs", SCALE, GAIN, log_error=LOG_ERROR)()
               for _ in range(n)]
    obs = venv.reset()
    for i, env in enumerate(singles):
        np.testing.assert_allclose(obs[i], env.reset(seed=seed + i)[0], rtol=RTOL, atol=RTOL)
    rng = np.random.default_rng(0)
    ends = []
    for k in range(80):
        ends += sb3_step(venv, singles, rng.uniform(-0.3, 0.3, (n, 6)).astype(np.float32), k)
    venv.close()
    failed = sum(term for _, term in ends)
    assert {i for i, _ in ends} == {0, 1, 2} and 0 < failed < len(ends)


def test_the_bonus_is_the_env_error_and_is_refused_without_one():
    """BatchedTaskObservation adds w ln(max_error / max(e, floor)) of the batched env's own
    error_norms(); without one (and no q_ref to read it from) the bonus is an error naming
    what it needs."""
    kwargs = {"episode_duration": 0.4}
    layout = _layout(kwargs)
    plain = make_batched_vec_env(ENV, kwargs, layout, 2, 3)
    shaped = make_batched_vec_env(ENV, kwargs, layout, 2, 3, log_error=LOG_ERROR)
    plain.reset(), shaped.reset()
    zero = np.zeros((2, 6), dtype=np.float32)
    for _ in range(3):
        r_plain = plain.step(zero)[1]
        r_shaped = shaped.step(zero)[1]
        e = shaped.venv.venv.error_norms()
        bonus = 0.1 * np.log(100.0 / np.maximum(e, 0.01))
        np.testing.assert_allclose(r_shaped, (r_plain + bonus).astype(np.float32), rtol=RTOL)
    assert np.all(e > 1.0)  # a start far from the goal: the bonus is the error's
    with pytest.raises(ValueError, match="error_norms"):
        BatchedTaskObservation(plain.venv, layout, lambda obs: obs, log_error=LOG_ERROR)
    plain.close(), shaped.close()
