"""The policy protocol every controller implements: SB3's ``predict`` with state in ``state``.

A controller sees only the observation and a :class:`~cir_gym.envs.base.TaskContext` (the
nominal robot, control period, action scaling). Its internal state (integrators, adaptive
estimates, filters) is a float vector per environment that travels in ``state``, shape
(n_envs, state_size), and is re-initialised where ``episode_start`` is true — exactly how SB3
treats recurrent policies, so ``stable_baselines3.common.evaluation.evaluate_policy`` and
:func:`cir_gym.evaluation.evaluate` both accept a controller unchanged.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import numpy as np

from cir_gym.envs.base import TaskContext

__all__ = ["Controller", "InvalidGain", "Observation"]

Observation = dict[str, np.ndarray]


class InvalidGain(ValueError):
    """An unknown gain name, or a gain outside its allowed range."""


class Controller:
    """Base class: subclasses define ``Gains`` (a frozen dataclass), ``control`` and state.

    Class attributes:
        name: the name ``baselines.make`` knows the controller by.
        tasks: environment names (ids without namespace and version) it applies to.
        Gains: frozen dataclass of gains with units in its docstring.
    """

    name: ClassVar[str] = ""
    tasks: ClassVar[tuple[str, ...]] = ()
    Gains: ClassVar[type] = type(None)

    def __init__(self, context: TaskContext, gains: Any = None, **overrides: Any) -> None:
        self.context = context
        self.gains = self.make_gains(gains, **overrides)
        self.dt = context.dt
        self.action_scale = np.asarray(context.action_scale, dtype=float)

    @classmethod
    def make_gains(cls, gains: Any = None, **overrides: Any) -> Any:
        """Build ``Gains`` from defaults and overrides; unknown names raise :class:`InvalidGain`."""
        fields = [f.name for f in dataclasses.fields(cls.Gains)]
        unknown = sorted(set(overrides) - set(fields))
        if unknown:
            raise InvalidGain(
                f"controller {cls.name!r} has no gain(s) {unknown}; allowed: {fields}"
            )
        base = gains if gains is not None else cls.Gains()
        return dataclasses.replace(base, **overrides)

    # ------------------------------------------------------------------ to override
    @property
    def state_size(self) -> int:
        """Length of the per-environment state vector."""
        return 0

    def initial_state(self, obs: Observation) -> np.ndarray:
        """State at the start of an episode (state_size,)."""
        return np.zeros(self.state_size)

    def control(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """Physical command (e.g. joint torques (n,)) for one observation; updates ``state``."""
        raise NotImplementedError

    # ------------------------------------------------------------------ protocol
    def predict(
        self,
        observation: Observation,
        state: np.ndarray | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """SB3's protocol: (action in [-1, 1], new state); single or batched observations."""
        if "q" not in observation:
            raise ValueError(
                f"observation must be a dict with a 'q' entry, got keys {list(observation)}"
            )
        for key, value in observation.items():
            if not np.all(np.isfinite(value)):
                raise ValueError(f"observation[{key!r}] contains NaN or inf")
        batched = np.ndim(observation["q"]) == 2  # every cir_gym observation has q (n,)
        n_envs = int(np.shape(observation["q"])[0]) if batched else 1
        if state is None:
            state = np.zeros((n_envs, self.state_size))
            episode_start = np.ones(n_envs, dtype=bool)
        else:
            state = np.array(state, dtype=float, copy=True).reshape(n_envs, self.state_size)
        starts = (
            np.ones(n_envs, dtype=bool)
            if episode_start is None
            else np.broadcast_to(np.asarray(episode_start, dtype=bool), (n_envs,))
        )
        actions = np.zeros((n_envs, self.action_scale.size), dtype=np.float32)
        for i in range(n_envs):
            obs_i = (
                {k: np.asarray(v[i], dtype=float) for k, v in observation.items()}
                if batched
                else {k: np.asarray(v, dtype=float) for k, v in observation.items()}
            )
            if starts[i]:
                state[i] = self.initial_state(obs_i)
            command = self.control(obs_i, state[i])
            if not np.all(np.isfinite(command)):
                raise FloatingPointError(
                    f"controller {self.name!r} produced a non-finite command {command}"
                )
            actions[i] = np.clip(command / self.action_scale, -1.0, 1.0)
        return (actions if batched else actions[0]), state

    def __call__(self, observation: Observation) -> np.ndarray:
        """Stateless convenience for a single step from a fresh state."""
        return self.predict(observation)[0]
