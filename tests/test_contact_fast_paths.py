"""The contact envs' step fast paths give the numbers of their plain paths, bit for bit.

The position interface computes
B(q) and n(q, q̇) with Robot's MuJoCo calls on an own MjData and its damped least squares
through numpy's solve gufunc. Each must equal its plain path: observations, rewards, flags and
infos, including a divergence (restored state) and states set from outside between steps.
"""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest

import cir_gym  # noqa: F401
from cir_gym import motion_interface as mi

PEG = "cir_gym/PegInHole-v2"
ADMITTANCE = "cir_gym/AdmittanceContact-v1"


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
def test_motion_interface_fast_torque_equals_robot_calls(env_id: str) -> None:
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
        fast = interface.torque(q, qd, 0.5)
        robot = interface.robot
        q_r = interface._q_start + 0.5 * interface._dq
        y = interface.kp * (q_r - q) + interface.kd * (interface._dq / interface._period - qd)
        np.testing.assert_array_equal(fast, robot.inertia(q) @ y + robot.bias(q, qd))
        # a list takes Robot's path (its validation): the same numbers
        np.testing.assert_array_equal(fast, interface.torque(q.tolist(), qd.tolist(), 0.5))
    with pytest.raises(ValueError, match="NaN or inf"):
        interface.torque(np.full(q0.size, np.nan), np.zeros(q0.size), 0.5)


def test_motion_interface_command_equals_damped_least_squares(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    env = gym.make(ADMITTANCE, control="position")
    env.reset(seed=0)
    interface = env.unwrapped.interface
    rng = np.random.default_rng(1)
    increments = 1e-3 * rng.standard_normal((10, 6))
    q_start = interface.q_c.copy()
    fast = []
    for dx in increments:
        interface.command(dx, 0.002)
        fast.append(interface.q_c.copy())
    interface.reset(q_start)
    monkeypatch.setattr(mi, "_INLINE_DLS", False)  # operational_space.damped_least_squares
    for dx, want in zip(increments, fast, strict=True):
        interface.command(dx, 0.002)
        np.testing.assert_array_equal(interface.q_c, want)


def _command_outcome(interface: mi.CartesianMotionInterface, q: np.ndarray) -> tuple:
    """(new setpoint or the exception's type and text, the warnings' texts) of one command
    from ``q``."""
    interface.reset(q)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            interface.command(np.array([1e-3, 0.0, 0.0, 0.0, 0.0, 1e-3]), 0.002)
            result: object = interface.q_c.copy()
        except Exception as exc:  # the outcome compared, whatever it is
            result = (type(exc), str(exc))
    return result, [str(w.message) for w in caught]


@pytest.mark.parametrize(
    ("damping", "singular"), [(1e-170, False), (1e-160, False), (1e-10, True), (1e-3, True)]
)
def test_motion_interface_tiny_damping_behaves_as_the_plain_solve(
    damping: float, singular: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A damping whose square rounds to 0 (1e-170) at q = 0 (a singular Jacobian), a
    subnormal square (1e-160), and a k² lost in rounding against J Jᵀ at a Jacobian with two
    equal rows (an exactly zero pivot): the fast path raises, warns and returns what
    np.linalg.solve's path does."""
    env = gym.make(ADMITTANCE, control="position")
    env.reset(seed=0)
    interface = env.unwrapped.interface
    interface.damping = damping
    if singular:
        J = np.zeros((6, interface.robot.n))
        J[0] = J[1] = np.linspace(0.1, 0.9, J.shape[1])
        J[2:, 2:6] = 0.5 * np.eye(4)
        monkeypatch.setattr(interface.robot, "jacobian", lambda site, q: J.copy())
    q = np.zeros(interface.robot.n)
    fast = _command_outcome(interface, q)
    monkeypatch.setattr(mi, "_INLINE_DLS", False)  # operational_space.damped_least_squares
    plain = _command_outcome(interface, q)
    assert fast[1] == plain[1]
    if isinstance(plain[0], tuple):
        assert fast[0] == plain[0]
    else:
        np.testing.assert_array_equal(fast[0], plain[0])
    if damping == 1e-170 or (singular and damping == 1e-10):  # the cases the fix is about
        assert plain[0] == (np.linalg.LinAlgError, "Singular matrix")


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
