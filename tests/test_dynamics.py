"""Tests of cir_gym.dynamics against MuJoCo, closed forms and finite differences."""

from __future__ import annotations

import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cir_gym.dynamics import (
    coriolis_matrix,
    excitation_trajectory,
    gravity_torque,
    identify,
    inertia_matrix,
    inertia_matrix_derivatives,
    inertial_parameters,
    parameter_names,
    regressor,
    rnea,
)
from cir_gym.dynamics.identification import base_parameter_structure

try:
    import cir_gym

    ROBOTS = Path(cir_gym.__file__).parent / "assets" / "robots"
except Exception:  # cir_gym/__init__ may import modules still being written
    ROBOTS = Path(__file__).parents[1] / "cir_gym" / "assets" / "robots"

ROBOT_NAMES = ("planar2r", "planar3r", "iiwa14")
RANDOM_SEEDS = (0, 1, 2, 3, 4, 5)
MODEL_IDS = ROBOT_NAMES + tuple(f"random{seed}" for seed in RANDOM_SEEDS)


# ----------------------------------------------------------------------------- models


def _quat(rng: np.random.Generator) -> np.ndarray:
    quat = rng.normal(size=4)
    return quat / np.linalg.norm(quat)


def _vec(values: np.ndarray) -> str:
    return " ".join(f"{value:.17g}" for value in values)


def _inertial(rng: np.random.Generator) -> str:
    """An <inertial> with a random COM, mass and full (off-diagonal) inertia."""
    x, y, z = rng.uniform(0.01, 0.1, size=3)
    principal = np.array([x + y, y + z, x + z])  # satisfies the triangle inequality
    axes = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    inertia = axes @ np.diag(principal) @ axes.T
    full = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2],
            inertia[1, 2]]  # fmt: skip
    return (
        f'<inertial pos="{_vec(rng.uniform(-0.1, 0.1, 3))}" mass="{rng.uniform(0.5, 3.0):.17g}" '
        f'fullinertia="{_vec(full)}"/>'
    )


def random_chain_xml(seed: int) -> str:
    """A random serial chain: 3-7 links, hinge and slide joints with random axes, anchors,
    references and armatures, random body offsets and orientations, welded bodies both as
    leaves and between links, a fixed base body with mass, and a tilted gravity."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 8))
    gravity = rng.normal(size=3) + np.array([0.0, 0.0, -3.0])
    gravity *= 9.81 / np.linalg.norm(gravity)
    parts = [
        '<mujoco><compiler inertiafromgeom="false" angle="radian"/>',
        f'<option gravity="{_vec(gravity)}"/><worldbody>',
        f'<body name="base" pos="{_vec(rng.uniform(-0.2, 0.2, 3))}" quat="{_vec(_quat(rng))}">',
        _inertial(rng),
    ]
    closing = ["</body>"]
    for i in range(n):
        slide = i > 0 and rng.random() < 0.3
        kind, limits = ("slide", "-0.5 0.5") if slide else ("hinge", "-2.5 2.5")
        parts.append(
            f'<body name="link{i}" pos="{_vec(rng.uniform(-0.3, 0.3, 3))}" '
            f'quat="{_vec(_quat(rng))}">'
        )
        parts.append(
            f'<joint name="joint{i}" type="{kind}" axis="{_vec(rng.normal(size=3))}" '
            f'pos="{_vec(rng.uniform(-0.1, 0.1, 3))}" ref="{rng.uniform(-0.3, 0.3):.17g}" '
            f'armature="{rng.uniform(0.0, 0.2):.17g}" range="{limits}"/>'
        )
        parts.append(_inertial(rng))
        closing.append("</body>")
        if rng.random() < 0.5:  # welded leaf body, merged into this link
            parts.append(
                f'<body name="weld{i}" pos="{_vec(rng.uniform(-0.2, 0.2, 3))}" '
                f'quat="{_vec(_quat(rng))}">{_inertial(rng)}</body>'
            )
        if i < n - 1 and rng.random() < 0.4:  # welded body between this link and the next
            parts.append(
                f'<body name="spacer{i}" pos="{_vec(rng.uniform(-0.2, 0.2, 3))}" '
                f'quat="{_vec(_quat(rng))}">{_inertial(rng)}'
            )
            closing.append("</body>")
    parts.extend(reversed(closing))
    parts.append("</worldbody></mujoco>")
    return "".join(parts)


def _without_passive_forces(model: mujoco.MjModel) -> mujoco.MjModel:
    """Zero damping/springs/gravcomp and disable constraints, so mj_inverse = rigid-body τ."""
    model.dof_damping[:] = 0.0
    model.jnt_stiffness[:] = 0.0
    model.body_gravcomp[:] = 0.0
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    return model


def load(model_id: str) -> mujoco.MjModel:
    """A fresh model: a shipped robot (required to exist) or a random chain."""
    if model_id.startswith("random"):
        model = mujoco.MjModel.from_xml_string(random_chain_xml(int(model_id[6:])))
    else:
        path = ROBOTS / f"{model_id}.xml"
        assert path.is_file(), f"robot file {path} is missing"
        model = mujoco.MjModel.from_xml_path(str(path))
    return _without_passive_forces(model)


def random_states(model: mujoco.MjModel, count: int, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    shape = (count, model.nv)
    return (
        rng.uniform(-2.0, 2.0, shape) * np.where(model.jnt_type == 2, 0.2, 1.0),
        rng.normal(size=shape),
        rng.normal(size=shape),
    )


def mujoco_terms(
    model: mujoco.MjModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MuJoCo's M(q), qfrc_bias(q, q̇) and qfrc_inverse(q, q̇, q̈)."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = q, qd
    mujoco.mj_forward(model, data)
    M = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, M)
    bias = data.qfrc_bias.copy()
    data.qacc[:] = qdd
    mujoco.mj_inverse(model, data)
    return M, bias, data.qfrc_inverse.copy()


def assert_close(actual: np.ndarray, expected: np.ndarray, rel: float, floor: float = 1e-12):
    """max |actual − expected| ≤ rel · max |expected| + floor."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    assert actual.shape == expected.shape
    error = np.max(np.abs(actual - expected))
    bound = rel * np.max(np.abs(expected)) + floor
    assert error <= bound, f"max error {error:.3g} > {bound:.3g}"


def test_robot_files_exist():
    for name in ROBOT_NAMES:
        assert (ROBOTS / f"{name}.xml").is_file(), f"missing {name}.xml in {ROBOTS}"


# ------------------------------------------------------------------- against MuJoCo


@pytest.mark.parametrize("model_id", MODEL_IDS)
def test_terms_match_mujoco(model_id: str):
    model = load(model_id)
    for q, qd, qdd in zip(*random_states(model, 4, seed=1), strict=True):
        M, bias, inverse = mujoco_terms(model, q, qd, qdd)
        _, bias_at_rest, _ = mujoco_terms(model, q, np.zeros_like(qd), qdd)
        assert_close(inertia_matrix(model, q), M, 1e-9)
        assert_close(gravity_torque(model, q), bias_at_rest, 1e-9, floor=1e-9)
        assert_close(coriolis_matrix(model, q, qd) @ qd + gravity_torque(model, q), bias, 1e-9)
        assert_close(rnea(model, q, qd, qdd), inverse, 1e-9)


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=20, deadline=None, derandomize=True, database=None)
def test_random_chains_match_mujoco(seed: int):
    model = _without_passive_forces(mujoco.MjModel.from_xml_string(random_chain_xml(seed)))
    q, qd, qdd = (state[0] for state in random_states(model, 1, seed=seed))
    M, bias, inverse = mujoco_terms(model, q, qd, qdd)
    assert_close(inertia_matrix(model, q), M, 1e-9)
    assert_close(coriolis_matrix(model, q, qd) @ qd + gravity_torque(model, q), bias, 1e-9)
    assert_close(rnea(model, q, qd, qdd), inverse, 1e-9)


@pytest.mark.parametrize("model_id", ("iiwa14", "random1"))
def test_batches_match_single_samples(model_id: str):
    model = load(model_id)
    q, qd, qdd = random_states(model, 5, seed=2)
    B, C, g = inertia_matrix(model, q), coriolis_matrix(model, q, qd), gravity_torque(model, q)
    tau, Y = rnea(model, q, qd, qdd), regressor(model, q, qd, qdd, qd_r=qdd)
    assert B.shape == (5, model.nv, model.nv) and Y.shape == (5, model.nv, 11 * model.nv)
    for k in range(5):
        assert_close(B[k], inertia_matrix(model, q[k]), 1e-14)
        assert_close(C[k], coriolis_matrix(model, q[k], qd[k]), 1e-14)
        assert_close(g[k], gravity_torque(model, q[k]), 1e-14)
        assert_close(tau[k], rnea(model, q[k], qd[k], qdd[k]), 1e-14)
        assert_close(Y[k], regressor(model, q[k], qd[k], qdd[k], qd_r=qdd[k]), 1e-14)


def test_external_wrench_maps_through_the_tip_jacobian():
    model = load("iiwa14")
    q, qd, qdd = (state[0] for state in random_states(model, 1, seed=3))
    wrench = np.array([10.0, -5.0, 20.0, 1.0, 2.0, -3.0])
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    tip = model.jnt_bodyid[model.njnt - 1]
    jac_p, jac_r = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    mujoco.mj_jac(model, data, jac_p, jac_r, data.xpos[tip], tip)
    expected = rnea(model, q, qd, qdd) + np.vstack([jac_p, jac_r]).T @ wrench
    assert_close(rnea(model, q, qd, qdd, f_ext=wrench), expected, 1e-12)


def test_payload_change_is_seen_at_the_next_call():
    model = load("iiwa14")
    q, qd, qdd = (state[0] for state in random_states(model, 1, seed=4))
    before = rnea(model, q, qd, qdd)
    payload = model.body("payload").id
    model.body_mass[payload] = 3.0
    model.body_ipos[payload] = [0.01, -0.02, 0.05]
    model.body_inertia[payload] = [0.02, 0.03, 0.04]
    # MuJoCo cached "inertial frame = body frame" at compile time (ipos was 0); tell it.
    model.body_sameframe[payload] = int(mujoco.mjtSameFrame.mjSAMEFRAME_NONE)
    _, _, inverse = mujoco_terms(model, q, qd, qdd)
    after = rnea(model, q, qd, qdd)
    assert np.max(np.abs(after - before)) > 1.0
    assert_close(after, inverse, 1e-9)
    link7 = parameter_names(model).index("link7.m")
    pi = inertial_parameters(model)
    assert pi[link7] == pytest.approx(1.2 + 3.0)
    assert pi[link7 + 3] == pytest.approx(1.2 * 0.02 + 3.0 * (0.045 + 0.05))  # m c_z


def test_disabled_gravity_is_respected():
    model = load("iiwa14")
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_GRAVITY)
    q, qd, qdd = (state[0] for state in random_states(model, 1, seed=25))
    np.testing.assert_array_equal(gravity_torque(model, q), np.zeros(model.nv))
    assert_close(rnea(model, q, qd, qdd), mujoco_terms(model, q, qd, qdd)[2], 1e-9)


def test_not_a_model_is_a_type_error():
    with pytest.raises(TypeError, match="MjModel"):
        inertia_matrix("iiwa14", np.zeros(7))


# ----------------------------------------------------------- Euler-Lagrange properties


@pytest.mark.parametrize("model_id", MODEL_IDS)
def test_inertia_matrix_derivatives_match_finite_differences(model_id: str):
    model = load(model_id)
    q = random_states(model, 1, seed=5)[0][0]
    dB = inertia_matrix_derivatives(model, q)
    step = 1e-6
    steps = step * np.eye(model.nv)
    numeric = (inertia_matrix(model, q + steps) - inertia_matrix(model, q - steps)) / (2 * step)
    # central differences: truncation ~ step², rounding ~ eps |B| / step
    assert_close(dB, numeric, 1e-7, floor=1e-8 * np.max(np.abs(inertia_matrix(model, q))))


@pytest.mark.parametrize("model_id", MODEL_IDS)
def test_b_dot_minus_2c_is_skew_symmetric(model_id: str):
    """N = Ḃ − 2C skew-symmetric at several random states, Ḃ by central differences of B.

    Central differences along q̇ err by ~step² (truncation) plus ~eps |B| / step (rounding),
    about 1e-9 · max |Ḃ| here: the bound 1e-6 · max |Ḃ| (+ 1e-12 for Ḃ ≈ 0) leaves a margin
    of ~300 and still catches a wrong Christoffel term (an O(1) relative error).
    """
    model = load(model_id)
    rng = np.random.default_rng(7)
    step = 1e-6
    for q, qd, _ in zip(*random_states(model, 5, seed=6), strict=True):
        B_dot = (inertia_matrix(model, q + step * qd) - inertia_matrix(model, q - step * qd)) / (
            2 * step
        )
        N = B_dot - 2 * coriolis_matrix(model, q, qd)
        bound = 1e-6 * np.max(np.abs(B_dot)) + 1e-12
        assert np.max(np.abs(N + N.T)) <= bound
        w = rng.normal(size=model.nv)
        assert abs(w @ N @ w) <= bound * (w @ w)


def test_planar2r_matches_the_textbook_closed_form():
    """B(q) and g(q) of planar2r against the two-link planar arm of Siciliano et al. (2009),
    sec. 7.3.2, for the shipped values and for random parameters written into the model.

    Textbook (link ℓ, motor m, reduction k_r, motor 2 mounted on link 1 at distance a1):
        b11 = I_ℓ1 + m_ℓ1 ℓ1² + k_r1² I_m1 + I_ℓ2 + m_ℓ2 (a1² + ℓ2² + 2 a1 ℓ2 c2) + I_m2 + m_m2 a1²
        b12 = I_ℓ2 + m_ℓ2 (ℓ2² + a1 ℓ2 c2) + k_r2 I_m2
        b22 = I_ℓ2 + m_ℓ2 ℓ2² + k_r2² I_m2
        g1 = (m_ℓ1 ℓ1 + m_m2 a1 + m_ℓ2 a1) g c1 + m_ℓ2 ℓ2 g c12,  g2 = m_ℓ2 ℓ2 g c12
    What the MJCF represents (see the comment in planar2r.xml): the link masses, COM distances
    and inertias about the axis (``body_mass``, ``body_ipos`` x, ``body_inertia`` y), a1 as
    ``body_pos`` x of link2, and the rotors only as ``dof_armature`` = k_r² I_m on the diagonal.
    It has no motor masses (m_m2 = 0) and no rotor inertia carried by link 1 (I_m2 in b11 = 0);
    the cross term k_r2 I_m2 in b12 cannot be written with MuJoCo's armature (diagonal only).
    """
    model = load("planar2r")
    link1, link2 = model.body("link1").id, model.body("link2").id
    g0 = -model.opt.gravity[2]
    m_m2 = I_m2 = kr2_I_m2 = 0.0  # the textbook terms the MJCF does not represent
    rng = np.random.default_rng(8)
    for trial in range(6):
        if trial > 0:  # trial 0: the shipped values (the book's numbers)
            a1 = rng.uniform(0.3, 1.5)
            m1, m2 = rng.uniform(1.0, 60.0, 2)
            l1, l2 = rng.uniform(0.05, 1.0) * a1, rng.uniform(0.05, 1.0)
            Iy1, Iy2 = rng.uniform(0.1, 15.0, 2)
            model.body_pos[link2] = (a1, 0.0, 0.0)
            model.body_mass[[link1, link2]] = m1, m2
            model.body_ipos[link1], model.body_ipos[link2] = (l1, 0.0, 0.0), (l2, 0.0, 0.0)
            for body, Iy in ((link1, Iy1), (link2, Iy2)):  # a slender rod: Ix small, Iz = Iy
                model.body_inertia[body] = (0.1 * Iy, Iy, Iy)
            model.dof_armature[:] = rng.uniform(0.0, 2.0, 2)
            mujoco.mj_setConst(model, mujoco.MjData(model))
        m1, m2 = model.body_mass[link1], model.body_mass[link2]
        a1 = model.body_pos[link2][0]
        l1, l2 = model.body_ipos[link1][0], model.body_ipos[link2][0]
        I1, I2 = model.body_inertia[link1][1], model.body_inertia[link2][1]  # about the y axis
        kr1_sq_I_m1, kr2_sq_I_m2 = model.dof_armature
        for q in random_states(model, 4, seed=trial)[0]:
            c1, c2, c12 = np.cos(q[0]), np.cos(q[1]), np.cos(q[0] + q[1])
            b11 = (
                I1 + m1 * l1**2 + kr1_sq_I_m1
                + I2 + m2 * (a1**2 + l2**2 + 2 * a1 * l2 * c2) + I_m2 + m_m2 * a1**2
            )  # fmt: skip
            b12 = I2 + m2 * (l2**2 + a1 * l2 * c2) + kr2_I_m2
            b22 = I2 + m2 * l2**2 + kr2_sq_I_m2
            B = np.array([[b11, b12], [b12, b22]])
            g1 = (m1 * l1 + m_m2 * a1 + m2 * a1) * g0 * c1 + m2 * l2 * g0 * c12
            g2 = m2 * l2 * g0 * c12
            M, g_mujoco, _ = mujoco_terms(model, q, np.zeros(2), np.zeros(2))
            assert_close(inertia_matrix(model, q), B, 1e-12)
            assert_close(M, B, 1e-12)
            assert_close(gravity_torque(model, q), np.array([g1, g2]), 1e-12)
            assert_close(g_mujoco, np.array([g1, g2]), 1e-12)


# ------------------------------------------------------------------------ regressor


@pytest.mark.parametrize("model_id", MODEL_IDS)
def test_regressor_times_parameters_is_rnea(model_id: str):
    model = load(model_id)
    q, qd, qdd = random_states(model, 4, seed=9)
    pi = inertial_parameters(model)
    assert pi.shape == (11 * model.nv,)
    assert len(parameter_names(model)) == pi.size
    for gravity in (True, False):
        Y = regressor(model, q, qd, qdd, gravity=gravity)
        assert_close(Y @ pi, rnea(model, q, qd, qdd, gravity=gravity), 1e-10, floor=1e-10)


@pytest.mark.parametrize("model_id", ("iiwa14", "random2"))
def test_regressor_does_not_depend_on_inertial_values(model_id: str):
    model = load(model_id)
    q, qd, qdd = random_states(model, 3, seed=10)
    Y = regressor(model, q, qd, qdd)
    model.body_mass[:] *= 1.7
    model.body_inertia[:] *= 0.6
    model.body_ipos[:] += 0.05
    model.dof_armature[:] += 0.3
    np.testing.assert_array_equal(regressor(model, q, qd, qdd), Y)


@pytest.mark.parametrize("model_id", ("planar2r", "iiwa14", "random3"))
def test_slotine_li_regressor(model_id: str):
    model = load(model_id)
    pi = inertial_parameters(model)
    for q, qd, qdd in zip(*random_states(model, 3, seed=11), strict=True):
        qd_r = np.random.default_rng(12).normal(size=model.nv)
        expected = (
            inertia_matrix(model, q) @ qdd
            + coriolis_matrix(model, q, qd) @ qd_r
            + gravity_torque(model, q)
        )
        assert_close(regressor(model, q, qd, qdd, qd_r=qd_r) @ pi, expected, 1e-10)


@pytest.mark.parametrize("model_id", ("iiwa14", "random4"))
def test_dynamics_are_linear_in_any_parameter_vector(model_id: str):
    """Non-physical π (negative or zero masses with first moments) still give τ = Y π."""
    model = load(model_id)
    pi = np.random.default_rng(13).normal(size=11 * model.nv)
    q, qd, qdd = random_states(model, 3, seed=14)
    assert_close(rnea(model, q, qd, qdd, parameters=pi), regressor(model, q, qd, qdd) @ pi, 1e-10)
    B = inertia_matrix(model, q, parameters=pi)
    C = coriolis_matrix(model, q, qd, parameters=pi)
    g = gravity_torque(model, q, parameters=pi)
    n_terms = np.einsum("bij,bj->bi", B, qdd) + np.einsum("bij,bj->bi", C, qd) + g
    assert_close(n_terms, rnea(model, q, qd, qdd, parameters=pi), 1e-10)


# ------------------------------------------------------------------- identification


def _relative_rms(error: np.ndarray, reference: np.ndarray) -> float:
    return float(np.sqrt(np.mean(error**2)) / np.sqrt(np.mean(reference**2)))


def _excitation_data(model: mujoco.MjModel, seed: int, dt: float = 0.05):
    trajectory = excitation_trajectory(model, duration=10.0, seed=seed)
    _, q, qd, qdd = trajectory.sample(dt)
    return q, qd, qdd


@pytest.mark.parametrize("model_id", ("iiwa14", "random0", "random5"))
def test_base_parameter_structure_reproduces_the_regressor(model_id: str):
    model = load(model_id)
    base, K = base_parameter_structure(model)
    q, qd, qdd = random_states(model, 30, seed=15)
    Y = regressor(model, q, qd, qdd)
    assert_close(Y[..., base] @ K, Y, 1e-9)
    assert np.linalg.matrix_rank(Y.reshape(-1, Y.shape[-1])) == base.size


@pytest.mark.parametrize("model_id", ("iiwa14", "iiwa14+payload", "random1"))
def test_identification_recovers_noise_free_torques(model_id: str):
    """Noise-free torques are recovered to numerical precision: measured ~1e-15 relative (the
    base regressor's condition number is ~1e2), asserted at 1e-11."""
    model = load(model_id.split("+")[0])
    if model_id.endswith("+payload"):
        payload = model.body("payload").id
        model.body_mass[payload] = 3.0
        model.body_ipos[payload] = [0.0, 0.02, 0.06]
        model.body_inertia[payload] = [0.015, 0.02, 0.01]
    q, qd, qdd = _excitation_data(model, seed=16)
    tau = rnea(model, q, qd, qdd)
    # The nominal model used for identification does not know the true inertial values.
    nominal = load(model_id.split("+")[0])
    nominal.body_mass[:] *= 0.5
    result = identify(nominal, q, qd, qdd, tau)
    assert np.isfinite(result.condition_number) and result.condition_number > 1.0
    assert result.residual_rms / np.sqrt(np.mean(tau**2)) < 1e-11
    assert len(result.base_parameter_names) == result.base_indices.size
    q_test, qd_test, qdd_test = random_states(model, 50, seed=17)
    truth = rnea(model, q_test, qd_test, qdd_test)
    predicted = result.predict_torque(q_test, qd_test, qdd_test)
    assert _relative_rms(predicted - truth, truth) < 1e-11
    assert_close(result.predict_torque(q_test[0], qd_test[0], qdd_test[0]), truth[0], 1e-11)
    for prior in (None, inertial_parameters(nominal)):
        pi = result.to_full_parameters(prior)
        plugged = rnea(nominal, q_test, qd_test, qdd_test, parameters=pi)
        assert _relative_rms(plugged - truth, truth) < 1e-11


def test_identification_with_friction():
    """Measured: torques ~4e-15 relative, friction coefficients ~7e-13 relative."""
    model = load("random0")
    q, qd, qdd = _excitation_data(model, seed=18, dt=0.02)
    viscous = np.linspace(0.5, 1.5, model.nv)
    coulomb = np.linspace(0.2, 0.8, model.nv)
    tau = rnea(model, q, qd, qdd) + viscous * qd + coulomb * np.sign(qd)
    result = identify(model, q, qd, qdd, tau, friction=True)
    assert result.residual_rms / np.sqrt(np.mean(tau**2)) < 1e-11
    np.testing.assert_allclose(result.viscous_friction, viscous, rtol=1e-9)
    np.testing.assert_allclose(result.coulomb_friction, coulomb, rtol=1e-9)
    assert_close(result.predict_torque(q, qd, qdd), tau, 1e-11)


def test_identification_needs_as_many_equations_as_base_parameters():
    model = load("iiwa14")
    base, _ = base_parameter_structure(model)
    needed = int(np.ceil(base.size / model.nv))
    assert (needed - 1) * model.nv < base.size <= needed * model.nv
    q, qd, qdd = random_states(model, needed, seed=26)
    tau = rnea(model, q, qd, qdd)
    few = needed - 1
    with pytest.raises(
        ValueError,
        match=rf"^{few} samples give {few * model.nv} equations for {base.size} base "
        rf"parameters; need at least {needed} samples$",
    ):
        identify(model, q[:few], qd[:few], qdd[:few], tau[:few])
    result = identify(model, q, qd, qdd, tau)  # exactly enough: accepted
    assert result.n_samples == needed


def test_identification_error_shrinks_with_more_samples():
    model = load("iiwa14")
    rng = np.random.default_rng(19)
    q_test, qd_test, qdd_test = random_states(model, 200, seed=20)
    truth = rnea(model, q_test, qd_test, qdd_test)
    errors = []
    for samples in (200, 5000):
        q, qd, qdd = random_states(model, samples, seed=21)
        tau = rnea(model, q, qd, qdd) + rng.normal(scale=0.5, size=q.shape)
        result = identify(model, q, qd, qdd, tau)
        assert np.isfinite(result.condition_number)
        assert result.residual_rms == pytest.approx(0.5, rel=0.15)
        errors.append(
            _relative_rms(result.predict_torque(q_test, qd_test, qdd_test) - truth, truth)
        )
    assert errors[1] < 0.5 * errors[0]


# ------------------------------------------------------------- excitation trajectory


@pytest.mark.parametrize("model_id", ("iiwa14", "planar3r", "random2"))
def test_excitation_trajectory_stays_in_the_limits(model_id: str):
    model = load(model_id)
    margin = 0.1
    trajectory = excitation_trajectory(model, duration=20.0, seed=22, margin=margin)
    times = np.linspace(0.0, 20.0, 20001)
    q, qd, qdd = trajectory(times)
    assert q.shape == qd.shape == qdd.shape == (times.size, model.nv)
    lower, upper = model.jnt_range[:, 0], model.jnt_range[:, 1]
    span = upper - lower
    assert np.all(q >= lower + margin * span) and np.all(q <= upper - margin * span)
    assert np.all(q.max(axis=0) - q.min(axis=0) > 0.5 * (1 - 2 * margin) * span)  # uses range
    if model_id != "random2":  # the shipped robots carry a velocity_limit numeric
        assert np.all(np.abs(qd) <= model.numeric("velocity_limit").data)
    q0, qd0, qdd0 = trajectory.evaluate(0.0)
    assert q0.shape == (model.nv,)
    np.testing.assert_allclose(qd0, 0.0, atol=1e-12)
    np.testing.assert_allclose(qdd0, 0.0, atol=1e-12)
    _, qd_end, _ = trajectory(20.0)  # 2 periods of 0.1 Hz: back at rest
    np.testing.assert_allclose(qd_end, 0.0, atol=1e-9)


def test_excitation_derivatives_match_finite_differences():
    model = load("iiwa14")
    trajectory = excitation_trajectory(model, duration=10.0, seed=23, n_harmonics=4)
    times = np.linspace(0.3, 9.7, 50)
    step = 1e-5
    q_plus, qd_plus, _ = trajectory(times + step)
    q_minus, qd_minus, _ = trajectory(times - step)
    _, qd, qdd = trajectory(times)
    assert_close((q_plus - q_minus) / (2 * step), qd, 1e-7)
    assert_close((qd_plus - qd_minus) / (2 * step), qdd, 1e-7)


def test_excitation_velocity_limit_argument():
    model = load("planar2r")
    trajectory = excitation_trajectory(model, duration=10.0, seed=24, velocity_limit=[0.3, 0.2])
    _, _, qd, _ = trajectory.sample(0.001)
    assert np.all(np.abs(qd) <= [0.3, 0.2])


# ---------------------------------------------------------------------- bad input


def test_bad_shapes_and_values_are_rejected():
    model = load("iiwa14")
    q = np.zeros(7)
    with pytest.raises(ValueError, match=r"q has shape \(6,\), expected \(7,\) or \(N, 7\)"):
        inertia_matrix(model, np.zeros(6))
    with pytest.raises(ValueError, match=r"shape \(2, 3, 7\)"):
        rnea(model, np.zeros((2, 3, 7)), q, q)
    with pytest.raises(ValueError, match="qd has shape"):
        rnea(model, q, np.zeros((1, 7)), q)
    with pytest.raises(ValueError, match="NaN or inf"):
        gravity_torque(model, np.full(7, np.nan))
    with pytest.raises(ValueError, match="qdd contains NaN or inf"):
        rnea(model, q, q, np.array([0, 0, 0, np.inf, 0, 0, 0]))
    with pytest.raises(ValueError, match="qd_r has shape"):
        regressor(model, q, q, q, qd_r=np.zeros(3))
    with pytest.raises(ValueError, match=r"f_ext has shape \(3,\)"):
        rnea(model, q, q, q, f_ext=np.zeros(3))
    with pytest.raises(ValueError, match=r"parameters has shape \(70,\), expected \(77,\)"):
        inertia_matrix(model, q, parameters=np.zeros(70))
    with pytest.raises(ValueError, match="same number of samples"):
        identify(model, np.zeros((10, 7)), np.zeros((10, 7)), np.zeros((9, 7)), np.zeros((10, 7)))
    with pytest.raises(ValueError, match=r"tau has shape \(10, 6\)"):
        identify(model, np.zeros((10, 7)), np.zeros((10, 7)), np.zeros((10, 7)), np.zeros((10, 6)))
    with pytest.raises(ValueError, match="duration"):
        excitation_trajectory(model, duration=-1.0)


def test_complex_input_is_rejected_not_truncated():
    """np.asarray(z, dtype=float) would keep the real part with only a ComplexWarning."""
    model = load("iiwa14")
    q, z = np.zeros(7), np.full(7, 0.1 + 0.2j)
    calls = {
        "q": (
            lambda: inertia_matrix(model, z),
            lambda: gravity_torque(model, z[None]),
            lambda: inertia_matrix_derivatives(model, z),
            lambda: rnea(model, z, q, q),
        ),
        "qd": (lambda: coriolis_matrix(model, q, z), lambda: regressor(model, q, z, q)),
        "qdd": (lambda: rnea(model, q, q, z.astype(np.complex64)),),
        "qd_r": (lambda: regressor(model, q, q, q, qd_r=z),),
        "f_ext": (lambda: rnea(model, q, q, q, f_ext=np.zeros(6, dtype=complex)),),
        "parameters": (lambda: inertia_matrix(model, q, parameters=np.zeros(77, dtype=complex)),),
        "tau": (lambda: identify(model, *(np.zeros((20, 7)),) * 3, np.zeros((20, 7)) + 0j),),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning before the error
        for name, functions in calls.items():
            for function in functions:
                with pytest.raises(ValueError, match=rf"^{name} is complex \(complex"):
                    function()
        with pytest.raises(ValueError, match=r"^qd is complex"):
            identify(model, *(np.zeros((20, 7)),) * 4).predict_torque(q, [z[0]] + [0] * 6, q)
        with pytest.raises(ValueError, match=r"q must be a real array of shape \(7,\)"):
            inertia_matrix(model, ["x"] * 7)


_BODY = '<inertial pos="0 0 0" mass="1" diaginertia="0.1 0.1 0.1"/>'

BAD_MODELS = {
    "free": f'<body name="b"><freejoint name="root"/>{_BODY}</body>',
    "ball": f'<body name="b"><joint name="j" type="ball"/>{_BODY}</body>',
    "2 joints": f'<body name="b"><joint name="j1"/><joint name="j2" axis="1 0 0"/>{_BODY}</body>',
    "branching": (
        f'<body name="b0"><joint name="j0"/>{_BODY}'
        f'<body name="b1"><joint name="j1"/>{_BODY}</body>'
        f'<body name="b2" pos="1 0 0"><joint name="j2"/>{_BODY}</body></body>'
    ),
    # a chain under a mocap body is not fixed to the world (data.mocap_pos moves it)
    "mocap": f'<body name="m" mocap="true"><body name="b"><joint name="j"/>{_BODY}</body></body>',
    "mocap body": (
        f'<body name="m" mocap="true" pos="0 0 1">{_BODY}<body name="spacer" pos="0 0 0.1">'
        f'<body name="b"><joint name="j"/>{_BODY}</body></body></body>'
    ),
}


@pytest.mark.parametrize("problem", sorted(BAD_MODELS))
def test_unsupported_models_are_rejected(problem: str):
    xml = f"<mujoco><worldbody>{BAD_MODELS[problem]}</worldbody></mujoco>"
    model = mujoco.MjModel.from_xml_string(xml)
    with pytest.raises(ValueError, match=problem) as error:
        inertia_matrix(model, np.zeros(model.nq))
    assert "supports serial chains" in str(error.value)


def test_equality_constraints_are_rejected():
    xml = (
        f'<mujoco><worldbody><body name="b0"><joint name="j0"/>{_BODY}'
        f'<body name="b1"><joint name="j1"/>{_BODY}</body></body></worldbody>'
        '<equality><joint joint1="j0" joint2="j1"/></equality></mujoco>'
    )
    model = mujoco.MjModel.from_xml_string(xml)
    with pytest.raises(ValueError, match="equality constraint"):
        rnea(model, np.zeros(2), np.zeros(2), np.zeros(2))


def test_a_mocap_body_beside_the_chain_is_allowed():
    """A mocap target (as in the scenes) that does not carry the chain is ignored."""
    xml = (
        f'<mujoco><worldbody><body name="target" mocap="true" pos="1 0 0">{_BODY}</body>'
        f'<body name="b0"><joint name="j0" axis="0 1 0"/>{_BODY}'
        f'<body name="b1" pos="0.5 0 0"><joint name="j1" axis="0 1 0"/>{_BODY}</body></body>'
        "</worldbody></mujoco>"
    )
    model = mujoco.MjModel.from_xml_string(xml)
    q, qd, qdd = (state[0] for state in random_states(model, 1, seed=27))
    M, _, inverse = mujoco_terms(model, q, qd, qdd)
    assert_close(inertia_matrix(model, q), M, 1e-12)
    assert_close(rnea(model, q, qd, qdd), inverse, 1e-12)
