"""PegInHole: insert a cylindrical peg into a round hole whose pose is known only approximately
(chapter 6: hybrid force/position control with a selection matrix)."""

from __future__ import annotations

import math
import sys
from functools import lru_cache
from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces

from cir_gym import peg_hole_geometry as geo
from cir_gym import trajectories as traj
from cir_gym.context import TaskContext
from cir_gym.envs.base import _MAX_SPEED_SQ, _STATE, _UNSTABLE_CONTIGUOUS, RobotEnv
from cir_gym.ft_sensor import PRESETS, WrenchSensor, sensor_spec, tool_gravity_wrench
from cir_gym.metrics import MetricSpec
from cir_gym.motion_interface import CartesianMotionInterface
from cir_gym.numeric import CLIP, index_view, max_of, mean_of
from cir_gym.operational_space import rotvec_error
from cir_gym.robot import Robot
from cir_gym.validation import InvalidArgument, check_number

CONTROLS = ("torque", "position")
#: Position interface: largest setpoint speed (m/s) and angular speed (rad/s); an action of 1 moves
#: the setpoint by this times the control period.
MAX_SPEED = 0.05
MAX_ANGULAR_SPEED = 0.5
#: Window of the force monitor (s): the contact force is averaged over the last 2 ms of physics
#: steps, as a force monitor sampling at 500 Hz sees it (an impact's sub-millisecond spike on the
#: rigid arm model is an impulse, not a sustained force).
FORCE_WINDOW = 2e-3
TOOL_COM = np.array(geo.PEG_COM)  # in the sensor frame
#: Orientation of the peg-tip frame in the hole frame when the peg is aligned with the bore
#: (peg z pointing into the hole: a half turn about y).
ALIGNED = np.diag([-1.0, 1.0, -1.0])
ALIGNED_QUAT = traj.quat_from_matrix(ALIGNED)
#: ALIGNEDᵀ's diagonal: X @ ALIGNED.T multiplies the columns of X by it
_ALIGNED_COLUMNS = np.diag(ALIGNED.T).copy()
#: Posture the start is pulled toward (the robot file's home): elbow bent, wrist off its
#: singularity.
PREFERRED_POSTURE = np.array([0.0, 0.6, 0.0, -1.4, 0.0, 0.9, 0.0])
STALL_SPEED = 1e-3  # m/s: axial speed below which a peg in two-point contact counts as stuck
# hot-path ufuncs, called directly (np.mean/np.clip wrappers cost more than the work)
_SUM = np.add.reduce
_isfinite = math.isfinite
_ADD, _SUB, _MUL = np.add, np.subtract, np.multiply
#: MuJoCo's whole integration state (what the next mj_step reads): _advance's undo
_INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
_MATMUL = np.matmul
_XYZ = np.arange(3)  # a contact's three efc_force rows from its efc_address
SIDE_NORMAL = 0.7  # |n · axis| below this: a contact on the bore's side (else top or bottom)
GOAL_SCALE = 0.05  # m: distance at which the distance reward saturates at −1


@lru_cache(maxsize=8)
def _start_posture(height: float) -> tuple[float, ...]:
    """Joint angles with the peg tip ``height`` above the nominal hole, aligned with its axis."""
    model, _ = geo.build_peg_in_hole()
    robot = Robot(model)
    target = np.asarray(geo.HOLE_POSITION) + np.array([0.0, 0.0, height])
    q = PREFERRED_POSTURE.copy()
    for _ in range(200):  # Newton steps with a null-space pull toward the preferred posture
        p, R = robot.site_pose("peg_tip", q)
        e = np.concatenate((target - p, rotvec_error(ALIGNED_QUAT, traj.quat_from_matrix(R))))
        J = robot.jacobian("peg_tip", q)
        J_pinv = np.linalg.pinv(J)
        q = q + J_pinv @ e + (np.eye(robot.n) - J_pinv @ J) @ (0.1 * (PREFERRED_POSTURE - q))
        if float(e @ e) < 1e-24:
            break
    return tuple(float(v) for v in q)


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
    convex collision (MuJoCo's native one reversed normals at the bore's edge). Measured
    (tests/test_peg_in_hole.py): steady-contact penetration below a fifth of the clearance at
    the smallest clearance (0.1 mm) under 100 N, no tunnelling at 0.5 m/s, a centred peg
    slides to the bottom without touching the walls.

    The arm is driven by joint torques (never a mocap body: it would teleport into contacts),
    by the agent (``control="torque"``) or by the robot's motion controller
    (``control="position"``). The wrist sensor (:mod:`cir_gym.ft_sensor`, preset ``sensor``)
    reads the interaction between the flange and the tool, the peg's weight included, in the
    sensor frame ``ft_site`` (z along the peg, pointing into the hole when aligned), filtered,
    delayed, sampled, noisy and quantised as the preset says. The true contact force is in
    ``info["contact_force"]``, never in the observation: the net force of the block on the peg,
    averaged over the last 2 ms of physics steps (a 500 Hz force monitor; on this rigid arm
    model an impact is a sub-millisecond spike of the 11 kg task-space inertia, an impulse
    rather than a sustained force), the largest value within the control period.

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
    - r_force = −``force_weight`` (|F| / ``force_limit``)², F the true net contact force;
    - r_success = ``success_bonus`` on the step the peg reaches the goal depth;
    - r_force_limit = −``failure_penalty`` on the step |F| exceeds ``force_limit``;
    - r_diverged = −``divergence_penalty`` on the step the physics diverged.

    An episode that ends as a failure (force limit or divergence) also loses, on its last
    step, the worst reward of every step it did not play without ending, (T − k)(1 +
    ``force_weight``) (T the episode's steps, k the steps played; r_distance = −1 and r_force
    at the force limit): playing on can never lose more than failing, so failing early never
    raises the return, at any discount γ ≤ 1 (``charge_unplayed_steps``, on by default since
    v1). Without it (v0's return) failing pays: 100 for exceeding the force limit against up
    to 1 + ``force_weight`` per remaining step, and a residual agent on ``hybrid_spiral``
    (tuned gains) learned to strike the surface within 0.8 s (return ≈ −410) rather than
    insert as its base does in ~5 s (≈ −900 to −1060); docs/agents.md, eleventh round.

    ## Starting State
    At rest, the peg tip ``start_height`` above the nominal hole on its axis, aligned with it,
    in the posture closest to the robot file's home (null-space Newton iterations).

    ## Episode End
    Terminated with success when the tip is ``success_depth`` × 25 mm deep in the true hole
    (``info["is_success"]``); terminated as a failure when the true contact force exceeds
    ``force_limit`` (``info["force_limit_exceeded"]``) or when the physics diverges
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
    | force_limit | 100.0 | true contact force that ends the episode as a failure (N) |
    | start_height | 0.01 | initial tip height above the nominal hole (m, in [0.002, 0.1]) |
    | success_depth | 0.9 | insertion depth counted as success, fraction of the 25 mm bore |
    | control_freq | 500.0 | control frequency (Hz); the physics step is 0.5 ms |
    | episode_duration | 12.0 | s (a spiral search on the sharp-edged hole takes up to ~8 s) |
    | force_weight | 1.0 | weight of the force term |
    | success_bonus | 100.0 | reward on success |
    | failure_penalty | 100.0 | reward lost when the force limit is exceeded |
    | divergence_penalty | 100.0 | reward lost when the physics diverges |
    | charge_unplayed_steps | True | a failed episode also loses the worst reward of each unplayed step (see Rewards; False: v0's return) |
    | render_mode | None | None, "human" or "rgb_array" |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    ``insertion_time`` (primary, s; the time limit when not inserted), ``peak_force`` (N, max
    of the true net contact force), ``mean_force`` (N, over the episode), ``force_impulse``
    (∫|F| dt, N s), ``final_depth`` (m, tip depth in the true hole at the end). Success: the
    peg reached the goal depth (so the success rate over episodes is the evaluator's).

    ## Reference controllers
    ``baselines.available("cir_gym/PegInHole-v1")``: hybrid_force_position, hybrid_spiral,
    position_only (baselines/hybrid.py); AdmittanceContact's ``admittance`` law applies through
    the adapter ``baselines.hybrid.PegAdmittance`` (axial force regulation only).

    ## Version History
    - v1: ``charge_unplayed_steps`` on by default (v0's return favoured failing). The
      dynamics, observations, metrics and success are v0's; only a failed episode's last
      reward differs (``charge_unplayed_steps=False`` gives v0's episodes exactly).
    - v0: initial version. Later, without a version bump (a new argument whose default kept
      v0's episodes): ``charge_unplayed_steps``.
    """

    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec(
            "insertion_time",
            "s",
            "lower",
            "time to the goal depth (time limit if not)",
            failure_scores_limit=True,
        ),
        MetricSpec("peak_force", "N", "lower", "peak net contact force"),
        MetricSpec("mean_force", "N", "lower", "mean net contact force"),
        MetricSpec("force_impulse", "N s", "lower", "integral of the net contact force"),
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
        if sensor not in PRESETS:
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

        model, self.geometry = geo.build_peg_in_hole(self.clearance, self.chamfer)
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
        self._window = max(1, round(FORCE_WINDOW / model.opt.timestep))
        # the force monitor's window: the last _window physics steps' net contact force (N),
        # Python floats (summed as numpy sums fewer than 8 terms: left to right)
        self._recent = [0.0] * self._window
        self._slot = 0
        self._qa, self._da = self.robot.qpos_adr, self.robot.dof_adr
        self._q_at, self._qd_at = index_view(self._qa), index_view(self._da)
        self._tip = model.site("peg_tip").id
        self._ft = model.site("ft_site").id
        self._block = model.body("block").id
        self._peg_geom = model.geom("peg_geom").id
        self._force_adr = model.sensor_adr[model.sensor("ft_force").id]
        self._torque_adr = model.sensor_adr[model.sensor("ft_torque").id]
        self.hole_pos = np.asarray(geo.HOLE_POSITION, dtype=float)  # nominal, world
        self.hole_quat = np.array([1.0, 0.0, 0.0, 0.0])
        self._R_hole = traj.matrix_from_quat(self.hole_quat)
        self._q0 = np.array(_start_posture(self.start_height))
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
        self.observation_space = spaces.Dict(
            {k: spaces.Box(-b, b, b.shape, dtype=np.float64) for k, b in self._obs_bounds.items()}
        )
        # _obs fills one flat buffer in this layout and clips it once
        self._obs_high = np.concatenate(list(self._obs_bounds.values()))
        self._obs_low = -self._obs_high
        self._obs_size = self._obs_high.size
        ends = np.cumsum([b.size for b in self._obs_bounds.values()])
        self._obs_slices = tuple(
            (k, slice(int(e - b.size), int(e)))
            for (k, b), e in zip(self._obs_bounds.items(), ends, strict=True)
        )
        self._obs_at = tuple(sl for _, sl in self._obs_slices)  # _obs's order
        self._rot = np.zeros((3, 3))  # _obs's scratch: the peg's rotation, hole frame
        self._rot_flat = self._rot.reshape(9)
        self._pos_tmp = np.zeros(3)
        self._period_start = np.zeros(mujoco.mj_stateSize(model, _INTEGRATION))  # _advance
        self._pass_state = np.zeros(mujoco.mj_stateSize(model, _STATE))  # _advance's save
        steps = self.max_steps
        self._force = np.zeros(steps)
        self._k = 0
        self._inserted_at: int | None = None
        self._diverged = False
        self.true_hole_pos = self.hole_pos.copy()
        self.true_hole_R = np.eye(3)
        self._jac = np.zeros((6, model.nv))  # [J_p; J_r] of the peg tip (mj_jacSite)
        self._jacp, self._jacr = self._jac[:3], self._jac[3:]
        self._cforce = np.zeros(6)
        #: every contact's force is its three efc_force rows: elliptic cones, every geom of
        #: condim 3 (a contact takes its geoms' larger condim) and no explicit pairs; read
        #: once from the env's own model (nothing changes these options afterwards)
        self._efc_rows = bool(
            model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
            and model.npair == 0
            and np.all(model.geom_condim == 3)
        )
        self._goal = self.true_hole_pos - self.goal_depth * self.true_hole_R[:, 2]
        self._wrench_view: np.ndarray | None = None

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
        self._goal = self.true_hole_pos - self.goal_depth * self.true_hole_R[:, 2]  # the reward's
        self.model.body_pos[self._block] = self.true_hole_pos
        self.model.body_quat[self._block] = quat
        self._reset_physics(self._q0, np.zeros(self.n))
        self.motion.reset(self._q0)
        R_ws = self.data.site_xmat[self._ft].reshape(3, 3)
        self.ft_sensor.reset(rng, tool_gravity_wrench(geo.PEG_MASS, TOOL_COM, R_ws))
        self._recent = [0.0] * self._window
        self._slot = 0
        self._k = 0
        self._inserted_at = None
        self._diverged = False
        self._force[:] = 0.0
        info = {
            "hole_offset": offset,
            "hole_tilt": float(np.rad2deg(tilt)),
            "hole_tilt_axis": axis,
        }
        return self._obs(), info

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        if self._k >= self.max_steps:
            raise RuntimeError("step() called after the episode ended; call reset()")
        a = self._check_action_peak(action)[0]
        diverged, f = self._advance(a)
        k = self._k
        self._k += 1
        depth, tip, two_point, wedged, jammed = self._contact_flags()
        self._force[k] = f
        # in_bore only where it decides (the radial distance of _contact_state)
        inserted = bool(not diverged and depth >= self.goal_depth and self._in_bore(tip))
        if inserted and self._inserted_at is None:
            self._inserted_at = self._k
        over = bool(not diverged and f > self.force_limit)

        to_goal = self._tip_views[0] - self._goal  # views: set by _simulate
        dist = math.sqrt(float(to_goal.dot(to_goal)))  # = np.linalg.norm: the same dot
        r_dist = -min(dist / GOAL_SCALE, 1.0)
        r_force = -self.force_weight * min(f / self.force_limit, 10.0) ** 2
        r_success = self.success_bonus if inserted else 0.0
        unplayed = (
            (self.max_steps - self._k) * self._worst_step
            if self.charge_unplayed_steps and (over or diverged)
            else 0.0
        )
        r_limit = -(self.failure_penalty + unplayed) if over else 0.0
        r_div = -(self.divergence_penalty + unplayed) if diverged else 0.0
        reward = r_dist + r_force + r_success + r_limit + r_div

        terminated = diverged or inserted or over
        truncated = self._k >= self.max_steps and not terminated
        info: dict[str, Any] = {
            "reward_distance": r_dist,
            "reward_force": r_force,
            "reward_success": r_success,
            "reward_force_limit": r_limit,
            "reward_diverged": r_div,
            "contact_force": f,
            "depth": depth,
            "two_point_contact": two_point,
            "wedged": wedged,
            "jammed": jammed,
            "force_limit_exceeded": over,
            "diverged": diverged,
        }
        if terminated or truncated:
            info["episode_metrics"] = self.episode_metrics()
            info["is_success"] = inserted
        return self._obs(), reward, terminated, truncated, info

    def episode_metrics(self) -> dict[str, float]:
        """Metrics of the episode so far (see ``metric_specs``)."""
        k = max(self._k, 1)
        force = self._force[:k]
        done = self._inserted_at
        return {
            "insertion_time": float((done if done is not None else self.max_steps) * self.dt),
            "peak_force": max_of(force),
            "mean_force": mean_of(force),
            "force_impulse": float(_SUM(force)) * self.dt,  # = float(np.sum(force) * dt)
            "final_depth": float(self._depth()),
        }

    def _advance(self, a: np.ndarray) -> tuple[bool, float]:
        """One control period, physics step by physics step (the sensor, the position
        interface and the force monitor run at the physics rate); return (diverged, peak of
        the windowed contact force over the period).

        A fast pass runs the period with RobotEnv._simulate's quick test per physics step
        (‖q̇‖² ≤ MAX_JOINT_SPEED²) and its warning test, plus a finite test of q at the end
        (a guard _simulate has dropped: a non-finite q makes MuJoCo's mj_checkPos warn at the
        next step, and a finite bounded q̇ keeps q finite), and leaves
        _simulate's saved state as its loop would (the state before the period's last
        step). If anything fails, the period is undone (MuJoCo's integration state and its
        whole warning state, every counter and last info, restored; nothing else was changed)
        and run again through ``_simulate`` one physics step at a time
        (:meth:`_advance_simulate`), which detects and restores exactly as before. MuJoCo logs
        a warning's text when its counter leaves 0, so a warning met in the undone pass is
        logged again by the rerun (the one difference from the plain loop: a repeated line in
        MuJoCo's log, not in any value)."""
        if self.control == "position":
            R_h = self._R_hole  # the action is in the nominal hole frame
            dx = a * self.increment_scale
            self.motion.command(np.concatenate((R_h @ dx[:3], R_h @ dx[3:])), self.dt)
            tau = None
        else:
            tau = a * self.torque_limit
        m, d = self.model, self.data
        if self._warn_data is not d:
            self._refresh_views(d)
        wrench = self._wrench_view  # None: the force and torque sensors are not neighbours
        if not _UNSTABLE_CONTIGUOUS or wrench is None:
            return self._advance_simulate(tau)
        d_ctrl, d_qpos, d_qvel = self._views
        warn = self._warn_view
        skip = self.frame_skip
        last = skip - 1
        step, get_state = mujoco.mj_step, mujoco.mj_getState
        # the period's start, to undo it: MuJoCo's integration state, its warning state (every
        # counter and last info: a pass may also count e.g. CONTACTFULL, the rerun again)
        start = self._period_start
        get_state(m, d, start, _INTEGRATION)
        before = warn.tobytes()
        number, lastinfo = self._warn_all
        warnings_before = (number.tobytes(), lastinfo.tobytes())
        # _simulate's saved state after its loop: the state before the last step (before the
        # only step, if one), kept aside until the pass succeeds
        saved = self._pass_state
        if not last:
            get_state(m, d, saved, _STATE)
        if tau is not None:  # held over the period (MuJoCo changes ctrl only on a warning)
            d_ctrl[:] = tau
        else:
            motion, limit, q_at, qd_at = self.motion, self.torque_limit, self._q_at, self._qd_at
        # the true wrench of every physics step, fed to the sensor model after the loop (one
        # call; nothing else in the loop reads the sensor or draws from its generator)
        wrenches: list[list[float]] = []
        recent, window, slot = list(self._recent), self._window, self._slot
        peak, ok = 0.0, True
        for i in range(skip):
            if tau is None:
                ctrl = motion.torque(d_qpos[q_at], d_qvel[qd_at], (i + 1) / skip)
                d_ctrl[:] = CLIP(ctrl, -limit, limit)
            if i == last and i:
                get_state(m, d, saved, _STATE)
            step(m, d)
            if not d_qvel.dot(d_qvel) <= _MAX_SPEED_SQ:
                ok = False
                break
            wrenches.append(wrench.tolist())
            slot += 1
            if slot == window:
                slot = 0
            if d.ncon:
                f = self._net_contact_force()
                recent[slot] = math.sqrt(f.dot(f))  # = np.linalg.norm(f)
            else:  # no contact: the net force is zero
                recent[slot] = 0.0
            # = np.mean: numpy sums fewer than 8 terms from left to right, as sum() does
            total = sum(recent) if window < 8 else float(_SUM(np.array(recent)))
            if total / window > peak:  # = max(peak, total / window)
                peak = total / window
        if ok and warn.tobytes() == before and _isfinite(d_qpos.dot(d_qpos)):
            # _simulate keeps the last finite state before a step: the one before the last
            # step (finite whenever MuJoCo did not warn: |q| <= 1e10 then, |q̇| checked)
            if _isfinite(saved.dot(saved)):  # (an overflow only skips the save, as there)
                self._safe_state, self._pass_state = saved, self._safe_state
            self._recent[:] = recent
            self._slot = slot
            self.ft_sensor.advance_many(wrenches)
            return False, peak
        # undo the period and run it through _simulate (its exact tests and restore)
        mujoco.mj_setState(m, d, start, _INTEGRATION)
        number[:] = np.frombuffer(warnings_before[0], dtype=number.dtype)
        lastinfo[:] = np.frombuffer(warnings_before[1], dtype=lastinfo.dtype)
        return self._advance_simulate(tau)

    def _advance_simulate(self, tau: np.ndarray | None) -> tuple[bool, float]:
        """:meth:`_advance`'s loop through :meth:`RobotEnv._simulate`, one physics step per
        call (where its inline form does not apply)."""
        skip, self.frame_skip = self.frame_skip, 1  # _simulate: one physics step per call
        peak, diverged = 0.0, False
        wrenches: list[list[float]] = []
        recent, window, slot = self._recent, self._window, self._slot
        simulate, d = self._simulate, self.data
        try:
            for i in range(skip):
                if tau is None:
                    ctrl = self.motion.torque(d.qpos[self._qa], d.qvel[self._da], (i + 1) / skip)
                    ctrl = CLIP(ctrl, -self.torque_limit, self.torque_limit)
                else:
                    ctrl = tau
                diverged = simulate(ctrl)
                if diverged:
                    break
                wrench = self._wrench_view  # set by _simulate (None: not contiguous)
                wrenches.append((self._true_wrench() if wrench is None else wrench).tolist())
                slot += 1
                if slot == window:
                    slot = 0
                if d.ncon:
                    f = self._net_contact_force()
                    recent[slot] = math.sqrt(f.dot(f))  # = np.linalg.norm(f)
                else:  # no contact: the net force is zero
                    recent[slot] = 0.0
                total = sum(recent) if window < 8 else float(_SUM(np.array(recent)))
                peak = max(peak, total / window)
        finally:
            self.frame_skip = skip
            self._slot = slot
            self.ft_sensor.advance_many(wrenches)
        return diverged, peak

    def _refresh_views(self, d: mujoco.MjData) -> None:
        """RobotEnv's views, and the F/T sensors' six values in ``d.sensordata`` (a view, when
        the force and torque sensors are neighbours: the true wrench without a copy)."""
        super()._refresh_views(d)
        adr = self._force_adr
        self._wrench_view = d.sensordata[adr : adr + 6] if self._torque_adr == adr + 3 else None
        self._tip_views = (d.site_xpos[self._tip], d.site_xmat[self._tip])
        self._warn_all = (d.warning.number, d.warning.lastinfo)  # _advance's undo

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state["_wrench_view"] = None  # rebuilt on the new MjData by _simulate
        state.pop("_tip_views", None)
        state.pop("_warn_all", None)  # views of MjData's, rebuilt with the others
        state["_jacp"] = state["_jacr"] = None  # views of _jac, rebuilt by __setstate__
        state["_rot_flat"] = None  # a view of _rot
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._jacp, self._jacr = self._jac[:3], self._jac[3:]
        self._rot_flat = self._rot.reshape(9)

    def _true_wrench(self) -> np.ndarray:
        d = self.data
        return np.concatenate(
            (
                d.sensordata[self._force_adr : self._force_adr + 3],
                d.sensordata[self._torque_adr : self._torque_adr + 3],
            )
        )

    def _net_contact_force(self) -> np.ndarray:
        """Net contact force on the peg (3,), world frame (N): Σ sign·frameᵀ f over the peg's
        contacts (:meth:`_peg_contact_forces`), added in MuJoCo's contact order."""
        got = self._peg_contact_forces()
        if got is None:
            return np.zeros(3)
        sign, frames, forces = got
        # each contact's frameᵀ f as a stacked product (the bits of frames[i].T @ f one by
        # one); the rows added in order from 0.0 (an axis-0 sum of rows: no pairwise order)
        world = _MATMUL(frames.transpose(0, 2, 1), forces[:, :, None])[:, :, 0]
        _MUL(world, sign, out=world)
        return world.sum(axis=0, initial=0.0)

    def _peg_contact_forces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The peg's contacts at once, in MuJoCo's contact order, or None if it touches nothing:
        sign (k, 1) (−1 where the peg is geom1: frame[0] points from geom1 to geom2, so
        sign·frame[0] is the normal pushing the peg), frames (k, 3, 3) (rows: normal, two
        tangents; world frame) and forces (k, 3) (N; normal and friction in the contact frame:
        what ``mj_contactForce`` returns). With elliptic cones and every contact of dimension
        3 (:attr:`_efc_rows`) in the constraint set, the forces are the contacts' rows of
        ``efc_force``, which ``mj_contactForce`` copies; otherwise it is called contact by
        contact. MuJoCo's contact arrays are read once, the geom pairs as a list (a few
        contacts: cheaper than numpy's masks)."""
        con = self.data.contact
        pairs = con.geom.tolist()
        peg = self._peg_geom
        idx = [i for i, (g1, g2) in enumerate(pairs) if g1 == peg or g2 == peg]
        if not idx:
            return None
        every = len(idx) == len(pairs)  # the usual case: the peg is in every contact
        sign = np.array([[-1.0] if pairs[i][0] == peg else [1.0] for i in idx])
        frames = (con.frame if every else con.frame[idx]).reshape(-1, 3, 3)
        adr = con.efc_address if every else con.efc_address[idx]
        if self._efc_rows and adr.min() >= 0:
            forces = self.data.efc_force[adr[:, None] + _XYZ]
        else:
            m, d, out = self.model, self.data, self._cforce
            forces = np.empty((len(idx), 3))
            for row, i in enumerate(idx):
                mujoco.mj_contactForce(m, d, i, out)
                forces[row] = out[:3]
        return sign, frames, forces

    # ------------------------------------------------------------------ contact
    def _tip_in_hole(self) -> np.ndarray:
        """Tip position in the true hole frame (m)."""
        self._data_views()  # (re)builds self._tip_views on a new MjData
        return self.true_hole_R.T @ (self._tip_views[0] - self.true_hole_pos)

    def _depth(self) -> float:
        return float(-self._tip_in_hole()[2])

    def _contact_state(self) -> dict[str, Any]:
        """Insertion depth and the two-point/jamming/wedging flags (see Episode End)."""
        depth, tip, two_point, wedged, jammed = self._contact_flags()
        return {
            "depth": depth,
            "two_point": two_point,
            "wedged": wedged,
            "jammed": jammed,
            "in_bore": self._in_bore(tip),
        }

    def _in_bore(self, tip: np.ndarray) -> bool:
        """The tip (in the true hole frame) within the bore's radius plus the chamfer."""
        radial = float(np.hypot(tip[0], tip[1]))
        return radial < self.geometry.hole_radius + self.geometry.chamfer

    def _contact_flags(self) -> tuple[float, np.ndarray, bool, bool, bool]:
        """(depth, tip in the true hole frame, two_point, wedged, jammed): _contact_state's
        values, the radial test left to the caller (step needs it only at the goal depth)."""
        m, d = self.model, self.data
        if self._warn_data is not d:  # the views of a new MjData
            self._refresh_views(d)
        side: list[np.ndarray] = []
        got = self._peg_contact_forces() if d.ncon else None
        if got is not None:
            axis = self.true_hole_R[:, 2]
            sign, frames, forces = got
            normals = frames[:, 0, :] * sign  # normals pushing the peg (k, 3)
            # n · axis per contact as a stacked (1×3)(3×1) product: the bits of n @ axis
            along = _MATMUL(normals[:, None, :], axis[:, None])[:, 0, 0].tolist()
            pressing = forces[:, 0].tolist()
            for j, a in enumerate(along):
                if abs(a) < SIDE_NORMAL and pressing[j] > 0:
                    lateral = normals[j] - a * axis
                    # ‖lateral‖ as np.linalg.norm computes it: sqrt of the same dot product
                    side.append(lateral / max(math.sqrt(float(lateral.dot(lateral))), 1e-12))
        # _tip_in_hole() on the views step's physics refreshed
        tip = self.true_hole_R.T @ (self._tip_views[0] - self.true_hole_pos)
        depth = float(-tip[2])
        if len(side) > 1 and any(
            float(a @ b) < -0.5 for i, a in enumerate(side) for b in side[i + 1 :]
        ):
            mujoco.mj_jacSite(m, d, self._jacp, self._jacr, self._tip)
            v_axis = float(self.true_hole_R[:, 2] @ (self._jacp @ d.qvel))
            wedged = depth < geo.FRICTION * 2 * self.geometry.hole_radius  # μ D
            return depth, tip, True, wedged, bool(not wedged and abs(v_axis) < STALL_SPEED)
        return depth, tip, False, False, False

    # ------------------------------------------------------------------ pictures
    def draw_task(self, scene: mujoco.MjvScene) -> None:
        """A cut-away of the block (the walls on the camera's side of the bore made
        translucent), the nominal hole frame, the true bore axis (green line) and the net contact
        force on the peg (red arrow, 1 mm per N, from the tip)."""
        from cir_gym import rendering

        kind = int(mujoco.mjtObj.mjOBJ_GEOM)
        block = self._block
        eye = np.mean([scene.camera[i].pos for i in range(2)], axis=0)
        to_eye = eye - self.true_hole_pos
        for i in range(scene.ngeom):
            g = scene.geoms[i]
            if g.objtype != kind or g.objid < 0 or self.model.geom_bodyid[g.objid] != block:
                continue
            if float((np.asarray(g.pos) - self.true_hole_pos) @ to_eye) > 0:
                g.rgba[3] = 0.15
        rendering.add_frame(scene, self.hole_pos, self._R_hole, 0.03, alpha=0.6)
        axis = self.true_hole_R[:, 2]
        rendering.add_line(
            scene,
            self.true_hole_pos + 0.03 * axis,
            self.true_hole_pos - self.geometry.depth * axis,
            2.0,
            rendering.GREEN,
        )
        force = self._net_contact_force()
        rendering.add_arrow(
            scene, self.data.site_xpos[self._tip], 1e-3 * force, 0.001, rendering.RED
        )

    def caption(self) -> str:
        """Time, insertion depth in the true hole and the contact force."""
        k = min(self._k, self.max_steps)
        f = self._force[k - 1] if k > 0 else 0.0
        return f"t {k * self.dt:5.2f} s  depth {1e3 * self._depth():6.2f} mm  |F| {f:5.1f} N"

    # ------------------------------------------------------------------ observation
    def wrench(self) -> np.ndarray:
        """Sensed wrench (6,): the sensor model's reading, sensor frame (N, N m)."""
        return self.ft_sensor.reading.copy()

    def _obs(self) -> dict[str, np.ndarray]:
        """One new flat buffer in the layout of ``_obs_bounds``, filled through precomputed
        slices (the products by the hole frame into their places with ``out=``), clipped
        once, handed out as views (each step's arrays are new)."""
        d = self.data
        _, qpos, qvel = self._data_views()
        xpos, xmat = self._tip_views
        mujoco.mj_jacSite(self.model, d, self._jacp, self._jacr, self._tip)
        vw = self._jac @ qvel  # [J_p q̇; J_r q̇]
        buf = np.empty(self._obs_size)  # one new buffer per step; the entries are its views
        q_at, qd_at, pos_at, quat_at, twist_at, wrench_at, hpos_at, hquat_at = self._obs_at
        buf[q_at] = qpos[self._q_at]
        buf[qd_at] = qvel[self._qd_at]
        R = self._rot  # R_holeᵀ R_tip ALIGNEDᵀ
        # R_holeᵀ (·) with R_hole = I (the nominal hole frame is the world's: hole_quat is
        # fixed at (1, 0, 0, 0)) and ALIGNED = diag(−1, 1, −1): every entry of the products is
        # one exact product (by 1 or −1) plus exact zeros, given as "+ 0.0" (an exact zero as
        # +0; tests/test_contact_fast_paths.py checks the explicit formula, −0 included)
        _ADD(_SUB(xpos, self.hole_pos, out=self._pos_tmp), 0.0, out=buf[pos_at])
        _ADD(_MUL(xmat.reshape(3, 3), _ALIGNED_COLUMNS, out=R), 0.0, out=R)
        _ADD(vw, 0.0, out=buf[twist_at])
        quat = buf[quat_at]
        mujoco.mju_mat2Quat(quat, self._rot_flat)  # as _quat: w >= 0
        if quat[0] < 0:
            np.negative(quat, out=quat)
        buf[wrench_at] = self.ft_sensor.reading
        buf[hpos_at] = self.hole_pos
        buf[hquat_at] = self.hole_quat
        # np.minimum(np.maximum(·, −b), b) of every entry: the clip ufunc (bounds ≠ 0)
        CLIP(buf, self._obs_low, self._obs_high, out=buf)
        return {key: buf[sl] for key, sl in self._obs_slices}

    @staticmethod
    def _quat(R: np.ndarray) -> np.ndarray:
        """Unit quaternion (w ≥ 0) of a rotation matrix (MuJoCo's C routine: the numpy one
        costs ~1 ms per call on a loaded machine)."""
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, np.ascontiguousarray(R).ravel())
        return quat if quat[0] >= 0 else -quat

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
