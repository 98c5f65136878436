"""CartesianTracking-v0's step on its fast path, bit for bit against the reference formulas.

With exact encoders ``step`` computes the errors, the reward and the observation from one
kinematics of the simulator's MjData, in Python floats and preallocated buffers
(``_obs_errors``). What it replaces is still in the env: ``_errors`` (the nominal Robot's
``site_pose``, ``np.linalg.norm``'s dot, ``operational_space.quat_angle``) and ``_obs`` (the
observation of the quantised-encoder path: ``Robot.site_pose``/``jacobian``, ``np.matmul``).
These tests hold the fast path to them with ``np.array_equal``/``==``, not a tolerance, on
this machine's numpy, BLAS and MuJoCo: a rewrite that rounds differently fails here.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from cir_gym.envs.cartesian_tracking import CartesianTrackingEnv

VARIANTS = [{}, {"payload_mass": 3.0}, {"path": "near_singular"}, {"path": "regulation"}]


def _reference_reward(env: CartesianTrackingEnv, a: np.ndarray, a_prev: np.ndarray, info: dict):
    """The reward terms as the docstring writes them (numpy's mean, exp, dot)."""
    e_sq = info["position_error"] ** 2 + (env.orientation_scale * info["orientation_error"]) ** 2
    r_track = -(1.0 - float(np.mean(np.exp(-e_sq / env.error_scales**2))))
    r_torque = -env.torque_weight * float(np.dot(a, a)) / env.n
    r_rate = -env.action_rate_weight * float(np.dot(a - a_prev, a - a_prev)) / env.n
    return r_track, r_torque, r_rate


@pytest.mark.parametrize("kwargs", VARIANTS, ids=lambda kw: ",".join(kw) or "default")
def test_step_errors_reward_and_observation_equal_the_reference_path(kwargs: dict) -> None:
    # no following-error stop: random torques play the whole 300 steps
    env = CartesianTrackingEnv(max_following_error=None, **kwargs)
    env.reset(seed=5)
    rng = np.random.default_rng(5)
    a_prev = np.zeros(env.n)
    qd_seen = []
    for _ in range(300):
        action = rng.uniform(-0.3, 0.3, env.n).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        a = action.astype(float)
        e_pos, e_ang = env._errors(env._k)
        assert info["position_error"] == e_pos
        assert info["orientation_error"] == e_ang
        r_track, r_torque, r_rate = _reference_reward(env, a, a_prev, info)
        assert info["reward_tracking"] == r_track
        assert info["reward_torque"] == r_torque
        assert info["reward_action_rate"] == r_rate
        assert reward == r_track + r_torque + r_rate
        reference = env._obs()
        assert list(obs) == list(reference)
        for key, value in reference.items():
            assert np.array_equal(obs[key], value), key
        assert obs["q"].base is obs["acc_ref"].base  # one buffer per step, views handed out
        qd_seen.append(env.data.qvel[env._da].copy())
        a_prev = a
        assert not (terminated or truncated)
    metrics = env.episode_metrics()
    speed = np.abs(np.array(qd_seen))
    assert metrics["peak_joint_speed"] == float(np.max(speed))
    assert metrics["peak_speed_ratio"] == float(np.max(speed / env.robot.velocity_limit))
    env.close()


def test_a_kept_observation_is_not_overwritten_by_later_steps() -> None:
    env = CartesianTrackingEnv()
    env.reset(seed=0)
    first = env.step(np.zeros(env.n))[0]
    kept = {key: value.copy() for key, value in first.items()}
    for _ in range(5):
        env.step(np.full(env.n, 0.05))
    for key, value in kept.items():
        assert np.array_equal(first[key], value), key


def test_the_orientation_error_ignores_the_sign_of_the_reference_quaternion() -> None:
    """The fast path drops Q_e's scalar part and its sign flip: θ̃ depends only on the squares
    of ε_e and on |Q̄·Q|, so −Q̄ gives the same errors and rewards bit for bit, and the
    observed Q follows Q̄ to its hemisphere."""
    env = CartesianTrackingEnv()
    env.reset(seed=2)
    flipped = copy.deepcopy(env)
    flipped._quat_ref[:] *= -1.0
    rng = np.random.default_rng(2)
    for _ in range(50):
        action = rng.uniform(-0.2, 0.2, env.n)
        obs, reward, _, _, info = env.step(action)
        obs_f, reward_f, _, _, info_f = flipped.step(action)
        assert reward_f == reward
        assert info_f == info
        assert np.array_equal(obs_f["quat_ref"], -obs["quat_ref"])
        assert np.array_equal(obs_f["quat"], -obs["quat"])
        assert float(np.dot(obs["quat"], obs["quat_ref"])) >= 0.0
