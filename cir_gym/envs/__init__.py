"""The environments: one module per task; ``ENVIRONMENTS`` maps each id to its class."""

from __future__ import annotations

import gymnasium as gym

from cir_gym.envs.base import EntryPoint, RobotEnv
from cir_gym.envs.elastic_joint_tracking import ElasticJointTrackingEnv
from cir_gym.envs.joint_tracking import JointTrackingEnv
from cir_gym.envs.redundant_ik import REDUNDANT_IK_ENVIRONMENTS, RedundantIK7Env, RedundantIKEnv
from cir_gym.envs.visual_servo import VISUAL_SERVO_ENVIRONMENTS

__all__ = [
    "ENVIRONMENTS",
    "ElasticJointTrackingEnv",
    "JointTrackingEnv",
    "RedundantIK7Env",
    "RedundantIKEnv",
    "RobotEnv",
    "register_envs",
]

#: id → (class, one-line description)
ENVIRONMENTS: dict[str, tuple[type[RobotEnv], str]] = {
    "cir_gym/JointTracking-v1": (
        JointTrackingEnv,
        "iiwa14 joint-space trajectory tracking with joint torques (ch. 4-5)",
    ),
    "cir_gym/ElasticJointTracking-v1": (
        ElasticJointTrackingEnv,
        "iiwa14 joint tracking through elastic transmissions (motor + spring + link, ch. 4)",
    ),
    **REDUNDANT_IK_ENVIRONMENTS,
    **VISUAL_SERVO_ENVIRONMENTS,
}


def register_envs() -> None:
    """Register every id in ``ENVIRONMENTS`` with Gymnasium (idempotent)."""
    for env_id, (cls, _) in ENVIRONMENTS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=EntryPoint(cls), disable_env_checker=False)
