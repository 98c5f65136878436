"""VisualServo: image-based and position-based visual servoing of the iiwa14 (chapter 7).

Two environments: an eye-in-hand camera on the flange looks at a planar target with four point
features (:class:`VisualServoEnv`, here), and a fixed camera watches four markers on the end
effector (:class:`~cir_gym.envs.visual_servo_eye_to_hand.VisualServoEyeToHandEnv`). The arm
is velocity-servoed in MuJoCo (velocity actuators with a 200 1/s bandwidth within the
data-sheet torque limits, gravity compensated); a twist action is turned into joint velocities
by the environment's own resolved-rate controller q̇ = J⁺ V through the flange Jacobian of its
nominal model, scaled down uniformly (direction kept) to the joint-velocity limits. What the
two share is in :mod:`cir_gym.envs.visual_servo_base`, the camera science (projection,
interaction matrix, pose from four points, visibility, marker detection) in
:mod:`cir_gym.vision`.
"""

from __future__ import annotations

from typing import ClassVar

import mujoco
import numpy as np

from cir_gym import rendering
from cir_gym.envs import visual_servo_scene as scene
from cir_gym.envs.base import RobotEnv
from cir_gym.envs.visual_servo_base import VisualServoBase, random_unit, rotation
from cir_gym.envs.visual_servo_eye_to_hand import VisualServoEyeToHandEnv

__all__ = ["VISUAL_SERVO_ENVIRONMENTS", "VisualServoEnv", "VisualServoEyeToHandEnv"]

class VisualServoEnv(VisualServoBase):
    """Eye-in-hand visual servoing: bring four image points to their desired positions.

    ## Description
    Chapter 7 on the `iiwa14`: the flange camera ``flange_cam`` (pinhole, 640 × 480 px,
    vertical field of view 60°: f = 415.69 px, principal point (319.5, 239.5) px; its optical
    frame, z forward and y down, is the ``flange`` site frame) looks at a planar target, four
    coloured discs at the corners of a 0.2 m square (ViSP's tutorial-ibvs-4pts target). The
    goal camera pose is fixed (joint configuration ``Q_GOAL``, camera at (0.826, 0, 0.45) m
    looking along +x, with room to back up 0.28 m along its axis); the target faces it at
    0.75 m, tilted per episode by a rotation vector
    of ≤ 0.2 rad (tilt) and turned about its normal by ≤ π. The desired features s* are the
    true camera's image of the target from the goal pose; the camera starts at a random offset
    from the goal (the moving frame's pose in the goal frame: translation ±0.12 m sideways,
    −0.25 … +0.05 m along the optical axis, rotation vector ±0.3 rad about x and y, ±1.0 rad
    about the optical axis), reachable and with every feature ≥ 40 px inside the image.
    The arm is velocity-servoed (MuJoCo velocity actuators, k_v = 200 B_ii(q_goal), within the
    data-sheet torque limits, gravity compensated): the environment's own resolved-rate
    controller turns a camera twist into q̇ = J⁺(q) V (flange Jacobian, the nominal hand-eye
    transform) scaled down uniformly to the joint-velocity limits.

    ## Action Space
    ``action="twist"``: ``Box(-1, 1, (6,), float32)``, the camera twist (v, ω) in the camera's
    optical frame, v = a[:3] · 0.3 m/s, ω = a[3:] · 1.0 rad/s. ``action="joint_velocity"``:
    ``Box(-1, 1, (7,), float32)``, q̇ = a ⊙ q̇_max (85, 85, 100, 75, 130, 135, 135) deg/s.
    Finite values outside [-1, 1] are clipped; NaN/inf or a wrong shape raise ``ValueError``.

    ## Observation Space
    ``Dict`` of float64 arrays (clipped to the bounds):

    | key | shape | meaning | bounds | unit |
    |---|---|---|---|---|
    | features | (8,) | observed features (u₁, v₁, …, u₄, v₄): red, green, blue, yellow | ±1280 | px |
    | features_ref | (8,) | desired features s* (exact) | ±1280 | px |
    | q | (7,) | joint positions | ±2π | rad |
    | image | (480, 640, 3) | the camera image, uint8 (only with ``obs_image=True``) | 0 … 255 | |

    ``features="projected"``: the exact projection by the true camera plus Gaussian noise of
    ``pixel_noise`` px per coordinate. ``features="detected"``: the camera image is rendered
    (``mujoco.Renderer``, needs an OpenGL backend: EGL or OSMesa) and each marker is found by
    its colour (:func:`cir_gym.vision.detect_markers`, centroid of its pixels); a marker not
    found keeps its last observed position and counts as a detection failure
    (``info["detection_failure"]``).
    Depth is not observed: controllers estimate it from the four points and the target model
    (``controller_context().extras["model_points"]``). Camera intrinsics (nominal) are in
    ``controller_context().extras["camera"]``.

    ## Rewards
    r = r_features + r_action + r_termination, each in ``info["reward_<name>"]``:
    - r_features = −(1 − (1/3) Σ_s exp(−e² / s²)), s ∈ (100, 10, 1) px, e the true feature
      error (RMS point distance ‖s − s*‖/2, px), in [−1, 0];
    - r_action = −``action_weight`` ‖a‖² / dim(a);
    - r_termination = −``termination_penalty`` − (T − k)(1 + ``action_weight``) on the step k
      that loses a feature, reaches a joint limit or diverges (T the episode's steps), else 0.

    (T − k)(1 + ``action_weight``) is the worst reward of every step the failed episode does not
    play (r_features = −1, ‖a‖² = dim(a)): playing on can never lose more than failing, so
    failing early never raises the return, at any discount γ ≤ 1 (with a constant penalty a
    PPO agent learned to lose the features at once). ``charge_unplayed_steps=False`` leaves
    the penalty alone.

    ## Starting State
    At rest at the start offset (see Description), drawn until reachable inside the joint
    limits (0.1 rad margin) with every feature ≥ 40 px inside the image and visible (200
    tries).
    ``start_offset=(tx, ty, tz, rx, ry, rz)`` sets it exactly (m, rotation vector in rad; the
    start camera's pose in the goal camera's optical frame) and leaves the target untilted
    (facing the goal camera squarely, like ViSP's cdMo = (0, 0, 0.75, 0, 0, 0)); an offset that
    is unreachable or does not see every feature raises ``InvalidArgument`` at reset.
    ``info["start_offset"]`` holds the offset used.

    ## Episode End
    Truncated after ``episode_duration`` s. Terminated (a failure) when a feature is lost
    (``info["feature_lost"]``): it leaves the image, goes behind the camera, or the camera
    cannot see it — a ray from the true camera's centre to the marker's centre
    (``mujoco.mj_ray``, :func:`cir_gym.vision.visible`) meets a link, the target's or the marker
    plate's body or any other rendered geom first (``info["features_visible"]``, (4,) bool);
    when a joint comes within 0.01 rad of its limit (``info["joint_limit"]``); or when the
    physics diverges (``info["diverged"]``). Success: not terminated and a final feature error
    < 1 px.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | action | "twist" | "twist" (camera twist) or "joint_velocity" |
    | features | "projected" | "projected" (exact + noise) or "detected" (rendered image) |
    | obs_image | False | add the camera image to the observation (renders every step) |
    | pixel_noise | 0.1 | std of the projected features' noise (px) |
    | camera_error | (0.0, 0.0, 0.0, 0.0) | true-camera errors unknown to controllers: focal-length scale error (relative, sign random), principal-point offset (px, random direction), hand-eye translation (m) and rotation (rad), random directions per episode |
    | start_offset | None | fixed start pose in the goal frame (tx, ty, tz, rx, ry, rz), or None (random) |
    | start_rotation | None | the random start's rotation bounds (tilt, spin) in rad: tilt about the goal frame's x and y (≤ 0.5), spin about its z axis (≤ π); None: (0.3, 1.0); (0.3, π) draws the 90°–180° rotation family too |
    | control_freq | 25.0 | control frequency (Hz); ViSP's 40 ms period |
    | episode_duration | 15.0 | s |
    | action_weight | 0.01 | weight of the action-size cost |
    | termination_penalty | 50.0 | reward lost on a failure, on top of the unplayed steps' charge |
    | charge_unplayed_steps | True | a failure also loses the worst reward of each unplayed step (see Rewards) |
    | render_mode | None | None, "human" or "rgb_array" (camera "side", the camera image inset) |
    | width | 480 | frame width (px) |
    | height | 360 | frame height (px) |

    ## Metrics
    ``final_feature_error`` (primary, px, true features), ``convergence_time`` (s: the first
    time after which the error stays below 1 px; the episode duration if it never does),
    ``path_length`` (m, of the camera), ``retreat`` (m: how far the camera went behind both
    its start and the goal along the goal's optical axis — Chaumette's camera retreat),
    ``detection_failures`` (markers not found over the episode; 0 with projected features).

    ## Reference controllers
    ``baselines.available("cir_gym/VisualServo-v1")``: ibvs, pbvs.

    ## Version History
    - v1: a marker the camera cannot see (a ray test from the camera centre) is lost and ends
      the episode (``info["features_visible"]``); a start must see every marker; a failure is
      charged the worst reward of each unplayed step, (T − k)(1 + ``action_weight``)
      (``charge_unplayed_steps``, default True; v0 charged T − k, so failing early could pay).
    - v0: initial version.
    """

    scene_file: ClassVar[str] = "visual_servo.xml"
    eye_in_hand: ClassVar[bool] = True
    marker_side: ClassVar[float] = 0.2
    marker_radius: ClassVar[float] = 0.015
    moving_offset: ClassVar[float] = 0.0
    start_translation: ClassVar[tuple[float, float, float, float]] = (0.12, 0.12, -0.25, 0.05)
    target_tilt: ClassVar[float] = 0.2  # rad

    def _add_task(self, spec: mujoco.MjSpec) -> None:
        scene.add_flange_camera(spec)  # the target and its markers are in the scene file

    def _place_target(self) -> None:
        """Target plane 0.75 m in front of the goal camera, tilted and turned per episode."""
        p_g, R_g = self._goal_pose
        if self.start_offset is None:
            rng = self.np_random
            tilt = self.target_tilt * float(rng.uniform(0, 1)) * random_unit(rng, 2)
            spin = float(rng.uniform(-np.pi, np.pi))
            R_t = R_g @ rotation(np.array([tilt[0], tilt[1], 0.0])) @ rotation(
                np.array([0.0, 0.0, spin])
            )
        else:
            R_t = R_g
        tid = self.model.body("target").id
        self.model.body_pos[tid] = p_g + scene.GOAL_DEPTH * R_g[:, 2]
        mujoco.mju_mat2Quat(self.model.body_quat[tid], R_t.ravel())

    def _twist_rotation(self, q: np.ndarray) -> np.ndarray:
        """The flange's (nominal camera's) rotation at q: the twist is in the optical frame."""
        return self.robot.site_pose(self._flange, q)[1]

    def draw_task(self, scene_: mujoco.MjvScene) -> None:
        super().draw_task(scene_)
        rendering.place_world_geoms(scene_, self.model)  # the target, moved per episode


VISUAL_SERVO_ENVIRONMENTS: dict[str, tuple[type[RobotEnv], str]] = {
    "cir_gym/VisualServo-v1": (
        VisualServoEnv,
        "iiwa14 eye-in-hand visual servoing on four image points with a camera twist (ch. 7)",
    ),
    "cir_gym/VisualServoEyeToHand-v1": (
        VisualServoEyeToHandEnv,
        "iiwa14 eye-to-hand visual servoing: a fixed camera guides four markers (ch. 7)",
    ),
}
