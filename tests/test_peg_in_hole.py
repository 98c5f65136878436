"""PegInHole: the contact physics (clearance exact, penetration, tunnelling, no artificial
jamming, torque-driven arm), the env's flags and arguments, and the selection matrix."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from cir_gym.baselines.hybrid import _rotvec, selection_matrix

from cir_gym import peg_hole_geometry as geo
from cir_gym import trajectories as traj
from cir_gym.envs.peg_in_hole import PegInHoleEnv
from cir_gym.operational_space import rotvec_error
from cir_gym.validation import InvalidArgument


def _exact_env(**kwargs: float) -> PegInHoleEnv:
    env = PegInHoleEnv(position_uncertainty=0.0, tilt_uncertainty=0.0, sensor="ideal", **kwargs)
    env.reset(seed=0)
    return env


def _push(
    env: PegInHoleEnv,
    force: np.ndarray,
    steps: int,
    tip_xy: np.ndarray | None = None,
    k_lat: float = 3000.0,
) -> list[float]:
    """Gravity compensation + Jᵀ[f; 0] at the tip (plus a lateral spring to ``tip_xy``), physics
    step by physics step; returns the deepest penetration of a peg contact at each step."""
    m, d = env.model, env.data
    tip = m.site("peg_tip").id
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    peg = m.geom("peg_geom").id
    depths = []
    for _ in range(steps):
        mujoco.mj_jacSite(m, d, jp, jr, tip)
        f = np.array(force, dtype=float)
        v = jp @ d.qvel
        if tip_xy is not None:
            f[:2] += k_lat * (tip_xy - d.site_xpos[tip][:2]) - 100.0 * v[:2]
        mu = -5.0 * (jr @ d.qvel)
        d.ctrl[:] = d.qfrc_bias + jp.T @ f + jr.T @ mu - 2.0 * d.qvel
        mujoco.mj_step(m, d)
        pen = [
            -d.contact.dist[i]
            for i in range(d.ncon)
            if peg in (d.contact.geom1[i], d.contact.geom2[i])
        ]
        depths.append(max(pen, default=0.0))
    return depths


def test_the_hole_is_primitives_with_the_exact_clearance() -> None:
    """No mesh (a mesh collides as its convex hull: a plug); each wall box's inner face lies at
    the hole radius r_peg + clearance/2 from the axis; margin 0 everywhere (< clearance)."""
    model, g = geo.build_peg_in_hole(clearance=1e-4)
    assert model.nmesh == 0
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    centre = data.site_xpos[model.site("hole").id]
    walls = [i for i in range(model.ngeom) if model.geom(i).name.startswith("wall")]
    assert len(walls) == geo.N_SIDES
    for i in walls:
        R = data.geom_xmat[i].reshape(3, 3)
        inner = data.geom_xpos[i] - R[:, 0] * model.geom_size[i][0]
        assert np.hypot(*(inner - centre)[:2]) == pytest.approx(g.peg_radius + 5e-5, abs=1e-12)
    assert np.all(model.geom_margin == 0.0)
    assert model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert model.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON


def test_the_arm_is_driven_by_torque_never_by_mocap() -> None:
    env = PegInHoleEnv()
    assert env.model.nmocap == 0
    assert all(int(t) == int(mujoco.mjtTrn.mjTRN_JOINT) for t in env.model.actuator_trntype)
    assert np.all(env.model.actuator_gainprm[:, 0] == 1.0)  # motors: ctrl is the torque


def test_steady_contact_penetration_is_below_a_fifth_of_the_smallest_clearance() -> None:
    """The peg pressed on the block's face with 100 N (the force limit) at clearance 0.1 mm:
    resting penetration < 20 µm (the default solref would give 0.2–0.4 mm)."""
    env = _exact_env(clearance=1e-4, start_height=0.002)
    centre = env.true_hole_pos[:2] + np.array([0.009, 0.0])
    _push(env, np.zeros(3), 200, centre)  # move beside the hole
    depths = _push(env, np.array([0.0, 0.0, -100.0]), 1200, centre)
    assert max(depths[-400:]) < 1e-4 / 5


def test_no_tunnelling_at_ten_times_the_largest_commanded_speed() -> None:
    """The peg thrown at the face at 0.5 m/s (10 × the position interface's top speed) with
    300 N behind it stays on the face: the tip never goes more than 0.5 mm into the block."""
    env = _exact_env(clearance=2e-3, start_height=0.02)
    m, d = env.model, env.data
    tip = m.site("peg_tip").id
    target = env.true_hole_pos[:2] + np.array([0.009, 0.0])
    _push(env, np.zeros(3), 300, target)
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jp, jr, tip)
    d.qvel[:] = np.linalg.pinv(np.vstack((jp, jr))) @ np.array([0, 0, -0.5, 0, 0, 0])
    lowest = np.inf
    for _ in range(400):
        _push(env, np.array([0.0, 0.0, -300.0]), 1, target)
        lowest = min(lowest, d.site_xpos[tip][2] - env.true_hole_pos[2])
    assert lowest > -5e-4


def test_a_centred_peg_goes_to_the_bottom_without_touching_the_walls() -> None:
    """Exact hole pose, smallest clearance, position interface straight down: success and no
    contact on the bore's side on the way (margin 0: no artificial jamming)."""
    env = PegInHoleEnv(
        control="position",
        clearance=1e-4,
        position_uncertainty=0.0,
        tilt_uncertainty=0.0,
        sensor="ideal",
        episode_duration=3.0,
    )
    env.reset(seed=0)
    down = np.array([0.0, 0.0, -0.6, 0.0, 0.0, 0.0])
    side_contacts = 0
    for _ in range(env.max_steps):
        _, _, terminated, truncated, info = env.step(down)
        side_contacts += info["two_point_contact"]
        d = env.data
        for i in range(d.ncon):
            names = {env.model.geom(int(g)).name for g in (d.contact.geom1[i], d.contact.geom2[i])}
            side_contacts += any(n.startswith("wall") for n in names)
        if terminated or truncated:
            break
    assert info["is_success"]
    assert side_contacts == 0


def test_bad_arguments_name_themselves() -> None:
    with pytest.raises(InvalidArgument, match="clearance"):
        PegInHoleEnv(clearance=5e-3)
    with pytest.raises(InvalidArgument, match="control"):
        PegInHoleEnv(control="velocity")
    with pytest.raises(InvalidArgument, match="sensor"):
        PegInHoleEnv(sensor="strain gauge")


def test_selection_matrices_split_force_and_motion_directions() -> None:
    """Insertion: force on x, y, rot x, rot y (zero lateral force and tilting moment), motion
    along and about the axis; search: force along the axis only. Σ is a projector."""
    s = selection_matrix()
    np.testing.assert_array_equal(np.diag(s), [1, 1, 0, 1, 1, 0])
    np.testing.assert_array_equal(s @ s, s)
    np.testing.assert_array_equal(np.diag(selection_matrix(search=True)), [0, 0, 1, 0, 0, 0])


def test_the_true_hole_pose_is_drawn_within_the_uncertainty() -> None:
    env = PegInHoleEnv()
    for seed in range(20):
        _, info = env.reset(seed=seed)
        assert np.linalg.norm(info["hole_offset"]) <= 0.002 + 1e-15
        assert 0.0 <= info["hole_tilt"] <= 2.0


def test_the_controllers_fast_rotation_vector_is_operational_space_rotvec_error() -> None:
    """baselines.hybrid._rotvec (MuJoCo's C routines) == log(R̄ Rᵀ) of cir_gym.operational_space,
    at random rotations (every angle in (0, π))."""
    rng = np.random.default_rng(0)
    quats = rng.normal(size=(50, 2, 4))
    for q_ref, q in quats / np.linalg.norm(quats, axis=-1, keepdims=True):
        R_ref, R = traj.matrix_from_quat(q_ref), traj.matrix_from_quat(q)
        np.testing.assert_allclose(_rotvec(R_ref @ R.T), rotvec_error(q_ref, q), atol=1e-9)


@pytest.mark.slow
def test_hybrid_inserts_where_position_only_hits_the_force_limit() -> None:
    """On the same hole pose (seed 1000, 3 mm chamfer): hybrid_force_position inserts with every
    single contact below the 100-N limit (its largest is ~79 N, a wall contact that the net
    force, ~40 N, hides); position_only, stiff to the nominal hole, ends at the force limit."""
    from cir_gym import baselines
    from cir_gym.evaluation import evaluate

    hybrid = baselines.make(
        "hybrid_force_position", "cir_gym/PegInHole-v2", env_kwargs={"chamfer": 0.003}
    )
    ep = evaluate(hybrid, "cir_gym/PegInHole-v2", 1, seed=1000, chamfer=0.003).episodes[0]
    assert ep.success and ep.metrics["peak_force"] < 100.0
    stiff = baselines.make("position_only", "cir_gym/PegInHole-v2")
    ep = evaluate(stiff, "cir_gym/PegInHole-v2", 1, seed=1000, chamfer=0.003).episodes[0]
    assert not ep.success and ep.metrics["peak_force"] > 100.0


def test_the_chamfer_is_a_45_degree_cone_from_the_bore_to_the_top_face() -> None:
    """Each chamfer box's inner face is the plane through (r_h, −c) and (r_h + c, 0) in the
    (radial, axial) plane of its side, and no box stands above the block's top face."""
    c = 0.002
    model, g = geo.build_peg_in_hole(clearance=5e-4, chamfer=c)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    centre = data.site_xpos[model.site("hole").id]
    for i in range(model.ngeom):
        name = model.geom(i).name
        if model.geom_bodyid[i] != model.body("block").id or name == "bottom":
            continue
        R = data.geom_xmat[i].reshape(3, 3)
        corners = np.array(
            [
                data.geom_xpos[i] + R @ (np.array([a, b, e]) * model.geom_size[i])
                for a in (-1, 1)
                for b in (-1, 1)
                for e in (-1, 1)
            ]
        )
        assert np.max(corners[:, 2] - centre[2]) < 1e-12, name
        if not name.startswith("chamfer"):
            continue
        normal = -R[:, 0]  # the inner face's outward normal (into the hole, upward)
        point = data.geom_xpos[i] + R[:, 0] * -model.geom_size[i][0]
        radial = np.array([*(point - centre)[:2], 0.0])
        radial /= np.linalg.norm(radial)
        for r, z in ((g.hole_radius, -c), (g.hole_radius + c, 0.0)):
            q = centre + r * radial + np.array([0.0, 0.0, z])
            # the polygon's facet plane: exact along the facet's mid-line
            assert abs(float((q - point) @ normal)) < 1e-12, (name, r, z)
        assert normal[2] == pytest.approx(np.sqrt(0.5), abs=1e-12)


def _two_point_pose(
    env: PegInHoleEnv, depth: float, shift: float = 0.0, v_axis: float = 0.0, overlap: float = 5e-6
) -> float:
    """Put the arm (kinematically, then ``mj_forward``) in the classic two-point contact of a
    peg tilted in the bore: tip ``depth`` below the top face, its leading bottom edge ``overlap``
    into the +y wall and its side ``overlap`` into the −y rim (the tilt θ solves
    2 (R + ε − r cos θ) = (ℓ + r sin θ) tan θ). ``shift`` moves the tip toward −y (m: > ε loses
    the bottom contact, < −ε the rim's); ``v_axis`` (m/s) slides the peg along its axis, into the
    hole. Returns θ (rad)."""
    from scipy.optimize import brentq

    from cir_gym.envs.peg_in_hole import ALIGNED
    from cir_gym.robot import Robot

    g = env.geometry
    R, r = g.hole_radius + overlap, g.peg_radius
    theta = brentq(
        lambda t: 2 * (R - r * np.cos(t)) - (depth + r * np.sin(t)) * np.tan(t), 1e-6, 0.7
    )
    target = env.true_hole_pos + np.array([0.0, R - r * np.cos(theta) - shift, -depth])
    c, s = np.cos(theta), np.sin(theta)
    quat = traj.quat_from_matrix(np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ ALIGNED)
    robot = Robot(env.model)
    q = env.data.qpos[env.robot.qpos_adr].copy()
    for _ in range(50):
        p, Rq = robot.site_pose("peg_tip", q)
        e = np.concatenate((target - p, rotvec_error(quat, traj.quat_from_matrix(Rq))))
        q = q + np.linalg.pinv(robot.jacobian("peg_tip", q)) @ e
    assert np.linalg.norm(e) < 1e-10
    d = env.data
    d.qpos[env.robot.qpos_adr] = q
    v = np.concatenate((v_axis * Rq[:, 2], np.zeros(3)))
    d.qvel[env.robot.dof_adr] = np.linalg.pinv(robot.jacobian("peg_tip", q)) @ v
    mujoco.mj_forward(env.model, d)
    return theta


@pytest.mark.parametrize(
    ("depth", "shift", "v_axis", "two_point", "wedged", "jammed"),
    [
        (0.010, 0.0, 0.0, True, False, True),  # deeper than μD, at rest: jammed
        (0.004, 0.0, 0.0, True, False, True),  # just deeper than μD = 3.15 mm
        (0.003, 0.0, 0.0, True, True, False),  # just shallower: wedged
        (0.002, 0.0, 0.0, True, True, False),
        (0.010, 0.0, 0.005, True, False, False),  # two-point but sliding in at 5 mm/s
        (0.010, 2e-5, 0.0, False, False, False),  # only the rim touches
        (0.010, -2e-5, 0.0, False, False, False),  # only the leading edge touches
        (0.002, 2e-5, 0.0, False, False, False),
    ],
)
def test_jam_and_wedge_flags_follow_their_conditions(
    depth: float, shift: float, v_axis: float, two_point: bool, wedged: bool, jammed: bool
) -> None:
    """The flags on constructed contact states: two-point contact (opposite side contacts)
    shallower than μ D (0.3 × 10.5 mm) is wedging, deeper and not advancing is jamming, one
    contact is neither."""
    env = _exact_env()
    _two_point_pose(env, depth, shift, v_axis)
    assert env._depth() == pytest.approx(depth, abs=1e-9)
    axial_speed = float(env.true_hole_R[:, 2] @ env._tip_twist()[:3])
    flags = env._contact_flags(env._depth(), axial_speed)  # the sensors after mj_forward
    assert (flags.two_point, flags.wedged, flags.jammed) == (two_point, wedged, jammed)


def test_the_admittance_adapter_sees_the_peg_tip_and_presses_the_reference_force() -> None:
    """PegAdmittance (interaction.py's admittance law on PegInHole): its translated tool pose is
    the peg tip of the nominal arm; with the hole off by 2 mm it lands on the face and then
    regulates the reference force (±20 %), never inserting (no lateral compliance)."""
    from cir_gym.baselines.hybrid import PegAdmittance

    # its landing on the face at the guard speed is a ~200 N impact at the physics step (a
    # rigid 11-kg arm on a 1-ms contact): the limit raised to see the regulation after it
    env = gym.make("cir_gym/PegInHole-v2", episode_duration=2.0, force_limit=1000.0)
    policy = PegAdmittance(env.unwrapped.controller_context(), insertion_force=10.0)
    obs, _ = env.reset(seed=1000)
    t = policy.translate(obs)
    p, _ = policy.robot.site_pose(policy.site, obs["q"])
    np.testing.assert_allclose(p, t["tool_pos"], atol=1e-9)
    state, start, forces = None, np.array([True]), []
    for _ in range(env.unwrapped.max_steps):
        action, state = policy.predict(obs, state, start)
        start = np.array([False])
        obs, _, terminated, truncated, info = env.step(action)
        forces.append(info["net_contact_force"])
        if terminated or truncated:
            break
    assert not info["is_success"] and not terminated
    assert np.mean(forces[-250:]) == pytest.approx(10.0, rel=0.2)


def _strike(charge: bool) -> tuple[list[float], int, dict]:
    """The peg driven straight down at full speed onto the face 2.9 mm beside the true hole
    (seed 3) until the 20-N force limit ends the episode: (rewards, steps played, last info)."""
    env = PegInHoleEnv(control="position", position_uncertainty=0.01, tilt_uncertainty=0.0,
                       sensor="ideal", force_limit=20.0, charge_unplayed_steps=charge)
    env.reset(seed=3)
    down = np.array([0, 0, -1, 0, 0, 0], dtype=np.float32)
    rewards = []
    for k in range(env.max_steps):
        _, r, terminated, truncated, info = env.step(down)
        rewards.append(r)
        if terminated or truncated:
            return rewards, k + 1, info
    raise AssertionError("the episode did not end")


def test_charge_unplayed_steps_charges_a_failure_the_worst_step_it_did_not_play() -> None:
    """Same episode with and without the charge: equal rewards up to the failing step, which
    loses (T − k)(1 + force_weight) more; the failure is at the force limit, not a success."""
    plain, k, info = _strike(False)
    charged, k2, info2 = _strike(True)
    assert k == k2 and info["force_limit_exceeded"] and not info["is_success"]
    assert plain[:-1] == charged[:-1]
    T = PegInHoleEnv(control="position").max_steps
    np.testing.assert_allclose(plain[-1] - charged[-1], (T - k) * 2.0, rtol=1e-12)
    assert info2["reward_force_limit"] == pytest.approx(-(100.0 + (T - k) * 2.0))
    # failing now is worse than playing on at the worst non-failing reward to the time limit
    assert charged[-1] < -(T - k + 1) * 2.0


def test_v1_charges_unplayed_steps_by_default() -> None:
    """PegInHole-v2's one change from v0: the charge is on unless asked off, through the
    registered id too (the default, not a registration kwarg)."""
    assert PegInHoleEnv().charge_unplayed_steps is True
    env = gym.make("cir_gym/PegInHole-v2")
    assert env.unwrapped.charge_unplayed_steps is True
    assert "charge_unplayed_steps" not in env.spec.kwargs
    off = gym.make("cir_gym/PegInHole-v2", charge_unplayed_steps=False)
    assert off.unwrapped.charge_unplayed_steps is False
    assert "cir_gym/PegInHole-v0" not in gym.registry


def test_charge_unplayed_steps_must_be_a_bool() -> None:
    with pytest.raises(InvalidArgument, match="charge_unplayed_steps must be True or False"):
        PegInHoleEnv(charge_unplayed_steps="yes")


# ---------------------------------------------------------------- forces, success, collisions
def _reference_contact_forces(m: mujoco.MjModel, d: mujoco.MjData) -> tuple[float, float]:
    """(largest single contact force, net force) (N) of every contact with the block, by
    mj_contactForce contact by contact (in this scene every contact is robot–block)."""
    block = m.body("block").id
    largest, net, f = 0.0, np.zeros(3), np.zeros(6)
    for i in range(d.ncon):
        g1, g2 = d.contact.geom[i]
        assert (m.geom_bodyid[g1] == block) != (m.geom_bodyid[g2] == block)
        mujoco.mj_contactForce(m, d, i, f)
        largest = max(largest, float(np.linalg.norm(f[:3])))
        sign = 1.0 if m.geom_bodyid[g1] == block else -1.0  # on the robot
        net += sign * d.contact.frame[i].reshape(3, 3).T @ f[:3]
    return largest, float(np.linalg.norm(net))


@pytest.mark.slow
def test_peak_force_is_the_largest_single_contact_at_every_physics_step(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """hybrid_spiral on seed 1017: the metrics are the largest single contact force and the
    largest net force over every physics step (measured here after each physics step by
    mj_contactForce), and the force limit reads the single contact. A 2-ms average of the net
    force (opposing wall forces cancel in it) reported 34 N here while a single wall contact
    carried 142 N, and the 100-N limit never tripped."""
    from cir_gym import baselines
    from cir_gym.evaluation import evaluate

    seen: dict[float, tuple[float, float]] = {}  # by the simulated time before the step
    last: list[mujoco.MjData] = []
    mj_step = mujoco.mj_step

    def step(m: mujoco.MjModel, d: mujoco.MjData, nstep: int = 1) -> None:
        for _ in range(nstep):
            t = d.time
            mj_step(m, d)
            seen[round(t, 9)] = _reference_contact_forces(m, d)
        last[:] = [d]

    monkeypatch.setattr(mujoco, "mj_step", step)
    policy = baselines.make("hybrid_spiral", "cir_gym/PegInHole-v2")
    ep = evaluate(policy, "cir_gym/PegInHole-v2", 1, seed=1017, batched=False).episodes[0]
    # the steps the episode played: a period stopped by the force limit is simulated again
    # from its start up to the stop, so its steps beyond the stop are not part of it
    end = last[0].time
    largest, net = np.array([f for t, f in seen.items() if t < end - 1e-9]).T
    assert ep.metrics["peak_force"] == pytest.approx(largest.max(), rel=1e-9)
    assert ep.metrics["peak_net_force"] == pytest.approx(net.max(), rel=1e-9)
    assert largest.max() > 100.0 and not ep.success  # the limit tripped on the single contact
    assert ep.terminated and ep.length < PegInHoleEnv().max_steps


def _quat_x(angle: float) -> np.ndarray:
    return np.array([np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0])


def test_a_peg_under_the_block_is_not_inserted() -> None:
    """A scripted setpoint path around and under the block (position interface): up, aside,
    the peg turned horizontal, down past the block and in under the bore's axis, 45 mm below
    the top face. The tip is then on the axis deeper than the goal, but below the bore's
    bottom and never entered through the top: not a success (it was, with 0 N of contact)."""
    env = PegInHoleEnv(
        control="position", position_uncertainty=0.0, tilt_uncertainty=0.0, sensor="ideal",
        episode_duration=20.0,
    )
    obs, _ = env.reset(seed=0)
    waypoints = [
        ((0.0, 0.0, 0.06), 0.0), ((0.0, -0.1, 0.06), 0.0), ((0.0, -0.1, 0.06), np.pi / 2),
        ((0.0, -0.1, -0.045), np.pi / 2), ((0.0, 0.0, -0.045), np.pi / 2),
    ]
    infos = []
    for target, angle in waypoints:
        for _ in range(3000):
            dp = np.asarray(target) - obs["peg_pos"]
            dphi = rotvec_error(_quat_x(angle), obs["peg_quat"])
            action = np.clip(np.concatenate((dp, dphi)) / env.increment_scale, -1, 1)
            obs, _, terminated, truncated, info = env.step(action.astype(np.float32))
            infos.append(info)
            assert not terminated and not truncated
            if np.linalg.norm(dp) < 2e-4 and np.linalg.norm(dphi) < 2e-3:
                break
    tip = env._tip_in_hole()
    assert np.hypot(tip[0], tip[1]) < 1e-4 and env._depth() > 0.044  # under the bore's axis
    assert max(i["contact_force"] for i in infos) == 0.0
    assert not env._entered


def test_a_peg_in_the_bore_is_inserted_only_between_the_goal_and_the_bottom() -> None:
    """A centred peg pushed down the exact bore ends the episode as a success at the goal depth,
    having entered through the top (position interface, straight down)."""
    env = PegInHoleEnv(
        control="position", position_uncertainty=0.0, tilt_uncertainty=0.0, sensor="ideal"
    )
    env.reset(seed=0)
    down = np.array([0, 0, -1, 0, 0, 0], dtype=np.float32)
    for _ in range(env.max_steps):
        _, _, terminated, truncated, info = env.step(down)
        if terminated or truncated:
            break
    assert info["is_success"] and env._entered
    assert env.goal_depth <= info["depth"] < env.goal_depth + 0.002


def test_the_arm_and_the_holder_collide_with_the_block_and_nothing_else() -> None:
    """Every robot geom (links, holder, peg) has a contact bit the block accepts; the links
    never collide with each other and nothing collides with the floor. With the tip put 65 mm
    down the bore (the flange 15 mm above the top face), the holder and the last link touch
    the block, and the env measures those contacts."""
    env = _exact_env()
    m = env.model
    block = m.body("block").id
    robot = [g for g in range(m.ngeom) if m.geom_bodyid[g] not in (0, block)]
    for g in robot:
        b = next(b for b in range(m.ngeom) if m.geom_bodyid[b] == block)
        assert m.geom_contype[g] & m.geom_conaffinity[b], m.geom(g).name
        for h in robot:
            if m.geom(g).name != "peg_geom" or m.geom(h).name != "peg_geom":
                both = (m.geom_contype[g] & m.geom_conaffinity[h]) or (
                    m.geom_contype[h] & m.geom_conaffinity[g]
                )
                assert not both, (m.geom(g).name, m.geom(h).name)
    floor = m.geom("floor").id
    assert m.geom_contype[floor] == m.geom_conaffinity[floor] == 0
    # the tip 65 mm down the axis, aligned (the peg through the bottom: a kinematic pose)
    robot_model = env.robot
    target = env.true_hole_pos + np.array([0.0, 0.0, -0.065])
    q = env.data.qpos[robot_model.qpos_adr].copy()
    from cir_gym.envs.peg_in_hole import ALIGNED

    aligned = traj.quat_from_matrix(ALIGNED)
    for _ in range(50):
        p, Rq = robot_model.site_pose("peg_tip", q)
        e = np.concatenate((target - p, rotvec_error(aligned, traj.quat_from_matrix(Rq))))
        q = q + np.linalg.pinv(robot_model.jacobian("peg_tip", q)) @ e
    env.data.qpos[robot_model.qpos_adr] = q
    mujoco.mj_forward(m, env.data)
    d = env.data
    touching = {m.geom(int(g)).name for g in d.contact.geom[: d.ncon].ravel()}
    assert {"payload_geom", "link7_geom"} <= touching, touching
    # the env's contact sensors measure them: the largest single contact is one of them
    forces = np.zeros((d.ncon, 6))
    for i in range(d.ncon):
        mujoco.mj_contactForce(m, d, i, forces[i])
    largest = np.max(np.linalg.norm(forces[:, :3], axis=1))
    assert env.sensors.largest(d.sensordata) == pytest.approx(largest, rel=1e-12)


def test_one_loop_keeps_the_episodes_of_the_former_fast_path() -> None:
    """The actions of PegInHole-v2 episodes recorded on the former code (a fast pass with an
    exact twin, tests/data/peg_in_hole_v1_episodes.npz: hybrid_spiral's first 1500 steps on seed
    1000, torque, into contact on the face; random position increments pressing down on seed
    1000 until that code's force limit) replayed on the one physics loop give the same
    observations. Tolerance 1e-9 (absolute, SI units): the loop and the sums are written
    plainly, so the last bits may differ from the former idioms' (they matched exactly when
    recorded), never more than rounding. The arm's new collisions with the block are not met
    on these paths."""
    data = np.load(Path(__file__).parent / "data" / "peg_in_hole_v1_episodes.npz")
    for control, every in (("torque", 50), ("position", 50)):
        env = gym.make("cir_gym/PegInHole-v2", control=control)
        env.reset(seed=1000)
        observed = []
        for action in data[f"{control}_actions"]:
            obs, _, terminated, truncated, _ = env.step(action)
            observed.append(np.concatenate([np.ravel(v) for v in obs.values()]))
            if terminated or truncated:
                break
        want = data[f"{control}_obs"]
        got = np.array(observed)[::every]
        n = min(len(got), len(want))
        assert n >= 4
        np.testing.assert_allclose(got[:n], want[:n], rtol=0, atol=1e-9)


# ---------------------------------------------------------------- the hybrid laws' force loop
def _actions_with_the_static_weight(name: str, steps: int, seed: int = 1000) -> list[float]:
    """Play ``name`` on PegInHole; from the first contact on, also ask it (from a copy of its
    state) for the action it would take if the F/T sensor read only the peg's static weight.
    Returns max |Δa| per step after contact."""
    from cir_gym import baselines
    from cir_gym.ft_sensor import tool_gravity_wrench

    env = gym.make("cir_gym/PegInHole-v2")
    u = env.unwrapped
    policy = baselines.make(name, "cir_gym/PegInHole-v2")
    obs, _ = env.reset(seed=seed)
    state, start, diffs, touched = None, np.array([True]), [], False
    for _ in range(steps):
        if touched:
            fake = dict(obs)
            R_ws = u.data.site_xmat[u.model.site("ft_site").id].reshape(3, 3)
            fake["wrench"] = tool_gravity_wrench(geo.PEG_MASS, geo.PEG_COM, R_ws)
            a_fake, _ = policy.predict(fake, np.array(state, copy=True), start)
        action, state = policy.predict(obs, state, start)
        if touched:
            diffs.append(float(np.max(np.abs(action - a_fake))))
        start = np.array([False])
        obs, _, terminated, truncated, info = env.step(action)
        touched = touched or info["contact_force"] > 0
        if terminated or truncated:
            break
    return diffs


@pytest.mark.parametrize("name", ["hybrid_force_position", "hybrid_spiral"])
def test_the_hybrid_laws_close_a_force_loop_on_the_measured_wrench(name: str) -> None:
    """In contact (seed 1000, the peg on the face beside the hole), the same state and
    observation with the F/T reading replaced by the peg's static weight give other torques:
    the force-controlled directions feed back the measured wrench (without the force loop
    every action was identical, max |Δa| = 0, through the search too)."""
    diffs = np.array(_actions_with_the_static_weight(name, 1400))
    assert len(diffs) > 100 and diffs.max() > 1e-3, (len(diffs), diffs.max(initial=0.0))
    # on most steps, not only where a contact test flips a mode
    assert np.mean(diffs > 1e-9) > 0.5


def test_the_force_gains_are_designed_against_the_contact_stiffness() -> None:
    """K_I,i = crossover_ratio · sqrt(k̂_i / Λ_ii): the course's integral force regulator with its
    crossover a fraction of the contact's natural frequency (k̂ r² on the moments); the
    integral acts on Σ only, opposes the measured wrench and stays within its bounds;
    crossover_ratio = 0 leaves no force feedback."""
    from cir_gym.baselines.hybrid import HYBRID_STATE, _fields

    from cir_gym import baselines

    policy = baselines.make("hybrid_force_position", "cir_gym/PegInHole-v2")
    g = policy.gains
    Lambda = np.diag([4.0, 5.0, 6.0, 0.01, 0.02, 0.03])
    k = np.r_[np.full(3, g.stiffness), np.full(3, g.stiffness * geo.PEG_RADIUS**2)]
    np.testing.assert_allclose(
        policy.force_gains(Lambda), g.crossover_ratio * np.sqrt(k / np.diag(Lambda))
    )
    assert np.all(np.sqrt(k / np.diag(Lambda)) > 10 * policy.force_gains(Lambda) * 0.999)
    state = np.zeros(policy.state_size)
    fields = _fields(state, HYBRID_STATE)
    gamma = np.array([5.0, -3.0, 7.0, 0.1, 0.0, 0.2])  # the peg pushes +x, −y, +z, …
    f = {"Lambda": Lambda, "gamma": gamma}
    sigma = selection_matrix()
    h = policy.force_loop(f, fields, sigma, np.zeros(6))
    K = policy.force_gains(Lambda)
    want = -policy.dt * K * np.diag(sigma) * gamma
    np.testing.assert_allclose(h, want)
    np.testing.assert_allclose(state[2:8], want)  # the named field is a view into the state row
    assert h[2] == h[5] == 0.0  # the motion-controlled directions carry no integral
    for _ in range(10_000):
        h = policy.force_loop(f, fields, sigma, np.zeros(6))
    assert abs(h[0]) == g.integral_limit and abs(h[3]) == g.integral_limit_moment
    off = baselines.make("hybrid_force_position", "cir_gym/PegInHole-v2", crossover_ratio=0.0)
    state = np.zeros(off.state_size)
    assert not np.any(off.force_loop(f, _fields(state, HYBRID_STATE), sigma, np.zeros(6)))


def test_a_peg_slid_flat_across_the_face_into_the_hole_is_inserted() -> None:
    """The true hole 6+ mm off (no tilt): the peg pressed flat on the face (its tip a few µm
    into the face's plane, beside the opening), slid across to the true axis and pushed in
    counts as inserted: the entry rule does not refuse a peg that reached the opening along
    the face."""
    env = PegInHoleEnv(  # the landing at 50 mm/s is an impact: no force limit here
        control="position", position_uncertainty=0.008, tilt_uncertainty=0.0, sensor="ideal",
        force_limit=1e4,
    )
    offsets = {s: np.linalg.norm(env.reset(seed=s)[1]["hole_offset"]) for s in range(100)}
    seed = next(s for s, r in offsets.items() if r > 0.006)
    obs, info = env.reset(seed=seed)
    true_xy = info["hole_offset"][:2]
    waypoints = [(0.0, 0.0, -2e-5), (*true_xy, -2e-5), (*true_xy, -0.024)]
    for target in waypoints:
        for _ in range(2000):
            dp = np.asarray(target) - obs["peg_pos"]
            action = np.clip(np.r_[dp, np.zeros(3)] / env.increment_scale, -1, 1)
            obs, _, terminated, truncated, info = env.step(action.astype(np.float32))
            if terminated or truncated or np.linalg.norm(dp) < 1e-5:
                break
        if terminated or truncated:
            break
    assert info["is_success"], info


def _all_contacts(env: PegInHoleEnv) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """From every contact of ``mjData.contact`` and ``mj_contactForce``: the largest single
    contact force (N), the net force on the robot (3,) (N, world), and every peg contact's
    normal pushing the peg away from the block (k, 3) and normal force (k,)."""
    m, d = env.model, env.data
    block = m.body("block").id
    peg = m.geom("peg_geom").id
    largest, net, normals, pressing = 0.0, np.zeros(3), [], []
    f = np.zeros(6)
    for i in range(d.ncon):
        g1, g2 = d.contact.geom[i]
        mujoco.mj_contactForce(m, d, i, f)
        frame = d.contact.frame[i].reshape(3, 3)
        sign = 1.0 if m.geom_bodyid[g1] == block else -1.0  # on the robot
        largest = max(largest, float(np.linalg.norm(f[:3])))
        net += sign * frame.T @ f[:3]
        if peg in (g1, g2):
            normals.append(sign * frame[0])
            pressing.append(f[0])
    return largest, net, np.array(normals).reshape(-1, 3), np.array(pressing)


def test_the_contact_sensors_read_every_contact_as_mj_contact_force() -> None:
    """hybrid_spiral on seed 0 (the peg hopping on the face, up to 62 peg contacts, 9 of them
    pressing): at every step the contact sensors' largest single contact and net force equal
    those of mj_contactForce on every contact (1e-9 relative: MuJoCo's own computation, summed
    in another order), and the flags from the peg sensor's strongest PEG_CONTACT_SLOTS
    contacts equal the flags from all of the peg's contacts."""
    from cir_gym import baselines
    from cir_gym.envs.peg_in_hole_contacts import contact_flags

    env = PegInHoleEnv()
    policy = baselines.make("hybrid_spiral", "cir_gym/PegInHole-v2")
    obs, _ = env.reset(seed=0)
    state, touching, most = None, 0, 0
    axis = env.true_hole_R[:, 2]
    for k in range(1400):
        action, state = policy.predict(obs, state, np.array([k == 0]))
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
        largest, net, normals, pressing = _all_contacts(env)
        sensed = env.data.sensordata
        assert env.sensors.largest(sensed) == pytest.approx(largest, rel=1e-9, abs=1e-9)
        np.testing.assert_allclose(env.sensors.net(sensed), net, rtol=1e-9, atol=1e-9)
        speed = float(axis @ env._tip_twist()[:3])
        want = contact_flags(normals, pressing, axis, info["depth"], speed, env._mu_diameter)
        got = (info["two_point_contact"], info["wedged"], info["jammed"])
        assert got == (want.two_point, want.wedged, want.jammed), k
        touching += largest > 0
        most = max(most, len(pressing))
    assert touching > 50 and most > geo.PEG_CONTACT_SLOTS, (touching, most)


def test_a_period_reads_each_physics_step_from_the_sensor_history() -> None:
    """Torque interface, the peg striking the bore's edge (~600 N): the period's rows the env
    reads from MuJoCo's history buffer after one mj_step call of 4 physics steps are the
    sensordata of each physics step stepped one by one from the same state (largest and net
    contact, wrist wrench: equal to the last bit)."""
    env = _exact_env(start_height=0.002, force_limit=1e4)
    m = env.model
    action = np.zeros(7, dtype=np.float32)
    action[1] = 0.3  # the shoulder lowers the arm: the peg strikes the bore's edge
    for _ in range(14):
        env.step(action)
    start = np.zeros(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_INTEGRATION))
    mujoco.mj_getState(m, env.data, start, mujoco.mjtState.mjSTATE_INTEGRATION)
    env.step(action)
    d = mujoco.MjData(m)
    mujoco.mj_setState(m, d, start, mujoco.mjtState.mjSTATE_INTEGRATION)
    d.ctrl[:] = action * env.torque_limit
    rows = []
    for _ in range(env.frame_skip):
        mujoco.mj_step(m, d)
        rows.append(d.sensordata.copy())
    rows = np.array(rows)
    got = env._period
    s = env.sensors
    assert np.max(s.largest(rows)) > 0  # in contact
    np.testing.assert_array_equal(s.largest(got), s.largest(rows))
    np.testing.assert_array_equal(s.net(got), s.net(rows))
    np.testing.assert_array_equal(s.wrist(got), s.wrist(rows))
