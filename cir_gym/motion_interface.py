"""The position interface of an industrial robot: Cartesian setpoint increments, executed stiffly.

An industrial controller does not accept joint torques: it takes a stream of Cartesian setpoint
increments (KUKA RSI, ABB EGM, UR servoL) and executes them with its own high-gain motion
controller. Chapter 6's *admittance control* is designed for exactly that interface: the
interaction controller computes a compliant frame x_c and the robot's stiff motion controller
makes x ≈ x_c. :class:`CartesianMotionInterface` is that robot-side controller:

1. every control period T, an increment δx = [δp; δφ] (6,) (m, rad; δφ a rotation vector in
   the world frame) moves the joint setpoint by differential inverse kinematics,
   δq = J*(q_c) δx with the damped least-squares inverse J* of the geometric Jacobian of the
   controlled site at the *setpoint* q_c (:func:`cir_gym.operational_space.damped_least_squares`),
   clipped to the joint limits. The Cartesian setpoint is x_c = k(q_c) (forward kinematics), so
   it never drifts from the joint setpoint;
2. the setpoint is interpolated linearly over the period (q_r = q_c,prev + s δq, q̇_r = δq/T,
   s = i/N for the N physics steps of a period), as an interpolator does;
3. at every physics step, joint-space inverse dynamics with the robot's nominal model,
   τ = B̂(q) (K_P (q_r − q) + K_D (q̇_r − q̇)) + n̂(q, q̇), K_P = ω_n² I, K_D = 2ζω_n I
   (chapter 5), gives the joint error dynamics q̃̈ + K_D q̃̇ + K_P q̃ = 0 with an exact model.

Bandwidth: with an exact model each joint's error obeys q̃̈ + 2ζω_n q̃̇ + ω_n² q̃ = 0, so the
pose follows the setpoint through ω_n²/(s² + 2ζω_n s + ω_n²) plus the velocity feed-forward,
which widens it. Measured on the iiwa with its tool at the AdmittanceContact start pose (a
1 mm sine along z in free space, 500 Hz setpoints, defaults ω_n = 150 rad/s, ζ = 1;
tests/test_ft_sensor.py::test_motion_interface_bandwidth): gain +0.3 dB at 5 Hz, +1.3 dB at
20 Hz, −0.6 dB at 40 Hz, −5.3 dB at 60 Hz: the −3 dB bandwidth is :data:`MEASURED_BANDWIDTH_HZ`
≈ 50 Hz, with 20° of phase lag at 20 Hz. Against a disturbance force the arm is a Cartesian
spring of stiffness ≈ Λ(q) ω_n² (Λ the task-space inertia, a few kg at the tool: ~10⁵ N/m),
as stiff as the stiffest surface of AdmittanceContact: "stiff" but not rigid, like a real arm.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from cir_gym.fast_solve import solve
from cir_gym.numeric import CLIP
from cir_gym.operational_space import damped_least_squares
from cir_gym.robot import Robot
from cir_gym.validation import InvalidArgument, check_number

#: command's damped least squares inline (False: operational_space.damped_least_squares
#: itself, the reference the inline form is tested against)
_INLINE_DLS = True
_F64 = np.dtype(np.float64)
_isfinite = math.isfinite

__all__ = ["MEASURED_BANDWIDTH_HZ", "CartesianMotionInterface"]

#: −3 dB bandwidth (Hz) of the setpoint-to-tool-position response with the default gains,
#: measured by tests/test_ft_sensor.py::test_motion_interface_bandwidth (a sine along z at the
#: AdmittanceContact start pose, in free space, 500 Hz setpoints).
MEASURED_BANDWIDTH_HZ = 50.0


class CartesianMotionInterface:
    """Cartesian setpoint increments → joint setpoint → stiff joint-space inverse dynamics.

    Args:
        robot: the robot's *nominal* model (the interface is the robot vendor's controller:
            it knows the arm and its tool, not the environment).
        site: the controlled site (the tool centre point).
        omega_n: natural frequency of the joint error dynamics (rad/s), in (0, 1000].
        zeta: damping ratio, in (0, 10].
        damping: damped least-squares factor k of the differential IK (m), in [0, 1].
    """

    def __init__(
        self,
        robot: Robot,
        site: str,
        *,
        omega_n: float = 150.0,
        zeta: float = 1.0,
        damping: float = 1e-3,
    ) -> None:
        self.robot = robot
        self.site = robot.site_id(site)
        self.omega_n = check_number("omega_n", omega_n, 0.0, 1000.0, low_open=True)
        self.zeta = check_number("zeta", zeta, 0.0, 10.0, low_open=True)
        self.damping = check_number("damping", damping, 0.0, 1.0)
        self.kp = self.omega_n**2
        self.kd = 2.0 * self.zeta * self.omega_n
        self.q_c = np.zeros(robot.n)  # joint setpoint at the end of the current period
        self._q_start = np.zeros(robot.n)
        self._dq = np.zeros(robot.n)
        self._period = 1.0
        self._dls_k: float | None = None  # the damping of _dls_diag (command)
        self._dls_diag = np.zeros((6, 6))
        # torque's model calls on an own MjData (Robot.inertia's and Robot.bias's MuJoCo
        # calls, in their order, without their per-call validation); built lazily
        self._fast: tuple[Any, ...] | None = None

    def reset(self, q: np.ndarray) -> None:
        """Hold the measured configuration ``q`` (n,)."""
        self.q_c[:] = q
        self._q_start[:] = q
        self._dq[:] = 0.0

    def command(self, increment: np.ndarray, period: float) -> None:
        """Start a control period of ``period`` s moving the setpoint by ``increment`` (6,)."""
        dx = np.asarray(increment, dtype=float)
        # all(map(isfinite, ...)): np.all(np.isfinite(dx)) on six numbers, exactly
        if dx.shape != (6,) or not all(map(_isfinite, dx.tolist())):
            raise InvalidArgument(f"increment must be 6 finite numbers [δp; δφ], got {increment!r}")
        J = self.robot.jacobian(self.site, self.q_c)
        k = self.damping
        if not _INLINE_DLS or J.shape[0] != 6 or not k * k > 0:
            J_star = damped_least_squares(J, k)
        else:  # damped_least_squares(J, k), operation for operation (k² > 0; a tiny k whose
            # square rounds to 0 takes that plain path). J Jᵀ + k² I is positive definite in
            # exact arithmetic, but rounding can still give LAPACK an exactly zero pivot (k² lost
            # against J Jᵀ at a rank-deficient J, k ≲ 1e-8 here), and the solve can overflow:
            # fast_solve.solve runs numpy's gufunc under np.linalg.solve's own error state
            # (LinAlgError "Singular matrix", as there)
            if k != self._dls_k:
                self._dls_diag = (np.asarray(k, dtype=float) ** 2)[..., None, None] * np.eye(6)
                self._dls_k = k
            JJt = J @ np.swapaxes(J, -1, -2) + self._dls_diag
            J_solved = solve(JJt, J)
            J_star = np.swapaxes(J_solved, -1, -2)
        # the clip ufunc (np.clip's values without its Python wrapper)
        q_new = CLIP(self.q_c + J_star @ dx, self.robot.lower, self.robot.upper)
        self._q_start[:] = self.q_c
        self._dq = q_new - self.q_c
        self.q_c[:] = q_new
        self._period = period

    def torque(self, q: np.ndarray, qd: np.ndarray, fraction: float) -> np.ndarray:
        """Joint torques (n,) at a physics step, ``fraction`` ∈ (0, 1] into the period."""
        q_r = self._q_start + min(fraction, 1.0) * self._dq
        qd_r = self._dq / self._period
        y = self.kp * (q_r - q) + self.kd * (qd_r - qd)
        robot = self.robot
        if (
            q.__class__ is np.ndarray
            and qd.__class__ is np.ndarray
            and q.dtype is _F64
            and qd.dtype is _F64
            and q.shape == qd.shape == (robot.n,)
            and robot._whole
            and _isfinite(y.dot(y))  # q and q̇ finite (Robot's checks; else its errors)
        ):
            fast = self._fast
            if fast is None:
                fast = self._fast = self._model_calls()
            m, d, qpos, qvel, M, vec = fast
            # Robot.inertia(q): qpos, kinematics, com positions, CRB, the full matrix
            qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_crb(m, d)
            mujoco.mj_fullM(m, d, M)
            # Robot.bias(q, q̇): qvel, com velocities, RNE without acceleration
            qvel[:] = qd
            mujoco.mj_comVel(m, d)
            mujoco.mj_rne(m, d, 0, vec)
            return M @ y + vec
        return robot.inertia(q) @ y + robot.bias(q, qd)

    def _model_calls(self) -> tuple[Any, ...]:
        """(model, an own MjData, its qpos and qvel, the inertia and bias buffers)."""
        m = self.robot.model
        d = mujoco.MjData(m)
        return m, d, d.qpos, d.qvel, np.zeros((m.nv, m.nv)), np.zeros(m.nv)

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_fast"] = None  # views of an MjData: rebuilt on first use
        return state

    def setpoint_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The Cartesian setpoint x_c = k(q_c): position (3,) and rotation (3, 3)."""
        return self.robot.site_pose(self.site, self.q_c)
