"""Chapter 5, joint space: PD + gravity, computed torque, robust and adaptive (Slotine-Li) control.

Every law uses the controller's own nominal :class:`~cir_gym.robot.Robot` (B̂, n̂, ĝ) evaluated
at the *measured* state, never the simulator. Errors are q̃ = q̄ − q, q̃̇ = q̄̇ − q̇.
Gains follow the course: a second-order error dynamics q̃̈ + K_D q̃̇ + K_P q̃ = 0 with natural
frequency ω_n and damping ζ gives K_P = ω_n² I, K_D = 2ζω_n I.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from cir_gym.baselines.base import Controller, InvalidGain, Observation

from cir_gym import dynamics
from cir_gym.context import TaskContext
from cir_gym.robot import ModelError, Robot

__all__ = [
    "AdaptiveControl",
    "ComputedTorque",
    "PDGravity",
    "RobustControl",
    "lyapunov_solution",
]

_MUL, _ADD, _SUB = np.multiply, np.add, np.subtract  # the ufuncs, out positional on the hot path

JOINT_TASKS = ("JointTracking",)
RIGID_MODEL_TASKS = ("JointTracking", "ElasticJointTracking")  # laws that work on link q, q̇


def _positive(name: str, value: float) -> None:
    if not np.isfinite(value) or value <= 0:
        raise InvalidGain(f"{name} must be a finite number > 0, got {value!r}")


class _ModelBased(Controller):
    """A controller with a nominal robot model (the env's, or one handed in, e.g. identified).

    ``robot=`` replaces the nominal :class:`Robot`; ``parameters=`` (11 n,) replaces its
    inertial parameters π (e.g. ``IdentificationResult.to_full_parameters()``), evaluated with
    the numpy dynamics of :mod:`cir_gym.dynamics`.
    """

    def __init__(
        self,
        context: TaskContext,
        gains=None,
        *,
        robot: Robot | None = None,
        parameters: np.ndarray | None = None,
        **overrides,
    ) -> None:
        super().__init__(context, gains, **overrides)
        self.robot = robot if robot is not None else context.nominal_robot()
        self.n = self.robot.n
        self.parameters = None if parameters is None else np.asarray(parameters, dtype=float)
        if self.parameters is not None:
            expected = dynamics.inertial_parameters(self.robot.model).shape
            if self.parameters.shape != expected or not np.all(np.isfinite(self.parameters)):
                raise InvalidGain(f"parameters must be {expected[0]} finite values")

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """τ = B̂(q) q̈ + n̂(q, q̇) of the controller's model."""
        if self.parameters is not None:
            return dynamics.rnea(self.robot.model, q, qd, qdd, parameters=self.parameters)
        rows = self.row_dynamics()
        if rows is not None:  # MuJoCo's Newton-Euler, the law's batched path too
            return rows.newton_euler(q, qd, qdd)
        return self.robot.inertia(q) @ qdd + self.robot.bias(q, qd)

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """ĝ(q) of the controller's model (N m)."""
        if self.parameters is not None:
            return dynamics.gravity_torque(self.robot.model, q, parameters=self.parameters)
        return self.robot.gravity(q)

    def inertia(self, q: np.ndarray) -> np.ndarray:
        """B̂(q) of the controller's model (kg m², armature included)."""
        if self.parameters is not None:
            return dynamics.inertia_matrix(self.robot.model, q, parameters=self.parameters)
        return self.robot.inertia(q)

    def home(self) -> np.ndarray:
        """The nominal robot's home keyframe (zeros without one)."""
        m = self.robot.model
        return m.key("home").qpos[self.robot.qpos_adr].copy() if m.nkey else np.zeros(self.n)


# ---------------------------------------------------------------------- PD + gravity
@dataclass(frozen=True)
class PDGravityGains:
    """ω (rad/s) and ζ of each joint's PD, scaled by the joint's nominal inertia B̂_ii(q_home):
    K_P = ω² diag(B̂), K_D = 2ζω diag(B̂) (N m/rad, N m s/rad)."""

    omega: float = 10.0
    zeta: float = 1.0

    def __post_init__(self) -> None:
        _positive("omega", self.omega)
        _positive("zeta", self.zeta)


class PDGravity(_ModelBased):
    """PD with gravity compensation: τ = ĝ(q) + K_P q̃ + K_D (q̄̇ − q̇).

    For regulation (q̄̇ = 0) this is the law of the course, τ = g(q) + K_P q̃ − K_D q̇,
    with the Lyapunov function V = ½q̇ᵀBq̇ + ½q̃ᵀK_P q̃ and V̇ = −q̇ᵀK_D q̇: q → q̄ when ĝ = g.
    With a gravity-model error the equilibrium has the offset K_P q̃ = g(q) − ĝ(q).
    ``parameters=`` (an identified π) gives ĝ and the B̂_ii that scale the gains.
    """

    name = "pd_gravity"
    tasks = RIGID_MODEL_TASKS
    Gains = PDGravityGains

    def __init__(
        self,
        context: TaskContext,
        gains=None,
        *,
        robot: Robot | None = None,
        parameters: np.ndarray | None = None,
        **overrides,
    ) -> None:
        super().__init__(context, gains, robot=robot, parameters=parameters, **overrides)
        b = np.diag(self.inertia(self.home()))
        self.kp = self.gains.omega**2 * b
        self.kd = 2.0 * self.gains.zeta * self.gains.omega * b

    vectorized = True

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        q = obs["q"]
        return (
            self.gravity(q) + self.kp * (obs["q_ref"] - q) + self.kd * (obs["qd_ref"] - obs["qd"])
        )

    def control_batch(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """:meth:`control` on rows (N, n): ĝ row by row in MuJoCo, the PD on all rows."""
        rows = self.row_dynamics()
        if rows is None:
            return super().control_batch(obs, state)
        q = obs["q"]
        # ĝ + K_P q̃ + K_D q̃̇ in control's order, the products in place (a·b = b·a); one
        # row's ĝ in RowDynamics' buffer, the sum a new array
        err = _SUB(obs["q_ref"], q)
        _MUL(err, self.kp, err)
        if q.ndim == 1:  # ĝ + K_P q̃ into q̃'s array
            tau = _ADD(rows.gravity_buffer(q), err, err)
        else:
            tau = rows.gravity(q)
            _ADD(tau, err, tau)
        err = _SUB(obs["qd_ref"], obs["qd"])
        return _ADD(tau, _MUL(err, self.kd, err), tau)


# ---------------------------------------------------------------------- computed torque
@dataclass(frozen=True)
class ComputedTorqueGains:
    """Error dynamics q̃̈ + K_D q̃̇ + K_P q̃ = 0 with K_P = ω_n² I, K_D = 2ζω_n I.

    omega_n: natural frequency (rad/s); zeta: damping ratio.
    """

    omega_n: float = 20.0
    zeta: float = 1.0

    def __post_init__(self) -> None:
        _positive("omega_n", self.omega_n)
        _positive("zeta", self.zeta)

    @property
    def kp(self) -> float:
        return self.omega_n**2

    @property
    def kd(self) -> float:
        return 2.0 * self.zeta * self.omega_n


class _InverseDynamicsLaw(_ModelBased):
    """τ = B̂(q) y + n̂(q, q̇) with the law's outer loop y (:meth:`outer_loop`)."""

    vectorized = True

    def outer_loop(self, obs: Observation) -> np.ndarray:
        """y (rad/s²) for one observation (n,) or rows of them (N, n)."""
        raise NotImplementedError

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        return self.inverse_dynamics(obs["q"], obs["qd"], self.outer_loop(obs))

    def control_batch(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """:meth:`control` on rows (N, n): y on all rows, B̂ y + n̂ row by row in MuJoCo."""
        rows = self.row_dynamics()
        if rows is None:
            return super().control_batch(obs, state)
        return rows.newton_euler(obs["q"], obs["qd"], self.outer_loop(obs))


class ComputedTorque(_InverseDynamicsLaw):
    """Inverse dynamics: τ = B̂(q) y + n̂(q, q̇), y = q̄̈ + K_D q̃̇ + K_P q̃.

    With the exact model the closed loop is q̃̈ + K_D q̃̇ + K_P q̃ = 0.
    """

    name = "computed_torque"
    tasks = RIGID_MODEL_TASKS
    Gains = ComputedTorqueGains
    _gain_vectors: tuple = (None, None, None)  # (gains, K_P (n,), K_D (n,)), see outer_loop

    def outer_loop(self, obs: Observation) -> np.ndarray:
        """y = q̄̈ + K_D q̃̇ + K_P q̃ (rad/s²), for one observation or rows of them."""
        g = self.gains
        if self._gain_vectors[0] is not g:  # K_P, K_D as (n,) arrays: a cheaper product
            self._gain_vectors = (g, np.full(self.n, g.kp), np.full(self.n, g.kd))
        _, kp, kd = self._gain_vectors
        # q̄̈ + K_D (q̄̇ − q̇) + K_P (q̄ − q) in that order, the products in place (a·b = b·a)
        d_err = _SUB(obs["qd_ref"], obs["qd"])
        p_err = _SUB(obs["q_ref"], obs["q"])
        _MUL(d_err, kd, d_err)
        _MUL(p_err, kp, p_err)
        y = _ADD(obs["qdd_ref"], d_err, d_err)  # into q̃̇'s array
        return _ADD(y, p_err, y)


# ---------------------------------------------------------------------- robust
def lyapunov_solution(H: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Q solving Hᵀ Q + Q H = −P (continuous Lyapunov equation) by vectorisation.

    Args:
        H: (m, m) Hurwitz matrix; P: (m, m) symmetric positive definite.
    Raises:
        InvalidGain: H not Hurwitz (no positive-definite solution).
    """
    m = H.shape[0]
    if np.max(np.linalg.eigvals(H).real) >= 0:
        raise InvalidGain("the error dynamics matrix is not Hurwitz: K_P and K_D must be > 0")
    eye = np.eye(m)
    A = np.kron(eye, H.T) + np.kron(H.T, eye)
    Q = np.linalg.solve(A, -P.reshape(-1, order="F")).reshape(m, m, order="F")
    return 0.5 * (Q + Q.T)


@dataclass(frozen=True)
class RobustGains:
    """Robust control gains.

    omega_n, zeta: nominal error dynamics (K_P = ω_n² I, K_D = 2ζω_n I).
    rho: bound ρ of the robustifying term (rad/s², in the weighted norm ‖S ·‖ of
        :class:`RobustControl`); None = computed from the uncertainty bounds below with the
        course's inequality.
    epsilon: boundary-layer width ε on ‖S z‖ (rad/s² · s … the units of z = DᵀQξ); None =
        ε = ρ max(Q₁₂/K_P, Q₂₂/K_D) / ``layer_gain_ratio``, see :class:`RobustControl`.
    layer_gain_ratio: κ, the largest share of the designed K_P, K_D that the layer's linear
        gain (ρ/ε) DᵀQ may add (default 1: inside the layer the law is computed torque with
        at most twice the designed gains; the layer smooths the switch, it is not a gain).
    payload_bound: largest unknown payload (kg) the bound must cover (payloads 0…bound).
    mass_scale_bound: largest relative link-mass error covered (0.2 = ±20 %, the range
        JointTracking's ``randomize`` draws).
    viscous_friction_bound, coulomb_friction_bound: largest unmodelled joint friction covered
        (N m s/rad, N m; the ranges ``randomize`` draws): F_v q̇ + F_c sign(q̇) enters ñ.
    error_bound: assumed bound on ‖ξ‖ = ‖[q̃; q̃̇]‖ during operation.
    qdd_ref_bound: Q_M, bound on ‖q̄̈‖ (rad/s²). Measured on JointTracking-v2's default
        "random" reference: max_t ‖q̄̈(t)‖ is 3.1–5.7 rad/s² over seeds 0…19, median 4.3,
        95th percentile 5.7 and max 7.6 (seed 106) over seeds 0…199; 10 keeps a 30 % margin
        over the largest measured value.
    """

    omega_n: float = 20.0
    zeta: float = 1.0
    rho: float | None = None
    epsilon: float | None = None
    layer_gain_ratio: float = 1.0
    payload_bound: float = 5.0
    mass_scale_bound: float = 0.2
    viscous_friction_bound: float = 1.0
    coulomb_friction_bound: float = 1.0
    error_bound: float = 0.1
    qdd_ref_bound: float = 10.0

    def __post_init__(self) -> None:
        for name in ("omega_n", "zeta", "layer_gain_ratio"):
            _positive(name, getattr(self, name))
        if self.epsilon is not None:
            _positive("epsilon", self.epsilon)
        for name in (
            "payload_bound",
            "mass_scale_bound",
            "viscous_friction_bound",
            "coulomb_friction_bound",
            "error_bound",
            "qdd_ref_bound",
        ):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise InvalidGain(f"{name} must be a finite number >= 0, got {v!r}")
        if self.mass_scale_bound >= 1:
            raise InvalidGain(f"mass_scale_bound must be < 1, got {self.mass_scale_bound!r}")
        if self.rho is not None and (not np.isfinite(self.rho) or self.rho < 0):
            raise InvalidGain(f"rho must be >= 0 or None, got {self.rho!r}")


class RobustControl(_InverseDynamicsLaw):
    """Robust control: τ = B̂ y + n̂, y = q̄̈ + K_D q̃̇ + K_P q̃ + w.

    ξ = [q̃; q̃̇], H̃ = [[0, I], [−K_P, −K_D]], Q solves H̃ᵀQ + QH̃ = −P with
    P = diag(K_P, I), D = [0; I], z = DᵀQξ and w = ρ z / max(‖S z‖, ε) (the boundary layer
    replaces the chattering switch).

    The boundary layer. Q = Q₂ ⊗ I, so per joint z = Q₁₂ q̃ + Q₂₂ q̃̇. Inside the layer
    (‖S z‖ < ε) w = (ρ/ε) z: computed torque with K_P + (ρ/ε)Q₁₂ and K_D + (ρ/ε)Q₂₂ (the
    attributes ``kp_layer``, ``kd_layer``). The layer is the course's remedy for the switch's
    chattering, so its gain must not replace the designed error dynamics: ε =
    ρ max(Q₁₂/K_P, Q₂₂/K_D)/κ keeps the added gains within κ (``layer_gain_ratio``) times the
    designed ones. (Before, ε was the narrowest layer the 2-ms sampling tolerates, ρ Q₂₂ dt/0.5:
    in-layer gains K_P ≈ 5400, K_D ≈ 290, i.e. computed torque at ω_n = 73.5, ζ = 1.97, and its
    lower error was that gain.) Outside the layer ‖S w‖ = ρ: the bounded correction with which
    the course's V̇ < 0 holds for every model of the uncertainty set, whatever the error; the
    price of the layer is that the error is only ultimately bounded, with V̇ ≤ −ξᵀPξ + ρε/2.

    Why S. The course's proof needs ‖I − B⁻¹B̂‖ ≤ α < 1 in the norm it uses for ‖η‖ and
    ‖w‖ = ρ (Cauchy-Schwarz, zᵀη ≤ ‖z‖‖η‖): an induced norm, not the spectral radius. For the
    iiwa the Euclidean norm fails: I − B⁻¹B̂ = B⁻¹ΔB is far from normal (B's eigenvalues span
    0.05…14 kg m² over the workspace, wrist to shoulder), so over the uncertainty set below
    ‖I − B⁻¹B̂‖₂ reaches ≈ 3 (measured 3.3 on 50 configurations) while its eigenvalues stay
    below 0.76; scaling B̂ up (c B̂, c = 1…1.2) only raises it (3.3…3.9). The textbook's
    B̂ = 2/(B_M + B_m) I would give α = (B_M − B_m)/(B_M + B_m) = 0.993 here and drop the
    inertia model. The proof holds in any joint coordinates, so it is applied to the same
    robot in the scaled coordinates q_s = S q, S = (B̄ / max B̄)^½ constant and diagonal,
    B̄ = diag B̂(q_home) (the constant diagonal part of B, armature included, as in chapter 4's
    B(q) = B̄ + ΔB(q)). There B_s = S⁻¹BS⁻¹, B̂_s = S⁻¹B̂S⁻¹, ñ_s = S⁻¹ñ, τ_s = S⁻¹τ, so

    - I − B_s⁻¹B̂_s = S (I − B⁻¹B̂) S⁻¹: α ≥ ‖S (I − B⁻¹B̂) S⁻¹‖₂ ≈ 0.86 < 1 (nearly
      B^{−½}ΔB B^{−½}, symmetric, whose norm is its spectral radius);
    - B_s⁻¹ ñ_s = S B⁻¹ ñ: the course's B_M Φ ≥ ‖B_s⁻¹‖ ‖ñ_s‖ is bounded directly by
      max ‖S B⁻¹ ñ‖ (attribute ``b_phi``);
    - K_P, K_D are multiples of I and Q = Q₂ ⊗ I commutes with diag(S, S), so z_s = S z and
      the course's w_s = ρ z_s/‖z_s‖ is w = S⁻¹w_s = ρ z/‖S z‖; τ = S τ_s = B̂ y + n̂;
    - ‖S‖₂ = 1, so ‖S q̄̈‖ ≤ ‖q̄̈‖ ≤ Q_M and ‖S ξ‖ ≤ ‖ξ‖: the bounds on the unweighted
      quantities stay valid.

    Hence ρ ≥ (α Q_M + α ‖K‖ ‖ξ‖ + B_M Φ) / (1 − α), the course's inequality in q_s. α and
    B_M Φ are maxima over ``n_samples`` random configurations within the joint limits and the
    corners of the uncertainty set (payload 0 or ``payload_bound``, mass scale 1 ±
    ``mass_scale_bound``, friction 0 or the friction bounds): a sampled bound, not a proof.
    With ±10 % masses, no friction and the default gains, 400 configurations gave α = 0.857,
    B_M Φ = 7.9 rad/s², ρ = 357 rad/s² (4000: α = 0.870, B_M Φ = 9.6); the defaults now
    cover ±20 % masses and the friction ``randomize`` draws (:attr:`alpha`, :attr:`b_phi`,
    :attr:`rho` hold the values). Inside the boundary layer w = (ρ/ε) z does not depend on ρ
    (ε ∝ ρ), so ρ only sets where the layer ends.
    """

    name = "robust"
    tasks = JOINT_TASKS
    Gains = RobustGains

    def __init__(
        self, context: TaskContext, gains=None, *, robot: Robot | None = None, **overrides
    ) -> None:
        super().__init__(context, gains, robot=robot, **overrides)
        n, g = self.n, self.gains
        kp, kd = g.omega_n**2, 2 * g.zeta * g.omega_n
        H = np.block([[np.zeros((n, n)), np.eye(n)], [-kp * np.eye(n), -kd * np.eye(n)]])
        # P = diag(K_P, I): weighting q̃ by K_P makes z = DᵀQξ ∝ q̃̇ + (K_D/2) q̃, a
        # sliding-surface-like combination; P = I would leave z almost pure velocity.
        P = np.diag(np.concatenate((np.full(n, kp), np.ones(n))))
        self.Q = lyapunov_solution(H, P)
        self.DtQ = self.Q[n:, :]  # Dᵀ Q, D = [0; I]
        b_bar = np.diag(self.inertia(self.home()))  # B̄ (kg m²)
        self.weight = np.sqrt(b_bar / np.max(b_bar))  # diagonal of S, ‖S‖₂ = 1
        self.rho = g.rho if g.rho is not None else self.rho_from_bounds()
        q12, q22 = float(self.Q[0, n]), float(self.Q[n, n])  # Q = Q₂ ⊗ I
        self.epsilon = (
            g.epsilon
            if g.epsilon is not None
            else max(self.rho * max(q12 / kp, q22 / kd) / g.layer_gain_ratio, 1e-9)
        )
        self.kp_layer = kp + self.rho * q12 / self.epsilon  # the gains inside the layer
        self.kd_layer = kd + self.rho * q22 / self.epsilon

    def uncertainty_set(self) -> list[Robot]:
        """The true robots at the corners of the declared mass uncertainty (the friction
        corners are added in :meth:`rho_from_bounds`)."""
        g = self.gains
        return [
            self.robot.with_error(ModelError(payload_mass=p, mass_scale=s))
            for p in (0.0, g.payload_bound)
            for s in (1.0 - g.mass_scale_bound, 1.0 + g.mass_scale_bound)
        ]

    def inertia_error_norm(self, B: np.ndarray, B_hat: np.ndarray) -> float:
        """‖S (I − B⁻¹B̂) S⁻¹‖₂, the course's ‖I − B⁻¹B̂‖ in the scaled coordinates."""
        s = self.weight
        E = np.eye(self.n) - np.linalg.solve(B, B_hat)
        return float(np.linalg.norm(s[:, None] * E / s[None, :], 2))

    def rho_from_bounds(self, n_samples: int = 400, seed: int = 0) -> float:
        """ρ from the course's inequality in the scaled coordinates (see the class)."""
        g = self.gains
        truths = self.uncertainty_set()
        rng = np.random.default_rng(seed)
        alpha = b_phi = 0.0
        lo, hi = self.robot.lower, self.robot.upper
        for _ in range(n_samples):
            q = rng.uniform(lo, hi)
            qd = rng.uniform(-1, 1, self.n) * np.minimum(self.robot.velocity_limit, 3.0)
            B_hat = self.inertia(q)
            n_hat = self.inverse_dynamics(q, qd, np.zeros(self.n))
            friction = g.viscous_friction_bound * qd + g.coulomb_friction_bound * np.sign(qd)
            for true in truths:
                B = true.inertia(q)
                alpha = max(alpha, self.inertia_error_norm(B, B_hat))
                for f in (0.0 * friction, friction):  # ñ = n̂ − n, n with the friction
                    n_tilde = n_hat - true.bias(q, qd) - f
                    b_phi = max(
                        b_phi, float(np.linalg.norm(self.weight * np.linalg.solve(B, n_tilde)))
                    )
        if alpha >= 1:
            raise InvalidGain(f"uncertainty too large for robust control: α = {alpha:.2f} ≥ 1")
        k_norm = np.hypot(g.omega_n**2, 2 * g.zeta * g.omega_n)
        self.alpha, self.b_phi = alpha, b_phi
        return float(
            (alpha * g.qdd_ref_bound + alpha * k_norm * g.error_bound + b_phi) / (1 - alpha)
        )

    def robust_term(self, e: np.ndarray, ed: np.ndarray) -> np.ndarray:
        """w = ρ z / max(‖S z‖, ε), z = DᵀQ [q̃; q̃̇] (rad/s²), for (n,) or rows (N, n)."""
        if e.ndim == 2:
            return np.array([self.robust_term(*row) for row in zip(e, ed, strict=True)])
        z = self.DtQ @ np.concatenate((e, ed))
        sz = self.weight * z
        # ‖S z‖ as np.linalg.norm computes it for a vector (sqrt of the dot product), without
        # its wrapper
        return self.rho * z / max(math.sqrt(sz.dot(sz)), self.epsilon)

    def outer_loop(self, obs: Observation) -> np.ndarray:
        """y = q̄̈ + K_D q̃̇ + K_P q̃ + w (rad/s²), for one observation or rows of them."""
        g = self.gains
        e, ed = obs["q_ref"] - obs["q"], obs["qd_ref"] - obs["qd"]
        w = self.robust_term(e, ed)
        return obs["qdd_ref"] + (2 * g.zeta * g.omega_n) * ed + g.omega_n**2 * e + w


# ---------------------------------------------------------------------- adaptive
@dataclass(frozen=True)
class AdaptiveGains:
    """Slotine-Li gains.

    lam: Λ = λ I (1/s), σ = q̃̇ + Λ q̃.
    kd: K_D = kd · diag(B̂(q_home)) (1/s). With λ = 10 and kd = 40 the law starts as the
        PD K_D σ = K_D q̃̇ + K_D Λ q̃ with the gains of computed torque (ω_n = 20, ζ = 1).
    gamma: adaptation gain, K_π⁻¹ = γ diag(scale²) with each parameter's plausible error as
        scale (:meth:`AdaptiveControl.parameter_scale`). Measured on the 3 kg payload:
        γ = 1 → 1.0e-2 rad RMS, 10 → 2.1e-3, 100 → 3.0e-4, 300 → the discrete adaptation
        starts to chatter (4 % saturated steps), 1000 → 51 %. The default keeps a 3× margin.
    adapt: "all" parameters, or "last_link" (the link carrying the payload).
    """

    lam: float = 10.0
    kd: float = 40.0
    gamma: float = 100.0
    adapt: str = "all"

    def __post_init__(self) -> None:
        for name in ("lam", "kd", "gamma"):
            _positive(name, getattr(self, name))
        if self.adapt not in ("all", "last_link"):
            raise InvalidGain(f"adapt must be 'all' or 'last_link', got {self.adapt!r}")


class AdaptiveControl(_ModelBased):
    """Adaptive control (Slotine-Li): τ = Y(q, q̇, q̇_r, q̈_r) π̂ + K_D σ, π̂̇ = K_π⁻¹ Yᵀ σ.

    q̇_r = q̄̇ + Λ q̃, q̈_r = q̄̈ + Λ q̃̇, σ = q̇_r − q̇. π̂ starts at the nominal parameters
    (:func:`cir_gym.dynamics.inertial_parameters`) and lives in the policy state, so it can be
    plotted; only Y π̃ → 0 is guaranteed, not π̂ → π.
    """

    name = "adaptive"
    tasks = JOINT_TASKS
    Gains = AdaptiveGains

    def __init__(
        self, context: TaskContext, gains=None, *, robot: Robot | None = None, **overrides
    ) -> None:
        super().__init__(context, gains, robot=robot, **overrides)
        self.model = self.robot.model
        self.pi0 = (
            dynamics.inertial_parameters(self.model)
            if self.parameters is None
            else self.parameters.copy()
        )
        home = self.model.key("home").qpos if self.model.nkey else np.zeros(self.n)
        self.kd = self.gains.kd * np.diag(self.robot.inertia(home))
        scale = self.parameter_scale()
        if self.gains.adapt == "last_link":
            mask = np.zeros_like(self.pi0)
            mask[10 * (self.n - 1) : 10 * self.n] = 1.0
            scale = scale * mask
        self.adapt_gain = self.gains.gamma * scale**2  # diagonal of K_π⁻¹

    def parameter_scale(self) -> np.ndarray:
        """Magnitude of each parameter's plausible error: per link [m, m c (3), I (6)] scaled
        as [m̄, m̄ · 0.1 m, m̄ · 0.01 m²] with m̄ = max(m, 1 kg); armatures by themselves."""
        n = self.n
        masses = np.maximum(self.pi0[0 : 10 * n : 10], 1.0)
        per_link = np.array([1.0, 0.1, 0.1, 0.1, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01])
        scale = (masses[:, None] * per_link[None, :]).ravel()
        return np.concatenate((scale, np.maximum(self.pi0[10 * n :], 1e-3)))

    @property
    def state_size(self) -> int:
        return self.pi0.size

    def initial_state(self, obs: Observation) -> np.ndarray:
        return self.pi0.copy()

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        q, qd = obs["q"], obs["qd"]
        lam = self.gains.lam
        e, ed = obs["q_ref"] - q, obs["qd_ref"] - qd
        qd_r = obs["qd_ref"] + lam * e
        qdd_r = obs["qdd_ref"] + lam * ed
        sigma = qd_r - qd
        Y = dynamics.regressor(self.model, q, qd, qdd_r, qd_r=qd_r)
        tau = Y @ state + self.kd * sigma
        state += self.dt * self.adapt_gain * (Y.T @ sigma)  # π̂̇ = K_π⁻¹ Yᵀ σ (Euler)
        return tau
