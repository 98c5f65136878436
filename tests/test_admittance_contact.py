"""AdmittanceContact-v0 and the chapter-6 controllers (baselines.interaction) against the theory."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from cir_gym.baselines.base import InvalidGain

import cir_gym  # noqa: F401  (registers the environments)
from cir_gym import baselines
from cir_gym.envs.admittance_contact import RANDOM_RANGES, AdmittanceContactEnv
from cir_gym.validation import InvalidArgument

ENV_ID = "cir_gym/AdmittanceContact-v0"


def _run(name: str, env_kwargs: dict, seed: int = 1, **gains) -> tuple[list[dict], dict, object]:
    """One episode of controller ``name``; the infos, the last obs and the policy."""
    env = gym.make(ENV_ID, **env_kwargs)
    policy = baselines.make(name, ENV_ID, env=env, **gains)
    obs, _ = env.reset(seed=seed)
    state, start, infos = None, True, []
    while True:
        action, state = policy.predict(obs, state, np.array([start]))
        start = False
        obs, _, terminated, truncated, info = env.step(action)
        info["obs"] = obs
        infos.append(info)
        if terminated or truncated:
            return infos, obs, policy


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"control": "velocity"}, "control"),
        ({"stiffness": 10.0}, "stiffness"),
        ({"stiffness": 1e6}, "stiffness"),
        ({"sensor": "robotiq"}, "sensor"),
        ({"sensor_rate": 5000.0}, "sensor_rate"),
        ({"sensor_noise": (0.1, 0.1, 0.1)}, "sensor_noise"),
        ({"force_ref": 80.0}, "force_ref"),
        ({"tilt_error": 1.0}, "tilt_error"),
        ({"timestep": 0.01}, "timestep"),
        ({"timestep": 0.0003}, "control_freq"),  # 2 ms is not a whole number of 0.3-ms steps
        # a tiny rate once asked the scene for ~4e296 steps of sensor history (TypeError)
        ({"control_freq": 1e-300}, "control_freq"),
        ({"control_freq": 333.0}, "control_freq"),
    ],
)
def test_bad_arguments_name_the_argument(kwargs: dict, name: str) -> None:
    with pytest.raises(InvalidArgument, match=name):
        AdmittanceContactEnv(**kwargs)


def test_randomize_draws_stiffness_damping_and_bias_in_their_ranges() -> None:
    env = AdmittanceContactEnv(randomize=True, episode_duration=0.1)
    draws = [env.reset(seed=s)[1]["surface"] for s in range(8)]
    k = np.array([d["stiffness"] for d in draws])
    assert np.all((k >= 1e3) & (k <= 1e5)) and np.ptp(np.log10(k)) > 0.5
    lo, hi = RANDOM_RANGES["damping"]
    assert all(lo <= d["damping"] <= hi for d in draws)
    assert all(np.all(np.abs(d["sensor_bias"][:3]) <= 2.0) for d in draws)
    assert all(5.0 <= d["force_ref"] <= 30.0 for d in draws)
    assert env.controller_context().extras["stiffness"] is None  # unknown to the controllers
    env.reset(seed=3)
    assert env.model.jnt_stiffness[env._slide_jnt] == draws[3]["stiffness"]


def test_an_episode_without_contact_scores_f_ref_and_full_contact_loss() -> None:
    env = AdmittanceContactEnv(control="position", force_ref=12.0, episode_duration=0.2)
    env.reset(seed=0)
    while True:  # hold the start pose, 3 cm above the surface
        _, _, terminated, truncated, info = env.step(np.zeros(6))
        if terminated or truncated:
            break
    m = info["episode_metrics"]
    assert m["force_rms_error"] == 12.0 and m["contact_loss"] == 1.0 and m["max_force"] == 0.0
    assert info["is_success"] is False


@pytest.mark.parametrize("stiffness", [1.0e3, 1.0e4, 1.0e5])
def test_no_contact_explosion_at_any_stiffness(stiffness: float) -> None:
    """Driving the tool into an undamped surface at full speed (0.25 m/s) ends at the force
    limit as a failure, never a divergence; the force never jumps far past the limit."""
    env = AdmittanceContactEnv(
        control="position", stiffness=stiffness, damping=0.0, episode_duration=1.0, sensor="ideal"
    )
    env.reset(seed=0)
    forces = []
    while True:
        obs, reward, terminated, truncated, info = env.step(np.array([0, 0, -1.0, 0, 0, 0]))
        forces.append(info["contact_force"])
        assert all(np.all(np.isfinite(v)) for v in obs.values()) and np.isfinite(reward)
        if terminated or truncated:
            break
    assert info["force_limit_exceeded"] and not info["diverged"]
    assert max(forces) < 1.5 * env.force_limit
    assert env.plate_deflection() * stiffness < 1.5 * env.force_limit


@pytest.mark.parametrize("stiffness", [1.0e3, 1.0e5])
def test_impedance_presses_with_kd_times_the_setpoint_penetration(stiffness: float) -> None:
    """No force loop: in steady state f = K_d,n (x − x_d)·n̂ (within 5 %), and on the soft
    surface the force is the series springs' K_d k/(K_d + k) × the setpoint's sink, not f̄."""
    env_kwargs = {
        "stiffness": stiffness,
        "force_ref": 10.0,
        "episode_duration": 1.9,
        "height_error": 0.0,
        "tilt_error": 0.0,
    }
    infos, _, policy = _run("impedance", env_kwargs)
    kd = policy.gains.normal_stiffness
    n = policy.normal
    window = infos[-150:]  # 1.6-1.9 s: pressed, before the wipe
    force = np.mean([i["contact_force"] for i in window])
    penetration = np.mean(
        [n @ (i["obs"]["tool_pos"] - policy.setpoint(i["obs"])[0]) for i in window]
    )
    assert force == pytest.approx(kd * penetration, rel=0.05)
    sink = 10.0 / kd  # the setpoint is f̄/K_d below the (here exact) nominal surface
    assert force == pytest.approx(kd * stiffness / (kd + stiffness) * sink, rel=0.05)


def test_explicit_force_above_its_crossover_rule_fails_on_the_stiff_surface() -> None:
    """K_if = 0.5 ω_n holds the contact at 1e5 N/m; K_if = 3 ω_n (> 2ζω_n, Routh) oscillates
    until the force limit stops the episode or the contact is lost."""
    env_kwargs = {"stiffness": 1.0e5, "force_ref": 20.0, "episode_duration": 2.8}
    ok, _, _ = _run("explicit_force", env_kwargs, crossover_ratio=0.5, cap_at_sensor=False)
    assert not ok[-1]["force_limit_exceeded"]
    pressed = [i["contact_force"] for i in ok[-150:]]  # 2.5-2.8 s, wiping
    assert min(pressed) > 0.5 and abs(np.mean(pressed) - 20.0) < 2.0
    bad, _, _ = _run("explicit_force", env_kwargs, crossover_ratio=3.0, cap_at_sensor=False)
    lost = np.mean([not i["in_contact"] for i in bad[len(bad) // 2 :]])
    assert bad[-1]["force_limit_exceeded"] or lost > 0.05


def test_admittance_on_the_position_interface_regulates_the_force() -> None:
    env_kwargs = {
        "control": "position",
        "stiffness": 1.0e4,
        "force_ref": 15.0,
        "episode_duration": 2.8,
    }
    infos, _, _ = _run("admittance", env_kwargs)
    pressed = [i["contact_force"] for i in infos[-150:]]
    assert abs(np.mean(pressed) - 15.0) < 2.0 and min(pressed) > 8.0  # wiping since 2 s


@pytest.mark.parametrize("name", ["impedance", "explicit_force"])
def test_torque_laws_refuse_the_position_interface(name: str) -> None:
    with pytest.raises(InvalidGain, match="torque"):
        baselines.make(name, ENV_ID, env_kwargs={"control": "position"})


def test_every_interaction_controller_applies_and_gains_are_checked() -> None:
    names = baselines.available(ENV_ID)
    assert {
        "impedance",
        "admittance",
        "explicit_force",
        "implicit_force",
        "parallel_force_position",
    } <= set(names)
    with pytest.raises(InvalidGain, match="crossover"):
        baselines.make("admittance", ENV_ID, crossover=-1.0)


def test_torque_interface_reads_every_physics_step_from_the_sensor_history() -> None:
    """One mj_step call per control period: the wrist sensor model gets each physics step's
    wrench in time order and the contact flag each step's plate force, exactly as when the
    period is stepped one physics step at a time."""
    import copy

    import mujoco

    from cir_gym.envs.admittance_contact import surface_force

    env = gym.make(ENV_ID, stiffness=1e4, force_ref=20.0, sensor_noise=0.0, sensor_resolution=0.0)
    u = env.unwrapped
    policy = baselines.make("explicit_force", ENV_ID, env=env)
    obs, _ = env.reset(seed=2)
    state, start, info = None, True, {"in_contact": False}
    for _ in range(1500):  # until the tool presses on the plate
        action, state = policy.predict(obs, state, np.array([start]))
        start = False
        obs, _, _, _, info = env.step(action)
        if info["in_contact"] and info["contact_force"] > 5.0:
            break
    assert info["in_contact"]
    action, state = policy.predict(obs, state, np.array([False]))
    # the reference: the same period one physics step at a time on a copy of the state
    m = u.model
    d = mujoco.MjData(m)
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    buf = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, u.data, buf, spec)
    mujoco.mj_setState(m, d, buf, spec)
    d.ctrl[:] = np.clip(action, -1, 1) * u.torque_limit
    sensor = copy.deepcopy(u.sensor)
    contact = []
    for _ in range(u._substeps):
        mujoco.mj_step(m, d)
        sensor.update(d.sensordata[u._sensor_adr])
        contact.append(-u._normal @ surface_force(m, d, u._plate_geom))
    _, _, _, _, info = env.step(action)
    np.testing.assert_array_equal(u.sensor.reading, sensor.reading)
    np.testing.assert_array_equal(u.sensor._filtered, sensor._filtered)
    hist = u.sensor_history(2) @ u._normal
    np.testing.assert_allclose(hist, contact, rtol=1e-9, atol=1e-9)
    assert np.ptp(contact) > 0.1 and info["in_contact"]  # values differ: the order is tested


def test_explicit_force_reference_ramps_from_the_contact_force_to_f_ref() -> None:
    """The quintic ramp starts at the contact force at rest and ends at f̄ at rest; its
    derivatives are the quintic's (central differences); ramp_time=0 is a step to f̄."""
    env = gym.make(ENV_ID, stiffness=1e4, force_ref=20.0)
    law = baselines.make("explicit_force", ENV_ID, env=env)
    from cir_gym.baselines.interaction import _COMMON

    state = np.zeros(law.state_size)
    state[_COMMON + 2] = 3.0  # f̂ at contact (N)
    T = law.ramp_time
    assert T == pytest.approx(0.3)

    def ref(t: float) -> np.ndarray:
        state[_COMMON + 1] = t
        return np.array(law.reference(20.0, state))

    np.testing.assert_allclose(ref(0.0), [3.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(ref(T), [20.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(ref(2 * T), [20.0, 0.0, 0.0], atol=1e-12)
    assert ref(T / 2)[0] == pytest.approx(11.5)  # the quintic is symmetric about its midpoint
    h = 1e-6
    for t in (0.05, 0.13, 0.21):
        assert ref(t)[1] == pytest.approx((ref(t + h)[0] - ref(t - h)[0]) / (2 * h), rel=1e-5)
        assert ref(t)[2] == pytest.approx((ref(t + h)[1] - ref(t - h)[1]) / (2 * h), rel=1e-4)
    step = baselines.make("explicit_force", ENV_ID, env=env, ramp_time=0.0)
    assert step.reference(20.0, state) == (20.0, 0.0, 0.0)
