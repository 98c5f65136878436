"""Small 3-D helpers: cross products, quaternions to rotations; the cross-product matrix S(v) is
:func:`cir_gym.trajectories.skew`, imported here for the dynamics modules."""

from __future__ import annotations

import numpy as np

from cir_gym.trajectories import skew  # S(v) x = v × x, for the dynamics modules


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


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b for broadcastable stacks of 3-vectors (faster than ``np.cross`` on small arrays)."""
    return (skew(a) @ b[..., None])[..., 0]

