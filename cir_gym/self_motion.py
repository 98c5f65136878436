"""The self-motion lap: a redundant arm's self-motion carried along a sampled task reference.

Configurations of the self-motion through q(0) (:func:`cir_gym.redundancy.walk_self_motion`)
are each moved along the reference by minimum-norm CLIK, all rows at once
(:func:`min_norm_samples`, on MuJoCo's batched kinematics :class:`RowKinematics`);
:func:`clearing_motion` searches that lap for a motion that stays on the task, inside the joint
and velocity limits and clear of an obstacle at every sample
(:func:`cir_gym.redundancy.witness_path`). It is what sets up a RedundantIK episode (where an
obstacle may go, which posture starts "manipulability"); nothing here knows an environment.

Shapes: n joints, p = ``pos_dim`` position coordinates (2 on the plane, 3 in space), m =
``task_dim`` task coordinates (2: position on the plane; 6: position and orientation),
N rows (configurations) at once, K + 1 samples of the reference.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, NamedTuple

import mujoco
import mujoco.batch
import numpy as np

from cir_gym.redundancy import (
    LAP_WINDOW,
    LinkCapsules,
    joint_limit_margin,
    lap_moves,
    orientation_error,
    orientation_errors,
    walk_self_motion,
    witness_path,
)
from cir_gym.robot import Robot

__all__ = [
    "LAP_CLEARANCE",
    "LAP_STRIDE",
    "LAP_TASK_TOLERANCE",
    "Reference",
    "RowKinematics",
    "RowPoses",
    "SelfMotionLap",
    "TaskKinematics",
    "clearing_motion",
    "min_norm_motion",
    "min_norm_samples",
    "self_motion_postures",
]

IK_TOLERANCE = 1e-12  # m (and rad): residual of an IK solve
IK_STEP = 0.2  # rad: the largest joint step of one Newton iteration of the IK
LAP_STRIDE = 5  # control steps between the samples of the self-motion lap
LAP_CLEARANCE = 0.005  # m, clearance a clearing motion keeps at every sample
LAP_TASK_TOLERANCE = 1e-3  # m (orientation: 10× in rad), task error of a usable configuration
LAP_CHUNK = 4  # samples of the lap computed at a time as an obstacle's search advances


@dataclass(frozen=True)
class Reference:
    """A task reference sampled at the control period: K + 1 samples, t_k = k ``dt``.

    Attributes:
        x: (K + 1, p) m, position x̄.
        xd: (K + 1, p) m/s, velocity x̄̇.
        R: (K + 1, 3, 3) orientation R̄ (identity on the plane).
        quat: (K + 1, 4) R̄ as unit quaternions (w, x, y, z), continuous along the lap.
        omega: (K + 1, 3) rad/s, angular velocity ω̄ (world frame; zero on the plane).
        dt: s, the control period.
    """

    x: np.ndarray
    xd: np.ndarray
    R: np.ndarray
    quat: np.ndarray
    omega: np.ndarray
    dt: float

    @property
    def steps(self) -> int:
        """K, the control steps of the lap."""
        return len(self.x) - 1

    def velocity(self, k: int, task_dim: int) -> np.ndarray:
        """The task velocity (m,) at sample k: x̄̇, or (x̄̇, ω̄) for a pose task."""
        return np.concatenate((self.xd[k], self.omega[k])) if task_dim == 6 else self.xd[k]


class RowPoses(NamedTuple):
    """Kinematics of N configurations (:meth:`RowKinematics.evaluate`)."""

    p: np.ndarray  # (N, 3) m, site position
    R: np.ndarray  # (N, 9) site rotation, row-major (MuJoCo's xmat)
    jacp: np.ndarray  # (N, 3, n) positional Jacobian
    jacr: np.ndarray  # (N, 3, n) rotational Jacobian
    geom_xpos: np.ndarray  # (N, c, 3) m, centres of the c link capsules
    geom_xmat: np.ndarray  # (N, c, 9) their rotations


class RowKinematics:
    """Forward kinematics of many configurations at once.

    One ``mujoco.batch.Batch`` on a copy of the model (contacts and constraints off: only the
    kinematics are read; not persistent: no MjData per row) runs, in C, MuJoCo's position
    stage on every row and then ``mj_jac`` at the site's position: the values of
    ``Robot.site_pose`` and ``Robot.jacobian`` row by row (tested), without a Python round
    trip per configuration. Grows to the rows asked.

    Args:
        model: the robot's model (its kinematic tree is copied once).
        robot: the robot (joint addresses).
        site: the task site's id.
        geom_ids: the capsule geoms whose poses :meth:`evaluate` also returns.
    """

    def __init__(
        self, model: mujoco.MjModel, robot: Robot, site: int, geom_ids: np.ndarray
    ) -> None:
        self.model = copy.copy(model)
        self.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(
            mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
        )
        self.site = site
        self.body = int(model.site_bodyid[site])
        self.geom_ids = geom_ids
        self.qpos_adr = robot.qpos_adr
        self.dof_adr = robot.dof_adr
        self.rows = 0
        self._batch: mujoco.batch.Batch | None = None

    def _grow(self, rows: int) -> None:
        self._batch = mujoco.batch.Batch(self.model, rows, nthread=1, persistent=False)
        self.rows = rows
        self._qpos = self._batch.bind("qpos")
        self._site_xpos = self._batch.bind("site_xpos")
        self._site_xmat = self._batch.bind("site_xmat")
        self._geom_xpos = self._batch.bind("geom_xpos")
        self._geom_xmat = self._batch.bind("geom_xmat")

    def evaluate(self, q: np.ndarray) -> RowPoses:
        """Kinematics of the rows of ``q`` (N, n), all new arrays."""
        N = len(q)
        if N > self.rows:
            self._grow(N)
        assert self._batch is not None
        ids = np.arange(N)
        self._qpos[:N, self.qpos_adr] = q
        self._batch.forward(ids, stage=int(mujoco.mjtStage.mjSTAGE_POS))
        p = self._site_xpos[:N, self.site].copy()
        jacp, jacr = self._batch.jac(self.body, p, ids)
        return RowPoses(
            p,
            self._site_xmat[:N, self.site].copy(),
            jacp[:, :, self.dof_adr],
            jacr[:, :, self.dof_adr],
            self._geom_xpos[:N, self.geom_ids],
            self._geom_xmat[:N, self.geom_ids],
        )


class TaskKinematics:
    """The kinematics of a task at one site of a robot: pose, task Jacobian, IK, many rows.

    Args:
        robot: the robot (its ``data`` holds the kinematics of the last q asked).
        site: the task site's name.
        pos_dim: p, position coordinates of the task (2: x, y of the plane z = 0; 3).
        task_dim: m, 2 (position on the plane) or 6 (position and orientation).
    """

    def __init__(self, robot: Robot, site: str, pos_dim: int, task_dim: int) -> None:
        self.robot = robot
        self.site_id = robot.site_id(site)
        self.pos_dim = pos_dim
        self.task_dim = task_dim
        self.capsules = LinkCapsules(robot.model)
        self._rows: RowKinematics | None = None

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The site position (p,) m and rotation (3, 3) at q (the robot's data then holds q)."""
        p, R = self.robot.site_pose(self.site_id, q)
        return p[: self.pos_dim], R

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """The task Jacobian (m, n): the first two rows of J_P on the plane, [J_P; J_O] else."""
        J = self.robot.jacobian(self.site_id, q)
        return J[:2] if self.task_dim == 2 else J

    def solve_ik(
        self, q: np.ndarray, x: np.ndarray, R: np.ndarray, iterations: int = 200
    ) -> np.ndarray:
        """Newton steps q ← q + J†(x − k(q)) (each capped at ``IK_STEP`` rad) to the pose (x, R)
        (orientation for a pose task only), until the residual is below ``IK_TOLERANCE``."""
        for _ in range(iterations):
            p, Rq = self.pose(q)
            e = x - p
            if self.task_dim == 6:
                e = np.concatenate((e, orientation_error(R, Rq)))
            if np.linalg.norm(e) < IK_TOLERANCE:
                break
            dq = np.linalg.lstsq(self.jacobian(q), e, rcond=None)[0]
            largest = float(np.max(np.abs(dq)))
            if largest > IK_STEP:
                dq *= IK_STEP / largest
            q = q + dq
        return q

    def rows(self, q: np.ndarray) -> RowPoses:
        """:meth:`RowKinematics.evaluate` of the rows of ``q`` (N, n) (made at first use)."""
        if self._rows is None:
            self._rows = RowKinematics(
                self.robot.model, self.robot, self.site_id, self.capsules.geom_ids
            )
        return self._rows.evaluate(q)

    def row_errors(self, rows: RowPoses, ref: Reference, k: int) -> np.ndarray:
        """Task errors (N, m) of the rows against sample k of the reference: x̄ − x, and for a
        pose task the rotation vector of R̄ Rᵀ."""
        e = ref.x[k] - rows.p[:, : self.pos_dim]
        if self.task_dim == 6:
            e = np.concatenate((e, orientation_errors(ref.R[k], rows.R)), axis=1)
        return e

    def row_jacobians(self, rows: RowPoses) -> np.ndarray:
        """Task Jacobians (N, m, n) of the rows."""
        if self.task_dim == 6:
            return np.concatenate((rows.jacp, rows.jacr), axis=1)
        return rows.jacp[:, :2]

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_rows"] = None  # a mujoco.batch.Batch: made again at first use
        return state


def min_norm_samples(
    kin: TaskKinematics, ref: Reference, q0: np.ndarray, stride: int
) -> Iterator[tuple[np.ndarray, np.ndarray, RowPoses, np.ndarray | None]]:
    """Minimum-norm CLIK along the reference from each row of ``q0`` (N, n), every ``stride``
    control steps: q ← q + J†(v̄ Δt + e) with Δt = ``stride`` control periods.

    Yields (q (N, n), e (N, m) the task errors there, the rows' kinematics, J (N, m, n)) at
    each sample k = 0, ``stride``, ... < K, then at the end of the lap (k = K) the same with
    J None. All rows at once, each row as it would be alone.
    """
    q = np.array(q0, dtype=float)
    dt = ref.dt * stride
    for k in range(0, ref.steps, stride):
        rows = kin.rows(q)
        e = kin.row_errors(rows, ref, k)
        J = kin.row_jacobians(rows)
        yield q, e, rows, J
        v = ref.velocity(k, kin.task_dim) + e / dt  # (N, m)
        q = q + dt * (np.linalg.pinv(J) @ v[:, :, None])[:, :, 0]
    rows = kin.rows(q)
    yield q, kin.row_errors(rows, ref, ref.steps), rows, None


def min_norm_motion(
    kin: TaskKinematics, ref: Reference, q0: np.ndarray, stride: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`min_norm_samples` run to the end: the joint paths (S + 1, N, n) and the
    manipulability sqrt(det J Jᵀ) at each of their first S samples (S, N). The joint limits
    are not enforced."""
    paths, w = [], []
    for q, _, _, J in min_norm_samples(kin, ref, q0, stride):
        paths.append(q)
        if J is not None:
            w.append(np.sqrt(np.maximum(np.linalg.det(J @ J.transpose(0, 2, 1)), 0.0)))
    return np.array(paths), np.array(w)


def self_motion_postures(
    kin: TaskKinematics,
    q: np.ndarray,
    ref: Reference,
    lower: np.ndarray,
    upper: np.ndarray,
    arc: float = np.pi,
    step: float = 0.05,
    margin: float = 0.6,
) -> list[np.ndarray]:
    """Configurations on the self-motion through ``q`` at the reference's first pose.

    Walks both ways along the unit null vector of J (dim ker J = 1, its sign kept continuous),
    re-solving the task after each ``step`` (rad), up to ``arc`` rad or until a joint comes
    within ``margin`` rad of its limit (or, when ``q`` itself is closer, within q's own
    margin: the iiwa's elbow q4 does not move along the self-motion); returns ``q`` and every
    5th point.
    """
    margin = min(margin, joint_limit_margin(q, lower, upper) - 1e-9)
    points = walk_self_motion(
        q,
        kin.jacobian,
        lambda x: kin.solve_ik(x, ref.x[0], ref.R[0], iterations=20),
        lambda _, x: joint_limit_margin(x, lower, upper) < margin,
        arc,
        step,
    )
    return [q.copy()] + [x for s, x in points if round(abs(s) / step) % 5 == 0]


class SelfMotionLap:
    """Configurations of the self-motion through q(0), each carried along the reference,
    computed sample by sample only as far as asked (:meth:`extend`).

    Nodes are taken along the self-motion (:func:`cir_gym.redundancy.walk_self_motion`, spaced
    0.9 of what the slowest joint moves in ``stride`` control periods, up to π rad each way
    and inside the joint limits), and each is moved along the reference by minimum-norm CLIK
    (:func:`min_norm_samples`). A configuration is usable inside the joint limits and on the
    task (position error below ``LAP_TASK_TOLERANCE`` m, orientation error below ten times
    that in rad). An obstacle's search (:func:`clearing_motion`) stops at the first sample it
    cannot reach, so a lap whose obstacles all fail early is never computed to its end.

    The arrays below are computed sample by sample: rows ``[:filled]`` hold values.

    Args:
        kin: the task's kinematics.
        ref: the reference.
        q0: (n,) rad, the start, on the task at the reference's first pose.
        lower: (n,) rad, the lower joint limits.
        upper: (n,) rad, the upper joint limits.
        velocity_limit: (n,) rad/s.
        stride: control steps between samples.

    Attributes:
        q: (K, N, n) rad, N nodes ordered along the self-motion at x̄(0), sampled every
            ``stride`` control steps (K samples).
        a: (K, N, c, 3) m, first end points of the c link capsules at each configuration.
        b: (K, N, c, 3) m, their other end points.
        usable: (K, N) inside the joint limits and on the task.
        steps: (K, 2 ``LAP_WINDOW`` + 1, N) the moves into each sample within ``bound``
            (:func:`cir_gym.redundancy.lap_moves`), shared by every obstacle tried.
        start: the node that is q(0).
        bound: (n,) rad, the most each joint moves between samples at its velocity limit.
    """

    def __init__(
        self,
        kin: TaskKinematics,
        ref: Reference,
        q0: np.ndarray,
        lower: np.ndarray,
        upper: np.ndarray,
        velocity_limit: np.ndarray,
        stride: int = LAP_STRIDE,
    ) -> None:
        self.kin, self.ref, self.stride = kin, ref, stride
        self.lower, self.upper = lower, upper
        self._q0 = q0.copy()
        self.bound = velocity_limit * ref.dt * stride
        self.K = len(range(0, ref.steps, stride)) + 1
        self.filled = 0
        self._samples: Iterator[tuple[np.ndarray, ...]] | None = None

    def _walk(self) -> None:
        """The nodes, the arrays, and the CLIK run (nothing along the reference yet)."""
        kin, ref, q0 = self.kin, self.ref, self._q0
        points = walk_self_motion(
            q0,
            kin.jacobian,
            lambda x: kin.solve_ik(x, ref.x[0], ref.R[0], iterations=20),
            lambda _, x: joint_limit_margin(x, self.lower, self.upper) <= 0.0,
            np.pi,
            0.9 * float(np.min(self.bound)),
        )
        points.append((0.0, q0.copy()))
        points.sort(key=lambda point: point[0])
        self.start = next(i for i, (arc, _) in enumerate(points) if arc == 0.0)
        nodes = np.array([x for _, x in points])
        K, N, c = self.K, len(nodes), len(kin.capsules.radius)
        self.N = N
        self.q = np.empty((K, N, len(q0)))
        self.a, self.b = np.empty((K, N, c, 3)), np.empty((K, N, c, 3))
        self.usable = np.empty((K, N), dtype=bool)
        self.steps = np.zeros((K, 2 * LAP_WINDOW + 1, N), dtype=bool)
        self._samples = min_norm_samples(kin, ref, nodes, self.stride)

    def extend(self, k: int) -> None:
        """Compute the samples up to k (included)."""
        if self._samples is None:
            self._walk()
        assert self._samples is not None
        pos = self.kin.pos_dim
        while self.filled <= k:
            q, e, rows, _ = next(self._samples)
            s = self.filled
            self.q[s] = q
            self.a[s], self.b[s] = self.kin.capsules.ends(rows.geom_xpos, rows.geom_xmat)
            on_task = np.linalg.norm(e[:, :pos], axis=1) < LAP_TASK_TOLERANCE
            if self.kin.task_dim == 6:
                on_task &= np.linalg.norm(e[:, 3:], axis=1) < 10.0 * LAP_TASK_TOLERANCE
            inside = np.all((q > self.lower) & (q < self.upper), axis=1)
            self.usable[s] = inside & on_task
            if s:
                self.steps[s] = lap_moves(self.q[s - 1], q, self.bound)
            self.filled += 1


def clearing_motion(
    lap: SelfMotionLap, centre: np.ndarray, radius: float, clearance: float = LAP_CLEARANCE
) -> np.ndarray | None:
    """A joint path (K, n) through ``lap`` that clears the obstacle sphere (``centre`` (3,),
    ``radius``, m) by ``clearance`` m at every sample, within the joint and velocity limits;
    None when the lap has none. The lap is computed only as far as the search gets."""
    lap.extend(0)
    capsules = lap.kin.capsules
    free = np.empty((lap.K, lap.N), dtype=bool)  # usable and clear, rows [:known]
    known = 0

    def usable(k: int) -> np.ndarray:
        nonlocal known
        if k >= known:  # a few samples ahead, their clearances at once
            lap.extend(min(k + LAP_CHUNK - 1, lap.K - 1))
            new = slice(known, lap.filled)
            clear = capsules.segment_clearance(lap.a[new], lap.b[new], centre, radius)
            free[new] = lap.usable[new] & (clear > clearance)
            known = lap.filled
        return free[k]

    def moves(k: int) -> np.ndarray:
        lap.extend(min(k + LAP_CHUNK - 1, lap.K - 1))
        return lap.steps[k]

    path = witness_path(lap.K, lap.N, lap.start, usable, moves)
    return None if path is None else lap.q[np.arange(len(path)), path]
