"""RedundantIK's arms: the facts and default arguments of each robot's task, one record each."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["IIWA14", "MANIPULABILITY_WINDOW", "PLANAR3R", "RedundantIKRobot"]

#: fraction of the lap (its start-up) that ``min_manipulability`` and the "manipulability"
#: start leave out: the reference barely moves there and a controller may reconfigure the arm
MANIPULABILITY_WINDOW = 0.1


@dataclass(frozen=True)
class RedundantIKRobot:
    """One arm of the RedundantIK task.

    Attributes:
        robot: the robot file's name (:func:`cir_gym.robot.robot_path`).
        site: the task site.
        pos_dim: position coordinates of the task: 2 (x, y in the plane z = 0) or 3.
        task_dim: 2 (position in the plane) or 6 (position and orientation).
        obstacle_geom: "cylinder" (a circle in the plane) or "sphere".
        obstacle_links: bodies whose capsules an obstacle is placed against.
        manipulability_scale: w₀ of the manipulability cost exp(−w / w₀) (task units).
        camera: (name, position (3,) m, vertical field of view deg) of a camera added to the
            scene, or None (MuJoCo's free camera).
        control_freq: Hz, the default control frequency.
        episode_duration: s, the default lap time.
        joint_window: rad, the default width of the narrowed joint range ("joint_limits").
    """

    robot: str
    site: str
    pos_dim: int
    task_dim: int
    obstacle_geom: str
    obstacle_links: tuple[str, ...]
    manipulability_scale: float
    camera: tuple[str, tuple[float, float, float], float] | None
    control_freq: float
    episode_duration: float
    joint_window: float


#: the planar 3R arm (links 0.5, 0.4, 0.3 m): position of ``ee`` in the plane, m = 2
PLANAR3R = RedundantIKRobot(
    robot="planar3r",
    site="ee",
    pos_dim=2,
    task_dim=2,
    obstacle_geom="cylinder",
    obstacle_links=("link1", "link2"),
    manipulability_scale=0.1,
    camera=("top", (0.4, 0.3, 2.6), 45.0),
    control_freq=200.0,
    episode_duration=5.0,
    joint_window=1.4,
)

#: the KUKA LBR iiwa 14: pose of ``tcp``, m = 6
IIWA14 = RedundantIKRobot(
    robot="iiwa14",
    site="tcp",
    pos_dim=3,
    task_dim=6,
    obstacle_geom="sphere",
    obstacle_links=("link3", "link4", "link5"),
    manipulability_scale=0.05,
    camera=None,
    control_freq=100.0,
    episode_duration=6.0,
    joint_window=0.6,
)
