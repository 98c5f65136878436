"""RedundantIK-v4, RedundantIK7-v5 and the chapter-1 kinematic controllers: theory checks."""

from __future__ import annotations

import ast
import re

import gymnasium as gym
import numpy as np
import pytest
from cir_gym.baselines import kinematic
from cir_gym.baselines.base import InvalidGain
from gymnasium.utils.env_checker import check_env

import cir_gym  # noqa: F401  (registers the environments it knows)
from cir_gym import redundancy, self_motion
from cir_gym.envs import redundant_ik_scene as scene
from cir_gym.envs.base import default_arguments
from cir_gym.envs.redundant_ik import (
    REDUNDANT_IK_ENVIRONMENTS,
    RedundantIK7Env,
    RedundantIKEnv,
)
from cir_gym.envs.redundant_ik_config import MANIPULABILITY_WINDOW
from cir_gym.robot import Robot
from cir_gym.validation import InvalidArgument

ENV = "cir_gym/RedundantIK-v4"
ENV7 = "cir_gym/RedundantIK7-v5"
CONTROLLERS = {cls.name: cls for cls in kinematic.KINEMATIC_CONTROLLERS}


@pytest.fixture(scope="module", autouse=True)
def registered():
    """Register the ids if the package registry does not (yet) hold them."""
    from cir_gym.envs.base import EntryPoint

    for env_id, (cls, _) in REDUNDANT_IK_ENVIRONMENTS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=EntryPoint(cls))


def controller(name: str, env: gym.Env, **gains) -> kinematic.Controller:
    return CONTROLLERS[name](env.unwrapped.controller_context(), **gains)


def rollout(policy, env, seed, steps=None):
    obs, _ = env.reset(seed=seed)
    state, out = None, []
    for k in range(steps or env.unwrapped.max_steps):
        action, state = policy.predict(obs, state, np.array([k == 0]))
        obs, reward, terminated, truncated, info = env.step(action)
        out.append((obs, reward, info))
        if terminated or truncated:
            break
    return out


# ---------------------------------------------------------------------- accuracy
@pytest.mark.parametrize("seed", [0, 2, 3])
def test_clik_tracks_the_planar_path_to_1e_4(seed):
    env = gym.make(ENV)
    steps = rollout(controller("clik", env), env, seed)
    info = steps[-1][2]
    assert not info["joint_limit_violation"]
    assert info["episode_metrics"]["rms_task_error"] <= 1e-4
    assert info["is_success"]


def test_clik_tracks_the_iiwa_pose():
    env = gym.make(ENV7)
    info = rollout(controller("clik", env), env, 0)[-1][2]
    assert info["episode_metrics"]["rms_task_error"] <= 1e-4
    assert info["episode_metrics"]["rms_orientation_error"] <= 1e-3
    assert info["is_success"]


def test_clik_error_decays_as_exp_minus_K_t():
    """ė + K e = 0 ⇒ e(t) = e(0) e^{−Kt}; the discrete loop gives e_k = e(0)(1 − KΔt)^k.

    With K = 20 1/s at 2 kHz (KΔt = 0.01), max_k |(1 − KΔt)^k − e^{−KkΔt}| ≤ KΔt/(2e) ≈ 0.2 %
    of e(0); the path's own O(Δt) tracking error adds < 1e-5 m. Tolerance 1 % of e(0).
    """
    K, e0_norm = 20.0, 0.01
    # a slow lap (20 s) so the reference barely moves during the 0.3 s transient observed
    env = gym.make(ENV, initial_error=e0_norm, control_freq=2000.0, episode_duration=20.0)
    policy = controller("clik", env, K=K)
    obs, _ = env.reset(seed=5)
    e0 = obs["x_ref"] - obs["x"]
    np.testing.assert_allclose(np.linalg.norm(e0), e0_norm, rtol=1e-6)
    errors, state = [], None
    for k in range(600):
        action, state = policy.predict(obs, state, np.array([k == 0]))
        obs, *_ = env.step(action)
        errors.append(obs["x_ref"] - obs["x"])
    t = np.arange(1, len(errors) + 1) * env.unwrapped.dt
    predicted = e0[None] * np.exp(-K * t)[:, None]
    assert np.max(np.abs(np.array(errors) - predicted)) < 0.01 * e0_norm
    wrong = e0[None] * np.exp(-1.3 * K * t)[:, None]  # a 30 % wrong rate is caught
    assert np.max(np.abs(np.array(errors) - wrong)) > 0.03 * e0_norm


def test_open_loop_pseudo_inverse_drifts_and_clik_does_not():
    env = gym.make(ENV)
    open_loop = rollout(controller("pseudo_inverse", env), env, 0)[-1][2]["episode_metrics"]
    closed = rollout(controller("clik", env), env, 0)[-1][2]["episode_metrics"]
    assert open_loop["rms_task_error"] > 10 * closed["rms_task_error"]


# ---------------------------------------------------------------------- null space
@pytest.mark.parametrize("robot_name,site,rows", [("planar3r", "ee", 2), ("iiwa14", "tcp", 6)])
def test_null_space_motion_does_not_move_the_end_effector(robot_name, site, rows):
    robot = Robot.from_name(robot_name)
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.uniform(robot.lower, robot.upper)
        J = robot.jacobian(site, q)[:rows]
        J_pinv = kinematic.pseudo_inverse(J)
        qd0 = rng.normal(size=robot.n)
        assert np.linalg.norm(J @ kinematic.null_space_projector(J, J_pinv) @ qd0) <= 1e-10


def test_null_space_scale_is_the_largest_that_respects_the_velocity_limits():
    rng = np.random.default_rng(0)
    qd_max = np.array([2.0, 1.5, 1.0])
    for _ in range(200):
        qd_task = rng.uniform(-0.9, 0.9) * qd_max * rng.uniform(0, 1, 3)
        qd_null = rng.normal(0, 2, 3)
        s = kinematic.null_space_scale(qd_task, qd_null, qd_max)
        qd = qd_task + s * qd_null
        assert 0.0 <= s <= 1.0 and np.all(np.abs(qd) <= qd_max + 1e-12)
        if s < 1.0:  # maximal: some joint sits exactly at its limit
            assert np.any(np.isclose(np.abs(qd), qd_max, rtol=0, atol=1e-12))
    assert kinematic.null_space_scale(np.array([2.5, 0, 0]), np.ones(3), qd_max) == 0.0


def test_weighted_pseudo_inverse_is_a_generalised_inverse():
    robot = Robot.from_name("iiwa14")
    J = robot.jacobian("tcp", robot.model.key("home").qpos)
    w_inv = np.linspace(0.5, 3.0, 7)
    np.testing.assert_allclose(J @ kinematic.weighted_pseudo_inverse(J, w_inv), np.eye(6),
                               atol=1e-10)


def test_nullspace_raises_the_manipulability_at_equal_task_error():
    env = gym.make(ENV)
    plain = rollout(controller("clik", env), env, 1)[-1][2]["episode_metrics"]
    ns = rollout(controller("clik_nullspace", env), env, 1)[-1][2]["episode_metrics"]
    assert ns["min_manipulability"] > 1.05 * plain["min_manipulability"]
    assert ns["rms_task_error"] < 2e-4


@pytest.mark.parametrize("env_id", [ENV, ENV7])
def test_self_motion_walk_holds_the_task_pose_and_stops_at_the_margin(env_id):
    """walk_self_motion: every point has q's task pose (the walk is internal motion), arc
    lengths step by ``step`` each way, and ``stop`` ends a side before a rejected point."""
    env = gym.make(env_id)
    obs, _ = env.reset(seed=3)
    policy = controller("clik_nullspace", env)
    q, lower, upper = obs["q"], obs["q_lower"], obs["q_upper"]
    p0, R0 = policy.robot.site_pose(policy.site_id, q)

    def restore(x):
        for _ in range(3):
            p, R = policy.robot.site_pose(policy.site_id, x)
            e = (p0 - p)[: policy.pos_dim]
            if policy.task_dim == 6:
                e = np.concatenate((e, redundancy.orientation_error(R0, R)))
            x = x + kinematic.pseudo_inverse(policy.task_jacobian(x)) @ e
        return x

    def stop(_, x):
        return redundancy.joint_limit_margin(x, lower, upper) < 0.1

    points = redundancy.walk_self_motion(q, policy.task_jacobian, restore, stop, np.pi, 0.1)
    arcs = np.array([s for s, _ in points])
    assert arcs[0] == pytest.approx(0.1) and np.any(arcs < 0)
    for side in (arcs[arcs > 0], -arcs[arcs < 0]):
        np.testing.assert_allclose(np.diff(side), 0.1)
    for _, x in points:
        p, R = policy.robot.site_pose(policy.site_id, x)
        np.testing.assert_allclose(p[: policy.pos_dim], p0[: policy.pos_dim], atol=1e-8)
        if policy.task_dim == 6:
            np.testing.assert_allclose(R @ R0.T, np.eye(3), atol=1e-7)
        assert redundancy.joint_limit_margin(x, lower, upper) >= 0.1
    # consecutive postures are about one step of arc apart (a unit-speed walk of the manifold)
    side = np.array([x for s, x in points if s > 0])
    np.testing.assert_allclose(np.linalg.norm(np.diff(side, axis=0), axis=1), 0.1, rtol=0.05)


def test_self_motion_search_leaves_the_local_maximum_the_gradient_stops_at():
    """RedundantIK7-v3 seed 1 starts on a plateau of w along the self-motion (a local
    maximum, the best postures ≈ 3 rad of arc away): the projected gradient alone
    (search_arc = 0) cannot improve on clik there; the self-motion search does, and its
    target is more manipulable than the start, inside the search margin, on the same pose."""
    env = gym.make(ENV7)
    plain = rollout(controller("clik", env), env, 1)[-1][2]["episode_metrics"]
    local = rollout(controller("clik_nullspace", env, search_arc=0.0), env, 1)[-1][2]
    ns = rollout(controller("clik_nullspace", env), env, 1)[-1][2]["episode_metrics"]
    assert local["episode_metrics"]["min_manipulability"] < 1.05 * plain["min_manipulability"]
    assert ns["min_manipulability"] > 1.15 * plain["min_manipulability"]
    assert ns["rms_task_error"] < 2e-4

    obs, _ = env.reset(seed=1)
    policy = controller("clik_nullspace", env)
    s_target, v = policy.self_motion_search(obs["q"], obs["q_lower"], obs["q_upper"])
    assert abs(s_target) > 1.0
    assert abs(np.linalg.norm(v) - 1) < 1e-12
    np.testing.assert_allclose(policy.task_jacobian(obs["q"]) @ v, 0.0, atol=1e-12)


@pytest.mark.parametrize(("gain", "value"), [("search_arc", -1.0), ("search_period", 0)])
def test_self_motion_search_gains_are_checked(gain, value):
    env = gym.make(ENV)
    with pytest.raises(InvalidGain, match=gain):
        controller("clik_nullspace", env, **{gain: value})


def test_saturation_in_the_null_space_holds_the_joint_and_keeps_the_task():
    """saturate_joint_limits: a joint beyond its bound is held at it and the other six
    still give J q̇ = v exactly where they can (random iiwa postures; without joint j the arm
    may be singular, e.g. joints 1 and 3 aligned); within bounds, q̇ is untouched."""
    robot = Robot.from_name("iiwa14")
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.uniform(-1.5, 1.5, 7)
        J = robot.jacobian("tcp", q)
        v = rng.normal(size=6)
        qd = kinematic.pseudo_inverse(J) @ v
        wide = np.full(7, 1e3)
        np.testing.assert_array_equal(kinematic.saturate_joint_limits(J, v, qd, -wide, wide), qd)
        j = int(rng.integers(7))
        upper = wide.copy()
        upper[j] = qd[j] - 0.5  # joint j must give up 0.5 rad/s
        out = kinematic.saturate_joint_limits(J, v, qd, -wide, upper)
        assert out[j] == pytest.approx(upper[j])
        if np.linalg.svd(np.delete(J, j, axis=1), compute_uv=False)[-1] > 1e-3:
            np.testing.assert_allclose(J @ out, v, atol=1e-8)


def test_nullspace_holds_the_joint_limit_clik_runs_into():
    """RedundantIK-v4 "joint_limits", seed 1: clik ends the episode at the narrowed joint's
    limit; clik_nullspace finishes the lap inside the limits."""
    env = gym.make(ENV, objective="joint_limits")
    plain = rollout(controller("clik", env), env, 1)
    ns = rollout(controller("clik_nullspace", env), env, 1)
    assert plain[-1][2]["episode_metrics"]["min_joint_limit_margin"] <= 0
    assert len(ns) == env.unwrapped.max_steps
    assert ns[-1][2]["episode_metrics"]["min_joint_limit_margin"] > 0


# ---------------------------------------------------------------------- singularities
def _stretched_observation(env: gym.Env) -> dict:
    """An observation at q = 0 (planar arm stretched: J has rank 1) with a reference move."""
    obs, _ = env.reset(seed=0)
    obs = {k: v.copy() for k, v in obs.items()}
    obs["q"] = np.zeros(3)
    obs["x"] = np.array([1.2, 0.0])
    obs["x_ref"] = np.array([1.19, 0.01])
    obs["xd_ref"] = np.array([-0.1, 0.1])
    return obs


@pytest.mark.parametrize("env_id", [ENV, ENV7])
def test_projected_gradient_is_the_textbook_law(env_id):
    """clik_projected_gradient: q̇ = J†(x̄̇ + K e) + (I − J†J) k₀ ∇w with ∇w of w = sqrt(det JJᵀ)
    (finite differences here), nothing else; clik_nullspace ascends ∇ ln w plus its barrier."""
    env = gym.make(env_id, episode_duration=0.5)
    obs, _ = env.reset(seed=0)
    policy = controller("clik_projected_gradient", env)
    q, n = obs["q"], env.unwrapped.n
    J = policy.task_jacobian(q)
    v = policy.reference_velocity(obs) + 50.0 * policy.task_error(obs)
    qd = policy.control(obs, np.zeros(0))
    np.testing.assert_allclose(J @ qd, v, atol=1e-9)  # the task, untouched by the null space

    def w(x):
        return redundancy.manipulability(policy.task_jacobian(x))

    h = 1e-6
    grad = np.array([(w(q + h * e) - w(q - h * e)) / (2 * h) for e in np.eye(n)])
    J_pinv = np.linalg.pinv(J)
    np.testing.assert_allclose(qd - J_pinv @ v, (np.eye(n) - J_pinv @ J) @ (30.0 * grad),
                               rtol=1e-6, atol=1e-9)
    enhanced = controller("clik_nullspace", env, search_arc=0.0)
    np.testing.assert_allclose(enhanced.objective_gradient(obs) - enhanced.limit_barrier(obs),
                               20.0 * grad / w(q), rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_controllers_never_return_nan_at_the_stretched_arm(name):
    env = gym.make(ENV)
    obs = _stretched_observation(env)
    policy = controller(name, env)
    if name in ("clik", "pseudo_inverse", "clik_weighted", "clik_nullspace",
                "clik_projected_gradient"):
        with pytest.raises(kinematic.SingularJacobian, match="singular"):
            policy.predict(obs)
        return
    action, _ = policy.predict(obs)
    assert np.all(np.isfinite(action))
    if name == "clik_dls":
        qd = policy.control(obs, np.zeros(0))
        v = obs["xd_ref"] + policy.gains.K * (obs["x_ref"] - obs["x"])
        assert np.linalg.norm(qd) <= np.linalg.norm(v) / (2 * policy.gains.damping) + 1e-9


@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_controllers_raise_or_stay_finite_at_the_upright_iiwa(name):
    """q = 0: the iiwa stands straight up, axes 1, 3, 5, 7 aligned — J (6×7) loses rank.
    A controller either raises SingularJacobian (documented) or returns a finite action."""
    env = gym.make(ENV7)
    obs, _ = env.reset(seed=0)
    obs = {k: v.copy() for k, v in obs.items()}
    obs["q"] = np.zeros(7)
    obs["x"] = env.unwrapped.kin.pose(obs["q"])[0]
    J = env.unwrapped.kin.jacobian(obs["q"])
    assert np.linalg.svd(J, compute_uv=False)[-1] < 1e-9
    policy = controller(name, env)
    try:
        action, _ = policy.predict(obs)
    except kinematic.SingularJacobian as exc:
        assert "singular" in str(exc)
        return
    assert np.all(np.isfinite(action)) and np.all(np.abs(action) <= 1.0)


def test_augmented_jacobian_reports_its_smallest_singular_value():
    env = gym.make(ENV)
    policy = controller("clik_augmented", env)
    obs, _ = env.reset(seed=0)
    _, state = policy.predict(obs)
    assert 0 < state[0, 1] == policy.last_sigma_min < np.inf


def test_augmented_jacobian_detects_an_algorithmic_singularity_and_stays_finite():
    """Planar arm, constraint c = (1, 1, 1) (the last link's absolute angle): at q2 = 0 the
    wrist point's Jacobian is rank 1 while J (2×3) has full rank, so J_aug = [J; cᵀ] is
    singular although the task is not (an *algorithmic* singularity)."""
    env = gym.make(ENV)
    policy = controller("clik_augmented", env)
    obs, _ = env.reset(seed=0)
    obs = {k: v.copy() for k, v in obs.items()}
    obs["q"] = np.array([0.3, 0.0, 0.8])
    J = env.unwrapped.kin.jacobian(obs["q"])
    assert np.linalg.svd(J, compute_uv=False)[-1] > 0.1  # the task Jacobian is fine
    obs["x"] = env.unwrapped.kin.pose(obs["q"])[0]
    obs["x_ref"] = obs["x"] + np.array([0.01, -0.01])
    action, state = policy.predict(obs)
    assert policy.last_sigma_min < policy.gains.region and policy.singular_steps == 1
    assert state[0, 1] == policy.last_sigma_min
    assert np.all(np.isfinite(action))


# ---------------------------------------------------------------------- env contract
@pytest.mark.parametrize("env_id", [ENV, ENV7])
@pytest.mark.parametrize("objective", ["manipulability", "joint_limits", "obstacle"])
def test_reward_is_the_sum_of_its_terms(env_id, objective):
    short = {} if objective == "obstacle" else {"episode_duration": 0.5}  # a lap to place it
    env = gym.make(env_id, objective=objective, **short)
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(env.unwrapped.max_steps):
        _, reward, terminated, truncated, info = env.step(rng.uniform(-0.3, 0.3, env.unwrapped.n))
        terms = sum(v for k, v in info.items() if k.startswith("reward_"))
        assert reward == pytest.approx(terms, abs=1e-12)
        if terminated or truncated:
            assert "episode_metrics" in info and "is_success" in info
            break


@pytest.mark.parametrize("cls", [RedundantIKEnv, RedundantIK7Env])
def test_check_env_passes(cls):
    check_env(cls(objective="obstacle"), skip_render_check=True)


@pytest.mark.parametrize("cls", [RedundantIKEnv, RedundantIK7Env])
def test_arguments_table_matches_the_signature(cls):
    section = cls.__doc__.split("## Arguments")[1].split("##")[0]
    table = dict(re.findall(r"^\s*\| (\w+) \| ([^|]+) \|", section, flags=re.M))
    defaults = default_arguments(cls)  # the arm's own, then the ones both arms share
    assert set(defaults) == set(table) - {"argument"}
    for name, default in defaults.items():
        assert ast.literal_eval(table[name].strip()) == default, name


def test_joint_limit_is_hard_and_terminates():
    env = gym.make(ENV, objective="joint_limits")
    env.reset(seed=0)
    base = env.unwrapped
    for _ in range(base.max_steps):
        _, _, terminated, _, info = env.step(np.ones(3))
        if terminated:
            break
    assert info["joint_limit_violation"] and terminated
    q = base.joint_positions
    assert np.all(q <= base.upper) and np.any(q == base.upper)


@pytest.mark.parametrize(("env_id", "seed"), [(ENV, 2), (ENV7, 10)])
def test_terminated_episode_is_scored_against_the_reference_it_no_longer_follows(env_id, seed):
    """clik runs the narrowed joint into its limit on these seeds while tracking to < 0.1 mm;
    the arm then stays at (p, R) while x̄(t), R̄(t) move on, and the metrics are those of the
    whole lap with that error (v3 held the last error: the stopped arm scored as tracking)."""
    env = gym.make(env_id, objective="joint_limits")
    steps = rollout(controller("clik", env), env, seed)
    base, info = env.unwrapped, steps[-1][2]
    errors = [step[2]["task_error"] for step in steps]
    rotations = [step[2].get("orientation_error", 0.0) for step in steps]
    k, terminated = len(errors), info["joint_limit_violation"]
    charge = (base.max_steps - k) * base.worst_step_reward()
    assert terminated and k < base.max_steps
    assert info["reward_termination"] == pytest.approx(-(50.0 + charge), rel=1e-12)
    assert not info["is_success"]
    p, R = base.kin.pose(base.joint_positions)  # the stopped arm
    later = range(k + 1, base.max_steps + 1)  # the references it would have followed
    e = np.array(errors + [np.linalg.norm(base.reference.x[j] - p) for j in later])
    metrics = info["episode_metrics"]
    assert metrics["rms_task_error"] == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-12)
    assert metrics["max_task_error"] == pytest.approx(np.max(e), rel=1e-12)
    assert errors[-1] < 1e-4 < 0.01 < metrics["max_task_error"]  # the reference moved on
    if base.task_dim == 6:
        r = np.array(rotations + [
            np.linalg.norm(redundancy.orientation_error(base.reference.R[j], R)) for j in later])
        assert metrics["rms_orientation_error"] == pytest.approx(np.sqrt(np.mean(r**2)),
                                                                 rel=1e-12)
    assert metrics["min_joint_limit_margin"] == 0.0  # the stopped arm sits on its limit


@pytest.mark.parametrize("env_id", [ENV, ENV7])
def test_failing_early_never_raises_the_return(env_id):
    """Driving a joint into its narrowed limit ends the episode within a few steps; with the
    unplayed steps charged (the default) that return is below the one of an arm that stands
    still for the whole lap while the reference runs away. Without the charge the crash paid
    (the previous default). Every step's reward is at least −worst_step_reward(), so no policy
    gains by stopping."""
    def lap_return(action_value, **kwargs):
        env = gym.make(env_id, objective="joint_limits", **kwargs)
        env.reset(seed=0)
        total, steps, done = 0.0, 0, False
        worst = env.unwrapped.worst_step_reward()
        while not done:
            _, reward, terminated, truncated, _ = env.step(
                np.full(env.action_space.shape, action_value))
            if not terminated:
                assert reward >= -worst - 1e-12
            total, steps, done = total + reward, steps + 1, terminated or truncated
        return total, steps, terminated

    still, still_steps, still_stopped = lap_return(0.0)
    crash, crash_steps, crash_stopped = lap_return(1.0)
    assert not still_stopped and crash_stopped and crash_steps < still_steps / 4
    assert crash < still
    free_crash, _, _ = lap_return(1.0, charge_unplayed_steps=False)
    assert free_crash > still  # what the charge prevents


def test_an_obstacle_episode_never_starts_without_an_obstacle(monkeypatch):
    """v3 went on without an obstacle when no draw could be placed (e.g. on short laps, where
    the links cannot sweep past one); now reset raises, naming episode_duration."""
    env = RedundantIKEnv(objective="obstacle", episode_duration=0.5)
    monkeypatch.setattr(scene, "draw_obstacle", lambda *args: (scene.DUMMY_OBSTACLE.copy(), None))
    with pytest.raises(InvalidArgument, match=r"no clearable obstacle.*episode_duration=0.5 s"):
        env.reset(seed=0)


@pytest.mark.parametrize("seed", [4, 6])
def test_iiwa_quaternions_share_one_continuous_hemisphere(seed):
    """quat and quat_ref both take the sign with ⟨Q, Q_home⟩ ≥ 0: along a tracked lap each is
    continuous and they agree. On these seeds R̄(t) crosses w = 0 (the tool points down,
    166° from the world frame), where v3's w ≥ 0 on quat_ref flipped it mid-episode."""
    env = gym.make(ENV7)
    policy = controller("clik", env)
    obs, _ = env.reset(seed=seed)
    quats, refs = [obs["quat"]], [obs["quat_ref"]]
    for _obs, _, _ in rollout(policy, env, seed):
        quats.append(_obs["quat"])
        refs.append(_obs["quat_ref"])
    Q, Q_ref = np.array(quats), np.array(refs)
    home = env.unwrapped._quat_home
    assert np.min(Q_ref[:, 0]) < 0 < np.max(Q_ref[:, 0])  # w changes sign along the lap
    for q in (Q, Q_ref):
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
        assert np.all(q @ home >= 0)
        assert np.min(np.sum(q[1:] * q[:-1], axis=1)) > 0.99  # no sign flip between steps
    assert np.min(np.sum(Q * Q_ref, axis=1)) > 0.999  # tracked: the same quaternion, same sign


def test_each_variant_is_ranked_on_its_own_objective():
    from cir_gym.evaluation import variant_primary_metric

    for cls in (RedundantIKEnv, RedundantIK7Env):
        names = {s.name for s in cls.metric_specs}
        assert set(cls.leaderboard_primary_metrics) == set(cls.leaderboard_variants)
        assert set(cls.leaderboard_primary_metrics.values()) <= names
        assert variant_primary_metric(cls, "manipulability") == "min_manipulability"
        assert variant_primary_metric(cls, "obstacle") == "min_clearance"
        assert variant_primary_metric(cls, "joint limits") == "min_joint_limit_margin"


@pytest.mark.parametrize("env_id", [ENV, ENV7])
def test_every_obstacle_episode_has_an_obstacle_clear_of_the_start(env_id):
    env = gym.make(env_id, objective="obstacle")
    for seed in range(6):
        obs, _ = env.reset(seed=seed)
        assert obs["obstacle"][-1] > 0, seed
        _, _, _, _, info = env.step(np.zeros(env.action_space.shape))
        assert info["clearance"] > 0.0, seed


@pytest.mark.parametrize(("env_id", "seed"), [(ENV, 0), (ENV, 7), (ENV7, 1)])
def test_the_clearing_motion_played_in_the_env_finishes_the_lap_clear_of_the_obstacle(
        env_id, seed):
    """v3: every obstacle comes with a motion that clears it; commanding that motion's
    velocities (within the limits) tracks the whole lap without a collision."""
    env = gym.make(env_id, objective="obstacle")
    env.reset(seed=seed)
    base = env.unwrapped
    path = base.clearing_motion()
    stride = self_motion.LAP_STRIDE
    assert path.shape == (base.max_steps // stride + 1, base.n)
    np.testing.assert_allclose(path[0], base._q0)
    qd = np.diff(path, axis=0) / (stride * base.dt)
    assert np.all(np.abs(qd) <= base.velocity_limit * (1 + 1e-12))
    clearances = []
    for k in range(base.max_steps):
        _, _, terminated, truncated, info = env.step(qd[k // stride] / base.velocity_limit)
        clearances.append(info["clearance"])
        assert not terminated, k
    assert truncated and info["is_success"]
    assert min(clearances) > 0.0
    assert gym.make(env_id).unwrapped.clearing_motion() is None


def test_lap_witness_follows_a_moving_free_interval_only_as_fast_as_the_bound():
    """Nodes 0..N−1 at q = 0.1 i (one joint); the free interval [c(k) − 3, c(k) + 3] moves one
    node per sample: a bound of 0.1 rad per sample follows it, 0.05 does not; a wall that
    closes the interval makes it infeasible."""
    K, N = 30, 60
    q = np.tile((0.1 * np.arange(N))[None, :, None], (K, 1, 1))
    centre = 10 + np.arange(K)
    usable = np.abs(np.arange(N)[None, :] - centre[:, None]) <= 3
    path = redundancy.lap_witness(q, usable, np.array([0.1 + 1e-12]), start=10)
    assert path is not None and path[0] == 10
    assert np.all(usable[np.arange(K), path])
    assert np.all(np.abs(np.diff(q[np.arange(K), path, 0])) <= 0.1 + 1e-12)
    assert redundancy.lap_witness(q, usable, np.array([0.05]), start=10) is None
    closed = usable.copy()
    closed[20] = False
    assert redundancy.lap_witness(q, closed, np.array([0.1 + 1e-12]), start=10) is None
    assert redundancy.lap_witness(q, usable, np.array([0.1 + 1e-12]), start=20) is None


@pytest.mark.parametrize("env_id", [ENV, ENV7])
def test_manipulability_start_is_the_worst_feasible_lap_of_the_self_motion(env_id):
    """v2: q(0) on the path, ≥ START_MARGIN inside the limits, its minimum-norm lap inside the
    limits and no more manipulable than the home-IK solution's (when that lap is feasible)."""
    env = gym.make(env_id)
    base = env.unwrapped
    start = int(MANIPULABILITY_WINDOW * base.max_steps / 10)

    def lap(q):
        motion, w = self_motion.min_norm_motion(base.kin, base.reference, q[None], stride=10)
        inside = np.all(motion >= base.file_lower) and np.all(motion <= base.file_upper)
        return bool(inside), float(np.min(w[start:]))

    for seed in range(4):
        obs, _ = env.reset(seed=seed)
        np.testing.assert_allclose(obs["x"], obs["x_ref"], atol=1e-9)
        q_home = base.kin.solve_ik(base.home.copy(), base.reference.x[0], base.reference.R[0])
        margin = redundancy.joint_limit_margin
        lower, upper = obs["q_lower"], obs["q_upper"]
        assert margin(obs["q"], lower, upper) >= min(
            scene.START_MARGIN, margin(q_home, lower, upper)) - 1e-9
        inside, w_start = lap(obs["q"])
        home_inside, w_home = lap(q_home)
        assert inside
        if home_inside:
            assert w_start <= w_home + 1e-12


def test_unknown_objective_names_the_allowed_ones():
    with pytest.raises(InvalidArgument, match=r"manipulability.*joint_limits.*obstacle"):
        gym.make(ENV, objective="energy")


def test_non_positive_gain_is_rejected():
    env = gym.make(ENV)
    with pytest.raises(InvalidGain, match="K"):
        controller("clik", env, K=0.0)


def test_same_seed_same_episode():
    a, b = gym.make(ENV7, objective="obstacle"), gym.make(ENV7, objective="obstacle")
    oa, _ = a.reset(seed=7)
    ob, _ = b.reset(seed=7)
    for k in oa:
        np.testing.assert_array_equal(oa[k], ob[k])


@pytest.mark.parametrize(("env_id", "objective"), [(ENV7, "obstacle"), (ENV, "joint_limits"),
                                                    (ENV7, "manipulability")])
def test_replay_restarts_the_last_task_exactly(env_id, objective):
    """reset(options={"replay": True}) after an episode gives the first observation, limits and
    obstacle again, and the same actions give the same rewards and errors; a new draw differs."""
    env = gym.make(env_id, objective=objective)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.2, 0.2, (30, env.action_space.shape[0]))

    def play():
        obs, info = env.reset(**kwargs)
        trace = [env.step(a)[1:] for a in actions]
        return obs, info, [(r, i["task_error"]) for r, _, _, i in trace]

    kwargs = {"seed": 5}
    first = play()
    kwargs = {"options": {"replay": True}}
    again = play()
    for a, b in zip(first[:2], again[:2], strict=True):
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    for (ra, ea), (rb, eb) in zip(first[2], again[2], strict=True):
        assert ra == rb and ea == eb
    kwargs = {}
    fresh = play()
    assert not np.array_equal(fresh[0]["x_ref"], first[0]["x_ref"])


def test_replay_options_are_checked():
    env = gym.make(ENV)
    with pytest.raises(InvalidArgument, match="before any task"):
        env.reset(options={"replay": True})
    env.reset(seed=0)
    with pytest.raises(InvalidArgument, match=r"unknown.*'replay'"):
        env.reset(options={"rewind": True})
    with pytest.raises(InvalidArgument, match="takes no seed"):
        env.reset(seed=1, options={"replay": True})
    with pytest.raises(InvalidArgument, match="must be a bool"):
        env.reset(options={"replay": 1})


def test_orientation_error_is_the_rotation_vector():
    from cir_gym.trajectories import matrix_from_axis_angle

    R = matrix_from_axis_angle([1.0, 2.0, 3.0], 0.7)
    axis = np.array([0.0, 0.6, 0.8])
    R_ref = matrix_from_axis_angle(axis, 2.9) @ R
    np.testing.assert_allclose(redundancy.orientation_error(R_ref, R), 2.9 * axis, atol=1e-12)


@pytest.mark.parametrize("env_id", [ENV, ENV7])
def test_row_kinematics_equal_the_robots_row_by_row(env_id):
    """The episode set-up's batched kinematics (mujoco.batch) give Robot.site_pose,
    Robot.jacobian and LinkCapsules.segments, whatever rows a call has (to 1e-12)."""
    base = gym.make(env_id).unwrapped
    kin = base.kin
    rows = self_motion.RowKinematics(base.model, base.robot, kin.site_id, kin.capsules.geom_ids)
    rng = np.random.default_rng(0)
    for count in (9, 1, 12):
        q = base.home + rng.uniform(-1.0, 1.0, (count, base.n))
        poses = rows.evaluate(q)
        for i, qi in enumerate(q):
            p_i, R_i = base.robot.site_pose(kin.site_id, qi)
            J = base.robot.jacobian(kin.site_id, qi)
            close = dict(rtol=0, atol=1e-12)
            np.testing.assert_allclose(poses.p[i], p_i, **close)
            np.testing.assert_allclose(poses.R[i], R_i.ravel(), **close)
            np.testing.assert_allclose(poses.jacp[i], J[:3], **close)
            np.testing.assert_allclose(poses.jacr[i], J[3:], **close)
            mine = kin.capsules.ends(poses.geom_xpos[i], poses.geom_xmat[i])
            for x, y in zip(mine, kin.capsules.segments(base.data), strict=True):
                np.testing.assert_allclose(x, y, **close)


def test_lap_witness_with_precomputed_steps_is_the_same():
    rng = np.random.default_rng(1)
    q = np.cumsum(rng.normal(0.0, 0.05, (40, 30, 2)), axis=0)
    usable = rng.random((40, 30)) < 0.8
    usable[0, 15] = True
    bound = np.array([0.12, 0.12])
    steps = redundancy.lap_steps(q, bound)
    assert np.array_equal(
        redundancy.lap_witness(q, usable, bound, 15, steps=steps),
        redundancy.lap_witness(q, usable, bound, 15),
    )


@pytest.mark.parametrize("cls", [RedundantIKEnv, RedundantIK7Env])
def test_clearance_is_mujocos_sphere_capsule_distance(cls):
    """LinkCapsules.clearance equals MuJoCo's own distance between the obstacle geom and the
    nearest link capsule (mj_geomDistance; the planar arm's obstacle as a sphere in its plane),
    to 1e-9 m, apart or overlapping, wherever the arm is. The capsules' axis is the geom's z
    axis, the third column of MuJoCo's row-major xmat (the third row was off by up to 0.25 m)."""
    import mujoco

    base = cls(objective="obstacle")
    caps, model, data = base.kin.capsules, base.model, base.data
    obstacle = model.geom("obstacle").id
    model.geom_type[obstacle] = mujoco.mjtGeom.mjGEOM_SPHERE
    rng = np.random.default_rng(0)
    for i in range(100):
        base.kin.pose(base.home + rng.uniform(-2.0, 2.0, base.n))
        a, _ = caps.segments(data)
        centre = a[rng.integers(len(a))] + rng.normal(0.0, 0.05, 3)
        centre[2] *= base.pos_dim == 3  # the planar arm's obstacles lie in its plane
        radius = float(rng.uniform(0.01, 0.07))
        model.geom_size[obstacle, 0] = radius
        data.geom_xpos[obstacle] = centre  # the obstacle is a world geom: its pose, set here
        theirs = min(mujoco.mj_geomDistance(model, data, obstacle, int(g), 10.0, None)
                     for g in caps.geom_ids)
        assert caps.clearance(data, centre, radius) == pytest.approx(theirs, abs=1e-9), i


def test_point_segment_distance_is_the_nearest_point_of_the_segment():
    """Against a dense sampling of each segment: the distance is the minimum over its points
    (to the sampling's resolution), with clamping to the end points."""
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    c = rng.normal(size=3)
    s = np.linspace(0.0, 1.0, 20001)[:, None, None]
    sampled = np.min(np.linalg.norm(c - (a + s * (b - a)), axis=-1), axis=0)
    d = redundancy.point_segment_distance(c, a, b)
    assert np.all(d <= sampled + 1e-12)
    np.testing.assert_allclose(d, sampled, atol=1e-6)
