"""The agent-side observation: the env's Dict flattened to one vector, plus task errors k_ref − k.

Rule (generic, so new environments work unchanged): for every key ``k`` of the Dict that has a
``k + "_ref"`` key of the same shape, append the error ``obs[k_ref] − obs[k]`` (for JointTracking:
q̃ = q̄ − q and q̃̇ = q̄̇ − q̇). The layout — the keys in order, then the errors — is an
:class:`ObservationLayout`, saved in each agent's ``config.yml`` so a loaded agent builds the same
vector from the env's raw observation (single or batched) without any wrapper.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

__all__ = ["ObservationLayout", "TaskObservation"]


@dataclass(frozen=True)
class ObservationLayout:
    """How a Dict observation becomes the agent's flat vector.

    Attributes:
        keys: Dict keys concatenated in this order.
        shapes: shape of each key's array (without the batch dimension).
        errors: keys ``k`` whose error ``k_ref − k`` is appended, in this order.
    """

    keys: tuple[str, ...]
    shapes: tuple[tuple[int, ...], ...]
    errors: tuple[str, ...] = ()

    @classmethod
    def from_space(cls, space: spaces.Space, task_errors: bool = True) -> ObservationLayout:
        """The layout of a Dict space (``task_errors``: add every ``k_ref − k``)."""
        if not isinstance(space, spaces.Dict):
            if isinstance(space, spaces.Box):
                return cls(keys=(), shapes=(tuple(space.shape),), errors=())
            raise TypeError(f"agents support Dict or Box observations, got {space}")
        keys = tuple(space.spaces)
        shapes = tuple(tuple(space[k].shape) for k in keys)
        errors = tuple(k for k in keys if f"{k}_ref" in space.spaces
                       and space[f"{k}_ref"].shape == space[k].shape) if task_errors else ()
        return cls(keys=keys, shapes=shapes, errors=errors)

    @property
    def size(self) -> int:
        sizes = {k: int(np.prod(s)) for k, s in zip(self.keys, self.shapes, strict=True)}
        if not self.keys:
            return int(np.prod(self.shapes[0]))
        return sum(sizes.values()) + sum(sizes[k] for k in self.errors)

    def space(self) -> spaces.Box:
        return spaces.Box(-np.inf, np.inf, (self.size,), dtype=np.float32)

    def is_batched(self, obs: Any) -> bool:
        first = obs[self.keys[0]] if self.keys else obs
        return np.ndim(first) == len(self.shapes[0]) + 1

    def flatten(self, obs: Any) -> np.ndarray:
        """(size,) for one observation, (n_envs, size) for a batch; float32."""
        if not self.keys:
            return np.asarray(obs, dtype=np.float32)
        missing = [k for k in self.keys if k not in obs]
        if missing:
            raise ValueError(f"observation lacks key(s) {missing}; expected {list(self.keys)}")
        batched = self.is_batched(obs)
        lead = (np.shape(obs[self.keys[0]])[0],) if batched else ()
        parts = [np.reshape(np.asarray(obs[k], dtype=np.float64), (*lead, -1))
                 for k in self.keys]
        parts += [np.reshape(np.asarray(obs[f"{k}_ref"], dtype=np.float64)
                             - np.asarray(obs[k], dtype=np.float64), (*lead, -1))
                  for k in self.errors]
        return np.concatenate(parts, axis=-1).astype(np.float32)

    def to_dict(self) -> dict[str, Any]:
        return {"keys": list(self.keys), "shapes": [list(s) for s in self.shapes],
                "errors": list(self.errors)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ObservationLayout:
        return cls(keys=tuple(d["keys"]), shapes=tuple(tuple(int(x) for x in s)
                                                       for s in d["shapes"]),
                   errors=tuple(d.get("errors", ())))

    def check_space(self, space: spaces.Space) -> None:
        """Raise ValueError if ``space`` is not the Dict this layout was made from."""
        if not self.keys:
            if tuple(space.shape or ()) != self.shapes[0]:
                raise ValueError(f"observation shape {space.shape} != trained {self.shapes[0]}")
            return
        if not isinstance(space, spaces.Dict):
            raise ValueError(f"expected a Dict observation space, got {space}")
        have = {k: tuple(s.shape) for k, s in space.spaces.items()}
        want = dict(zip(self.keys, self.shapes, strict=True))
        if have != want:
            raise ValueError(f"observation space {have} differs from the trained one {want}")


class TaskObservation(gym.ObservationWrapper):
    """Flatten a Dict observation by an :class:`ObservationLayout` (keys, then k_ref − k)."""

    def __init__(self, env: gym.Env, layout: ObservationLayout | None = None,
                 task_errors: bool = True) -> None:
        super().__init__(env)
        self.layout = layout or ObservationLayout.from_space(env.observation_space, task_errors)
        self.layout.check_space(env.observation_space)
        self.observation_space = self.layout.space()

    def observation(self, observation: Any) -> np.ndarray:
        return self.layout.flatten(observation)
