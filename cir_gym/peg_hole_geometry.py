"""The peg-in-hole scene: the iiwa14 holding a cylindrical peg above a block with a round hole.

Built programmatically with ``mujoco.MjSpec`` so that the clearance is exact (no mesh, no
rounding in an XML file). MuJoCo collides a mesh as its convex hull, so a hole modelled as one
mesh would be a solid plug; the hole here is a ring of ``N_SIDES`` overlapping boxes whose
inner faces are the sides of a regular polygon *circumscribing* the circle of the hole radius.
The peg (a true cylinder) touches a face at exactly the nominal radial gap; the polygon's
corners only add room (at most R_h (1/cos(π/N) − 1) = 5 µm for the 5 mm hole at N = 64).
Each box extends beyond its polygon side: the extension lies inside its neighbours' material
(the hole is convex), so the boxes overlap and nothing leaks between them.

The optional chamfer is a second ring of boxes, each turned 45° about its tangent so that its
inner face is the cone r = R_h + c + z (−c ≤ z ≤ 0, z from the block top); the box's highest
point is the top edge of the chamfer, so nothing stands above the block's top face. Above
z = −c the straight wall steps back to R_h + c.

Collision bits: the peg has contype 2, the arm's links and the peg's holder contype 1 (the robot
file's default, conaffinity 0: the links never collide with each other), the block conaffinity
2 | 1, so the peg, its holder and every link collide with the block and nothing else collides
(the floor has contype = conaffinity = 0).

Physics settings (the numbers are the module constants below; why each one):

* ``TIMESTEP`` = 0.5 ms. A contact stiff enough to keep the resting penetration under a fifth of
  the smallest clearance (0.1 mm diametral → 20 µm) needs a short solref time constant, and
  MuJoCo clamps the time constant to ≥ 2 timesteps; 1 ms would allow only 2 ms.
* ``SOLREF`` = (1 ms, 1): time constant 2 × timestep (the stiffest MuJoCo honours), critical
  damping. Penetration r ≈ a (1 − d) τ² ζ² with the pressing acceleration a, so halving τ cuts
  it by 4 against the default (20 ms: 0.2–0.4 mm resting penetration, more than the clearance).
* ``SOLIMP`` = (0.99, 0.999, 0.1 mm, 0.5, 2): impedance d close to 1 (0.99 at contact onset,
  0.999 beyond 0.1 mm), i.e. a hard contact; the transition width is about the smallest
  radial gap so the walls stiffen before a peg could pass a quarter of the gap.
* ``CONE`` elliptic and ``IMPRATIO`` = 10: slipping contacts with friction (the peg sliding
  along the wall) are resolved accurately only with elliptic cones; impratio > 1 makes the
  friction dimensions stiffer than the normal one, so that sticking is sticking.
* ``SOLVER`` Newton, ``ITERATIONS`` = 50, ``TOLERANCE`` = 1e-10: the exact second-order solver
  (a few iterations usually) for stiff contacts.
* ``MARGIN`` = 0: a margin at or above the radial gap makes the walls push on a peg that does
  not touch them (artificial jamming). With margin 0 a contact exists only at penetration.
* ``NATIVE_CCD`` = False: cylinder–box pairs go through MuJoCo's general convex collision;
  its native (default) GJK/EPA gave, for a peg's flat end sliding across the top edge of a
  wall box, a second contact with the normal reversed (+z, the box "above" the peg) at the
  same point, ~100 N pairs that cancel in the net force but not in the friction they bring
  (stick-slip, 100 N spikes); libccd's MPR gives consistent normals there.
* ``FRICTION`` = 0.3 (steel on steel, lubricated to dry ≈ 0.15–0.6): the friction coefficient
  in the notes' jamming and wedging conditions (Whitney 1982).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cir_gym.robot import RobotFileError, robot_path

__all__ = [
    "HoleGeometry",
    "build_peg_in_hole",
]

# --------------------------------------------------------------------- geometry (SI units)
PEG_RADIUS = 0.005  # m: a 10 mm peg (IndustReal and Factory use 8–16 mm)
PEG_LENGTH = 0.06  # m
PEG_MASS = 0.1  # kg (steel, 10 mm × 60 mm ≈ 0.037 kg plus its holder)
PEG_OFFSET = 0.02  # m: peg base beyond the flange (a holder between flange and peg)
#: the peg's centre of mass in the sensor (flange) frame (m)
PEG_COM = (0.0, 0.0, PEG_OFFSET + PEG_LENGTH / 2)
HOLE_DEPTH = 0.025  # m
WALL_THICKNESS = 0.02  # m: radial thickness of the ring boxes
N_SIDES = 64  # polygon sides of the hole
BLOCK_HALF = 0.04  # m: half side of the (visual) block
HOLE_POSITION = (0.6, 0.0, 0.15)  # m: nominal centre of the hole's top opening (world)
CLEARANCE_RANGE = (1e-4, 2e-3)  # m, diametral
CHAMFER_RANGE = (0.0, 3e-3)  # m

# --------------------------------------------------------------------- physics
TIMESTEP = 5e-4  # s
SOLREF = (1e-3, 1.0)  # (time constant s, damping ratio)
SOLIMP = (0.99, 0.999, 1e-4, 0.5, 2.0)
CONE = mujoco.mjtCone.mjCONE_ELLIPTIC
IMPRATIO = 10.0
SOLVER = mujoco.mjtSolver.mjSOL_NEWTON
ITERATIONS = 50
TOLERANCE = 1e-10
MARGIN = 0.0
NATIVE_CCD = False
FRICTION = 0.3

# --------------------------------------------------------------------- contact sensors
#: names of the scene's contact sensors (see _add_contact_sensors)
LARGEST_CONTACT = "largest_contact"
NET_CONTACT = "net_contact"
PEG_CONTACTS = "peg_contacts"
#: the sensors whose values of every physics step a control period needs: the largest and
#: the net contact force, the wrist's force and torque (the robot file's F/T sensor)
HISTORY_SENSORS = (LARGEST_CONTACT, NET_CONTACT, "ft_force", "ft_torque")
#: slots of PEG_CONTACTS: the peg's strongest contacts reported (the rest are dropped)
PEG_CONTACT_SLOTS = 16
ROBOT_ROOT = "base"  # the robot file's root body
# MuJoCo's contact-sensor parameters (sensor_intprm: data bits, reduction, slots); the
# reductions as the XML's reduce="maxforce" / "netforce" compile (MuJoCo has no enum for them)
CONTACT_FOUND, CONTACT_FORCE, CONTACT_NORMAL = (
    1 << int(f)
    for f in (
        mujoco.mjtConDataField.mjCONDATA_FOUND,
        mujoco.mjtConDataField.mjCONDATA_FORCE,
        mujoco.mjtConDataField.mjCONDATA_NORMAL,
    )
)
REDUCE_MAXFORCE, REDUCE_NETFORCE = 2, 3

PEG_CONTYPE = 2
ARM_CONTYPE = 1  # the robot file's default for its links
BLOCK_CONAFFINITY = PEG_CONTYPE | ARM_CONTYPE


@dataclass(frozen=True)
class HoleGeometry:
    """Dimensions of one built scene (m).

    Attributes:
        clearance: diametral clearance, hole diameter − peg diameter.
        chamfer: width (= depth, 45°) of the hole's chamfer; 0 = sharp edge.
        peg_radius, hole_radius, depth: the cylinder and the bore.
        tip_offset: peg tip beyond the flange along the flange z axis.
    """

    clearance: float
    chamfer: float
    peg_radius: float = PEG_RADIUS
    depth: float = HOLE_DEPTH
    tip_offset: float = PEG_OFFSET + PEG_LENGTH

    @property
    def hole_radius(self) -> float:
        return self.peg_radius + self.clearance / 2


def _quat_z(angle: float) -> np.ndarray:
    return np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, a, b)
    return out


def _ring(
    body: mujoco.MjsBody, name: str, r_in: float, z_low: float, z_high: float, rgba: list[float]
) -> None:
    """Boxes whose inner faces are the sides of the N-gon of inradius ``r_in``, z in [low, high]."""
    half_t = WALL_THICKNESS / 2
    half_w = (r_in + WALL_THICKNESS) * np.tan(np.pi / N_SIDES) * 1.05  # overlap neighbours
    half_h = (z_high - z_low) / 2
    for i in range(N_SIDES):
        phi = 2 * np.pi * i / N_SIDES
        c = r_in + half_t
        body.add_geom(
            name=f"{name}{i}",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[half_t, half_w, half_h],
            pos=[c * np.cos(phi), c * np.sin(phi), (z_low + z_high) / 2],
            quat=_quat_z(phi),
            rgba=rgba,
        )


def _chamfer_ring(body: mujoco.MjsBody, r_in: float, chamfer: float, rgba: list[float]) -> None:
    """Boxes turned 45° whose inner faces make the cone r = r_in + chamfer + z, −chamfer ≤ z ≤ 0."""
    t = chamfer  # thickness behind the face: fills the triangle up to the stepped-back wall
    half_face = chamfer / np.sqrt(2)  # half the slant length
    half_w = (r_in + 2 * chamfer) * np.tan(np.pi / N_SIDES) * 1.05
    # in the (r, z) plane: face from (r_in, −c) to (r_in + c, 0); material along (1, −1)/√2
    mid = np.array([r_in + chamfer / 2, -chamfer / 2])
    centre = mid + (t / 2) * np.array([1.0, -1.0]) / np.sqrt(2)
    tilt = np.array([np.cos(np.pi / 8), 0.0, np.sin(np.pi / 8), 0.0])  # +45° about y
    for i in range(N_SIDES):
        phi = 2 * np.pi * i / N_SIDES
        body.add_geom(
            name=f"chamfer{i}",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[t / 2, half_w, half_face],
            pos=[centre[0] * np.cos(phi), centre[0] * np.sin(phi), centre[1]],
            quat=_quat_mul(_quat_z(phi), tilt),
            rgba=rgba,
        )


def _contact_sensor(
    spec: mujoco.MjSpec, name: str, robot: tuple[mujoco.mjtObj, str], data: int, reduce: int,
    num: int,
) -> None:
    """A MuJoCo contact sensor on the contacts between ``robot`` (a geom or a body's subtree)
    and the block; its normals point from the robot into the block."""
    spec.add_sensor(
        name=name,
        type=mujoco.mjtSensor.mjSENS_CONTACT,
        objtype=robot[0],
        objname=robot[1],
        reftype=mujoco.mjtObj.mjOBJ_BODY,
        refname="block",
        intprm=[data, reduce, num],
    )


def _add_contact_sensors(spec: mujoco.MjSpec) -> None:
    """The robot–block contacts as MuJoCo contact sensors (evaluated in C with the step's
    constraint forces, so a physics step's contacts are read from ``sensordata``):
    :data:`LARGEST_CONTACT` (the contact of largest force, its force in the contact frame),
    :data:`NET_CONTACT` (the net force, world frame) and :data:`PEG_CONTACTS` (the peg's
    :data:`PEG_CONTACT_SLOTS` strongest contacts: count, force in the contact frame, normal)."""
    robot = (mujoco.mjtObj.mjOBJ_XBODY, ROBOT_ROOT)  # the arm's subtree: links, holder, peg
    _contact_sensor(spec, LARGEST_CONTACT, robot, CONTACT_FORCE, REDUCE_MAXFORCE, 1)
    _contact_sensor(spec, NET_CONTACT, robot, CONTACT_FORCE, REDUCE_NETFORCE, 1)
    _contact_sensor(
        spec, PEG_CONTACTS, (mujoco.mjtObj.mjOBJ_GEOM, "peg_geom"),
        CONTACT_FOUND | CONTACT_FORCE | CONTACT_NORMAL, REDUCE_MAXFORCE, PEG_CONTACT_SLOTS,
    )


def build_peg_in_hole(
    clearance: float = 5e-4,
    chamfer: float = 0.0,
    hole_pos: np.ndarray | None = None,
    hole_quat: np.ndarray | None = None,
    history: int = 0,
) -> tuple[mujoco.MjModel, HoleGeometry]:
    """Compile the scene; the hole's top centre at ``hole_pos`` with orientation ``hole_quat``.

    Args:
        clearance: diametral clearance (m), in ``CLEARANCE_RANGE``.
        chamfer: chamfer width (m), in ``CHAMFER_RANGE``.
        hole_pos: (3,) true position of the hole frame (top centre, z along the bore axis
            pointing out of the hole); default ``HOLE_POSITION``.
        hole_quat: (4,) w-first orientation of the hole frame; default identity.
        history: physics steps kept in MuJoCo's history buffer of the sensors of
            :data:`HISTORY_SENSORS` (``nsample``; 0: none): with a control period's steps,
            ``mjData.history`` holds every physics step of the period after one
            ``mj_step(m, d, history)``.

    The block is a mocap-free static body, so its pose can be changed per episode without
    recompiling: write ``model.body_pos``/``body_quat`` of body ``block`` and call mj_forward.
    """
    geom = HoleGeometry(clearance=float(clearance), chamfer=float(chamfer))
    try:
        spec = mujoco.MjSpec.from_file(str(robot_path("iiwa14")))
    except ValueError as exc:
        raise RobotFileError(f"cannot load the iiwa14 robot file: {exc}") from exc
    opt = spec.option
    opt.timestep = TIMESTEP
    opt.cone = CONE
    opt.impratio = IMPRATIO
    opt.solver = SOLVER
    opt.iterations = ITERATIONS
    opt.tolerance = TOLERANCE
    if not NATIVE_CCD:
        opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)

    holder = spec.body("payload")
    spec.geom("payload_geom").contype = ARM_CONTYPE  # the peg's holder is a part: it collides
    # the robot file compiles with inertiafromgeom="false": the peg's inertial is explicit
    i_xx = PEG_MASS * (3 * geom.peg_radius**2 + PEG_LENGTH**2) / 12
    peg = holder.add_body(
        name="peg",
        pos=[0.0, 0.0, 0.0],
        mass=PEG_MASS,
        ipos=[0.0, 0.0, PEG_OFFSET + PEG_LENGTH / 2],
        inertia=[i_xx, i_xx, PEG_MASS * geom.peg_radius**2 / 2],
        explicitinertial=True,
    )
    peg.add_geom(
        name="peg_geom",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[geom.peg_radius, PEG_LENGTH / 2, 0.0],
        pos=[0.0, 0.0, PEG_OFFSET + PEG_LENGTH / 2],
        contype=PEG_CONTYPE,
        conaffinity=0,
        friction=[FRICTION, 0.005, 1e-4],
        solref=list(SOLREF),
        solimp=list(SOLIMP),
        margin=MARGIN,
        rgba=[0.75, 0.75, 0.8, 1.0],
    )
    peg.add_site(name="peg_tip", pos=[0.0, 0.0, geom.tip_offset])

    pos = np.array(HOLE_POSITION if hole_pos is None else hole_pos, dtype=float)
    quat = np.array([1.0, 0.0, 0.0, 0.0] if hole_quat is None else hole_quat, dtype=float)
    block = spec.worldbody.add_body(name="block", pos=pos.tolist(), quat=quat.tolist())
    block.add_site(name="hole", pos=[0.0, 0.0, 0.0])
    spec.worldbody.add_camera(  # a close-up of the hole for render(): 14 cm away, from above
        name="hole_cam",
        pos=(pos + np.array([0.06, -0.12, 0.06])).tolist(),
        mode=mujoco.mjtCamLight.mjCAMLIGHT_TARGETBODY,
        targetbody="block",
        fovy=45.0,
    )
    rgba = [0.45, 0.5, 0.6, 1.0]
    r_h = geom.hole_radius
    d = geom.depth
    c = geom.chamfer
    if c > 0:
        _ring(block, "wall", r_h, -d, -c, rgba)
        _ring(block, "top", r_h + c, -c, 0.0, rgba)
        _chamfer_ring(block, r_h, c, rgba)
    else:
        _ring(block, "wall", r_h, -d, 0.0, rgba)
    block.add_geom(  # the hole's bottom
        name="bottom",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[BLOCK_HALF, BLOCK_HALF, 0.005],
        pos=[0.0, 0.0, -d - 0.005],
        rgba=rgba,
    )
    for g in block.geoms:
        g.contype = 0
        g.conaffinity = BLOCK_CONAFFINITY
        g.friction = [FRICTION, 0.005, 1e-4]
        g.solref = list(SOLREF)
        g.solimp = list(SOLIMP)
        g.margin = MARGIN
    _add_contact_sensors(spec)
    for name in HISTORY_SENSORS if history else ():
        spec.sensor(name).nsample = int(history)  # history only: sensordata is unchanged
    try:
        model = spec.compile()
    except ValueError as exc:
        raise RobotFileError(f"cannot compile the peg-in-hole scene: {exc}") from exc
    return model, geom
