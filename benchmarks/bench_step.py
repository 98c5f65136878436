"""Python overhead of ``env.step`` and of the controllers' ``predict`` against MuJoCo's own cost.

    python benchmarks/bench_step.py [--steps 100] [--repeat 10] [--batch 16] [--env ID ...]
                                    [--num-envs 64] [--nthread 1] [--out results/benchmarks.md]

Ratios, not absolute times: every pair of loops is timed alternately in the same run and the
best of ``--repeat`` trials is kept, so a loaded machine slows both sides alike. Time is the
process's CPU time (``time.process_time``: other jobs' time slices are not counted; MuJoCo's
batch threads are), so short trials on a shared machine still measure the code.

Environments (each built with ``gymnasium.make`` and its default wrappers, zero action, resets
not timed):

- physics-driven envs (every env whose ``step`` runs ``mj_step``: the torque-driven ones and
  VisualServo, whose joint velocity servos are simulated): overhead = time of ``env.step``
  minus the ``mj_step`` calls that step makes, replayed on the states it visited (a
  :class:`PhysicsTape` records, in an untimed pass over the same steps, MuJoCo's full
  integration state before every ``mj_step`` call and its ``nstep``; the replay restores each
  state with ``mj_setState`` and steps it, minus the same ``mj_setState`` loop alone). So a
  contact env's physics is timed with its contacts, the way the env pays for them, not on a
  fresh ``MjData`` in free space (``_tape.py``, shared with ``bench_leaderboard_bound.py``).
  Gymnasium's ``Reacher-v5`` is measured the same way; the table gives each env's overhead /
  Reacher's overhead.
- contact envs in contact (:data:`DRIVEN`): the zero action never reaches the surface
  (PegInHole's zero-action row is free fall), so these envs get a second row whose steps are
  driven by a controller's actions after an untimed warm-up from the reset: the recording
  pass calls ``predict`` (its state carried, as the evaluator does) and keeps the actions,
  the timed loop replays them (the controller's time is not in the step's), and the tape
  holds the physics of those contact steps only.
- kinematic envs (RedundantIK, RedundantIK7: no dynamics in ``step``): overhead = time of
  ``env.step`` minus ``mj_kinematics + mj_comPos + mj_jacSite`` (the end-effector site), and
  the ratio of that overhead to the same kinematics.

Plumbing: RobotEnv's ``_check_action`` (a finite in-range action) and ``_simulate`` minus
the ``frame_skip`` × ``mj_step`` it runs, per env, in units of one ``mj_step``.

Controllers: every controller in ``baselines.CONTROLLERS`` on the first registered env it
applies to: ``predict`` on one observation (fresh state each call: the first step of an
episode) against one ``mj_step`` of that env's model (replayed on the states of the env's
zero-action steps, as above); then ``predict`` on ``--batch`` stacked observations, per row.

Vector env: env-steps/s of ``--num-envs`` JointTracking copies in
``cir_gym.envs.vector.JointTrackingVectorEnv``, of the same model's raw ``mujoco.batch.Batch.step``
and of Gymnasium's ``SyncVectorEnv`` of the single env (``gymnasium.make_vec``); when ``--env``
includes PegInHole-v2, its batched env against SyncVectorEnv at ``--peg-copies`` copies, both
control interfaces (:func:`bench_peg_vector`).

Prints markdown and writes it to ``--out`` under the heading ``## env.step and predict``,
replacing only that section (other sections of the file, e.g. vector-env scaling, are kept).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from _sections import write_section  # sibling modules: the scripts run as files
from _tape import PhysicsTape, replay_seconds

import cir_gym
from cir_gym import baselines

KINEMATIC = ("cir_gym/RedundantIK-v4", "cir_gym/RedundantIK7-v5")
#: contact envs timed a second time in contact: the controller whose actions drive the steps
#: and the steps played untimed from the reset first (the zero action never touches the
#: surface: PegInHole's zero-action row is free fall and one impact; on seed 0 these
#: controllers touch at step ~700 (PegInHole) and ~870 (AdmittanceContact))
DRIVEN = {
    "cir_gym/PegInHole-v2": ("hybrid_force_position", 1000),
    "cir_gym/AdmittanceContact-v2": ("admittance", 1000),
}
REFERENCE = "Reacher-v5"

SECTION = "## env.step and predict"
OUT = Path(__file__).parents[1] / "results" / "benchmarks.md"


def best_pair(
    mine: Callable[[], float], raw: Callable[[], float], repeat: int
) -> tuple[float, float]:
    """Best-of-``repeat`` seconds per call of two loops timed alternately.

    Each loop returns its own per-call time (so it can leave out resets).
    """
    mine()
    raw()
    t_mine, t_raw = [], []
    for _ in range(repeat):
        t_mine.append(mine())
        t_raw.append(raw())
    return min(t_mine), min(t_raw)


def step_loop(
    env: gym.Env,
    steps: int,
    count: bool = False,
    actions: Callable[[Any, bool], np.ndarray] | None = None,
    warmup: int = 0,
) -> Callable[[], float]:
    """Seconds per ``env.step`` over up to ``steps`` steps; resets untimed.

    Each call continues the episode of the last (a fresh loop starts with ``reset(seed=0)``)
    and resets it when fewer than ``steps`` steps are left. ``actions``: a function of the
    observation and of whether it is an episode's first giving each action (default: the
    zero action); ``warmup``: steps played untimed after every reset (a driven row times the
    contact phase, not the approach). ``count``: return the number of steps played instead
    of a time (the untimed recording pass of :func:`recorded_step_loop`).

    Without a warm-up an episode shorter than ``steps`` just ends a call early (Reacher-v5's
    50 steps); a driven loop's recorded actions assume whole calls, so there it is an error.

    Raises:
        ValueError: a warm-up and an episode shorter than ``warmup + steps``, or an episode
            that ends in the warm-up.
    """
    limit = env.spec.max_episode_steps or 10**9
    if warmup and limit - warmup < steps:
        raise ValueError(
            f"{env.spec.id}: {limit} steps per episode leave fewer than steps={steps} after "
            f"a warm-up of {warmup}"
        )
    zero = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    act = actions if actions is not None else (lambda _obs, _first: zero)
    left = [0]
    obs: list[Any] = [None]
    first = [False]

    def prime() -> None:
        """Reset (and play the warm-up) when fewer than ``steps`` steps are left."""
        if left[0] < steps:
            obs[0], _ = env.reset(seed=0)
            first[0] = True
            for k in range(warmup):
                obs[0], _, terminated, truncated, _ = env.step(act(obs[0], first[0]))
                first[0] = False
                if terminated or truncated:
                    raise ValueError(
                        f"{env.spec.id}: the episode ended at step {k + 1} of the warm-up"
                    )
            left[0] = limit - warmup

    def loop() -> float:
        prime()
        n = 0
        o, f = obs[0], first[0]
        t0 = time.process_time()
        for _ in range(steps):
            o, _, terminated, truncated, _ = env.step(act(o, f))
            f = False
            n += 1
            if terminated or truncated:
                break
        t = time.process_time() - t0
        obs[0], first[0] = o, False
        left[0] = 0 if (terminated or truncated) else left[0] - n
        return n if count else t / n

    loop.prime = prime  # type: ignore[attr-defined]
    return loop


def recorded_step_loop(
    env: gym.Env, steps: int, trials: int, policy: Any = None, warmup: int = 0
) -> tuple[Callable[[], float], PhysicsTape]:
    """:func:`step_loop` and the physics of its first ``trials`` calls.

    An untimed pass of ``trials`` calls of a fresh :func:`step_loop` records the ``mj_step``
    calls of each (one tape segment per trial); the returned loop starts over from the same
    seeded reset, so its k-th call plays the very steps of segment k (the env is
    deterministic: same seed, same actions). Every episode starts from ``reset(seed=0)``, so
    a model the env changes at reset (PegInHole's hole pose, a randomized mass) is the same
    in every recorded step and at the replay.

    ``policy`` (a controller): the recording pass takes its actions (``predict`` with its
    state carried, as the evaluator does) and records them; the returned loop replays them
    in order (the controller's own time is not in the step's), after ``warmup`` untimed steps
    from each reset.
    """
    tape = PhysicsTape(env.unwrapped.model)
    if policy is None:
        counted = step_loop(env, steps, count=True, warmup=warmup)
        played = None
    else:
        played: list[np.ndarray] = []
        state: list[Any] = [None]

        def drive(o: Any, first: bool) -> np.ndarray:
            action, state[0] = policy.predict(
                o, state=None if first else state[0], episode_start=np.array([first])
            )
            played.append(action)
            return action

        counted = step_loop(env, steps, count=True, actions=drive, warmup=warmup)
    for _ in range(trials):
        counted.prime()  # a reset and its warm-up stay off the tape
        with tape:
            tape.cut(counted())
    if played is None:
        return step_loop(env, steps, warmup=warmup), tape
    replay = iter(played)

    def replayed(_obs: Any, _first: bool) -> np.ndarray:
        action = next(replay, None)
        if action is None:
            raise RuntimeError(
                f"the replay called for more than the {len(played)} recorded actions: time "
                f"the loop as often as it was recorded ({trials} calls)"
            )
        return action

    return step_loop(env, steps, actions=replayed, warmup=warmup), tape


def replay_loop(tape: PhysicsTape, per_mj_step: bool = False) -> Callable[[], float]:
    """Seconds of the physics of the tape's next segment (cycling), per env step (or per
    physics step): each recorded state restored with ``mj_setState`` and stepped with its
    ``nstep``, minus the same ``mj_setState`` loop alone, on an own MjData."""
    data = mujoco.MjData(tape.model)
    turn = [0]

    def loop() -> float:
        segment = tape.segments[turn[0] % len(tape.segments)]
        turn[0] += 1
        seconds = replay_seconds(segment, data)
        return seconds / (sum(segment.nsteps) if per_mj_step else segment.env_steps)

    return loop


def physics_loop(model: mujoco.MjModel, steps: int) -> Callable[[], float]:
    """Seconds per ``mj_step`` at zero control on a fresh MjData (for the kinematic envs,
    whose steps run no physics to replay)."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    qpos0, qvel0 = data.qpos.copy(), data.qvel.copy()

    def loop() -> float:
        data.qpos[:] = qpos0
        data.qvel[:] = qvel0
        data.time = 0.0
        t0 = time.process_time()
        for _ in range(steps):
            mujoco.mj_step(model, data)
        return (time.process_time() - t0) / steps

    return loop


def kinematics_loop(model: mujoco.MjModel, site: int, steps: int) -> Callable[[], float]:
    """Seconds per mj_kinematics + mj_comPos + mj_jacSite on a fresh MjData."""
    data = mujoco.MjData(model)
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))

    def loop() -> float:
        t0 = time.process_time()
        for _ in range(steps):
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            mujoco.mj_jacSite(model, data, jacp, jacr, site)
        return (time.process_time() - t0) / steps

    return loop


def bench_envs(ids: list[str], steps: int, repeat: int, ratios: dict | None = None) -> list[str]:
    rows = []
    results = {}
    cases = [(env_id, None) for env_id in [REFERENCE, *ids]]
    cases += [(env_id, DRIVEN[env_id]) for env_id in ids if env_id in DRIVEN]
    for env_id, driven in cases:
        env = gym.make(env_id)
        env.reset(seed=0)
        u = env.unwrapped
        label = env_id
        if driven is not None:
            name, warmup = driven
            policy = baselines.make(name, env_id)
            mine, tape = recorded_step_loop(env, steps, repeat + 1, policy, warmup)
            raw = replay_loop(tape)
            what = f"{tape.steps_per_env_step():g} × mj_step, replayed"
            label = f"{env_id}, driven by {name} in contact (steps {warmup}+)"
        elif env_id in KINEMATIC:
            mine = step_loop(env, steps)
            site = u.model.nsite - 1
            ctx = u.controller_context()
            if ctx.site is not None:
                site = mujoco.mj_name2id(u.model, mujoco.mjtObj.mjOBJ_SITE, ctx.site)
            raw = kinematics_loop(u.model, site, steps)
            what = "mj_kinematics + mj_comPos + mj_jacSite"
        else:
            mine, tape = recorded_step_loop(env, steps, repeat + 1)  # best_pair: 1 + repeat
            raw = replay_loop(tape)
            per = tape.steps_per_env_step()
            what = f"{per:g} × mj_step, replayed"
        t_step, t_raw = best_pair(mine, raw, repeat)
        results[label] = (t_step, t_raw, what, env_id in KINEMATIC)
        env.close()
        print(f"  {label}: step {t_step * 1e6:.1f} µs, {what} {t_raw * 1e6:.1f} µs", flush=True)
    ref_over = results[REFERENCE][0] - results[REFERENCE][1]
    rows.append(
        "| env | MuJoCo part | step / MuJoCo part | overhead / Reacher-v5's overhead "
        "| overhead / MuJoCo part |"
    )
    rows.append("|---|---|---:|---:|---:|")
    for env_id, (t_step, t_raw, what, kin) in results.items():
        over = t_step - t_raw
        vs_ref = "—" if kin else f"{over / ref_over:.2f}"
        if ratios is not None and not kin and env_id != REFERENCE:
            ratios[env_id] = over / ref_over
        rows.append(f"| {env_id} | {what} | {t_step / t_raw:.2f} | {vs_ref} | {over / t_raw:.2f} |")
    return rows


def bench_plumbing(ids: list[str], steps: int, repeat: int) -> list[str]:
    """RobotEnv's shared per-step plumbing: ``_check_action`` and ``_simulate`` minus its
    ``frame_skip`` × ``mj_step``, on the env's own MjData (the state evolves alike on both
    sides: each side steps the same data in turn)."""
    rows = [
        "| env | _check_action / mj_step | (_simulate − physics) / mj_step |",
        "|---|---:|---:|",
    ]
    for env_id in ids:
        if env_id in KINEMATIC:
            continue
        env = gym.make(env_id)
        env.reset(seed=0)
        u = env.unwrapped
        action = np.full(env.action_space.shape, 0.1, dtype=env.action_space.dtype)
        ctrl = u.data.ctrl.copy()
        m, d, skip = u.model, u.data, u.frame_skip

        def check(u=u, action=action) -> float:
            t0 = time.process_time()
            for _ in range(steps):
                u._check_action(action)
            return (time.process_time() - t0) / steps

        def simulate(u=u, ctrl=ctrl) -> float:
            t0 = time.process_time()
            for _ in range(steps):
                u._simulate(ctrl)
            return (time.process_time() - t0) / steps

        def physics(m=m, d=d, skip=skip) -> float:
            t0 = time.process_time()
            for _ in range(steps):
                for _ in range(skip):
                    mujoco.mj_step(m, d)
            return (time.process_time() - t0) / steps

        t_sim, t_phys = best_pair(simulate, physics, repeat)
        t_check = min(check() for _ in range(repeat))
        one = t_phys / skip
        rows.append(f"| {env_id} | {t_check / one:.2f} | {(t_sim - t_phys) / one:.2f} |")
        env.close()
    return rows


def stack(obs: dict, n: int) -> dict:
    return {k: np.stack([np.asarray(v)] * n) for k, v in obs.items()}


def bench_controllers(
    ids: list[str], calls: int, repeat: int, batch: int, ratios: dict | None = None
) -> list[str]:
    rows = [
        f"| controller | env | predict(1 obs) / mj_step | predict({batch} obs) per row / mj_step "
        "| per row / single |",
        "|---|---|---:|---:|---:|",
    ]
    envs: dict[str, gym.Env] = {}
    units: dict[str, Callable[[], float]] = {}  # env id → one mj_step on its visited states
    for name in baselines.CONTROLLERS:
        env_id = next((i for i in ids if name in baselines.available(i)), None)
        if env_id is None:
            continue
        if env_id not in envs:
            envs[env_id] = gym.make(env_id)
            if env_id in KINEMATIC:  # no physics in its steps: mj_step on a fresh MjData
                units[env_id] = physics_loop(envs[env_id].unwrapped.model, calls)
            else:
                stepped = gym.make(env_id)
                tape = recorded_step_loop(stepped, calls, 2)[1]
                units[env_id] = replay_loop(tape, per_mj_step=True)
                stepped.close()
        env = envs[env_id]
        obs, _ = env.reset(seed=0)
        policy = baselines.make(name, env_id, env=env)

        def single(policy=policy, obs=obs) -> float:
            t0 = time.process_time()
            for _ in range(calls):
                policy.predict(obs)
            return (time.process_time() - t0) / calls

        raw = units[env_id]
        t_pred, t_step = best_pair(single, raw, repeat)
        many = stack(obs, batch)
        try:
            batched_policy = baselines.make(name, env_id, env=env)
            batched_policy.predict(many)

            def batched(policy=batched_policy, many=many) -> float:
                t0 = time.process_time()
                for _ in range(max(1, calls // batch)):
                    policy.predict(many)
                return (time.process_time() - t0) / (max(1, calls // batch) * batch)

            t_batch, t_step2 = best_pair(batched, raw, repeat)
            per_row = f"{t_batch / t_step2:.2f}"
            vs_single = f"{(t_batch / t_step2) / (t_pred / t_step):.2f}"
        except Exception as exc:  # a controller that takes single observations only
            per_row, vs_single = f"not batched ({type(exc).__name__})", "—"
        print(
            f"  {name} on {env_id}: predict {t_pred * 1e6:.1f} µs, mj_step {t_step * 1e6:.1f} µs",
            flush=True,
        )
        rows.append(f"| {name} | {env_id} | {t_pred / t_step:.2f} | {per_row} | {vs_single} |")
        if ratios is not None:
            ratios[name] = (t_pred / t_step, per_row, vs_single)
    for env in envs.values():
        env.close()
    return rows


def bench_vector(num_envs: int, steps: int, repeat: int, nthread: int) -> list[str]:
    """env-steps/s of JointTracking: the batched vector env, its raw batched physics, and
    Gymnasium's SyncVectorEnv of the single env; ``max_following_error=None`` (zero torques
    would end every episode within a few dozen steps: resets are not what this times)."""
    import mujoco.batch

    from cir_gym.envs.vector import JointTrackingVectorEnv

    kw = {"max_following_error": None}
    vec = JointTrackingVectorEnv(num_envs, nthread=nthread, **kw)
    vec.reset(seed=0)
    sync = gym.make_vec(
        "cir_gym/JointTracking-v2", num_envs=num_envs, vectorization_mode="sync", **kw
    )
    sync.reset(seed=0)
    raw = mujoco.batch.Batch(vec.template.model, nsim=num_envs, nthread=nthread)
    raw.state[:] = vec.batch.state
    skip = vec.template.frame_skip
    zeros = np.zeros(vec.action_space.shape, dtype=np.float32)
    n_vec = max(1, steps // 4)  # vector steps per trial

    def timed(step: Callable[[], Any], n: int) -> Callable[[], float]:
        def loop() -> float:
            t0 = time.process_time()
            for _ in range(n):
                step()
            return (time.process_time() - t0) / (n * num_envs)

        return loop

    t_vec, t_raw = best_pair(
        timed(lambda: vec.step(zeros), n_vec), timed(lambda: raw.step(nstep=skip), n_vec), repeat
    )
    t_sync = min(timed(lambda: sync.step(zeros), max(1, n_vec // 4))() for _ in range(3))
    vec.close()
    sync.close()
    return [
        f"JointTracking-v2 × {num_envs}, zero torques, `max_following_error=None`, "
        f"MuJoCo threads: {nthread or 'all CPUs'}.",
        "",
        "| what | env-steps/s | vs SyncVectorEnv |",
        "|---|---:|---:|",
        f"| gymnasium SyncVectorEnv of the single env | {1 / t_sync:,.0f} | 1.00 |",
        f"| cir_gym.envs.vector.JointTrackingVectorEnv | {1 / t_vec:,.0f} | {t_sync / t_vec:.2f} |",
        f"| raw mujoco.batch.Batch.step(nstep={skip}), same model | {1 / t_raw:,.0f} "
        f"| {t_sync / t_raw:.2f} |",
    ]


PEG = "cir_gym/PegInHole-v2"
#: PegInHole's batched rows: the interface and arguments, and what the zero action does there
PEG_CASES = (
    ("torque", {"force_limit": 1e4}, "zero torque: the arm falls on the block and rests on it "
     "(in contact on ~87 % of the steps; force limit raised so that the episodes go on)"),
    ("position", {"control": "position"}, "zero increment: the motion controller holds the "
     "start pose (free space, 10 mm above the hole)"),
)


def _vector_step_time(
    env: Any, actions: np.ndarray, steps: int, clock: Callable[[], float] = time.process_time
) -> float:
    """Seconds per env-step of ``steps`` calls of a vector env's ``step(actions)``."""
    t0 = clock()
    for _ in range(steps):
        env.step(actions)
    return (clock() - t0) / (steps * len(actions))


def bench_peg_vector(copies: list[int], steps: int, repeat: int, nthread: int) -> list[str]:
    """env-steps/s of ``cir_gym.envs.peg_in_hole_vector.PegInHoleVectorEnv`` against Gymnasium's
    SyncVectorEnv of the single env at each number of copies, both control interfaces (the
    zero action, autoreset on both sides; process CPU time with ``nthread`` MuJoCo threads,
    alternately, best of ``repeat``), then the batched env with 2 threads in wall time."""
    from cir_gym.envs.peg_in_hole_vector import PegInHoleVectorEnv

    rows = [
        "| interface | copies | SyncVectorEnv env-steps/s | batched env-steps/s | batched / "
        "Sync | batched, 2 threads, wall env-steps/s |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for control, kwargs, _ in PEG_CASES:
        for n in copies:
            vec = PegInHoleVectorEnv(n, nthread=nthread, **kwargs)
            sync = gym.make_vec(PEG, num_envs=n, vectorization_mode="sync", **kwargs)
            wide = PegInHoleVectorEnv(n, nthread=2, **kwargs)
            zeros = np.zeros(vec.action_space.shape, dtype=np.float32)
            for env in (vec, sync, wide):
                env.reset(seed=0)
                for _ in range(20):  # into the contact phase (torque: the arm has fallen)
                    env.step(zeros)
            per = max(2, steps // 8)
            batched, synced = (partial(_vector_step_time, e, zeros, per) for e in (vec, sync))
            t_vec, t_sync = best_pair(batched, synced, repeat)
            wall = partial(_vector_step_time, wide, zeros, per, time.perf_counter)
            t_wide = min(wall() for _ in range(repeat))
            rows.append(
                f"| {control} | {n} | {1 / t_sync:,.0f} | {1 / t_vec:,.0f} | "
                f"{t_sync / t_vec:.2f} | {1 / t_wide:,.0f} |"
            )
            print(f"  PegInHole {control} x{n}: sync {t_sync * 1e6:.0f} us, batched "
                  f"{t_vec * 1e6:.0f} us, 2 threads wall {t_wide * 1e6:.0f} us", flush=True)
            for env in (vec, sync, wide):
                env.close()
    notes = [f"- {control}: {what}." for control, _, what in PEG_CASES]
    return [*rows, "", *notes]


#: issue 21's targets: the torque envs' step overhead at most Reacher-v5's; the joint-space
#: laws' predict on one observation at most 2 mj_step
TORQUE_ENVS = ("cir_gym/JointTracking-v2", "cir_gym/ElasticJointTracking-v3")
TARGET_LAWS = ("pd_gravity", "computed_torque")


def target_lines(env_ratios: dict[str, float], ctrl_ratios: dict[str, tuple]) -> list[str]:
    """Issue 21's targets for the joint-space envs and laws, met or missed, from this run."""

    def verdict(ok: bool) -> str:
        return "met" if ok else "missed"

    lines = ["Issue 21 targets in this run (joint-space envs and laws):", ""]
    for env_id in TORQUE_ENVS:
        if env_id in env_ratios:
            r = env_ratios[env_id]
            lines.append(f"- {env_id}: overhead {r:.2f}× Reacher-v5's (≤ 1): {verdict(r <= 1)}")
    for name in TARGET_LAWS:
        if name in ctrl_ratios:
            single, per_row, vs_single = ctrl_ratios[name]
            lines.append(
                f"- {name}: predict(1 obs) {single:.2f} mj_step (≤ 2): {verdict(single <= 2)}; "
                f"a batched row {per_row} mj_step ({vs_single} of a single call)"
            )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=100, help="steps/calls per timed trial")
    parser.add_argument("--repeat", type=int, default=10, help="trials; the best is kept")
    parser.add_argument("--batch", type=int, default=16, help="rows of the batched predict")
    parser.add_argument("--num-envs", type=int, default=64, help="copies of the vector env")
    parser.add_argument("--nthread", type=int, default=1, help="MuJoCo threads (0: all CPUs)")
    parser.add_argument(
        "--peg-copies", type=int, nargs="*", default=[16, 64],
        help="copies of the batched PegInHole (run when --env includes it)",
    )
    parser.add_argument("--env", nargs="*", default=None, help="env ids (default: all)")
    parser.add_argument("--out", type=Path, default=OUT, help="markdown file ('-' for none)")
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore")
    ids = args.env or list(cir_gym.ENVIRONMENTS)
    print("env.step:", flush=True)
    env_ratios: dict[str, float] = {}
    ctrl_ratios: dict[str, tuple] = {}
    env_rows = bench_envs(ids, args.steps, args.repeat, env_ratios)
    plumbing_rows = bench_plumbing(ids, args.steps, args.repeat)
    print("controllers:", flush=True)
    ctrl_rows = bench_controllers(ids, args.steps, args.repeat, args.batch, ctrl_ratios)
    print("vector env:", flush=True)
    vec_rows = bench_vector(args.num_envs, args.steps, args.repeat, args.nthread)
    peg_rows = (
        bench_peg_vector(args.peg_copies, args.steps, args.repeat, args.nthread)
        if PEG in ids
        else []
    )
    body = "\n".join(
        [
            f"`python benchmarks/bench_step.py --steps {args.steps} --repeat {args.repeat} "
            f"--batch {args.batch}` (mujoco {mujoco.__version__}, gymnasium {gym.__version__}; "
            "process CPU time, best of the trials, the two sides of each ratio timed "
            "alternately in one run).",
            "",
            "`env.step` through `gymnasium.make` (default wrappers), zero action, resets not "
            "timed. Overhead = step − MuJoCo part: for the physics-driven envs the `mj_step` "
            "calls of those very steps, replayed on the states they visited (each state "
            "restored with `mj_setState`, whose own cost is subtracted), so contacts are "
            "timed as the env meets them; for RedundantIK the kinematics named. Reacher-v5 "
            "is Gymnasium's, measured the same way. The zero action never touches a surface, "
            "so the contact envs get a second row *in contact*: the steps after an untimed "
            "warm-up, driven by the named controller's actions (recorded in an untimed pass, "
            "replayed in the timed one: the controller's own time is not in the step's).",
            "",
            *env_rows,
            "",
            *target_lines(env_ratios, ctrl_ratios),
            "",
            "RobotEnv's shared plumbing per step (cir_gym/envs/base.py), in units of one "
            "`mj_step` of the env's model (a difference of two timings: with many substeps "
            "(VisualServo: 20) it is below their spread and can come out negative):",
            "",
            *plumbing_rows,
            "",
            "Controllers' `predict` (fresh state: an episode's first step) against one "
            "`mj_step` of the env's model (on the states of its zero-action steps; RedundantIK, "
            "which steps no physics: on a fresh MjData); batched: "
            "stacked copies of the observation; the "
            "last column is a batched row's cost over a single call's (< 1: batching pays). "
            "The joint-space laws (decentralized, `pd_gravity`, `computed_torque`, `robust`) "
            "set `vectorized`: their law runs on all rows at once, the model calls "
            "(`baselines.base.RowDynamics` on an own MjData: ĝ by `Robot.gravity`'s calls, "
            "B̂ q̈ + n̂ by `mj_rne` with q̈ plus the armature's term) row by row; the others run "
            "`control` row by row.",
            "",
            *ctrl_rows,
            "",
            "Batched JointTracking (`cir_gym/vector.py`):",
            "",
            *vec_rows,
            *(
                [
                    "",
                    "Batched PegInHole (`cir_gym/envs/peg_in_hole_vector.py`), MuJoCo threads: "
                    f"{args.nthread or 'all CPUs'} (the last column: 2):",
                    "",
                    *peg_rows,
                ]
                if peg_rows
                else []
            ),
        ]
    )
    print()
    print(body)
    if str(args.out) != "-":
        write_section(args.out, SECTION, body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
