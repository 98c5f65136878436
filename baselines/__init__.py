"""The course's controllers as policies with SB3's ``predict`` protocol.

>>> from cir_gym import baselines
>>> baselines.available("cir_gym/JointTracking-v2")   # doctest: +SKIP
>>> policy = baselines.make("computed_torque", "cir_gym/JointTracking-v2", omega_n=25.0)
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
from cir_gym.baselines.base import Controller, InvalidGain
from cir_gym.baselines.centralized import AdaptiveControl, ComputedTorque, PDGravity, RobustControl
from cir_gym.baselines.decentralized import (
    DecentralizedFeedforward,
    IndependentPID,
    PCascade,
    PPIFeedforward,
)
from cir_gym.baselines.hybrid import HYBRID_CONTROLLERS, TASK_ADAPTERS
from cir_gym.baselines.interaction import INTERACTION_CONTROLLERS
from cir_gym.baselines.kinematic import KINEMATIC_CONTROLLERS
from cir_gym.baselines.operational_space import OPERATIONAL_SPACE_CONTROLLERS
from cir_gym.baselines.setpoint import SETPOINT_CONTROLLERS
from cir_gym.baselines.visual_servo import VISUAL_SERVO_CONTROLLERS

import cir_gym  # noqa: F401  (registers the environments)

__all__ = [
    "CONTROLLERS",
    "Controller",
    "InvalidGain",
    "available",
    "controller_class",
    "make",
    "task_name",
]

CONTROLLERS: dict[str, type[Controller]] = {
    cls.name: cls
    for cls in (
        IndependentPID,
        PCascade,
        PPIFeedforward,
        DecentralizedFeedforward,
        PDGravity,
        ComputedTorque,
        RobustControl,
        AdaptiveControl,
        *KINEMATIC_CONTROLLERS,
        *OPERATIONAL_SPACE_CONTROLLERS,
        *INTERACTION_CONTROLLERS,
        *VISUAL_SERVO_CONTROLLERS,
        *HYBRID_CONTROLLERS,
        *SETPOINT_CONTROLLERS,
    )
}


def task_name(env_id: str) -> str:
    """'cir_gym:cir_gym/JointTracking-v2' → 'JointTracking'."""
    return env_id.split(":")[-1].split("/")[-1].rsplit("-v", 1)[0]


def available(env_id: str) -> list[str]:
    """Names of the controllers that apply to an environment id (task adapters included)."""
    task = task_name(env_id)
    names = [name for name, cls in CONTROLLERS.items() if task in cls.tasks]
    return names + [n for n, t in TASK_ADAPTERS if t == task and n not in names]


def controller_class(name: str, env_id: str) -> type[Controller]:
    """The class that implements controller ``name`` on ``env_id``.

    Usually ``CONTROLLERS[name]``; a law written for one task and carried to another through
    an observation adapter (``baselines.hybrid.TASK_ADAPTERS``: AdmittanceContact's
    ``admittance`` on PegInHole) has its own class there, with its own ``Gains``.
    """
    return TASK_ADAPTERS.get((name, task_name(env_id)), CONTROLLERS[name])


def make(
    name: str,
    env_id: str,
    *,
    env: gym.Env | None = None,
    env_kwargs: dict[str, Any] | None = None,
    **gains: Any,
) -> Controller:
    """Build controller ``name`` for ``env_id``.

    Args:
        name: a controller name (see :func:`available`).
        env_id: the environment id; its ``controller_context()`` gives the nominal model.
        env: an existing environment of that id (avoids building one).
        env_kwargs: arguments of the environment to build; only without ``env`` (with both
            the arguments could not apply: ValueError).
        **gains: gain overrides (the controller's ``Gains`` fields) and ``robot=`` (a nominal
            :class:`~cir_gym.robot.Robot`, e.g. an identified model).

    Raises:
        ValueError: unknown controller, a controller that does not apply, both ``env`` and
            ``env_kwargs``.
        InvalidGain: (a ValueError) an unknown gain, a gain of the wrong type (a float gain
            takes an int or float, not a bool, str or list) or out of its range.
    """
    if name not in CONTROLLERS:
        raise ValueError(f"unknown controller {name!r}; available: {sorted(CONTROLLERS)}")
    if env_id.split(":")[-1] not in gym.registry:
        raise ValueError(
            f"unknown environment {env_id!r}; registered: "
            f"{sorted(k for k in gym.registry if k.startswith('cir_gym/'))}"
        )
    if name not in available(env_id):
        raise ValueError(
            f"controller {name!r} does not apply to {env_id}; available there: {available(env_id)}"
        )
    if env is not None and env_kwargs:
        raise ValueError(
            f"make() got env= and env_kwargs={env_kwargs!r}: the controller reads the given "
            f"env's context, so env_kwargs would be ignored; pass one of the two"
        )
    if env is None:
        env = gym.make(env_id, **(env_kwargs or {}))
        context = env.unwrapped.controller_context()
        env.close()
    else:
        context = env.unwrapped.controller_context()
    return controller_class(name, env_id)(context, **gains)
