"""The visual-servoing scenes: their numbers, the model building and the camera's pictures.

Used by :mod:`cir_gym.envs.visual_servo_base`. The scene files (``assets/scenes/
visual_servo*.xml``) hold the iiwa14, the target or the camera stand; at run time the
environment adds its rendering camera ``servo_cam`` (the true camera, moved by the calibration
error), the marker plate of the eye-to-hand task, gravity compensation and the velocity servos.
"""

from __future__ import annotations

import os
from typing import Any

import mujoco
import numpy as np

from cir_gym.envs.base import GL_DISABLED, GL_HELP
from cir_gym.robot import ASSETS, Robot
from cir_gym.vision import MARKER_COLOURS

__all__ = [
    "FOVY",
    "GOAL_DEPTH",
    "IMAGE_HEIGHT",
    "IMAGE_WIDTH",
    "Q_GOAL",
    "add_fixed_camera",
    "add_flange_camera",
    "add_marker_plate",
    "build_model",
    "camera_inset",
    "camera_renderer",
    "camera_view",
    "model_points",
    "velocity_servos",
]

#: the goal configuration: flange (= eye-in-hand optical frame) at (0.826, 0, 0.45) m looking
#: along +x (world), elbow at 1.07 rad (closed form in the arm's plane: wrist 0.70 m out,
#: 0.09 m above the shoulder). Backing the camera up along its axis closes the elbow: there is
#: room for 0.28 m (then joint 4 reaches its limit) and 0.08 m forward (then the arm nears its
#: stretched singularity). q7 = −1.2 leaves room for rotations about the optical axis of
#: −105° … +200°.
Q_GOAL = (0.0, 0.923, 0.0, -1.0687, 0.0, -0.4209, -1.2)
GOAL_DEPTH = 0.75  # m: target plane in front of the goal camera (ViSP's cdMo)
IMAGE_WIDTH, IMAGE_HEIGHT, FOVY = 640, 480, 60.0  # the camera (flange_cam's fovy)
SERVO_BANDWIDTH = 200.0  # 1/s: velocity-servo gain k_v,i = 200 B_ii(q_goal)
TIMESTEP = 0.002  # s: physics step (implicitfast integrates the servo damping stably)
PIXEL_SIZE = 1e-5  # m: the camera's sensor pixel (MuJoCo's intrinsics are in sensor units)


def build_model(scene: str, add_task: Any) -> mujoco.MjModel:
    """The compiled scene ``scene`` (a file of ``assets/scenes``) after ``add_task(spec)``
    added the task's bodies and camera, every body gravity-compensated (the arm's own
    controller compensates gravity; set before compiling)."""
    spec = mujoco.MjSpec.from_file(str(ASSETS / "scenes" / scene))
    spec.option.timestep = TIMESTEP
    add_task(spec)
    for body in spec.bodies:
        body.gravcomp = 1.0
    return spec.compile()


def model_points(side: float) -> np.ndarray:
    """The four marker centres (4, 3) in the target (plate) frame: the corners of a square of
    ``side`` m in its plane z = 0, in the features' order (red, green, blue, yellow)."""
    h = side / 2.0
    return np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])


def _set_intrinsics(cam: Any) -> None:
    """Explicit intrinsics: 640 × 480 px, focal (H/2)/tan(fovy/2), centred, 10 µm pixels."""
    f = 0.5 * IMAGE_HEIGHT / np.tan(np.deg2rad(FOVY) / 2.0)
    cam.resolution = [IMAGE_WIDTH, IMAGE_HEIGHT]
    cam.sensor_size = [IMAGE_WIDTH * PIXEL_SIZE, IMAGE_HEIGHT * PIXEL_SIZE]
    cam.focal_pixel = [f, f]
    cam.principal_pixel = [0.0, 0.0]


def add_flange_camera(spec: mujoco.MjSpec) -> None:
    """``servo_cam`` on link7 at ``flange_cam``'s pose (xyaxes "1 0 0 0 -1 0": a rotation by π
    about x), which the calibration error moves per episode."""
    nominal = spec.camera("flange_cam")
    cam = spec.body("link7").add_camera(
        name="servo_cam", pos=list(nominal.pos), quat=[0.0, 1.0, 0.0, 0.0]
    )
    _set_intrinsics(cam)


def add_marker_plate(spec: mujoco.MjSpec, points: np.ndarray, radius: float, offset: float
                     ) -> None:
    """A 0.2 m plate on link7, its face ``offset`` m beyond the flange, carrying discs of
    ``radius`` m at ``points`` (4, 3) (geoms ``marker0`` … ``marker3``)."""
    plate = spec.body("link7").add_body(name="marker_plate", pos=[0.0, 0.0, 0.045 + offset])
    plate.add_geom(
        name="marker_plate_geom",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.1, 0.1, 0.004],
        pos=[0.0, 0.0, -0.005],
        rgba=[0.15, 0.15, 0.17, 1.0],
        contype=0,
        conaffinity=0,
    )
    for i, (x, y, _) in enumerate(points):
        plate.add_geom(
            name=f"marker{i}",
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[radius, 0.001, 0.0],
            pos=[x, y, 0.0],
            rgba=[*MARKER_COLOURS[i], 1.0],
            contype=0,
            conaffinity=0,
        )


def add_fixed_camera(spec: mujoco.MjSpec, position: tuple[float, ...], R: np.ndarray) -> None:
    """``servo_cam`` fixed in the world at ``position`` with optical axes ``R`` (3, 3, optical
    → world); MuJoCo's camera axes are the optical (x, −y, −z)."""
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, (R @ np.diag([1.0, -1.0, -1.0])).ravel())
    cam = spec.worldbody.add_camera(name="servo_cam", pos=list(position), quat=list(quat))
    _set_intrinsics(cam)


def velocity_servos(model: mujoco.MjModel, robot: Robot, q_goal: np.ndarray) -> None:
    """The arm's motors become velocity servos τ = k_v (q̇_cmd − q̇), k_v = 200 B_ii(q_goal),
    |q̇_cmd| ≤ q̇_max (ctrlrange), |τ| ≤ τ_max (forcerange)."""
    kv = SERVO_BANDWIDTH * np.diag(robot.inertia(q_goal))
    for j, a in enumerate(robot.actuator_ids):
        model.actuator_gainprm[a, :3] = (kv[j], 0.0, 0.0)
        model.actuator_biastype[a] = int(mujoco.mjtBias.mjBIAS_AFFINE)
        model.actuator_biasprm[a, :3] = (0.0, 0.0, -kv[j])
        model.actuator_ctrlrange[a] = (-robot.velocity_limit[j], robot.velocity_limit[j])
        model.actuator_forcerange[a] = (-robot.torque_limit[j], robot.torque_limit[j])
        model.actuator_forcelimited[a] = 1


# ---------------------------------------------------------------------- the camera's pictures
def camera_renderer(model: mujoco.MjModel, height: int, width: int, what: str
                    ) -> mujoco.Renderer:
    """An offscreen renderer for the servo camera's image; a clear error without OpenGL that
    names ``what`` needs it."""
    backend = os.environ.get("MUJOCO_GL", "").strip().lower()
    if backend in GL_DISABLED:
        raise RuntimeError(f"{what} renders the camera image: {GL_HELP} (MUJOCO_GL={backend!r})")
    try:
        renderer = mujoco.Renderer(model, height, width)
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


def camera_view(renderer: mujoco.Renderer, data: mujoco.MjData, camera: int, out: np.ndarray
                ) -> None:
    """Camera ``camera``'s view into ``out`` (renderer.height, renderer.width, 3). Geom group 1
    (the robot file's translucent payload placeholder at the flange, around the eye-in-hand
    camera) is not part of the task and hidden."""
    option = mujoco.MjvOption()
    option.geomgroup[1] = 0
    renderer.update_scene(data, camera=camera, scene_option=option)
    renderer.render(out=out)


def camera_inset(frame: np.ndarray, image: np.ndarray | None, s_ref: np.ndarray,
                 s_true: np.ndarray) -> np.ndarray:
    """``frame`` with the camera's ``image`` (any size, 4:3) and the features (current ● cyan,
    desired ○ white, (4, 2) px of the 640 × 480 image) in its bottom-right ninth."""
    h, w = frame.shape[:2]
    ih, iw = h // 3, w // 3
    if ih < 8 or iw < 8:
        return frame
    sy, sx = IMAGE_HEIGHT / ih, IMAGE_WIDTH / iw
    inset = np.full((ih, iw, 3), 30, dtype=np.uint8)
    if image is not None:
        rows, cols = image.shape[:2]
        inset = image[(np.arange(ih) * (rows / ih)).astype(int)][
            :, (np.arange(iw) * (cols / iw)).astype(int)
        ].copy()
    for s, colour, r in ((s_ref, (255, 255, 255), 2), (s_true, (0, 255, 255), 1)):
        for u, v in s:
            c, rr = int(u / sx), int(v / sy)
            if 0 <= rr < ih and 0 <= c < iw:
                inset[max(rr - r, 0) : rr + r + 1, max(c - r, 0) : c + r + 1] = colour
    frame[h - ih :, w - iw :] = inset
    return frame
