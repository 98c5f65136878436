"""The row-vectorised laws (``RowLaw``): a batch of observations gives, row for row, the
command of each observation alone, and each row is the course's law.

Two tolerances, two reasons:

* a row of a batch against the same observation alone: **bit for bit**. One observation runs
  the very code of a batch (a row of one); every product is a stacked matrix product or
  solve (one BLAS/LAPACK call per row's matrices, the same call for any number of rows), the
  rest is element-wise, and the model calls run row by row. So ``evaluate`` may batch these
  controllers (``batches_exactly``) and its episodes are the sequential ones.
* a row against the law written out here with the nominal ``Robot``'s single-state methods
  (B̂ formed, then B̂ y + n̂; ``np.linalg.pinv``; Λ by ``inv``): **1e-11 of the largest
  torque**. The same formulas, with sums in other orders (Newton-Euler instead of B̂ y + n̂:
  ~1e-14 relative, a pseudo-inverse by SVD instead of a solve: ~1e-13 on these
  well-conditioned Jacobians).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from cir_gym.baselines.base import RobotRows, RowDynamics

from cir_gym import baselines
from cir_gym import operational_space as osp

CARTESIAN = "cir_gym/CartesianTracking-v1"
OS_LAWS = ("os_pd_gravity", "os_inverse_dynamics", "os_inverse_dynamics_dls", "os_khatib")
REL = 1e-11


def _rollout(env_id: str, policy_name: str, seeds: range, steps: int, every: int,
             **env_kwargs) -> dict[str, np.ndarray]:
    """Observations (stacked) every ``every`` steps of short episodes under a controller."""
    env = gym.make(env_id, **env_kwargs)
    policy = baselines.make(policy_name, env_id, env=env.unwrapped)
    rows = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        state, start = None, np.ones(1, dtype=bool)
        for k in range(steps):
            action, state = policy.predict(obs, state, start)
            start[:] = False
            if k % every == 0:
                rows.append({key: np.array(v) for key, v in obs.items()})
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
    env.close()
    return {key: np.stack([r[key] for r in rows]) for key in rows[0]}


@pytest.fixture(scope="module")
def cartesian_obs() -> dict[str, np.ndarray]:
    obs = _rollout(CARTESIAN, "os_khatib", range(2), 240, 3)  # 160 rows
    rng = np.random.default_rng(0)
    obs["qd"] = obs["qd"] + rng.normal(0.0, 0.3, obs["qd"].shape)  # velocity errors too
    return obs


def _row(obs: dict[str, np.ndarray], i: int) -> dict[str, np.ndarray]:
    return {k: v[i].copy() for k, v in obs.items()}


@pytest.mark.parametrize("name", OS_LAWS)
def test_operational_space_rows_equal_each_row_alone_bit_for_bit(name, cartesian_obs) -> None:
    policy = baselines.make(name, CARTESIAN)
    assert policy.vectorized
    n_rows = len(cartesian_obs["q"])
    rng = np.random.default_rng(1)
    posture = cartesian_obs["q"] + rng.normal(0.0, 0.2, cartesian_obs["q"].shape)
    alone = np.stack([policy.control(_row(cartesian_obs, i), posture[i].copy())
                      for i in range(n_rows)])
    for count in (1, 3, 16, 128):  # batches up to evaluate's MAX_BATCH, rows reordered
        pick = rng.permutation(n_rows)[:count]
        rows = {k: v[pick] for k, v in cartesian_obs.items()}
        np.testing.assert_array_equal(policy.control_batch(rows, posture[pick]), alone[pick])
    # predict: the actions of a batch with some rows starting are those of each row alone
    starts = np.arange(n_rows) % 3 == 0
    actions, state = policy.predict(cartesian_obs, posture.copy(), starts)
    for i in range(n_rows):
        one, one_state = policy.predict(_row(cartesian_obs, i), posture[i : i + 1].copy(),
                                        starts[i : i + 1])
        np.testing.assert_array_equal(actions[i], one)
        np.testing.assert_array_equal(state[i], one_state[0])


def _reference_torque(policy, obs: dict[str, np.ndarray], q0: np.ndarray) -> np.ndarray:
    """The law of ``policy`` on one observation, written out with the Robot's methods."""
    robot, site, g = policy.robot, policy.site, policy.gains
    q, qd = obs["q"], obs["qd"]
    kin = osp.pose_error_kinematics(robot, site, q, qd, obs["x_ref"], obs["quat_ref"],
                                    obs["twist_ref"], obs["acc_ref"])
    J_A, B, n = kin.J_A, robot.inertia(q), robot.bias(q, qd)
    if policy.name == "os_pd_gravity":
        force = policy.kp * kin.error + policy.kd * kin.error_rate
        return robot.gravity(q) + J_A.T @ force - policy.kn * qd
    command = kin.task_acceleration + 2 * g.zeta * g.omega_n * kin.error_rate \
        + g.omega_n**2 * kin.error
    y0 = g.posture_omega**2 * (q0 - q) - 2 * g.posture_zeta * g.posture_omega * qd
    if policy.name == "os_khatib":
        Lam = np.linalg.inv(J_A @ np.linalg.inv(B) @ J_A.T)
        J_bar = np.linalg.inv(B) @ J_A.T @ Lam
        N = np.eye(len(q)) - J_bar @ J_A
        return J_A.T @ (Lam @ command + J_bar.T @ n) + N.T @ (B @ y0 + n)
    J_inv = np.linalg.pinv(J_A)  # σ_min ≥ region on these paths: the DLS law is the plain one
    assert np.linalg.svd(J_A, compute_uv=False)[-1] > getattr(g, "region", 0.0)
    y = J_inv @ command + (np.eye(len(q)) - J_inv @ J_A) @ y0
    return B @ y + n


@pytest.mark.parametrize("name", OS_LAWS)
def test_operational_space_rows_are_the_course_law(name, cartesian_obs) -> None:
    policy = baselines.make(name, CARTESIAN)
    posture = cartesian_obs["q"] + 0.1
    tau = policy.control_batch(cartesian_obs, posture)
    for i in range(len(tau)):
        want = _reference_torque(policy, _row(cartesian_obs, i), posture[i])
        np.testing.assert_allclose(tau[i], want, rtol=0, atol=REL * np.max(np.abs(want)))


def test_pose_error_rows_equal_the_single_pose_function(cartesian_obs) -> None:
    """pose_error_from_kinematics on rows equals pose_error_kinematics (the Robot's methods) on
    each row to 1e-13 (the same formula; MuJoCo's J̇q̇ as one (6, n) product instead of two
    (3, n) ones, so the sums run in another order)."""
    policy = baselines.make("os_khatib", CARTESIAN)
    kin = policy.kinematics(cartesian_obs)
    for i in range(len(cartesian_obs["q"])):
        o = _row(cartesian_obs, i)
        one = osp.pose_error_kinematics(policy.robot, policy.site, o["q"], o["qd"], o["x_ref"],
                                        o["quat_ref"], o["twist_ref"], o["acc_ref"])
        for field in ("error", "error_rate", "J_A", "ref_rate", "ref_acc", "JA_dot_qd"):
            np.testing.assert_allclose(getattr(kin, field)[i], getattr(one, field),
                                       rtol=0, atol=1e-13, err_msg=field)


def test_robot_rows_fallback_equals_row_dynamics(cartesian_obs) -> None:
    """RobotRows (the Robot's own methods, for robots RowDynamics does not serve) gives the
    site terms, ĝ and the inverse dynamics of RowDynamics (the same MuJoCo calls: 1e-12, the
    inverse dynamics formed as B̂ q̈ + n̂ rather than by Newton-Euler)."""
    policy = baselines.make("os_khatib", CARTESIAN)
    fast, slow = RowDynamics.for_robot(policy.robot), RobotRows(policy.robot)
    q, qd = cartesian_obs["q"][:5], cartesian_obs["qd"][:5]
    a = fast.site_terms(policy.site_id, q, qd, inertia=True, bias=True, rotations=(0, 1))
    b = slow.site_terms(policy.site_id, q, qd, inertia=True, bias=True, rotations=(0, 1))
    assert a.rotations.shape == (5, 2, 3, 3)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.gravity(q), slow.gravity(q), rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.newton_euler(q, qd, qd), slow.newton_euler(q, qd, qd),
                               rtol=0, atol=1e-11)


# ---------------------------------------------------------------------- interaction laws
CONTACT = "cir_gym/AdmittanceContact-v2"
CONTACT_KW = {"stiffness": 1.0e4, "force_ref": 20.0}
TORQUE_LAWS = ("impedance", "admittance", "explicit_force", "implicit_force",
               "parallel_force_position")
VARIANTS = {  # (law, gains): the force reference's ramp and the feed-forward paths too
    **{(name, "course"): {} for name in TORQUE_LAWS},
    ("explicit_force", "ramp + feed-forward"): {"ramp_time": 0.3, "feedforward": True},
    ("admittance", "ramp"): {"ramp_time": 0.3},
    ("implicit_force", "ramp"): {"ramp_time": 0.3},
    ("parallel_force_position", "ramp"): {"ramp_time": 0.3},
}


@pytest.fixture(scope="module", params=["torque", "position"])
def contact_run(request) -> tuple[str, dict[str, np.ndarray]]:
    """Observations of one episode's first 2.5 s (held still, the approach, the first
    contact at ~2.3 s, pressing) under admittance control, every step."""
    control = request.param
    kw = {**CONTACT_KW, "control": control}
    obs = _rollout(CONTACT, "admittance", range(1), 1250, 1, **kw)
    return control, obs


def _law_states(policy, obs: dict[str, np.ndarray]) -> np.ndarray:
    """The law's state before each step of ``obs``, the law run along it (open loop)."""
    states, state = [], None
    for k in range(len(obs["q"])):
        start = np.array([k == 0])
        if state is not None:
            states.append(state[0].copy())
        _, state = policy.predict(_row(obs, k), state, start)
    return np.stack(states)


@pytest.mark.parametrize(("name", "variant"), list(VARIANTS))
def test_interaction_rows_equal_each_row_alone_bit_for_bit(name, variant, contact_run) -> None:
    """Rows at every phase (held still and re-biasing, approaching, the first contact,
    pressing) in one batch: each row's command and new state are those of the row alone."""
    control, obs = contact_run
    env_kwargs = {**CONTACT_KW, "control": control}
    try:
        policy = baselines.make(name, CONTACT, env_kwargs=env_kwargs, **VARIANTS[name, variant])
    except baselines.InvalidGain:  # a torque law on the position interface
        assert control == "position" and name in ("impedance", "explicit_force")
        return
    assert policy.vectorized
    states = _law_states(policy, obs)
    obs = {k: v[1:] for k, v in obs.items()}  # (the state before step k + 1)
    contact = states[:, 7] != 0.0
    first = int(np.argmax(contact))  # the step whose control sets the contact latch
    first = first - 1 if first else len(contact) - 1
    assert contact.any() and (states[:, 8] < policy.gains.bias_time).any()
    rng = np.random.default_rng(2)
    pick = np.unique(np.concatenate(([0, 10, first, first + 1], rng.choice(len(contact), 12))))
    rows = {k: v[pick] for k, v in obs.items()}
    batch_state = states[pick].copy()
    batch = policy.control_batch(rows, batch_state)
    for j, i in enumerate(pick):
        state = states[i].copy()
        np.testing.assert_array_equal(batch[j], policy.control(_row(obs, i), state))
        np.testing.assert_array_equal(batch_state[j], state)
    assert (batch_state[:, 7] != states[pick, 7]).any()  # the first contact is in the batch


def test_interaction_osc_torque_is_the_course_law(contact_run) -> None:
    """The inner motion law on rows, τ = Jᵀ Λ ([a_p; a_o] − J̇q̇) + n̂ + N_dynᵀ B̂ y₀, against
    the formula with the Robot's methods (Λ and J̄ by inv): 1e-11 of the largest torque."""
    control, obs = contact_run
    if control != "torque":
        pytest.skip("the inner motion law runs on the torque interface only")
    policy = baselines.make("impedance", CONTACT, env_kwargs={**CONTACT_KW, "control": control})
    rows = {k: v[::50] for k, v in obs.items()}
    state = np.stack([policy.initial_state(_row(rows, i)) for i in range(len(rows["q"]))])
    state[:, 10:17] += 0.05  # a posture target away from q
    terms = policy.model_rows().site_terms(policy.site, rows["q"], rows["qd"], inertia=True,
                                           bias=True)
    a_p = np.random.default_rng(3).normal(0.0, 2.0, (len(rows["q"]), 3))
    tau = policy.osc_torque(rows, state, terms, a_p)
    robot, g = policy.robot, policy.gains
    for i in range(len(tau)):
        o = _row(rows, i)
        q, qd = o["q"], o["qd"]
        J, B = robot.jacobian(policy.site, q), robot.inertia(q)
        B_inv = np.linalg.inv(B)
        Lam = np.linalg.inv(J @ B_inv @ J.T)
        w = g.motion_omega
        a_o = w * w * osp.rotvec_error(policy.quat_ref, o["tool_quat"]) \
            - 2 * w * o["tool_angvel"]
        F = Lam @ (np.concatenate((a_p[i], a_o)) - robot.jacobian_dot_qdot(policy.site, q, qd))
        N = np.eye(len(q)) - B_inv @ J.T @ Lam @ J
        wp = g.posture_omega
        y0 = wp * wp * (state[i, 10:17] - q) - 2 * wp * qd
        want = J.T @ F + robot.bias(q, qd) + N.T @ (B @ y0)
        np.testing.assert_allclose(tau[i], want, rtol=0, atol=REL * np.max(np.abs(want)))


def test_an_adapter_that_redefines_control_is_served_row_by_row() -> None:
    """A RowLaw subclass that translates one observation in ``control`` is not vectorised
    (predict must call its control per row); one that writes control_rows is (PegInHole's
    admittance adapter translates rows in its control_rows)."""
    from cir_gym.baselines.hybrid import PegAdmittance
    from cir_gym.baselines.interaction import Admittance

    class Translating(Admittance):
        def control(self, obs, state):
            return super().control(obs, state)

    class Rows(Admittance):
        def control(self, obs, state):
            return super().control(obs, state)

        def control_rows(self, obs, state):
            return super().control_rows(obs, state)

    assert Admittance.vectorized and Rows.vectorized
    assert not Translating.vectorized
    assert PegAdmittance.vectorized


# ---------------------------------------------------------------------- PegInHole laws
PEG = "cir_gym/PegInHole-v2"
#: (law, env arguments): the start 2 mm above the nominal hole, so that a few hundred steps
#: reach every phase (approach, the first contact, the spiral search, the drop into the hole,
#: the bore); position_only's episodes end at the force limit and restart within the run
PEG_RUNS = {
    "hybrid_force_position": {"start_height": 0.002, "chamfer": 0.001},
    "hybrid_spiral": {"start_height": 0.002},
    "position_spiral": {"start_height": 0.002},
    "position_only": {"start_height": 0.002},
    "admittance": {"start_height": 0.002},
}
PEG_COPIES, PEG_STEPS = 8, 800


def _peg_phases(policy, state: np.ndarray, obs: dict[str, np.ndarray]) -> np.ndarray:
    """A label per row (N,) of the law's phase: the spiral's mode; hybrid_force_position's
    Σ (0 above the bore, 1 in it); admittance's contact latch; position_only's 0."""
    from cir_gym.baselines.hybrid import _fields
    from cir_gym.baselines.interaction import _CONTACT

    if policy.name in ("hybrid_spiral", "position_spiral"):
        return _fields(state, policy.layout)["mode"].astype(int)
    if policy.name == "hybrid_force_position":
        return (obs["peg_pos"][:, 2] < -policy.gains.guard_height).astype(int)
    if policy.name == "admittance":
        return (state[:, _CONTACT] != 0.0).astype(int)  # the interaction laws' contact latch
    return np.zeros(len(state), dtype=int)


@pytest.fixture(scope="module", params=list(PEG_RUNS))
def peg_run(request):
    """A law driving ``PEG_COPIES`` copies of the batched PegInHole for ``PEG_STEPS`` steps
    (seeds 1000-1007: each copy its own true hole pose), its batched predict checked at every
    step against each row predicted alone from its own state (bit for bit: actions and new
    states). Returns (policy, observations (T, N, ...), states before each step (T, N, size),
    starts (T, N), phases (T + 1, N))."""
    from cir_gym.envs.peg_in_hole_vector import PegInHoleVectorEnv

    name = request.param
    kwargs = PEG_RUNS[name]
    env = PegInHoleVectorEnv(num_envs=PEG_COPIES, **kwargs)
    policy = baselines.make(name, PEG, env_kwargs=kwargs)
    assert policy.vectorized
    obs, _ = env.reset(seed=1000)
    state, start = np.zeros((PEG_COPIES, policy.state_size)), np.ones(PEG_COPIES, dtype=bool)
    seen = {"obs": [], "state": [], "start": [], "phase": []}
    for _ in range(PEG_STEPS):
        seen["obs"].append({k: v.copy() for k, v in obs.items()})
        seen["state"].append(state.copy())
        seen["start"].append(start.copy())
        action, new_state = policy.predict(obs, state, start)
        for i in range(PEG_COPIES):
            one, one_state = policy.predict(_row(obs, i), state[i : i + 1].copy(),
                                            start[i : i + 1])
            np.testing.assert_array_equal(action[i], one)
            np.testing.assert_array_equal(new_state[i], one_state[0])
        seen["phase"].append(_peg_phases(policy, new_state, obs))
        state = new_state
        obs, _, terminated, truncated, _ = env.step(action)
        start = terminated | truncated
    env.close()
    stacked = {k: np.stack([o[k] for o in seen["obs"]]) for k in seen["obs"][0]}
    return (policy, stacked, np.stack(seen["state"]), np.stack(seen["start"]),
            np.stack(seen["phase"]))


def test_peg_in_hole_runs_reach_every_phase(peg_run) -> None:
    """The batched runs above (each step bit for bit against the rows alone) go through the
    phases their law has: the spiral's approach, search and found (and a row changing
    phase); hybrid_force_position's Σ_face and Σ in the bore; admittance's free approach and
    contact; position_only's restarts after the force limit."""
    policy, _, _, starts, phases = peg_run
    want = {"hybrid_spiral": {0, 1, 2}, "position_spiral": {0, 1, 2},
            "hybrid_force_position": {0, 1}, "admittance": {0, 1},
            "position_only": {0}}[policy.name]
    assert set(np.unique(phases)) == want
    if len(want) > 1:
        assert (phases[1:] != phases[:-1]).any()  # a row changes phase within a step
    if policy.name == "position_only":
        assert starts[1:].any()  # an episode ended and its copy restarted


def test_peg_in_hole_rows_of_any_phase_and_hole_pose_equal_each_row_alone(peg_run) -> None:
    """One batch of rows from different steps and copies (every phase of the law, rows
    restarting their episode) with each row's nominal hole moved and turned by a different
    amount (the laws read the hole frame from the observation): each row's action and new
    state are those of the row alone, bit for bit (the same reasons as the laws above)."""
    policy, obs, states, starts, phases = peg_run
    rng = np.random.default_rng(4)
    steps, copies = np.meshgrid(np.arange(PEG_STEPS), np.arange(PEG_COPIES), indexing="ij")
    label = phases * 2 + starts  # pick rows of every phase, starting or not
    changed = np.zeros_like(label, dtype=bool)
    changed[1:] = phases[1:] != phases[:-1]  # rows whose step changes their phase
    pick = np.concatenate([rng.choice(np.flatnonzero(label.ravel() == v), 6)
                           for v in np.unique(label)]
                          + [np.flatnonzero(changed.ravel())[:6]])
    pick = rng.permutation(np.concatenate((pick, rng.choice(label.size, 24))))
    k, i = steps.ravel()[pick], copies.ravel()[pick]
    rows = {key: value[k, i].copy() for key, value in obs.items()}
    n = len(pick)
    rows["hole_pos"] += rng.normal(0.0, 0.002, (n, 3))
    tilt = rng.normal(0.0, 0.03, (n, 3))  # rad
    turn = np.array([osp.rotvec_from_quat(q) for q in rows["hole_quat"]]) + tilt
    angle = np.linalg.norm(turn, axis=1, keepdims=True)
    rows["hole_quat"] = np.concatenate(
        (np.cos(angle / 2), np.sin(angle / 2) * turn / np.maximum(angle, 1e-12)), axis=1)
    state = states[k, i]
    actions, new_state = policy.predict(rows, state.copy(), starts[k, i])
    assert len(np.unique(_peg_phases(policy, new_state, rows))) == len(np.unique(phases))
    for j in range(n):
        one, one_state = policy.predict(_row(rows, j), state[j : j + 1].copy(),
                                        starts[k[j], i[j] : i[j] + 1])
        np.testing.assert_array_equal(actions[j], one)
        np.testing.assert_array_equal(new_state[j], one_state[0])
