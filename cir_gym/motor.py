"""Chapter 4: the manipulator seen from its motors through rigid gears (control-laws.md §4).

Joint i is driven by a motor of rotor inertia J_m,i through a gear of ratio n_i, N = diag(nᵢ):

    q_m = N q,   τ_lm = N⁻¹ τ   (the link torque τ loads the motor with N⁻¹ τ),
    B(q) = B̄ + ΔB(q),   B̄ the constant diagonal part of the link inertia,
    (J_m + B̄_r) q̈_m + D_m q̇_m + d = τ_m,   B̄_r = N⁻¹ B̄ N⁻¹,
    d = N⁻¹ ΔB(q) N⁻¹ q̈_m + N⁻¹ C(q, q̇) N⁻¹ q̇_m + N⁻¹ g(q) = N⁻¹ (ΔB(q) q̈ + C q̇ + g).

B(q) here is the LINK inertia: a :class:`~cir_gym.robot.Robot`'s ``inertia`` includes MuJoCo's
``armature``, the reflected rotor inertia N² J_m (the motor's J_m seen from the link), which
this module removes — on the motor side the rotor is the separate J_m. Gear ratios are (n,)
arrays (or scalars, broadcast); N⁻¹ M N⁻¹ is ``M / outer(n, n)``.
"""

from __future__ import annotations

import numpy as np

from cir_gym.robot import Robot

__all__ = [
    "average_inertia",
    "inertia_residual",
    "joint_positions",
    "joint_torques",
    "link_inertia",
    "motor_positions",
    "motor_side_disturbance",
    "motor_side_inertia",
    "motor_torques",
]


def _home(robot: Robot) -> np.ndarray:
    m = robot.model
    return m.key("home").qpos[robot.qpos_adr].copy() if m.nkey else np.zeros(robot.n)


def motor_positions(q: np.ndarray, gear_ratio: np.ndarray | float) -> np.ndarray:
    """q_m = N q (n,), rad on the motor shafts (also for velocities and accelerations)."""
    return np.asarray(gear_ratio) * np.asarray(q)


def joint_positions(q_m: np.ndarray, gear_ratio: np.ndarray | float) -> np.ndarray:
    """q = N⁻¹ q_m (n,), rad at the joints: the inverse of :func:`motor_positions`."""
    return np.asarray(q_m) / np.asarray(gear_ratio)


def motor_torques(tau: np.ndarray, gear_ratio: np.ndarray | float) -> np.ndarray:
    """τ_m = N⁻¹ τ (n,), N m on the motor shafts: the motor torque that a rigid gear turns
    into the joint torque τ (the load torque τ_lm the link puts on the motor)."""
    return np.asarray(tau) / np.asarray(gear_ratio)


def joint_torques(tau_m: np.ndarray, gear_ratio: np.ndarray | float) -> np.ndarray:
    """τ = N τ_m (n,), N m at the joints: the inverse of :func:`motor_torques`."""
    return np.asarray(gear_ratio) * np.asarray(tau_m)


def link_inertia(robot: Robot, q: np.ndarray) -> np.ndarray:
    """B(q) (n, n) of the links alone (kg m²): ``robot.inertia`` minus the armature N² J_m."""
    armature = robot.model.dof_armature[robot.dof_adr]
    return robot.inertia(q) - np.diag(armature)


def average_inertia(robot: Robot, q: np.ndarray | None = None) -> np.ndarray:
    """B̄ (n, n): the constant diagonal part of the link inertia, diag B(q) at ``q`` (default:
    the robot's home keyframe). The notes' "average inertia"; the decentralized design of
    :mod:`baselines.decentralized` uses the same B̄_ii (J_l of joint i)."""
    return np.diag(np.diag(link_inertia(robot, _home(robot) if q is None else q)))


def inertia_residual(robot: Robot, q: np.ndarray, B_bar: np.ndarray | None = None) -> np.ndarray:
    """ΔB(q) = B(q) − B̄ (n, n), kg m² (B̄ = :func:`average_inertia` when not given)."""
    B_bar = average_inertia(robot) if B_bar is None else B_bar
    return link_inertia(robot, q) - B_bar


def motor_side_inertia(B: np.ndarray, gear_ratio: np.ndarray | float) -> np.ndarray:
    """N⁻¹ B N⁻¹ (n, n), kg m² seen from the motors; B̄_r for B = B̄ (diagonal, scales as
    1/n²). Add diag(J_m) for the motor-side inertia of the drive."""
    B = np.asarray(B, dtype=float)
    n = np.broadcast_to(np.asarray(gear_ratio, dtype=float), (B.shape[0],))
    return B / np.outer(n, n)


def motor_side_disturbance(
    robot: Robot,
    q: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    gear_ratio: np.ndarray | float,
    B_bar: np.ndarray | None = None,
) -> np.ndarray:
    """d = N⁻¹ΔB(q)N⁻¹ q̈_m + N⁻¹C(q, q̇)N⁻¹ q̇_m + N⁻¹ g(q) (n,), N m on the motor shafts.

    q, qd, qdd are the JOINT state (q̈_m = N q̈), so d = N⁻¹ (ΔB(q) q̈ + C(q, q̇) q̇ + g(q)):
    for a fixed joint state ‖d‖ shrinks as 1/n, the notes' reason for decentralized control
    at large gear ratios. Evaluated at the reference (q̄, q̄̇, q̄̈) on a nominal model this is
    the feed-forward d̂ of chapter 4. B̄ = :func:`average_inertia` when not given.
    """
    qdd = np.asarray(qdd, dtype=float)
    delta_B = inertia_residual(robot, q, B_bar)
    return motor_torques(delta_B @ qdd + robot.bias(q, qd), gear_ratio)  # bias = C q̇ + g
