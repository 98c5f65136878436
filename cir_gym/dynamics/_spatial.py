"""Small 3-D helpers: cross-product matrices, cross products, quaternions to rotations."""

from __future__ import annotations

import numpy as np


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions (w, x, y, z), normalised first.

    # (..., 4) -> (..., 3, 3)
    """
    quat = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(quat, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def skew(vector: np.ndarray) -> np.ndarray:
    """Cross-product matrices S(v), S(v) u = v × u.  # (..., 3) -> (..., 3, 3)"""
    return (vector @ _LEVI_CIVITA).reshape(*vector.shape[:-1], 3, 3)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b for broadcastable stacks of 3-vectors (faster than ``np.cross`` on small arrays)."""
    return (skew(a) @ b[..., None])[..., 0]


# (v @ _LEVI_CIVITA).reshape(3, 3) = S(v): for each even permutation (i, j, k),
# S[i, j] = −v_k and S[j, i] = +v_k.
_LEVI_CIVITA = np.zeros((3, 9))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _LEVI_CIVITA[_k, 3 * _j + _i] = 1.0
    _LEVI_CIVITA[_k, 3 * _i + _j] = -1.0
