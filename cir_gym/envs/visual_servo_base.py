"""What the two visual-servoing environments share: the velocity-servoed arm, the camera and its
features, the episode (reset, step, reward, metrics) and the controllers' context.

The environments (:mod:`cir_gym.envs.visual_servo`, :mod:`cir_gym.envs.visual_servo_eye_to_hand`)
set the geometry: where the camera is, what moves (the camera or a marker plate), the target.
The camera science (projection, visibility, detection) is in :mod:`cir_gym.vision`; the scene
building and the camera's pictures in :mod:`cir_gym.envs.visual_servo_scene`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces

from cir_gym import rendering
from cir_gym import trajectories as traj
from cir_gym.context import TaskContext
from cir_gym.envs import visual_servo_scene as scene
from cir_gym.envs.base import RobotEnv
from cir_gym.metrics import MetricSpec
from cir_gym.redundancy import orientation_error
from cir_gym.robot import Robot
from cir_gym.validation import InvalidArgument, as_float_array, check_number
from cir_gym.vision import (
    Camera,
    camera_points,
    detect_markers,
    optical_pose,
    project,
    visible,
)

__all__ = ["VisualServoBase"]

ACTIONS = ("twist", "joint_velocity")
FEATURES = ("projected", "detected")
#: (v_x, v_y, v_z) m/s and (ω_x, ω_y, ω_z) rad/s per unit of a twist action
TWIST_LIMIT = (0.3, 0.3, 0.3, 1.0, 1.0, 1.0)
JOINT_MARGIN = 0.01  # rad: closer to a joint limit ends the episode
START_IMAGE_MARGIN = 40.0  # px: random starts keep every feature this far inside the image
CONVERGED = 1.0  # px: success threshold of the final feature error
START_TRIES = 200
ERROR_LIMITS = (0.5, 100.0, 0.1, 0.3)  # camera_error maxima: focal, principal, hand-eye t, R
REWARD_SCALES = np.array([100.0, 10.0, 1.0])  # px, the feature reward's kernels
MIN_DEPTH = 1e-6  # m: a point this close to the camera plane or behind it has no image


def rotation(axis_angle: np.ndarray) -> np.ndarray:
    """The rotation matrix (3, 3) of a rotation vector (3,) (rad)."""
    theta = float(np.linalg.norm(axis_angle))
    if theta < 1e-15:
        return np.eye(3)
    return traj.matrix_from_axis_angle(axis_angle / theta, theta)


def random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    """A direction (n,) drawn uniformly."""
    v = rng.standard_normal(n)
    return v / np.linalg.norm(v)


class VisualServoBase(RobotEnv):
    """Shared plumbing; subclasses set the geometry (see the two environment docstrings)."""

    scene_file: ClassVar[str] = ""
    eye_in_hand: ClassVar[bool] = True
    marker_side: ClassVar[float] = 0.2  # m
    marker_radius: ClassVar[float] = 0.015  # m
    moving_offset: ClassVar[float] = 0.0  # m: the moving frame's origin along flange z
    start_translation: ClassVar[tuple[float, float, float, float]] = (0.12, 0.12, -0.25, 0.05)
    #: rad: the random start's default rotation bounds (tilt about x and y, spin about the axis)
    start_rotation_default: ClassVar[tuple[float, float]] = (0.3, 1.0)
    primary_metric: ClassVar[str] = "final_feature_error"
    success_threshold: ClassVar[float] = CONVERGED
    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec(
            "final_feature_error", "px", "lower",
            "RMS point distance ‖s − s*‖/2 at the end (true features)",
        ),
        MetricSpec(
            "convergence_time", "s", "lower",
            "first time after which the feature error stays < 1 px (duration if never)",
            failure_scores_limit=True,
        ),
        MetricSpec("path_length", "m", "lower", "length of the moving frame's path"),
        MetricSpec(
            "retreat", "m", "lower",
            "max distance behind both the start and the goal along the goal's axis",
        ),
        MetricSpec("detection_failures", "", "lower", "markers not found in the image"),
    )
    reward_arguments: ClassVar[frozenset[str]] = frozenset((
        "action_weight", "termination_penalty", "charge_unplayed_steps",
    ))
    leaderboard_variants: ClassVar[dict[str, dict[str, Any]]] = {
        "projected features": {},
        "calibration error": {"camera_error": (0.05, 10.0, 0.01, 0.02)},
    }

    def __init__(
        self,
        action: str = "twist",
        features: str = "projected",
        obs_image: bool = False,
        pixel_noise: float = 0.1,
        camera_error: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
        start_offset: tuple[float, ...] | None = None,
        start_rotation: tuple[float, float] | None = None,
        control_freq: float = 25.0,
        episode_duration: float = 15.0,
        action_weight: float = 0.01,
        termination_penalty: float = 50.0,
        charge_unplayed_steps: bool = True,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 360,
    ) -> None:
        """See the environment docstrings (## Arguments)."""
        if action not in ACTIONS:
            raise InvalidArgument(f"action must be one of {ACTIONS}, got {action!r}")
        if features not in FEATURES:
            raise InvalidArgument(f"features must be one of {FEATURES}, got {features!r}")
        if not isinstance(obs_image, bool):
            raise InvalidArgument(f"obs_image must be True or False, got {obs_image!r}")
        self.action_kind, self.features, self.obs_image = action, features, obs_image
        self.pixel_noise = check_number("pixel_noise", pixel_noise, 0.0, 10.0)
        self.camera_error = self._check_camera_error(camera_error)
        self.action_weight = check_number("action_weight", action_weight, 0.0, 10.0)
        self.termination_penalty = check_number(
            "termination_penalty", termination_penalty, 0.0, 1e6
        )
        self.start_offset = self._check_start_offset(start_offset)
        self.start_rotation = self._check_start_rotation(start_rotation)
        if not isinstance(charge_unplayed_steps, (bool, np.bool_)):
            raise InvalidArgument(
                f"charge_unplayed_steps must be True or False, got {charge_unplayed_steps!r}"
            )
        self.charge_unplayed_steps = bool(charge_unplayed_steps)
        #: the worst reward of a step: r_features = −1 and r_action = −action_weight (‖a‖² ≤
        #: dim a after clipping)
        self._worst_step = -(1.0 + self.action_weight)

        self.model_points = scene.model_points(self.marker_side)
        model = scene.build_model(self.scene_file, self._add_task)
        super().__init__(
            model,
            control_freq=control_freq,
            episode_duration=episode_duration,
            render_mode=render_mode,
            width=width,
            height=height,
            camera="side",
        )
        self.robot = Robot(model, [f"joint{i}" for i in range(1, 8)])  # kinematics queries
        self.n = 7
        self.qpos_adr = self.robot.qpos_adr
        self.dof_adr = self.robot.dof_adr
        self.lower, self.upper = self.robot.lower.copy(), self.robot.upper.copy()
        self.velocity_limit = self.robot.velocity_limit.copy()
        self.twist_limit = np.array(TWIST_LIMIT)
        self.q_goal = np.array(scene.Q_GOAL)
        self._flange = self.robot.site_id("flange")
        self._cam_id = model.camera("servo_cam").id
        self._marker_ids = np.array([model.geom(f"marker{i}").id for i in range(4)])
        self.nominal_camera = Camera.from_fovy(scene.FOVY, scene.IMAGE_WIDTH, scene.IMAGE_HEIGHT)
        self.true_camera = self.nominal_camera
        scene.velocity_servos(model, self.robot, self.q_goal)
        self._nominal_cam_pose = (
            model.cam_pos[self._cam_id].copy(),
            model.cam_quat[self._cam_id].copy(),
        )
        self._eye: mujoco.Renderer | None = None
        self._eye_small: mujoco.Renderer | None = None  # the rendered frame's camera inset

        n_act = 6 if action == "twist" else 7
        self.action_space = spaces.Box(-1.0, 1.0, (n_act,), dtype=np.float32)
        bound = 2.0 * scene.IMAGE_WIDTH
        obs = {
            "features": spaces.Box(-bound, bound, (8,), dtype=np.float64),
            "features_ref": spaces.Box(-bound, bound, (8,), dtype=np.float64),
            "q": spaces.Box(-2 * np.pi, 2 * np.pi, (7,), dtype=np.float64),
        }
        if obs_image:
            shape = (scene.IMAGE_HEIGHT, scene.IMAGE_WIDTH, 3)
            obs["image"] = spaces.Box(0, 255, shape, dtype=np.uint8)
        self.observation_space = spaces.Dict(obs)
        self._bound = bound

        steps = self.max_steps
        self._err = np.zeros(steps + 1)  # true feature error (px) at each step
        self._pos = np.zeros((steps + 1, 3))  # moving frame position in the goal frame
        self._s_ref = np.zeros((4, 2))  # desired features s* (px)
        self._s_obs = np.zeros((4, 2))  # observed features (px)
        self._s_true = np.zeros((4, 2))  # the true camera's features (px)
        self._image = np.zeros((scene.IMAGE_HEIGHT, scene.IMAGE_WIDTH, 3), dtype=np.uint8)
        self._detect_failures = 0
        self._k = 0  # steps played
        self._goal_pose = (np.zeros(3), np.eye(3))
        self._start = np.zeros(6)
        if self.start_offset is not None:  # an infeasible offset is an argument error
            self.reset(seed=0)

    # ------------------------------------------------------------------ arguments
    @staticmethod
    def _check_camera_error(value: Any) -> np.ndarray:
        arr = as_float_array("camera_error", value)
        lim = np.array(ERROR_LIMITS)
        if arr.shape != (4,) or np.any(arr < 0) or np.any(arr > lim):
            raise InvalidArgument(
                "camera_error must be 4 numbers (relative focal-length error ≤ 0.5, "
                "principal-point offset ≤ 100 px, hand-eye translation ≤ 0.1 m, hand-eye "
                f"rotation ≤ 0.3 rad), each ≥ 0, got {value!r}"
            )
        return arr

    def _check_start_rotation(self, value: Any) -> tuple[float, float]:
        if value is None:
            return self.start_rotation_default
        arr = as_float_array("start_rotation", value)
        if arr.shape != (2,) or not (0 <= arr[0] <= 0.5 and 0 <= arr[1] <= np.pi):
            raise InvalidArgument(
                "start_rotation must be None (the default, "
                f"{self.start_rotation_default}) or 2 numbers (tilt, spin): the random start's "
                "rotation bounds about the goal frame's x and y (rad, 0 to 0.5) and about its "
                f"z axis (rad, 0 to π), got {value!r}"
            )
        return float(arr[0]), float(arr[1])

    @staticmethod
    def _check_start_offset(value: Any) -> np.ndarray | None:
        if value is None:
            return None
        arr = as_float_array("start_offset", value)
        if arr.shape != (6,) or np.linalg.norm(arr[:3]) > 1.0 or np.linalg.norm(arr[3:]) > np.pi:
            raise InvalidArgument(
                "start_offset must be None or 6 numbers (tx, ty, tz, rx, ry, rz): the start "
                "pose of the moving frame in its goal frame, translation (m, norm ≤ 1) and "
                f"rotation vector (rad, norm ≤ π), got {value!r}"
            )
        return arr

    # ------------------------------------------------------------------ subclass hooks
    def _add_task(self, spec: mujoco.MjSpec) -> None:
        """Add the servo camera (and the markers if they move with the arm) to ``spec``."""
        raise NotImplementedError

    def _place_target(self) -> None:
        """Move the target for this episode (eye in hand); nothing by default."""

    def _twist_rotation(self, q: np.ndarray) -> np.ndarray:
        """R (3, 3): the twist action's frame → world at the joints q."""
        raise NotImplementedError

    def _nominal_world_camera(self) -> tuple[np.ndarray, np.ndarray]:
        """The nominal camera pose (p (3,), R (3, 3) optical → world) of a fixed camera."""
        raise NotImplementedError

    # ------------------------------------------------------------------ geometry
    def _moving_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nominal world pose (p (3,), R (3, 3)) of the moving frame (camera or marker plate)
        at q, through the Robot's kinematics."""
        p, R = self.robot.site_pose(self._flange, q)
        return p + self.moving_offset * R[:, 2], R

    def _moving_jacobian(self, q: np.ndarray) -> np.ndarray:
        """Geometric Jacobian (6, 7) of the moving frame's origin (world frame) at q."""
        J = self.robot.jacobian(self._flange, q)
        if self.moving_offset:
            r = self.moving_offset * self.robot.site_pose(self._flange, q)[1][:, 2]
            J[:3] -= traj.skew(r) @ J[3:]  # v_o = v_f + ω × r = v_f − r × ω
        return J

    def _solve_ik(self, q: np.ndarray, p: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, float]:
        """Newton steps on the moving frame's pose (steps capped at 0.2 rad); (q, residual)."""
        err = np.inf
        for _ in range(100):
            pq, Rq = self._moving_pose(q)
            e = np.concatenate((p - pq, orientation_error(R, Rq)))
            err = float(np.linalg.norm(e))
            if err < 1e-12:
                break
            dq = np.linalg.lstsq(self._moving_jacobian(q), e, rcond=None)[0]
            step = float(np.max(np.abs(dq)))
            q = q + (dq * (0.2 / step) if step > 0.2 else dq)
        return q, err

    def _kinematics(self) -> None:
        """``self.data``'s poses, Jacobian terms and camera pose at its joints."""
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    def _true_features(self) -> np.ndarray | None:
        """Pixel features (4, 2) of the true camera (``self.data``'s current poses), or None if
        a marker is behind the camera (depth ≤ 1 µm)."""
        d, cid = self.data, self._cam_id
        p_c, R_c = optical_pose(d.cam_xpos[cid], d.cam_xmat[cid])
        P = camera_points(d.geom_xpos[self._marker_ids], p_c, R_c)
        if (P[:, 2] <= MIN_DEPTH).any():
            return None
        return project(P, self.true_camera)

    def _in_view(self, s: np.ndarray) -> bool:
        """Every feature (4, 2) inside the true image (NaN is not)."""
        return bool(np.all(self.true_camera.inside(s)))

    def _visible(self) -> np.ndarray:
        """(4,) True where the true camera has a line of sight to the marker's centre (no link,
        plate or other object in between, nearer than its near clipping plane;
        :func:`cir_gym.vision.visible`)."""
        m, d, cid = self.model, self.data, self._cam_id
        near = m.vis.map.znear * m.stat.extent  # the renderer's near clipping distance
        return visible(m, d, d.cam_xpos[cid], self._marker_ids, near)

    # ------------------------------------------------------------------ episode setup
    def _draw_camera_error(self) -> None:
        """This episode's true camera: intrinsics and pose errors at the given magnitudes,
        random directions (known only to the simulator)."""
        rng = self.np_random
        e_f, e_c, e_t, e_r = self.camera_error
        scale = 1.0 + e_f * float(rng.choice((-1.0, 1.0)))
        offset = e_c * random_unit(rng, 2)
        dt = e_t * random_unit(rng, 3)
        dR = rotation(e_r * random_unit(rng, 3))
        self.true_camera = self.nominal_camera.with_error(
            scale, (float(offset[0]), float(offset[1]))
        )
        m, cid = self.model, self._cam_id
        pos, quat = self._nominal_cam_pose
        R_nom = np.empty(9)
        mujoco.mju_quat2Mat(R_nom, quat)
        R_true = R_nom.reshape(3, 3) @ dR  # error expressed in the camera's own frame
        m.cam_pos[cid] = pos + R_nom.reshape(3, 3) @ dt
        mujoco.mju_mat2Quat(m.cam_quat[cid], R_true.ravel())
        # MuJoCo's intrinsic: focal lengths and a principal-point shift in sensor units (m);
        # a shift p moves the rendered image by −p / pixel (measured), so the principal point
        # moves by +offset with p = −offset · pixel
        pixel = scene.PIXEL_SIZE
        f = self.true_camera.fu * pixel
        m.cam_intrinsic[cid] = (f, f, -offset[0] * pixel, -offset[1] * pixel)

    def _draw_start(self) -> tuple[np.ndarray, np.ndarray | None]:
        """(start offset (6,), q(0)): drawn until reachable with every feature in view (q(0)
        None: the given ``start_offset`` is not)."""
        rng = self.np_random
        lx, ly, z0, z1 = self.start_translation
        tilt, spin = self.start_rotation
        for _ in range(START_TRIES):
            if self.start_offset is not None:
                offset = self.start_offset
            else:
                offset = np.array([
                    rng.uniform(-lx, lx), rng.uniform(-ly, ly), rng.uniform(z0, z1),
                    rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt), rng.uniform(-spin, spin),
                ])
            q = self._start_configuration(offset)
            if q is not None or self.start_offset is not None:
                return offset, q
        raise RuntimeError("no feasible start found")  # pragma: no cover

    def _start_configuration(self, offset: np.ndarray) -> np.ndarray | None:
        """The joints that put the moving frame at ``offset`` in its goal frame, or None if
        they are not inside the joint limits (0.1 rad margin) or do not see every feature."""
        p_g, R_g = self._goal_pose
        R = R_g @ rotation(offset[3:])
        p = p_g + R_g @ offset[:3]
        q, err = self._solve_ik(self.q_goal.copy(), p, R)
        if err > 1e-9 or np.any(q < self.lower + 0.1) or np.any(q > self.upper - 0.1):
            return None
        self._set_state(q)
        s = self._true_features()
        margin = 0.0 if self.start_offset is not None else START_IMAGE_MARGIN
        if s is None or not np.all(self.true_camera.inside(s, margin)):
            return None
        if not self._visible().all():
            return None
        return q

    def _set_state(self, q: np.ndarray) -> None:
        self.data.qpos[self.qpos_adr] = q
        self.data.qvel[:] = 0.0
        self._kinematics()

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        self._goal_pose = self._moving_pose(self.q_goal)
        self._draw_camera_error()
        self._place_target()
        self._set_state(self.q_goal)
        s_ref = self._true_features()
        if s_ref is None:  # pragma: no cover - the goal sees the target by construction
            raise RuntimeError("the goal camera does not see the target")
        self._s_ref = s_ref
        offset, q0 = self._draw_start()
        if q0 is None:
            raise InvalidArgument(
                f"start_offset {tuple(self.start_offset)} is not reachable inside the joint "
                "limits with every feature in the image"
            )
        self._start = offset
        qpos = self.data.qpos.copy()
        qpos[self.qpos_adr] = q0
        self._reset_physics(qpos, np.zeros(self.model.nv))
        self._kinematics()
        self._k = 0
        self._detect_failures = 0
        self._err[:] = 0.0
        self._pos[:] = 0.0
        self._s_true = self._true_features()
        self._s_obs = self._s_true.copy()
        self._observe()
        self._record(0)
        return self._obs(), {"start_offset": offset.copy()}

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        a, _ = self._check_action(action)
        diverged = self._simulate(self._ctrl(self._joint_command(a)))
        self._kinematics()
        self._k += 1
        k = self._k
        q = self.data.qpos[self.qpos_adr]
        at_limit = bool((q < self.lower + JOINT_MARGIN).any() or (q > self.upper - JOINT_MARGIN).any())
        s = None if diverged else self._true_features()
        seen = np.zeros(4, dtype=bool) if s is None else self._visible()
        if s is None:  # diverged or a marker behind the camera: the last seen features kept
            lost = True
        else:  # a feature is lost when it leaves the image or something hides it
            lost = not (self._in_view(s) and seen.all())
            self._s_true = s
        detection_failure = self._observe()
        e = self._record(k)
        terminated = bool(diverged or lost or at_limit)
        terms = self.reward_terms(e, a, terminated, self.max_steps - k)
        info: dict[str, Any] = {name: float(value) for name, value in terms.items()}
        reward = info["reward_features"] + info["reward_action"] + info["reward_termination"]
        truncated = k >= self.max_steps and not terminated
        info.update(feature_error=e, feature_lost=lost, features_visible=seen, joint_limit=at_limit,
                    detection_failure=detection_failure, diverged=bool(diverged))
        if terminated or truncated:
            metrics = self.episode_metrics()
            info["episode_metrics"] = metrics
            info["is_success"] = bool(not terminated and metrics["final_feature_error"] < CONVERGED)
        return self._obs(), reward, terminated, truncated, info

    def reward_terms(self, e: Any, a: np.ndarray, terminated: Any, steps_left: Any
                     ) -> dict[str, Any]:
        """The reward's terms (## Rewards) of a step, ``info["reward_<name>"]``: from the true
        feature error e (px), the action a (m,), whether the step ended the episode and the
        steps T − k left unplayed; or of rows of steps (e (N,), a (N, m), (N,), (N,)), each
        term then (N,). The reward is r_features + r_action + r_termination."""
        e = np.asarray(e)
        r_features = -(1.0 - np.mean(np.exp(-(e[..., None] ** 2) / REWARD_SCALES**2), axis=-1))
        r_action = -self.action_weight * np.sum(a * a, axis=-1) / a.shape[-1]
        # a failure: the penalty, and the worst reward of every unplayed step
        unplayed = steps_left * self._worst_step if self.charge_unplayed_steps else 0.0
        r_term = np.where(terminated, -self.termination_penalty + unplayed, 0.0)
        return {"reward_features": r_features, "reward_action": r_action,
                "reward_termination": r_term}

    def _joint_command(self, a: np.ndarray) -> np.ndarray:
        """q̇ (7,) from the action: a ⊙ q̇_max, or q̇ = J⁺ V for a twist V = a ⊙ twist limits,
        J the moving frame's Jacobian at the current joints (resolved rate, minimum norm)."""
        if self.action_kind == "joint_velocity":
            return a * self.velocity_limit
        q = self.data.qpos[self.qpos_adr].copy()
        if not np.isfinite(q).all():  # a corrupted state: the physics step reports it
            return np.zeros(self.n)
        R = self._twist_rotation(q)
        V = a * self.twist_limit
        V_world = np.concatenate((R @ V[:3], R @ V[3:]))
        J = self._moving_jacobian(q)
        try:
            return J.T @ np.linalg.solve(J @ J.T, V_world)  # J⁺ V
        except np.linalg.LinAlgError:  # exactly singular: the least-squares solution
            return np.linalg.lstsq(J, V_world, rcond=None)[0]

    def _ctrl(self, qd: np.ndarray) -> np.ndarray:
        """Velocity-servo commands (nu,): q̇ scaled down uniformly (direction kept) to the
        actuators' ctrlrange."""
        limit = self.model.actuator_ctrlrange[self.robot.actuator_ids, 1]  # > 0
        ratio = float((np.abs(qd) / limit).max())
        if ratio > 1.0:
            qd = qd / ratio
        ctrl = np.zeros(self.model.nu)
        ctrl[self.robot.actuator_ids] = qd
        return ctrl

    # ------------------------------------------------------------------ observation
    def _observe(self) -> bool:
        """Update the observed features (and the image); True if a marker was not found."""
        failure = False
        if self.features == "projected":
            noise = self.np_random.standard_normal(8).reshape(4, 2)
            self._s_obs = self._s_true + noise * self.pixel_noise
        else:
            self._render_camera()
            s, found = detect_markers(self._image)
            self._s_obs = np.where(found[:, None], s, self._s_obs)  # missing: hold the last
            failure = not bool(np.all(found))
            self._detect_failures += int(np.sum(~found))
        if self.obs_image and self.features == "projected":
            self._render_camera()
        return failure

    def _render_camera(self) -> None:
        if self._eye is None:
            what = f'features="{self.features}", obs_image={self.obs_image}'
            self._eye = scene.camera_renderer(
                self.model, scene.IMAGE_HEIGHT, scene.IMAGE_WIDTH, what
            )
        scene.camera_view(self._eye, self.data, self._cam_id, self._image)

    def _obs(self) -> dict[str, np.ndarray]:
        bound = self._bound
        out = {
            "features": np.clip(self._s_obs.ravel(), -bound, bound),
            "features_ref": np.clip(self._s_ref.ravel(), -bound, bound),
            "q": np.clip(self.data.qpos[self.qpos_adr], -2 * np.pi, 2 * np.pi),
        }
        if self.obs_image:
            out["image"] = self._image.copy()
        return out

    def _record(self, k: int) -> float:
        """Store and return the true feature error (px) at step k, and store the moving frame's
        position in the goal frame (``self.data``'s poses)."""
        e = float(np.sqrt(np.sum((self._s_true - self._s_ref) ** 2) / len(self._s_ref)))
        self._err[k] = e
        p_g, R_g = self._goal_pose
        d = self.data
        z = d.site_xmat[self._flange].reshape(3, 3)[:, 2]
        p = d.site_xpos[self._flange] + self.moving_offset * z
        self._pos[k] = R_g.T @ (p - p_g)
        return e

    def episode_metrics(self) -> dict[str, float]:
        """Metrics of the episode so far (see ``metric_specs``)."""
        k = max(self._k, 1)
        e = self._err[: k + 1]
        below = e < CONVERGED
        if below[-1]:
            last_above = np.flatnonzero(~below)
            t_conv = 0.0 if last_above.size == 0 else (last_above[-1] + 1) * self.dt
        else:
            t_conv = self.max_steps * self.dt
        pos = self._pos[: k + 1]
        behind = np.max(-pos[:, 2])  # along the goal's axis: −z is backwards
        return {
            "final_feature_error": float(e[-1]),
            "convergence_time": float(t_conv),
            "path_length": float(np.sum(np.linalg.norm(np.diff(pos, axis=0), axis=1))),
            "retreat": float(max(0.0, behind - max(-pos[0, 2], 0.0))),
            "detection_failures": float(self._detect_failures),
        }

    # ------------------------------------------------------------------ pictures
    def draw_task(self, scene_: mujoco.MjvScene) -> None:
        p_g, R_g = self._goal_pose
        rendering.add_frame(scene_, p_g, R_g, 0.08, 0.004)
        k = max(self._k, 1)
        if k > 1:
            path = p_g + self._pos[: k + 1] @ R_g.T
            rendering.add_polyline(scene_, path, 0.003, rendering.REFERENCE)

    def caption(self) -> str:
        k = min(self._k, self.max_steps)
        return f"t {k * self.dt:5.2f} s  |s - s*| {self._err[k]:6.2f} px"

    def render(self) -> np.ndarray | None:
        frame = super().render()
        if frame is None or not self.draw_markers:
            return frame
        try:
            if self.obs_image or self.features == "detected":  # this step's image exists
                image = self._image
            else:
                image = self._small_camera_view(frame.shape[0] // 3)
        except RuntimeError:  # no OpenGL for the camera: the features only
            image = None
        return scene.camera_inset(frame, image, self._s_ref, self._s_true)

    def _small_camera_view(self, height: int) -> np.ndarray:
        """The camera's view rendered ``height`` px tall (4:3), for the frame's inset."""
        width = max(1, round(height * scene.IMAGE_WIDTH / scene.IMAGE_HEIGHT))
        small = self._eye_small
        if small is None or (small.height, small.width) != (height, width):
            if small is not None:
                small.close()
            what = "the rendered frame's camera inset"
            small = self._eye_small = scene.camera_renderer(self.model, height, width, what)
        image = np.empty((height, width, 3), dtype=np.uint8)
        scene.camera_view(small, self.data, self._cam_id, image)
        return image

    def close(self) -> None:
        for name in ("_eye", "_eye_small"):
            renderer = getattr(self, name, None)
            if renderer is not None:
                renderer.close()
                setattr(self, name, None)
        super().close()

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state["_eye"] = None
        state["_eye_small"] = None
        return state

    # ------------------------------------------------------------------ controllers
    def controller_context(self) -> TaskContext:
        extras = {
            "eye_in_hand": self.eye_in_hand,
            "camera": self.nominal_camera,
            "model_points": self.model_points.copy(),
            "moving_offset": self.moving_offset,
            "twist_limit": self.twist_limit.copy(),
            "velocity_limit": self.velocity_limit.copy(),
        }
        if not self.eye_in_hand:
            extras["camera_pose"] = self._nominal_world_camera()
        scale = self.twist_limit if self.action_kind == "twist" else self.velocity_limit
        return TaskContext(
            robot="iiwa14",
            dt=self.dt,
            action_kind=self.action_kind,
            action_scale=scale.copy(),
            site="flange",
            extras=extras,
        )
