"""CartesianTracking: track a flange pose reference with joint torques (chapter 5.2)."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces

from cir_gym import operational_space as osp
from cir_gym import trajectories as traj
from cir_gym.context import TaskContext
from cir_gym.envs.base import RobotEnv, model_error_arguments
from cir_gym.metrics import MetricSpec
from cir_gym.numeric import CLIP, index_view, max_of, mean_of, rms_of
from cir_gym.robot import (
    Robot,
    apply_model_error,
    draw_model_error,
    inertial_arrays,
    restore_inertial_arrays,
)
from cir_gym.validation import (
    InvalidArgument,
    as_float_array,
    check_encoder_resolution,
    check_flag,
    check_number,
)

PATHS = ("random", "segment", "circle", "figure_eight", "near_singular", "regulation")
SHAPES = ("segment", "circle", "figure_eight")  # what path="random" draws from
SITE = "flange"
#: a drawn path is kept only if CLIK on the nominal kinematics follows it (see
#: CartesianTrackingEnv._kinematically_feasible); else it is drawn again, at most this often
MAX_PATH_DRAWS = 50
MIN_SINGULAR_VALUE = 0.05  # of J (6 × 7) along the path; feasible paths stay above ~0.15
FEASIBILITY_STRIDE = 10  # control steps between the checked samples

#: half-width (rad) of the box around the home posture where starts and goals are drawn
POSTURE_SPREAD = 0.3
#: near_singular: q2 (rad) held on the joint path whose q6 crosses 0 (the 6 × 7 Jacobian
#: of the iiwa loses rank where q2 = q6 = 0: A1 ∥ A3 and A5 ∥ A7 together)
NEAR_SINGULAR_Q2 = np.deg2rad(2.0)
NEAR_SINGULAR_Q6 = 0.3  # rad: q6 goes from +0.3 to −0.3 (through 0 at mid-episode)


_ABS, _MAX = np.abs, np.max
# hot-path ufuncs called directly (np.clip/np.sum add a Python layer over the same loops)
_EXP, _SUM = np.exp, np.add.reduce
_MUL, _NEG, _ARCTAN2 = np.multiply, np.negative, np.arctan2
_EMPTY = np.empty
_sqrt = math.sqrt


def _quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of one rotation matrix (MuJoCo's C call; either sign)."""
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(R).ravel())
    return quat


class CartesianTrackingEnv(RobotEnv):
    """Track a flange pose (p̄, Q̄) with twist and acceleration on the KUKA iiwa 14, with joint
    torques: operational-space control of a redundant arm (chapter 5.2).

    ## Description
    The 7-joint arm must make its ``flange`` site follow a position and orientation reference
    (6 task coordinates, one degree of redundancy) built with :mod:`cir_gym.trajectories`:
    a straight segment, a circle or a figure eight (quintic timing law: start and end at rest)
    with the orientation interpolated by slerp (a constant-axis rotation,
    :class:`~cir_gym.trajectories.OrientationInterpolation`); or a fixed target pose
    (``path="regulation"``); or ``path="near_singular"``, a motion that passes close to a
    singularity. The simulator holds the true robot; controllers get the nominal model through
    :meth:`controller_context` (site ``flange``), so the model-error arguments (payload, mass
    scale, friction) are unknown to them — exactly as in ``JointTracking-v1``, whose
    :class:`~cir_gym.robot.ModelError` and ``MODEL_ERROR_RANGES`` are reused unchanged.

    The shared operational-space science (orientation errors, the analytic Jacobian of the pose
    error, J̇q̇, Λ(q), the dynamically consistent pseudo-inverse) is in
    :mod:`cir_gym.operational_space`.

    **Workspace.** Every path starts at the flange pose of a start posture q(0) drawn uniformly
    in home ± 0.3 rad per joint (home = (0, 0.6, 0, −1.4, 0, 0.9, 0) rad: flange at
    (0.63, 0, 0.42) m pointing down), so the arm starts exactly on the reference:

    | path | reference |
    |---|---|
    | segment | p(0) → p(0) + d, ‖d‖ ~ U(0.1, 0.25) m in a random direction |
    | circle | one turn of radius U(0.05, 0.12) m through p(0), random plane |
    | figure_eight | one turn of a 1:2 Lissajous, half-axes U(0.05, 0.12) × U(0.03, 0.08) m, centred on p(0), random plane |
    | random | one of the three above, uniformly |
    | near_singular | the flange pose along a joint-space quintic in which q6 goes from +0.3 to −0.3 rad with q2 = 2°: at mid-episode the arm is within 2° of q2 = q6 = 0, where its 6 × 7 Jacobian loses rank (A1 ∥ A3 and A5 ∥ A7); q6 = 0 alone does not make the redundant arm singular |
    | regulation | a constant pose, the flange pose of a goal posture in home ± 0.3 rad; the start is another such posture |

    Segments, circles and figure eights rotate by U(0.2, 0.6) rad about a random axis over the
    episode (quintic timing), all reaching their end at ``episode_duration``. A drawn path is
    kept only if closed-loop inverse kinematics on the nominal kinematics follows it from q(0)
    inside the joint limits with the smallest singular value of J above 0.05; otherwise it is drawn again (some draws leave the reachable workspace, e.g.
    seed 1001's, where every operational-space law saturated). A seed whose first draw passes
    keeps the path it had before this check.

    ## Action Space
    ``Box(-1, 1, (7,), float32)``: τ = a ⊙ τ_max with τ_max = (320, 320, 176, 176, 110, 40,
    40) N m. Finite values outside [-1, 1] are clipped (counted as saturated); NaN/inf or a
    wrong shape raise ``ValueError``.

    ## Observation Space
    ``Dict`` of float64 arrays (SI units, world = base frame):

    | key | shape | meaning | bounds | unit |
    |---|---|---|---|---|
    | q | 7 | measured joint positions (quantized to ``encoder_resolution``) | ±2π | rad |
    | qd | 7 | measured joint velocities (difference of the measured positions when quantized) | ±50 | rad/s |
    | x | 3 | flange position p = k(q) of the measured q | ±3 | m |
    | quat | 4 | flange orientation (w, x, y, z), on the hemisphere of ``quat_ref`` | ±1 | |
    | twist | 6 | flange twist [v; ω] = J(q) q̇ of the measured q, q̇ | ±50 | m/s, rad/s |
    | x_ref | 3 | p̄(t) | ±3 | m |
    | quat_ref | 4 | Q̄(t) (w, x, y, z), continuous in time | ±1 | |
    | twist_ref | 6 | [ṗ̄; ω̄] | ±50 | m/s, rad/s |
    | acc_ref | 6 | [p̈̄; ω̄̇] | ±500 | m/s², rad/s² |

    **Quaternion signs (one convention for both).** Q and −Q are the same rotation. Q̄(t) is
    continuous: Q̄(0) has w ≥ 0 and each next sample the sign closer to the previous one;
    ``quat`` is the sign of the measured orientation with Q·Q̄(t) ≥ 0. So both are continuous
    while the error stays below π, and Q̄ − Q is small when the error is (no flips).

    ## Rewards
    r = r_tracking + r_torque + r_action_rate + r_following_error + r_diverged, each in
    ``info["reward_<name>"]``:
    - r_tracking = −(1 − (1/3) Σ_s exp(−e² / s²)) with the pose error
      e² = ‖p̄ − p‖² + (``orientation_scale`` θ̃)², θ̃ the orientation error angle, and
      s ∈ ``error_scales`` = (0.1, 0.01, 0.001) m: in [−1, 0];
    - r_torque = −``torque_weight`` ‖a‖² / 7;
    - r_action_rate = −``action_rate_weight`` ‖a_k − a_{k−1}‖² / 7;
    - r_following_error = −``following_error_penalty`` on the step the following-error
      monitor stops the episode, else 0;
    - r_diverged = −``divergence_penalty`` on the step the physics diverged, else 0.

    ## Starting State
    At rest at q(0), on the reference (+ U(±``initial_error``) rad per joint); for
    ``regulation`` at rest at a start posture away from the target pose (see Workspace).

    ## Episode End
    Truncated after ``episode_duration`` s. Terminated when the physics diverges
    (``info["diverged"] = True``; the last finite state is kept) or, like the following-error
    monitor of an industrial drive, when the position error exceeds its initial value +
    ``max_following_error`` or the orientation error angle its initial value +
    ``max_orientation_following_error`` (``info["following_error_exceeded"] = True``; the
    start offset of ``regulation`` or ``initial_error`` is not a following error). A stopped
    episode is scored over the whole horizon: its last errors are held for the steps it did
    not play.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | path | "random" | "random", "segment", "circle", "figure_eight", "near_singular", "regulation" (see Workspace) |
    | control_freq | 500.0 | control frequency (Hz); the physics step is 1 ms |
    | episode_duration | 4.0 | s |
    | payload_mass | 0.0 | unknown payload at the flange (kg) |
    | mass_scale | 1.0 | true link masses and inertias / nominal ones |
    | viscous_friction | 0.0 | true joint viscous friction (N m s/rad), unmodelled |
    | coulomb_friction | 0.0 | true joint Coulomb friction (N m), unmodelled |
    | torque_noise | 0.0 | std of Gaussian noise added to the applied torque (N m) |
    | encoder_resolution | 0.0 | position quantum of the encoders (rad, 0 = exact, else in [1e-12, 0.1]) |
    | randomize | False | per reset, draw payload_mass, mass_scale, viscous_friction, coulomb_friction from ``cir_gym.robot.MODEL_ERROR_RANGES`` (uniform), overriding those 4 arguments |
    | initial_error | 0.0 | max initial joint offset from the start posture (rad) |
    | error_scales | (0.1, 0.01, 0.001) | reward kernel widths (m, each in [1e-9, 1e3]) |
    | orientation_scale | 0.1 | metres of pose error per radian of orientation error in the reward (m/rad) |
    | torque_weight | 0.01 | weight of the torque term |
    | action_rate_weight | 0.01 | weight of the action-rate term |
    | divergence_penalty | 100.0 | reward lost when the physics diverges |
    | max_following_error | 0.2 | growth of the position error over its initial value (m) that ends the episode; None = never |
    | max_orientation_following_error | 1.0 | growth of the orientation error angle over its initial value (rad) that ends the episode |
    | following_error_penalty | 50.0 | reward lost when the following error ends the episode |
    | success_threshold | 0.01 | position error (m) to stay below after the settling window |
    | orientation_threshold | 0.05 | orientation error (rad) to stay below after the settling window |
    | settling_time | 1.0 | s: success is judged on t ≥ settling_time (at least the last step) |
    | render_mode | None | None, "human" or "rgb_array" |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    ``position_rms`` (primary, m: RMS of ‖p̄ − p‖ over the steps), ``orientation_rms`` (rad: RMS
    of the error angle θ̃ = 2 atan2(‖ε_e‖, |η_e|) of Q̄ ⊗ Q⁻¹), ``max_position_error`` (m),
    ``max_orientation_error`` (rad), ``final_position_error`` (m), ``final_orientation_error``
    (rad), ``rms_torque`` (N m), ``peak_joint_speed`` (rad/s, max |q̇_i|),
    ``peak_speed_ratio`` (max |q̇_i| / q̇_max,i: ≤ 1 within the data-sheet speed limits),
    ``joint_drift`` (rad: ‖(I − J†J)(q(T) − q(0))‖ at the last configuration, the part of the
    posture change that the task does not explain: the self-motion the redundancy let
    happen), ``saturation`` (fraction of steps with a clipped or saturated joint). Success:
    no divergence, not stopped, and both errors below ``success_threshold`` and
    ``orientation_threshold`` at every step with t ≥ ``settling_time`` (never judged on the
    start offset of ``regulation``).

    ## Reference controllers
    ``baselines.available("cir_gym/CartesianTracking-v0")``: os_pd_gravity (regulation),
    os_inverse_dynamics, os_inverse_dynamics_dls, os_khatib.

    ## Version History
    - v0: initial version (with the kinematic feasibility check of the drawn paths).
    """

    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec("position_rms", "m", "lower", "RMS flange position error"),
        MetricSpec("orientation_rms", "rad", "lower", "RMS flange orientation error angle"),
        MetricSpec("max_position_error", "m", "lower", "max flange position error"),
        MetricSpec("max_orientation_error", "rad", "lower", "max orientation error angle"),
        MetricSpec("final_position_error", "m", "lower", "position error at the last step"),
        MetricSpec("final_orientation_error", "rad", "lower", "orientation error at the end"),
        MetricSpec("rms_torque", "N m", "lower", "RMS joint torque"),
        MetricSpec("peak_joint_speed", "rad/s", "lower", "max joint speed"),
        MetricSpec("peak_speed_ratio", "", "lower", "max joint speed / its limit"),
        MetricSpec("joint_drift", "rad", "lower", "self-motion over the episode"),
        MetricSpec("saturation", "", "lower", "fraction of steps with a saturated joint"),
    )
    primary_metric: ClassVar[str] = "position_rms"
    reward_arguments: ClassVar[frozenset[str]] = frozenset((
        "error_scales", "orientation_scale", "torque_weight", "action_rate_weight",
        "divergence_penalty", "following_error_penalty",
    ))
    leaderboard_variants: ClassVar[dict[str, dict[str, Any]]] = {
        "exact model": {},
        "unknown 3 kg payload": {"payload_mass": 3.0},
        "near singular": {"path": "near_singular"},
    }
    robot_name: ClassVar[str] = "iiwa14"

    def __init__(
        self,
        path: str = "random",
        control_freq: float = 500.0,
        episode_duration: float = 4.0,
        payload_mass: float = 0.0,
        mass_scale: float = 1.0,
        viscous_friction: float = 0.0,
        coulomb_friction: float = 0.0,
        torque_noise: float = 0.0,
        encoder_resolution: float = 0.0,
        randomize: bool = False,
        initial_error: float = 0.0,
        error_scales: tuple[float, ...] = (0.1, 0.01, 0.001),
        orientation_scale: float = 0.1,
        torque_weight: float = 0.01,
        action_rate_weight: float = 0.01,
        divergence_penalty: float = 100.0,
        max_following_error: float | None = 0.2,
        max_orientation_following_error: float = 1.0,
        following_error_penalty: float = 50.0,
        success_threshold: float = 0.01,
        orientation_threshold: float = 0.05,
        settling_time: float = 1.0,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ) -> None:
        if path not in PATHS:
            raise InvalidArgument(f"path must be one of {PATHS}, got {path!r}")
        self.path = path
        self.model_error = model_error_arguments(
            payload_mass, mass_scale, viscous_friction, coulomb_friction
        )
        self.torque_noise = check_number("torque_noise", torque_noise, 0.0, 1000.0)
        self.encoder_resolution = check_encoder_resolution(encoder_resolution)
        self.randomize = check_flag("randomize", randomize)
        self.initial_error = check_number("initial_error", initial_error, 0.0, 1.0)
        scales = np.atleast_1d(as_float_array("error_scales", error_scales))
        if scales.ndim != 1 or scales.size == 0 or not np.all((scales >= 1e-9) & (scales <= 1e3)):
            raise InvalidArgument(
                f"error_scales must be numbers in [1e-9, 1e3] m, got {error_scales!r}"
            )
        self.error_scales = scales
        self.orientation_scale = check_number("orientation_scale", orientation_scale, 0.0, 100.0)
        self.torque_weight = check_number("torque_weight", torque_weight, 0.0, 10.0)
        self.action_rate_weight = check_number("action_rate_weight", action_rate_weight, 0.0, 10.0)
        self.divergence_penalty = check_number("divergence_penalty", divergence_penalty, 0.0, 1e6)
        self.max_following_error = (
            None
            if max_following_error is None
            else check_number("max_following_error", max_following_error, 0.0, 100.0, low_open=True)
        )
        self.max_orientation_following_error = check_number(
            "max_orientation_following_error",
            max_orientation_following_error,
            0.0,
            10.0,
            low_open=True,
        )
        self.following_error_penalty = check_number(
            "following_error_penalty", following_error_penalty, 0.0, 1e6
        )
        self.success_threshold = check_number(
            "success_threshold", success_threshold, 0.0, 10.0, low_open=True
        )
        self.orientation_threshold = check_number(
            "orientation_threshold", orientation_threshold, 0.0, 10.0, low_open=True
        )
        self.settling_time = check_number("settling_time", settling_time, 0.0, 3600.0)

        self.robot = Robot.from_name(self.robot_name)  # the simulator's (true) robot
        self._nominal_arrays = inertial_arrays(self.robot.model)
        apply_model_error(self.robot.model, self.model_error)
        super().__init__(
            self.robot.model,
            control_freq=control_freq,
            episode_duration=episode_duration,
            render_mode=render_mode,
            width=width,
            height=height,
        )
        n = self.n = self.robot.n
        self.torque_limit = self.robot.torque_limit.copy()
        self._qa, self._da = self.robot.qpos_adr, self.robot.dof_adr
        self._site = self.robot.site_id(SITE)
        self.action_space = spaces.Box(-1.0, 1.0, (n,), dtype=np.float32)
        self._obs_bounds = {
            "q": (n, 2 * np.pi),
            "qd": (n, 50.0),
            "x": (3, 3.0),
            "quat": (4, 1.0),
            "twist": (6, 50.0),
            "x_ref": (3, 3.0),
            "quat_ref": (4, 1.0),
            "twist_ref": (6, 50.0),
            "acc_ref": (6, 500.0),
        }
        self.observation_space = spaces.Dict(
            {
                k: spaces.Box(-b, b, (size,), dtype=np.float64)
                for k, (size, b) in self._obs_bounds.items()
            }
        )
        # the observation is built in one flat buffer per step (views handed out, one clip)
        ends = np.cumsum([size for size, _ in self._obs_bounds.values()])
        self._obs_slices = {
            key: slice(int(end - size), int(end))
            for (key, (size, _)), end in zip(self._obs_bounds.items(), ends, strict=True)
        }
        self._obs_high = np.concatenate([np.full(size, b) for size, b in self._obs_bounds.values()])
        self._obs_low = -self._obs_high
        self._obs_size = self._obs_high.size
        at = self._obs_slices
        self._refs_at = slice(at["x_ref"].start, at["acc_ref"].stop)  # x_ref ... acc_ref
        self._q_at, self._qd_at = index_view(self._qa), index_view(self._da)
        self._scales_sq = self.error_scales**2  # the reward's s²
        self._jac = np.zeros((6, self.model.nv))  # mj_jacSite's [J_P; J_O] on self.data
        self._jac_rows = (self._jac[:3], self._jac[3:])  # its outputs (views of _jac)
        self._kernels = np.zeros(self._scales_sq.size)  # the reward's exp(−e² / s²)
        # (index, s²) pairs: −e² / s² divided in Python floats (IEEE, as numpy's divide)
        self._scales_sq_items = tuple(enumerate(self._scales_sq.tolist()))
        # numpy's arctan2 (not libm's: they differ in the last bit) on 0-d arrays: the
        # ufunc's cheapest call (no conversion of Python floats)
        self._atan2_args = (np.zeros(()), np.zeros(()), np.zeros(()))
        self._whole = self.model.nv == n and np.array_equal(self._da, np.arange(n))
        self._site_views: tuple[np.ndarray, ...] = ()
        steps = self.max_steps
        # the reference, one row per control instant: [p̄ (3), Q̄ (4), [ṗ̄; ω̄] (6), [p̈̄; ω̄̇] (6)],
        # the observation's last four entries in its order (one copy per step); _x_ref,
        # _quat_ref, _twist_ref and _acc_ref are views of its columns
        self._refs = np.zeros((steps + 1, 19))
        self._ref_views()
        # the observation's views in the key order above (step builds its dict from these)
        self._obs_slice_tuple = tuple(self._obs_slices.values())
        # qpos/qvel are the robot's joints (the iiwa's model): copied without an index view
        self._joints_whole = (
            self.model.nq == n and self._whole and np.array_equal(self._qa, np.arange(n))
        )
        self._pos_err = np.zeros(steps)  # ‖p̄ − p‖ per step (m)
        self._ang_err = np.zeros(steps)  # θ̃ per step (rad)
        self._tau = np.zeros((steps, n))
        self._qd_true = np.zeros((steps, n))  # the true q̇ per step (|q̇|: at the metrics)
        self._sat = np.zeros(steps, dtype=bool)
        self._k = 0
        self._k_scored = 0
        self._a_prev = np.zeros(n)
        self._q_meas_prev = np.zeros(n)
        self._q_start = np.zeros(n)
        self._limits = (0.0, 0.0)
        self.episode_model_error = self.model_error

    # ------------------------------------------------------------------ reference
    def _home(self) -> np.ndarray:
        return self.model.key("home").qpos[self._qa].copy()

    def _posture(self, rng: np.random.Generator) -> np.ndarray:
        return self._home() + rng.uniform(-POSTURE_SPREAD, POSTURE_SPREAD, self.n)

    def _unit(self, rng: np.random.Generator) -> np.ndarray:
        v = rng.standard_normal(3)
        return v / np.linalg.norm(v)

    def _make_reference(self) -> np.ndarray:
        """Fill the reference arrays (every control instant); return the start posture q(0)."""
        rng = self.np_random
        T = self.max_steps * self.dt
        t = np.arange(self.max_steps + 1) * self.dt
        if self.path == "near_singular":
            return self._joint_space_reference(rng, T, t)
        q0 = self._posture(rng)
        p0, R0 = self.robot.site_pose(self._site, q0)
        if self.path == "regulation":
            p1, R1 = self.robot.site_pose(self._site, self._posture(rng))
            self._x_ref[:] = p1
            self._quat_ref[:] = traj.quat_from_matrix(R1)
            self._twist_ref[:] = 0.0
            self._acc_ref[:] = 0.0
            return q0
        shape = SHAPES[rng.integers(len(SHAPES))] if self.path == "random" else self.path
        timing = traj.TimingLaw.quintic(T)
        normal = self._unit(rng)
        if shape == "segment":
            curve: Any = traj.Segment(p0, p0 + rng.uniform(0.1, 0.25) * self._unit(rng), timing)
        elif shape == "circle":
            r = rng.uniform(0.05, 0.12)
            u = traj.Circle(p0, r, timing, normal=normal).u  # the plane's first axis
            curve = traj.Circle(p0 - r * u, r, timing, normal=normal)  # θ₀ = 0 at p0
        else:
            curve = traj.FigureEight(
                p0, rng.uniform(0.05, 0.12), rng.uniform(0.03, 0.08), timing, normal=normal
            )
        turn = traj.matrix_from_axis_angle(self._unit(rng), rng.uniform(0.2, 0.6))
        orient = traj.OrientationInterpolation(R0, R0 @ turn, timing)
        p, v, a = curve.evaluate(t)
        R, w, wd = orient.evaluate(t)
        self._x_ref[:] = p
        self._quat_ref[:] = traj.quat_from_matrix(R)
        self._twist_ref[:] = np.concatenate((v, w), axis=1)
        self._acc_ref[:] = np.concatenate((a, wd), axis=1)
        return q0

    def _joint_space_reference(
        self, rng: np.random.Generator, T: float, t: np.ndarray
    ) -> np.ndarray:
        """near_singular: the flange pose, twist J q̇ and acceleration J q̈ + J̇ q̇ along a
        joint quintic through q2 = 2°, q6 = 0 (exact kinematics: the model errors are in the
        masses only)."""
        qa, qb = self._posture(rng), self._posture(rng)
        qa[1] = qb[1] = NEAR_SINGULAR_Q2
        qa[5], qb[5] = NEAR_SINGULAR_Q6, -NEAR_SINGULAR_Q6
        qs, qds, qdds = traj.QuinticPolynomial(qa, qb, T).evaluate(t)
        for k, (q, qd, qdd) in enumerate(zip(qs, qds, qdds, strict=True)):
            p, R = self.robot.site_pose(self._site, q)
            J = self.robot.jacobian(self._site, q)
            self._x_ref[k] = p
            self._quat_ref[k] = _quat(R)
            self._twist_ref[k] = J @ qd
            self._acc_ref[k] = J @ qdd + self.robot.jacobian_dot_qdot(self._site, q, qd)
        return qa

    def _ref_views(self) -> None:
        """The reference's columns of ``self._refs`` (views: what reset writes, step reads)."""
        refs = self._refs
        self._x_ref, self._quat_ref = refs[:, 0:3], refs[:, 3:7]
        self._twist_ref, self._acc_ref = refs[:, 7:13], refs[:, 13:19]

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._ref_views()  # pickled views come back as copies
        self._jac_rows = (self._jac[:3], self._jac[3:])

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        rng = self.np_random
        if self.randomize:
            self.episode_model_error = draw_model_error(rng)
            restore_inertial_arrays(self.model, self._nominal_arrays)
            apply_model_error(self.model, self.episode_model_error)
            self.robot.invalidate()
        for _ in range(MAX_PATH_DRAWS):
            q0 = self._make_reference()
            self._quat_ref[:] = osp.continuous_quats(self._quat_ref)
            if self.path in ("regulation", "near_singular") or self._kinematically_feasible(q0):
                break
        else:
            raise RuntimeError(
                f"no kinematically feasible {self.path!r} path in {MAX_PATH_DRAWS} draws"
            )
        if self.initial_error > 0:
            q0 = q0 + rng.uniform(-self.initial_error, self.initial_error, self.n)
        self._reset_physics(q0, np.zeros(self.n))
        self._q_start[:] = q0
        self._k = 0
        self._k_scored = 0
        self._a_prev = np.zeros(self.n)  # step keeps the action array itself (its own copy)
        self._q_meas_prev[:] = self._quantize(q0)
        e_pos, e_ang = self._errors(0)
        follow = self.max_following_error
        self._limits = (
            np.inf if follow is None else e_pos + follow,
            np.inf if follow is None else e_ang + self.max_orientation_following_error,
        )
        return self._obs(), {"model_error": self.episode_model_error}

    def _kinematically_feasible(self, q0: np.ndarray) -> bool:
        """Whether closed-loop inverse kinematics on the nominal kinematics follows the reference
        from q0 inside the joint limits with the smallest singular value of J above ``MIN_SINGULAR_VALUE`` (checked every ``FEASIBILITY_STRIDE``
        control steps: q̇ = J⁺(ẋ̄ + K_clik e), K_clik = 1 / (2 · stride · dt))."""
        r, site = self.robot, self._site
        stride = FEASIBILITY_STRIDE
        h = stride * self.dt
        gain = 0.5 / h
        q = q0.copy()
        for k in range(0, self.max_steps + 1, stride):
            J = r.jacobian(site, q)
            JJt = J @ J.T
            if np.sqrt(max(np.linalg.eigvalsh(JJt)[0], 0.0)) < MIN_SINGULAR_VALUE:
                return False
            p, R = r.site_pose(site, q)
            e = np.concatenate(
                (
                    self._x_ref[k] - p,
                    osp.rotvec_error(self._quat_ref[k], traj.quat_from_matrix(R)),
                )
            )
            q = q + h * (J.T @ np.linalg.solve(JJt, self._twist_ref[k] + gain * e))
            if np.any(q < r.lower) or np.any(q > r.upper):
                return False
        return True

    def _errors(self, k: int) -> tuple[float, float]:
        """‖p̄_k − p‖ (m) and θ̃ (rad) of the true flange pose now.

        Scalar arithmetic bit-identical to ``np.linalg.norm`` and
        :func:`~cir_gym.operational_space.orientation_angle` (the step's hot path).
        """
        p, R = self.robot.site_pose(self._site, self.data.qpos[self._qa])
        return self._errors_at(k, p, R)

    def _errors_at(self, k: int, p: np.ndarray, R: np.ndarray) -> tuple[float, float]:
        """:meth:`_errors` of a flange pose ``p`` (3,), ``R`` (3, 3) or flat (9,)."""
        d = self._x_ref[k] - p
        e_pos = math.sqrt(float(d.dot(d)))  # = np.linalg.norm(d): the same BLAS dot
        e_ang = osp.quat_angle(self._quat_ref[k].tolist(), _quat(R).tolist())
        return e_pos, e_ang

    def _refresh_views(self, d: mujoco.MjData) -> None:
        """RobotEnv's views, and the flange site's rows of ``d.site_xpos``/``site_xmat``."""
        super()._refresh_views(d)
        self._site_views = (d.site_xpos[self._site], d.site_xmat[self._site])

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state["_site_views"] = ()  # rebuilt on the new MjData by _simulate
        return state

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        k = self._k
        if k >= self.max_steps:
            raise RuntimeError("step() called after the episode ended; call reset()")
        a, _, peak = self._check_action_peak(action)
        tau = _MUL(a, self.torque_limit, self._tau[k])  # recorded without the noise
        if self.torque_noise > 0:
            tau = tau + self.torque_noise * self.np_random.standard_normal(self.n)
        exact = self.encoder_resolution <= 0  # measured q = true q: one kinematics for both
        if not exact:  # the previous measurement, for the velocity estimate
            self._q_meas_prev[:] = self._quantize(self.data.qpos[self._qa])
        diverged = self._simulate(tau)
        self._k = k1 = k + 1
        if exact:  # _flange_now inlined: the kinematics of self.data now
            m, d = self.model, self.data
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            obs, buf, qd, e_pos, e_ang = self._obs_errors(k1, *self._site_views)
            self._qd_true[k] = qd  # (obs["qd"] before its clip)
        else:
            e_pos, e_ang = self._errors(k1)
            self._qd_true[k] = self._views[2][self._qd_at]  # views: set by _simulate
        self._pos_err[k] = e_pos
        self._ang_err[k] = e_ang
        self._sat[k] = peak >= 1.0  # clipped (peak 1), or an entry at ±1

        e_sq = e_pos**2 + (self.orientation_scale * e_ang) ** 2
        kernel = self._kernels
        for i, s_sq in self._scales_sq_items:
            kernel[i] = -e_sq / s_sq
        _EXP(kernel, kernel)
        size = kernel.size
        if size < 8:  # = np.mean: below 8 terms numpy's sum adds from left to right
            total = 0.0
            for term in kernel.tolist():
                total += term
        else:
            total = float(_SUM(kernel))
        r_track = -(1.0 - total / size)
        n = self.n
        r_torque = -self.torque_weight * float(a.dot(a)) / n
        da = a - self._a_prev
        r_rate = -self.action_rate_weight * float(da.dot(da)) / n
        r_div = -self.divergence_penalty if diverged else 0.0
        limit_pos, limit_ang = self._limits
        stopped = not diverged and (e_pos > limit_pos or e_ang > limit_ang)
        r_follow = -self.following_error_penalty if stopped else 0.0
        self._a_prev = a  # a new array of _check_action_peak's, never the caller's
        reward = r_track + r_torque + r_rate + r_follow + r_div

        terminated = diverged or stopped
        truncated = k1 >= self.max_steps and not terminated
        info: dict[str, Any] = {
            "reward_tracking": r_track,
            "reward_torque": r_torque,
            "reward_action_rate": r_rate,
            "reward_following_error": r_follow,
            "reward_diverged": r_div,
            "position_error": e_pos,
            "orientation_error": e_ang,
            "following_error_exceeded": stopped,
            "diverged": diverged,
        }
        if stopped:  # scored over the whole horizon: the last errors held
            self._pos_err[k1:] = e_pos
            self._ang_err[k1:] = e_ang
            self._k_scored = self.max_steps
        if terminated or truncated:
            metrics = self.episode_metrics()
            info["episode_metrics"] = metrics
            info["is_success"] = bool(not terminated and self._settled())
        if exact:
            CLIP(buf, self._obs_low, self._obs_high, buf)
        else:
            obs = self._obs()
        return obs, reward, terminated, truncated, info

    def _flange_now(self) -> tuple[np.ndarray, np.ndarray]:
        """The flange's position (3,) and rotation (9,, row-major) at the simulator's q now,
        as views of ``self.data``: its kinematics (mj_kinematics, mj_comPos: what
        ``Robot.site_pose``/``jacobian`` run on the robot's own MjData for the same q, so the
        same numbers) recomputed in place. The next ``mj_step`` recomputes every such field
        from qpos and qvel, so the physics is untouched. (``step`` runs these two calls
        inline.)"""
        m, d = self.model, self.data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        return self._site_views

    def _obs_exact(self, x: np.ndarray, R: np.ndarray) -> dict[str, np.ndarray]:
        """:meth:`_obs` without encoder quantisation, from the flange pose ``x``, ``R`` (flat)
        that :meth:`_flange_now` computed on ``self.data``: the observation ``step`` returns."""
        obs, buf, *_ = self._obs_errors(min(self._k, self.max_steps), x, R)
        CLIP(buf, self._obs_low, self._obs_high, buf)
        return obs

    def _obs_errors(
        self, k: int, p: np.ndarray, R: np.ndarray
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, float, float]:
        """Without encoder quantisation: the observation at control instant ``k`` (its flat
        buffer still to be clipped), that buffer, its ``qd`` view, and the errors
        ‖p̄_k − p‖ and θ̃ (:meth:`_errors`), from the flange pose ``p``, ``R`` (flat) that
        :meth:`_flange_now` computed on ``self.data``.

        The Jacobian is mj_jacSite's on ``self.data``, the call ``Robot.jacobian`` makes. The
        errors are those of :meth:`_errors_at`, operation for operation: ``np.linalg.norm``'s
        BLAS dot, and :func:`~cir_gym.operational_space.quat_angle` in Python floats (the
        sign flip of Q_e and its scalar part do not enter the angle: only ε_e's squares and
        |Q̄·Q| do) with numpy's arctan2.
        """
        m, d = self.model, self.data
        buf = _EMPTY(self._obs_size)
        s_q, s_qd, s_x, s_quat, s_twist, s_xr, s_qr, s_tr, s_ar = self._obs_slice_tuple
        q, qd, x, quat = buf[s_q], buf[s_qd], buf[s_x], buf[s_quat]
        twist, x_ref, quat_ref = buf[s_twist], buf[s_xr], buf[s_qr]
        obs = {
            "q": q,
            "qd": qd,
            "x": x,
            "quat": quat,
            "twist": twist,
            "x_ref": x_ref,
            "quat_ref": quat_ref,
            "twist_ref": buf[s_tr],
            "acc_ref": buf[s_ar],
        }
        _, qpos, qvel = self._views
        if self._joints_whole:
            q[:] = qpos
            qd[:] = qvel
        else:
            q[:] = qpos[self._q_at]
            qd[:] = qvel[self._qd_at]
        x[:] = p
        mujoco.mju_mat2Quat(quat, R)
        buf[self._refs_at] = self._refs[k]  # x_ref, quat_ref, twist_ref, acc_ref
        jac = self._jac
        jac_p, jac_r = self._jac_rows
        mujoco.mj_jacSite(m, d, jac_p, jac_r, self._site)
        (jac if self._whole else jac[:, self._da]).dot(qd, twist)  # = np.matmul: BLAS gemv
        diff = x_ref - x
        e_pos = _sqrt(float(diff.dot(diff)))  # = np.linalg.norm(d): the same BLAS dot
        q0, q1, q2, q3 = quat.tolist()
        r0, r1, r2, r3 = quat_ref.tolist()
        dot = 0.0 + r0 * q0 + r1 * q1 + r2 * q2 + r3 * q3  # osp.quat_dot(Q̄, Q) = Q·Q̄
        if dot < 0.0:  # align_quat: Q·Q̄ ≥ 0 (the error above is the same for ±Q)
            _NEG(quat, quat)
        # ε_e of Q_e = Q̄ ⊗ Q⁻¹ (trajectories.quat_mul with the conjugate's negated entries)
        ex = r0 * -q1 + r1 * q0 + r2 * -q3 - r3 * -q2
        ey = r0 * -q2 - r1 * -q3 + r2 * q0 + r3 * -q1
        ez = r0 * -q3 + r1 * -q2 - r2 * -q1 + r3 * q0
        norms = _sqrt(0.0 + r0 * r0 + r1 * r1 + r2 * r2 + r3 * r3) * _sqrt(
            0.0 + q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
        )
        eps_arr, dot_arr, angle = self._atan2_args
        eps_arr[()] = _sqrt(0.0 + ex * ex + ey * ey + ez * ez) / norms
        dot_arr[()] = abs(dot) / norms
        e_ang = 2.0 * float(_ARCTAN2(eps_arr, dot_arr, angle))
        return obs, buf, qd, e_pos, e_ang

    def _settled(self) -> bool:
        """Both errors below their thresholds at every step with t ≥ settling_time."""
        k = max(self._k, 1)
        first = min(max(int(np.ceil(self.settling_time / self.dt)) - 1, 0), k - 1)
        return bool(
            np.max(self._pos_err[first:k]) < self.success_threshold
            and np.max(self._ang_err[first:k]) < self.orientation_threshold
        )

    def episode_metrics(self) -> dict[str, float]:
        """Metrics of the episode so far (see ``metric_specs``)."""
        k = max(self._k, 1)
        scored = max(k, self._k_scored)
        pos, ang = self._pos_err[:scored], self._ang_err[:scored]
        q = self.data.qpos[self._qa]
        J = self.robot.jacobian(self._site, q)
        drift = osp.null_space_projector(J, np.linalg.pinv(J)) @ (q - self._q_start)
        speed = _ABS(self._qd_true[:k])
        return {
            "position_rms": rms_of(pos),
            "orientation_rms": rms_of(ang),
            "max_position_error": max_of(pos),
            "max_orientation_error": max_of(ang),
            "final_position_error": float(pos[-1]),
            "final_orientation_error": float(ang[-1]),
            "rms_torque": rms_of(self._tau[:k]),
            "peak_joint_speed": max_of(speed),
            "peak_speed_ratio": max_of(speed / self.robot.velocity_limit),
            "joint_drift": float(np.linalg.norm(drift)),
            "saturation": mean_of(self._sat[:k]),
        }

    # ------------------------------------------------------------------ observation
    def _quantize(self, q: np.ndarray) -> np.ndarray:
        res = self.encoder_resolution
        return np.round(q / res) * res if res > 0 else q.copy()

    def _obs(self) -> dict[str, np.ndarray]:
        """The observation: one new flat buffer, filled, clipped to the bounds once, handed
        out as views (each step's arrays are new; nothing is shared with the env's state)."""
        k = min(self._k, self.max_steps)
        buf = np.empty(self._obs_high.size)
        v = {key: buf[sl] for key, sl in self._obs_slices.items()}
        q, qd = v["q"], v["qd"]
        q[:] = self._quantize(self.data.qpos[self._qa])
        if self.encoder_resolution <= 0:
            qd[:] = self.data.qvel[self._da]
        elif self._k > 0:
            np.divide(q - self._q_meas_prev, self.dt, out=qd)
        else:
            qd[:] = 0.0
        x, R = self.robot.site_pose(self._site, q)
        np.matmul(self.robot.jacobian(self._site, q), qd, out=v["twist"])
        return self._finish_obs(buf, v, k, x, R.ravel())

    def _finish_obs(
        self, buf: np.ndarray, v: dict[str, np.ndarray], k: int, x: np.ndarray, R: np.ndarray
    ) -> dict[str, np.ndarray]:
        """Fill the flange pose (``x``, flat ``R``) and the references at sample ``k`` into
        the views ``v`` of ``buf``, clip ``buf`` to the bounds once, return ``v``."""
        v["x"][:] = x
        quat_ref = self._quat_ref[k]
        quat = v["quat"]
        mujoco.mju_mat2Quat(quat, R)
        if osp.quat_dot(quat.tolist(), quat_ref.tolist()) < 0.0:  # align_quat: Q·Q̄ ≥ 0
            np.negative(quat, out=quat)
        v["x_ref"][:] = self._x_ref[k]
        v["quat_ref"][:] = quat_ref
        v["twist_ref"][:] = self._twist_ref[k]
        v["acc_ref"][:] = self._acc_ref[k]
        CLIP(buf, self._obs_low, self._obs_high, out=buf)
        return v

    def controller_context(self) -> TaskContext:
        return TaskContext(
            robot=self.robot_name,
            dt=self.dt,
            action_kind="joint_torque",
            action_scale=self.torque_limit.copy(),
            site=SITE,
            extras={"path": self.path},
        )

    # ------------------------------------------------------------------ pictures
    def draw_task(self, scene: Any) -> None:
        """The reference path, the target frame (reference) and the flange's frame."""
        from cir_gym import rendering

        k = min(self._k, self.max_steps)
        if self.path != "regulation":
            rendering.add_polyline(
                scene, self._x_ref, 0.004, rendering.REFERENCE, max_segments=rendering.TRACE_SAMPLES
            )
        rendering.add_frame(
            scene, self._x_ref[k], traj.matrix_from_quat(self._quat_ref[k]), 0.12, 0.006, alpha=0.5
        )
        rendering.add_sphere(scene, self._x_ref[k], 0.015, rendering.TARGET)
        p, R = self.robot.site_pose(self._site, self.data.qpos[self._qa])
        rendering.add_frame(scene, p, R, 0.08, 0.004)

    def caption(self) -> str:
        """``t``, the position error (mm) and the orientation error (deg) now."""
        k = min(self._k, self.max_steps)
        e_pos, e_ang = self._errors(k)
        return (
            f"t = {k * self.dt:5.2f} s  |p_ref - p| = {1e3 * e_pos:7.2f} mm  "
            f"angle {np.rad2deg(e_ang):6.2f} deg"
        )
