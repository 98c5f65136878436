"""Record MuJoCo's ``mj_step`` calls and replay them: the physics part of a benchmark's ratio.

A :class:`PhysicsTape` records, while ``with tape:`` is open, MuJoCo's full integration state
(time, qpos, qvel, act, sensor history, warm start, ctrl, applied forces, mocap, ...) before
every ``mj_step`` call and the call's ``nstep``; :func:`replay_seconds` steps those states
again and times only ``mj_step``. So the physics of a run is timed on the states the run
visited (contacts as the env met them), not on a fresh ``MjData`` in free space. Used by
``bench_step.py`` (the env-step and predict ratios) and ``bench_leaderboard_bound.py`` (the
leaderboard's physics floor). Imported by the scripts of this directory as a sibling module.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from typing import NamedTuple

import mujoco
import numpy as np

__all__ = ["INTEGRATION", "PhysicsTape", "Segment", "replay_seconds"]

INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)


class Segment(NamedTuple):
    """Recorded calls on one model: the state before each call (``mj_stateSize`` values),
    its ``nstep``, and the env steps the segment covered (set by :meth:`PhysicsTape.cut`)."""

    model: mujoco.MjModel
    states: list[np.ndarray]
    nsteps: list[int]
    env_steps: int | None = None


class PhysicsTape:
    """The ``mj_step`` calls made while it records, in segments.

    ``with tape:`` replaces ``mujoco.mj_step`` by a wrapper that records, then calls the
    original (the physics is unchanged: ``mj_getState`` only reads), and puts it back.

    - ``PhysicsTape(model)``: that model's calls only, into one open segment that
      :meth:`cut` closes (e.g. one segment per timed trial, with the env steps it covered);
      replayed on ``model`` itself.
    - ``PhysicsTape()``: every model's calls, a segment per episode of each model, with a
      copy of the model as it was then. An episode starts where the model's simulated time
      goes back (``reset`` sets it to 0). The copy matters: an env may change its model at
      ``reset`` (PegInHole moves the hole block, ``randomize`` draws masses or a
      stiffness), so replaying an early episode on the model of the last one would time
      other contacts.
    """

    def __init__(self, model: mujoco.MjModel | None = None) -> None:
        self.model = model
        self.segments: list[Segment] = []
        self._open: Segment | None = None if model is None else Segment(model, [], [])
        self._orig: Callable[..., None] | None = None

    def __enter__(self) -> PhysicsTape:
        orig = self._orig = mujoco.mj_step
        only = self.model
        segments = self.segments
        current: dict[int, tuple[float, Segment]] = {}  # id(model) → (last time, its segment)

        def recording_step(m: mujoco.MjModel, d: mujoco.MjData, nstep: int = 1) -> None:
            if only is not None:
                if m is not only:
                    orig(m, d, nstep)
                    return
                segment = self._open
            else:
                last = current.get(id(m))
                if last is None or d.time < last[0]:  # a new episode: the model as it is now
                    segment = Segment(copy.copy(m), [], [])
                    segments.append(segment)
                else:
                    segment = last[1]
            state = np.empty(mujoco.mj_stateSize(m, INTEGRATION))
            mujoco.mj_getState(m, d, state, INTEGRATION)
            segment.states.append(state)
            segment.nsteps.append(int(nstep))
            orig(m, d, nstep)
            if only is None:
                current[id(m)] = (d.time, segment)

        mujoco.mj_step = recording_step
        return self

    def __exit__(self, *exc: object) -> None:
        mujoco.mj_step = self._orig

    def cut(self, env_steps: int) -> None:
        """Close the calls recorded since the last cut as one segment of ``env_steps`` env
        steps (a tape of one model)."""
        if self._open is None:
            raise ValueError("cut() needs a tape of one model: PhysicsTape(model)")
        self.segments.append(self._open._replace(env_steps=env_steps))
        self._open = Segment(self.model, [], [])

    def physics_steps(self) -> int:
        """Physics steps (the sum of the calls' ``nstep``) in every closed segment."""
        return sum(sum(s.nsteps) for s in self.segments)

    def steps_per_env_step(self) -> float:
        """Physics steps per env step over the cut segments (the env's frame_skip)."""
        env_steps = sum(s.env_steps or 0 for s in self.segments)
        return self.physics_steps() / max(1, env_steps)


def replay_seconds(segment: Segment, data: mujoco.MjData | None = None) -> float:
    """CPU seconds of ``mj_step`` on the segment's recorded calls: each state restored with
    ``mj_setState`` and stepped with its ``nstep``, minus the same ``mj_setState`` loop alone,
    on ``data`` (a new MjData of the segment's model if None)."""
    m = segment.model
    d = mujoco.MjData(m) if data is None else data
    set_state, mj_step = mujoco.mj_setState, mujoco.mj_step
    calls = list(zip(segment.states, segment.nsteps, strict=True))
    t0 = time.process_time()
    for s, n in calls:
        set_state(m, d, s, INTEGRATION)
        mj_step(m, d, n)
    t1 = time.process_time()
    for s, _n in calls:
        set_state(m, d, s, INTEGRATION)
    t2 = time.process_time()
    return (t1 - t0) - (t2 - t1)
