"""AdmittanceContact: press on a compliant surface with a reference force while wiping (chapter 6)."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces

from cir_gym import rendering
from cir_gym.context import TaskContext
from cir_gym.envs.base import (
    _MAX_SPEED_SQ,
    _STATE,
    _UNSTABLE_CONTIGUOUS,
    MIN_CONTROL_FREQ,
    RobotEnv,
)
from cir_gym.envs.base import frame_skip as physics_steps
from cir_gym.ft_sensor import (
    PRESETS,
    WrenchSensor,
    contact_wrench,
    sensor_spec,
    tool_gravity_wrench,
)
from cir_gym.metrics import MetricSpec
from cir_gym.motion_interface import CartesianMotionInterface
from cir_gym.numeric import _SUM, CLIP, index_view, max_of, mean_of, rms_of
from cir_gym.robot import (
    ASSETS,
    PAYLOAD_OFFSET,
    PAYLOAD_RADIUS,
    ModelError,
    Robot,
    apply_model_error,
)
from cir_gym.validation import InvalidArgument, check_number

__all__ = [
    "AdmittanceContactEnv",
    "build_model",
    "surface_force",
    "tool_robot",
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
APPROACH_HEIGHT = 0.03  # m
WIPE_START = 2.0  # s
WIPE_AMPLITUDE = 0.05  # m
WIPE_FREQUENCY = 0.25  # Hz: peak speed 2π A f = 0.079 m/s
CONTACT_THRESHOLD = 0.5  # N: true normal force above which the tool is in contact
STIFFNESS_RANGE = (1.0e3, 1.0e5)  # N/m
FORCE_REF_RANGE = (5.0, 30.0)  # N
#: position interface: action 1 = this speed (m/s for δp, rad/s for δφ) over one period
MAX_SPEED = np.array([0.25, 0.25, 0.25, 1.0, 1.0, 1.0])
#: ranges drawn per episode when randomize=True (stiffness log-uniform, others uniform)
RANDOM_RANGES = {
    "stiffness": STIFFNESS_RANGE,  # N/m, log-uniform
    "damping": (5.0, 50.0),  # N s/m
    "sensor_bias_force": (-2.0, 2.0),  # N, each axis
    "sensor_bias_torque": (-0.1, 0.1),  # N m, each axis
}
CONTROLS = ("torque", "position")
#: physics step (s). 0.25 ms, not the robot file's 1 ms: the tool-plate contact is stiff (solref
#: time constant 2 ms) and the tool slides on it with friction; at a 1-ms step (time constant =
#: 2 steps, MuJoCo's limit) the sliding contact chatters in 1-ms bounces that ring the plate
#: (measured at 1e5 N/m, 20 N, admittance: force RMS error 4.05 N at 1 ms, 1.40 N at 0.5 ms,
#: 0.67 N at 0.25 ms; frictionless, 0.46 N at 1 ms): a discretisation error, not physics, so the
#: step is refined until it is small (scripts/eval_contact.py, "physics step").
TIMESTEP = 0.00025
_SITE_OBJ = mujoco.mjtObj.mjOBJ_SITE  # _obs's mj_objectVelocity (an attribute lookup less)
#: what the next mj_step reads, and the sensors' history: _motion_period's undo
_UNDO_STATE = int(mujoco.mjtState.mjSTATE_INTEGRATION | mujoco.mjtState.mjSTATE_HISTORY)
_isfinite = math.isfinite


def build_model(
    stiffness: float, damping: float, timestep: float = TIMESTEP, history: int = 1
) -> mujoco.MjModel:
    """The scene (robot, tool, sprung plate) with the plate's spring (N/m) and damper (N s/m),
    simulated with the physics step ``timestep`` (s).

    The wrist sensors ``ft_force``/``ft_torque`` and a ``plate_contact`` sensor (the net contact
    force on the plate, world frame, N: MuJoCo's contact sensor, ``reduce="netforce"``) keep
    their last ``history`` physics steps' values in MuJoCo's sensor history (``nsample``), so
    a control period of that many steps runs in one ``mj_step`` call and the env reads every
    step's values afterwards.

    The tool is added to the robot's ``payload`` body (beyond ``ft_site``) with MjSpec: the
    payload's inertial is the tool's (:data:`TOOL_MASS`, the centre of mass and inertia of
    :func:`cir_gym.robot.apply_model_error`'s payload model), so :func:`tool_robot` is an exact
    nominal model. Geoms carry no mass (``inertiafromgeom="false"`` in the robot file).
    """
    spec = mujoco.MjSpec.from_file(str(SCENE))
    spec.option.timestep = timestep
    spec.add_sensor(
        name="plate_contact",
        type=mujoco.mjtSensor.mjSENS_CONTACT,
        objtype=mujoco.mjtObj.mjOBJ_GEOM,
        objname="surface_geom",
        intprm=[2, 3, 1],  # data: force; reduce: netforce; one (net) contact
    )
    for name in ("ft_force", "ft_torque", "plate_contact"):
        spec.sensor(name).nsample = history
    payload = spec.body("payload")
    payload.mass = TOOL_MASS
    payload.ipos = TOOL_COM
    payload.inertia = [0.4 * TOOL_MASS * PAYLOAD_RADIUS**2] * 3
    surface = spec.geom("surface_geom")
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
    tip.contype, tip.conaffinity = 1, 0
    tip.rgba = [0.9, 0.5, 0.1, 1.0]
    # the same stiff contact parameters on both sides (MuJoCo mixes the two geoms' values)
    tip.solref, tip.solimp, tip.friction = surface.solref, surface.solimp, surface.friction
    tip.margin, tip.gap = surface.margin, surface.gap
    joint = spec.joint("surface_slide")
    joint.stiffness = [stiffness, 0.0, 0.0]
    joint.damping = [damping, 0.0, 0.0]
    return spec.compile()


def tool_robot() -> Robot:
    """The nominal iiwa14 with the tool (a controller's model: the robot file plus the tool)."""
    robot = Robot.from_name("iiwa14")
    apply_model_error(robot.model, ModelError(payload_mass=TOOL_MASS))
    robot.invalidate()
    return robot


def surface_force(model: mujoco.MjModel, data: mujoco.MjData, geom: int) -> np.ndarray:
    """Total contact force (3,) on geom ``geom`` (the plate) from every contact, world frame (N)."""
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


def _quat(R: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, R.reshape(9))
    return q if q[0] >= 0 else -q


class AdmittanceContactEnv(RobotEnv):
    """Press a tool on a compliant surface with a reference normal force while wiping a path.

    ## Description
    Chapter 6's interaction-control problem. The KUKA iiwa 14 carries a 0.3 kg tool with a
    hemispherical tip behind a wrist force/torque sensor. Below it, a 0.2-kg plate on a prismatic
    joint with a real spring and damper (``stiffness`` N/m, ``damping`` N s/m: the surface's
    contact stiffness and damping realised exactly, which MuJoCo's mass-normalised ``solref``
    cannot do; the tool-plate contact itself is stiff: < 1 µm of penetration at 20 N; scene
    ``assets/scenes/admittance_contact.xml``). At 1e5 N/m the plate's own mode is at
    √(k/m)/2π ≈ 110 Hz, lightly damped at the default damping (ζ = 0.07). The physics step is
    0.25 ms (``timestep``, :data:`TIMESTEP`): at MuJoCo's usual 1 ms the sliding stiff contact
    chattered in 1-ms bounces that rang this mode (a ±5 N ripple at 1e5 N/m that shrinks as the
    step is refined, so a discretisation error).
    The tool starts 3 cm above the *nominal* surface (the plane z = 0.20 m, normal +z); the
    true surface is off by a height and a tilt drawn per episode (U(±``height_error``) m,
    U(±``tilt_error``) rad about a random horizontal axis), known to the controllers only
    nominally. The controller must approach, make contact, press with the reference normal force
    f̄ (``force_ref`` N, drawn from U(5, 30) per episode when None) and follow a wiping path on the
    surface: from t = 2 s the tip's reference moves by 5 cm · sin(2π · 0.25 Hz · (t − 2)) along
    a random horizontal direction (peak 0.079 m/s), on the nominal surface.

    The true normal force f (N, ``info["contact_force"]``, never observed) is the load in the
    surface's spring and damper, k x + c ẋ: what a load cell under the plate reads, equal to the
    tool's contact force at rest. MuJoCo's per-step contact force is not used for it: it is not
    smooth from one physics step to the next while the tool slides; the plate's spring carries
    the mean. ``info["in_contact"]``: the tool touched the plate during the control period. The
    controllers measure the wrench through the sensor model (:mod:`cir_gym.ft_sensor`), which
    includes the tool's weight, a bias, noise, quantisation, a low-pass filter, a delay and
    sampling with zero-order hold (presets ``"robotiq_ft300"``, ``"ati_gamma"``, ``"ideal"``);
    the reading lags the true wrench by one further physics step (MuJoCo computes sensors before
    it integrates). With ``randomize=True`` each reset draws the stiffness (log-uniform in
    [1e3, 1e5] N/m), the damping (U(5, 50) N s/m) and the sensor bias (U(±2) N, U(±0.1) N m per
    axis) and ignores ``stiffness``, ``damping`` and ``sensor_bias``; the draw is in
    ``info["surface"]`` of ``reset``.

    ## Action Space
    ``control="torque"``: ``Box(-1, 1, (7,), float32)``, τ = a ⊙ τ_max (τ_max = 320, 320, 176,
    176, 110, 40, 40 N m). ``control="position"`` (the interface of an industrial robot):
    ``Box(-1, 1, (6,), float32)``, a Cartesian setpoint increment δx = a ⊙ (0.25, 0.25, 0.25 m/s,
    1, 1, 1 rad/s) · T per control period T (δp in m, δφ a rotation vector in rad, world frame),
    executed by the env's own stiff motion controller (:mod:`cir_gym.motion_interface`:
    differential IK of the setpoint and joint-space inverse dynamics with ω_n = 150 rad/s at
    every physics step; measured setpoint-to-pose bandwidth ≈ 50 Hz). Finite values outside
    [-1, 1] are clipped; NaN/inf or a wrong shape raise ``ValueError``.

    ## Observation Space
    ``Dict`` of float64 arrays (clipped to the bounds):

    | key | shape | meaning | bounds | unit |
    |---|---|---|---|---|
    | q | 7 | joint positions | ±2π | rad |
    | qd | 7 | joint velocities | ±50 | rad/s |
    | tool_pos | 3 | tool tip (site ``tcp``) position, world | ±2 | m |
    | tool_quat | 4 | tool orientation (w, x, y, z), tool → world | ±1 | |
    | tool_vel | 3 | tool tip linear velocity, world | ±10 | m/s |
    | tool_angvel | 3 | tool angular velocity, world | ±50 | rad/s |
    | wrench | 6 | F/T sensor reading [f; μ] in the sensor frame (``ft_site``, the flange: z along the tool): what the flange exerts on the tool, so the tool's weight plus the force the tool exerts on the surface; bias and noise included | ±1000 | N, N m |
    | f_ref | 1 | reference normal force f̄ | [0, 100] | N |
    | tool_pos_ref | 3 | path reference of the tip (on the nominal surface after the start) | ±2 | m |
    | tool_vel_ref | 3 | its velocity | ±10 | m/s |
    | setpoint_pos | 3 | position interface: the Cartesian setpoint x_c; torque: = tool_pos | ±2 | m |
    | setpoint_quat | 4 | position interface: the setpoint orientation; torque: = tool_quat | ±1 | |

    ## Rewards
    r = r_force + r_path + r_action_rate + r_force_limit + r_diverged, each in
    ``info["reward_<name>"]``:
    - r_force = −(1 − ½ Σ_s exp(−(f − f̄)² / s²)), s ∈ (``force_scale``, ``force_scale``/5) N, in
      [−1, 0], from the true normal force;
    - r_path = −``path_weight`` (1 − exp(−‖e_t‖² / ``path_scale``²)), e_t the tip's path error
      in the nominal surface's plane;
    - r_action_rate = −``action_rate_weight`` ‖a_k − a_{k−1}‖² / dim(a);
    - r_force_limit = −(``force_limit_penalty`` + N_left (1 + ``path_weight``)) on the step the
      force exceeds ``force_limit``, N_left the steps the stop leaves unplayed: the rest of the
      horizon at the worst per-step reward, as the metrics score a stopped episode, so that
      ending an episode early never pays (with all rewards ≤ 0 a fixed penalty made slamming
      into the surface the best return for an agent that cannot yet press well);
    - r_diverged = −(``divergence_penalty`` + N_left (1 + ``path_weight``)) likewise.

    ## Starting State
    At rest at ``START_Q`` (tip 3 cm above the nominal surface, tool pointing down), the sensor
    in steady state (filter and delay line at the static reading).

    ## Episode End
    Truncated after ``episode_duration`` s. Terminated when the physics diverges
    (``info["diverged"]``) or the normal force exceeds ``force_limit`` (a failure,
    ``info["force_limit_exceeded"]``); a stopped episode is scored over the whole horizon with
    the force error f̄ and contact lost for the steps it did not play.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | control | "torque" | "torque" (joint torques) or "position" (Cartesian setpoint increments) |
    | control_freq | 500.0 | control frequency (Hz), the physics rate divided by an integer |
    | timestep | 0.00025 | physics step (s), in [1e-4, 1e-3] (see :data:`TIMESTEP`) |
    | episode_duration | 5.0 | s |
    | stiffness | 10000.0 | surface stiffness (N/m), in [1e3, 1e5] |
    | damping | 20.0 | surface damping (N s/m), in [0, 1e4] |
    | force_ref | None | reference normal force f̄ (N) in [0, 50]; None = U(5, 30) per episode |
    | height_error | 0.005 | max surface height error (m), in [0, 0.02] |
    | tilt_error | 0.0524 | max surface tilt (rad, 3°), in [0, 0.2] |
    | randomize | False | per reset, draw stiffness, damping and sensor bias from ``RANDOM_RANGES`` |
    | sensor | "robotiq_ft300" | sensor preset: "robotiq_ft300", "ati_gamma" or "ideal" |
    | sensor_bias | None | bias (6,) [N, N m] replacing the preset's; None = preset's (zero) |
    | sensor_noise | None | noise std (force N, torque N m); None = preset's |
    | sensor_resolution | None | quantum (force N, torque N m); None = preset's |
    | sensor_rate | None | sample rate (Hz, ≤ 1000, or inf); None = preset's |
    | sensor_cutoff | None | low-pass cut-off (Hz, or inf); None = preset's |
    | sensor_delay | None | transport delay (s); None = preset's |
    | force_limit | 100.0 | normal force (N) that ends the episode as a failure |
    | settle_time | 0.5 | s after the first contact before the force error is scored |
    | force_scale | 10.0 | force reward kernel width (N), in [1e-3, 1e3] |
    | path_scale | 0.01 | path reward kernel width (m), in [1e-6, 10] |
    | path_weight | 0.5 | weight of the path term |
    | action_rate_weight | 0.01 | weight of the action-rate term |
    | force_limit_penalty | 50.0 | reward lost when the force limit ends the episode (plus the rest of the horizon) |
    | divergence_penalty | 100.0 | reward lost when the physics diverges (plus the rest of the horizon) |
    | success_threshold | 1.0 | normal-force RMS error (N) below which an episode succeeds |
    | render_mode | None | None, "human" or "rgb_array" |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    Over the scoring window, from ``settle_time`` after the first contact to the end:
    ``force_rms_error`` (primary, N; f̄ if the tool never touched), ``contact_loss`` (fraction of
    the window's steps with f < 0.5 N; 1 if never touched), ``path_error`` (m, RMS of e_t).
    Over the episode: ``peak_overshoot`` (N, max(f − f̄, 0) after the first contact) and
    ``max_force`` (N). Success: no divergence, no force-limit stop, ``force_rms_error`` <
    ``success_threshold`` and ``contact_loss`` < 0.01.

    ## Reference controllers
    ``baselines.available("cir_gym/AdmittanceContact-v0")``: impedance, admittance,
    explicit_force, implicit_force, parallel_force_position (:mod:`baselines.interaction`).

    ## Version History
    - v0: initial version. Changed before the issue closed (no v1): the physics step 1 ms →
      0.25 ms (``timestep``) and a stop's cost includes the rest of the horizon; the shipped
      agents were retrained on this version.
    """

    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec("force_rms_error", "N", "lower", "normal-force RMS error after settling"),
        MetricSpec("peak_overshoot", "N", "lower", "max normal force above f_ref after contact"),
        MetricSpec("contact_loss", "", "lower", "fraction of scored steps without contact"),
        MetricSpec("path_error", "m", "lower", "RMS path error in the surface plane"),
        MetricSpec("max_force", "N", "lower", "maximum normal force"),
    )
    primary_metric: ClassVar[str] = "force_rms_error"
    reward_arguments: ClassVar[frozenset[str]] = frozenset((
        "force_scale", "path_scale", "path_weight", "action_rate_weight",
        "force_limit_penalty", "divergence_penalty",
    ))
    leaderboard_variants: ClassVar[dict[str, dict[str, Any]]] = {
        "stiffness 1e3 N/m": {"stiffness": 1.0e3, "force_ref": 20.0},
        "stiffness 1e4 N/m": {"stiffness": 1.0e4, "force_ref": 20.0},
        "stiffness 1e5 N/m": {"stiffness": 1.0e5, "force_ref": 20.0},
        "unknown stiffness (randomize)": {"randomize": True},
    }
    robot_name: ClassVar[str] = "iiwa14"

    def __init__(
        self,
        control: str = "torque",
        control_freq: float = 500.0,
        episode_duration: float = 5.0,
        timestep: float = TIMESTEP,
        stiffness: float = 10000.0,
        damping: float = 20.0,
        force_ref: float | None = None,
        height_error: float = 0.005,
        tilt_error: float = 0.0524,
        randomize: bool = False,
        sensor: str = "robotiq_ft300",
        sensor_bias: Any = None,
        sensor_noise: Any = None,
        sensor_resolution: Any = None,
        sensor_rate: float | None = None,
        sensor_cutoff: float | None = None,
        sensor_delay: float | None = None,
        force_limit: float = 100.0,
        settle_time: float = 0.5,
        force_scale: float = 10.0,
        path_scale: float = 0.01,
        path_weight: float = 0.5,
        action_rate_weight: float = 0.01,
        force_limit_penalty: float = 50.0,
        divergence_penalty: float = 100.0,
        success_threshold: float = 1.0,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ) -> None:
        if control not in CONTROLS:
            raise InvalidArgument(f"control must be one of {CONTROLS}, got {control!r}")
        self.control = control
        self.stiffness = check_number("stiffness", stiffness, *STIFFNESS_RANGE)
        self.damping = check_number("damping", damping, 0.0, 1.0e4)
        self.force_ref = (
            None if force_ref is None else check_number("force_ref", force_ref, 0.0, 50.0)
        )
        # + 0.0 turns −0.0 into 0.0 (uniform(−0.0, 0.0) is an error in numpy)
        self.height_error = check_number("height_error", height_error, 0.0, 0.02) + 0.0
        self.tilt_error = check_number("tilt_error", tilt_error, 0.0, 0.2) + 0.0
        if not isinstance(randomize, (bool, np.bool_)):
            raise InvalidArgument(f"randomize must be True or False, got {randomize!r}")
        self.randomize = bool(randomize)
        if not isinstance(sensor, str) or sensor not in PRESETS:
            raise InvalidArgument(f"sensor must be one of {sorted(PRESETS)}, got {sensor!r}")
        spec = PRESETS[sensor]
        for argument, field, value in (
            ("sensor_bias", "bias", sensor_bias),
            ("sensor_noise", "noise_std", sensor_noise),
            ("sensor_resolution", "resolution", sensor_resolution),
            ("sensor_rate", "sample_rate", sensor_rate),
            ("sensor_cutoff", "cutoff", sensor_cutoff),
            ("sensor_delay", "delay", sensor_delay),
        ):
            if value is not None:
                try:
                    spec = sensor_spec(spec, **{field: value})
                except InvalidArgument as exc:
                    raise InvalidArgument(f"{argument}: {exc}") from exc
        self.sensor_spec = spec
        self.sensor_name = sensor
        self.force_limit = check_number("force_limit", force_limit, 1.0, 1000.0)
        self.settle_time = check_number("settle_time", settle_time, 0.0, 10.0)
        self.force_scale = check_number("force_scale", force_scale, 1e-3, 1000.0)
        self.path_scale = check_number("path_scale", path_scale, 1e-6, 10.0)
        self.path_weight = check_number("path_weight", path_weight, 0.0, 10.0)
        self.action_rate_weight = check_number("action_rate_weight", action_rate_weight, 0.0, 10.0)
        self.force_limit_penalty = check_number(
            "force_limit_penalty", force_limit_penalty, 0.0, 1e6
        )
        self.divergence_penalty = check_number("divergence_penalty", divergence_penalty, 0.0, 1e6)
        self.success_threshold = check_number(
            "success_threshold", success_threshold, 0.0, 100.0, low_open=True
        )

        # the solref time constant (2 ms) must stay ≥ 2 physics steps
        self.timestep = check_number("timestep", timestep, 1.0e-4, 1.0e-3)
        # physics steps per control period, checked as RobotEnv checks them (the model keeps
        # that many steps of sensor history, so it is built only for a valid control_freq)
        control_freq = check_number(
            "control_freq", control_freq, MIN_CONTROL_FREQ, 1.0 / self.timestep
        )
        history = physics_steps(control_freq, self.timestep)
        model = build_model(self.stiffness, self.damping, self.timestep, history)
        super().__init__(
            model,
            control_freq=control_freq,
            episode_duration=episode_duration,
            render_mode=render_mode,
            width=width,
            height=height,
        )
        # the control period holds self._substeps = frame_skip physics steps: one _simulate
        # call on the torque interface (the sensors' history holds every step's values), one
        # call per physics step on the position interface (its motion controller runs at the
        # physics rate)
        self._substeps = self.frame_skip
        self.robot = Robot(model, JOINTS)  # the simulator's arm
        self.n = self.robot.n
        self._qa, self._da = self.robot.qpos_adr, self.robot.dof_adr
        self.torque_limit = self.robot.torque_limit.copy()
        self._site = self.robot.site_id(SITE)
        self._ft_site = self.robot.site_id("ft_site")
        self._plate_geom = model.geom("surface_geom").id
        self._mount = model.body("surface_mount").id
        self._mount_pos0 = model.body_pos[self._mount].copy()
        self._mount_quat0 = model.body_quat[self._mount].copy()
        slide = model.joint("surface_slide")
        self._slide_jnt, self._slide_dof = slide.id, int(model.jnt_dofadr[slide.id])
        self._slide_qpos = int(model.jnt_qposadr[slide.id])
        adr = [int(model.sensor_adr[model.sensor(s).id]) for s in ("ft_force", "ft_torque")]
        self._sensor_adr = np.r_[adr[0] : adr[0] + 3, adr[1] : adr[1] + 3]
        self._contact_adr = int(model.sensor_adr[model.sensor("plate_contact").id])
        # MuJoCo's sensor history of one sensor: [·, newest slot, n times, n × dim values]
        self._history_adr = [
            int(model.sensor_historyadr[model.sensor(s).id])
            for s in ("ft_force", "ft_torque", "plate_contact")
        ]
        self._history_index: dict[int, np.ndarray] = {}  # newest ring slot -> value indices
        # newest ring slot -> (the period's wrenches (n, 6) and contact forces (n, 3) in
        # MuJoCo's history, oldest first): _read_history's two gathers
        self._period_index: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        try:
            self.sensor = WrenchSensor(self.sensor_spec, model.opt.timestep)
        except InvalidArgument as exc:  # the only physics-dependent limit: the sample rate
            raise InvalidArgument(f"sensor_rate: {exc}") from exc
        self.interface = (
            CartesianMotionInterface(tool_robot(), SITE) if control == "position" else None
        )
        self.increment_scale = MAX_SPEED * self.dt
        dim = self.n if control == "torque" else 6
        self.action_space = spaces.Box(-1.0, 1.0, (dim,), dtype=np.float32)
        self._bounds = {
            "q": (7, 2 * np.pi),
            "qd": (7, 50.0),
            "tool_pos": (3, 2.0),
            "tool_quat": (4, 1.0),
            "tool_vel": (3, 10.0),
            "tool_angvel": (3, 50.0),
            "wrench": (6, 1000.0),
            "f_ref": (1, 100.0),
            "tool_pos_ref": (3, 2.0),
            "tool_vel_ref": (3, 10.0),
            "setpoint_pos": (3, 2.0),
            "setpoint_quat": (4, 1.0),
        }
        self.observation_space = spaces.Dict(
            {
                k: spaces.Box(0.0 if k == "f_ref" else -b, b, (n,), dtype=np.float64)
                for k, (n, b) in self._bounds.items()
            }
        )
        # _obs fills one array (the keys in the order of _bounds) and clips it once
        sizes = [n for n, _ in self._bounds.values()]
        ends = np.cumsum(sizes)
        self._obs_slices = [slice(int(e - n), int(e)) for n, e in zip(sizes, ends, strict=True)]
        self._obs_size = int(ends[-1])
        self._obs_low = np.concatenate([self.observation_space[k].low for k in self._bounds])
        self._obs_high = np.concatenate([self.observation_space[k].high for k in self._bounds])
        self._obs_items = tuple(zip(self._bounds, self._obs_slices, strict=True))
        at = dict(self._obs_items)
        self._q_at, self._qd_at = index_view(self._qa), index_view(self._da)
        # the observation's slices that _obs fills (setpoint pose: next to each other, as
        # the tool's pose is)
        self._pose_at = slice(at["tool_pos"].start, at["tool_quat"].stop)
        self._setpoint_at = slice(at["setpoint_pos"].start, at["setpoint_quat"].stop)
        self._refs_at = slice(at["f_ref"].start, at["tool_vel_ref"].stop)
        self._vel_buf = np.zeros(6)  # mj_objectVelocity's [ω; v] of the tcp
        self._period_start = np.zeros(mujoco.mj_stateSize(model, _UNDO_STATE))
        self._pass_state = np.zeros(mujoco.mj_stateSize(model, _STATE))
        steps = self.max_steps
        self._pos_ref = np.zeros((steps + 1, 3))
        self._vel_ref = np.zeros((steps + 1, 3))
        self._ref_rows = np.zeros((steps + 1, 7))  # [f_ref, pos_ref, vel_ref] (reset)
        self._force = np.zeros(steps)  # true normal force after each step
        self._path = np.zeros(steps)  # tangential path error (m)
        self._touch = np.zeros(steps, dtype=bool)  # tool-plate contact during the period
        self._k = 0
        self._first_contact: int | None = None
        self._stopped_at: int | None = None
        self._a_prev = np.zeros(dim)
        self._f_ref = 0.0
        self._normal = SURFACE_NORMAL.copy()
        self._surface = {}
        self._episode_stiffness = self.stiffness
        self._episode_damping = self.damping

    # ------------------------------------------------------------------ episode set-up
    def _draw_surface(self) -> dict[str, Any]:
        rng = self.np_random
        if self.randomize:
            lo, hi = RANDOM_RANGES["stiffness"]
            k = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
            c = float(rng.uniform(*RANDOM_RANGES["damping"]))
            bias = np.concatenate(
                (
                    rng.uniform(*RANDOM_RANGES["sensor_bias_force"], 3),
                    rng.uniform(*RANDOM_RANGES["sensor_bias_torque"], 3),
                )
            )
        else:
            k, c, bias = self.stiffness, self.damping, np.array(self.sensor_spec.bias)
        dh = float(rng.uniform(-self.height_error, self.height_error))
        tilt = float(rng.uniform(-self.tilt_error, self.tilt_error))
        phi = float(rng.uniform(0.0, 2 * np.pi))
        axis = np.array([np.cos(phi), np.sin(phi), 0.0])
        f_ref = float(rng.uniform(*FORCE_REF_RANGE)) if self.force_ref is None else self.force_ref
        psi = float(rng.uniform(0.0, 2 * np.pi))
        direction = np.array([np.cos(psi), np.sin(psi), 0.0])
        return {
            "stiffness": k,
            "damping": c,
            "sensor_bias": bias,
            "height_error": dh,
            "tilt": tilt,
            "tilt_axis": axis,
            "force_ref": f_ref,
            "wipe_direction": direction,
        }

    def _apply_surface(self, s: dict[str, Any]) -> None:
        m = self.model
        m.jnt_stiffness[self._slide_jnt] = s["stiffness"]
        m.dof_damping[self._slide_dof] = s["damping"]
        quat = np.zeros(4)
        mujoco.mju_axisAngle2Quat(quat, s["tilt_axis"], s["tilt"])
        m.body_quat[self._mount] = quat
        m.body_pos[self._mount] = self._mount_pos0 + s["height_error"] * SURFACE_NORMAL
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, quat)
        self._normal = R.reshape(3, 3) @ SURFACE_NORMAL

    def _make_reference(self, s: dict[str, Any]) -> None:
        t = np.arange(self.max_steps + 1) * self.dt
        start = SURFACE_POINT + APPROACH_HEIGHT * SURFACE_NORMAL
        # descend to the nominal surface over the first second (quintic), then wipe
        tau = np.clip(t / 1.0, 0.0, 1.0)
        blend = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        dblend = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) * (t <= 1.0)
        w = 2 * np.pi * WIPE_FREQUENCY
        active = t >= WIPE_START
        s_wipe = np.where(active, WIPE_AMPLITUDE * np.sin(w * (t - WIPE_START)), 0.0)
        v_wipe = np.where(active, WIPE_AMPLITUDE * w * np.cos(w * (t - WIPE_START)), 0.0)
        d = s["wipe_direction"]
        self._pos_ref = start + np.outer(blend, SURFACE_POINT - start) + np.outer(s_wipe, d)
        self._vel_ref = np.outer(dblend, SURFACE_POINT - start) + np.outer(v_wipe, d)

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        s = self._draw_surface()
        self._surface = s
        self._apply_surface(s)
        self._make_reference(s)
        self._f_ref = s["force_ref"]
        # _obs's f_ref, tool_pos_ref, tool_vel_ref (neighbours) of every step, one row each
        refs = self._ref_rows = np.empty((len(self._pos_ref), 7))
        refs[:, 0] = self._f_ref
        refs[:, 1:4] = self._pos_ref
        refs[:, 4:7] = self._vel_ref
        qpos = self.model.qpos0.copy()
        qpos[self._qa] = START_Q
        self._reset_physics(qpos, np.zeros(self.model.nv))
        if self.interface is not None:
            self.interface.reset(START_Q)
        # the arm was held at rest: the sensor starts in steady state at the tool's weight
        R = self.data.site_xmat[self._ft_site].reshape(3, 3)
        rest = tool_gravity_wrench(TOOL_MASS, TOOL_COM, R)
        self.sensor.reset(self.np_random, rest, s["sensor_bias"])
        self._k = 0
        self._first_contact = None
        self._stopped_at = None
        self._a_prev[:] = 0.0
        info = {
            "surface": {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in s.items()}
        }
        return self._obs(), info

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        if self._k >= self.max_steps:
            raise RuntimeError("step() called after the episode ended; call reset()")
        a = self._check_action_peak(action)[0]
        if self.interface is None:  # one call: the torque is held over the period
            diverged = self._simulate(a * self.torque_limit)
            contact = 0.0 if diverged else self._read_history()
        else:
            self.interface.command(a * self.increment_scale, self.dt)
            diverged, contact = self._motion_period()
        # fresh poses and velocities for the observation (the stages of mj_forward it needs:
        # contacts and constraint forces stay those of the period's last physics step)
        m, d = self.model, self.data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_camlight(m, d)
        mujoco.mj_comVel(m, d)
        k = self._k
        self._k = k1 = k + 1
        touching = contact / self._substeps > CONTACT_THRESHOLD
        # normal_force() and _path_error_vector() on the views _simulate refreshed, in Python
        # floats (the same IEEE operations as numpy's scalars)
        _, qpos, qvel = self._views
        stiffness, damping = self._spring_views
        dof = self._slide_dof
        x = -qpos.item(self._slide_qpos)  # compression (m)
        force = stiffness.item(self._slide_jnt) * x - damping.item(dof) * qvel.item(dof)
        self._force[k] = force
        e = self._pos_ref[min(k1, self.max_steps)] - self._tcp_views[0]
        # e_t = e − (e·n̂) n̂ with n̂ = SURFACE_NORMAL = e_z: e·n̂ is e_z (the other products
        # are zeros), so e_t = (e_x, e_y, ±0) and ‖e_t‖² the same dot of (e_x, e_y, 0)
        e[2] = 0.0
        path_sq = float(e.dot(e))
        self._path[k] = math.sqrt(path_sq)  # = np.linalg.norm(e_t)
        self._touch[k] = touching
        if self._first_contact is None and touching:
            self._first_contact = k
        over = bool(not diverged and force > self.force_limit)

        err = force - self._f_ref
        s = self.force_scale
        r_force = -(1.0 - 0.5 * (math.exp(-((err / s) ** 2)) + math.exp(-((5 * err / s) ** 2))))
        r_path = -self.path_weight * (1.0 - math.exp(-path_sq / self.path_scale**2))
        da = a - self._a_prev
        r_rate = -self.action_rate_weight * float(da.dot(da)) / a.size
        # a stop also costs the rest of the horizon at the worst per-step reward (as the metrics
        # score it): ending the episode early never pays
        rest = (self.max_steps - self._k) * (1.0 + self.path_weight)
        r_limit = -(self.force_limit_penalty + rest) if over else 0.0
        r_div = -(self.divergence_penalty + rest) if diverged else 0.0
        self._a_prev[:] = a
        reward = r_force + r_path + r_rate + r_limit + r_div
        terminated = diverged or over
        if terminated:
            self._stopped_at = self._k
        truncated = self._k >= self.max_steps and not terminated
        info: dict[str, Any] = {
            "reward_force": r_force,
            "reward_path": r_path,
            "reward_action_rate": r_rate,
            "reward_force_limit": r_limit,
            "reward_diverged": r_div,
            "contact_force": force,
            "in_contact": touching,
            "force_error": err,
            "path_error": self._path[k],
            "force_limit_exceeded": over,
            "diverged": diverged,
        }
        if terminated or truncated:
            metrics = self.episode_metrics()
            info["episode_metrics"] = metrics
            info["is_success"] = bool(
                not terminated
                and metrics["force_rms_error"] < self.success_threshold
                and metrics["contact_loss"] < 0.01
            )
        return self._obs(), reward, terminated, truncated, info

    def sensor_history(self, which: int) -> np.ndarray:
        """The last control period's values of sensor ``which`` (0 ``ft_force``, 1 ``ft_torque``,
        2 ``plate_contact``), one row per physics step, oldest first: (substeps, 3)."""
        return self._history()[which]

    def _history(self) -> np.ndarray:
        """(3, substeps, 3): the three sensors' last control period, oldest step first."""
        hist = self.data.history
        # every sensor records every physics step, so their ring buffers turn together
        newest = int(hist[self._history_adr[0] + 1])
        index = self._history_index.get(newest)
        if index is None:
            n = self._substeps
            order = (np.arange(1, n + 1) + newest) % n  # ring slots, oldest first
            index = np.array(
                [h + 2 + n + 3 * order[:, None] + np.arange(3) for h in self._history_adr]
            )
            self._history_index[newest] = index
        return hist[index]

    def _read_history(self) -> float:
        """Feed the period's wrenches to the sensor model (oldest first) from MuJoCo's sensor
        history; return Σ over the period's physics steps of the tool-plate normal force (N).

        Two gathers from ``d.history`` with indices built once per ring position: the
        wrenches (n, 6) as :meth:`_history`'s force and torque rows side by side, and the
        contact forces (n, 3), the very array :meth:`_history` gives for sensor 2."""
        hist = self._hist
        newest = int(hist.item(self._history_adr[0] + 1))
        index = self._period_index.get(newest)
        if index is None:
            rows = self._history_index.get(newest)
            if rows is None:
                self._history()  # builds self._history_index[newest]
                rows = self._history_index[newest]
            index = (np.concatenate((rows[0], rows[1]), axis=1), rows[2].copy())
            self._period_index[newest] = index
        self.sensor.advance_many(hist[index[0]].tolist())
        # the sensor's net force is the one the plate exerts (−surface_force): n̂ · it = the
        # push along the inward normal
        return float(self._normal.dot(_SUM(hist[index[1]], 0)))  # = .sum(axis=0)

    def _refresh_views(self, d: mujoco.MjData) -> None:
        """RobotEnv's views, and those of ``d`` that step and _obs read: the sensor history,
        the tcp's position and rotation rows, the slide joint's position and velocity."""
        super()._refresh_views(d)
        self._hist = d.history
        self._tcp_views = (d.site_xpos[self._site], d.site_xmat[self._site])
        m = self.model
        self._spring_views = (m.jnt_stiffness, m.dof_damping)
        self._warn_all = (d.warning.number, d.warning.lastinfo)  # _motion_period's undo

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        for name in (
            "_hist",
            "_tcp_views",
            "_spring_views",
            "_warn_all",
        ):  # rebuilt on the new MjData
            state.pop(name, None)
        return state

    def _motion_period(self) -> tuple[bool, float]:
        """The position interface: the motion controller's torque recomputed at every physics
        step; return (diverged, Σ of the tool-plate normal force).

        A fast pass as PegInHole's (``_advance``): _simulate's speed test per physics step,
        its warning and finite-q tests at the end, its saved state set only on success; on
        any failure the period is undone (MuJoCo's integration state, sensor history and whole
        warning state, every counter and last info) and run again through _simulate
        (:meth:`_motion_period_simulate`). MuJoCo logs a warning's text when its counter leaves
        0, so a warning met in the undone pass is logged again by the rerun (a repeated line
        in MuJoCo's log, not in any value)."""
        m, d = self.model, self.data
        if self._warn_data is not d:
            self._refresh_views(d)
        if not _UNSTABLE_CONTIGUOUS:
            return self._motion_period_simulate()
        n = self._substeps
        _, qpos, qvel = self._views
        warn = self._warn_view
        sd = d.sensordata
        f0, t0, c0 = self._sensor_adr[0], self._sensor_adr[3], self._contact_adr
        both = t0 == f0 + 3  # force and torque side by side: one slice
        torque, limit = self.interface.torque, self.torque_limit
        q_at, qd_at, normal = self._q_at, self._qd_at, self._normal
        step, get_state = mujoco.mj_step, mujoco.mj_getState
        start, saved, last = self._period_start, self._pass_state, n - 1
        get_state(m, d, start, _UNDO_STATE)
        before = warn.tobytes()
        # MuJoCo's whole warning state, to undo (a pass may also count e.g. CONTACTFULL)
        number, lastinfo = self._warn_all
        warnings_before = (number.tobytes(), lastinfo.tobytes())
        if not last:
            get_state(m, d, saved, _STATE)
        rows: list[list[float]] = []
        contact, ok = 0.0, True
        d_ctrl = self._views[0]
        for i in range(n):
            tau = torque(qpos[q_at], qvel[qd_at], (i + 1) / n)
            d_ctrl[:] = CLIP(tau, -limit, limit)
            if i == last and i:
                get_state(m, d, saved, _STATE)
            step(m, d)
            if not qvel.dot(qvel) <= _MAX_SPEED_SQ:
                ok = False
                break
            if both:
                rows.append(sd[f0 : f0 + 6].tolist())
            else:
                rows.append(sd[f0 : f0 + 3].tolist() + sd[t0 : t0 + 3].tolist())
            contact += float(normal @ sd[c0 : c0 + 3])
        if ok and warn.tobytes() == before and _isfinite(qpos.dot(qpos)):
            if _isfinite(saved.dot(saved)):  # _simulate's last save (an overflow skips it)
                self._safe_state, self._pass_state = saved, self._safe_state
            self.sensor.advance_many(rows)
            return False, contact
        mujoco.mj_setState(m, d, start, _UNDO_STATE)
        number[:] = np.frombuffer(warnings_before[0], dtype=number.dtype)
        lastinfo[:] = np.frombuffer(warnings_before[1], dtype=lastinfo.dtype)
        return self._motion_period_simulate()

    def _motion_period_simulate(self) -> tuple[bool, float]:
        """:meth:`_motion_period` through _simulate, one physics step per call.

        The period's true wrenches are fed to the sensor model in one call after the loop
        (nothing in the loop reads the sensor or draws from its generator: the same rows in
        the same order, the same noise stream); the joint state goes to the motion controller
        as views of MuJoCo's arrays (read before the step)."""
        d, n = self.data, self._substeps
        _, qpos, qvel = self._data_views()
        sd = d.sensordata
        f0, t0, c0 = self._sensor_adr[0], self._sensor_adr[3], self._contact_adr
        both = t0 == f0 + 3  # force and torque side by side: one slice
        torque, limit = self.interface.torque, self.torque_limit
        q_at, qd_at, normal = self._q_at, self._qd_at, self._normal
        rows: list[list[float]] = []
        contact = 0.0
        skip, self.frame_skip = self.frame_skip, 1
        try:
            for i in range(n):
                tau = torque(qpos[q_at], qvel[qd_at], (i + 1) / n)
                if self._simulate(CLIP(tau, -limit, limit)):
                    return True, contact
                if both:
                    rows.append(sd[f0 : f0 + 6].tolist())
                else:
                    rows.append(sd[f0 : f0 + 3].tolist() + sd[t0 : t0 + 3].tolist())
                contact += float(normal @ sd[c0 : c0 + 3])
        finally:
            self.frame_skip = skip
            self.sensor.advance_many(rows)
        return False, contact

    # ------------------------------------------------------------------ measurements
    def normal_force(self) -> float:
        """True normal force (N): the load in the surface's spring and damper, k x + c ẋ.

        What a load cell under the plate reads; it equals the tool's contact force at rest and
        differs from it by the plate's inertial force (0.2 kg). MuJoCo's per-step contact force
        itself is not smooth: with a contact as stiff as this one the tip and the light plate
        exchange the load in bounces of one physics step (worst at a 1-ms step, see
        :data:`TIMESTEP`).
        """
        m, d = self.model, self.data
        x = -d.qpos[self._slide_qpos]  # compression (m)
        return float(
            m.jnt_stiffness[self._slide_jnt] * x
            - m.dof_damping[self._slide_dof] * d.qvel[self._slide_dof]
        )

    def contact_normal_force(self) -> float:
        """The tool-plate contact force along the true inward normal (N), this physics step."""
        return float(-self._normal @ surface_force(self.model, self.data, self._plate_geom))

    def plate_deflection(self) -> float:
        """Compression of the surface's spring (m, positive when pressed)."""
        return float(-self.data.qpos[self._slide_qpos])

    def _path_error_vector(self) -> np.ndarray:
        k = min(self._k, self.max_steps)
        e = self._pos_ref[k] - self.data.site_xpos[self._site]
        return e - (e @ SURFACE_NORMAL) * SURFACE_NORMAL

    def episode_metrics(self) -> dict[str, float]:
        """Metrics of the episode so far (see ``metric_specs`` and the Metrics section)."""
        k = max(self._k, 1)
        end = self.max_steps if self._stopped_at is not None else k
        force = np.zeros(end)
        force[: self._k] = self._force[: self._k]  # steps not played: no contact (f = 0)
        touch = np.zeros(end, dtype=bool)
        touch[: self._k] = self._touch[: self._k]
        path = np.zeros(end)
        path[: self._k] = self._path[: self._k]
        if self._k < end:
            path[self._k :] = path[self._k - 1] if self._k else 0.0
        f_ref = self._f_ref
        played = self._force[: self._k]
        if self._first_contact is None:
            rms, loss, path_rms, overshoot = f_ref, 1.0, rms_of(path), 0.0
        else:
            start = min(self._first_contact + round(self.settle_time / self.dt), end - 1)
            window = force[start:end]
            rms = rms_of(window - f_ref)
            loss = 1.0 - mean_of(touch[start:end])
            path_rms = rms_of(path[start:end])
            overshoot = max(max_of(played[self._first_contact :]) - f_ref, 0.0)
        return {
            "force_rms_error": rms,
            "peak_overshoot": overshoot,
            "contact_loss": loss,
            "path_error": path_rms,
            "max_force": max_of(played) if played.size else 0.0,
        }

    def _obs(self) -> dict[str, np.ndarray]:
        """One new flat buffer in the layout of ``_bounds``, filled, clipped once, handed out
        as views (each step's arrays are new; nothing is shared with the env's state)."""
        m, d = self.model, self.data
        _, qpos, qvel = self._data_views()
        pos, xmat = self._tcp_views
        k = min(self._k, self.max_steps)
        vel = self._vel_buf
        mujoco.mj_objectVelocity(m, d, _SITE_OBJ, self._site, vel, 0)
        buf = np.empty(self._obs_size)
        sl = self._obs_slices  # q, qd, tool_pos, tool_quat, tool_vel, tool_angvel, wrench,
        # f_ref, tool_pos_ref, tool_vel_ref, setpoint_pos, setpoint_quat
        buf[sl[0]] = qpos[self._q_at]
        buf[sl[1]] = qvel[self._qd_at]
        buf[sl[2]] = pos
        quat = buf[sl[3]]
        mujoco.mju_mat2Quat(quat, xmat)
        if not quat[0] >= 0:  # _quat: w ≥ 0
            np.negative(quat, out=quat)
        buf[sl[4]] = vel[3:]
        buf[sl[5]] = vel[:3]
        buf[sl[6]] = self.sensor.reading
        buf[self._refs_at] = self._ref_rows[k]  # f_ref, tool_pos_ref, tool_vel_ref
        if self.interface is not None:
            sp, sR = self.interface.setpoint_pose()
            buf[sl[10]] = sp
            buf[sl[11]] = _quat(sR)
        else:
            buf[self._setpoint_at] = buf[self._pose_at]
        CLIP(buf, self._obs_low, self._obs_high, out=buf)
        return {key: buf[s] for key, s in self._obs_items}

    def measured_contact_wrench(self) -> np.ndarray:
        """The sensor's reading compensated with the true bias and tool weight (world, (6,))."""
        R = self.data.site_xmat[self._ft_site].reshape(3, 3)
        return contact_wrench(
            self.sensor.reading, R, tool_mass=TOOL_MASS, tool_com=TOOL_COM, bias=self.sensor.bias
        )

    # ------------------------------------------------------------------ controllers
    def controller_context(self) -> TaskContext:
        spec = self.sensor_spec
        return TaskContext(
            robot=self.robot_name,
            dt=self.dt,
            action_kind="joint_torque" if self.control == "torque" else "cartesian_increment",
            action_scale=(
                self.torque_limit.copy()
                if self.control == "torque"
                else self.increment_scale.copy()
            ),
            site=SITE,
            extras={
                "tool_mass": TOOL_MASS,
                "tool_com": TOOL_COM.copy(),
                "surface_point": SURFACE_POINT.copy(),
                "surface_normal": SURFACE_NORMAL.copy(),
                "tool_quat": TOOL_QUAT.copy(),
                # the surface's stiffness as far as a controller knows it: None when drawn
                "stiffness": None if self.randomize else self.stiffness,
                "stiffness_range": STIFFNESS_RANGE,
                "force_limit": self.force_limit,
                "sensor_period": self.sensor.sample_period,
                "sensor_cutoff": spec.cutoff,
                "sensor_delay": spec.delay,
                "physics_timestep": float(self.model.opt.timestep),
            },
        )

    # ------------------------------------------------------------------ pictures
    def draw_task(self, scene: mujoco.MjvScene) -> None:
        """The wiping path, the reference force (blue) and the measured force (red) at the tip."""
        k = min(self._k, self.max_steps)
        rendering.add_polyline(
            scene, self._pos_ref[:: max(1, len(self._pos_ref) // 120)], 0.003, rendering.REFERENCE
        )
        tip = self.data.site_xpos[self._site]
        scale = 0.005  # m per N; arrows end at the tip, pushing on the surface
        rendering.add_sphere(scene, self._pos_ref[k], 0.008, rendering.TARGET)
        side = np.array([0.0, 0.05, 0.0])
        if self._f_ref > 0:  # reference force (blue), beside the measured one
            f_ref = -self._f_ref * scale * SURFACE_NORMAL
            rendering.add_arrow(scene, tip - f_ref + side[[1, 0, 2]], f_ref, 0.006, rendering.BLUE)
        f = self.measured_contact_wrench()[:3] * scale  # measured (red): the sensor, compensated
        if np.linalg.norm(f) > 0.2 * scale:
            rendering.add_arrow(scene, tip - f - side, f, 0.006, rendering.RED)

    def caption(self) -> str:
        k = min(self._k, self.max_steps)
        f = self._force[k - 1] if k > 0 else 0.0
        return f"t {k * self.dt:5.2f} s  f {f:5.1f} N  f_ref {self._f_ref:4.1f} N"
