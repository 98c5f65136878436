"""JointTracking-v2 and the joint-space controllers of chapters 4 and 5: properties from theory."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import cir_gym
from cir_gym import baselines, motor
from cir_gym.envs.joint_tracking import RANDOM_RANGES
from cir_gym.evaluation import evaluate
from cir_gym.robot import ModelError, Robot

ENV = "cir_gym/JointTracking-v2"


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
    env = gym.make(ENV, initial_error=0.05, control_freq=1000.0, max_episode_steps=-1)
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
    env = gym.make(
        ENV, reference="regulation", payload_mass=3.0, episode_duration=6.0, max_episode_steps=-1
    )  # longer than the registered TimeLimit
    policy = baselines.make("pd_gravity", ENV, env=env)
    steps, _ = rollout(policy, env, seed=4)
    obs = steps[-1][0]
    q, q_err = obs["q"], obs["q_ref"] - obs["q"]
    true_robot = Robot.from_name("iiwa14").with_error(ModelError(payload_mass=3.0))
    true_robot.set_armature(env.unwrapped.armature)
    predicted = (true_robot.gravity(q) - policy.robot.gravity(q)) / policy.kp
    assert np.max(np.abs(q_err)) > 1e-3  # a visible offset
    np.testing.assert_allclose(q_err, predicted, atol=2e-3 * np.max(np.abs(predicted)) + 1e-7)


def test_robust_inside_its_boundary_layer_is_computed_torque_at_the_layer_gains():
    """Inside the layer w = (ρ/ε) z: the law is computed torque with K_P + ρQ₁₂/ε and
    K_D + ρQ₂₂/ε, which the default ε keeps within twice the designed gains (the layer is a
    chattering remedy, not a gain: the old ε gave K_P ≈ 5400 for the designed 400)."""
    policy = baselines.make("robust", ENV)
    kp, kd = 20.0**2, 2 * 20.0
    assert kp < policy.kp_layer <= 2 * kp + 1e-9 and kd < policy.kd_layer <= 2 * kd + 1e-9
    env = gym.make(ENV, initial_error=0.01)
    obs, _ = env.reset(seed=0)
    z = policy.DtQ @ np.concatenate((obs["q_ref"] - obs["q"], obs["qd_ref"] - obs["qd"]))
    assert np.linalg.norm(policy.weight * z) < policy.epsilon  # inside the layer
    omega = np.sqrt(policy.kp_layer)
    ct = baselines.make("computed_torque", ENV, omega_n=omega, zeta=policy.kd_layer / (2 * omega))
    np.testing.assert_allclose(policy(obs), ct(obs), rtol=1e-9, atol=1e-12)
    # outside the layer the robust term is the course's bounded w: ‖S w‖ = ρ
    far = {**obs, "q": obs["q"] + 3.0}
    z = policy.DtQ @ np.concatenate((far["q_ref"] - far["q"], far["qd_ref"] - far["qd"]))
    assert np.linalg.norm(policy.weight * z) > policy.epsilon
    nominal = baselines.make("computed_torque", ENV)  # the designed ω_n = 20, ζ = 1
    w = np.linalg.solve(
        policy.inertia(far["q"]),
        policy.control(far, np.zeros(0)) - nominal.control(far, np.zeros(0)),
    )
    assert np.linalg.norm(policy.weight * w) == pytest.approx(policy.rho, rel=1e-9)


def test_robust_bound_covers_the_friction_and_masses_randomize_draws():
    """The default uncertainty set is RANDOM_RANGES' (±20 % masses, friction ≤ 1), so ρ is
    larger than the bound without friction and with ±10 % masses."""
    g = baselines.make("robust", ENV).gains
    assert g.mass_scale_bound == pytest.approx(RANDOM_RANGES["mass_scale"][1] - 1.0)
    assert g.viscous_friction_bound == RANDOM_RANGES["viscous_friction"][1]
    assert g.coulomb_friction_bound == RANDOM_RANGES["coulomb_friction"][1]
    narrow = baselines.make(
        "robust", ENV, mass_scale_bound=0.1, viscous_friction_bound=0.0, coulomb_friction_bound=0.0
    )
    assert baselines.make("robust", ENV).rho > narrow.rho


def test_robust_alpha_bounds_the_weighted_norm_of_the_inertia_error_below_one():
    """‖S (I − B⁻¹B̂) S⁻¹‖₂ ≤ α < 1 on fresh configurations and uncertainties inside the
    declared set, while the unweighted ‖I − B⁻¹B̂‖₂ exceeds 1 (why S is needed)."""
    policy = baselines.make("robust", ENV)
    assert 0.0 < policy.alpha < 1.0
    np.testing.assert_allclose(np.max(policy.weight), 1.0)  # ‖S‖₂ = 1
    rng = np.random.default_rng(123)
    weighted, plain = [], []
    for _ in range(30):
        true = policy.robot.with_error(
            ModelError(payload_mass=rng.uniform(0, 5), mass_scale=rng.uniform(0.9, 1.1))
        )
        q = rng.uniform(policy.robot.lower, policy.robot.upper)
        B, B_hat = true.inertia(q), policy.robot.inertia(q)
        weighted.append(policy.inertia_error_norm(B, B_hat))
        plain.append(np.linalg.norm(np.eye(7) - np.linalg.solve(B, B_hat), 2))
    assert max(weighted) <= policy.alpha
    assert max(plain) > 1.0
    expected = (
        policy.alpha * policy.gains.qdd_ref_bound
        + policy.alpha * np.hypot(400.0, 40.0) * policy.gains.error_bound
        + policy.b_phi
    ) / (1 - policy.alpha)
    assert policy.rho == pytest.approx(expected)


def test_lyapunov_solution_solves_the_equation():
    from cir_gym.baselines.centralized import lyapunov_solution

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
    result = evaluate(policy, ENV, 1, 2, max_episode_steps=-1, **kwargs)
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
    worst = 1.0 + 0.01 + 4 * 0.01  # r_tracking = −1, ‖a‖²/7 = 1, ‖Δa‖²/7 = 4 at the defaults
    unplayed = base.max_steps - (k + 1)
    assert info["reward_following_error"] == pytest.approx(-(50.0 + unplayed * worst), rel=1e-15)
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


def test_randomize_draws_the_model_error_per_seed_and_overrides_only_those_arguments():
    """randomize=True: payload, mass scale and both frictions from RANDOM_RANGES replace the
    arguments, per reset, in the simulator; torque noise and encoder resolution stay."""
    kwargs = {
        "payload_mass": 1.0,
        "mass_scale": 1.5,
        "torque_noise": 0.3,
        "encoder_resolution": 1e-4,
        "episode_duration": 0.1,
    }
    env = gym.make(ENV, randomize=True, **kwargs)
    base = env.unwrapped
    nominal = Robot.from_name("iiwa14").model
    moving = nominal.body_dofnum > 0
    payload = base.model.body("payload").id
    draws, masses = [], []
    for seed in (1, 2):
        _, info = env.reset(seed=seed)
        err = info["model_error"]
        for name, (lo, hi) in RANDOM_RANGES.items():
            assert lo <= getattr(err, name) <= hi, name
        assert err.mass_scale != 1.5 and err.payload_mass != 1.0  # the arguments are overridden
        model = base.model
        np.testing.assert_allclose(model.body_mass[payload], err.payload_mass)
        links = moving.copy()
        links[payload] = False
        scaled = err.mass_scale * nominal.body_mass[links]
        np.testing.assert_allclose(model.body_mass[links], scaled)
        np.testing.assert_allclose(model.dof_damping, err.viscous_friction)
        np.testing.assert_allclose(model.dof_frictionloss, err.coulomb_friction)
        assert base.torque_noise == 0.3 and base.encoder_resolution == 1e-4
        draws.append(err)
        masses.append(model.body_mass.copy())
    assert draws[0] != draws[1]
    assert all(getattr(draws[0], f) != getattr(draws[1], f) for f in RANDOM_RANGES)
    assert not np.allclose(masses[0], masses[1])
    # the same seed draws the same robot; the controller's model never changes
    _, info = env.reset(seed=1)
    assert info["model_error"] == draws[0]
    np.testing.assert_array_equal(base.model.body_mass, masses[0])
    ctx_mass = base.controller_context().nominal_robot().model.body_mass
    np.testing.assert_array_equal(ctx_mass, nominal.body_mass)
    # without randomize the arguments are the episode's model error
    _, info = gym.make(ENV, **kwargs).reset(seed=1)
    assert info["model_error"] == ModelError(payload_mass=1.0, mass_scale=1.5)


def _random_states(robot, count, seed):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield (
            rng.uniform(robot.lower, robot.upper),
            rng.uniform(-0.5, 0.5, robot.n) * robot.velocity_limit,
            rng.uniform(-5.0, 5.0, robot.n),
        )


def test_motor_side_maps_round_trip_and_conserve_power():
    rng = np.random.default_rng(0)
    N = np.array([160, 160, 160, 160, 100, 100, 100.0])
    q, qd, tau = rng.normal(size=(3, 7))
    np.testing.assert_allclose(motor.motor_positions(q, N), N * q)
    np.testing.assert_allclose(motor.joint_positions(motor.motor_positions(q, N), N), q)
    np.testing.assert_allclose(motor.motor_torques(tau, N), tau / N)
    np.testing.assert_allclose(motor.joint_torques(motor.motor_torques(tau, N), N), tau)
    # an ideal gear transmits power: τ_mᵀ q̇_m = τᵀ q̇
    power_m = motor.motor_torques(tau, N) @ motor.motor_positions(qd, N)
    assert power_m == pytest.approx(tau @ qd, rel=1e-12)


def test_motor_side_inertia_is_diagonal_scales_as_inverse_square_and_dominates_at_large_n():
    robot = Robot.from_name("iiwa14")
    J_m = robot.rotor_inertia
    B_bar = motor.average_inertia(robot)
    assert np.count_nonzero(B_bar - np.diag(np.diag(B_bar))) == 0
    assert np.all(np.diag(B_bar) > 0)
    for n in (1.0, 10.0, 160.0):
        B_bar_r = motor.motor_side_inertia(B_bar, n)
        np.testing.assert_allclose(motor.motor_side_inertia(B_bar, 2 * n), B_bar_r / 4)
        np.testing.assert_allclose(B_bar_r, B_bar / n**2)
    # the decentralized design's J_eff is J_m + B̄_r,ii
    from cir_gym.baselines.decentralized import effective_motor_inertia

    N = robot.gear_ratio
    np.testing.assert_allclose(
        effective_motor_inertia(robot, N, J_m), J_m + np.diag(motor.motor_side_inertia(B_bar, N))
    )
    # seen from the motors, J_m + N⁻¹B(q)N⁻¹ tends to the constant diagonal J_m + B̄_r:
    # the deviation N⁻¹ΔB(q)N⁻¹, relative to the diagonal, falls as 1/n² once n² J_m ≫ B̄
    coupling = []
    for n in (1.0, 10.0, 100.0, 1000.0):
        worst = 0.0
        for q, _, _ in _random_states(robot, 10, seed=1):
            M = np.diag(J_m) + motor.motor_side_inertia(motor.link_inertia(robot, q), n)
            dev = motor.motor_side_inertia(motor.inertia_residual(robot, q, B_bar), n)
            d = np.sqrt(np.diag(M))
            worst = max(worst, float(np.max(np.abs(dev) / np.outer(d, d))))
        coupling.append(worst)
    assert np.all(np.diff(coupling) < 0)
    assert coupling[0] > 1.0 > 0.1 > coupling[-1]


def test_motor_side_disturbance_is_the_definition_and_shrinks_as_one_over_n():
    """d = N⁻¹ΔB(q)N⁻¹ q̈_m + N⁻¹C N⁻¹ q̇_m + N⁻¹ g(q), written out here from its terms."""
    robot = Robot.from_name("iiwa14")
    B_bar = motor.average_inertia(robot)
    armature = np.diag(robot.model.dof_armature)
    for q, qd, qdd in _random_states(robot, 5, seed=2):
        delta_B = robot.inertia(q) - armature - B_bar
        c_qd = robot.bias(q, qd) - robot.gravity(q)  # C(q, q̇) q̇
        g = robot.gravity(q)
        norms = []
        for n in (1.0, 10.0, 100.0, 160.0):
            N_inv = np.eye(7) / n
            qdd_m = n * qdd  # q̈_m = N q̈; C(q, q̇) N⁻¹ q̇_m = C(q, q̇) q̇
            expected = N_inv @ delta_B @ N_inv @ qdd_m + N_inv @ c_qd + N_inv @ g
            d = motor.motor_side_disturbance(robot, q, qd, qdd, n)
            np.testing.assert_allclose(d, expected, rtol=1e-10, atol=1e-12)
            norms.append(np.linalg.norm(d))
        assert norms[0] > 1.0
        np.testing.assert_allclose(np.array(norms) * [1, 10, 100, 160], norms[0], rtol=1e-10)


def test_motor_side_model_reproduces_the_rigid_gear_dynamics():
    """(J_m + B̄_r) q̈_m + d = N⁻¹ τ, τ = B(q) q̈ + n(q, q̇) with B holding the armature N² J_m."""
    env = gym.make(ENV, gear_ratio=50.0)
    ctx = env.unwrapped.controller_context()
    robot = ctx.nominal_robot()
    N, J_m = ctx.gear_ratio, ctx.rotor_inertia
    np.testing.assert_allclose(robot.model.dof_armature, N**2 * J_m)
    B_bar_r = motor.motor_side_inertia(motor.average_inertia(robot), N)
    for q, qd, qdd in _random_states(robot, 5, seed=3):
        qdd_m = motor.motor_positions(qdd, N)
        lhs = (np.diag(J_m) + B_bar_r) @ qdd_m + motor.motor_side_disturbance(robot, q, qd, qdd, N)
        rhs = motor.motor_torques(robot.inverse_dynamics(q, qd, qdd), N)
        np.testing.assert_allclose(lhs, rhs, rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------------- issue 19
def _run(env, policy, seed):
    obs, _ = env.reset(seed=seed)
    state, total = None, 0.0
    for k in range(env.unwrapped.max_steps):
        action, state = policy.predict(obs, state, np.array([k == 0]))
        obs, reward, terminated, truncated, info = env.step(action)
        total += reward
        if terminated or truncated:
            return info, total, k + 1
    raise AssertionError("the episode did not end")


def test_regulation_succeeds_once_settled_and_the_offset_is_judged_only_in_the_window():
    """Before: success used the max error including the initial offset, so a regulation
    episode (random start) never succeeded, even with a 5.6e-9 rad final error."""
    env = gym.make(ENV, reference="regulation", episode_duration=3.0)
    policy = baselines.make("pd_gravity", ENV, env=env)
    info, _, _ = _run(env, policy, seed=0)
    assert info["episode_metrics"]["max_error"] > 0.05  # the offset is still in max_error
    assert info["episode_metrics"]["final_error"] < 1e-4
    assert info["is_success"]
    # no window: the offset is judged and the episode fails
    env0 = gym.make(ENV, reference="regulation", episode_duration=3.0, settling_time=0.0)
    info0, _, _ = _run(env0, baselines.make("pd_gravity", ENV, env=env0), seed=0)
    assert not info0["is_success"]
    # an episode that starts on its reference gets no window: a late error still counts
    assert env.unwrapped._judged_from > 0
    on_ref = gym.make(ENV, episode_duration=0.5)
    on_ref.reset(seed=0)
    assert on_ref.unwrapped._judged_from == 0


def test_control_freq_is_a_physics_rate_divisor_or_rejected_by_name():
    """300 Hz on the 1-ms step used to run at 333.3 Hz (rounded frame skip)."""
    with pytest.raises(ValueError, match=r"control_freq.*333\.333"):
        gym.make(ENV, control_freq=300.0)
    env = gym.make(ENV, control_freq=250.0)
    assert env.unwrapped.dt == pytest.approx(1 / 250.0, rel=1e-12)
    elastic = gym.make("cir_gym/ElasticJointTracking-v3", control_freq=400.0)  # 0.5-ms step
    assert elastic.unwrapped.frame_skip == 5


@pytest.mark.parametrize("env_id", [ENV, "cir_gym/ElasticJointTracking-v3"])
def test_registered_max_episode_steps_is_the_default_episode_and_timelimit_agrees(env_id):
    spec = gym.spec(env_id)
    env = gym.make(env_id)
    assert spec.max_episode_steps == env.unwrapped.max_steps
    assert env.spec.max_episode_steps == env.unwrapped.max_steps
    env.reset(seed=0)
    base, limit = env.unwrapped, spec.max_episode_steps
    base._k = limit - 1  # the last step: TimeLimit and the env truncate it together
    *_, terminated, truncated, _ = env.step(np.zeros(7))
    assert truncated and not terminated
    with pytest.warns(UserWarning, match="max_episode_steps"):
        gym.make(env_id, episode_duration=8.0)  # TimeLimit would cut this episode short
    longer = gym.make(env_id, episode_duration=8.0, max_episode_steps=-1)
    assert longer.unwrapped.max_steps == 2 * limit


def test_industrial_drive_quantizes_differentiates_delays_and_ripples():
    from cir_gym.drives import INDUSTRIAL, DriveModel

    res = 2 * np.pi / 2**20
    assert INDUSTRIAL.resolution == pytest.approx(res)
    env = gym.make(ENV, drive="industrial", episode_duration=0.1).unwrapped
    obs0, _ = env.reset(seed=1)
    obs1, *_ = env.step(np.full(7, 0.05))
    np.testing.assert_allclose(obs1["q"] / res, np.round(obs1["q"] / res), atol=1e-6)
    np.testing.assert_allclose(obs1["qd"], (obs1["q"] - obs0["q"]) / env.dt, atol=1e-12)
    # delay alone: commands a, b, c are applied as a, a, b
    delay = DriveModel(encoder_bits=0, velocity_from_differences=False, torque_ripple=0.0)
    late = gym.make(ENV, drive=delay, episode_duration=0.1).unwrapped
    ideal = gym.make(ENV, episode_duration=0.1).unwrapped
    a, b, c = (np.full(7, v) for v in (0.05, -0.05, 0.1))
    late.reset(seed=2)
    ideal.reset(seed=2)
    for cmd in (a, b, c):
        late.step(cmd)
    for cmd in (a, a, b):
        ideal.step(cmd)
    np.testing.assert_allclose(late.data.qpos, ideal.data.qpos, atol=1e-12)
    # ripple alone: τ (1 + r sin(h N q)) reaches the actuators
    ripple = DriveModel(encoder_bits=0, velocity_from_differences=False, delay_steps=0)
    rip = gym.make(ENV, drive=ripple, episode_duration=0.1).unwrapped
    rip.reset(seed=3)
    q = rip.data.qpos[rip._qa].copy()
    rip.step(a)
    expected = a * rip.torque_limit * (1 + 0.02 * np.sin(6 * rip.gear_ratio * q))
    np.testing.assert_allclose(rip.data.ctrl, expected, rtol=1e-12)
    with pytest.raises(ValueError, match="drive"):
        gym.make(ENV, drive="perfect")
    with pytest.raises(ValueError, match="encoder_resolution"):
        gym.make(ENV, drive="industrial", encoder_resolution=1e-5)


def test_p_pi_feedforward_keeps_a_given_k_ff():
    """It used to overwrite any k_ff with 1 (setdefault on the overrides, not on gains=)."""
    from cir_gym.baselines.decentralized import FeedforwardCascadeGains

    assert baselines.make("p_pi_feedforward", ENV).gains.k_ff == 1.0
    assert baselines.make("p_pi_feedforward", ENV, k_ff=0.3).gains.k_ff == 0.3
    ctx = gym.make(ENV).unwrapped.controller_context()
    given = baselines.CONTROLLERS["p_pi_feedforward"](ctx, FeedforwardCascadeGains(k_ff=0.4))
    assert given.gains.k_ff == 0.4


def test_pd_gravity_uses_identified_parameters():
    """parameters= used to be accepted and ignored: ĝ came from the nominal robot."""
    from cir_gym import dynamics

    true = Robot.from_name("iiwa14").with_error(ModelError(payload_mass=3.0))
    pi_true = dynamics.inertial_parameters(true.model)
    policy = baselines.make("pd_gravity", ENV, parameters=pi_true)
    nominal = baselines.make("pd_gravity", ENV)
    q = true.model.key("home").qpos.copy() + 0.3
    np.testing.assert_allclose(policy.gravity(q), true.gravity(q), rtol=1e-9, atol=1e-9)
    assert not np.allclose(nominal.gravity(q), true.gravity(q), rtol=1e-3)


def test_make_rejects_env_with_env_kwargs():
    env = gym.make(ENV)
    with pytest.raises(ValueError, match="env_kwargs"):
        baselines.make("pid", ENV, env=env, env_kwargs={"payload_mass": 3.0})


@pytest.mark.parametrize("name", ["pid", "p_pi_cascade"])
def test_integrators_do_not_wind_up_while_the_torque_saturates(name):
    """Back-calculation: under a constant error that saturates every joint the integral
    settles (at u − u_sat = N k e); the plain integrator grows by Δt e every step."""
    env = gym.make(ENV)
    obs, _ = env.reset(seed=0)
    far = {**obs, "q": obs["q"] - 1.0, "qd": obs["qd_ref"]}  # 1 rad on every joint: saturated
    states = {}
    for mode in ("back_calculation", "clamping", "none"):
        policy = baselines.make(name, ENV, anti_windup=mode)
        state = policy.initial_state(far)
        history = []
        for _ in range(2000):
            command = policy.control(far, state)
            history.append(state.copy())
        assert np.all(np.abs(command) > policy.action_scale)
        states[mode] = np.array(history)
    back = states["back_calculation"]
    np.testing.assert_allclose(back[-1], back[-500], rtol=1e-6)  # settled
    np.testing.assert_allclose(states["clamping"][-1], 0.0, atol=1e-12)  # never integrated
    assert np.all(np.abs(states["none"][-1]) > 10 * np.abs(back[-1]))  # wound up
    with pytest.raises(ValueError, match="anti_windup"):
        baselines.make(name, ENV, anti_windup="sometimes")


@pytest.mark.parametrize("name", ["pid", "p_pi_cascade"])
def test_anti_windup_lets_regulation_reach_its_setpoint(name):
    """A large regulation move saturates the torque for a while: the wound-up integral of the
    plain loops then overshoots and has not recovered by the end of the 4-s episode (final
    error 0.067 rad for pid and 3.6 rad for the cascade on seed 2000); with back-calculation
    the arm settles (< 1e-10 rad)."""
    kwargs = {"reference": "regulation"}
    final = {}
    for mode in ("back_calculation", "none"):
        policy = baselines.make(name, ENV, env_kwargs=kwargs, anti_windup=mode)
        final[mode] = evaluate(policy, ENV, 1, 2000, **kwargs).episodes[0].metrics["final_error"]
    assert final["back_calculation"] < 1e-6 and final["none"] > 0.05


# ---------------------------------------------------------------------------------------------
# The hot paths (issue 21) against straightforward reference computations
# ---------------------------------------------------------------------------------------------


def _reference_step(env, obs_before_k, action, a_prev):
    """What one JointTracking step must give, written plainly from the docstring (np.clip,
    np.mean, np.linalg.norm), from the env's state after the step (ideal drive)."""
    u = env.unwrapped
    a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
    q = u.data.qpos[u.robot.qpos_adr]
    qd = u.data.qvel[u.robot.dof_adr]
    k = u._k
    err = u._ref[0, k] - q
    err_sq = float(err @ err)
    w = u.reward_model
    r_track = -(1.0 - float(np.mean(np.exp(-err_sq / w.error_scales**2))))
    r_torque = -w.torque_weight * float(a @ a) / u.n
    r_rate = -w.action_rate_weight * float((a - a_prev) @ (a - a_prev)) / u.n
    raw = {"q": q, "qd": qd, "q_ref": u._ref[0, k], "qd_ref": u._ref[1, k], "qdd_ref": u._ref[2, k]}
    bounds = {"q": 2 * np.pi, "qd": 50.0, "q_ref": 2 * np.pi, "qd_ref": 50.0, "qdd_ref": 500.0}
    obs = {key: np.clip(v, -bounds[key], bounds[key]) for key, v in raw.items()}
    return obs, r_track, r_torque, r_rate, float(np.linalg.norm(err)), a


@pytest.mark.parametrize(
    "kwargs", [{}, {"reference": "sine", "payload_mass": 2.0}, {"action_rate_weight": 0.5}]
)
def test_step_matches_a_plain_reference_computation_and_keeps_past_observations(kwargs):
    """Every observation entry exactly (copies and one clip of the simulator's numbers),
    every reward term and the joint error to 1e-15 relative (1e-14 for their sum: numpy's dot
    and a sum of squares may round a 7-term sum differently in the last bit), saturation and
    torque metrics as the docstring defines them; observations returned earlier are never
    changed by later steps (the step builds one fresh array per step)."""
    env = gym.make(ENV, episode_duration=0.3, max_following_error=None, **kwargs)
    obs, _ = env.reset(seed=7)
    rng = np.random.default_rng(7)
    kept, a_prev, sat, tau = [], np.zeros(7), [], []
    for k in range(env.unwrapped.max_steps):
        action = rng.uniform(-1.3, 1.3, 7).astype(np.float32)  # some entries clipped
        if k % 3 == 0:
            action[:] = 0.0
        if k % 7 == 1:
            action[2] = 1.0  # at the limit: saturated, not clipped
        kept.append(({key: v for key, v in obs.items()}, {key: v.copy() for key, v in obs.items()}))
        obs, reward, terminated, truncated, info = env.step(action)
        want_obs, r_track, r_torque, r_rate, joint_error, a = _reference_step(
            env, None, action, a_prev
        )
        for key in want_obs:
            np.testing.assert_array_equal(obs[key], want_obs[key], err_msg=f"{k} {key}")
        assert info["reward_tracking"] == pytest.approx(r_track, rel=1e-15, abs=1e-15)
        assert info["reward_torque"] == pytest.approx(r_torque, rel=1e-15, abs=1e-18)
        assert info["reward_action_rate"] == pytest.approx(r_rate, rel=1e-15, abs=1e-18)
        assert info["joint_error"] == pytest.approx(joint_error, rel=1e-15)
        assert reward == pytest.approx(r_track + r_torque + r_rate, rel=1e-14, abs=1e-15)
        sat.append(bool(np.any(np.abs(a) >= 1.0)))
        tau.append(a * env.unwrapped.torque_limit)
        a_prev = a
        if terminated or truncated:
            break
    assert truncated
    metrics = info["episode_metrics"]
    assert metrics["saturation"] == pytest.approx(np.mean(sat), rel=1e-15)
    assert 0 < metrics["saturation"] < 1
    assert metrics["rms_torque"] == pytest.approx(np.sqrt(np.mean(np.square(tau))), rel=1e-14)
    for returned, copy in kept:  # what a user kept is what was returned
        for key in copy:
            np.testing.assert_array_equal(returned[key], copy[key])


@pytest.mark.parametrize("drive_kwargs", [{"drive": "industrial"}, {"encoder_resolution": 1e-3}])
def test_measured_rows_match_the_sensor_models(drive_kwargs):
    """With the industrial drive q is the encoder reading Δ round(q / Δ) and q̇ the backward
    difference of two readings; with ``encoder_resolution`` likewise (q̇ = 0 at reset)."""
    env = gym.make(ENV, episode_duration=0.1, **drive_kwargs)
    u = env.unwrapped
    res = u.drive.resolution if u.drive is not None else u.encoder_resolution
    obs, _ = env.reset(seed=3)
    q_prev_meas = obs["q"].copy()
    if u.drive is None:
        np.testing.assert_array_equal(obs["qd"], 0.0)
    for _ in range(20):
        obs, *_ = env.step(np.full(7, 0.05, dtype=np.float32))
        q_meas = np.round(u.data.qpos[:7] / res) * res
        np.testing.assert_array_equal(obs["q"], q_meas)
        np.testing.assert_array_equal(obs["qd"], (q_meas - q_prev_meas) / u.dt)
        q_prev_meas = q_meas


def test_index_view_is_a_slice_exactly_when_the_addresses_are_evenly_spaced():
    from cir_gym.numeric import index_view

    data = np.arange(20.0)
    for idx in ([0, 1, 2, 3], [13, 12, 11, 10, 9, 8, 7], [6, 5, 4, 3, 2, 1, 0], [4], [1, 3, 5]):
        view = index_view(np.array(idx))
        assert isinstance(view, slice), idx
        np.testing.assert_array_equal(data[view], data[idx])
    for idx in ([0, 2, 3], [3, 3], []):
        got = index_view(np.array(idx, dtype=int))
        assert not isinstance(got, slice)
        np.testing.assert_array_equal(data[got], data[idx])


def test_an_unpickled_env_steps_as_the_original_and_still_detects_divergence():
    """The cached views of MuJoCo's arrays are rebuilt for the new MjData after pickling."""
    import pickle

    env = gym.make(ENV, episode_duration=0.2, max_following_error=None).unwrapped
    env.reset(seed=1)
    for _ in range(5):
        env.step(np.full(7, 0.1, dtype=np.float32))
    twin = pickle.loads(pickle.dumps(env))
    for _ in range(5):
        a, b = (
            env.step(np.full(7, -0.2, dtype=np.float32)),
            twin.step(np.full(7, -0.2, dtype=np.float32)),
        )
        for key in a[0]:
            np.testing.assert_array_equal(a[0][key], b[0][key])
        assert a[1] == b[1]
    twin.data.qvel[0] = 1e6  # absurd speed: the next step must end as diverged, state restored
    _, _, terminated, _, info = twin.step(np.zeros(7, dtype=np.float32))
    assert terminated and info["diverged"]


JOINT_LAWS = [
    "pid",
    "p_pi_cascade",
    "p_pi_feedforward",
    "decentralized_feedforward",
    "pd_gravity",
    "computed_torque",
    "robust",
]


def _observations(env_id, n, seed=0, **kwargs):
    """n different observations of env_id (a few steps apart, under a weak random torque)."""
    env = gym.make(env_id, max_following_error=None, **kwargs)
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        for _ in range(3):
            obs, *_ = env.step(rng.uniform(-0.05, 0.05, 7).astype(np.float32))
        out.append(obs)
    return env, out


@pytest.mark.parametrize("env_id", [ENV, "cir_gym/ElasticJointTracking-v3"])
def test_batched_predict_is_row_by_row_predict_bit_for_bit(env_id):
    """For every vectorised law: a batch of N different observations and states (N = 1, 4)
    gives, row for row, the action and state of predict on that row alone, which is the
    law's plain ``control`` (Robot.inertia/bias/gravity, one row) scaled and clipped."""
    env, rows = _observations(env_id, 4)
    stacked = {k: np.stack([o[k] for o in rows]) for k in rows[0]}
    for name in baselines.available(env_id):
        if name not in JOINT_LAWS:
            continue
        policy = baselines.make(name, env_id, env=env)
        assert policy.vectorized
        _, state = policy.predict(stacked)  # a batch of states: after one step
        state = state + np.arange(state.size).reshape(state.shape) * 1e-3
        for n in (1, 4):
            sub = {k: v[:n] for k, v in stacked.items()}
            actions, new_state = policy.predict(sub, state[:n], np.zeros(n, dtype=bool))
            assert actions.shape == (n, 7) and actions.dtype == np.float32
            for i in range(n):
                single = {k: v[i] for k, v in sub.items()}
                a_i, s_i = policy.predict(single, state[i : i + 1], np.zeros(1, dtype=bool))
                np.testing.assert_array_equal(actions[i], a_i, err_msg=f"{name} {n} {i}")
                np.testing.assert_array_equal(new_state[i], s_i[0], err_msg=name)
                s_plain = state[i].copy()
                command = policy.control(single, s_plain)  # the law on one row, plainly
                want = np.clip(command / policy.action_scale, -1, 1).astype(np.float32)
                np.testing.assert_array_equal(a_i, want, err_msg=name)
                np.testing.assert_array_equal(s_i[0], s_plain, err_msg=name)


def test_row_dynamics_are_the_robot_calls_bit_for_bit():
    """RowDynamics (the controllers' batched model calls) against Robot.gravity and
    Robot.inertia(q) @ q̈ + Robot.bias(q, q̇) on random states, one row and a batch."""
    from cir_gym.baselines.base import RowDynamics

    robot = Robot.from_name("iiwa14")
    rows = RowDynamics.for_robot(robot)
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.lower, robot.upper, (5, 7))
    qd, qdd = rng.normal(0, 1, (5, 7)), rng.normal(0, 3, (5, 7))
    g_rows, tau_rows = rows.gravity(q), rows.inverse_dynamics(q, qd, qdd)
    for i in range(5):
        g = robot.gravity(q[i])
        tau = robot.inertia(q[i]) @ qdd[i] + robot.bias(q[i], qd[i])
        np.testing.assert_array_equal(g_rows[i], g)
        np.testing.assert_array_equal(rows.gravity(q[i]), g)
        np.testing.assert_array_equal(tau_rows[i], tau)
        np.testing.assert_array_equal(rows.inverse_dynamics(q[i], qd[i], qdd[i]), tau)
    import pickle

    twin = pickle.loads(pickle.dumps(rows))
    np.testing.assert_array_equal(twin.inverse_dynamics(q, qd, qdd), tau_rows)


def test_predict_still_names_a_non_finite_observation_and_command():
    env, rows = _observations(ENV, 1)
    policy = baselines.make("computed_torque", ENV, env=env)
    for key in rows[0]:
        bad = {k: v.copy() for k, v in rows[0].items()}
        bad[key][3] = np.nan
        with pytest.raises(ValueError, match=rf"observation\['{key}'\] contains NaN or inf"):
            policy.predict(bad)
    shared = rows[0]  # an env observation: the rows of one array, checked as that array
    assert all(v.base is shared["q"].base for v in shared.values())
    shared["qdd_ref"][1] = np.inf
    with pytest.raises(ValueError, match=r"observation\['qdd_ref'\] contains NaN or inf"):
        policy.predict(shared)
    shared["qdd_ref"][1] = 0.0
    huge = {k: np.full(7, 1e200) for k in rows[0]}  # finite, squares overflow: still accepted
    policy_pd = baselines.make("pd_gravity", ENV, env=env)
    actions, _ = policy_pd.predict({**rows[0], "qdd_ref": huge["qdd_ref"]})
    assert np.all(np.isfinite(actions))
    policy.robot.model.opt.gravity[2] = np.inf  # a model that yields an infinite torque
    with pytest.raises(FloatingPointError, match="non-finite command"):
        policy.predict(rows[0])


def _episode_return(env_id: str, policy, seed: int, **kwargs) -> tuple[float, int]:
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


@pytest.mark.parametrize(
    ("env_id", "law"),
    [(ENV, "pd_gravity"), ("cir_gym/ElasticJointTracking-v3", "p_pi_cascade")],
)
def test_failing_early_never_raises_the_return(env_id: str, law: str) -> None:
    """A constant +1 torque trips the following-error monitor within ~15 steps; charged the
    worst reward of each unplayed step, it scores below a finished episode of a reference
    law; without the charge (−57) it would beat it (pd_gravity −554; p_pi_cascade on the
    elastic joints −1,029, seed 1000)."""
    failed, steps = _episode_return(env_id, None, 1000)
    finished, length = _episode_return(env_id, baselines.make(law, env_id), 1000)
    max_steps = gym.make(env_id).unwrapped.max_steps
    assert steps < 0.05 * max_steps and length == max_steps
    assert failed < finished
    assert failed <= -(max_steps - steps) * (1.0 + 0.01 + 4 * 0.01)  # the worst steps, charged
    uncharged, _ = _episode_return(env_id, None, 1000, charge_unplayed_steps=False)
    assert uncharged > finished  # what the charge prevents


def test_intersample_error_of_a_pd_law_equals_its_sampled_error():
    """scripts/eval_intersample.py: the 1-ms reference grid lines up with the env's (the RMS
    over joints and steps, as the env's metric): PD + gravity, smooth between its samples at
    100 Hz, has the same RMS error at every physics step as at its control instants (< 1 %),
    and a policy that holds a constant zero torque (the arm falls between samples) does not
    get a ratio of 1 by construction."""
    from cir_gym import baselines
    from scripts.research.eval_intersample import physics_rate_errors

    kwargs = {"control_freq": 100.0, "episode_duration": 1.0}
    pd = baselines.make("pd_gravity", "cir_gym/JointTracking-v2", env_kwargs=kwargs)
    sampled, every_step, n = physics_rate_errors(pd, kwargs, 1000)
    assert n == 1000  # 1 s of 1-ms physics steps
    assert every_step == pytest.approx(sampled, rel=0.01)

    class Zero:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros(7, dtype=np.float32), None

    sampled, every_step, _ = physics_rate_errors(Zero(), kwargs, 1000)
    assert every_step != pytest.approx(sampled, rel=1e-3)


@pytest.mark.parametrize("env_id", ["cir_gym/JointTracking-v2", "cir_gym/ElasticJointTracking-v3"])
@pytest.mark.parametrize("setting", [{"torque_noise": 0.5}, {"encoder_resolution": 1e-3}])
def test_a_sensor_or_noise_setting_changed_between_episodes_holds_from_the_next_reset(
    env_id: str, setting: dict
) -> None:
    """The step's shortcuts for an ideal drive (no noise, no encoder: the measured rows copied
    as they are) are rebuilt at reset: an env whose torque_noise or encoder_resolution is set
    after construction plays the next episode as one built with it (the same seeds)."""
    built = gym.make(env_id, **setting).unwrapped
    changed = gym.make(env_id).unwrapped
    changed.reset(seed=0)
    changed.step(np.zeros(7))  # an episode played with the ideal settings first
    for key, value in setting.items():
        setattr(changed, key, value)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.2, 0.2, (30, 7))
    obs_b, _ = built.reset(seed=3)
    obs_c, _ = changed.reset(seed=3)
    for k in obs_b:
        np.testing.assert_array_equal(obs_b[k], obs_c[k])
    for a in actions:
        ob, rb, *_ = built.step(a)
        oc, rc, *_ = changed.step(a)
        assert rb == rc
        for k in ob:
            np.testing.assert_array_equal(ob[k], oc[k])
