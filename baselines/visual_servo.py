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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from cir_gym.baselines.base import Controller, InvalidGain, Observation

from cir_gym.context import TaskContext
from cir_gym.vision import (
    Camera,
    damped_pinv,
    interaction_matrix,
    normalise,
    planar_pose,
    pose_error,
    transform_points,
)

__all__ = ["IBVS", "PBVS", "VISUAL_SERVO_CONTROLLERS", "EyeToHandIBVS", "adaptive_gain"]

DEPTHS = ("current", "desired", "mean")


def adaptive_gain(x: float, lambda_0: float, lambda_inf: float, slope: float) -> float:
    """ViSP's adaptive gain λ(x) = (λ₀ − λ∞) exp(−λ'₀ x / (λ₀ − λ∞)) + λ∞ (1/s)."""
    span = lambda_0 - lambda_inf
    if span <= 0.0:
        return lambda_inf
    return float(span * np.exp(-slope * x / span) + lambda_inf)


def _skew(p: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])


def _fit(command: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """``command`` scaled down uniformly so that |command_i| ≤ limit_i (direction kept)."""
    ratio = float(np.max(np.abs(command) / limit))
    return command / ratio if ratio > 1.0 else command


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
    """Shared: the camera model, the target model, the action mapping."""

    Gains = ServoGains

    def __init__(self, context: TaskContext, gains: Any = None, robot: Any = None,
                 **overrides: Any) -> None:
        super().__init__(context, gains, **overrides)
        extras = context.extras
        self.camera: Camera = extras["camera"]
        self.model_points = np.asarray(extras["model_points"], dtype=float)
        self.twist_limit = np.asarray(extras["twist_limit"], dtype=float)
        self.velocity_limit = np.asarray(extras["velocity_limit"], dtype=float)
        self.moving_offset = float(extras["moving_offset"])
        self.robot = robot if robot is not None else context.nominal_robot()
        self.site = context.site

    def _gain(self, e: np.ndarray) -> float:
        if self.gains.adaptive is None:
            return self.gains.gain
        x = float(np.max(np.abs(e)))  # ‖e‖∞ in normalised coordinates
        return adaptive_gain(x, *self.gains.adaptive)

    def _features(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        return (np.asarray(obs["features"], dtype=float).reshape(4, 2),
                np.asarray(obs["features_ref"], dtype=float).reshape(4, 2))

    def _pose(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return planar_pose(self.model_points, s, self.camera)

    def _depths(self, s: np.ndarray) -> np.ndarray:
        R, t = self._pose(s)
        return np.maximum(transform_points(R, t, self.model_points)[:, 2], 1e-3)

    def _L(self, s: np.ndarray, s_ref: np.ndarray, extra: Any = None) -> np.ndarray:
        """L̂ (8, 6) at the current, the desired or both (mean) features."""
        depth = self.gains.depth
        parts = []
        if depth in ("current", "mean"):
            parts.append(self._interaction(s))
        if depth in ("desired", "mean"):
            parts.append(self._interaction(s_ref))
        return sum(parts) / len(parts)

    def _interaction(self, s: np.ndarray) -> np.ndarray:
        return interaction_matrix(s, self._depths(s), self.camera)

    def _inverse(self, A: np.ndarray) -> np.ndarray:
        """The damped least-squares inverse A* of an image Jacobian (``damping`` μ)."""
        return damped_pinv(A, self.gains.damping)

    def _error(self, s: np.ndarray, s_ref: np.ndarray) -> tuple[np.ndarray, float]:
        """e (8,) in pixels and the gain λ (adaptive on the normalised error)."""
        e = (s - s_ref).ravel()
        return e, self._gain(normalise(s, self.camera) - normalise(s_ref, self.camera))

    def _camera_action(self, twist: np.ndarray, obs: Observation) -> np.ndarray:
        """Eye-in-hand: the camera twist (optical = flange frame) as the env's command."""
        if self.context.action_kind == "twist":
            return _fit(twist, self.twist_limit)
        q = np.asarray(obs["q"], dtype=float)
        R = self.robot.site_pose(self.site, q)[1]
        J = self.robot.jacobian(self.site, q)
        qd = np.linalg.pinv(J) @ np.concatenate((R @ twist[:3], R @ twist[3:]))
        return _fit(qd, self.velocity_limit)


class IBVS(_VisualServo):
    """Image-based visual servoing, eye in hand: v_c = −λ L̂* (s − s*)."""

    name = "ibvs"
    tasks = ("VisualServo",)

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        s, s_ref = self._features(obs)
        e, lam = self._error(s, s_ref)
        twist = -lam * self._inverse(self._L(s, s_ref)) @ e
        return self._camera_action(twist, obs)


class PBVS(_VisualServo):
    """Position-based visual servoing, eye in hand: v = −λ c*R_cᵀ c*t_c, ω = −λ θu."""

    name = "pbvs"
    tasks = ("VisualServo",)

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        s, s_ref = self._features(obs)
        R, t = self._pose(s)
        R_ref, t_ref = self._pose(s_ref)
        t_e, theta_u = pose_error(R, t, R_ref, t_ref)
        lam = self._gain(np.concatenate((t_e, theta_u)))
        R_e = R_ref @ R.T
        twist = np.concatenate((-lam * R_e.T @ t_e, -lam * theta_u))
        return self._camera_action(twist, obs)


class EyeToHandIBVS(_VisualServo):
    """Image-based visual servoing with a fixed camera: V_m = −λ (L̂ G)* e, or through the
    robot Jacobian q̇ = −λ (L̂ G M J(q))* e (``action="joint_velocity"``)."""

    name = "ibvs_eye_to_hand"
    tasks = ("VisualServoEyeToHand",)

    def __init__(self, context: TaskContext, gains: Any = None, robot: Any = None,
                 **overrides: Any) -> None:
        super().__init__(context, gains, robot, **overrides)
        self.camera_position, self.camera_rotation = (np.asarray(a, dtype=float) for a in
                                                      context.extras["camera_pose"])

    def _interaction(self, s: np.ndarray) -> np.ndarray:
        """L G (8, 6): features against the markers' twist in the camera frame."""
        R, t = self._pose(s)
        Z = np.maximum(transform_points(R, t, self.model_points)[:, 2], 1e-3)
        G = np.zeros((6, 6))
        G[:3, :3] = -np.eye(3)
        G[:3, 3:] = -_skew(t)
        G[3:, 3:] = -np.eye(3)
        return interaction_matrix(s, Z, self.camera) @ G

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        s, s_ref = self._features(obs)
        e, lam = self._error(s, s_ref)
        LG = self._L(s, s_ref)
        if self.context.action_kind == "twist":
            return _fit(-lam * self._inverse(LG) @ e, self.twist_limit)
        q = np.asarray(obs["q"], dtype=float)
        R_f = self.robot.site_pose(self.site, q)[1]
        J = self.robot.jacobian(self.site, q)
        Rc = self.camera_rotation  # optical → world (nominal extrinsics)
        r = self.moving_offset * R_f[:, 2]  # flange → marker origin (world)
        M = np.zeros((6, 6))  # flange world twist → marker twist in camera axes
        M[:3, :3] = Rc.T
        M[:3, 3:] = -Rc.T @ _skew(r)  # v_m = v_f + ω × r
        M[3:, 3:] = Rc.T
        J_image = LG @ M @ J
        return _fit(-lam * self._inverse(J_image) @ e, self.velocity_limit)


VISUAL_SERVO_CONTROLLERS: tuple[type[Controller], ...] = (IBVS, PBVS, EyeToHandIBVS)
