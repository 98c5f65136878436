"""VisualServo(-EyeToHand)-v1 as environments: the episode's rules, misuse, pickling."""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest

import cir_gym  # noqa: F401
from cir_gym import baselines
from cir_gym.envs.visual_servo_base import rotation
from cir_gym.fast_solve import solve

EYE_IN_HAND, EYE_TO_HAND = ENVS = ("cir_gym/VisualServo-v1", "cir_gym/VisualServoEyeToHand-v1")
LAWS = {ENVS[0]: "ibvs", ENVS[1]: "ibvs_eye_to_hand"}


@pytest.mark.parametrize("env_id", ENVS)
def test_a_pickled_env_continues_the_same_episode(env_id: str) -> None:
    env = gym.make(env_id).unwrapped
    obs, _ = env.reset(seed=3)
    policy = baselines.make(LAWS[env_id], env_id, env=env)
    for _ in range(5):
        obs = env.step(policy.predict(obs, None, np.array([True]))[0])[0]
    copy = pickle.loads(pickle.dumps(env))
    for _ in range(20):
        action = policy.predict(obs, None, np.array([True]))[0]
        (obs, r, te, tr, info), (obs_c, r_c, te_c, tr_c, info_c) = env.step(action), copy.step(
            action
        )
        for key in obs:
            np.testing.assert_array_equal(obs[key], obs_c[key])
        assert (r, te, tr, info["feature_error"]) == (r_c, te_c, tr_c, info_c["feature_error"])
    np.testing.assert_array_equal(env._s_true, copy._s_true)


@pytest.mark.parametrize("env_id", ENVS)
def test_step_before_reset_and_after_the_end_raise(env_id: str) -> None:
    env = gym.make(env_id, episode_duration=0.12).unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(env.action_space.shape))
    env.reset(seed=0)
    for _ in range(3):
        _, _, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape))
    assert truncated and not terminated
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(env.action_space.shape))


def test_joint_velocities_are_scaled_down_uniformly_to_the_servo_limits() -> None:
    env = gym.make(ENVS[0]).unwrapped
    env.reset(seed=0)
    qd = np.linspace(-1.0, 1.0, 7)
    limit = env.model.actuator_ctrlrange[:, 1]
    ctrl = env._ctrl(qd * 100.0)
    assert np.max(np.abs(ctrl) / limit) == pytest.approx(1.0)
    np.testing.assert_allclose(ctrl / np.linalg.norm(ctrl), qd / np.linalg.norm(qd))
    np.testing.assert_array_equal(env._ctrl(0.1 * qd), 0.1 * qd)  # inside the limits: as is


@pytest.mark.parametrize("numpy_internals", [True, False])
def test_solve_is_numpy_solve_with_its_errors(numpy_internals, monkeypatch) -> None:
    """cir_gym.fast_solve.solve (the motion interface's damped least squares) gives
    np.linalg.solve's bits and errors for vector and matrix right-hand sides, with numpy's
    internals and in its fallback (another numpy's layout)."""
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


def test_eye_to_hand_marker_hidden_behind_its_plate_is_lost() -> None:
    """The plate turned 97° away from the fixed camera: every marker still projects inside
    the image, but the plate is between the camera and each disc. The ray test reports them
    hidden and the episode ends with the features lost."""
    env = gym.make(EYE_TO_HAND, pixel_noise=0.0).unwrapped
    env.reset(seed=0)
    p_g, R_g = env._goal_pose
    q, _ = env._solve_ik(env.q_goal.copy(), p_g, R_g @ rotation(np.array([1.7, 0.0, 0.0])))
    env._set_state(q)
    p, R = env._moving_pose(q)
    # the discs lie on the plate's +z face: that face is turned away from the camera
    assert R[:, 2] @ (np.asarray(env.camera_position) - p) < 0.0
    _, _, terminated, _, info = env.step(np.zeros(6))
    assert env._in_view(env._s_true)  # every marker inside the image
    assert not info["features_visible"].any()
    assert info["feature_lost"] and terminated and not info["is_success"]


@pytest.mark.parametrize("env_id", ENVS)
def test_every_feature_is_visible_on_the_default_starts_and_ibvs_episodes(env_id: str) -> None:
    env = gym.make(env_id).unwrapped
    policy = baselines.make(LAWS[env_id], env_id, env=env)
    obs, _ = env.reset(seed=1)
    assert env._visible().all()
    for _ in range(50):
        obs, _, _, _, info = env.step(
            policy.predict(obs, None, np.array([True]))[0]
        )
        assert info["features_visible"].all() and not info["feature_lost"]


@pytest.mark.parametrize("charge", [True, False])
def test_failing_early_is_charged_the_worst_reward_of_the_unplayed_steps(charge: bool) -> None:
    """A camera flung sideways loses the features at step k: its last reward holds the
    penalty and, by default, (T − k)(1 + action_weight), the worst reward of the T − k steps
    it did not play (r_features = −1, ‖a‖²/dim = 1), so no early end beats playing on."""
    weight, penalty = 0.2, 0.0
    env = gym.make(EYE_IN_HAND, action_weight=weight, termination_penalty=penalty,
                   charge_unplayed_steps=charge).unwrapped
    env.reset(seed=0)
    total, k = 0.0, 0
    while True:
        _, reward, terminated, truncated, info = env.step(np.array([1.0, 0, 0, 0, 0, 0]))
        total, k = total + reward, k + 1
        if terminated or truncated:
            break
    assert terminated and info["feature_lost"] and k < env.max_steps
    unplayed = (env.max_steps - k) * (1.0 + weight) if charge else 0.0
    assert info["reward_termination"] == pytest.approx(-penalty - unplayed)
    if charge:  # never more than the worst return of the steps it did not play
        assert total <= -(env.max_steps - k) * (1.0 + weight)
    with pytest.raises(ValueError, match="charge_unplayed_steps"):
        gym.make(EYE_IN_HAND, charge_unplayed_steps="yes")


@pytest.mark.parametrize("env_id", ["cir_gym/VisualServo-v1", "cir_gym/VisualServoEyeToHand-v1"])
def test_start_rotation_widens_the_random_start_and_rejects_bad_bounds(env_id):
    """start_rotation=(tilt, spin) bounds the random start's rotation (the default draws spin
    within ±1 rad); (0.3, π) reaches the 90°-180° family; a bad bound names the argument."""
    import gymnasium as gym

    from cir_gym.validation import InvalidArgument

    def spins(**kw):
        env = gym.make(env_id, **kw)
        out = [env.reset(seed=s)[1]["start_offset"][5] for s in range(12)]
        env.close()
        return np.abs(out)

    assert spins().max() <= 1.0
    assert spins(start_rotation=(0.3, np.pi)).max() > 1.6  # beyond 90 degrees
    for bad in [(0.3,), (0.6, 1.0), (0.3, 4.0), "wide"]:
        with pytest.raises(InvalidArgument, match="start_rotation"):
            gym.make(env_id, start_rotation=bad)
