"""CartesianTracking's pictures: the markers ``render`` draws and the frames' caption."""

from __future__ import annotations

from typing import Any

import numpy as np

from cir_gym import rendering
from cir_gym import trajectories as traj


def draw_cartesian_tracking(env: Any, scene: Any) -> None:
    """A CartesianTrackingEnv's markers: the reference path (not for ``regulation``), the
    reference frame and a target sphere at p̄(t), and the flange's frame now (visual-only
    geoms appended to ``scene``)."""
    k = min(env._k, env.max_steps)
    if env.path != "regulation":
        rendering.add_polyline(
            scene, env._x_ref, 0.004, rendering.REFERENCE, max_segments=rendering.TRACE_SAMPLES
        )
    rendering.add_frame(
        scene, env._x_ref[k], traj.matrix_from_quat(env._quat_ref[k]), 0.12, 0.006, alpha=0.5
    )
    rendering.add_sphere(scene, env._x_ref[k], 0.015, rendering.TARGET)
    p, R = env.flange_pose()
    rendering.add_frame(scene, p, R, 0.08, 0.004)


def cartesian_caption(env: Any) -> str:
    """A CartesianTrackingEnv's caption: ``t``, the position error (mm) and the orientation error (deg) now."""
    k = min(env._k, env.max_steps)
    e_pos, e_ang = env.pose_errors(k)
    return (
        f"t = {k * env.dt:5.2f} s  |p_ref - p| = {1e3 * e_pos:7.2f} mm  "
        f"angle {np.rad2deg(e_ang):6.2f} deg"
    )
