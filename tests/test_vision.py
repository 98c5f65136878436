"""cir_gym.vision: projection, interaction matrix, planar pose (chapter 7's science)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cir_gym import trajectories as traj
from cir_gym.vision import (
    MUJOCO_TO_OPTICAL,
    Camera,
    damped_pinv,
    detect_markers,
    interaction_matrix,
    optical_pose,
    planar_pose,
    pose_error,
    project,
    transform_points,
    twist_between,
    visible,
)

CAMERA = Camera.from_fovy(60.0, 640, 480)
SQUARE = np.array([[-0.1, -0.1, 0.0], [0.1, -0.1, 0.0], [0.1, 0.1, 0.0], [-0.1, 0.1, 0.0]])


def _random_pose(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A target pose in front of the camera: tilt ≤ 0.6 rad, any roll, depth 0.5-1.5 m."""
    axis = rng.standard_normal(3)
    R = traj.matrix_from_axis_angle(axis / np.linalg.norm(axis), rng.uniform(0, 0.6))
    R = R @ traj.matrix_from_axis_angle(np.array([0.0, 0.0, 1.0]), rng.uniform(-np.pi, np.pi))
    t = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(0.5, 1.5)])
    return R, t


def _moved(points: np.ndarray, twist: np.ndarray, h: float) -> np.ndarray:
    """Points (fixed in the world) seen from the camera after it moves with a constant twist
    (v, ω) (optical frame) for h seconds: its new pose in its old frame is (exp(h[ω]×), c)
    with c = ∫₀ʰ exp(τ[ω]×) v dτ = h v + h²/2 ω × v + h³/6 ω × (ω × v) + O(h⁴); points map
    by the inverse."""
    v, w = twist[:3], twist[3:]
    R = traj.matrix_from_axis_angle(w / np.linalg.norm(w), np.linalg.norm(w) * h)
    c = h * v + h**2 / 2 * np.cross(w, v) + h**3 / 6 * np.cross(w, np.cross(w, v))
    return (points - c) @ R  # Rᵀ (P − c) row-wise


def test_interaction_matrix_equals_finite_differences_of_the_projection() -> None:
    """ṡ = L (v, ω): central differences of the pixels under a small camera twist."""
    rng = np.random.default_rng(0)
    cam = Camera(640, 480, 500.0, 470.0, 330.0, 250.0)  # f_u ≠ f_v, off-centre
    for _ in range(20):
        R, t = _random_pose(rng)
        P = transform_points(R, t, SQUARE)
        s = project(P, cam)
        L = interaction_matrix(s, P[:, 2], cam)
        twist = rng.standard_normal(6)
        h = 1e-5
        fd = (project(_moved(P, twist, h), cam) - project(_moved(P, twist, -h), cam)) / (2 * h)
        np.testing.assert_allclose(L @ twist, fd.ravel(), rtol=1e-5, atol=1e-4)


def test_interaction_matrix_is_the_notes_form_in_pixels() -> None:
    """With f_u = f_v = λ and x, y relative to the principal point: the notes' L(λ, x, y, Z)."""
    lam = CAMERA.fu
    s = np.array([[400.0, 100.0], [12.0, 470.0]])
    Z = np.array([0.8, 1.7])
    L = interaction_matrix(s, Z, CAMERA)
    for i, ((u, v), z) in enumerate(zip(s, Z, strict=True)):
        x, y = u - CAMERA.cu, v - CAMERA.cv
        notes = np.array([
            [-lam / z, 0, x / z, x * y / lam, -(lam**2 + x**2) / lam, y],
            [0, -lam / z, y / z, (lam**2 + y**2) / lam, -x * y / lam, -x]])
        np.testing.assert_allclose(L[2 * i:2 * i + 2], notes, rtol=1e-12)
    # the rotational part does not depend on the depth; one point leaves a 4-D null space
    np.testing.assert_allclose(interaction_matrix(s, 5.0, CAMERA)[:, 3:], L[:, 3:])
    assert np.linalg.matrix_rank(L[:2]) == 2
    assert np.linalg.matrix_rank(interaction_matrix(project(
        transform_points(np.eye(3), [0, 0, 1], SQUARE), CAMERA), 1.0, CAMERA)) == 6


def test_planar_pose_is_exact_on_noise_free_points() -> None:
    """Four coplanar points → the target pose to 1e-9, from any pose in front of the camera."""
    rng = np.random.default_rng(1)
    cam = Camera(640, 480, 500.0, 470.0, 330.0, 250.0)
    for _ in range(50):
        R, t = _random_pose(rng)
        s = project(transform_points(R, t, SQUARE), cam)
        R_hat, t_hat = planar_pose(SQUARE, s, cam)
        np.testing.assert_allclose(R_hat, R, atol=1e-9)
        np.testing.assert_allclose(t_hat, t, atol=1e-9)


def test_pose_error_and_twist_transform() -> None:
    """pose_error is zero at the desired pose and gives the camera's pose in the desired frame;
    twist_between moves a rigid motion's description between frames."""
    rng = np.random.default_rng(2)
    R_ref, t_ref = _random_pose(rng)
    t_e, tu = pose_error(R_ref, t_ref, R_ref, t_ref)
    np.testing.assert_allclose(np.concatenate((t_e, tu)), 0.0, atol=1e-12)
    # a camera displaced by (R_d, t_d) in the desired frame sees the target at
    # (R_dᵀ R_ref, R_dᵀ (t_ref − t_d))
    R_d = traj.matrix_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.7)
    t_d = np.array([0.1, -0.2, 0.3])
    R, t = R_d.T @ R_ref, R_d.T @ (t_ref - t_d)
    t_e, tu = pose_error(R, t, R_ref, t_ref)
    np.testing.assert_allclose(t_e, t_d, atol=1e-12)
    np.testing.assert_allclose(tu, [0.0, 0.0, 0.7], atol=1e-12)
    # twist_between: point velocities agree
    v_b, w_b = rng.standard_normal(3), rng.standard_normal(3)
    W = twist_between(R_d, t_d)
    v_a, w_a = np.split(W @ np.concatenate((v_b, w_b)), 2)
    p_a = rng.standard_normal(3)  # any point, in frame a
    vel_a = v_a + np.cross(w_a, p_a)  # its velocity from a's description
    p_b = R_d.T @ (p_a - t_d)
    np.testing.assert_allclose(vel_a, R_d @ (v_b + np.cross(w_b, p_b)), atol=1e-12)


def test_mujoco_camera_convention() -> None:
    """A MuJoCo camera looks along its −z with y up: a point ahead projects to the principal
    point, a point above the axis to a smaller row v, right of it to a larger column u."""
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><camera name="c" pos="0 0 1" xyaxes="0 1 0 -1 0 0" fovy="60"/>'
        "</worldbody></mujoco>")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    p, R = optical_pose(data.cam_xpos[0], data.cam_xmat[0])
    cam = Camera.from_model(model, "c", 640, 480)
    mj_axes = data.cam_xmat[0].reshape(3, 3)
    ahead = p - 2.0 * mj_axes[:, 2]
    up = ahead + 0.1 * mj_axes[:, 1]
    right = ahead + 0.1 * mj_axes[:, 0]
    s = project(transform_points(R.T, -R.T @ p, np.array([ahead, up, right])), cam)
    np.testing.assert_allclose(s[0], [cam.cu, cam.cv], atol=1e-9)
    assert s[1, 1] < cam.cv and s[2, 0] > cam.cu
    np.testing.assert_allclose(MUJOCO_TO_OPTICAL @ MUJOCO_TO_OPTICAL, np.eye(3))


def test_bad_inputs_raise() -> None:
    with pytest.raises(ValueError, match="behind"):
        project(np.array([[0.0, 0.0, -1.0]]), CAMERA)
    with pytest.raises(ValueError, match="depth"):
        interaction_matrix(np.zeros((1, 2)), 0.0, CAMERA)
    with pytest.raises(ValueError, match="fovy"):
        Camera.from_fovy(180.0, 640, 480)


_RAY_SCENE = """
<mujoco>
  <worldbody>
    <body name="mount" pos="0 0 0">
      <geom name="housing" type="capsule" fromto="0 0 -0.05 0 0 0.05" size="0.05"/>
    </body>
    <geom name="marker" type="cylinder" pos="0 0 1" size="0.02 0.001"/>
    <body name="blocker" pos="0 0 0.5">
      <joint name="slide" type="slide" axis="1 0 0"/>
      <geom name="wall" type="box" size="0.05 0.05 0.005"/>
    </body>
    <geom name="placeholder" type="box" pos="0 0 0.3" size="0.05 0.05 0.005" group="1"/>
    <geom name="lens_dust" type="sphere" pos="0 0 0.05" size="0.002"/>
  </worldbody>
</mujoco>
"""


def test_visible_is_a_line_of_sight_test() -> None:
    """A wall between the camera and a marker hides it, moved aside it does not; the capsule
    around the camera (culled from inside by the renderer), a group-1 placeholder and a speck
    nearer than the near plane do not hide it."""
    model = mujoco.MjModel.from_xml_string(_RAY_SCENE)
    data = mujoco.MjData(model)
    marker = np.array([model.geom("marker").id])
    mujoco.mj_kinematics(model, data)
    camera = np.zeros(3)
    assert not visible(model, data, camera, marker, near=0.06)[0]  # the wall
    data.qpos[0] = 0.2  # the wall slid aside
    mujoco.mj_kinematics(model, data)
    assert visible(model, data, camera, marker, near=0.06)[0]
    assert not visible(model, data, camera, marker, near=0.0)[0]  # the speck, nearer than 6 cm
    data.qpos[0] = 0.0
    mujoco.mj_kinematics(model, data)
    behind = np.array([0.0, 0.0, 1.5])  # from the far side: no wall in between
    assert visible(model, data, behind, marker, near=0.06)[0]


def test_damped_pinv_is_the_course_damped_least_squares() -> None:
    """A* = Aᵀ (A Aᵀ + μ² I)⁻¹ for a tall and a wide A; μ = 0 is the pseudo-inverse; a rank-
    deficient A's command stays bounded by ‖e‖ / (2μ) and varies smoothly with A."""
    rng = np.random.default_rng(0)
    for shape in ((8, 6), (6, 7)):
        A = rng.standard_normal(shape)
        mu = 0.3
        expected = A.T @ np.linalg.inv(A @ A.T + mu**2 * np.eye(shape[0]))
        np.testing.assert_allclose(damped_pinv(A, mu), expected, atol=1e-12)
        np.testing.assert_allclose(damped_pinv(A, 0.0), np.linalg.pinv(A), atol=1e-12)
    A = rng.standard_normal((8, 6))
    A[:, 5] = A[:, 4]  # exactly rank 5
    e = rng.standard_normal(8)
    nudged = A + 1e-12 * rng.standard_normal(A.shape)
    assert np.linalg.norm(damped_pinv(A, 1.0) @ e) <= np.linalg.norm(e) / 2.0
    np.testing.assert_allclose(damped_pinv(nudged, 1.0) @ e, damped_pinv(A, 1.0) @ e, atol=1e-9)
    assert np.linalg.norm(np.linalg.pinv(nudged) @ e - np.linalg.pinv(A) @ e) > 1.0  # pinv: not
    with pytest.raises(ValueError, match="damping"):
        damped_pinv(A, -1.0)


def test_detect_markers_finds_the_centroids_of_saturated_discs() -> None:
    image = np.full((48, 64, 3), 40, dtype=np.uint8)
    image[10:15, 20:25] = (230, 10, 10)  # red, centre (22, 12)
    image[30:33, 40:44] = (220, 210, 0)  # yellow, centre (41.5, 31)
    image[0:2, 0:1] = (0, 0, 250)  # blue: 2 pixels, below min_pixels
    s, found = detect_markers(image)
    assert found.tolist() == [True, False, False, True]
    np.testing.assert_allclose(s[0], (22.0, 12.0))
    np.testing.assert_allclose(s[3], (41.5, 31.0))
    assert np.isnan(s[1]).all() and np.isnan(s[2]).all()
