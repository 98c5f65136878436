"""The environments: one module per task; ``ENVIRONMENTS`` maps each id to its class."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from cir_gym.envs.admittance_contact import AdmittanceContactEnv
from cir_gym.envs.agent_ready import AdmittanceContactImpedanceEnv, PegInHoleImpedanceEnv
from cir_gym.envs.base import EntryPoint, RobotEnv, default_max_episode_steps
from cir_gym.envs.cartesian_tracking import CartesianTrackingEnv
from cir_gym.envs.elastic_joint_tracking import ElasticJointTrackingEnv
from cir_gym.envs.joint_tracking import JointTrackingEnv
from cir_gym.envs.peg_in_hole import PegInHoleEnv
from cir_gym.envs.redundant_ik import REDUNDANT_IK_ENVIRONMENTS, RedundantIK7Env, RedundantIKEnv
from cir_gym.envs.visual_servo import VISUAL_SERVO_ENVIRONMENTS

__all__ = [
    "BATCHED_ENVIRONMENTS",
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
    "cir_gym/JointTracking-v2": (
        JointTrackingEnv,
        "iiwa14 joint-space trajectory tracking with joint torques (ch. 4-5)",
    ),
    "cir_gym/ElasticJointTracking-v3": (
        ElasticJointTrackingEnv,
        "iiwa14 joint tracking through elastic transmissions (motor + spring + link, ch. 4)",
    ),
    **REDUNDANT_IK_ENVIRONMENTS,
    **VISUAL_SERVO_ENVIRONMENTS,
    "cir_gym/AdmittanceContact-v2": (
        AdmittanceContactEnv,
        "iiwa14 pressing on a compliant surface while wiping: interaction control (ch. 6)",
    ),
    "cir_gym/PegInHole-v2": (
        PegInHoleEnv,
        "iiwa14 inserting a peg into a hole known only approximately: hybrid force/position control (ch. 6)",
    ),
    "cir_gym/CartesianTracking-v1": (
        CartesianTrackingEnv,
        "iiwa14 flange pose tracking with joint torques: operational-space control (ch. 5.2)",
    ),
    "cir_gym/PegInHoleImpedance-v0": (
        PegInHoleImpedanceEnv,
        "PegInHole for agents: 20-Hz pose-setpoint increments of a Cartesian impedance loop (ch. 6)",
    ),
    "cir_gym/AdmittanceContactImpedance-v1": (
        AdmittanceContactImpedanceEnv,
        "AdmittanceContact for agents: 20-Hz setpoint increments of a Cartesian impedance loop",
    ),
}


#: id → ``"module:Class"`` of its native batched env on ``mujoco.batch`` (a
#: :class:`cir_gym.envs.vector_base.BatchedTaskEnv`): ``cir_gym.envs.vector.VECTOR_ENVS`` imports a
#: class on first use, so registering the ids does not import ``mujoco.batch``
BATCHED_ENVIRONMENTS: dict[str, str] = {
    "cir_gym/JointTracking-v2": "cir_gym.envs.vector:JointTrackingVectorEnv",
    "cir_gym/ElasticJointTracking-v3": "cir_gym.envs.vector:ElasticJointTrackingVectorEnv",
    "cir_gym/CartesianTracking-v1": "cir_gym.envs.cartesian_vector:CartesianTrackingVectorEnv",
    "cir_gym/AdmittanceContact-v2": "cir_gym.envs.admittance_vector:AdmittanceContactVectorEnv",
    "cir_gym/PegInHole-v2": "cir_gym.envs.peg_in_hole_vector:PegInHoleVectorEnv",
    "cir_gym/RedundantIK-v4": "cir_gym.envs.redundant_ik_vector:RedundantIKVectorEnv",
    "cir_gym/RedundantIK7-v5": "cir_gym.envs.redundant_ik_vector:RedundantIK7VectorEnv",
    "cir_gym/AdmittanceContactImpedance-v1": (
        "cir_gym.envs.agent_ready_vector:AdmittanceContactImpedanceVectorEnv"
    ),
    "cir_gym/PegInHoleImpedance-v0": "cir_gym.envs.agent_ready_vector:PegInHoleImpedanceVectorEnv",
    "cir_gym/VisualServo-v1": "cir_gym.envs.visual_servo_vector:VisualServoVectorEnv",
    "cir_gym/VisualServoEyeToHand-v1": (
        "cir_gym.envs.visual_servo_eye_to_hand_vector:VisualServoEyeToHandVectorEnv"
    ),
}


class VectorEntryPoint:
    """``gymnasium.register``'s ``vector_entry_point`` of one id: imports ``cir_gym.envs.vector`` on
    first use and returns :func:`cir_gym.envs.vector.vector_entry_point`'s batched env."""

    def __init__(self, env_id: str) -> None:
        self.env_id = env_id

    def __call__(self, num_envs: int = 1, **kwargs: Any) -> gym.vector.VectorEnv:
        from cir_gym.envs.vector import vector_entry_point

        return vector_entry_point(self.env_id, num_envs, **kwargs)


def register_envs() -> None:
    """Register every id in ``ENVIRONMENTS`` with Gymnasium (idempotent).

    Each spec's ``max_episode_steps`` is the episode length of the class's default arguments,
    round(episode_duration · control_freq) (:func:`~cir_gym.envs.base.default_max_episode_steps`),
    the step at which the env truncates itself: ``gymnasium.make``'s TimeLimit ends the same
    step. Made with a longer episode, pass ``max_episode_steps`` (or -1) to ``gymnasium.make``
    (the entry point warns).

    The ids of ``BATCHED_ENVIRONMENTS`` also get a ``vector_entry_point``:
    ``gymnasium.make_vec(id, num_envs)`` (mode None or ``"vector_entry_point"``) builds the
    native batched env of :mod:`cir_gym.envs.vector`; ``vectorization_mode="sync"`` still gives
    Gymnasium's SyncVectorEnv.
    """
    for env_id, (cls, _) in ENVIRONMENTS.items():
        if env_id not in gym.registry:
            steps = default_max_episode_steps(cls)
            gym.register(
                id=env_id,
                entry_point=EntryPoint(cls, steps),
                disable_env_checker=False,
                max_episode_steps=steps,
                vector_entry_point=(
                    VectorEntryPoint(env_id) if env_id in BATCHED_ENVIRONMENTS else None
                ),
            )
