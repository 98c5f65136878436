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

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from cir_gym import operational_space as osp
from cir_gym import trajectories as traj
from cir_gym.context import TaskContext
from cir_gym.robot import Robot
from cir_gym.validation import InvalidArgument

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
    """Rotation matrix (3, 3) of a rotation vector φ = θ r (3,) (rad): Rodrigues' formula."""
    theta = math.sqrt(float(phi @ phi))
    if theta < 1e-12:
        return np.eye(3) + osp.skew(phi)
    K = osp.skew(phi / theta)
    return np.eye(3) + math.sin(theta) * K + (1.0 - math.cos(theta)) * (K @ K)


def log_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation vector φ (3,) of a rotation matrix (3, 3), θ = ‖φ‖ ∈ [0, π] (rad)."""
    return osp.rotvec_from_quat(traj.quat_from_matrix(R))


def pose_error(p_d: np.ndarray, R_d: np.ndarray, p: np.ndarray, R: np.ndarray) -> np.ndarray:
    """x̃ = [p_d − p; log(R_d Rᵀ)] (6,): position error (m) and orientation error as a rotation
    vector (rad), both in the world frame (the frame of the geometric Jacobian's rows)."""
    return np.concatenate((p_d - p, log_rotation(R_d @ R.T)))


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
    """τ = Jᵀ(K_p x̃ − K_d ẋ) + g(q) + Nᵀ τ₀ at a site of a nominal robot (module docstring).

    Args:
        robot: the nominal model (e.g. :func:`tool_robot`); never the simulator's.
        site: the controlled point's site.
        gains: :class:`ImpedanceGains`.
        q_rest: (n,) posture the null-space regulator pulls towards (rad).
    """

    def __init__(self, robot: Robot, site: str, gains: ImpedanceGains, q_rest: np.ndarray) -> None:
        self.robot = robot
        self.site = robot.site_id(site)
        self.gains = gains
        self.q_rest = np.array(q_rest, dtype=float)
        if self.q_rest.shape != (robot.n,):
            raise InvalidArgument(f"q_rest must have shape ({robot.n},), got {self.q_rest.shape}")

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The controlled point's position (3,) m and rotation (3, 3) (site → world) at q."""
        return self.robot.site_pose(self.site, q)

    def task_inertia(self, q: np.ndarray) -> np.ndarray:
        """Λ(q) = (J B⁻¹ Jᵀ)⁻¹ (6, 6) at the controlled point (kg, kg m)."""
        return osp.task_inertia(self.robot.jacobian(self.site, q), self.robot.inertia(q))

    def torque(
        self,
        q: np.ndarray,
        qd: np.ndarray,
        p_d: np.ndarray,
        R_d: np.ndarray,
        stiffness: np.ndarray | None = None,
        damping: np.ndarray | None = None,
    ) -> np.ndarray:
        """Joint torque τ (n,) N m driving the controlled point to the setpoint (p_d, R_d).

        Args:
            q, qd: measured joint positions (rad) and velocities (rad/s), (n,).
            p_d: setpoint position (3,) m, world; R_d: setpoint rotation (3, 3), world.
            stiffness, damping: K_p, K_d (6,) for this call (variable impedance); None: the
                gains'.
        """
        K_p = self.gains.stiffness if stiffness is None else stiffness
        K_d = self.gains.damping if damping is None else damping
        p, R = self.pose(q)
        J = self.robot.jacobian(self.site, q)
        x_err = pose_error(p_d, R_d, p, R)
        twist = J @ qd
        tau = J.T @ (K_p * x_err - K_d * twist) + self.robot.gravity(q)
        g = self.gains
        if g.posture_stiffness > 0.0 or g.posture_damping > 0.0:
            B = self.robot.inertia(q)
            J_bar = osp.dynamically_consistent_inverse(J, B)
            tau0 = g.posture_stiffness * (self.q_rest - q) - g.posture_damping * qd
            tau += tau0 - J.T @ (J_bar.T @ tau0)  # Nᵀ τ₀ = (I − Jᵀ J̄ᵀ) τ₀
        return tau
