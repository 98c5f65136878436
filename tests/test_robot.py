"""`Robot`: every Jacobian against finite differences, dynamics against the numpy chapter 2."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cir_gym import dynamics
from cir_gym.robot import ModelError, Robot, RobotFileError

SITES = {"iiwa14": "tcp", "planar2r": "ee", "planar3r": "ee"}


def rotation_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of R (3,)."""
    angle = np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))
    if angle < 1e-12:
        return np.zeros(3)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return angle / (2 * np.sin(angle)) * w


def random_state(robot: Robot, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    q = rng.uniform(0.8 * robot.lower, 0.8 * robot.upper)
    return q, rng.uniform(-1, 1, robot.n)


@pytest.mark.parametrize("name", sorted(SITES))
def test_geometric_jacobian_matches_finite_differences(name):
    robot, site, rng = Robot.from_name(name), SITES[name], np.random.default_rng(0)
    h = 1e-6
    for _ in range(5):
        q, _ = random_state(robot, rng)
        J = robot.jacobian(site, q)
        p0, R0 = robot.site_pose(site, q)
        for i in range(robot.n):
            dq = np.zeros(robot.n)
            dq[i] = h
            p1, R1 = robot.site_pose(site, q + dq)
            np.testing.assert_allclose(J[:3, i], (p1 - p0) / h, atol=1e-5)
            np.testing.assert_allclose(J[3:, i], rotation_log(R1 @ R0.T) / h, atol=1e-5)


@pytest.mark.parametrize("name", sorted(SITES))
def test_jacobian_dot_qdot_matches_the_time_derivative_of_j(name):
    robot, site, rng = Robot.from_name(name), SITES[name], np.random.default_rng(1)
    h = 1e-6
    for _ in range(5):
        q, qd = random_state(robot, rng)
        numeric = (robot.jacobian(site, q + h * qd) - robot.jacobian(site, q - h * qd)) / (2 * h)
        np.testing.assert_allclose(robot.jacobian_dot_qdot(site, q, qd), numeric @ qd, atol=1e-6)


def test_analytic_jacobian_matches_zyx_euler_rates():
    robot, rng = Robot.from_name("iiwa14"), np.random.default_rng(2)

    def zyx(R: np.ndarray) -> np.ndarray:
        return np.array(
            [np.arctan2(R[1, 0], R[0, 0]), -np.arcsin(R[2, 0]), np.arctan2(R[2, 1], R[2, 2])]
        )

    h = 1e-6
    for _ in range(5):
        q, qd = random_state(robot, rng)
        JA = robot.analytic_jacobian("tcp", q)
        phi_dot = (
            zyx(robot.site_pose("tcp", q + h * qd)[1]) - zyx(robot.site_pose("tcp", q - h * qd)[1])
        ) / (2 * h)
        np.testing.assert_allclose(JA[3:] @ qd, phi_dot, atol=1e-5)


@pytest.mark.parametrize("name", sorted(SITES))
def test_mujoco_dynamics_agree_with_the_numpy_chapter_2(name):
    robot, rng = Robot.from_name(name), np.random.default_rng(3)
    for _ in range(3):
        q, qd = random_state(robot, rng)
        qdd = rng.normal(size=robot.n)
        np.testing.assert_allclose(
            robot.inertia(q), dynamics.inertia_matrix(robot.model, q), rtol=1e-9, atol=1e-9
        )
        np.testing.assert_allclose(
            robot.inverse_dynamics(q, qd, qdd),
            dynamics.rnea(robot.model, q, qd, qdd),
            rtol=1e-9,
            atol=1e-9,
        )


def test_with_error_changes_the_copy_only_and_the_payload_adds_its_weight():
    nominal = Robot.from_name("iiwa14")
    q = nominal.model.key("home").qpos.copy()
    heavy = nominal.with_error(ModelError(payload_mass=2.0))
    assert nominal.model.body("payload").mass[0] == 0.0
    # the extra gravity torque is J_Pᵀ of the payload's weight at its centre of mass
    jacp = np.zeros((3, heavy.n))
    heavy.site_pose("flange", q)
    bid = heavy.model.body("payload").id
    mujoco.mj_jac(heavy.model, heavy.data, jacp, None, heavy.data.xipos[bid], bid)
    expected = -jacp.T @ (2.0 * heavy.model.opt.gravity)
    np.testing.assert_allclose(heavy.gravity(q) - nominal.gravity(q), expected, atol=1e-9)
    scaled = nominal.with_error(mass_scale=1.1)
    moving = nominal.model.body_dofnum > 0  # the fixed base keeps its mass
    np.testing.assert_allclose(
        scaled.model.body_mass[moving], 1.1 * nominal.model.body_mass[moving]
    )
    np.testing.assert_allclose(scaled.model.body_mass[~moving], nominal.model.body_mass[~moving])
    friction = nominal.with_error(viscous_friction=0.5, coulomb_friction=0.2)
    np.testing.assert_allclose(friction.friction(np.ones(7)), 0.7)


def test_bad_robot_files_and_arguments_are_reported():
    with pytest.raises(RobotFileError, match="neither a shipped robot"):
        Robot.from_name("ur5")
    with pytest.raises(ValueError, match="payload_mass"):
        ModelError(payload_mass=-1.0)
    with pytest.raises(ValueError, match="site 'nope' not in the model"):
        Robot.from_name("planar3r").jacobian("nope", np.zeros(3))
