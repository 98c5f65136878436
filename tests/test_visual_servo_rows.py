"""The eye-in-hand visual-servoing laws on rows (``RowLaw``: IBVS, PBVS) and cir_gym.vision's
science they use, on rows (N, 4, 2) against one observation (4, 2) at a time.

Two tolerances, two reasons (as tests/test_batched_laws.py):

* a row of a batch against the same observation alone: **bit for bit** (one observation is
  the law's one-row case; every product is a stacked matrix product, SVD or determinant, one
  LAPACK call per row's matrix), so ``evaluate`` may batch these controllers;
* a row against the law written out here with cir_gym.vision's single-case functions
  (``planar_pose``, ``interaction_matrix``, ``damped_pinv``, ``pose_error``): **1e-12 of
  the largest command** (the row law stacks its products where this one multiplies one
  observation's; measured: bit for bit on these observations).
"""

from __future__ import annotations

import numpy as np
import pytest
from lockstep import row, sampled_observations

from cir_gym import baselines, vision
from cir_gym.envs.visual_servo_vector import VisualServoVectorEnv

ENV = "cir_gym/VisualServo-v1"
REL = 1e-12
#: (law, gains, env arguments): every branch of the laws (where L̂ is evaluated, the adaptive
#: gain, the pseudo-inverse, the joint-velocity action through the nominal robot)
LAWS = [
    ("ibvs", {}, {}),
    ("ibvs", {"depth": "mean"}, {}),
    ("ibvs", {"depth": "desired", "adaptive": (4.0, 0.4, 30.0)}, {}),
    ("ibvs", {"damping": 0.0}, {}),
    ("ibvs", {}, {"action": "joint_velocity"}),
    ("pbvs", {}, {}),
    ("pbvs", {"adaptive": (4.0, 0.4, 30.0)}, {"action": "joint_velocity"}),
]


@pytest.fixture(scope="module")
def servo_obs() -> dict[str, np.ndarray]:
    """96 observations of the rotation family with a calibration error: IBVS plus noise on
    16 batched copies (features anywhere in the image, rotations up to 180°), every 4th step."""
    envs = VisualServoVectorEnv(num_envs=16, nthread=1, start_rotation=(0.3, np.pi),
                                camera_error=(0.05, 10.0, 0.01, 0.02), pixel_noise=0.5)
    return sampled_observations(envs, baselines.make("ibvs", ENV))


def _law(name: str, gains: dict, env_kwargs: dict):
    return baselines.make(name, ENV, env_kwargs=env_kwargs, **gains)


@pytest.mark.parametrize("name, gains, env_kwargs", LAWS)
def test_rows_equal_each_row_alone_bit_for_bit(name, gains, env_kwargs, servo_obs) -> None:
    policy = _law(name, gains, env_kwargs)
    assert policy.vectorized
    n = len(servo_obs["q"])
    state = np.zeros((n, 0))
    alone = np.stack([policy.control(row(servo_obs, i), state[i]) for i in range(n)])
    rng = np.random.default_rng(1)
    for count in (1, 3, 16, n):  # batches of any size, rows reordered
        pick = rng.permutation(n)[:count]
        rows = {key: v[pick] for key, v in servo_obs.items()}
        np.testing.assert_array_equal(policy.control_batch(rows, state[pick]), alone[pick])
    actions, _ = policy.predict(servo_obs, None, np.ones(n, dtype=bool))
    np.testing.assert_array_equal(actions, np.stack([policy.predict(row(servo_obs, i))[0]
                                                     for i in range(n)]))


def _course_twist(policy, obs: dict[str, np.ndarray]) -> np.ndarray:
    """The camera twist (6,) of the course's law on one observation, written with
    cir_gym.vision's single-case functions (module docstring of baselines/visual_servo.py)."""
    cam, P, g = policy.camera, policy.model_points, policy.gains
    s, s_ref = obs["features"].reshape(4, 2), obs["features_ref"].reshape(4, 2)

    def lam(size: float) -> float:
        return g.gain if g.adaptive is None else baselines.visual_servo.adaptive_gain(
            size, *g.adaptive)

    if policy.name == "pbvs":
        R, t = vision.planar_pose(P, s, cam)
        R_ref, t_ref = vision.planar_pose(P, s_ref, cam)
        t_e, theta_u = vision.pose_error(R, t, R_ref, t_ref)
        gain = lam(float(np.max(np.abs(np.concatenate((t_e, theta_u))))))
        return np.concatenate((-gain * (R_ref @ R.T).T @ t_e, -gain * theta_u))

    def interaction(x: np.ndarray) -> np.ndarray:
        R, t = vision.planar_pose(P, x, cam)
        Z = np.maximum(vision.transform_points(R, t, P)[:, 2], 1e-3)
        return vision.interaction_matrix(x, Z, cam)

    at = {"current": [s], "desired": [s_ref], "mean": [s, s_ref]}[g.depth]
    L = sum(interaction(x) for x in at) / len(at)
    size = float(np.max(np.abs(vision.normalise(s, cam) - vision.normalise(s_ref, cam))))
    return -lam(size) * vision.damped_pinv(L, g.damping) @ (s - s_ref).ravel()


def _course_command(policy, obs: dict[str, np.ndarray]) -> np.ndarray:
    """The course law's command: the twist, or J⁺ [R v; R ω] (the nominal robot), each
    scaled down uniformly to its limits."""
    twist = _course_twist(policy, obs)
    if policy.context.action_kind == "twist":
        command, limit = twist, policy.twist_limit
    else:
        R = policy.robot.site_pose(policy.site, obs["q"])[1]
        J = policy.robot.jacobian(policy.site, obs["q"])
        command = np.linalg.pinv(J) @ np.concatenate((R @ twist[:3], R @ twist[3:]))
        limit = policy.velocity_limit
    ratio = float(np.max(np.abs(command) / limit))
    return command / ratio if ratio > 1.0 else command


@pytest.mark.parametrize("name, gains, env_kwargs", LAWS)
def test_rows_are_the_course_law(name, gains, env_kwargs, servo_obs) -> None:
    policy = _law(name, gains, env_kwargs)
    n = len(servo_obs["q"])
    got = policy.control_batch(servo_obs, np.zeros((n, 0)))
    want = np.stack([_course_command(policy, row(servo_obs, i)) for i in range(n)])
    scale = np.max(np.abs(want), axis=1, keepdims=True)
    assert np.max(np.abs(got - want) / scale) <= REL
    assert np.ptp(want[:, 0]) > 0.1 * np.max(np.abs(want[:, 0]))  # the rows differ


def test_cir_gym_vision_on_rows_is_each_row_alone(servo_obs) -> None:
    """Pose, homography, normalised coordinates, interaction matrix and damped inverse of
    every observed feature set: the function's row on rows (N, 4, 2) is its result on that
    observation (4, 2) alone."""
    cam = vision.Camera.from_fovy(60.0, 640, 480)
    P = baselines.make("ibvs", ENV).model_points
    s = servo_obs["features"].reshape(-1, 4, 2)
    R, t = vision.planar_pose(P, s, cam)
    H = vision.homography(P[:, :2], vision.normalise(s, cam))
    Z = np.maximum(vision.transform_points(R, t, P)[..., 2], 1e-3)
    L = vision.interaction_matrix(s, Z, cam)
    t_e, theta_u = vision.pose_error(R, t, R[::-1], t[::-1])  # against another row's pose
    for i in range(len(s)):
        R_i, t_i = vision.planar_pose(P, s[i], cam)
        np.testing.assert_allclose(R[i], R_i, rtol=0, atol=REL)
        np.testing.assert_allclose(t[i], t_i, rtol=REL, atol=REL)
        np.testing.assert_allclose(H[i], vision.homography(P[:, :2], vision.normalise(s[i], cam)),
                                   rtol=0, atol=REL)
        L_i = vision.interaction_matrix(s[i], Z[i], cam)
        np.testing.assert_allclose(L[i], L_i, rtol=REL, atol=REL * np.max(np.abs(L_i)))
        for mu in (0.0, 1.0, 30.0):
            np.testing.assert_allclose(vision.damped_pinv(L, mu)[i], vision.damped_pinv(L_i, mu),
                                       rtol=REL, atol=REL / np.min(Z))
        t_e_i, theta_u_i = vision.pose_error(R[i], t[i], R[-1 - i], t[-1 - i])
        np.testing.assert_allclose(t_e[i], t_e_i, rtol=0, atol=REL)
        np.testing.assert_allclose(theta_u[i], theta_u_i, rtol=0, atol=REL)
    with pytest.raises(ValueError, match="depth"):
        vision.interaction_matrix(s, -Z, cam)
    with pytest.raises(ValueError, match="damping"):
        vision.damped_pinv(L, -1.0)
    with pytest.raises(ValueError, match="plane"):
        vision.planar_pose(P + 0.1, s, cam)
