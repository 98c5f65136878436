"""Chapter 2, robot dynamics, in numpy from a compiled ``mujoco.MjModel``.

Supported models: a serial chain fixed to the world — every body with a joint has exactly one
hinge or slide joint and hangs from the previous such body (directly or through bodies without
joints); bodies without joints are welded to their link and merged into it (mass, COM and
inertia by the parallel-axis theorem); bodies without joints fixed to the world are ignored.
Anything else (free or ball joints, branching trees, several joints in a body, a chain hanging
from a mocap body, equality constraints) raises ``ValueError``.

Everything is read from the model arrays (``body_pos``, ``body_quat``, ``jnt_pos``,
``jnt_axis``, ``qpos0``, ``body_ipos``, ``body_iquat``, ``body_mass``, ``body_inertia``,
``dof_armature``, ``opt.gravity``) at every call — a cache keyed on a copy of those arrays
avoids recomputing the constant parts — so changing e.g. a payload mass at run time is seen by
the next call. Only MuJoCo's passive forces (damping, springs) and constraints are left out.

Functions (q, q̇, q̈ of shape (n,) or a batch (N, n), real and finite, else ``ValueError``; SI
units):

- ``inertia_matrix(model, q)`` → B(q) (n, n), armature on the diagonal
- ``inertia_matrix_derivatives(model, q)`` → ∂B/∂q_k stacked over k (n, n, n)
- ``coriolis_matrix(model, q, qd)`` → C(q, q̇) (n, n) from the Christoffel symbols
- ``gravity_torque(model, q)`` → g(q) (n,)
- ``rnea(model, q, qd, qdd, *, gravity=True, f_ext=None)`` → τ (n,), recursive Newton-Euler
- ``inertial_parameters(model)`` → π (11 n,), ``parameter_names(model)`` → its names
- ``regressor(model, q, qd, qdd, *, qd_r=None, gravity=True)`` → Y (n, 11 n), τ = Y π
- ``identify(model, q, qd, qdd, tau, *, friction=False)`` → ``IdentificationResult``
- ``excitation_trajectory(model, *, duration, ...)`` → ``ExcitationTrajectory``

The dynamics functions accept ``parameters=π`` to use other inertial values than the model's
(e.g. ``IdentificationResult.to_full_parameters()``).
"""

from cir_gym.dynamics.dynamic_regressor import regressor
from cir_gym.dynamics.excitation import ExcitationTrajectory, excitation_trajectory
from cir_gym.dynamics.identification import IdentificationResult, identify
from cir_gym.dynamics.lagrange import (
    coriolis_matrix,
    gravity_torque,
    inertia_matrix,
    inertia_matrix_derivatives,
)
from cir_gym.dynamics.newton_euler import rnea
from cir_gym.dynamics.parameters import LINK_PARAMETER_NAMES, inertial_parameters, parameter_names

__all__ = [
    "LINK_PARAMETER_NAMES",
    "ExcitationTrajectory",
    "IdentificationResult",
    "coriolis_matrix",
    "excitation_trajectory",
    "gravity_torque",
    "identify",
    "inertia_matrix",
    "inertia_matrix_derivatives",
    "inertial_parameters",
    "parameter_names",
    "regressor",
    "rnea",
]
