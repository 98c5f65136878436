"""RedundantIK's scene and episode draws: the model, the reference path, the obstacle, the
"manipulability" start and the "joint_limits" window, and the pictures ``render`` draws.

Every draw takes the episode's random generator and consumes it in a fixed order, so a seed
gives one task.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from cir_gym import rendering
from cir_gym import trajectories as traj
from cir_gym.envs.redundant_ik_config import MANIPULABILITY_WINDOW, RedundantIKRobot
from cir_gym.operational_space import align_quat
from cir_gym.redundancy import null_vector
from cir_gym.robot import robot_path
from cir_gym.self_motion import (
    LAP_STRIDE,
    Reference,
    SelfMotionLap,
    TaskKinematics,
    clearing_motion,
    min_norm_motion,
    min_norm_samples,
    self_motion_postures,
)

__all__ = [
    "DUMMY_OBSTACLE",
    "SHAPES",
    "START_MARGIN",
    "build_model",
    "caption",
    "draw_obstacle",
    "draw_task",
    "narrowed_joint_window",
    "planar_path",
    "poorly_conditioned_start",
    "spatial_path",
]

SHAPES = ("circle", "ellipse", "figure_eight")
CONTROL_TIMESTEP = 1e-4  # s, model timestep: only the unit of the control period (no dynamics)
DUMMY_OBSTACLE_CENTRE = 10.0  # m, every coordinate of the far-away dummy obstacle (radius 0)
#: (centre (3,), radius) of "no obstacle": far away, radius 0
DUMMY_OBSTACLE = np.array([DUMMY_OBSTACLE_CENTRE] * 3 + [0.0])
OBSTACLE_DRAWS = 30  # obstacle placements tried on one path
SELF_MOTION_SHARE = 0.1  # min |v_j| (unit null vector) of a joint narrowed for "joint_limits"
START_MARGIN = 0.3  # rad: "manipulability" start candidates keep this far from the limits
SPATIAL_CENTRE_SPREAD = 0.03  # m: the iiwa's path centre within ± this of the home tcp
_GEOM_TYPES = {"cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER, "sphere": mujoco.mjtGeom.mjGEOM_SPHERE}


# ---------------------------------------------------------------------- model
def build_model(arm: RedundantIKRobot) -> mujoco.MjModel:
    """The robot file plus an obstacle geom (moved per episode; no contacts: the clearance is
    computed analytically) and the arm's camera, if it has one."""
    spec = mujoco.MjSpec.from_file(str(robot_path(arm.robot)))
    spec.option.timestep = CONTROL_TIMESTEP
    # compiled at the base (so the free camera frames the robot); moved at every reset
    spec.worldbody.add_geom(
        name="obstacle",
        type=_GEOM_TYPES[arm.obstacle_geom],
        size=[0.05, 0.05, 0.0],
        pos=[0.0, 0.0, 0.0],
        contype=0,
        conaffinity=0,
        rgba=[0.9, 0.1, 0.1, 0.8],
    )
    if arm.camera is not None:
        name, pos, fovy = arm.camera
        spec.worldbody.add_camera(name=name, pos=list(pos), fovy=fovy)
    return spec.compile()


# ---------------------------------------------------------------------- reference
def _closed_path(
    shape: str,
    centre: np.ndarray,
    size: float,
    aspect: float,
    timing: traj.TimingLaw,
    start_angle: float,
    turns: float,
    **plane: Any,
) -> traj.Circle | traj.Ellipse | traj.FigureEight:
    if shape == "circle":
        return traj.Circle(centre, size, timing, start_angle=start_angle, turns=turns, **plane)
    if shape == "ellipse":
        return traj.Ellipse(
            centre, size, aspect * size, timing, start_angle=start_angle, turns=turns, **plane
        )
    return traj.FigureEight(
        centre, size, aspect * size, timing, start_angle=start_angle, turns=turns, **plane
    )


def planar_path(
    rng: np.random.Generator, p_home: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The planar arm's lap: x̄ (K + 1, 2) m and x̄̇ (K + 1, 2) m/s at the times t (K + 1,) s.

    A circle, ellipse or figure eight (size 0.1–0.25 m, aspect 0.5–1, axes at a random angle,
    random start angle and direction) centred 0.5–0.8 m from the base within ±0.8 rad of the
    home position ``p_home`` (2,), traced once with a quintic timing law over t[-1].
    """
    heading = float(np.arctan2(p_home[1], p_home[0]) + rng.uniform(-0.8, 0.8))
    rho = rng.uniform(0.5, 0.8)
    centre = rho * np.array([np.cos(heading), np.sin(heading)])
    shape = SHAPES[int(rng.integers(len(SHAPES)))]
    size = float(rng.uniform(0.1, 0.25))
    aspect = float(rng.uniform(0.5, 1.0))
    angle = float(rng.uniform(-np.pi, np.pi))  # orientation of the shape's axes
    axes = ((np.cos(angle), np.sin(angle)), (-np.sin(angle), np.cos(angle)))
    timing = traj.TimingLaw.quintic(float(t[-1]))
    start_angle = float(rng.uniform(-np.pi, np.pi))
    turns = float(rng.choice((-1.0, 1.0)))
    path = _closed_path(shape, centre, size, aspect, timing, start_angle, turns, axes=axes)
    x, xd, _ = path.evaluate(t)
    return x, xd


def spatial_path(
    rng: np.random.Generator,
    p_home: np.ndarray,
    R_home: np.ndarray,
    quat_home: np.ndarray,
    t: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """The iiwa's lap at the times t (K + 1,) s: x̄, x̄̇ (K + 1, 3), R̄ (K + 1, 3, 3), its
    quaternion (K + 1, 4) on the hemisphere of ``quat_home`` and ω̄ (K + 1, 3) rad/s.

    A circle, ellipse or figure eight (size 0.05–0.15 m, aspect 0.5–1) in a random plane,
    centred within ``SPATIAL_CENTRE_SPREAD`` of the home tcp position ``p_home``, traced once
    with a quintic timing law σ(t); R̄(t) = Rot(r, α sin 2πσ) R_home (world axis r random,
    α ∈ [0.1, 0.3] rad), ω̄ = r α 2π cos(2πσ) σ̇.
    """
    normal = rng.standard_normal(3)
    centre = p_home + rng.uniform(-SPATIAL_CENTRE_SPREAD, SPATIAL_CENTRE_SPREAD, 3)
    shape = SHAPES[int(rng.integers(len(SHAPES)))]
    size = float(rng.uniform(0.05, 0.15))
    aspect = float(rng.uniform(0.5, 1.0))
    timing = traj.TimingLaw.quintic(float(t[-1]))
    start_angle = float(rng.uniform(-np.pi, np.pi))
    turns = float(rng.choice((-1.0, 1.0)))
    path = _closed_path(shape, centre, size, aspect, timing, start_angle, turns, normal=normal)
    x, xd, _ = path.evaluate(t)
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    alpha = float(rng.uniform(0.1, 0.3))
    s, sd, _ = timing.evaluate(t)
    sigma, sigma_d = s / timing.length, sd / timing.length
    R = traj.matrix_from_axis_angle(axis, alpha * np.sin(2 * np.pi * sigma)) @ R_home
    # the hemisphere of the home orientation (continuous: R̄ stays within 0.3 rad of it)
    quat = align_quat(traj.quat_from_matrix(R), quat_home)
    omega = (alpha * 2 * np.pi * np.cos(2 * np.pi * sigma) * sigma_d)[:, None] * axis
    return x, xd, R, quat, omega


# ---------------------------------------------------------------------- objectives' set-ups
def _random_normal(rng: np.random.Generator, axis: np.ndarray, pos_dim: int) -> np.ndarray:
    """A random unit vector normal to ``axis`` (in the plane z = 0 when ``pos_dim`` is 2)."""
    if pos_dim == 2:
        normal = np.array([-axis[1], axis[0], 0.0])
        return normal / np.linalg.norm(normal) * rng.choice((-1.0, 1.0))
    v = rng.standard_normal(3)
    v -= (v @ axis) / (axis @ axis) * axis
    return v / np.linalg.norm(v)


def draw_obstacle(
    rng: np.random.Generator,
    kin: TaskKinematics,
    ref: Reference,
    q0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    velocity_limit: np.ndarray,
    links: tuple[str, ...],
) -> tuple[np.ndarray, np.ndarray | None]:
    """An obstacle on the minimum-norm sweep of ``links`` and the motion that clears it.

    A random instant t* ∈ [0.3, 0.8] T of the minimum-norm (pseudo-inverse CLIK) motion from
    q(0) and a random point of one of the links' capsules are drawn; the obstacle (radius
    4–7 cm) overlaps that capsule by 5–20 mm there, on a random side. Draws that come within
    radius + 0.08 m of the task path, that are within 3 cm of the arm at q(0), or that no
    motion along the self-motion lap clears (:func:`cir_gym.self_motion.clearing_motion`:
    within the joint and velocity limits, ``LAP_CLEARANCE`` at every sample of the whole lap)
    are rejected (``OBSTACLE_DRAWS`` tries).

    Returns:
        (centre (3,), radius) m and the clearing motion (K, n); ``DUMMY_OBSTACLE`` and None
        when no draw was kept.
    """
    model, capsules = kin.robot.model, kin.capsules
    bodies = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in links]
    pick = [i for i, g in enumerate(capsules.geom_ids) if model.geom_bodyid[g] in bodies]
    lap = SelfMotionLap(kin, ref, q0, lower, upper, velocity_limit)  # computed as needed
    samples = min_norm_samples(kin, ref, q0[None], LAP_STRIDE)  # q(0)'s own motion, as drawn
    motion: list[np.ndarray] = []
    for _ in range(OBSTACLE_DRAWS):
        k = int(rng.integers(int(0.3 * lap.K), int(0.8 * lap.K)))
        while len(motion) <= k:
            motion.append(next(samples)[0][0])
        kin.pose(motion[k])
        a, b = capsules.segments(kin.robot.data)
        i = int(rng.choice(pick))
        point = a[i] + rng.uniform(0.3, 1.0) * (b[i] - a[i])
        radius = float(rng.uniform(0.04, 0.07))
        normal = _random_normal(rng, b[i] - a[i], kin.pos_dim)
        depth = float(rng.uniform(0.005, 0.02))
        centre = point + (capsules.radius[i] + radius - depth) * normal
        d_path = np.min(np.linalg.norm(ref.x - centre[: kin.pos_dim], axis=1))
        kin.pose(q0)
        if d_path > radius + 0.08 and capsules.clearance(kin.robot.data, centre, radius) > 0.03:
            witness = clearing_motion(lap, centre, radius)
            if witness is not None:
                return np.concatenate((centre, [radius])), witness
    return DUMMY_OBSTACLE.copy(), None


def poorly_conditioned_start(
    kin: TaskKinematics, ref: Reference, q: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> np.ndarray:
    """"manipulability": the posture whose minimum-norm lap is least manipulable.

    Candidates: ``q`` (on the reference's first pose) and the postures of its self-motion
    there (:func:`cir_gym.self_motion.self_motion_postures`, ≥ ``START_MARGIN`` rad from every
    joint limit, or no closer than ``q``). From each, the minimum-norm (pseudo-inverse CLIK)
    motion along the whole reference is run; candidates whose motion leaves the joint limits
    are dropped (plain CLIK could not finish the lap, so the comparison would not be at equal
    task error), and of the rest the one whose motion reaches the least manipulability over
    t ≥ ``MANIPULABILITY_WINDOW`` T is returned: the redundancy starts badly used for the
    whole lap, as the metric measures it.
    """
    postures = self_motion_postures(kin, q, ref, lower, upper, margin=START_MARGIN)
    motions, ws = min_norm_motion(kin, ref, np.array(postures), stride=10)  # all at once
    best, start = np.inf, q
    for i, posture in enumerate(postures):
        motion, w = motions[:, i], ws[:, i]
        if np.any(motion < lower) or np.any(motion > upper):
            continue
        w_lap = float(np.min(w[int(MANIPULABILITY_WINDOW * len(w)) :]))
        if w_lap < best:
            best, start = w_lap, posture
    return start


def narrowed_joint_window(
    rng: np.random.Generator,
    kin: TaskKinematics,
    q0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    width: float,
) -> tuple[np.ndarray, np.ndarray]:
    """"joint_limits": the joint limits (n,) each rad with one random joint's range ``width``.

    q(0) sits 10–25 % of the window from a random side of it, so minimum-norm motion runs
    into that limit on many paths, while the self-motion can move the joint towards the
    window's centre. The other joints keep ``lower``/``upper``; the window is clipped to them.
    Only a joint that the self-motion moves is narrowed (|v_j| ≥ ``SELF_MOTION_SHARE`` for the
    unit null vector v of J at q(0)): on the iiwa the elbow q4 is fixed by the
    shoulder–wrist distance, which the pose task fixes, so no kinematic controller could keep
    a narrowed q4 in range.
    """
    v = null_vector(kin.jacobian(q0))
    movable = np.flatnonzero(np.abs(v) >= SELF_MOTION_SHARE)
    j = int(movable[rng.integers(movable.size)])
    frac = float(rng.uniform(0.1, 0.25))
    frac = frac if rng.random() < 0.5 else 1.0 - frac
    lower, upper = lower.copy(), upper.copy()
    lower[j] = max(q0[j] - frac * width, lower[j])
    upper[j] = min(lower[j] + width, upper[j])
    return lower, upper


# ---------------------------------------------------------------------- pictures
def _as_3d(points: np.ndarray) -> np.ndarray:
    """Points (..., 2) of the plane z = 0 (or (..., 3)) as (..., 3)."""
    pts = np.asarray(points, dtype=float)
    if pts.shape[-1] == 3:
        return pts
    return np.concatenate((pts, np.zeros((*pts.shape[:-1], 1))), axis=-1)


def draw_task(env: Any, scene: mujoco.MjvScene) -> None:
    """A RedundantIK env's markers: the closed reference path, the target (a frame for the
    pose task), joint-limit warnings, the obstacle (a model geom, moved per episode) with a
    translucent halo when the arm comes within 5 cm."""
    k = env.step_count
    path = _as_3d(env.reference.x)
    rendering.add_polyline(
        scene, path, 0.004, rendering.REFERENCE, max_segments=rendering.TRACE_SAMPLES
    )
    target = path[k]
    if env.task_dim == 6:
        rendering.add_frame(scene, target, env.reference.R[k], 0.12, 0.006)
        rendering.add_sphere(scene, target, 0.015, rendering.TARGET)
    else:
        rendering.add_sphere(scene, target, 0.025, rendering.TARGET)
    rendering.tint_joint_limits(
        scene, env.model, env.robot.joint_ids, env.joint_positions, env.lower, env.upper
    )
    rendering.place_world_geoms(scene, env.model)  # the obstacle, moved per episode
    radius = env.obstacle_radius
    if radius > 0 and k > 0:
        clear = float(env.trace["clearance"][k - 1])
        if clear < 0.05:  # a halo out to the arm: orange, more opaque as it closes in
            near = max(clear, 0.0)
            colour = (1.0, 0.6, 0.1, 0.15 + 0.35 * (1.0 - near / 0.05))
            rendering.add_sphere(scene, env.obstacle_centre, radius + near, colour)


def caption(env: Any) -> str:
    """``t``, the task error (mm, and deg for the pose task) and the objective's quantity
    (w, joint-limit margin or clearance)."""
    k = env.step_count
    if k == 0:
        return f"t {0.0:5.2f} s  {env.objective}"
    now = env.trace[k - 1]
    text = f"t {k * env.dt:5.2f} s  e {1e3 * now['task_error']:5.2f} mm"
    if env.task_dim == 6:
        text += f" {np.degrees(now['orientation_error']):5.2f}°"
    if env.objective == "manipulability":
        text += f"  w {now['manipulability']:.3f}"
    elif env.objective == "joint_limits":
        text += f"  margin {now['joint_limit_margin']:.3f} rad"
    else:
        text += f"  clear {100 * now['clearance']:4.1f} cm"
    return text
