"""cir_gym.operational_space against finite differences, closed forms and MuJoCo."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cir_gym import operational_space as osp
from cir_gym import trajectories as traj
from cir_gym.robot import Robot

SITE = "flange"


@pytest.fixture(scope="module")
def robot() -> Robot:
    return Robot.from_name("iiwa14")


def _random_quats(rng: np.random.Generator, k: int) -> np.ndarray:
    q = rng.standard_normal((k, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _exp(phi: np.ndarray) -> np.ndarray:
    theta = np.linalg.norm(phi)
    if theta == 0:
        return np.eye(3)
    return traj.matrix_from_axis_angle(phi / theta, theta)


def _vee(S: np.ndarray) -> np.ndarray:
    return np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]]) / 2


# ---------------------------------------------------------------------- orientation errors
def test_rotvec_error_is_the_axis_angle_of_R_ref_Rt_and_sign_free() -> None:
    rng = np.random.default_rng(0)
    qa, qb = _random_quats(rng, 50), _random_quats(rng, 50)
    phi = osp.rotvec_error(qa, qb)  # batched
    for a, b, p in zip(qa, qb, phi, strict=True):
        R_e = traj.matrix_from_quat(a) @ traj.matrix_from_quat(b).T
        r, theta = traj.axis_angle_from_matrix(R_e)
        np.testing.assert_allclose(p, theta * r, atol=1e-12)
        np.testing.assert_allclose(_exp(p), R_e, atol=1e-12)
    np.testing.assert_allclose(osp.rotvec_error(-qa, qb), phi, atol=1e-14)
    np.testing.assert_allclose(osp.rotvec_error(qa, -qb), phi, atol=1e-14)
    np.testing.assert_allclose(
        osp.orientation_angle(qa, qb), np.linalg.norm(phi, axis=1), atol=1e-12
    )
    assert np.all(np.linalg.norm(phi, axis=1) <= np.pi + 1e-12)


def test_quat_error_is_siciliano_e_O_on_the_short_hemisphere() -> None:
    rng = np.random.default_rng(1)
    for a, b in zip(_random_quats(rng, 30), _random_quats(rng, 30), strict=True):
        e = osp.quat_error(a, b)
        eta_d, eps_d, eta, eps = a[0], a[1:], b[0], b[1:]
        siciliano = eta * eps_d - eta_d * eps - np.cross(eps_d, eps)
        sign = 1.0 if float(a @ b) >= 0 else -1.0  # η_e = Q̄·Q
        np.testing.assert_allclose(e, sign * siciliano, atol=1e-14)
        np.testing.assert_allclose(osp.quat_error(a, -b), e, atol=1e-14)
        theta = np.linalg.norm(osp.rotvec_error(a, b))
        np.testing.assert_allclose(np.linalg.norm(e), np.sin(theta / 2), atol=1e-12)


def test_small_rotation_vector_is_accurate() -> None:
    r = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    for theta in (1e-12, 1e-8, 1e-4):
        quat = traj.quat_from_matrix(traj.matrix_from_axis_angle(r, theta))
        np.testing.assert_allclose(
            osp.rotvec_error(quat, [1, 0, 0, 0]), theta * r, rtol=1e-9, atol=1e-20
        )


def test_continuous_quats_and_align() -> None:
    rng = np.random.default_rng(2)
    R = traj.OrientationInterpolation(
        np.eye(3), traj.matrix_from_axis_angle([0, 0, 1], 3.0), traj.TimingLaw.quintic(1.0)
    )
    quats = traj.quat_from_matrix(R.evaluate(np.linspace(0, 1, 200))[0])
    flipped = quats * rng.choice([-1.0, 1.0], size=(200, 1))
    c = osp.continuous_quats(flipped)
    assert c[0, 0] >= 0
    assert np.all(np.sum(c[1:] * c[:-1], axis=1) > 0)
    np.testing.assert_allclose(np.abs(np.sum(c * quats, axis=1)), 1.0, atol=1e-12)
    a = osp.align_quat(-quats[5], quats[6])
    assert float(a @ quats[6]) > 0


# ---------------------------------------------------------------------- SO(3) Jacobians
@pytest.mark.parametrize("theta", [0.0, 1e-3, 0.049, 0.051, 0.7, 2.0, 3.1])
def test_left_jacobian_against_finite_differences(theta: float) -> None:
    rng = np.random.default_rng(3)
    axis = rng.standard_normal(3)
    phi = theta * axis / np.linalg.norm(axis)
    v = rng.standard_normal(3)
    h = 1e-6
    Rdot = (_exp(phi + h * v) - _exp(phi - h * v)) / (2 * h)
    omega = _vee(Rdot @ _exp(phi).T)  # world-frame angular velocity
    np.testing.assert_allclose(osp.left_jacobian(phi) @ v, omega, atol=1e-8)
    np.testing.assert_allclose(
        osp.left_jacobian_inverse(phi) @ osp.left_jacobian(phi), np.eye(3), atol=1e-12
    )
    # d/dt J_l⁻¹ along φ̇ = v
    D = (osp.left_jacobian_inverse(phi + h * v) - osp.left_jacobian_inverse(phi - h * v)) / (2 * h)
    np.testing.assert_allclose(osp.left_jacobian_inverse_dot(phi, v), D, atol=1e-8)


def test_quat_times_conj_is_quat_mul_with_the_conjugate() -> None:
    """The structure-constant product equals trajectories.quat_mul(q̄, quat_conj(q)) to
    4e-16 (the same four exact products per entry, summed in another order), batched and
    broadcast; skew's matrix-product path equals S(v) x = v × x exactly."""
    rng = np.random.default_rng(9)
    a, b = _random_quats(rng, 64), _random_quats(rng, 64)
    want = traj.quat_mul(a, traj.quat_conj(b))
    np.testing.assert_allclose(osp.quat_times_conj(a, b), want, rtol=0, atol=4e-16)
    broadcast = traj.quat_mul(a[0], traj.quat_conj(b))
    np.testing.assert_allclose(osp.quat_times_conj(a[0], b), broadcast, rtol=0, atol=4e-16)
    v, x = rng.standard_normal((64, 3)), rng.standard_normal((64, 3))
    S = osp.skew(v)
    assert S.shape == (64, 3, 3)
    np.testing.assert_array_equal(S, np.stack([osp.skew(r) for r in v]))
    np.testing.assert_allclose((S @ x[..., None])[..., 0], np.cross(v, x), atol=1e-15)


def test_jacobians_are_batched() -> None:
    rng = np.random.default_rng(4)
    phi, v = rng.standard_normal((5, 3)), rng.standard_normal((5, 3))
    Jb, Db = osp.left_jacobian_inverse(phi), osp.left_jacobian_inverse_dot(phi, v)
    for i in range(5):
        np.testing.assert_allclose(Jb[i], osp.left_jacobian_inverse(phi[i]), atol=1e-15)
        np.testing.assert_allclose(Db[i], osp.left_jacobian_inverse_dot(phi[i], v[i]), atol=1e-15)


def test_pose_error_kinematics_against_finite_differences(robot: Robot) -> None:
    """x̃̇ = ẋ̄_A − J_A q̇ and x̃̈ = ẍ̄_A − J̇_A q̇ − J_A q̈ along q(t) and a moving reference."""
    rng = np.random.default_rng(5)
    q0 = robot.model.key("home").qpos.copy() + rng.uniform(-0.3, 0.3, 7)
    qd0, qdd = rng.uniform(-1, 1, 7), rng.uniform(-2, 2, 7)
    timing = traj.TimingLaw.quintic(2.0)
    circle = traj.Circle([0.5, 0.1, 0.6], 0.1, traj.TimingLaw.quintic(2.0))
    R0 = traj.matrix_from_axis_angle([1, 0, 0], 2.5)  # ~2.5 rad from the arm's frame: large φ
    orient = traj.OrientationInterpolation(
        R0, R0 @ traj.matrix_from_axis_angle([0, 1, 1], 1.0), timing
    )

    def at(t: float) -> osp.PoseErrorKinematics:
        q = q0 + qd0 * t + 0.5 * qdd * t**2
        qd = qd0 + qdd * t
        p, v, a = circle.evaluate(0.7 + t)
        R, w, wd = orient.evaluate(0.7 + t)
        return osp.pose_error_kinematics(
            robot,
            SITE,
            q,
            qd,
            p,
            traj.quat_from_matrix(R),
            np.concatenate((v, w)),
            np.concatenate((a, wd)),
        )

    k0 = at(0.0)
    assert 1.0 < np.linalg.norm(k0.error[3:]) < np.pi  # a large orientation error
    h = 1e-4
    kp, km = at(h), at(-h)
    fd_rate = (kp.error - km.error) / (2 * h)
    fd_acc = (kp.error - 2 * k0.error + km.error) / h**2
    np.testing.assert_allclose(k0.error_rate, fd_rate, atol=1e-7)
    np.testing.assert_allclose(k0.error_rate, k0.ref_rate - k0.J_A @ qd0, atol=1e-12)
    np.testing.assert_allclose(k0.task_acceleration - k0.J_A @ qdd, fd_acc, atol=2e-4)
    fd_rate_dot = (kp.error_rate - km.error_rate) / (2 * h)
    np.testing.assert_allclose(k0.task_acceleration - k0.J_A @ qdd, fd_rate_dot, atol=1e-6)
    np.testing.assert_allclose(k0.twist, robot.jacobian(SITE, q0) @ qd0, atol=1e-12)


def test_jdot_qdot_against_finite_differences(robot: Robot) -> None:
    rng = np.random.default_rng(6)
    q, qd = robot.model.key("home").qpos + rng.uniform(-0.5, 0.5, 7), rng.uniform(-1, 1, 7)
    h = 1e-6
    Jdot = (robot.jacobian(SITE, q + h * qd) - robot.jacobian(SITE, q - h * qd)) / (2 * h)
    np.testing.assert_allclose(robot.jacobian_dot_qdot(SITE, q, qd), Jdot @ qd, atol=1e-7)


# ---------------------------------------------------------------------- task-space dynamics
def _mujoco_qacc(robot: Robot, q: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """MuJoCo's forward dynamics q̈ at (q, q̇ = 0) under τ (no friction in the file)."""
    d = mujoco.MjData(robot.model)
    d.qpos[:] = q
    d.qfrc_applied[:] = tau
    mujoco.mj_forward(robot.model, d)
    return d.qacc.copy()


def test_task_inertia_against_mujoco(robot: Robot) -> None:
    """A task force F, applied as τ = g + Jᵀ F at rest, accelerates the site by ẍ = Λ⁻¹ F."""
    rng = np.random.default_rng(7)
    q = robot.model.key("home").qpos + rng.uniform(-0.4, 0.4, 7)
    J, B = robot.jacobian(SITE, q), robot.inertia(q)
    Lam = osp.task_inertia(J, B)
    F = rng.standard_normal(6)
    xdd = J @ _mujoco_qacc(robot, q, robot.gravity(q) + J.T @ F)
    np.testing.assert_allclose(Lam @ xdd, F, rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(Lam, Lam.T, atol=1e-9)
    # regularised form: (Λ⁻¹ + k² I)⁻¹, bounded by 1/k²
    k = 0.3
    Lk = osp.task_inertia(J, B, damping=k)
    np.testing.assert_allclose(np.linalg.inv(Lk), np.linalg.inv(Lam) + k**2 * np.eye(6), atol=1e-9)
    assert np.max(np.linalg.eigvalsh(Lk)) <= 1 / k**2
    with pytest.raises(ValueError, match="damping"):
        osp.task_inertia(J, B, damping=-1.0)


def test_task_inertia_blows_up_at_the_wrist_singularity_unless_damped(robot: Robot) -> None:
    # the 6 × 7 Jacobian loses rank when A1 ∥ A3 (q2 = 0) and A5 ∥ A7 (q6 = 0) together
    q = robot.model.key("home").qpos.copy()
    q[1] = 0.0
    eig = []
    for q6 in (0.3, 0.03, 0.003):
        q[5] = q6
        J, B = robot.jacobian(SITE, q), robot.inertia(q)
        eig.append(
            (
                np.max(np.linalg.eigvalsh(osp.task_inertia(J, B))),
                np.max(np.linalg.eigvalsh(osp.task_inertia(J, B, damping=0.1))),
            )
        )
    plain, damped = np.array(eig).T
    assert plain[2] > 1e3 * plain[0]  # ~1/σ² growth
    assert np.all(damped <= 100.0 + 1e-9)


def test_dynamically_consistent_inverse_and_null_space(robot: Robot) -> None:
    rng = np.random.default_rng(8)
    q = robot.model.key("home").qpos + rng.uniform(-0.4, 0.4, 7)
    J, B = robot.jacobian(SITE, q), robot.inertia(q)
    Jbar = osp.dynamically_consistent_inverse(J, B)
    np.testing.assert_allclose(J @ Jbar, np.eye(6), atol=1e-9)
    N = osp.null_space_projector(J, Jbar)
    np.testing.assert_allclose(N @ N, N, atol=1e-9)
    np.testing.assert_allclose(J @ np.linalg.solve(B, N.T), 0.0, atol=1e-10)
    # in MuJoCo: a posture torque Nᵀ τ₀ adds no task acceleration
    tau0 = rng.standard_normal(7) * 20
    g = robot.gravity(q)
    a0 = J @ _mujoco_qacc(robot, q, g)
    a1 = J @ _mujoco_qacc(robot, q, g + N.T @ tau0)
    np.testing.assert_allclose(a1, a0, atol=1e-9)
    assert np.linalg.norm(_mujoco_qacc(robot, q, g + N.T @ tau0)) > 1e-2  # it moves the joints
    # the Moore–Penrose projector of velocities: J (I − J†J) = 0
    N_mp = osp.null_space_projector(J, np.linalg.pinv(J))
    np.testing.assert_allclose(J @ N_mp, 0.0, atol=1e-12)


def test_damped_least_squares() -> None:
    rng = np.random.default_rng(9)
    J = rng.standard_normal((4, 6, 7))
    np.testing.assert_allclose(osp.damped_least_squares(J, 0.0), np.linalg.pinv(J), atol=1e-10)
    k = np.array([0.0, 0.1, 1.0, 3.0])
    Js = osp.damped_least_squares(J, k)
    for i in range(4):
        U, s, Vt = np.linalg.svd(J[i], full_matrices=False)
        np.testing.assert_allclose(Js[i], Vt.T @ np.diag(s / (s**2 + k[i] ** 2)) @ U.T, atol=1e-10)
    Jsing = J[0].copy()
    Jsing[5] = Jsing[4]  # rank 5
    assert np.linalg.norm(osp.damped_least_squares(Jsing, 0.1), 2) <= 1 / (2 * 0.1) + 1e-9
    with pytest.raises(ValueError, match="damping"):
        osp.damped_least_squares(J[0], -0.1)


def test_damping_schedule() -> None:
    s = np.array([0.0, 0.05, 0.1, 0.2])
    k = osp.damping_schedule(s, damping=0.2, region=0.1)
    np.testing.assert_allclose(k, [0.2, 0.2 * np.sqrt(0.75), 0.0, 0.0])
    eps = 1e-9  # continuous at the edge of the region
    assert osp.damping_schedule(0.1 - eps, 0.2, 0.1) < 1e-3
    with pytest.raises(ValueError):
        osp.damping_schedule(s, 0.2, 0.0)


def test_single_pose_fast_paths_equal_the_array_paths() -> None:
    """orientation_angle, align_quat and rotvec_from_quat of one quaternion (the envs' and
    controllers' scalar paths) equal the batched array code, also at tiny angles, on the far
    hemisphere and at θ = π: align_quat and rotvec_from_quat bit for bit, orientation_angle to
    2e-15 rad (the array path sums ε_e's four products in BLAS's order, the scalar path in
    the formula's: ε_e's absolute round-off, ~1e-16, moves θ by about twice that)."""
    rng = np.random.default_rng(3)
    ref = _random_quats(rng, 400)
    near = ref + rng.standard_normal((400, 4)) * 10.0 ** rng.uniform(-9, 0, (400, 1))
    near /= np.linalg.norm(near, axis=1, keepdims=True)
    near[::3] *= -1.0  # either sign
    special = np.array([[1.0, 0, 0, 0], [-1.0, 0, 0, 0], [0.0, 1, 0, 0], [1.0, 1e-13, 0, 0]])
    ref, near = np.vstack((ref, special)), np.vstack((near, special[::-1]))
    angle = osp.orientation_angle(ref, near)
    aligned = osp.align_quat(near, ref)
    rotvec = osp.rotvec_from_quat(near)
    for i in range(len(ref)):
        assert abs(osp.orientation_angle(ref[i], near[i]) - angle[i]) <= 2e-15
        assert osp.align_quat(near[i], ref[i]).tobytes() == aligned[i].tobytes()
        assert osp.rotvec_from_quat(near[i]).tobytes() == rotvec[i].tobytes()
    assert osp.quat_angle([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]) == pytest.approx(np.pi)
    with pytest.raises(ValueError, match="damping"):
        osp.damped_least_squares(np.eye(3), -1.0)
    with pytest.raises(ValueError, match="damping"):
        osp.damped_least_squares(np.eye(3), np.nan)
