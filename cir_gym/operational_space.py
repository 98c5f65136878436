"""Operational space (chapter 5.2 and beyond): orientation errors on SO(3), the analytic Jacobian
of the pose error, J̇q̇, the task-space inertia Λ(q), the dynamically consistent pseudo-inverse
and null-space projector, and damped least squares.

Conventions (as :mod:`cir_gym.robot` and :mod:`cir_gym.trajectories`): quaternions are
(w, x, y, z); rotations map the end-effector frame to the world (base) frame; angular velocities
ω are in the world frame; geometric Jacobians are (6, n) ``[J_P; J_O]`` in the world frame
(:meth:`cir_gym.robot.Robot.jacobian`); twists are (6,) ``[v; ω]``. Functions on arrays
broadcast over leading axes (batches) where that is cheap: their shapes are written (..., k).

**The orientation representation** (the course's x̃ = x̄ − x with an orientation that is valid on
all of SO(3), not Euler angles): the orientation error is the rotation vector (exponential
coordinates, axis-angle form) of R̄ Rᵀ,

    φ = θ r = log(R̄ Rᵀ) ∈ R³,  θ ∈ [0, π],

i.e. the rotation, in the world frame, that takes the current frame R onto the reference R̄
(undefined only at θ = π exactly, where the shorter rotation is not unique). Its rate is

    φ̇ = J_l⁻¹(φ) ω̄ − J_r⁻¹(φ) ω,        (Barfoot, *State Estimation for Robotics*, §7.1.5)

with J_l, J_r = J_l(−φ) the left and right Jacobians of SO(3). So the pose error
x̃ = [p̄ − p; φ] (6,) has the **analytic Jacobian** J_A = [J_P; J_r⁻¹(φ) J_O]:
x̃̇ = ẋ̄_A − J_A q̇ with ẋ̄_A = [ṗ̄; J_l⁻¹(φ) ω̄], and x̃̈ = ẍ̄_A − J̇_A q̇ − J_A q̈ with the
terms of :func:`pose_error_kinematics`. Commanding J_A q̈ = ẍ̄_A − J̇_A q̇ + K_D x̃̇ + K_P x̃ gives
exactly x̃̈ + K_D x̃̇ + K_P x̃ = 0 for position *and* orientation, at any error below π. For
small errors φ ≈ 2ε (the quaternion form) and J_r⁻¹ ≈ I (the geometric Jacobian).

The **quaternion form** (Siciliano et al. §3.7.3) is the vector part ε of Q_e = Q̄ ⊗ Q⁻¹ on the
hemisphere η ≥ 0 (:func:`quat_error`); both forms give the same error for Q and −Q.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from cir_gym import trajectories as traj
from cir_gym.robot import Robot
from cir_gym.trajectories import skew  # S(v) x = v × x; re-exported here

__all__ = [
    "PoseErrorKinematics",
    "align_quat",
    "continuous_quats",
    "damped_least_squares",
    "damping_schedule",
    "dynamically_consistent_inverse",
    "error_rate",
    "left_jacobian",
    "left_jacobian_inverse",
    "left_jacobian_inverse_dot",
    "null_space_projector",
    "orientation_angle",
    "pose_error_from_kinematics",
    "pose_error_kinematics",
    "quat_angle",
    "quat_dot",
    "quat_error",
    "quat_times_conj",
    "rotvec_error",
    "rotvec_from_quat",
    "skew",
    "task_inertia",
]

_ARCTAN2 = np.arctan2  # numpy's, not math.atan2: they differ in the last bit
_SUM = np.add.reduce  # np.sum without its Python wrapper (the hot paths on rows)
_SMALL_ANGLE = 0.05  # rad: below, the SO(3) Jacobian coefficients use their Taylor series


# ---------------------------------------------------------------------- quaternions
def align_quat(quat: ArrayLike, to: ArrayLike) -> np.ndarray:
    """``quat`` or ``−quat`` (the same rotation), whichever has ``quat · to ≥ 0`` (..., 4).

    Puts a measured quaternion on the hemisphere of a reference, so that both are continuous
    together while the error stays below π.
    """
    q, r = np.asarray(quat, dtype=float), np.asarray(to, dtype=float)
    if q.shape == r.shape == (4,):  # one pose (the envs' hot path): no temporaries
        return -q if quat_dot(q.tolist(), r.tolist()) < 0.0 else q * 1.0
    sign = np.where(_SUM(q * r, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    return q * sign


def quat_dot(a: list[float], b: list[float]) -> float:
    """a · b of two quaternions given as 4 floats each, summed in numpy's order for short
    rows (bit-identical to ``np.sum(a * b)``, the sign test of :func:`align_quat`)."""
    return 0.0 + a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]


def continuous_quats(quats: ArrayLike) -> np.ndarray:
    """A sequence of quaternions (k, 4) made continuous: the first has w ≥ 0, each next one
    the sign that makes its dot product with the previous one ≥ 0."""
    q = np.array(quats, dtype=float)
    if q.ndim != 2 or q.shape[1] != 4:
        raise ValueError(f"quats must have shape (k, 4), got {q.shape}")
    if q.shape[0] and q[0, 0] < 0:
        q[0] = -q[0]
    dots = np.sum(q[1:] * q[:-1], axis=1)
    # flipping q_k changes the sign of its dot product with q_{k-1} and with q_{k+1}: the
    # cumulative product of the signs makes every consecutive pair agree
    signs = np.concatenate(([1.0], np.cumprod(np.where(dots < 0.0, -1.0, 1.0))))
    return q * signs[:, None]


def quat_error(quat_ref: ArrayLike, quat: ArrayLike) -> np.ndarray:
    """Quaternion form of the orientation error: ε_e (..., 3) of Q_e = Q̄ ⊗ Q⁻¹ with η_e ≥ 0.

    Siciliano's e_O = η ε̄ − η̄ ε − S(ε̄) ε (world frame), taken on the shorter rotation so that
    Q and −Q give the same error; ‖ε_e‖ = sin(θ/2) with θ the error angle.
    """
    qe = quat_times_conj(quat_ref, quat)
    sign = np.where(qe[..., :1] < 0.0, -1.0, 1.0)
    return sign * qe[..., 1:]


def _times_conj_constants() -> np.ndarray:
    """T (16, 4): Q̄ ⊗ Q⁻¹ = vec(Q̄ Qᵀ) T for unit quaternions, T[4j + k] = e_j ⊗ e_k⁻¹ — the
    structure constants of :func:`cir_gym.trajectories.quat_mul` with the conjugate, taken
    from it on the basis quaternions (entries 0 and ±1)."""
    E = np.eye(4)
    return traj.quat_mul(E[:, None, :], traj.quat_conj(E)[None, :, :]).reshape(16, 4)


_TIMES_CONJ = _times_conj_constants()


def quat_times_conj(quat_ref: ArrayLike, quat: ArrayLike) -> np.ndarray:
    """Q̄ ⊗ Q⁻¹ (..., 4) of unit quaternions (..., 4) (broadcasts): the product of
    :func:`cir_gym.trajectories.quat_mul` with the conjugate as one outer product and one
    matrix product with its constants (a tenth of the cost on rows of poses). Equal to it up to
    the order of the four products' sum (the constants are 0 and ±1: each product is exact)."""
    a, b = np.asarray(quat_ref, dtype=float), np.asarray(quat, dtype=float)
    outer = a[..., :, None] * b[..., None, :]
    # a (1, 16) row times T for each pose: one BLAS call per pose, the same for any number
    # of poses (a (N, 16) matrix product's kernel could block the poses differently)
    return (outer.reshape(*outer.shape[:-2], 1, 16) @ _TIMES_CONJ)[..., 0, :]


def rotvec_from_quat(quat: ArrayLike) -> np.ndarray:
    """Rotation vector θ r (..., 3) of unit quaternions (..., 4), θ ∈ [0, π] (rad)."""
    q = np.asarray(quat, dtype=float)
    if q.shape == (4,):  # one quaternion (the controllers' hot path): the same operations
        w, x, y, z = q.tolist()
        if w < 0.0:
            w, x, y, z = -w, -x, -y, -z
        s1 = math.sqrt(0.0 + x * x + y * y + z * z)
        scale1 = 2.0 * float(_ARCTAN2(s1, w)) / s1 if s1 > 1e-12 else 2.0
        return np.array([scale1 * x, scale1 * y, scale1 * z])
    q = q * np.where(q[..., :1] < 0.0, -1.0, 1.0)  # η ≥ 0: the shorter rotation
    eps = q[..., 1:]
    s = np.sqrt(_SUM(eps * eps, axis=-1, keepdims=True))
    theta = 2.0 * np.arctan2(s, q[..., :1])
    # θ / sin(θ/2) → 2 as θ → 0 (the ratio is 2 (1 + θ²/24 + ...) there)
    finite = s > 1e-12
    scale = np.where(finite, theta / np.where(finite, s, 1.0), 2.0)
    return scale * eps


def rotvec_error(quat_ref: ArrayLike, quat: ArrayLike) -> np.ndarray:
    """Axis-angle form of the orientation error: φ = θ r = log(R̄ Rᵀ) (..., 3), rad, world
    frame, θ ∈ [0, π] (the shorter rotation); Q and −Q give the same error."""
    return rotvec_from_quat(quat_times_conj(quat_ref, quat))


def orientation_angle(quat_ref: ArrayLike, quat: ArrayLike) -> np.ndarray:
    """Angle θ ∈ [0, π] (rad, shape (...)) of the rotation between two orientations."""
    q, r = np.asarray(quat_ref, dtype=float), np.asarray(quat, dtype=float)
    if q.shape == r.shape == (4,):  # one pose (the envs' hot path)
        return np.float64(quat_angle(q.tolist(), r.tolist()))
    # 2 acos |q·r| loses precision near 0; 2 atan2(‖ε_e‖, |η_e|) does not (and does not
    # depend on the quaternions' norms), η_e = q·r
    qe = quat_times_conj(q, r)
    eps = qe[..., 1:]
    return 2.0 * np.arctan2(np.sqrt(_SUM(eps * eps, axis=-1)), np.abs(qe[..., 0]))


def quat_angle(quat_ref: list[float], quat: list[float]) -> float:
    """:func:`orientation_angle` of two single quaternions given as 4 floats each (rad).

    The array version's formula on Python floats (numpy's ``arctan2`` is kept because its
    SIMD kernel and libm's differ in the last bit): equal to it to a few units in the last
    place (its products are summed in another order), at ~1/30 of the cost.
    """
    r0, r1, r2, r3 = quat_ref
    q0, q1, q2, q3 = quat
    # Q_e = Q̄ ⊗ Q⁻¹ (trajectories.quat_mul with the conjugate's negated entries)
    w = r0 * q0 - r1 * -q1 - r2 * -q2 - r3 * -q3
    x = r0 * -q1 + r1 * q0 + r2 * -q3 - r3 * -q2
    y = r0 * -q2 - r1 * -q3 + r2 * q0 + r3 * -q1
    z = r0 * -q3 + r1 * -q2 - r2 * -q1 + r3 * q0
    if w < 0.0:  # the hemisphere η_e ≥ 0 (quat_error)
        x, y, z = -x, -y, -z
    norms = math.sqrt(quat_dot(quat_ref, quat_ref)) * math.sqrt(quat_dot(quat, quat))
    dot = abs(quat_dot(quat_ref, quat)) / norms
    eps = math.sqrt(0.0 + x * x + y * y + z * z) / norms
    return 2.0 * float(_ARCTAN2(eps, dot))


# ---------------------------------------------------------------------- SO(3) Jacobians
def _coefficients(theta: np.ndarray) -> tuple[np.ndarray, ...]:
    """a, b, c, d(θ) of J_l = I + a S + b S², J_l⁻¹ = I − S/2 + c S², d = c'(θ)/θ."""
    if np.ndim(theta) == 0:  # numpy scalars, so that c[..., None, None] works
        return tuple(map(np.float64, _scalar_coefficients(float(theta))))
    small = theta < _SMALL_ANGLE
    t = np.where(small, 1.0, theta)  # a safe angle for the closed forms
    t2 = theta**2
    a = np.where(small, 0.5 - t2 / 24 + t2**2 / 720, (1 - np.cos(t)) / t**2)
    b = np.where(small, 1 / 6 - t2 / 120 + t2**2 / 5040, (t - np.sin(t)) / t**3)
    return (a, b, *_inverse_coefficients(theta))


def _inverse_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """c, d(θ) of J_l⁻¹ = I − S/2 + c S², d = c'(θ)/θ, for an array of angles (rad)."""
    small = theta < _SMALL_ANGLE
    t = np.where(small, 1.0, theta)  # a safe angle for the closed forms
    t2 = theta * theta
    u = 1.0 / t
    sin_half = np.sin(0.5 * t)
    half_cot = 0.5 * np.cos(0.5 * t) / sin_half  # cot(θ/2)/2
    # c = 1/θ² − cot(θ/2)/(2θ);  c' = −2/θ³ + cot(θ/2)/(2θ²) + 1/(4θ sin²(θ/2)), d = c'/θ
    c = np.where(small, 1 / 12 + t2 * (1 / 720 + t2 / 30240), u * (u - half_cot))
    c_prime = u * (u * (half_cot - 2.0 * u) + 0.25 / (sin_half * sin_half))
    d = np.where(small, 1 / 360 + t2 * (1 / 7560 + t2 / 201600), c_prime * u)
    return c, d


def _scalar_coefficients(t: float) -> tuple[float, float, float, float]:
    """:func:`_coefficients` of one angle with the math module (the controllers' hot path)."""
    t2 = t * t
    if t < _SMALL_ANGLE:
        return (
            0.5 - t2 / 24 + t2**2 / 720,
            1 / 6 - t2 / 120 + t2**2 / 5040,
            1 / 12 + t2 / 720 + t2**2 / 30240,
            1 / 360 + t2 / 7560 + t2**2 / 201600,
        )
    half_cot = math.cos(t / 2) / math.sin(t / 2)
    c_prime = -2 / t**3 + half_cot / (2 * t2) + 1 / (4 * t * math.sin(t / 2) ** 2)
    return (
        (1 - math.cos(t)) / t2,
        (t - math.sin(t)) / t**3,
        1 / t2 - half_cot / (2 * t),
        c_prime / t,
    )


def left_jacobian(phi: ArrayLike) -> np.ndarray:
    """Left Jacobian of SO(3) J_l(φ) (..., 3, 3): ω = J_l(φ) φ̇ for R = exp(S(φ)), ω in the
    world frame. J_l = I + (1 − cos θ)/θ² S + (θ − sin θ)/θ³ S², S = S(φ), θ = ‖φ‖."""
    phi = np.asarray(phi, dtype=float)
    a, b, _, _ = _coefficients(np.linalg.norm(phi, axis=-1))
    S = skew(phi)
    return np.eye(3) + a[..., None, None] * S + b[..., None, None] * (S @ S)


def left_jacobian_inverse(phi: ArrayLike) -> np.ndarray:
    """J_l⁻¹(φ) = I − S/2 + (1/θ² − cot(θ/2)/(2θ)) S² (..., 3, 3): φ̇ = J_l⁻¹(φ) ω.

    Finite for θ < 2π; the right Jacobian's inverse is J_r⁻¹(φ) = J_l⁻¹(−φ).
    """
    phi = np.asarray(phi, dtype=float)
    _, _, c, _ = _coefficients(np.linalg.norm(phi, axis=-1))
    S = skew(phi)
    return np.eye(3) - 0.5 * S + c[..., None, None] * (S @ S)


def left_jacobian_inverse_dot(phi: ArrayLike, phi_dot: ArrayLike) -> np.ndarray:
    """d/dt J_l⁻¹(φ(t)) (..., 3, 3) for φ̇ = ``phi_dot``:
    −S(φ̇)/2 + c'(θ) θ̇ S² + c (S(φ̇) S + S S(φ̇)), with θ̇ = φᵀφ̇/θ."""
    phi, phi_dot = np.asarray(phi, dtype=float), np.asarray(phi_dot, dtype=float)
    _, _, c, d = _coefficients(np.linalg.norm(phi, axis=-1))
    S, Sd = skew(phi), skew(phi_dot)
    rate = np.sum(phi * phi_dot, axis=-1)  # θ θ̇; d = c'/θ, so c' θ̇ = d θ θ̇
    return (
        -0.5 * Sd + (d * rate)[..., None, None] * (S @ S) + c[..., None, None] * (Sd @ S + S @ Sd)
    )


def error_rate(phi: ArrayLike, omega_ref: ArrayLike, omega: ArrayLike) -> np.ndarray:
    """φ̇ (..., 3) of the orientation error φ = log(R̄ Rᵀ): J_l⁻¹(φ) ω̄ − J_r⁻¹(φ) ω (rad/s)."""
    phi = np.asarray(phi, dtype=float)
    w_ref = np.asarray(omega_ref, dtype=float)[..., None]
    w = np.asarray(omega, dtype=float)[..., None]
    return (left_jacobian_inverse(phi) @ w_ref - left_jacobian_inverse(-phi) @ w)[..., 0]


# ---------------------------------------------------------------------- the pose error
@dataclass(frozen=True)
class PoseErrorKinematics:
    """The pose error of a site and its first two time derivatives' ingredients (one instant;
    for rows of states every field has the rows' leading axes, e.g. error (N, 6)).

    With x̃ = [p̄ − p; log(R̄ Rᵀ)] (module docstring):
    x̃̇ = ``error_rate`` = ``ref_rate`` − J_A q̇ and
    x̃̈ = ``ref_acc`` − ``JA_dot_qd`` − J_A q̈.

    Attributes:
        error: x̃ (6,), m and rad.
        error_rate: x̃̇ (6,), m/s and rad/s.
        J_A: analytic Jacobian (6, n) of the pose error, [J_P; J_r⁻¹(φ) J_O].
        J: geometric Jacobian (6, n) of the site (world frame).
        ref_rate: ẋ̄_A (6,) = [ṗ̄; J_l⁻¹(φ) ω̄].
        ref_acc: ẍ̄_A (6,) = [p̈̄; J_l⁻¹(φ) ω̄̇ + (d/dt J_l⁻¹(φ)) ω̄].
        JA_dot_qd: J̇_A q̇ (6,) = [J̇_P q̇; J_r⁻¹(φ) J̇_O q̇ + (d/dt J_r⁻¹(φ)) ω].
        twist: the site's twist [v; ω] (6,) = J q̇.
    """

    error: np.ndarray
    error_rate: np.ndarray
    J_A: np.ndarray
    J: np.ndarray
    ref_rate: np.ndarray
    ref_acc: np.ndarray
    JA_dot_qd: np.ndarray
    twist: np.ndarray

    @property
    def task_acceleration(self) -> np.ndarray:
        """ẍ̄_A − J̇_A q̇ (6,): J_A q̈ must equal this plus the feedback for x̃̈ = −feedback."""
        return self.ref_acc - self.JA_dot_qd


def pose_error_kinematics(
    robot: Robot,
    site: str | int,
    q: np.ndarray,
    qd: np.ndarray,
    x_ref: ArrayLike,
    quat_ref: ArrayLike,
    twist_ref: ArrayLike,
    acc_ref: ArrayLike,
) -> PoseErrorKinematics:
    """The pose error of ``site`` against a reference, with J_A and J̇_A q̇, at (q, q̇).

    Uses :meth:`Robot.site_pose`, :meth:`Robot.jacobian` and :meth:`Robot.jacobian_dot_qdot`
    (MuJoCo's mj_jacSite and mj_jacDot) of ``robot`` (a controller's nominal model), then
    :func:`pose_error_from_kinematics`.

    Args:
        robot: the model; site: the end-effector site.
        q, qd: joint positions (n,) rad and velocities (n,) rad/s.
        x_ref: p̄ (3,) m; quat_ref: Q̄ (4,) (w, x, y, z), either sign.
        twist_ref: [ṗ̄; ω̄] (6,) m/s, rad/s (world); acc_ref: [p̈̄; ω̄̇] (6,) m/s², rad/s².
    """
    x, R = robot.site_pose(site, q)
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(R).ravel())
    return pose_error_from_kinematics(
        x, quat, robot.jacobian(site, q), robot.jacobian_dot_qdot(site, q, qd), qd,
        x_ref, quat_ref, twist_ref, acc_ref,
    )


def _times(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A v (..., m) for matrices (..., m, k) and vectors (..., k)."""
    return (A @ v[..., None])[..., 0]


def pose_error_from_kinematics(
    x: ArrayLike,
    quat: ArrayLike,
    J: ArrayLike,
    jdqd: ArrayLike,
    qd: ArrayLike,
    x_ref: ArrayLike,
    quat_ref: ArrayLike,
    twist_ref: ArrayLike,
    acc_ref: ArrayLike,
) -> PoseErrorKinematics:
    """:class:`PoseErrorKinematics` from a site's kinematics, for one state or rows (...).

    Args:
        x: site position p (..., 3), m; quat: its orientation Q (..., 4), either sign.
        J: geometric Jacobian (..., 6, n); jdqd: J̇ q̇ (..., 6); qd: q̇ (..., n), rad/s.
        x_ref, quat_ref, twist_ref, acc_ref: p̄ (..., 3), Q̄ (..., 4), [ṗ̄; ω̄] (..., 6) and
            [p̈̄; ω̄̇] (..., 6) (see :func:`pose_error_kinematics`).

    The fields have the rows' leading axes (error (..., 6), J_A (..., 6, n), ...).
    """
    J, jdqd = np.asarray(J, dtype=float), np.asarray(jdqd, dtype=float)
    twist_ref = np.asarray(twist_ref, dtype=float)
    acc_ref = np.asarray(acc_ref, dtype=float)
    twist = _times(J, np.asarray(qd, dtype=float))
    # φ = log(Q̄ ⊗ Q⁻¹) (Q̄ ⊗ Q⁻¹ normalised: rotvec_from_quat takes unit quaternions)
    q_err = quat_times_conj(quat_ref, quat)
    q_err = q_err / np.sqrt(_SUM(q_err * q_err, axis=-1, keepdims=True))
    phi = rotvec_from_quat(q_err)
    c, d = _inverse_coefficients(np.sqrt(_SUM(phi * phi, axis=-1)))
    c, d = np.asarray(c)[..., None, None], np.asarray(d)[..., None, None]
    S = skew(phi)
    S2 = S @ S
    eye_cS2 = np.eye(3) + c * S2
    half_S = 0.5 * S
    Jl_inv = eye_cS2 - half_S  # J_l⁻¹(φ)
    Jr_inv = eye_cS2 + half_S  # J_r⁻¹(φ) = J_l⁻¹(−φ)
    w_ref, w = twist_ref[..., 3:], twist[..., 3:]
    phi_dot = _times(Jl_inv, w_ref) - _times(Jr_inv, w)
    # d/dt J_l⁻¹(φ) and d/dt J_r⁻¹(φ) = D J_l⁻¹(−φ)[−φ̇] (left_jacobian_inverse_dot)
    Sd = skew(phi_dot)
    rate = _SUM(phi * phi_dot, axis=-1)[..., None, None]  # θ θ̇
    common = (d * rate) * S2 + c * (Sd @ S + S @ Sd)
    half_Sd = 0.5 * Sd
    Jl_inv_dot, Jr_inv_dot = common - half_Sd, common + half_Sd
    J_A = np.concatenate((J[..., :3, :], Jr_inv @ J[..., 3:, :]), axis=-2)
    ref_rate = np.concatenate((twist_ref[..., :3], _times(Jl_inv, w_ref)), axis=-1)
    ref_acc = np.concatenate(
        (acc_ref[..., :3], _times(Jl_inv, acc_ref[..., 3:]) + _times(Jl_inv_dot, w_ref)),
        axis=-1,
    )
    JA_dot_qd = np.concatenate(
        (jdqd[..., :3], _times(Jr_inv, jdqd[..., 3:]) + _times(Jr_inv_dot, w)), axis=-1
    )
    return PoseErrorKinematics(
        error=np.concatenate((np.asarray(x_ref, dtype=float) - x, phi), axis=-1),
        error_rate=np.concatenate((twist_ref[..., :3] - twist[..., :3], phi_dot), axis=-1),
        J_A=J_A,
        J=J,
        ref_rate=ref_rate,
        ref_acc=ref_acc,
        JA_dot_qd=JA_dot_qd,
        twist=twist,
    )


# ---------------------------------------------------------------------- task-space dynamics
def task_inertia(J: ArrayLike, B: ArrayLike, damping: float = 0.0) -> np.ndarray:
    """Task-space (operational-space) inertia Λ = (J B⁻¹ Jᵀ + k² I)⁻¹ (..., m, m).

    ``damping`` k = 0 (default) is Khatib's Λ(q) = (J B⁻¹ Jᵀ)⁻¹, which grows without bound as J
    loses rank (its largest eigenvalue ~ 1/σ_min², kg or kg m²): the failure of the plain law
    near a singularity. k > 0 is the regularised (Tikhonov) form: Λ ≤ I/k² in every direction,
    and k² (units of 1/kg) is negligible against J B⁻¹ Jᵀ away from singularities.

    Args:
        J: Jacobian (..., m, n) (geometric or analytic: Λ is the inertia seen in its rows).
        B: joint-space inertia (..., n, n), symmetric positive definite (kg m²).
        damping: k ≥ 0.

    Raises:
        numpy.linalg.LinAlgError: J B⁻¹ Jᵀ exactly singular and k = 0.
    """
    J, B = np.asarray(J, dtype=float), np.asarray(B, dtype=float)
    if not np.isfinite(damping) or damping < 0:
        raise ValueError(f"damping must be a finite number >= 0, got {damping!r}")
    JBJ = J @ np.linalg.solve(B, np.swapaxes(J, -1, -2))
    m = J.shape[-2]
    return np.linalg.inv(JBJ + damping**2 * np.eye(m))


def dynamically_consistent_inverse(
    J: ArrayLike, B: ArrayLike, Lambda: ArrayLike | None = None
) -> np.ndarray:
    """J̄ = B⁻¹ Jᵀ Λ (..., n, m): the inertia-weighted pseudo-inverse (Khatib 1987).

    J J̄ = I (for the undamped Λ), and a joint torque Nᵀ τ₀ with N = I − J̄ J gives no task
    acceleration (J B⁻¹ Nᵀ = 0). ``Lambda`` defaults to :func:`task_inertia` (undamped).
    """
    J, B = np.asarray(J, dtype=float), np.asarray(B, dtype=float)
    L = task_inertia(J, B) if Lambda is None else np.asarray(Lambda, dtype=float)
    return np.linalg.solve(B, np.swapaxes(J, -1, -2)) @ L


def null_space_projector(J: ArrayLike, J_inv: ArrayLike) -> np.ndarray:
    """N = I − J⁺ J (..., n, n) for a generalised inverse J⁺ (n, m) of J (m, n).

    With the Moore–Penrose J† it projects joint *velocities/accelerations* onto ker J; with the
    dynamically consistent J̄ its transpose Nᵀ = I − Jᵀ J̄ᵀ projects joint *torques*: Nᵀ τ₀
    leaves the task acceleration unchanged.
    """
    J, J_inv = np.asarray(J, dtype=float), np.asarray(J_inv, dtype=float)
    return np.eye(J.shape[-1]) - J_inv @ J


def damped_least_squares(J: ArrayLike, damping: ArrayLike) -> np.ndarray:
    """J* = Jᵀ (J Jᵀ + k² I)⁻¹ (..., n, m), k = ``damping`` ≥ 0 (scalar or (...,)).

    k = 0 is the right pseudo-inverse J† of a full-rank J. For k > 0 every singular value σ of
    J becomes σ/(σ² + k²) ≤ 1/(2k) in J*: bounded at any configuration, at the price of a task
    error in the directions where σ ≲ k (Nakamura & Hanafusa 1986; Wampler 1986).
    """
    J = np.asarray(J, dtype=float)
    k = np.asarray(damping, dtype=float)
    if k.ndim == 0:  # one number (the common case): no array reductions
        if not (math.isfinite(float(k)) and float(k) >= 0):
            raise ValueError(f"damping must be finite and >= 0, got {damping!r}")
    elif np.any(~np.isfinite(k)) or np.any(k < 0):
        raise ValueError(f"damping must be finite and >= 0, got {damping!r}")
    m = J.shape[-2]
    JJt = J @ np.swapaxes(J, -1, -2) + (k**2)[..., None, None] * np.eye(m)
    return np.swapaxes(np.linalg.solve(JJt, J), -1, -2)


def damping_schedule(sigma_min: ArrayLike, damping: float, region: float) -> np.ndarray:
    """k(σ_min) = k_max √(1 − (σ_min/ε)²) for σ_min < ε, else 0 (shape of ``sigma_min``).

    Maciejewski & Klein (1988): no damping (exact solution) away from the singular region,
    the full damping k_max = ``damping`` at σ_min = 0, continuous in between; ε = ``region``
    (same unit as σ: m/rad for a position row of J).
    """
    s = np.asarray(sigma_min, dtype=float)
    if not (np.isfinite(damping) and damping >= 0 and np.isfinite(region) and region > 0):
        raise ValueError(
            f"damping must be >= 0 and region > 0 (finite), got {damping!r}, {region!r}"
        )
    return damping * np.sqrt(np.clip(1.0 - (s / region) ** 2, 0.0, None))
