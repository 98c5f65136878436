"""The contact envs: the position interface's torque law (one arm and N arms), and a pickled env
continues the same episode."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest

import cir_gym  # noqa: F401
from cir_gym import motion_interface as mi

PEG = "cir_gym/PegInHole-v2"
ADMITTANCE = "cir_gym/AdmittanceContact-v2"


def _rollout(
    env: gym.Env, seed: int, steps: int, diverge_at: int | None = None, nan_at: int | None = None
) -> list:
    """Observations, rewards, flags and infos of steps with small random actions pushing
    down (``diverge_at``: the joint speeds set absurd before that step; ``nan_at``: a joint
    position set to NaN before that step, which MuJoCo answers with a warning)."""
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    out = [obs, info]
    down = np.zeros(env.action_space.shape)
    if env.unwrapped.control == "position":
        down[2] = -0.5
    for k in range(steps):
        if k == diverge_at:
            env.unwrapped.data.qvel[:] = 5e3
        if k == nan_at:
            env.unwrapped.data.qpos[1] = np.nan
        action = (down + rng.uniform(-0.3, 0.3, env.action_space.shape)).astype(np.float32)
        out.append(env.step(action))
        if out[-1][2] or out[-1][3]:
            break
    return out


def _assert_same(a: object, b: object) -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b)
        for key in a:
            _assert_same(a[key], b[key])
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    else:
        assert type(a) is type(b)
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("env_id", [PEG, ADMITTANCE])
def test_motion_interface_torque_is_the_inverse_dynamics_of_the_nominal_model(env_id: str) -> None:
    """τ = B̂(q) y + n̂(q, q̇) by Newton–Euler with q̈ = y plus the armature equals Robot's
    inertia and bias to 1e-12 relative (the same model, summed in another order)."""
    env = gym.make(env_id, control="position")
    env.reset(seed=0)
    u = env.unwrapped
    interface = u.motion if env_id == PEG else u.interface
    interface.command(np.array([1e-4, -2e-4, -3e-4, 1e-3, 0.0, -1e-3]), u.dt)
    rng = np.random.default_rng(0)
    q0 = interface.q_c.copy()
    for _ in range(20):
        q = q0 + 0.05 * rng.standard_normal(q0.size)
        qd = rng.standard_normal(q0.size)
        tau = interface.torque(q, qd, 0.5)
        robot = interface.robot
        q_r, qd_r = interface.reference(0.5)
        y = interface.kp * (q_r - q) + interface.kd * (qd_r - qd)
        want = robot.inertia(q) @ y + robot.bias(q, qd)
        np.testing.assert_allclose(tau, want, rtol=0, atol=1e-12 * np.max(np.abs(want)))
        np.testing.assert_array_equal(tau, interface.torque(q.tolist(), qd.tolist(), 0.5))
    with pytest.raises(ValueError, match="NaN or inf"):
        interface.torque(np.full(q0.size, np.nan), np.zeros(q0.size), 0.5)
    with pytest.raises(ValueError, match="shape"):
        interface.torque(np.zeros(q0.size + 1), np.zeros(q0.size + 1), 0.5)


def test_motion_interface_on_n_arms_is_each_arm_alone() -> None:
    """An interface reset with (N, n) configurations commands and drives each arm as a
    one-arm interface does (the same calls, row by row: equal to the last bit)."""
    env = gym.make(PEG, control="position")
    env.reset(seed=0)
    one = env.unwrapped.motion
    many = mi.CartesianMotionInterface(one.robot, "peg_tip")
    rng = np.random.default_rng(3)
    q0 = one.q_c.copy()
    starts = q0 + 0.01 * rng.standard_normal((5, q0.size))
    many.reset(starts)
    increments = 1e-4 * rng.standard_normal((3, 5, 6))
    q, qd = starts + 1e-3, rng.standard_normal(starts.shape)
    taus = []
    for dx in increments:
        many.command(dx, 0.002)
        taus.append(many.torque(q, qd, 0.5))
    many.reset(q0, rows=[1])
    for i in range(5):
        one.reset(starts[i])
        for dx, tau in zip(increments, taus, strict=True):
            one.command(dx[i], 0.002)
            np.testing.assert_array_equal(one.torque(q[i], qd[i], 0.5), tau[i])
    np.testing.assert_array_equal(many.q_c[1], q0)
    with pytest.raises(mi.InvalidArgument, match="increment"):
        many.command(np.zeros(6), 0.002)


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        (PEG, {"control": "position"}),
        (ADMITTANCE, {"control": "position"}),
        (PEG, {"force_limit": 1e4}),  # random torques strike the block: no stop at 100 N
    ],
)
def test_a_pickled_contact_env_continues_the_same_episode(env_id: str, kwargs: dict) -> None:
    env = gym.make(env_id, episode_duration=0.2, **kwargs)
    _rollout(env, 2, 10)
    twin = pickle.loads(pickle.dumps(env))
    rng = np.random.default_rng(5)
    for _ in range(15):
        action = rng.uniform(-0.2, 0.2, env.action_space.shape).astype(np.float32)
        _assert_same(env.step(action), twin.step(action))
