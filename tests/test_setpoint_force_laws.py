"""The course's position-based force laws on the agent-ready contact variant
(baselines/setpoint.py: admittance_setpoint, implicit_force_setpoint): their gains are the
design rule's numbers on the env's own loop, the force converges to f̄ on a plate of known
stiffness, a batch of rows gives each row's action alone, and bad gains are refused by name.

The variant's id is looked up in the registry (its version changes with the task's).
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from cir_gym.baselines import setpoint
from cir_gym.baselines.base import InvalidGain
from cir_gym.baselines.interaction import CommonGains

import cir_gym
from cir_gym import baselines
from cir_gym.scoring.policies import policy_names, task_id

CONTACT = next(e for e in cir_gym.ENVIRONMENTS
               if e.startswith("cir_gym/AdmittanceContactImpedance-"))
FORCE_LAWS = ("admittance_setpoint", "implicit_force_setpoint")
#: the surface where the controllers think it is: no height or tilt error to integrate away
FLAT = {"force_ref": 20.0, "height_error": 0.0, "tilt_error": 0.0, "episode_duration": 6.0}


def test_the_force_laws_are_the_contact_variant_s_controllers() -> None:
    assert set(FORCE_LAWS) <= set(baselines.available(CONTACT))
    assert set(FORCE_LAWS) <= set(policy_names(CONTACT))
    with pytest.raises(ValueError, match="does not apply"):
        baselines.make("admittance_setpoint", task_id(CONTACT))  # the torque interface
    with pytest.raises(InvalidGain, match="variable_stiffness=False"):
        baselines.make("implicit_force_setpoint", CONTACT,
                       env_kwargs={"variable_stiffness": True})


def _designed(name: str, **kw):
    """The law ``name`` designed at the env's start posture, the env's loop damping along the
    normal K_d,z (N s/m) and the sensor's lag τ_s (s), from the env itself."""
    gains = {k: kw.pop(k) for k in ("crossover", "normal_stiffness") if k in kw}
    env = gym.make(CONTACT, **kw)
    policy = baselines.make(name, CONTACT, env=env, **gains)
    obs, _ = env.reset(seed=1000)
    policy.predict(obs, None, episode_start=[True])  # designs at q₀
    ex = env.unwrapped.controller_context().extras
    tau_s = (ex["sensor_delay"] + ex["sensor_period"] / 2 + 1 / (2 * math.pi * ex["sensor_cutoff"])
             + env.unwrapped.dt + ex["physics_timestep"])
    K_dz = env.unwrapped.K_d[2]
    env.close()
    return policy, K_dz, tau_s


@pytest.mark.parametrize("kw, k_hat, rounded", [
    ({"randomize": True}, 1e5, 4.89),  # unknown: the stiffest plate, the sensor binds
    ({"stiffness": 1e3}, 1e3, 3.45),  # a known soft plate: the loop's lag binds
    ({"stiffness": 1e5, "crossover": 2.0}, 1e5, 2.0),  # the gain caps it lower
    ({"stiffness": 1e5, "crossover": 50.0}, 1e5, 4.89),  # never above the rule
    # K_p,n overridden: the loop's lag (K_p + k̂)/(3 K_d,n) with the env's damping binds
    ({"stiffness": 1e3, "normal_stiffness": 1500.0}, 1e3, 4.32),
])
def test_gains_are_the_design_rule_s(kw, k_hat, rounded) -> None:
    """ω_c = min(crossover, 1/(3 τ_s), (K_p + k̂)/(3 K_d,n)); admittance D_d = k̂_e/ω_c,
    M_d = D_d K_d,n/K_env (the filter's pole on the lead's zero); implicit k_Pf = ω_c,
    k_If = ω_c²/4, the compensator's ω_i = K_env/K_d,n; k̂_e = 1/(1/K_p + 1/k̂). K_p is the
    ``normal_stiffness`` gain (default the env's K_env = 1000 N/m); K_d,n and ω_L are the
    env's own whatever K_p says."""
    admittance, K_dz, tau_s = _designed("admittance_setpoint", **dict(kw))
    implicit, _, _ = _designed("implicit_force_setpoint", **dict(kw))
    K_env = 1000.0
    K_p = kw.get("normal_stiffness", K_env)
    w_c = min(kw.get("crossover", math.inf), 1 / (3 * tau_s), (K_p + k_hat) / (3 * K_dz))
    k_e = 1 / (1 / K_p + 1 / k_hat)
    assert w_c == pytest.approx(rounded, abs=0.005)
    assert admittance.k_hat == implicit.k_hat == k_hat
    assert admittance.normal_damping == pytest.approx(K_dz, rel=1e-12)
    assert admittance.omega_c == pytest.approx(w_c, rel=1e-12)
    assert admittance.k_e == implicit.k_e == pytest.approx(k_e, rel=1e-12)
    assert admittance.D_d == pytest.approx(k_e / w_c, rel=1e-12)
    assert admittance.M_d == pytest.approx(k_e / w_c * K_dz / K_env, rel=1e-12)
    assert admittance.gains.stiffness_normal == 0.0  # integral force control
    assert implicit.k_pf == pytest.approx(w_c, rel=1e-12)
    assert implicit.k_if == pytest.approx(w_c**2 / 4, rel=1e-12)
    assert implicit.omega_i == pytest.approx(K_env / K_dz, rel=1e-12)


def _forces(name: str, seed: int, **kw) -> np.ndarray:
    """The normal force f (N) of each policy step of an episode of ``name`` (as long as the
    env's ``episode_duration``)."""
    steps = round(kw.get("episode_duration", 5.0) / 0.05)  # 20-Hz policy steps
    env = gym.make(CONTACT, max_episode_steps=steps, **kw)
    policy = baselines.make(name, CONTACT, env=env)
    obs, _ = env.reset(seed=seed)
    state, start, forces = None, [True], []
    while True:
        action, state = policy.predict(obs, state, episode_start=start)
        start = [False]
        obs, _, terminated, truncated, info = env.step(action)
        forces.append(info["contact_force"])
        if terminated or truncated:
            break
    env.close()
    return np.array(forces)


@pytest.mark.filterwarnings("ignore:.*registered max_episode_steps")  # 6 s, told to make
@pytest.mark.parametrize("name, stiffness, settle", [
    ("admittance_setpoint", 1e4, 1.5),  # measured: within 0.5 N after 0.55 s
    ("admittance_setpoint", 1e3, 1.5),  # after 1.0 s (ω_c 3.45 rad/s: the loop's lag binds)
    ("implicit_force_setpoint", 1e4, 2.5),  # after 1.75 s: the PI zero's slow overshoot
])
def test_the_force_converges_to_the_reference_on_a_known_plate(name, stiffness, settle) -> None:
    """On a flat plate of known stiffness the force is within 0.5 N of f̄ = 20 N from
    ``settle`` s after the first contact to the end of the episode, the wipe included."""
    f = _forces(name, 1000, stiffness=stiffness, **FLAT)
    first = int(np.argmax(f > 0.5))
    settled = f[first + round(settle / 0.05):]
    assert first > 0 and len(settled) >= 30  # 1.5 s of it or more, while wiping
    assert np.max(np.abs(settled - 20.0)) < 0.5


@pytest.mark.parametrize("name", FORCE_LAWS)
def test_rows_of_every_phase_equal_each_row_alone(name) -> None:
    """Stacked observations and states of three randomized episodes (holding still,
    approaching, in contact, wiping) give each row's action and new state alone, bit for
    bit."""
    env = gym.make(CONTACT, randomize=True)
    policy = baselines.make(name, CONTACT, env=env)
    rows, states, touching = [], [], []
    for seed in (1000, 1003, 1005):
        obs, _ = env.reset(seed=seed)
        state, start = None, [True]
        for k in range(70):
            action, new_state = policy.predict(obs, state, episode_start=start)
            if k % 3 == 1:
                rows.append(obs)
                states.append(state[0].copy())
            state, start = new_state, [False]
            obs, _, _, _, info = env.step(action)
            touching.append(info["contact_force"] > 0.5)
    env.close()
    assert any(touching) and not all(touching)
    stacked = {key: np.stack([r[key] for r in rows]) for key in rows[0]}
    actions, new_states = policy.predict(stacked, np.array(states), np.zeros(len(rows), bool))
    for i, obs in enumerate(rows):
        action, new_state = policy.predict(obs, states[i][None].copy(), [False])
        np.testing.assert_array_equal(actions[i], action)
        np.testing.assert_array_equal(new_states[i], new_state[0])


@pytest.mark.parametrize("gains, match", [
    (lambda: baselines.make("admittance_setpoint", CONTACT, crossover=-1.0),
     "gain 'crossover' of controller 'admittance_setpoint' must be a finite number > 0"),
    (lambda: setpoint.AdmittanceSetpointGains(crossover=float("nan")), "crossover"),
    (lambda: setpoint.AdmittanceSetpointGains(damping="2"),
     "gain 'damping' of controller 'admittance_setpoint' must be a finite real number"),
    (lambda: setpoint.AdmittanceSetpointGains(mass=0.0), "mass must be a finite number > 0"),
    (lambda: setpoint.ImplicitForceSetpointGains(integral_ratio=-0.1), "integral_ratio"),
    (lambda: setpoint.ImplicitForceSetpointGains(normal_stiffness=0.0),
     "gain 'normal_stiffness' of controller 'implicit_force_setpoint' .* > 0, got 0.0"),
    (lambda: baselines.make("implicit_force_setpoint", CONTACT, contact_force="1"),
     "contact_force"),
    (lambda: baselines.make("admittance_setpoint", CONTACT, ramp_time=-0.5), "ramp_time"),
    (lambda: setpoint.LoopGains(normal_stiffness=-1.0), "'normal_stiffness' .* > 0"),
    (lambda: setpoint.LoopGains(slow_speed=0.0), "slow_speed must be a finite number > 0"),
    (lambda: setpoint.ForceLoopGains(crossover=0.0), "'crossover' .* > 0"),
])
def test_bad_gains_raise_invalid_gain_naming_the_gain(gains, match) -> None:
    with pytest.raises(InvalidGain, match=match):
        gains()


def test_the_shared_gains_stand_alone() -> None:
    """LoopGains and ForceLoopGains are interaction gains (CommonGains) of their own: built
    alone, they hold the interaction laws' fields with this interface's contact force."""
    loop, force = setpoint.LoopGains(), setpoint.ForceLoopGains(crossover=2.0)
    assert isinstance(loop, CommonGains) and isinstance(force, setpoint.LoopGains)
    assert loop.contact_force == 1.0 and loop.normal_stiffness is None
    assert loop.slow_speed == CommonGains().slow_speed
    assert force.crossover == 2.0


@pytest.mark.parametrize("name", FORCE_LAWS)
def test_the_force_laws_take_the_interaction_laws_force_ramp(name) -> None:
    """ramp_time is offered to every force law (0, the course's step, by default)."""
    assert baselines.make(name, CONTACT).gains.ramp_time == 0.0
    assert baselines.make(name, CONTACT, ramp_time=0.5).gains.ramp_time == 0.5
