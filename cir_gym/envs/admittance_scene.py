"""AdmittanceContact's scene: the iiwa 14 with its tool over a sprung plate, and its drawing.

:func:`build_model` completes ``assets/scenes/admittance_contact.xml`` with MjSpec: the tool,
the tool-plate contact pair, the plate's spring and damper, and the sensors the env reads at
every physics step.

The tool-plate contact (an explicit contact pair, elliptic friction cone):

* stiff along the normal (``solref`` 2 ms, ``solimp`` 0.99): < 10 µm of penetration at 20 N,
  so the plate's spring, not the contact, is the surface's compliance;
* Coulomb friction μ = :data:`FRICTION` with its own reference time constant
  :data:`FRICTION_TIMECONST` (``solreffriction``). With the normal's 2 ms on the friction rows
  too (MuJoCo's default), the friction rows' reference acceleration −b v_t (b = 2/(d · 2 ms) ≈
  1000 s⁻¹) enters the cone's normal dynamics while the tool slides: at the wiping speed it is
  larger than the static term that keeps the tip pressed ((1 − d)/d · f / m ≈ 1 m/s² at
  20 N on the 0.2-kg plate), the contact separated for one physics step in ~13 and came back
  at 25 N (a 0 → 25 N sawtooth every ~3 ms: the tip left the plate on 5.8 % of the physics
  steps at 1e4 N/m, in 47 % of the 2-ms control periods; frictionless, never). The friction
  rows' 100-ms time constant makes that term 50 × smaller (b ≈ 20 s⁻¹): no physics step
  without contact while wiping (0.079 m/s) nor while sliding at the position interface's
  0.25 m/s on a flat plate (20-ms: 3.8 % of the steps there; 50-ms: 2 % at 1e5 N/m), and
  sliding friction is still Coulomb's (|f_t| / f_n = μ while the tool slides; tests).
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from cir_gym import rendering
from cir_gym.ft_sensor import PRESETS, SensorSpec, sensor_spec
from cir_gym.robot import (
    ASSETS,
    PAYLOAD_OFFSET,
    PAYLOAD_RADIUS,
    ModelError,
    Robot,
    apply_model_error,
)
from cir_gym.validation import InvalidArgument

__all__ = [
    "FORCE_REF_RANGE",
    "FRICTION",
    "FRICTION_TIMECONST",
    "JOINTS",
    "PLATE_TRAVEL",
    "RANDOM_RANGES",
    "RECORDED_SENSORS",
    "SCENE",
    "SITE",
    "START_Q",
    "STIFFNESS_RANGE",
    "SURFACE_NORMAL",
    "SURFACE_POINT",
    "TIMESTEP",
    "TOOL_COM",
    "TOOL_LENGTH",
    "TOOL_MASS",
    "TOOL_QUAT",
    "TOOL_RADIUS",
    "PeriodRecord",
    "build_model",
    "draw",
    "draw_surface",
    "positive_w",
    "quat_of",
    "surface_force",
    "tilt_rotation",
    "tool_robot",
    "wipe_reference",
    "wrist_sensor_spec",
]

SCENE = ASSETS / "scenes" / "admittance_contact.xml"
JOINTS = [f"joint{i}" for i in range(1, 8)]
SITE = "tcp"  # the tool tip: the lowest point of the hemisphere when the tool points down
TOOL_MASS = 0.3  # kg, centre of mass PAYLOAD_OFFSET beyond the flange (the payload model)
TOOL_COM = np.array([0.0, 0.0, PAYLOAD_OFFSET])  # m, in the sensor (flange) frame
TOOL_RADIUS = 0.012  # m, hemispherical tip
TOOL_LENGTH = 0.1  # m, flange to tip (the tcp site)
#: nominal surface: a point of its top face and its outward normal (world frame)
SURFACE_POINT = np.array([0.6, 0.0, 0.20])
SURFACE_NORMAL = np.array([0.0, 0.0, 1.0])
#: tool orientation of the task (tool axis along −z): rotation π about y, quaternion (w, x, y, z)
TOOL_QUAT = np.array([0.0, 0.0, 1.0, 0.0])
#: start: the tip 3 cm above the nominal surface point, tool pointing down (IK with posture
#: regularisation towards the iiwa's home; smallest singular value of J there 0.214)
START_Q = np.array([0.0, 0.69776, 0.0, -1.47298, 0.0, 0.97085, 0.0])
#: physics step (s). 0.25 ms, not the robot file's 1 ms: the tool-plate contact is stiff (solref
#: time constant 2 ms = 8 steps); at 1 ms (2 steps, MuJoCo's limit) the sliding contact
#: chattered in 1-ms bounces that rang the plate (scripts/research/eval_contact.py).
TIMESTEP = 0.00025
FRICTION = 0.1  # Coulomb friction coefficient of the tool-plate contact
FRICTION_TIMECONST = 0.1  # s, the friction rows' reference time constant (module docstring)
#: the plate's travel below its rest position (m): a stiff end stop (the slide joint's range)
PLATE_TRAVEL = 0.12
APPROACH_HEIGHT = 0.03  # m
WIPE_START = 2.0  # s
WIPE_AMPLITUDE = 0.05  # m
WIPE_FREQUENCY = 0.25  # Hz: peak speed 2π A f = 0.079 m/s
STIFFNESS_RANGE = (1.0e3, 1.0e5)  # N/m
FORCE_REF_RANGE = (5.0, 30.0)  # N
#: ranges drawn per episode when randomize=True (stiffness log-uniform, others uniform)
RANDOM_RANGES = {
    "stiffness": STIFFNESS_RANGE,  # N/m, log-uniform
    "damping": (5.0, 50.0),  # N s/m
    "sensor_bias_force": (-2.0, 2.0),  # N, each axis
    "sensor_bias_torque": (-0.1, 0.1),  # N m, each axis
}
#: the sensors read at every physics step: the wrist's wrench, the tool-plate contact force
#: and the plate's largest single contact (build_model)
RECORDED_SENSORS = ("ft_force", "ft_torque", "tool_contact", "peak_contact")
#: the tool-plate contact's normal parameters (the plate's class in the scene file)
_SOLREF = (0.002, 1.0)
_SOLIMP = (0.99, 0.99, 0.001, 0.5, 2.0)


def build_model(
    stiffness: float, damping: float, timestep: float = TIMESTEP, samples: int = 8
) -> mujoco.MjModel:
    """The scene with the plate's spring (N/m) and damper (N s/m), physics step ``timestep`` (s),
    and a history of the last ``samples`` physics steps (a control period's) for the sensors
    of :data:`RECORDED_SENSORS` (:class:`PeriodRecord` reads it).

    The tool is added to the robot's ``payload`` body (beyond ``ft_site``): the payload's
    inertial is the tool's (:data:`TOOL_MASS`, the centre of mass and inertia of
    :func:`cir_gym.robot.apply_model_error`'s payload model), so :func:`tool_robot` is an exact
    nominal model. Only the tip collides with the plate through the explicit pair (module
    docstring); the arm's links collide with the plate through the default contact rules.

    Sensors, after the wrist's ``ft_force`` and ``ft_torque`` (sensordata[:6]):

    * ``tool_contact`` (3,): the net force of the tool-plate contact, world frame (N), the
      force the plate exerts on the tip: n̂ · it is the tool's push along the inward normal;
    * ``peak_contact`` (3,): the contact on the plate (the tool or any link) with the largest
      force, its force in its contact frame (N; normal, two tangential): its magnitude is the
      largest single contact force (:func:`cir_gym.envs.contact_force.largest_contact_force`).
    """
    spec = mujoco.MjSpec.from_file(str(SCENE))
    spec.option.timestep = timestep
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    payload = spec.body("payload")
    payload.mass = TOOL_MASS
    payload.ipos = TOOL_COM
    payload.inertia = [0.4 * TOOL_MASS * PAYLOAD_RADIUS**2] * 3
    shaft = payload.add_geom()
    shaft.name = "tool_shaft"
    shaft.type = mujoco.mjtGeom.mjGEOM_CYLINDER
    shaft.fromto = [0.0, 0.0, 0.0, 0.0, 0.0, TOOL_LENGTH - TOOL_RADIUS]
    shaft.size = [0.8 * TOOL_RADIUS, 0.0, 0.0]
    shaft.contype = shaft.conaffinity = 0
    shaft.rgba = [0.3, 0.3, 0.35, 1.0]
    tip = payload.add_geom()
    tip.name = "tool_tip"
    tip.type = mujoco.mjtGeom.mjGEOM_SPHERE
    tip.pos = [0.0, 0.0, TOOL_LENGTH - TOOL_RADIUS]
    tip.size = [TOOL_RADIUS, 0.0, 0.0]
    tip.contype = tip.conaffinity = 0  # the pair below is its only contact
    tip.rgba = [0.9, 0.5, 0.1, 1.0]
    pair = spec.add_pair()
    pair.name = "tool_plate"
    pair.geomname1, pair.geomname2 = "surface_geom", "tool_tip"
    pair.condim = 3
    pair.friction = [FRICTION, FRICTION, 0.005, 0.0001, 0.0001]
    pair.solref = list(_SOLREF)
    pair.solreffriction = [FRICTION_TIMECONST, 1.0]
    pair.solimp = list(_SOLIMP)
    for name, reduce, ref in (("tool_contact", 3, "tool_tip"), ("peak_contact", 2, None)):
        sensor = spec.add_sensor(
            name=name,
            type=mujoco.mjtSensor.mjSENS_CONTACT,
            objtype=mujoco.mjtObj.mjOBJ_GEOM,
            objname="surface_geom",
            intprm=[2, reduce, 1],  # data: force; reduce: 3 netforce, 2 maxforce; one contact
        )
        if ref is not None:
            sensor.reftype, sensor.refname = mujoco.mjtObj.mjOBJ_GEOM, ref
    for name in RECORDED_SENSORS:  # MuJoCo keeps each step's value (mjData.history)
        spec.sensor(name).nsample = samples
    joint = spec.joint("surface_slide")
    joint.stiffness = [stiffness, 0.0, 0.0]
    joint.damping = [damping, 0.0, 0.0]
    joint.range = [-PLATE_TRAVEL, 0.05]
    return spec.compile()


class PeriodRecord:
    """A control period's sensordata, physics step by physics step, from MuJoCo's sensor
    history (``mjData.history``; the model from :func:`build_model`).

    MuJoCo keeps the last ``nsample`` values of each sensor of :data:`RECORDED_SENSORS` in a
    ring: per sensor, at ``sensor_historyadr``, two header numbers (the second: the ring's
    cursor, the newest sample's slot), ``nsample`` times, then ``nsample`` values of
    ``sensor_dim`` numbers. Calling the record on ``history`` ((nhistory,) of one MjData, or
    (N, nhistory) of a batch's rows) gives the samples oldest first in sensordata's layout,
    (n, nsensordata) or (N, n, nsensordata) (the columns of other sensors 0): row k is what
    ``mjData.sensordata`` held after the k-th of the last n physics steps.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        ids = [model.sensor(name).id for name in RECORDED_SENSORS]
        counts = {int(model.sensor_history[i, 0]) for i in ids}
        if len(counts) != 1 or 0 in counts:
            raise InvalidArgument(f"the sensors {RECORDED_SENSORS} need one nsample > 0")
        self.samples = n = counts.pop()
        self.nsensordata = model.nsensordata
        self.columns = np.concatenate([  # sensordata addresses of the recorded sensors
            np.arange(model.sensor_dim[i]) + model.sensor_adr[i] for i in ids
        ])
        # history address of each column's value in ring slot p: (n, columns)
        slot = np.arange(n)[:, None]
        self._value_at = np.concatenate([
            model.sensor_historyadr[i] + 2 + n + slot * model.sensor_dim[i]
            + np.arange(model.sensor_dim[i])
            for i in ids
        ], axis=1)
        self._cursor_at = int(model.sensor_historyadr[ids[0]]) + 1  # they are sampled together
        self._ahead = 1 + np.arange(n)  # the oldest sample is the one after the cursor
        self._every_column = np.array_equal(np.sort(self.columns), np.arange(self.nsensordata))
        self._rows = np.zeros((0, 1, 1), dtype=np.int64)

    def __call__(self, history: np.ndarray) -> np.ndarray:
        cursor = history[..., self._cursor_at].astype(np.int64)  # () or (N,)
        slots = (cursor[..., None] + self._ahead) % self.samples  # ring slots, oldest first
        index = self._value_at[slots]  # (..., n, columns): history addresses
        values = history[index] if history.ndim == 1 else history[self._row_of(index), index]
        if self._every_column:
            return values
        record = np.zeros((*np.shape(cursor), self.samples, self.nsensordata))
        record[..., self.columns] = values
        return record

    def _row_of(self, index: np.ndarray) -> np.ndarray:
        """(N, 1, 1) row numbers that pair with ``index`` (N, n, columns) in a fancy index."""
        if len(self._rows) != len(index):
            self._rows = np.arange(len(index))[:, None, None]
        return self._rows


def wrist_sensor_spec(sensor: str, **overrides: Any) -> SensorSpec:
    """The wrist sensor: preset ``sensor`` with the env's ``sensor_*`` arguments that are not
    None (``sensor_bias``, ``sensor_noise``, ``sensor_resolution``, ``sensor_rate``,
    ``sensor_cutoff``, ``sensor_delay``).

    Raises:
        InvalidArgument: naming the argument and what is allowed.
    """
    if not isinstance(sensor, str) or sensor not in PRESETS:
        raise InvalidArgument(f"sensor must be one of {sorted(PRESETS)}, got {sensor!r}")
    fields = {
        "sensor_bias": "bias",
        "sensor_noise": "noise_std",
        "sensor_resolution": "resolution",
        "sensor_rate": "sample_rate",
        "sensor_cutoff": "cutoff",
        "sensor_delay": "delay",
    }
    spec = PRESETS[sensor]
    for argument, value in overrides.items():
        if value is not None:
            try:
                spec = sensor_spec(spec, **{fields[argument]: value})
            except InvalidArgument as exc:
                raise InvalidArgument(f"{argument}: {exc}") from exc
    return spec


def tool_robot() -> Robot:
    """The nominal iiwa14 with the tool (a controller's model: the robot file plus the tool)."""
    robot = Robot.from_name("iiwa14")
    apply_model_error(robot.model, ModelError(payload_mass=TOOL_MASS))
    robot.invalidate()
    return robot


def surface_force(model: mujoco.MjModel, data: mujoco.MjData, geom: int) -> np.ndarray:
    """Total contact force (3,) on geom ``geom`` from every contact, world frame (N)."""
    total = np.zeros(3)
    f = np.zeros(6)
    for i in range(data.ncon):
        c = data.contact[i]
        if geom not in (c.geom1, c.geom2):
            continue
        mujoco.mj_contactForce(model, data, i, f)
        world = c.frame.reshape(3, 3).T @ f[:3]  # on geom2, pushing it along the normal
        total += world if c.geom2 == geom else -world
    return total


def draw_surface(
    rng: np.random.Generator,
    nominal: tuple[float, float, np.ndarray],
    randomize: bool,
    height_error: float,
    tilt_error: float,
    force_ref: float | None,
) -> dict[str, Any]:
    """One episode's surface and task: the stiffness (N/m), damping (N s/m) and sensor bias
    (6,) (``nominal``'s, or drawn from :data:`RANDOM_RANGES` when ``randomize``), the height
    error U(±``height_error``) m, the tilt U(±``tilt_error``) rad about a random horizontal
    axis, f̄ (``force_ref``, or U(:data:`FORCE_REF_RANGE`) N when None) and the wiping
    direction (a random horizontal unit vector)."""
    if randomize:
        lo, hi = RANDOM_RANGES["stiffness"]
        k = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        c = float(rng.uniform(*RANDOM_RANGES["damping"]))
        bias = np.concatenate((
            rng.uniform(*RANDOM_RANGES["sensor_bias_force"], 3),
            rng.uniform(*RANDOM_RANGES["sensor_bias_torque"], 3),
        ))
    else:
        k, c, bias = nominal[0], nominal[1], np.array(nominal[2])
    dh = float(rng.uniform(-height_error, height_error))
    tilt = float(rng.uniform(-tilt_error, tilt_error))
    phi = float(rng.uniform(0.0, 2 * np.pi))
    f_ref = float(rng.uniform(*FORCE_REF_RANGE)) if force_ref is None else force_ref
    psi = float(rng.uniform(0.0, 2 * np.pi))
    return {
        "stiffness": k,
        "damping": c,
        "sensor_bias": bias,
        "height_error": dh,
        "tilt": tilt,
        "tilt_axis": np.array([np.cos(phi), np.sin(phi), 0.0]),
        "force_ref": f_ref,
        "wipe_direction": np.array([np.cos(psi), np.sin(psi), 0.0]),
    }


def tilt_rotation(axis: np.ndarray, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """The rotation by ``angle`` (rad) about the unit ``axis`` (3,): its quaternion (4,) and its
    matrix (3, 3)."""
    quat, R = np.zeros(4), np.zeros(9)
    mujoco.mju_axisAngle2Quat(quat, axis, angle)
    mujoco.mju_quat2Mat(R, quat)
    return quat, R.reshape(3, 3)


def wipe_reference(t: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tip's reference position and velocity (len(t), 3) at the times ``t`` (s): from the
    start, :data:`APPROACH_HEIGHT` above the nominal surface point, down to it in 1 s
    (quintic), then from :data:`WIPE_START` a sine of :data:`WIPE_AMPLITUDE` and
    :data:`WIPE_FREQUENCY` along ``direction`` (3,) in the nominal surface."""
    start = SURFACE_POINT + APPROACH_HEIGHT * SURFACE_NORMAL
    tau = np.clip(t / 1.0, 0.0, 1.0)
    blend = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    dblend = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) * (t <= 1.0)
    w = 2 * np.pi * WIPE_FREQUENCY
    active = t >= WIPE_START
    s_wipe = np.where(active, WIPE_AMPLITUDE * np.sin(w * (t - WIPE_START)), 0.0)
    v_wipe = np.where(active, WIPE_AMPLITUDE * w * np.cos(w * (t - WIPE_START)), 0.0)
    position = start + np.outer(blend, SURFACE_POINT - start) + np.outer(s_wipe, direction)
    velocity = np.outer(dblend, SURFACE_POINT - start) + np.outer(v_wipe, direction)
    return position, velocity


def quat_of(R: np.ndarray) -> np.ndarray:
    """The unit quaternions (w, x, y, z), w ≥ 0, of rotation matrices ``R`` (..., 3, 3):
    (..., 4). MuJoCo's ``mju_mat2Quat`` matrix by matrix (one C call each: for one matrix
    ten times cheaper than a vectorised conversion's numpy calls, and the same numbers for
    a single env and a batch of copies)."""
    if np.ndim(R) == 2:
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, np.ascontiguousarray(R).reshape(9))
        return q if q[0] >= 0 else -q
    rows = np.ascontiguousarray(R, dtype=float).reshape(-1, 9)
    q = np.empty((len(rows), 4))
    for quat, mat in zip(q, rows, strict=True):
        mujoco.mju_mat2Quat(quat, mat)
    q[q[:, 0] < 0] *= -1.0
    return q.reshape(*np.shape(R)[:-2], 4)


def positive_w(quat: np.ndarray) -> np.ndarray:
    """The same rotations as the unit quaternions ``quat`` (..., 4) (w, x, y, z), with w ≥ 0."""
    return np.where(quat[..., :1] < 0, -quat, quat)


def draw(
    scene: mujoco.MjvScene,
    path: np.ndarray,
    target: np.ndarray,
    tip: np.ndarray,
    f_ref: float,
    f_measured: np.ndarray,
) -> None:
    """The wiping ``path`` (N, 3), the reference point ``target`` (3,), and at the ``tip`` (3,)
    the reference force f̄ (N, blue, along −n̂) beside the measured force (3,) (N, red)."""
    scale = 0.005  # m per N; arrows end at the tip, pushing on the surface
    rendering.add_polyline(scene, path[:: max(1, len(path) // 120)], 0.003, rendering.REFERENCE)
    rendering.add_sphere(scene, target, 0.008, rendering.TARGET)
    side = np.array([0.0, 0.05, 0.0])
    if f_ref > 0:
        arrow = -f_ref * scale * SURFACE_NORMAL
        rendering.add_arrow(scene, tip - arrow + side[[1, 0, 2]], arrow, 0.006, rendering.BLUE)
    arrow = f_measured * scale
    if np.linalg.norm(arrow) > 0.2 * scale:
        rendering.add_arrow(scene, tip - arrow - side, arrow, 0.006, rendering.RED)
