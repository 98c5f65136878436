"""CartesianTracking-v1 and the operational-space controllers: closed forms and theory."""

from __future__ import annotations

import copy
import warnings
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from cir_gym import baselines
from cir_gym import operational_space as osp
from cir_gym import trajectories as traj
from cir_gym.envs.cartesian_tracking import (
    NEAR_SINGULAR_Q2,
    NEAR_SINGULAR_Q6,
    PATHS,
    CartesianTrackingEnv,
)
from cir_gym.envs.joint_tracking import RANDOM_RANGES
from cir_gym.validation import InvalidArgument

ENV_ID = "cir_gym/CartesianTracking-v1"


def _run(env: CartesianTrackingEnv, policy: Any, seed: int) -> tuple[list[dict], dict]:
    """One episode; returns the observations and the last info."""
    obs, _ = env.reset(seed=seed)
    trace, state, start = [obs], None, np.array([True])
    while True:
        action, state = policy.predict(obs, state, start)
        start = np.array([False])
        obs, _, terminated, truncated, info = env.step(action)
        trace.append(obs)
        if terminated or truncated:
            return trace, info


def _mujoco_qacc(robot: Any, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
    d = mujoco.MjData(robot.model)
    d.qpos[:], d.qvel[:], d.qfrc_applied[:] = q, qd, tau
    mujoco.mj_forward(robot.model, d)
    return d.qacc.copy()


def _mid_episode_obs(path: str = "circle", steps: int = 200, seed: int = 3) -> dict:
    env = CartesianTrackingEnv(path=path)
    policy = baselines.make("os_inverse_dynamics", ENV_ID, env=env)
    obs, _ = env.reset(seed=seed)
    state, start = None, np.array([True])
    for _ in range(steps):
        action, state = policy.predict(obs, state, start)
        start = np.array([False])
        obs, *_ = env.step(action)
    # a pose and velocity error on top, so that every term of the laws matters
    rng = np.random.default_rng(seed)
    obs = {k: v.copy() for k, v in obs.items()}
    obs["qd"] = obs["qd"] + rng.uniform(-0.3, 0.3, 7)
    obs["x_ref"] = obs["x_ref"] + rng.uniform(-0.05, 0.05, 3)
    turn = traj.quat_from_matrix(traj.matrix_from_axis_angle([1.0, 2.0, -1.0], 0.8))
    obs["quat_ref"] = traj.quat_mul(turn, obs["quat_ref"])
    return obs


# ---------------------------------------------------------------------- the environment
@pytest.mark.parametrize("path", PATHS)
def test_every_path_passes_the_gymnasium_checker(path: str) -> None:
    """Every ``path`` (test_conformance checks the leaderboard variants, not this argument)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(ENV_ID, path=path, episode_duration=0.05)
        check_env(env.unwrapped, skip_render_check=True)
        env.close()


def test_bad_path_is_rejected_by_name() -> None:
    with pytest.raises(InvalidArgument, match="path"):
        CartesianTrackingEnv(path="spiral")


@pytest.mark.parametrize("path", ["segment", "circle", "figure_eight", "near_singular"])
def test_reference_is_consistent_and_starts_at_the_arm(path: str) -> None:
    """twist_ref and acc_ref are the derivatives of the pose reference (central differences,
    ω from the quaternions); the arm starts on it at rest; the observation is k(q), J q̇."""
    env = CartesianTrackingEnv(path=path, episode_duration=1.0)
    obs, _ = env.reset(seed=4)
    assert np.linalg.norm(obs["x"] - obs["x_ref"]) < 1e-12
    assert osp.orientation_angle(obs["quat_ref"], obs["quat"]) < 1e-7
    dt = env.dt
    x, Q, tw, acc = env._x_ref, env._quat_ref, env._twist_ref, env._acc_ref
    dQ = (Q[2:] - Q[:-2]) / (2 * dt)
    omega = 2 * traj.quat_mul(dQ, traj.quat_conj(Q[1:-1]))[:, 1:]  # ω = 2 Q̇ ⊗ Q⁻¹
    pairs = [((x[2:] - x[:-2]) / (2 * dt), tw[1:-1, :3]), (omega, tw[1:-1, 3:]),
             ((tw[2:] - tw[:-2]) / (2 * dt), acc[1:-1])]
    for fd, exact in pairs:  # central differences: O(dt²), ~1e-4 of the peak values here
        assert np.max(np.abs(fd - exact)) < 2e-3 * np.max(np.abs(exact))
    assert np.max(np.abs(tw[:, 3:])) > 0.1  # the orientation does move
    if path == "near_singular":
        q = env.data.qpos
        assert q[1] == pytest.approx(NEAR_SINGULAR_Q2) and q[5] == pytest.approx(NEAR_SINGULAR_Q6)


def test_quaternions_share_one_continuous_hemisphere() -> None:
    """quat_ref never flips sign along the episode and quat · quat_ref ≥ 0 at every step,
    even for a reference that turns by more than π in total through w = 0."""
    env = CartesianTrackingEnv(path="segment", episode_duration=0.5)
    obs, _ = env.reset(seed=0)
    refs, quats = [obs["quat_ref"]], [obs["quat"]]
    for _ in range(env.max_steps):
        obs, _, terminated, truncated, _ = env.step(np.zeros(7))
        refs.append(obs["quat_ref"])
        quats.append(obs["quat"])
        if terminated or truncated:
            break
    refs, quats = np.array(refs), np.array(quats)
    assert refs[0, 0] >= 0
    assert np.all(np.sum(refs[1:] * refs[:-1], axis=1) > 0)
    assert np.all(np.sum(quats * refs, axis=1) >= 0)
    flipped = osp.continuous_quats(-np.array([[1, 0, 0, 0], [0, 1, 0, 0], [-1, 0.01, 0, 0]]))
    assert np.all(np.sum(flipped[1:] * flipped[:-1], axis=1) >= 0)


def test_model_errors_reach_the_simulator_only() -> None:
    env = CartesianTrackingEnv(payload_mass=3.0)
    bid = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_BODY, "payload")
    assert env.model.body_mass[bid] == 3.0
    nominal = env.controller_context().nominal_robot()
    assert nominal.model.body_mass[bid] != 3.0
    env = CartesianTrackingEnv(randomize=True)
    _, info = env.reset(seed=1)
    lo, hi = RANDOM_RANGES["payload_mass"]
    assert lo <= info["model_error"].payload_mass <= hi
    assert env.model.body_mass[bid] == pytest.approx(info["model_error"].payload_mass)


def test_a_falling_arm_is_stopped_by_the_following_error_monitor() -> None:
    env = CartesianTrackingEnv(path="circle", episode_duration=2.0)
    env.reset(seed=0)
    for _ in range(env.max_steps):
        _, _, terminated, truncated, info = env.step(np.zeros(7))
        if terminated or truncated:
            break
    assert terminated and info["following_error_exceeded"] and not info["diverged"]
    assert env._k < env.max_steps and info["is_success"] is False
    reward = env.reward_model
    unplayed = env.max_steps - env._k
    assert info["reward_following_error"] == pytest.approx(
        -(reward.following_error_penalty + unplayed * reward.worst_step), rel=1e-15
    )
    metrics = info["episode_metrics"]
    assert metrics["final_position_error"] > env.max_following_error


def _episode_return(env_id: str, policy: Any, seed: int, **kwargs: Any) -> tuple[float, int]:
    """(return, steps) of one episode; ``policy`` None holds a constant +1 torque action."""
    env = gym.make(env_id, max_episode_steps=-1, **kwargs)
    obs, _ = env.reset(seed=seed)
    state, start, total, steps = None, np.array([True]), 0.0, 0
    while True:
        if policy is None:
            action = np.ones(7, dtype=np.float32)
        else:
            action, state = policy.predict(obs, state, start)
            start = np.array([False])
        obs, reward, terminated, truncated, _ = env.step(action)
        total += reward
        steps += 1
        if terminated or truncated:
            env.close()
            return total, steps


def test_failing_early_never_raises_the_return() -> None:
    """A constant +1 torque loses the flange within ~20 steps; charged the worst reward of
    each unplayed step, its return is below a finished os_pd_gravity episode's (without the
    charge it was −64 against −488: failing early paid)."""
    max_steps = CartesianTrackingEnv().max_steps
    failed, steps = _episode_return(ENV_ID, None, 1000)
    assert steps < 0.05 * max_steps
    finished, length = _episode_return(ENV_ID, baselines.make("os_pd_gravity", ENV_ID), 1000)
    assert length == max_steps
    assert failed < finished
    assert failed <= -(max_steps - steps) * CartesianTrackingEnv().reward_model.worst_step
    uncharged, _ = _episode_return(ENV_ID, None, 1000, charge_unplayed_steps=False)
    assert uncharged > finished  # what the charge prevents


# ---------------------------------------------------------------------- the laws, instantly
@pytest.mark.parametrize("name", ["os_inverse_dynamics", "os_khatib"])
def test_closed_loop_is_the_linear_error_dynamics_in_mujoco(name: str) -> None:
    """With the exact model, MuJoCo's q̈ under the law gives x̃̈ = −K_D x̃̇ − K_P x̃ (to 1e-7)
    at a state with large position, orientation (0.8 rad) and velocity errors."""
    obs = _mid_episode_obs()
    env = gym.make(ENV_ID).unwrapped
    policy = baselines.make(name, ENV_ID, env=env)
    state = np.asarray(obs["q"]) + 0.1  # a posture target away from q
    tau = policy.control(obs, state)
    robot = policy.robot
    kin = policy.kinematics(obs)
    assert np.linalg.norm(kin.error[3:]) > 0.5
    qdd = _mujoco_qacc(robot, obs["q"], obs["qd"], tau)
    err_acc = kin.task_acceleration - kin.J_A @ qdd
    g = policy.gains
    expected = -2 * g.zeta * g.omega_n * kin.error_rate - g.omega_n**2 * kin.error
    np.testing.assert_allclose(err_acc, expected, atol=1e-7 * np.max(np.abs(expected)))


def test_khatib_posture_torque_does_not_change_the_task_acceleration() -> None:
    """Adding N_dynᵀ τ₀ changes q̈ but not J_A q̈ (MuJoCo forward dynamics, 1e-9)."""
    obs = _mid_episode_obs()
    env = gym.make(ENV_ID).unwrapped
    policy = baselines.make("os_khatib", ENV_ID, env=env)
    task, posture = policy.torques(obs, np.asarray(obs["q"]) + 0.2)
    assert np.linalg.norm(posture) > 1.0
    robot = policy.robot
    J_A = policy.kinematics(obs).J_A
    qdd_task = _mujoco_qacc(robot, obs["q"], obs["qd"], task)
    qdd_all = _mujoco_qacc(robot, obs["q"], obs["qd"], task + posture)
    assert np.linalg.norm(qdd_all - qdd_task) > 1e-2
    np.testing.assert_allclose(J_A @ qdd_all, J_A @ qdd_task, atol=1e-9)


def test_dls_is_the_plain_law_away_from_singularities_and_bounded_near_them() -> None:
    obs = _mid_episode_obs()
    env = gym.make(ENV_ID).unwrapped
    plain = baselines.make("os_inverse_dynamics", ENV_ID, env=env)
    dls = baselines.make("os_inverse_dynamics_dls", ENV_ID, env=env)
    state = np.asarray(obs["q"]).copy()
    np.testing.assert_array_equal(plain.control(obs, state), dls.control(obs, state))
    J = plain.robot.jacobian("flange", obs["q"])
    q = obs["q"].copy()
    q[1] = q[5] = 1e-4  # A1 ∥ A3 and A5 ∥ A7: the 6 × 7 Jacobian nearly loses rank
    near = {**obs, "q": q}
    J = plain.robot.jacobian("flange", q)
    assert np.linalg.svd(J, compute_uv=False)[-1] < 1e-3
    y_plain = plain.joint_acceleration(near, state)
    y_dls = dls.joint_acceleration(near, state)
    assert np.linalg.norm(y_dls) < 1e-2 * np.linalg.norm(y_plain)


def test_error_follows_the_closed_form_response_from_an_initial_pose_error() -> None:
    """Regulation from rest with a 0.1-0.3 m and 0.3-1.1 rad pose error, exact model:
    x̃(t) = x̃(0) (1 + ω_n t) e^{−ω_n t} (ζ = 1) for position and orientation error vectors,
    to 1 % of the initial error (the 2 ms zero-order hold is the difference)."""
    env = CartesianTrackingEnv(path="regulation", episode_duration=1.0)
    policy = baselines.make("os_inverse_dynamics", ENV_ID, env=env, omega_n=10.0)
    trace, info = _run(env, policy, seed=2)
    assert not info["diverged"]
    err = np.array([np.concatenate((o["x_ref"] - o["x"],
                                    osp.rotvec_error(o["quat_ref"], o["quat"]))) for o in trace])
    t = np.arange(len(trace)) * env.dt
    w = 10.0
    closed = err[0] * ((1 + w * t) * np.exp(-w * t))[:, None]
    assert np.linalg.norm(err[0, :3]) > 0.05 and np.linalg.norm(err[0, 3:]) > 0.3
    for block in (slice(0, 3), slice(3, 6)):
        dev = np.max(np.linalg.norm(err[:, block] - closed[:, block], axis=1))
        assert dev < 0.01 * np.linalg.norm(err[0, block]), dev


def test_os_inverse_dynamics_tracks_the_default_path_on_the_exact_model_short() -> None:
    """The first second of the default 4 s episode (the full claim is the slow test)."""
    env = CartesianTrackingEnv()
    policy = baselines.make("os_inverse_dynamics", ENV_ID, env=env)
    obs, _ = env.reset(seed=0)
    state, start, errors = None, np.array([True]), []
    for _ in range(500):
        action, state = policy.predict(obs, state, start)
        start = np.array([False])
        obs, _, _, _, info = env.step(action)
        errors.append((info["position_error"], info["orientation_error"]))
    rms = np.sqrt(np.mean(np.square(errors), axis=0))
    assert rms[0] <= 1e-4 and rms[1] <= 1e-3


# ---------------------------------------------------------------------- the claims (slow)
@pytest.mark.slow
def test_os_inverse_dynamics_on_the_exact_model_ten_seeds() -> None:
    """≤ 1e-4 m and ≤ 1e-3 rad RMS on the default path, 10 seeds."""
    env = CartesianTrackingEnv()
    policy = baselines.make("os_inverse_dynamics", ENV_ID, env=env)
    for seed in range(10):
        _, info = _run(env, policy, seed)
        m = info["episode_metrics"]
        assert m["position_rms"] <= 1e-4 and m["orientation_rms"] <= 1e-3, (seed, m)


@pytest.mark.slow
def test_os_pd_gravity_converges_from_twenty_random_starts() -> None:
    """Regulation, exact model: 20 of 20 seeds end within 1 mm (and succeed)."""
    env = CartesianTrackingEnv(path="regulation")
    policy = baselines.make("os_pd_gravity", ENV_ID, env=env)
    for seed in range(20):
        _, info = _run(env, policy, seed)
        m = info["episode_metrics"]
        assert m["final_position_error"] <= 1e-3 and info["is_success"], (seed, m)


def test_os_pd_gravity_converges_from_a_random_start_short() -> None:
    env = CartesianTrackingEnv(path="regulation", episode_duration=2.5)
    policy = baselines.make("os_pd_gravity", ENV_ID, env=env)
    _, info = _run(env, policy, seed=1)
    assert info["episode_metrics"]["final_position_error"] <= 1e-3
    assert info["episode_metrics"]["max_position_error"] > 0.05  # not judged on the start
    assert info["is_success"]


@pytest.mark.slow
def test_near_singular_plain_law_overspeeds_and_the_damped_law_does_not() -> None:
    """near_singular under the unknown 3 kg payload: the plain law exceeds the joint-speed
    limits, the damped least squares stays within them, finite throughout."""
    env = CartesianTrackingEnv(path="near_singular", payload_mass=3.0)
    plain = baselines.make("os_inverse_dynamics", ENV_ID, env=env)
    dls = baselines.make("os_inverse_dynamics_dls", ENV_ID, env=env)
    _, info_plain = _run(env, plain, seed=0)
    _, info_dls = _run(env, dls, seed=0)
    assert info_plain["episode_metrics"]["peak_speed_ratio"] > 2.0
    assert info_dls["episode_metrics"]["peak_speed_ratio"] < 1.0
    assert not info_dls["diverged"]


def test_a_path_that_leaves_the_reachable_workspace_is_drawn_again(monkeypatch) -> None:
    """Seed 1001's first draw takes the flange where CLIK's J loses rank (every
    operational-space law saturated on it); the env redraws it, and the exact inverse
    dynamics then tracks the path it gets to 0.1 mm RMS."""
    from cir_gym.envs import cartesian_tracking
    from cir_gym.envs.cartesian_reference import PoseReference, kinematically_feasible
    from cir_gym.evaluation import evaluate

    def feasible(env: CartesianTrackingEnv) -> bool:
        reference = PoseReference(env._x_ref, env._quat_ref, env._twist_ref, env._acc_ref)
        q0 = env.data.qpos[env._qa].copy()
        return kinematically_feasible(env.robot, env._site, reference, q0, env.dt)

    env = gym.make(ENV_ID).unwrapped
    env.reset(seed=1001)
    assert feasible(env)
    kept = env._x_ref.copy()
    with monkeypatch.context() as patch:
        patch.setattr(cartesian_tracking, "kinematically_feasible", lambda *args: True)
        env.reset(seed=1001)
    assert not feasible(env)
    assert not np.array_equal(kept, env._x_ref)
    env.reset(seed=1001)
    np.testing.assert_array_equal(kept, env._x_ref)
    policy = baselines.make("os_inverse_dynamics", ENV_ID)
    episode = evaluate(policy, ENV_ID, 1, 1001).episodes[0]
    assert episode.success and episode.metrics["position_rms"] <= 1e-4


def test_the_observation_is_the_flange_of_the_measured_joints() -> None:
    """x, quat and twist are k(q), Q(q) on Q̄'s hemisphere and J(q) q̇ of the observed q, q̇
    (MuJoCo's kinematics on a fresh MjData), the reference rows Q̄ (w ≥ 0 at the start)."""
    env = gym.make(ENV_ID, payload_mass=3.0).unwrapped
    obs, _ = env.reset(seed=3)
    assert obs["quat_ref"][0] >= 0.0
    rng = np.random.default_rng(0)
    model = env.robot.model
    data = mujoco.MjData(model)
    site = model.site("flange").id
    for _ in range(40):
        obs = env.step(rng.uniform(-0.3, 0.3, env.action_space.shape))[0]
        data.qpos[:] = obs["q"]
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        jac = np.zeros((6, model.nv))
        mujoco.mj_jacSite(model, data, jac[:3], jac[3:], site)
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, data.site_xmat[site])
        quat *= np.sign(quat @ obs["quat_ref"])
        np.testing.assert_allclose(obs["x"], data.site_xpos[site], rtol=0, atol=1e-12)
        np.testing.assert_allclose(obs["quat"], quat, rtol=0, atol=1e-12)
        np.testing.assert_allclose(obs["twist"], jac @ obs["qd"], rtol=0, atol=1e-12)
        assert obs["quat"] @ obs["quat_ref"] >= 0.0
    env.close()


@pytest.mark.parametrize("clone", ["pickle", "deepcopy"])
def test_a_copied_env_resets_and_steps_like_the_original(clone: str) -> None:
    """A pickled or deep-copied env resets and steps as the original (same observations and
    rewards on the same seed and actions)."""
    import copy
    import pickle

    env = gym.make("cir_gym/CartesianTracking-v1").unwrapped
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(3):
        env.step(rng.uniform(-0.2, 0.2, 7))
    other = pickle.loads(pickle.dumps(env)) if clone == "pickle" else copy.deepcopy(env)
    for e in (env, other):
        e.reset(seed=7)
    for _ in range(5):
        a = rng.uniform(-0.2, 0.2, 7)
        (o1, r1, *_), (o2, r2, *_) = env.step(a), other.step(a)
        assert r1 == r2
        for key in o1:
            np.testing.assert_array_equal(o1[key], o2[key], err_msg=key)


# ---------------------------------------------------------------------- the step's numbers
STEP_VARIANTS = [{}, {"payload_mass": 3.0}, {"path": "near_singular"}, {"path": "regulation"}]


@pytest.mark.parametrize("kwargs", STEP_VARIANTS, ids=lambda kw: ",".join(kw) or "default")
def test_step_errors_reward_and_metrics_follow_the_docstring(kwargs: dict) -> None:
    """Each step's errors are ‖p̄ − p‖ and 2 atan2(‖ε_e‖, |η_e|) of the true flange (MuJoCo's
    kinematics on a fresh MjData), its reward terms the docstring's formulas (numpy's mean,
    exp, dot), the speed metrics the true q̇'s. Tolerance 1e-12 relative (1e-15 absolute):
    the same formulas evaluated in another order round differently in the last bits."""
    env = CartesianTrackingEnv(max_following_error=None, **kwargs)  # plays all 300 steps
    env.reset(seed=5)
    model, site = env.robot.model, env.robot.site_id("flange")
    data = mujoco.MjData(model)
    rng = np.random.default_rng(5)
    a_prev, qd_seen = np.zeros(env.n), []
    w = env.reward_model
    for _ in range(300):
        action = rng.uniform(-0.3, 0.3, env.n).astype(np.float32)
        _, reward, terminated, truncated, info = env.step(action)
        data.qpos[:] = env.data.qpos
        mujoco.mj_kinematics(model, data)
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, data.site_xmat[site])
        k = env._k
        e_pos = np.linalg.norm(env._x_ref[k] - data.site_xpos[site])
        e_ang = float(osp.orientation_angle(env._quat_ref[k], quat))
        assert info["position_error"] == pytest.approx(e_pos, rel=1e-12, abs=1e-15)
        assert info["orientation_error"] == pytest.approx(e_ang, rel=1e-12, abs=1e-15)
        a = action.astype(float)
        e_sq = e_pos**2 + (env.orientation_scale * e_ang) ** 2
        r_track = -(1.0 - float(np.mean(np.exp(-e_sq / w.error_scales**2))))
        r_torque = -w.torque_weight * float(np.dot(a, a)) / env.n
        r_rate = -w.action_rate_weight * float(np.dot(a - a_prev, a - a_prev)) / env.n
        assert info["reward_tracking"] == pytest.approx(r_track, rel=1e-12, abs=1e-15)
        assert info["reward_torque"] == pytest.approx(r_torque, rel=1e-12, abs=1e-15)
        assert info["reward_action_rate"] == pytest.approx(r_rate, rel=1e-12, abs=1e-15)
        assert reward == pytest.approx(r_track + r_torque + r_rate, rel=1e-12, abs=1e-15)
        qd_seen.append(env.data.qvel[env._da].copy())
        a_prev = a
        assert not (terminated or truncated)
    metrics = env.episode_metrics()
    speed = np.abs(np.array(qd_seen))
    assert metrics["peak_joint_speed"] == pytest.approx(np.max(speed), rel=1e-12)
    assert metrics["peak_speed_ratio"] == pytest.approx(
        np.max(speed / env.robot.velocity_limit), rel=1e-12
    )
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
    """Q̄ and −Q̄ are the same orientation: the errors and rewards agree (to 1e-12: the
    error angle is computed from |Q̄·Q| and ‖ε_e‖, equal up to rounding), and the observed Q
    follows Q̄ to its hemisphere."""
    env = CartesianTrackingEnv()
    env.reset(seed=2)
    flipped = copy.deepcopy(env)
    flipped._quat_ref[:] *= -1.0
    rng = np.random.default_rng(2)
    for _ in range(50):
        action = rng.uniform(-0.2, 0.2, env.n)
        obs, reward, _, _, info = env.step(action)
        obs_f, reward_f, _, _, info_f = flipped.step(action)
        assert reward_f == pytest.approx(reward, rel=1e-12)
        assert info_f["orientation_error"] == pytest.approx(info["orientation_error"], rel=1e-12)
        assert np.array_equal(obs_f["quat_ref"], -obs["quat_ref"])
        np.testing.assert_allclose(obs_f["quat"], -obs["quat"], rtol=0, atol=1e-15)
        assert float(np.dot(obs["quat"], obs["quat_ref"])) >= 0.0
