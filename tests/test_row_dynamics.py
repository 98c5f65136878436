"""baselines.base.RowDynamics.newton_euler: the laws' inverse dynamics by MuJoCo's mj_rne."""

from __future__ import annotations

import pickle

import numpy as np
from cir_gym.baselines.base import RowDynamics

from cir_gym.robot import Robot


def _states(robot: Robot, n: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot.lower, robot.upper, (n, robot.n))
    return q, rng.normal(0, 2, (n, robot.n)), rng.normal(0, 20, (n, robot.n))


def _close(a: np.ndarray, b: np.ndarray) -> None:
    """Equal to rounding: within 1e-12 of each row's largest component."""
    scale = np.max(np.abs(b), axis=-1, keepdims=True)
    assert np.all(np.abs(a - b) <= 1e-12 * scale), np.max(np.abs(a - b) / scale)


def test_newton_euler_is_inverse_dynamics_to_rounding():
    """B̂ q̈ + n̂ without B̂ (mj_rne with q̈, plus the armature's term mj_rne leaves out)
    equals B̂(q) q̈ + n̂(q, q̇) formed from Robot.inertia and Robot.bias, one row and rows."""
    robot = Robot.from_name("iiwa14")
    assert np.any(robot.model.dof_armature > 0)  # the armature term is exercised
    rows = RowDynamics.for_robot(robot)
    q, qd, qdd = _states(robot, 200)
    tau = rows.newton_euler(q, qd, qdd)
    assert tau.shape == q.shape
    for i in range(len(q)):
        want = robot.inertia(q[i]) @ qdd[i] + robot.bias(q[i], qd[i])
        one = rows.newton_euler(q[i], qd[i], qdd[i])
        np.testing.assert_array_equal(one, tau[i])  # a row alone = that row in a batch
        _close(one, want)
    np.testing.assert_array_equal(rows.newton_euler(q[:1], qd[:1], qdd[:1])[0], tau[0])
    twin = pickle.loads(pickle.dumps(rows))
    np.testing.assert_array_equal(twin.newton_euler(q, qd, qdd), tau)


def test_newton_euler_sees_the_models_armature_now():
    """An armature written into the model after the RowDynamics was built (as
    Robot.set_armature does) is in the next call's torque."""
    robot = Robot.from_name("iiwa14")
    rows = RowDynamics.for_robot(robot)
    q, qd, qdd = _states(robot, 3, seed=1)
    robot.set_armature(np.full(robot.n, 0.5))
    for i in range(3):
        want = robot.inertia(q[i]) @ qdd[i] + robot.bias(q[i], qd[i])
        _close(rows.newton_euler(q[i], qd[i], qdd[i]), want)
