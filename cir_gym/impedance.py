"""Cartesian impedance control with gravity compensation on a nominal model (chapter 6).

The law (``control-laws.md`` §5 "Operational space: PD + gravity", the active-compliance form of
§6 "Impedance control" without force measurement; cir-notes 5.2.1 and 6.2.1):

    τ = Jᵀ(q) (K_p x̃ − K_d ẋ) + g(q) + Nᵀ(q) τ₀,

with x̃ = [p_d − p; log(R_d Rᵀ)] (6,) the pose error of the controlled point (position in m, the
orientation error as a rotation vector in rad, world frame), ẋ = J(q) q̇ its twist (geometric
Jacobian J, (6, n)), K_p, K_d diagonal (6,) stiffness and damping, g(q) the gravity torque of the
nominal arm *with its tool*, and τ₀ = K_n (q_rest − q) − D_n q̇ a joint posture regulator acting
only in the null space of the task (Nᵀ = I − Jᵀ J̄ᵀ, J̄ = B⁻¹ Jᵀ Λ the dynamically consistent
inverse): a 7-joint arm has one self-motion the 6-D impedance does not hold.

At rest in contact (q̇ = 0, exact gravity compensation) the closed loop balances Jᵀ K_p x̃ against
the contact's Jᵀ γ_e: the end effector behaves as a spring K_p around the setpoint, γ_e = K_p x̃
(the robot's own inertia, not an assigned M_d, sets the transient: chapter 6's "coupled and only
partially assignable" impedance). This is the task-space impedance of Isaac Lab's Factory and
IndustReal and of robosuite's variable-impedance controllers without inertial decoupling.

Everything here uses only a nominal model (a :class:`~cir_gym.robot.Robot` built from a
:class:`~cir_gym.context.TaskContext`): what a real robot's controller has.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import mujoco
import mujoco.batch
import numpy as np

from cir_gym import operational_space as osp
from cir_gym import trajectories as traj
from cir_gym.context import TaskContext
from cir_gym.robot import Robot
from cir_gym.validation import InvalidArgument

_VELOCITY_STAGE = int(mujoco.mjtStage.mjSTAGE_VEL)
#: v = R[_VEE_ROW, _VEE_COL] − R[_VEE_COL, _VEE_ROW] = [R₃₂ − R₂₃, R₁₃ − R₃₁, R₂₁ − R₁₂]
_VEE_ROW, _VEE_COL = np.array([2, 0, 1]), np.array([1, 2, 0])
#: a × b = a[_CROSS_A] b[_CROSS_B] − a[_CROSS_B] b[_CROSS_A] (mju_cross's order)
_CROSS_A, _CROSS_B = np.array([1, 2, 0]), np.array([2, 0, 1])
#: the nominal arm's evaluation needs kinematics, B and the bias only
_UNUSED_STAGES = int(
    mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    | mujoco.mjtDisableBit.mjDSBL_CONTACT
    | mujoco.mjtDisableBit.mjDSBL_SENSOR
    | mujoco.mjtDisableBit.mjDSBL_ACTUATION
)


def _dof_chain(m: mujoco.MjModel, body: int) -> np.ndarray | None:
    """(nv, 1) mask of the dofs that move ``body`` (mj_jac's ancestor chain), or None when
    they are all the model's."""
    while body and not m.body_dofnum[body]:
        body = int(m.body_parentid[body])
    chain = np.zeros((m.nv, 1))
    i = int(m.body_dofadr[body] + m.body_dofnum[body] - 1) if body else -1
    while i >= 0:
        chain[i] = 1.0
        i = int(m.dof_parentid[i])
    return None if chain.all() else chain

__all__ = [
    "CartesianImpedance",
    "ImpedanceGains",
    "critical_damping",
    "exp_rotvec",
    "log_rotation",
    "pose_error",
    "tool_robot",
]


def exp_rotvec(phi: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors φ = θ r (..., 3) (rad): Rodrigues'
    formula R = I + sin θ S(r) + (1 − cos θ) S(r)², with R = I + S(φ) below θ = 1e-12."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)[..., None, None]
    S = osp.skew(phi)  # S(φ) = θ S(r)
    tiny = theta < 1e-12
    with np.errstate(invalid="ignore", divide="ignore"):
        K = S / np.where(tiny, 1.0, theta)
    turn = np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)
    return np.eye(3) + np.where(tiny, S, turn)


def log_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation vectors φ (..., 3) of rotation matrices (..., 3, 3), θ = ‖φ‖ ∈ [0, π] (rad).

    φ = θ / (2 sin θ) · v with v = [R₃₂ − R₂₃, R₁₃ − R₃₁, R₂₁ − R₁₂] = 2 sin θ r and
    θ = atan2(‖v‖, tr R − 1); within 5e-4 rad of θ = π, where v no longer gives the axis
    accurately, from the quaternion (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    v = R[..., _VEE_ROW, _VEE_COL] - R[..., _VEE_COL, _VEE_ROW]
    two_sin = np.sqrt(np.sum(v * v, axis=-1))
    two_cos = np.trace(R, axis1=-2, axis2=-1) - 1.0
    # θ / (2 sin θ) (→ 1/2 as θ → 0; v = 0 at θ = 0)
    phi = (np.arctan2(two_sin, two_cos) / np.maximum(two_sin, 1e-300))[..., None] * v
    if np.min(two_cos) < -1.999:  # near π: 2 sin θ < 1e-3 there implies 2 cos θ < −1.999
        flipped = (two_sin < 1e-3) & (two_cos < 0.0)
        phi[flipped] = osp.rotvec_from_quat(traj.quat_from_matrix(R[flipped]))
    return phi


def pose_error(p_d: np.ndarray, R_d: np.ndarray, p: np.ndarray, R: np.ndarray) -> np.ndarray:
    """x̃ = [p_d − p; log(R_d Rᵀ)] (..., 6): position error (m) and orientation error as a
    rotation vector (rad), both in the world frame (the frame of the geometric Jacobian's rows).
    Positions (..., 3), rotations (..., 3, 3)."""
    return np.concatenate((p_d - p, log_rotation(R_d @ np.swapaxes(R, -1, -2))), axis=-1)


def critical_damping(stiffness: np.ndarray, inertia: np.ndarray, ratio: float = 1.0) -> np.ndarray:
    """K_d = 2 ζ √(K_p m) (6,): the damping giving ratio ζ to a mass ``inertia`` (kg or kg m²,
    per direction) on a spring ``stiffness`` (N/m or N m/rad)."""
    return 2.0 * ratio * np.sqrt(np.asarray(stiffness, float) * np.asarray(inertia, float))


def tool_robot(context: TaskContext, tcp_offset: float | None = None) -> Robot:
    """The nominal arm of ``context`` carrying the task's tool, with the ``tcp`` site at the
    controlled point.

    The tool's mass ``extras["tool_mass"]`` (kg) is put on the robot file's ``payload`` body
    (the sensor frame) at ``extras["tool_com"]`` (m, sensor frame), as a point mass: g(q) then
    holds the tool's weight. ``tcp_offset`` (m): the ``tcp`` site moved to this distance beyond
    the flange along the flange's z axis (PegInHole's peg tip, ``extras["tip_offset"]``);
    None keeps the robot file's ``tcp``.
    """
    robot = context.nominal_robot()
    m = robot.model
    mass = float(context.extras.get("tool_mass", 0.0))
    if mass > 0.0:
        payload = m.body("payload").id
        m.body_mass[payload] = mass
        m.body_ipos[payload] = np.asarray(context.extras.get("tool_com", np.zeros(3)), float)
        m.body_iquat[payload] = (1.0, 0.0, 0.0, 0.0)
        m.body_inertia[payload] = 1e-6  # kg m²: a point mass (MuJoCo needs a positive inertia)
    if tcp_offset is not None:
        tcp, flange = m.site("tcp").id, m.site("flange").id
        if m.site_bodyid[tcp] != m.site_bodyid[flange]:
            raise ValueError("the nominal arm's tcp and flange sites are on different bodies")
        R_f = traj.matrix_from_quat(m.site_quat[flange])
        m.site_pos[tcp] = m.site_pos[flange] + R_f @ np.array([0.0, 0.0, float(tcp_offset)])
        m.site_quat[tcp] = m.site_quat[flange]
    # the derived constants (subtree masses) follow the new inertials
    mujoco.mj_setConst(m, mujoco.MjData(m))
    robot.invalidate()
    return robot


@dataclass(frozen=True)
class ImpedanceGains:
    """Gains of :class:`CartesianImpedance`.

    Attributes:
        stiffness: K_p (6,): N/m for x, y, z, then N m/rad for the three rotations.
        damping: K_d (6,): N s/m, then N m s/rad.
        posture_stiffness: K_n of the null-space posture regulator (N m/rad, every joint).
        posture_damping: D_n (N m s/rad, every joint).
    """

    stiffness: np.ndarray
    damping: np.ndarray
    posture_stiffness: float = 10.0
    posture_damping: float = 2.0

    def __post_init__(self) -> None:
        for name in ("stiffness", "damping"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (6,) or not np.all(np.isfinite(value)) or np.any(value < 0):
                raise InvalidArgument(
                    f"{name} must be 6 finite numbers >= 0 (3 translational, 3 rotational), "
                    f"got {getattr(self, name)!r}"
                )
            object.__setattr__(self, name, value)
        for name in ("posture_stiffness", "posture_damping"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise InvalidArgument(f"{name} must be a finite number >= 0, got {value!r}")


class CartesianImpedance:
    """τ = Jᵀ(K_p x̃ − K_d ẋ) + g(q) + Nᵀ τ₀ at a site of a nominal robot (module docstring), for
    one arm or for N arms at once: every method takes q of shape (n,) (one arm) or (N, n) and
    answers with the same leading shape.

    The nominal model is evaluated for all arms by one ``mujoco.batch.Batch`` (MuJoCo's own
    computations, row by row, to the velocity stage at q̇ = 0: forward kinematics, B(q) from
    the composite rigid bodies with the armature, g(q) as the bias; the site's Jacobian by
    ``mj_jac``'s formula on the rows' ``cdof``), and the law is numpy on (..., 6) and (..., n)
    arrays: one arm is the one-row case of the same code.

    Args:
        robot: the nominal model (e.g. :func:`tool_robot`); never the simulator's.
        site: the controlled point's site.
        gains: :class:`ImpedanceGains` (K_p, K_d are the defaults of :meth:`torque`).
        q_rest: posture the null-space regulator pulls towards (rad): (n,) for one arm, or
            (N, n), one per arm; a live array (``q_rest[i] = q`` sets arm i's).
    """

    def __init__(self, robot: Robot, site: str, gains: ImpedanceGains, q_rest: np.ndarray) -> None:
        self.robot = robot
        self.site = robot.site_id(site)
        self.gains = gains
        self.q_rest = np.array(q_rest, dtype=float)
        n = robot.n
        if self.q_rest.ndim not in (1, 2) or self.q_rest.shape[-1] != n:
            raise InvalidArgument(
                f"q_rest must have shape ({n},) or (num_arms, {n}), got {self.q_rest.shape}"
            )
        self.num_arms = 1 if self.q_rest.ndim == 1 else self.q_rest.shape[0]
        self._build_arms()

    def _build_arms(self) -> None:
        """The batch of the nominal arm (one row per arm) and its bound fields."""
        robot = self.robot
        m = copy.deepcopy(robot.model)  # without what B, g and J do not need
        m.opt.disableflags |= _UNUSED_STAGES
        self._arms = mujoco.batch.Batch(m, nsim=self.num_arms, nthread=1)
        self._qpos = self._arms.bind("qpos")  # (N, nq); q̇ stays 0: qfrc_bias is g(q)
        self._site_xpos = self._arms.bind("site_xpos")
        self._site_xmat = self._arms.bind("site_xmat")
        self._M = self._arms.bind("M")  # B(q) in MuJoCo's sparse rows (N, nM)
        self._bias = self._arms.bind("qfrc_bias")
        self._cdof = self._arms.bind("cdof")  # (N, nv, 6): each dof's [ω; v] about the com
        self._subtree_com = self._arms.bind("subtree_com")
        body = int(m.site_bodyid[self.site])
        self._root = int(m.body_rootid[body])
        self._chain = _dof_chain(m, body)
        # B's lower-triangle entries: M[:, k] is B[row[k], col[k]] (and B[col[k], row[k]])
        self._M_row = np.repeat(np.arange(m.nv), m.M_rownnz)
        self._M_col = m.M_colind.copy()
        self._qadr, self._dadr = robot.qpos_adr, robot.dof_adr
        # the arm's dofs are the model's, in order: no selection of rows and columns
        self._whole = np.array_equal(self._dadr, np.arange(m.nv))
        self._q_key: bytes | None = None
        self._p = self._R = self._J = self._B = self._g = np.zeros(0)

    def __getstate__(self) -> dict[str, Any]:
        """Pickled without the batch (a C object): :meth:`__setstate__` builds it again."""
        keep = ("robot", "site", "gains", "q_rest", "num_arms")
        return {name: self.__dict__[name] for name in keep}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._build_arms()

    def _evaluate(self, q: np.ndarray) -> None:
        """The nominal model's site pose, Jacobian, B and g at ``q`` (N, n), row by row
        (kept until q changes)."""
        key = q.tobytes()
        if key == self._q_key:
            return
        if not np.isfinite(np.sum(q)):
            raise ValueError("q contains NaN or inf; expected finite values")
        self._qpos[:, self._qadr] = q
        self._arms.forward(stage=_VELOCITY_STAGE)  # kinematics, B (crb), bias at q̇ = 0
        self._p = self._site_xpos[:, self.site].copy()  # (N, 3)
        self._R = self._site_xmat[:, self.site].reshape(-1, 3, 3)  # (N, 3, 3)
        # mj_jac: J_O = ω, J_P = v + ω × (p − c_root) of each dof of the site's chain
        cdof = self._cdof if self._chain is None else self._cdof * self._chain
        w, r = cdof[:, :, :3], (self._p - self._subtree_com[:, self._root])[:, None, :]
        a, b = _CROSS_A, _CROSS_B
        jacp = cdof[:, :, 3:] + (w[..., a] * r[..., b] - w[..., b] * r[..., a])
        J = np.concatenate((jacp, w), axis=2).transpose(0, 2, 1).copy()  # [J_P; J_O] (N, 6, nv)
        nv = self.robot.model.nv
        B = np.zeros((q.shape[0], nv, nv))
        B[:, self._M_row, self._M_col] = self._M
        B[:, self._M_col, self._M_row] = self._M
        g = self._bias  # g(q) (N, nv)
        if not self._whole:
            J, B, g = J[:, :, self._dadr], B[:, self._dadr][:, :, self._dadr], g[:, self._dadr]
        self._J, self._B, self._g = J, B, g.copy()  # (N, 6, n), (N, n, n), (N, n)
        self._q_key = key

    def _rows(self, q: np.ndarray) -> tuple[np.ndarray, tuple[int, ...]]:
        """``q`` as (N, n) float64 rows, and the leading shape of the answers (() or (N,))."""
        q = np.asarray(q, dtype=float)
        lead = q.shape[:-1]
        n, arms = self.robot.n, self.num_arms
        if q.shape[-1:] != (n,) or (arms,) != (lead or (1,)):
            allowed = f"({n},)" if arms == 1 else f"({arms}, {n})"
            raise ValueError(f"q must have shape {allowed}, got {q.shape}")
        rows = q.reshape(arms, n)
        self._evaluate(rows)
        return rows, lead

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The controlled point's position (..., 3) m and rotation (..., 3, 3) (site → world)."""
        _, lead = self._rows(q)
        return self._p.reshape(*lead, 3).copy(), self._R.reshape(*lead, 3, 3).copy()

    def task_inertia(self, q: np.ndarray) -> np.ndarray:
        """Λ(q) = (J B⁻¹ Jᵀ)⁻¹ (..., 6, 6) at the controlled point (kg, kg m)."""
        _, lead = self._rows(q)
        return osp.task_inertia(self._J, self._B).reshape(*lead, 6, 6)

    def torque(
        self,
        q: np.ndarray,
        qd: np.ndarray,
        p_d: np.ndarray,
        R_d: np.ndarray,
        stiffness: np.ndarray | None = None,
        damping: np.ndarray | None = None,
    ) -> np.ndarray:
        """Joint torques τ (..., n) N m driving the controlled points to the setpoints.

        Args:
            q, qd: measured joint positions (rad) and velocities (rad/s), (n,) or (N, n).
            p_d: setpoint positions (..., 3) m, world; R_d: setpoint rotations (..., 3, 3).
            stiffness, damping: K_p, K_d (6,) or (N, 6) for this call (variable impedance);
                None: the gains'.
        """
        rows, lead = self._rows(q)
        g = self.gains
        K_p = g.stiffness if stiffness is None else stiffness
        K_d = g.damping if damping is None else damping
        n = self.robot.n
        qd = np.reshape(qd, (-1, n, 1))  # (N, n, 1)
        J, B = self._J, self._B
        JT = np.swapaxes(J, -1, -2)
        x_err = pose_error(np.reshape(p_d, (-1, 3)), np.reshape(R_d, (-1, 3, 3)), self._p, self._R)
        # the impedance's wrench K_p x̃ − K_d ẋ, ẋ = J q̇ (N, 6, 1); K_p, K_d (6,) or (N, 6)
        wrench = (K_p * x_err)[:, :, None] - np.reshape(K_d, (-1, 6, 1)) * (J @ qd)
        tau = self._g.copy()
        if g.posture_stiffness > 0.0 or g.posture_damping > 0.0:
            tau0 = g.posture_stiffness * (self.q_rest.reshape(-1, n, 1) - rows[:, :, None]) \
                - g.posture_damping * qd  # (N, n, 1)
            # Nᵀ τ₀ = τ₀ − Jᵀ J̄ᵀ τ₀ with J̄ᵀ τ₀ = Λ J B⁻¹ τ₀, Λ = (J B⁻¹ Jᵀ)⁻¹: one solve
            # with B for [Jᵀ τ₀] and one with Λ⁻¹ (the dynamically consistent inverse, unformed)
            task_inverse = J @ np.linalg.solve(B, np.concatenate((JT, tau0), axis=2))
            # [Λ⁻¹ | J B⁻¹ τ₀] (N, 6, 7): J̄ᵀ τ₀ = Λ (J B⁻¹ τ₀)
            wrench -= np.linalg.solve(task_inverse[:, :, :6], task_inverse[:, :, 6:])
            tau += tau0[..., 0]
        tau += (JT @ wrench)[..., 0]  # τ = Jᵀ(K_p x̃ − K_d ẋ − J̄ᵀ τ₀) + g + τ₀
        return tau.reshape(*lead, n)
