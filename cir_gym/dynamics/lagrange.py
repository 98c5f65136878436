"""Euler-Lagrange dynamics terms: B(q), ∂B/∂q, the Christoffel C(q, q̇) and g(q).

    B(q) = Σ_i [m_i J_P^(ℓi)ᵀ J_P^(ℓi) + J_O^(ℓi)ᵀ R_i I_i R_iᵀ J_O^(ℓi)] + diag(armature)
    c_ijk = ½ (∂b_ij/∂q_k + ∂b_ik/∂q_j − ∂b_jk/∂q_i),  c_ij = Σ_k c_ijk q̇_k
    g_i(q) = −Σ_j m_j g₀ᵀ J_P,i^(ℓj)(q)

J_P^(ℓi) is the Jacobian of link i's centre of mass C_i and I_i its inertia about C_i. We use
the same sums written about the link-frame origin O_i (the form of the textbook's "linearity
in the dynamic parameters"): with J_v the Jacobian of O_i, h_i = R_i m_i r_Ci the first moment
and Ī_i = R_i (I_i + m_i S(r_Ci)ᵀ S(r_Ci)) R_iᵀ the inertia about O_i,
J_P^(ℓi) = J_v − S(R_i r_Ci) J_O turns the terms of link i into

    m_i J_vᵀ J_v + J_vᵀ S(h_i)ᵀ J_O + J_Oᵀ S(h_i) J_v + J_Oᵀ Ī_i J_O = J_iᵀ M_i J_i,
    J_i = [J_v; J_O],  M_i = [[m_i E, −S(h_i)], [S(h_i), Ī_i]] (spatial inertia about O_i),

and m_j J_P^(ℓj) g₀ = J_vᵀ m_j g₀ + J_Oᵀ (h_j × g₀). Identical for a physical link, but linear in
π = [m, m r_C, Ī] and free of a division by m_i, so it holds for any parameter vector (an
identified or adapted estimate, a massless link with a first moment).

The derivatives of B are exact. With ω_j the angular part of joint j's twist (z_j or 0):
∂J_v,j/∂q_k = ω_min(j,k) × J_v,max(j,k) (for a point on link i ≥ j, k), ∂J_O,j/∂q_k = ω_k × ω_j for
k < j (else 0), and M_i rotates with the link: ∂M_i/∂q_k = Ŝ_k M_i − M_i Ŝ_k for k ≤ i,
Ŝ_k = diag(S(ω_k), S(ω_k)). These are ∂z_j/∂q_k = z_k × z_j and ∂p/∂q_k = z_k × (p − p_k)
for a revolute joint k before j, and ∂R_i/∂q_k = S(z_k) R_i.

Every function takes q of shape (n,) or a batch (N, n) and returns the matching shape.
"""

from __future__ import annotations

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from cir_gym.dynamics._checks import as_batch, matching_batch
from cir_gym.dynamics._spatial import cross, skew
from cir_gym.dynamics.chain import ChainModel
from cir_gym.dynamics.kinematics import (
    ChainKinematics,
    forward_kinematics,
    orientation_jacobians,
    point_jacobians,
)
from cir_gym.dynamics.parameters import LinkInertias, resolve


def spatial_inertias(R: np.ndarray, inertias: LinkInertias) -> np.ndarray:
    """M_i = [[m E, −S(h)], [S(h), Ī]] in world axes about each link origin.  # (N, n, 6, 6)

    Args:
        R: link orientations.  # (N, n, 3, 3)
        inertias: per-link mass, first moment, inertia about the origin (link frame).
    """
    h = (R @ inertias.first_moment[:, :, None])[..., 0]  # h_i = R_i m_i r_Ci
    S_h = skew(h)
    M = np.empty((*R.shape[:-2], 6, 6))
    M[..., :3, :3] = inertias.mass[:, None, None] * np.eye(3)
    M[..., :3, 3:] = -S_h
    M[..., 3:, :3] = S_h
    M[..., 3:, 3:] = R @ inertias.inertia @ np.swapaxes(R, -1, -2)  # R_i Ī_i R_iᵀ
    return M


def _link_terms(
    chain: ChainModel, inertias: LinkInertias, q: np.ndarray
) -> tuple[ChainKinematics, np.ndarray, np.ndarray]:
    """Kinematics, link Jacobians J_i = [J_v; J_O] (N, n, 6, n), spatial inertias (N, n, 6, 6)."""
    kin = forward_kinematics(chain, q)
    J = np.concatenate(
        [point_jacobians(chain, kin, kin.p), orientation_jacobians(chain, kin)], axis=-2
    )
    return kin, J, spatial_inertias(kin.R, inertias)


def _inertia_matrix(
    chain: ChainModel, inertias: LinkInertias, J: np.ndarray, M: np.ndarray
) -> np.ndarray:
    batch, n = J.shape[0], chain.n
    stacked = J.reshape(batch, 6 * n, n)
    B = np.swapaxes(stacked, 1, 2) @ (M @ J).reshape(batch, 6 * n, n)  # Σ_i J_iᵀ M_i J_i
    B[:, np.arange(n), np.arange(n)] += inertias.armature
    return B


def inertia_matrix(
    model: mujoco.MjModel, q: ArrayLike, *, parameters: ArrayLike | None = None
) -> np.ndarray:
    """Joint-space inertia matrix B(q), armature included (what ``mj_fullM`` returns).

    Args:
        model: a serial chain of hinge/slide joints (see ``cir_gym.dynamics``).
        q: joint positions (rad or m).  # (n,) or (N, n)
        parameters: dynamic parameters π to use instead of the model's.  # (11 n,)

    Returns:
        B(q) (kg m², kg m or kg).  # (n, n) or (N, n, n)
    """
    chain, inertias = resolve(model, parameters)
    q, single = as_batch("q", q, chain.n)
    _, J, M = _link_terms(chain, inertias, q)
    B = _inertia_matrix(chain, inertias, J, M)
    return B[0] if single else B


def _inertia_matrix_derivatives(
    chain: ChainModel, kin: ChainKinematics, J: np.ndarray, M: np.ndarray
) -> np.ndarray:
    """dB[:, k] = ∂B/∂q_k, exact.  # (N, n, n, n)"""
    n = chain.n
    index = np.arange(n)
    first = np.minimum.outer(index, index)  # [k, j] -> min(k, j)
    last = np.maximum.outer(index, index)
    w = kin.w  # (N, n, 3)
    batch = w.shape[0]
    J_rows = np.swapaxes(J, -1, -2)  # (N, i, j, 6)
    # ∂J_v,j/∂q_k = ω_min(j,k) × J_v,max(j,k); zero when max(j, k) > i (J_v is masked).
    dJ_v = cross(w[:, None, first], J_rows[:, :, last, :3])  # (N, i, k, j, 3)
    # ∂J_O,j/∂q_k = ω_k × ω_j for k < j ≤ i.
    after = (index[:, None] < index[None, :])[:, :, None]  # k < j
    on_link = chain.lower[:, None, :, None]  # (i, 1, j, 1): j ≤ i
    dJ_O = (cross(w[:, :, None], w[:, None, :]) * after)[:, None] * on_link  # (N, i, k, j, 3)
    dJ = np.concatenate([dJ_v, dJ_O], axis=-1)  # (N, i, k, j, 6)
    MJ = M @ J  # (N, i, 6, n)
    dB = np.einsum("biyl,bikjy->bklj", MJ, dJ)  # Σ_i J_iᵀ M_i ∂J_i (M symmetric)
    # Σ_{i ≥ k} J_iᵀ (Ŝ_k M_i − M_i Ŝ_k) J_i = X_k + X_kᵀ, X_k = −Σ_{i ≥ k} (Ŝ_k J_i)ᵀ M_i J_i
    rotated = cross(w[:, None, :, None, None, :], J_rows.reshape(batch, n, 1, n, 2, 3))
    rotated = rotated.reshape(batch, n, n, n, 6) * chain.lower[:, :, None, None]  # k ≤ i
    dB -= np.einsum("bikly,biyj->bklj", rotated, MJ)
    return dB + np.swapaxes(dB, -1, -2)


def inertia_matrix_derivatives(
    model: mujoco.MjModel, q: ArrayLike, *, parameters: ArrayLike | None = None
) -> np.ndarray:
    """Exact partial derivatives of the inertia matrix, dB[k] = ∂B/∂q_k.

    Args:
        model: a serial chain of hinge/slide joints.
        q: joint positions.  # (n,) or (N, n)
        parameters: dynamic parameters π to use instead of the model's.  # (11 n,)

    Returns:
        ∂B/∂q_k stacked over k.  # (n, n, n) or (N, n, n, n)
    """
    chain, inertias = resolve(model, parameters)
    q, single = as_batch("q", q, chain.n)
    kin, J, M = _link_terms(chain, inertias, q)
    dB = _inertia_matrix_derivatives(chain, kin, J, M)
    return dB[0] if single else dB


def coriolis_matrix(
    model: mujoco.MjModel,
    q: ArrayLike,
    qd: ArrayLike,
    *,
    parameters: ArrayLike | None = None,
) -> np.ndarray:
    """Coriolis/centrifugal matrix C(q, q̇) from the Christoffel symbols.

    c_ij = Σ_k ½ (∂b_ij/∂q_k + ∂b_ik/∂q_j − ∂b_jk/∂q_i) q̇_k; with this choice Ḃ − 2C is
    skew-symmetric and C(q, q̇) q̇ is the velocity part of MuJoCo's ``qfrc_bias``.

    Args:
        model: a serial chain of hinge/slide joints.
        q: joint positions.  # (n,) or (N, n)
        qd: joint velocities.  # like q
        parameters: dynamic parameters π to use instead of the model's.  # (11 n,)

    Returns:
        C(q, q̇) (C q̇ in N m or N).  # (n, n) or (N, n, n)
    """
    chain, inertias = resolve(model, parameters)
    q, single = as_batch("q", q, chain.n)
    qd = matching_batch("qd", qd, chain.n, q, single)
    kin, J, M = _link_terms(chain, inertias, q)
    dB = _inertia_matrix_derivatives(chain, kin, J, M)  # [b, k, i, j] = ∂b_ij/∂q_k
    B_dot = np.einsum("bkij,bk->bij", dB, qd)  # Σ_k ∂b_ij/∂q_k q̇_k
    D = np.einsum("bijk,bk->bij", dB, qd)  # D_ij = Σ_k ∂b_jk/∂q_i q̇_k
    C = 0.5 * (B_dot + np.swapaxes(D, 1, 2) - D)
    return C[0] if single else C


def gravity_torque(
    model: mujoco.MjModel, q: ArrayLike, *, parameters: ArrayLike | None = None
) -> np.ndarray:
    """Gravity torque g(q) = −Σ_j m_j J_P^(ℓj)(q)ᵀ g₀ (g₀ = ``model.opt.gravity``).

    Args:
        model: a serial chain of hinge/slide joints.
        q: joint positions.  # (n,) or (N, n)
        parameters: dynamic parameters π to use instead of the model's.  # (11 n,)

    Returns:
        g(q) (N m or N).  # (n,) or (N, n)
    """
    chain, inertias = resolve(model, parameters)
    q, single = as_batch("q", q, chain.n)
    kin = forward_kinematics(chain, q)
    J_v = point_jacobians(chain, kin, kin.p)  # (N, n, 3, n)
    J_O = orientation_jacobians(chain, kin)
    h = (kin.R @ inertias.first_moment[:, :, None])[..., 0]  # R_i m_i r_Ci
    weight = inertias.mass[:, None] * chain.gravity  # m_j g₀ at O_j ...
    moment = cross(h, chain.gravity)  # ... and its moment h_j × g₀ about O_j
    batch, n = q.shape
    g = -(
        weight.reshape(1, 1, 3 * n) @ J_v.reshape(batch, 3 * n, n)
        + moment.reshape(batch, 1, 3 * n) @ J_O.reshape(batch, 3 * n, n)
    )[:, 0]
    return g[0] if single else g
