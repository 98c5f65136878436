"""Shared MuJoCo-environment plumbing: model loading, stepping, divergence, validation, rendering.

A task module subclasses :class:`RobotEnv` and writes the task: spaces, reference, reward,
metrics. The base class owns what every task does the same way:

* ``_check_action``: a clear error for a wrong shape, dtype or a non-finite action, and
  clipping of finite values to ``[-1, 1]`` (documented in every env);
* ``_simulate``: ``frame_skip`` physics steps at a zero-order-hold control, with divergence
  detection (non-finite state, MuJoCo's bad-acceleration warning, absurd speeds) that
  restores the last finite state so observations stay finite;
* rendering with ``mujoco.Renderer`` (shadows, reflections, skybox and MSAA off: software
  GL on headless machines is ~100× faster that way), a lazy human viewer; both raise a
  RuntimeError saying what is missing (GL libraries, a display) instead of crashing. Both
  show the task: :meth:`RobotEnv.draw_task` adds visual-only markers (cir_gym.rendering) and
  ``rgb_array`` frames carry :meth:`RobotEnv.caption`; the robot files hold the checker floor
  and the free camera's framing. ``rgb_array_list`` draws frames at a fixed rate of simulated
  time (at most :data:`MAX_VIDEO_FPS`) for real-time videos;
* the order of calls: ``step`` or ``render`` before ``reset``, and ``step`` after the
  episode's end, raise :class:`ResetNeeded` (``RobotEnv.__init_subclass__`` wraps each
  task's ``step``, ``reset`` and ``render`` once).
"""

from __future__ import annotations

import functools
import inspect
import math
import os
import sys
import time
import warnings
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from cir_gym import rendering
from cir_gym.context import TaskContext
from cir_gym.metrics import MetricSpec
from cir_gym.numeric import CLIP
from cir_gym.robot import ModelError
from cir_gym.validation import InvalidArgument, check_number

__all__ = [
    "MAX_VIDEO_FPS",
    "EpisodeLongerThanSpec",
    "ResetNeeded",
    "RobotEnv",
    "check_kwargs",
    "make_env",
    "video_stride",
]

GL_HELP = (
    "MuJoCo could not create an OpenGL context for rendering. On a headless Debian/Ubuntu "
    "machine install Mesa (apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6) "
    "and set MUJOCO_GL=egl (or MUJOCO_GL=osmesa) before importing mujoco."
)
DISPLAY_HELP = (
    'render_mode="human" opens a window and needs a display, but neither DISPLAY nor '
    'WAYLAND_DISPLAY is set. On a headless machine use render_mode="rgb_array" (render() '
    "returns the frames; gymnasium.wrappers.RecordVideo writes them to a video)."
)
#: MUJOCO_GL values with which mujoco creates no GL context (cir_gym sets "disable" on a
#: headless machine without libEGL and libOSMesa, see cir_gym/__init__.py).
GL_DISABLED = ("disable", "disabled", "off", "false", "0")

MIN_CONTROL_FREQ = 1.0  # Hz: below, one step would hold ≥ 1 s of physics (1e-9 Hz hangs)

MAX_JOINT_SPEED = 1.0e3  # rad/s: beyond this the simulation is declared diverged

#: most frames per second of simulated time that ``rgb_array_list`` and ``human`` show
MAX_VIDEO_FPS = 60.0

_MAX_SPEED_SQ = MAX_JOINT_SPEED**2  # ‖q̇‖² bound of the pre-check in _simulate
_STATE = int(
    mujoco.mjtState.mjSTATE_QPOS | mujoco.mjtState.mjSTATE_QVEL | mujoco.mjtState.mjSTATE_ACT
)
_UNSTABLE_WARNINGS = sorted(
    int(w)
    for w in (
        mujoco.mjtWarning.mjWARN_BADQACC,
        mujoco.mjtWarning.mjWARN_BADQPOS,
        mujoco.mjtWarning.mjWARN_BADQVEL,
        mujoco.mjtWarning.mjWARN_BADCTRL,
    )
)
# MuJoCo's four are neighbours (a slice of the counters); if a future enum splits them, the
# slice widens and _simulate counts them one by one instead (RobotEnv._instability_warnings)
_UNSTABLE_FIRST, _UNSTABLE_LAST = _UNSTABLE_WARNINGS[0], _UNSTABLE_WARNINGS[-1]
_UNSTABLE_CONTIGUOUS = _UNSTABLE_LAST - _UNSTABLE_FIRST + 1 == len(_UNSTABLE_WARNINGS)


def _has_display() -> bool:
    """False on Linux/BSD without an X11 or Wayland display (macOS and Windows always have one)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _init_parameters(cls: type) -> list[inspect.Parameter]:
    """Keyword parameters of ``cls.__init__``, then the parent's while a ``**kwargs`` passes on."""
    found: list[inspect.Parameter] = []
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        params = inspect.signature(vars(klass)["__init__"]).parameters.values()
        found += [
            p
            for p in params
            if p.name != "self" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
        ]
        if not any(p.kind == p.VAR_KEYWORD for p in params):
            break
    return found


def constructor_arguments(cls: type) -> list[str]:
    """Keyword arguments of ``cls``; a ``**kwargs`` passed to the parent adds the parent's."""
    return list(dict.fromkeys(p.name for p in _init_parameters(cls)))


def check_kwargs(cls: type, kwargs: dict[str, Any]) -> None:
    """Raise :class:`InvalidArgument` naming the allowed keywords if ``kwargs`` has others."""
    allowed = constructor_arguments(cls)
    unknown = sorted(set(kwargs) - set(allowed))
    if unknown:
        raise InvalidArgument(
            f"{cls.__name__} got unknown argument(s) {unknown}; allowed: {sorted(allowed)}"
        )


def model_error_arguments(
    payload_mass: Any, mass_scale: Any, viscous_friction: Any, coulomb_friction: Any
) -> ModelError:
    """The four model-error arguments of the torque-driven envs, checked, as a ModelError."""
    return ModelError(
        payload_mass=check_number("payload_mass", payload_mass, 0.0, 50.0),
        mass_scale=check_number("mass_scale", mass_scale, 0.0, 10.0, low_open=True),
        viscous_friction=check_number("viscous_friction", viscous_friction, 0.0, 100.0),
        coulomb_friction=check_number("coulomb_friction", coulomb_friction, 0.0, 100.0),
    )


def frame_skip(control_freq: float, timestep: float) -> int:
    """Physics steps per control period, 1 / (control_freq · timestep), which must be an integer.

    A control period is a whole number of physics steps; a frequency that is not the physics
    rate divided by an integer is rejected rather than rounded (300 Hz on a 1-ms step would
    run at 333.3 Hz).

    Raises:
        InvalidArgument: naming ``control_freq`` and the nearest allowed frequencies.
    """
    ratio = 1.0 / (control_freq * timestep)
    skip = max(1, round(ratio))
    if abs(ratio - skip) > 1e-6 * ratio:
        rate = 1.0 / timestep
        near = sorted({rate / k for k in (max(1, int(ratio)), int(ratio) + 1)}, reverse=True)
        raise InvalidArgument(
            f"control_freq must be the physics rate {rate:g} Hz divided by an integer (a "
            f"control period is a whole number of {timestep * 1e3:g}-ms physics steps), got "
            f"{control_freq!r} Hz; nearest allowed: {', '.join(f'{f:.6g}' for f in near)} Hz"
        )
    return skip


def default_arguments(cls: type) -> dict[str, Any]:
    """Default values of ``cls``'s keyword arguments (a ``**kwargs`` passed on: the parent's)."""
    defaults: dict[str, Any] = {}
    for p in _init_parameters(cls):
        if p.default is not p.empty:
            defaults.setdefault(p.name, p.default)
    return defaults


def default_max_episode_steps(cls: type) -> int | None:
    """Steps of an episode with the default arguments, round(episode_duration · control_freq)
    (exact: :func:`frame_skip` makes the control period 1 / control_freq); None for a class
    without both defaults."""
    d = default_arguments(cls)
    duration, freq = d.get("episode_duration"), d.get("control_freq")
    if not isinstance(duration, (int, float)) or not isinstance(freq, (int, float)):
        return None
    return max(1, round(duration * freq))


class EpisodeLongerThanSpec(UserWarning):
    """An env made with a longer episode than its registered ``max_episode_steps``: the
    ``TimeLimit`` that ``gymnasium.make`` adds would cut it (:func:`make_env` adds none)."""


def make_env(env_id: str, **kwargs: Any) -> gym.Env:
    """``gymnasium.make(env_id, **kwargs)`` without the registered spec's ``TimeLimit``.

    Every cir_gym env truncates itself after its own ``episode_duration``; the spec's
    ``max_episode_steps`` is that of the default arguments, so an episode made longer through
    ``kwargs`` would be cut by the ``TimeLimit``. The evaluator, the CLI and the training code
    make their environments here.
    """
    kwargs.setdefault("max_episode_steps", -1)  # a caller's own limit still applies
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EpisodeLongerThanSpec)
        return gym.make(env_id, **kwargs)


class EntryPoint:
    """A picklable ``gymnasium.register`` entry point that rejects unknown keyword arguments.

    ``max_episode_steps`` is the registered spec's (the default episode's steps, applied by
    ``gymnasium.make`` as a ``TimeLimit``). An env whose own episode is longer (another
    ``episode_duration`` or ``control_freq``) would be cut short by that TimeLimit: a warning
    says so and names the ``max_episode_steps`` to pass to ``gymnasium.make`` (or -1: the env
    truncates itself). A shorter one truncates itself before the TimeLimit, at its own step.
    """

    def __init__(self, cls: type, max_episode_steps: int | None = None) -> None:
        self.cls = cls
        self.max_episode_steps = max_episode_steps

    def __call__(self, **kwargs: Any) -> gym.Env:
        check_kwargs(self.cls, kwargs)
        env = self.cls(**kwargs)
        limit = getattr(self, "max_episode_steps", None)  # unpickled from an older version
        steps = getattr(env, "max_steps", None)
        if limit is not None and steps is not None and steps > limit:
            warnings.warn(
                f"{self.cls.__name__}: this episode has {steps} steps but the registered "
                f"max_episode_steps is {limit}; unless gymnasium.make got max_episode_steps="
                f"{steps} (or -1), its TimeLimit ends the episode at step {limit}",
                EpisodeLongerThanSpec,
                stacklevel=2,
            )
        return env


class ResetNeeded(gym.error.ResetNeeded, RuntimeError):
    """``step`` before the first ``reset`` or after the episode ended, or ``render`` before
    the first ``reset``: the message says to call ``reset()``. Gymnasium's ``ResetNeeded``
    (what its ``OrderEnforcing`` wrapper raises), and a RuntimeError."""


def video_stride(dt: float) -> int:
    """Control steps per video frame for a control period ``dt`` (s): the fewest whose frame
    rate 1 / (stride · dt) is at most :data:`MAX_VIDEO_FPS`, a whole number of frames per
    second where a stride up to twice that allows it (500 Hz → 10: 50 fps; 1 kHz → 20;
    50 Hz → 1)."""
    first = max(1, math.ceil(1.0 / (dt * MAX_VIDEO_FPS) - 1e-9))
    for stride in range(first, 2 * first + 1):
        fps = 1.0 / (stride * dt)
        if abs(fps - round(fps)) <= 1e-9 * fps:
            return stride
    return first


def _guard_reset(reset: Any) -> Any:
    """``reset`` that marks the episode running (and shows its first frame, see render)."""

    @functools.wraps(reset)
    def guarded(self: RobotEnv, *args: Any, **kwargs: Any) -> Any:
        result = reset(self, *args, **kwargs)
        if type(self).reset is not guarded:  # a parent's reset: the subclass's guard marks
            return result
        self._needs_reset = False
        self._ever_reset = True
        self._steps = 0
        self._frames = []
        self._shown_frame = -1
        if self._video:
            self._video_frame()
        return result

    guarded.__cir_gym_guard__ = True  # type: ignore[attr-defined]
    return guarded


def _guard_step(step: Any) -> Any:
    """``step`` that raises :class:`ResetNeeded` before a reset or after the episode's end,
    and marks the end (see :meth:`RobotEnv.__init_subclass__`)."""

    @functools.wraps(step)
    def guarded(self: RobotEnv, action: Any) -> Any:
        if self._needs_reset:
            raise self._reset_needed("step")
        result = step(self, action)
        if type(self).step is not guarded:  # a parent's step: the subclass's guard counts
            return result
        self._steps += 1
        if result[2] or result[3]:  # terminated or truncated
            self._needs_reset = True
        if self._video and self._steps % self.render_stride == 0:
            self._video_frame()
        return result

    guarded.__cir_gym_guard__ = True  # type: ignore[attr-defined]
    return guarded


def _guard_render(render: Any) -> Any:
    """A subclass's ``render``: :class:`ResetNeeded` before a reset; in ``rgb_array_list``
    mode the frames collected since the last call (the subclass's render draws each one)."""

    @functools.wraps(render)
    def guarded(self: RobotEnv) -> Any:
        if self._in_render:  # drawing one frame (_draw): a parent's render, or a video frame
            return render(self)
        if not self._ever_reset:
            raise self._reset_needed("render")
        if self.render_mode == "rgb_array_list":
            return self._take_frames()
        if self.render_mode == "human":
            return self._show(render)
        return self._draw(render)

    guarded.__cir_gym_guard__ = True  # type: ignore[attr-defined]
    return guarded


def _guard_init(init: Any) -> Any:
    """``__init__`` after which a reset is needed, even if the constructor reset the env
    itself (e.g. to check an argument)."""

    @functools.wraps(init)
    def guarded(self: RobotEnv, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        if type(self).__init__ is guarded:
            self._needs_reset = True
            self._ever_reset = False
            self._frames = []

    guarded.__cir_gym_guard__ = True  # type: ignore[attr-defined]
    return guarded


_GUARDS = {
    "__init__": _guard_init,
    "reset": _guard_reset,
    "step": _guard_step,
    "render": _guard_render,
}


class RobotEnv(gym.Env[dict, np.ndarray]):
    """Base class of the cir_gym environments (see the module docstring).

    Order of calls: ``step`` before the first ``reset`` or after an episode ended
    (terminated or truncated), and ``render`` before the first ``reset``, raise
    :class:`ResetNeeded` saying to call ``reset()`` (checked here for every subclass, not only
    under ``gymnasium.make``'s ``OrderEnforcing``).

    Render modes:

    * ``"rgb_array"``: ``render()`` returns the frame of the current state, uint8
      (height, width, 3), on every call; ``metadata["render_fps"]`` is then the control rate
      1 / ``dt`` (one frame per step is real time).
    * ``"rgb_array_list"``: the env draws a frame at ``reset`` and every ``render_stride``
      steps (a fixed rate of simulated time, at most ``MAX_VIDEO_FPS``: 50 Hz at a 500-Hz
      control rate), and ``render()`` returns the frames drawn since its last call (a list,
      often empty); ``render_fps`` is that frame rate. ``gymnasium.wrappers.RecordVideo``
      on this mode writes a video that plays in real time (it warns once that a call
      between two frames returned none).
    * ``"human"``: a MuJoCo viewer, synced when ``render()`` is called at most once per
      frame (``render_fps`` of simulated time) and paced to the wall clock.

    Gymnasium's ``check_env`` opens the ``human`` mode: on a machine without a display pass
    ``check_env(env.unwrapped, skip_render_check=True)``.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["human", "rgb_array", "rgb_array_list"],
        "render_fps": 50,
    }
    # the order of calls (see _guard_step); class defaults until the first reset
    _needs_reset: bool = True
    _ever_reset: bool = False
    _in_render: bool = False  # inside _frame: drawing one frame
    _video: bool = False  # rgb_array_list: frames drawn at reset and every render_stride steps
    _steps: int = 0  # steps since the last reset
    _frames: list[np.ndarray] = []  # noqa: RUF012 (replaced per instance at reset)
    _shown_frame: int = -1  # human: index of the last frame shown (steps // render_stride)
    _wall_start: float = 0.0  # human: wall-clock time of simulated time 0 (time.perf_counter)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Wrap the subclass's own ``__init__``, ``reset``, ``step`` and ``render`` (see
        :data:`_GUARDS`): the order of calls is checked and the video frames drawn here, once
        for every env. Only the guard of ``type(self)``'s own method acts (a subclass's ``step`` may call its
        parent's). The cost per step is a few attribute reads (~0.6 µs)."""
        super().__init_subclass__(**kwargs)
        for name, guard in _GUARDS.items():
            method = vars(cls).get(name)
            if callable(method) and not getattr(method, "__cir_gym_guard__", False):
                setattr(cls, name, guard(method))
    metric_specs: ClassVar[tuple[MetricSpec, ...]] = ()
    primary_metric: ClassVar[str] = ""
    #: constructor arguments that shape only the reward: the dynamics, observations, episode
    #: end, metrics and success do not depend on them (tests/test_conformance.py checks it),
    #: so a controller's tuned gains (``cir_gym.cli.tuned_gains``) hold whatever their values
    reward_arguments: ClassVar[frozenset[str]] = frozenset()
    success_threshold: ClassVar[float] = 0.0

    def __init__(
        self,
        model: mujoco.MjModel,
        *,
        control_freq: float,
        episode_duration: float,
        render_mode: str | None,
        width: int,
        height: int,
        camera: str | int = -1,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise InvalidArgument(
                f"render_mode must be None or one of {self.metadata['render_modes']}, "
                f"got {render_mode!r}"
            )
        self.model = model
        self.data = mujoco.MjData(model)
        timestep = model.opt.timestep
        control_freq = check_number("control_freq", control_freq, MIN_CONTROL_FREQ, 1.0 / timestep)
        self.frame_skip = frame_skip(control_freq, timestep)
        self.dt = self.frame_skip * timestep  # s, control period: exactly 1 / control_freq
        episode_duration = check_number(
            "episode_duration", episode_duration, 0.0, 3600.0, low_open=True
        )
        self.max_steps = max(1, round(episode_duration / self.dt))
        self.render_mode = render_mode
        self.width = int(check_number("width", width, 16, 4096))
        self.height = int(check_number("height", height, 16, 4096))
        self.camera = camera
        #: control steps per frame of rgb_array_list and human (see the class docstring)
        self.render_stride = 1 if render_mode == "rgb_array" else video_stride(self.dt)
        fps = 1.0 / (self.render_stride * self.dt)
        self.metadata = {
            **self.metadata,
            "render_fps": round(fps) if abs(fps - round(fps)) <= 1e-9 * fps else fps,
        }
        self._video = render_mode == "rgb_array_list"
        self._renderer: mujoco.Renderer | None = None
        self._viewer: Any = None
        size = mujoco.mj_stateSize(model, _STATE)
        self._safe_state = np.zeros(size)  # the last finite (qpos, qvel, act), see _simulate
        self._scratch_state = np.zeros(size)
        mujoco.mj_getState(model, self.data, self._safe_state, _STATE)
        self._warn_data: mujoco.MjData | None = None  # self.data of the cached views below
        self._warn_view = np.zeros(0, np.int32)
        self._views: tuple[np.ndarray, ...] = ()  # (ctrl, qpos, qvel) of self._warn_data

    # ------------------------------------------------------------------ validation
    def _check_action(self, action: Any) -> tuple[np.ndarray, bool]:
        """Validate an action; return it as float64 clipped to [-1, 1] and whether it was clipped.

        The result is a new array (never the caller's); see :meth:`_check_action_peak`.

        Raises:
            ValueError: wrong shape, a non-numeric dtype, or NaN/inf entries.
        """
        a, clipped, _ = self._check_action_peak(action)
        return a, clipped

    def _check_action_peak(self, action: Any) -> tuple[np.ndarray, bool, float]:
        """:meth:`_check_action`, plus max |a_i| of the returned action (1.0 if clipped).

        The entries as Python floats (cheaper than numpy reductions on a few elements): their
        sum decides finiteness (NaN and inf propagate), the largest |a_i| the clipping; the
        errors come only after. A float array of the right shape (a policy's action) skips
        the conversions.

        Raises:
            ValueError: wrong shape, a non-numeric dtype, or NaN/inf entries.
        """
        shape = self.action_space.shape
        if type(action) is np.ndarray and action.shape == shape and action.dtype.kind == "f":
            a = action.astype(float)  # float64, a new array
        else:
            a = self._action_array(action, shape)
        values = a.tolist() if a.ndim == 1 else a.ravel().tolist()
        # the common case, finite and in range: a finite sum means no NaN/inf (an overflow
        # of finite values only takes the exact path below)
        if values and math.isfinite(sum(values)):
            peak = max(map(abs, values))
            if peak <= 1.0:
                return a, False, peak
        elif not values:
            return a, False, 0.0
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action contains NaN or inf: {a}; expected finite values in [-1, 1]")
        return CLIP(a, -1.0, 1.0, out=a), True, 1.0

    @staticmethod
    def _action_array(action: Any, shape: tuple[int, ...]) -> np.ndarray:
        """``action`` as a new float64 array of ``shape`` (a flat sequence of its size is
        reshaped).

        Raises:
            ValueError: ragged or non-numeric input, or another shape.
        """
        try:
            raw = np.asarray(action)
        except (TypeError, ValueError) as exc:  # ragged nested sequences
            raise ValueError(
                f"action must be a numeric array of shape {shape}, got {action!r}"
            ) from exc
        if raw.dtype.kind not in "biuf":
            raise ValueError(
                f"action must be a numeric array of shape {shape} with values in [-1, 1], "
                f"got {action!r} (dtype {raw.dtype})"
            )
        a = raw.astype(float)  # float64, a new array
        if a.shape != shape:
            if a.size == int(np.prod(shape)) and a.ndim <= 1:
                a = a.reshape(shape)
            else:
                raise ValueError(
                    f"action has shape {a.shape}; this environment expects shape {shape} "
                    f"(values in [-1, 1])"
                )
        return a

    # ------------------------------------------------------------------ physics
    def _simulate(self, ctrl: np.ndarray, qfrc: np.ndarray | None = None) -> bool:
        """Hold ``ctrl`` for ``frame_skip`` steps; return True (and restore) if it diverged.

        Cost beyond the one ``mj_step(m, d, frame_skip)`` call: one ``mj_getState`` and one
        dot product for the finite check of the state before (kept to restore it on
        divergence), a bytes compare of MuJoCo's instability-warning counters and one dot
        product after: ‖q̇‖² ≤ MAX_JOINT_SPEED² implies every |q̇_i| ≤ MAX_JOINT_SPEED and a
        finite q̇ (NaN fails every comparison; an overflow only sends the step to the exact
        element-wise checks, which run only when it flags something). q needs no test of
        its own: every ``mj_step`` starts with ``mj_checkPos``, which resets a q with a NaN
        or beyond 1e10 and counts a BADQPOS warning (a diverged step), and then adds h q̇
        with that finite, bounded q̇ (the Euler and implicit integrators every cir_gym model
        uses; RK4 would integrate intermediate velocities), so a step that ends without a
        new warning and with ‖q̇‖ ≤ MAX_JOINT_SPEED ends with a finite q. The views of
        ``ctrl``, ``qpos``, ``qvel`` and the counters are built once per MjData.
        """
        m, d = self.model, self.data
        if self._warn_data is not d:  # views of MuJoCo's arrays, rebuilt if data changed
            self._refresh_views(d)
        d_ctrl, _, d_qvel = self._views
        warn = self._warn_view
        scratch = self._scratch_state
        mujoco.mj_getState(m, d, scratch, _STATE)
        if math.isfinite(scratch.dot(scratch)):  # all finite (an overflow only skips this save)
            self._scratch_state, self._safe_state = self._safe_state, scratch
        d_ctrl[:] = ctrl
        if qfrc is not None:
            d.qfrc_applied[:] = qfrc
        warnings_before = warn.tobytes() if _UNSTABLE_CONTIGUOUS else self._instability_warnings()
        mujoco.mj_step(m, d, self.frame_skip)
        # MuJoCo resets a bad state or zeroes a huge control and counts a warning (the
        # counters only grow, so changed bytes mean a new warning)
        diverged = (
            warn.tobytes() != warnings_before
            if _UNSTABLE_CONTIGUOUS
            else self._instability_warnings() > warnings_before
        )
        if not diverged and not d_qvel.dot(d_qvel) <= _MAX_SPEED_SQ:
            # NaN fails every comparison: exact checks only here
            with np.errstate(all="ignore"):
                diverged = bool(
                    not np.all(np.isfinite(d.qpos))
                    or not np.all(np.isfinite(d.qvel))
                    or np.max(np.abs(d.qvel), initial=0.0) > MAX_JOINT_SPEED
                )
        if diverged:
            mujoco.mj_resetData(m, d)
            mujoco.mj_setState(m, d, self._safe_state, _STATE)
            mujoco.mj_forward(m, d)
        return diverged

    def _data_views(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ctrl, qpos, qvel) of ``self.data``: views built once per MjData (a pybind
        property builds a new array on every access)."""
        if self._warn_data is not self.data:
            self._refresh_views(self.data)
        return self._views

    def _refresh_views(self, d: mujoco.MjData) -> None:
        """Build the cached views of ``d`` (a subclass may add its own, after this)."""
        self._warn_view = d.warning.number[_UNSTABLE_FIRST : _UNSTABLE_LAST + 1]
        self._views = (d.ctrl, d.qpos, d.qvel)
        self._warn_data = d

    _UNSTABLE = (
        mujoco.mjtWarning.mjWARN_BADQACC,
        mujoco.mjtWarning.mjWARN_BADQPOS,
        mujoco.mjtWarning.mjWARN_BADQVEL,
        mujoco.mjtWarning.mjWARN_BADCTRL,
    )

    def _instability_warnings(self) -> int:
        return sum(self.data.warning[w].number for w in self._UNSTABLE)

    def _reset_physics(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        mujoco.mj_forward(self.model, self.data)
        mujoco.mj_getState(self.model, self.data, self._safe_state, _STATE)

    # ------------------------------------------------------------------ rendering
    #: render() draws the task's markers (:meth:`draw_task`) and the :meth:`caption`; set False
    #: on an instance for the bare robot (e.g. an image observation, a benchmark)
    draw_markers: bool = True

    def draw_task(self, scene: mujoco.MjvScene) -> None:
        """Append the task's visual-only markers to ``scene`` (default: none).

        Called by :meth:`render` after ``update_scene``; use the ``add_*`` functions of
        :mod:`cir_gym.rendering` (the reference, the target frame, obstacles, force arrows).
        Never touch the physics here: ``self.data`` is read only.
        """

    def caption(self) -> str:
        """One line drawn on ``rgb_array`` frames: the time and the task's primary error."""
        return f"t = {self.data.time:5.2f} s"

    def render(self) -> np.ndarray | list[np.ndarray] | None:
        """The frame of the current state (``rgb_array``), the frames drawn since the last call
        (``rgb_array_list``), or None after syncing the viewer (``human``); see the class
        docstring. A subclass that overrides it draws one frame: it calls ``super().render()``
        and returns the frame it made of it (the modes are handled around it)."""
        if self.render_mode in ("rgb_array", "rgb_array_list"):
            if self._renderer is None:
                self._renderer = self._make_renderer()
            self._renderer.update_scene(self.data, camera=self.camera)
            if not self.draw_markers:
                return self._renderer.render()
            scene = self._renderer.scene
            rendering.begin_frame(scene)  # add_polyline: 2-D overlays, drawn after the 3-D scene
            try:
                self.draw_task(scene)
                frame = self._renderer.render()
            except BaseException:
                rendering.finish_frame(np.zeros((1, 1, 3), np.uint8), scene)  # drop the overlays
                raise
            return rendering.finish_frame(frame, scene, self.caption())
        if self.render_mode == "human":
            if self._viewer is None:
                if not _has_display():  # else mujoco.viewer exits the whole process
                    raise RuntimeError(DISPLAY_HELP)
                import mujoco.viewer

                self._viewer = mujoco.viewer.launch_passive(self.model, self.data)
            if self.draw_markers:
                with self._viewer.lock():
                    self._viewer.user_scn.ngeom = 0
                    self.draw_task(self._viewer.user_scn)
            self._viewer.sync()
        return None

    def _reset_needed(self, call: str) -> ResetNeeded:
        name = type(self).__name__
        if not self._ever_reset:
            return ResetNeeded(f"{name}.{call}() called before reset(); call reset() first")
        return ResetNeeded(
            f"{name}.{call}() called after the episode ended (terminated or truncated); call "
            "reset() to start a new episode"
        )

    def _draw(self, render: Any) -> Any:
        """``render(self)`` as one frame: the modes' handling of the render guard skipped."""
        self._in_render = True
        try:
            return render(self)
        finally:
            self._in_render = False

    def _video_frame(self) -> None:
        """rgb_array_list: draw the frame of the current state into the list render returns."""
        self._frames.append(self._draw(type(self).render))

    def _take_frames(self) -> list[np.ndarray]:
        frames, self._frames = self._frames, []
        return frames

    def _show(self, render: Any) -> None:
        """human: sync the viewer if a frame instant (every ``render_stride`` steps) passed
        since the last one shown, then wait until the wall clock reaches the simulated time."""
        index = self._steps // self.render_stride
        if index == self._shown_frame:
            return None
        self._draw(render)
        now, sim_time = time.perf_counter(), self._steps * self.dt
        if self._shown_frame < 0:
            self._wall_start = now - sim_time
        else:  # behind the wall clock (a slow step): no catching up, the pace restarts here
            self._wall_start = max(self._wall_start, now - sim_time)
            time.sleep(max(0.0, self._wall_start + sim_time - now))
        self._shown_frame = index
        return None

    def _make_renderer(self) -> mujoco.Renderer:
        backend = os.environ.get("MUJOCO_GL", "").strip().lower()
        if backend in GL_DISABLED:
            raise RuntimeError(
                f"{GL_HELP} (rendering is disabled: MUJOCO_GL={backend!r}; cir_gym sets it on "
                f"a machine without a display when it finds neither libEGL nor libOSMesa)"
            )
        self.model.vis.global_.offwidth = max(self.model.vis.global_.offwidth, self.width)
        self.model.vis.global_.offheight = max(self.model.vis.global_.offheight, self.height)
        self.model.vis.quality.offsamples = 0
        try:
            renderer = mujoco.Renderer(self.model, self.height, self.width)
        except Exception as exc:  # any GL failure: name the packages that fix it
            raise RuntimeError(f"{GL_HELP} ({type(exc).__name__}: {exc})") from exc
        for flag in (
            mujoco.mjtRndFlag.mjRND_SHADOW,
            mujoco.mjtRndFlag.mjRND_REFLECTION,
            mujoco.mjtRndFlag.mjRND_SKYBOX,
        ):
            renderer.scene.flags[flag] = False
        rendering.sharp_floor(renderer)  # nearest-texel checker floor: ~0.6 ms less in llvmpipe
        return renderer

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_renderer"] = None
        state["_viewer"] = None
        # views into MuJoCo's arrays would come back as copies, detached from the new MjData
        state["_warn_data"] = None
        state["_warn_view"] = np.zeros(0, np.int32)
        state["_views"] = ()
        return state

    # ------------------------------------------------------------------ controllers
    def controller_context(self) -> TaskContext:
        """What a controller may know of this task (see :class:`TaskContext`)."""
        raise NotImplementedError


RobotEnv.render = _guard_render(RobotEnv.render)  # type: ignore[method-assign]
