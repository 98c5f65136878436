"""The plumbing every native batched env shares: ``num_envs`` copies of one single env whose
physics runs on one ``mujoco.batch.Batch``, with Gymnasium's ``SAME_STEP`` autoreset.

A batched env batches a single env (``env_class``, a :class:`~cir_gym.envs.base.RobotEnv`):
the single env's ``step`` is the specification, and each copy must equal it step for step
(observations, rewards, ends, final metrics) to a tolerance its tests state. This module holds
what does not depend on the task; a subclass writes the task's step in array form.

What :class:`BatchedTaskEnv` does
---------------------------------
* **Arguments.** ``BatchedTaskEnv(num_envs, nthread, **kwargs)``: ``num_envs`` ≥ 1,
  ``nthread`` ≥ 0 (MuJoCo threads, 0: all CPUs), ``kwargs`` the single env's arguments.
  :meth:`unsupported` names the first argument the subclass does not batch (see
  ``fixed_arguments`` below; ``render_mode`` is never batched); the constructor raises
  ``InvalidArgument`` with that reason, and ``cir_gym.make_vec`` falls back to a
  ``SyncVectorEnv`` of the single env instead. Unknown arguments are named as
  ``gymnasium.make`` names them; every other value is validated by the single env itself.
* **The template.** ``self.template = env_class(**kwargs)``: one single env that makes every
  reset (reference, initial state) and whose arrays and methods the subclass may call (e.g.
  ``episode_metrics`` on a copy's history). Its spaces are the single spaces.
* **The batch.** ``self.batch = mujoco.batch.Batch(template.model, num_envs, nthread)``;
  ``self._qpos`` (N, nq), ``self._qvel`` (N, nv), ``self._ctrl`` (N, nu) are its live bound
  rows (``self.batch.bind(name)`` gives any other MjData field).
* **Resets and seeding.** Copy ``i`` has its own generator ``self._rngs[i]``. ``reset(seed=s)``
  seeds copy i with ``s + i`` (a list seeds copy by copy, None leaves a generator as it is),
  so copy i of ``reset(seed=s)`` is the single env after ``reset(seed=s + i)`` and its later
  episodes are the single env's next ``reset()``. A copy's reset (:meth:`_reset_copy`) hands
  its generator to the template, calls ``template.reset()``, writes the template's MjData
  integration state (``mjSTATE_INTEGRATION``) into the batch's row i, zeroes ``self._k[i]``
  and calls the subclass's :meth:`_start_episode`.
* **Step.** :meth:`step` checks the actions (shape ``(N, m)``, numeric, finite: ValueError
  naming the copies; values outside [-1, 1] clipped), raises RuntimeError on a copy past its
  end, advances the step counters (``self._k``: steps played in each copy's episode) and calls
  the subclass's :meth:`_task_step`. Truncation is ``self._k ≥ template.max_steps`` and not
  terminated (RobotEnv's episode end). Every copy that ended gets its final observation and
  info (``infos["final_obs"]``, ``infos["final_info"]``, masks ``"_final_obs"``,
  ``"_final_info"``) and is reset in the same step (``SAME_STEP``); its reset info is added
  to ``infos`` under the copy's mask, as Gymnasium's SyncVectorEnv does.
* **Physics.** :meth:`_simulate` writes the control (and optional applied joint forces), runs
  ``Batch.step(nstep)``, and judges divergence per copy as ``RobotEnv._simulate`` judges one
  env: a new MuJoCo instability warning, a non-finite q or q̇, or |q̇| > MAX_JOINT_SPEED. A
  diverged copy gets back its last finite qpos, qvel (and act), with ``Batch.forward`` run on
  it as the single env runs ``mj_forward``.
* ``close()`` closes the template.

What a subclass implements
--------------------------
Class attributes:

* ``env_class``: the single env class (a RobotEnv with ``max_steps``, ``frame_skip``, ``dt``,
  ``metric_specs``, ``primary_metric``); ``env_id``: its registered id.
* ``fixed_arguments``: ``{argument: the only value batched}`` (e.g. ``{"randomize": False,
  "torque_noise": 0.0}``): any other value is unsupported. Override :meth:`unsupported`
  (calling ``super().unsupported(kwargs)`` first) for rules that are not "one fixed value".
* ``episode_state``: names of template attributes that a reset draws or sets (the reference,
  limits, ``_a_prev``, ``_k_scored``...; arrays or numbers). Each gets a per-copy array of
  the same name on the batched env, ``(N, *shape)`` of its dtype, filled from the template at
  every reset of the copy (``self._x_ref[i] = template._x_ref``).
* ``episode_history``: names of template arrays the single env's step writes (error, torque,
  saturation histories...): each gets a per-copy array of the same name, ``(N, *shape)``,
  which ``_task_step`` writes row by row. :meth:`_load_template` (i) hands copy i's
  ``episode_state``, ``episode_history`` and step counter ``_k`` to the template, whose own
  ``episode_metrics()`` (and success rule) then scores the copy's episode.

Methods (N = ``num_envs``; arrays are float64 unless said):

* ``_allocate(self) -> None`` (optional): allocate any other per-copy arrays, once, at the
  end of ``__init__``.
* ``_start_episode(self, i: int) -> None`` (optional): copy i has just been reset and its
  ``episode_state`` copied: the template holds the new episode (the batch's row i its
  state). Copy anything else the task step needs.
* ``_task_step(self, a, peak, k) -> TaskStep``, i.e. ``(obs, reward, terminated, infos)``:
  one control step of every copy. ``a`` (N, m): the actions clipped to [-1, 1]; ``peak`` (N,): max |a| of each
  row before clipping (≥ 1: clipped or at the limit, the single env's saturation flag);
  ``k`` (N,) int: steps played before this one (the row of this step in the histories);
  ``self._k`` already holds ``k + 1``. Run the physics (usually
  ``diverged = self._simulate(ctrl)``), then the single env's task arithmetic on the
  (N, ...) arrays. Return ``obs``: dict key → (N, ...) array (the single env's keys, clipped
  as it clips them; rows of ended copies are overwritten with their reset observation by
  the base), ``reward`` (N,), ``terminated`` (N,) bool, ``infos``: the step's info as
  ``self._step_infos({name: (N,) or (N, ...) array})`` (every copy has every key).
* ``_episode_end(self, i, infos, terminated, truncated) -> dict``: copy i's episode ended at
  this step: the single env's info of that last step, i.e. its per-step entries (usually
  ``self._row_info(infos, i)``) plus ``"episode_metrics"`` (dict name → float) and
  ``"is_success"`` (bool). Called before copy i is reset (the template is free to use).

Optional: ``_truncated(self, terminated)`` for another truncation rule;
``close_extras`` (call ``super().close_extras()``).

Register a new class in ``cir_gym.envs.BATCHED_ENVIRONMENTS`` (id → ``"module:Class"``):
``cir_gym.envs.vector.VECTOR_ENVS`` imports it on first use, ``gymnasium.make_vec`` gets a
``vector_entry_point`` for the id, and ``cir_gym.evaluation.evaluate`` batches its episodes.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import mujoco.batch
import numpy as np
from gymnasium.vector.utils import batch_space

from cir_gym.envs.base import (
    _UNSTABLE_WARNINGS as _UNSTABLE,  # MuJoCo's instability warnings, as RobotEnv counts them
)
from cir_gym.envs.base import MAX_JOINT_SPEED, RobotEnv, check_kwargs
from cir_gym.validation import InvalidArgument, check_number

__all__ = ["BatchedTaskEnv", "TaskStep"]

#: what ``_task_step`` returns: (obs key → (N, ...), reward (N,), terminated (N,), infos)
TaskStep = tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, dict[str, Any]]

_INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
_WARNINGS: slice | list[int] = (
    slice(_UNSTABLE[0], _UNSTABLE[-1] + 1)
    if _UNSTABLE[-1] - _UNSTABLE[0] + 1 == len(_UNSTABLE)
    else list(_UNSTABLE)
)


class BatchedTaskEnv(gym.vector.VectorEnv):
    """``num_envs`` copies of ``env_class`` stepped by one ``mujoco.batch.Batch`` (see the module
    docstring for what a subclass implements).

    Args:
        num_envs: number of copies (≥ 1).
        nthread: MuJoCo threads (0: all CPUs).
        **kwargs: the single env's arguments, except those :meth:`unsupported` names.

    Raises:
        InvalidArgument: ``num_envs`` < 1, ``nthread`` < 0, an unsupported argument, or one
            the single env rejects.
    """

    metadata: ClassVar[dict[str, Any]] = {"autoreset_mode": gym.vector.AutoresetMode.SAME_STEP}
    #: the single env whose step the subclass batches (its ``step`` is the specification)
    env_class: ClassVar[type[RobotEnv]]
    env_id: ClassVar[str]
    #: argument → the only value the batched step supports
    fixed_arguments: ClassVar[dict[str, Any]] = {}
    #: template attributes drawn or set by a reset: per-copy arrays, copied at each reset
    episode_state: ClassVar[tuple[str, ...]] = ()
    #: template arrays written by the step: per-copy arrays (see _load_template)
    episode_history: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def unsupported(cls, kwargs: dict[str, Any]) -> str | None:
        """Why ``kwargs`` cannot be batched here (the first unsupported argument), or None."""
        for name, value in cls.fixed_arguments.items():
            if name in kwargs and kwargs[name] != value:
                return f"{name}={kwargs[name]!r} (supported: {name}={value!r} only)"
        if kwargs.get("render_mode") is not None:
            return f"render_mode={kwargs['render_mode']!r} (the batched env does not render)"
        return None

    def __init__(self, num_envs: int = 64, nthread: int = 0, **kwargs: Any) -> None:
        num_envs = int(check_number("num_envs", num_envs, 1, 1e6))
        nthread = int(check_number("nthread", nthread, 0, 1024))
        reason = self.unsupported(kwargs)
        if reason is not None:
            raise InvalidArgument(
                f"{type(self).__name__} cannot batch {reason}; cir_gym.make_vec("
                f"{self.env_id!r}, ...) falls back to a SyncVectorEnv of the single env"
            )
        check_kwargs(self.env_class, kwargs)  # an unknown argument: named, as gymnasium.make
        self.template = self.env_class(**kwargs)  # validates every other argument
        t = self.template
        self.num_envs = num_envs
        self.single_observation_space = t.observation_space
        self.single_action_space = t.action_space
        self.observation_space = batch_space(t.observation_space, num_envs)
        self.action_space = batch_space(t.action_space, num_envs)
        self.metadata = {**self.metadata, "render_fps": t.metadata["render_fps"]}
        self.spec = None
        self.render_mode = None

        self.batch = mujoco.batch.Batch(t.model, nsim=num_envs, nthread=nthread)
        self._qpos = self.batch.bind("qpos")
        self._qvel = self.batch.bind("qvel")
        self._ctrl = self.batch.bind("ctrl")
        self._act = self.batch.bind("act") if t.model.na else None
        self._qfrc: np.ndarray | None = None  # qfrc_applied, bound on first use
        self._state_row = np.zeros(mujoco.mj_stateSize(t.model, _INTEGRATION))
        self._safe_q = np.zeros((num_envs, t.model.nq))  # the last finite state of each copy
        self._safe_qd = np.zeros((num_envs, t.model.nv))
        self._safe_act = np.zeros((num_envs, t.model.na))
        # an own generator per copy (unseeded until reset(seed=...))
        self._rngs = [gym.utils.seeding.np_random()[0] for _ in range(num_envs)]
        self._k = np.zeros(num_envs, dtype=np.int64)  # steps played in each copy's episode
        self._rows = np.arange(num_envs)
        for name in (*self.episode_state, *self.episode_history):
            value = np.asarray(getattr(t, name))
            setattr(self, name, np.zeros((num_envs, *value.shape), dtype=value.dtype))
        self._allocate()

    # ------------------------------------------------------------------ subclass hooks
    def _allocate(self) -> None:
        """Allocate the task's per-copy arrays (called once, at the end of ``__init__``)."""

    def _start_episode(self, i: int) -> None:
        """Copy the new episode of copy ``i`` from the template into the task's arrays (beyond
        ``episode_state``, which the base copies)."""

    def _task_step(self, a: np.ndarray, peak: np.ndarray, k: np.ndarray) -> TaskStep:
        """Physics and task of one control step of every copy: (obs, reward, terminated, infos)."""
        raise NotImplementedError

    def _episode_end(
        self, i: int, infos: dict[str, Any], terminated: bool, truncated: bool
    ) -> dict[str, Any]:
        """The single env's info on copy ``i``'s last step (with episode_metrics, is_success)."""
        raise NotImplementedError

    def _truncated(self, terminated: np.ndarray) -> np.ndarray:
        """(N,) bool: the copies at their episode's last step and not terminated."""
        return (self._k >= self.template.max_steps) & ~terminated

    # ------------------------------------------------------------------ resets
    def _reset_copy(self, i: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Reset copy ``i`` with the template and its generator; write its state into row i."""
        t = self.template
        t._np_random = self._rngs[i]
        obs, info = t.reset()
        self.batch.reset(ids=[i], stage=int(mujoco.mjtStage.mjSTAGE_NONE))
        mujoco.mj_getState(t.model, t.data, self._state_row, _INTEGRATION)
        self.batch.state[i] = self._state_row
        self._safe_q[i] = t.data.qpos
        self._safe_qd[i] = t.data.qvel
        self._safe_act[i] = t.data.act
        self._k[i] = 0
        for name in self.episode_state:
            getattr(self, name)[i] = getattr(t, name)
        self._start_episode(i)
        return obs, info

    def _load_template(self, i: int) -> None:
        """Hand copy ``i``'s episode (``episode_state``, ``episode_history`` and ``_k``, the
        steps played) to the template, so that its own methods score it."""
        t = self.template
        for name in ("_k", *self.episode_state, *self.episode_history):
            row = getattr(self, name)[i]
            held = getattr(t, name)
            if isinstance(held, np.ndarray):
                held[...] = row
            else:  # a number
                setattr(t, name, row.item())

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed if isinstance(seed, int) else None)
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be an int or {self.num_envs} seeds, got {seed!r}")
        for i, s in enumerate(seeds):
            if s is not None:
                self._rngs[i], _ = gym.utils.seeding.np_random(s)
        obs_list, infos = [], {}
        for i in range(self.num_envs):
            obs, info = self._reset_copy(i)
            obs_list.append(obs)
            infos = self._add_info(infos, info, i)
        keys = self.single_observation_space.spaces
        return {key: np.stack([o[key] for o in obs_list]) for key in keys}, infos

    # ------------------------------------------------------------------ step
    def step(
        self, actions: Any
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        a, peak = self._check_actions(actions)
        if np.any(self._k >= self.template.max_steps):
            raise RuntimeError("step() on a finished copy; the vector env resets them itself")
        k = self._k.copy()
        self._k += 1
        obs, reward, terminated, infos = self._task_step(a, peak, k)
        truncated = self._truncated(terminated)
        step_infos = dict(infos)  # the step's own entries (the resets below add theirs)
        for i in np.flatnonzero(terminated | truncated):
            i = int(i)
            final_info = self._episode_end(i, step_infos, bool(terminated[i]), bool(truncated[i]))
            final_obs = {key: v[i].copy() for key, v in obs.items()}
            new_obs, reset_info = self._reset_copy(i)
            for key in obs:
                obs[key][i] = new_obs[key]
            infos = self._add_info(infos, {"final_obs": final_obs, "final_info": final_info}, i)
            infos = self._add_info(infos, reset_info, i)
        return obs, reward, terminated, truncated, infos

    def _check_actions(self, actions: Any) -> tuple[np.ndarray, np.ndarray]:
        """(actions clipped to [-1, 1] as float64 (N, m), max |action| of each row (N,))."""
        shape = self.action_space.shape
        try:
            raw = np.asarray(actions)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"actions must be a numeric array of shape {shape}") from exc
        if raw.dtype.kind not in "biuf" or raw.shape != shape:
            raise ValueError(
                f"actions must be a numeric array of shape {shape} with values in [-1, 1], "
                f"got shape {raw.shape} dtype {raw.dtype}"
            )
        a = raw.astype(np.float64)
        peak = np.max(np.abs(a), axis=1)  # NaN propagates, inf stays: one reduction checks both
        if not np.all(np.isfinite(peak)):
            bad = np.flatnonzero(~np.isfinite(peak))
            raise ValueError(f"actions of envs {bad.tolist()} contain NaN or inf")
        if np.any(peak > 1.0):
            np.clip(a, -1.0, 1.0, out=a)
        return a, peak

    def _step_infos(self, values: dict[str, np.ndarray]) -> dict[str, Any]:
        """A step's infos with every copy's entry: ``values`` with an all-true mask per key."""
        ones = np.ones(self.num_envs, dtype=bool)
        infos: dict[str, Any] = {}
        for key, value in values.items():
            infos[key] = value
            infos["_" + key] = ones
        return infos

    @staticmethod
    def _row_info(infos: dict[str, Any], i: int) -> dict[str, Any]:
        """Copy ``i``'s entries of a step's infos (``_step_infos``) as the single env's info:
        Python floats and bools for scalars, arrays copied."""
        row: dict[str, Any] = {}
        for key, value in infos.items():
            if key.startswith("_"):
                continue
            v = value[i]
            row[key] = v.item() if np.ndim(v) == 0 else np.array(v)
        return row

    # ------------------------------------------------------------------ physics
    def _simulate(
        self, ctrl: np.ndarray, nstep: int | None = None, qfrc: np.ndarray | None = None
    ) -> np.ndarray:
        """Hold ``ctrl`` (N, nu) (and applied joint forces ``qfrc`` (N, nv)) for ``nstep``
        physics steps (default: the template's ``frame_skip``) of every copy; return the
        (N,) copies that diverged, restored to their last finite state (RobotEnv._simulate's
        rule, copy by copy)."""
        q, qd = self._qpos, self._qvel
        # the last finite state (a finite sum: every row is finite)
        if np.isfinite(np.sum(q)) and np.isfinite(np.sum(qd)):
            self._safe_q[:] = q
            self._safe_qd[:] = qd
            if self._act is not None:
                self._safe_act[:] = self._act
        else:
            finite = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(qd), axis=1)
            self._safe_q[finite] = q[finite]
            self._safe_qd[finite] = qd[finite]
            if self._act is not None:
                self._safe_act[finite] = self._act[finite]
        warnings_before = self._warning_counts().copy()
        self._ctrl[:] = ctrl
        if qfrc is not None:
            if self._qfrc is None:
                self._qfrc = self.batch.bind("qfrc_applied")
            self._qfrc[:] = qfrc
        self.batch.step(nstep=self.template.frame_skip if nstep is None else nstep)
        diverged = self._diverged(warnings_before)
        if np.any(diverged):  # the last finite state, as RobotEnv._simulate restores it
            q[diverged] = self._safe_q[diverged]
            qd[diverged] = self._safe_qd[diverged]
            if self._act is not None:
                self._act[diverged] = self._safe_act[diverged]
            self.batch.forward(ids=np.flatnonzero(diverged))
        return diverged

    def _warning_counts(self) -> np.ndarray:
        """MuJoCo's instability-warning counters of every copy (N, 4): a view of the batch's
        while the four are neighbours in mjtWarning (as in MuJoCo 4), else a copy."""
        return self.batch.warning[:, _WARNINGS, 1]

    def _diverged(self, warnings_before: np.ndarray) -> np.ndarray:
        """(N,) bool: a new MuJoCo instability warning, a non-finite q or q̇, or |q̇| above
        MAX_JOINT_SPEED, per copy, as RobotEnv._simulate judges one env. Two whole-batch
        reductions decide; the per-row checks run only when they flag something."""
        q, qd = self._qpos, self._qvel
        new_warning = self._warning_counts() != warnings_before  # the counters only grow
        if (
            not new_warning.any()
            and np.max(np.abs(qd)) <= MAX_JOINT_SPEED
            and np.isfinite(np.sum(q))
        ):  # NaN fails the comparison and the finite sum
            return np.zeros(self.num_envs, dtype=bool)
        with np.errstate(all="ignore"):
            return (
                np.any(new_warning, axis=1)
                | ~np.all(np.isfinite(q), axis=1)
                | ~np.all(np.isfinite(qd), axis=1)
                | (np.max(np.abs(qd), axis=1) > MAX_JOINT_SPEED)
            )

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()
