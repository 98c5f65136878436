"""AdmittanceContact and the chapter-6 controllers (cir_gym.baselines.interaction) against the
theory and the physics."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from cir_gym.baselines.base import InvalidGain

import cir_gym  # noqa: F401  (registers the environments)
from cir_gym import baselines
from cir_gym.envs.admittance_contact import RANDOM_RANGES, AdmittanceContactEnv
from cir_gym.validation import InvalidArgument

ENV_ID = "cir_gym/AdmittanceContact-v2"


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
def test_impedance_presses_with_f_ref_at_its_equilibrium_with_the_surface(stiffness: float) -> None:
    """No force loop: in steady state f = K_d,n (x − x_d)·n̂ (within 5 %), and with the sink
    designed against the surface, f̄ (1/K_d,n + 1/k̂), the force on the exact nominal surface
    is f̄ (within 5 %); the sink f̄/K_d,n alone gives the series springs' f̄ k/(K_d,n + k)."""
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
    assert force == pytest.approx(10.0, rel=0.05)
    infos, _, _ = _run("impedance", env_kwargs, surface_compliance=False)
    force = np.mean([i["contact_force"] for i in infos[-150:]])
    assert force == pytest.approx(10.0 * stiffness / (kd + stiffness), rel=0.05)


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


def _press_and_wipe(control: str, stiffness: float, duration: float) -> tuple[list, object]:
    """admittance control until ``duration`` s (contact at ~1.3 s, wiping from 2 s): the infos
    and the per-physics-step tool forces of every period after 2.2 s."""
    env = gym.make(
        ENV_ID, control=control, stiffness=stiffness, force_ref=20.0, episode_duration=duration
    )
    u = env.unwrapped
    policy = baselines.make("admittance", ENV_ID, env=env)
    obs, _ = env.reset(seed=2000)
    state, start, infos, steps = None, True, [], []
    while True:
        action, state = policy.predict(obs, state, np.array([start]))
        start = False
        obs, _, terminated, truncated, info = env.step(action)
        infos.append(info)
        if u._k * u.dt > 2.2:
            steps.append(u.tool_force_steps.copy())
        if terminated or truncated:
            return infos, np.array(steps)


@pytest.mark.parametrize("stiffness", [1.0e3, 1.0e5])
def test_the_wiping_tool_stays_on_the_plate_at_every_physics_step(stiffness: float) -> None:
    """While wiping (admittance, 20 N) the tool's normal contact force stays above 0.5 N at
    every 0.25-ms physics step (with the friction rows on the normal's 2-ms reference it fell
    to 0 for one step in ~13, a 0 -> 25 N sawtooth, in ~47 % of the control periods), near
    f̄; and the contact flag is the physics-step one."""
    infos, steps = _press_and_wipe("torque", stiffness, 3.0)
    assert steps.shape[1] == 8 and steps.min() > 5.0 and abs(steps.mean() - 20.0) < 1.0
    assert np.ptp(steps, axis=1).max() < 5.0  # no sawtooth within a period
    assert all(i["in_contact"] and i["contact_steps"] == 1.0 for i in infos[-400:])


def test_fast_sliding_keeps_the_contact_and_the_friction_is_coulombs() -> None:
    """Position interface: pressed with ~20 N on a flat plate, then slid at 0.25 m/s (the
    interface's top speed, 3 x the wipe's): no physics step without contact once sliding (the
    first 10 periods, a jolt from rest to top speed in one period, left out; a 20-ms friction
    time constant lost 3.8 % of the steps after them at 1e4 N/m), and |f_t| / f_n = μ."""
    import mujoco

    from cir_gym.envs.admittance_scene import FRICTION

    env = AdmittanceContactEnv(
        control="position", stiffness=1e4, sensor="ideal", height_error=0.0, tilt_error=0.0
    )
    env.reset(seed=1)
    while env.normal_force() < 20.0:
        env.step(np.array([0, 0, -0.1, 0, 0, 0]))
    ratios, touch = [], []
    for k in range(100):
        env.step(np.array([1.0, 0, 0, 0, 0, 0]))
        if k >= 10:
            touch.append(env.tool_force_steps.min())
        m, d, f = env.model, env.data, np.zeros(6)
        for i in range(d.ncon):
            mujoco.mj_contactForce(m, d, i, f)
            ratios.append(np.hypot(f[1], f[2]) / f[0])
    assert min(touch) > 0.5
    assert np.median(ratios[len(ratios) // 2 :]) == pytest.approx(FRICTION, rel=0.02)


def test_contact_is_the_tools_and_the_force_limit_sees_every_contact() -> None:
    """Pushing down at full speed on the soft surface with a 1000-N limit: the plate stops at
    its end stop, the tip never goes through it, and the stop comes from the largest single
    contact force at physics resolution (the plate's spring load is ~120 N there). Each step's
    contact force is the tool's contact (mj_contactForce of the tip's contact)."""
    import mujoco

    from cir_gym.envs.admittance_scene import PLATE_TRAVEL

    env = AdmittanceContactEnv(
        control="position", stiffness=1e3, sensor="ideal", force_limit=1000.0
    )
    env.reset(seed=0)
    m, d = env.model, env.data
    tip_geom, f = m.geom("tool_tip").id, np.zeros(6)
    while True:
        _, _, terminated, truncated, info = env.step(np.array([0, 0, -1.0, 0, 0, 0]))
        top = d.site_xpos[m.site("surface_site").id]
        assert (d.site_xpos[env._site] - top) @ env._normal > -1e-3  # never through the plate
        tool = 0.0
        for i in range(d.ncon):
            if tip_geom in (d.contact[i].geom1, d.contact[i].geom2):
                mujoco.mj_contactForce(m, d, i, f)
                tool += f[0]
        assert env.tool_force_steps[-1] == pytest.approx(tool, rel=0.02, abs=0.05)
        if terminated or truncated:
            break
    assert info["force_limit_exceeded"] and not truncated
    assert info["peak_contact_force"] > 1000.0 > info["plate_load"]
    assert env.plate_deflection() < PLATE_TRAVEL + 1e-3
    assert info["episode_metrics"]["max_force"] == info["peak_contact_force"]


#: an arm pose with link 5 and link 6 pressed into the plate (found among random poses near
#: START_Q): one period at zero torque from it
TWO_LINKS_ON_THE_PLATE = np.array([-0.016, 1.476, -0.315, -0.814, 0.406, 0.644, -0.553])


def _plate_contacts(model, data) -> tuple[np.ndarray, np.ndarray]:
    """Every contact on the plate now: its whole force, rotated from the contact frame to the
    world (k, 3) (N, MuJoCo's mj_contactForce), and its normal force (k,) (N)."""
    import mujoco

    plate, f = model.geom("surface_geom").id, np.zeros(6)
    forces, normals = [np.zeros(3)], [0.0]
    for i, c in enumerate(data.contact):
        if plate in (c.geom1, c.geom2):
            mujoco.mj_contactForce(model, data, i, f)
            forces.append(c.frame.reshape(3, 3).T @ f[:3])
            normals.append(f[0])
    return np.array(forces), np.array(normals)


def test_max_force_is_the_whole_force_of_the_largest_single_contact() -> None:
    """Two links on the plate for one period (stepped by hand on a copy of the state): at every
    physics step the largest single contact force is max_i ‖f_i‖, f_i a contact's whole force
    (normal and friction) from mj_contactForce; info["peak_contact_force"] and ``max_force``
    are its largest. v1's measure, the normal component of the contact with the largest
    force, is below another contact's normal force here, and a force limit between v1's
    measure and the whole force stops the episode (the plate's load is far below it)."""
    import mujoco

    limit = 18.0
    env = AdmittanceContactEnv(
        stiffness=1e4, sensor="ideal", height_error=0.0, tilt_error=0.0, force_limit=limit
    )
    env.reset(seed=0)
    m = env.model
    env.data.qpos[env._qa] = TWO_LINKS_ON_THE_PLATE
    mujoco.mj_forward(m, env.data)
    d = mujoco.MjData(m)
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    buf = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, env.data, buf, spec)
    mujoco.mj_setState(m, d, buf, spec)
    whole, v1, normal = [], [], []  # per physics step (N)
    for _ in range(env.substeps):
        mujoco.mj_step(m, d)
        forces, normals = _plate_contacts(m, d)
        size = np.linalg.norm(forces, axis=1)
        whole.append(size.max())
        v1.append(normals[np.argmax(size)])
        normal.append(normals.max())
    whole, v1, normal = np.array(whole), np.array(v1), np.array(normal)
    assert np.min(v1 / normal) < 0.999  # the largest contact's normal below another's
    assert v1.max() < limit < whole.max()
    _, _, terminated, _, info = env.step(np.zeros(7))
    np.testing.assert_allclose(env.peak_force_steps, whole, rtol=1e-9, atol=1e-9)
    assert info["peak_contact_force"] == pytest.approx(whole.max(), rel=1e-12)
    assert info["episode_metrics"]["max_force"] == info["peak_contact_force"]
    assert terminated and info["force_limit_exceeded"] and abs(info["plate_load"]) < 0.5 * limit


def test_the_torque_interface_feeds_every_physics_step_to_the_sensor_in_order() -> None:
    """The one simulation loop: the same period stepped by hand on a copy of the state gives
    the same wrist-sensor state and the same tool forces, step by step."""
    import copy

    import mujoco

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
    m = u.model
    d = mujoco.MjData(m)
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    buf = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, u.data, buf, spec)
    mujoco.mj_setState(m, d, buf, spec)
    d.ctrl[:] = np.clip(action, -1, 1) * u.torque_limit
    sensor = copy.deepcopy(u.sensor)
    tool = m.geom("tool_tip").id
    contact = []
    for _ in range(u.substeps):
        mujoco.mj_step(m, d)
        sensor.update(d.sensordata[:6])
        f, total = np.zeros(6), 0.0
        for i in range(d.ncon):
            if tool in (d.contact[i].geom1, d.contact[i].geom2):
                mujoco.mj_contactForce(m, d, i, f)
                total += f[0]
        contact.append(total)
    _, _, _, _, info = env.step(action)
    # the env feeds the period at once (the filter as a matrix product), the copy step by step:
    # equal to round-off of the ~10-N wrench
    np.testing.assert_allclose(u.sensor.reading, sensor.reading, rtol=0, atol=1e-12)
    np.testing.assert_allclose(u.sensor._filtered, sensor._filtered, rtol=0, atol=1e-12)
    # the contact normal is the tilted plate's (n̂ · f equals f_n to cos of the frames' angle)
    np.testing.assert_allclose(u.tool_force_steps, contact, rtol=1e-6, atol=1e-6)
    assert np.ptp(contact) > 0.01 and info["contact_force"] == pytest.approx(np.mean(contact))


def test_a_stop_charges_the_unplayed_steps_at_the_worst_step_reward() -> None:
    """On by default: a force-limit stop at step k costs the penalty plus (T − k)(1 +
    path_weight + 4 action_rate_weight), so a stopped episode's return is below any finished
    one's worst; charge_unplayed_steps=False: the penalty alone."""
    for charge in (True, False):
        kwargs = {"control": "position", "stiffness": 1e5, "action_rate_weight": 0.5}
        if not charge:
            kwargs["charge_unplayed_steps"] = False
        env = gym.make(ENV_ID, **kwargs)
        env.reset(seed=0)
        total = 0.0
        while True:
            _, r, terminated, truncated, info = env.step(np.array([0, 0, -1.0, 0, 0, 0]))
            total += r
            if terminated or truncated:
                break
        u = env.unwrapped
        assert info["force_limit_exceeded"]
        left = u.max_steps - u._k
        worst = 1.0 + u.path_weight + 4 * u.action_rate_weight
        expected = u.force_limit_penalty + (left * worst if charge else 0.0)
        assert info["reward_force_limit"] == pytest.approx(-expected)
        if charge:
            assert total < -u.max_steps * (1.0 + u.path_weight) + u._k * worst


def test_step_before_reset_or_after_the_end_raises() -> None:
    env = AdmittanceContactEnv(control="position", episode_duration=0.01)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(6))
    env.reset(seed=0)
    while not env.step(np.zeros(6))[3]:
        pass
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(6))


def test_impedance_refuses_a_ramp_it_has_no_force_reference_for() -> None:
    """ramp_time shapes a force reference; impedance has none (its setpoint sink is static), so
    a ramp given to it is refused by name instead of being ignored."""
    with pytest.raises(InvalidGain, match="ramp_time must be 0 for impedance"):
        baselines.make("impedance", ENV_ID, ramp_time=0.3)
    assert baselines.make("impedance", ENV_ID, ramp_time=0.0).gains.ramp_time == 0.0


def test_the_force_laws_take_f_ref_as_a_step_unless_every_one_is_given_the_ramp() -> None:
    """The course's form (default): f_r = f̄ from the first contact, for every force law.
    With ramp_time, every law tracks the same quintic from the contact force to f̄ (ends at
    f̄ at rest; its derivatives the quintic's); the feed-forward is off unless asked."""
    from cir_gym.baselines.interaction import _CONTACT, _F_CONTACT, _T_CONTACT

    env = gym.make(ENV_ID, stiffness=1e4, force_ref=20.0)
    obs = {"f_ref": np.array([20.0])}
    names = ("admittance", "explicit_force", "implicit_force", "parallel_force_position")
    for name in names:
        law = baselines.make(name, ENV_ID, env=env)
        state = np.zeros(law.state_size)
        state[_CONTACT], state[_F_CONTACT], state[_T_CONTACT] = 1.0, 3.0, 0.0
        assert law.force_reference(obs, state) == (20.0, 0.0, 0.0)
    explicit = baselines.make("explicit_force", ENV_ID, env=env, ramp_time=0.3)
    explicit.initial_state({**env.reset(seed=0)[0]})
    assert not explicit.ff
    refs = []
    for name in names:
        law = baselines.make(name, ENV_ID, env=env, ramp_time=0.3)
        state = np.zeros(law.state_size)
        state[_CONTACT], state[_F_CONTACT] = 1.0, 3.0

        def ref(t: float, law: object = law, state: np.ndarray = state) -> np.ndarray:
            state[_T_CONTACT] = t
            return np.array(law.force_reference(obs, state))

        np.testing.assert_allclose(ref(0.0), [3.0, 0.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(ref(0.3), [20.0, 0.0, 0.0], atol=1e-9)
        assert ref(0.15)[0] == pytest.approx(11.5)  # symmetric about its midpoint
        h = 1e-6
        for t in (0.05, 0.13, 0.21):
            assert ref(t)[1] == pytest.approx((ref(t + h)[0] - ref(t - h)[0]) / (2 * h), rel=1e-5)
            assert ref(t)[2] == pytest.approx((ref(t + h)[1] - ref(t - h)[1]) / (2 * h), rel=1e-4)
        refs.append([ref(t) for t in (0.1, 0.2)])
    assert all(np.array_equal(refs[0], r) for r in refs)


def test_one_simulation_loop() -> None:
    """Both interfaces step the physics in one loop (``_advance``): one call of RobotEnv's
    ``_simulate`` in the module, no ``mj_step`` of its own, no fast-path twin."""
    import inspect

    from cir_gym.envs import admittance_contact

    source = inspect.getsource(admittance_contact)
    assert source.count("._simulate(") == 1 and "mj_step" not in source
    assert "_simulate(" in inspect.getsource(AdmittanceContactEnv._advance)
    assert len(source.splitlines()) <= 665  # the Version History grows; a twin loop would not fit


@pytest.mark.parametrize(("gains", "name"), [
    ("cir_gym.baselines.interaction:ImpedanceGains", "mass"),
    ("cir_gym.baselines.hybrid:HybridSpiralGains", "search_force"),
])
def test_a_gain_of_the_wrong_type_built_directly_is_refused_by_name(gains: str, name: str) -> None:
    """Gains built directly (not through baselines.make, which checks types first) refuse a
    string by name as InvalidGain, not with numpy's TypeError."""
    import importlib

    module, cls = gains.split(":")
    with pytest.raises(InvalidGain, match=name):
        getattr(importlib.import_module(module), cls)(**{name: "2"})
