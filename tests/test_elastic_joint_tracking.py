"""ElasticJointTracking-v3: the elastic transmission of chapter 4 behaves as modelled."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from cir_gym.baselines.decentralized import MAX_OMEGA_DT

import cir_gym  # noqa: F401  (registers the ids)
from cir_gym import baselines
from cir_gym.motor import average_inertia

ENV = "cir_gym/ElasticJointTracking-v3"


def motor_dofs(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """(qpos, dof) addresses of the hinges motor1..motor7, by name."""
    ids = [model.joint(f"motor{i}").id for i in range(1, 8)]
    return model.jnt_qposadr[ids], model.jnt_dofadr[ids]


@pytest.fixture
def env():
    env = gym.make(ENV, reference="regulation", episode_duration=0.1)
    yield env
    env.close()


def test_reset_preloads_the_springs_so_gravity_torque_holds_the_arm_still(env):
    """θ(0) − q(0) = g(q(0)) / k_el; the motor torque g(q) then balances the springs, which
    balance gravity: one step leaves q̇ and θ̇ at ~0, whereas zero torque lets the arm move."""
    base = env.unwrapped
    obs, _ = env.reset(seed=0)
    q0 = obs["q"]
    g = base.robot.gravity(q0)
    assert np.max(np.abs(g)) > 1.0  # a loaded posture
    np.testing.assert_allclose(obs["q_motor"] - q0, g / base.stiffness, atol=1e-12)
    np.testing.assert_array_equal(obs["qd"], 0.0)
    np.testing.assert_array_equal(obs["qd_motor"], 0.0)
    obs, *_ = env.step(g / base.torque_limit)  # motor torque = gravity (link side)
    assert np.max(np.abs(obs["qd"])) < 1e-6
    assert np.max(np.abs(obs["qd_motor"])) < 1e-6
    np.testing.assert_allclose(obs["q"], q0, atol=1e-8)
    # without the motor torque the springs unload: a visible motion in one step
    env.reset(seed=0)
    obs, *_ = env.step(np.zeros(7))
    assert np.max(np.abs(obs["qd_motor"])) > 1e-2


def test_spring_torque_on_the_link_is_k_el_times_theta_minus_q(env):
    """MuJoCo's tendon spring and damper against τ = k_el (θ − q) + d (θ̇ − q̇) on the link and
    its reaction on the motor, at an arbitrary deflected, moving state."""
    base = env.unwrapped
    env.reset(seed=1)
    model = base.model
    ma, md = motor_dofs(model)
    la, ld = base.robot.qpos_adr, base.robot.dof_adr
    rng = np.random.default_rng(0)
    data = mujoco.MjData(model)
    q = rng.uniform(base.robot.lower, base.robot.upper) * 0.5
    theta = q + rng.uniform(-0.01, 0.01, 7)
    qd, theta_d = rng.uniform(-1, 1, 7), rng.uniform(-1, 1, 7)
    data.qpos[la], data.qpos[ma] = q, theta
    data.qvel[ld], data.qvel[md] = qd, theta_d
    mujoco.mj_forward(model, data)
    k, d = base.stiffness, model.tendon_damping[:7]
    assert np.all(d > 0) and np.all(model.dof_damping == 0)
    np.testing.assert_allclose(data.ten_length[:7], theta - q, atol=1e-12)
    spring = k * (theta - q)
    np.testing.assert_allclose(data.qfrc_spring[ld], spring, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(data.qfrc_spring[md], -spring, rtol=1e-9, atol=1e-9)
    damper = d * (theta_d - qd)
    np.testing.assert_allclose(data.qfrc_passive[ld], spring + damper, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(data.qfrc_passive[md], -(spring + damper), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(data.ten_velocity[:7], theta_d - qd, atol=1e-12)


def test_q_motor_observation_is_the_motor_joint_state(env):
    base = env.unwrapped
    ma, md = motor_dofs(base.model)
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(1)
    for _ in range(5):
        np.testing.assert_array_equal(obs["q_motor"], base.data.qpos[ma])
        np.testing.assert_array_equal(obs["qd_motor"], base.data.qvel[md])
        np.testing.assert_array_equal(obs["q"], base.data.qpos[base.robot.qpos_adr])
        obs, *_ = env.step(rng.uniform(-0.1, 0.1, 7))
    assert not np.allclose(obs["q_motor"], obs["q"])  # two distinct hinges per joint


@pytest.mark.parametrize("name", ["p_pi_cascade", "p_pi_feedforward"])
def test_cascade_speed_bandwidth_is_0_7_omega_z(env, name):
    """ω_z = sqrt(k_el,m / (J_l / n²)) with the motor-side stiffness k_el,m = k_el / n² (the
    env's k_el acts between θ = q_m / n and q) and J_l = B̄_ii; ω_cv = 0.7 ω_z, capped at
    0.25/dt."""
    base = env.unwrapped
    ctx = base.controller_context()
    policy = baselines.make(name, ENV, env=env)
    n = ctx.gear_ratio
    J_l = np.diag(average_inertia(ctx.nominal_robot()))
    k_motor = ctx.extras["stiffness"] / n**2
    omega_z = np.sqrt(k_motor / (J_l / n**2))
    np.testing.assert_allclose(policy.omega_z, omega_z, rtol=1e-12)
    cap = MAX_OMEGA_DT / base.dt
    expected = np.minimum(0.7 * omega_z, cap)
    np.testing.assert_allclose(policy.omega_cv, expected, rtol=1e-12)
    free = 0.7 * omega_z < cap
    assert np.sum(free) >= 4  # most joints use the notes' 0.7 ω_z, not the cap
    np.testing.assert_allclose(policy.omega_cv[free] / omega_z[free], 0.7, rtol=1e-12)
    # the rigid env has no ω_z: the default 80 rad/s
    rigid = baselines.make(name, "cir_gym/JointTracking-v2")
    assert rigid.omega_z is None
    np.testing.assert_allclose(rigid.omega_cv, 80.0)


# ---------------------------------------------------------------------- issue 19
def test_friction_acts_once_on_the_motor_side():
    """v1 applied viscous_friction and coulomb_friction to the motor AND the link hinges."""
    base = gym.make(ENV, viscous_friction=0.7, coulomb_friction=0.4).unwrapped
    m = base.model
    _, motor = motor_dofs(m)
    link = base.robot.dof_adr
    np.testing.assert_allclose(m.dof_damping[motor], 0.7)
    np.testing.assert_allclose(m.dof_frictionloss[motor], 0.4)
    np.testing.assert_allclose(m.dof_damping[link], 0.0)
    np.testing.assert_allclose(m.dof_frictionloss[link], 0.0)
    randomized = gym.make(ENV, randomize=True).unwrapped
    _, info = randomized.reset(seed=0)
    err = info["model_error"]
    np.testing.assert_allclose(randomized.model.dof_damping[motor], err.viscous_friction)
    np.testing.assert_allclose(randomized.model.dof_damping[link], 0.0)


def test_controllers_get_the_nominal_stiffness_and_the_simulator_the_true_one():
    base = gym.make(ENV, stiffness=2000.0, stiffness_scale=0.8).unwrapped
    np.testing.assert_allclose(base.model.tendon_stiffness[:7], 1600.0)
    np.testing.assert_allclose(base.controller_context().extras["stiffness"], 2000.0)
    with pytest.raises(ValueError, match="stiffness_scale"):
        gym.make(ENV, stiffness_scale=0.0)


@pytest.mark.parametrize("name", ["pid", "p_pi_cascade"])
def test_motor_loops_compensate_the_spring_deflection_of_gravity(name):
    """The motor reference θ̄ = q̄ + K̂⁻¹ĝ(q̄) puts the link on q̄; the v1 loops (θ̄ = q̄) left
    the link K⁻¹g(q̄) below it (≈ 0.02 rad on the shoulder at the default stiffness)."""
    kwargs = {"reference": "regulation", "episode_duration": 3.0}
    env = gym.make(ENV, **kwargs)
    policy = baselines.make(name, ENV, env=env)
    obs, _ = env.reset(seed=1)
    state = None
    for k in range(env.unwrapped.max_steps):
        action, state = policy.predict(obs, state, np.array([k == 0]))
        obs, *_ = env.step(action)
    base = env.unwrapped
    sag = np.abs(base._rigid.gravity(obs["q_ref"]) / base.stiffness)
    assert np.max(sag) > 5e-3  # what the v1 loops left
    assert np.max(np.abs(obs["q_ref"] - obs["q"])) < 0.05 * np.max(sag)
    np.testing.assert_allclose(policy.references(obs)[0],
                               obs["q_ref"] + policy.robot.gravity(obs["q_ref"]) / base.stiffness)


def test_stopping_early_never_raises_the_return():
    """A policy that lets the arm fall is stopped by the following-error monitor. v1 charged
    50 for it, so its return (−227 for PPO) beat any controller's (−622); v2 also charges the
    worst reward of every unplayed step, so the stopped return is at most what the same
    episode would score played to the end at the worst step reward, and below the return of
    the same falling arm left to play on."""
    short = {"episode_duration": 0.6}
    stopped = gym.make(ENV, **short)
    base = stopped.unwrapped
    stopped.reset(seed=0)
    rewards, k = [], 0
    while True:
        _, r, terminated, truncated, info = stopped.step(np.zeros(7))
        rewards.append(r)
        k += 1
        if terminated or truncated:
            break
    assert info["following_error_exceeded"] and k < base.max_steps
    unplayed = base.max_steps - k
    weights = base.reward_model
    worst = 1.0 + weights.torque_weight + 4.0 * weights.action_rate_weight
    assert info["reward_following_error"] == pytest.approx(
        -(weights.following_error_penalty + unplayed * worst))
    played_on = gym.make(ENV, max_following_error=None, **short)
    played_on.reset(seed=0)
    total = sum(played_on.step(np.zeros(7))[1] for _ in range(base.max_steps))
    assert sum(rewards) < total
    # at any discount γ: the stop step's loss is at least the discounted worst remainder
    for gamma in (0.9, 0.99, 1.0):
        remainder = sum(gamma**j * worst for j in range(1, unplayed + 1))
        assert -info["reward_following_error"] >= remainder
    # v1's reward (the flag off) is what made stopping pay
    old = gym.make(ENV, charge_unplayed_steps=False, **short)
    old.reset(seed=0)
    old_total = 0.0
    while True:
        _, r, terminated, truncated, _ = old.step(np.zeros(7))
        old_total += r
        if terminated or truncated:
            break
    assert old_total > total
