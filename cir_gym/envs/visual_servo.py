"""VisualServo: image-based and position-based visual servoing of the iiwa14 (chapter 7).

Two environments share this module: an eye-in-hand camera on the flange looks at a planar
target with four point features (:class:`VisualServoEnv`), and a fixed camera watches four
markers on the end effector (:class:`VisualServoEyeToHandEnv`). The arm is velocity-servoed
in MuJoCo (velocity actuators with a 200 1/s bandwidth within the data-sheet torque limits,
gravity compensated); a twist action is turned into joint velocities by the environment's own
resolved-rate controller q̇ = J⁺ V through the flange Jacobian of its nominal model, scaled down
uniformly (direction kept) to the joint-velocity limits. The camera science (projection,
interaction matrix, pose from four points) is in :mod:`cir_gym.vision`.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces

from cir_gym import rendering
from cir_gym import trajectories as traj
from cir_gym.context import TaskContext
from cir_gym.envs.base import GL_DISABLED, GL_HELP, RobotEnv
from cir_gym.fast_solve import solve
from cir_gym.metrics import MetricSpec
from cir_gym.numeric import CLIP
from cir_gym.redundancy import orientation_error
from cir_gym.robot import ASSETS, Robot
from cir_gym.validation import InvalidArgument, as_float_array, check_number
from cir_gym.vision import MUJOCO_TO_OPTICAL, Camera

as_strided = np.lib.stride_tricks.as_strided

_MAXR, _ABS = np.maximum.reduce, np.absolute  # np.max and np.abs without their wrappers
_ADDR = np.add.reduce  # ndarray.sum without its wrapper
_SUB, _MUL, _DIV, _EXP = np.subtract, np.multiply, np.divide, np.exp
#: the products A @ B as np.dot with an output: the very BLAS calls of np.matmul (gemv, gemm,
#: syrk for J Jᵀ) with less dispatch (~0.2 µs a call on these 3- to 7-element operands)
_DOT = np.dot


__all__ = [
    "VISUAL_SERVO_ENVIRONMENTS",
    "VisualServoEnv",
    "VisualServoEyeToHandEnv",
    "detect_markers",
]

ACTIONS = ("twist", "joint_velocity")
FEATURES = ("projected", "detected")
#: (v_x, v_y, v_z) m/s and (ω_x, ω_y, ω_z) rad/s per unit of a twist action
TWIST_LIMIT = (0.3, 0.3, 0.3, 1.0, 1.0, 1.0)
#: the goal configuration: flange (= eye-in-hand optical frame) at (0.826, 0, 0.45) m looking
#: along +x (world), elbow at 1.07 rad (closed form in the arm's plane: wrist 0.70 m out,
#: 0.09 m above the shoulder). Backing the camera up along its axis closes the elbow: there is
#: room for 0.28 m (then joint 4 reaches its limit) and 0.08 m forward (then the arm nears its
#: stretched singularity). q7 = −1.2 leaves room for rotations about the optical axis of
#: −105° … +200°.
Q_GOAL = (0.0, 0.923, 0.0, -1.0687, 0.0, -0.4209, -1.2)
GOAL_DEPTH = 0.75  # m: target plane in front of the goal camera (ViSP's cdMo)
IMAGE_WIDTH, IMAGE_HEIGHT, FOVY = 640, 480, 60.0  # the camera (flange_cam's fovy)
MARKER_COLOURS = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 1.0, 0.0))
SERVO_BANDWIDTH = 200.0  # 1/s: velocity-servo gain k_v,i = 200 B_ii(q_goal)
TIMESTEP = 0.002  # s: physics step (implicitfast integrates the servo damping stably)
JOINT_MARGIN = 0.01  # rad: closer to a joint limit ends the episode
START_IMAGE_MARGIN = 40.0  # px: random starts keep every feature this far inside the image
CONVERGED = 1.0  # px: success threshold of the final feature error
START_TRIES = 200
ERROR_LIMITS = (0.5, 100.0, 0.1, 0.3)  # camera_error maxima: focal, principal, hand-eye t, R
MIN_MARKER_PIXELS = 4
REWARD_SCALES_SQ = np.array([100.0, 10.0, 1.0]) ** 2  # px², the feature reward's kernels


def detect_markers(
    image: np.ndarray,
    colours: tuple[tuple[float, ...], ...] = MARKER_COLOURS,
    min_pixels: int = MIN_MARKER_PIXELS,
) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (k, 2) (u, v) px of saturated colour blobs in an RGB image, and found (k,).

    A pixel belongs to colour c (components 0 or 1) when its channels where c = 1 are ≥ 90,
    within 0.8× of each other (yellow is not orange) and at least 2.5× its channels where
    c = 0 (plus 20). Fewer than ``min_pixels`` pixels: not
    found (centroid NaN). Pixel centres at integer coordinates (row 0 at the top).
    """
    img = np.asarray(image, dtype=np.int32)
    out = np.full((len(colours), 2), np.nan)
    found = np.zeros(len(colours), dtype=bool)
    for i, c in enumerate(colours):
        on = np.array(c) > 0.5
        lit = np.min(img[..., on], axis=-1)
        dark = np.max(img[..., ~on], axis=-1) if np.any(~on) else np.zeros(img.shape[:2])
        mask = (lit >= 90) & (lit >= 0.8 * np.max(img[..., on], axis=-1)) & (lit >= 2.5 * dark + 20)
        rows, cols = np.nonzero(mask)
        if rows.size >= min_pixels:
            out[i] = cols.mean(), rows.mean()
            found[i] = True
    return out, found


def _rotation(axis_angle: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(axis_angle))
    if theta < 1e-15:
        return np.eye(3)
    return traj.matrix_from_axis_angle(axis_angle / theta, theta)


def _random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal(n)
    return v / np.linalg.norm(v)


class _VisualServoBase(RobotEnv):
    """Shared plumbing; subclasses set the geometry (see the two environment docstrings)."""

    scene: ClassVar[str] = ""
    eye_in_hand: ClassVar[bool] = True
    marker_side: ClassVar[float] = 0.2  # m
    marker_radius: ClassVar[float] = 0.015  # m
    moving_offset: ClassVar[float] = 0.0  # m: the moving frame's origin along flange z
    start_translation: ClassVar[tuple[float, float, float, float]] = (0.12, 0.12, -0.25, 0.05)
    start_rotation: ClassVar[tuple[float, float]] = (0.3, 1.0)  # rad: tilt, about the axis
    primary_metric: ClassVar[str] = "final_feature_error"
    success_threshold: ClassVar[float] = CONVERGED
    metric_specs: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec(
            "final_feature_error",
            "px",
            "lower",
            "RMS point distance ‖s − s*‖/2 at the end (true features)",
        ),
        MetricSpec(
            "convergence_time",
            "s",
            "lower",
            "first time after which the feature error stays < 1 px (duration if never)",
            failure_scores_limit=True,
        ),
        MetricSpec("path_length", "m", "lower", "length of the moving frame's path"),
        MetricSpec(
            "retreat",
            "m",
            "lower",
            "max distance behind both the start and the goal along the goal's axis",
        ),
        MetricSpec("detection_failures", "", "lower", "markers not found in the image"),
    )
    reward_arguments: ClassVar[frozenset[str]] = frozenset((
        "action_weight", "termination_penalty",
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
        control_freq: float = 25.0,
        episode_duration: float = 15.0,
        action_weight: float = 0.01,
        termination_penalty: float = 50.0,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 360,
    ) -> None:
        """See the environment docstrings (## Arguments)."""
        self._setup(
            action=action,
            features=features,
            obs_image=obs_image,
            pixel_noise=pixel_noise,
            camera_error=camera_error,
            start_offset=start_offset,
            control_freq=control_freq,
            episode_duration=episode_duration,
            action_weight=action_weight,
            termination_penalty=termination_penalty,
            render_mode=render_mode,
            width=width,
            height=height,
        )

    def _setup(
        self,
        *,
        action: str,
        features: str,
        obs_image: bool,
        pixel_noise: float,
        camera_error: Any,
        start_offset: Any,
        control_freq: float,
        episode_duration: float,
        action_weight: float,
        termination_penalty: float,
        render_mode: str | None,
        width: int,
        height: int,
    ) -> None:
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

        model = self._build_model()
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
        first = int(self.qpos_adr[0])  # the joints' rows of qpos: a slice when consecutive
        consecutive = np.array_equal(self.qpos_adr, np.arange(first, first + len(self.qpos_adr)))
        self._q_rows = slice(first, first + len(self.qpos_adr)) if consecutive else self.qpos_adr
        self.lower, self.upper = self.robot.lower.copy(), self.robot.upper.copy()
        self.velocity_limit = self.robot.velocity_limit.copy()
        self.twist_limit = np.array(TWIST_LIMIT)
        self.q_goal = np.array(Q_GOAL)
        self._flange = self.robot.site_id("flange")
        self._cam_id = model.camera("servo_cam").id
        self._marker_ids = np.array([model.geom(f"marker{i}").id for i in range(4)])
        # the markers' rows of geom_xpos: a slice (a view) when their ids are consecutive
        first = int(self._marker_ids[0])
        consecutive = np.array_equal(self._marker_ids, np.arange(first, first + 4))
        self._marker_rows = slice(first, first + 4) if consecutive else self._marker_ids
        self._hot_data: mujoco.MjData | None = None  # the MjData of the views, _hot_views
        # the step's fast path: self.data's own position stage (kinematics and com positions,
        # the Robot's calls) at the joints' current bytes _kin_key gives the Jacobian and the
        # flange pose, when the joints are the whole state (as the Robot's: the same numbers)
        self._fast = bool(self.robot._whole)
        self._kin_key: bytes | None = None
        nv = model.nv
        self._jac = np.zeros((8, nv))  # [J_P; J_O; J_O's rows 0, 1 again] (the offset's ω × r)
        self._r5 = np.zeros(5)  # (r0, r1, r2, r0, r1): r = offset · z_flange
        self._scratch = np.zeros((2, 3, nv))
        self._twists = np.zeros((2, 6))  # V, V_world
        self._jjt = np.zeros((6, 6))
        self._qd = np.zeros(nv)
        self._rc = np.zeros((3, 3))  # the true camera's optical frame → world
        self._rc_key: bytes | None = None  # cam_xmat's bytes behind _rc (a world-fixed camera)
        # a camera fixed in the world: mj_step's own mj_camlight leaves its pose current
        self._camera_fixed = bool(
            model.cam_bodyid[self._cam_id] == 0
            and model.cam_mode[self._cam_id] == int(mujoco.mjtCamLight.mjCAMLIGHT_FIXED)
        )
        self._goal_lists: tuple[Any, list, np.ndarray | None] = (None, [], None)
        self._points = np.zeros((2, 4, 3))  # markers − camera (world), then (optical frame)
        self._p3 = np.zeros(3)
        self._kernel = np.zeros(len(REWARD_SCALES_SQ))
        self._noise = np.zeros(8)  # the projected features' noise (u₁, v₁, …), in px / σ
        self._projection: tuple = (None, 0.0, 0.0, 0.0, 0.0)  # (camera, f_u, f_v, c_u, c_v)
        self.model_points = self._model_points()
        self.nominal_camera = Camera.from_fovy(FOVY, IMAGE_WIDTH, IMAGE_HEIGHT)
        self.true_camera = self.nominal_camera
        self._setup_servos()
        self._nominal_cam_pose = (
            model.cam_pos[self._cam_id].copy(),
            model.cam_quat[self._cam_id].copy(),
        )
        self._nominal_intrinsic = model.cam_intrinsic[self._cam_id].copy()
        self._eye: mujoco.Renderer | None = None
        self._eye_small: mujoco.Renderer | None = None  # the rendered frame's camera inset

        n_act = 6 if action == "twist" else 7
        self.action_space = spaces.Box(-1.0, 1.0, (n_act,), dtype=np.float32)
        bound = 2.0 * IMAGE_WIDTH
        obs = {
            "features": spaces.Box(-bound, bound, (8,), dtype=np.float64),
            "features_ref": spaces.Box(-bound, bound, (8,), dtype=np.float64),
            "q": spaces.Box(-2 * np.pi, 2 * np.pi, (7,), dtype=np.float64),
        }
        if obs_image:
            obs["image"] = spaces.Box(0, 255, (IMAGE_HEIGHT, IMAGE_WIDTH, 3), dtype=np.uint8)
        self.observation_space = spaces.Dict(obs)
        self._bound = bound
        self._obs_high = np.r_[np.full(16, float(bound)), np.full(7, 2 * np.pi)]  # _obs's clip
        self._obs_low = -self._obs_high

        steps = self.max_steps
        self._err = np.zeros(steps + 1)  # true feature error (px) at each step
        self._pos = np.zeros((steps + 1, 3))  # moving frame position in the goal frame
        self._s_ref = np.zeros((4, 2))
        self._s_ref_list: tuple[Any, list] = (None, [])  # (_s_ref, its flat list)
        self._s_obs = np.zeros((4, 2))
        self._s_true = np.zeros((4, 2))
        self._image = np.zeros((IMAGE_HEIGHT, IMAGE_WIDTH, 3), dtype=np.uint8)
        self._detect_failures = 0
        self._k = 0
        self._k_end = 0
        self._done = False
        self._goal_pose = (np.zeros(3), np.eye(3))
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

    # ------------------------------------------------------------------ model
    def _build_model(self) -> mujoco.MjModel:
        spec = mujoco.MjSpec.from_file(str(ASSETS / "scenes" / self.scene))
        spec.option.timestep = TIMESTEP
        self._add_markers_and_camera(spec)
        for body in spec.bodies:  # the arm's own controller compensates gravity (set before
            body.gravcomp = 1.0  # compiling: MuJoCo counts gravity-compensated bodies then)
        return spec.compile()

    def _add_markers_and_camera(self, spec: mujoco.MjSpec) -> None:
        raise NotImplementedError

    @staticmethod
    def _camera_spec(cam: Any) -> None:
        """Explicit intrinsics: 640 × 480 px, focal (H/2)/tan(fovy/2), centred."""
        f = 0.5 * IMAGE_HEIGHT / np.tan(np.deg2rad(FOVY) / 2.0)
        cam.resolution = [IMAGE_WIDTH, IMAGE_HEIGHT]
        cam.sensor_size = [IMAGE_WIDTH * 1e-5, IMAGE_HEIGHT * 1e-5]  # 10 µm pixels
        cam.focal_pixel = [f, f]
        cam.principal_pixel = [0.0, 0.0]

    def _model_points(self) -> np.ndarray:
        h = self.marker_side / 2.0
        return np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])

    def _setup_servos(self) -> None:
        """Motors → velocity servos: τ = k_v (q̇_cmd − q̇), |q̇_cmd| ≤ q̇_max, |τ| ≤ τ_max."""
        m = self.model
        B = self.robot.inertia(self.q_goal)
        kv = SERVO_BANDWIDTH * np.diag(B)
        for j, a in enumerate(self.robot.actuator_ids):
            tau = self.robot.torque_limit[j]
            m.actuator_gainprm[a, :3] = (kv[j], 0.0, 0.0)
            m.actuator_biastype[a] = int(mujoco.mjtBias.mjBIAS_AFFINE)
            m.actuator_biasprm[a, :3] = (0.0, 0.0, -kv[j])
            m.actuator_ctrlrange[a] = (-self.velocity_limit[j], self.velocity_limit[j])
            m.actuator_forcerange[a] = (-tau, tau)
            m.actuator_forcelimited[a] = 1
        self._act = self.robot.actuator_ids.copy()
        # every actuator, in order: the control vector is q̇ itself (_ctrl)
        self._act_all = np.array_equal(self._act, np.arange(m.nu))
        # the joint-limit test's thresholds (step)
        self._low_stop = self.lower + JOINT_MARGIN
        self._high_stop = self.upper - JOINT_MARGIN
        self._low_list, self._high_list = self._low_stop.tolist(), self._high_stop.tolist()

    # ------------------------------------------------------------------ geometry
    def _moving_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nominal world pose of the moving frame (camera or marker plate) at q."""
        p, R = self.robot.site_pose(self._flange, q)
        return p + self.moving_offset * R[:, 2], R

    def _solve_ik(self, q: np.ndarray, p: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, float]:
        """Newton steps on the moving frame's pose (steps capped at 0.2 rad); (q, residual)."""
        err = np.inf
        for _ in range(100):
            pq, Rq = self._moving_pose(q)
            e = np.concatenate((p - pq, orientation_error(R, Rq)))
            err = float(np.linalg.norm(e))
            if err < 1e-12:
                break
            J = self._moving_jacobian(q)
            dq = np.linalg.lstsq(J, e, rcond=None)[0]
            step = float(np.max(np.abs(dq)))
            q = q + (dq * (0.2 / step) if step > 0.2 else dq)
        return q, err

    def _moving_jacobian(self, q: np.ndarray) -> np.ndarray:
        """Geometric Jacobian (6, 7) of the moving frame's origin (world frame)."""
        J = self.robot.jacobian(self._flange, q)
        if self.moving_offset:
            r0, r1, r2 = (
                self.moving_offset * self.robot.site_pose(self._flange, q)[1][:, 2]
            ).tolist()
            w0, w1, w2 = J[3:]  # v_o = v_f + ω × r = v_f − r × ω (np.cross's operations)
            J[0] -= r1 * w2 - r2 * w1
            J[1] -= r2 * w0 - r0 * w2
            J[2] -= r0 * w1 - r1 * w0
        return J

    def _true_features(self) -> np.ndarray | None:
        """Pixel features (4, 2) of the true camera, or None if a point is behind it."""
        s = self._true_feature_list()
        return None if s is None else np.array(s).reshape(-1, 2)

    def _true_feature_list(self) -> list[float] | None:
        """:meth:`_true_features` as a flat list (u₁, v₁, …, u₄, v₄) of Python floats.

        :func:`~cir_gym.vision.optical_pose` and :func:`~cir_gym.vision.project` inlined
        (the same operations: the step's hot path): the frames in scratch buffers, the
        pinhole's few divisions on Python floats."""
        if self._hot_data is not self.data:
            self._hot_views()
        R_c, shifted, points = self._rc, self._v_shifted, self._v_points
        if self._camera_fixed:  # R_c changes only with the model (the episode's camera)
            key = self._v_cam_xmat.tobytes()
            if key != self._rc_key:
                _DOT(self._v_cam_xmat, MUJOCO_TO_OPTICAL, out=R_c)
                self._rc_key = key
        else:
            _DOT(self._v_cam_xmat, MUJOCO_TO_OPTICAL, out=R_c)
        markers = self._v_markers
        if markers is None:  # marker rows not consecutive: a copy
            markers = self._v_geom_xpos[self._marker_rows]
        _SUB(markers, self._v_cam_xpos, out=shifted)
        _DOT(shifted, R_c, out=points)
        cam = self.true_camera
        projection = self._projection
        if projection[0] is not cam:  # the episode's true camera, as Python floats
            projection = (cam, float(cam.fu), float(cam.fv), float(cam.cu), float(cam.cv))
            self._projection = projection
        _, fu, fv, cu, cv = projection
        s = []
        for X, Y, Z in points.tolist():
            if Z <= 1e-6:  # = (Z <= 1e-6).any(): NaN fails every comparison (and goes on)
                return None
            s += (cu + fu * X / Z, cv + fv * Y / Z)  # c + f X / Z, in project's order
        return s

    def _hot_views(self) -> None:
        """Views of ``self.data``'s arrays (a pybind property builds a new array on every
        access) and of the step's scratch buffers, built once per MjData (and after
        unpickling, which copies views)."""
        d, cid, fl = self.data, self._cam_id, self._flange
        self._kin_key = None  # a new MjData: its position stage is not known to be current
        self._v_cam_xmat = d.cam_xmat[cid].reshape(3, 3)
        self._v_cam_xpos = d.cam_xpos[cid]
        self._v_geom_xpos = d.geom_xpos
        rows = self._marker_rows
        self._v_markers = d.geom_xpos[rows] if isinstance(rows, slice) else None
        self._v_q = d.qpos[self._q_rows] if isinstance(self._q_rows, slice) else None
        self._v_flange_p = d.site_xpos[fl]
        self._v_flange_R = d.site_xmat[fl].reshape(3, 3)
        self._v_flange_z = d.site_xmat[fl][2::3]
        shifted, points = self._points
        self._v_shifted, self._v_points = shifted, points
        jac = self._jac
        self._v_J, self._v_JT = jac[:6], jac[:6].T
        self._v_Jp, self._v_Jr = jac[0:3], jac[3:6]
        self._v_w_head, self._v_w_tail = jac[3:5], jac[6:8]
        row, col = jac.strides
        # [(w2, w0, w1), (w1, w2, w0)]: rows 5-7 and 4-6 of jac as one (2, 3, nv) view
        self._v_w_ab = as_strided(jac[5:], (2, 3, jac.shape[1]), (-row, row, col))
        r5 = self._r5
        self._v_r, self._v_r_head, self._v_r_tail = r5[:3], r5[:2], r5[3:]
        # [(r1, r2, r0), (r2, r0, r1)] as a (2, 3, 1) view of r5[1:5]
        self._v_r_ab = as_strided(r5[1:], (2, 3, 1), (r5.strides[0], r5.strides[0], 0))
        self._v_cross = self._scratch, self._scratch[0], self._scratch[1]
        self._v_twist_R = self._twist_rotation()
        V, V_world = self._twists
        self._v_V, self._v_Vw = V, V_world
        self._v_V_parts = (V[:3], V[3:], V_world[:3], V_world[3:])
        self._v_ctrl_limit = (
            self.model.actuator_ctrlrange[:, 1] if self._act_all else None
        )  # the model's, live (tests scale it in place)
        self._hot_data = d

    def _in_image(self, s: np.ndarray) -> bool:
        """Every feature (k, 2) inside the true image (``Camera.inside`` of all, one pass;
        NaN is outside)."""
        cam = self.true_camera
        return self._inside(s.ravel().tolist(), cam.width - 0.5, cam.height - 0.5)

    @staticmethod
    def _inside(s: list[float], high_u: float, high_v: float) -> bool:
        """Every feature of the flat (u₁, v₁, …) ``s`` in [−0.5, high_u] × [−0.5, high_v]
        (NaN is not)."""
        pairs = iter(s)
        for u, v in zip(pairs, pairs, strict=True):
            if not (u >= -0.5 and v >= -0.5 and u <= high_u and v <= high_v):
                return False
        return True

    # The true and the observed features: (array or None, flat list or None), each made from
    # the other on demand (the step computes Python floats, other callers read arrays).
    @property
    def _s_true(self) -> np.ndarray:
        arr, flat = self._s_true_pair
        if arr is None:
            arr = np.array(flat).reshape(-1, 2)
            self._s_true_pair = (arr, flat)
        return arr

    @_s_true.setter
    def _s_true(self, value: np.ndarray) -> None:
        self._s_true_pair = (value, None)

    def _s_true_flat(self) -> list[float]:
        arr, flat = self._s_true_pair
        if flat is None:
            flat = arr.ravel().tolist()
            self._s_true_pair = (arr, flat)
        return flat

    @property
    def _s_obs(self) -> np.ndarray:
        arr, flat = self._s_obs_pair
        if arr is None:
            arr = np.array(flat).reshape(-1, 2)
            self._s_obs_pair = (arr, flat)
        return arr

    @_s_obs.setter
    def _s_obs(self, value: np.ndarray) -> None:
        self._s_obs_pair = (value, None)

    def _s_obs_flat(self) -> list[float]:
        arr, flat = self._s_obs_pair
        if flat is None:
            flat = arr.ravel().tolist()
            self._s_obs_pair = (arr, flat)
        return flat

    def _s_ref_flat(self) -> list[float]:
        ref, flat = self._s_ref_list
        if ref is not self._s_ref:
            ref, flat = self._s_ref, self._s_ref.ravel().tolist()
            self._s_ref_list = (ref, flat)
        return flat

    def _kinematics(self) -> None:
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    # ------------------------------------------------------------------ episode setup
    def _draw_camera_error(self) -> None:
        """This episode's true camera: intrinsics and pose errors at the given magnitudes,
        random directions (known only to the simulator)."""
        rng = self.np_random
        e_f, e_c, e_t, e_r = self.camera_error
        scale = 1.0 + e_f * float(rng.choice((-1.0, 1.0)))
        offset = e_c * _random_unit(rng, 2)
        dt = e_t * _random_unit(rng, 3)
        dR = _rotation(e_r * _random_unit(rng, 3))
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
        pixel = 1e-5
        f = self.true_camera.fu * pixel
        m.cam_intrinsic[cid] = (f, f, -offset[0] * pixel, -offset[1] * pixel)

    def _draw_start(self) -> tuple[np.ndarray, np.ndarray]:
        """(start offset (6,), q(0)): drawn until reachable with every feature in view."""
        rng = self.np_random
        lx, ly, z0, z1 = self.start_translation
        tilt, spin = self.start_rotation
        for _ in range(START_TRIES):
            if self.start_offset is not None:
                offset = self.start_offset
            else:
                offset = np.array(
                    [
                        rng.uniform(-lx, lx),
                        rng.uniform(-ly, ly),
                        rng.uniform(z0, z1),
                        rng.uniform(-tilt, tilt),
                        rng.uniform(-tilt, tilt),
                        rng.uniform(-spin, spin),
                    ]
                )
            q = self._start_configuration(offset)
            if q is not None or self.start_offset is not None:
                return offset, q
        raise RuntimeError("no feasible start found")  # pragma: no cover

    def _start_configuration(self, offset: np.ndarray) -> np.ndarray | None:
        p_g, R_g = self._goal_pose
        R = R_g @ _rotation(offset[3:])
        p = p_g + R_g @ offset[:3]
        q, err = self._solve_ik(self.q_goal.copy(), p, R)
        if err > 1e-9 or np.any(q < self.lower + 0.1) or np.any(q > self.upper - 0.1):
            return None
        self._set_state(q)
        s = self._true_features()
        margin = 0.0 if self.start_offset is not None else START_IMAGE_MARGIN
        if s is None or not np.all(self.true_camera.inside(s, margin)):
            return None
        return q

    def _set_state(self, q: np.ndarray) -> None:
        self.data.qpos[self.qpos_adr] = q
        self.data.qvel[:] = 0.0
        self._kinematics()

    def _place_target(self) -> None:
        """Subclass hook: move the target (eye-in-hand) for this episode."""

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
        mujoco.mj_camlight(self.model, self.data)
        self._k = 0
        self._k_end = 0
        self._done = False
        self._detect_failures = 0
        self._err[:] = 0.0
        self._pos[:] = 0.0
        self._kin_key = None  # the first step runs the position stage (once per episode)
        self._s_true = self._true_features()
        self._s_obs = self._s_true.copy()
        self._observe()
        self._record(0)
        return self._obs(), {"start_offset": offset.copy()}

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        a, _ = self._check_action(action)
        m, d = self.model, self.data
        if self._hot_data is not d:
            self._hot_views()
        qd = self._joint_command(a)
        diverged = self._simulate(self._ctrl(qd))
        mujoco.mj_kinematics(m, d)
        if self._fast:  # self.data's position stage serves _record and the next Jacobian
            mujoco.mj_comPos(m, d)
            q = self._v_q
            self._kin_key = q.tobytes()
        else:
            q = d.qpos[self._q_rows].copy()
        if not self._camera_fixed:  # else mj_step's mj_camlight left its pose current
            mujoco.mj_camlight(m, d)
        k = self._k + 1 if self._k < self.max_steps else self.max_steps  # min(k, N − 1) + 1
        self._k = k
        q_list = q.tolist()
        at_limit = False  # = any(q < low stop) or any(q > high stop), on Python floats
        for x, low, high in zip(q_list, self._low_list, self._high_list, strict=True):
            if x < low or x > high:
                at_limit = True
                break
        s = None if diverged else self._true_feature_list()
        if s is None:
            lost = True
            s = self._s_true_flat()  # the last seen
        else:
            cam = self.true_camera
            lost = not self._inside(s, cam.width - 0.5, cam.height - 0.5)
            self._s_true_pair = (None, s)
        detection_failure = self._observe(s)
        e = self._record(k, None if self._fast else q, s)
        terminated = diverged or lost or at_limit
        kernel = self._kernel
        _DIV(-(e**2), REWARD_SCALES_SQ, out=kernel)
        _EXP(kernel, out=kernel)
        r_features = -(1.0 - float(_ADDR(kernel)) / kernel.size)  # = np.mean, one reduction
        r_action = -self.action_weight * float(a.dot(a)) / a.size  # a @ a's BLAS ddot
        # a failure is charged the rest of the episode at the worst feature reward (−1 per
        # step) on top of the penalty, so that ending an episode early never pays
        r_term = (-self.termination_penalty - float(self.max_steps - k)) if terminated else 0.0
        reward = r_features + r_action + r_term
        truncated = k >= self.max_steps and not terminated
        if not self._done:
            self._k_end = k
        self._done = self._done or terminated or truncated
        info: dict[str, Any] = {
            "reward_features": r_features,
            "reward_action": r_action,
            "reward_termination": r_term,
            "feature_error": e,
            "feature_lost": lost,
            "joint_limit": at_limit,
            "detection_failure": detection_failure,
            "diverged": bool(diverged),
        }
        if terminated or truncated:
            metrics = self.episode_metrics()
            info["episode_metrics"] = metrics
            info["is_success"] = bool(not terminated and metrics["final_feature_error"] < CONVERGED)
        return self._obs(q_list), reward, terminated, truncated, info

    def _joint_command(self, a: np.ndarray) -> np.ndarray:
        """q̇ (7,) from the action: a ⊙ q̇_max, or J⁺ V for a twist V = a ⊙ twist limits.

        The twist's Jacobian and flange pose come from ``self.data``'s position stage at the
        current joints (the fast path: run again only if the joints changed since the last
        step's), else from the Robot's own MjData; the same numbers."""
        if self.action_kind == "joint_velocity":
            return a * self.velocity_limit
        if not self._fast:
            return self._joint_command_robot(a, self.data.qpos[self._q_rows].copy())
        q = self._v_q
        m, d = self.model, self.data
        key = q.tobytes()
        if key != self._kin_key:  # a reset, or the state was set from outside (the last
            # step's state is finite: _simulate restores a diverged one)
            if not math.isfinite(q.dot(q)) and not np.all(np.isfinite(q)):  # corrupted:
                return np.zeros(self.n)  # the physics step reports it
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            self._kin_key = key
        _MUL(a, self.twist_limit, out=self._v_V)
        Jp = self._v_Jp
        mujoco.mj_jacSite(m, d, Jp, self._v_Jr, self._flange)
        if self.moving_offset:  # v_o = v_f + ω × r = v_f − r × ω, _moving_jacobian's operations
            _MUL(self._v_flange_z, self.moving_offset, out=self._v_r)
            self._v_r_tail[:] = self._v_r_head
            self._v_w_tail[:] = self._v_w_head
            t, t1, t2 = self._v_cross
            _MUL(self._v_w_ab, self._v_r_ab, out=t)  # (r1 w2, r2 w0, r0 w1), (r2 w1, r0 w2, r1 w0)
            _SUB(t1, t2, out=t1)
            _SUB(Jp, t1, out=Jp)
        R = self._v_twist_R
        Va, Vb, Wa, Wb = self._v_V_parts
        _DOT(R, Va, out=Wa)
        _DOT(R, Vb, out=Wb)
        V_world, J, JT = self._v_Vw, self._v_J, self._v_JT
        JJT = _DOT(J, JT, out=self._jjt)
        try:
            return _DOT(JT, solve(JJT, V_world), out=self._qd)  # J⁺ V
        except np.linalg.LinAlgError:  # exactly singular: the least-squares solution
            return np.linalg.lstsq(J, V_world, rcond=None)[0]

    def _joint_command_robot(self, a: np.ndarray, q: np.ndarray) -> np.ndarray:
        """:meth:`_joint_command` through the Robot (joints that are not the whole state)."""
        if not math.isfinite(q.dot(q)) and not np.all(np.isfinite(q)):  # a corrupted state:
            return np.zeros(self.n)  # the physics step reports it
        V = a * self.twist_limit
        J = self._moving_jacobian(q)
        V_world = self._world_twist(V, q)
        try:
            return J.T @ np.linalg.solve(J @ J.T, V_world)  # J⁺ V
        except np.linalg.LinAlgError:  # exactly singular: the least-squares solution
            return np.linalg.lstsq(J, V_world, rcond=None)[0]

    def _world_twist(self, V: np.ndarray, q: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _twist_rotation(self) -> np.ndarray:
        """R (3, 3) of the twist's frame → world now (fast path: ``self.data``'s)."""
        raise NotImplementedError

    def _ctrl(self, qd: np.ndarray) -> np.ndarray:
        """Velocity-servo commands: q̇ scaled down uniformly to the actuators' ctrlrange (an
        array the caller may not keep: _simulate copies it)."""
        if self._hot_data is not self.data:
            self._hot_views()
        limit = self._v_ctrl_limit  # the model's now (tests scale it)
        if limit is None:
            limit = self.model.actuator_ctrlrange[self._act, 1]
        # ratio = np.max(np.abs(qd) / limit) on Python floats (NaN wins, as np.maximum's)
        ratio = -math.inf
        try:
            for x, high in zip(qd.tolist(), limit.tolist(), strict=True):
                r = abs(x) / high
                if r > ratio or r != r:
                    ratio = r
                    if r != r:
                        break
        except ZeroDivisionError:  # a zero limit: numpy's inf/NaN, without warnings
            with np.errstate(all="ignore"):
                ratio = float(_MAXR(_ABS(qd) / limit))
        if math.isfinite(ratio) and ratio > 1.0:
            qd = qd / ratio
        if self._act_all:  # every actuator, in order
            return qd
        ctrl = np.zeros(self.model.nu)
        ctrl[self._act] = qd
        return ctrl

    # ------------------------------------------------------------------ observation
    def _observe(self, s: list[float] | None = None) -> bool:
        """Update the observed features (and the image); True if a marker was not found.
        ``s``: the true features as a flat list, if the caller has it."""
        failure = False
        if self.features == "projected":
            # normal(0, 1, (4, 2)) draws 0.0 + 1.0 z from the same z in the same order: z
            # itself, but +0.0 for z = −0.0, and u + (±0.0 σ) differs only for u = −0.0, which
            # no pixel coordinate c + f X / Z (c ≠ −0.0) is
            noise = self.np_random.standard_normal(out=self._noise).tolist()
            scale = self.pixel_noise  # s + noise · σ, on Python floats
            if s is None:
                s = self._s_true_flat()
            self._s_obs_pair = (None, [u + n * scale for u, n in zip(s, noise, strict=True)])
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
            self._eye = self._make_camera_renderer()
        self._camera_view(self._eye, self._image)

    def _camera_view(self, renderer: mujoco.Renderer, out: np.ndarray) -> None:
        """The servo camera's view into ``out`` (renderer.height, renderer.width, 3)."""
        # geom group 1 holds the robot file's translucent payload placeholder at the flange,
        # around the camera: not part of this task, hidden from the camera
        option = mujoco.MjvOption()
        option.geomgroup[1] = 0
        renderer.update_scene(self.data, camera=self._cam_id, scene_option=option)
        renderer.render(out=out)

    def _make_camera_renderer(
        self, height: int = IMAGE_HEIGHT, width: int = IMAGE_WIDTH
    ) -> mujoco.Renderer:
        import os

        backend = os.environ.get("MUJOCO_GL", "").strip().lower()
        what = f'features="{self.features}", obs_image={self.obs_image}'
        if backend in GL_DISABLED:
            raise RuntimeError(
                f"{what} renders the camera image: {GL_HELP} (MUJOCO_GL={backend!r})"
            )
        try:
            renderer = mujoco.Renderer(self.model, height, width)
        except Exception as exc:
            raise RuntimeError(
                f"{what} renders the camera image: {GL_HELP} ({type(exc).__name__}: {exc})"
            ) from exc
        for flag in (
            mujoco.mjtRndFlag.mjRND_SHADOW,
            mujoco.mjtRndFlag.mjRND_REFLECTION,
            mujoco.mjtRndFlag.mjRND_SKYBOX,
        ):
            renderer.scene.flags[flag] = False
        return renderer

    def _obs(self, q: list[float] | None = None) -> dict[str, np.ndarray]:
        """The observation; ``q``: the joint positions as Python floats, if the caller has
        them."""
        if q is None:
            q = self.data.qpos[self._q_rows].tolist()
        buf = np.array(self._s_obs_flat() + self._s_ref_flat() + q)  # one new buffer, views
        CLIP(buf, self._obs_low, self._obs_high, out=buf)  # ±bound (px), ±2π (rad): one call
        out = {"features": buf[:8], "features_ref": buf[8:16], "q": buf[16:]}
        if self.obs_image:
            out["image"] = self._image.copy()
        return out

    def _record(self, k: int, q: np.ndarray | None = None, s: list[float] | None = None
                ) -> float:
        """The true feature error (px, returned) and the moving frame's position (goal frame)
        at step k. ``q``: the joint positions now, for the Robot's kinematics; None: those of
        ``self.data`` (its position stage is current), or the Robot's at ``self.data``'s
        joints when the joints are not the whole state. ``s``: the true features' flat list,
        if the caller has it."""
        if s is None:
            s = self._s_true_flat()
        a, b = iter(s), iter(self._s_ref_flat())
        # ((s − s*)²).tolist() summed in numpy's order: 0.0 + u² + v² per point
        total = sum(
            [
                0.0 + (u - ur) * (u - ur) + (v - vr) * (v - vr)
                for u, v, ur, vr in zip(a, a, b, b, strict=True)
            ]
        )
        e = math.sqrt((0.0 + total) / (len(s) // 2))
        self._err[k] = e
        goal, p_g, R_gT = self._goal_lists
        if goal is not self._goal_pose:
            goal = self._goal_pose
            p_g, R_gT = goal[0].tolist(), goal[1].T
            self._goal_lists = (goal, p_g, R_gT)
        if q is None and self._fast:
            if self._hot_data is not self.data:
                self._hot_views()
            # _moving_pose's p + offset z, then − p_g, on Python floats
            (x, y, z), (zx, zy, zz), off = (
                self._v_flange_p.tolist(),
                self._v_flange_z.tolist(),
                self.moving_offset,
            )
            p = self._p3
            p[0] = x + off * zx - p_g[0]
            p[1] = y + off * zy - p_g[1]
            p[2] = z + off * zz - p_g[2]
        else:
            if q is None:
                q = self.data.qpos[self._q_rows].copy()
            p = self._moving_pose(q)[0] - goal[0]
        _DOT(R_gT, p, out=self._pos[k])
        return e

    def episode_metrics(self) -> dict[str, float]:
        """Metrics of the episode so far (see ``metric_specs``)."""
        k = max(self._k_end, 1)
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
    def draw_task(self, scene: mujoco.MjvScene) -> None:
        p_g, R_g = self._goal_pose
        rendering.add_frame(scene, p_g, R_g, 0.08, 0.004)
        k = max(self._k, 1)
        path = p_g + self._pos[: k + 1] @ R_g.T
        if k > 1:
            rendering.add_polyline(scene, path, 0.003, rendering.REFERENCE)

    def caption(self) -> str:
        k = min(self._k, self.max_steps)
        return f"t {k * self.dt:5.2f} s  |s - s*| {self._err[k]:6.2f} px"

    def render(self) -> np.ndarray | None:
        frame = super().render()
        if frame is None or not self.draw_markers:
            return frame
        return self._inset(frame)

    def _inset(self, frame: np.ndarray) -> np.ndarray:
        """The camera's view (features: current ● / desired ○) in the bottom-right quarter."""
        h, w = frame.shape[:2]
        ih, iw = h // 3, w // 3
        if ih < 8 or iw < 8:
            return frame
        sy, sx = IMAGE_HEIGHT / ih, IMAGE_WIDTH / iw
        inset = np.full((ih, iw, 3), 30, dtype=np.uint8)
        try:
            if self.obs_image or self.features == "detected":  # this step's image exists
                image, rows, cols = self._image, IMAGE_HEIGHT, IMAGE_WIDTH
            else:  # the camera's view rendered at the inset's height only (4:3 kept)
                image = self._small_camera_view(ih)
                rows, cols = image.shape[:2]
            inset = image[(np.arange(ih) * (rows / ih)).astype(int)][
                :, (np.arange(iw) * (cols / iw)).astype(int)
            ].copy()
        except RuntimeError:
            pass
        for s, colour, r in ((self._s_ref, (255, 255, 255), 2), (self._s_true, (0, 255, 255), 1)):
            for u, v in s:
                c, rr = int(u / sx), int(v / sy)
                if 0 <= rr < ih and 0 <= c < iw:
                    inset[max(rr - r, 0) : rr + r + 1, max(c - r, 0) : c + r + 1] = colour
        frame[h - ih :, w - iw :] = inset
        return frame

    def _small_camera_view(self, height: int) -> np.ndarray:
        """The camera's view rendered ``height`` px tall (the image's aspect ratio), for the
        inset: ~1/30 of the pixels of the full 640 × 480 image at a 320 px frame."""
        width = max(1, round(height * IMAGE_WIDTH / IMAGE_HEIGHT))
        small = self._eye_small
        if small is None or (small.height, small.width) != (height, width):
            if small is not None:
                small.close()
            small = self._eye_small = self._make_camera_renderer(height, width)
        image = np.empty((height, width, 3), dtype=np.uint8)
        self._camera_view(small, image)
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
        state["_hot_data"] = None  # views would come back as copies, detached from the MjData
        for name in [k for k in state if k.startswith("_v_")]:
            del state[name]
        state["_goal_lists"] = (None, [], None)  # holds a view of the goal rotation
        return state

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

    def _nominal_world_camera(self) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError


class VisualServoEnv(_VisualServoBase):
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
    its colour (:func:`detect_markers`, centroid of its pixels); a marker not found keeps its
    last observed position and counts as a detection failure (``info["detection_failure"]``).
    Depth is not observed: controllers estimate it from the four points and the target model
    (``controller_context().extras["model_points"]``). Camera intrinsics (nominal) are in
    ``controller_context().extras["camera"]``.

    ## Rewards
    r = r_features + r_action + r_termination, each in ``info["reward_<name>"]``:
    - r_features = −(1 − (1/3) Σ_s exp(−e² / s²)), s ∈ (100, 10, 1) px, e the true feature
      error (RMS point distance ‖s − s*‖/2, px), in [−1, 0];
    - r_action = −``action_weight`` ‖a‖² / dim(a);
    - r_termination = −``termination_penalty`` − (steps left in the episode) on the step that
      loses a feature, reaches a joint limit or diverges, else 0: the rest of the episode is
      charged at the worst feature reward, so ending early never pays (with a constant
      penalty a PPO agent learned to lose the features at once).

    ## Starting State
    At rest at the start offset (see Description), drawn until reachable inside the joint
    limits (0.1 rad margin) with every feature ≥ 40 px inside the image (200 tries).
    ``start_offset=(tx, ty, tz, rx, ry, rz)`` sets it exactly (m, rotation vector in rad; the
    start camera's pose in the goal camera's optical frame) and leaves the target untilted
    (facing the goal camera squarely, like ViSP's cdMo = (0, 0, 0.75, 0, 0, 0)); an offset that
    is unreachable or does not see every feature raises ``InvalidArgument`` at reset.
    ``info["start_offset"]`` holds the offset used.

    ## Episode End
    Truncated after ``episode_duration`` s. Terminated (a failure) when a feature leaves the
    image or goes behind the camera (``info["feature_lost"]``), a joint comes within 0.01 rad
    of its limit (``info["joint_limit"]``), or the physics diverges (``info["diverged"]``).
    Success: not terminated and a final feature error < 1 px.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | action | "twist" | "twist" (camera twist) or "joint_velocity" |
    | features | "projected" | "projected" (exact + noise) or "detected" (rendered image) |
    | obs_image | False | add the camera image to the observation (renders every step) |
    | pixel_noise | 0.1 | std of the projected features' noise (px) |
    | camera_error | (0.0, 0.0, 0.0, 0.0) | true-camera errors unknown to controllers: focal-length scale error (relative, sign random), principal-point offset (px, random direction), hand-eye translation (m) and rotation (rad), random directions per episode |
    | start_offset | None | fixed start pose in the goal frame (tx, ty, tz, rx, ry, rz), or None (random) |
    | control_freq | 25.0 | control frequency (Hz); ViSP's 40 ms period |
    | episode_duration | 15.0 | s |
    | action_weight | 0.01 | weight of the action-size cost |
    | termination_penalty | 50.0 | reward lost on a failure, on top of the steps left |
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
    ``baselines.available("cir_gym/VisualServo-v0")``: ibvs, pbvs.

    ## Version History
    - v0: initial version.
    """

    scene: ClassVar[str] = "visual_servo.xml"
    eye_in_hand: ClassVar[bool] = True
    marker_side: ClassVar[float] = 0.2
    marker_radius: ClassVar[float] = 0.015
    moving_offset: ClassVar[float] = 0.0
    start_translation: ClassVar[tuple[float, float, float, float]] = (0.12, 0.12, -0.25, 0.05)
    target_tilt: ClassVar[float] = 0.2  # rad

    def _add_markers_and_camera(self, spec: mujoco.MjSpec) -> None:
        # flange_cam's pose (xyaxes "1 0 0 0 -1 0": a rotation by π about x), moved per
        # episode by the hand-eye error
        nominal = spec.camera("flange_cam")
        cam = spec.body("link7").add_camera(
            name="servo_cam", pos=list(nominal.pos), quat=[0.0, 1.0, 0.0, 0.0]
        )
        self._camera_spec(cam)

    def _place_target(self) -> None:
        """Target plane 0.75 m in front of the goal camera, tilted and turned per episode."""
        p_g, R_g = self._goal_pose
        if self.start_offset is None:
            rng = self.np_random
            tilt = self.target_tilt * float(rng.uniform(0, 1)) * _random_unit(rng, 2)
            spin = float(rng.uniform(-np.pi, np.pi))
            R_t = (
                R_g
                @ _rotation(np.array([tilt[0], tilt[1], 0.0]))
                @ _rotation(np.array([0.0, 0.0, spin]))
            )
        else:
            R_t = R_g
        p_t = p_g + GOAL_DEPTH * R_g[:, 2]
        tid = self.model.body("target").id
        self.model.body_pos[tid] = p_t
        mujoco.mju_mat2Quat(self.model.body_quat[tid], R_t.ravel())

    def _world_twist(self, V: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Camera twist (optical frame, nominally the flange frame) → world (6,)."""
        R = self.robot.site_pose(self._flange, q)[1]
        return np.concatenate((R @ V[:3], R @ V[3:]))

    def _twist_rotation(self) -> np.ndarray:
        return self._v_flange_R  # the flange's (nominal camera's) rotation, self.data's

    def draw_task(self, scene: mujoco.MjvScene) -> None:
        super().draw_task(scene)
        rendering.place_world_geoms(scene, self.model)  # the target, moved per episode


class VisualServoEyeToHandEnv(_VisualServoBase):
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
    The arm is velocity-servoed as in ``VisualServo-v0``.

    ## Action Space
    ``action="twist"``: ``Box(-1, 1, (6,), float32)``, the plate's twist expressed in the
    (nominal) camera's optical frame: v (m/s, velocity of the plate centre) = a[:3] · 0.3, ω
    (rad/s) = a[3:] · 1.0; the environment maps it to the world with the nominal camera pose
    and to q̇ = J⁺ V through the plate's Jacobian, scaled down uniformly to the joint-velocity
    limits. ``action="joint_velocity"``: ``Box(-1, 1, (7,), float32)``, q̇ = a ⊙ q̇_max.
    Finite values outside [-1, 1] are clipped; NaN/inf or a wrong shape raise ``ValueError``.

    ## Observation Space
    As ``VisualServo-v0`` (features of the four markers in the fixed camera, s*, q; the image
    with ``obs_image=True``). The nominal camera pose in the world is
    ``controller_context().extras["camera_pose"]`` (p (3,), R (3, 3) optical → world).

    ## Rewards
    As ``VisualServo-v0``.

    ## Starting State
    At rest at the start offset (see Description); ``start_offset`` sets the plate's start
    pose in its goal frame exactly (raises ``InvalidArgument`` at reset if unreachable or out
    of view).

    ## Episode End
    As ``VisualServo-v0``. ``camera_error``'s hand-eye terms here displace the fixed camera
    from its nominal pose (extrinsic calibration error).

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | action | "twist" | "twist" (camera twist) or "joint_velocity" |
    | features | "projected" | "projected" (exact + noise) or "detected" (rendered image) |
    | obs_image | False | add the camera image to the observation (renders every step) |
    | pixel_noise | 0.1 | std of the projected features' noise (px) |
    | camera_error | (0.0, 0.0, 0.0, 0.0) | true-camera errors unknown to controllers: focal-length scale error (relative, sign random), principal-point offset (px, random direction), hand-eye translation (m) and rotation (rad), random directions per episode |
    | start_offset | None | fixed start pose in the goal frame (tx, ty, tz, rx, ry, rz), or None (random) |
    | control_freq | 25.0 | control frequency (Hz); ViSP's 40 ms period |
    | episode_duration | 15.0 | s |
    | action_weight | 0.01 | weight of the action-size cost |
    | termination_penalty | 50.0 | reward lost on a failure, on top of the steps left |
    | render_mode | None | None, "human" or "rgb_array" (camera "side", the camera image inset) |
    | width | 480 | frame width (px) |
    | height | 360 | frame height (px) |

    ## Metrics
    As ``VisualServo-v0``; ``path_length`` and ``retreat`` are the plate's (retreat: away from
    the camera, behind both start and goal).

    ## Reference controllers
    ``baselines.available("cir_gym/VisualServoEyeToHand-v0")``: ibvs_eye_to_hand.

    ## Version History
    - v0: initial version.
    """

    scene: ClassVar[str] = "visual_servo_eye_to_hand.xml"
    eye_in_hand: ClassVar[bool] = False
    marker_side: ClassVar[float] = 0.16
    marker_radius: ClassVar[float] = 0.012
    moving_offset: ClassVar[float] = 0.03  # m beyond the flange (link7 z = 0.045 + 0.03)
    start_translation: ClassVar[tuple[float, float, float, float]] = (0.1, 0.1, -0.2, 0.05)
    camera_position: ClassVar[tuple[float, float, float]] = (1.606, 0.0, 0.45)

    def _add_markers_and_camera(self, spec: mujoco.MjSpec) -> None:
        link7 = spec.body("link7")
        plate = link7.add_body(name="marker_plate", pos=[0.0, 0.0, 0.045 + self.moving_offset])
        plate.add_geom(
            name="marker_plate_geom",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[0.1, 0.1, 0.004],
            pos=[0.0, 0.0, -0.005],
            rgba=[0.15, 0.15, 0.17, 1.0],
            contype=0,
            conaffinity=0,
        )
        for i, (x, y, _) in enumerate(self._model_points()):
            plate.add_geom(
                name=f"marker{i}",
                type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                size=[self.marker_radius, 0.001, 0.0],
                pos=[x, y, 0.0],
                rgba=[*MARKER_COLOURS[i], 1.0],
                contype=0,
                conaffinity=0,
            )
        # optical axes (x, y, z) = (y_w, −z_w, −x_w); MuJoCo's camera axes: (x, −y, −z)
        quat = np.empty(4)
        mujoco.mju_mat2Quat(
            quat, np.column_stack(([0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])).ravel()
        )
        cam = spec.worldbody.add_camera(
            name="servo_cam", pos=list(self.camera_position), quat=list(quat)
        )
        self._camera_spec(cam)

    #: the fixed camera's optical frame → world (nominal)
    _CAMERA_R: ClassVar[np.ndarray] = np.column_stack(
        ([0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0])
    )

    def _nominal_world_camera(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.camera_position), self._CAMERA_R.copy()

    def _world_twist(self, V: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Plate twist in the nominal camera frame → world (6,)."""
        R = self._CAMERA_R
        return np.concatenate((R @ V[:3], R @ V[3:]))

    def _twist_rotation(self) -> np.ndarray:
        return self._CAMERA_R


VISUAL_SERVO_ENVIRONMENTS: dict[str, tuple[type[RobotEnv], str]] = {
    "cir_gym/VisualServo-v0": (
        VisualServoEnv,
        "iiwa14 eye-in-hand visual servoing on four image points with a camera twist (ch. 7)",
    ),
    "cir_gym/VisualServoEyeToHand-v0": (
        VisualServoEyeToHandEnv,
        "iiwa14 eye-to-hand visual servoing: a fixed camera guides four markers (ch. 7)",
    ),
}
