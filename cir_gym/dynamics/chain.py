"""The serial chain inside an ``MjModel``: its links, joints and constant arrays.

A *link* is a body with one hinge or slide joint plus every joint-less body welded to it.
Link i hangs from link i - 1 (the world for the first link) through a chain of joint-less
bodies. ``chain_model(model)`` returns the topology (cached per model object) together with
the constant arrays read from the model: fixed frames, joint axes, inertial parameters and
gravity. The arrays are re-read whenever any of the model arrays they come from changes
(the cache key is a copy of those arrays), so writing ``model.body_mass[...]`` at run time
is seen by the next call.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import mujoco
import numpy as np

from cir_gym.dynamics._spatial import quat_to_matrix, skew

HINGE = int(mujoco.mjtJoint.mjJNT_HINGE)
SLIDE = int(mujoco.mjtJoint.mjJNT_SLIDE)
_GRAVITY_OFF = int(mujoco.mjtDisableBit.mjDSBL_GRAVITY)
_JOINT_TYPE_NAMES = {0: "free", 1: "ball", 2: "slide", 3: "hinge"}

SUPPORTED = (
    "cir_gym.dynamics supports serial chains fixed to the world: one hinge or slide joint per "
    "moving body, each moving body hanging from the previous one (directly or through bodies "
    "without joints, which are welded to their link), no mocap body in the chain, no equality "
    "constraints"
)


@dataclass(frozen=True, eq=False)
class ChainTopology:
    """Which bodies and joints form the chain (constant for a compiled model).

    Attributes:
        n: number of joints (= links).
        link_bodies: body id of each link's moving body, base to tip.  # (n,)
        joints: joint id of each link.  # (n,)
        revolute: True for hinge joints, False for slide joints.  # (n,)
        link_paths: for each link, the bodies from the previous link (exclusive; the world for
            link 0) to the link's body (inclusive), in order.
        member_links: link index of every body merged into a link (link bodies first).  # (M,)
        member_paths: for every member body, the bodies from its link body (exclusive) to the
            member (inclusive); empty for the link body itself.
    """

    n: int
    link_bodies: np.ndarray
    joints: np.ndarray
    revolute: np.ndarray
    link_paths: tuple[tuple[int, ...], ...]
    member_links: np.ndarray
    member_paths: tuple[tuple[int, ...], ...]


@dataclass(frozen=True, eq=False)
class ChainModel:
    """Topology plus the constant arrays the dynamics needs, read from the model arrays.

    Frames: ``T_fix[i]`` maps link i's body frame at θ_i = 0 into the previous link's body frame
    (the world for i = 0); the joint adds exp(ξ̂_i θ_i) with θ_i = q_i − qpos0_i, so
    T_{i−1,i}(q_i) = T_fix[i] + f1(θ_i) X1[i] + f2(θ_i) X2[i] (Rodrigues' formula for a twist:
    f1 = sin θ, f2 = 1 − cos θ for a hinge; f1 = θ, f2 = 0 for a slide).

    Attributes:
        topology: the chain's bodies and joints.
        T_fix: fixed transforms, previous link → link at θ = 0.  # (n, 4, 4)
        X1: T_fix ξ̂ (ξ̂ the 4x4 joint twist in the link frame).  # (n, 4, 4)
        X2: T_fix ξ̂².  # (n, 4, 4)
        qpos0: joint reference positions (MuJoCo's ``qpos0``).  # (n,)
        points: link-frame columns [axis; 0] and [anchor; 1] of the joints.  # (n, 4, 2)
        parameters: inertial parameters π (see ``parameters.py``).  # (11 n,)
        mass: link masses m_i (kg).  # (n,)
        first_moment: m_i r_Ci, COM times mass in the link frame (kg m).  # (n, 3)
        inertia: link inertias about the link-frame origin, link axes (kg m²).  # (n, 3, 3)
        armature: reflected rotor inertias (kg m² or kg).  # (n,)
        gravity: gravity acceleration g₀ in the world frame (m/s², zero if disabled).  # (3,)
        lower: lower[i, j] = 1 for j ≤ i: sums over the links before i (inclusive).  # (n, n)
        strictly_lower: 1 for j < i.  # (n, n)
        upper: 1 for j ≥ i: sums over the links beyond i (inclusive).  # (n, n)
        next_link: index of the next link (the last link for the last).  # (n,)
        coriolis_factor: 1 for a hinge, 2 for a slide (ω × q̇ z and 2 ω × q̇ z).  # (n,)
        has_slides: whether any joint is a slide.
    """

    topology: ChainTopology
    T_fix: np.ndarray
    X1: np.ndarray
    X2: np.ndarray
    qpos0: np.ndarray
    points: np.ndarray
    parameters: np.ndarray
    mass: np.ndarray
    first_moment: np.ndarray
    inertia: np.ndarray
    armature: np.ndarray
    gravity: np.ndarray
    lower: np.ndarray
    strictly_lower: np.ndarray
    upper: np.ndarray
    next_link: np.ndarray
    coriolis_factor: np.ndarray
    has_slides: bool

    @property
    def n(self) -> int:
        return self.topology.n

    @property
    def revolute(self) -> np.ndarray:
        return self.topology.revolute


def _body_name(model: mujoco.MjModel, body: int) -> str:
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body)
    return f"'{name}'" if name else f"#{body}"


def _joint_name(model: mujoco.MjModel, joint: int) -> str:
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
    return f"'{name}'" if name else f"#{joint}"


def _topology(model: mujoco.MjModel) -> ChainTopology:
    """Find the serial chain of ``model`` or raise ``ValueError`` saying why there is none."""
    for joint in range(model.njnt):
        kind = int(model.jnt_type[joint])
        if kind not in (HINGE, SLIDE):
            raise ValueError(
                f"joint {_joint_name(model, joint)} is a {_JOINT_TYPE_NAMES.get(kind, kind)} "
                f"joint, which is not supported; {SUPPORTED}"
            )
    if model.njnt == 0 or model.nv == 0:
        raise ValueError(f"the model has no joints; {SUPPORTED}")
    if model.nq != model.nv:
        raise ValueError(f"the model has nq = {model.nq} != nv = {model.nv}; {SUPPORTED}")
    if model.neq > 0:
        raise ValueError(
            f"the model has {model.neq} equality constraint(s), which are not supported; "
            f"{SUPPORTED}"
        )
    if model.ntendon > 0 and np.any(model.tendon_armature != 0.0):
        raise ValueError(f"tendon armature is not supported; {SUPPORTED}")
    parents = model.body_parentid
    joint_count = model.body_jntnum
    for body in range(model.nbody):
        if joint_count[body] > 1:
            raise ValueError(
                f"body {_body_name(model, body)} has {joint_count[body]} joints, which is not "
                f"supported; {SUPPORTED}"
            )

    def moving_ancestor(body: int) -> int:
        body = int(parents[body])
        while body != 0 and joint_count[body] == 0:
            body = int(parents[body])
        return body

    def path(ancestor: int, body: int) -> tuple[int, ...]:
        bodies = []
        while body != ancestor:
            bodies.append(body)
            body = int(parents[body])
        return tuple(reversed(bodies))

    link_bodies = [body for body in range(1, model.nbody) if joint_count[body] == 1]
    link_index = {body: i for i, body in enumerate(link_bodies)}
    link_paths = []
    previous = 0
    for body in link_bodies:
        ancestor = moving_ancestor(body)
        if ancestor != previous:
            raise ValueError(
                f"body {_body_name(model, body)} hangs from {_body_name(model, ancestor)}, not "
                f"from the previous link {_body_name(model, previous)}: branching trees are not "
                f"supported; {SUPPORTED}"
            )
        link_paths.append(path(ancestor, body))
        previous = body
    # A mocap body (a child of the world moved by data.mocap_pos/quat) is not fixed: a chain
    # hanging from one would be treated as fixed to the world, with wrong dynamics.
    for bodies in link_paths:
        mocap = [body for body in bodies if model.body_mocapid[body] >= 0]
        if mocap:
            raise ValueError(
                f"body {_body_name(model, mocap[0])} is a mocap body and the chain hangs from "
                f"it: its base is not fixed to the world; {SUPPORTED}"
            )
    joints = np.array([model.body_jntadr[body] for body in link_bodies], dtype=int)
    if np.any(model.jnt_dofadr[joints] != np.arange(len(joints))) or np.any(
        model.jnt_qposadr[joints] != np.arange(len(joints))
    ):
        raise ValueError(f"the joints are not numbered along the chain; {SUPPORTED}")

    member_links = list(range(len(link_bodies)))
    member_paths: list[tuple[int, ...]] = [() for _ in link_bodies]
    for body in range(1, model.nbody):
        if joint_count[body] == 0:
            ancestor = moving_ancestor(body)
            if ancestor != 0:  # welded to a link; bodies fixed to the world are ignored
                member_links.append(link_index[ancestor])
                member_paths.append(path(ancestor, body))
    return ChainTopology(
        n=len(link_bodies),
        link_bodies=np.array(link_bodies, dtype=int),
        joints=joints,
        revolute=model.jnt_type[joints] == HINGE,
        link_paths=tuple(link_paths),
        member_links=np.array(member_links, dtype=int),
        member_paths=tuple(member_paths),
    )


def _transform(model: mujoco.MjModel, bodies: tuple[int, ...]) -> np.ndarray:
    """Transform through the fixed body frames ``bodies``, parent to child.  # (4, 4)"""
    transform = np.eye(4)
    for body in bodies:
        step = np.eye(4)
        step[:3, :3] = quat_to_matrix(model.body_quat[body])
        step[:3, 3] = model.body_pos[body]
        transform = transform @ step
    return transform


def _member_parameters(model: mujoco.MjModel, topology: ChainTopology) -> np.ndarray:
    """Inertial parameters π of every link (10 per link), merged over welded bodies.  # (n, 10)

    For each member body: mass m, COM c and inertia I_C in the link frame, then
    π = [m, m c, I_O] with I_O = I_C + m (cᵀc E − c cᵀ) about the link-frame origin
    (parallel-axis theorem); the rows of all members of a link are summed.
    """
    bodies = np.concatenate([topology.link_bodies, _member_ends(topology)]).astype(int)
    link_from_body = np.stack([_transform(model, path) for path in topology.member_paths])
    R = link_from_body[:, :3, :3] @ quat_to_matrix(model.body_iquat[bodies])
    mass = model.body_mass[bodies]
    com = (link_from_body[:, :3, :3] @ model.body_ipos[bodies][:, :, None])[:, :, 0]
    com = com + link_from_body[:, :3, 3]
    inertia_com = (R * model.body_inertia[bodies][:, None, :]) @ np.swapaxes(R, -1, -2)
    steiner = np.einsum("b,bi,bj->bij", mass, com, com)
    inertia_origin = inertia_com + np.eye(3) * np.trace(steiner, axis1=1, axis2=2)[:, None, None]
    inertia_origin = inertia_origin - steiner
    rows = np.column_stack(
        [mass, mass[:, None] * com, inertia_origin[:, _UPPER[0], _UPPER[1]]]
    )  # (M, 10)
    summed = np.zeros((topology.n, 10))
    np.add.at(summed, topology.member_links, rows)
    return summed


def _member_ends(topology: ChainTopology) -> np.ndarray:
    return np.array([path[-1] for path in topology.member_paths[topology.n :]], dtype=int)


# Index pairs of the 6 independent inertia entries in the order xx, xy, xz, yy, yz, zz.
_UPPER = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))


def split_parameters(parameters: np.ndarray, n: int) -> tuple[np.ndarray, ...]:
    """Per-link views of π, linear in π (no division by the mass).

    Args:
        parameters: π = [10 per link..., n armatures].  # (11 n,)
        n: number of links.

    Returns:
        mass (n,), first moment m c in the link frame (n, 3), inertia about the link origin in
        link axes (n, 3, 3), armature (n,).
    """
    links = parameters[: 10 * n].reshape(n, 10)
    return links[:, 0], links[:, 1:4], links[:, _SYMMETRIC], parameters[10 * n :]


# links[:, _SYMMETRIC] rebuilds the symmetric 3x3 inertia from columns 4..9 of π.
_SYMMETRIC = np.array([[4, 5, 6], [5, 7, 8], [6, 8, 9]])


def _chain_arrays(model: mujoco.MjModel, topology: ChainTopology) -> ChainModel:
    n = topology.n
    T_fix = np.stack([_transform(model, path) for path in topology.link_paths])
    joints = topology.joints
    axis = model.jnt_axis[joints] / np.linalg.norm(model.jnt_axis[joints], axis=1, keepdims=True)
    anchor = model.jnt_pos[joints].copy()
    # Joint twist in the link frame, ξ̂ = [[S(u), −S(u) s], [0, 0]] (hinge about axis u through
    # the anchor s) or [[0, u], [0, 0]] (slide along u).
    twist = np.zeros((n, 4, 4))
    S = skew(axis)
    rev = topology.revolute
    twist[rev, :3, :3] = S[rev]
    twist[rev, :3, 3] = -(S[rev] @ anchor[rev][:, :, None])[:, :, 0]
    twist[~rev, :3, 3] = axis[~rev]
    anchor[~rev] = 0.0  # a slide joint has no axis point; use the link origin
    parameters = np.concatenate(
        [_member_parameters(model, topology).ravel(), model.dof_armature[:n]]
    )
    parameters.setflags(write=False)  # shared by every call until the model arrays change
    mass, first_moment, inertia, armature = split_parameters(parameters, n)
    points = np.zeros((n, 4, 2))
    points[:, :3, 0] = axis
    points[:, :3, 1] = anchor
    points[:, 3, 1] = 1.0
    gravity_on = not (model.opt.disableflags & _GRAVITY_OFF)
    return ChainModel(
        topology=topology,
        T_fix=T_fix,
        X1=T_fix @ twist,
        X2=T_fix @ twist @ twist,
        qpos0=model.qpos0[:n].copy(),
        points=points,
        parameters=parameters,
        mass=mass,
        first_moment=first_moment,
        inertia=inertia,
        armature=armature,
        gravity=np.array(model.opt.gravity, dtype=float) * gravity_on,
        lower=np.tril(np.ones((n, n))),
        strictly_lower=np.tril(np.ones((n, n)), -1),
        upper=np.triu(np.ones((n, n))),
        next_link=np.minimum(np.arange(1, n + 1), n - 1),
        coriolis_factor=np.where(rev, 1.0, 2.0),
        has_slides=bool(np.any(~rev)),
    )


def _array_key(model: mujoco.MjModel) -> bytes:
    """Copy of every model array the chain arrays are computed from."""
    option = model.opt
    return b"".join(
        (
            model.body_pos.tobytes(),
            model.body_quat.tobytes(),
            model.body_ipos.tobytes(),
            model.body_iquat.tobytes(),
            model.body_mass.tobytes(),
            model.body_inertia.tobytes(),
            model.jnt_pos.tobytes(),
            model.jnt_axis.tobytes(),
            model.qpos0.tobytes(),
            model.dof_armature.tobytes(),
            option.gravity.tobytes(),
            int(option.disableflags).to_bytes(8, "little"),
        )
    )


_TOPOLOGY: weakref.WeakKeyDictionary[mujoco.MjModel, ChainTopology] = weakref.WeakKeyDictionary()
_ARRAYS: weakref.WeakKeyDictionary[mujoco.MjModel, tuple[bytes, ChainModel]] = (
    weakref.WeakKeyDictionary()
)


def chain_topology(model: mujoco.MjModel) -> ChainTopology:
    """The chain's bodies and joints (cached per model object).

    Raises:
        ValueError: the model is not a serial chain of hinge and slide joints fixed to the world
            (e.g. it hangs from a mocap body).
    """
    topology = _TOPOLOGY.get(model)
    if topology is None:
        topology = _TOPOLOGY[model] = _topology(model)
    return topology


def chain_model(model: mujoco.MjModel) -> ChainModel:
    """Topology and constant arrays of ``model``, recomputed when the model arrays change.

    Raises:
        ValueError: the model is not a serial chain of hinge and slide joints fixed to the world.
    """
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"expected a mujoco.MjModel, got {type(model).__name__}")
    key = _array_key(model)
    cached = _ARRAYS.get(model)
    if cached is None or cached[0] != key:
        cached = _ARRAYS[model] = (key, _chain_arrays(model, chain_topology(model)))
    return cached[1]
