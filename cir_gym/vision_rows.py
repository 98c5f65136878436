"""The point-feature science of :mod:`cir_gym.vision` on stacked rows: normalised coordinates,
the interaction matrix, the homography and the planar target's pose, the damped inverse.

Each function takes one case or rows of them (leading axes ``...``, e.g. (N, k, 2) features
of N observations) and is :mod:`cir_gym.vision`'s formula written with numpy's stacked
arithmetic: element-wise operations, and one LAPACK call per row's matrix (``svd``, ``det``,
``pinv`` on stacks), so a row gives the same numbers alone or in a batch. Against the
single-case functions of :mod:`cir_gym.vision` a row agrees to round-off (the norms are sums
over an axis instead of dot products; tests/test_visual_servo_vector.py states the tolerance).
Conventions (optical frame, pixels, feature order) are :mod:`cir_gym.vision`'s.
"""

from __future__ import annotations

import numpy as np

from cir_gym.vision import Camera

__all__ = [
    "damped_pinv_rows",
    "homography_rows",
    "interaction_matrix_rows",
    "normalise_rows",
    "planar_pose_rows",
]


def normalise_rows(s: np.ndarray, camera: Camera) -> np.ndarray:
    """Normalised image coordinates (..., k, 2) x_n = (u − c_u)/f_u, y_n = (v − c_v)/f_v of
    pixel features s (..., k, 2)."""
    centre, focal = np.array((camera.cu, camera.cv)), np.array((camera.fu, camera.fv))
    return (np.asarray(s, dtype=float) - centre) / focal


def interaction_matrix_rows(s: np.ndarray, depth: np.ndarray, camera: Camera) -> np.ndarray:
    """Interaction matrices L (..., 2k, 6) of features s (..., k, 2) at depths Z (..., k) (m,
    > 0): :func:`cir_gym.vision.interaction_matrix` on each row (rows 2i, 2i+1: point i).

    Raises:
        ValueError: a depth that is not finite or not > 0.
    """
    xn = normalise_rows(s, camera)
    Z = np.broadcast_to(np.asarray(depth, dtype=float), xn.shape[:-1])
    if not np.all(np.isfinite(Z)) or np.any(Z <= 0.0):
        raise ValueError(f"depth must be finite and > 0, got {Z}")
    x, y = xn[..., 0], xn[..., 1]
    zero = np.zeros_like(x)
    L = np.stack((-1.0 / Z, zero, x / Z, x * y, -(1.0 + x * x), y,  # u row (÷ f_u)
                  zero, -1.0 / Z, y / Z, 1.0 + y * y, -x * y, -x), axis=-1)  # v row (÷ f_v)
    L = L.reshape(*L.shape[:-1], 2, 6) * np.array((camera.fu, camera.fv))[:, None]
    return L.reshape(*L.shape[:-3], 2 * L.shape[-3], 6)  # rows 2i, 2i+1: point i


def homography_rows(plane_points: np.ndarray, image_points: np.ndarray) -> np.ndarray:
    """Homographies H (..., 3, 3), ‖H‖_F = 1, (x, y, 1) ∝ H (X, Y, 1), of k ≥ 4 plane points
    (k, 2) (shared) and normalised image points (..., k, 2): the null vector of each row's
    2k × 9 direct-linear-transform system (:func:`cir_gym.vision.homography`)."""
    P = np.asarray(plane_points, dtype=float)
    P_h = np.concatenate((P, np.ones((len(P), 1))), axis=1)  # (X, Y, 1) (k, 3)
    m = np.asarray(image_points, dtype=float)
    A = np.zeros((*m.shape[:-1], 2, 9))  # (..., k, 2, 9): rows 2i, 2i+1 of point i
    A[..., 0, :3] = P_h
    A[..., 0, 6:] = -m[..., 0, None] * P_h  # −x (X, Y, 1)
    A[..., 1, 3:6] = P_h
    A[..., 1, 6:] = -m[..., 1, None] * P_h  # −y (X, Y, 1)
    A = A.reshape(*A.shape[:-3], 2 * A.shape[-3], 9)
    return np.linalg.svd(A)[2][..., -1, :].reshape(*A.shape[:-2], 3, 3)


def planar_pose_rows(model_points: np.ndarray, s: np.ndarray, camera: Camera
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Poses (R (..., 3, 3) target→camera, t (..., 3) m) of a planar target from the features
    s (..., k, 2) of its k ≥ 4 points ``model_points`` (k, 3) (plane z = 0):
    :func:`cir_gym.vision.planar_pose` on each row (H ∝ [r₁ r₂ t] scaled by the mean of
    1/‖h₁‖, 1/‖h₂‖ with t_z > 0, r₃ = r₁ × r₂, the nearest rotation by SVD).

    Raises:
        ValueError: model points off the plane z = 0.
    """
    P = np.asarray(model_points, dtype=float).reshape(-1, 3)
    if np.any(np.abs(P[:, 2]) > 1e-12):
        raise ValueError("planar_pose_rows needs model points in the plane z = 0")
    H = homography_rows(P[:, :2], normalise_rows(s, camera))
    h1, h2 = H[..., :, 0], H[..., :, 1]
    scale = 2.0 / (np.sqrt(np.sum(h1 * h1, axis=-1)) + np.sqrt(np.sum(h2 * h2, axis=-1)))
    H = H * scale[..., None, None]
    H = np.where(H[..., 2:, 2:] < 0.0, -H, H)  # t_z = H[2, 2] > 0: the target in front
    r1, r2 = H[..., :, 0], H[..., :, 1]
    M = H.copy()
    M[..., :, 2] = _cross(r1, r2)  # [r₁ r₂ r₁ × r₂]
    U, _, Vt = np.linalg.svd(M)
    U[..., :, 2] *= np.linalg.det(U @ Vt)[..., None]  # U diag(1, 1, det(U Vᵀ))
    return U @ Vt, H[..., :, 2].copy()


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b (..., 3) of rows of 3-vectors (np.cross's formula without its axis handling)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


def damped_pinv_rows(A: np.ndarray, damping: float) -> np.ndarray:
    """Damped least-squares inverses A* = V diag(σᵢ / (σᵢ² + μ²)) Uᵀ (..., n, m) of A
    (..., m, n) (:func:`cir_gym.vision.damped_pinv`; μ = ``damping`` ≥ 0, 0: the
    pseudo-inverse)."""
    if not np.isfinite(damping) or damping < 0.0:
        raise ValueError(f"damping must be a finite number >= 0, got {damping!r}")
    if damping == 0.0:
        return np.linalg.pinv(A)
    U, sigma, Vt = np.linalg.svd(np.asarray(A, dtype=float), full_matrices=False)
    gains = sigma / (sigma * sigma + damping * damping)
    return (np.swapaxes(Vt, -1, -2) * gains[..., None, :]) @ np.swapaxes(U, -1, -2)
