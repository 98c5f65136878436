"""Chapter 1: differential inverse kinematics and redundancy resolution as policies.

Every law returns joint velocities q̇ (n,) in rad/s for the tasks ``RedundantIK`` (planar3r,
position of ``ee``, m = 2) and ``RedundantIK7`` (iiwa14, pose of ``tcp``, m = 6). The base
class divides by the velocity limits and clips to [-1, 1], so commands beyond the limits are
saturated by the environment's action scaling.

Notation: x̄, x̄̇ the reference (``x_ref``, ``xd_ref``; for 6-D also ``quat_ref``,
``omega_ref``), e = [x̄ − x; e_O] the task error with e_O the rotation vector of R̄ Rᵀ
(:func:`cir_gym.redundancy.quat_orientation_error`), J (m, n) the geometric task Jacobian
of the controller's own nominal robot at the measured q (rows [J_P; J_O], the first two rows
of J_P on the plane). CLIK: q̇ = J†(x̄̇ + K e) gives ė + K e = 0, e(t) = e(0) exp(−K t);
with the control period Δt the discrete loop is e_{k+1} = (1 − K Δt) e_k (stable for
K Δt < 2; the default K = 50 1/s at 100 Hz gives K Δt = 0.5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from cir_gym.baselines.base import Controller, InvalidGain, Observation

from cir_gym.context import TaskContext
from cir_gym.redundancy import (
    OBJECTIVES,
    LinkCapsules,
    joint_limit_margin,
    joint_limit_objective_gradient,
    manipulability,
    null_vector,
    orientation_error,
    quat_orientation_error,
    walk_self_motion,
)
from cir_gym.robot import Robot

__all__ = [
    "CLIK",
    "KINEMATIC_CONTROLLERS",
    "AugmentedJacobianCLIK",
    "DampedLeastSquaresCLIK",
    "JacobianTranspose",
    "NullSpaceCLIK",
    "ProjectedGradientCLIK",
    "PseudoInverse",
    "SingularJacobian",
    "WeightedCLIK",
    "damped_pseudo_inverse",
    "null_space_projector",
    "pseudo_inverse",
    "saturate_joint_limits",
    "weighted_pseudo_inverse",
]

KINEMATIC_TASKS = ("RedundantIK", "RedundantIK7")
SINGULAR_TOLERANCE = 1e-9  # σ_min(J) below which J† does not exist (SingularJacobian)
SEARCH_HYSTERESIS = 0.02  # a self-motion target must beat the current w by 2 % to be taken
LIMIT_GUARD = 0.005  # rad: clik_nullspace never commands a step to within this of a limit


class SingularJacobian(FloatingPointError):
    """J J ᵀ is singular (σ_min(J) < ``SINGULAR_TOLERANCE``): the pseudo-inverse does not exist."""


def _positive(name: str, value: float) -> None:
    if isinstance(value, bool) or not np.isfinite(value) or value <= 0:
        raise InvalidGain(f"{name} must be a finite number > 0, got {value!r}")


# ---------------------------------------------------------------------- linear algebra
def pseudo_inverse(J: np.ndarray) -> np.ndarray:
    """Right pseudo-inverse J† = Jᵀ(J Jᵀ)⁻¹ (n, m) of a full-row-rank J (m, n).

    Raises:
        SingularJacobian: σ_min(J) < ``SINGULAR_TOLERANCE`` (J Jᵀ not invertible).
    """
    sigma = np.linalg.svd(J, compute_uv=False)
    if sigma[-1] < SINGULAR_TOLERANCE:
        raise SingularJacobian(
            f"the Jacobian is singular (smallest singular value {sigma[-1]:.2e}); "
            f"use clik_dls near singular configurations"
        )
    return np.linalg.solve(J @ J.T, J).T


def weighted_pseudo_inverse(J: np.ndarray, w_inv: np.ndarray) -> np.ndarray:
    """J_W† = W⁻¹Jᵀ(J W⁻¹ Jᵀ)⁻¹ (n, m) for a diagonal weight, ``w_inv`` = diag(W⁻¹) (n,)."""
    sigma = np.linalg.svd(J * np.sqrt(w_inv), compute_uv=False)
    if sigma[-1] < SINGULAR_TOLERANCE:
        raise SingularJacobian(f"J W^-1/2 is singular (smallest singular value {sigma[-1]:.2e})")
    JW = J * w_inv  # J W⁻¹ (m, n)
    return np.linalg.solve(JW @ J.T, JW).T


def damped_pseudo_inverse(J: np.ndarray, damping: float) -> np.ndarray:
    """Damped least squares J* = Jᵀ(J Jᵀ + k² I)⁻¹ (n, m), k = ``damping`` ≥ 0.

    ‖J* v‖ ≤ ‖v‖ / (2k) for k > 0: bounded at any configuration.
    """
    m = J.shape[0]
    return np.linalg.solve(J @ J.T + damping**2 * np.eye(m), J).T


def variable_damping(sigma_min: float, damping: float, region: float) -> float:
    """k(σ) = k_max sqrt(1 − (σ/ε)²) inside the singular region σ < ε, else 0.

    (Maciejewski & Klein's damping: exact least squares away from singularities, the full
    damping k_max at σ = 0, continuous in between.)
    """
    if sigma_min >= region:
        return 0.0
    return damping * float(np.sqrt(1.0 - (sigma_min / region) ** 2))


def null_space_scale(qd_task: np.ndarray, qd_null: np.ndarray, qd_max: np.ndarray) -> float:
    """Largest s ∈ [0, 1] with |q̇_task + s q̇_null| ≤ q̇_max on every joint (task priority).

    The environment clips each joint's command to its velocity limit, which bends a command
    that exceeds it away from the task; scaling the null-space part first keeps the primary
    task (the saturation-in-the-null-space idea of Flacco, De Luca and Khatib, ICRA 2012, in its
    simplest form). If q̇_task alone exceeds a limit, s = 0 and the env clips as before.
    """
    s = 1.0
    for a, b, m in zip(qd_task, qd_null, qd_max, strict=True):
        if abs(a + b) <= m or b == 0.0:
            continue
        if abs(a) >= m:
            return 0.0
        s = min(s, ((m if b > 0 else -m) - a) / b)
    return max(s, 0.0)


def saturate_joint_limits(J: np.ndarray, v: np.ndarray, qd: np.ndarray, qd_lower: np.ndarray,
                          qd_upper: np.ndarray) -> np.ndarray:
    """Joint velocities (n,) within [qd_lower, qd_upper] that still give J q̇ = v if they can.

    Saturation in the null space (Flacco, De Luca and Khatib, ICRA 2012) for one task: the
    joint that exceeds its bound most is held at the bound and the task re-solved with the
    others, q̇_free = (J_free)† (v − J q̇_held), at most n − m times (the redundancy: beyond
    it the task could not be solved); a rank-deficient J_free gives the least-squares q̇_free
    of least norm. ``qd`` is returned unchanged when it is within bounds.
    """
    n, m = J.shape[1], J.shape[0]
    free, held = np.ones(n, dtype=bool), np.zeros(n)
    for _ in range(n - m):
        excess = np.maximum(qd - qd_upper, qd_lower - qd)
        excess[~free] = -np.inf
        j = int(np.argmax(excess))
        if excess[j] <= 0:
            break
        free[j] = False
        held[j] = np.clip(qd[j], qd_lower[j], qd_upper[j])
        qd = held.copy()
        qd[free] = np.linalg.lstsq(J[:, free], v - J @ held, rcond=None)[0]
    return qd


def null_space_projector(J: np.ndarray, J_pinv: np.ndarray) -> np.ndarray:
    """I − J† J (n, n): J (I − J†J) q̇₀ = 0 for every q̇₀ (internal motion)."""
    return np.eye(J.shape[1]) - J_pinv @ J


# ---------------------------------------------------------------------- base
class _KinematicController(Controller):
    """Shared task plumbing: task Jacobian, task error and reference velocity from ``obs``.

    Args:
        context: the environment's :class:`TaskContext` (site, task dimension, objective).
        robot: a nominal :class:`Robot` to use instead of ``context.nominal_robot()``.
    """

    tasks = KINEMATIC_TASKS

    def __init__(self, context: TaskContext, gains=None, *, robot: Robot | None = None,
                 **overrides) -> None:
        super().__init__(context, gains, **overrides)
        if context.action_kind != "joint_velocity":
            raise ValueError(f"{self.name} commands joint velocities; the task's action is "
                             f"{context.action_kind!r}")
        self.robot = robot if robot is not None else context.nominal_robot()
        self.n = self.robot.n
        self.site_id = self.robot.site_id(context.site or "ee")
        self.task_dim = int(context.extras.get("task_dim", 2))
        self.pos_dim = 2 if self.task_dim == 2 else 3
        self.objective = str(context.extras.get("objective", "manipulability"))
        if self.objective not in OBJECTIVES:
            raise ValueError(f"objective must be one of {OBJECTIVES}, got {self.objective!r}")

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        """SB3's protocol; a NaN/inf in any observation entry raises ValueError (broken sensor)."""
        for key, value in observation.items():
            if not np.all(np.isfinite(value)):
                raise ValueError(f"{self.name}: observation {key!r} is not finite: {value}")
        return super().predict(observation, state, episode_start, deterministic)

    def task_jacobian(self, q: np.ndarray) -> np.ndarray:
        """Geometric task Jacobian (m, n): [J_P; J_O] (6-D) or the first two rows of J_P."""
        J = self.robot.jacobian(self.site_id, q)
        return J[:2] if self.task_dim == 2 else J

    def task_error(self, obs: Observation) -> np.ndarray:
        """e (m,) = [x̄ − x; θr of R̄ Rᵀ] (m, rad)."""
        e = obs["x_ref"] - obs["x"]
        if self.task_dim == 6:
            e = np.concatenate((e, quat_orientation_error(obs["quat_ref"], obs["quat"])))
        return e

    def reference_velocity(self, obs: Observation) -> np.ndarray:
        """x̄̇ (m,) = [ṗ̄; ω̄] (m/s, rad/s)."""
        if self.task_dim == 6:
            return np.concatenate((obs["xd_ref"], obs["omega_ref"]))
        return obs["xd_ref"]


# ---------------------------------------------------------------------- Jacobian transpose
@dataclass(frozen=True)
class JacobianTransposeGains:
    """K: gain of q̇ = Jᵀ K e (rad s⁻¹ m⁻² on positions; the same number on orientation rows).

    Discrete stability needs K Δt λ_max(J Jᵀ) < 2; λ_max ≲ 2 m² for the planar arm at its
    reach, so K = 60 at Δt = 10 ms keeps K Δt λ_max ≤ 1.2.
    """

    K: float = 60.0

    def __post_init__(self) -> None:
        _positive("K", self.K)


class JacobianTranspose(_KinematicController):
    """Jacobian transpose: q̇ = Jᵀ K e (no inversion, no feed-forward; V = ½ eᵀKe decreases
    for a constant reference, and a moving one leaves an error of order ‖x̄̇‖ / (K σ²))."""

    name = "jacobian_transpose"
    Gains = JacobianTransposeGains

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        J = self.task_jacobian(obs["q"])
        return J.T @ (self.gains.K * self.task_error(obs))


# ---------------------------------------------------------------------- pseudo-inverse
@dataclass(frozen=True)
class PseudoInverseGains:
    """No gain: open-loop q̇ = J† x̄̇ (the error drifts, nothing corrects it)."""


class PseudoInverse(_KinematicController):
    """Open-loop differential inverse kinematics q̇ = J†(q) x̄̇.

    Raises :class:`SingularJacobian` at a singular configuration (σ_min < 1e-9).
    """

    name = "pseudo_inverse"
    Gains = PseudoInverseGains

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        return pseudo_inverse(self.task_jacobian(obs["q"])) @ self.reference_velocity(obs)


# ---------------------------------------------------------------------- CLIK
@dataclass(frozen=True)
class CLIKGains:
    """K (1/s): error dynamics ė + K e = 0 (time constant 1/K). K Δt = 0.5 at 100 Hz."""

    K: float = 50.0

    def __post_init__(self) -> None:
        _positive("K", self.K)


class CLIK(_KinematicController):
    """Closed-loop inverse kinematics q̇ = J†(x̄̇ + K e) (minimum-norm joint velocities).

    Raises :class:`SingularJacobian` at a singular configuration (σ_min < 1e-9); near one,
    J† grows like 1/σ_min and so do the joint speeds (see ``clik_dls``).
    """

    name = "clik"
    Gains = CLIKGains

    def task_velocity(self, obs: Observation) -> np.ndarray:
        """v = x̄̇ + K e (m,)."""
        return self.reference_velocity(obs) + self.gains.K * self.task_error(obs)

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        return pseudo_inverse(self.task_jacobian(obs["q"])) @ self.task_velocity(obs)


# ---------------------------------------------------------------------- damped least squares
@dataclass(frozen=True)
class DampedLeastSquaresGains:
    """K (1/s) as CLIK; damping k_max (task units: m) applied when σ_min(J) < region (m).

    k = k_max sqrt(1 − (σ_min/ε)²) inside σ_min < ε, 0 outside: exact CLIK away from
    singularities, ‖q̇‖ ≤ ‖x̄̇ + K e‖ / (2 k_max) at a singularity.
    """

    K: float = 50.0
    damping: float = 0.05
    region: float = 0.1

    def __post_init__(self) -> None:
        _positive("K", self.K)
        _positive("damping", self.damping)
        _positive("region", self.region)


class DampedLeastSquaresCLIK(CLIK):
    """CLIK with damped least squares: q̇ = J*(x̄̇ + K e), J* = Jᵀ(J Jᵀ + k² I)⁻¹, k variable.

    Attributes:
        last_damping: k (m) of the last call; last_sigma_min: σ_min(J) of the last call.
    """

    name = "clik_dls"
    Gains = DampedLeastSquaresGains

    last_damping: float = 0.0
    last_sigma_min: float = np.inf

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        J = self.task_jacobian(obs["q"])
        sigma = float(np.linalg.svd(J, compute_uv=False)[-1])
        k = variable_damping(sigma, self.gains.damping, self.gains.region)
        self.last_sigma_min, self.last_damping = sigma, k
        return damped_pseudo_inverse(J, k) @ self.task_velocity(obs)


# ---------------------------------------------------------------------- weighted
@dataclass(frozen=True)
class WeightedCLIKGains:
    """K (1/s) as CLIK. W = diag(1/(q_iM − q_im)²) from the observed joint ranges (no gain)."""

    K: float = 50.0

    def __post_init__(self) -> None:
        _positive("K", self.K)


class WeightedCLIK(CLIK):
    """Weighted minimum norm CLIK: q̇ = J_W†(x̄̇ + K e), J_W† = W⁻¹Jᵀ(J W⁻¹ Jᵀ)⁻¹.

    W = diag(1/(q_iM − q_im)²) minimises Σ (q̇_i / range_i)²: a joint with a narrow range
    moves less (scale-free: only ratios of W matter).
    """

    name = "clik_weighted"
    Gains = WeightedCLIKGains

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        w_inv = (obs["q_upper"] - obs["q_lower"]) ** 2  # diag(W⁻¹) (n,)
        J = self.task_jacobian(obs["q"])
        return weighted_pseudo_inverse(J, w_inv) @ self.task_velocity(obs)


# ---------------------------------------------------------------------- null space
@dataclass(frozen=True)
class NullSpaceCLIKGains:
    """Gains of ``clik_nullspace``: K (1/s) as CLIK, and k₀ of q̇₀ = k₀ ∇w for each objective
    (the env's ``objective``).

    - ``k0_manipulability`` (rad² s⁻¹): w = sqrt(det J Jᵀ), ascended along ∇ ln w = ∇w / w
      (the same maximiser, but scale-free: one k₀ serves the 2×3 and the 6×7 Jacobian).
      Chosen by a sweep on the "manipulability" episodes (seeds 0–29, gain in mean minimum w
      over ``clik``): iiwa 6 → +9.5 %, 20 → +19.7 %, 30 → +21 %, 60 → +22.9 % with 1/30
      episodes driven into a joint limit (w peaks near the q2/q6 limits on the iiwa), RMS
      task error +12 % at 20; the plane is insensitive (6 → +49.8 %, 20 → +50.7 %).
    - ``k0_joint_limits`` (rad² s⁻¹): w = −(1/2n) Σ ((q_i − q̄_i)/(q_iM − q_im))².
    - In every objective, a barrier of ``k0_limit_barrier`` (rad/s) times
      (m_act − m_i)₊ / m_i on each joint whose margin m_i to a limit is below
      ``limit_activation`` m_act (rad), pushing away from that limit (the quadratic term
      alone, the textbook's, left 2/30 planar and 3/30 iiwa "joint_limits" episodes at a
      limit; with the barrier 1/30 and 0/30).
    - ``k0_obstacle`` (rad/s per unit ∇d): a barrier on the clearance d (m),
      q̇₀ = k₀ ((d_act − d)₊ / d) ∇d, pushes away within ``activation_distance`` d_act (m)
      and grows without bound as d → 0 (a quadratic penalty (d_act − d)₊ ∇d stays bounded,
      so the task's motion can push the arm into the obstacle).

    ``fd_step`` (rad): central-difference step of the numerical gradients.

    Self-motion search ("manipulability" only; ``search_arc`` = 0 leaves the gradient
    alone): every ``search_period`` control steps the self-motion through the measured q
    (holding its pose) is walked ± ``search_arc`` rad in ``search_step`` rad steps, and the
    most manipulable posture with every joint ≥ ``search_margin`` rad inside its limits, at
    arc length s* (rad), becomes the target: q̇₀ = k_search s* v (v the unit null vector,
    ``k_search`` in 1/s) until the next search, the gradient taking over when the current
    posture is the best (within 2 %). Why: w along the iiwa's self-motion has several local
    maxima (a plateau in the middle of the arc, the best postures 2–3 rad away), and the
    gradient alone stops at the nearest one: on 100 "manipulability" episodes it gained
    +16.6 % over ``clik``, with the search +39.9 % (``search_margin`` 0.2 or 0.3,
    ``k_search`` 2 or 5, a search every 10 or 25 steps: all within 0.1 %). On the plane w is
    unimodal along the self-motion and both reach ≈ +50 %.
    """

    K: float = 50.0
    k0_manipulability: float = 20.0
    k0_joint_limits: float = 10.0
    k0_limit_barrier: float = 1.0
    limit_activation: float = 0.15
    k0_obstacle: float = 5.0
    activation_distance: float = 0.15
    fd_step: float = 1e-6
    search_arc: float = np.pi
    search_step: float = 0.1
    search_margin: float = 0.3
    k_search: float = 5.0
    search_period: int = 10

    def __post_init__(self) -> None:
        for name in ("K", "k0_manipulability", "k0_joint_limits", "k0_limit_barrier",
                     "limit_activation", "k0_obstacle", "activation_distance", "fd_step",
                     "search_step", "search_margin", "k_search"):
            _positive(name, getattr(self, name))
        if not np.isfinite(self.search_arc) or self.search_arc < 0:
            raise InvalidGain(f"search_arc must be a finite number ≥ 0 (0: no search), got "
                              f"{self.search_arc!r}")
        if self.search_period < 1:
            raise InvalidGain(f"search_period must be an integer ≥ 1, got {self.search_period!r}")


class NullSpaceCLIK(CLIK):
    """CLIK with a projected gradient: q̇ = J†(x̄̇ + K e) + s (I − J†J) k₀ ∇w(q), where
    s ∈ [0, 1] (:func:`null_space_scale`) shrinks the secondary motion just enough to keep the
    command within the velocity limits, so the task is not the one that gives way (on
    RedundantIK-v1, 30 seeds: RMS task error 4.5e-4 → 3.5e-5 m with "manipulability"). Not
    with "obstacle", where a collision ends the episode and the clearance barrier must be able
    to override the task (scaled, 9 instead of 5 of 30 planar episodes collided).

    w is the environment's objective (``context.extras["objective"]``): manipulability,
    distance from the joint limits (analytic gradient, ranges from the observation) or
    obstacle clearance (analytic capsule distance of the nominal robot to ``obs["obstacle"]``).
    Numerical gradients by central differences. The projection leaves the task untouched:
    J (I − J†J) = 0. A command that would end the control step within ``LIMIT_GUARD`` of a
    joint limit is saturated in the null space (:func:`saturate_joint_limits`): that joint
    is held and the task re-solved with the others (the limit barrier alone left 5/100
    planar "joint_limits" episodes of v2 at a limit; with it, seeds 0–49: 2 → 0, the two
    episodes finishing with the task error a fixed joint leaves, up to 4.9e-2 m RMS).
    With "manipulability", q̇₀ also comes from a search along the
    self-motion (:meth:`self_motion_search`), which leaves the local maxima of w the gradient
    stops at; its target travels in ``state`` = [steps to the next search, s*, v (n,)].
    """

    name = "clik_nullspace"
    Gains = NullSpaceCLIKGains

    def __init__(self, context: TaskContext, gains=None, *, robot: Robot | None = None,
                 **overrides) -> None:
        super().__init__(context, gains, robot=robot, **overrides)
        self.capsules = LinkCapsules(self.robot.model)
        self._eye = np.eye(self.n)

    # ------------------------------------------------------------------ objectives
    def manipulability(self, q: np.ndarray) -> float:
        return manipulability(self.task_jacobian(q))

    def clearance(self, q: np.ndarray, obstacle: np.ndarray) -> float:
        """Clearance (m) of the nominal robot's capsules to the observed obstacle."""
        self.robot.site_pose(self.site_id, q)  # forward kinematics of the nominal robot
        centre = np.zeros(3)
        centre[: self.pos_dim] = obstacle[: self.pos_dim]
        return self.capsules.clearance(self.robot.data, centre, float(obstacle[-1]))

    def _central_difference(self, f, q: np.ndarray) -> np.ndarray:
        h = self.gains.fd_step
        grad = np.empty(self.n)
        for i in range(self.n):
            dq = h * self._eye[i]
            grad[i] = (f(q + dq) - f(q - dq)) / (2 * h)
        return grad

    def limit_barrier(self, obs: Observation) -> np.ndarray:
        """k0_limit_barrier Σ (m_act − m_i)₊ / m_i away from each near limit (n,), rad/s.

        Active in every objective: a joint-limit violation ends the episode whatever the
        secondary task (pushing away from an obstacle drove 7/30 planar episodes into a limit).
        """
        q, lower, upper, g = obs["q"], obs["q_lower"], obs["q_upper"], self.gains
        m_lo, m_up = q - lower, upper - q
        push = (np.maximum(g.limit_activation - m_lo, 0.0) / np.maximum(m_lo, 1e-3)
                - np.maximum(g.limit_activation - m_up, 0.0) / np.maximum(m_up, 1e-3))
        return g.k0_limit_barrier * push

    def objective_gradient(self, obs: Observation) -> np.ndarray:
        """k₀ ∇w (n,), the preferred joint velocity q̇₀ (rad/s), plus the joint-limit barrier."""
        return self._objective_gradient(obs) + self.limit_barrier(obs)

    def _objective_gradient(self, obs: Observation) -> np.ndarray:
        q, g = obs["q"], self.gains
        if self.objective == "manipulability":
            grad = self._central_difference(self.manipulability, q)
            return g.k0_manipulability * grad / max(self.manipulability(q), 1e-9)
        if self.objective == "joint_limits":
            return g.k0_joint_limits * joint_limit_objective_gradient(
                q, obs["q_lower"], obs["q_upper"])
        obstacle = obs["obstacle"]
        if obstacle[-1] <= 0:
            return np.zeros(self.n)  # no obstacle this episode
        d = self.clearance(q, obstacle)
        if d >= g.activation_distance:
            return np.zeros(self.n)
        push = (g.activation_distance - d) / max(d, 1e-3)  # grows without bound as d → 0
        grad = self._central_difference(lambda x: self.clearance(x, obstacle), q)
        return g.k0_obstacle * push * grad

    @property
    def state_size(self) -> int:
        return 2 + self.n

    def self_motion_search(self, q: np.ndarray, lower: np.ndarray, upper: np.ndarray
                           ) -> tuple[float, np.ndarray]:
        """Arc length s* (rad) to the most manipulable posture of the self-motion through q,
        and the null vector v (n,) whose direction is s > 0.

        The walk holds q's own task pose (one Newton step back to it after each step) and
        goes on through postures closer than ``search_margin`` to a limit only while it moves
        away from that limit; such postures are not targets. s* = 0 when q is a target and no
        posture beats it by ``SEARCH_HYSTERESIS``.
        """
        g = self.gains
        p0, R0 = self.robot.site_pose(self.site_id, q)

        def restore_pose(x: np.ndarray) -> np.ndarray:
            p, R = self.robot.site_pose(self.site_id, x)
            e = (p0 - p)[: self.pos_dim]
            if self.task_dim == 6:
                e = np.concatenate((e, orientation_error(R0, R)))
            return x + pseudo_inverse(jacobian(x)) @ e

        # J and the limit margin of a posture, computed once per search: the walk takes J at
        # each posture it reaches (for the null vector) and the margin of each in its stop
        # test, and the search asks for both again (the same bytes give the same numbers)
        jacobians: dict[bytes, np.ndarray] = {}
        margins: dict[bytes, float] = {}

        def jacobian(x: np.ndarray) -> np.ndarray:
            key = x.tobytes()
            J = jacobians.get(key)
            if J is None:
                J = jacobians[key] = self.task_jacobian(x)
            return J

        def margin(x: np.ndarray) -> float:
            key = x.tobytes()
            m = margins.get(key)
            if m is None:
                m = margins[key] = joint_limit_margin(x, lower, upper)
            return m

        def stop(x: np.ndarray, x_next: np.ndarray) -> bool:
            return margin(x_next) < min(g.search_margin, margin(x))

        w_here = manipulability(jacobian(q)) if margin(q) >= g.search_margin else -np.inf
        best, s_best = w_here, 0.0
        for s, x in walk_self_motion(q, jacobian, restore_pose, stop,
                                     g.search_arc, g.search_step):
            if margin(x) >= g.search_margin and (w := manipulability(jacobian(x))) > best:
                best, s_best = w, s
        if np.isfinite(w_here) and best < (1 + SEARCH_HYSTERESIS) * w_here:
            s_best = 0.0
        return s_best, null_vector(jacobian(q))

    def preferred_velocity(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """q̇₀ (n,), rad/s: the objective's gradient, or the pull k_search s* v towards the
        self-motion search's target; plus the joint-limit barrier."""
        g = self.gains
        if self.objective != "manipulability" or g.search_arc == 0:
            return self.objective_gradient(obs)
        q = obs["q"]
        if state[0] <= 0:
            state[1], state[2:] = self.self_motion_search(q, obs["q_lower"], obs["q_upper"])
            state[0] = g.search_period
        state[0] -= 1
        v = null_vector(self.task_jacobian(q))
        state[2:] = v if v @ state[2:] >= 0 else -v  # the same direction as the search's
        if state[1] == 0:
            return self.objective_gradient(obs)
        return g.k_search * state[1] * state[2:] + self.limit_barrier(obs)

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        qd0 = self.preferred_velocity(obs, state)
        J = self.task_jacobian(obs["q"])
        J_pinv = pseudo_inverse(J)
        qd_task = J_pinv @ self.task_velocity(obs)
        qd_null = null_space_projector(J, J_pinv) @ qd0
        if self.objective != "obstacle":  # a collision ends the episode: the barrier may win
            qd_null = null_space_scale(qd_task, qd_null, self.context.action_scale) * qd_null
        # the joint limits are hard: a joint that would end the step within LIMIT_GUARD of one
        # is held short of it and the task re-solved with the others
        q, dt = obs["q"], self.context.dt
        return saturate_joint_limits(J, self.task_velocity(obs), qd_task + qd_null,
                                     (obs["q_lower"] + LIMIT_GUARD - q) / dt,
                                     (obs["q_upper"] - LIMIT_GUARD - q) / dt)


# ---------------------------------------------------------------------- textbook null space
@dataclass(frozen=True)
class ProjectedGradientGains:
    """Gains of ``clik_projected_gradient``: K (1/s) as CLIK, and k₀ of the projected
    gradient q̇₀ = k₀ ∇w for each objective.

    - ``k0_manipulability`` (rad² s⁻¹ per unit of w, m² on the plane): w = sqrt(det J Jᵀ)
      (∇w itself, not ∇ ln w: its size follows w's units, so one k₀ means more on the plane,
      where w ≈ 0.1–0.3 m², than on the iiwa, where the 6×7 w ≈ 0.02–0.1). A sweep on the
      "manipulability" episodes, seeds 0–4 (mean minimum w against ``clik``'s, RMS task
      error): plane 30 → +50.5 %, 3.8e-4 m (clik 3.2e-5 m); 100 → +50.8 %, 6.9e-3 m (the
      unscaled null-space motion runs into the velocity limits, whose clipping bends the
      task); iiwa 30 → +0.0 %, 100 → +3.6 %, 300 → +12.9 % at 2.6e-3 m, 1000 → +16.5 % at
      8.6e-3 m. No single k₀ serves both robots: 30 keeps the task on both.
    - ``k0_joint_limits`` (rad² s⁻¹): w = −(1/2n) Σ ((q_i − q̄_i)/(q_iM − q_im))² (as
      ``clik_nullspace``'s, which is already the textbook term).
    - ``k0_obstacle`` (rad/s per unit ∇d): w = d, the clearance (m) to the obstacle, ascended
      everywhere (the textbook's distance objective: no activation distance, no barrier).

    ``fd_step`` (rad): central-difference step of the numerical gradients.
    """

    K: float = 50.0
    k0_manipulability: float = 30.0
    k0_joint_limits: float = 10.0
    k0_obstacle: float = 5.0
    fd_step: float = 1e-6

    def __post_init__(self) -> None:
        for name in ("K", "k0_manipulability", "k0_joint_limits", "k0_obstacle", "fd_step"):
            _positive(name, getattr(self, name))


class ProjectedGradientCLIK(NullSpaceCLIK):
    """The textbook null-space law of the course: q̇ = J†(x̄̇ + K e) + (I − J†J) k₀ ∇w(q).

    Nothing else: no logarithm of w, no joint-limit barrier, no scaling of the null-space
    motion to the velocity limits, no saturation in the null space at the joint limits, no
    self-motion search (``clik_nullspace`` adds all of them; this law is the baseline they
    are measured against). w is the environment's objective as in ``clik_nullspace``;
    numerical gradients by central differences. Raises :class:`SingularJacobian` as ``clik``.
    """

    name = "clik_projected_gradient"
    Gains = ProjectedGradientGains

    @property
    def state_size(self) -> int:
        return 0

    def objective_gradient(self, obs: Observation) -> np.ndarray:
        """q̇₀ = k₀ ∇w (n,), rad/s."""
        q, g = obs["q"], self.gains
        if self.objective == "manipulability":
            return g.k0_manipulability * self._central_difference(self.manipulability, q)
        if self.objective == "joint_limits":
            return g.k0_joint_limits * joint_limit_objective_gradient(
                q, obs["q_lower"], obs["q_upper"])
        obstacle = obs["obstacle"]
        if obstacle[-1] <= 0:
            return np.zeros(self.n)  # no obstacle
        return g.k0_obstacle * self._central_difference(
            lambda x: self.clearance(x, obstacle), q)

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        J = self.task_jacobian(obs["q"])
        J_pinv = pseudo_inverse(J)
        return (J_pinv @ self.task_velocity(obs)
                + null_space_projector(J, J_pinv) @ self.objective_gradient(obs))


# ---------------------------------------------------------------------- augmented Jacobian
@dataclass(frozen=True)
class AugmentedJacobianGains:
    """K (1/s) on the task and on the constraint y = cᵀq; near an algorithmic singularity
    (σ_min(J_aug) < region) the inverse is damped with k_max = damping (as ``clik_dls``)."""

    K: float = 50.0
    damping: float = 0.05
    region: float = 0.05

    def __post_init__(self) -> None:
        _positive("K", self.K)
        _positive("damping", self.damping)
        _positive("region", self.region)


class AugmentedJacobianCLIK(CLIK):
    """Augmented Jacobian: q̇ = J_aug⁻¹ [x̄̇ + K e; K (y₀ − cᵀq)], J_aug = [J; cᵀ] (n, n).

    The constraint task y = cᵀq is held at its value y₀ at the start of the episode
    (kept in ``state``): on the plane c = (1, 1, 1), the absolute angle of the last link
    (the end effector's orientation, making the arm non-redundant); on the iiwa c = e₃, the
    redundant joint 3 locked. J_aug is square, so its inverse adds *algorithmic*
    singularities where J has full rank but cᵀ is a combination of J's rows (e.g. the
    planar wrist point stretched). σ_min(J_aug) is reported in ``state[1]`` and
    ``last_sigma_min``; below ``region`` the inverse is damped (never NaN, the task degrades)
    and ``singular_steps`` counts such steps.
    """

    name = "clik_augmented"
    Gains = AugmentedJacobianGains

    def __init__(self, context: TaskContext, gains=None, *, robot: Robot | None = None,
                 **overrides) -> None:
        super().__init__(context, gains, robot=robot, **overrides)
        self.c = np.ones(self.n) if self.task_dim == 2 else np.eye(self.n)[2]  # (n,)
        self.last_sigma_min = np.inf
        self.singular_steps = 0

    @property
    def state_size(self) -> int:
        return 2  # y₀ (rad), σ_min(J_aug) of the last step

    def initial_state(self, obs: Observation) -> np.ndarray:
        return np.array([float(self.c @ obs["q"]), np.inf])

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        q = obs["q"]
        J_aug = np.vstack((self.task_jacobian(q), self.c))
        v_aug = np.append(self.task_velocity(obs), self.gains.K * (state[0] - self.c @ q))
        sigma = float(np.linalg.svd(J_aug, compute_uv=False)[-1])
        state[1] = self.last_sigma_min = sigma
        if sigma < self.gains.region:
            self.singular_steps += 1
            k = variable_damping(sigma, self.gains.damping, self.gains.region)
            return damped_pseudo_inverse(J_aug, k) @ v_aug
        return np.linalg.solve(J_aug, v_aug)


KINEMATIC_CONTROLLERS: tuple[type[Controller], ...] = (
    JacobianTranspose,
    PseudoInverse,
    CLIK,
    DampedLeastSquaresCLIK,
    WeightedCLIK,
    NullSpaceCLIK,
    ProjectedGradientCLIK,
    AugmentedJacobianCLIK,
)
