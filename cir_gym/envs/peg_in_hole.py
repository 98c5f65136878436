"""PegInHole: insert a cylindrical peg into a round hole whose pose is known only approximately
(chapter 6: hybrid force/position control with a selection matrix)."""

from __future__ import annotations

import sys
from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces

from cir_gym import peg_hole_geometry as geo
from cir_gym import trajectories as traj
from cir_gym.context import TaskContext
from cir_gym.envs.base import MIN_CONTROL_FREQ, RobotEnv, frame_skip
from cir_gym.envs.peg_in_hole_contacts import ContactFlags, ContactSensors, contact_flags
from cir_gym.envs.peg_in_hole_scene import ALIGNED, draw_task, start_posture
from cir_gym.ft_sensor import PRESETS, WrenchSensor, sensor_spec, tool_gravity_wrench
from cir_gym.metrics import MetricSpec
from cir_gym.motion_interface import CartesianMotionInterface
from cir_gym.numeric import CLIP
from cir_gym.robot import Robot
from cir_gym.validation import InvalidArgument, check_number

__all__ = ["ALIGNED", "CONTROLS", "PegInHoleEnv", "tip_twist"]

_INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)

CONTROLS = ("torque", "position")
#: Position interface: largest setpoint speed (m/s) and angular speed (rad/s); an action of 1 moves
#: the setpoint by this times the control period.
MAX_SPEED = 0.05
MAX_ANGULAR_SPEED = 0.5
TOOL_COM = np.array(geo.PEG_COM)  # in the sensor frame
GOAL_SCALE = 0.05  # m: distance at which the distance reward saturates at −1
#: m: how far below the bore's bottom the tip may read (contact penetration, < 20 µm at 100 N)
#: and still count as in the bore
BOTTOM_TOLERANCE = 5e-4
#: m: the tip counts as gone into the block's top face when it is this far below the face's
#: plane (contact penetration of a peg resting on the face is µm; a square peg's tip can go
#: this deep only through the opening)
ENTRY_DEPTH = 5e-4


_NEXT, _PREV = np.array([1, 2, 0]), np.array([2, 0, 1])  # (a × b)_i = a_{i+1} b_{i+2} − a_{i+2} b_{i+1}


def tip_twist(
    cdof: np.ndarray, qvel: np.ndarray, tip: np.ndarray, origin: np.ndarray
) -> np.ndarray:
    """The tip's velocity [v; ω] (..., 6), world frame (m/s, rad/s), from MuJoCo's motion
    axes ``cdof`` (..., nv, 6) (ω part first, linear part at ``origin``, the arm's subtree
    centre of mass (..., 3)), the joint speeds ``qvel`` (..., nv) and the tip's position
    ``tip`` (..., 3): J q̇ as ``mj_jacSite`` builds J (every dof moves the tip: a serial arm),
    ω = Σ_j c_ω,j q̇_j, v = Σ_j c_v,j q̇_j + ω × (p_tip − origin)."""
    c = (qvel[..., None, :] @ cdof)[..., 0, :]  # Σ_j c_j q̇_j: [ω; v at the origin]
    w, r = c[..., :3], tip - origin
    w_x_r = w[..., _NEXT] * r[..., _PREV] - w[..., _PREV] * r[..., _NEXT]  # ω × r
    return np.concatenate((c[..., 3:] + w_x_r, w), axis=-1)


class PegInHoleEnv(RobotEnv):
    """Insert a peg held by the KUKA iiwa 14 into a hole whose pose is known only approximately.

    ## Description
    The iiwa holds a cylindrical steel peg (10 mm diameter, 60 mm long, 0.1 kg) rigidly behind a
    wrist force/torque sensor, its tip ``start_height`` above the *nominal* hole: a round bore
    (25 mm deep) in a block, with a diametral ``clearance`` and an optional 45° ``chamfer``.
    Each episode draws the *true* hole pose around the nominal one: a lateral offset uniform
    in a disc of radius ``position_uncertainty`` and a tilt of the bore axis uniform in
    [0, ``tilt_uncertainty``] degrees about a random horizontal axis. The controllers know
    only the nominal pose (in the observation) and must find the hole with the sensed wrench:
    the natural constraints of the bore (no lateral motion, no tilting) against the artificial
    ones of the task (zero lateral force and tilting moment, motion along the axis) — the
    selection matrix of hybrid force/position control (chapter 6).

    Contact physics (the scene is built by :mod:`cir_gym.peg_hole_geometry`, which justifies
    every number): the bore is a ring of 64 overlapping boxes (a mesh would collide as its
    convex hull, a solid plug), physics step 0.5 ms, solref (1 ms, 1), solimp (0.99, 0.999,
    0.1 mm), elliptic cones with impratio 10, Newton solver, margin 0, friction 0.3, libccd's
    convex collision. The peg, its holder and every link of the arm collide with the block
    (the arm's links not with each other, nothing with the floor). Measured
    (tests/test_peg_in_hole.py): steady-contact penetration below a fifth of the clearance at
    the smallest clearance (0.1 mm) under 100 N, no tunnelling at 0.5 m/s, a centred peg
    slides to the bottom without touching the walls.

    The arm is driven by joint torques (never a mocap body: it would teleport into contacts),
    by the agent (``control="torque"``) or by the robot's motion controller
    (``control="position"``). The wrist sensor (:mod:`cir_gym.ft_sensor`, preset ``sensor``)
    reads the interaction between the flange and the tool, the peg's weight included, in the
    sensor frame ``ft_site`` (z along the peg, pointing into the hole when aligned), filtered,
    delayed, sampled, noisy and quantised as the preset says.

    The true contact forces are never observed. Every physics step, the contacts between the
    robot (peg, holder, links) and the block are measured by MuJoCo's contact sensors
    (:mod:`cir_gym.envs.peg_in_hole_contacts`): ``info["contact_force"]`` is the largest single
    contact force of the control period (what damages a part: opposing wall contacts do not
    cancel in it) and ``info["net_contact_force"]`` the largest net force (their vector sum,
    what the wrist feels).

    Batched: :class:`cir_gym.envs.peg_in_hole_vector.PegInHoleVectorEnv` steps N copies of
    this env on one ``mujoco.batch.Batch``, each copy equal to this env (both interfaces).

    ## Action Space
    - ``control="torque"``: ``Box(-1, 1, (7,), float32)``: τ = a ⊙ τ_max with τ_max = (320, 320,
      176, 176, 110, 40, 40) N m; gravity is not compensated by the env.
    - ``control="position"``: ``Box(-1, 1, (6,), float32)``: a Cartesian setpoint increment of
      the peg tip per control period, [δp; δφ] = a ⊙ (0.05 m/s, 0.05, 0.05, 0.5 rad/s, 0.5,
      0.5) × Δt in the nominal hole frame (δφ a rotation vector), executed by the robot's own
      stiff motion controller (:class:`cir_gym.motion_interface.CartesianMotionInterface`:
      differential IK of the setpoint, joint-space inverse dynamics at ω_n = 150 rad/s every
      physics step, −3 dB bandwidth ≈ 50 Hz; the interface of an industrial robot).

    Finite values outside [-1, 1] are clipped; NaN/inf or a wrong shape raise ``ValueError``.

    ## Observation Space
    ``Dict`` of float64 arrays (values clipped to the bounds):

    | key | shape | meaning | bounds | unit |
    |---|---|---|---|---|
    | q | 7 | joint positions | ±2π | rad |
    | qd | 7 | joint velocities | ±50 | rad/s |
    | peg_pos | 3 | peg tip position in the nominal hole frame | ±2 | m |
    | peg_quat | 4 | peg orientation relative to aligned with the nominal bore (w first, w ≥ 0; aligned = (1, 0, 0, 0)) | ±1 | |
    | peg_twist | 6 | tip velocity v, ω in the nominal hole frame | ±10, ±50 | m/s, rad/s |
    | wrench | 6 | sensed force, torque on the tool, sensor frame | ±1000, ±100 | N, N m |
    | hole_pos | 3 | nominal hole position (top centre) in the world | ±2 | m |
    | hole_quat | 4 | nominal hole orientation in the world (z out of the hole) | ±1 | |

    The nominal hole frame has its origin at the centre of the hole's top opening and its z
    axis along the bore, pointing out of the hole.

    ## Rewards
    r = r_distance + r_force + r_success + r_force_limit + r_diverged, each in
    ``info["reward_<name>"]``:
    - r_distance = −min(‖p_tip − p_goal‖ / 0.05 m, 1), p_goal the point on the true axis at
      ``success_depth`` × depth;
    - r_force = −``force_weight`` min(F / ``force_limit``, 10)², F the largest single contact
      force of the control period;
    - r_success = ``success_bonus`` on the step the peg is inserted (see Episode End);
    - r_force_limit = −``failure_penalty`` on the step F exceeds ``force_limit``;
    - r_diverged = −``divergence_penalty`` on the step the physics diverged.

    An episode that ends as a failure (force limit or divergence) also loses, on its last
    step, the worst reward of every step it did not play without ending, (T − k)(1 +
    ``force_weight``) (T the episode's steps, k the steps played; r_distance = −1 and r_force
    at the force limit): failing early never raises the return, at any discount γ ≤ 1
    (``charge_unplayed_steps``; False: no such charge).

    ## Starting State
    At rest, the peg tip ``start_height`` above the nominal hole on its axis, aligned with it,
    in the posture closest to the robot file's home (null-space Newton iterations).

    ## Episode End
    Terminated with success when the peg is inserted (``info["is_success"]``): its tip in the
    true bore, at a depth between the goal (``success_depth`` × 25 mm) and the bottom (plus
    0.5 mm for contact penetration), radially within the bore's radius, having entered through
    the top opening (the tip went 0.5 mm below the top face's plane within the opening's
    radius, chamfer included, and has not come back above that since). Terminated as a failure when any single
    robot–block contact force exceeds ``force_limit`` at a physics step (the period stops
    there, ``info["force_limit_exceeded"]``) or when the physics diverges
    (``info["diverged"]``, the last finite state kept); truncated after ``episode_duration``.

    ``info`` also flags the contact state each step, in the true hole frame:
    - ``two_point_contact``: contacts on the bore's side (normal within 45° of horizontal) on
      opposite sides (lateral normals with a negative dot product below −0.5);
    - ``wedged``: two-point contact at an insertion depth ℓ < μ D (μ = 0.3, D the hole
      diameter), Whitney's geometric wedging condition (Whitney 1982, "Quasi-static assembly of
      compliantly supported rigid parts"): the two contact forces can then point at each other
      inside their friction cones and hold the peg whatever force is applied;
    - ``jammed``: two-point contact deeper than μ D while the peg does not advance (axial
      speed < 1 mm/s): the applied force and moment are outside Whitney's jamming diagram
      (the wall friction balances the push). We detect the outcome (stalled in two-point
      contact) rather than the force-ratio diagram, which needs the applied wrench at the
      tip that the env does not see.

    Not detected: whether the two contact forces of a shallow two-point contact actually lie in
    their friction cones (a wedged peg may still come free when pulled back) and the jamming
    diagram's force/moment ratios. tests/test_peg_in_hole.py puts the arm in constructed
    two-point contacts (a peg tilted so that its leading edge touches one wall and its side
    the opposite rim): at rest 2 and 3 mm deep it is wedged, 4 and 10 mm deep jammed, sliding
    in at 5 mm/s neither, and with one of the two contacts lifted by 20 µm none of the flags.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | control | "torque" | "torque" (joint torques) or "position" (Cartesian setpoint increments) |
    | sensor | "ati_gamma" | wrist F/T sensor preset: "ati_gamma", "robotiq_ft300" or "ideal" |
    | clearance | 0.0005 | diametral clearance, hole − peg diameter (m, in [1e-4, 2e-3]) |
    | chamfer | 0.0 | 45° chamfer width at the hole's edge (m, in [0, 3e-3]) |
    | position_uncertainty | 0.002 | radius of the disc the true hole position is drawn in (m, ≤ 0.01) |
    | tilt_uncertainty | 2.0 | largest tilt of the true bore axis (degrees, ≤ 10) |
    | force_limit | 100.0 | largest single contact force that ends the episode as a failure (N) |
    | start_height | 0.01 | initial tip height above the nominal hole (m, in [0.002, 0.1]) |
    | success_depth | 0.9 | insertion depth counted as success, fraction of the 25 mm bore |
    | control_freq | 500.0 | control frequency (Hz); the physics step is 0.5 ms |
    | episode_duration | 12.0 | s (a spiral search on the sharp-edged hole takes up to ~8 s) |
    | force_weight | 1.0 | weight of the force term |
    | success_bonus | 100.0 | reward on success |
    | failure_penalty | 100.0 | reward lost when the force limit is exceeded |
    | divergence_penalty | 100.0 | reward lost when the physics diverges |
    | charge_unplayed_steps | True | a failed episode also loses the worst reward of each unplayed step (see Rewards) |
    | render_mode | None | None, "human" or "rgb_array" |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    At physics-step resolution: ``insertion_time`` (primary, s; the time limit when not
    inserted), ``peak_force`` (N, the largest single robot–block contact force),
    ``peak_net_force`` (N, the largest net contact force on the robot), ``mean_force`` (N, the
    net force's mean over the episode), ``force_impulse`` (∫|F_net| dt, N s), ``jammed_time``
    (s with the ``jammed`` flag), ``final_depth`` (m, tip depth in the true hole at the end).
    Success: the peg inserted (see Episode End).

    ## Reference controllers
    ``baselines.available("cir_gym/PegInHole-v2")``: hybrid_force_position, hybrid_spiral,
    position_only (baselines/hybrid.py; position_only has no search and fails by
    construction whenever the hole is off by more than the clearance); AdmittanceContact's
    ``admittance`` law applies through the adapter ``baselines.hybrid.PegAdmittance`` (axial
    force regulation only).

    ## Version History
    - v2: the force limit, ``peak_force`` and ``info["contact_force"]`` read the
      largest single robot–block contact at every physics step (were the 2-ms average of the
      net force on the peg); new metrics ``peak_net_force`` and ``jammed_time``; success needs
      the tip inside the bore (depth bounded by the bottom, entered through the top); the arm
      and the peg's holder collide with the block.
    - v1: ``charge_unplayed_steps`` on by default (v0's return favoured failing).
    - v0: initial version.
    """

    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec(
            "insertion_time",
            "s",
            "lower",
            "time to the goal depth in the bore (time limit if not)",
            failure_scores_limit=True,
        ),
        MetricSpec("peak_force", "N", "lower", "largest single robot-block contact force"),
        MetricSpec("peak_net_force", "N", "lower", "largest net contact force on the robot"),
        MetricSpec("mean_force", "N", "lower", "mean net contact force"),
        MetricSpec("force_impulse", "N s", "lower", "integral of the net contact force"),
        MetricSpec("jammed_time", "s", "lower", "time jammed in two-point contact"),
        MetricSpec("final_depth", "m", "higher", "tip depth in the true hole at the end"),
    )
    primary_metric: ClassVar[str] = "insertion_time"
    reward_arguments: ClassVar[frozenset[str]] = frozenset((
        "force_weight", "success_bonus", "failure_penalty", "divergence_penalty",
        "charge_unplayed_steps",
    ))
    leaderboard_variants: ClassVar[dict[str, dict[str, Any]]] = {
        "sharp edge": {},
        "3 mm chamfer": {"chamfer": 0.003},
    }
    robot_name: ClassVar[str] = "iiwa14"

    def __init__(
        self,
        control: str = "torque",
        sensor: str = "ati_gamma",
        clearance: float = 0.0005,
        chamfer: float = 0.0,
        position_uncertainty: float = 0.002,
        tilt_uncertainty: float = 2.0,
        force_limit: float = 100.0,
        start_height: float = 0.01,
        success_depth: float = 0.9,
        control_freq: float = 500.0,
        episode_duration: float = 12.0,
        force_weight: float = 1.0,
        success_bonus: float = 100.0,
        failure_penalty: float = 100.0,
        divergence_penalty: float = 100.0,
        charge_unplayed_steps: bool = True,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ) -> None:
        if control not in CONTROLS:
            raise InvalidArgument(f"control must be one of {CONTROLS}, got {control!r}")
        self.control = control
        if not isinstance(sensor, str) or sensor not in PRESETS:
            raise InvalidArgument(f"sensor must be one of {sorted(PRESETS)}, got {sensor!r}")
        self.sensor = sensor
        self.clearance = check_number("clearance", clearance, *geo.CLEARANCE_RANGE)
        self.chamfer = check_number("chamfer", chamfer, *geo.CHAMFER_RANGE)
        if 0.0 < self.chamfer < sys.float_info.min:  # half of it, a box's size, would be 0
            raise InvalidArgument(
                f"chamfer must be 0 or at least {sys.float_info.min:g} m (a normal float), "
                f"got {chamfer!r}"
            )
        self.position_uncertainty = check_number(
            "position_uncertainty", position_uncertainty, 0.0, 0.01
        )
        self.tilt_uncertainty = check_number("tilt_uncertainty", tilt_uncertainty, 0.0, 10.0)
        self.force_limit = check_number("force_limit", force_limit, 0.0, 1e4, low_open=True)
        self.start_height = check_number("start_height", start_height, 0.002, 0.1)
        self.success_depth = check_number("success_depth", success_depth, 0.0, 0.98, low_open=True)
        self.force_weight = check_number("force_weight", force_weight, 0.0, 100.0)
        self.success_bonus = check_number("success_bonus", success_bonus, 0.0, 1e6)
        self.failure_penalty = check_number("failure_penalty", failure_penalty, 0.0, 1e6)
        self.divergence_penalty = check_number("divergence_penalty", divergence_penalty, 0.0, 1e6)
        if not isinstance(charge_unplayed_steps, (bool, np.bool_)):
            raise InvalidArgument(
                f"charge_unplayed_steps must be True or False, got {charge_unplayed_steps!r}"
            )
        self.charge_unplayed_steps = bool(charge_unplayed_steps)
        # the worst reward of a step that does not end the episode: r_distance = −1, r_force
        # at the force limit
        self._worst_step = 1.0 + self.force_weight

        # the control period's physics steps in the sensors' history (see _advance)
        control_freq = check_number(
            "control_freq", control_freq, MIN_CONTROL_FREQ, 1.0 / geo.TIMESTEP
        )
        steps = frame_skip(control_freq, geo.TIMESTEP)
        model, self.geometry = geo.build_peg_in_hole(self.clearance, self.chamfer, history=steps)
        super().__init__(
            model,
            control_freq=control_freq,
            episode_duration=episode_duration,
            render_mode=render_mode,
            width=width,
            height=height,
            camera="hole_cam",
        )
        self.robot = Robot(model)
        self.n = self.robot.n
        self.torque_limit = self.robot.torque_limit.copy()
        self.ft_sensor = WrenchSensor(sensor_spec(self.sensor), model.opt.timestep)
        # the robot vendor's controller behind the position interface: it knows the arm and
        # its tool (a separate copy of the model: its own MjData, never the simulator's)
        self.motion = CartesianMotionInterface(
            Robot(geo.build_peg_in_hole(self.clearance, self.chamfer)[0]), "peg_tip"
        )
        self.increment_scale = np.r_[np.full(3, MAX_SPEED), np.full(3, MAX_ANGULAR_SPEED)] * self.dt
        self.action_scale = (
            self.torque_limit.copy() if control == "torque" else self.increment_scale.copy()
        )
        self._tip = model.site("peg_tip").id
        self._ft = model.site("ft_site").id
        self._block = model.body("block").id
        self._arm_root = int(model.body_rootid[model.site_bodyid[self._tip]])
        self.sensors = ContactSensors(model)
        # sensordata of each physics step of a control period (frame_skip, nsensordata)
        self._period = np.zeros((self.frame_skip, model.nsensordata))
        self._period_start = np.zeros(mujoco.mj_stateSize(model, _INTEGRATION))
        self._mu_diameter = geo.FRICTION * 2 * self.geometry.hole_radius
        self.hole_pos = np.asarray(geo.HOLE_POSITION, dtype=float)  # nominal, world
        self.hole_quat = np.array([1.0, 0.0, 0.0, 0.0])
        self._R_hole = traj.matrix_from_quat(self.hole_quat)
        self._q0 = np.array(start_posture(self.start_height))
        self.goal_depth = self.success_depth * self.geometry.depth

        self.action_space = spaces.Box(
            -1.0, 1.0, (self.n if control == "torque" else 6,), dtype=np.float32
        )
        self._obs_bounds = {
            "q": np.full(self.n, 2 * np.pi),
            "qd": np.full(self.n, 50.0),
            "peg_pos": np.full(3, 2.0),
            "peg_quat": np.ones(4),
            "peg_twist": np.r_[np.full(3, 10.0), np.full(3, 50.0)],
            "wrench": np.r_[np.full(3, 1000.0), np.full(3, 100.0)],
            "hole_pos": np.full(3, 2.0),
            "hole_quat": np.ones(4),
        }
        self._obs_low = {key: -b for key, b in self._obs_bounds.items()}
        self.observation_space = spaces.Dict(
            {k: spaces.Box(-b, b, b.shape, dtype=np.float64) for k, b in self._obs_bounds.items()}
        )
        # per control step: the largest single contact force, the largest net force and the
        # sum of the net force over its physics steps (N)
        self._force = np.zeros(self.max_steps)
        self._net_peak = np.zeros(self.max_steps)
        self._net_sum = np.zeros(self.max_steps)
        self._jammed_steps = 0
        self._k = 0
        self._inserted_at: int | None = None
        self._entered = False  # the tip went into the bore through the top opening
        self._final_depth = 0.0  # tip depth in the true hole now (m)
        self.true_hole_pos = self.hole_pos.copy()
        self.true_hole_R = np.eye(3)
        self._goal = self.true_hole_pos - self.goal_depth * self.true_hole_R[:, 2]

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        rng = self.np_random
        radius = self.position_uncertainty * np.sqrt(rng.uniform())
        angle = rng.uniform(0.0, 2 * np.pi)
        offset = np.array([radius * np.cos(angle), radius * np.sin(angle), 0.0])
        tilt = np.deg2rad(self.tilt_uncertainty) * rng.uniform()
        tilt_axis_angle = rng.uniform(0.0, 2 * np.pi)
        axis = np.array([np.cos(tilt_axis_angle), np.sin(tilt_axis_angle), 0.0])
        quat = np.concatenate(([np.cos(tilt / 2)], np.sin(tilt / 2) * axis))
        self.true_hole_pos = self.hole_pos + offset
        self.true_hole_R = traj.matrix_from_quat(quat)
        self._goal = self.true_hole_pos - self.goal_depth * self.true_hole_R[:, 2]
        self.model.body_pos[self._block] = self.true_hole_pos
        self.model.body_quat[self._block] = quat
        self._reset_physics(self._q0, np.zeros(self.n))
        self.motion.reset(self._q0)
        R_ws = self.data.site_xmat[self._ft].reshape(3, 3)
        self.ft_sensor.reset(rng, tool_gravity_wrench(geo.PEG_MASS, TOOL_COM, R_ws))
        self._k = 0
        self._inserted_at = None
        self._entered = False
        self._final_depth = self._depth()
        self._jammed_steps = 0
        self._force[:] = 0.0
        self._net_peak[:] = 0.0
        self._net_sum[:] = 0.0
        info = {
            "hole_offset": offset,
            "hole_tilt": float(np.rad2deg(tilt)),
            "hole_tilt_axis": axis,
        }
        return self._obs(), info

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        if self._k >= self.max_steps:
            raise RuntimeError("step() called after the episode ended; call reset()")
        a = self._check_action(action)[0]
        z_before = self._tip_in_hole()[2]
        diverged, force, net_peak, net_sum = self._advance(a)
        k = self._k
        self._k += 1
        self._force[k], self._net_peak[k], self._net_sum[k] = force, net_peak, net_sum
        tip = self._tip_in_hole()
        depth = self._final_depth = float(-tip[2])
        twist = self._tip_twist()
        flags = self._contact_flags(depth, float(self.true_hole_R[:, 2] @ twist[:3]))
        self._jammed_steps += flags.jammed
        radial = float(np.hypot(tip[0], tip[1]))
        if tip[2] > -ENTRY_DEPTH:  # at or above the top face: not in the bore
            self._entered = False
        elif z_before > -ENTRY_DEPTH:  # went below the top face this step: through the opening?
            self._entered = radial < self.geometry.hole_radius + self.geometry.chamfer
        inserted = bool(
            not diverged
            and self._entered
            and self.goal_depth <= depth <= self.geometry.depth + BOTTOM_TOLERANCE
            and radial < self.geometry.hole_radius
        )
        if inserted and self._inserted_at is None:
            self._inserted_at = self._k
        over = bool(not diverged and force > self.force_limit)

        dist = float(np.linalg.norm(self.data.site_xpos[self._tip] - self._goal))
        terms = {
            name: float(v)
            for name, v in self._reward_terms(
                dist, force, inserted, over, diverged, self._k
            ).items()
        }
        reward = sum(terms.values())
        terminated = diverged or inserted or over
        truncated = self._k >= self.max_steps and not terminated
        info: dict[str, Any] = self._step_info(terms, force, net_peak, depth, flags, over, diverged)
        if terminated or truncated:
            info["episode_metrics"] = self.episode_metrics()
            info["is_success"] = inserted
        return self._obs(twist), reward, terminated, truncated, info

    def _reward_terms(
        self, dist: Any, force: Any, inserted: Any, over: Any, diverged: Any, played: Any
    ) -> dict[str, np.ndarray]:
        """The reward's terms (see Rewards), in the order they are summed, of this env (numbers)
        or of a batch of its copies ((N,) arrays, e.g. the vector env's): the tip's distance
        to the goal ``dist`` (m), the period's largest single contact force ``force`` (N), and
        whether the step inserted, went over the force limit or diverged, and the steps
        ``played`` in the episode (this one included)."""
        unplayed = np.where(
            self.charge_unplayed_steps & (over | diverged),
            (self.max_steps - played) * self._worst_step,
            0.0,
        )
        return {
            "reward_distance": -np.minimum(dist / GOAL_SCALE, 1.0),
            "reward_force": -self.force_weight * np.minimum(force / self.force_limit, 10.0) ** 2,
            "reward_success": np.where(inserted, self.success_bonus, 0.0),
            "reward_force_limit": np.where(over, -(self.failure_penalty + unplayed), 0.0),
            "reward_diverged": np.where(diverged, -(self.divergence_penalty + unplayed), 0.0),
        }

    @staticmethod
    def _step_info(
        terms: dict[str, Any], force: Any, net_peak: Any, depth: Any, flags: ContactFlags,
        over: Any, diverged: Any,
    ) -> dict[str, Any]:
        """A step's ``info`` (before the episode's end adds its entries), of one env or of a
        batch's copies."""
        return {
            **terms,
            "contact_force": force,
            "net_contact_force": net_peak,
            "depth": depth,
            "two_point_contact": flags.two_point,
            "wedged": flags.wedged,
            "jammed": flags.jammed,
            "force_limit_exceeded": over,
            "diverged": diverged,
        }

    def episode_metrics(self) -> dict[str, float]:
        """Metrics of the episode so far (see ``metric_specs``)."""
        k = max(self._k, 1)
        done = self._inserted_at
        h = self.model.opt.timestep
        return {
            "insertion_time": float((done if done is not None else self.max_steps) * self.dt),
            "peak_force": float(np.max(self._force[:k])),
            "peak_net_force": float(np.max(self._net_peak[:k])),
            "mean_force": float(np.sum(self._net_sum[:k]) * h / (k * self.dt)),
            "force_impulse": float(np.sum(self._net_sum[:k]) * h),
            "jammed_time": self._jammed_steps * self.dt,
            "final_depth": self._final_depth,
        }

    # ------------------------------------------------------------------ physics
    def _advance(self, a: np.ndarray) -> tuple[bool, float, float, float]:
        """One control period: its physics steps (:meth:`_physics`), then the contact
        sensors' readings of each of them from MuJoCo's history buffer.

        The period stops at the physics step where a single contact exceeds ``force_limit``:
        the period is simulated again from its start up to that step (the same
        computation), then ``mj_forward`` (the flags and the observation read the stopped
        state). A diverged period (state restored to the last finite one) counts no contact.

        Returns:
            (diverged, the largest single contact force (N), the largest net contact force
            (N), the sum of the net force's magnitude over the physics steps (N)). The F/T
            sensor is fed the wrist's wrench of every physics step played and, for the rest
            of a stopped period, that of the stopped state (the arm held).
        """
        if self.control == "position":
            R_h = self._R_hole  # the action is in the nominal hole frame
            dx = a * self.increment_scale
            self.motion.command(np.concatenate((R_h @ dx[:3], R_h @ dx[3:])), self.dt)
            tau = None
        else:
            tau = a * self.torque_limit
        m, d, steps, period = self.model, self.data, self.frame_skip, self._period
        mujoco.mj_getState(m, d, self._period_start, _INTEGRATION)
        diverged = self._physics(tau, steps)
        played = 0 if diverged else steps
        largest = np.zeros(0)
        if not diverged:
            self.sensors.period(d.history, period)
            largest = self.sensors.largest(period)  # (steps,)
            over = np.flatnonzero(largest > self.force_limit)
            if over.size:  # a single contact over the limit: stop at that physics step
                played = int(over[0]) + 1
                if played < steps:
                    mujoco.mj_setState(m, d, self._period_start, _INTEGRATION)
                    self._physics(tau, played)
                mujoco.mj_forward(m, d)  # mj_step leaves the kinematics of the step before
        peak = float(largest[:played].max()) if played else 0.0
        net = np.linalg.norm(self.sensors.net(period[:played]), axis=-1) if peak > 0 else ()
        period[played:] = d.sensordata  # stopped early: the sensor feels the stopped state
        self.ft_sensor.advance_many(self.sensors.wrist(period))
        if peak == 0.0:  # no contact in the period
            return diverged, 0.0, 0.0, 0.0
        return diverged, peak, float(net.max()), float(net.sum())

    def _physics(self, tau: np.ndarray | None, steps: int) -> bool:
        """The first ``steps`` physics steps of the control period: the torque ``tau`` held
        (torque interface: one ``mj_step`` call), or the position interface's torque at
        each physics step (``tau`` None). Returns True if the physics diverged (state
        restored by ``_simulate``)."""
        skip = self.frame_skip
        try:
            if tau is not None:
                self.frame_skip = steps  # _simulate runs frame_skip physics steps
                return self._simulate(tau)
            self.frame_skip = 1
            d, qa, da = self.data, self.robot.qpos_adr, self.robot.dof_adr
            for i in range(steps):
                tau_i = self.motion.torque(d.qpos[qa], d.qvel[da], (i + 1) / skip)
                if self._simulate(np.clip(tau_i, -self.torque_limit, self.torque_limit)):
                    return True
            return False
        finally:
            self.frame_skip = skip

    # ------------------------------------------------------------------ contact
    def _tip_in_hole(self) -> np.ndarray:
        """Tip position in the true hole frame (3,) (m)."""
        return self.true_hole_R.T @ (self.data.site_xpos[self._tip] - self.true_hole_pos)

    def _depth(self) -> float:
        """Tip depth in the true hole (m): −z of :meth:`_tip_in_hole`."""
        return float(-self._tip_in_hole()[2])

    def _tip_twist(self) -> np.ndarray:
        """The tip's velocity [v; ω] (6,), world frame (m/s, rad/s) (:func:`tip_twist`)."""
        d = self.data
        return tip_twist(d.cdof, d.qvel, d.site_xpos[self._tip], d.subtree_com[self._arm_root])

    def _contact_flags(self, depth: float, axial_speed: float) -> ContactFlags:
        """Two-point contact, wedging and jamming of the peg now (see Episode End), from the
        peg's contacts at the last physics step; ``axial_speed``: the tip's speed along the
        true axis (m/s)."""
        sensed = self.data.sensordata
        if self.sensors.peg_count(sensed) < 2:  # two-point contact needs two contacts
            return ContactFlags()
        normal, pressing = self.sensors.peg(sensed)
        axis = self.true_hole_R[:, 2]
        return contact_flags(normal, pressing, axis, depth, axial_speed, self._mu_diameter)

    # ------------------------------------------------------------------ pictures
    def draw_task(self, scene: mujoco.MjvScene) -> None:
        """The block cut away, the nominal hole frame, the true bore axis and the net contact
        force (:func:`cir_gym.envs.peg_in_hole_scene.draw_task`)."""
        draw_task(
            scene,
            self.model,
            self.hole_pos,
            self.true_hole_pos,
            self.true_hole_R,
            self.geometry.depth,
            self.data.site_xpos[self._tip].copy(),
            self.sensors.net(self.data.sensordata),
        )

    def caption(self) -> str:
        """Time, insertion depth in the true hole and the largest single contact force."""
        k = min(self._k, self.max_steps)
        f = self._force[k - 1] if k > 0 else 0.0
        return f"t {k * self.dt:5.2f} s  depth {1e3 * self._depth():6.2f} mm  |F| {f:5.1f} N"

    # ------------------------------------------------------------------ observation
    def wrench(self) -> np.ndarray:
        """Sensed wrench (6,): the sensor model's reading, sensor frame (N, N m)."""
        return self.ft_sensor.reading.copy()

    def _obs(self, twist: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The observation; ``twist``: the tip's [v; ω] now if already computed."""
        d, R_h = self.data, self._R_hole
        twist = self._tip_twist() if twist is None else twist
        v, w = twist[:3], twist[3:]
        R_tip = d.site_xmat[self._tip].reshape(3, 3)
        obs = {
            "q": d.qpos[self.robot.qpos_adr].copy(),
            "qd": d.qvel[self.robot.dof_adr].copy(),
            "peg_pos": R_h.T @ (d.site_xpos[self._tip] - self.hole_pos),
            "peg_quat": traj.quat_from_matrix(R_h.T @ R_tip @ ALIGNED.T),
            "peg_twist": np.concatenate((R_h.T @ v, R_h.T @ w)),
            "wrench": self.ft_sensor.reading.copy(),
            "hole_pos": self.hole_pos.copy(),
            "hole_quat": self.hole_quat.copy(),
        }
        low, high = self._obs_low, self._obs_bounds
        return {key: CLIP(x, low[key], high[key]) for key, x in obs.items()}

    def controller_context(self) -> TaskContext:
        return TaskContext(
            robot=self.robot_name,
            dt=self.dt,
            action_kind="joint_torque" if self.control == "torque" else "cartesian_increment",
            action_scale=self.action_scale.copy(),
            site="flange",
            extras={
                "tool_mass": geo.PEG_MASS,
                "tool_com": TOOL_COM.copy(),
                "hole_position": np.array(geo.HOLE_POSITION),
                "tip_offset": self.geometry.tip_offset,
                "clearance": self.clearance,
                "chamfer": self.chamfer,
                "hole_depth": self.geometry.depth,
                "peg_radius": self.geometry.peg_radius,
                "goal_depth": self.goal_depth,
                "force_limit": self.force_limit,
                "position_uncertainty": self.position_uncertainty,
                "tilt_uncertainty": self.tilt_uncertainty,
            },
        )
