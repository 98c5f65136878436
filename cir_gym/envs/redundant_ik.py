"""RedundantIK: closed-loop inverse kinematics and the use of redundancy (chapter 1).

Two kinematic environments, one per arm: the action is a joint-velocity command integrated
exactly over the control period (q ← q + Δt q̇, then forward kinematics), with no dynamics. A
redundant arm (n > m) tracks a closed task-space path; a secondary objective (manipulability,
distance from joint limits, obstacle clearance) is scored and can be optimised in the null
space of J.

This module holds the two documentation pages and each arm's reference; the task they share
(spaces, reset, step, reward, metrics) is :mod:`cir_gym.envs.redundant_ik_base`, the arms'
facts and defaults :mod:`cir_gym.envs.redundant_ik_config`, the episode draws and pictures
:mod:`cir_gym.envs.redundant_ik_scene`, and the science :mod:`cir_gym.redundancy` and
:mod:`cir_gym.self_motion`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from cir_gym.envs import redundant_ik_scene as scene
from cir_gym.envs.base import RobotEnv
from cir_gym.envs.redundant_ik_base import RedundantIKBase
from cir_gym.envs.redundant_ik_config import IIWA14, PLANAR3R, RedundantIKRobot
from cir_gym.metrics import MetricSpec
from cir_gym.self_motion import Reference

__all__ = [
    "REDUNDANT_IK_ENVIRONMENTS",
    "RedundantIK7Env",
    "RedundantIKEnv",
]


class RedundantIKEnv(RedundantIKBase):
    """Track a closed planar path with the end effector of a 3R planar arm (n = 3, m = 2).

    ## Description
    The redundancy-resolution problem of chapter 1: the `planar3r` arm (links 0.5, 0.4, 0.3 m
    in the plane z = 0) must move its end effector (site ``ee``) along a closed path, with one
    degree of redundancy left (dim ker J = 1). Kinematic control: the action is a joint-velocity
    command integrated exactly over the control period (q ← q + Δt q̇, then forward kinematics);
    there are no dynamics. Each episode draws a circle, an ellipse or a figure eight (centre at
    0.5–0.8 m from the base within ±0.8 rad of the home end-effector direction, size
    0.1–0.25 m, aspect 0.5–1, random start angle and direction) traced once with a quintic
    timing law. ``objective`` selects the secondary task the reward scores:
    "manipulability" (w = sqrt(det JJᵀ)), "joint_limits" (one joint's range narrowed per episode,
    see Starting State) or "obstacle" (a circle in the plane, drawn as a cylinder, placed on
    the sweep of links 1–2 under minimum-norm motion, see Starting State). Clearance is
    computed analytically: the distance from the obstacle's centre to each link capsule's
    segment minus the capsule and obstacle radii (negative when they intersect).

    Batched: :class:`cir_gym.envs.redundant_ik_vector.RedundantIKVectorEnv` steps N copies of this env
    (their kinematics in one ``mujoco.batch.Batch`` call), each copy equal to this env.

    ## Action Space
    ``Box(-1, 1, (3,), float32)``: q̇ = a ⊙ q̇_max with q̇_max = (2, 2, 2) rad/s. Finite values
    outside [-1, 1] are clipped (so commands beyond the velocity limits are saturated); NaN/inf
    or a wrong shape raise ``ValueError``.

    ## Observation Space
    ``Dict`` of float64 arrays (values clipped to the bounds):

    | key | shape | meaning | bounds | unit |
    |---|---|---|---|---|
    | q | (3,) | joint positions | ±2π | rad |
    | x | (2,) | end-effector position (x, y) | ±3 | m |
    | x_ref | (2,) | reference position x̄(t) | ±3 | m |
    | xd_ref | (2,) | reference velocity x̄̇(t) | ±10 | m/s |
    | q_lower | (3,) | this episode's lower joint limits | ±2π | rad |
    | q_upper | (3,) | this episode's upper joint limits | ±2π | rad |
    | obstacle | (3,) | obstacle centre (x, y) and radius; (10, 10, 0) when there is none | ±20 | m |

    ## Rewards
    r = r_tracking + r_orientation + r_secondary + r_velocity + r_termination, each in
    ``info["reward_<name>"]``:
    - r_tracking = −(1 − (1/3) Σ_s exp(−‖x̄ − x‖² / s²)), s ∈ ``error_scales``, in [−1, 0];
    - r_orientation = 0 (no orientation task on the plane);
    - r_secondary = −``secondary_weight`` c, c ∈ [0, 1]: exp(−w / 0.1) for "manipulability",
      −8 w_jl(q) = (4/n) Σ ((q_i − q̄_i)/(q_iM − q_im))² for "joint_limits",
      exp(−max(clearance, 0) / 0.05 m) for "obstacle";
    - r_velocity = −``velocity_weight`` ‖a‖² / 3;
    - r_termination = −``termination_penalty`` on the step that violates a joint limit or
      collides, else 0 (the default, 50 ≈ 1/(1 − γ) for γ = 0.98, charges a lost episode
      the cost of staying lost).

    With ``charge_unplayed_steps=True`` (the default) a terminated episode also loses, on its
    last step, the worst reward of every step it did not play, (T − k)(1 +
    ``secondary_weight`` + ``velocity_weight``) (T the lap's steps, k the steps played; the
    worst step: r_tracking = −1, a secondary cost of 1, ‖a‖² = n). Playing on can then never
    lose more than stopping: ending early never raises the return, at any discount γ ≤ 1
    (``False``: the penalty alone, 50 against up to ~1.1 per remaining step, so an arm that
    crashes into a joint limit or the obstacle early scores better than one that plays a
    poor lap to the end).

    ## Starting State
    At rest on the path: q(0) is the home keyframe (0.2, 0.8, 0.6) moved to x̄(0) by Newton
    steps q ← q + J†(x̄(0) − k(q)) (residual < 1e-12 m). For "manipulability" the redundancy
    starts badly used: of that solution and the postures of its self-motion at x̄(0) (every
    0.25 rad of arc up to ±π, ≥ 0.3 rad from every joint limit or no closer than that
    solution), q(0) is the one from which minimum-norm CLIK (q̇ = J†(x̄̇ + e/Δt)) would trace
    the lap inside the joint limits with the least manipulability over t ≥ 0.1 T, so the
    metric shows whether a controller uses the redundancy (plain CLIK can finish the lap, so
    the comparison is at equal task error). With ``initial_error`` the arm starts
    at x̄(0) + δ, ‖δ‖ = ``initial_error``. For "joint_limits" one random joint's range is
    narrowed to width ``joint_window`` with q(0) at 10–25 % of it from a random side (within
    the file's range; ``q_lower``/``q_upper`` in the observation); only a joint that the
    self-motion moves is drawn (|v_j| ≥ 0.1 for the unit null vector v of J at q(0)). For "obstacle" the
    obstacle (radius 4–7 cm) overlaps a link capsule by 5–20 mm at a random instant of the
    minimum-norm (pseudo-inverse CLIK) motion, at least radius + 8 cm away from the path and
    3 cm away from the arm at q(0), and only if a motion along the self-motion clears it by
    5 mm over the whole lap within the joint and velocity limits (``clearing_motion()`` returns
    that motion); a new path is drawn until such an obstacle exists, so every "obstacle"
    episode has one: after 20 paths ``reset`` raises ``InvalidArgument`` naming
    ``episode_duration`` (a lap too short for the links to sweep past an obstacle, e.g.
    0.5 s; the default placed one on every seed tested). The placement is why plain CLIK
    collides in every "obstacle" episode, and the "manipulability" start why it is poorly
    manipulable: by construction of the variants.
    ``reset(options={"replay": True})`` (no seed) starts the last drawn task again exactly
    (reference, obstacle, joint window, q(0)) without drawing: ~0.1 ms against up to ~0.2 s
    for an "obstacle" draw; any other option raises ``InvalidArgument``.

    ## Episode End
    Truncated after ``episode_duration`` s (one lap). Terminated when a step would cross a
    joint limit (the joint stops at the limit, ``info["joint_limit_violation"] = True``) or
    when a link touches the obstacle (``info["collision"] = True``). ``info["diverged"]`` is
    always False (kinematic simulation: actions are clipped and integrated exactly, so nothing
    can diverge). A step after the episode's end raises ``ResetNeeded``: call ``reset()``.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | objective | "manipulability" | secondary task scored: "manipulability", "joint_limits", "obstacle" |
    | control_freq | 200.0 | control frequency (Hz), Δt = 1/control_freq |
    | episode_duration | 5.0 | s: one lap of the path (quintic timing law, at rest at both ends) |
    | initial_error | 0.0 | initial task-position offset (m) in a random direction |
    | joint_window | 1.4 | width (rad) of the narrowed joint range for "joint_limits" |
    | error_scales | (0.1, 0.01, 0.001) | tracking-reward kernel widths (m, each in [1e-9, 1e3]) |
    | secondary_weight | 0.1 | weight of the secondary-objective cost |
    | velocity_weight | 0.01 | weight of the joint-velocity term |
    | termination_penalty | 50.0 | reward lost on a joint-limit violation or a collision |
    | charge_unplayed_steps | True | a terminated episode also loses the worst reward of each unplayed step (see Rewards) |
    | success_threshold | 0.001 | max position error (m) below which an episode succeeds |
    | render_mode | None | None, "human" or "rgb_array" (camera "top" looks down on the plane) |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    ``rms_task_error`` (primary, m), ``max_task_error`` (m), ``min_manipulability`` (m², higher
    is better; over t ≥ 0.1 T: the start-up tenth of the lap, where the reference barely moves
    and a controller may reconfigure the arm, is excluded), ``min_joint_limit_margin`` (rad, higher is better), ``min_clearance`` (m,
    higher is better; about 16.6 m to the far-away dummy obstacle of the other objectives),
    ``joint_drift`` (‖q(T) − q(0)‖ after the closed path, rad). A terminated episode is scored
    over the whole lap as if the arm stayed where it stopped: its error against the reference
    it no longer follows, its manipulability, margin and clearance unchanged. Success: no
    termination and ``max_task_error`` < ``success_threshold``. The leaderboard ranks each
    variant by success rate, then by the metric of its own objective
    (``leaderboard_primary_metrics``): ``min_manipulability`` ("manipulability"),
    ``min_clearance`` ("obstacle"), ``min_joint_limit_margin`` ("joint limits").

    ## Reference controllers
    ``baselines.available("cir_gym/RedundantIK-v4")``: jacobian_transpose, pseudo_inverse,
    clik, clik_dls, clik_weighted, clik_nullspace, clik_projected_gradient, clik_augmented.

    ## Version History
    - v4: the link capsules lie along each geom's z axis (the clearance, collisions, obstacle
      placement, the obstacle reward term and ``min_clearance`` used a wrong axis, off by up
      to 0.25 m; they now equal MuJoCo's ``mj_geomDistance``); ``charge_unplayed_steps`` on by
      default: a terminated episode also loses the worst reward of each unplayed step.
    - v3: an "obstacle" is kept only if a motion along the self-motion clears it over the
      whole lap within the joint and velocity limits (:meth:`clearing_motion`); v2 checked one
      instant: 15 of the 21 planar and 13 of the 16 iiwa episodes (of 100) that
      clik_nullspace collided in had no such motion. "manipulability" and "joint_limits"
      episodes are identical to v2's. Later, without a new version (observations, rewards and
      episodes unchanged): a terminated episode's metrics score the stopped arm against the
      moving reference (they held its last error, so a collision scored as good tracking);
      ``reset`` raises ``RuntimeError`` where it would have left an "obstacle" episode
      without an obstacle (never on the seeds tested).
    - v2: the "manipulability" start is the self-motion posture (≥ 0.3 rad from the limits)
      whose minimum-norm lap, inside the joint limits, is least manipulable (v1's least
      manipulable posture at t = 0 was, on the iiwa, a stationary point of w along the
      self-motion that no gradient method leaves, and on the plane said little about the lap).
    - v1: every "obstacle" episode has an obstacle (v0 left 7 % of them without); the
      "manipulability" start is the worst posture of the whole self-motion; "joint_limits"
      narrows only a joint the self-motion moves;
      ``termination_penalty`` 1000 → 50; terminated episodes are scored over the whole lap.
    - v0: initial version.
    """

    arm: ClassVar[RedundantIKRobot] = PLANAR3R
    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec("rms_task_error", "m", "lower", "RMS end-effector position error"),
        MetricSpec("max_task_error", "m", "lower", "max end-effector position error"),
        MetricSpec("min_manipulability", "m^2", "higher", "min sqrt(det(J Jᵀ))"),
        MetricSpec("min_joint_limit_margin", "rad", "higher", "min distance to a joint limit"),
        MetricSpec("min_clearance", "m", "higher", "min link–obstacle distance"),
        MetricSpec("joint_drift", "rad", "lower", "‖q(T) − q(0)‖ after the closed path"),
    )

    def __init__(
        self,
        objective: str = "manipulability",
        control_freq: float = PLANAR3R.control_freq,
        episode_duration: float = PLANAR3R.episode_duration,
        joint_window: float = PLANAR3R.joint_window,
        **kwargs: Any,
    ) -> None:
        """See ## Arguments; the arguments not named here are the same for both arms."""
        super().__init__(objective=objective, control_freq=control_freq,
                         episode_duration=episode_duration, joint_window=joint_window, **kwargs)

    def _draw_reference(self) -> Reference:
        t = self._time_grid()
        x, xd = scene.planar_path(self.np_random, self.kin.pose(self.home)[0], t)
        K = len(t)
        R = np.tile(np.eye(3), (K, 1, 1))
        quat = np.tile([1.0, 0.0, 0.0, 0.0], (K, 1))
        return Reference(x, xd, R, quat, np.zeros((K, 3)), self.dt)


class RedundantIK7Env(RedundantIKBase):
    """Track a closed 3-D path and an orientation with the tool of a 7-DoF arm (n = 7, m = 6).

    ## Description
    Chapter 1 on the `iiwa14`: the pose of site ``tcp`` (position and orientation, m = 6) must
    follow a closed path, with one degree of redundancy (the arm's self-motion, "elbow
    angle"). Kinematic control: the action is a joint-velocity command integrated exactly over
    the control period; no dynamics. Each episode draws a circle, an ellipse or a figure eight
    of size 0.05–0.15 m (aspect 0.5–1) in a random plane whose centre is within 3 cm of the home
    tcp position, traced once with a quintic timing law σ(t), and an orientation reference
    R̄(t) = Rot(r, α sin 2πσ(t)) R_home (world axis r random, α ∈ [0.1, 0.3] rad), closed as
    well; ω̄ = r α 2π cos(2πσ) σ̇. The orientation error is the rotation vector of R̄ Rᵀ
    (through its quaternion), never an Euler-angle difference. ``objective`` as in
    ``RedundantIK-v4``; the obstacle is a sphere on the sweep of links 3–5 (around the
    elbow), and the clearance is computed analytically (centre to capsule segments, minus the
    radii).

    Batched: :class:`cir_gym.envs.redundant_ik_vector.RedundantIK7VectorEnv` steps N copies of this env
    (their kinematics in one ``mujoco.batch.Batch`` call), each copy equal to this env.

    ## Action Space
    ``Box(-1, 1, (7,), float32)``: q̇ = a ⊙ q̇_max with q̇_max = (85, 85, 100, 75, 130, 135, 135)
    deg/s (data sheet, in rad/s). Finite values outside [-1, 1] are clipped; NaN/inf or a wrong
    shape raise ``ValueError``.

    ## Observation Space
    ``Dict`` of float64 arrays (values clipped to the bounds):

    | key | shape | meaning | bounds | unit |
    |---|---|---|---|---|
    | q | (7,) | joint positions | ±2π | rad |
    | x | (3,) | tcp position | ±3 | m |
    | x_ref | (3,) | reference position x̄(t) | ±3 | m |
    | xd_ref | (3,) | reference velocity | ±10 | m/s |
    | quat | (4,) | tcp orientation (w, x, y, z), on the home hemisphere (below) | ±1 | |
    | quat_ref | (4,) | reference orientation (w, x, y, z), on the home hemisphere | ±1 | |
    | omega_ref | (3,) | reference angular velocity (world frame) | ±20 | rad/s |
    | q_lower | (7,) | this episode's lower joint limits | ±2π | rad |
    | q_upper | (7,) | this episode's upper joint limits | ±2π | rad |
    | obstacle | (4,) | sphere centre and radius; (10, 10, 10, 0) when there is none | ±20 | m |

    Both quaternions take the sign with ⟨Q, Q_home⟩ ≥ 0, Q_home the tcp orientation at the
    home keyframe ((0.12, 0, 0.99, 0): the tool points down, 166° from the world frame), so
    both are continuous while the orientation stays within π of home (the reference stays
    within 0.3 rad of it); w may be negative.

    ## Rewards
    As ``RedundantIK-v4``, with r_orientation = −(1 − (1/3) Σ_s exp(−θ² / s²)), θ the
    orientation error (rad) and s ∈ 10 × ``error_scales`` (rad), and the manipulability cost
    exp(−w / 0.05); the worst step that ``charge_unplayed_steps`` charges per unplayed step is
    2 + ``secondary_weight`` + ``velocity_weight`` (r_orientation = −1 as well).

    ## Starting State
    As ``RedundantIK-v4``, from the home keyframe (0, 0.6, 0, −1.4, 0, 0.9, 0) to the pose
    (x̄(0), R̄(0)); ``initial_error`` offsets the position only.

    ## Episode End
    As ``RedundantIK-v4``.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | objective | "manipulability" | secondary task scored: "manipulability", "joint_limits", "obstacle" |
    | control_freq | 100.0 | control frequency (Hz), Δt = 1/control_freq |
    | episode_duration | 6.0 | s: one lap of the path (quintic timing law, at rest at both ends) |
    | initial_error | 0.0 | initial task-position offset (m) in a random direction |
    | joint_window | 0.6 | width (rad) of the narrowed joint range for "joint_limits" |
    | error_scales | (0.1, 0.01, 0.001) | tracking-reward kernel widths (m, each in [1e-9, 1e3]) |
    | secondary_weight | 0.1 | weight of the secondary-objective cost |
    | velocity_weight | 0.01 | weight of the joint-velocity term |
    | termination_penalty | 50.0 | reward lost on a joint-limit violation or a collision |
    | charge_unplayed_steps | True | a terminated episode also loses the worst reward of each unplayed step (see Rewards) |
    | success_threshold | 0.001 | max position error (m); the orientation must stay below 10× (rad) |
    | render_mode | None | None, "human" or "rgb_array" (MuJoCo's free camera) |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    As ``RedundantIK-v4`` plus ``rms_orientation_error`` and ``max_orientation_error`` (rad);
    manipulability of the 6×7 Jacobian (mixed units). Success: no termination,
    ``max_task_error`` < ``success_threshold`` and ``max_orientation_error`` <
    10 ``success_threshold``.

    ## Reference controllers
    ``baselines.available("cir_gym/RedundantIK7-v5")``: jacobian_transpose, pseudo_inverse,
    clik, clik_dls, clik_weighted, clik_nullspace, clik_projected_gradient, clik_augmented.

    ## Version History
    - v5: the link capsules lie along each geom's z axis (the clearance, collisions, obstacle
      placement, the obstacle reward term and ``min_clearance`` used a wrong axis, off by up
      to 0.10 m; they now equal MuJoCo's ``mj_geomDistance``); ``charge_unplayed_steps`` on by
      default: a terminated episode also loses the worst reward of each unplayed step.
    - v4: ``quat`` and ``quat_ref`` on one continuous hemisphere, ⟨Q, Q_home⟩ ≥ 0. v3 forced
      w ≥ 0 on ``quat_ref``, which flipped sign mid-episode wherever w crossed 0 (3 of the
      first 40 "manipulability" episodes), while ``quat`` (MuJoCo's ``mju_mat2Quat``,
      documented w ≥ 0) kept the sign of its largest component and so did not follow it.
      Terminated episodes scored against the moving reference and no episode without an
      obstacle, as ``RedundantIK-v3``'s later note. Otherwise as v3.
    - v0–v3: as ``RedundantIK-v4`` (v3: obstacles clearable over the whole lap; v2: the
      "manipulability" start; v1: obstacles, joint windows, termination penalty; v0: initial
      version).
    """

    arm: ClassVar[RedundantIKRobot] = IIWA14
    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec("rms_task_error", "m", "lower", "RMS tcp position error"),
        MetricSpec("max_task_error", "m", "lower", "max tcp position error"),
        MetricSpec("rms_orientation_error", "rad", "lower", "RMS tcp orientation error"),
        MetricSpec("max_orientation_error", "rad", "lower", "max tcp orientation error"),
        MetricSpec("min_manipulability", "", "higher", "min sqrt(det(J Jᵀ)) of the 6×7 J"),
        MetricSpec("min_joint_limit_margin", "rad", "higher", "min distance to a joint limit"),
        MetricSpec("min_clearance", "m", "higher", "min link–obstacle distance"),
        MetricSpec("joint_drift", "rad", "lower", "‖q(T) − q(0)‖ after the closed path"),
    )

    def __init__(
        self,
        objective: str = "manipulability",
        control_freq: float = IIWA14.control_freq,
        episode_duration: float = IIWA14.episode_duration,
        joint_window: float = IIWA14.joint_window,
        **kwargs: Any,
    ) -> None:
        """See ## Arguments; the arguments not named here are the same for both arms."""
        super().__init__(objective=objective, control_freq=control_freq,
                         episode_duration=episode_duration, joint_window=joint_window, **kwargs)

    def _draw_reference(self) -> Reference:
        p_home, R_home = self.kin.pose(self.home)
        x, xd, R, quat, omega = scene.spatial_path(
            self.np_random, p_home, R_home, self._quat_home, self._time_grid()
        )
        return Reference(x, xd, R, quat, omega, self.dt)


REDUNDANT_IK_ENVIRONMENTS: dict[str, tuple[type[RobotEnv], str]] = {
    "cir_gym/RedundantIK-v4": (
        RedundantIKEnv,
        "planar3r closed-path tracking with joint velocities; redundancy for a secondary "
        "objective (ch. 1)",
    ),
    "cir_gym/RedundantIK7-v5": (
        RedundantIK7Env,
        "iiwa14 6-D pose tracking of a closed path with joint velocities; redundancy (ch. 1)",
    ),
}
