"""JointTracking-v1 and the joint-space controllers of chapters 4 and 5: properties from theory."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import baselines
import cir_gym
from cir_gym.evaluation import evaluate
from cir_gym.robot import ModelError, Robot

ENV = "cir_gym/JointTracking-v1"


def rollout(policy, env, seed, steps=None):
    obs, _ = env.reset(seed=seed)
    state, start, out = None, True, []
    for _ in range(steps or env.unwrapped.max_steps):
        action, state = policy.predict(obs, state, np.array([start]))
        start = False
        obs, reward, terminated, truncated, info = env.step(action)
        out.append((obs, reward, info))
        if terminated or truncated:
            break
    return out, state


def test_computed_torque_exact_model_tracks_to_1e_3():
    policy = baselines.make("computed_torque", ENV)
    result = evaluate(policy, ENV, n_episodes=2, seed=0)
    assert result.summary["rms_error"]["worst"] <= 1e-3
    assert result.success_rate == 1.0


def test_computed_torque_error_follows_closed_form_second_order_dynamics():
    """q̃̈ + K_D q̃̇ + K_P q̃ = 0 with ζ = 1: q̃(t) = q̃(0)(1 + ω t)e^{−ωt} when q̃̇(0) = 0."""
    env = gym.make(ENV, initial_error=0.05, control_freq=1000.0)
    omega = 20.0
    policy = baselines.make("computed_torque", ENV, env=env, omega_n=omega, zeta=1.0)
    obs, _ = env.reset(seed=3)
    e0 = obs["q_ref"] - obs["q"]
    assert np.max(np.abs(e0)) > 0.02
    errors, state = [], None
    for k in range(1000):
        action, state = policy.predict(obs, state, np.array([k == 0]))
        obs, *_ = env.step(action)
        errors.append(obs["q_ref"] - obs["q"])
    t = (np.arange(1, 1001)) * env.unwrapped.dt
    predicted = e0[None] * ((1 + omega * t) * np.exp(-omega * t))[:, None]
    # a 1 kHz zero-order hold delays the loop by half a period: < 2 % of the initial error
    assert np.max(np.abs(np.array(errors) - predicted)) < 0.02 * np.max(np.abs(e0))
    # and a wrong gain is caught: ω = 25 predicts a visibly different transient
    wrong = e0[None] * ((1 + 25 * t) * np.exp(-25 * t))[:, None]
    assert np.max(np.abs(np.array(errors) - wrong)) > 0.05 * np.max(np.abs(e0))


def test_pd_gravity_regulates_from_random_starts():
    kwargs = {"reference": "regulation"}
    policy = baselines.make("pd_gravity", ENV, env_kwargs=kwargs)
    result = evaluate(policy, ENV, n_episodes=3, seed=10, **kwargs)
    for ep in result.episodes:
        assert ep.metrics["final_error"] <= 1e-4


def test_pd_gravity_offset_matches_theory_under_gravity_model_error():
    """At equilibrium K_P q̃ = g(q) − ĝ(q): the offset the theory predicts."""
    env = gym.make(ENV, reference="regulation", payload_mass=3.0, episode_duration=6.0)
    policy = baselines.make("pd_gravity", ENV, env=env)
    steps, _ = rollout(policy, env, seed=4)
    obs = steps[-1][0]
    q, q_err = obs["q"], obs["q_ref"] - obs["q"]
    true_robot = Robot.from_name("iiwa14").with_error(ModelError(payload_mass=3.0))
    true_robot.set_armature(env.unwrapped.armature)
    predicted = (true_robot.gravity(q) - policy.robot.gravity(q)) / policy.kp
    assert np.max(np.abs(q_err)) > 1e-3  # a visible offset
    np.testing.assert_allclose(q_err, predicted, atol=2e-3 * np.max(np.abs(predicted)) + 1e-7)


def test_robust_control_cuts_the_payload_error_of_nominal_computed_torque():
    kwargs = {"payload_mass": 3.0}
    ct = evaluate(baselines.make("computed_torque", ENV, env_kwargs=kwargs), ENV, 1, 0, **kwargs)
    rb = evaluate(baselines.make("robust", ENV, env_kwargs=kwargs), ENV, 1, 0, **kwargs)
    assert rb.summary["rms_error"]["mean"] < 0.5 * ct.summary["rms_error"]["mean"]


def test_lyapunov_solution_solves_the_equation():
    from baselines.centralized import lyapunov_solution

    n = 3
    H = np.block([[np.zeros((n, n)), np.eye(n)], [-400 * np.eye(n), -40 * np.eye(n)]])
    P = np.diag(np.concatenate((np.full(n, 400.0), np.ones(n))))
    Q = lyapunov_solution(H, P)
    np.testing.assert_allclose(H.T @ Q + Q @ H, -P, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(Q) > 0)
    with pytest.raises(ValueError, match="Hurwitz"):
        lyapunov_solution(-H, P)


@pytest.mark.parametrize(
    "name", ["pid", "p_pi_cascade", "p_pi_feedforward", "decentralized_feedforward"]
)
def test_decentralized_controllers_track_with_zero_static_error(name):
    """Integral action rejects the constant gravity disturbance d (chapter 4)."""
    kwargs = {"reference": "regulation", "episode_duration": 6.0}
    policy = baselines.make(name, ENV, env_kwargs=kwargs)
    result = evaluate(policy, ENV, 1, 2, **kwargs)
    assert result.episodes[0].metrics["final_error"] < 1e-3


def test_feedforward_improves_the_cascade():
    plain = evaluate(baselines.make("p_pi_cascade", ENV), ENV, 1, 0)
    ff = evaluate(baselines.make("p_pi_feedforward", ENV), ENV, 1, 0)
    full = evaluate(baselines.make("decentralized_feedforward", ENV), ENV, 1, 0)
    e = [r.summary["rms_error"]["mean"] for r in (plain, ff, full)]
    assert e[0] > e[1] > e[2]


def test_gear_ratio_sets_the_reflected_rotor_inertia():
    env = gym.make(ENV, gear_ratio=50.0, rotor_inertia=2e-4)
    base = env.unwrapped
    np.testing.assert_allclose(base.model.dof_armature, 50.0**2 * 2e-4)
    ctx = base.controller_context()
    np.testing.assert_allclose(ctx.nominal_robot().model.dof_armature, 0.5)


def test_info_terms_sum_to_reward_and_metrics_at_episode_end():
    env = gym.make(ENV, episode_duration=0.1)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(env.unwrapped.max_steps):
        _, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, 7))
        terms = sum(v for k, v in info.items() if k.startswith("reward_"))
        assert reward == pytest.approx(terms, abs=1e-12)
    assert truncated and not terminated
    assert set(info["episode_metrics"]) == {s.name for s in env.unwrapped.metric_specs}
    assert "is_success" in info


def test_following_error_monitor_stops_a_lost_episode_and_scores_the_whole_horizon():
    env = gym.make(ENV, initial_error=0.05)
    base = env.unwrapped
    obs, _ = env.reset(seed=3)
    e0 = float(np.linalg.norm(obs["q_ref"] - obs["q"]))
    errors = []
    for _ in range(base.max_steps):  # zero torque: the arm falls
        _, reward, terminated, truncated, info = env.step(np.zeros(7))
        errors.append(info["joint_error"])
        if terminated or truncated:
            break
    k = len(errors) - 1
    assert terminated and not truncated and info["following_error_exceeded"]
    assert not info["diverged"] and not info["is_success"]
    assert errors[-1] > e0 + 0.5 >= max(errors[:-1])  # trips on the first step past the bound
    assert info["reward_following_error"] == -50.0
    terms = sum(v for key, v in info.items() if key.startswith("reward_"))
    assert reward == pytest.approx(terms, abs=1e-12)
    # the last error is held for the unplayed steps: RMS over the whole horizon
    held = base._err[k]
    expected = np.sqrt(
        (np.sum(base._err[: k + 1] ** 2) + (base.max_steps - k - 1) * held @ held)
        / (base.max_steps * 7)
    )
    assert info["episode_metrics"]["rms_error"] == pytest.approx(expected, rel=1e-12)
    assert k < 0.2 * base.max_steps
    # disabled: the same actions run to the end
    env = gym.make(ENV, initial_error=0.05, max_following_error=None)
    env.reset(seed=3)
    for _ in range(k + 1):
        _, _, terminated, _, info = env.step(np.zeros(7))
    assert not terminated and not info["following_error_exceeded"]


def test_bad_input_is_reported_clearly():
    with pytest.raises(ValueError, match="allowed"):
        gym.make(ENV, payload=3.0)
    with pytest.raises(ValueError, match="reference must be one of"):
        gym.make(ENV, reference="spiral")
    with pytest.raises(ValueError, match="payload_mass"):
        gym.make(ENV, payload_mass=-1.0)
    with pytest.raises(ValueError, match="allowed"):
        baselines.make("computed_torque", ENV, kp=3.0)
    with pytest.raises(ValueError, match="available"):
        baselines.make("lqr", ENV)
    env = gym.make(ENV)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"expects shape \(7,\)"):
        env.step(np.zeros(6))
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.full(7, np.nan))
    env.step(np.zeros(7))  # still usable


@pytest.mark.parametrize("torque", [1e8, 1e12])  # huge accelerations; a control MuJoCo rejects
def test_diverging_physics_ends_the_episode_with_a_flag(torque):
    env = gym.make(ENV)
    base = env.unwrapped
    env.reset(seed=0)
    base.torque_limit[:] = torque  # a broken actuator model: absurd torques
    base.model.actuator_ctrlrange[:] = [-torque, torque]
    obs, reward, terminated, _, info = env.step(np.ones(7))
    assert terminated and info["diverged"]
    assert all(np.all(np.isfinite(v)) for v in obs.values())
    assert np.isfinite(reward)
    base.torque_limit[:] = base.robot.torque_limit
    base.model.actuator_ctrlrange[:, 0] = -base.robot.torque_limit
    base.model.actuator_ctrlrange[:, 1] = base.robot.torque_limit
    env.reset(seed=1)
    _, _, terminated, _, info = env.step(np.zeros(7))
    assert not terminated and not info["diverged"]


def test_controllers_use_only_the_nominal_model():
    """The simulator's payload must not leak into the controller's model."""
    env = gym.make(ENV, payload_mass=3.0)
    policy = baselines.make("computed_torque", ENV, env=env)
    assert policy.robot.model.body("payload").mass[0] == 0.0
    assert env.unwrapped.model.body("payload").mass[0] == 3.0
    assert policy.robot.model is not env.unwrapped.model


def test_registry_lists_joint_tracking():
    assert ENV in cir_gym.ENVIRONMENTS
    assert {"computed_torque", "pd_gravity", "robust", "pid"} <= set(baselines.available(ENV))


def test_adaptive_control_learns_the_payload_and_drives_y_pi_tilde_to_zero():
    from cir_gym import dynamics

    kwargs = {"payload_mass": 3.0, "episode_duration": 3.0}
    ct = evaluate(baselines.make("computed_torque", ENV, env_kwargs=kwargs), ENV, 1, 0, **kwargs)
    policy = baselines.make("adaptive", ENV, env_kwargs=kwargs)
    ad = evaluate(policy, ENV, 1, 0, record=True, **kwargs)
    assert ad.summary["rms_error"]["mean"] < 0.2 * ct.summary["rms_error"]["mean"]
    trace = ad.episodes[0].trace
    true = Robot.from_name("iiwa14").with_error(ModelError(payload_mass=3.0))
    true.set_armature(policy.robot.model.dof_armature)
    pi_true = dynamics.inertial_parameters(true.model)
    lam = policy.gains.lam
    q, qd = trace["obs/q"], trace["obs/qd"]
    e, ed = trace["obs/q_ref"] - q, trace["obs/qd_ref"] - qd
    qd_r, qdd_r = trace["obs/qd_ref"] + lam * e, trace["obs/qdd_ref"] + lam * ed

    def y_pi_tilde(k):
        Y = dynamics.regressor(policy.model, q[k], qd[k], qdd_r[k], qd_r=qd_r[k])
        return np.linalg.norm(Y @ (pi_true - trace["state"][k]))

    early = np.mean([y_pi_tilde(k) for k in range(0, 50, 5)])
    late = np.mean([y_pi_tilde(k) for k in range(len(q) - 500, len(q), 25)])
    assert late < 0.3 * early
