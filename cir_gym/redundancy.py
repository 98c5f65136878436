"""Redundancy science (chapter 1): what a redundant arm's self-motion can be used for.

Kinematic measures shared by the RedundantIK environments (:mod:`cir_gym.envs.redundant_ik`)
and the controllers of :mod:`cir_gym.baselines.kinematic`: Yoshikawa's manipulability, the
joint-limit objective, its gradient and the joint-limit margin, the null vector of J and the
self-motion through a configuration, the SO(3) orientation error (through unit quaternions),
the analytic capsule–obstacle clearance of the robot's links, and the search for a motion
through sampled self-motion configurations (:func:`lap_witness`; the lap itself, carried
along a reference, is :mod:`cir_gym.self_motion`). Nothing here knows a task: the environment
draws references and scores episodes, the controllers choose q̇.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator

import mujoco
import numpy as np

__all__ = [
    "OBJECTIVES",
    "LinkCapsules",
    "joint_limit_margin",
    "joint_limit_objective",
    "joint_limit_objective_gradient",
    "lap_moves",
    "lap_steps",
    "lap_witness",
    "manipulability",
    "null_vector",
    "orientation_error",
    "orientation_errors",
    "point_segment_distance",
    "quat_orientation_error",
    "walk_self_motion",
    "walk_self_motions",
    "witness_path",
]

OBJECTIVES = ("manipulability", "joint_limits", "obstacle")  # what the self-motion serves
LAP_WINDOW = 8  # neighbouring self-motion nodes a witness may move to in one sample


# ---------------------------------------------------------------------- kinematic measures
# Stacked inputs: a Jacobian (m, n) or rows of them (..., m, n), a joint vector (n,) or rows
# (..., n) (with the limits (n,) or rows like q); numpy's stacked linear algebra does each
# row's matrices alone, so a row gives the same numbers alone or in a batch. A measure of one
# J or q is a float.
def _number(x: np.ndarray) -> float | np.ndarray:
    """A float for a 0-d result (one J or q), else the array."""
    return float(x) if np.ndim(x) == 0 else x


def manipulability(J: np.ndarray) -> float | np.ndarray:
    """Yoshikawa's manipulability w = sqrt(det(J Jᵀ)) (...) of task Jacobians J (..., m, n)."""
    return _number(np.sqrt(np.maximum(np.linalg.det(J @ np.swapaxes(J, -1, -2)), 0.0)))


def joint_limit_objective(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> float:
    """w(q) = −(1/2n) Σ ((q_i − q̄_i)/(q_iM − q_im))², q̄ the range midpoint; in [−1/8, 0]
    (one q (n,))."""
    u = (q - 0.5 * (lower + upper)) / (upper - lower)
    return float(-0.5 * (u @ u) / q.size)


def joint_limit_objective_gradient(
    q: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> np.ndarray:
    """∂w/∂q (..., n) of :func:`joint_limit_objective` at q (..., n):
    −(q_i − q̄_i) / (n (q_iM − q_im)²)."""
    r = upper - lower
    return -(q - 0.5 * (lower + upper)) / (q.shape[-1] * r * r)


def joint_limit_margin(
    q: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> float | np.ndarray:
    """min_i min(q_i − q_im, q_iM − q_i) (...) rad of q (..., n): the distance to the nearest
    joint limit."""
    return _number(np.minimum((q - lower).min(axis=-1), (upper - q).min(axis=-1)))


def null_vector(J: np.ndarray) -> np.ndarray:
    """Unit vectors (..., n) spanning ker J of Jacobians (..., m, n) with dim ker J = 1: the
    last right singular vector (its sign is arbitrary)."""
    return np.linalg.svd(J)[2][..., -1, :]


def walk_self_motions(
    q: np.ndarray,
    jacobians: Callable[[np.ndarray], np.ndarray],
    project: Callable[[np.ndarray, np.ndarray], np.ndarray],
    stop: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
    arc: float,
    step: float,
) -> Iterator[tuple[float, np.ndarray, np.ndarray, np.ndarray]]:
    """The self-motions through the rows of ``q`` (N, n), all rows at once.

    Walks each way (s > 0 first) along the unit null vector v of J (:func:`null_vector`: dim
    ker J = 1 on both robots; its sign kept continuous along the walk), taking
    x ← project(x + step v, rows) (``project`` restores the rows' task poses, e.g. by Newton
    steps), until ``stop(rows, x, x_next)`` (M,) or |s| would exceed ``arc`` (rad). After
    each step yields (s, rows (M,), x (M, n), J (M, m, n)): the signed arc length s (rad),
    the rows still walking (indices into q), their new points and ``jacobians`` there (the
    next step's null vectors come from those J). Rows are walked alone: a row's points are
    the same in any batch. ``jacobians``: rows (M, n) → (M, m, n); ``q`` is never yielded.
    """
    J0 = jacobians(q)
    v0 = null_vector(J0)
    for sign in (1.0, -1.0):
        x, J, prev = q.copy(), J0.copy(), sign * v0
        walking = np.arange(len(q))
        for i in range(1, int(arc / step) + 1):
            v = null_vector(J[walking])
            prev[walking] = np.where((v * prev[walking]).sum(axis=-1)[:, None] >= 0, v, -v)
            x_next = project(x[walking] + step * prev[walking], walking)
            go = ~stop(walking, x[walking], x_next)
            walking, x_next = walking[go], x_next[go]
            if not walking.size:
                break
            x[walking] = x_next
            J[walking] = J_next = jacobians(x_next)
            yield sign * i * step, walking, x_next, J_next


def walk_self_motion(
    q: np.ndarray,
    jacobian: Callable[[np.ndarray], np.ndarray],
    project: Callable[[np.ndarray], np.ndarray],
    stop: Callable[[np.ndarray, np.ndarray], bool],
    arc: float,
    step: float,
) -> list[tuple[float, np.ndarray]]:
    """Points (s, q_s) of the self-motion through one ``q`` (n,): s (rad) the signed arc
    length, s > 0 first, then s < 0.

    :func:`walk_self_motions` of one row: ``jacobian`` (n,) → (m, n), ``project`` (n,) → (n,)
    and ``stop(q_previous, q) → bool`` take one configuration. ``q`` itself is not included.
    """
    return [
        (s, x[0].copy())
        for s, _, x, _ in walk_self_motions(
            np.asarray(q, dtype=float)[None],
            lambda x: jacobian(x[0])[None],
            lambda x, _: project(x[0])[None],
            lambda _, x, x_next: np.array([bool(stop(x[0], x_next[0]))]),
            arc,
            step,
        )
    ]


def lap_moves(
    q_prev: np.ndarray, q_next: np.ndarray, bound: np.ndarray, window: int = LAP_WINDOW
) -> np.ndarray:
    """Which moves from the N nodes ``q_prev`` (N, n) of one sample to ``q_next`` (N, n) of the
    next stay within ``bound`` (n,) per joint: booleans (2 ``window`` + 1, N), [o, i] for node i
    reached from node j = i − (o − ``window``) with |q_next[i] − q_prev[j]| ≤ ``bound`` (False
    where j does not exist)."""
    j, inside = _neighbours(len(q_next), window)
    return inside & (np.abs(q_next - q_prev[j]) <= bound).all(axis=2)


@functools.lru_cache(maxsize=8)
def _neighbours(N: int, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Node j = i − (o − window) (clipped into [0, N)) for each offset o and node i, and
    whether it exists: (2 window + 1, N) each, read-only (cached)."""
    j = np.arange(N)[None, :] - np.arange(-window, window + 1)[:, None]
    inside = (j >= 0) & (j < N)
    j = np.clip(j, 0, N - 1)
    j.flags.writeable = inside.flags.writeable = False
    return j, inside


def lap_steps(q: np.ndarray, bound: np.ndarray, window: int = LAP_WINDOW) -> np.ndarray:
    """:func:`lap_moves` between every two consecutive samples of ``q`` (K, N, n): booleans
    (K, 2 ``window`` + 1, N), row k the moves from sample k − 1 to k (row 0 unused). It does
    not depend on which nodes are usable, so a lap computes it once for every obstacle tried.
    """
    K, N, _ = q.shape
    steps = np.zeros((K, 2 * window + 1, N), dtype=bool)
    for k in range(1, K):
        steps[k] = lap_moves(q[k - 1], q[k], bound, window)
    return steps


def lap_witness(
    q: np.ndarray,
    usable: np.ndarray,
    bound: np.ndarray,
    start: int,
    window: int = LAP_WINDOW,
    steps: np.ndarray | None = None,
) -> np.ndarray | None:
    """A motion through sampled configurations, or None when none exists.

    ``q`` (K, N, n) holds N configurations at each of K sample times (N nodes of a
    self-motion, ordered along it), ``usable`` (K, N) which of them may be visited. Returns
    node indices (K,) starting at ``start`` with every node usable and every step between
    consecutive samples within ``bound`` (n,) per joint (|Δq_j| ≤ bound_j), moving at most
    ``window`` nodes along the ordering per sample (:func:`witness_path`). ``steps``:
    :func:`lap_steps` of (q, bound, window), when the caller has it already.
    """
    K, N, _ = q.shape
    if steps is None:
        steps = lap_steps(q, bound, window)
    return witness_path(K, N, start, usable.__getitem__, steps.__getitem__, window)


def witness_path(
    K: int,
    N: int,
    start: int,
    usable: Callable[[int], np.ndarray],
    moves: Callable[[int], np.ndarray],
    window: int = LAP_WINDOW,
) -> np.ndarray | None:
    """:func:`lap_witness` on samples asked for one at a time, in order: ``usable(k)`` (N,)
    and ``moves(k)`` (:func:`lap_moves` into sample k, k ≥ 1), so a caller can compute a
    sample only when the search gets there (it stops at the first sample nothing reaches).

    Forward reachability with parent pointers (dynamic programming), O(K N window); a node's
    parent is the first reachable node in the order i + ``window``, ..., i − ``window``.
    """
    if not usable(0)[start]:
        return None
    j = _neighbours(N, window)[0]
    nodes = np.arange(N)
    reach = np.zeros(N, dtype=bool)
    reach[start] = True
    parent = np.full((K, N), -1)
    for k in range(1, K):
        ok = moves(k) & reach[j]  # (2 window + 1, N): reachable from that neighbour
        new = ok.any(axis=0)
        parent[k, new] = j[ok.argmax(axis=0), nodes][new]  # the first neighbour in order
        reach = new & usable(k)
        if not reach.any():
            return None
    path = np.empty(K, dtype=int)
    path[-1] = int(np.flatnonzero(reach)[0])
    for k in range(K - 1, 0, -1):
        path[k - 1] = parent[k, path[k]]
    return path


def orientation_error(R_ref: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotation vector θ r (3,) of R_ref Rᵀ (world frame), θ ∈ [0, π] (rad).

    Computed through unit quaternions (:func:`quat_orientation_error`), so it is defined on
    SO(3) (no Euler angles) and d(θ r)/dt ≈ ω_ref − ω for small errors.
    """
    quat_ref, quat = np.empty(4), np.empty(4)
    mujoco.mju_mat2Quat(quat_ref, np.ascontiguousarray(R_ref).ravel())
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(R).ravel())
    return quat_orientation_error(quat_ref, quat)


def orientation_errors(R_ref: np.ndarray, R: np.ndarray) -> np.ndarray:
    """:func:`orientation_error` (N, 3) of one reference R_ref (3, 3) against each rotation of
    R (N, 9) (rows of MuJoCo's ``xmat``)."""
    return np.array([orientation_error(R_ref, Ri.reshape(3, 3)) for Ri in R]).reshape(-1, 3)


def quat_orientation_error(quat_ref: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """Rotation vector θ r (3,) of Q_ref ⊗ Q⁻¹ (quaternions (w, x, y, z), world frame).

    With Q_e = (η, ε) = Q_ref ⊗ Q⁻¹: θ r = 2 atan2(‖ε‖, η) ε/‖ε‖, wrapped to θ ∈ [0, π] (the
    shorter rotation, so Q and −Q give the same error). MuJoCo's C helpers do the arithmetic.
    """
    conj, err, vec = np.empty(4), np.empty(4), np.empty(3)
    mujoco.mju_negQuat(conj, quat)
    mujoco.mju_mulQuat(err, quat_ref, conj)
    mujoco.mju_quat2Vel(vec, err, 1.0)
    return vec


class LinkCapsules:
    """The robot's moving capsule geoms as segments, for an analytic clearance.

    Each capsule is the set of points within ``radius`` of a segment [a, b] along the geom's z
    axis (half length ``size[1]``). The clearance to a spherical obstacle (centre c, radius
    ρ; a cylinder along z for the planar arm, whose links lie in the plane of c) is
    min_i (dist(c, [a_i, b_i]) − r_i) − ρ: negative when they intersect.

    Args:
        model: a model holding the robot (its capsules on bodies with joints).
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        capsule = int(mujoco.mjtGeom.mjGEOM_CAPSULE)
        moving = model.body_dofnum > 0
        ids = [
            g
            for g in range(model.ngeom)
            if int(model.geom_type[g]) == capsule
            and moving[model.geom_bodyid[g]]
            and model.geom_contype[g] != 0
        ]
        self.geom_ids = np.array(ids, dtype=int)
        self.radius = model.geom_size[self.geom_ids, 0].copy()  # (c,) m
        self.half_length = model.geom_size[self.geom_ids, 1].copy()  # (c,) m

    def segments(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """End points a, b (c, 3) in the world frame (after ``mj_kinematics``)."""
        return self.ends(data.geom_xpos[self.geom_ids], data.geom_xmat[self.geom_ids])

    def ends(self, centre: np.ndarray, xmat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """End points a, b (..., c, 3) of the capsules with centres (..., c, 3) and rotations
        (..., c, 9) (MuJoCo's ``geom_xpos`` and ``geom_xmat`` of ``geom_ids``)."""
        z = xmat[..., 2::3]  # the geom's z axis: the third column of the row-major R (9,)
        half = self.half_length[:, None] * z
        return centre - half, centre + half

    def clearance(self, data: mujoco.MjData, centre: np.ndarray, radius: float) -> float:
        """Minimum distance (m) between the obstacle sphere and the capsules (< 0: collision):
        :meth:`segment_clearance` of :meth:`segments`."""
        return float(self.segment_clearance(*self.segments(data), centre, radius))

    def segment_clearance(
        self, a: np.ndarray, b: np.ndarray, centre: np.ndarray, radius: float
    ) -> np.ndarray:
        """:meth:`clearance` of stored capsule end points a, b (..., c, 3): shape (...)."""
        return (point_segment_distance(centre, a, b) - self.radius).min(axis=-1) - radius


def point_segment_distance(c: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (...,) from the point c (3,) to the segments [a, b] (..., 3)."""
    ab, ac = b - a, c - a
    t = np.einsum("...j,...j->...", ac, ab) / np.maximum(np.einsum("...j,...j->...", ab, ab), 1e-18)
    d = ac - np.minimum(np.maximum(t, 0.0), 1.0)[..., None] * ab  # c − closest point
    return np.sqrt(np.einsum("...j,...j->...", d, d))
