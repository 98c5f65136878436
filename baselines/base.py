"""The policy protocol every controller implements: SB3's ``predict`` with state in ``state``.

A controller sees only the observation and a :class:`~cir_gym.context.TaskContext` (the
nominal robot, control period, action scaling). Its internal state (integrators, adaptive
estimates, filters) is a float vector per environment that travels in ``state``, shape
(n_envs, state_size), and is re-initialised where ``episode_start`` is true — exactly how SB3
treats recurrent policies, so ``stable_baselines3.common.evaluation.evaluate_policy`` and
:func:`cir_gym.evaluation.evaluate` both accept a controller unchanged.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import types
import typing
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import mujoco
import numpy as np

from cir_gym.context import TaskContext
from cir_gym.numeric import CLIP
from cir_gym.robot import Robot

__all__ = [
    "Controller",
    "InvalidGain",
    "Observation",
    "RobotRows",
    "RowDynamics",
    "RowLaw",
    "SiteTerms",
    "check_gain_type",
    "is_real",
    "matvec",
    "rows_method",
    "transpose",
]

Observation = dict[str, np.ndarray]

_isfinite = math.isfinite
_F64 = np.dtype(np.float64)
_NDARRAY = np.ndarray
_MUL, _ADD = np.multiply, np.add


def _float_observation(observation: Observation) -> Observation:
    """``observation`` with float64 arrays (the same arrays where they are already), checked:
    ValueError naming the first key with a NaN or inf value.

    One finiteness test of all the values decides the common case; only a failing one looks
    for the key to name. A cir_gym env's
    observation is the rows of one float64 array: then that array is checked as it is (a
    superset of the values) and the dict is used as it is; else the values are converted
    and concatenated.
    """
    base = getattr(observation.get("q"), "base", None)
    shared = type(base) is _NDARRAY and (base.dtype is _F64 or base.dtype == _F64)
    if shared:
        for v in observation.values():
            if type(v) is not _NDARRAY or v.base is not base:
                shared = False
                break
    if shared:
        obs, flat = observation, base.ravel()
    else:
        obs = {k: np.asarray(v, dtype=float) for k, v in observation.items()}
        flat = np.concatenate(tuple(obs.values()), axis=None)
    if np.isfinite(flat).all():
        return obs
    for key, value in obs.items():
        if not np.all(np.isfinite(value)):
            raise ValueError(f"observation[{key!r}] contains NaN or inf")
    return obs


_NO_STATE = np.zeros(0)  # the state row of a stateless law (nothing can be written to it)
_NO_STATE.flags.writeable = False


# The state ``predict`` returns for one observation of a stateless law: (1, 0), one array for
# every call (a new one cost a tenth of a pd_gravity predict's plumbing); it has no element,
# so sharing it among the calls is harmless.
_NO_STATES = np.zeros((1, 0))


_UNIT_BOUNDS: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}


def _unit_bounds(shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(−1, +1) as read-only arrays of ``shape`` (an action row's), built once per shape:
    numpy's clip ufunc converts float scalars on every call (≈ 0.45 µs, measured), arrays
    not; rows (N, m) broadcast against them."""
    bounds = _UNIT_BOUNDS.get(shape)
    if bounds is None:
        bounds = _UNIT_BOUNDS[shape] = (np.full(shape, -1.0), np.full(shape, 1.0))
        for b in bounds:
            b.flags.writeable = False
    return bounds


def _check_command(name: str, commands: np.ndarray) -> None:
    """FloatingPointError showing the first non-finite command (one row, or the only one)."""
    rows = commands.reshape(-1, commands.shape[-1]) if commands.ndim else commands.reshape(1, 1)
    bad = ~np.all(np.isfinite(rows), axis=1)
    if np.any(bad):
        raise FloatingPointError(
            f"controller {name!r} produced a non-finite command {rows[int(np.argmax(bad))]}"
        )


def _row(obs: Observation, i: int) -> Observation:
    """Row ``i`` of stacked observations (views)."""
    return {k: v[i] for k, v in obs.items()}


class InvalidGain(ValueError):
    """An unknown gain name, a gain of the wrong type, or a gain outside its allowed range."""


def is_real(value: Any) -> bool:
    """An int or float (numpy scalars included), not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _annotation_types(owner: type, field: dataclasses.Field) -> set[type]:
    """The plain types a field's annotation names (``float | None`` → {float, NoneType})."""
    try:
        hint = typing.get_type_hints(owner)[field.name]
    except (NameError, TypeError, AttributeError):  # unresolvable: fall back to the default
        return set()
    origin = typing.get_origin(hint)
    args = typing.get_args(hint) if origin in (typing.Union, types.UnionType) else (hint,)
    return {typing.get_origin(a) or a for a in args if isinstance(typing.get_origin(a) or a, type)}


def _field_default(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return dataclasses.MISSING


def _real_sequence(value: Any, shape: tuple[int, ...] | None) -> np.ndarray | None:
    """``value`` as a float array if it holds finite reals (in ``shape``), else None."""
    if isinstance(value, (str, bytes)):
        return None
    try:
        items = np.asarray(value, dtype=object)
    except ValueError:  # ragged nesting
        return None
    if items.ndim == 0:
        return None
    if shape is not None and items.shape != shape:
        return None
    if not all(is_real(x) and np.isfinite(float(x)) for x in items.ravel()):
        return None
    return np.asarray(value, dtype=float)


def check_gain_type(owner: type, field: dataclasses.Field, value: Any, controller: str) -> Any:
    """``value`` checked against the field's default and annotation; returns it normalised.

    A float field takes a finite real number (int or float, not bool or str) and stores a
    float; a tuple/array field takes finite real numbers, as many as its default has; a str
    or bool field takes a str or bool; ``None`` only where the default or annotation allows it.
    Ranges (> 0, ...) are left to each ``Gains.__post_init__``.

    Raises:
        InvalidGain: naming the gain, the value and what is allowed.
    """
    default = _field_default(field)
    kinds = _annotation_types(owner, field)
    if default is not None and default is not dataclasses.MISSING:
        kinds.add(np.ndarray if isinstance(default, np.ndarray) else type(default))
    optional = default is None or type(None) in kinds
    kinds.discard(type(None))
    if float in kinds:
        kinds.discard(int)  # a float field takes ints already
    if not kinds:  # nothing to check against (e.g. an ``Any`` field without a default)
        return value
    if value is None and optional:
        return None
    allowed: list[str] = []
    for kind in sorted(kinds, key=lambda k: k.__name__):
        if issubclass(kind, (tuple, list, np.ndarray)):
            shape = np.shape(default) if isinstance(default, (tuple, list, np.ndarray)) else None
            count = "" if shape is None else " × ".join(map(str, shape)) + " "
            allowed.append(f"a sequence of {count}finite real numbers")
            array = _real_sequence(value, shape)
            if array is not None:
                return array if issubclass(kind, np.ndarray) else kind(array.tolist())
        elif issubclass(kind, numbers.Real) and kind is not bool:
            integral = issubclass(kind, numbers.Integral)
            allowed.append(
                "a finite integer" if integral else "a finite real number (int or float)"
            )
            if is_real(value) and np.isfinite(float(value)):
                if not integral:
                    return float(value)
                if isinstance(value, numbers.Integral):
                    return int(value)
        else:
            allowed.append(f"a {kind.__name__}")
            if isinstance(value, kind) and (kind is bool or not isinstance(value, bool)):
                return value
    if optional:
        allowed.append("None")
    raise InvalidGain(
        f"gain {field.name!r} of controller {controller!r} must be "
        f"{' or '.join(dict.fromkeys(allowed))}, "
        f"got {value!r} ({type(value).__name__})"
    )


class SiteTerms(NamedTuple):
    """A site's kinematics and the arm's dynamics at rows of states (N rows).

    Attributes:
        x: site position (N, 3), m (world).
        quat: site orientation (N, 4), (w, x, y, z), ``mju_mat2Quat`` of its rotation.
        J: geometric Jacobian [J_P; J_O] (N, 6, n), world frame.
        jdqd: J̇ q̇ (N, 6), m/s², rad/s².
        inertia: B̂(q) (N, n, n), armature included (kg m²), or None when not asked for.
        bias: n̂(q, q̇) = Ĉ q̇ + ĝ (N, n), N m, or None when not asked for.
        rotations: the rotations (site → world) of other sites asked for (N, k, 3, 3), or None.
    """

    x: np.ndarray
    quat: np.ndarray
    J: np.ndarray
    jdqd: np.ndarray
    inertia: np.ndarray | None
    bias: np.ndarray | None
    rotations: np.ndarray | None = None


def matvec(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A v (N, m) for rows of matrices (N, m, k) and vectors (N, k): one BLAS call per row,
    the same for any N (so a row's product does not depend on the others)."""
    return (A @ v[..., None])[..., 0]


def transpose(A: np.ndarray) -> np.ndarray:
    """Aᵀ (..., k, m) of a matrix or of rows of matrices (..., m, k) (a view)."""
    return np.swapaxes(A, -1, -2)


class RowDynamics:
    """ĝ(q) and B̂(q) y + n̂(q, q̇) of a robot model for rows of states, by MuJoCo's C calls.

    :meth:`gravity` and :meth:`inverse_dynamics` are the calls of :meth:`Robot.gravity`,
    :meth:`Robot.inertia` and :meth:`Robot.bias`, in their order (so the numbers are theirs,
    bit for bit); :meth:`newton_euler` is the same τ by MuJoCo's recursive Newton-Euler
    without forming B̂ (equal to rounding, the laws' fast path). All on an own ``MjData``, one
    row after the other, without the Robot's per-call validation (``Controller.predict`` has
    checked the observation) and without its cache. Only for a robot whose joints are the
    model's whole state, in order (:meth:`for_robot` returns None otherwise). Pickles as its
    model.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self._build()

    def _build(self) -> None:
        self.data = mujoco.MjData(self.model)
        self._qpos, self._qvel = self.data.qpos, self.data.qvel  # views, built once
        self._qacc = self.data.qacc
        # a view of the model's armatures: an env that changes them (Robot.set_armature
        # writes into the model) is seen at the next call
        self._armature = self.model.dof_armature
        self._M = np.zeros((self.model.nv, self.model.nv))
        self._rne = np.zeros(self.model.nv)  # mj_rne's output of a single row (a buffer)
        self._g = np.zeros(self.model.nv)  # gravity_buffer's
        # gravity's own data: q̇ = 0 for good, so the body velocities and ċdof that
        # mj_comVel computes here stay zero at every q (kinematics does not touch them):
        # one call now is Robot.gravity's call at every q
        self._gravity_data = mujoco.MjData(self.model)
        mujoco.mj_comVel(self.model, self._gravity_data)
        self._gravity_qpos = self._gravity_data.qpos  # a view (the property builds a new one)

    def __getstate__(self) -> dict[str, Any]:
        return {"model": self.model}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.model = state["model"]
        self._build()

    @classmethod
    def for_robot(cls, robot: Robot) -> RowDynamics | None:
        """Row dynamics of ``robot``'s model, or None when its joints are not the whole state."""
        m = robot.model
        whole = m.nq == m.nv == robot.n and np.array_equal(robot.qpos_adr, np.arange(robot.n))
        return cls(m) if whole else None

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """ĝ(q) (N, n) for q (N, n) (or (n,) for (n,)), N m."""
        out = np.empty(q.shape)
        if q.ndim == 1:  # one row, without the row loop
            self._gravity_row(q, out)
            return out
        n = q.shape[-1]
        for q_i, g_i in zip(q.reshape(-1, n), out.reshape(-1, n), strict=False):
            self._gravity_row(q_i, g_i)
        return out

    def gravity_buffer(self, q: np.ndarray) -> np.ndarray:
        """ĝ(q) (n,) for one q (n,), as :meth:`gravity`, in a buffer of this object that the
        next call overwrites (for a caller that only reads it before then). PD + gravity's
        one-row hot path: :meth:`_gravity_row` written out (a call less)."""
        m, d, out = self.model, self._gravity_data, self._g
        self._gravity_qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_rne(m, d, 0, out)
        return out

    def _gravity_row(self, q: np.ndarray, out: np.ndarray) -> None:
        m, d = self.model, self._gravity_data
        self._gravity_qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_rne(m, d, 0, out)

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """τ = B̂(q) q̈ + n̂(q, q̇) (N, n) for rows (N, n) (or (n,)): B̂ q̈ one row at a time
        (the matrix-vector product of ``Robot.inertia(q) @ qdd``), then + n̂ on all rows."""
        bias = np.empty(q.shape)
        if q.ndim == 1:  # one row, without the row loop
            return self._inertia_row(q, qd, bias).dot(qdd) + bias
        tau = np.empty(q.shape)
        n = q.shape[-1]
        for q_i, qd_i, qdd_i, b_i, t_i in zip(
            q.reshape(-1, n),
            qd.reshape(-1, n),
            qdd.reshape(-1, n),
            bias.reshape(-1, n),
            tau.reshape(-1, n),
            strict=False,  # (equal lengths; strict=True costs 2 µs)
        ):
            t_i[:] = self._inertia_row(q_i, qd_i, b_i).dot(qdd_i)
        return tau + bias

    def newton_euler(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """τ = B̂(q) q̈ + n̂(q, q̇) (N, n) for rows (N, n) (or (n,)) by MuJoCo's recursive
        Newton-Euler: q, q̇, q̈ set, ``mj_kinematics``, ``mj_comPos``, ``mj_comVel`` and
        ``mj_rne`` with the acceleration (the rigid bodies' M(q) q̈ + c(q, q̇) + g(q)), plus
        the armature's diag(I_a) q̈ that ``mj_rne`` leaves out (``mj_crb`` adds it to B̂'s
        diagonal) on all rows at once.

        The torque of :meth:`inverse_dynamics` (B̂ formed, then B̂ q̈ + n̂) summed in another
        order: equal to ≈ 1e-14 of its largest component (measured over 20,000 random
        states of the iiwa14), and ≈ 1 µs cheaper per row (no ``mj_crb``, ``mj_fullM`` and
        matrix-vector product). No passive or constraint forces (``mj_inverse`` would add
        them, and run collision detection to find the constraints).
        """
        if q.ndim == 1:  # one row (computed torque's hot path): _newton_euler_row written out
            # (a call less), the rigid bodies' τ into a buffer, + diag(I_a) q̈
            m, d = self.model, self.data
            self._qpos[:] = q
            self._qvel[:] = qd
            self._qacc[:] = qdd
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_comVel(m, d)
            rigid = self._rne
            mujoco.mj_rne(m, d, 1, rigid)
            tau = _MUL(self._armature, qdd)
            return _ADD(rigid, tau, tau)
        tau = np.empty(q.shape)
        n = q.shape[-1]
        for q_i, qd_i, qdd_i, t_i in zip(
            q.reshape(-1, n),
            qd.reshape(-1, n),
            qdd.reshape(-1, n),
            tau.reshape(-1, n),
            strict=False,  # (equal lengths)
        ):
            self._newton_euler_row(q_i, qd_i, qdd_i, t_i)
        return _ADD(tau, _MUL(self._armature, qdd), out=tau)

    def _newton_euler_row(
        self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, out: np.ndarray
    ) -> None:
        """M(q) q̈ + c(q, q̇) + g(q) of the rigid bodies (no armature) into ``out``."""
        m, d = self.model, self.data
        self._qpos[:] = q
        self._qvel[:] = qd
        self._qacc[:] = qdd
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        mujoco.mj_rne(m, d, 1, out)

    def site_terms(
        self, site: int, q: np.ndarray, qd: np.ndarray, *, inertia: bool = False,
        bias: bool = False, rotations: tuple[int, ...] = (),
    ) -> SiteTerms:
        """:class:`SiteTerms` of site id ``site`` for rows q, q̇ (N, n): per row one
        ``mj_kinematics``, ``mj_comPos``, ``mj_comVel``, then ``mj_jacSite``, ``mj_jacDot``
        (J̇ q̇ as one batched product after the loop), ``mju_mat2Quat`` and, when asked,
        ``mj_crb`` + ``mj_fullM`` (B̂), ``mj_rne`` (n̂) and the rotations of the site ids
        ``rotations`` — the calls of :meth:`Robot.site_pose`, :meth:`Robot.jacobian`,
        :meth:`Robot.jacobian_dot_qdot`, :meth:`Robot.inertia` and :meth:`Robot.bias`, on
        this object's data."""
        m, d = self.model, self.data
        rows, nv = len(q), m.nv
        x, quat = np.empty((rows, 3)), np.empty((rows, 4))
        J, Jdot = np.empty((rows, 6, nv)), np.empty((rows, 6, nv))
        B = np.empty((rows, nv, nv)) if inertia else None
        n = np.empty((rows, nv)) if bias else None
        R = np.empty((rows, len(rotations), 9)) if rotations else None
        others = list(rotations)
        body = int(m.site_bodyid[site])
        site_xpos, site_xmat = d.site_xpos[site], d.site_xmat[site]
        for i in range(rows):
            self._qpos[:] = q[i]
            self._qvel[:] = qd[i]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_comVel(m, d)
            J_i, Jdot_i = J[i], Jdot[i]
            mujoco.mj_jacSite(m, d, J_i[:3], J_i[3:], site)
            mujoco.mj_jacDot(m, d, Jdot_i[:3], Jdot_i[3:], site_xpos, body)
            x[i] = site_xpos
            mujoco.mju_mat2Quat(quat[i], site_xmat)
            if B is not None:
                mujoco.mj_crb(m, d)
                mujoco.mj_fullM(m, d, B[i])
            if n is not None:
                mujoco.mj_rne(m, d, 0, n[i])
            if R is not None:
                R[i] = d.site_xmat[others]
        return SiteTerms(
            x, quat, J, matvec(Jdot, qd), B, n,
            None if R is None else R.reshape(rows, len(others), 3, 3),
        )

    def _inertia_row(self, q: np.ndarray, qd: np.ndarray, bias: np.ndarray) -> np.ndarray:
        """B̂(q) (a buffer, overwritten by the next call); n̂(q, q̇) into ``bias``."""
        m, d, M = self.model, self.data, self._M
        self._qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_crb(m, d)
        mujoco.mj_fullM(m, d, M)
        self._qvel[:] = qd
        mujoco.mj_comVel(m, d)
        mujoco.mj_rne(m, d, 0, bias)
        return M


class RobotRows:
    """The row calls of :class:`RowDynamics` (:meth:`~RowDynamics.gravity`,
    :meth:`~RowDynamics.newton_euler`, :meth:`~RowDynamics.site_terms`) through a
    :class:`Robot`'s own methods, row by row: for a robot whose joints are not its model's
    whole state (where :meth:`RowDynamics.for_robot` gives None)."""

    def __init__(self, robot: Robot) -> None:
        self.robot = robot

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """ĝ(q) (N, n) for rows q (N, n)."""
        return np.stack([self.robot.gravity(q_i) for q_i in q])

    def newton_euler(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """B̂(q) q̈ + n̂(q, q̇) (N, n) for rows (N, n)."""
        return np.stack([self.robot.inverse_dynamics(*row) for row in zip(q, qd, qdd, strict=True)])

    def site_terms(
        self, site: int, q: np.ndarray, qd: np.ndarray, *, inertia: bool = False,
        bias: bool = False, rotations: tuple[int, ...] = (),
    ) -> SiteTerms:
        """:class:`SiteTerms` (see :meth:`RowDynamics.site_terms`) by the Robot's methods."""
        r = self.robot
        x, quat = np.empty((len(q), 3)), np.empty((len(q), 4))
        for i, q_i in enumerate(q):
            x[i], R = r.site_pose(site, q_i)
            mujoco.mju_mat2Quat(quat[i], R.ravel())
        return SiteTerms(
            x,
            quat,
            np.stack([r.jacobian(site, q_i) for q_i in q]),
            np.stack([r.jacobian_dot_qdot(site, *row) for row in zip(q, qd, strict=True)]),
            np.stack([r.inertia(q_i) for q_i in q]) if inertia else None,
            np.stack([r.bias(*row) for row in zip(q, qd, strict=True)]) if bias else None,
            np.array([[r.site_pose(o, q_i)[1] for o in rotations] for q_i in q])
            if rotations else None,
        )


class Controller:
    """Base class: subclasses define ``Gains`` (a frozen dataclass), ``control`` and state.

    Class attributes:
        name: the name ``baselines.make`` knows the controller by.
        tasks: environment names (ids without namespace and version) it applies to.
        Gains: frozen dataclass of gains with units in its docstring.
    """

    name: ClassVar[str] = ""
    tasks: ClassVar[tuple[str, ...]] = ()
    Gains: ClassVar[type] = type(None)

    def __init__(self, context: TaskContext, gains: Any = None, **overrides: Any) -> None:
        self.context = context
        self.gains = self.make_gains(gains, **overrides)
        self.dt = context.dt
        self.action_scale = np.asarray(context.action_scale, dtype=float)

    @classmethod
    def make_gains(cls, gains: Any = None, **overrides: Any) -> Any:
        """Build ``Gains`` from defaults and overrides.

        Raises:
            InvalidGain: an unknown gain name, a ``gains`` that is not a ``Gains``, an override
                of the wrong type (see :func:`check_gain_type`), or one ``Gains`` rejects.
        """
        fields = {f.name: f for f in dataclasses.fields(cls.Gains)}
        unknown = sorted(set(overrides) - set(fields))
        if unknown:
            raise InvalidGain(
                f"controller {cls.name!r} has no gain(s) {unknown}; allowed: {list(fields)}"
            )
        if gains is not None and not isinstance(gains, cls.Gains):
            raise InvalidGain(
                f"gains of controller {cls.name!r} must be a {cls.Gains.__name__}, "
                f"got {type(gains).__name__}"
            )
        checked = {
            key: check_gain_type(cls.Gains, fields[key], value, cls.name)
            for key, value in overrides.items()
        }
        base = gains if gains is not None else cls.Gains()
        return dataclasses.replace(base, **checked)

    # ------------------------------------------------------------------ to override
    @property
    def state_size(self) -> int:
        """Length of the per-environment state vector."""
        return 0

    def initial_state(self, obs: Observation) -> np.ndarray:
        """State at the start of an episode (state_size,)."""
        return np.zeros(self.state_size)

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """Physical command (e.g. joint torques (n,)) for one observation; updates ``state``."""
        raise NotImplementedError

    def control_batch(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """Physical commands for stacked observations (each value (N, ...), float64; commands
        (N, m), ``state`` (N, state_size) updated in place) or for one observation (1-D
        values, command (m,), ``state`` (state_size,)). Used by :meth:`predict` when the
        class sets ``vectorized = True``: a law whose arithmetic is element-wise over the rows
        (and whose model calls run row by row, e.g. :class:`RowDynamics`) computes every row
        bit for bit as :meth:`control` computes it alone, without a Python dict per row.
        Default: :meth:`control` on each row."""
        if obs["q"].ndim == 1:
            return np.asarray(self.control(obs, state), dtype=float)
        out = np.empty((len(obs["q"]), self.action_scale.size))
        for i in range(len(out)):
            out[i] = self.control(_row(obs, i), state[i])
        return out

    def row_dynamics(self) -> RowDynamics | None:
        """:class:`RowDynamics` of the controller's nominal ``self.robot`` (built on first use
        and again when ``self.robot`` changes), or None: no ``robot``, identified
        ``parameters`` (evaluated by :mod:`cir_gym.dynamics` instead), or a robot whose joints
        are not its model's whole state."""
        robot = getattr(self, "robot", None)
        if robot is None or getattr(self, "parameters", None) is not None:
            return None
        cached = self.__dict__.get("_row_dynamics")
        if cached is None or cached[0] is not robot.model:
            cached = self._row_dynamics = (robot.model, RowDynamics.for_robot(robot))
        return cached[1]

    def model_rows(self) -> RowDynamics | RobotRows:
        """The row calls of the nominal ``self.robot``'s model: :meth:`row_dynamics`, or
        :class:`RobotRows` where that is None."""
        rows = self.row_dynamics()
        if rows is None:
            rows = self.__dict__.get("_robot_rows")
            if rows is None or rows.robot is not self.robot:
                rows = self._robot_rows = RobotRows(self.robot)
        return rows

    #: True when :meth:`control_batch` is the law on all rows at once (and ``initial_state``
    #: has no side effect, so every starting row is initialised before the batch is run);
    #: False (default): ``initial_state`` and ``control`` row by row, as a row alone.
    vectorized: ClassVar[bool] = False

    # ------------------------------------------------------------------ protocol
    def predict(
        self,
        observation: Observation,
        state: np.ndarray | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """SB3's protocol: (action in [-1, 1], new state); single or batched observations.

        Plumbing cost: one float64 view per key, one finite check over the whole observation
        (a dot product of all its values; the per-key check that names the culprit runs only
        when that fails), one of the command, and the scaling/clipping on all rows at once.
        A single observation is a batch of one row (the same code, so a row gives the same
        action alone or in a batch).

        Raises:
            ValueError: an observation without ``q``, or with NaN/inf values (naming the key).
            FloatingPointError: the law produced a non-finite command.
        """
        if "q" not in observation:
            raise ValueError(
                f"observation must be a dict with a 'q' entry, got keys {list(observation)}"
            )
        obs = _float_observation(observation)
        batched = obs["q"].ndim == 2  # every cir_gym observation has q (n,)
        size = self.state_size
        if (
            not (batched or size)
            and self.vectorized
            and (state is None or getattr(state, "size", None) == 0)
        ):  # a stateless law on one observation: no state rows to build
            return self._finish(self.control_batch(obs, _NO_STATE), False), _NO_STATES
        n_envs = len(obs["q"]) if batched else 1
        if state is None:
            state = np.zeros((n_envs, size))
            starts = None  # every row starts
        else:
            state = np.array(state, dtype=float, copy=True).reshape(n_envs, size)
            starts = (
                None
                if episode_start is None
                else np.broadcast_to(np.asarray(episode_start, dtype=bool), (n_envs,))
            )
        if self.vectorized:  # the law on all rows at once (a single observation: 1-D values)
            if size:
                for i in range(n_envs) if starts is None else np.flatnonzero(starts):
                    state[i] = self.initial_state(_row(obs, i) if batched else obs)
            commands = self.control_batch(obs, state if batched else state[0])
        elif batched:
            commands = np.empty((n_envs, self.action_scale.size))
            for i in range(n_envs):
                obs_i = _row(obs, i)
                if starts is None or starts[i]:
                    state[i] = self.initial_state(obs_i)
                commands[i] = self.control(obs_i, state[i])
        else:
            if starts is None or starts[0]:
                state[0] = self.initial_state(obs)
            commands = np.asarray(self.control(obs, state[0]), dtype=float)
        return self._finish(commands, batched), state

    def _finish(self, commands: np.ndarray, batched: bool) -> np.ndarray:
        """Commands → actions: scaled, checked finite (one dot product), clipped to [-1, 1] in
        float64, then rounded to float32."""
        actions = commands / self.action_scale
        flat = actions if batched is False else actions.ravel()
        if not _isfinite(flat.dot(flat)):  # NaN/inf (or an overflow: the exact check decides)
            _check_command(self.name, commands)
        row = actions.shape[-1:]
        low, high = _UNIT_BOUNDS.get(row) or _unit_bounds(row)
        CLIP(actions, low, high, actions)  # (into a float32 out=: slower, a casting loop)
        return actions.astype(np.float32)  # clipped in float64, then rounded

    def __call__(self, observation: Observation) -> np.ndarray:
        """Stateless convenience for a single step from a fresh state."""
        return self.predict(observation)[0]


def _first_row(result: Any) -> Any:
    """Row 0 of a result computed on rows: arrays, tuples (named too) and dataclasses of them."""
    if isinstance(result, np.ndarray):
        return result[0]
    if isinstance(result, tuple):
        rows = [_first_row(r) for r in result]
        return type(result)._make(rows) if hasattr(result, "_fields") else tuple(rows)
    if dataclasses.is_dataclass(result) and not isinstance(result, type):
        return type(result)(
            **{f.name: _first_row(getattr(result, f.name)) for f in dataclasses.fields(result)}
        )
    return result


def rows_method(method: Callable[..., Any]) -> Callable[..., Any]:
    """Lets a method written on rows — ``method(self, obs, *arrays)`` with observation values
    (N, ...) and arrays (N, ...) — take one observation (1-D ``q``) as a row of one: the
    values and arrays get a leading axis (views: a float64 state updated in place is the
    caller's), and the result (arrays, tuples, dataclasses of them) is given back as that
    row. So one observation runs the very code of a batch."""

    @functools.wraps(method)
    def one_or_rows(self: Any, obs: Observation, *arrays: np.ndarray) -> Any:
        if np.ndim(obs["q"]) != 1:
            return method(self, obs, *arrays)
        rows = {k: np.asarray(v, dtype=float)[None] for k, v in obs.items()}
        return _first_row(method(self, rows, *(np.asarray(a)[None] for a in arrays)))

    return one_or_rows


class RowLaw(Controller):
    """A controller whose law is written once, on rows (:meth:`control_rows`): one
    observation is its one-row case, so a row gives the same command alone or in a batch
    when its arithmetic is row by row — element-wise numpy, stacked matrix products and
    solves (one BLAS/LAPACK call per row's matrices), model calls row by row (tested)."""

    vectorized = True

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """A subclass that redefines :meth:`control` alone (an adapter translating one
        observation before the law) is served row by row through it (``vectorized`` False);
        one that writes :meth:`control_rows` stays vectorised."""
        super().__init_subclass__(**kwargs)
        if "control" in cls.__dict__ and "control_rows" not in cls.__dict__:
            cls.vectorized = False

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """The law on rows: values (N, ...), ``state`` (N, state_size) updated in place;
        commands (N, m)."""
        raise NotImplementedError

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        return self.control_batch(obs, state)

    @rows_method
    def control_batch(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """:meth:`control_rows` on stacked observations, or on one as a row of one."""
        return self.control_rows(obs, state)
