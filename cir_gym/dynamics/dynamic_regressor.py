"""The dynamic regressor Y(q, q̇, q̈) with τ = Y π, and its Slotine-Li form.

The Newton-Euler equations of link i about its frame origin O_i, in link-frame axes, are linear
in π_i = [m, m c, I_O]:

    f_i = m a_O + ω̇ × m c + ω × (ω × m c)
    n_i = I_O ω̇ + ω × (I_O ω) + m c × a_O

with a_O the acceleration of O_i (gravity included as −g₀) and ω, ω̇ from the Newton-Euler
forward recursion. So [f_i; n_i] = W_i π_i with a 6 x 10 matrix W_i of kinematic quantities, and
τ = Σ_i J_iᵀ [f_i; n_i] with J_i the geometric Jacobian of O_i in link-frame axes gives the
block Y_i = J_iᵀ W_i. The last n columns multiply the armatures: diag(q̈).

Slotine-Li: with qd_r given, Y π = B(q) q̈_r + C(q, q̇) q̇_r + g(q) with the Christoffel C.
Because C(q, a) b is symmetric in a and b, it is the polar form of h(v) = C(q, v) v (the
velocity part of the regressor, quadratic in v): C(q, a) b = ¼ [h(a + b) − h(a − b)]
= h((a + b)/2) − h((a − b)/2). So Y_SL = Y(q, (q̇ + q̇_r)/2, q̈_r) − Y_v(q, (q̇ − q̇_r)/2) with
Y_v the velocity-only regressor (no acceleration, no gravity): two regressor evaluations.
"""

from __future__ import annotations

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from cir_gym.dynamics._checks import as_batch, matching_batch
from cir_gym.dynamics._spatial import skew
from cir_gym.dynamics.chain import ChainModel, chain_model
from cir_gym.dynamics.kinematics import (
    ChainKinematics,
    forward_kinematics,
    orientation_jacobians,
    point_jacobians,
)
from cir_gym.dynamics.newton_euler import link_accelerations

# (v @ _INERTIA_PRODUCT).reshape(3, 6) = L(v), with L(v) [I_xx, I_xy, I_xz, I_yy, I_yz, I_zz] = I v.
_INERTIA_PRODUCT = np.zeros((3, 18))
for _row, _column, _component in (
    (0, 0, 0), (0, 1, 1), (0, 2, 2),
    (1, 1, 0), (1, 3, 1), (1, 4, 2),
    (2, 2, 0), (2, 4, 1), (2, 5, 2),
):  # fmt: skip
    _INERTIA_PRODUCT[_component, 6 * _row + _column] = 1.0


def _inertia_product(vector: np.ndarray) -> np.ndarray:
    """L(v) such that L(v) π_I = I v.  # (..., 3) -> (..., 3, 6)"""
    return (vector @ _INERTIA_PRODUCT).reshape(*vector.shape[:-1], 3, 6)


def _link_frame_jacobians(chain: ChainModel, kin: ChainKinematics) -> np.ndarray:
    """Geometric Jacobians of the link-frame origins, in link-frame axes.  # (N, n, 6, n)"""
    J_P = point_jacobians(chain, kin, kin.p)  # (N, n, 3, n)
    J_O = orientation_jacobians(chain, kin)
    R_T = np.swapaxes(kin.R, -1, -2)
    return np.concatenate([R_T @ J_P, R_T @ J_O], axis=-2)


def _regressor(
    chain: ChainModel,
    kin: ChainKinematics,
    jacobians: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    base_acceleration: np.ndarray,
) -> np.ndarray:
    """Y for motions (..., N, n) at the configurations of ``kin``.  # (..., N, n, 11 n)"""
    n = chain.n
    motion = link_accelerations(chain, kin, qd, qdd, base_acceleration, kin.p)
    # Rotate ω, ω̇ and a_O (acceleration of the link origin) into the link frames.
    world = np.concatenate(
        (motion.omega[..., None], motion.omega_dot[..., None], motion.acceleration[..., None]), -1
    )
    local = np.swapaxes(kin.R, -1, -2) @ world
    w, dw, acc = local[..., 0], local[..., 1], local[..., 2]
    S_w = skew(w)
    W = np.zeros((*w.shape[:-1], 6, 10))
    W[..., :3, 0] = acc  # m a_O
    W[..., :3, 1:4] = skew(dw) + S_w @ S_w  # ω̇ × m c + ω × (ω × m c)
    W[..., 3:, 1:4] = -skew(acc)  # m c × a_O
    W[..., 3:, 4:] = _inertia_product(dw) + S_w @ _inertia_product(w)  # I ω̇ + ω × I ω
    links = np.swapaxes(jacobians, -1, -2) @ W  # Y_i = J_iᵀ W_i, (..., i, j, 10)
    links = np.swapaxes(links, -3, -2).reshape(*links.shape[:-3], n, 10 * n)
    armature = qdd[..., :, None] * np.eye(n)  # τ_i += armature_i q̈_i
    return np.concatenate([links, armature], axis=-1)


def regressor(
    model: mujoco.MjModel,
    q: ArrayLike,
    qd: ArrayLike,
    qdd: ArrayLike,
    *,
    qd_r: ArrayLike | None = None,
    gravity: bool = True,
) -> np.ndarray:
    """Regressor Y, linear map from the dynamic parameters π to the joint torques.

    ``regressor(model, q, qd, qdd) @ inertial_parameters(model) == rnea(model, q, qd, qdd)``.
    Y depends on the kinematics (and gravity) only, never on the model's inertial values.

    Args:
        model: a serial chain of hinge/slide joints (see ``cir_gym.dynamics``).
        q: joint positions (rad or m).  # (n,) or (N, n)
        qd: joint velocities q̇.  # like q
        qdd: joint accelerations (q̈, or q̈_r for Slotine-Li).  # like q
        qd_r: reference velocity q̇_r; if given, Y π = B(q) qdd + C(q, q̇) q̇_r + g(q) with the
            Christoffel C (Slotine-Li adaptive control).  # like q
        gravity: include the gravity terms (base acceleration −g₀).

    Returns:
        Y with columns ordered like ``parameter_names(model)``.  # (n, 11 n) or (N, n, 11 n)
    """
    chain = chain_model(model)
    n = chain.n
    q, single = as_batch("q", q, n)
    qd = matching_batch("qd", qd, n, q, single)
    qdd = matching_batch("qdd", qdd, n, q, single)
    kin = forward_kinematics(chain, q)
    jacobians = _link_frame_jacobians(chain, kin)
    base = -chain.gravity if gravity else np.zeros(3)
    if qd_r is None:
        Y = _regressor(chain, kin, jacobians, qd, qdd, base)
    else:
        qd_r = matching_batch("qd_r", qd_r, n, q, single)
        # Y(q, (q̇ + q̇_r)/2, q̈_r) with gravity, minus h((q̇ − q̇_r)/2) without
        velocities = np.stack([0.5 * (qd + qd_r), 0.5 * (qd - qd_r)])
        accelerations = np.stack([qdd, np.zeros_like(qdd)])
        bases = np.zeros((2, 1, 1, 3))
        bases[0] = base
        Ys = _regressor(chain, kin, jacobians, velocities, accelerations, bases)
        Y = Ys[0] - Ys[1]
    return Y[0] if single else Y
