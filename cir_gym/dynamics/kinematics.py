"""Forward kinematics of the chain and the link Jacobians, in numpy from the model arrays.

Each joint i is a twist ξ_i = (v_i, ω_i) in the world frame: ω_i = z_i, v_i = a_i × z_i for a
hinge with axis z_i through the anchor point a_i; ω_i = 0, v_i = z_i for a slide along z_i.
Column j of the position Jacobian of a point x on link i is then ω_j × x + v_j for j ≤ i
(= z_j × (x − a_j) for a hinge, z_j for a slide) and column j of the orientation Jacobian is
ω_j, exactly the textbook's columns [z_{j−1} × (p − p_{j−1}); z_{j−1}] and [z_{j−1}; 0].
Every array carries a leading batch axis N.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from cir_gym.dynamics._spatial import cross, skew
from cir_gym.dynamics.chain import ChainModel


class ChainKinematics(NamedTuple):
    """Link frames and joint twists at a batch of configurations (world frame, SI units).

    Attributes:
        R: link orientations, world ← link.  # (N, n, 3, 3)
        p: link frame origins (m).  # (N, n, 3)
        z: joint axes, unit vectors.  # (N, n, 3)
        a: joint anchors, points on the hinge axes (link origin for a slide) (m).  # (N, n, 3)
        w: angular part of the joint twists, z (hinge) or 0 (slide).  # (N, n, 3)
        v: linear part of the joint twists, a × z (hinge) or z (slide); None when not
            requested.  # (N, n, 3)
    """

    R: np.ndarray
    p: np.ndarray
    z: np.ndarray
    a: np.ndarray
    w: np.ndarray
    v: np.ndarray | None


def forward_kinematics(chain: ChainModel, q: np.ndarray, *, twists: bool = True) -> ChainKinematics:
    """Link frames T_0i = T_01(q_1) ⋯ T_(i−1)i(q_i) by the product of exponentials.

    Args:
        chain: the chain's constant arrays.
        q: joint positions (rad or m).  # (N, n)
        twists: also compute the linear parts v of the joint twists (needed by Jacobians).
    """
    n = chain.n
    revolute = chain.revolute
    theta = q - chain.qpos0
    # T_(i−1)i = T_fix exp(ξ̂ θ) = T_fix + f1 T_fix ξ̂ + f2 T_fix ξ̂² (Rodrigues for twists)
    f1 = np.where(revolute, np.sin(theta), theta) if chain.has_slides else np.sin(theta)
    f2 = 1.0 - np.cos(theta)
    T = chain.T_fix + f1[..., None, None] * chain.X1 + f2[..., None, None] * chain.X2
    # Prefix products T_0i by doubling: after the pass with step s, T[i] = T_(i−2s+1)…T_i.
    step = 1
    while step < n:
        T[:, step:] = T[:, :-step] @ T[:, step:]
        step *= 2
    columns = T @ chain.points  # (N, n, 4, 2): axes and anchors
    z = columns[..., :3, 0]
    a = columns[..., :3, 1]
    w = z * revolute[:, None] if chain.has_slides else z
    v = np.where(revolute[:, None], cross(a, z), z) if twists else None
    return ChainKinematics(R=T[..., :3, :3], p=T[..., :3, 3], z=z, a=a, w=w, v=v)


def point_jacobians(chain: ChainModel, kin: ChainKinematics, points: np.ndarray) -> np.ndarray:
    """Position Jacobians of one point per link, column j = ω_j × x_i + v_j for j ≤ i.

    Args:
        chain: the chain's constant arrays.
        kin: forward kinematics.
        points: one world point x_i fixed to each link i.  # (N, n, 3)

    Returns:
        J_P with J_P[:, i] the 3 x n Jacobian of x_i.  # (N, n, 3, n)
    """
    if kin.v is None:
        raise ValueError("point_jacobians needs forward_kinematics(..., twists=True)")
    w_columns = np.swapaxes(kin.w, -1, -2)[:, None]  # (N, 1, 3, n)
    v_columns = np.swapaxes(kin.v, -1, -2)[:, None]
    return (v_columns - skew(points) @ w_columns) * chain.lower[:, None, :]


def orientation_jacobians(chain: ChainModel, kin: ChainKinematics) -> np.ndarray:
    """Orientation Jacobians of the links, column j = ω_j (z_j or 0) for j ≤ i.  # (N, n, 3, n)"""
    return np.swapaxes(kin.w, -1, -2)[:, None] * chain.lower[:, None, :]
