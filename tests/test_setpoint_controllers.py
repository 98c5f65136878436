"""The course's controllers on the agent-ready interface (baselines/setpoint.py): what the
physics of each task shows they do, that a batch of rows gives each row's action alone and
batched episodes the sequential ones.

Measured (results quoted in the commit and the lead's report; seeds 1000-1029): on
PegInHoleImpedance-v0 impedance_insertion inserts through the 3-mm chamfer 30/30, and on the
sharp edge only where the hole happens to lie within the clearance (2/30); impedance_spiral
finds and inserts 26/30 there. The tests use a few of those seeds.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from cir_gym.baselines import setpoint
from cir_gym.baselines.base import InvalidGain

from cir_gym import baselines
from cir_gym.evaluation import EvaluationResult, evaluate
from cir_gym.scoring.policies import policy_names

PEG = "cir_gym/PegInHoleImpedance-v0"
CONTACT = "cir_gym/AdmittanceContactImpedance-v1"
CHAMFER = {"chamfer": 0.003}
#: batched and sequential episodes of the agent-ready variants agree to round-off
#: (tests/test_vector_agent_ready.py holds each batched copy to its single env at 1e-12)
TOL = 1e-9


def _episodes(name: str, env_id: str, seeds: int, seed: int, **kw) -> EvaluationResult:
    return evaluate(baselines.make(name, env_id, env_kwargs=kw), env_id, seeds, seed, **kw)


def test_the_controllers_are_the_agent_ready_ids_policies() -> None:
    assert baselines.available(PEG) == ["impedance_insertion", "impedance_spiral"]
    assert baselines.available(CONTACT) == [
        "impedance_setpoint", "admittance_setpoint", "implicit_force_setpoint"]
    assert {"impedance_insertion", "impedance_spiral"} <= set(policy_names(PEG))
    assert "impedance_setpoint" in policy_names(CONTACT)
    # the torque interface and a variable stiffness are refused, naming what is needed
    with pytest.raises(ValueError, match="does not apply"):
        baselines.make("impedance_insertion", "cir_gym/PegInHole-v2")
    with pytest.raises(InvalidGain, match="variable_stiffness=False"):
        baselines.make("impedance_spiral", PEG, env_kwargs={"variable_stiffness": True})
    with pytest.raises(InvalidGain, match="search_force"):
        baselines.make("impedance_spiral", PEG, search_force=-1.0)


@pytest.mark.parametrize("gains, match", [
    (lambda: setpoint.ImpedanceSpiralGains(search_force="2"),
     "gain 'search_force' of controller 'impedance_spiral' must be a finite real number"),
    (lambda: setpoint.ImpedanceSpiralGains(pitch=0.0), "gain 'pitch' .* > 0, got 0.0"),
    (lambda: setpoint.ImpedanceInsertionGains(speed=float("nan")), "gain 'speed'"),
    (lambda: setpoint.ImpedanceSetpointGains(normal_stiffness="1e3"),
     "gain 'normal_stiffness' of controller 'impedance_setpoint' .* or None, got '1e3'"),
    (lambda: setpoint.ImpedanceSetpointGains(approach_speed="2"), "gain 'approach_speed'"),
])
def test_gains_built_directly_refuse_a_bad_value_naming_the_gain(gains, match) -> None:
    """A Gains built without ``make`` checks types as ``make`` does (InvalidGain, not a
    TypeError from the range check) and the ranges."""
    with pytest.raises(InvalidGain, match=match):
        gains()


def test_impedance_setpoint_refuses_a_force_ramp_as_impedance_does() -> None:
    """ramp_time shapes a force reference; impedance_setpoint has none (its sink is static),
    as interaction.Impedance, so ramp_time > 0 is refused in the same words."""
    with pytest.raises(InvalidGain, match="ramp_time must be 0 for impedance_setpoint"):
        baselines.make("impedance_setpoint", CONTACT, ramp_time=0.3)
    with pytest.raises(InvalidGain, match="no force reference to shape"):
        setpoint.ImpedanceSetpointGains(ramp_time=0.3)
    assert baselines.make("impedance_setpoint", CONTACT, ramp_time=0).gains.ramp_time == 0.0


def test_insertion_presses_the_face_with_the_designed_force() -> None:
    """f = K·Δx: on the sharp edge with the hole 1.4 mm off (seed 1000) the peg lands on the
    face and stays there, the setpoint Δ = f̄/K_z = 8 mm below the tip, and the wrist reads
    f̄ = 8 N along the axis (the largest single contact force the same)."""
    env = gym.make(PEG, episode_duration=8.0)
    policy = baselines.make("impedance_insertion", PEG, env=env)
    obs, _ = env.reset(seed=1000)
    state, start, done = None, True, False
    while not done:
        action, state = policy.predict(obs, state, episode_start=[start])
        start = False
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    peg = policy.peg_frame({k: v[None] for k, v in obs.items()})
    assert not info["is_success"] and abs(obs["peg_pos"][2]) < 2e-4  # on the face
    assert peg.x[0, 2] - peg.x_d[0, 2] == pytest.approx(0.008, abs=1e-4)  # the lead Δ
    assert peg.push[0] == pytest.approx(8.0, abs=0.3)  # K Δ
    assert info["contact_force"] == pytest.approx(8.0, abs=0.5)


def test_insertion_through_the_chamfer_and_spiral_search_on_the_sharp_edge() -> None:
    """The chamfer guides the laterally free peg into holes up to 2 mm off (seeds 1000-1001:
    1.4 and 1.6 mm), inserted in about 7 s with small forces; on the sharp edge the spiral
    finds holes 0.9 and 0.6 mm off (seeds 1003, 1005)."""
    chamfer = _episodes("impedance_insertion", PEG, 2, 1000, **CHAMFER)
    assert all(e.success for e in chamfer.episodes)
    assert all(e.metrics["insertion_time"] < 8.0 for e in chamfer.episodes)
    assert all(e.metrics["peak_force"] < 60.0 for e in chamfer.episodes)
    spiral = [_episodes("impedance_spiral", PEG, 1, seed).episodes[0] for seed in (1003, 1005)]
    assert all(e.success for e in spiral)
    assert all(e.metrics["insertion_time"] < 10.0 for e in spiral)


def test_impedance_setpoint_presses_with_the_reference_on_the_nominal_surface() -> None:
    """With the surface where the controllers think it is (no height or tilt error) the
    designed sink f̄ (1/K + 1/k̂) gives f̄: the force RMS error is a fraction of a newton
    (success) on the 1e4 and 1e5 N/m plates, while wiping."""
    for stiffness in (1e4, 1e5):
        kw = dict(stiffness=stiffness, force_ref=20.0, height_error=0.0, tilt_error=0.0)
        result = _episodes("impedance_setpoint", CONTACT, 2, 1000, **kw)
        assert all(e.success for e in result.episodes)
        assert all(e.metrics["force_rms_error"] < 0.5 for e in result.episodes)
        assert all(e.metrics["path_error"] < 0.005 for e in result.episodes)


def test_impedance_setpoint_sink_is_impedance_s_design() -> None:
    """The sink is interaction.Impedance's f̄ (1/K_d,n + 1/k̂) with K_d,n the loop's stiffness
    along the normal (1000 N/m by default, 400 N/m when the env says so)."""
    for k_loop in (1000.0, 400.0):
        policy = baselines.make("impedance_setpoint", CONTACT,
                                env_kwargs={"stiffness": 1e4, "impedance_stiffness": k_loop})
        torque = baselines.make("impedance", "cir_gym/AdmittanceContact-v2",
                                env_kwargs={"stiffness": 1e4}, normal_stiffness=k_loop)
        f = np.array([5.0, 20.0])
        assert policy.sink(f) == pytest.approx(torque.sink(f), rel=1e-15)
        assert policy.sink(f) == pytest.approx(f * (1 / k_loop + 1e-4), rel=1e-15)


def test_impedance_setpoint_leads_by_the_env_s_damping() -> None:
    """The velocity lead K_p⁻¹ K_d = 2ζ √(Λ/K_p) uses the env's ζ, which the context carries
    (``impedance_damping_ratio``): at ζ = 0.5 it is half the lead at the default ζ = 1."""
    leads = {}
    for zeta in (1.0, 0.5):
        env = gym.make(CONTACT, damping_ratio=zeta)
        assert env.unwrapped.controller_context().extras["impedance_damping_ratio"] == zeta
        policy = baselines.make("impedance_setpoint", CONTACT, env=env)
        obs, _ = env.reset(seed=1000)
        policy.predict(obs, None, episode_start=[True])
        leads[zeta] = policy.velocity_lead.copy()
        env.close()
    assert np.all((leads[1.0] > 0.1) & (leads[1.0] < 0.4))  # s: 0.17-0.27 s per world axis
    np.testing.assert_allclose(leads[0.5], 0.5 * leads[1.0], rtol=1e-12)


def _rows_alone(env_id: str, name: str, steps: int, **kw) -> None:
    """On 3 copies of the batched env, the action of the stacked observations is each row's
    own (bit for bit), with each row's state."""
    envs = gym.make_vec(env_id, num_envs=3, **kw)
    policy = baselines.make(name, env_id, env_kwargs=kw)
    obs, _ = envs.reset(seed=[1000, 1003, 1005])
    state, starts = None, np.ones(3, bool)
    singles = [None] * 3
    for _ in range(steps):
        actions, new_state = policy.predict(obs, state, episode_start=starts)
        for i in range(3):
            row = {k: v[i] for k, v in obs.items()}
            single, singles[i] = policy.predict(row, singles[i], episode_start=[starts[i]])
            np.testing.assert_array_equal(single, actions[i])
            np.testing.assert_array_equal(singles[i][0], new_state[i])
        state, starts = new_state, np.zeros(3, bool)
        obs, *_ = envs.step(actions)
    envs.close()


def test_a_batch_of_rows_gives_each_row_its_own_action() -> None:
    _rows_alone(PEG, "impedance_spiral", 70)  # through the landing and into the search
    _rows_alone(PEG, "impedance_insertion", 90, **CHAMFER)  # into the bore
    _rows_alone(CONTACT, "impedance_setpoint", 50)  # the approach, contact, the wipe's start


@pytest.mark.parametrize("name, env_id, kw", [
    ("impedance_insertion", PEG, {"episode_duration": 8.0, **CHAMFER}),
    ("impedance_spiral", PEG, {"episode_duration": 4.0}),
    ("impedance_setpoint", CONTACT, {"episode_duration": 3.0, "randomize": True}),
])
def test_batched_evaluation_gives_the_sequential_episodes(name, env_id, kw) -> None:
    policy = baselines.make(name, env_id, env_kwargs=kw)
    fast = evaluate(policy, env_id, 2, 1000, **kw)
    slow = evaluate(policy, env_id, 2, 1000, batched=False, **kw)
    for f, s in zip(fast.episodes, slow.episodes, strict=True):
        assert (f.seed, f.length, f.success, f.terminated) == (s.seed, s.length, s.success,
                                                              s.terminated)
        assert f.episode_return == pytest.approx(s.episode_return, rel=TOL, abs=TOL)
        assert f.metrics == pytest.approx(s.metrics, rel=TOL, abs=TOL)
