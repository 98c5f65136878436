"""Chapter 4: independent-joint (decentralized) control seen from the motors.

Each joint is a motor of rotor inertia J_m behind a gear of ratio n: q_m = n q, τ = n τ_m
(:mod:`cir_gym.motor`). The load seen by motor i is J_eff = J_m + B̄_r,ii = J_m + J_l / n²,
J_l = B̄_ii the link inertia about joint i at the home pose (B̂_ii minus the armature): the one
model number the course's design uses. The rest of the manipulator (coupling, Coriolis,
gravity) is the disturbance d of :func:`cir_gym.motor.motor_side_disturbance`, rejected by the
loop; ``decentralized_feedforward`` also feeds the nominal d̂ forward.

Design (control-laws.md §4): speed PI R_PI = k_pv (1 + s t_iv)/(s t_iv) with
k_pv = ω_cv J_eff and 1/t_iv = ``integral_ratio`` · ω_cv (0.1…0.3); position P k_pp = ω_cp
well below ω_cv; speed feed-forward k_ff q̄̇_m. With position measurement only, the PID on
position places a triple pole at −ω: k_d = 3ωJ, k_p = 3ω²J, k_i = ω³J.

Anti-windup: every integrator (the PID's ∫q̃_m, the cascade's ∫e_v) is corrected by
back-calculation (Åström & Hägglund, *Advanced PID Control*, ISA 2006, §3.5): the excess of the
command over the torque limit, u_sat − u, is fed back into the integrator with the tracking
time T_t = T_i (the PI's t_iv; the PID's k_p/k_i = 3/ω), so while the actuator saturates the
integral settles instead of growing, and the loop leaves saturation without the overshoot a
wound-up integral causes. (Conditional integration, the other textbook remedy, was tried and
rejected: in the loops that chatter between both torque limits at small gear ratios it
integrates only the unsaturated half-cycles and drifts, e.g. ∫e_v → −6 and a 0.15-rad error on
JointTracking-v2 at N = 50, seed 2001, where back-calculation and no anti-windup stay at
0.014 rad.)

Elastic joints (the task gives ``extras["stiffness"]``, the nominal K): the loops close on the
motor encoders θ (link units), and a spring holding the link against gravity is deflected by
θ − q = K⁻¹g(q). The motor reference is therefore θ̄ = q̄ + K̂⁻¹ĝ(q̄) (and
θ̄̇ = q̄̇ + K̂⁻¹ dĝ(q̄)/dt), the elastic-joint gravity compensation of the course; on the
reference θ̄ the link sits at q̄ (with the nominal ĝ and K̂), not g/k_el below it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from cir_gym.baselines.base import Controller, InvalidGain, Observation

from cir_gym.context import TaskContext
from cir_gym.motor import (
    average_inertia,
    joint_torques,
    motor_positions,
    motor_side_inertia,
    motor_torques,
)
from cir_gym.numeric import CLIP
from cir_gym.robot import Robot

__all__ = [
    "CascadeGains",
    "DecentralizedFeedforward",
    "FeedforwardCascadeGains",
    "IndependentPID",
    "PCascade",
    "PIDGains",
    "PPIFeedforward",
    "effective_motor_inertia",
]

JOINT_TASKS = ("JointTracking", "ElasticJointTracking")
#: highest loop bandwidth used by default, as a fraction of the sampling rate (ω dt)
MAX_OMEGA_DT = 0.25


def effective_motor_inertia(
    robot: Robot, gear_ratio: np.ndarray, rotor_inertia: np.ndarray
) -> np.ndarray:
    """J_eff = J_m + B̄_r,ii = J_m + J_l / n² (n,) in kg m² (motor side), B̄_r = N⁻¹B̄N⁻¹ with
    J_l = B̄_ii = B̂_ii(q_home) − armature (:func:`cir_gym.motor.average_inertia`)."""
    B_bar_r = motor_side_inertia(average_inertia(robot), gear_ratio)
    return rotor_inertia + np.diag(B_bar_r)


class _Decentralized(Controller):
    tasks = JOINT_TASKS
    #: every law below is element-wise per joint, so :meth:`control` runs on rows (N, n) as
    #: it runs on one observation; the model calls (ĝ, B̂ q̈ + n̂) go row by row
    vectorized = True
    #: finite-difference step (s) of dĝ(q̄)/dt ≈ (ĝ(q̄ + h q̄̇) − ĝ(q̄)) / h
    GRAVITY_RATE_STEP = 1e-6

    def __init__(
        self, context: TaskContext, gains=None, *, robot: Robot | None = None, **overrides
    ) -> None:
        super().__init__(context, gains, **overrides)
        robot = robot if robot is not None else context.nominal_robot()
        self.robot = robot
        self.n = robot.n
        self.N = (context.gear_ratio if context.gear_ratio is not None else robot.gear_ratio).copy()
        J_m = context.rotor_inertia if context.rotor_inertia is not None else robot.rotor_inertia
        self.J_eff = effective_motor_inertia(robot, self.N, J_m)
        # Elastic joints: ω_z = sqrt(k_el / (J_l / n²)) (motor side) = sqrt(k_el,link / J_l).
        stiffness = context.extras.get("stiffness")
        self.omega_z = None
        self.stiffness = None if stiffness is None else np.asarray(stiffness, dtype=float)
        if stiffness is not None:
            J_l = (self.J_eff - J_m) * self.N**2
            self.omega_z = np.sqrt(self.stiffness / J_l)

    def references(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """The reference (position, speed) the loop tracks, in joint units: q̄, q̄̇; with
        elastic joints the motor reference θ̄ = q̄ + K̂⁻¹ĝ(q̄) and its rate (module docstring)."""
        q_ref, qd_ref = obs["q_ref"], obs["qd_ref"]
        if self.stiffness is None:
            return q_ref, qd_ref
        g = self.nominal_gravity(q_ref)
        h = self.GRAVITY_RATE_STEP
        g_rate = (self.nominal_gravity(q_ref + h * qd_ref) - g) / h
        return q_ref + g / self.stiffness, qd_ref + g_rate / self.stiffness

    def nominal_gravity(self, q: np.ndarray) -> np.ndarray:
        """ĝ(q) of the nominal robot for q (n,) or rows (N, n) (N m)."""
        rows = self.row_dynamics()
        if rows is not None:
            return rows.gravity(q)
        if q.ndim == 1:
            return self.robot.gravity(q)
        return np.array([self.robot.gravity(q_i) for q_i in q])

    def nominal_inverse_dynamics(
        self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
    ) -> np.ndarray:
        """B̂(q) q̈ + n̂(q, q̇) of the nominal robot for (n,) or rows (N, n) (N m)."""
        rows = self.row_dynamics()
        if rows is not None:
            return rows.newton_euler(q, qd, qdd)
        if q.ndim == 1:
            return self.robot.inertia(q) @ qdd + self.robot.bias(q, qd)
        return np.array(
            [self.nominal_inverse_dynamics(*row) for row in zip(q, qd, qdd, strict=True)]
        )

    def control_batch(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        return np.asarray(self.control(obs, state), dtype=float)

    def anti_windup(
        self, command: np.ndarray, error: np.ndarray, state: np.ndarray, gain: np.ndarray
    ) -> None:
        """Correct the integral ``state`` (already advanced by Δt e) after the joint command u
        (N m) was computed from it, per ``gains.anti_windup``:

        - "back_calculation": ∫e += Δt (u_sat − u) / (N k T_t), u_sat = u clipped to the
          torque limit, k the loop's proportional gain (motor side), the tracking time
          T_t = T_i the integral time, so ``gain`` = N k;
        - "clamping" (conditional integration): where u exceeds the limit in the direction
          of ``error``, undo this step's Δt e;
        - "none": the plain integrator.
        """
        mode = self.gains.anti_windup
        if mode == "back_calculation":
            excess = CLIP(command, -self.action_scale, self.action_scale) - command
            state += self.dt * excess / gain
        elif mode == "clamping":
            windup = (np.abs(command) > self.action_scale) & (np.sign(command) == np.sign(error))
            state[windup] -= self.dt * error[windup]

    def measured(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """Joint position and speed the loop closes on: the motor encoders (θ = q_m / n, in
        link units) when the task has them, else the joint ones."""
        if "q_motor" in obs:
            return obs["q_motor"], obs["qd_motor"]
        return obs["q"], obs["qd"]


ANTI_WINDUP = ("back_calculation", "clamping", "none")


def _check_anti_windup(value: str) -> None:
    if value not in ANTI_WINDUP:
        raise InvalidGain(f"anti_windup must be one of {ANTI_WINDUP}, got {value!r}")


@dataclass(frozen=True)
class PIDGains:
    """omega: triple closed-loop pole (rad/s) of each joint's PID on position;
    anti_windup: "back_calculation", "clamping" or "none" (module docstring)."""

    omega: float = 20.0
    anti_windup: str = "back_calculation"

    def __post_init__(self) -> None:
        if not np.isfinite(self.omega) or self.omega <= 0:
            raise InvalidGain(f"omega must be > 0, got {self.omega!r}")
        _check_anti_windup(self.anti_windup)


class IndependentPID(_Decentralized):
    """Independent joint PID on position (no model beyond J_eff): τ_m = k_p q̃_m + k_i ∫q̃_m +
    k_d q̃̇_m, τ = n τ_m. State: ∫q̃_m (n,), with back-calculation anti-windup."""

    name = "pid"
    Gains = PIDGains

    @property
    def state_size(self) -> int:
        return self.n

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        w, J = self.gains.omega, self.J_eff
        q, qd = self.measured(obs)
        q_ref, qd_ref = self.references(obs)
        e_m = motor_positions(q_ref - q, self.N)  # q̃_m = n q̃
        ed_m = motor_positions(qd_ref - qd, self.N)
        state += self.dt * e_m
        tau = joint_torques(3 * w**2 * J * e_m + w**3 * J * state + 3 * w * J * ed_m, self.N)
        self.anti_windup(tau, e_m, state, self.N * 3 * w**2 * J)  # N k_p, T_t = k_p / k_i
        return tau


@dataclass(frozen=True)
class CascadeGains:
    """omega_cv: speed-loop bandwidth ω_cv (rad/s); None = 80 rad/s on rigid joints and
    0.7 ω_z on elastic ones (the notes' choice), capped at 0.25/dt;
    integral_ratio: 1/(t_iv ω_cv) (0.1…0.3);
    omega_cp: position-loop crossover ω_cp = k_pp (rad/s); None = ω_cv / 5 (well below ω_cv);
    k_ff: speed feed-forward in [0, 1];
    anti_windup: "back_calculation", "clamping" or "none" (module docstring)."""

    omega_cv: float | None = None
    integral_ratio: float = 0.2
    omega_cp: float | None = None
    k_ff: float = 0.0
    anti_windup: str = "back_calculation"

    def __post_init__(self) -> None:
        for name in ("omega_cv", "integral_ratio", "omega_cp"):
            v = getattr(self, name)
            if v is not None and (not np.isfinite(v) or v <= 0):
                raise InvalidGain(f"{name} must be > 0, got {v!r}")
        if not 0.0 <= self.k_ff <= 1.0:
            raise InvalidGain(f"k_ff must be in [0, 1], got {self.k_ff!r}")
        _check_anti_windup(self.anti_windup)
        if (
            self.omega_cp is not None
            and self.omega_cv is not None
            and self.omega_cp >= self.omega_cv
        ):
            raise InvalidGain("omega_cp must be well below omega_cv")


class PCascade(_Decentralized):
    """Position P + speed PI cascade on the motor side (Fig. 4.6 of the notes without k_ff).

    ω_ref = k_pp (q̄_m − q_m) + k_ff q̄̇_m; τ_m = k_pv (e_v + ∫e_v / t_iv), e_v = ω_ref − q̇_m.
    State: ∫e_v (n,), with back-calculation anti-windup.
    """

    name = "p_pi_cascade"
    Gains = CascadeGains

    def __init__(
        self, context: TaskContext, gains=None, *, robot: Robot | None = None, **overrides
    ) -> None:
        super().__init__(context, gains, robot=robot, **overrides)
        g = self.gains
        if g.omega_cv is not None:
            w_cv = np.full(self.n, g.omega_cv)
        elif self.omega_z is not None:
            w_cv = np.minimum(0.7 * self.omega_z, MAX_OMEGA_DT / self.dt)
        else:
            w_cv = np.full(self.n, 80.0)
        self.omega_cv = w_cv
        self.omega_cp = np.full(self.n, g.omega_cp) if g.omega_cp is not None else w_cv / 5
        self.k_pv = w_cv * self.J_eff  # ω_cv = k_pv / (J_m + J_l/n²)

    @property
    def state_size(self) -> int:
        return self.n

    def feedforward(self, obs: Observation) -> np.ndarray:
        """Extra motor torque fed forward (n,) — none for the plain cascade."""
        return np.zeros(self.n)

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        g = self.gains
        q, qd = self.measured(obs)
        q_ref, qd_ref = self.references(obs)
        inv_tiv = g.integral_ratio * self.omega_cv
        # ω_ref = k_pp q̃_m + k_ff q̄̇_m with q_m = N q (products kept in their original order)
        w_ref = self.omega_cp * self.N * (q_ref - q) + g.k_ff * self.N * qd_ref
        e_v = w_ref - motor_positions(qd, self.N)
        state += self.dt * e_v
        tau = joint_torques(self.k_pv * (e_v + inv_tiv * state) + self.feedforward(obs), self.N)
        self.anti_windup(tau, e_v, state, self.N * self.k_pv)  # N k_pv, T_t = t_iv
        return tau


@dataclass(frozen=True)
class FeedforwardCascadeGains(CascadeGains):
    """:class:`CascadeGains` with the speed feed-forward on by default (k_ff = 1)."""

    k_ff: float = 1.0


class PPIFeedforward(PCascade):
    """The P/PI cascade with speed feed-forward k_ff q̄̇_m (default k_ff = 1; a ``k_ff=`` or a
    ``gains=FeedforwardCascadeGains(k_ff=...)`` is used as given)."""

    name = "p_pi_feedforward"
    Gains = FeedforwardCascadeGains


class DecentralizedFeedforward(PPIFeedforward):
    """P/PI with speed feed-forward plus the computed torque feed-forward of the notes:
    τ_m,ff = (J_m + B̄_r) q̄̈_m + d̂ = n⁻¹ (B̂(q̄) q̄̈ + n̂(q̄, q̄̇)), from the nominal model at
    the reference (not the measured state), so the loop stays decentralized. (B̂ includes
    the armature n² J_m, so n⁻¹ B̂ q̄̈ = (J_m + B̄_r) q̄̈_m + n⁻¹ΔB q̄̈; d̂ is
    :func:`cir_gym.motor.motor_side_disturbance` at the reference.)"""

    name = "decentralized_feedforward"

    def feedforward(self, obs: Observation) -> np.ndarray:
        tau_ff = self.nominal_inverse_dynamics(obs["q_ref"], obs["qd_ref"], obs["qdd_ref"])
        return motor_torques(tau_ff, self.N)
