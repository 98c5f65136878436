"""Hybrid force/position control for the peg-in-hole task (chapter 6), and its foil.

The task frame is the *nominal* hole frame (origin at the centre of the hole's top opening, z
along the bore, out of the hole); wrenches are taken at the peg tip. The bore imposes the
**natural constraints** (a peg in the bore cannot translate sideways nor tilt:
v_x = v_y = 0, ω_x = ω_y = 0; nothing resists sliding along or turning about the axis:
f_z = 0, μ_z = 0). The task sets the complementary **artificial constraints**: zero lateral
force and zero tilting moment, f_x = f_y = 0, μ_x = μ_y = 0 (so the bore's walls, not the
controller, decide where the peg goes sideways and how it tilts), and a motion along the axis,
v_z = v̄ (insertion) and ω_z = 0 (the peg need not turn). The selection matrix of the notes
(1 on the force-controlled directions) is therefore

    Σ = diag(1, 1, 0, 1, 1, 0)  in (x, y, z, rot x, rot y, rot z) of the hole frame

(:func:`selection_matrix`). Σ applies in the bore (the tip deeper than ``guard_height``
below the nominal top face). Above and on the face the peg is not yet in the bore, so nothing
tilts it back if it tilts: Σ_face = diag(1, 1, 0, 0, 0, 0) holds it square to the nominal
axis (zero lateral force, motion along the axis and in the three rotations). The commanded
wrench at the tip is

    h_c = Σ [γ̄ + u_I − D_F ẋ + K_tilt φ] + M (I − Σ) [K_P (x̄ − x) − K_D ẋ],
    u_I = K_I ∫ Σ (γ̄ − γ̂) dt,  γ̄ = 0 (in the bore and above it),

with the motion law an acceleration through the task-space inertia Λ_h = R Λ(q) Rᵀ of the
tip in the hole frame: above the bore M = Λ_h (the inverse-dynamics form: a motion command
along the axis accelerates the tip along the axis only, ẍ = (I − Σ) a + Λ⁻¹ Σ h_f, instead of
dragging it sideways through the off-diagonal inertia); in the bore M = (I − Σ) Λ_h, the
motion wrench filtered by the selection matrix (its components on the force-controlled
directions, Λ's coupling terms times the axial command, pushed the peg into the walls and
tilted it). γ̂ is the measured wrench the peg exerts on the environment (the F/T reading minus
the peg's weight, moved to the tip, :func:`cir_gym.ft_sensor.contact_wrench`).

The force loop on Σ is the course's explicit force control: an integral regulator
R_f(s) = K_I/s around the contact, whose force response is G_f(s) = ω_n²/(s² + ω_n²) with
ω_n = sqrt(k_e/m); the crossover ω_cf ≈ K_I is put below ω_n. Here m is the tip's task
inertia Λ_ii in each force-controlled direction (from the nominal model, every step) and k_e
the contact stiffness the law designs with (``stiffness``, k̂_e r² on the moments), so
K_I,i = ``crossover_ratio`` · sqrt(k̂_i/Λ_ii) (:meth:`HybridForcePosition.force_gains`). The
integral is bounded (``integral_limit``: crossing the clearance the peg sees no force) and
is zero off Σ. The accommodation damping −D_F ẋ stays (the course's loop assumes a damped
mass: with R_f = K_I/s alone the loop on an undamped spring is unstable), and so does a weak
tilt spring K_tilt toward the nominal axis (a compliance centre at the tip, weak enough that
the walls tilt the peg by the hole's 2°). ``crossover_ratio=0`` turns the force loop off:
the force-controlled directions then follow γ̄ by accommodation alone (no force feedback).
Joint torques: τ = g(q) + J_tipᵀ h_c + N_dynᵀ τ_posture (gravity of the nominal arm and peg;
the posture term acts in the null space of the dynamically consistent inverse, so it leaves
the tip alone). The axial command is saturated at ``push_force`` and the axial reference
advances at ``guard_speed`` within ``guard_height`` of the nominal face (a guarded move).

``hybrid_spiral`` adds the classic search: while the peg rests on the block beside the hole
(axial contact force above ``contact_force`` and no drop below the surface height found at
contact) the roles of x, y and z swap — Σ_search = diag(0, 0, 1, 0, 0, 0): the tip follows an
Archimedean spiral r = p θ / 2π (pitch p = the hole's diametral clearance scale, 0.5 mm) in
the hole plane at ``omega_search`` (stiff enough to slide against friction) while pressing
with ``search_force``: γ̄_z = −``search_force`` through the same integral force loop (on Σ_search,
the axial direction), with the damping −D_F ż; the peg is held square to the face. A drop of
``drop`` below the contact height means the tip found the hole: the controller returns to Σ
and inserts.

``position_spiral`` is hybrid_spiral without the force loop: the same approach, spiral and
insertion with γ̄ = 0 on Σ by accommodation alone (K_I = 0) and, on the face, the axial push as
feed-forward plus damping, h_z = −``search_force`` − D_F ż. The F/T reading only detects the
contact (and the tip's height the drop): position control with a spiral search, which inserts
where the force loop makes the spiral hit the force limit.

``position_only`` is stiff Cartesian position control of the tip down the nominal hole's axis
(τ = g + J_tipᵀ (K_P x̃ − K_D ẋ), no force feedback, no search): the reason force control
exists. It fails by construction: with the hole off by more than the radial clearance it lands
on the block and its spring presses K_P × 22.5 mm = 112 N into the face.

Every law is written once on rows of observations (:class:`~cir_gym.baselines.base.RowLaw`):
Σ, the guarded reference and the spiral's phases are per-row masks, the model calls run row by
row, and one observation is a row of one, so a batch gives each row's command alone
(tests/test_batched_laws.py). The state holds the posture target q₀ of the null-space term.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any, ClassVar

import mujoco
import numpy as np
from cir_gym.baselines.base import (
    Controller,
    InvalidGain,
    Observation,
    RowLaw,
    is_real,
    matvec,
    transpose,
)
from cir_gym.baselines.interaction import Admittance, AdmittanceGains

from cir_gym.context import TaskContext
from cir_gym.ft_sensor import contact_wrench
from cir_gym.operational_space import (
    dynamically_consistent_inverse,
    null_space_projector,
    skew,
    task_inertia,
)
from cir_gym.robot import ModelError, Robot, apply_model_error

__all__ = [
    "HYBRID_CONTROLLERS",
    "HYBRID_STATE",
    "POSITION_SPIRAL_STATE",
    "POSITION_STATE",
    "SPIRAL_STATE",
    "TASK_ADAPTERS",
    "AccommodationGains",
    "AdmittanceGainsPeg",
    "HybridForcePosition",
    "HybridForcePositionGains",
    "HybridSpiral",
    "HybridSpiralGains",
    "PegAdmittance",
    "PositionOnly",
    "PositionOnlyGains",
    "PositionSpiral",
    "PositionSpiralGains",
    "SpiralSearchGains",
    "selection_matrix",
]

#: Orientation of the tip frame in the hole frame when the peg is aligned with the bore.
ALIGNED = np.diag([-1.0, 1.0, -1.0])

#: The law's quantities at rows of observations (see :meth:`HybridForcePosition.frames`).
Frames = dict[str, np.ndarray]


def _rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector θ r (..., 3) of rotation matrices (..., 3, 3), θ ∈ [0, π] (the shorter
    rotation, as :func:`cir_gym.operational_space.rotvec_error`): MuJoCo's C routines, one
    matrix after the other (for the few rows of a batch far cheaper than numpy's array
    temporaries, and a row's result does not depend on the others)."""
    R = np.ascontiguousarray(R, dtype=float)
    phi, quat = np.empty(R.shape[:-1]), np.empty(4)
    for R_i, phi_i in zip(R.reshape(-1, 9), phi.reshape(-1, 3), strict=True):
        mujoco.mju_mat2Quat(quat, R_i)
        mujoco.mju_quat2Vel(phi_i, quat, 1.0)
    return phi


def _matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) (w, x, y, z): MuJoCo's
    ``mju_quat2Mat``, one quaternion after the other (as :func:`_rotvec`)."""
    quat = np.ascontiguousarray(quat, dtype=float)
    R = np.empty((*quat.shape[:-1], 3, 3))
    for q_i, R_i in zip(quat.reshape(-1, 4), R.reshape(-1, 9), strict=True):
        mujoco.mju_quat2Mat(R_i, q_i)
    return R


def _quaternion(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) (w, x, y, z) of rotation matrices (..., 3, 3): MuJoCo's
    ``mju_mat2Quat``, one matrix after the other (as :func:`_rotvec`)."""
    R = np.ascontiguousarray(R, dtype=float)
    quat = np.empty((*R.shape[:-2], 4))
    for R_i, q_i in zip(R.reshape(-1, 9), quat.reshape(-1, 4), strict=True):
        mujoco.mju_mat2Quat(q_i, R_i)
    return quat


_NEXT, _PREV = [1, 2, 0], [2, 0, 1]  # (a × b)_i = a_{i+1} b_{i+2} − a_{i+2} b_{i+1}


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b (..., 3) of vectors (..., 3) (broadcasts), without ``np.cross``'s axis handling."""
    return a[..., _NEXT] * b[..., _PREV] - a[..., _PREV] * b[..., _NEXT]


def _block_diag2(R: np.ndarray) -> np.ndarray:
    """diag(R, R) (..., 6, 6) of rotations (..., 3, 3) (the twist/wrench rotation)."""
    R6 = np.zeros((*R.shape[:-2], 6, 6))
    R6[..., :3, :3] = R
    R6[..., 3:, 3:] = R
    return R6


def _take(frames: Frames, rows: np.ndarray) -> Frames:
    """The ``rows`` (a mask or indices) of every quantity of ``frames``."""
    return {key: value[rows] for key, value in frames.items()}


def selection_matrix(search: bool = False, face: bool = False) -> np.ndarray:
    """Σ (6, 6): 1 on the force-controlled directions of the hole frame (see the module doc).

    ``search=False``: insertion, Σ = diag(1, 1, 0, 1, 1, 0) (zero lateral force and tilting
    moment, motion along and about the axis). ``search=True``: spiral search on the block's
    face, Σ = diag(0, 0, 1, 0, 0, 0): the face is the constraint now (natural: v_z = 0), so
    press along the axis and move in the plane, holding the peg square to the face.
    ``face=True``: above the bore and on the face, Σ = diag(1, 1, 0, 0, 0, 0): the peg is held
    square to the nominal face (a free tilt there tips the peg over the hole's edge).
    """
    if search:
        return np.diag([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    if face:
        return np.diag([1.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    return np.diag([1.0, 1.0, 0.0, 1.0, 1.0, 0.0])


def _require_torque(name: str, context: TaskContext) -> None:
    if context.action_kind != "joint_torque":
        raise ValueError(
            f"controller {name!r} commands joint torques: make the env with "
            f"control='torque', not {context.action_kind!r}"
        )


def _check_positive(owner: str, **values: float) -> None:
    for name, value in values.items():
        if not is_real(value) or not np.isfinite(value) or value < 0:
            raise InvalidGain(
                f"gain {name!r} of {owner} must be a finite number >= 0, got {value!r}"
            )


#: State of :class:`HybridForcePosition` (float64 rows, viewed with named fields): time since
#: the start (s), the axial reference z̄ in the hole frame (m), and the force loop's integral
#: term u_I (6,) in the hole frame (N, N m); then the posture target ``q0`` (n,) (rad, the
#: posture at the episode's start) of every tip controller (:func:`_with_posture`).
HYBRID_STATE = np.dtype([("t", "f8"), ("z_ref", "f8"), ("force_integral", "f8", (6,))])
#: :data:`HYBRID_STATE` plus the spiral search: mode (0 approach/insert, 1 search, 2 found),
#: spiral angle θ (rad), spiral centre (2,) and contact height z_c (m), hole frame.
_SEARCH_FIELDS = [("mode", "f8"), ("theta", "f8"), ("centre", "f8", (2,)), ("z_contact", "f8")]
SPIRAL_STATE = np.dtype([*HYBRID_STATE.descr, *_SEARCH_FIELDS])
#: State of :class:`PositionSpiral`: :data:`SPIRAL_STATE` without the force loop's integral.
POSITION_SPIRAL_STATE = np.dtype([("t", "f8"), ("z_ref", "f8"), *_SEARCH_FIELDS])
#: State of :class:`PositionOnly`: the axial reference z̄ (m), then the posture target.
POSITION_STATE = np.dtype([("z_ref", "f8")])
APPROACH, SEARCH, FOUND = 0, 1, 2


def spiral_point(fields: np.ndarray, pitch: float, speed: float, dt: float) -> np.ndarray:
    """The spiral search's next point (N, 2) (m, hole plane): θ in ``fields`` advanced by one
    period ``dt`` at ``speed`` (m/s) along the Archimedean spiral r = ``pitch`` θ/2π about
    ``fields["centre"]`` (the step's radius at least ``pitch``/2, so the first turn is not a
    spin on the spot)."""
    theta = fields["theta"]
    r = pitch * theta / (2 * np.pi)
    theta += speed * dt / np.maximum(r, pitch / 2)
    r = pitch * theta / (2 * np.pi)
    return fields["centre"] + r[:, None] * np.stack((np.cos(theta), np.sin(theta)), axis=-1)


def _with_posture(layout: np.dtype, n: int) -> np.dtype:
    """``layout`` followed by the posture target ``q0`` (n,) (rad)."""
    return np.dtype([*layout.descr, ("q0", "f8", (n,))])


def _fields(state: np.ndarray, layout: np.dtype) -> np.ndarray:
    """State rows (..., size) float64 seen with the named fields of ``layout`` (views: writes
    go to the rows); a layout shorter than a row names the row's leading part. One row (size,)
    gives one record (``np.void``), rows (N, size) a structured array (N,)."""
    return state[..., : layout.itemsize // 8].view(layout)[..., 0]


@dataclass(frozen=True)
class AccommodationGains:
    """Gains the hybrid laws share, the force loop aside (hole frame, at the tip): the motion
    law, the accommodation on the force-controlled directions, the guarded move and the
    posture. A law with these alone (:class:`PositionSpiral`) reads the F/T sensor only to
    detect contact.

    Attributes:
        omega_n: natural frequency of the motion-controlled directions (rad/s):
            K_P = ω_n², K_D = 2 ζ ω_n (per unit task inertia, the course's design).
        zeta: their damping ratio.
        d_f: damping of the lateral force-controlled directions (N s/m).
        d_f_rot: damping of the tilting directions (N m s/rad).
        contact_force: axial push (N) above which the peg is on the block.
        k_tilt: weak rotational stiffness toward the nominal axis in the moment-controlled
            directions (N m/rad): a compliance centre at the tip, so that the peg does not
            wander in free space, weak enough that the bore's walls tilt it (2° ≈ 0.2 N m).
        speed: insertion speed v̄ along the axis (m/s).
        guard_speed: speed within ``guard_height`` of the nominal top face (m/s): a guarded
            move, so that landing on the block beside the hole is not an impact.
        guard_height: (m) above and below the nominal top face.
        push_force: bound on the axial force command (N).
        posture_stiffness, posture_damping: null-space posture PD (N m/rad, N m s/rad).
    """

    omega_n: float = 30.0
    zeta: float = 1.0
    d_f: float = 150.0
    d_f_rot: float = 2.0
    contact_force: float = 2.0
    k_tilt: float = 0.5
    speed: float = 0.01
    guard_speed: float = 0.002
    guard_height: float = 0.0015
    push_force: float = 15.0
    posture_stiffness: float = 20.0
    posture_damping: float = 5.0

    def __post_init__(self) -> None:
        _check_positive(type(self).__name__, **self.__dict__)


@dataclass(frozen=True)
class HybridForcePositionGains(AccommodationGains):
    """Gains of :class:`HybridForcePosition`: :class:`AccommodationGains` plus the force loop's

    Attributes:
        stiffness: the contact stiffness k̂_e the force loop is designed against (N/m): steel
            on steel behind MuJoCo's 1-ms contact, the figure PegInHole's admittance adapter
            designs with (moments: k̂_e r², a rim contact at the peg's radius r).
        crossover_ratio: the force loop's crossover ω_cf as a fraction of the contact's natural
            frequency ω_n,i = sqrt(k̂_i / Λ_ii) in each force-controlled direction i (Λ the
            tip's task inertia, hole frame): the integral gain K_I,i = ratio · ω_n,i (1/s), the
            course's explicit force control R_f(s) = K_I/s with ω_cf ≈ K_I < ω_n. 0: no force
            feedback (the force-controlled directions follow γ̄ by accommodation alone).
        integral_limit: bound on the integral term's force (N; anti-windup: a peg crossing the
            clearance sees no force, so the integral would otherwise hold its push).
        integral_limit_moment: its bound on the moments (N m).
    """

    stiffness: float = 1e7
    crossover_ratio: float = 0.1
    integral_limit: float = 10.0
    integral_limit_moment: float = 0.2


class _TipController(RowLaw):
    """Shared kinematics: the peg tip of the nominal arm (flange + tool offset) in the hole frame.

    The nominal robot carries the peg as the file's ``payload`` (its centre of mass lies 5 cm
    beyond the flange, as the peg's does), so g(q) includes the peg's weight. Every law is
    written once on rows of observations (values (N, ...), state (N, size)): the model calls
    row by row (:meth:`Controller.model_rows`), the arithmetic on all rows; one observation is
    a row of one. The state is the law's fields (``law_state``) and the posture target q₀.
    """

    tasks: ClassVar[tuple[str, ...]] = ("PegInHole",)
    #: the law's own state fields (the posture target q₀ follows them)
    law_state: ClassVar[np.dtype] = np.dtype([])

    def __init__(
        self,
        context: TaskContext,
        gains: Any = None,
        *,
        robot: Robot | None = None,
        **overrides: Any,
    ) -> None:
        _require_torque(self.name, context)
        super().__init__(context, gains, **overrides)
        extras = context.extras
        self.robot = robot if robot is not None else context.nominal_robot()
        self.tool_mass = float(extras.get("tool_mass", 0.0))
        if robot is None and self.tool_mass > 0:
            apply_model_error(self.robot.model, ModelError(payload_mass=self.tool_mass))
            self.robot.invalidate()
        self.tip_offset = float(extras.get("tip_offset", 0.0))
        self.tool_com = np.array(extras.get("tool_com", np.zeros(3)), dtype=float)  # sensor frame
        self.site = self.robot.site_id(context.site or "flange")
        self.layout = _with_posture(self.law_state, self.robot.n)

    @property
    def state_size(self) -> int:
        return self.layout.itemsize // 8

    def initial_state(self, obs: Observation) -> np.ndarray:
        """The law's fields at zero, z̄ (when the law has one) at the tip's height, q₀ = q."""
        state = np.zeros(self.state_size)
        fields = _fields(state, self.layout)
        if "z_ref" in self.layout.names:
            fields["z_ref"] = obs["peg_pos"][2]
        fields["q0"] = obs["q"]
        return state

    def tip_terms(self, obs: Observation, q0: np.ndarray) -> Frames:
        """The nominal arm at rows of measured states, at the peg tip, world frame: ``q``,
        ``qd`` and the posture target ``q0`` (N, n); ``p_flange``, ``p_tip`` (N, 3) (m);
        ``R_tip`` (N, 3, 3) (the flange's rotation, tip → world); ``J`` (N, 6, n) the tip's
        geometric Jacobian; ``inertia`` B̂(q) (N, n, n) (kg m²); ``gravity`` ĝ(q) (N, n) (N m)."""
        q, qd = obs["q"], obs["qd"]
        rows = self.model_rows()
        flange = rows.site_terms(self.site, q, qd, inertia=True, rotations=(self.site,))
        R = flange.rotations[:, 0]
        r = R[..., :, 2] * self.tip_offset  # flange → tip (N, 3)
        J = flange.J.copy()
        J[:, :3] -= skew(r) @ flange.J[:, 3:]  # v_tip = v_f + ω × r = v_f − S(r) ω
        return {
            "q": q,
            "qd": qd,
            "q0": q0,
            "p_flange": flange.x,
            "p_tip": flange.x + r,
            "R_tip": R,
            "J": J,
            "inertia": flange.inertia,
            "gravity": rows.gravity(q),
        }

    def task_wrench_torque(
        self, arm: Frames, h_world: np.ndarray, Lambda: np.ndarray | None = None
    ) -> np.ndarray:
        """τ = ĝ(q) + Jᵀ h + N_dynᵀ τ₀ (N, n) (N m): the tip wrench h (N, 6) (world frame), and
        the posture PD τ₀ = K_p,0 (q₀ − q) − K_d,0 q̇ in the null space of the dynamically
        consistent inverse J̄ = B̂⁻¹ Jᵀ Λ (``Lambda``: the tip's world-frame Λ if known).
        ``arm``: :meth:`tip_terms`."""
        g = self.gains
        J, B = arm["J"], arm["inertia"]
        J_bar = dynamically_consistent_inverse(J, B, Lambda)
        N = null_space_projector(J, J_bar)
        tau0 = g.posture_stiffness * (arm["q0"] - arm["q"]) - g.posture_damping * arm["qd"]
        return arm["gravity"] + matvec(transpose(J), h_world) + matvec(transpose(N), tau0)

    @staticmethod
    def hole_frame(obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """The nominal hole's position (..., 3) (m) and rotation hole → world (..., 3, 3)."""
        return obs["hole_pos"], _matrix(obs["hole_quat"])

    def measured_wrench_at_tip(self, obs: Observation, arm: Frames) -> np.ndarray:
        """γ̂ (N, 6), world frame, moments about the tip: the peg's push on the environment.

        :func:`cir_gym.ft_sensor.contact_wrench` of the readings w (the static peg's reading
        removed, rotated to the world by the flange's R; moments about the sensor), the
        moment then moved from the sensor to the tip: μ_tip = μ + (p_flange − p_tip) × f."""
        h = contact_wrench(obs["wrench"], arm["R_tip"], tool_mass=self.tool_mass,
                           tool_com=self.tool_com)
        f = h[..., :3]
        return np.concatenate((f, h[..., 3:] + _cross(arm["p_flange"] - arm["p_tip"], f)),
                              axis=-1)


class HybridForcePosition(_TipController):
    """Hybrid force/position control with the selection matrix Σ (see the module docstring).

    State: :data:`HYBRID_STATE` (time, axial reference, the force loop's integral) and the
    posture target q₀.
    """

    name: ClassVar[str] = "hybrid_force_position"
    Gains: ClassVar[type] = HybridForcePositionGains
    law_state: ClassVar[np.dtype] = HYBRID_STATE

    @functools.cached_property
    def contact_stiffness(self) -> np.ndarray:
        """k̂ (6,): the contact stiffness on the forces (N/m), k̂ r_peg² on the moments (N m/rad)."""
        k, r = self.gains.stiffness, float(self.context.extras.get("peg_radius", 0.005))
        return np.r_[np.full(3, k), np.full(3, k * r * r)]

    @functools.cached_property
    def integral_bound(self) -> np.ndarray:
        """The bounds of the force loop's integral u_I (6,) (N, N m)."""
        g = self.gains
        return np.r_[np.full(3, g.integral_limit), np.full(3, g.integral_limit_moment)]

    @functools.cached_property
    def accommodation(self) -> np.ndarray:
        """D_F (6,): the accommodation damping (N s/m, N m s/rad)."""
        return np.r_[np.full(3, self.gains.d_f), np.full(3, self.gains.d_f_rot)]

    def frames(self, obs: Observation, q0: np.ndarray) -> Frames:
        """:meth:`tip_terms` plus, in the nominal hole frame (rotation R_h): the tip's position
        ``x`` (N, 3) (m), its orientation error ``phi`` = log(R̄ R_relᵀ) (N, 3) (rad) from the
        aligned R̄, its twist ``v`` (N, 6), the measured wrench ``gamma`` γ̂ (N, 6) and the
        tip's task inertia ``Lambda`` Λ_h = R6ᵀ Λ R6 (N, 6, 6); ``R6`` = diag(R_h, R_h) and
        the world-frame ``Lambda_world`` Λ."""
        arm = self.tip_terms(obs, q0)
        p_h, R_h = self.hole_frame(obs)
        R6 = _block_diag2(R_h)
        R6_T = transpose(R6)
        Lambda_world = task_inertia(arm["J"], arm["inertia"])
        R_rel = transpose(R_h) @ arm["R_tip"]  # the tip's orientation in the hole frame
        return {
            **arm,
            "R6": R6,
            "x": matvec(transpose(R_h), arm["p_tip"] - p_h),
            "phi": _rotvec(ALIGNED @ transpose(R_rel)),
            "v": matvec(R6_T, matvec(arm["J"], arm["qd"])),
            "gamma": matvec(R6_T, self.measured_wrench_at_tip(obs, arm)),
            "Lambda": R6_T @ Lambda_world @ R6,
            "Lambda_world": Lambda_world,
        }

    def force_gains(self, Lambda: np.ndarray) -> np.ndarray:
        """K_I (..., 6) (1/s): crossover_ratio · sqrt(k̂_i / Λ_ii) per direction of the hole
        frame, k̂ = stiffness on the forces and stiffness · r_peg² on the moments, for task
        inertias Λ (..., 6, 6)."""
        Lambda_ii = np.diagonal(Lambda, axis1=-2, axis2=-1)
        return self.gains.crossover_ratio * np.sqrt(self.contact_stiffness / Lambda_ii)

    def force_loop(
        self, f: Frames, fields: np.ndarray, sigma: np.ndarray, gamma_ref: np.ndarray
    ) -> np.ndarray:
        """The integral force law on the force-controlled directions,
        u_I ← Σ (u_I + Δt K_I Σ (γ̄ − γ̂)), bounded by the integral limits (zero off Σ);
        returns γ̄ + u_I (..., 6) (N, N m). ``fields``: the state's named fields (u_I is
        updated in them); ``sigma`` Σ (..., 6, 6); ``f``: ``Lambda`` and ``gamma``."""
        limit = self.integral_bound
        u = fields["force_integral"]
        error = gamma_ref - f["gamma"]
        u += self.dt * matvec(sigma, self.force_gains(f["Lambda"]) * error)
        u[...] = np.clip(matvec(sigma, u), -limit, limit)  # no integral off Σ
        return gamma_ref + u

    def restart_force_loop(self, fields: np.ndarray, rows: np.ndarray) -> None:
        """u_I ← 0 on ``rows`` (a mask) of the state's named ``fields``: a new phase's loop."""
        fields["force_integral"][rows] = 0.0

    def hybrid_wrench(
        self,
        f: Frames,
        x_ref: np.ndarray,
        sigma: np.ndarray,
        h_force: np.ndarray,
        omega_n: float | np.ndarray | None = None,
        decouple: bool | np.ndarray = True,
    ) -> np.ndarray:
        """h_c (N, 6) in the hole frame: Σ (h_force − D_F ẋ + K_tilt φ) + (I − Σ) motion law (at
        ``omega_n``); ``h_force`` the force loop's command (:meth:`force_loop`), ``x_ref``
        (N, 3) the motion reference (m), ``sigma`` Σ (N, 6, 6) or (6, 6).

        ``decouple`` (per row): the motion wrench is Λ (I − Σ) a, whose components on the
        force-controlled directions cancel the inertial coupling in free space; ``False`` keeps
        only its motion components, (I − Σ) Λ (I − Σ) a: in the bore those components would
        push the peg sideways and tilt it against the walls (the inconsistency the selection
        matrix filters, in the notes' words) and jam it.
        """
        g = self.gains
        w = np.asarray(g.omega_n if omega_n is None else omega_n)[..., None]
        v, phi, L = f["v"], f["phi"], f["Lambda"]
        # Σ: the force command with the accommodation damping D_F and a weak spring toward
        # the nominal axis (compliance)
        h_f = h_force - self.accommodation * v
        h_f[..., 3:] += g.k_tilt * phi
        # I − Σ: the motion law a = K_P x̃ − K_D ẋ, K_P = ω_n², K_D = 2 ζ ω_n
        e = np.concatenate((x_ref - f["x"], phi), axis=-1)
        a = w**2 * e - 2 * g.zeta * w * v
        a_max = g.push_force / L[..., 2, 2]  # the axial command presses with at most push_force
        a[..., 2] = np.clip(a[..., 2], -a_max, a_max)
        motion = np.eye(6) - sigma
        h_motion = matvec(L, matvec(motion, a))
        h_motion = np.where(np.asarray(decouple)[..., None], h_motion, matvec(motion, h_motion))
        return matvec(sigma, h_f) + h_motion

    def torque(self, f: Frames, h_hole: np.ndarray) -> np.ndarray:
        """Joint torques (N, n) of the tip wrench h_hole (N, 6) in the hole frame."""
        return self.task_wrench_torque(f, matvec(f["R6"], h_hole), f["Lambda_world"])

    def advance_reference(self, fields: np.ndarray, z: np.ndarray) -> None:
        """z̄ ← z̄ − v Δt (v̄, or the guard speed near the top face), at most 5 mm ahead of the
        tip's height z (N,)."""
        g = self.gains
        v = np.where(np.abs(z) < g.guard_height, g.guard_speed, g.speed)
        fields["z_ref"] = np.maximum(fields["z_ref"] - v * self.dt, z - 0.005)

    def insert(self, f: Frames, fields: np.ndarray) -> np.ndarray:
        """The approach and the insertion: Σ_face above the bore, Σ in it, γ̄ = 0."""
        x = f["x"]
        self.advance_reference(fields, x[:, 2])
        x_ref = np.stack((x[:, 0], x[:, 1], fields["z_ref"]), axis=-1)
        in_bore = x[:, 2] < -self.gains.guard_height
        sigma = np.where(in_bore[:, None, None], selection_matrix(), selection_matrix(face=True))
        h_force = self.force_loop(f, fields, sigma, np.zeros(6))
        return self.torque(f, self.hybrid_wrench(f, x_ref, sigma, h_force, decouple=~in_bore))

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        fields = _fields(state, self.layout)
        fields["t"] += self.dt
        return self.insert(self.frames(obs, fields["q0"]), fields)


@dataclass(frozen=True)
class SpiralSearchGains:
    """The spiral search's gains (a mixin of :class:`HybridSpiralGains` and
    :class:`PositionSpiralGains`, checked by their :class:`AccommodationGains` base).

    Attributes:
        drop: drop below the contact height (m) that means the hole is found.
        search_force: axial push during the search (N).
        pitch: spiral pitch (m, distance between turns).
        search_speed: speed along the spiral (m/s).
        omega_search: natural frequency of the motion control in the plane during the search
            (rad/s): stiff enough that the tip slides across the face against friction.
        speed: insertion speed v̄ along the axis once the hole is found (m/s): 7 mm/s, slower
            than hybrid_force_position's 10 mm/s (the walls turn the arm to the hole's tilt
            while it goes in, and the force that rotates the arm's inertia grows with speed).
    """

    speed: float = 0.007
    drop: float = 0.0005
    search_force: float = 4.0
    pitch: float = 0.0005
    search_speed: float = 0.005
    omega_search: float = 80.0


@dataclass(frozen=True)
class HybridSpiralGains(SpiralSearchGains, HybridForcePositionGains):
    """Gains of :class:`HybridSpiral`: those of hybrid_force_position and the spiral search's
    (:class:`SpiralSearchGains`: its ``speed`` 7 mm/s; ``search_force`` is the force reference
    γ̄_z of Σ_search)."""


class HybridSpiral(HybridForcePosition):
    """hybrid_force_position plus a spiral search on the block (see the module docstring).

    State: :data:`SPIRAL_STATE` and the posture target q₀.
    """

    name: ClassVar[str] = "hybrid_spiral"
    Gains: ClassVar[type] = HybridSpiralGains
    law_state: ClassVar[np.dtype] = SPIRAL_STATE

    def update_mode(self, f: Frames, fields: np.ndarray) -> None:
        """The search's phases, row by row: APPROACH → SEARCH when the peg pushes on the block
        (the axial force above ``contact_force``) no deeper than ``drop``; SEARCH → FOUND when
        the tip drops ``drop`` below the contact height (it is in the hole). Each new phase
        starts its force loop from zero."""
        g = self.gains
        x, mode = f["x"], fields["mode"]
        pushing = -f["gamma"][:, 2] > g.contact_force  # the peg pushes the block along −z
        touch = (mode == APPROACH) & pushing & (x[:, 2] > -g.drop)
        mode[touch] = SEARCH  # on the block beside the hole
        fields["theta"][touch] = 0.0
        fields["centre"][touch] = x[touch, :2]
        fields["z_contact"][touch] = x[touch, 2]
        self.restart_force_loop(fields, touch)
        dropped = (mode == SEARCH) & (x[:, 2] < fields["z_contact"] - g.drop)
        mode[dropped] = FOUND  # the tip is in the hole
        fields["z_ref"][dropped] = x[dropped, 2]
        self.restart_force_loop(fields, dropped)

    def search(self, f: Frames, fields: np.ndarray) -> np.ndarray:
        """Joint torques (N, n) of the spiral search (:meth:`search_wrench`)."""
        return self.torque(f, self.search_wrench(f, fields))

    def search_wrench(self, f: Frames, fields: np.ndarray) -> np.ndarray:
        """The spiral search's h_c (N, 6), hole frame: Σ_search, the tip along r = p θ / 2π
        around the contact point at ``omega_search``, pressing with γ̄_z = −``search_force``
        (the force loop's γ̄_z + u_I,z with the damping −D_F ż). Advances θ in ``fields``."""
        g = self.gains
        target = spiral_point(fields, g.pitch, g.search_speed, self.dt)
        x_ref = np.concatenate((target, f["x"][:, 2:]), axis=-1)
        sigma = selection_matrix(search=True)
        push = np.array([0.0, 0.0, -g.search_force, 0.0, 0.0, 0.0])
        h_force = self.force_loop(f, fields, sigma, push)
        return self.hybrid_wrench(f, x_ref, sigma, h_force, g.omega_search)

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        fields = _fields(state, self.layout)
        fields["t"] += self.dt
        f = self.frames(obs, fields["q0"])
        self.update_mode(f, fields)
        searching = fields["mode"] == SEARCH
        tau = np.empty((len(searching), self.robot.n))
        for rows, law in ((~searching, self.insert), (searching, self.search)):
            if rows.any():  # each phase's law on its rows, with their state rows
                state_rows = state[rows]
                tau[rows] = law(_take(f, rows), _fields(state_rows, self.layout))
                state[rows] = state_rows
        return tau


@dataclass(frozen=True)
class PositionSpiralGains(SpiralSearchGains, AccommodationGains):
    """Gains of :class:`PositionSpiral`: hybrid_spiral's without the force loop's
    (:class:`AccommodationGains` and :class:`SpiralSearchGains`; no ``stiffness``,
    ``crossover_ratio`` or integral limits)."""


class PositionSpiral(HybridSpiral):
    """Position control with the spiral search: hybrid_spiral without its force loop.

    The law: hybrid_spiral's approach, search and insertion (Σ_face above the bore, Σ in it,
    Σ_search on the face; the same motion law, accommodation −D_F ẋ, tilt spring, guarded move
    and spiral), with no force loop: γ̄ = 0 on Σ by accommodation alone (K_I = 0), and on the
    face the axial command is a feed-forward push with damping, h_z = −``search_force``
    − D_F ż, in place of the whole axial row of the hybrid wrench (hybrid_spiral at
    ``crossover_ratio=0`` adds the inertial coupling Λ_z,: (I − Σ) a of the in-plane motion to
    it: up to 0.003 of the action scale on 917 of 3654 steps of seed 3000).

    What it knows: the nominal hole pose, the nominal arm and peg, and the F/T reading, which
    it uses only to detect the contact (the axial push above ``contact_force``); the drop into
    the hole it detects from the tip's height. After the first contact the reading no longer
    enters any command: it is position control with a spiral search, not force control.

    What it measures against hybrid_spiral: with the force loop the peg hops harder on the face
    and hits the 100-N single-contact limit. On PegInHole-v2's leaderboard seeds 1000-1029 (30
    episodes, default gains; results/leaderboard.md) this law inserts 26/30 (87 % [70, 95]) on
    the sharp edge and 25/30 (83 % [66, 93]) with the 3 mm chamfer, 4 and 5 stopped at the
    limit; hybrid_spiral 9/30 and 10/30, 21 and 20 stopped. On seeds 3000-3029 (sharp edge)
    results/peg_in_hole/laws.md gives hybrid_spiral 5/30 with the loop (25 stopped) and 25/30
    with ``crossover_ratio=0`` (4 stopped); this law's own 27/30 there (3 stopped) is in
    results/peg_in_hole/README.md.

    State: :data:`POSITION_SPIRAL_STATE` and the posture target q₀.
    """

    name: ClassVar[str] = "position_spiral"
    Gains: ClassVar[type] = PositionSpiralGains
    law_state: ClassVar[np.dtype] = POSITION_SPIRAL_STATE

    def force_loop(
        self, f: Frames, fields: np.ndarray, sigma: np.ndarray, gamma_ref: np.ndarray
    ) -> np.ndarray:
        """No force loop: γ̄ as given (the force-controlled directions follow it by
        accommodation alone); the measured wrench is not read."""
        return gamma_ref

    def restart_force_loop(self, fields: np.ndarray, rows: np.ndarray) -> None:
        """Nothing to restart: the law has no force integral."""

    def force_gains(self, Lambda: np.ndarray) -> np.ndarray:
        """K_I = 0 (..., 6): no force feedback, whatever the task inertias Λ (..., 6, 6)."""
        return np.zeros(np.shape(Lambda)[:-1])

    def search_wrench(self, f: Frames, fields: np.ndarray) -> np.ndarray:
        """hybrid_spiral's search wrench (N, 6) with its axial row replaced by the feed-forward
        push with damping, h_z = −``search_force`` − D_F ż (no force feedback against the stiff
        face: 11 kg of task inertia on a 1-ms contact with a delayed sensor bounces)."""
        h = super().search_wrench(f, fields)
        h[:, 2] = -self.gains.search_force - self.gains.d_f * f["v"][:, 2]
        return h


@dataclass(frozen=True)
class PositionOnlyGains:
    """Gains of :class:`PositionOnly` (hole frame, at the tip).

    Attributes:
        k_p: translational stiffness (N/m); k_p_rot rotational (N m/rad).
        k_d: damping (N s/m); k_d_rot (N m s/rad).
        speed: speed of the reference down the nominal axis (m/s).
        posture_stiffness, posture_damping: null-space posture PD (N m/rad, N m s/rad).
    """

    k_p: float = 5000.0
    k_d: float = 200.0
    k_p_rot: float = 200.0
    k_d_rot: float = 5.0
    speed: float = 0.02
    posture_stiffness: float = 20.0
    posture_damping: float = 5.0

    def __post_init__(self) -> None:
        _check_positive("position_only", **self.__dict__)


class PositionOnly(_TipController):
    """Stiff Cartesian position control down the nominal hole axis, no force feedback, no search.

    It fails by construction whenever the true hole is off the nominal axis by more than the
    radial clearance (PegInHole's default ±2 mm against 0.25 mm): the reference goes down to
    the goal depth on the nominal axis, so the tip lands on the face and the spring presses
    K_P × (goal depth) = 5000 N/m × 22.5 mm = 112 N into it until the time limit or the 100-N
    single-contact limit (0/30 inserted, 63 % stopped at the limit on held-out seeds,
    results/peg_in_hole/laws.md). It is the foil that shows why force control exists, not a
    competitor.

    State: :data:`POSITION_STATE` and the posture target q₀.
    """

    name: ClassVar[str] = "position_only"
    Gains: ClassVar[type] = PositionOnlyGains
    law_state: ClassVar[np.dtype] = POSITION_STATE

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        g = self.gains
        fields = _fields(state, self.layout)
        arm = self.tip_terms(obs, fields["q0"])
        p_h, R_h = self.hole_frame(obs)
        goal = -float(self.context.extras.get("goal_depth", 0.0225))
        fields["z_ref"] = np.maximum(fields["z_ref"] - g.speed * self.dt, goal)
        x_ref = p_h + R_h[..., :, 2] * fields["z_ref"][:, None]  # on the nominal axis
        R_ref = R_h @ ALIGNED
        phi = _rotvec(R_ref @ transpose(arm["R_tip"]))  # log(R̄ Rᵀ)
        twist = matvec(arm["J"], arm["qd"])
        h = np.concatenate(
            (
                g.k_p * (x_ref - arm["p_tip"]) - g.k_d * twist[:, :3],
                g.k_p_rot * phi - g.k_d_rot * twist[:, 3:],
            ),
            axis=-1,
        )
        return self.task_wrench_torque(arm, h)


@dataclass(frozen=True)
class AdmittanceGainsPeg(AdmittanceGains):
    """Gains of :class:`PegAdmittance`: interaction.py's admittance gains, plus

    Attributes:
        insertion_force: the reference force f̄ along the nominal bore axis (N), pushing in.
        stiffness: the block as the law designs for it (N/m): steel on steel behind MuJoCo's
            1 ms contact, far stiffer than the arm's servo (Λ ω_i² ≈ 2.5·10⁵ N/m), so the
            effective stiffness k̂_e is the servo's.
    """

    insertion_force: float = 10.0
    stiffness: float | None = 1e7

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_positive("admittance", insertion_force=self.insertion_force)


class PegAdmittance(Admittance):
    """AdmittanceContact's ``admittance`` law (:class:`baselines.interaction.Admittance`,
    imported, not copied) applied to PegInHole through an adapter.

    The adapter translates the task: the "surface" is the block's *nominal* top face (point =
    nominal hole position, normal n̂ = nominal bore axis, out of the hole), the path reference is
    the nominal hole axis (fixed: zero velocity), the reference force is ``insertion_force``
    along −n̂ and the task's tool orientation is the peg aligned with the nominal bore. The law
    itself is unchanged: a guarded approach along −n̂, then M_d Δ̈ + D_d Δ̇ = f̂ − f̄ on the depth
    (integral force control along the axis) through the stiff inner motion loop, which holds
    the tip on the nominal axis laterally and the peg square to the nominal face. So it
    regulates the pushing force along the axis and nothing else: a hole off by more than the
    radial clearance is never found (the peg presses f̄ on the face until the time limit),
    which is what the selection matrix of hybrid control adds (lateral force control).

    The observation is translated per step (:meth:`translate`, on all rows at once): tool
    pose and twist of the peg tip in the world from the nominal hole frame; the nominal arm's
    ``tcp`` site is moved to the peg tip (``tip_offset`` beyond the flange) so the law's
    Jacobians are the tip's. Torque interface only (PegInHole's observation has no
    motion-controller setpoint).
    """

    name = "admittance"
    tasks: ClassVar[tuple[str, ...]] = ("PegInHole",)
    Gains = AdmittanceGainsPeg

    def __init__(
        self,
        context: TaskContext,
        gains: Any = None,
        *,
        robot: Robot | None = None,
        **overrides: Any,
    ) -> None:
        _require_torque(self.name, context)
        ex = context.extras
        if not {"tip_offset", "tool_com", "hole_position"} <= set(ex):
            raise InvalidGain(f"{self.name} (PegInHole adapter) needs a PegInHole context")
        hole_pos = np.array(ex["hole_position"], dtype=float)
        R_h = np.eye(3)  # the nominal hole frame is aligned with the world (env: hole_quat)
        extras = {
            **ex,
            "tool_com": np.array(ex["tool_com"], dtype=float),
            "surface_point": hole_pos,
            "surface_normal": R_h[:, 2].copy(),
            "tool_quat": _quaternion(R_h @ ALIGNED),
            "stiffness_range": (1e3, 1e7),
        }
        translated = dataclasses.replace(context, site="tcp", extras=extras)
        if robot is None:
            robot = translated.nominal_robot()
            tool_mass = float(ex.get("tool_mass", 0.0))
            if tool_mass > 0:
                apply_model_error(robot.model, ModelError(payload_mass=tool_mass))
            m = robot.model
            tcp, flange = m.site("tcp").id, m.site("flange").id
            if m.site_bodyid[tcp] != m.site_bodyid[flange]:
                raise ValueError("the nominal arm's tcp and flange sites are on different bodies")
            R_f = _matrix(m.site_quat[flange])
            m.site_pos[tcp] = m.site_pos[flange] + R_f @ np.array([0.0, 0.0, ex["tip_offset"]])
            m.site_quat[tcp] = m.site_quat[flange]
            robot.invalidate()
        super().__init__(translated, gains, robot=robot, **overrides)
        self.hole_pos, self.R_h = hole_pos, R_h

    def translate(self, obs: Observation) -> Observation:
        """AdmittanceContact's observation keys from PegInHole's (world frame, SI), for one
        observation or rows."""
        p_h, R_h = obs["hole_pos"], _matrix(obs["hole_quat"])
        R_tip = R_h @ _matrix(obs["peg_quat"]) @ ALIGNED
        twist = obs["peg_twist"]
        return {
            "q": obs["q"],
            "qd": obs["qd"],
            "wrench": obs["wrench"],
            "tool_pos": p_h + matvec(R_h, obs["peg_pos"]),
            "tool_quat": _quaternion(R_tip),
            "tool_vel": matvec(R_h, twist[..., :3]),
            "tool_angvel": matvec(R_h, twist[..., 3:]),
            "tool_pos_ref": np.array(p_h, dtype=float),
            "tool_vel_ref": np.zeros(np.shape(p_h)),
            "f_ref": np.full((*np.shape(p_h)[:-1], 1), self.gains.insertion_force),
        }

    def initial_state(self, obs: Observation) -> np.ndarray:
        return super().initial_state(self.translate(obs))

    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        return super().control_rows(self.translate(obs), state)


#: Controllers whose law is registered for another task and applies to PegInHole through an
#: adapter here: (name, task) → class. ``baselines.make`` must pick these before
#: ``CONTROLLERS[name]`` (the name ``admittance`` is AdmittanceContact's).
TASK_ADAPTERS: dict[tuple[str, str], type[Controller]] = {
    ("admittance", "PegInHole"): PegAdmittance
}

HYBRID_CONTROLLERS: tuple[type[Controller], ...] = (
    HybridForcePosition, HybridSpiral, PositionSpiral, PositionOnly
)
