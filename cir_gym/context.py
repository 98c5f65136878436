"""What a controller may know about a task: the one door through which nominal facts reach it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cir_gym.robot import Robot


@dataclass(frozen=True)
class TaskContext:
    """What a controller may know about a task: never the simulator, only nominal facts.

    Attributes:
        robot: shipped robot name or MJCF path of the *nominal* model.
        dt: control period (s).
        action_kind: "joint_torque", "joint_velocity", … (what ``action * action_scale`` is).
        action_scale: (n,) physical units per unit of action.
        armature: (n,) reflected rotor inertia the task's motors give (kg m²), or None for the
            robot file's values.
        gear_ratio, rotor_inertia: (n,) motor side of the joints (chapter 4).
        site: the task's end-effector site, if any.
        extras: task-specific facts (objective, obstacle handling, ...).
    """

    robot: str
    dt: float
    action_kind: str
    action_scale: np.ndarray
    armature: np.ndarray | None = None
    gear_ratio: np.ndarray | None = None
    rotor_inertia: np.ndarray | None = None
    site: str | None = None
    extras: dict[str, Any] = field(default_factory=dict)

    def nominal_robot(self) -> Robot:
        """A fresh nominal :class:`Robot` (the file's parameters, the task's motors)."""
        robot = Robot.from_name(self.robot)
        if self.armature is not None:
            robot.set_armature(self.armature)
        return robot
