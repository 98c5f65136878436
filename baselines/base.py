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
import numbers
import types
import typing
from typing import Any, ClassVar

import numpy as np

from cir_gym.envs.base import TaskContext

__all__ = ["Controller", "InvalidGain", "Observation", "check_gain_type"]

Observation = dict[str, np.ndarray]


class InvalidGain(ValueError):
    """An unknown gain name, a gain of the wrong type, or a gain outside its allowed range."""


def _is_real(value: Any) -> bool:
    """An int or float (numpy scalars included), not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _annotation_types(owner: type, field: dataclasses.Field) -> set[type]:
    """The plain types a field's annotation names (``float | None`` → {float, NoneType})."""
    try:
        hint = typing.get_type_hints(owner)[field.name]
    except (NameError, TypeError, AttributeError):  # unresolvable: fall back to the default
        return set()
    origin = typing.get_origin(hint)
    args = typing.get_args(hint) if origin in (typing.Union, types.UnionType) else (hint,)
    return {typing.get_origin(a) or a for a in args if isinstance(typing.get_origin(a) or a, type)}


def _field_default(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return dataclasses.MISSING


def _real_sequence(value: Any, shape: tuple[int, ...] | None) -> np.ndarray | None:
    """``value`` as a float array if it holds finite reals (in ``shape``), else None."""
    if isinstance(value, (str, bytes)):
        return None
    try:
        items = np.asarray(value, dtype=object)
    except ValueError:  # ragged nesting
        return None
    if items.ndim == 0:
        return None
    if shape is not None and items.shape != shape:
        return None
    if not all(_is_real(x) and np.isfinite(float(x)) for x in items.ravel()):
        return None
    return np.asarray(value, dtype=float)


def check_gain_type(owner: type, field: dataclasses.Field, value: Any, controller: str) -> Any:
    """``value`` checked against the field's default and annotation; returns it normalised.

    A float field takes a finite real number (int or float, not bool or str) and stores a
    float; a tuple/array field takes finite real numbers, as many as its default has; a str
    or bool field takes a str or bool; ``None`` only where the default or annotation allows it.
    Ranges (> 0, ...) are left to each ``Gains.__post_init__``.

    Raises:
        InvalidGain: naming the gain, the value and what is allowed.
    """
    default = _field_default(field)
    kinds = _annotation_types(owner, field)
    if default is not None and default is not dataclasses.MISSING:
        kinds.add(np.ndarray if isinstance(default, np.ndarray) else type(default))
    optional = default is None or type(None) in kinds
    kinds.discard(type(None))
    if float in kinds:
        kinds.discard(int)  # a float field takes ints already
    if not kinds:  # nothing to check against (e.g. an ``Any`` field without a default)
        return value
    if value is None and optional:
        return None
    allowed: list[str] = []
    for kind in sorted(kinds, key=lambda k: k.__name__):
        if issubclass(kind, (tuple, list, np.ndarray)):
            shape = np.shape(default) if isinstance(default, (tuple, list, np.ndarray)) else None
            count = "" if shape is None else " × ".join(map(str, shape)) + " "
            allowed.append(f"a sequence of {count}finite real numbers")
            array = _real_sequence(value, shape)
            if array is not None:
                return array if issubclass(kind, np.ndarray) else kind(array.tolist())
        elif issubclass(kind, numbers.Real) and kind is not bool:
            integral = issubclass(kind, numbers.Integral)
            allowed.append(
                "a finite integer" if integral else "a finite real number (int or float)"
            )
            if _is_real(value) and np.isfinite(float(value)):
                if not integral:
                    return float(value)
                if isinstance(value, numbers.Integral):
                    return int(value)
        else:
            allowed.append(f"a {kind.__name__}")
            if isinstance(value, kind) and (kind is bool or not isinstance(value, bool)):
                return value
    if optional:
        allowed.append("None")
    raise InvalidGain(
        f"gain {field.name!r} of controller {controller!r} must be "
        f"{' or '.join(dict.fromkeys(allowed))}, "
        f"got {value!r} ({type(value).__name__})"
    )


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
        """Build ``Gains`` from defaults and overrides.

        Raises:
            InvalidGain: an unknown gain name, a ``gains`` that is not a ``Gains``, an override
                of the wrong type (see :func:`check_gain_type`), or one ``Gains`` rejects.
        """
        fields = {f.name: f for f in dataclasses.fields(cls.Gains)}
        unknown = sorted(set(overrides) - set(fields))
        if unknown:
            raise InvalidGain(
                f"controller {cls.name!r} has no gain(s) {unknown}; allowed: {list(fields)}"
            )
        if gains is not None and not isinstance(gains, cls.Gains):
            raise InvalidGain(
                f"gains of controller {cls.name!r} must be a {cls.Gains.__name__}, "
                f"got {type(gains).__name__}"
            )
        checked = {
            key: check_gain_type(cls.Gains, fields[key], value, cls.name)
            for key, value in overrides.items()
        }
        base = gains if gains is not None else cls.Gains()
        return dataclasses.replace(base, **checked)

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
