"""CartesianTracking: track a flange pose reference with joint torques (chapter 5.2)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from cir_gym import operational_space as osp
from cir_gym.context import TaskContext
from cir_gym.envs.base import RobotEnv, model_error_arguments
from cir_gym.envs.cartesian_reference import (
    IIWA14_WORKSPACE,
    PATHS,
    SHAPES,
    PoseReference,
    draw_pose_reference,
    kinematically_feasible,
    quat_of,
)
from cir_gym.envs.cartesian_scene import cartesian_caption, draw_cartesian_tracking
from cir_gym.envs.tracking_reward import TERMS, TrackingReward
from cir_gym.metrics import MetricSpec
from cir_gym.numeric import CLIP, index_view
from cir_gym.robot import (
    Robot,
    apply_model_error,
    draw_model_error,
    inertial_arrays,
    restore_inertial_arrays,
)
from cir_gym.validation import (
    InvalidArgument,
    check_encoder_resolution,
    check_flag,
    check_number,
)

__all__ = [
    "NEAR_SINGULAR_Q2",
    "NEAR_SINGULAR_Q6",
    "PATHS",
    "SHAPES",
    "CartesianTrackingEnv",
    "flange_pose_errors",
    "following_error_exceeded",
    "held_errors",
    "observe",
    "pose_error_sq",
]

SITE = "flange"
#: near_singular: q2 (rad) held on the joint path whose q6 crosses 0 (the iiwa's 6 × 7
#: Jacobian loses rank where q2 = q6 = 0)
NEAR_SINGULAR_Q2 = IIWA14_WORKSPACE.near_singular_q2
NEAR_SINGULAR_Q6 = IIWA14_WORKSPACE.near_singular_q6  # rad: q6 from +0.3 to −0.3


# The task's arithmetic, on one env's arrays or on (N, ...) arrays of N copies (the batched
# env, cir_gym/envs/cartesian_vector.py, calls the same functions).
def flange_pose_errors(
    x_ref: np.ndarray, quat_ref: np.ndarray, x: np.ndarray, quat: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """‖p̄ − p‖ (m) and the error angle θ̃ (rad) of Q̄ ⊗ Q⁻¹, each (...), of positions p̄, p
    (..., 3) and quaternions Q̄, Q (..., 4) (either sign)."""
    d = x_ref - x
    return np.sqrt(np.sum(d * d, axis=-1)), osp.orientation_angle(quat_ref, quat)


def pose_error_sq(e_pos: np.ndarray, e_ang: np.ndarray, orientation_scale: float) -> np.ndarray:
    """The pose error e² = ‖p̄ − p‖² + (``orientation_scale`` θ̃)² (m², (...)) of r_tracking."""
    return e_pos**2 + (orientation_scale * e_ang) ** 2


def following_error_exceeded(
    e_pos: np.ndarray, e_ang: np.ndarray, limits: np.ndarray, diverged: np.ndarray
) -> np.ndarray:
    """The following-error monitor (...) bool: not diverged, and the position error (m) or
    the angle error (rad) above its limit, ``limits`` (..., 2) = (position, angle)."""
    over = np.logical_or(e_pos > limits[..., 0], e_ang > limits[..., 1])
    return np.logical_and(np.logical_not(diverged), over)


def held_errors(
    e_pos: np.ndarray, e_ang: np.ndarray, limits: np.ndarray, diverged: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The position (m) and angle (rad) errors held over a stopped or diverged episode's
    unplayed steps (...): the last errors; after a divergence at least the (finite) limits
    ``limits`` (..., 2), so a divergence never scores better than being stopped."""
    held = []
    for e, limit in ((e_pos, limits[..., 0]), (e_ang, limits[..., 1])):
        raise_to_limit = np.logical_and(diverged, np.isfinite(limit))
        held.append(np.where(raise_to_limit, np.maximum(e, limit), e))
    return held[0], held[1]


def observe(
    state: tuple[np.ndarray, ...],
    J: np.ndarray,
    reference: tuple[np.ndarray, ...],
    low: np.ndarray,
    high: np.ndarray,
) -> np.ndarray:
    """The observation as one flat vector (..., 40), clipped to [low, high].

    Args:
        state: measured q, q̇ (..., n), flange position p (..., 3) and quaternion (..., 4) (of
            either sign; put on Q̄'s hemisphere here).
        J: the flange's geometric Jacobian (..., 6, n) at q: the twist is [v; ω] = J q̇.
        reference: p̄ (..., 3), Q̄ (..., 4), [ṗ̄; ω̄] (..., 6), [p̈̄; ω̄̇] (..., 6) now.
        low, high: the bounds (40,).
    """
    q, qd, x, quat = state
    twist = np.matmul(J, qd[..., None])[..., 0]  # [v; ω] = J(q) q̇
    quat = osp.align_quat(quat, reference[1])  # on Q̄'s hemisphere
    flat = np.concatenate((q, qd, x, quat, twist, *reference), axis=-1)
    return CLIP(flat, low, high, out=flat)


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
    scale, friction) are unknown to them — exactly as in ``JointTracking-v2``, whose
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
    inside the joint limits with the smallest singular value of J above 0.05; otherwise it is
    drawn again (some draws leave the reachable workspace, e.g. seed 1001's, where every
    operational-space law saturated). The numbers are the iiwa's
    :data:`~cir_gym.envs.cartesian_reference.IIWA14_WORKSPACE`.

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

    With ``charge_unplayed_steps=True`` (the default) a stopped or diverged episode also
    loses, on its last step, the worst reward of every step it did not play, (T − k)(1 +
    ``torque_weight`` + 4 ``action_rate_weight``), so ending early never raises the return, at
    any discount γ ≤ 1 (JointTracking's rule: :class:`~cir_gym.envs.tracking_reward.TrackingReward`).

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
    not play; a diverged one too, its last finite errors held at least at the following-error
    limits (so a divergence never scores better than being stopped).

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
    | charge_unplayed_steps | True | a stopped or diverged episode also loses the worst reward of each unplayed step (see Rewards) |
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
    ``baselines.available("cir_gym/CartesianTracking-v1")``: os_pd_gravity (regulation),
    os_inverse_dynamics, os_inverse_dynamics_dls, os_khatib.

    ## Version History
    - v1: ``charge_unplayed_steps`` (default True): a stopped or diverged episode also loses the
      worst reward of each unplayed step (v0 paid for being stopped early: −62 against −485
      for a finished episode); a diverged episode is scored over the whole horizon, its last
      finite errors held at least at the following-error limits (v0: the played steps only).
      Dynamics, observations and success are v0's.
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
        "divergence_penalty", "following_error_penalty", "charge_unplayed_steps",
    ))
    leaderboard_variants: ClassVar[dict[str, dict[str, Any]]] = {
        "exact model": {},
        "unknown 3 kg payload": {"payload_mass": 3.0},
        "near singular": {"path": "near_singular"},
    }
    robot_name: ClassVar[str] = "iiwa14"
    workspace = IIWA14_WORKSPACE

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
        charge_unplayed_steps: bool = True,
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
        # the reward's weights (error_scales in m: the pose error e below)
        self.reward_model = TrackingReward.from_arguments(
            error_scales,
            "m",
            torque_weight,
            action_rate_weight,
            divergence_penalty,
            following_error_penalty,
            charge_unplayed_steps,
        )
        self.orientation_scale = check_number("orientation_scale", orientation_scale, 0.0, 100.0)
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
        # the joints' addresses in qpos and qvel (slices where evenly spaced: views)
        self._qa, self._da = index_view(self.robot.qpos_adr), index_view(self.robot.dof_adr)
        self._site = self.robot.site_id(SITE)
        self.action_space = spaces.Box(-1.0, 1.0, (n,), dtype=np.float32)
        bounds = {  # key: (size, bound)
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
            {k: spaces.Box(-b, b, (size,), dtype=np.float64) for k, (size, b) in bounds.items()}
        )
        # the observation is one flat array per step, its entries views of it: their slices
        ends = np.cumsum([size for size, _ in bounds.values()])
        self._obs_slices = {
            key: slice(int(end - size), int(end))
            for (key, (size, _)), end in zip(bounds.items(), ends, strict=True)
        }
        self._obs_high = np.concatenate([np.full(size, b) for size, b in bounds.values()])
        self._obs_low = -self._obs_high
        steps = self.max_steps
        self._set_reference(
            PoseReference(
                np.zeros((steps + 1, 3)),
                np.zeros((steps + 1, 4)),
                np.zeros((steps + 1, 6)),
                np.zeros((steps + 1, 6)),
            )
        )
        self._pos_err = np.zeros(steps)  # ‖p̄ − p‖ per step (m)
        self._ang_err = np.zeros(steps)  # θ̃ per step (rad)
        self._tau = np.zeros((steps, n))  # commanded torque per step (N m)
        self._qd_true = np.zeros((steps, n))  # the true q̇ per step (rad/s)
        self._sat = np.zeros(steps, dtype=bool)
        self._k = 0
        self._k_scored = 0
        self._a_prev = np.zeros(n)
        self._q_meas_prev = np.zeros(n)
        self._q_start = np.zeros(n)
        self._limits = np.zeros(2)  # position (m) and angle (rad) errors that stop the episode
        self.episode_model_error = self.model_error

    def _set_reference(self, reference: PoseReference) -> None:
        """Hold ``reference``: p̄ ``_x_ref``, Q̄ ``_quat_ref``, [ṗ̄; ω̄] ``_twist_ref`` and
        [p̈̄; ω̄̇] ``_acc_ref``, one row per control instant."""
        self._x_ref, self._quat_ref, self._twist_ref, self._acc_ref = reference

    def _home(self) -> np.ndarray:
        return self.model.key("home").qpos[self._qa].copy()

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        rng = self.np_random
        if self.randomize:
            self.episode_model_error = draw_model_error(rng)
            restore_inertial_arrays(self.model, self._nominal_arrays)
            apply_model_error(self.model, self.episode_model_error)
            self.robot.invalidate()
        times = np.arange(self.max_steps + 1) * self.dt
        for _ in range(self.workspace.max_draws):
            reference, q0 = draw_pose_reference(
                self.path, rng, self.robot, self._site, self._home(), times, self.workspace
            )
            if self.path in ("regulation", "near_singular") or kinematically_feasible(
                self.robot, self._site, reference, q0, self.dt, self.workspace
            ):
                break
        else:
            raise RuntimeError(
                f"no kinematically feasible {self.path!r} path in {self.workspace.max_draws} "
                f"draws"
            )
        self._set_reference(reference)
        if self.initial_error > 0:
            q0 = q0 + rng.uniform(-self.initial_error, self.initial_error, self.n)
        self._reset_physics(q0, np.zeros(self.n))
        self._q_start[:] = q0
        self._k = 0
        self._k_scored = 0
        self._a_prev = np.zeros(self.n)
        self._q_meas_prev = self._quantize(q0)
        e_pos, e_ang = self.pose_errors(0)
        follow = self.max_following_error
        self._limits = np.array(
            [
                np.inf if follow is None else e_pos + follow,
                np.inf if follow is None else e_ang + self.max_orientation_following_error,
            ]
        )
        return self._obs(), {"model_error": self.episode_model_error}

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        k = self._k  # (RobotEnv raises ResetNeeded on a step after the episode's end)
        a, _, peak = self._check_action_peak(action)
        tau = a * self.torque_limit
        self._tau[k] = tau  # recorded without the noise
        if self.torque_noise > 0:
            tau = tau + self.torque_noise * self.np_random.standard_normal(self.n)
        if self.encoder_resolution > 0:  # the reading before the step, for q̇ by differences
            self._q_meas_prev = self._quantize(self.data.qpos[self._qa])
        diverged = self._simulate(tau)
        self._k += 1

        e_pos, e_ang = self.pose_errors(self._k)
        self._pos_err[k] = e_pos
        self._ang_err[k] = e_ang
        self._qd_true[k] = self.data.qvel[self._da]
        self._sat[k] = peak >= 1.0  # clipped (peak 1), or an entry at ±1
        stopped = bool(following_error_exceeded(e_pos, e_ang, self._limits, diverged))
        error_sq = pose_error_sq(e_pos, e_ang, self.orientation_scale)
        terms = self.reward_model(
            error_sq, a, self._a_prev, diverged, stopped, self.max_steps - self._k
        )
        info: dict[str, Any] = {name: float(terms[name]) for name in TERMS}
        reward = sum(info.values())
        self._a_prev = a
        terminated = diverged or stopped
        truncated = self._k >= self.max_steps and not terminated
        info.update(
            position_error=e_pos,
            orientation_error=e_ang,
            following_error_exceeded=stopped,
            diverged=diverged,
        )
        if stopped or diverged:  # scored over the whole horizon (section Episode End)
            held_pos, held_ang = held_errors(e_pos, e_ang, self._limits, diverged)
            self._pos_err[self._k :] = held_pos
            self._ang_err[self._k :] = held_ang
            self._k_scored = self.max_steps
        if terminated or truncated:
            info["episode_metrics"] = self.episode_metrics()
            info["is_success"] = not terminated and self._settled()
        return self._obs(), reward, terminated, truncated, info

    def flange_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The true flange position p (3,) m and rotation R (3, 3) now."""
        return self.robot.site_pose(self._site, self.data.qpos[self._qa])

    def pose_errors(self, k: int) -> tuple[float, float]:
        """‖p̄_k − p‖ (m) and the error angle θ̃ of Q̄_k ⊗ Q⁻¹ (rad) of the true flange now."""
        p, R = self.flange_pose()
        e_pos, e_ang = flange_pose_errors(self._x_ref[k], self._quat_ref[k], p, quat_of(R))
        return float(e_pos), float(e_ang)

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
        scored = max(k, self._k_scored)  # a stopped episode: the whole horizon
        pos, ang = self._pos_err[:scored], self._ang_err[:scored]
        q = self.data.qpos[self._qa]
        J = self.robot.jacobian(self._site, q)
        drift = osp.null_space_projector(J, np.linalg.pinv(J)) @ (q - self._q_start)
        speed = np.abs(self._qd_true[:k])
        return {
            "position_rms": float(np.sqrt(np.mean(pos**2))),
            "orientation_rms": float(np.sqrt(np.mean(ang**2))),
            "max_position_error": float(np.max(pos)),
            "max_orientation_error": float(np.max(ang)),
            "final_position_error": float(pos[-1]),
            "final_orientation_error": float(ang[-1]),
            "rms_torque": float(np.sqrt(np.mean(self._tau[:k] ** 2))),
            "peak_joint_speed": float(np.max(speed)),
            "peak_speed_ratio": float(np.max(speed / self.robot.velocity_limit)),
            "joint_drift": float(np.linalg.norm(drift)),
            "saturation": float(np.mean(self._sat[:k])),
        }

    # ------------------------------------------------------------------ observation
    def _quantize(self, q: np.ndarray) -> np.ndarray:
        res = self.encoder_resolution
        return np.round(q / res) * res if res > 0 else q.copy()

    def _obs(self) -> dict[str, np.ndarray]:
        """The observation at step k from the measured q, q̇ (the flange pose and twist of
        the measured q), clipped to the bounds: the entries are views of one new flat array
        per call (an observation kept is never written to again)."""
        k = min(self._k, self.max_steps)
        q = self._quantize(self.data.qpos[self._qa])
        if self.encoder_resolution <= 0:
            qd = self.data.qvel[self._da]
        else:
            qd = (q - self._q_meas_prev) / self.dt if self._k > 0 else np.zeros(self.n)
        x, R = self.robot.site_pose(self._site, q)
        J = self.robot.jacobian(self._site, q)
        reference = (self._x_ref[k], self._quat_ref[k], self._twist_ref[k], self._acc_ref[k])
        flat = observe((q, qd, x, quat_of(R)), J, reference, self._obs_low, self._obs_high)
        return {key: flat[at] for key, at in self._obs_slices.items()}

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
        draw_cartesian_tracking(self, scene)

    def caption(self) -> str:
        """``t``, the position error (mm) and the orientation error (deg) now."""
        return cartesian_caption(self)
