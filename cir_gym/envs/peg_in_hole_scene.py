"""PegInHole's scene around the physics: the start posture and the drawing of the task."""

from __future__ import annotations

from functools import lru_cache

import mujoco
import numpy as np

from cir_gym import peg_hole_geometry as geo
from cir_gym import trajectories as traj
from cir_gym.operational_space import rotvec_error
from cir_gym.robot import Robot

__all__ = ["ALIGNED", "ALIGNED_QUAT", "PREFERRED_POSTURE", "draw_task", "start_posture"]

#: Orientation of the peg-tip frame in the hole frame when the peg is aligned with the bore
#: (peg z pointing into the hole: a half turn about y).
ALIGNED = np.diag([-1.0, 1.0, -1.0])
ALIGNED_QUAT = traj.quat_from_matrix(ALIGNED)
#: Posture the start is pulled toward (the robot file's home): elbow bent, wrist off its
#: singularity.
PREFERRED_POSTURE = np.array([0.0, 0.6, 0.0, -1.4, 0.0, 0.9, 0.0])


@lru_cache(maxsize=8)
def start_posture(height: float) -> tuple[float, ...]:
    """Joint angles (7,) with the peg tip ``height`` (m) above the nominal hole, aligned with its
    axis: Newton steps on the tip pose with a null-space pull toward :data:`PREFERRED_POSTURE`."""
    model, _ = geo.build_peg_in_hole()
    robot = Robot(model)
    target = np.asarray(geo.HOLE_POSITION) + np.array([0.0, 0.0, height])
    q = PREFERRED_POSTURE.copy()
    for _ in range(200):
        p, R = robot.site_pose("peg_tip", q)
        e = np.concatenate((target - p, rotvec_error(ALIGNED_QUAT, traj.quat_from_matrix(R))))
        J = robot.jacobian("peg_tip", q)
        J_pinv = np.linalg.pinv(J)
        q = q + J_pinv @ e + (np.eye(robot.n) - J_pinv @ J) @ (0.1 * (PREFERRED_POSTURE - q))
        if float(e @ e) < 1e-24:
            break
    return tuple(float(v) for v in q)


def draw_task(
    scene: mujoco.MjvScene,
    model: mujoco.MjModel,
    hole_pos: np.ndarray,
    true_hole_pos: np.ndarray,
    true_hole_R: np.ndarray,
    depth: float,
    tip: np.ndarray,
    net_force: np.ndarray,
) -> None:
    """A cut-away of the block (the walls on the camera's side of the bore made translucent),
    the nominal hole frame, the true bore axis (green line, ``depth`` m deep) and the net
    contact force on the robot (red arrow from the tip ``tip`` (3,), 1 mm per N)."""
    from cir_gym import rendering

    kind = int(mujoco.mjtObj.mjOBJ_GEOM)
    block = model.body("block").id
    eye = np.mean([scene.camera[i].pos for i in range(2)], axis=0)
    to_eye = eye - true_hole_pos
    for i in range(scene.ngeom):
        g = scene.geoms[i]
        if g.objtype != kind or g.objid < 0 or model.geom_bodyid[g.objid] != block:
            continue
        if float((np.asarray(g.pos) - true_hole_pos) @ to_eye) > 0:
            g.rgba[3] = 0.15
    rendering.add_frame(scene, hole_pos, np.eye(3), 0.03, alpha=0.6)
    axis = true_hole_R[:, 2]
    rendering.add_line(
        scene, true_hole_pos + 0.03 * axis, true_hole_pos - depth * axis, 2.0, rendering.GREEN
    )
    rendering.add_arrow(scene, tip, 1e-3 * net_force, 0.001, rendering.RED)
