"""The wrist F/T sensor model, the compliant surface's spring and the position interface."""

from __future__ import annotations

import math

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import cir_gym
from cir_gym.envs.admittance_contact import (
    JOINTS,
    START_Q,
    TOOL_COM,
    TOOL_MASS,
    AdmittanceContactEnv,
    build_model,
    tool_robot,
)
from cir_gym.envs.base import constructor_arguments
from cir_gym.ft_sensor import (
    PRESETS,
    SensorSpec,
    WrenchSensor,
    contact_wrench,
    preset,
    sensor_spec,
    tool_gravity_wrench,
)
from cir_gym.motion_interface import MEASURED_BANDWIDTH_HZ, CartesianMotionInterface
from cir_gym.robot import Robot
from cir_gym.validation import InvalidArgument

H = 1e-3  # physics step (s)


def _run(sensor: WrenchSensor, signal: np.ndarray) -> np.ndarray:
    sensor.reset(np.random.default_rng(0), signal[0])
    return np.array([sensor.update(w) for w in signal[1:]])


def test_ideal_sensor_reads_the_true_wrench_every_step() -> None:
    signal = np.random.default_rng(1).normal(size=(50, 6))
    out = _run(WrenchSensor(PRESETS["ideal"], H), signal)
    np.testing.assert_array_equal(out, signal[1:])


def test_first_order_filter_step_response_is_one_minus_exp() -> None:
    cutoff = 20.0
    sensor = WrenchSensor(SensorSpec(cutoff=cutoff), H)
    signal = np.zeros((101, 6))
    signal[1:] = 1.0
    out = _run(sensor, signal)
    n = np.arange(1, 101)
    np.testing.assert_allclose(out[:, 2], 1 - np.exp(-2 * math.pi * cutoff * n * H), rtol=1e-12)


def test_delay_and_zero_order_hold() -> None:
    sensor = WrenchSensor(SensorSpec(sample_rate=100.0, delay=0.004), H)
    assert sensor.sample_steps == 10 and sensor.delay_steps == 4
    assert sensor.sample_period == pytest.approx(0.01)
    signal = np.outer(np.arange(60.0), np.ones(6))  # w(k) = k
    out = _run(sensor, signal)[:, 0]
    # samples at steps 10, 20, ... of the value 4 steps earlier, held in between
    expected = [0.0 if k < 10 else 10 * (k // 10) - 4 for k in range(1, 60)]
    np.testing.assert_array_equal(out, expected)


def test_noise_bias_and_resolution() -> None:
    spec = sensor_spec("ati_gamma", bias=(1, -2, 3, 0.1, 0.2, -0.3), cutoff=math.inf, delay=0.0)
    sensor = WrenchSensor(spec, H)
    out = _run(sensor, np.zeros((20001, 6)))
    np.testing.assert_allclose(out.mean(0), spec.bias, atol=5e-4)
    np.testing.assert_allclose(out[:, :3].std(0), 0.01, rtol=0.05)
    np.testing.assert_allclose(out[:, 3:].std(0), 0.0005, rtol=0.1)
    quanta = out[:, :3] / spec.resolution[0]
    np.testing.assert_allclose(quanta, np.round(quanta), atol=1e-9)


def test_presets_are_the_cited_sensors() -> None:
    robotiq, ati = PRESETS["robotiq_ft300"], PRESETS["ati_gamma"]
    assert robotiq.sample_rate == 100.0 and robotiq.noise_std[0] == 0.1
    assert ati.sample_rate == 1000.0 and ati.noise_std[0] == 0.01


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"noise_std": -1.0}, "noise_std"),
        ({"resolution": (0.1, 0.2, 0.3)}, "resolution"),
        ({"sample_rate": 0.0}, "sample_rate"),
        ({"cutoff": float("nan")}, "cutoff"),
        ({"delay": 2.0}, "delay"),
        ({"bias": (1.0, 2.0)}, "bias"),
    ],
)
def test_bad_sensor_parameters_name_the_parameter(kwargs: dict, name: str) -> None:
    with pytest.raises(InvalidArgument, match=name):
        SensorSpec(**kwargs)


def test_unknown_preset_and_too_fast_sampling_are_rejected() -> None:
    with pytest.raises(InvalidArgument, match="robotiq_ft300"):
        sensor_spec("robotiq")
    with pytest.raises(InvalidArgument, match="sample_rate"):
        WrenchSensor(SensorSpec(sample_rate=5000.0), H)


#: values of ``sensor`` that are no preset: unhashable ones raised a bare TypeError before
NOT_PRESETS = [["ati_gamma"], {"ati_gamma": 1}, ("ati_gamma",), None, 3, "ATI_GAMMA"]
SENSOR_ENVS = [e for e, (cls, _) in cir_gym.ENVIRONMENTS.items()
               if "sensor" in constructor_arguments(cls)]
assert len(SENSOR_ENVS) >= 2, SENSOR_ENVS  # PegInHole and AdmittanceContact at least


def _names_sensor_value_and_presets(message: str, value: object) -> None:
    assert "sensor" in message and repr(value) in message, message
    assert all(name in message for name in PRESETS), message


@pytest.mark.parametrize("value", NOT_PRESETS, ids=repr)
def test_a_sensor_that_is_no_preset_is_an_invalid_argument_naming_it(value: object) -> None:
    """preset() and sensor_spec() refuse any non-preset value, hashable or not, with an
    InvalidArgument naming ``sensor``, the value and the presets."""
    for lookup in (preset, sensor_spec):
        with pytest.raises(InvalidArgument) as exc:
            lookup(value)
        _names_sensor_value_and_presets(str(exc.value), value)
    assert preset("ideal") is PRESETS["ideal"]


@pytest.mark.parametrize("env_id", SENSOR_ENVS)
@pytest.mark.parametrize("value", NOT_PRESETS, ids=repr)
def test_env_sensor_that_is_no_preset_names_the_argument(env_id: str, value: object) -> None:
    """PegInHole's and AdmittanceContact's ``sensor=["ati_gamma"]`` (and other non-presets):
    InvalidArgument naming ``sensor``, the value and the presets, not an unhashable-type
    TypeError."""
    with pytest.raises(InvalidArgument) as exc:
        gym.make(env_id, sensor=value)
    _names_sensor_value_and_presets(str(exc.value), value)


# ---------------------------------------------------------------------- against MuJoCo
def _hold(env: AdmittanceContactEnv, steps: int, action: np.ndarray | None = None) -> None:
    a = np.zeros(6) if action is None else action
    for _ in range(steps):
        env.step(a)


def test_static_tool_reads_its_weight_in_the_sensor_frame() -> None:
    env = AdmittanceContactEnv(control="position", sensor="ideal")
    env.reset(seed=0)
    _hold(env, 250)  # 0.5 s held by the stiff motion controller
    d = env.data
    R = d.site_xmat[env.model.site("ft_site").id].reshape(3, 3)
    expected = tool_gravity_wrench(TOOL_MASS, TOOL_COM, R)
    np.testing.assert_allclose(d.sensordata[:6], expected, atol=2e-3)
    # the tool points down: the supporting force is +m g along world z
    np.testing.assert_allclose(R @ expected[:3], [0, 0, TOOL_MASS * 9.81], atol=1e-9)


@pytest.mark.parametrize("stiffness", [1.0e3, 1.0e4, 1.0e5])
def test_static_deflection_times_stiffness_is_the_contact_force(stiffness: float) -> None:
    """The surface is the plate's spring, in N/m: deflection × k = force within 2 %; the
    compensated sensor reading is the same force; the stiff contact barely penetrates."""
    env = AdmittanceContactEnv(
        control="position", sensor="ideal", stiffness=stiffness, damping=50.0, force_ref=20.0
    )
    env.reset(seed=3)
    down = np.array([0, 0, -0.08, 0, 0, 0])  # 2 cm/s
    for _ in range(2000):
        env.step(down)
        if env.plate_deflection() * stiffness > 15.0:  # the spring's force, not the impact
            break
    _hold(env, 400)
    force = env.normal_force()
    assert 5.0 < force < 60.0
    assert env.plate_deflection() * stiffness == pytest.approx(force, rel=0.02)
    measured = env.measured_contact_wrench()[:3]  # what the tool exerts on the surface
    assert -measured @ env._normal == pytest.approx(force, rel=0.02)
    plate_top = env.data.site_xpos[env.model.site("surface_site").id]
    tip = env.data.site_xpos[env.model.site("tcp").id]
    assert (tip - plate_top) @ env._normal > -5e-4  # penetration below 0.5 mm


def test_contact_wrench_removes_weight_and_bias() -> None:
    R = np.array([[-1.0, 0, 0], [0, 1.0, 0], [0, 0, -1.0]])
    bias = np.array([0.5, -0.2, 1.0, 0.01, 0.02, 0.03])
    push = np.array([0.0, 0.0, -20.0])  # on the surface, world frame
    reading = tool_gravity_wrench(TOOL_MASS, TOOL_COM, R) + bias
    reading[:3] += R.T @ push
    h = contact_wrench(reading, R, tool_mass=TOOL_MASS, tool_com=TOOL_COM, bias=bias)
    np.testing.assert_allclose(h[:3], push, atol=1e-12)


# ---------------------------------------------------------------------- position interface
def _interface_gain(freq: float, amplitude: float = 1e-3, period: float = 0.002) -> float:
    model = build_model(1.0e4, 20.0)
    data = mujoco.MjData(model)
    data.qpos[:7] = START_Q
    mujoco.mj_forward(model, data)
    interface = CartesianMotionInterface(tool_robot(), "tcp")
    interface.reset(START_Q)
    site = model.site("tcp").id
    z0 = data.site_xpos[site][2]
    substeps = round(period / model.opt.timestep)
    n = int(max(3.0 / freq, 0.6) / period)
    z, ref, prev = np.zeros(n), np.zeros(n), 0.0
    for k in range(n):
        ref[k] = amplitude * math.sin(2 * math.pi * freq * (k + 1) * period)
        interface.command(np.array([0, 0, ref[k] - prev, 0, 0, 0]), period)
        prev = ref[k]
        for i in range(substeps):
            data.ctrl[:] = interface.torque(
                data.qpos[:7].copy(), data.qvel[:7].copy(), (i + 1) / substeps
            )
            mujoco.mj_step(model, data)
        z[k] = data.site_xpos[site][2] - z0
    keep = slice(n // 3, n)
    c = np.exp(-2j * math.pi * freq * (np.arange(n) + 1)[keep] * period)
    return 20 * math.log10(abs(z[keep] @ c) / abs(ref[keep] @ c))


def test_motion_interface_bandwidth() -> None:
    """The documented bandwidth: flat at 5 Hz, −3 dB between 40 and 60 Hz (≈ 50 Hz)."""
    assert abs(_interface_gain(5.0)) < 1.0
    assert _interface_gain(40.0) > -3.0 > _interface_gain(60.0)
    assert 40.0 < MEASURED_BANDWIDTH_HZ < 60.0


def test_motion_interface_rejects_bad_gains_and_increments() -> None:
    robot = Robot(build_model(1e4, 1.0), JOINTS)
    with pytest.raises(InvalidArgument, match="omega_n"):
        CartesianMotionInterface(robot, "tcp", omega_n=-1.0)
    interface = CartesianMotionInterface(robot, "tcp")
    interface.reset(START_Q)
    with pytest.raises(InvalidArgument, match="increment"):
        interface.command(np.zeros(3), 0.002)


#: the filter over a period is a matrix product (WrenchSensor._filter_matrices), step by step a
#: recursion: the two round differently, by a few ulps of the ~10-N signal
ROUND_OFF = 1e-12


@pytest.mark.parametrize("preset", ["robotiq_ft300", "ati_gamma", "ideal"])
def test_update_many_is_update_step_by_step(preset: str) -> None:
    """The env feeds a control period's wrenches at once: the same readings as one by one
    (filter, delay line, sampling and the noise draws in the same order), to round-off
    (no quantisation here: it would hide the round-off)."""
    spec = sensor_spec(preset, bias=(0.1, -0.2, 0.3, 0.01, 0.0, -0.01), resolution=0.0)
    one, many = WrenchSensor(spec, 2.5e-4), WrenchSensor(spec, 2.5e-4)
    signal = np.random.default_rng(5).normal(0.0, 10.0, (161, 6))
    one.reset(np.random.default_rng(1), signal[0])
    many.reset(np.random.default_rng(1), signal[0])
    for chunk in signal[1:].reshape(20, 8, 6):
        for w in chunk:
            one.update(w)
        np.testing.assert_allclose(many.update_many(chunk), one.reading, rtol=0, atol=ROUND_OFF)
    np.testing.assert_allclose(many._filtered, one._filtered, rtol=0, atol=ROUND_OFF)


@pytest.mark.parametrize("preset", ["robotiq_ft300", "ati_gamma"])
def test_a_batched_sensors_rows_are_single_sensors(preset: str) -> None:
    """Row i of a batch (num_envs=4) reads what a single sensor reset with row i's generator
    reads, with rows reset at different times (their sample clocks apart) and periods of
    different lengths; a reset row starts over without touching the others."""
    spec = sensor_spec(preset, bias=(0.1, -0.2, 0.3, 0.01, 0.0, -0.01), resolution=0.0)
    N = 4
    batch = WrenchSensor(spec, 2.5e-4, num_envs=N)
    singles = [WrenchSensor(spec, 2.5e-4) for _ in range(N)]
    signal = np.random.default_rng(7).normal(0.0, 10.0, (N, 400, 6))
    bias = np.random.default_rng(8).uniform(-1, 1, (N, 6))
    batch.reset([np.random.default_rng(i) for i in range(N)], signal[:, 0], bias)
    for i, s in enumerate(singles):
        s.reset(np.random.default_rng(i), signal[i, 0], bias[i])
    k = 1
    for period, reset_row in ((8, None), (3, 2), (8, None), (16, 0), (1, None), (8, 1)):
        chunk = signal[:, k : k + period]
        batch.advance_many(chunk)
        for i, s in enumerate(singles):
            s.advance_many(chunk[i])
        k += period
        if reset_row is not None:
            g = 100 + reset_row
            batch.reset([np.random.default_rng(g)], signal[reset_row, k], rows=[reset_row])
            singles[reset_row].reset(np.random.default_rng(g), signal[reset_row, k])
            k += 1
        expected = np.array([s.reading for s in singles])
        np.testing.assert_allclose(batch.reading, expected, rtol=0, atol=ROUND_OFF)
    # some rows only (a copy whose period diverged is not advanced): the others as before
    chunk = signal[:, k : k + 8]
    batch.advance_many(chunk[[0, 3]], rows=[0, 3])
    batch.advance_many(chunk[1:2], rows=np.array([False, True, False, False]))
    for i in (0, 1, 3):
        singles[i].advance_many(chunk[i])
    expected = np.array([s.reading for s in singles])
    np.testing.assert_allclose(batch.reading, expected, rtol=0, atol=ROUND_OFF)
    np.testing.assert_allclose(batch._filtered, [s._filtered for s in singles], atol=ROUND_OFF)
    assert batch.reading.shape == (N, 6) and batch.bias.shape == (N, 6)
    np.testing.assert_array_equal(batch.bias[2], spec.bias)  # reset without a bias: the spec's
    with pytest.raises(InvalidArgument, match="rng"):
        batch.reset([np.random.default_rng(0)], np.zeros(6))  # 1 generator for 4 rows
