"""VisualServo(-EyeToHand)-v0 and the visual-servoing controllers: theory and anchors."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import cir_gym  # noqa: F401
from cir_gym import baselines
from cir_gym import trajectories as traj
from cir_gym.vision import detect_markers, optical_pose

EYE_IN_HAND = "cir_gym/VisualServo-v1"
EYE_TO_HAND = "cir_gym/VisualServoEyeToHand-v1"


def _rotvec(R: np.ndarray) -> np.ndarray:
    axis, theta = traj.axis_angle_from_matrix(R)
    return axis * theta


def visp_start_offset(t_o: tuple[float, float, float], theta_u_deg: tuple[float, float, float],
                      goal_depth: float = 0.75) -> tuple[float, ...]:
    """start_offset of ViSP's cMo = (t_o, θu) with cdMo = (0, 0, goal_depth, 0, 0, 0):
    c*Mc = c*Mo cMo⁻¹ = (R_oᵀ, (0, 0, d) − R_oᵀ t_o)."""
    tu = np.deg2rad(theta_u_deg)
    R_o = traj.matrix_from_axis_angle(tu / np.linalg.norm(tu), np.linalg.norm(tu))
    t = np.array([0.0, 0.0, goal_depth]) - R_o.T @ np.asarray(t_o)
    return (*t, *_rotvec(R_o.T))


def run(env_id: str, policy: str, seed: int = 0, gains: dict | None = None, **kwargs
        ) -> tuple[dict, list[np.ndarray], gym.Env]:
    """One episode; returns the last info, the observations and the env."""
    env = gym.make(env_id, **kwargs)
    ctrl = baselines.make(policy, env_id, env=env, **(gains or {}))
    obs, _ = env.reset(seed=seed)
    seen, state, start = [obs], None, True
    while True:
        action, state = ctrl.predict(obs, state, np.array([start]))
        start = False
        obs, _, terminated, truncated, info = env.step(action)
        seen.append(obs)
        if terminated or truncated:
            return info, seen, env


def test_exact_interaction_matrix_gives_exponential_decay_and_straight_feature_paths() -> None:
    """IBVS with L at the true depths (noise-free features, exact intrinsics): e(t) =
    e(0) exp(−λ t) within 3 % over 4 s, and every feature moves on a straight line to s*."""
    lam = 0.5
    _, seen, env = run(EYE_IN_HAND, "ibvs", gains={"gain": lam}, pixel_noise=0.0,
                          start_offset=(0.04, -0.03, -0.08, 0.05, -0.04, 0.3),
                          episode_duration=4.0)
    dt = env.unwrapped.dt
    e = np.array([o["features"] - o["features_ref"] for o in seen])
    norm = np.linalg.norm(e, axis=1)
    t = np.arange(len(norm)) * dt
    np.testing.assert_allclose(norm / norm[0], np.exp(-lam * t), rtol=0.03, atol=1e-3)
    # straight lines: the error keeps its direction
    cos = e @ e[0] / (norm * norm[0])
    assert np.min(cos[t < 3.0]) > 0.999


def test_convergence_time_of_a_failed_episode_is_the_duration_and_flagged_censored() -> None:
    """A camera that never moves does not converge: its convergence_time is the episode's
    duration (a limit, not a measurement), and the metric's spec says so, so the leaderboard
    prints no factor of it between policies that fail (MetricSpec.failure_scores_limit)."""
    env = gym.make(EYE_IN_HAND, episode_duration=1.0)
    env.reset(seed=0)
    while True:
        _, _, terminated, truncated, info = env.step(np.zeros(env.action_space.shape))
        if terminated or truncated:
            break
    assert not info["is_success"]
    base = env.unwrapped
    assert info["episode_metrics"]["convergence_time"] == pytest.approx(base.max_steps * base.dt)
    specs = {s.name: s for s in base.metric_specs}
    assert specs["convergence_time"].failure_scores_limit
    assert not specs["final_feature_error"].failure_scores_limit  # measured in every episode


def test_visp_tutorial_ibvs_4pts_configuration_converges() -> None:
    """ViSP tutorial-ibvs-4pts: a 0.2 m square, desired camera 0.75 m in front, start at
    (0.15, −0.1, 1.0) m and θu = (10°, −10°, 50°), λ = 0.5, L at the current features: the
    features converge below 1 px (ViSP's stop: squared normalised error < 1e-4)."""
    offset = visp_start_offset((0.15, -0.1, 1.0), (10.0, -10.0, 50.0))
    info, seen, env = run(EYE_IN_HAND, "ibvs", gains={"gain": 0.5}, start_offset=offset,
                          pixel_noise=0.0)
    assert info["is_success"], info["episode_metrics"]
    cam = env.unwrapped.nominal_camera
    e = (seen[-1]["features"] - seen[-1]["features_ref"]).reshape(4, 2) / cam.fu
    assert float(np.sum(e**2)) < 1e-4


def test_corke_rotation_about_the_optical_axis() -> None:
    """Corke's ~115° rotation about the optical axis: IBVS backs the camera up along its axis
    (Chaumette's camera retreat; 0.66 m in free space by the same law, more than the arm's
    0.28 m of room, so joint 4 reaches its limit); PBVS rotates in place and converges. At 75°
    the IBVS retreat fits and IBVS converges."""
    offset = (0, 0, 0, 0, 0, np.deg2rad(115))
    ibvs, _, _ = run(EYE_IN_HAND, "ibvs", start_offset=offset, pixel_noise=0.0)
    assert ibvs["joint_limit"] and ibvs["episode_metrics"]["retreat"] > 0.25, ibvs
    pbvs, _, _ = run(EYE_IN_HAND, "pbvs", start_offset=offset, pixel_noise=0.0)
    assert pbvs["is_success"] and pbvs["episode_metrics"]["retreat"] < 0.005, pbvs
    ibvs, _, _ = run(EYE_IN_HAND, "ibvs", start_offset=(0, 0, 0, 0, 0, np.deg2rad(75)),
                     pixel_noise=0.0)
    assert ibvs["is_success"] and ibvs["episode_metrics"]["retreat"] > 0.1, ibvs


def test_ibvs_fails_at_180_degrees_where_pbvs_converges() -> None:
    """At 180° about the optical axis IBVS only retreats (the rotation is in the null space
    of its command; Chaumette 1998) and never converges; PBVS does."""
    offset = (0, 0, 0, 0, 0, np.pi)
    ibvs, _, _ = run(EYE_IN_HAND, "ibvs", start_offset=offset, pixel_noise=0.0)
    pbvs, _, _ = run(EYE_IN_HAND, "pbvs", start_offset=offset, pixel_noise=0.0)
    assert not ibvs["is_success"]
    assert ibvs["episode_metrics"]["retreat"] > 0.2
    assert pbvs["is_success"], pbvs["episode_metrics"]


def test_pbvs_loses_the_features_where_ibvs_with_the_mean_interaction_matrix_converges(
) -> None:
    """A large translation with a 145° rotation about the optical axis, the target near the
    image border: PBVS's rotation swings the features out of the image (Chaumette &
    Hutchinson 2006); IBVS with L̂ = ½ (L + L*) keeps them in view and converges."""
    offset = (0.2, -0.15, 0.05, 0.0, 0.41, 2.53)
    pbvs, _, _ = run(EYE_IN_HAND, "pbvs", start_offset=offset, pixel_noise=0.0)
    assert pbvs["feature_lost"] and not pbvs["is_success"]
    ibvs, _, _ = run(EYE_IN_HAND, "ibvs", gains={"depth": "mean"}, start_offset=offset,
                     pixel_noise=0.0)
    assert ibvs["is_success"], ibvs["episode_metrics"]


def test_eye_to_hand_ibvs_through_the_robot_jacobian_converges() -> None:
    """The eye-to-hand law with joint velocities through J(q), and with a twist, converge."""
    for action in ("joint_velocity", "twist"):
        info, _, _ = run(EYE_TO_HAND, "ibvs_eye_to_hand", seed=1, action=action)
        assert info["is_success"], (action, info["episode_metrics"])


def test_servo_camera_is_the_flange_camera_without_calibration_error() -> None:
    """The rendering camera sits exactly at flange_cam (and its optical frame is the flange
    frame) when camera_error is zero."""
    env = gym.make(EYE_IN_HAND).unwrapped
    env.reset(seed=3)
    d, m = env.data, env.model
    a, b = m.camera("servo_cam").id, m.camera("flange_cam").id
    np.testing.assert_allclose(d.cam_xpos[a], d.cam_xpos[b], atol=1e-12)
    np.testing.assert_allclose(d.cam_xmat[a], d.cam_xmat[b], atol=1e-12)
    p, R = optical_pose(d.cam_xpos[a], d.cam_xmat[a])
    sid = m.site("flange").id
    np.testing.assert_allclose(R, d.site_xmat[sid].reshape(3, 3), atol=1e-12)
    np.testing.assert_allclose(p, d.site_xpos[sid], atol=1e-12)


def _gl_available() -> bool:
    try:
        mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 16, 16).close()
    except Exception:
        return False
    return True


@pytest.mark.skipif(not _gl_available(), reason="no OpenGL backend")
@pytest.mark.parametrize("env_id", [EYE_IN_HAND, EYE_TO_HAND])
def test_detected_features_match_the_projection(env_id: str) -> None:
    """Colour detection in the rendered image agrees with the exact projection to 0.5 px,
    also with intrinsics and hand-eye errors (MuJoCo renders the true camera)."""
    for error in ((0.0, 0.0, 0.0, 0.0), (0.1, 30.0, 0.02, 0.05)):
        env = gym.make(env_id, features="detected", camera_error=error).unwrapped
        for seed in range(3):
            env.reset(seed=seed)
            env._render_camera()
            s, found = detect_markers(env._image)
            assert found.all()
            assert np.max(np.abs(s - env._s_true)) < 0.5, (error, seed, s - env._s_true)
        env.close()


@pytest.mark.slow
@pytest.mark.skipif(not _gl_available(), reason="no OpenGL backend")
def test_detected_episode_ends_within_1_px_of_the_projected_one() -> None:
    """Same seed, IBVS: the detected-feature episode's final error is within 1 px of the
    projected one's, with no detection failure."""
    finals = {}
    for features in ("projected", "detected"):
        info, _, env = run(EYE_IN_HAND, "ibvs", seed=4, features=features, pixel_noise=0.0,
                           episode_duration=8.0)
        finals[features] = info["episode_metrics"]["final_feature_error"]
        assert info["episode_metrics"]["detection_failures"] == 0
        env.close()
    assert abs(finals["detected"] - finals["projected"]) < 1.0, finals


def test_detected_features_without_gl_name_the_packages(monkeypatch: pytest.MonkeyPatch
                                                        ) -> None:
    """features="detected" renders: without a GL backend the error names the Debian packages."""

    def no_gl(*args: object, **kwargs: object) -> None:
        raise mujoco.FatalError("gladLoadGL error")

    monkeypatch.setattr(mujoco, "Renderer", no_gl)
    env = gym.make(EYE_IN_HAND, features="detected")
    with pytest.raises(RuntimeError, match="libegl1") as exc:
        env.reset(seed=0)
    assert "libosmesa6" in str(exc.value) and "features" in str(exc.value)


def test_unreachable_start_offset_is_an_argument_error() -> None:
    with pytest.raises(ValueError, match="start_offset"):
        gym.make(EYE_IN_HAND, start_offset=(0.9, 0.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="camera_error"):
        gym.make(EYE_IN_HAND, camera_error=(0.9, 0.0, 0.0, 0.0))


def test_ibvs_command_is_continuous_where_the_mean_interaction_matrix_is_singular() -> None:
    """At a rotation of π about the optical axis (s = −s* about the principal point) the mean
    L̂ is singular (smallest singular value ~1e-10 px). The damped least-squares inverse gives
    a command that does not depend on 1e-7 px of feature noise and asks for no turn; the
    pseudo-inverse (damping 0) turns the camera at full speed in a direction the noise picks."""
    env = gym.make(EYE_IN_HAND, pixel_noise=0.0).unwrapped
    obs, _ = env.reset(seed=0)
    cam = env.nominal_camera
    s_ref = obs["features_ref"].reshape(4, 2)
    mirrored = (2.0 * np.array([cam.cu, cam.cv]) - s_ref).ravel()
    rng = np.random.default_rng(0)
    nudged = [mirrored + 1e-7 * rng.standard_normal(8) for _ in range(6)]
    damped = baselines.make("ibvs", EYE_IN_HAND, env=env, depth="mean")
    assert damped.gains.damping == 1.0
    sigma = np.linalg.svd(damped._L(mirrored.reshape(4, 2), s_ref), compute_uv=False)
    assert sigma[-1] < 1e-6 * sigma[0]
    actions = np.array([damped.predict({**obs, "features": f}, None, np.array([True]))[0]
                        for f in nudged])
    assert np.max(np.abs(actions - actions[0])) < 1e-4
    assert np.max(np.abs(actions[:, 5])) < 1e-4  # no turn about the optical axis
    plain = baselines.make("ibvs", EYE_IN_HAND, env=env, depth="mean", damping=0.0)
    turns = [plain.predict({**obs, "features": f}, None, np.array([True]))[0][5] for f in nudged]
    assert max(np.abs(turns)) > 0.5 and min(turns) < 0.0 < max(turns)
