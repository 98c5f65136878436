"""Recursive Newton-Euler inverse dynamics τ = B(q) q̈ + C(q, q̇) q̇ + g(q) (+ Jᵀ h_e).

The recursions of the course notes, with every vector in the world frame:

forward, from the base (ω₀ = ω̇₀ = 0, p̈₀ = −g₀):
    ω_i  = ω_{i−1} + q̇_i z_i                              (hinge; a slide leaves ω unchanged)
    ω̇_i  = ω̇_{i−1} + q̈_i z_i + ω_{i−1} × q̇_i z_i
    p̈_i  = p̈_{i−1} + ω̇_{i−1} × r_{i−1,i} + ω_{i−1} × (ω_{i−1} × r_{i−1,i})
           (+ q̈_i z_i + 2 ω_{i−1} × q̇_i z_i for a slide)
    p̈_Oi = p̈_i + ω̇_i × r_{i,Oi} + ω_i × (ω_i × r_{i,Oi})
backward, from the tip (f_{n+1} = f_e, μ_{n+1} = μ_e):
    f_i = f_{i+1} + m_i p̈_Ci,  m_i p̈_Ci = m_i p̈_Oi + ω̇_i × h_i + ω_i × (ω_i × h_i)
    μ_i = μ_{i+1} + r_{i,i+1} × f_{i+1} + r_{i,Oi} × m_i p̈_Ci + Ī_i ω̇_i + ω_i × (Ī_i ω_i)
          + h_i × p̈_Oi
    τ_i = μ_iᵀ z_i (hinge) or f_iᵀ z_i (slide), plus armature_i q̈_i.

p_i is the anchor a_i of joint i (a point of its axis, on both links i − 1 and i; for a slide
the link origin), r_{i−1,i} = a_i − a_{i−1}, μ_i is the moment about a_i, and link i's inertial
terms are taken about its frame origin O_i: h_i = R_i m_i r_Ci (first moment) and Ī_i the
inertia about O_i (the notes' r_{i,Ci} × m_i p̈_Ci + I_i ω̇_i + ω_i × I_i ω_i, rewritten so that
it is linear in π and never divides by m_i). r_Ci and Ī_i are constants of the link frame,
rotated into the world by R_i. Once every vector is in one frame each recursion is
x_i = x_{i−1} + Δ_i, so it is evaluated as a sum over the links before (or beyond) i — a product
with a triangular matrix of ones — which keeps the cost to a few dozen numpy calls for any
number of links. Moments are summed about the world origin and moved to the anchors at the
end: μ_i = M_i − a_i × f_i.

Not included: joint damping, friction, springs and other passive forces (MuJoCo's
``qfrc_passive``) and constraint forces, so ``rnea`` equals ``mj_inverse``'s ``qfrc_inverse``
for a model without damping, springs and active constraints.
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from cir_gym.dynamics._checks import as_batch, matching_batch
from cir_gym.dynamics._spatial import cross, skew
from cir_gym.dynamics.chain import ChainModel
from cir_gym.dynamics.kinematics import ChainKinematics, forward_kinematics
from cir_gym.dynamics.parameters import resolve


class LinkMotion(NamedTuple):
    """Result of the forward recursion (world frame).

    Attributes:
        omega: angular velocities ω_i (rad/s).  # (..., N, n, 3)
        omega_dot: angular accelerations ω̇_i (rad/s²).  # (..., N, n, 3)
        S_omega: cross-product matrices S(ω_i).  # (..., N, n, 3, 3)
        transport: S(ω̇_i) + S(ω_i)², p̈_y − p̈_x = transport (y − x) on link i.  # like S_omega
        acceleration: accelerations of the requested points, p̈₀ = −g₀ included (m/s²).
            # (..., N, n, 3)
    """

    omega: np.ndarray
    omega_dot: np.ndarray
    S_omega: np.ndarray
    transport: np.ndarray
    acceleration: np.ndarray


def link_accelerations(
    chain: ChainModel,
    kin: ChainKinematics,
    qd: np.ndarray,
    qdd: np.ndarray,
    base_acceleration: np.ndarray,
    points: np.ndarray,
) -> LinkMotion:
    """Forward recursion of Newton-Euler: ω_i, ω̇_i and the acceleration of one point per link.

    Args:
        chain: the chain's constant arrays.
        kin: forward kinematics (batch N).
        qd: joint velocities.  # (..., N, n)
        qdd: joint accelerations.  # (..., N, n)
        base_acceleration: p̈₀, −g₀ with gravity.  # broadcastable to (..., N, n, 3)
        points: a world point fixed to each link (e.g. its origin).  # (N, n, 3)
    """
    w_qd = kin.w * qd[..., None]  # q̇_i z_i (hinge)
    omega = chain.lower @ w_qd  # ω_i = ω_{i−1} + q̇_i z_i
    S_omega = skew(omega)
    # ω_{i−1} × q̇_i z_i (hinge) and 2 ω_{i−1} × q̇_i z_i (slide); ω_{i−1} × z_i = ω_i × z_i
    if chain.has_slides:
        moving_axis = kin.z * (qd * chain.coriolis_factor)[..., None]
        coriolis = (S_omega @ moving_axis[..., None])[..., 0]
        omega_dot = chain.lower @ (kin.w * qdd[..., None] + coriolis * chain.revolute[:, None])
    else:
        coriolis = (S_omega @ w_qd[..., None])[..., 0]
        omega_dot = chain.lower @ (kin.w * qdd[..., None] + coriolis)
    # p̈_x = p̈_i + (S(ω̇_i) + S(ω_i)²) (x − a_i) for the next anchor and the requested point
    transport = skew(omega_dot) + S_omega @ S_omega
    arms = np.concatenate((kin.a[..., chain.next_link, :, None], points[..., None]), axis=-1)
    arms -= kin.a[..., None]
    moved = transport @ arms  # (..., N, n, 3, 2)
    anchor = chain.strictly_lower @ moved[..., 0] + base_acceleration  # p̈_i
    if chain.has_slides:
        slide = ~chain.revolute[:, None]
        anchor = anchor + chain.lower @ ((kin.z * qdd[..., None] + coriolis) * slide)
    return LinkMotion(omega, omega_dot, S_omega, transport, anchor + moved[..., 1])


def rnea(
    model: mujoco.MjModel,
    q: ArrayLike,
    qd: ArrayLike,
    qdd: ArrayLike,
    *,
    gravity: bool = True,
    f_ext: ArrayLike | None = None,
    parameters: ArrayLike | None = None,
) -> np.ndarray:
    """Inverse dynamics by the recursive Newton-Euler algorithm.

    τ = B(q) q̈ + C(q, q̇) q̇ + g(q) + J_nᵀ(q) h_e, armature included in B; no damping or
    friction (add F_v q̇ + f_s yourself if your model has them).

    Args:
        model: a serial chain of hinge/slide joints (see ``cir_gym.dynamics``).
        q: joint positions (rad or m).  # (n,) or (N, n)
        qd: joint velocities.  # like q
        qdd: joint accelerations.  # like q
        gravity: include g(q) (base acceleration −g₀ with g₀ = ``model.opt.gravity``).
        f_ext: h_e = [f_e; μ_e], the force (N) and moment (N m) the last link exerts on the
            environment, world-frame components, moment about the last link's frame origin;
            J_n is the geometric Jacobian of that origin. None for free motion.  # (6,) or (N, 6)
        parameters: dynamic parameters π to use instead of the model's.  # (11 n,)

    Returns:
        Joint torques/forces τ (N m or N).  # (n,) or (N, n)
    """
    chain, inertias = resolve(model, parameters)
    n = chain.n
    q, single = as_batch("q", q, n)
    qd = matching_batch("qd", qd, n, q, single)
    qdd = matching_batch("qdd", qdd, n, q, single)
    kin = forward_kinematics(chain, q, twists=False)
    base = -chain.gravity if gravity else np.zeros(3)
    motion = link_accelerations(chain, kin, qd, qdd, base, kin.p)
    acc_origin = motion.acceleration  # p̈_Oi
    h = (kin.R @ inertias.first_moment[:, :, None])[..., 0]  # h_i = R_i m_i r_Ci
    force = inertias.mass[:, None] * acc_origin + (motion.transport @ h[..., None])[..., 0]
    I_w = kin.R @ inertias.inertia @ np.swapaxes(kin.R, -1, -2)  # R_i Ī_i R_iᵀ
    I_w_omega = I_w @ np.concatenate((motion.omega_dot[..., None], motion.omega[..., None]), -1)
    euler = I_w_omega[..., 0] + (motion.S_omega @ I_w_omega[..., 1:])[..., 0]  # Ī ω̇ + ω × Ī ω
    moment_origin = euler + cross(h, acc_origin)  # moment of link i's wrench about O_i
    # Backward recursion: sums over the links beyond i, moments about the world origin.
    f = chain.upper @ force
    moment = chain.upper @ (cross(kin.p, force) + moment_origin)
    if f_ext is not None:
        wrench = matching_batch("f_ext", f_ext, 6, q, single, per_joint=False)
        f = f + wrench[:, None, :3]
        tip_moment = wrench[:, 3:] + cross(kin.p[:, -1], wrench[:, :3])
        moment = moment + tip_moment[:, None, :]
    mu = moment - cross(kin.a, f)  # μ_i about the anchor a_i
    if chain.has_slides:
        mu = np.where(chain.revolute[:, None], mu, f)  # a slide transmits the force f_i
    tau = (kin.z * mu).sum(axis=-1) + inertias.armature * qdd
    return tau[0] if single else tau
