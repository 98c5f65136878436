"""Chapter 5.2, operational space: PD + gravity, inverse dynamics (plain and damped least
squares) and Khatib's operational-space formulation, for the redundant iiwa.

Every law uses the controller's nominal :class:`~cir_gym.robot.Robot` at the *measured* state
and the pose error of :func:`cir_gym.operational_space.pose_error_kinematics`:
x̃ = [p̄ − p; φ] with φ = log(R̄ Rᵀ) the orientation error in axis-angle form (valid on all of
SO(3)), its analytic Jacobian J_A = [J_P; J_r⁻¹(φ) J_O] and J̇_A q̇, so that
x̃̇ = ẋ̄_A − J_A q̇ and x̃̈ = ẍ̄_A − J̇_A q̇ − J_A q̈ exactly.

Gains follow the course: the error dynamics x̃̈ + K_D x̃̇ + K_P x̃ = 0 with natural frequency
ω_n and damping ζ give K_P = ω_n² I, K_D = 2ζω_n I (position and orientation alike).

**Redundancy** (7 joints, 6 task coordinates: one self-motion). The task leaves the arm free
to move along ker J_A; left alone that self-motion drifts. Each law adds a joint-space posture
term toward the posture q₀ measured at the start of the episode (held in the controller's
state), y₀ = K_P,0 (q₀ − q) − K_D,0 q̇ with K_P,0 = ω_0², K_D,0 = 2ζ_0 ω_0, projected so that
it cannot disturb the task: through I − J_A⁺J_A on accelerations (inverse dynamics) or
through the dynamically consistent N_dynᵀ on torques (Khatib). PD + gravity damps the
self-motion with a joint damping instead (it has no acceleration-level projector).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from cir_gym.baselines.base import (
    InvalidGain,
    Observation,
    RowLaw,
    SiteTerms,
    matvec,
    rows_method,
)

from cir_gym import operational_space as osp
from cir_gym.context import TaskContext
from cir_gym.robot import Robot

__all__ = [
    "OPERATIONAL_SPACE_CONTROLLERS",
    "OSInverseDynamics",
    "OSInverseDynamicsDLS",
    "OSKhatib",
    "OSPDGravity",
]

TASKS = ("CartesianTracking",)


def _check_positive(gains: object, *names: str, allow_zero: tuple[str, ...] = ()) -> None:
    for name in names:
        value = getattr(gains, name)
        zero_ok = name in allow_zero
        if not np.isfinite(value) or value < 0 or (value == 0 and not zero_ok):
            bound = ">= 0" if zero_ok else "> 0"
            raise InvalidGain(f"{name} must be a finite number {bound}, got {value!r}")


def _transpose(A: np.ndarray) -> np.ndarray:
    """Aᵀ of rows of matrices (N, m, k) → (N, k, m)."""
    return np.swapaxes(A, -1, -2)


class _OperationalSpace(RowLaw):
    """Shared plumbing: the nominal robot, the site, the posture target q₀ in the state.

    Each law is written once on rows of observations (:meth:`control_rows`, values (N, ...)):
    the model calls row by row (:meth:`Controller.model_rows`), the arithmetic on all rows.
    """

    tasks = TASKS

    def __init__(self, context: TaskContext, gains=None, *, robot: Robot | None = None,
                 **overrides) -> None:
        super().__init__(context, gains, **overrides)
        self.robot = robot if robot is not None else context.nominal_robot()
        self.n = self.robot.n
        self.site = context.site or "flange"
        self.site_id = self.robot.site_id(self.site)

    @property
    def state_size(self) -> int:
        return self.n  # the posture target q₀

    def initial_state(self, obs: Observation) -> np.ndarray:
        return np.array(obs["q"], dtype=float)

    def site_terms(self, obs: Observation, *, dynamics: bool = False) -> SiteTerms:
        """The nominal model's site terms at rows of measured states (B̂, n̂ with
        ``dynamics``)."""
        return self.model_rows().site_terms(
            self.site_id, obs["q"], obs["qd"], inertia=dynamics, bias=dynamics
        )

    def pose_error(self, obs: Observation, terms: SiteTerms) -> osp.PoseErrorKinematics:
        """The pose error, J_A and J̇_A q̇ of rows from their site terms."""
        return osp.pose_error_from_kinematics(
            terms.x, terms.quat, terms.J, terms.jdqd, obs["qd"], obs["x_ref"], obs["quat_ref"],
            obs["twist_ref"], obs["acc_ref"],
        )

    @rows_method
    def kinematics(self, obs: Observation) -> osp.PoseErrorKinematics:
        """The pose error, J_A and J̇_A q̇ of the nominal model at the measured state (one
        observation, or rows)."""
        return self.pose_error(obs, self.site_terms(obs))

    def task_command(self, kin: osp.PoseErrorKinematics) -> np.ndarray:
        """ẍ̄_A + K_D x̃̇ + K_P x̃ − J̇_A q̇ (N, 6): the J_A q̈ that gives the error dynamics."""
        g = self.gains
        kp, kd = g.omega_n**2, 2.0 * g.zeta * g.omega_n
        return kin.task_acceleration + kd * kin.error_rate + kp * kin.error

    def posture_acceleration(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """y₀ = ω_0² (q₀ − q) − 2ζ_0ω_0 q̇ (N, n), rad/s²."""
        g = self.gains
        w0 = g.posture_omega
        return w0**2 * (state - obs["q"]) - 2.0 * g.posture_zeta * w0 * obs["qd"]


# ---------------------------------------------------------------------- PD + gravity
@dataclass(frozen=True)
class OSPDGravityGains:
    """K_P = ω² M, K_D = 2ζω M with M = diag(m_p I₃, m_o I₃) the mean diagonal of the nominal
    task inertia Λ(q_home) (kg, kg m²): a task-space PD tuned like a mass-spring-damper of
    frequency ``omega`` (rad/s) and damping ``zeta``. ``null_damping`` (1/s): joint damping
    K_N = null_damping · diag(B̂(q_home)) (N m s/rad) against the undamped self-motion."""

    omega: float = 10.0
    zeta: float = 1.0
    null_damping: float = 2.0

    def __post_init__(self) -> None:
        _check_positive(self, "omega", "zeta", "null_damping", allow_zero=("null_damping",))


class OSPDGravity(_OperationalSpace):
    """PD + gravity in the operational space: τ = ĝ(q) + J_Aᵀ(K_P x̃ + K_D x̃̇) − K_N q̇.

    For regulation (ẋ̄ = 0, so x̃̇ = −J_A q̇) this is the course's
    τ = g(q) + J_Aᵀ(K_P x̃ − K_D J_A q̇), plus a joint damping −K_N q̇ on the redundant arm.
    V = ½q̇ᵀBq̇ + ½x̃ᵀK_P x̃ has V̇ = −q̇ᵀ(J_AᵀK_D J_A + K_N)q̇ ≤ 0 (x̃̇ = −J_A q̇ exactly with
    the analytic Jacobian of the error), and at rest J_Aᵀ K_P x̃ = 0, so x̃ = 0 where J_A has
    full rank: the arm converges to the target pose when ĝ = g.
    """

    name = "os_pd_gravity"
    Gains = OSPDGravityGains

    def __init__(self, context: TaskContext, gains=None, *, robot: Robot | None = None,
                 **overrides) -> None:
        super().__init__(context, gains, robot=robot, **overrides)
        home = self.robot.model.key("home").qpos[self.robot.qpos_adr]
        B = self.robot.inertia(home)
        Lam = osp.task_inertia(self.robot.jacobian(self.site, home), B)
        d = np.diag(Lam)
        m = np.concatenate((np.full(3, d[:3].mean()), np.full(3, d[3:].mean())))
        g = self.gains
        self.kp = g.omega**2 * m
        self.kd = 2.0 * g.zeta * g.omega * m
        self.kn = g.null_damping * np.diag(B)

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        kin = self.kinematics(obs)
        force = self.kp * kin.error + self.kd * kin.error_rate
        gravity = self.model_rows().gravity(obs["q"])
        return gravity + matvec(_transpose(kin.J_A), force) - self.kn * obs["qd"]


# ---------------------------------------------------------------------- inverse dynamics
@dataclass(frozen=True)
class OSInverseDynamicsGains:
    """Error dynamics x̃̈ + K_D x̃̇ + K_P x̃ = 0, K_P = ω_n² I, K_D = 2ζω_n I (ω_n rad/s);
    posture y₀ = ω_0²(q₀ − q) − 2ζ_0ω_0 q̇ in the null space (``posture_omega`` ω_0 rad/s,
    ``posture_zeta`` ζ_0)."""

    omega_n: float = 20.0
    zeta: float = 1.0
    posture_omega: float = 5.0
    posture_zeta: float = 1.0

    def __post_init__(self) -> None:
        _check_positive(self, "omega_n", "zeta", "posture_omega", "posture_zeta",
                        allow_zero=("posture_omega",))


class OSInverseDynamics(_OperationalSpace):
    """Inverse dynamics in the operational space: τ = B̂(q) y + n̂(q, q̇),
    y = J_A⁺ (ẍ̄_A + K_D x̃̇ + K_P x̃ − J̇_A q̇) + (I − J_A⁺J_A) y₀.

    J_A⁺ = J_Aᵀ(J_A J_Aᵀ)⁻¹ is the right (Moore–Penrose) pseudo-inverse: the minimum-norm
    joint acceleration that gives the task acceleration; the posture y₀ acts in ker J_A. With
    the exact model x̃̈ + K_D x̃̇ + K_P x̃ = 0 exactly. Near a singularity J_A⁺ grows like
    1/σ_min: the plain law (see :class:`OSInverseDynamicsDLS`).
    """

    name = "os_inverse_dynamics"
    Gains = OSInverseDynamicsGains

    def inverse(self, J_A: np.ndarray) -> np.ndarray:
        """The generalised inverse of J_A used for the task (N, n, 6) for J_A (N, 6, n)."""
        return osp.damped_least_squares(J_A, 0.0)

    @rows_method
    def joint_acceleration(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """y (n,) or (N, n), rad/s², for one observation or rows."""
        kin = self.kinematics(obs)
        J_inv = self.inverse(kin.J_A)
        y0 = self.posture_acceleration(obs, state)
        N = osp.null_space_projector(kin.J_A, J_inv)
        return matvec(J_inv, self.task_command(kin)) + matvec(N, y0)

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        # τ = B̂(q) y + n̂(q, q̇) by Newton-Euler (equal to forming B̂ to ~1e-14 relative)
        y = self.joint_acceleration(obs, state)
        return self.model_rows().newton_euler(obs["q"], obs["qd"], y)


@dataclass(frozen=True)
class OSInverseDynamicsDLSGains(OSInverseDynamicsGains):
    """The gains of os_inverse_dynamics, plus the damping schedule of the damped least
    squares: k(σ) = ``damping`` √(1 − (σ/``region``)²) for σ < ``region``, else 0, σ the
    smallest singular value of J_A (m/rad units of J: 1 for the position rows)."""

    damping: float = 0.1
    region: float = 0.1

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_positive(self, "damping", "region", allow_zero=("damping",))


class OSInverseDynamicsDLS(OSInverseDynamics):
    """os_inverse_dynamics with J_A⁺ replaced by damped least squares
    J_A* = J_Aᵀ(J_A J_Aᵀ + k² I)⁻¹, k from the Maciejewski–Klein schedule
    (:func:`cir_gym.operational_space.damping_schedule`): identical to the plain law while
    σ_min(J_A) ≥ ``region`` (everywhere on the ordinary paths); near a singularity the joint
    acceleration stays bounded (‖J_A*‖ ≤ 1/(2k)) and the task error in the near-singular
    direction is accepted instead. The posture term uses N = I − J_A* J_A.
    """

    name = "os_inverse_dynamics_dls"
    Gains = OSInverseDynamicsDLSGains

    def inverse(self, J_A: np.ndarray) -> np.ndarray:
        sigma = np.linalg.svd(J_A, compute_uv=False)[..., -1]
        k = osp.damping_schedule(sigma, self.gains.damping, self.gains.region)
        return osp.damped_least_squares(J_A, k)


# ---------------------------------------------------------------------- Khatib
@dataclass(frozen=True)
class OSKhatibGains(OSInverseDynamicsGains):
    """The gains of os_inverse_dynamics, plus ``lambda_damping`` k (1/√kg): Λ = (J_A B̂⁻¹ J_Aᵀ +
    k² I)⁻¹ (:func:`cir_gym.operational_space.task_inertia`; 0 = Khatib's plain Λ)."""

    lambda_damping: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_positive(self, "lambda_damping", allow_zero=("lambda_damping",))


class OSKhatib(_OperationalSpace):
    """Khatib's operational-space formulation (Khatib 1987; beyond the course):

    τ = J_Aᵀ Λ (ẍ̄_A + K_D x̃̇ + K_P x̃ − J̇_A q̇) + J_Aᵀ J̄ᵀ n̂ + N_dynᵀ τ₀,

    with Λ = (J_A B̂⁻¹ J_Aᵀ)⁻¹ the task inertia, J̄ = B̂⁻¹ J_Aᵀ Λ the dynamically consistent
    pseudo-inverse, J_Aᵀ J̄ᵀ n̂ = J_Aᵀ(μ + p) the Coriolis/centrifugal and gravity forces seen
    in the task, N_dyn = I − J̄ J_A, and the posture torque τ₀ = B̂ y₀ + n̂. Since
    J_A B̂⁻¹ N_dynᵀ = 0, τ₀ cannot change the task acceleration (with the exact model), and
    the closed loop is x̃̈ + K_D x̃̇ + K_P x̃ = 0. Equivalent to inverse dynamics with the
    inertia-weighted pseudo-inverse J̄ in place of J_A⁺.
    """

    name = "os_khatib"
    Gains = OSKhatibGains

    @rows_method
    def torques(self, obs: Observation, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(task torque, posture torque N_dynᵀ τ₀), both (n,) N m for one observation or
        (N, n) for rows; their sum is τ."""
        terms = self.site_terms(obs, dynamics=True)
        kin = self.pose_error(obs, terms)
        B, n, J_A = terms.inertia, terms.bias, kin.J_A
        Lam = osp.task_inertia(J_A, B, self.gains.lambda_damping)
        J_bar = osp.dynamically_consistent_inverse(J_A, B, Lam)
        N = osp.null_space_projector(J_A, J_bar)
        task = matvec(_transpose(J_A),
                      matvec(Lam, self.task_command(kin)) + matvec(_transpose(J_bar), n))
        tau0 = matvec(B, self.posture_acceleration(obs, state)) + n
        return task, matvec(_transpose(N), tau0)

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        task, posture = self.torques(obs, state)
        return task + posture


OPERATIONAL_SPACE_CONTROLLERS = (OSPDGravity, OSInverseDynamics, OSInverseDynamicsDLS, OSKhatib)
