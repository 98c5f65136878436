"""RedundantIK: closed-loop inverse kinematics and the use of redundancy (chapter 1).

Two kinematic environments: the action is a joint-velocity command integrated exactly over the
control period (q ← q + Δt q̇, then forward kinematics), with no dynamics. A redundant arm
(n > m) tracks a closed task-space path; a secondary objective (manipulability, distance from
joint limits, obstacle clearance) is scored and can be optimised in the null space of J.

The task alone lives here; the redundancy science it scores with (manipulability, joint-limit
objective and margin, the self-motion, the SO(3) orientation error, the capsule–obstacle
clearance, the lap-witness search) is :mod:`cir_gym.redundancy`, shared with the controllers.
"""

from __future__ import annotations

import copy
import math
import operator
from collections.abc import Iterator
from typing import Any, ClassVar

import mujoco
import mujoco.batch
import numpy as np
from gymnasium import spaces

from cir_gym import trajectories as traj
from cir_gym.context import TaskContext
from cir_gym.envs.base import RobotEnv
from cir_gym.metrics import MetricSpec
from cir_gym.numeric import CLIP
from cir_gym.operational_space import align_quat, quat_dot
from cir_gym.redundancy import (
    LAP_WINDOW,
    OBJECTIVES,
    LinkCapsules,
    joint_limit_margin,
    joint_limit_objective,
    lap_moves,
    manipulability,
    null_vector,
    orientation_error,
    orientation_errors,
    walk_self_motion,
    witness_path,
)
from cir_gym.robot import Robot, robot_path
from cir_gym.validation import InvalidArgument, check_number

__all__ = [
    "REDUNDANT_IK_ENVIRONMENTS",
    "SHAPES",
    "RedundantIK7Env",
    "RedundantIKEnv",
]

SHAPES = ("circle", "ellipse", "figure_eight")
DUMMY_OBSTACLE_CENTRE = 10.0  # m, every coordinate of the far-away dummy obstacle (radius 0)
IK_TOLERANCE = 1e-12  # m (and rad): residual of the reset IK solve
SELF_MOTION_SHARE = 0.1  # min |v_j| (unit null vector) of a joint narrowed for "joint_limits"
OBSTACLE_PATH_TRIES = 20  # paths drawn for "obstacle" until an obstacle can be placed
MANIPULABILITY_WINDOW = 0.1  # fraction of the lap excluded from min_manipulability (start-up)
START_MARGIN = 0.3  # rad: "manipulability" start candidates keep this far from the limits
CONTROL_TIMESTEP = 1e-4  # s, model timestep: only the unit of the control period (no dynamics)
LAP_STRIDE = 5  # control steps between the samples of the self-motion lap (obstacle placement)
LAP_CLEARANCE = 0.005  # m, clearance the witness motion keeps at every sample
LAP_TASK_TOLERANCE = 1e-3  # m, task error above which a transported configuration is unusable
LAP_CHUNK = 4  # samples of the lap computed at a time as an obstacle's search advances


def _all_numbers(action: Any) -> bool:
    """True for a (nested) list of real numbers."""
    flat = np.asarray(action, dtype=object).ravel()
    return all(
        isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
        for v in flat
    )


def _norms_below(d: np.ndarray, tolerance: float) -> np.ndarray:
    """‖d_i‖ < tolerance for each row of d (N, m), decided as ``np.linalg.norm(d_i)`` would:
    rows whose squared norm is within 1e-9 (relative) of tolerance² are recomputed with it
    (its BLAS dot may round differently from the vectorised sum, never by that much)."""
    square = np.einsum("ij,ij->i", d, d)
    below = np.sqrt(square) < tolerance
    for i in np.flatnonzero(np.abs(square - tolerance**2) <= 1e-9 * tolerance**2):
        below[i] = np.linalg.norm(d[i]) < tolerance
    return below


class SelfMotionLap:
    """Configurations of the self-motion through q(0), each carried along the reference,
    computed sample by sample only as far as asked (:meth:`extend`).

    Nodes are taken along the self-motion (:func:`walk_self_motion`, spaced 0.9 of what the
    slowest joint moves in ``LAP_STRIDE`` control periods, up to π rad each way and inside the
    joint limits) and each is moved along the reference by minimum-norm CLIK
    (:meth:`_RedundantIKBase._min_norm_samples`). A configuration is usable inside the limits
    and on the task (error < ``LAP_TASK_TOLERANCE``; orientation ten times that in rad). An
    obstacle's search (:meth:`_RedundantIKBase._clearing_motion`) stops at the first sample it
    cannot reach, so a lap whose obstacles all fail early is never computed to its end, and
    a path whose obstacles fail the cheap tests never walks its self-motion.

    Attributes (rows ``[:filled]`` computed):
        q: (K, N, n) rad, N nodes ordered along the self-motion at x̄(0), sampled every
            ``LAP_STRIDE`` control steps (K samples).
        a, b: (K, N, c, 3) m, end points of the c link capsules at each configuration.
        usable: (K, N) inside the joint limits and on the task.
        steps: (K, 2 LAP_WINDOW + 1, N) the moves into each sample within ``bound``
            (:func:`cir_gym.redundancy.lap_moves`), shared by every obstacle tried.
        start: the node that is q(0); bound: (n,) rad, the most each joint moves between
            samples at its velocity limit.
    """

    def __init__(self, env: _RedundantIKBase, q0: np.ndarray) -> None:
        self._env = env
        self._q0 = q0.copy()
        self.bound = env.velocity_limit * env.dt * LAP_STRIDE
        self.K = len(range(0, env.max_steps, LAP_STRIDE)) + 1
        self.filled = 0
        self._samples: Iterator[tuple[np.ndarray, ...]] | None = None

    def _walk(self) -> None:
        """The nodes, the arrays, and the CLIK run (nothing along the reference yet)."""
        env, q0 = self._env, self._q0
        points = walk_self_motion(
            q0,
            env._task_jacobian,
            lambda x: env._solve_ik(x, env._x_ref[0], env._R_ref[0], iterations=20),
            lambda _, x: joint_limit_margin(x, env.file_lower, env.file_upper) <= 0.0,
            np.pi,
            0.9 * float(np.min(self.bound)),
        )
        points.append((0.0, q0.copy()))
        points.sort(key=lambda point: point[0])
        self.start = next(i for i, (arc, _) in enumerate(points) if arc == 0.0)
        nodes = np.array([x for _, x in points])
        K, N, c = self.K, len(nodes), len(env.capsules.radius)
        self.N = N
        self.q = np.empty((K, N, env.n))
        self.a, self.b = np.empty((K, N, c, 3)), np.empty((K, N, c, 3))
        self.usable = np.empty((K, N), dtype=bool)
        self.steps = np.zeros((K, 2 * LAP_WINDOW + 1, N), dtype=bool)
        self._samples = env._min_norm_samples(nodes, LAP_STRIDE, final_kinematics=True)

    def extend(self, k: int) -> None:
        """Compute the samples up to k (included)."""
        if self._samples is None:
            self._walk()
        env, pos = self._env, self._env.pos_dim
        while self.filled <= k:
            assert self._samples is not None
            q, e, kinematics, _ = next(self._samples)
            s = self.filled
            self.q[s] = q
            self.a[s], self.b[s] = env.capsules.ends(kinematics[4], kinematics[5])
            on_task = _norms_below(e[:, :pos], LAP_TASK_TOLERANCE)
            if env.task_dim == 6:
                on_task &= _norms_below(e[:, 3:], 10.0 * LAP_TASK_TOLERANCE)
            inside = np.all((q > env.file_lower) & (q < env.file_upper), axis=1)
            self.usable[s] = inside & on_task
            if s:
                self.steps[s] = lap_moves(self.q[s - 1], q, self.bound)
            self.filled += 1


class RowKinematics:
    """Forward kinematics of many configurations at once, for an episode's set-up.

    One ``mujoco.batch.Batch`` on a copy of the model (contacts and constraints off: only the
    kinematics are read; not persistent: no MjData per row, ~5 MB instead of ~20) runs, in C,
    MuJoCo's position stage on every row and then ``mj_jac`` at the site's position: the
    values of ``Robot.site_pose`` and ``Robot.jacobian`` (``mj_kinematics``, ``mj_comPos``,
    ``mj_jacSite``) row by row, bit for bit (tested), without a Python round trip per
    configuration. Grows to the rows asked.

    Args:
        model: the environment's model (its kinematic tree is copied once).
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

    def evaluate(
        self, q: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Kinematics of the rows of ``q`` (N, n): site position (N, 3), rotation (N, 9),
        positional and rotational Jacobians (N, 3, n) each, capsule centres (N, c, 3) and
        rotations (N, c, 9), all new arrays."""
        N = len(q)
        if N > self.rows:
            self._grow(N)
        assert self._batch is not None
        ids = np.arange(N)
        self._qpos[:N, self.qpos_adr] = q
        self._batch.forward(ids, stage=int(mujoco.mjtStage.mjSTAGE_POS))
        p = self._site_xpos[:N, self.site]  # a view, copied below
        jacp, jacr = self._batch.jac(self.body, p, ids)
        return (
            p.copy(),
            self._site_xmat[:N, self.site].copy(),
            np.ascontiguousarray(jacp[:, :, self.dof_adr]),
            np.ascontiguousarray(jacr[:, :, self.dof_adr]),
            self._geom_xpos[:N, self.geom_ids],
            self._geom_xmat[:N, self.geom_ids],
        )


# ---------------------------------------------------------------------- environment base
class _RedundantIKBase(RobotEnv):
    """Shared kinematic plumbing of :class:`RedundantIKEnv` and :class:`RedundantIK7Env`.

    Subclasses set ``robot_name``, ``site``, ``pos_dim`` (2 or 3), ``task_dim`` (2 or 6) and
    implement ``_draw_path`` (the reference) and ``_obstacle_box`` (the drawn obstacle).
    """

    robot_name: ClassVar[str] = ""
    site: ClassVar[str] = ""
    pos_dim: ClassVar[int] = 2
    task_dim: ClassVar[int] = 2
    obstacle_type: ClassVar[int] = int(mujoco.mjtGeom.mjGEOM_SPHERE)
    manipulability_scale: ClassVar[float] = 0.1  # scale of the manipulability cost (task units)
    obstacle_links: ClassVar[tuple[str, ...]] = ()  # bodies whose capsules the obstacle targets
    #: arguments that set what the task asks, not a condition it is asked under: an agent
    #: trained for one objective is not scored on another's variant (agents.trained_for)
    agent_task_keys: ClassVar[tuple[str, ...]] = ("objective",)
    #: reset(options={"replay": True}) starts the last drawn task again (TaskReplay)
    replayable_tasks: ClassVar[bool] = True
    reward_arguments: ClassVar[frozenset[str]] = frozenset((
        "error_scales", "secondary_weight", "velocity_weight", "termination_penalty",
    ))
    leaderboard_variants: ClassVar[dict[str, dict[str, Any]]] = {
        "manipulability": {"objective": "manipulability"},
        "obstacle": {"objective": "obstacle"},
        "joint limits": {"objective": "joint_limits"},
    }
    primary_metric: ClassVar[str] = "rms_task_error"
    #: what each variant is ranked on after the success rate: its own objective's metric
    leaderboard_primary_metrics: ClassVar[dict[str, str]] = {
        "manipulability": "min_manipulability",
        "obstacle": "min_clearance",
        "joint limits": "min_joint_limit_margin",
    }

    def _setup(
        self,
        *,
        objective: str,
        control_freq: float,
        episode_duration: float,
        initial_error: float,
        joint_window: float,
        error_scales: tuple[float, ...],
        secondary_weight: float,
        velocity_weight: float,
        termination_penalty: float,
        success_threshold: float,
        render_mode: str | None,
        width: int,
        height: int,
    ) -> None:
        if objective not in OBJECTIVES:
            raise InvalidArgument(f"objective must be one of {OBJECTIVES}, got {objective!r}")
        self.objective = objective
        self.initial_error = check_number("initial_error", initial_error, 0.0, 0.1)
        self.joint_window = check_number(
            "joint_window", joint_window, 0.0, 2 * np.pi, low_open=True
        )
        try:
            scales = np.atleast_1d(np.asarray(error_scales, dtype=float))
        except (TypeError, ValueError) as exc:
            raise InvalidArgument(
                f"error_scales must be positive numbers (m), got {error_scales!r}"
            ) from exc
        if scales.ndim != 1 or scales.size == 0 or not np.all((scales >= 1e-9) & (scales <= 1e3)):
            raise InvalidArgument(
                f"error_scales must be numbers in [1e-9, 1e3] m, got {error_scales!r}"
            )
        self.error_scales = scales
        self.orientation_scales = scales * 10.0  # rad: 1 mm ↔ 0.01 rad
        self._error_scales_sq = self.error_scales**2  # the rewards' kernel widths², per step
        self._orientation_scales_sq = self.orientation_scales**2
        self._quats = tuple(np.empty(4) for _ in range(4))  # step's orientation_errors scratch
        self._phi = np.empty((1, 3))  # and its output
        self.secondary_weight = check_number("secondary_weight", secondary_weight, 0.0, 10.0)
        self.velocity_weight = check_number("velocity_weight", velocity_weight, 0.0, 10.0)
        self.termination_penalty = check_number(
            "termination_penalty", termination_penalty, 0.0, 1e6
        )
        self.success_threshold = check_number(
            "success_threshold", success_threshold, 0.0, 1.0, low_open=True
        )

        model = self._build_model()
        self.robot = Robot(model)
        super().__init__(
            model,
            control_freq=control_freq,
            episode_duration=episode_duration,
            render_mode=render_mode,
            width=width,
            height=height,
            camera=self._camera_name(),
        )
        self.data = self.robot.data  # kinematics only: the robot's MjData is the scene's
        self.n = n = self.robot.n
        self.file_lower, self.file_upper = self.robot.lower.copy(), self.robot.upper.copy()
        self.lower, self.upper = self.file_lower.copy(), self.file_upper.copy()
        self.velocity_limit = self.robot.velocity_limit.copy()
        self._site_id = self.robot.site_id(self.site)
        self._obstacle_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "obstacle")
        self.capsules = LinkCapsules(model)
        self.home = model.key("home").qpos[self.robot.qpos_adr].copy()
        # quaternions are observed on the hemisphere ⟨Q, Q_home⟩ ≥ 0 of the home orientation
        self._quat_home = traj.quat_from_matrix(self._forward(self.home)[1])
        self._quat_home_floats = self._quat_home.tolist()

        self.action_space = spaces.Box(-1.0, 1.0, (n,), dtype=np.float32)
        p = self.pos_dim
        bounds: dict[str, tuple[float, int]] = {
            "q": (2 * np.pi, n),
            "x": (3.0, p),
            "x_ref": (3.0, p),
            "xd_ref": (10.0, p),
        }
        if self.task_dim == 6:
            bounds |= {"quat": (1.0, 4), "quat_ref": (1.0, 4), "omega_ref": (20.0, 3)}
        bounds |= {
            "q_lower": (2 * np.pi, n),
            "q_upper": (2 * np.pi, n),
            "obstacle": (2 * DUMMY_OBSTACLE_CENTRE, p + 1),
        }
        self._obs_bounds = {k: b for k, (b, _) in bounds.items()}
        self.observation_space = spaces.Dict(
            {k: spaces.Box(-b, b, (size,), dtype=np.float64) for k, (b, size) in bounds.items()}
        )
        # the observation is built in one flat buffer per step (views handed out, one clip)
        ends = np.cumsum([size for _, size in bounds.values()])
        self._obs_slices = {
            key: slice(int(end - size), int(end))
            for (key, (_, size)), end in zip(bounds.items(), ends, strict=True)
        }
        self._obs_high = np.concatenate([np.full(size, b) for b, size in bounds.values()])
        self._obs_low = -self._obs_high

        steps = self.max_steps
        self._x_ref = np.zeros((steps + 1, p))
        self._xd_ref = np.zeros((steps + 1, p))
        self._R_ref = np.tile(np.eye(3), (steps + 1, 1, 1))
        self._quat_ref = np.zeros((steps + 1, 4))
        self._omega_ref = np.zeros((steps + 1, 3))
        self._trace = np.zeros((6, steps))  # task err, orient. err, manip., margin, clearance
        self._obstacle = np.zeros(p + 1)
        self._q = self.home.copy()
        self._q0 = self.home.copy()
        self._witness: np.ndarray | None = None
        self._task: tuple | None = None  # the last drawn task, for reset(options={"replay": True})
        self._rows: RowKinematics | None = None
        self._k = 0
        self._k_scored = 0
        self._done = False

    # ------------------------------------------------------------------ model
    def _build_model(self) -> mujoco.MjModel:
        """The robot file plus an obstacle geom (moved per episode) and, for the plane, a camera."""
        spec = mujoco.MjSpec.from_file(str(robot_path(self.robot_name)))
        spec.option.timestep = CONTROL_TIMESTEP
        # compiled at the base (so the free camera frames the robot); moved at every reset
        spec.worldbody.add_geom(
            name="obstacle",
            type=mujoco.mjtGeom(self.obstacle_type),
            size=[0.05, 0.05, 0.0],
            pos=[0.0, 0.0, 0.0],
            contype=0,
            conaffinity=0,
            rgba=[0.9, 0.1, 0.1, 0.8],
        )
        self._add_camera(spec)
        return spec.compile()

    def _add_camera(self, spec: mujoco.MjSpec) -> None:
        """Hook: add a camera to the scene (none by default: MuJoCo's free camera)."""

    def _camera_name(self) -> str | int:
        return -1

    # ------------------------------------------------------------------ kinematics
    def _forward(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Set q; return the site position (pos_dim,) and rotation (3, 3)."""
        p, R = self.robot.site_pose(self._site_id, q)
        return p[: self.pos_dim], R

    def _task_jacobian(self, q: np.ndarray) -> np.ndarray:
        J = self.robot.jacobian(self._site_id, q)
        return J[:2] if self.task_dim == 2 else J

    def _solve_ik(
        self, q: np.ndarray, x: np.ndarray, R: np.ndarray, iterations: int = 200
    ) -> np.ndarray:
        """Newton steps q ← q + J†(x − k(q)) (capped at 0.2 rad) to the pose (x, R)."""
        for _ in range(iterations):
            p, Rq = self._forward(q)
            e = x - p
            if self.task_dim == 6:
                e = np.concatenate((e, orientation_error(R, Rq)))
            if float(e @ e) < IK_TOLERANCE**2:
                break
            dq = np.linalg.lstsq(self._task_jacobian(q), e, rcond=None)[0]
            step = float(np.max(np.abs(dq)))
            q = q + (dq * (0.2 / step) if step > 0.2 else dq)
        return q

    def _row_kinematics(self) -> RowKinematics:
        """The batched kinematics of the episode set-up (made at first use, not pickled)."""
        if self._rows is None:
            self._rows = RowKinematics(
                self.model, self.robot, self._site_id, self.capsules.geom_ids
            )
        return self._rows

    def _row_kinematics_one(self, q: np.ndarray) -> tuple[np.ndarray, ...]:
        """:meth:`RowKinematics.evaluate` of one row, through the env's own Robot: the same
        values (tested), without a batch call's cost (q(0)'s own motion, in ``reset``)."""
        p, R = self.robot.site_pose(self._site_id, q)
        J = self.robot.jacobian(self._site_id, q)
        ids = self.capsules.geom_ids
        return (
            p[None],
            R.reshape(1, 9),
            J[None, :3],
            J[None, 3:],
            self.data.geom_xpos[ids][None],
            self.data.geom_xmat[ids][None],
        )

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state["_rows"] = None  # a mujoco.batch.Batch: made again at first use
        return state

    def _min_norm_samples(
        self, q0: np.ndarray, stride: int, final_kinematics: bool = False
    ) -> Iterator[tuple[np.ndarray, ...]]:
        """Minimum-norm CLIK along the reference from each row of ``q0`` (N, n), every
        ``stride`` steps: q ← q + J†(x̄̇ Δt + e) with Δt = ``stride`` control periods.

        Yields, at each sample k = 0, ``stride``, ... < ``max_steps``, (q (N, n), e (N,
        task_dim) the task errors against the reference there, the rows'
        :meth:`RowKinematics.evaluate`, J (N, task_dim, n)), then at the end of the lap
        (``max_steps``) the last q with, when ``final_kinematics``, its errors and kinematics
        (else None) and J None. e is one array overwritten at every sample. All rows at once,
        each row as it would be alone.
        """
        q = np.array(q0, dtype=float)
        dt = self.dt * stride
        pos = self.pos_dim
        e = np.empty((len(q), self.task_dim))
        rows = self._row_kinematics()

        def errors(k: int) -> tuple[np.ndarray, ...]:
            kinematics = rows.evaluate(q) if len(q) > 1 else self._row_kinematics_one(q[0])
            e[:, :pos] = self._x_ref[k] - kinematics[0][:, :pos]
            if self.task_dim == 6:
                orientation_errors(self._R_ref[k], kinematics[1], e[:, 3:])
            return kinematics

        for k in range(0, self.max_steps, stride):
            kinematics = errors(k)
            if self.task_dim == 6:
                J = np.concatenate(kinematics[2:4], axis=1)
                v = np.concatenate((self._xd_ref[k], self._omega_ref[k]))
            else:
                J = np.ascontiguousarray(kinematics[2][:, :2])
                v = self._xd_ref[k]
            yield q, e, kinematics, J
            q = q + dt * np.einsum("nij,nj->ni", np.linalg.pinv(J), v + e / dt)
        if final_kinematics:
            yield q, e, errors(self.max_steps), None
        else:
            yield q, None, None, None

    def _min_norm_motion(
        self, q0: np.ndarray, stride: int = 5
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_min_norm_samples` run to the end: the joint paths (k + 1, N, n) and the
        manipulability at each of their first k points (k, N).

        Used only to set up an episode (where the obstacle goes and which motions avoid it,
        which posture starts "manipulability"); the joint limits are not enforced.
        """
        paths, w = [], []
        for q, _, _, J in self._min_norm_samples(q0, stride):
            paths.append(q.copy())
            if J is not None:
                w.append(np.sqrt(np.maximum(np.linalg.det(J @ J.transpose(0, 2, 1)), 0.0)))
        return np.array(paths), np.array(w)

    def _clearing_motion(
        self, lap: SelfMotionLap, centre: np.ndarray, radius: float
    ) -> np.ndarray | None:
        """A joint path (K, n) through ``lap`` that clears the obstacle by ``LAP_CLEARANCE``
        at every sample, within the joint and velocity limits; None when the lap has none.
        The lap is computed only as far as the search gets."""

        lap.extend(0)
        free = np.empty((lap.K, lap.N), dtype=bool)  # usable and clear, rows [:known]
        known = 0

        def usable(k: int) -> np.ndarray:
            nonlocal known
            if k >= known:  # a few samples ahead, their clearances at once
                lap.extend(min(k + LAP_CHUNK - 1, lap.K - 1))
                new = slice(known, lap.filled)
                clear = self.capsules.segment_clearance(lap.a[new], lap.b[new], centre, radius)
                free[new] = lap.usable[new] & (clear > LAP_CLEARANCE)
                known = lap.filled
            return free[k]

        def moves(k: int) -> np.ndarray:
            lap.extend(min(k + LAP_CHUNK - 1, lap.K - 1))
            return lap.steps[k]

        path = witness_path(lap.K, lap.N, lap.start, usable, moves)
        return None if path is None else lap.q[np.arange(len(path)), path]

    # ------------------------------------------------------------------ episode setup
    def _draw_path(self) -> None:
        """Fill ``_x_ref``, ``_xd_ref`` (and the orientation reference) for this episode."""
        raise NotImplementedError

    def _draw_obstacle(self, q0: np.ndarray) -> np.ndarray:
        """Centre (3,) and radius of an obstacle on the elbow's minimum-norm sweep.

        A random instant t* ∈ [0.3, 0.8] T of the minimum-norm (pseudo-inverse) motion and a
        random point of one of the ``obstacle_links`` capsules are drawn; the obstacle overlaps
        that capsule by 5–20 mm there, on a random side. Draws that come within
        ``radius + 0.08`` m of the task path, that collide at q(0), or that no motion along the
        self-motion lap clears (:meth:`_clearing_motion`: within the joint and velocity
        limits, ``LAP_CLEARANCE`` at every sample of the whole lap) are rejected (30 tries).
        The clearing motion found is kept (:meth:`clearing_motion`).
        """
        rng = self.np_random
        lap = SelfMotionLap(self, q0)  # computed only as far as an obstacle's search needs
        # the minimum-norm motion from q(0) (the lap's row of q(0), alone), as far as drawn
        samples = self._min_norm_samples(q0[None], LAP_STRIDE)
        motion: list[np.ndarray] = []
        bodies = [
            mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, b) for b in self.obstacle_links
        ]
        pick = [
            i for i, g in enumerate(self.capsules.geom_ids) if self.model.geom_bodyid[g] in bodies
        ]
        path_pts = self._x_ref
        best = np.array([DUMMY_OBSTACLE_CENTRE] * 3 + [0.0])
        for _ in range(30):
            k = int(rng.integers(int(0.3 * lap.K), int(0.8 * lap.K)))
            while len(motion) <= k:
                motion.append(next(samples)[0][0].copy())
            self._forward(motion[k])
            a, b = self.capsules.segments(self.data)
            i = int(rng.choice(pick))
            point = a[i] + rng.uniform(0.3, 1.0) * (b[i] - a[i])
            radius = float(rng.uniform(0.04, 0.07))
            normal = self._random_normal(b[i] - a[i])
            depth = float(rng.uniform(0.005, 0.02))
            centre = point + (self.capsules.radius[i] + radius - depth) * normal
            d_path = np.min(np.linalg.norm(path_pts - centre[: self.pos_dim], axis=1))
            self._forward(q0)
            if d_path > radius + 0.08 and self.capsules.clearance(self.data, centre, radius) > 0.03:
                witness = self._clearing_motion(lap, centre, radius)
                if witness is not None:
                    best = np.concatenate((centre, [radius]))
                    self._witness = witness
                    break
        return best

    def clearing_motion(self) -> np.ndarray | None:
        """objective="obstacle": the joint path (K, n) that showed this episode's obstacle can
        be cleared, one configuration every ``LAP_STRIDE`` control steps from q(0) (on the task,
        inside the joint limits, |Δq_j| ≤ q̇_j,max · ``LAP_STRIDE`` Δt, clearance ≥
        ``LAP_CLEARANCE`` at every sample). It needs the whole reference in advance, so it is a
        certificate of the instance, not a policy. None for the other objectives.
        """
        return None if self._witness is None else self._witness.copy()

    def _random_normal(self, axis: np.ndarray) -> np.ndarray:
        """A random unit vector normal to ``axis`` (in the plane z = 0 for the planar arm)."""
        rng = self.np_random
        if self.pos_dim == 2:
            nrm = np.array([-axis[1], axis[0], 0.0])
            return nrm / np.linalg.norm(nrm) * rng.choice((-1.0, 1.0))
        v = rng.standard_normal(3)
        v -= (v @ axis) / (axis @ axis) * axis
        return v / np.linalg.norm(v)

    def _set_obstacle(self, box: np.ndarray) -> None:
        """Move the obstacle geom and store its observation (centre (pos_dim,), radius)."""
        centre, radius = box[:3], float(box[3])
        self._obstacle_centre = centre.copy()
        self._obstacle_radius = radius
        self.model.geom_pos[self._obstacle_id] = centre
        self.model.geom_size[self._obstacle_id, 0] = max(radius, 1e-3)
        self.model.geom_rgba[self._obstacle_id, 3] = 0.8 if radius > 0 else 0.0
        self._obstacle = np.concatenate((centre[: self.pos_dim], [radius]))

    def _self_motion(
        self, q: np.ndarray, arc: float = np.pi, step: float = 0.05, margin: float = 0.6, k: int = 0
    ) -> list[np.ndarray]:
        """Configurations on the self-motion manifold through ``q`` at the reference pose of
        control step ``k`` (x̄(0) by default).

        Walks both ways along the unit null vector of J (dim ker J = 1 on both robots, its sign
        kept continuous), re-solving the task after each ``step`` (rad), up to ``arc`` rad or
        until a joint comes within ``margin`` rad of its limit (or, when ``q`` itself is
        closer, within q's own margin: the iiwa's elbow q4 does not move along the self-motion);
        returns ``q`` and every 5th point.
        """
        margin = min(margin, joint_limit_margin(q, self.file_lower, self.file_upper) - 1e-9)
        points = walk_self_motion(
            q,
            self._task_jacobian,
            lambda x: self._solve_ik(x, self._x_ref[k], self._R_ref[k], iterations=20),
            lambda _, x: joint_limit_margin(x, self.file_lower, self.file_upper) < margin,
            arc,
            step,
        )
        return [q.copy()] + [x for s, x in points if round(abs(s) / step) % 5 == 0]

    def _poorly_conditioned_start(self, q_home_ik: np.ndarray) -> np.ndarray:
        """objective="manipulability": the posture whose minimum-norm lap is least manipulable.

        Candidates: the home-IK solution and the configurations of its :meth:`_self_motion`
        at x̄(0) (≥ ``START_MARGIN`` rad from every joint limit, or no closer than the home-IK
        solution). From each, the minimum-norm (pseudo-inverse CLIK) motion along the whole
        reference is run (:meth:`_min_norm_motion`); candidates whose motion leaves the joint
        limits are dropped (plain CLIK could not finish the lap, so the comparison would not be
        at equal task error), and of the rest the one whose motion reaches the least
        manipulability over t ≥ 0.1 T is returned: the redundancy starts badly used for the
        whole lap, as the metric measures it. v1 took the least manipulable posture at t = 0:
        on the iiwa that is an interior minimum of w along the self-motion, a stationary point
        no gradient method leaves, and postures that are poor at t = 0 need not be poor later.
        """
        sols = self._self_motion(q_home_ik, margin=START_MARGIN)
        best, start = np.inf, q_home_ik
        motions, ws = self._min_norm_motion(np.array(sols), stride=10)  # all at once, row-wise
        for i, q in enumerate(sols):
            motion, w = motions[:, i], ws[:, i]
            if np.any(motion < self.file_lower) or np.any(motion > self.file_upper):
                continue
            w_lap = float(np.min(w[int(MANIPULABILITY_WINDOW * len(w)) :]))
            if w_lap < best:
                best, start = w_lap, q
        return start

    def _set_joint_window(self, q0: np.ndarray) -> None:
        """objective="joint_limits": one random joint gets a range of width ``joint_window``.

        q(0) sits 10–25 % of the window from a random side of it, so minimum-norm motion runs
        into that limit on many paths, while the self-motion can move the joint towards the
        window's centre. The other joints keep the file's ranges; all are clipped to them.
        Only a joint that the self-motion moves is narrowed (|v_j| ≥ 0.1 for the unit null
        vector v of J at q(0)): on the iiwa the elbow q4 is fixed by the shoulder–wrist
        distance, which the pose task fixes, so no kinematic controller could keep a narrowed
        q4 in range (v0 drew such instances).
        """
        rng = self.np_random
        v = null_vector(self._task_jacobian(q0))
        movable = np.flatnonzero(np.abs(v) >= SELF_MOTION_SHARE)
        j = int(movable[rng.integers(movable.size)])
        frac = float(rng.uniform(0.1, 0.25))
        frac = frac if rng.random() < 0.5 else 1.0 - frac
        self.lower, self.upper = self.file_lower.copy(), self.file_upper.copy()
        self.lower[j] = max(q0[j] - frac * self.joint_window, self.file_lower[j])
        self.upper[j] = min(self.lower[j] + self.joint_window, self.file_upper[j])

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Draw a new task, or with ``options={"replay": True}`` start the last one again.

        A replay restores the previous reset's reference, obstacle, joint window and q(0)
        exactly and draws nothing (no seed allowed): it costs a forward-kinematics call where
        a draw costs up to ~0.2 s ("obstacle" on the iiwa), so a training wrapper can repeat
        tasks cheaply (:class:`agents.shaping.TaskReplay`). The episode then plays as the
        first play of that task did, for the same actions.
        """
        replay = self._replay_option(seed, options)
        if replay:
            super().reset()
            return self._start(*self._task)
        super().reset(seed=seed)
        rng = self.np_random
        self.lower, self.upper = self.file_lower.copy(), self.file_upper.copy()
        self._set_obstacle(np.array([DUMMY_OBSTACLE_CENTRE] * 3 + [0.0]))
        self._witness = None
        for _ in range(OBSTACLE_PATH_TRIES):  # "obstacle": a new path until one is placed
            self._draw_path()
            q0 = self._solve_ik(self.home.copy(), self._x_ref[0], self._R_ref[0])
            if self.objective != "obstacle":
                break
            box = self._draw_obstacle(q0)
            if box[-1] > 0:
                self._set_obstacle(box)
                break
        else:  # only "obstacle" gets here (v3 went on without an obstacle)
            raise InvalidArgument(
                f"objective='obstacle': no clearable obstacle on {OBSTACLE_PATH_TRIES} paths of "
                f"30 draws each with episode_duration={self.max_steps * self.dt:g} s: the links "
                f"must sweep 3 cm past an obstacle that a self-motion can also avoid, which a "
                f"short lap does not allow (the default duration placed one on every seed "
                f"tested, 0-99); use a longer episode_duration"
            )
        if self.objective == "manipulability":
            q0 = self._poorly_conditioned_start(q0)
        if self.initial_error > 0:
            d = rng.standard_normal(self.pos_dim)
            offset = self.initial_error * d / np.linalg.norm(d)
            q0 = self._solve_ik(q0, self._x_ref[0] + offset, self._R_ref[0])
        if self.objective == "joint_limits":
            self._set_joint_window(q0)
        refs = (self._x_ref, self._xd_ref, self._R_ref, self._quat_ref, self._omega_ref)
        self._task = (tuple(r.copy() for r in refs), self._obstacle_box(), self._witness,
                      self.lower.copy(), self.upper.copy(), q0.copy())
        return self._start(*self._task)

    def _replay_option(self, seed: int | None, options: dict | None) -> bool:
        """Validate reset's ``options``: only ``{"replay": bool}``, no seed with a replay."""
        if not options:
            return False
        unknown = set(options) - {"replay"}
        if unknown:
            raise InvalidArgument(f"reset options: unknown {sorted(unknown)}; allowed: 'replay'")
        replay = options.get("replay", False)
        if not isinstance(replay, bool | np.bool_):
            raise InvalidArgument(f"reset option 'replay' must be a bool, got {replay!r}")
        if replay and seed is not None:
            raise InvalidArgument("reset(seed=..., options={'replay': True}): a replay draws "
                                  "nothing, so it takes no seed")
        if replay and self._task is None:
            raise InvalidArgument("reset(options={'replay': True}) before any task was drawn: "
                                  "call reset() first")
        return bool(replay)

    def _obstacle_box(self) -> np.ndarray:
        """The current obstacle as (centre (3,), radius), as :meth:`_set_obstacle` takes it."""
        return np.concatenate((self._obstacle_centre, [self._obstacle_radius]))

    def _start(self, refs: tuple[np.ndarray, ...], box: np.ndarray, witness: np.ndarray | None,
               lower: np.ndarray, upper: np.ndarray, q0: np.ndarray) -> tuple[dict, dict]:
        """Set up the episode of a drawn task (reference, obstacle, limits, q(0))."""
        for dst, src in zip((self._x_ref, self._xd_ref, self._R_ref, self._quat_ref,
                             self._omega_ref), refs, strict=True):
            dst[:] = src
        self._set_obstacle(box)
        self._witness = witness
        self.lower, self.upper = lower.copy(), upper.copy()
        self.model.jnt_range[self.robot.joint_ids, 0] = self.lower
        self.model.jnt_range[self.robot.joint_ids, 1] = self.upper
        self._q = q0.copy()
        self._q0 = q0.copy()
        self._forward(q0)
        self._k = 0
        self._k_scored = 0
        self._done = False
        self._trace[:] = 0.0
        info = {
            "obstacle": self._obstacle.copy(),
            "q_lower": self.lower.copy(),
            "q_upper": self.upper.copy(),
        }
        return self._obs(), info

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        a, _ = self._check_action(action)
        qd = a * self.velocity_limit  # q̇ (rad/s), clipped to the velocity limits
        q = self._q + self.dt * qd  # exact integration of a constant q̇ over Δt
        values = q.tolist()  # the limit test on Python floats: exact, cheaper than 4 numpy calls
        violation = any(map(operator.lt, values, self.lower.tolist())) or any(
            map(operator.gt, values, self.upper.tolist())
        )
        if violation:
            q = np.clip(q, self.lower, self.upper)  # stops at the limit
        self._q = q
        k = min(self._k, self.max_steps - 1)  # past the end: the last reference is held
        self._k = k + 1
        p, R = self._forward(q)
        d = self._x_ref[self._k] - p
        e_pos = math.sqrt(float(d.dot(d)))  # = np.linalg.norm(d): the same BLAS dot
        if self.task_dim == 6:  # orientation_error(R̄, R) in the env's buffers
            phi = orientation_errors(self._R_ref[self._k], R.reshape(1, 9), self._phi,
                                     self._quats)[0]
            e_rot = math.sqrt(float(phi.dot(phi)))
        else:
            e_rot = 0.0
        w = manipulability(self._task_jacobian(q))
        margin = joint_limit_margin(q, self.lower, self.upper)
        clear = self.capsules.clearance(self.data, self._obstacle_centre, self._obstacle_radius)
        collision = clear < 0.0
        self._trace[:, k] = (e_pos, e_rot, w, margin, clear, 0.0)

        kernel = np.exp(-(e_pos**2) / self._error_scales_sq)
        r_track = -(1.0 - float(kernel.sum()) / kernel.size)  # = np.mean, one reduction
        if self.task_dim == 6:
            kernel = np.exp(-(e_rot**2) / self._orientation_scales_sq)
            r_orient = -(1.0 - float(kernel.sum()) / kernel.size)
        else:
            r_orient = 0.0
        r_secondary = -self.secondary_weight * self._secondary_cost(q, w, clear)
        r_velocity = -self.velocity_weight * float(a @ a) / self.n
        terminated = violation or collision
        r_term = -self.termination_penalty if terminated else 0.0
        reward = r_track + r_orient + r_secondary + r_velocity + r_term
        truncated = self._k >= self.max_steps and not terminated
        self._done = terminated or truncated
        info: dict[str, Any] = {
            "reward_tracking": r_track,
            "reward_orientation": r_orient,
            "reward_secondary": r_secondary,
            "reward_velocity": r_velocity,
            "reward_termination": r_term,
            "task_error": e_pos,
            "manipulability": w,
            "joint_limit_margin": margin,
            "clearance": clear,
            "joint_limit_violation": violation,
            "collision": collision,
            "diverged": False,
        }
        if self.task_dim == 6:
            info["orientation_error"] = e_rot
        if terminated:  # scored over the whole lap: the arm stays where it stopped
            self._score_stopped_arm(k, np.array(p), np.array(R))
        if self._done:
            metrics = self.episode_metrics()
            info["episode_metrics"] = metrics
            ok = metrics["max_task_error"] < self.success_threshold
            if self.task_dim == 6:
                ok = ok and metrics["max_orientation_error"] < 10.0 * self.success_threshold
            info["is_success"] = bool(not terminated and ok)
        return self._obs(p, R), reward, terminated, truncated, info

    def _score_stopped_arm(self, k: int, p: np.ndarray, R: np.ndarray) -> None:
        """Fill the trace after control step ``k`` as if the arm stayed at the pose (p, R) where
        the episode terminated: its error against the reference it no longer follows (which
        moves on to the end of the lap); manipulability, joint-limit margin and clearance of
        the stopped arm, unchanged. v3 held the last error instead, so an arm stopped by a
        collision or a joint limit scored its last (small) tracking error for the whole lap.
        """
        later = np.arange(k + 1, self.max_steps)
        self._trace[:, later] = self._trace[:, k : k + 1]
        self._trace[0, later] = np.linalg.norm(self._x_ref[later + 1] - p, axis=1)
        if self.task_dim == 6:
            self._trace[1, later] = [
                np.linalg.norm(orientation_error(self._R_ref[j + 1], R)) for j in later
            ]
        self._k_scored = self.max_steps

    def _check_action(self, action: Any) -> tuple[np.ndarray, bool]:
        """The base class's check, plus: strings or objects are not actions (even "0.1")."""
        if isinstance(action, np.ndarray):  # np.asarray(action) would be action itself
            kind = action.dtype.kind
        else:
            kind = np.asarray(action, dtype=object if isinstance(action, list) else None).dtype.kind
        if kind in "USO" and not (kind == "O" and _all_numbers(action)):
            raise ValueError(
                f"action must be numbers of shape {self.action_space.shape} in "
                f"[-1, 1], got {action!r}"
            )
        return super()._check_action(action)

    def _secondary_cost(self, q: np.ndarray, w: float, clear: float) -> float:
        """Objective cost in [0, 1]: exp(−w/w₀), −8 w_jl(q), or exp(−clearance / 5 cm)."""
        if self.objective == "manipulability":
            return float(np.exp(-w / self.manipulability_scale))
        if self.objective == "joint_limits":
            return -8.0 * joint_limit_objective(q, self.lower, self.upper)
        return float(np.exp(-max(clear, 0.0) / 0.05))

    def episode_metrics(self) -> dict[str, float]:
        """Metrics of the episode so far (see ``metric_specs``)."""
        k = max(self._k, self._k_scored, 1)
        e, r, w, margin, clear = self._trace[:5, :k]
        metrics = {
            "rms_task_error": float(np.sqrt(np.mean(e**2))),
            "max_task_error": float(np.max(e)),
        }
        if self.task_dim == 6:
            metrics["rms_orientation_error"] = float(np.sqrt(np.mean(r**2)))
            metrics["max_orientation_error"] = float(np.max(r))
        metrics |= {
            "min_manipulability": float(
                np.min(
                    w[int(MANIPULABILITY_WINDOW * self.max_steps) :]
                    if k > MANIPULABILITY_WINDOW * self.max_steps
                    else w
                )
            ),
            "min_joint_limit_margin": float(np.min(margin)),
            "min_clearance": float(np.min(clear)),
            "joint_drift": float(np.linalg.norm(self._q - self._q0)),
        }
        return metrics

    def render(self) -> np.ndarray | None:
        mujoco.mj_camlight(self.model, self.data)  # kinematics alone leaves cameras/lights unset
        return super().render()

    def draw_task(self, scene: mujoco.MjvScene) -> None:
        """The reference path, the target (frame), joint-limit warnings (cir_gym.rendering)."""
        from cir_gym import rendering

        rendering.draw_redundant_ik(self, scene)

    def caption(self) -> str:
        from cir_gym import rendering

        return rendering.redundant_ik_caption(self)

    # ------------------------------------------------------------------ observation
    def _obs(
        self, p: np.ndarray | None = None, R: np.ndarray | None = None
    ) -> dict[str, np.ndarray]:
        """The observation: one new flat buffer, filled, clipped to the bounds once, handed
        out as views (each step's arrays are new; nothing is shared with the env's state).
        ``p``, ``R``: the site pose at the current q when the caller has it (``step``)."""
        k = self._k
        if p is None or R is None:
            p, R = self._forward(self._q)
        buf = np.empty(self._obs_high.size)
        v = {key: buf[sl] for key, sl in self._obs_slices.items()}
        v["q"][:] = self._q
        v["x"][:] = p
        v["x_ref"][:] = self._x_ref[k]
        v["xd_ref"][:] = self._xd_ref[k]
        if self.task_dim == 6:
            # align_quat(quat_from_matrix(R), Q_home) on Python floats, its one-matrix path
            quat = traj._quat_from_matrix_floats(R.ravel().tolist())
            if quat is None:  # not a rotation: the array path (its NaN)
                v["quat"][:] = align_quat(traj.quat_from_matrix(R), self._quat_home)
            else:
                home = self._quat_home_floats
                v["quat"][:] = quat if quat_dot(quat, home) >= 0.0 else [-x for x in quat]
            v["quat_ref"][:] = self._quat_ref[k]
            v["omega_ref"][:] = self._omega_ref[k]
        v["q_lower"][:] = self.lower
        v["q_upper"][:] = self.upper
        v["obstacle"][:] = self._obstacle
        CLIP(buf, self._obs_low, self._obs_high, out=buf)
        return v

    def controller_context(self) -> TaskContext:
        return TaskContext(
            robot=self.robot_name,
            dt=self.dt,
            action_kind="joint_velocity",
            action_scale=self.velocity_limit.copy(),
            site=self.site,
            extras={
                "objective": self.objective,
                "task_dim": self.task_dim,
                "pos_dim": self.pos_dim,
            },
        )

    def _time_grid(self) -> np.ndarray:
        return np.arange(self.max_steps + 1) * self.dt

    def _closed_path(
        self,
        shape: str,
        centre: np.ndarray,
        size: float,
        aspect: float,
        timing: traj.TimingLaw,
        start_angle: float,
        turns: float,
        **plane: Any,
    ) -> traj.Ellipse | traj.FigureEight:
        if shape == "circle":
            return traj.Circle(centre, size, timing, start_angle=start_angle, turns=turns, **plane)
        if shape == "ellipse":
            return traj.Ellipse(
                centre, size, aspect * size, timing, start_angle=start_angle, turns=turns, **plane
            )
        return traj.FigureEight(
            centre, size, aspect * size, timing, start_angle=start_angle, turns=turns, **plane
        )


# ---------------------------------------------------------------------- planar3r
class RedundantIKEnv(_RedundantIKBase):
    """Track a closed planar path with the end effector of a 3R planar arm (n = 3, m = 2).

    ## Description
    The redundancy-resolution problem of chapter 1: the `planar3r` arm (links 0.5, 0.4, 0.3 m
    in the plane z = 0) must move its end effector (site ``ee``) along a closed path, with one
    degree of redundancy left (dim ker J = 1). Kinematic control: the action is a joint-velocity
    command integrated exactly over the control period (q ← q + Δt q̇, then forward kinematics);
    there are no dynamics. Each episode draws a circle, an ellipse or a figure eight (centre at
    0.5–0.8 m from the base within ±0.8 rad of the home end-effector direction, size
    0.1–0.25 m, aspect 0.5–1, random start angle and direction) traced once with a quintic
    timing law. ``objective`` selects the secondary task the reward scores:
    "manipulability" (w = sqrt(det JJᵀ)), "joint_limits" (one joint's range narrowed per episode,
    see Starting State) or "obstacle" (a circle in the plane, drawn as a cylinder, placed on
    the sweep of links 1–2 under minimum-norm motion, see Starting State). Clearance is
    computed analytically: the distance from the obstacle's centre to each link capsule's
    segment minus the capsule and obstacle radii (negative when they intersect).

    ## Action Space
    ``Box(-1, 1, (3,), float32)``: q̇ = a ⊙ q̇_max with q̇_max = (2, 2, 2) rad/s. Finite values
    outside [-1, 1] are clipped (so commands beyond the velocity limits are saturated); NaN/inf
    or a wrong shape raise ``ValueError``.

    ## Observation Space
    ``Dict`` of float64 arrays (values clipped to the bounds):

    | key | shape | meaning | bounds | unit |
    |---|---|---|---|---|
    | q | (3,) | joint positions | ±2π | rad |
    | x | (2,) | end-effector position (x, y) | ±3 | m |
    | x_ref | (2,) | reference position x̄(t) | ±3 | m |
    | xd_ref | (2,) | reference velocity x̄̇(t) | ±10 | m/s |
    | q_lower | (3,) | this episode's lower joint limits | ±2π | rad |
    | q_upper | (3,) | this episode's upper joint limits | ±2π | rad |
    | obstacle | (3,) | obstacle centre (x, y) and radius; (10, 10, 0) when there is none | ±20 | m |

    ## Rewards
    r = r_tracking + r_orientation + r_secondary + r_velocity + r_termination, each in
    ``info["reward_<name>"]``:
    - r_tracking = −(1 − (1/3) Σ_s exp(−‖x̄ − x‖² / s²)), s ∈ ``error_scales``, in [−1, 0];
    - r_orientation = 0 (no orientation task on the plane);
    - r_secondary = −``secondary_weight`` c, c ∈ [0, 1]: exp(−w / 0.1) for "manipulability",
      −8 w_jl(q) = (4/n) Σ ((q_i − q̄_i)/(q_iM − q_im))² for "joint_limits",
      exp(−max(clearance, 0) / 0.05 m) for "obstacle";
    - r_velocity = −``velocity_weight`` ‖a‖² / 3;
    - r_termination = −``termination_penalty`` on the step that violates a joint limit or
      collides, else 0 (the default, 50 ≈ 1/(1 − γ) for γ = 0.98, charges a lost episode
      the cost of staying lost; v0's 1000 dominated every return and an agent's value scale).

    ## Starting State
    At rest on the path: q(0) is the home keyframe (0.2, 0.8, 0.6) moved to x̄(0) by Newton
    steps q ← q + J†(x̄(0) − k(q)) (residual < 1e-12 m). For "manipulability" the redundancy
    starts badly used: of that solution and the postures of its self-motion at x̄(0) (every
    0.25 rad of arc up to ±π, ≥ 0.3 rad from every joint limit or no closer than that
    solution), q(0) is the one from which minimum-norm CLIK (q̇ = J†(x̄̇ + e/Δt)) would trace
    the lap inside the joint limits with the least manipulability over t ≥ 0.1 T, so the
    metric shows whether a controller uses the redundancy (plain CLIK can finish the lap, so
    the comparison is at equal task error). With ``initial_error`` the arm starts
    at x̄(0) + δ, ‖δ‖ = ``initial_error``. For "joint_limits" one random joint's range is
    narrowed to width ``joint_window`` with q(0) at 10–25 % of it from a random side (within
    the file's range; ``q_lower``/``q_upper`` in the observation); only a joint that the
    self-motion moves is drawn (|v_j| ≥ 0.1 for the unit null vector v of J at q(0)). For "obstacle" the
    obstacle (radius 4–7 cm) overlaps a link capsule by 5–20 mm at a random instant of the
    minimum-norm (pseudo-inverse CLIK) motion, at least radius + 8 cm away from the path and
    3 cm away from the arm at q(0), and only if a motion along the self-motion clears it by
    5 mm over the whole lap within the joint and velocity limits (``clearing_motion()`` returns
    that motion); a new path is drawn until such an obstacle exists, so every "obstacle"
    episode has one: after 20 paths ``reset`` raises ``InvalidArgument`` naming
    ``episode_duration`` (a lap too short for the links to sweep past an obstacle, e.g.
    0.5 s; the default placed one on every seed tested). The placement is why plain CLIK
    collides in every "obstacle" episode, and the "manipulability" start why it is poorly
    manipulable: by construction of the variants.
    ``reset(options={"replay": True})`` (no seed) starts the last drawn task again exactly
    (reference, obstacle, joint window, q(0)) without drawing: ~0.1 ms against up to ~0.2 s
    for an "obstacle" draw; any other option raises ``InvalidArgument``.

    ## Episode End
    Truncated after ``episode_duration`` s (one lap). Terminated when a step would cross a
    joint limit (the joint stops at the limit, ``info["joint_limit_violation"] = True``) or
    when a link touches the obstacle (``info["collision"] = True``). ``info["diverged"]`` is
    always False (kinematic simulation: actions are clipped and integrated exactly, so nothing
    can diverge). Stepping on after an episode end continues from the stopped state with the
    last reference held; call ``reset()``.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | objective | "manipulability" | secondary task scored: "manipulability", "joint_limits", "obstacle" |
    | control_freq | 200.0 | control frequency (Hz), Δt = 1/control_freq |
    | episode_duration | 5.0 | s: one lap of the path (quintic timing law, at rest at both ends) |
    | initial_error | 0.0 | initial task-position offset (m) in a random direction |
    | joint_window | 1.4 | width (rad) of the narrowed joint range for "joint_limits" |
    | error_scales | (0.1, 0.01, 0.001) | tracking-reward kernel widths (m, each in [1e-9, 1e3]) |
    | secondary_weight | 0.1 | weight of the secondary-objective cost |
    | velocity_weight | 0.01 | weight of the joint-velocity term |
    | termination_penalty | 50.0 | reward lost on a joint-limit violation or a collision |
    | success_threshold | 0.001 | max position error (m) below which an episode succeeds |
    | render_mode | None | None, "human" or "rgb_array" (camera "top" looks down on the plane) |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    ``rms_task_error`` (primary, m), ``max_task_error`` (m), ``min_manipulability`` (m², higher
    is better; over t ≥ 0.1 T: the start-up tenth of the lap, where the reference barely moves
    and a controller may reconfigure the arm, is excluded), ``min_joint_limit_margin`` (rad, higher is better), ``min_clearance`` (m,
    higher is better; about 14 m to the far-away dummy obstacle of the other objectives),
    ``joint_drift`` (‖q(T) − q(0)‖ after the closed path, rad). A terminated episode is scored
    over the whole lap as if the arm stayed where it stopped: its error against the reference
    it no longer follows, its manipulability, margin and clearance unchanged. Success: no
    termination and ``max_task_error`` < ``success_threshold``. The leaderboard ranks each
    variant by success rate, then by the metric of its own objective
    (``leaderboard_primary_metrics``): ``min_manipulability`` ("manipulability"),
    ``min_clearance`` ("obstacle"), ``min_joint_limit_margin`` ("joint limits").

    ## Reference controllers
    ``baselines.available("cir_gym/RedundantIK-v3")``: jacobian_transpose, pseudo_inverse,
    clik, clik_dls, clik_weighted, clik_nullspace, clik_projected_gradient, clik_augmented.

    ## Version History
    - v3: an "obstacle" is kept only if a motion along the self-motion clears it over the
      whole lap within the joint and velocity limits (:meth:`clearing_motion`); v2 checked one
      instant: 15 of the 21 planar and 13 of the 16 iiwa episodes (of 100) that
      clik_nullspace collided in had no such motion. "manipulability" and "joint_limits"
      episodes are identical to v2's. Later, without a new version (observations, rewards and
      episodes unchanged): a terminated episode's metrics score the stopped arm against the
      moving reference (they held its last error, so a collision scored as good tracking);
      ``reset`` raises ``RuntimeError`` where it would have left an "obstacle" episode
      without an obstacle (never on the seeds tested).
    - v2: the "manipulability" start is the self-motion posture (≥ 0.3 rad from the limits)
      whose minimum-norm lap, inside the joint limits, is least manipulable (v1's least
      manipulable posture at t = 0 was, on the iiwa, a stationary point of w along the
      self-motion that no gradient method leaves, and on the plane said little about the lap).
    - v1: every "obstacle" episode has an obstacle (v0 left 7 % of them without); the
      "manipulability" start is the worst posture of the whole self-motion; "joint_limits"
      narrows only a joint the self-motion moves;
      ``termination_penalty`` 1000 → 50; terminated episodes are scored over the whole lap.
    - v0: initial version.
    """

    robot_name: ClassVar[str] = "planar3r"
    site: ClassVar[str] = "ee"
    pos_dim: ClassVar[int] = 2
    task_dim: ClassVar[int] = 2
    obstacle_type: ClassVar[int] = int(mujoco.mjtGeom.mjGEOM_CYLINDER)
    manipulability_scale: ClassVar[float] = 0.1
    obstacle_links: ClassVar[tuple[str, ...]] = ("link1", "link2")
    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec("rms_task_error", "m", "lower", "RMS end-effector position error"),
        MetricSpec("max_task_error", "m", "lower", "max end-effector position error"),
        MetricSpec("min_manipulability", "m^2", "higher", "min sqrt(det(J Jᵀ))"),
        MetricSpec("min_joint_limit_margin", "rad", "higher", "min distance to a joint limit"),
        MetricSpec("min_clearance", "m", "higher", "min link–obstacle distance"),
        MetricSpec("joint_drift", "rad", "lower", "‖q(T) − q(0)‖ after the closed path"),
    )

    def __init__(
        self,
        objective: str = "manipulability",
        control_freq: float = 200.0,
        episode_duration: float = 5.0,
        initial_error: float = 0.0,
        joint_window: float = 1.4,
        error_scales: tuple[float, ...] = (0.1, 0.01, 0.001),
        secondary_weight: float = 0.1,
        velocity_weight: float = 0.01,
        termination_penalty: float = 50.0,
        success_threshold: float = 0.001,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ) -> None:
        self._setup(
            objective=objective,
            control_freq=control_freq,
            episode_duration=episode_duration,
            initial_error=initial_error,
            joint_window=joint_window,
            error_scales=error_scales,
            secondary_weight=secondary_weight,
            velocity_weight=velocity_weight,
            termination_penalty=termination_penalty,
            success_threshold=success_threshold,
            render_mode=render_mode,
            width=width,
            height=height,
        )

    def _add_camera(self, spec: mujoco.MjSpec) -> None:
        spec.worldbody.add_camera(name="top", pos=[0.4, 0.3, 2.6], fovy=45.0)

    def _camera_name(self) -> str | int:
        return "top"

    def _draw_path(self) -> None:
        rng = self.np_random
        p_home, _ = self._forward(self.home)
        heading = float(np.arctan2(p_home[1], p_home[0]) + rng.uniform(-0.8, 0.8))
        rho = rng.uniform(0.5, 0.8)
        centre = rho * np.array([np.cos(heading), np.sin(heading)])
        shape = SHAPES[int(rng.integers(len(SHAPES)))]
        size = float(rng.uniform(0.1, 0.25))
        aspect = float(rng.uniform(0.5, 1.0))
        angle = float(rng.uniform(-np.pi, np.pi))  # orientation of the shape's axes
        axes = ((np.cos(angle), np.sin(angle)), (-np.sin(angle), np.cos(angle)))
        timing = traj.TimingLaw.quintic(self.max_steps * self.dt)
        path = self._closed_path(
            shape,
            centre,
            size,
            aspect,
            timing,
            float(rng.uniform(-np.pi, np.pi)),
            float(rng.choice((-1.0, 1.0))),
            axes=axes,
        )
        self._x_ref[:], self._xd_ref[:], _ = path.evaluate(self._time_grid())


# ---------------------------------------------------------------------- iiwa14
class RedundantIK7Env(_RedundantIKBase):
    """Track a closed 3-D path and an orientation with the tool of a 7-DoF arm (n = 7, m = 6).

    ## Description
    Chapter 1 on the `iiwa14`: the pose of site ``tcp`` (position and orientation, m = 6) must
    follow a closed path, with one degree of redundancy (the arm's self-motion, "elbow
    angle"). Kinematic control: the action is a joint-velocity command integrated exactly over
    the control period; no dynamics. Each episode draws a circle, an ellipse or a figure eight
    of size 0.05–0.15 m (aspect 0.5–1) in a random plane whose centre is within 3 cm of the home
    tcp position, traced once with a quintic timing law σ(t), and an orientation reference
    R̄(t) = Rot(r, α sin 2πσ(t)) R_home (world axis r random, α ∈ [0.1, 0.3] rad), closed as
    well; ω̄ = r α 2π cos(2πσ) σ̇. The orientation error is the rotation vector of R̄ Rᵀ
    (through its quaternion), never an Euler-angle difference. ``objective`` as in
    ``RedundantIK-v3``; the obstacle is a sphere on the sweep of links 3–5 (around the
    elbow), and the clearance is computed analytically (centre to capsule segments, minus the
    radii).

    ## Action Space
    ``Box(-1, 1, (7,), float32)``: q̇ = a ⊙ q̇_max with q̇_max = (85, 85, 100, 75, 130, 135, 135)
    deg/s (data sheet, in rad/s). Finite values outside [-1, 1] are clipped; NaN/inf or a wrong
    shape raise ``ValueError``.

    ## Observation Space
    ``Dict`` of float64 arrays (values clipped to the bounds):

    | key | shape | meaning | bounds | unit |
    |---|---|---|---|---|
    | q | (7,) | joint positions | ±2π | rad |
    | x | (3,) | tcp position | ±3 | m |
    | x_ref | (3,) | reference position x̄(t) | ±3 | m |
    | xd_ref | (3,) | reference velocity | ±10 | m/s |
    | quat | (4,) | tcp orientation (w, x, y, z), on the home hemisphere (below) | ±1 | |
    | quat_ref | (4,) | reference orientation (w, x, y, z), on the home hemisphere | ±1 | |
    | omega_ref | (3,) | reference angular velocity (world frame) | ±20 | rad/s |
    | q_lower | (7,) | this episode's lower joint limits | ±2π | rad |
    | q_upper | (7,) | this episode's upper joint limits | ±2π | rad |
    | obstacle | (4,) | sphere centre and radius; (10, 10, 10, 0) when there is none | ±20 | m |

    Both quaternions take the sign with ⟨Q, Q_home⟩ ≥ 0, Q_home the tcp orientation at the
    home keyframe ((0.12, 0, 0.99, 0): the tool points down, 166° from the world frame), so
    both are continuous while the orientation stays within π of home (the reference stays
    within 0.3 rad of it); w may be negative.

    ## Rewards
    As ``RedundantIK-v3``, with r_orientation = −(1 − (1/3) Σ_s exp(−θ² / s²)), θ the
    orientation error (rad) and s ∈ 10 × ``error_scales`` (rad), and the manipulability cost
    exp(−w / 0.05).

    ## Starting State
    As ``RedundantIK-v3``, from the home keyframe (0, 0.6, 0, −1.4, 0, 0.9, 0) to the pose
    (x̄(0), R̄(0)); ``initial_error`` offsets the position only.

    ## Episode End
    As ``RedundantIK-v3``.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | objective | "manipulability" | secondary task scored: "manipulability", "joint_limits", "obstacle" |
    | control_freq | 100.0 | control frequency (Hz), Δt = 1/control_freq |
    | episode_duration | 6.0 | s: one lap of the path (quintic timing law, at rest at both ends) |
    | initial_error | 0.0 | initial task-position offset (m) in a random direction |
    | joint_window | 0.6 | width (rad) of the narrowed joint range for "joint_limits" |
    | error_scales | (0.1, 0.01, 0.001) | tracking-reward kernel widths (m, each in [1e-9, 1e3]) |
    | secondary_weight | 0.1 | weight of the secondary-objective cost |
    | velocity_weight | 0.01 | weight of the joint-velocity term |
    | termination_penalty | 50.0 | reward lost on a joint-limit violation or a collision |
    | success_threshold | 0.001 | max position error (m); the orientation must stay below 10× (rad) |
    | render_mode | None | None, "human" or "rgb_array" (MuJoCo's free camera) |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    As ``RedundantIK-v3`` plus ``rms_orientation_error`` and ``max_orientation_error`` (rad);
    manipulability of the 6×7 Jacobian (mixed units). Success: no termination,
    ``max_task_error`` < ``success_threshold`` and ``max_orientation_error`` <
    10 ``success_threshold``.

    ## Reference controllers
    ``baselines.available("cir_gym/RedundantIK7-v4")``: jacobian_transpose, pseudo_inverse,
    clik, clik_dls, clik_weighted, clik_nullspace, clik_projected_gradient, clik_augmented.

    ## Version History
    - v4: ``quat`` and ``quat_ref`` on one continuous hemisphere, ⟨Q, Q_home⟩ ≥ 0. v3 forced
      w ≥ 0 on ``quat_ref``, which flipped sign mid-episode wherever w crossed 0 (3 of the
      first 40 "manipulability" episodes), while ``quat`` (MuJoCo's ``mju_mat2Quat``,
      documented w ≥ 0) kept the sign of its largest component and so did not follow it.
      Terminated episodes scored against the moving reference and no episode without an
      obstacle, as ``RedundantIK-v3``'s later note. Otherwise as v3.
    - v0–v3: as ``RedundantIK-v3`` (v3: obstacles clearable over the whole lap; v2: the
      "manipulability" start; v1: obstacles, joint windows, termination penalty; v0: initial
      version).
    """

    robot_name: ClassVar[str] = "iiwa14"
    site: ClassVar[str] = "tcp"
    pos_dim: ClassVar[int] = 3
    task_dim: ClassVar[int] = 6
    obstacle_type: ClassVar[int] = int(mujoco.mjtGeom.mjGEOM_SPHERE)
    manipulability_scale: ClassVar[float] = 0.05
    obstacle_links: ClassVar[tuple[str, ...]] = ("link3", "link4", "link5")
    centre_spread: ClassVar[float] = 0.03  # m: path centre within ± this of the home tcp
    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec("rms_task_error", "m", "lower", "RMS tcp position error"),
        MetricSpec("max_task_error", "m", "lower", "max tcp position error"),
        MetricSpec("rms_orientation_error", "rad", "lower", "RMS tcp orientation error"),
        MetricSpec("max_orientation_error", "rad", "lower", "max tcp orientation error"),
        MetricSpec("min_manipulability", "", "higher", "min sqrt(det(J Jᵀ)) of the 6×7 J"),
        MetricSpec("min_joint_limit_margin", "rad", "higher", "min distance to a joint limit"),
        MetricSpec("min_clearance", "m", "higher", "min link–obstacle distance"),
        MetricSpec("joint_drift", "rad", "lower", "‖q(T) − q(0)‖ after the closed path"),
    )

    def __init__(
        self,
        objective: str = "manipulability",
        control_freq: float = 100.0,
        episode_duration: float = 6.0,
        initial_error: float = 0.0,
        joint_window: float = 0.6,
        error_scales: tuple[float, ...] = (0.1, 0.01, 0.001),
        secondary_weight: float = 0.1,
        velocity_weight: float = 0.01,
        termination_penalty: float = 50.0,
        success_threshold: float = 0.001,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ) -> None:
        self._setup(
            objective=objective,
            control_freq=control_freq,
            episode_duration=episode_duration,
            initial_error=initial_error,
            joint_window=joint_window,
            error_scales=error_scales,
            secondary_weight=secondary_weight,
            velocity_weight=velocity_weight,
            termination_penalty=termination_penalty,
            success_threshold=success_threshold,
            render_mode=render_mode,
            width=width,
            height=height,
        )

    def _draw_path(self) -> None:
        rng = self.np_random
        p_home, R_home = self._forward(self.home)
        normal = rng.standard_normal(3)
        centre = p_home + rng.uniform(-self.centre_spread, self.centre_spread, 3)
        shape = SHAPES[int(rng.integers(len(SHAPES)))]
        size = float(rng.uniform(0.05, 0.15))
        aspect = float(rng.uniform(0.5, 1.0))
        T = self.max_steps * self.dt
        timing = traj.TimingLaw.quintic(T)
        path = self._closed_path(
            shape,
            centre,
            size,
            aspect,
            timing,
            float(rng.uniform(-np.pi, np.pi)),
            float(rng.choice((-1.0, 1.0))),
            normal=normal,
        )
        t = self._time_grid()
        self._x_ref[:], self._xd_ref[:], _ = path.evaluate(t)
        # R̄(t) = Rot(r, α sin 2πσ) R_home, ω̄ = r α 2π cos(2πσ) σ̇ (world frame)
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        alpha = float(rng.uniform(0.1, 0.3))
        s, sd, _ = timing.evaluate(t)
        sigma, sigma_d = s / timing.length, sd / timing.length
        self._R_ref[:] = (
            traj.matrix_from_axis_angle(axis, alpha * np.sin(2 * np.pi * sigma)) @ R_home
        )
        # the hemisphere of the home orientation (continuous: R̄ stays within 0.3 rad of it)
        self._quat_ref[:] = align_quat(traj.quat_from_matrix(self._R_ref), self._quat_home)
        rate = alpha * 2 * np.pi * np.cos(2 * np.pi * sigma) * sigma_d
        self._omega_ref[:] = rate[:, None] * axis


REDUNDANT_IK_ENVIRONMENTS: dict[str, tuple[type[RobotEnv], str]] = {
    "cir_gym/RedundantIK-v3": (
        RedundantIKEnv,
        "planar3r closed-path tracking with joint velocities; redundancy for a secondary "
        "objective (ch. 1)",
    ),
    "cir_gym/RedundantIK7-v4": (
        RedundantIK7Env,
        "iiwa14 6-D pose tracking of a closed path with joint velocities; redundancy (ch. 1)",
    ),
}
