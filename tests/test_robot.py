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


# Every Robot method that takes joint values, as f(robot, q, qd); each validates q and/or qd.
JOINT_CALLS = {
    "inertia": lambda r, q, qd: r.inertia(q),
    "bias": lambda r, q, qd: r.bias(q, qd),
    "gravity": lambda r, q, qd: r.gravity(q),
    "inverse_dynamics": lambda r, q, qd: r.inverse_dynamics(q, qd, qd),
    "jacobian": lambda r, q, qd: r.jacobian("tcp", q),
    "jacobian_by_id": lambda r, q, qd: r.jacobian(r.site_id("tcp"), q),
    "analytic_jacobian": lambda r, q, qd: r.analytic_jacobian("tcp", q),
    "site_pose": lambda r, q, qd: r.site_pose("flange", q),
    "jacobian_dot_qdot": lambda r, q, qd: r.jacobian_dot_qdot("tcp", q, qd),
}
TAKES_QD = ("bias", "inverse_dynamics", "jacobian_dot_qdot")

BAD_SHAPES = {
    "too short": (np.zeros(6), r"has shape \(6,\), expected \(7,\) \(joints: joint1\.\.joint7\)"),
    "one entry": (np.zeros(1), r"has shape \(1,\), expected \(7,\)"),
    "scalar": (0.3, r"has shape \(\), expected \(7,\)"),
    "row": (np.zeros((1, 7)), r"has shape \(1, 7\), expected \(7,\)"),
    "column": (np.zeros((7, 1)), r"has shape \(7, 1\), expected \(7,\)"),
    "batch": (np.zeros((2, 7)), r"has shape \(2, 7\), expected \(7,\)"),
}
BAD_VALUES = {
    "nan": (np.array([0, 0.6, 0, np.nan, 0, 0.9, 0]), "contains NaN or inf"),
    "inf": (np.array([0, 0.6, 0, -1.4, 0, 0.9, np.inf]), "contains NaN or inf"),
    "complex": (np.full(7, 0.1 + 0.2j), r"has dtype complex128, expected real numbers"),
    "complex, zero imaginary": (np.full(7, 0.1 + 0j), r"has dtype complex128, expected real"),
    "strings": (np.array(["0"] * 7), r"has dtype <U1, expected real numbers"),
    "objects": (np.array([None] * 7), r"has dtype object, expected real numbers"),
}


@pytest.mark.parametrize("call", sorted(JOINT_CALLS))
@pytest.mark.parametrize("bad", sorted(BAD_SHAPES) + sorted(BAD_VALUES))
def test_joint_arguments_must_be_real_finite_vectors_of_n(call, bad):
    robot = Robot.from_name("iiwa14")
    good = robot.model.key("home").qpos.copy()
    value, message = {**BAD_SHAPES, **BAD_VALUES}[bad]
    with pytest.raises(ValueError, match=rf"^q {message}"):
        JOINT_CALLS[call](robot, value, np.zeros(7))
    if call in TAKES_QD:
        with pytest.raises(ValueError, match=rf"^qd {message}"):
            JOINT_CALLS[call](robot, good, value)
    # the robot still works after a rejected call
    np.testing.assert_allclose(
        robot.inertia(good), Robot.from_name("iiwa14").inertia(good), rtol=1e-12
    )


def test_qdd_and_friction_velocities_are_validated():
    robot, q = Robot.from_name("iiwa14"), np.zeros(7)
    with pytest.raises(ValueError, match=r"^qdd has shape \(1,\), expected \(7,\)"):
        robot.inverse_dynamics(q, q, np.ones(1))
    with pytest.raises(ValueError, match=r"^qdd contains NaN or inf"):
        robot.inverse_dynamics(q, q, np.full(7, np.nan))
    with pytest.raises(ValueError, match=r"^qd has shape \(\), expected \(7,\)"):
        robot.friction(1.0)
    with pytest.raises(ValueError, match=r"^qd has dtype complex128"):
        robot.friction(np.ones(7, dtype=complex))


def test_the_cached_configuration_does_not_let_a_reshaped_copy_through():
    """The cache compares the bytes of q: a (1, n) array has the same bytes as its (n,) row."""
    robot = Robot.from_name("iiwa14")
    q = robot.model.key("home").qpos.copy()
    robot.inertia(q)
    with pytest.raises(ValueError, match=r"q has shape \(1, 7\)"):
        robot.inertia(q[None, :])


def test_real_inputs_of_any_real_dtype_and_lists_are_accepted():
    robot = Robot.from_name("planar3r")
    q = np.array([0.2, 0.8, 0.6])
    reference = robot.inertia(q), robot.jacobian("ee", q), robot.bias(q, np.ones(3))
    for same in (q.tolist(), tuple(q), np.asarray(q, dtype=">f8")):
        np.testing.assert_array_equal(robot.inertia(same), reference[0])
        np.testing.assert_array_equal(robot.jacobian("ee", same), reference[1])
    np.testing.assert_allclose(robot.inertia(q.astype(np.float32)), reference[0], rtol=1e-6)
    np.testing.assert_array_equal(robot.bias(q, np.ones(3, dtype=int)), reference[2])
    np.testing.assert_array_equal(robot.bias(q, [1, 1, 1]), reference[2])
    np.testing.assert_array_equal(
        robot.inertia(np.zeros(3, dtype=np.uint8)), robot.inertia([0.0] * 3)
    )


def test_a_one_joint_robot_names_its_joint_and_rejects_a_scalar():
    xml = (
        '<mujoco><worldbody><body name="b"><joint name="hinge"/>'
        '<inertial pos="0.1 0 0" mass="1" diaginertia="0.1 0.1 0.1"/></body></worldbody></mujoco>'
    )
    robot = Robot(mujoco.MjModel.from_xml_string(xml))
    assert robot.inertia(np.array([0.3])).shape == (1, 1)
    with pytest.raises(ValueError, match=r"q has shape \(\), expected \(1,\) \(joints: hinge\)"):
        robot.inertia(0.3)
