"""The agent-ready variants (cir_gym.envs.agent_ready) and their impedance loop (cir_gym.impedance).

What is protected: Gymnasium's checker passes; an action of zeros holds the arm up (the torque
interface's zero action drops it within 60 steps); the metrics and success are the task's own
for the torques the loop played; every reward is on one scale and failing early never pays;
the impedance law is the chapter-6 law on the nominal model (checked against its formula).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import cir_gym  # noqa: F401  (registers the ids)
from cir_gym.envs.admittance_contact import AdmittanceContactEnv
from cir_gym.envs.agent_ready import (
    STIFFNESS_RANGE,
    AdmittanceContactImpedanceEnv,
    PegInHoleImpedanceEnv,
    move_setpoint,
)
from cir_gym.envs.peg_in_hole import PegInHoleEnv
from cir_gym.impedance import (
    CartesianImpedance,
    ImpedanceGains,
    exp_rotvec,
    log_rotation,
    pose_error,
)
from cir_gym.validation import InvalidArgument

PEG = "cir_gym/PegInHoleImpedance-v0"
CONTACT = "cir_gym/AdmittanceContactImpedance-v1"
IDS = (PEG, CONTACT)
TASK = {PEG: PegInHoleEnv, CONTACT: AdmittanceContactEnv}


def _task_kwargs(env: Any) -> dict[str, Any]:
    """The task arguments of a variant's inner task, for a torque env of the same task."""
    task = env.unwrapped.task
    if isinstance(task, PegInHoleEnv):
        return {"episode_duration": task.max_steps * task.dt}
    return {"episode_duration": task.max_steps * task.dt, "stiffness": task.stiffness,
            "force_ref": task.force_ref}


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_checker_passes(env_id: str) -> None:
    env = gym.make(env_id, episode_duration=0.5)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_registered_episode_lengths_are_a_few_hundred_policy_steps_or_the_tasks() -> None:
    assert gym.spec(PEG).max_episode_steps == 240  # 12 s at 20 Hz
    assert gym.spec(CONTACT).max_episode_steps == 100  # AdmittanceContact's 5 s at 20 Hz


@pytest.mark.parametrize("env_id", IDS)
def test_zero_action_holds_the_arm_up_where_zero_torque_drops_it(env_id: str) -> None:
    """Zeros on the impedance interface: 2 s (40 policy steps) with the tip within 0.1 mm of its
    start and no contact at all. Zeros on the task's torque interface: contact within 60 steps."""
    env = gym.make(env_id, episode_duration=2.0)
    obs, _ = env.reset(seed=3)
    p0, _ = env.unwrapped.impedance.pose(obs["q"])
    for _ in range(40):
        obs, _, terminated, truncated, info = env.step(np.zeros(6))
        assert not terminated
        p, _ = env.unwrapped.impedance.pose(obs["q"])
        assert np.linalg.norm(p - p0) < 1e-4
    assert truncated
    metrics = info["episode_metrics"]
    if env_id == PEG:
        assert metrics["peak_force"] == 0.0 and metrics["final_depth"] < -0.0099
    else:
        assert metrics["max_force"] == 0.0 and metrics["contact_loss"] == 1.0
    torque = TASK[env_id]()
    torque.reset(seed=3)
    touched = False
    for _ in range(60):
        _, _, terminated, _, info = torque.step(np.zeros(7))
        touched = info["contact_force"] > 0.0 or terminated
        if touched:
            break
    assert touched, "the torque interface's zero action no longer drops the arm"


def _played(env: Any) -> list[np.ndarray]:
    """Record the torque actions the variant's loop gives its task (instance attribute)."""
    task = env.unwrapped.task
    played: list[np.ndarray] = []
    step = task.step

    def recording(action: Any) -> Any:
        played.append(np.array(action, dtype=float))
        return step(action)

    task.step = recording
    return played


@pytest.mark.parametrize("env_id", IDS)
def test_metrics_and_success_are_the_tasks_for_the_torques_played(env_id: str) -> None:
    """Replaying the loop's torques on the task's own torque env (same seed, same arguments)
    gives the same episode metrics and success: the variant reports the task's, unchanged."""
    kwargs = {"episode_duration": 1.0} | ({"force_ref": 20.0} if env_id == CONTACT else {})
    env = gym.make(env_id, **kwargs)
    played = _played(env)
    env.reset(seed=7)
    rng = np.random.default_rng(0)
    down = np.r_[0.0, 0.0, -1.0, 0.0, 0.0, 0.0]
    done = False
    while not done:  # press down with some noise: contact on both tasks
        a = np.clip(down + 0.3 * rng.standard_normal(6), -1, 1)
        _, _, terminated, truncated, info = env.step(a)
        done = terminated or truncated
    torque = TASK[env_id](**_task_kwargs(env))
    torque.reset(seed=7)
    for u in played:
        _, _, terminated, truncated, replay = torque.step(u)
    assert terminated or truncated
    assert replay["episode_metrics"] == info["episode_metrics"]
    assert replay["is_success"] == info["is_success"]
    if env_id == CONTACT:
        assert info["episode_metrics"]["contact_loss"] < 1.0  # it touched: not a vacuous match


@pytest.mark.parametrize("env_id", IDS)
def test_rewards_are_on_one_scale(env_id: str) -> None:
    """Every step that does not end the episode: r ∈ [−(1 + w_a), 0], r = Σ reward terms."""
    env = gym.make(env_id, episode_duration=1.0)
    env.reset(seed=2)
    w = env.unwrapped.action_rate_weight
    rng = np.random.default_rng(1)
    for _ in range(20):
        _, r, terminated, truncated, info = env.step(rng.uniform(-1, 1, 6))
        terms = [v for k, v in info.items() if k.startswith("reward_")]
        assert r == pytest.approx(math.fsum(terms), abs=1e-12)
        if terminated or truncated:
            break
        assert -(1.0 + w) - 1e-12 <= r <= 0.0


def _fail_early(env_id: str) -> tuple[float, int, float, Any]:
    """Press down until the (low) force limit stops the episode: (return, steps played, the
    return without the terminal term, the env)."""
    kwargs = {"force_limit": 5.0} if env_id == PEG else {"force_limit": 5.0, "force_ref": 20.0}
    env = gym.make(env_id, **kwargs)
    env.reset(seed=4)
    total, k = 0.0, 0
    while True:
        _, r, terminated, truncated, info = env.step(np.r_[0.0, 0.0, -1.0, 0.0, 0.0, 0.0])
        total += r
        k += 1
        if terminated or truncated:
            break
    assert terminated and info["force_limit_exceeded"] and not info["is_success"]
    return total, k, total - info["reward_failure"], env


@pytest.mark.parametrize("env_id", IDS)
def test_failing_early_never_pays(env_id: str) -> None:
    """A force-limit stop at step k is charged the penalty plus the worst reward of each of the
    T − k unplayed steps: its return is below that of any way of playing the episode out, and
    no terminal term is larger than an episode's worst return plus the penalty."""
    total, k, played, env = _fail_early(env_id)
    base = env.unwrapped
    T, worst = base.max_steps, base.worst_step_reward()
    assert k < T / 2  # early
    assert total == pytest.approx(played - base.failure_penalty - (T - k) * worst)
    # holding still from the start, on the same seed, returns more than failing
    env.reset(seed=4)
    held, done = 0.0, False
    while not done:
        _, r, terminated, truncated, _ = env.step(np.zeros(6))
        held += r
        done = terminated or truncated
    assert not terminated and total < held


def test_success_bonus_is_smaller_than_an_episode() -> None:
    env = PegInHoleImpedanceEnv()
    assert env.success_bonus < env.max_steps * env.worst_step_reward()


def test_setpoint_stays_within_its_offset_of_the_pose() -> None:
    """Pushing the setpoint down into the block for 2 s: never more than max_setpoint_offset
    (1 cm) from the tip, so the static force stays near K_p × 1 cm = 10 N."""
    env = gym.make(PEG, episode_duration=2.0, position_uncertainty=0.0, tilt_uncertainty=0.0,
                   clearance=0.0005)
    env.reset(seed=0)
    base = env.unwrapped
    for _ in range(40):
        obs, _, terminated, truncated, _ = env.step(np.r_[0.3, 0.0, -1.0, 0.0, 0.0, 0.0])
        off = obs["setpoint_offset"]
        assert np.linalg.norm(off[:3]) <= base.max_setpoint_offset + 2e-3  # the arm moved
        if terminated or truncated:
            break


def test_variable_stiffness_sets_the_gains_on_a_log_scale() -> None:
    env = gym.make(PEG, episode_duration=0.5, variable_stiffness=True)
    assert env.action_space.shape == (12,)
    env.reset(seed=0)
    a = np.r_[np.zeros(6), 1.0, -1.0, 0.0, 1.0, -1.0, 0.0]
    obs, *_ = env.step(a)
    (k_lo, k_hi), (r_lo, r_hi) = STIFFNESS_RANGE
    expected = [k_hi, k_lo, math.sqrt(k_lo * k_hi), r_hi, r_lo, math.sqrt(r_lo * r_hi)]
    assert obs["stiffness"] == pytest.approx(expected)
    base = env.unwrapped
    # critical damping of the design inertia diag Λ(q₀)
    assert base.K_d == pytest.approx(2 * np.sqrt(base.K_p * base._m_eff))


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [({"control_freq": 30.0}, "control_freq"), ({"control_freq": 100.0}, "control_freq"),
     ({"episode_duration": 0.07}, "episode_duration"), ({"max_translation": 0.5},
                                                         "max_translation"),
     ({"impedance_stiffness": 1e6}, "impedance_stiffness"),
     ({"variable_stiffness": 1}, "variable_stiffness")],
)
def test_bad_arguments_name_themselves(kwargs: dict[str, Any], name: str) -> None:
    with pytest.raises(InvalidArgument, match=name):
        PegInHoleImpedanceEnv(**kwargs)


def test_impedance_law_is_the_formula_on_the_nominal_model() -> None:
    """τ = Jᵀ(K_p x̃ − K_d J q̇) + g(q) + (I − Jᵀ J̄ᵀ) τ₀, computed here from the robot's own
    J, g, B; at the setpoint and at rest it is the gravity torque alone."""
    env = AdmittanceContactImpedanceEnv(episode_duration=0.5)
    obs, _ = env.reset(seed=0)
    imp: CartesianImpedance = env.impedance
    robot = imp.robot
    rng = np.random.default_rng(5)
    q = obs["q"] + 0.05 * rng.standard_normal(7)
    qd = 0.3 * rng.standard_normal(7)
    p_d = imp.pose(obs["q"])[0] + np.array([0.01, -0.02, 0.005])
    R_d = exp_rotvec(np.array([0.05, 0.0, -0.1])) @ imp.pose(obs["q"])[1]
    tau = imp.torque(q, qd, p_d, R_d)
    J = robot.jacobian(imp.site, q)
    B = robot.inertia(q)
    p, R = imp.pose(q)
    g = imp.gains
    tau0 = g.posture_stiffness * (imp.q_rest - q) - g.posture_damping * qd
    Lam = np.linalg.inv(J @ np.linalg.solve(B, J.T))
    J_bar = np.linalg.solve(B, J.T) @ Lam
    expected = (J.T @ (g.stiffness * pose_error(p_d, R_d, p, R) - g.damping * (J @ qd))
                + robot.gravity(q) + (np.eye(7) - J.T @ J_bar.T) @ tau0)
    assert tau == pytest.approx(expected, rel=1e-9, abs=1e-9)
    p0, R0 = imp.pose(imp.q_rest)
    assert imp.torque(imp.q_rest, np.zeros(7), p0, R0) == pytest.approx(
        robot.gravity(imp.q_rest), abs=1e-9)
    # the tool's weight is in ĝ: a nominal arm without it needs less torque
    bare = CartesianImpedance(env.task_context.nominal_robot(), "tcp", g, imp.q_rest)
    assert not np.allclose(bare.robot.gravity(imp.q_rest), robot.gravity(imp.q_rest))


def test_rotation_helpers_invert() -> None:
    phi = np.array([0.3, -0.2, 0.9])
    R = exp_rotvec(phi)
    assert R @ R.T == pytest.approx(np.eye(3), abs=1e-12)
    assert pose_error(np.zeros(3), R, np.zeros(3), np.eye(3))[3:] == pytest.approx(phi)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-3, 0.5, 2.0, 3.1, math.pi - 1e-4, math.pi - 1e-8])
def test_log_rotation_inverts_exp_on_arrays_at_every_angle(angle: float) -> None:
    """log(exp(φ)) = φ for 20 axes at once ((20, 3) → (20, 3, 3) → (20, 3)), from 0 to within
    1e-8 of π (where log switches to the quaternion): to 1e-12 rad, except that the
    conditioning of the axis near π (∝ 1/sin θ) allows 1e-9 rad there."""
    rng = np.random.default_rng(4)
    axes = rng.standard_normal((20, 3))
    phi = angle * axes / np.linalg.norm(axes, axis=1, keepdims=True)
    R = exp_rotvec(phi)
    assert R.shape == (20, 3, 3)
    tol = 1e-9 if angle > 3.0 else 1e-12
    np.testing.assert_allclose(log_rotation(R), phi, atol=tol)
    np.testing.assert_allclose(log_rotation(R[3]), phi[3], atol=tol)  # one matrix: (3,)


def test_setpoint_moves_are_clamped_row_by_row() -> None:
    """move_setpoint on N setpoints: each row as if alone, within max_offset (m) and
    max_angle (rad) of its pose, the unclamped increments applied exactly."""
    rng = np.random.default_rng(6)
    N = 5
    p, R = rng.uniform(-0.5, 0.5, (N, 3)), exp_rotvec(rng.uniform(-1, 1, (N, 3)))
    p_d = p + 0.004 * rng.standard_normal((N, 3))
    R_d = exp_rotvec(0.05 * rng.standard_normal((N, 3))) @ R
    dx = np.r_[0.0, 1e-3, 0.05, 0.0, 0.2].reshape(N, 1) * np.r_[1, 1, 1, 1, 1, 1.0]
    new_p, new_R = move_setpoint(p_d, R_d, dx, p, R, 0.01, 0.1)
    for i in range(N):
        one_p, one_R = move_setpoint(p_d[i], R_d[i], dx[i], p[i], R[i], 0.01, 0.1)
        np.testing.assert_allclose(new_p[i], one_p, atol=1e-15)
        np.testing.assert_allclose(new_R[i], one_R, atol=1e-15)
    offset = np.linalg.norm(new_p - p, axis=1)
    angle = np.linalg.norm(log_rotation(new_R @ np.swapaxes(R, 1, 2)), axis=1)
    assert np.all(offset <= 0.01 + 1e-15) and np.all(angle <= 0.1 + 1e-12)
    assert offset[2] == pytest.approx(0.01) and angle[4] == pytest.approx(0.1)  # clamped
    np.testing.assert_allclose(new_p[0], p_d[0], atol=1e-15)  # no increment: unchanged


def test_gains_reject_bad_values() -> None:
    with pytest.raises(InvalidArgument, match="stiffness"):
        ImpedanceGains(np.ones(5), np.ones(6))
    with pytest.raises(InvalidArgument, match="damping"):
        ImpedanceGains(np.ones(6), -np.ones(6))
