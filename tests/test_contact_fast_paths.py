"""The contact envs' step fast paths give the numbers of their plain paths, bit for bit.

PegInHole runs RobotEnv._simulate's per-physics-step checks inline (``_advance``; the loop
through ``_simulate`` is kept as ``_advance_simulate``), the position interface computes
B(q) and n(q, q̇) with Robot's MuJoCo calls on an own MjData and its damped least squares
through numpy's solve gufunc. Each must equal its plain path: observations, rewards, flags and
infos, including a divergence (restored state) and states set from outside between steps.
"""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest

import cir_gym  # noqa: F401
from cir_gym import motion_interface as mi
from cir_gym.envs import admittance_contact, peg_in_hole
from cir_gym.envs.admittance_contact import AdmittanceContactEnv

PEG = "cir_gym/PegInHole-v1"
ADMITTANCE = "cir_gym/AdmittanceContact-v0"


def _rollout(
    env: gym.Env, seed: int, steps: int, diverge_at: int | None = None, nan_at: int | None = None
) -> list:
    """Observations, rewards, flags and infos of steps with small random actions pushing
    down (``diverge_at``: the joint speeds set absurd before that step; ``nan_at``: a joint
    position set to NaN before that step, which MuJoCo answers with a warning)."""
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    out = [obs, info]
    down = np.zeros(env.action_space.shape)
    if env.unwrapped.control == "position":
        down[2] = -0.5
    for k in range(steps):
        if k == diverge_at:
            env.unwrapped.data.qvel[:] = 5e3
        if k == nan_at:
            env.unwrapped.data.qpos[1] = np.nan
        action = (down + rng.uniform(-0.3, 0.3, env.action_space.shape)).astype(np.float32)
        out.append(env.step(action))
        if out[-1][2] or out[-1][3]:
            break
    return out


def _assert_same(a: object, b: object) -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b)
        for key in a:
            _assert_same(a[key], b[key])
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    else:
        assert type(a) is type(b)
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("control", ["torque", "position"])
@pytest.mark.parametrize(("diverge_at", "nan_at"), [(None, None), (3, None), (None, 4)])
def test_peg_fast_pass_equals_the_simulate_loop(
    control: str, diverge_at: int | None, nan_at: int | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The fast pass, and its undo and rerun on a divergence (a speed test failing inside the
    period; a NaN state, answered by MuJoCo's warning), give the _simulate loop's numbers."""
    kwargs = {"control": control, "episode_duration": 0.1, "sensor": "robotiq_ft300"}
    if control == "position" and nan_at is not None:
        # a NaN written into data.qpos from outside between steps (an externally corrupted
        # state): the motion controller reads it before MuJoCo steps and refuses it
        # (ValueError), on both paths. A NaN reached by the physics never gets there: the
        # fast pass breaks on the speed test, MuJoCo resets a bad state with a warning, and the
        # step ends with info["diverged"] (the divergence cases here and in the recordings)
        for plain in (False, True):
            if plain:
                monkeypatch.setattr(peg_in_hole, "_UNSTABLE_CONTIGUOUS", False)
            with pytest.raises(ValueError, match="NaN"):
                _rollout(gym.make(PEG, **kwargs), 3, 60, diverge_at, nan_at)
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fast = _rollout(gym.make(PEG, **kwargs), 3, 60, diverge_at, nan_at)
        monkeypatch.setattr(peg_in_hole, "_UNSTABLE_CONTIGUOUS", False)  # _advance_simulate
        plain = _rollout(gym.make(PEG, **kwargs), 3, 60, diverge_at, nan_at)
    _assert_same(fast, plain)
    if diverge_at is not None or nan_at is not None:
        assert fast[-1][4]["diverged"]


@pytest.mark.parametrize("diverge_at", [None, 3])
@pytest.mark.parametrize("sensor", ["robotiq_ft300", "ati_gamma"])
def test_admittance_motion_fast_pass_equals_the_simulate_loop(
    diverge_at: int | None, sensor: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """AdmittanceContact's position interface: the fast pass (and its undo and rerun on a
    divergence) gives the _simulate loop's numbers, the sensor history included."""
    kwargs = {"control": "position", "episode_duration": 0.1, "sensor": sensor}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make(ADMITTANCE, **kwargs)
        fast = _rollout(env, 4, 50, diverge_at)
        fast.append(env.unwrapped.sensor_history(0))
        monkeypatch.setattr(admittance_contact, "_UNSTABLE_CONTIGUOUS", False)
        env = gym.make(ADMITTANCE, **kwargs)
        plain = _rollout(env, 4, 50, diverge_at)
        plain.append(env.unwrapped.sensor_history(0))
    _assert_same(fast, plain)
    if diverge_at is not None:
        assert fast[-2][4]["diverged"]


@pytest.mark.parametrize(
    ("env_id", "control", "module"),
    [
        (PEG, "torque", peg_in_hole),
        (PEG, "position", peg_in_hole),
        (ADMITTANCE, "position", admittance_contact),
    ],
)
def test_an_undone_fast_pass_leaves_no_warning_counted(
    env_id: str, control: str, module: object, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A warning other than the instability ones (here CONTACTFULL, raised at every physics
    step by a wrapped mj_step) met in a fast pass that is then undone (every pass, by a speed
    bound of -1 in the fast test only; _simulate reruns the period without diverging):
    MuJoCo's whole warning state (counters and last infos) is the _simulate loop's."""
    import mujoco

    mj_step, full = mujoco.mj_step, int(mujoco.mjtWarning.mjWARN_CONTACTFULL)

    def step(m: mujoco.MjModel, d: mujoco.MjData, nstep: int = 1) -> None:
        for _ in range(nstep):
            mj_step(m, d)
            d.warning.number[full] += 1
            d.warning.lastinfo[full] = d.warning.number[full] % 7

    monkeypatch.setattr(mujoco, "mj_step", step)
    ends = []
    for plain in (False, True):
        with monkeypatch.context() as patch:
            if plain:
                patch.setattr(module, "_UNSTABLE_CONTIGUOUS", False)
            else:
                patch.setattr(module, "_MAX_SPEED_SQ", -1.0)  # every fast pass undone
            env = gym.make(env_id, control=control, episode_duration=0.1)
            out = _rollout(env, 3, 5)
        w = env.unwrapped.data.warning
        ends.append((out, w.number.copy(), w.lastinfo.copy()))
    (fast, number, lastinfo), (plain_out, plain_number, plain_lastinfo) = ends
    _assert_same(fast, plain_out)
    assert not fast[-1][4]["diverged"] and number[full] > 0
    np.testing.assert_array_equal(number, plain_number)
    np.testing.assert_array_equal(lastinfo, plain_lastinfo)


def _reference_contact_state(env: object) -> dict:
    """PegInHole._contact_state as of 4038a6b (before _contact_flags), the reference."""
    import math

    import mujoco

    from cir_gym import peg_hole_geometry as geo
    from cir_gym.envs.peg_in_hole import SIDE_NORMAL, STALL_SPEED

    m, d = env.model, env.data
    axis = env.true_hole_R[:, 2]
    side: list[np.ndarray] = []
    for i in range(d.ncon):
        contact = d.contact[i]
        if env._peg_geom not in contact.geom:
            continue
        mujoco.mj_contactForce(m, d, i, env._cforce)
        sign = -1.0 if contact.geom[0] == env._peg_geom else 1.0  # frame[0]: geom1 → geom2
        n = sign * contact.frame[:3]  # normal pushing the peg
        along = float(n @ axis)
        if abs(along) < SIDE_NORMAL and env._cforce[0] > 0:
            lateral = n - along * axis
            side.append(lateral / max(math.sqrt(float(lateral.dot(lateral))), 1e-12))
    tip = env._tip_in_hole()
    depth = float(-tip[2])
    two_point = len(side) > 1 and any(
        float(a @ b) < -0.5 for i, a in enumerate(side) for b in side[i + 1 :]
    )
    mu_d = geo.FRICTION * 2 * env.geometry.hole_radius
    v_axis = 0.0
    if two_point:
        mujoco.mj_jacSite(m, d, env._jacp, env._jacr, env._tip)
        v_axis = float(axis @ (env._jacp @ d.qvel))
    wedged = bool(two_point and depth < mu_d)
    jammed = bool(two_point and not wedged and abs(v_axis) < STALL_SPEED)
    radial = float(np.hypot(tip[0], tip[1]))
    return {
        "depth": depth,
        "two_point": bool(two_point),
        "wedged": wedged,
        "jammed": jammed,
        "in_bore": radial < env.geometry.hole_radius + env.geometry.chamfer,
    }


def _assert_contact_state_is_the_reference(u: object) -> None:
    want = _reference_contact_state(u)
    _assert_same(u._contact_state(), want)
    depth, tip, two_point, wedged, jammed = u._contact_flags()
    _assert_same([depth, two_point, wedged, jammed], [want[k] for k in list(want)[:4]])
    np.testing.assert_array_equal(tip, u._tip_in_hole())


def _reference_net_contact_force(env: object) -> np.ndarray:
    """PegInHole._net_contact_force as of 66ecae3 (mj_contactForce contact by contact)."""
    import mujoco

    m, d = env.model, env.data
    total = np.zeros(3)
    force = np.zeros(6)
    for i in range(d.ncon):
        contact = d.contact[i]
        if env._peg_geom in contact.geom:
            mujoco.mj_contactForce(m, d, i, force)
            sign = -1.0 if contact.geom[0] == env._peg_geom else 1.0
            total += sign * (contact.frame.reshape(3, 3).T @ force[:3])
    return total


@pytest.mark.parametrize("elliptic", [True, False])
def test_peg_net_contact_force_is_the_sum_of_mj_contact_force(elliptic: bool) -> None:
    """The contacts' forces read from efc_force at once (elliptic cones) or by mj_contactForce
    (the other path) and summed as stacked products: the contact-by-contact sum of
    mj_contactForce, within rounding, with the peg pushed on the rim, on the face and into
    two-point contacts (one to several peg contacts), and with a geom that is in only some of
    the contacts. (Bit-identity with the former code was checked on recorded rollouts; the
    test holds the formula within rounding, which does not depend on the BLAS build.)"""
    from test_peg_in_hole import _exact_env, _push, _two_point_pose

    counts = set()

    def check(u: object) -> None:
        want = _reference_net_contact_force(u)
        np.testing.assert_allclose(u._net_contact_force(), want, rtol=1e-12, atol=1e-9)
        counts.add(sum(u._peg_geom in u.data.contact[i].geom for i in range(u.data.ncon)))

    u = _exact_env()
    u._efc_rows = elliptic and u._efc_rows  # False: the mj_contactForce loop
    centre = u.true_hole_pos[:2]
    for k in range(24):
        offset = 0.0045 * np.array([np.cos(k), np.sin(k)])  # on the rim and the face
        _push(u, np.array([0.0, 0.0, -15.0]), 40, tip_xy=centre + offset)
        check(u)
    for depth, shift in [(0.010, 0.0), (0.003, 0.0), (0.010, 2e-5)]:
        u = _exact_env()
        u._efc_rows = elliptic and u._efc_rows
        _two_point_pose(u, depth, shift)
        check(u)
    assert max(counts) >= 2 and len(counts) >= 3, counts
    # a list of contacts of which only some are "the peg's": name one block geom the peg
    pairs = u.data.contact.geom.tolist()
    blocks = sorted({g for pair in pairs for g in pair} - {u._peg_geom})
    assert len(blocks) >= 2, pairs  # the two-point pose touches two of the block's geoms
    u._peg_geom = blocks[0]
    check(u)
    assert 0 < len(u._peg_contact_forces()[0]) < len(pairs)


def test_peg_contact_state_is_the_4038a6b_contact_state() -> None:
    """_contact_state (a wrapper of _contact_flags) and _contact_flags against the former
    body of _contact_state: along a pushing rollout, and on constructed two-point contacts
    (jammed, wedged, sliding, one contact; test_peg_in_hole's poses)."""
    from test_peg_in_hole import _exact_env, _two_point_pose

    env = gym.make(PEG, episode_duration=0.2, control="position")
    rng = np.random.default_rng(1)
    env.reset(seed=1)
    down = np.array([0.0, 0.0, -0.5, 0.0, 0.0, 0.0])
    for _ in range(40):
        _assert_contact_state_is_the_reference(env.unwrapped)
        action = (down + rng.uniform(-0.3, 0.3, 6)).astype(np.float32)
        if any(env.step(action)[2:4]):
            break
    _assert_contact_state_is_the_reference(env.unwrapped)
    flags = set()
    for depth, shift, v_axis in [
        (0.010, 0.0, 0.0),
        (0.003, 0.0, 0.0),
        (0.010, 0.0, 0.005),
        (0.010, 2e-5, 0.0),
    ]:
        u = _exact_env()
        _two_point_pose(u, depth, shift, v_axis)
        _assert_contact_state_is_the_reference(u)
        state = _reference_contact_state(u)
        flags.add((state["two_point"], state["wedged"], state["jammed"]))
    assert len(flags) == 4  # jammed, wedged, sliding and one contact all met


@pytest.mark.parametrize("env_id", [PEG, ADMITTANCE])
def test_motion_interface_fast_torque_equals_robot_calls(env_id: str) -> None:
    env = gym.make(env_id, control="position")
    env.reset(seed=0)
    u = env.unwrapped
    interface = u.motion if env_id == PEG else u.interface
    interface.command(np.array([1e-4, -2e-4, -3e-4, 1e-3, 0.0, -1e-3]), u.dt)
    rng = np.random.default_rng(0)
    q0 = interface.q_c.copy()
    for _ in range(20):
        q = q0 + 0.05 * rng.standard_normal(q0.size)
        qd = rng.standard_normal(q0.size)
        fast = interface.torque(q, qd, 0.5)
        robot = interface.robot
        q_r = interface._q_start + 0.5 * interface._dq
        y = interface.kp * (q_r - q) + interface.kd * (interface._dq / interface._period - qd)
        np.testing.assert_array_equal(fast, robot.inertia(q) @ y + robot.bias(q, qd))
        # a list takes Robot's path (its validation): the same numbers
        np.testing.assert_array_equal(fast, interface.torque(q.tolist(), qd.tolist(), 0.5))
    with pytest.raises(ValueError, match="NaN or inf"):
        interface.torque(np.full(q0.size, np.nan), np.zeros(q0.size), 0.5)


def test_motion_interface_command_equals_damped_least_squares(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    env = gym.make(ADMITTANCE, control="position")
    env.reset(seed=0)
    interface = env.unwrapped.interface
    rng = np.random.default_rng(1)
    increments = 1e-3 * rng.standard_normal((10, 6))
    q_start = interface.q_c.copy()
    fast = []
    for dx in increments:
        interface.command(dx, 0.002)
        fast.append(interface.q_c.copy())
    interface.reset(q_start)
    monkeypatch.setattr(mi, "_INLINE_DLS", False)  # operational_space.damped_least_squares
    for dx, want in zip(increments, fast, strict=True):
        interface.command(dx, 0.002)
        np.testing.assert_array_equal(interface.q_c, want)


def _command_outcome(interface: mi.CartesianMotionInterface, q: np.ndarray) -> tuple:
    """(new setpoint or the exception's type and text, the warnings' texts) of one command
    from ``q``."""
    interface.reset(q)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            interface.command(np.array([1e-3, 0.0, 0.0, 0.0, 0.0, 1e-3]), 0.002)
            result: object = interface.q_c.copy()
        except Exception as exc:  # the outcome compared, whatever it is
            result = (type(exc), str(exc))
    return result, [str(w.message) for w in caught]


@pytest.mark.parametrize(
    ("damping", "singular"), [(1e-170, False), (1e-160, False), (1e-10, True), (1e-3, True)]
)
def test_motion_interface_tiny_damping_behaves_as_the_plain_solve(
    damping: float, singular: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A damping whose square rounds to 0 (1e-170) at q = 0 (a singular Jacobian), a
    subnormal square (1e-160), and a k² lost in rounding against J Jᵀ at a Jacobian with two
    equal rows (an exactly zero pivot): the fast path raises, warns and returns what
    np.linalg.solve's path does."""
    env = gym.make(ADMITTANCE, control="position")
    env.reset(seed=0)
    interface = env.unwrapped.interface
    interface.damping = damping
    if singular:
        J = np.zeros((6, interface.robot.n))
        J[0] = J[1] = np.linspace(0.1, 0.9, J.shape[1])
        J[2:, 2:6] = 0.5 * np.eye(4)
        monkeypatch.setattr(interface.robot, "jacobian", lambda site, q: J.copy())
    q = np.zeros(interface.robot.n)
    fast = _command_outcome(interface, q)
    monkeypatch.setattr(mi, "_INLINE_DLS", False)  # operational_space.damped_least_squares
    plain = _command_outcome(interface, q)
    assert fast[1] == plain[1]
    if isinstance(plain[0], tuple):
        assert fast[0] == plain[0]
    else:
        np.testing.assert_array_equal(fast[0], plain[0])
    if damping == 1e-170 or (singular and damping == 1e-10):  # the cases the fix is about
        assert plain[0] == (np.linalg.LinAlgError, "Singular matrix")


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [(PEG, {"control": "position"}), (ADMITTANCE, {"control": "position"}), (PEG, {})],
)
def test_a_pickled_contact_env_continues_the_same_episode(env_id: str, kwargs: dict) -> None:
    env = gym.make(env_id, episode_duration=0.2, **kwargs)
    _rollout(env, 2, 10)
    twin = pickle.loads(pickle.dumps(env))
    rng = np.random.default_rng(5)
    for _ in range(15):
        action = rng.uniform(-0.2, 0.2, env.action_space.shape).astype(np.float32)
        _assert_same(env.step(action), twin.step(action))


def test_admittance_reference_rows_are_the_reference() -> None:
    env = AdmittanceContactEnv(episode_duration=0.2)
    env.reset(seed=4)
    rows = env._ref_rows
    np.testing.assert_array_equal(rows[:, 0], env._f_ref)
    np.testing.assert_array_equal(rows[:, 1:4], env._pos_ref)
    np.testing.assert_array_equal(rows[:, 4:7], env._vel_ref)


def test_peg_observation_products_by_the_identity_are_the_explicit_products() -> None:
    """PegInHole's _obs replaces its products by R_hole = I and ALIGNED = diag(−1, 1, −1)
    with the explicit products "+ 0.0" (an exact zero as +0): the same bytes as that formula
    written entry by entry, −0 and tiny numbers included, and the matmuls' values (their
    zeros' signs depend on the BLAS, so only the values are compared)."""
    from cir_gym.envs.peg_in_hole import _ALIGNED_COLUMNS, ALIGNED

    env = gym.make(PEG)
    env.reset(seed=0)
    R_hole = env.unwrapped._R_hole
    assert np.array_equal(R_hole, np.eye(3)) and not np.signbit(R_hole).any()
    rng = np.random.default_rng(0)
    values = np.array([0.0, -0.0, 1.5, -2.25, 1e-300, -1e-300, 0.3, -7.0])
    for _ in range(500):
        X = rng.choice(values, size=(3, 3))
        v = rng.choice(values, size=3)
        w = rng.choice(values, size=6)
        # Σ_k R_hole[k, i] X[k, l] ALIGNED[j, l] with exact zeros summed as +0
        explicit = np.array(
            [[float(X[i, j] * ALIGNED[j, j]) + 0.0 for j in range(3)] for i in range(3)]
        )
        assert (X * _ALIGNED_COLUMNS + 0.0).tobytes() == explicit.tobytes()
        assert (v + 0.0).tobytes() == np.array([float(x) + 0.0 for x in v]).tobytes()
        assert (w + 0.0).tobytes() == np.array([float(x) + 0.0 for x in w]).tobytes()
        np.testing.assert_array_equal(X * _ALIGNED_COLUMNS + 0.0, R_hole.T @ X @ ALIGNED.T)
        np.testing.assert_array_equal(v + 0.0, R_hole.T @ v)
        np.testing.assert_array_equal(w + 0.0, (w.reshape(2, 3) @ R_hole).reshape(6))
    # the observation is that formula on the simulated state
    u = env.unwrapped
    obs = u._obs()
    xpos, xmat = u._tip_views
    pos = np.clip(
        np.array([float(a - b) + 0.0 for a, b in zip(xpos, u.hole_pos, strict=True)]), -2.0, 2.0
    )
    assert obs["peg_pos"].tobytes() == pos.tobytes()
    R = np.array(
        [[float(xmat[3 * i + j] * ALIGNED[j, j]) + 0.0 for j in range(3)] for i in range(3)]
    )
    np.testing.assert_array_equal(obs["peg_quat"], u._quat(R))
