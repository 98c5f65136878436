"""VisualServoEyeToHand: eye-to-hand visual servoing of the iiwa14 (chapter 7).

A fixed camera on a stand guides four markers on a plate at the flange; the plumbing it shares
with the eye-in-hand task is :class:`~cir_gym.envs.visual_servo_base.VisualServoBase`.
"""

from __future__ import annotations

from typing import ClassVar

import mujoco
import numpy as np

from cir_gym.envs import visual_servo_scene as scene
from cir_gym.envs.visual_servo_base import VisualServoBase

__all__ = ["VisualServoEyeToHandEnv"]

#: the fixed camera's optical frame → world (nominal): optical (x, y, z) = (y_w, −z_w, −x_w)
CAMERA_R = np.column_stack(([0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]))


class VisualServoEyeToHandEnv(VisualServoBase):
    """Eye-to-hand visual servoing: a fixed camera guides four markers on the end effector.

    ## Description
    Chapter 7's other camera placement: a fixed camera (640 × 480 px, fovy 60°, f = 415.69 px,
    principal point (319.5, 239.5) px) on a stand at (1.606, 0, 0.45) m looks back along −x at
    a 0.2 m plate on link7 (centre 30 mm beyond the flange along its axis) carrying four
    coloured discs at the corners of a 0.16 m square. At the goal configuration ``Q_GOAL`` the
    plate faces the camera 0.75 m away; the desired features s* are the true camera's image of
    the markers there. The plate starts at a random offset from its goal pose (translation
    ±0.1 m sideways, −0.2 … +0.05 m along its normal, rotation vector ±0.3 rad about x and
    y, ±1.0 rad about the normal), reachable and with every feature ≥ 40 px inside the image.
    The arm is velocity-servoed as in ``VisualServo-v1``.

    ## Action Space
    ``action="twist"``: ``Box(-1, 1, (6,), float32)``, the plate's twist expressed in the
    (nominal) camera's optical frame: v (m/s, velocity of the plate centre) = a[:3] · 0.3, ω
    (rad/s) = a[3:] · 1.0; the environment maps it to the world with the nominal camera pose
    and to q̇ = J⁺ V through the plate's Jacobian, scaled down uniformly to the joint-velocity
    limits. ``action="joint_velocity"``: ``Box(-1, 1, (7,), float32)``, q̇ = a ⊙ q̇_max.
    Finite values outside [-1, 1] are clipped; NaN/inf or a wrong shape raise ``ValueError``.

    ## Observation Space
    As ``VisualServo-v1`` (features of the four markers in the fixed camera, s*, q; the image
    with ``obs_image=True``). The nominal camera pose in the world is
    ``controller_context().extras["camera_pose"]`` (p (3,), R (3, 3) optical → world).

    ## Rewards
    As ``VisualServo-v1``.

    ## Starting State
    At rest at the start offset (see Description); ``start_offset`` sets the plate's start
    pose in its goal frame exactly (raises ``InvalidArgument`` at reset if unreachable or out
    of view).

    ## Episode End
    As ``VisualServo-v1``: here the arm, or the marker plate itself when it turns away from
    the camera, can hide a marker that is still inside the image (the ray test ends the
    episode then). ``camera_error``'s hand-eye terms here displace the fixed camera from its
    nominal pose (extrinsic calibration error).

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
    As ``VisualServo-v1``; ``path_length`` and ``retreat`` are the plate's (retreat: away from
    the camera, behind both start and goal).

    ## Reference controllers
    ``baselines.available("cir_gym/VisualServoEyeToHand-v1")``: ibvs_eye_to_hand.

    ## Version History
    - v1: a marker the camera cannot see (a ray test from the camera centre) is lost and ends
      the episode (``info["features_visible"]``); a start must see every marker; a failure is
      charged the worst reward of each unplayed step, (T − k)(1 + ``action_weight``)
      (``charge_unplayed_steps``, default True; v0 charged T − k, so failing early could pay).
    - v0: initial version.
    """

    scene_file: ClassVar[str] = "visual_servo_eye_to_hand.xml"
    eye_in_hand: ClassVar[bool] = False
    marker_side: ClassVar[float] = 0.16
    marker_radius: ClassVar[float] = 0.012
    moving_offset: ClassVar[float] = 0.03  # m beyond the flange (link7 z = 0.045 + 0.03)
    start_translation: ClassVar[tuple[float, float, float, float]] = (0.1, 0.1, -0.2, 0.05)
    camera_position: ClassVar[tuple[float, float, float]] = (1.606, 0.0, 0.45)

    def _add_task(self, spec: mujoco.MjSpec) -> None:
        scene.add_marker_plate(spec, self.model_points, self.marker_radius, self.moving_offset)
        scene.add_fixed_camera(spec, self.camera_position, CAMERA_R)

    def _nominal_world_camera(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.camera_position), CAMERA_R.copy()

    def _twist_rotation(self, q: np.ndarray) -> np.ndarray:
        """The nominal camera's rotation: the twist is in its optical frame."""
        return CAMERA_R
