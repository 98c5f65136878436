"""Chapter 7: image-based and position-based visual servoing as policies.

Every law computes a twist and hands the environment an action in [-1, 1]: the twist divided
by the twist limits, scaled down uniformly when a component would exceed 1 (the direction of
the twist is kept, unlike a per-component clip). With ``action="joint_velocity"`` the twist is
mapped through the controller's own nominal robot Jacobian and scaled the same way to the
joint-velocity limits.

Notation (control-laws.md §7, :mod:`cir_gym.vision`): s, s* (4, 2) the current and desired
pixel features, e = s − s* (8,), L(s, Z) the interaction matrix (8, 6) of the camera twist
(v, ω) in the optical frame. The depths Z are not observed: they are estimated from the four
points and the known target model (``planar_pose``: homography decomposition with the nominal
intrinsics), so a calibration error reaches the depth estimate as it would on a real robot.

* ``ibvs``: v_c = −λ L̂* e with L̂ = L(s, Ẑ) ("current"), L(s*, Z*) ("desired") or
  ½ (L(s, Ẑ) + L(s*, Z*)) ("mean", Malis's choice), and L̂* the damped least-squares inverse
  below. With an exact L̂ = L the features obey ė = −λ e: e(t) = e(0) exp(−λ t), straight
  lines in the image. ViSP's adaptive gain
  λ(x) = (λ₀ − λ∞) exp(−λ'₀ x / (λ₀ − λ∞)) + λ∞ (x = ‖e‖∞ in normalised coordinates) is an
  option (``adaptive``).
* ``pbvs``: the target's pose (R, t) in the current camera and (R*, t*) in the desired one
  give the current camera's pose in the desired frame, t_e = c*t_c and θu of c*R_c
  (:func:`cir_gym.vision.pose_error`); v_c = −λ c*R_cᵀ t_e, ω_c = −λ θu: t_e and θu both decay
  as exp(−λ t) and the camera moves on a straight line (Chaumette & Hutchinson 2006).
* ``ibvs_eye_to_hand``: a fixed camera and markers on the end effector. The markers' frame
  (origin p_m in the camera frame) moving with twist (v_m, ω_m) (camera axes) moves the
  features like a camera twist (v_c, ω_c) = (−v_m − [p_m]× ω_m, −ω_m), so
  ṡ = L G V_m with G = [[−I, −[p_m]×], [0, −I]]; V_m = −λ (L̂ G)⁺ e, and with joint velocities
  through the robot Jacobian the image Jacobian J_I = L̂ G M J(q) (M: the flange's world twist
  to the markers' twist in the nominal camera frame), q̇ = −λ J_I* e.

Damped least squares (control-laws.md §1, the course's inverse near singularities): the IBVS
laws invert L̂ (and L̂ G, J_I) as A* = Aᵀ (A Aᵀ + μ² I)⁻¹ = V diag(σᵢ / (σᵢ² + μ²)) Uᵀ
(:func:`cir_gym.vision.damped_pinv`) with μ = ``damping`` = 1 px per unit twist (m/s, rad/s;
per rad/s of joint velocity for J_I). Design: on the default episodes the smallest singular
value of L̂ is 8.7 … 13 px (current, desired and mean L̂, 12 seeds), so μ = 1 px keeps at least
98.7 % of the pseudo-inverse's gain in every direction there (σ² / (σ² + μ²)), while a
direction whose σ falls below μ is attenuated instead of inverted: ‖L̂* e‖ ≤ ‖e‖ / (2 μ). The
mean L̂ is singular at a rotation of π about the optical axis (s = −s* about the principal
point: the v_z and ω_z columns of L(s) and L(s*) cancel, smallest σ 8e-11 px), where the
pseudo-inverse turned the camera at full speed in a direction its round-off chose (1/σ ≈ 1e10).
With the damping the law asks for no turn at the singular point itself (the error is
orthogonal to the range of L̂: an unstable equilibrium); whatever breaks the symmetry (feature
noise, the start pose's last bits) grows and chooses the direction, at the law's own rate.
``damping=0`` is the pseudo-inverse. PBVS inverts nothing: its rotation error θu has no
defined axis at θ = π, so there too the noise of the pose estimate chooses the turn.

Gains: λ = 0.5 1/s, ViSP's tutorial-ibvs-4pts value at its 40 ms period (the default
control period here); the adaptive option's ViSP values are λ₀ = 4, λ∞ = 0.4, λ'₀ = 30.

Rows: ``ibvs`` and ``pbvs`` are written once on rows of observations (``RowLaw``), one
observation being a row of one: a batch (a vector env's copies, the batched evaluator, a
residual agent's base) gives each row the command it gives alone, bit for bit
(tests/test_visual_servo_rows.py). The laws' vision steps are :mod:`cir_gym.vision`'s
functions, which take one observation or rows of them (element-wise numpy and one LAPACK call
per row's matrix, so a row gives the same numbers alone or in a batch). So is
``ibvs_eye_to_hand`` (its nominal-robot Jacobians, with ``action="joint_velocity"``, row by
row).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from cir_gym.baselines.base import Controller, InvalidGain, Observation, RowLaw

from cir_gym.context import TaskContext
from cir_gym.trajectories import skew
from cir_gym.vision import (
    damped_pinv,
    interaction_matrix,
    normalise,
    planar_pose,
    pose_error,
    transform_points,
)

__all__ = ["IBVS", "PBVS", "VISUAL_SERVO_CONTROLLERS", "EyeToHandIBVS", "adaptive_gain"]

DEPTHS = ("current", "desired", "mean")


def adaptive_gain(x: float | np.ndarray, lambda_0: float, lambda_inf: float, slope: float
                  ) -> float | np.ndarray:
    """ViSP's adaptive gain λ(x) = (λ₀ − λ∞) exp(−λ'₀ x / (λ₀ − λ∞)) + λ∞ (1/s) of an error
    size x (a number, or rows (N,): λ (N,))."""
    span = lambda_0 - lambda_inf
    if span <= 0.0:
        return lambda_inf if np.ndim(x) == 0 else np.full(np.shape(x), lambda_inf)
    value = span * np.exp(-slope * np.asarray(x, dtype=float) / span) + lambda_inf
    return float(value) if np.ndim(value) == 0 else value


def _fit(command: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """``command`` (..., m) scaled down uniformly (each row) so that |command_i| ≤ limit_i
    (direction kept)."""
    ratio = np.max(np.abs(command) / limit, axis=-1)
    return command / np.maximum(ratio, 1.0)[..., None]  # a command within its limits / 1


def _matvec(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A x (..., m) of matrices A (..., m, n) and vectors x (..., n): one matrix-vector product
    per row."""
    return (A @ x[..., None])[..., 0]


@dataclass(frozen=True)
class ServoGains:
    """Visual-servoing gains.

    Attributes:
        gain: λ (1/s), the feature (or pose) error's decay rate.
        depth: where L̂ is evaluated: "current", "desired" or "mean" (IBVS laws only).
        adaptive: (λ₀, λ∞, λ'₀) for ViSP's adaptive gain instead of ``gain``, or None.
        damping: μ (px per unit twist), the damped least-squares inverse's damping (IBVS laws;
            0: the pseudo-inverse). See the module docstring for its design.
    """

    gain: float = 0.5
    depth: str = "current"
    adaptive: tuple[float, float, float] | None = None
    damping: float = 1.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.gain) or self.gain <= 0:
            raise InvalidGain(f"gain must be a finite number > 0 (1/s), got {self.gain!r}")
        if not np.isfinite(self.damping) or self.damping < 0:
            raise InvalidGain(f"damping must be a finite number >= 0 (px), got {self.damping!r}")
        if self.depth not in DEPTHS:
            raise InvalidGain(f"depth must be one of {DEPTHS}, got {self.depth!r}")
        if self.adaptive is not None:
            a = np.asarray(self.adaptive, dtype=float)
            if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a <= 0):
                raise InvalidGain(f"adaptive must be None or (λ₀, λ∞, λ'₀) > 0, got "
                                  f"{self.adaptive!r}")


class _VisualServo(Controller):
    """Shared: the camera model, the target model, the action limits, and the laws' steps on
    one observation's features s (4, 2) or on rows of them (N, 4, 2) (:mod:`cir_gym.vision`'s
    functions: a row gives the same numbers alone or in a batch)."""

    Gains = ServoGains

    def __init__(self, context: TaskContext, gains: Any = None, robot: Any = None,
                 **overrides: Any) -> None:
        super().__init__(context, gains, **overrides)
        extras = context.extras
        self.camera = extras["camera"]
        self.model_points = np.asarray(extras["model_points"], dtype=float)
        self.twist_limit = np.asarray(extras["twist_limit"], dtype=float)
        self.velocity_limit = np.asarray(extras["velocity_limit"], dtype=float)
        self.moving_offset = float(extras["moving_offset"])
        self.robot = robot if robot is not None else context.nominal_robot()
        self.site = context.site

    def _gain(self, size: float | np.ndarray) -> float | np.ndarray:
        """λ (1/s): ``gain``, or the adaptive gain of the error's size ‖e‖∞ (rows: (N,))."""
        if self.gains.adaptive is None:
            return self.gains.gain
        return adaptive_gain(size, *self.gains.adaptive)

    def _features(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """s, s* (..., 4, 2) px."""
        s, s_ref = (np.asarray(obs[key], dtype=float) for key in ("features", "features_ref"))
        return s.reshape(*s.shape[:-1], 4, 2), s_ref.reshape(*s_ref.shape[:-1], 4, 2)

    def _pose(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The target's pose (R (..., 3, 3), t (..., 3)) in the camera, from s (..., 4, 2)."""
        return planar_pose(self.model_points, s, self.camera)

    def _depths(self, s: np.ndarray) -> np.ndarray:
        """Ẑ (..., 4) m of the points (≥ 1 mm), from their pose estimate."""
        R, t = self._pose(s)
        return np.maximum(transform_points(R, t, self.model_points)[..., 2], 1e-3)  # R P + t

    def _L(self, s: np.ndarray, s_ref: np.ndarray) -> np.ndarray:
        """L̂ (..., 8, 6) at the current, the desired or both (mean) features."""
        depth = self.gains.depth
        parts = []
        if depth in ("current", "mean"):
            parts.append(self._interaction(s))
        if depth in ("desired", "mean"):
            parts.append(self._interaction(s_ref))
        return sum(parts) / len(parts)

    def _interaction(self, s: np.ndarray) -> np.ndarray:
        """L(s, Ẑ) (..., 8, 6)."""
        return interaction_matrix(s, self._depths(s), self.camera)

    def _inverse(self, A: np.ndarray) -> np.ndarray:
        """The damped least-squares inverse A* of image Jacobians (..., 8, 6) (``damping`` μ)."""
        return damped_pinv(A, self.gains.damping)

    def _flange_rows(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nominal robot's flange rotations R (N, 3, 3), flange → world, and geometric
        Jacobians J (N, 6, 7) at the joints q (N, 7), row by row."""
        R = np.stack([self.robot.site_pose(self.site, q_i)[1] for q_i in q])
        J = np.stack([self.robot.jacobian(self.site, q_i) for q_i in q])
        return R, J

    def _error(self, s: np.ndarray, s_ref: np.ndarray) -> tuple[np.ndarray, Any]:
        """e (..., 8) in pixels and the gain λ (adaptive on the normalised error's ‖·‖∞)."""
        e = (s - s_ref).reshape(*s.shape[:-2], 8)
        normalised = normalise(s, self.camera) - normalise(s_ref, self.camera)
        return e, self._gain(np.max(np.abs(normalised), axis=(-2, -1)))


class _EyeInHand(_VisualServo, RowLaw):
    """An eye-in-hand law written on rows (:meth:`control_rows`): one observation is its one-row
    case (``RowLaw``)."""

    def _camera_action(self, twist: np.ndarray, obs: Observation) -> np.ndarray:
        """The camera twists (N, 6) (optical = flange frame) as the env's commands (N, m): the
        twists, or q̇ = J⁺ [R v; R ω] through the nominal robot (row by row), each scaled down
        uniformly to its limits."""
        if self.context.action_kind == "twist":
            return _fit(twist, self.twist_limit)
        R, J = self._flange_rows(np.asarray(obs["q"], dtype=float))
        world = np.concatenate((_matvec(R, twist[:, :3]), _matvec(R, twist[:, 3:])), axis=1)
        return _fit(_matvec(np.linalg.pinv(J), world), self.velocity_limit)


class IBVS(_EyeInHand):
    """Image-based visual servoing, eye in hand: v_c = −λ L̂* (s − s*)."""

    name = "ibvs"
    tasks = ("VisualServo",)

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        s, s_ref = self._features(obs)
        e, lam = self._error(s, s_ref)
        gain = -np.broadcast_to(lam, e.shape[:1])[:, None, None]  # −λ (N, 1, 1)
        twist = _matvec(gain * self._inverse(self._L(s, s_ref)), e)
        return self._camera_action(twist, obs)


class PBVS(_EyeInHand):
    """Position-based visual servoing, eye in hand: v = −λ c*R_cᵀ c*t_c, ω = −λ θu."""

    name = "pbvs"
    tasks = ("VisualServo",)

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        s, s_ref = self._features(obs)
        R, t = self._pose(s)
        R_ref, t_ref = self._pose(s_ref)
        t_e, theta_u = pose_error(R, t, R_ref, t_ref)  # c*t_c, θu of c*R_c (N, 3) each
        R_e = R_ref @ np.swapaxes(R, 1, 2)  # c*R_c (N, 3, 3)
        lam = self._gain(np.max(np.abs(np.concatenate((t_e, theta_u), axis=1)), axis=1))
        lam = np.broadcast_to(lam, t_e.shape[:1])[:, None]  # (N, 1)
        v = _matvec(-lam[:, :, None] * np.swapaxes(R_e, 1, 2), t_e)
        return self._camera_action(np.concatenate((v, -lam * theta_u), axis=1), obs)


class EyeToHandIBVS(_VisualServo, RowLaw):
    """Image-based visual servoing with a fixed camera: V_m = −λ (L̂ G)* e, or through the
    robot Jacobian q̇ = −λ (L̂ G M J(q))* e (``action="joint_velocity"``); written on rows
    (:meth:`control_rows`), one observation is its one-row case (``RowLaw``)."""

    name = "ibvs_eye_to_hand"
    tasks = ("VisualServoEyeToHand",)

    def __init__(self, context: TaskContext, gains: Any = None, robot: Any = None,
                 **overrides: Any) -> None:
        super().__init__(context, gains, robot, **overrides)
        self.camera_position, self.camera_rotation = (np.asarray(a, dtype=float) for a in
                                                      context.extras["camera_pose"])

    def _interaction(self, s: np.ndarray) -> np.ndarray:
        """L G (N, 8, 6): features against the markers' twist in the camera frame, of rows
        s (N, 4, 2)."""
        R, t = self._pose(s)
        Z = np.maximum(transform_points(R, t, self.model_points)[..., 2], 1e-3)
        G = np.zeros((*t.shape[:-1], 6, 6))
        G[..., :3, :3] = -np.eye(3)
        G[..., :3, 3:] = -skew(t)
        G[..., 3:, 3:] = -np.eye(3)
        return interaction_matrix(s, Z, self.camera) @ G

    def _marker_map(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(M (N, 6, 6), J (N, 6, 7)) at the joints q (N, 7), through the nominal robot (row by
        row): J the flange's geometric Jacobian, M its world twist → the markers' twist in the
        nominal camera's axes, v_m = Rcᵀ (v_f + ω × r), ω_m = Rcᵀ ω (r: flange → marker
        origin)."""
        R_f, J = self._flange_rows(q)
        Rc = self.camera_rotation  # optical → world (nominal extrinsics)
        r = self.moving_offset * R_f[:, :, 2]  # (N, 3) world
        M = np.zeros((len(q), 6, 6))
        M[:, :3, :3] = Rc.T
        M[:, :3, 3:] = -Rc.T @ skew(r)  # v_m = v_f + ω × r
        M[:, 3:, 3:] = Rc.T
        return M, J

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        s, s_ref = self._features(obs)
        e, lam = self._error(s, s_ref)
        gain = -np.broadcast_to(lam, e.shape[:1])[:, None, None]  # −λ (N, 1, 1)
        LG = self._L(s, s_ref)
        if self.context.action_kind == "twist":
            return _fit(_matvec(gain * self._inverse(LG), e), self.twist_limit)
        M, J = self._marker_map(np.asarray(obs["q"], dtype=float))
        J_image = LG @ M @ J  # (N, 8, 7)
        return _fit(_matvec(gain * self._inverse(J_image), e), self.velocity_limit)


VISUAL_SERVO_CONTROLLERS: tuple[type[Controller], ...] = (IBVS, PBVS, EyeToHandIBVS)
