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

One interface drives one arm or a batch of N arms (a vector env's copies): its setpoint state
has the shape of the configuration given to :meth:`CartesianMotionInterface.reset`, (n,) or
(N, n), and :meth:`~CartesianMotionInterface.command` and
:meth:`~CartesianMotionInterface.torque` then take (6,) / (n,) or (N, 6) / (N, n) arrays.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from cir_gym.operational_space import damped_least_squares
from cir_gym.robot import Robot
from cir_gym.validation import InvalidArgument, check_number

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

    Attributes:
        q_c: joint setpoint at the end of the current period, (n,) or (N, n) (rad).
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
        self.q_c = np.zeros(robot.n)
        self._q_start = np.zeros(robot.n)  # joint setpoint at the start of the period
        self._dq = np.zeros(robot.n)  # the period's setpoint step δq
        self._period = 1.0
        self._data: mujoco.MjData | None = None  # B̂ and n̂'s own MjData, built on first use

    # ------------------------------------------------------------------ setpoint
    def reset(self, q: np.ndarray, rows: Any = None) -> None:
        """Hold the measured configuration ``q``: (n,) for one arm, (N, n) for N arms (the
        setpoint state takes its shape); with ``rows`` (indices or a mask of an N-arm
        interface) only those arms, ``q`` then (len(rows), n) or (n,) for all of them."""
        q = np.asarray(q, dtype=float)
        if rows is None:
            if q.shape[-1:] != (self.robot.n,) or q.ndim > 2:
                raise InvalidArgument(
                    f"q must have shape ({self.robot.n},) or (N, {self.robot.n}), got {q.shape}"
                )
            self.q_c = q.copy()
            self._q_start = q.copy()
            self._dq = np.zeros_like(q)
            return
        self.q_c[rows] = q
        self._q_start[rows] = q
        self._dq[rows] = 0.0

    def command(self, increment: np.ndarray, period: float) -> None:
        """Start a control period of ``period`` s moving the setpoint by ``increment``
        [δp; δφ] ((6,), or (N, 6) for N arms; m, rad, world frame):
        q_c ← clip(q_c + J*(q_c) δx) (see the module docstring)."""
        dx = np.asarray(increment, dtype=float)
        if dx.shape != (*self.q_c.shape[:-1], 6) or not np.all(np.isfinite(dx)):
            raise InvalidArgument(
                f"increment must be finite, shape {(*self.q_c.shape[:-1], 6)} ([δp; δφ] per "
                f"arm), got {increment!r}"
            )
        if self.q_c.ndim == 1:
            J = self.robot.jacobian(self.site, self.q_c)  # (6, n)
        else:
            J = np.stack([self.robot.jacobian(self.site, q) for q in self.q_c])  # (N, 6, n)
        J_star = damped_least_squares(J, self.damping)  # (..., n, 6)
        q_new = np.clip(self.q_c + (J_star @ dx[..., None])[..., 0], self.robot.lower,
                        self.robot.upper)
        self._q_start = self.q_c
        self._dq = q_new - self.q_c
        self.q_c = q_new
        self._period = period

    def reference(self, fraction: float) -> tuple[np.ndarray, np.ndarray]:
        """The interpolated joint reference q_r = q_c,prev + s δq and q̇_r = δq / T at
        ``fraction`` s ∈ (0, 1] into the period (shapes of :attr:`q_c`)."""
        return self._q_start + min(fraction, 1.0) * self._dq, self._dq / self._period

    # ------------------------------------------------------------------ torque
    def torque(self, q: np.ndarray, qd: np.ndarray, fraction: float) -> np.ndarray:
        """Joint torques τ = B̂(q) y + n̂(q, q̇), y = K_P (q_r − q) + K_D (q̇_r − q̇), at a
        physics step ``fraction`` ∈ (0, 1] into the period; q, q̇ and τ shaped as
        :attr:`q_c` ((n,) or (N, n); rad, rad/s, N m).

        Raises:
            ValueError: q or q̇ of another shape, or not finite.
        """
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        if q.shape != self.q_c.shape or qd.shape != self.q_c.shape:
            raise ValueError(
                f"q and qd must have shape {self.q_c.shape}, got {q.shape} and {qd.shape}"
            )
        q_r, qd_r = self.reference(fraction)
        y = self.kp * (q_r - q) + self.kd * (qd_r - qd)
        if not np.isfinite(y).all():  # the setpoint is finite: q or q̇ is not
            raise ValueError("q or qd contains NaN or inf; expected finite values")
        return self.inverse_dynamics(q, qd, y)

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, y: np.ndarray) -> np.ndarray:
        """τ = B̂(q) y + n̂(q, q̇) of the nominal model, arm by arm ((n,) or (N, n) each):
        Newton–Euler with q̈ = y (mj_rne), plus the rotor inertias (armature) that B̂ holds
        and Newton–Euler does not."""
        if self._data is None:
            self._new_data()
        m, d, (qpos, qvel, qacc), full = self.robot.model, self._data, self._views, self._full
        qa, da = self._qpos_index, self._dof_index
        if q.ndim == 1:
            q, qd, y = q[None], qd[None], y[None]
        tau = np.empty(y.shape)
        for i in range(len(y)):
            qpos[qa] = q[i]
            qvel[da] = qd[i]
            qacc[da] = y[i]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_comVel(m, d)
            mujoco.mj_rne(m, d, 1, full)
            tau[i] = full[da]
        tau += self._armature * y
        return tau.reshape(self.q_c.shape) if self.q_c.ndim == 1 else tau

    def _new_data(self) -> None:
        """The nominal model's own MjData, views of its qpos, qvel and qacc (a pybind
        property builds a new array on every access), the joints' indices (slices when
        contiguous) and rotor inertias."""
        robot, m = self.robot, self.robot.model
        self._data = mujoco.MjData(m)
        self._views = (self._data.qpos, self._data.qvel, self._data.qacc)
        self._full = np.zeros(m.nv)
        self._qpos_index = _as_slice(robot.qpos_adr)
        self._dof_index = _as_slice(robot.dof_adr)
        self._armature = m.dof_armature[robot.dof_adr].copy()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_data"] = None  # rebuilt on first use
        state.pop("_views", None)
        return state

    def setpoint_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The Cartesian setpoint x_c = k(q_c) of a one-arm interface: position (3,) and
        rotation (3, 3)."""
        return self.robot.site_pose(self.site, self.q_c)


def _as_slice(index: np.ndarray) -> slice | np.ndarray:
    """``index`` as a slice if its entries are consecutive (cheaper to index with)."""
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index
