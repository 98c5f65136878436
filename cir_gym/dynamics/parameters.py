"""The dynamic parameters π of a chain: 10 inertial parameters per link, then the armatures.

Per link i (body frame of its moving body, welded bodies merged in):
``[m, m c_x, m c_y, m c_z, I_xx, I_xy, I_xz, I_yy, I_yz, I_zz]`` with c the centre of mass and
I the inertia tensor about the LINK-FRAME ORIGIN, both in link-frame axes (kg, kg m, kg m²).
The torque is linear in these (τ = Y(q, q̇, q̈) π). After the 10 n link parameters come the n
joint armatures (reflected rotor inertias k_r² I_m, MuJoCo's ``dof_armature``), so π has 11 n
entries.
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from cir_gym.dynamics._checks import as_vector
from cir_gym.dynamics.chain import ChainModel, chain_model, split_parameters

LINK_PARAMETER_NAMES = ("m", "mc_x", "mc_y", "mc_z", "I_xx", "I_xy", "I_xz", "I_yy", "I_yz", "I_zz")


class LinkInertias(NamedTuple):
    """Per-link inertial values the dynamics functions use, all linear in π.

    mass (n,) kg; first_moment m r_C (n, 3) kg m in the link frame; inertia (n, 3, 3) kg m²
    about the link-frame origin in link axes; armature (n,).
    """

    mass: np.ndarray
    first_moment: np.ndarray
    inertia: np.ndarray
    armature: np.ndarray


def inertial_parameters(model: mujoco.MjModel) -> np.ndarray:
    """The parameter vector π of ``model``, read from its current arrays.

    Args:
        model: a serial chain (see ``cir_gym.dynamics``).

    Returns:
        π = [m, m c (3), I_O (6)] per link, then the n armatures.  # (11 n,)
    """
    return chain_model(model).parameters.copy()


def parameter_names(model: mujoco.MjModel) -> list[str]:
    """Names of the entries of π, e.g. ``"link1.m"``, ``"link1.I_xy"``, ``"joint1.armature"``."""
    chain = chain_model(model)
    names = []
    for body in chain.topology.link_bodies:
        link = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(body)) or f"body{body}"
        names.extend(f"{link}.{name}" for name in LINK_PARAMETER_NAMES)
    for joint in chain.topology.joints:
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, int(joint)) or f"joint{joint}"
        names.append(f"{name}.armature")
    return names


def resolve(model: mujoco.MjModel, parameters: ArrayLike | None) -> tuple[ChainModel, LinkInertias]:
    """The chain of ``model`` and the inertial values to use: the model's, or ``parameters``.

    Any π is accepted, physical or not (an identified or adapted estimate): every dynamics
    function is linear in π and never divides by a mass.

    Args:
        model: a serial chain.
        parameters: π overriding the model's inertial values, or None.  # (11 n,)
    """
    chain = chain_model(model)
    if parameters is None:
        return chain, LinkInertias(chain.mass, chain.first_moment, chain.inertia, chain.armature)
    values = as_vector("parameters", parameters, 11 * chain.n)
    return chain, LinkInertias(*split_parameters(values, chain.n))
