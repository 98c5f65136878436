"""VisualServo's step fast path gives the numbers of its plain path, bit for bit.

The step reads the twist's Jacobian and the flange pose from the env's own MjData (its
position stage, rerun when the joints changed from outside) instead of the Robot's, solves
J Jᵀ x = V through numpy's gufunc directly and keeps the features as Python floats; the
plain path (``_fast = False``, the Robot's kinematics, as for joints that are not the whole
state) and numpy's public calls must give the same observations, rewards and infos.
"""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest

import cir_gym  # noqa: F401
from cir_gym import baselines
from cir_gym.fast_solve import solve

ENVS = ("cir_gym/VisualServo-v0", "cir_gym/VisualServoEyeToHand-v0")


def _rollout(env: gym.Env, seed: int, steps: int, meddle: bool = False) -> list:
    """Observations, rewards, flags and infos of random-action steps (``meddle``: the joint
    positions are set from outside now and then, between steps)."""
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    out = [obs, info]
    for k in range(steps):
        if meddle and k % 7 == 3:
            u = env.unwrapped
            u.data.qpos[:] += 1e-3 * rng.standard_normal(u.model.nq)
        action = rng.uniform(-0.4, 0.4, env.action_space.shape).astype(np.float32)
        out.append(env.step(action))
        if out[-1][2] or out[-1][3]:
            break
    return out


def _assert_identical(a: object, b: object) -> None:
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            _assert_identical(a[key], b[key])
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_identical(x, y)
    else:
        x, y = np.asarray(a), np.asarray(b)
        assert x.dtype == y.dtype and x.shape == y.shape
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), (x, y)


@pytest.mark.parametrize("env_id", ENVS)
@pytest.mark.parametrize("kwargs", [{}, {"camera_error": (0.05, 10.0, 0.01, 0.02)}])
@pytest.mark.parametrize("meddle", [False, True])
def test_fast_step_equals_the_robot_kinematics_path(env_id: str, kwargs: dict, meddle: bool
                                                     ) -> None:
    fast = gym.make(env_id, **kwargs)
    plain = gym.make(env_id, **kwargs)
    assert fast.unwrapped._fast
    plain.unwrapped._fast = False  # the Robot's kinematics, numpy's arrays
    for seed in (0, 1):
        _assert_identical(_rollout(fast, seed, 60, meddle), _rollout(plain, seed, 60, meddle))


@pytest.mark.parametrize("env_id", ENVS)
def test_a_pickled_env_continues_the_same_episode(env_id: str) -> None:
    env = gym.make(env_id).unwrapped
    env.reset(seed=3)
    policy = baselines.make("ibvs" if env_id == ENVS[0] else "ibvs_eye_to_hand", env_id, env=env)
    obs = env._obs()
    for _ in range(5):
        obs = env.step(policy.predict(obs, None, np.array([True]))[0])[0]
    copy = pickle.loads(pickle.dumps(env))
    for _ in range(20):
        action = policy.predict(obs, None, np.array([True]))[0]
        a, b = env.step(action), copy.step(action)
        _assert_identical(a, b)
        obs = a[0]
    np.testing.assert_array_equal(env._s_true, copy._s_true)


@pytest.mark.parametrize("numpy_internals", [True, False])
def test_solve_is_numpy_solve_with_its_errors(numpy_internals, monkeypatch) -> None:
    """cir_gym.fast_solve.solve (VisualServo's J⁺V, the motion interface's damped least
    squares) gives np.linalg.solve's bits and errors for vector and matrix right-hand sides,
    with numpy's internals and in its fallback (another numpy's layout)."""
    from cir_gym import fast_solve

    if not numpy_internals:
        monkeypatch.setattr(fast_solve, "_FP_STATE", None)
    rng = np.random.default_rng(0)
    for _ in range(200):
        J = rng.standard_normal((6, 7))
        A, b = J @ J.T, rng.standard_normal(6)
        np.testing.assert_array_equal(solve(A, b), np.linalg.solve(A, b))
        np.testing.assert_array_equal(solve(A + np.eye(6), J), np.linalg.solve(A + np.eye(6), J))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no floating-point warning either
        with pytest.raises(np.linalg.LinAlgError):
            solve(np.zeros((6, 6)), np.ones(6))
        with pytest.raises(np.linalg.LinAlgError):
            solve(np.zeros((6, 6)), np.ones((6, 7)))


def test_servo_scaling_with_a_zero_limit_follows_numpy_without_warnings() -> None:
    env = gym.make(ENVS[0]).unwrapped
    env.reset(seed=0)
    saved = env.model.actuator_ctrlrange.copy()
    try:
        qd = np.linspace(-1.0, 1.0, 7)
        env.model.actuator_ctrlrange[2, 1] = 0.0  # |q̇| / 0: inf or NaN, numpy's way
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            np.testing.assert_array_equal(env._ctrl(qd), qd)  # a NaN ratio: not scaled
        env.model.actuator_ctrlrange[:, 1] = 0.25  # scaled down uniformly to the limit
        np.testing.assert_array_equal(env._ctrl(qd), qd / 4.0)
    finally:
        env.model.actuator_ctrlrange[:] = saved
