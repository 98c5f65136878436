"""AdmittanceContact: press on a compliant surface with a reference force while wiping (chapter 6)."""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces

from cir_gym.context import TaskContext
from cir_gym.envs import admittance_scene as scene
from cir_gym.envs.admittance_scene import (
    JOINTS,
    RANDOM_RANGES,
    SITE,
    START_Q,
    STIFFNESS_RANGE,
    SURFACE_NORMAL,
    SURFACE_POINT,
    TIMESTEP,
    TOOL_COM,
    TOOL_MASS,
    TOOL_QUAT,
    build_model,
    tool_robot,
)
from cir_gym.envs.admittance_task import (
    CONTACT_THRESHOLD,
    REWARD_TERMS,
    AdmittanceReward,
    episode_metrics,
    period_forces,
)
from cir_gym.envs.base import MIN_CONTROL_FREQ, RobotEnv
from cir_gym.envs.base import frame_skip as physics_steps
from cir_gym.ft_sensor import WrenchSensor, contact_wrench, tool_gravity_wrench
from cir_gym.metrics import MetricSpec
from cir_gym.motion_interface import CartesianMotionInterface
from cir_gym.numeric import CLIP
from cir_gym.robot import Robot
from cir_gym.validation import InvalidArgument, check_number

__all__ = [
    "JOINTS",
    "RANDOM_RANGES",
    "START_Q",
    "TOOL_COM",
    "TOOL_MASS",
    "AdmittanceContactEnv",
    "build_model",
    "tool_robot",
]

#: position interface: action 1 = this speed (m/s for δp, rad/s for δφ) over one period
MAX_SPEED = np.array([0.25, 0.25, 0.25, 1.0, 1.0, 1.0])
CONTROLS = ("torque", "position")
#: observation keys: (size, bound); every array is float64 and clipped to ±bound (f_ref ≥ 0)
OBSERVATION = {
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


class AdmittanceContactEnv(RobotEnv):
    """Press a tool on a compliant surface with a reference normal force while wiping a path.

    ## Description
    Chapter 6's interaction-control problem. The KUKA iiwa 14 carries a 0.3 kg tool with a
    hemispherical tip behind a wrist force/torque sensor. Below it, a 0.2-kg plate on a prismatic
    joint with a real spring and damper (``stiffness`` N/m, ``damping`` N s/m: the surface's
    stiffness and damping in SI units, which MuJoCo's mass-normalised ``solref`` cannot give)
    and a stiff end stop 12 cm down. The tool-plate contact is stiff (< 10 µm at 20 N) with
    Coulomb friction μ = 0.1; the arm's links collide with the plate too (scene, contact
    parameters and why: :mod:`cir_gym.envs.admittance_scene`). At 1e5 N/m the plate's mode is
    at √(k/m)/2π ≈ 110 Hz (ζ = 0.07 at the default damping). Physics step 0.25 ms.
    The tool starts 3 cm above the *nominal* surface (the plane z = 0.20 m, normal +z); the
    true surface is off by a height and a tilt drawn per episode (U(±``height_error``) m,
    U(±``tilt_error``) rad about a random horizontal axis), known to the controllers only
    nominally. The controller must approach, make contact, press with the reference normal force
    f̄ (``force_ref`` N, drawn from U(5, 30) per episode when None) and follow a wiping path on the
    surface: from t = 2 s the tip's reference moves by 5 cm · sin(2π · 0.25 Hz · (t − 2)) along
    a random horizontal direction (peak 0.079 m/s), on the nominal surface.

    Contact forces are read at every physics step. The normal force f (N,
    ``info["contact_force"]``, never observed) is the tool's: its contact force on the plate
    along the true normal, averaged over the control period. ``info["in_contact"]``: the tool
    pressed (> 0.5 N) at every physics step of the period (``info["contact_steps"]``: the
    fraction it did); ``info["peak_contact_force"]``: the largest single contact force ‖f_i‖
    (normal and friction) on the plate (the tool's or a link's) in the period;
    ``info["plate_load"]``: k x + c ẋ, what a load cell under the plate reads. The controllers
    measure the wrench through the sensor model (:mod:`cir_gym.ft_sensor`: the tool's weight,
    bias, noise, quantisation, low-pass filter, delay, zero-order-hold sampling; presets
    ``"robotiq_ft300"``, ``"ati_gamma"``, ``"ideal"``), one physics step late (MuJoCo computes
    sensors before it integrates). With ``randomize=True`` each reset draws the stiffness
    (log-uniform in [1e3, 1e5] N/m), the damping (U(5, 50) N s/m) and the sensor bias (U(±2) N,
    U(±0.1) N m per axis) and ignores ``stiffness``, ``damping`` and ``sensor_bias``; the draw
    is in ``info["surface"]`` of ``reset``.

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
      [−1, 0];
    - r_path = −``path_weight`` (1 − exp(−‖e_t‖² / ``path_scale``²)), e_t the tip's path error
      in the nominal surface's plane;
    - r_action_rate = −``action_rate_weight`` ‖a_k − a_{k−1}‖² / dim(a);
    - r_force_limit = −``force_limit_penalty`` on the step the force limit stops the episode;
    - r_diverged = −``divergence_penalty`` on the step the physics diverged.

    With ``charge_unplayed_steps=True`` (the default) a stopped or diverged episode also loses,
    on its last step, the worst reward of every step it did not play, (T − k)(1 +
    ``path_weight`` + 4 ``action_rate_weight``) (T the episode's steps, k the steps played; in
    its r_force_limit or r_diverged): ending early never raises the return, at any discount
    γ ≤ 1, as the metrics score a stopped episode over the whole horizon.

    ## Starting State
    At rest at ``START_Q`` (tip 3 cm above the nominal surface, tool pointing down), the sensor
    in steady state (filter and delay line at the static reading).

    ## Episode End
    Truncated after ``episode_duration`` s. Terminated when the physics diverges
    (``info["diverged"]``; that control period counts as not played: no contact) or, at any
    physics step, a single contact force ‖f_i‖ on the plate (the tool's or a link's) or the
    plate's load exceeds ``force_limit`` (a failure, ``info["force_limit_exceeded"]``).
    ``step`` after the end or before ``reset`` raises.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | control | "torque" | "torque" (joint torques) or "position" (Cartesian setpoint increments) |
    | control_freq | 500.0 | control frequency (Hz), the physics rate divided by an integer |
    | episode_duration | 5.0 | s |
    | timestep | 0.00025 | physics step (s), in [1e-4, 1e-3] |
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
    | force_limit | 100.0 | contact force (N) that ends the episode as a failure |
    | settle_time | 0.5 | s after the first contact before the force error is scored |
    | force_scale | 10.0 | force reward kernel width (N), in [1e-3, 1e3] |
    | path_scale | 0.01 | path reward kernel width (m), in [1e-6, 10] |
    | path_weight | 0.5 | weight of the path term |
    | action_rate_weight | 0.01 | weight of the action-rate term |
    | force_limit_penalty | 50.0 | reward lost when the force limit ends the episode |
    | divergence_penalty | 100.0 | reward lost when the physics diverges |
    | charge_unplayed_steps | True | a stopped or diverged episode also loses the worst reward of each unplayed step (see Rewards) |
    | success_threshold | 1.0 | normal-force RMS error (N) below which an episode succeeds |
    | render_mode | None | None, "human" or "rgb_array" |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    Over the scoring window, from ``settle_time`` after the first contact to the end of the
    horizon: ``force_rms_error`` (primary, N; f̄ if the tool never touched), ``contact_loss``
    (the fraction of the window's *physics steps* in which the tool's normal contact force is
    below 0.5 N; 1 if never touched), ``path_error`` (m, RMS of e_t). Over the episode:
    ``peak_overshoot`` (N, max(f − f̄, 0) after the first contact) and ``max_force`` (N, the
    largest single contact force on the plate at any physics step, max_i ‖f_i‖ of the
    contacts' whole forces f_i, normal and friction: what the force limit tests). A stopped
    episode is scored over the whole horizon, its unplayed steps with f = 0 and no contact.
    Success: no divergence, no force-limit stop, ``force_rms_error`` < ``success_threshold``
    and ``contact_loss`` < 0.01.

    ## Reference controllers
    ``baselines.available("cir_gym/AdmittanceContact-v2")``: impedance, admittance,
    explicit_force, implicit_force, parallel_force_position (:mod:`cir_gym.baselines.interaction`).

    ## Version History
    - v0: initial version. Changed before the issue closed (no v1): the physics step 1 ms →
      0.25 ms (``timestep``) and a stop's cost includes the rest of the horizon; the shipped
      agents were retrained on this version.
    - v1: the force, contact and contact loss are the tool's, at every 0.25-ms physics step;
      the force limit and ``max_force`` on the largest single contact (tool or link) or the
      plate's load; a 12-cm plate end stop (the tool no longer tunnels through the plate);
      a tip–plate contact pair with an elliptic cone and a 100-ms friction time constant (the
      tip stays on the plate while wiping); ``charge_unplayed_steps`` on by default.
    - v2: ``max_force``, ``info["peak_contact_force"]`` and the force limit read the whole
      force ‖f_i‖ (normal and friction) of the largest single contact, as PegInHole-v2 (v1:
      that contact's normal force, below another contact's in 50 of 959 random multi-contact
      poses); ``max_force`` +0.1-0.5 % on the course controllers' episodes.
    """

    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec("force_rms_error", "N", "lower", "normal-force RMS error after settling"),
        MetricSpec("peak_overshoot", "N", "lower", "max normal force above f_ref after contact"),
        MetricSpec("contact_loss", "", "lower", "fraction of scored physics steps without contact"),
        MetricSpec("path_error", "m", "lower", "RMS path error in the surface plane"),
        MetricSpec("max_force", "N", "lower", "largest single contact force, any physics step"),
    )
    primary_metric: ClassVar[str] = "force_rms_error"
    reward_arguments: ClassVar[frozenset[str]] = frozenset((
        "force_scale", "path_scale", "path_weight", "action_rate_weight",
        "force_limit_penalty", "divergence_penalty", "charge_unplayed_steps",
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
        charge_unplayed_steps: bool = True,
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
        flags = (("randomize", randomize), ("charge_unplayed_steps", charge_unplayed_steps))
        for name, flag in flags:
            if not isinstance(flag, (bool, np.bool_)):
                raise InvalidArgument(f"{name} must be True or False, got {flag!r}")
        self.randomize = bool(randomize)
        self.charge_unplayed_steps = bool(charge_unplayed_steps)
        self.sensor_spec = scene.wrist_sensor_spec(
            sensor,
            sensor_bias=sensor_bias,
            sensor_noise=sensor_noise,
            sensor_resolution=sensor_resolution,
            sensor_rate=sensor_rate,
            sensor_cutoff=sensor_cutoff,
            sensor_delay=sensor_delay,
        )
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
        control_freq = check_number(
            "control_freq", control_freq, MIN_CONTROL_FREQ, 1.0 / self.timestep
        )
        # a whole number of physics steps per period (else a clear error), each one recorded
        model = build_model(
            self.stiffness, self.damping, self.timestep, physics_steps(control_freq, self.timestep)
        )
        super().__init__(
            model,
            control_freq=control_freq,
            episode_duration=episode_duration,
            render_mode=render_mode,
            width=width,
            height=height,
        )
        # a control period is `substeps` = frame_skip physics steps: one physics call at the
        # torque interface's held torque, one per physics step for the position interface's
        # motion controller; MuJoCo's sensor history keeps every step's contact forces
        self.substeps = self.frame_skip
        self.robot = Robot(model, JOINTS)  # the simulator's arm
        self.n = self.robot.n
        self._qa, self._da = self.robot.qpos_adr, self.robot.dof_adr
        self.torque_limit = self.robot.torque_limit.copy()
        self._site = self.robot.site_id(SITE)
        self._ft_site = self.robot.site_id("ft_site")
        self._tool_body = int(model.site_bodyid[self._site])  # the tcp's frame is this body's
        self._plate_geom = model.geom("surface_geom").id
        self._mount = model.body("surface_mount").id
        self._mount_pos0 = model.body_pos[self._mount].copy()
        slide = model.joint("surface_slide")
        self._slide_jnt, self._slide_dof = slide.id, int(model.jnt_dofadr[slide.id])
        self._slide_qpos = int(model.jnt_qposadr[slide.id])
        adr = {s: int(model.sensor_adr[model.sensor(s).id]) for s in scene.RECORDED_SENSORS}
        self._wrench_at = np.r_[adr["ft_force"] : adr["ft_force"] + 3,
                                adr["ft_torque"] : adr["ft_torque"] + 3]
        self._tool_at = slice(adr["tool_contact"], adr["tool_contact"] + 3)
        self._peak_at = slice(adr["peak_contact"], adr["peak_contact"] + 3)
        try:
            self.sensor = WrenchSensor(self.sensor_spec, model.opt.timestep)
        except InvalidArgument as exc:  # the only physics-dependent limit: the sample rate
            raise InvalidArgument(f"sensor_rate: {exc}") from exc
        self.interface = (
            CartesianMotionInterface(tool_robot(), SITE) if control == "position" else None
        )
        self.increment_scale = MAX_SPEED * self.dt
        dim = self.n if control == "torque" else 6
        self.reward_model = AdmittanceReward(
            self.force_scale, self.path_scale, self.path_weight, self.action_rate_weight,
            self.force_limit_penalty, self.divergence_penalty, self.charge_unplayed_steps,
            self.max_steps, dim,
        )
        self.action_space = spaces.Box(-1.0, 1.0, (dim,), dtype=np.float32)
        self.observation_space = spaces.Dict({
            key: spaces.Box(0.0 if key == "f_ref" else -bound, bound, (size,), dtype=np.float64)
            for key, (size, bound) in OBSERVATION.items()
        })
        #: key → (low, high) of the observation space, as its arrays
        self.observation_bounds = {
            key: (space.low, space.high) for key, space in self.observation_space.spaces.items()
        }
        steps = self.max_steps
        # the last control period, one entry per physics step
        self.period_record = scene.PeriodRecord(model)  # the period's sensordata, step by step
        self.tool_force_steps = np.zeros(self.substeps)  # tool's normal contact force (N)
        self.peak_force_steps = np.zeros(self.substeps)  # largest single contact force (N)
        # per control step of the episode
        self._force = np.zeros(steps)  # f: the tool's normal force, period mean (N)
        self._touch = np.zeros(steps)  # fraction of the period's physics steps in contact
        self._peak = np.zeros(steps)  # largest single contact force in the period (N)
        self._path = np.zeros(steps)  # tangential path error (m)
        self._pos_ref = np.zeros((steps + 1, 3))
        self._vel_ref = np.zeros((steps + 1, 3))
        self._k = 0
        self._ended = True  # no episode yet: step() needs reset()
        self._first_contact: int | None = None
        self._stopped_at: int | None = None
        self._a_prev = np.zeros(dim)
        self._f_ref = 0.0
        self._normal = SURFACE_NORMAL.copy()
        self._surface: dict[str, Any] = {}

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        s = scene.draw_surface(
            self.np_random,
            (self.stiffness, self.damping, np.array(self.sensor_spec.bias)),
            self.randomize,
            self.height_error,
            self.tilt_error,
            self.force_ref,
        )
        self._surface = s
        m = self.model
        m.jnt_stiffness[self._slide_jnt] = s["stiffness"]
        m.dof_damping[self._slide_dof] = s["damping"]
        m.body_pos[self._mount] = self._mount_pos0 + s["height_error"] * SURFACE_NORMAL
        m.body_quat[self._mount], R = scene.tilt_rotation(s["tilt_axis"], s["tilt"])
        self._normal = R @ SURFACE_NORMAL
        t = np.arange(self.max_steps + 1) * self.dt
        self._pos_ref, self._vel_ref = scene.wipe_reference(t, s["wipe_direction"])
        self._f_ref = s["force_ref"]
        qpos = self.model.qpos0.copy()
        qpos[self._qa] = START_Q
        self._reset_physics(qpos, np.zeros(self.model.nv))
        if self.interface is not None:
            self.interface.reset(START_Q)
        # the arm was held at rest: the sensor starts in steady state at the tool's weight
        R = self.data.site_xmat[self._ft_site].reshape(3, 3)
        self.sensor.reset(self.np_random, tool_gravity_wrench(TOOL_MASS, TOOL_COM, R),
                          s["sensor_bias"])
        self._k = 0
        self._ended = False
        self._first_contact = None
        self._stopped_at = None
        self._a_prev[:] = 0.0
        info = {"surface": {k: (v.copy() if isinstance(v, np.ndarray) else v)
                            for k, v in s.items()}}
        return self._obs(), info

    def _advance(self, a: np.ndarray) -> bool:
        """One control period; return True if the physics diverged.

        The torque interface holds τ = a ⊙ τ_max for the period (one ``_simulate`` of
        ``substeps`` physics steps); the position interface's motion controller computes τ at
        every physics step (clipped to τ_max; one ``_simulate`` per step). Then the period's
        sensordata, step by step from MuJoCo's sensor history (:class:`PeriodRecord`), feeds
        the wrist's true wrenches to the sensor model and the tool's normal contact force and
        the largest single contact force on the plate to ``tool_force_steps`` /
        ``peak_force_steps`` (:func:`period_forces`). A period in which the physics diverged
        is not played: the state goes back to the last finite one (RobotEnv._simulate) and
        its forces are 0."""
        d, n = self.data, self.substeps
        held = self.interface is None  # the torque interface: τ held for the whole period
        self.frame_skip = n if held else 1  # physics steps per RobotEnv._simulate call
        diverged = False
        try:
            for i in range(0, n, self.frame_skip):
                if held:
                    tau = a * self.torque_limit
                else:
                    tau = self.interface.torque(d.qpos[self._qa], d.qvel[self._da], (i + 1) / n)
                    tau = np.clip(tau, -self.torque_limit, self.torque_limit)
                diverged = self._simulate(tau)
                if diverged:
                    break
        finally:
            self.frame_skip = n
        record = self.period_record(d.history)
        if diverged:
            record[:] = 0.0
        else:
            self.sensor.advance_many(record[:, self._wrench_at])
        self.tool_force_steps, self.peak_force_steps = period_forces(
            record, self._normal, self._tool_at, self._peak_at
        )
        return diverged

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        if self._ended:
            raise RuntimeError(
                "step() called before reset() or after the episode ended; call reset()"
            )
        a = self._check_action(action)[0]
        if self.interface is not None:
            self.interface.command(a * self.increment_scale, self.dt)
        diverged = self._advance(a)
        # poses and velocities of the state reached, for the observation and the path error
        m, d = self.model, self.data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_camlight(m, d)
        mujoco.mj_comVel(m, d)
        k = self._k
        self._k = k + 1
        force = float(np.mean(self.tool_force_steps))
        touch = float(np.mean(self.tool_force_steps > CONTACT_THRESHOLD))
        peak = float(np.max(self.peak_force_steps))
        load = self.normal_force()
        e_t = self._path_error_vector()
        self._force[k], self._touch[k], self._peak[k] = force, touch, peak
        self._path[k] = float(np.linalg.norm(e_t))
        if self._first_contact is None and touch > 0.0:
            self._first_contact = k
        over = not diverged and max(peak, load) > self.force_limit
        err = force - self._f_ref
        terms = self.reward_model.terms(
            err, float(e_t @ e_t), float(np.sum((a - self._a_prev) ** 2)), over, diverged, self._k
        )
        r_force, r_path, r_rate, r_limit, r_div = (float(terms[t]) for t in REWARD_TERMS)
        self._a_prev[:] = a
        reward = r_force + r_path + r_rate + r_limit + r_div
        terminated = diverged or over
        truncated = self._k >= self.max_steps and not terminated
        if terminated:
            self._stopped_at = self._k
        self._ended = terminated or truncated
        info: dict[str, Any] = {
            "reward_force": r_force,
            "reward_path": r_path,
            "reward_action_rate": r_rate,
            "reward_force_limit": r_limit,
            "reward_diverged": r_div,
            "contact_force": force,
            "in_contact": touch == 1.0,
            "contact_steps": touch,
            "peak_contact_force": peak,
            "plate_load": load,
            "force_error": err,
            "path_error": self._path[k],
            "force_limit_exceeded": over,
            "diverged": diverged,
        }
        if self._ended:
            metrics = self.episode_metrics()
            info["episode_metrics"] = metrics
            info["is_success"] = self.succeeded(metrics, terminated)
        return self._obs(), reward, terminated, truncated, info

    def succeeded(self, metrics: dict[str, float], terminated: bool) -> bool:
        """Success of an ended episode with ``metrics`` (see Metrics): not stopped, the force
        RMS error below ``success_threshold`` and contact lost on < 1 % of the scored steps."""
        return bool(
            not terminated
            and metrics["force_rms_error"] < self.success_threshold
            and metrics["contact_loss"] < 0.01
        )

    def worst_step_reward(self) -> float:
        """The magnitude of the worst reward of one step: what ``charge_unplayed_steps``
        charges per unplayed step (:meth:`AdmittanceReward.worst_step`)."""
        return self.reward_model.worst_step()

    # ------------------------------------------------------------------ measurements
    def normal_force(self) -> float:
        """The load in the plate's spring and damper, k x + c ẋ (N): what a load cell under the
        plate reads. It equals the tool's contact force at rest when only the tool touches,
        and differs from it by the plate's inertial force (0.2 kg)."""
        m, d = self.model, self.data
        x = -d.qpos[self._slide_qpos]  # compression (m)
        return float(
            m.jnt_stiffness[self._slide_jnt] * x
            - m.dof_damping[self._slide_dof] * d.qvel[self._slide_dof]
        )

    def plate_deflection(self) -> float:
        """Compression of the surface's spring (m, positive when pressed)."""
        return float(-self.data.qpos[self._slide_qpos])

    def _path_error_vector(self) -> np.ndarray:
        e = self._pos_ref[min(self._k, self.max_steps)] - self.data.site_xpos[self._site]
        return e - (e @ SURFACE_NORMAL) * SURFACE_NORMAL

    def episode_metrics(self) -> dict[str, float]:
        """Metrics of the episode so far (see ``metric_specs`` and the Metrics section)."""
        return episode_metrics(
            self._force, self._touch, self._peak, self._path, self._k,
            self._stopped_at is not None, self._first_contact, self._f_ref,
            round(self.settle_time / self.dt), self.max_steps,
        )

    def _obs(self) -> dict[str, np.ndarray]:
        m, d = self.model, self.data
        k = min(self._k, self.max_steps)
        vel = np.zeros(6)  # [ω; v] of the tcp, world frame
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, self._site, vel, 0)
        tool_pos = d.site_xpos[self._site].copy()
        tool_quat = scene.positive_w(d.xquat[self._tool_body])  # the tcp is aligned with it
        if self.interface is not None:
            setpoint_pos, setpoint_R = self.interface.setpoint_pose()
            setpoint_quat = scene.quat_of(setpoint_R)
        else:
            setpoint_pos, setpoint_quat = tool_pos, tool_quat
        obs = {
            "q": d.qpos[self._qa],
            "qd": d.qvel[self._da],
            "tool_pos": tool_pos,
            "tool_quat": tool_quat,
            "tool_vel": vel[3:],
            "tool_angvel": vel[:3],
            "wrench": self.sensor.reading,
            "f_ref": np.array([self._f_ref]),
            "tool_pos_ref": self._pos_ref[k],
            "tool_vel_ref": self._vel_ref[k],
            "setpoint_pos": setpoint_pos,
            "setpoint_quat": setpoint_quat,
        }
        return {key: CLIP(value, *self.observation_bounds[key]) for key, value in obs.items()}

    def measured_contact_wrench(self) -> np.ndarray:
        """The sensor's reading compensated with the true bias and tool weight (world, (6,))."""
        R = self.data.site_xmat[self._ft_site].reshape(3, 3)
        return contact_wrench(
            self.sensor.reading, R, tool_mass=TOOL_MASS, tool_com=TOOL_COM, bias=self.sensor.bias
        )

    # ------------------------------------------------------------------ controllers
    def controller_context(self) -> TaskContext:
        spec = self.sensor_spec
        torque = self.control == "torque"
        return TaskContext(
            robot=self.robot_name,
            dt=self.dt,
            action_kind="joint_torque" if torque else "cartesian_increment",
            action_scale=self.torque_limit.copy() if torque else self.increment_scale.copy(),
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
    def draw_task(self, mjv_scene: mujoco.MjvScene) -> None:
        """The wiping path, the reference force (blue) and the measured force (red) at the tip."""
        k = min(self._k, self.max_steps)
        scene.draw(
            mjv_scene,
            self._pos_ref,
            self._pos_ref[k],
            self.data.site_xpos[self._site],
            self._f_ref,
            self.measured_contact_wrench()[:3],
        )

    def caption(self) -> str:
        k = min(self._k, self.max_steps)
        f = self._force[k - 1] if k > 0 else 0.0
        return f"t {k * self.dt:5.2f} s  f {f:5.1f} N  f_ref {self._f_ref:4.1f} N"
