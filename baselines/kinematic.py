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
from cir_gym.baselines.base import (
    Controller,
    InvalidGain,
    Observation,
    RowLaw,
    matvec,
    rows_method,
    transpose,
)

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
    walk_self_motions,
)
from cir_gym.robot import Robot
from cir_gym.self_motion import RowKinematics, RowPoses

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
# Every function takes one matrix (m, n) or rows of them (N, m, n) (numpy's stacked linear
# algebra: one LAPACK call per row's matrices, so a row gives the same numbers alone or in a
# batch); the laws run on rows (``RowLaw``), one observation being a row of one.
def pseudo_inverse(J: np.ndarray) -> np.ndarray:
    """Right pseudo-inverse J† = Jᵀ(J Jᵀ)⁻¹ (n, m) of a full-row-rank J (m, n) (or of each of
    rows (N, m, n)).

    Raises:
        SingularJacobian: σ_min(J) < ``SINGULAR_TOLERANCE`` (J Jᵀ not invertible), in any row.
    """
    sigma = np.linalg.svd(J, compute_uv=False)
    smallest = float(np.min(sigma[..., -1]))
    if smallest < SINGULAR_TOLERANCE:
        raise SingularJacobian(
            f"the Jacobian is singular (smallest singular value {smallest:.2e}); "
            f"use clik_dls near singular configurations"
        )
    return transpose(np.linalg.solve(J @ transpose(J), J))


def weighted_pseudo_inverse(J: np.ndarray, w_inv: np.ndarray) -> np.ndarray:
    """J_W† = W⁻¹Jᵀ(J W⁻¹ Jᵀ)⁻¹ (n, m) for a diagonal weight, ``w_inv`` = diag(W⁻¹) (n,) (rows:
    J (N, m, n), ``w_inv`` (N, n))."""
    w = np.asarray(w_inv)[..., None, :]
    sigma = np.linalg.svd(J * np.sqrt(w), compute_uv=False)
    smallest = float(np.min(sigma[..., -1]))
    if smallest < SINGULAR_TOLERANCE:
        raise SingularJacobian(f"J W^-1/2 is singular (smallest singular value {smallest:.2e})")
    JW = J * w  # J W⁻¹ (m, n)
    return transpose(np.linalg.solve(JW @ transpose(J), JW))


def damped_pseudo_inverse(J: np.ndarray, damping: float | np.ndarray) -> np.ndarray:
    """Damped least squares J* = Jᵀ(J Jᵀ + k² I)⁻¹ (n, m), k = ``damping`` ≥ 0 (rows: J
    (N, m, n), k (N,) or a number).

    ‖J* v‖ ≤ ‖v‖ / (2k) for k > 0: bounded at any configuration.
    """
    m = J.shape[-2]
    k2 = np.asarray(damping, dtype=float)[..., None, None] ** 2
    return transpose(np.linalg.solve(J @ transpose(J) + k2 * np.eye(m), J))


def variable_damping(sigma_min: float | np.ndarray, damping: float, region: float
                     ) -> float | np.ndarray:
    """k(σ) = k_max sqrt(1 − (σ/ε)²) inside the singular region σ < ε, else 0 (a number, or
    (N,) for rows of σ_min).

    (Maciejewski & Klein's damping: exact least squares away from singularities, the full
    damping k_max at σ = 0, continuous in between.)
    """
    sigma = np.asarray(sigma_min, dtype=float)
    inside = np.sqrt(np.maximum(1.0 - (sigma / region) ** 2, 0.0))
    k = np.where(sigma >= region, 0.0, damping * inside)
    return float(k) if k.ndim == 0 else k


def null_space_scales(qd_task: np.ndarray, qd_null: np.ndarray, qd_max: np.ndarray
                      ) -> np.ndarray:
    """:func:`null_space_scale` of rows (N, n): s (N,), all joints at once (a minimum, so
    the order does not matter)."""
    scaled = (np.abs(qd_task + qd_null) > qd_max) & (qd_null != 0.0)  # joints that limit s
    blocked = np.any(scaled & (np.abs(qd_task) >= qd_max), axis=1)  # q̇_task alone exceeds
    bound = np.where(qd_null > 0, qd_max, -qd_max) - qd_task
    ratio = np.divide(bound, qd_null, out=np.full(qd_task.shape, np.inf), where=scaled)
    s = np.minimum(ratio.min(axis=1), 1.0)
    return np.where(blocked, 0.0, np.maximum(s, 0.0))


def null_space_scale(qd_task: np.ndarray, qd_null: np.ndarray, qd_max: np.ndarray) -> float:
    """Largest s ∈ [0, 1] with |q̇_task + s q̇_null| ≤ q̇_max on every joint (task priority).

    The environment clips each joint's command to its velocity limit, which bends a command
    that exceeds it away from the task; scaling the null-space part first keeps the primary
    task (the saturation-in-the-null-space idea of Flacco, De Luca and Khatib, ICRA 2012, in its
    simplest form). If q̇_task alone exceeds a limit, s = 0 and the env clips as before.
    """
    return float(null_space_scales(qd_task[None], qd_null[None], qd_max)[0])


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


def saturate_rows(J: np.ndarray, v: np.ndarray, qd: np.ndarray, qd_lower: np.ndarray,
                  qd_upper: np.ndarray) -> np.ndarray:
    """:func:`saturate_joint_limits` of rows (N, ...) (qd (N, n) updated in place): only the
    rows with a joint out of its bounds are re-solved, one by one."""
    out = np.flatnonzero(np.any((qd < qd_lower) | (qd > qd_upper), axis=1))
    for i in out:
        qd[i] = saturate_joint_limits(J[i], v[i], qd[i], qd_lower[i], qd_upper[i])
    return qd


def null_space_projector(J: np.ndarray, J_pinv: np.ndarray) -> np.ndarray:
    """I − J† J (n, n) (or rows): J (I − J†J) q̇₀ = 0 for every q̇₀ (internal motion)."""
    return np.eye(J.shape[-1]) - J_pinv @ J


# ---------------------------------------------------------------------- base
class _KinematicController(RowLaw):
    """Shared task plumbing on rows: the nominal robot's kinematics at rows of q (MuJoCo's
    batched kinematics, :class:`cir_gym.self_motion.RowKinematics`), task Jacobians, task
    errors and reference velocities from ``obs``. The laws are written once on rows
    (:meth:`control_rows`); one observation is a row of one, so a row's command is the same
    alone or in a batch.

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
        self.capsules = LinkCapsules(self.robot.model)
        self._eye = np.eye(self.n)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state.pop("_kinematics", None)  # a mujoco.batch.Batch: made again at first use
        return state

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        """SB3's protocol; a NaN/inf in any observation entry raises ValueError (broken sensor)."""
        for key, value in observation.items():
            if not np.all(np.isfinite(value)):
                raise ValueError(f"{self.name}: observation {key!r} is not finite: {value}")
        return super().predict(observation, state, episode_start, deterministic)

    def kinematics(self, q: np.ndarray) -> RowPoses:
        """The nominal robot's site pose, Jacobians and capsule poses at rows q (N, n)."""
        cached = self.__dict__.get("_kinematics")
        if cached is None or cached[0] is not self.robot:
            rows = RowKinematics(self.robot.model, self.robot, self.site_id,
                                 self.capsules.geom_ids)
            cached = self._kinematics = (self.robot, rows)
        return cached[1].evaluate(q)

    def task_jacobians(self, q: np.ndarray) -> np.ndarray:
        """Geometric task Jacobians (N, m, n) at rows q (N, n) (:meth:`jacobians_of` their
        :meth:`kinematics`)."""
        return self.jacobians_of(self.kinematics(q))

    def jacobians_of(self, rows: RowPoses) -> np.ndarray:
        """Geometric task Jacobians (N, m, n) of evaluated kinematics: [J_P; J_O] or J_P's
        first two rows."""
        if self.task_dim == 6:
            return np.concatenate((rows.jacp, rows.jacr), axis=1)
        return rows.jacp[:, :2]

    def task_jacobian(self, q: np.ndarray) -> np.ndarray:
        """Geometric task Jacobian (m, n) at one q (n,)."""
        return self.task_jacobians(np.asarray(q, dtype=float)[None])[0]

    @rows_method
    def task_error(self, obs: Observation) -> np.ndarray:
        """e (N, m) = [x̄ − x; θr of R̄ Rᵀ] (m, rad)."""
        e = obs["x_ref"] - obs["x"]
        if self.task_dim == 6:
            rot = [quat_orientation_error(r, q) for r, q in zip(obs["quat_ref"], obs["quat"],
                                                                strict=True)]
            e = np.concatenate((e, np.reshape(rot, (-1, 3))), axis=1)
        return e

    @rows_method
    def reference_velocity(self, obs: Observation) -> np.ndarray:
        """x̄̇ (N, m) = [ṗ̄; ω̄] (m/s, rad/s)."""
        if self.task_dim == 6:
            return np.concatenate((obs["xd_ref"], obs["omega_ref"]), axis=1)
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

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        J = self.task_jacobians(obs["q"])
        return matvec(transpose(J), self.gains.K * self.task_error(obs))


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

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        return matvec(pseudo_inverse(self.task_jacobians(obs["q"])), self.reference_velocity(obs))


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

    @rows_method
    def task_velocity(self, obs: Observation) -> np.ndarray:
        """v = x̄̇ + K e (N, m)."""
        return self.reference_velocity(obs) + self.gains.K * self.task_error(obs)

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        return matvec(pseudo_inverse(self.task_jacobians(obs["q"])), self.task_velocity(obs))


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
        last_damping: k (m) of the last row of the last call (of its batch; the only row
            when one observation was predicted); last_sigma_min: σ_min(J) of that row.
    """

    name = "clik_dls"
    Gains = DampedLeastSquaresGains

    last_damping: float = 0.0
    last_sigma_min: float = np.inf

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        J = self.task_jacobians(obs["q"])
        sigma = np.linalg.svd(J, compute_uv=False)[:, -1]
        k = variable_damping(sigma, self.gains.damping, self.gains.region)
        self.last_sigma_min, self.last_damping = float(sigma[-1]), float(k[-1])
        return matvec(damped_pseudo_inverse(J, k), self.task_velocity(obs))


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

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        w_inv = (obs["q_upper"] - obs["q_lower"]) ** 2  # diag(W⁻¹) (N, n)
        J = self.task_jacobians(obs["q"])
        return matvec(weighted_pseudo_inverse(J, w_inv), self.task_velocity(obs))


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

    # ------------------------------------------------------------------ objectives
    def manipulability(self, q: np.ndarray) -> float:
        """w = sqrt(det J Jᵀ) of the nominal robot at one q (n,)."""
        return float(manipulability(self.task_jacobians(np.asarray(q, dtype=float)[None]))[0])

    def clearance(self, q: np.ndarray, obstacle: np.ndarray) -> float:
        """Clearance (m) of the nominal robot's capsules at one q (n,) to the observed
        obstacle."""
        return float(self.clearances(np.asarray(q, dtype=float)[None],
                                     np.asarray(obstacle, dtype=float)[None])[0])

    def clearances(self, q: np.ndarray, obstacle: np.ndarray) -> np.ndarray:
        """Clearances (N,) m of the nominal robot's capsules at rows q (N, n) to the observed
        obstacles (N, p + 1) (centre, radius)."""
        rows = self.kinematics(q)
        centre = np.zeros((len(q), 1, 3))
        centre[:, 0, : self.pos_dim] = obstacle[:, : self.pos_dim]
        a, b = self.capsules.ends(rows.geom_xpos, rows.geom_xmat)
        return self.capsules.segment_clearance(a, b, centre, obstacle[:, -1])

    def _central_difference(self, f, q: np.ndarray, *args: np.ndarray) -> np.ndarray:
        """∇f (N, n) of a function of rows f(q (M, n), *args (M, ...)) → (M,) at rows q (N, n):
        (f(q + h e_i) − f(q − h e_i)) / 2h, every row and joint in one call of f."""
        h, (N, n) = self.gains.fd_step, q.shape
        dq = h * self._eye  # (n, n)
        points = np.concatenate((q[:, None] + dq, q[:, None] - dq), axis=1)  # (N, 2n, n)
        values = f(points.reshape(-1, n), *(np.repeat(a, 2 * n, axis=0) for a in args))
        values = values.reshape(N, 2, n)
        return (values[:, 0] - values[:, 1]) / (2 * h)

    def _manipulabilities(self, q: np.ndarray) -> np.ndarray:
        return manipulability(self.task_jacobians(q))

    @rows_method
    def limit_barrier(self, obs: Observation) -> np.ndarray:
        """k0_limit_barrier Σ (m_act − m_i)₊ / m_i away from each near limit (N, n), rad/s.

        Active in every objective: a joint-limit violation ends the episode whatever the
        secondary task (pushing away from an obstacle drove 7/30 planar episodes into a limit).
        """
        q, lower, upper, g = obs["q"], obs["q_lower"], obs["q_upper"], self.gains
        m_lo, m_up = q - lower, upper - q
        push = (np.maximum(g.limit_activation - m_lo, 0.0) / np.maximum(m_lo, 1e-3)
                - np.maximum(g.limit_activation - m_up, 0.0) / np.maximum(m_up, 1e-3))
        return g.k0_limit_barrier * push

    @rows_method
    def objective_gradient(self, obs: Observation) -> np.ndarray:
        """k₀ ∇w (N, n), the preferred joint velocity q̇₀ (rad/s), plus the joint-limit
        barrier."""
        return self._objective_gradient(obs) + self.limit_barrier(obs)

    def _objective_gradient(self, obs: Observation) -> np.ndarray:
        q, g = obs["q"], self.gains
        if self.objective == "manipulability":
            grad = self._central_difference(self._manipulabilities, q)
            return g.k0_manipulability * grad / np.maximum(self._manipulabilities(q), 1e-9)[:, None]
        if self.objective == "joint_limits":
            return g.k0_joint_limits * joint_limit_objective_gradient(
                q, obs["q_lower"], obs["q_upper"])
        out = np.zeros(q.shape)
        obstacle = obs["obstacle"]
        near = np.flatnonzero(obstacle[:, -1] > 0)  # rows with an obstacle this episode
        if near.size:
            d = self.clearances(q[near], obstacle[near])
            near, d = near[d < g.activation_distance], d[d < g.activation_distance]
        if near.size:
            push = (g.activation_distance - d) / np.maximum(d, 1e-3)  # unbounded as d → 0
            grad = self._central_difference(self.clearances, q[near], obstacle[near])
            out[near] = g.k0_obstacle * push[:, None] * grad
        return out

    @property
    def state_size(self) -> int:
        return 2 + self.n

    def self_motion_search(self, q: np.ndarray, lower: np.ndarray, upper: np.ndarray
                           ) -> tuple[float, np.ndarray]:
        """:meth:`self_motion_searches` of one q (n,): (s*, v (n,))."""
        s, v = self.self_motion_searches(*(np.asarray(x, dtype=float)[None]
                                           for x in (q, lower, upper)))
        return float(s[0]), v[0]

    def self_motion_searches(self, q: np.ndarray, lower: np.ndarray, upper: np.ndarray
                             ) -> tuple[np.ndarray, np.ndarray]:
        """Arc lengths s* (N,) rad to the most manipulable posture of the self-motion through
        each row of q (N, n), and the null vectors v (N, n) whose direction is s > 0.

        Each row's walk (:func:`cir_gym.redundancy.walk_self_motions`, all rows at once) holds
        its q's task pose (one Newton step back to it after each step) and goes on through
        postures closer than ``search_margin`` to a limit only while it moves away from that
        limit; such postures are not targets. s* = 0 when q is a target and no posture beats
        it by ``SEARCH_HYSTERESIS``.
        """
        g = self.gains
        home = self.kinematics(q)
        J0 = self.jacobians_of(home)
        w_here = np.where(joint_limit_margin(q, lower, upper) >= g.search_margin,
                          manipulability(J0), -np.inf)
        best, s_best = w_here.copy(), np.zeros(len(q))

        def margin(rows: np.ndarray, x: np.ndarray) -> np.ndarray:
            return joint_limit_margin(x, lower[rows], upper[rows])

        def stop(rows: np.ndarray, x: np.ndarray, x_next: np.ndarray) -> np.ndarray:
            """x_next within search_margin of a limit, and nearer to it than x."""
            return margin(rows, x_next) < np.minimum(g.search_margin, margin(rows, x))

        for s, rows, x, J in walk_self_motions(
            q, self.task_jacobians, lambda x, rows: self._restore_pose(x, home, rows), stop,
            g.search_arc, g.search_step,
        ):
            w = manipulability(J)
            better = (margin(rows, x) >= g.search_margin) & (w > best[rows])
            best[rows[better]] = w[better]
            s_best[rows[better]] = s
        s_best[np.isfinite(w_here) & (best < (1 + SEARCH_HYSTERESIS) * w_here)] = 0.0
        return s_best, null_vector(J0)

    def _restore_pose(self, x: np.ndarray, home: RowPoses, which: np.ndarray) -> np.ndarray:
        """One Newton step x + J†(x)(k(q) − k(x)) of rows x (M, n) back to the task poses of
        the rows ``which`` (M,) of ``home``."""
        rows = self.kinematics(x)
        e = (home.p[which] - rows.p)[:, : self.pos_dim]
        if self.task_dim == 6:
            rot = [orientation_error(R0.reshape(3, 3), R.reshape(3, 3))
                   for R0, R in zip(home.R[which], rows.R, strict=True)]
            e = np.concatenate((e, np.reshape(rot, (-1, 3))), axis=1)
        return x + matvec(pseudo_inverse(self.jacobians_of(rows)), e)

    def preferred_velocity(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """q̇₀ (N, n), rad/s: the objective's gradient, or the pull k_search s* v towards the
        self-motion search's target; plus the joint-limit barrier."""
        g = self.gains
        if self.objective != "manipulability" or g.search_arc == 0:
            return self.objective_gradient(obs)
        q = obs["q"]
        due = np.flatnonzero(state[:, 0] <= 0)
        if due.size:
            state[due, 1], state[due, 2:] = self.self_motion_searches(
                q[due], obs["q_lower"][due], obs["q_upper"][due])
            state[due, 0] = g.search_period
        state[:, 0] -= 1
        v = null_vector(self.task_jacobians(q))
        # the same direction as the search's
        state[:, 2:] = np.where((v * state[:, 2:]).sum(axis=1)[:, None] >= 0, v, -v)
        qd0 = g.k_search * state[:, 1:2] * state[:, 2:] + self.limit_barrier(obs)
        local = state[:, 1] == 0
        if local.any():
            qd0[local] = self.objective_gradient({k: v[local] for k, v in obs.items()})
        return qd0

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        qd0 = self.preferred_velocity(obs, state)
        J = self.task_jacobians(obs["q"])
        J_pinv = pseudo_inverse(J)
        v = self.task_velocity(obs)
        qd_task = matvec(J_pinv, v)
        qd_null = matvec(null_space_projector(J, J_pinv), qd0)
        if self.objective != "obstacle":  # a collision ends the episode: the barrier may win
            scale = null_space_scales(qd_task, qd_null, self.context.action_scale)
            qd_null = scale[:, None] * qd_null
        # the joint limits are hard: a joint that would end the step within LIMIT_GUARD of one
        # is held short of it and the task re-solved with the others
        q, dt = obs["q"], self.context.dt
        return saturate_rows(J, v, qd_task + qd_null, (obs["q_lower"] + LIMIT_GUARD - q) / dt,
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

    @rows_method
    def objective_gradient(self, obs: Observation) -> np.ndarray:
        """q̇₀ = k₀ ∇w (N, n), rad/s."""
        q, g = obs["q"], self.gains
        if self.objective == "manipulability":
            return g.k0_manipulability * self._central_difference(self._manipulabilities, q)
        if self.objective == "joint_limits":
            return g.k0_joint_limits * joint_limit_objective_gradient(
                q, obs["q_lower"], obs["q_upper"])
        out = np.zeros(q.shape)
        obstacle = obs["obstacle"]
        near = np.flatnonzero(obstacle[:, -1] > 0)  # rows with an obstacle
        if near.size:
            out[near] = g.k0_obstacle * self._central_difference(
                self.clearances, q[near], obstacle[near])
        return out

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        J = self.task_jacobians(obs["q"])
        J_pinv = pseudo_inverse(J)
        return (matvec(J_pinv, self.task_velocity(obs))
                + matvec(null_space_projector(J, J_pinv), self.objective_gradient(obs)))


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
    planar wrist point stretched). σ_min(J_aug) is reported in ``state[1]`` of each row and
    in ``last_sigma_min`` (the last row of the last call's batch; the only row when one
    observation was predicted); below ``region`` the inverse is damped (never NaN, the task
    degrades) and ``singular_steps`` counts such steps (of every row).
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

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        q = obs["q"]
        J = self.task_jacobians(q)
        J_aug = np.concatenate((J, np.broadcast_to(self.c, (len(q), 1, self.n))), axis=1)
        y = (q * self.c).sum(axis=1)  # cᵀq (N,)
        hold = self.gains.K * (state[:, 0] - y)  # K (y₀ − cᵀq) (N,)
        v_aug = np.concatenate((self.task_velocity(obs), hold[:, None]), axis=1)
        sigma = np.linalg.svd(J_aug, compute_uv=False)[:, -1]
        state[:, 1] = sigma
        self.last_sigma_min = float(sigma[-1])
        singular = sigma < self.gains.region
        qd = np.empty_like(q)
        if singular.any():
            self.singular_steps += int(singular.sum())
            k = variable_damping(sigma[singular], self.gains.damping, self.gains.region)
            qd[singular] = matvec(damped_pseudo_inverse(J_aug[singular], k), v_aug[singular])
        if not singular.all():
            qd[~singular] = np.linalg.solve(J_aug[~singular], v_aug[~singular][..., None])[..., 0]
        return qd


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
