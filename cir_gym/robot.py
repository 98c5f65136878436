"""A robot: an ``MjModel`` with named joints and sites, and its kinematics and dynamics.

Every quantity is computed by MuJoCo's C functions on the robot's *own* ``MjData``, so the
simulator and each controller own a separate :class:`Robot` and never share state. A
controller's robot is the *nominal* model; :meth:`Robot.with_error` builds a copy with a
deliberate parameter error (unknown payload, link-mass scale, friction) for the simulator.

Conventions: joint positions ``q`` (n,) in rad (m for slide joints), velocities ``qd`` (n,),
geometric Jacobians (6, n) stacked as ``[J_P; J_O]`` in the world frame, rotations (3, 3)
from the site frame to the world frame. Every ``q``, ``qd`` and ``qdd`` argument must have
shape (n,) exactly (a scalar or a (1,) array is not broadcast) and be real and finite; anything
else raises ``ValueError`` naming the argument and the joints.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

__all__ = [
    "ASSETS",
    "MODEL_ERROR_RANGES",
    "ModelError",
    "Robot",
    "RobotFileError",
    "draw_model_error",
    "inertial_arrays",
    "restore_inertial_arrays",
    "robot_path",
]

ASSETS = Path(__file__).parent / "assets"
ROBOTS = ("iiwa14", "planar2r", "planar3r")
_FLOAT64 = np.dtype(np.float64)
_REAL_KINDS = ("f", "i", "u")  # numpy dtype kinds accepted as joint values (float, int, uint)


class RobotFileError(ValueError):
    """A robot file does not exist, does not parse, or lacks what cir_gym needs."""


def robot_path(name: str) -> Path:
    """Path of a shipped robot MJCF (``iiwa14``, ``planar2r``, ``planar3r``) or of a file."""
    if name in ROBOTS:
        return ASSETS / "robots" / f"{name}.xml"
    path = Path(name)
    if not path.is_file():
        raise RobotFileError(
            f"robot {name!r} is neither a shipped robot {ROBOTS} nor an existing MJCF file"
        )
    return path


def load_model(name_or_path: str | Path) -> mujoco.MjModel:
    """Compile an MJCF file, turning MuJoCo's parse errors into :class:`RobotFileError`."""
    path = robot_path(str(name_or_path))
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:  # MuJoCo raises ValueError on XML/compile errors
        raise RobotFileError(f"cannot load robot file {path}: {exc}") from exc


@dataclass(frozen=True)
class ModelError:
    """A deliberate difference between the true robot (simulator) and its nominal model.

    Attributes:
        payload_mass: mass (kg) of an unknown payload at the flange (a 5 cm sphere whose centre
            is 5 cm beyond the flange); needs a body named ``payload`` in the model.
        mass_scale: factor on every link mass and inertia (1 = exact).
        viscous_friction: joint viscous friction F_v (N m s/rad), same on every joint.
        coulomb_friction: joint Coulomb friction f_s (N m), same on every joint.
    """

    payload_mass: float = 0.0
    mass_scale: float = 1.0
    viscous_friction: float = 0.0
    coulomb_friction: float = 0.0

    def __post_init__(self) -> None:
        for name in ("payload_mass", "viscous_friction", "coulomb_friction"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if not np.isfinite(self.mass_scale) or self.mass_scale <= 0:
            raise ValueError(f"mass_scale must be a finite number > 0, got {self.mass_scale!r}")


PAYLOAD_RADIUS = 0.05  # m, sphere radius of the payload
PAYLOAD_OFFSET = 0.05  # m, payload centre beyond the flange along the flange z axis


def apply_model_error(model: mujoco.MjModel, error: ModelError) -> None:
    """Write ``error`` into ``model`` in place (masses, inertias, damping, frictionloss).

    Ends with ``mj_setConst``: MuJoCo's dynamics also read derived constants (subtree masses),
    and skipping it leaves the simulator with a gravity that matches neither model.
    """
    moving = model.body_dofnum > 0
    if error.mass_scale != 1.0:
        model.body_mass[moving] *= error.mass_scale
        model.body_inertia[moving] *= error.mass_scale
    if error.payload_mass > 0:
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "payload")
        if bid < 0:
            raise ValueError("payload_mass needs a body named 'payload' in the robot model")
        model.body_mass[bid] = error.payload_mass
        model.body_ipos[bid] = (0.0, 0.0, PAYLOAD_OFFSET)
        model.body_iquat[bid] = (1.0, 0.0, 0.0, 0.0)
        model.body_inertia[bid] = 0.4 * error.payload_mass * PAYLOAD_RADIUS**2
    model.dof_damping[:] = error.viscous_friction
    model.dof_frictionloss[:] = error.coulomb_friction
    mujoco.mj_setConst(model, mujoco.MjData(model))



#: Uniform ranges of a random model error, drawn per episode by the torque-driven envs'
#: ``randomize=True`` (±20 % masses, frictions up to 1).
MODEL_ERROR_RANGES: dict[str, tuple[float, float]] = {
    "payload_mass": (0.0, 5.0),  # kg
    "mass_scale": (0.8, 1.2),
    "viscous_friction": (0.0, 1.0),  # N m s/rad
    "coulomb_friction": (0.0, 1.0),  # N m
}

#: The model fields :func:`apply_model_error` writes.
INERTIAL_FIELDS = (
    "body_mass",
    "body_inertia",
    "body_ipos",
    "body_iquat",
    "dof_damping",
    "dof_frictionloss",
)


def draw_model_error(rng: np.random.Generator) -> ModelError:
    """A model error drawn uniformly from :data:`MODEL_ERROR_RANGES` (in its key order)."""
    return ModelError(**{k: float(rng.uniform(*r)) for k, r in MODEL_ERROR_RANGES.items()})


def inertial_arrays(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """Copies of the fields a model error changes (to undo it with
    :func:`restore_inertial_arrays` before applying another one)."""
    return {f: getattr(model, f).copy() for f in INERTIAL_FIELDS}


def restore_inertial_arrays(model: mujoco.MjModel, arrays: dict[str, np.ndarray]) -> None:
    """Put back the values of :func:`inertial_arrays` (``apply_model_error`` then recomputes
    the constants)."""
    for f, v in arrays.items():
        getattr(model, f)[:] = v


class Robot:
    """A serial robot in MuJoCo: kinematics and dynamics through MuJoCo's C calls.

    Args:
        model: compiled model; the robot's joints are the ones named in ``joints`` (default:
            every hinge/slide joint, in model order).
        joints: joint names, in the order of ``q``.

    Attributes:
        n: number of joints.
        lower, upper: joint limits (n,) (rad or m).
        velocity_limit: (n,) rad/s from the ``velocity_limit`` custom numeric (inf if absent).
        torque_limit: (n,) N m from the actuators' ctrlrange (inf if absent).
    """

    def __init__(self, model: mujoco.MjModel, joints: list[str] | None = None) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        if joints is None:
            joints = [
                model.joint(j).name
                for j in range(model.njnt)
                if int(model.jnt_type[j])
                in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
            ]
        ids = []
        for name in joints:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise RobotFileError(f"joint {name!r} not in the model")
            ids.append(jid)
        if not ids:
            raise RobotFileError("the model has no hinge or slide joints: not a robot arm")
        self.joint_names = list(joints)
        self.joint_ids = np.array(ids, dtype=int)
        self.n = len(ids)
        self.qpos_adr = model.jnt_qposadr[self.joint_ids].copy()
        self.dof_adr = model.jnt_dofadr[self.joint_ids].copy()
        # Fast path: the robot's joints are the whole state, in order.
        self._whole = model.nq == model.nv == self.n and np.array_equal(
            self.qpos_adr, np.arange(self.n)
        )
        self.lower = model.jnt_range[self.joint_ids, 0].copy()
        self.upper = model.jnt_range[self.joint_ids, 1].copy()
        self.velocity_limit = self._numeric("velocity_limit", np.inf)
        self.gear_ratio = self._numeric("gear_ratio", 1.0)
        self.rotor_inertia = self._numeric("rotor_inertia", 0.0)
        self.torque_limit = np.full(self.n, np.inf)
        self.actuator_ids = np.full(self.n, -1)
        for a in range(model.nu):
            if int(model.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
                continue
            hit = np.flatnonzero(self.joint_ids == model.actuator_trnid[a, 0])
            if hit.size:
                self.actuator_ids[hit[0]] = a
                if model.actuator_ctrllimited[a]:
                    self.torque_limit[hit[0]] = model.actuator_ctrlrange[a, 1] * abs(
                        model.actuator_gear[a, 0]
                    )
        self._M = np.zeros((model.nv, model.nv))
        self._vec = np.zeros(model.nv)
        self._jac = np.zeros((6, model.nv))  # [J_P; J_O], rows filled in place by mj_jacSite
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._site_ids: dict[str, int] = {}
        self._q_key: bytes | None = None
        self._crb_done = False
        self._shape = (self.n,)
        names = self.joint_names
        self._joint_text = names[0] if self.n == 1 else f"{names[0]}..{names[-1]}"

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_name(cls, name: str, joints: list[str] | None = None) -> Robot:
        """Load a shipped robot (``iiwa14``, ``planar2r``, ``planar3r``) or an MJCF path."""
        return cls(load_model(name), joints)

    def copy(self) -> Robot:
        """An independent robot with a deep copy of the model."""
        return Robot(copy.deepcopy(self.model), self.joint_names)

    def with_error(self, error: ModelError | None = None, **kwargs: float) -> Robot:
        """A copy of this robot with a deliberate model error (see :class:`ModelError`)."""
        error = error if error is not None else ModelError(**kwargs)
        robot = self.copy()
        apply_model_error(robot.model, error)
        return robot

    def set_armature(self, armature: np.ndarray) -> None:
        """Set the reflected rotor inertia k_r² I_m (kg m², shape (n,)) of every joint."""
        self.model.dof_armature[self.dof_adr] = armature
        self.invalidate()

    def _numeric(self, name: str, default: float) -> np.ndarray:
        nid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_NUMERIC, name)
        if nid < 0:
            return np.full(self.n, default)
        data = self.model.numeric(nid).data
        if data.size != self.n:
            raise RobotFileError(f"custom numeric {name!r} has {data.size} values, need {self.n}")
        return np.array(data, dtype=float)

    def invalidate(self) -> None:
        """Forget cached kinematics: call after changing ``self.model`` in place."""
        self._q_key = None

    def site_id(self, site: str) -> int:
        if site in self._site_ids:
            return self._site_ids[site]
        sid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, site)
        if sid < 0:
            names = [self.model.site(i).name for i in range(self.model.nsite)]
            raise ValueError(f"site {site!r} not in the model; sites: {names}")
        self._site_ids[site] = sid
        return sid

    # ------------------------------------------------------------------ state
    def _vector(self, name: str, value: np.ndarray) -> np.ndarray:
        """``value`` as a float64 array of shape (n,); ValueError if not real or not (n,).

        Finiteness is checked separately (:meth:`_check_finite`) so that ``_set_q`` can skip it
        for the cached configuration. Cheap on the common path (a float64 array).
        """
        array = np.asarray(value)
        if array.dtype is not _FLOAT64:
            if array.dtype.kind not in _REAL_KINDS:
                raise ValueError(
                    f"{name} has dtype {array.dtype}, expected real numbers "
                    f"(joints: {self._joint_text})"
                )
            array = array.astype(np.float64)
        if array.shape != self._shape:
            raise ValueError(
                f"{name} has shape {array.shape}, expected ({self.n},) (joints: {self._joint_text})"
            )
        return array

    @staticmethod
    def _check_finite(name: str, array: np.ndarray) -> None:
        # all(map(math.isfinite, list)) is exact and ~4x cheaper than np.isfinite(a).all() on a
        # short vector (0.4 µs against 1.8 µs here; a raw MuJoCo call costs ~2.3 µs).
        if not all(map(math.isfinite, array.tolist())):
            raise ValueError(f"{name} contains NaN or inf; expected finite values")

    def _set_q(self, q: np.ndarray) -> None:
        """Validate q (see :meth:`_vector`) and run the position-dependent computations."""
        q = self._vector("q", q)
        key = q.tobytes()
        if key == self._q_key:  # same shape (checked above) and bytes: validated already
            return
        self._check_finite("q", q)
        if self._whole:
            self.data.qpos[:] = q
        else:
            self.data.qpos[self.qpos_adr] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        self._q_key = key
        self._crb_done = False

    def _take(self, full: np.ndarray) -> np.ndarray:
        return full.copy() if self._whole else full[self.dof_adr]

    # ------------------------------------------------------------------ kinematics
    def site_pose(self, site: str | int, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics of a site: position (3,) m and rotation (3, 3) site→world."""
        sid = site if isinstance(site, int) else self.site_id(site)
        self._set_q(q)
        return self.data.site_xpos[sid].copy(), self.data.site_xmat[sid].reshape(3, 3).copy()

    def jacobian(self, site: str | int, q: np.ndarray) -> np.ndarray:
        """Geometric Jacobian (6, n) of a site, ``[J_P; J_O]`` in the world frame."""
        sid = site if isinstance(site, int) else self.site_id(site)
        self._set_q(q)
        mujoco.mj_jacSite(self.model, self.data, self._jac[:3], self._jac[3:], sid)
        return self._jac.copy() if self._whole else self._jac[:, self.dof_adr]

    def jacobian_dot_qdot(self, site: str | int, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """J̇(q, q̇) q̇ (6,) of a site: the site's acceleration at q̈ = 0 (linear; angular)."""
        sid = site if isinstance(site, int) else self.site_id(site)
        self._set_q(q)
        self._set_qd(qd)
        body = int(self.model.site_bodyid[sid])
        mujoco.mj_jacDot(
            self.model, self.data, self._jacp, self._jacr, self.data.site_xpos[sid], body
        )
        qdf = self.data.qvel
        return np.concatenate((self._jacp @ qdf, self._jacr @ qdf))

    def analytic_jacobian(self, site: str | int, q: np.ndarray) -> np.ndarray:
        """Analytic Jacobian (6, n) with the orientation as ZYX Euler angles (φ, θ, ψ).

        J_A = T_A(φ)⁻¹ J with T_A mapping Euler-angle rates to the angular velocity; singular
        when cos θ = 0 (a representation singularity, reported as a ValueError).
        """
        J = self.jacobian(site, q)
        R = self.site_pose(site, q)[1]
        phi = np.arctan2(R[1, 0], R[0, 0])
        theta = -np.arcsin(np.clip(R[2, 0], -1.0, 1.0))
        c_t = np.cos(theta)
        if abs(c_t) < 1e-9:
            raise ValueError("ZYX Euler representation singular (cos θ = 0)")
        c_p, s_p, s_t = np.cos(phi), np.sin(phi), np.sin(theta)
        # ω = T(φ, θ) [φ̇, θ̇, ψ̇]ᵀ for R = Rz(φ) Ry(θ) Rx(ψ)
        T = np.array([[0.0, -s_p, c_p * c_t], [0.0, c_p, s_p * c_t], [1.0, 0.0, -s_t]])
        J[3:] = np.linalg.solve(T, J[3:])
        return J

    # ------------------------------------------------------------------ dynamics
    def _set_qd(self, qd: np.ndarray) -> None:
        """Validate q̇ (shape (n,), real, finite) and compute the body velocities."""
        qd = self._vector("qd", qd)
        self._check_finite("qd", qd)
        if self._whole:
            self.data.qvel[:] = qd
        else:
            self.data.qvel[:] = 0.0
            self.data.qvel[self.dof_adr] = qd
        mujoco.mj_comVel(self.model, self.data)

    def inertia(self, q: np.ndarray) -> np.ndarray:
        """Inertia matrix B(q) (n, n), armature included (kg m²)."""
        self._set_q(q)
        if not self._crb_done:
            mujoco.mj_crb(self.model, self.data)
            self._crb_done = True
        mujoco.mj_fullM(self.model, self.data, self._M)
        if self._whole:
            return self._M.copy()
        return self._M[np.ix_(self.dof_adr, self.dof_adr)]

    def bias(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """n(q, q̇) = C(q, q̇) q̇ + g(q) (n,), N m. No friction."""
        self._set_q(q)
        self._set_qd(qd)
        mujoco.mj_rne(self.model, self.data, 0, self._vec)
        return self._take(self._vec)

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """Gravity torque g(q) (n,), N m."""
        self._set_q(q)
        self.data.qvel[:] = 0.0
        mujoco.mj_comVel(self.model, self.data)
        mujoco.mj_rne(self.model, self.data, 0, self._vec)
        return self._take(self._vec)

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """τ = B(q) q̈ + n(q, q̇) (n,), N m (no friction)."""
        B, n = self.inertia(q), self.bias(q, qd)  # validate q, q̇, then q̈
        qdd = self._vector("qdd", qdd)
        self._check_finite("qdd", qdd)
        return B @ qdd + n

    def friction(self, qd: np.ndarray) -> np.ndarray:
        """Joint friction F_v q̇ + f_s sign(q̇) (n,) from the model's damping and frictionloss."""
        qd = self._vector("qd", qd)
        self._check_finite("qd", qd)
        fv = self.model.dof_damping[self.dof_adr]
        fs = self.model.dof_frictionloss[self.dof_adr]
        return fv * qd + fs * np.sign(qd)
