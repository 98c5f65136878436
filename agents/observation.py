"""The agent-side observation: the env's Dict flattened to one vector, plus task errors k_ref − k.

Rule (generic, so new environments work unchanged): for every key ``k`` of the Dict that has a
``k + "_ref"`` key of the same shape, append the error ``obs[k_ref] − obs[k]`` (for JointTracking:
q̃ = q̄ − q and q̃̇ = q̄̇ − q̇). The layout — the keys in order, then the errors — is an
:class:`ObservationLayout`, saved in each agent's ``config.yml`` so a loaded agent builds the same
vector from the env's raw observation (single or batched) without any wrapper.

Optional *features* computed from the observation with the task's nominal model (what a
controller may know, :meth:`RobotEnv.controller_context`), appended after the errors:

* ``gravity``: ĝ(q) ⊘ τ_max, the nominal gravity torque in action units (joint-torque tasks).
  With it, PD + gravity, a = ĝ(q)/τ_max + K_P q̃ + K_D q̃̇, is a *linear* function of the
  agent's observation.

* ``pinv_feedforward``: J†(q) x̄̇ ⊘ q̇_max, the open-loop differential-IK command in action
  units (joint-velocity tasks: RedundantIK), J the nominal task Jacobian;
* ``pinv_error``: J†(q) e ⊘ q̇_max, e = [x̄ − x; θr] the task error (m, rad).
  With both, CLIK's a = J†(x̄̇ + K e) ⊘ q̇_max is the *linear* function f_ff + K f_err of the
  agent's observation: the features build in the nominal kinematics (J and its pseudo-inverse),
  as ``gravity`` builds in the nominal gravity model; what is left to learn is the gain and the
  secondary task in the null space (docs/research/agents.md measures what they change).

They are bound to an environment with :meth:`ObservationLayout.bind` (a loaded agent binds to
the env it is built for); a layout without features needs no binding.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

__all__ = ["FEATURES", "ObservationLayout", "TaskObservation", "gravity_feature",
           "pseudo_inverse_features"]

#: optional observation features → what they are (see the module docstring)
FEATURES = {
    "gravity": "nominal gravity torque / tau_max (joint-torque tasks; needs an observation 'q')",
    "pinv_feedforward": "J^+(q) xd_ref / qd_max, open-loop differential IK (joint-velocity tasks)",
    "pinv_error": "J^+(q) e / qd_max, e the task error [x_ref - x; theta r] (joint-velocity tasks)",
}

Feature = Callable[[Any], np.ndarray]


def _feature_context(env: gym.Env, action_kind: str, who: str) -> Any:
    """``env``'s TaskContext, or ValueError unless it is a cir_gym env with ``action_kind``."""
    base = env.unwrapped
    if not hasattr(base, "controller_context"):
        raise ValueError(f"the {who} feature needs a cir_gym RobotEnv (controller_context)")
    ctx = base.controller_context()
    if ctx.action_kind != action_kind:
        raise ValueError(f"the {who} feature needs {action_kind.replace('_', '-')} actions, "
                         f"not {ctx.action_kind!r}")
    return ctx


def gravity_feature(env: gym.Env) -> Feature:
    """obs ↦ ĝ(q) ⊘ τ_max from ``env``'s nominal model (single or batched observation)."""
    ctx = _feature_context(env, "joint_torque", "'gravity'")
    robot = ctx.nominal_robot()
    scale = np.asarray(ctx.action_scale, dtype=np.float64)

    def gravity(obs: Any) -> np.ndarray:
        q = np.asarray(obs["q"], dtype=np.float64)
        if q.ndim == 1:
            return robot.gravity(q) / scale
        return np.stack([robot.gravity(row) for row in q]) / scale

    return gravity


def pseudo_inverse_features(env: gym.Env) -> tuple[Feature, Feature]:
    """(obs ↦ J†x̄̇ ⊘ q̇_max, obs ↦ J†e ⊘ q̇_max) with ``env``'s nominal kinematics, through
    the course's own CLIK plumbing (:class:`baselines.kinematic.CLIK`: the task Jacobian, e and
    x̄̇ exactly as the controller forms them), single or batched observations. At a singular
    configuration (σ_min < 1e-9, where J† does not exist) the damped J* with k = 1e-3 is used.
    """
    from cir_gym.baselines.kinematic import (
        CLIK,
        SingularJacobian,
        damped_pseudo_inverse,
        pseudo_inverse,
    )

    ctx = _feature_context(env, "joint_velocity", "pinv_*")
    clik = CLIK(ctx)
    scale = np.asarray(ctx.action_scale, dtype=np.float64)

    last: list[Any] = [None, None]  # (q bytes, J†): both features of one observation share it

    def pinv(q: np.ndarray) -> np.ndarray:
        key = q.tobytes()
        if key != last[0]:
            J = clik.task_jacobian(q)
            try:
                last[1] = pseudo_inverse(J)
            except SingularJacobian:
                last[1] = damped_pseudo_inverse(J, 1e-3)
            last[0] = key
        return last[1]

    def rows(obs: Any) -> list[dict[str, np.ndarray]]:
        q = np.asarray(obs["q"], dtype=np.float64)
        if q.ndim == 1:
            return [obs]
        return [{k: np.asarray(v)[i] for k, v in obs.items()} for i in range(q.shape[0])]

    def make(term: Callable[[dict], np.ndarray]) -> Feature:
        def feature(obs: Any) -> np.ndarray:
            out = np.stack([pinv(np.asarray(o["q"], dtype=np.float64)) @ term(o)
                            for o in rows(obs)]) / scale
            return out[0] if np.ndim(obs["q"]) == 1 else out
        return feature

    return make(clik.reference_velocity), make(clik.task_error)


def _pinv_features(env: gym.Env) -> dict[str, Feature]:
    return dict(zip(("pinv_feedforward", "pinv_error"), pseudo_inverse_features(env),
                    strict=True))


#: feature name → ``env ↦ {name: feature}`` (a factory may make several features that share
#: work: both pinv_* features come from one call, so they share one J† per observation)
FEATURE_FACTORIES: dict[str, Callable[[gym.Env], dict[str, Feature]]] = {
    "gravity": lambda env: {"gravity": gravity_feature(env)},
    "pinv_feedforward": _pinv_features,
    "pinv_error": _pinv_features,
}


@dataclass(frozen=True)
class ObservationLayout:
    """How a Dict observation becomes the agent's flat vector.

    Attributes:
        keys: Dict keys concatenated in this order.
        shapes: shape of each key's array (without the batch dimension).
        errors: keys ``k`` whose error ``k_ref − k`` is appended, in this order.
        features: names from :data:`FEATURES` appended last (each of the size of ``q``).
    """

    keys: tuple[str, ...]
    shapes: tuple[tuple[int, ...], ...]
    errors: tuple[str, ...] = ()
    features: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        unknown = [f for f in self.features if f not in FEATURES]
        if unknown:
            raise ValueError(f"unknown observation feature(s) {unknown}; allowed: "
                             f"{sorted(FEATURES)}")
        if self.features and "q" not in self.keys:
            raise ValueError(f"features {list(self.features)} need an observation key 'q'")

    @classmethod
    def from_space(cls, space: spaces.Space, task_errors: bool = True,
                   features: tuple[str, ...] | list[str] = ()) -> ObservationLayout:
        """The layout of a Dict space (``task_errors``: add every ``k_ref − k``; ``features``:
        names from :data:`FEATURES`)."""
        if not isinstance(space, spaces.Dict):
            if isinstance(space, spaces.Box):
                if features:
                    raise ValueError("observation features need a Dict observation with 'q'")
                return cls(keys=(), shapes=(tuple(space.shape),), errors=())
            raise TypeError(f"agents support Dict or Box observations, got {space}")
        keys = tuple(space.spaces)
        shapes = tuple(tuple(space[k].shape) for k in keys)
        errors = tuple(k for k in keys if f"{k}_ref" in space.spaces
                       and space[f"{k}_ref"].shape == space[k].shape) if task_errors else ()
        return cls(keys=keys, shapes=shapes, errors=errors, features=tuple(features))

    @property
    def size(self) -> int:
        sizes = {k: int(np.prod(s)) for k, s in zip(self.keys, self.shapes, strict=True)}
        if not self.keys:
            return int(np.prod(self.shapes[0]))
        return (sum(sizes.values()) + sum(sizes[k] for k in self.errors)
                + len(self.features) * sizes.get("q", 0))

    def bind(self, env: gym.Env) -> Callable[[Any], np.ndarray]:
        """``obs ↦ flat vector`` with this layout's features computed from ``env``'s nominal
        model (for a layout without features, just :meth:`flatten`)."""
        if not self.features:
            return self.flatten
        made: dict[str, Feature] = {}
        for f in self.features:
            if f not in made:
                made.update(FEATURE_FACTORIES[f](env))
        fns = [made[f] for f in self.features]
        return lambda obs: self.flatten(obs, fns)

    def space(self) -> spaces.Box:
        return spaces.Box(-np.inf, np.inf, (self.size,), dtype=np.float32)

    def is_batched(self, obs: Any) -> bool:
        first = obs[self.keys[0]] if self.keys else obs
        return np.ndim(first) == len(self.shapes[0]) + 1

    def flatten(self, obs: Any, features: list[Feature] | None = None) -> np.ndarray:
        """(size,) for one observation, (n_envs, size) for a batch; float32. ``features``: the
        bound feature functions (:meth:`bind`), needed when the layout has features."""
        if self.features and (features is None or len(features) != len(self.features)):
            raise ValueError(f"this layout appends features {list(self.features)}: use "
                             f"layout.bind(env)(obs)")
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
        parts += [np.reshape(f(obs), (*lead, -1)) for f in features or ()]
        return np.concatenate(parts, axis=-1).astype(np.float32)

    def to_dict(self) -> dict[str, Any]:
        d = {"keys": list(self.keys), "shapes": [list(s) for s in self.shapes],
             "errors": list(self.errors)}
        if self.features:  # absent in the configs of agents trained without features
            d["features"] = list(self.features)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ObservationLayout:
        return cls(keys=tuple(d["keys"]), shapes=tuple(tuple(int(x) for x in s)
                                                       for s in d["shapes"]),
                   errors=tuple(d.get("errors", ())), features=tuple(d.get("features", ())))

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
    """Flatten a Dict observation by an :class:`ObservationLayout` (keys, k_ref − k, features).

    Without ``layout`` the layout is made from the env's space with ``task_errors`` and
    ``features``: that is how rl-zoo3 uses it (``env_wrapper:`` in agents/hyperparams/*.yml).
    """

    def __init__(self, env: gym.Env, layout: ObservationLayout | None = None,
                 task_errors: bool = True, features: tuple[str, ...] | list[str] = ()) -> None:
        super().__init__(env)
        self.layout = layout or ObservationLayout.from_space(env.observation_space, task_errors,
                                                             features)
        self.layout.check_space(env.observation_space)
        self.observation_space = self.layout.space()
        self._flatten = self.layout.bind(env)

    def observation(self, observation: Any) -> np.ndarray:
        return self._flatten(observation)
