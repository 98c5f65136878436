"""The flange-pose references of CartesianTracking: the workspace a reset draws paths in.

A reference is the pose p̄(t), Q̄(t), the twist [ṗ̄; ω̄] and the acceleration [p̈̄; ω̄̇] of the
flange at the control instants t_k = k Δt, k = 0 … K, built with :mod:`cir_gym.trajectories`
(positions on a segment, circle or figure eight with a quintic timing law, the orientation
by slerp about a constant axis) or from a joint-space quintic (``near_singular``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import mujoco
import numpy as np

from cir_gym import operational_space as osp
from cir_gym import trajectories as traj
from cir_gym.robot import Robot

PATHS = ("random", "segment", "circle", "figure_eight", "near_singular", "regulation")
SHAPES = ("segment", "circle", "figure_eight")  # what path="random" draws from


@dataclass(frozen=True)
class CartesianWorkspace:
    """Where a robot's paths are drawn (uniform draws; lengths in m, angles in rad).

    Attributes:
        posture_spread: half-width of the box around the home posture where start postures
            (and regulation goals) are drawn, per joint.
        segment_length: (low, high) length of a segment.
        circle_radius: (low, high) radius of a circle.
        eight_half_axes: ((low, high), (low, high)) half-axes of a figure eight.
        rotation: (low, high) angle the orientation turns by over the episode.
        near_singular_q2: q2 held on the near_singular joint path.
        near_singular_q6: q6 goes from +this to −this on that path (0 at mid-episode).
        min_singular_value: smallest singular value of J (6 × n) a kept path stays above.
        feasibility_stride: control steps between the samples the feasibility check visits.
        max_draws: draws of a path before a reset gives up.
    """

    posture_spread: float = 0.3
    segment_length: tuple[float, float] = (0.1, 0.25)
    circle_radius: tuple[float, float] = (0.05, 0.12)
    eight_half_axes: tuple[tuple[float, float], tuple[float, float]] = ((0.05, 0.12), (0.03, 0.08))
    rotation: tuple[float, float] = (0.2, 0.6)
    near_singular_q2: float = float(np.deg2rad(2.0))
    near_singular_q6: float = 0.3
    min_singular_value: float = 0.05
    feasibility_stride: int = 10
    max_draws: int = 50


#: The iiwa 14's workspace: its 6 × 7 Jacobian loses rank where q2 = q6 = 0 (A1 ∥ A3 and
#: A5 ∥ A7 together); feasible paths keep a smallest singular value above ~0.15.
IIWA14_WORKSPACE = CartesianWorkspace()


class PoseReference(NamedTuple):
    """A flange reference at K + 1 control instants (world frame, SI units)."""

    position: np.ndarray  # p̄ (K + 1, 3) m
    quat: np.ndarray  # Q̄ (K + 1, 4) (w, x, y, z), continuous in time, w ≥ 0 at t = 0
    twist: np.ndarray  # [ṗ̄; ω̄] (K + 1, 6) m/s, rad/s
    acceleration: np.ndarray  # [p̈̄; ω̄̇] (K + 1, 6) m/s², rad/s²


def quat_of(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) (..., 4) of rotation matrices (..., 3, 3) or flat (..., 9)
    (either sign: MuJoCo's ``mju_mat2Quat``, matrix by matrix)."""
    R = np.ascontiguousarray(R, dtype=float)
    if R.size == 9:  # one rotation (the single env's hot path)
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, R.ravel())
        return quat
    lead = R.shape[:-1] if R.shape[-1] == 9 else R.shape[:-2]
    flat = R.reshape(-1, 9)
    quat = np.empty((flat.shape[0], 4))
    for mat, out in zip(flat, quat, strict=True):
        mujoco.mju_mat2Quat(out, mat)
    return quat.reshape(*lead, 4)


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def draw_pose_reference(
    path: str,
    rng: np.random.Generator,
    robot: Robot,
    site: int,
    home: np.ndarray,
    times: np.ndarray,
    workspace: CartesianWorkspace = IIWA14_WORKSPACE,
) -> tuple[PoseReference, np.ndarray]:
    """One draw of a ``path`` reference (see ``PATHS``) and its start posture q(0) (n,).

    Every path starts at the flange pose of q(0), drawn in home ± ``posture_spread``; the
    shapes end at ``times[-1]`` (quintic timing), turning the orientation by an angle in
    ``rotation`` about a random axis. ``regulation`` holds the flange pose of another such
    posture; ``near_singular`` follows a joint quintic with q2 = ``near_singular_q2`` and q6
    from +``near_singular_q6`` to its negative.
    """
    n = home.size
    spread = workspace.posture_spread

    def posture() -> np.ndarray:
        return home + rng.uniform(-spread, spread, n)

    if path == "near_singular":
        qa, qb = posture(), posture()
        qa[1] = qb[1] = workspace.near_singular_q2
        qa[5], qb[5] = workspace.near_singular_q6, -workspace.near_singular_q6
        return _joint_space_reference(robot, site, qa, qb, times), qa
    q0 = posture()
    p0, R0 = robot.site_pose(site, q0)
    K1 = times.size
    if path == "regulation":
        p1, R1 = robot.site_pose(site, posture())
        quat = np.tile(traj.quat_from_matrix(R1), (K1, 1))
        zeros = np.zeros((K1, 6))
        position = np.tile(p1, (K1, 1))
        return PoseReference(position, osp.continuous_quats(quat), zeros, zeros.copy()), q0
    shape = SHAPES[rng.integers(len(SHAPES))] if path == "random" else path
    timing = traj.TimingLaw.quintic(float(times[-1]))
    normal = _unit(rng)
    curve: Any
    if shape == "segment":
        curve = traj.Segment(p0, p0 + rng.uniform(*workspace.segment_length) * _unit(rng), timing)
    elif shape == "circle":
        r = rng.uniform(*workspace.circle_radius)
        u = traj.Circle(p0, r, timing, normal=normal).u  # the plane's first axis
        curve = traj.Circle(p0 - r * u, r, timing, normal=normal)  # θ₀ = 0 at p0
    elif shape == "figure_eight":
        (a_lo, a_hi), (b_lo, b_hi) = workspace.eight_half_axes
        curve = traj.FigureEight(
            p0, rng.uniform(a_lo, a_hi), rng.uniform(b_lo, b_hi), timing, normal=normal
        )
    else:
        raise ValueError(f"path must be one of {PATHS}, got {path!r}")
    turn = traj.matrix_from_axis_angle(_unit(rng), rng.uniform(*workspace.rotation))
    p, v, a = curve.evaluate(times)
    R, w, wd = traj.OrientationInterpolation(R0, R0 @ turn, timing).evaluate(times)
    reference = PoseReference(
        p,
        osp.continuous_quats(traj.quat_from_matrix(R)),
        np.concatenate((v, w), axis=1),
        np.concatenate((a, wd), axis=1),
    )
    return reference, q0


def _joint_space_reference(
    robot: Robot, site: int, qa: np.ndarray, qb: np.ndarray, times: np.ndarray
) -> PoseReference:
    """The flange pose, twist J q̇ and acceleration J q̈ + J̇ q̇ along the joint quintic from
    ``qa`` to ``qb`` (the robot's kinematics: the model errors are in the masses only)."""
    qs, qds, qdds = traj.QuinticPolynomial(qa, qb, float(times[-1])).evaluate(times)
    K1 = times.size
    ref = PoseReference(np.zeros((K1, 3)), np.zeros((K1, 4)), np.zeros((K1, 6)), np.zeros((K1, 6)))
    for k, (q, qd, qdd) in enumerate(zip(qs, qds, qdds, strict=True)):
        p, R = robot.site_pose(site, q)
        J = robot.jacobian(site, q)
        ref.position[k] = p
        ref.quat[k] = quat_of(R)
        ref.twist[k] = J @ qd
        ref.acceleration[k] = J @ qdd + robot.jacobian_dot_qdot(site, q, qd)
    return ref._replace(quat=osp.continuous_quats(ref.quat))


def kinematically_feasible(
    robot: Robot,
    site: int,
    reference: PoseReference,
    q0: np.ndarray,
    dt: float,
    workspace: CartesianWorkspace = IIWA14_WORKSPACE,
) -> bool:
    """Whether closed-loop inverse kinematics follows ``reference`` from ``q0`` inside the
    joint limits with the smallest singular value of J above ``min_singular_value``.

    Checked every ``feasibility_stride`` control steps h = stride · ``dt``:
    q ← q + h J⁺(ẋ̄ + K_clik e), K_clik = 1 / (2 h), e = [p̄ − p; rotvec error].
    """
    stride = workspace.feasibility_stride
    h = stride * dt
    gain = 0.5 / h
    q = q0.copy()
    for k in range(0, len(reference.position), stride):
        J = robot.jacobian(site, q)
        JJt = J @ J.T
        if np.sqrt(max(np.linalg.eigvalsh(JJt)[0], 0.0)) < workspace.min_singular_value:
            return False
        p, R = robot.site_pose(site, q)
        e = np.concatenate(
            (
                reference.position[k] - p,
                osp.rotvec_error(reference.quat[k], traj.quat_from_matrix(R)),
            )
        )
        q = q + h * (J.T @ np.linalg.solve(JJt, reference.twist[k] + gain * e))
        if np.any(q < robot.lower) or np.any(q > robot.upper):
            return False
    return True
