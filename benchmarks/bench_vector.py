"""Batched envs (free and in contact), the batched evaluator, a 100-seed leaderboard estimate
and RL training throughput on the batched contact envs.

    python benchmarks/bench_vector.py [--num-envs 16 64] [--envs ID ...] [--steps 200]
                                      [--repeat 5] [--episodes 100] [--seq-episodes 10]
                                      [--other-episodes 1] [--rl-steps 2048] [--rl-warmup 256]
                                      [--skip ... | --only ...] [--out results/benchmarks.md]

    python benchmarks/bench_vector.py --only residual --out -   # part 5 alone (~2 CPU min)
    python benchmarks/bench_vector.py --only residual_vs --rl-steps 8192 --out -   # part 6

Six parts, written under the heading ``## Vector env`` of ``--out`` (only that section is
replaced; the other sections belong to other scripts):

1. ``throughput``: env-steps/s of each ``--num-envs`` count of copies of every id of
   ``cir_gym.envs.vector.VECTOR_ENVS`` (or ``--envs``) in its native batched env, of the same
   model's raw ``mujoco.batch.Batch`` and of Gymnasium's ``SyncVectorEnv`` of the single env
   (SAME_STEP autoreset, as ``cir_gym.make_vec``'s fallback). Two tables:

   * zero actions, ``max_following_error=None`` where the env has it (resets are not what
     this times; the torque tasks' copies then never touch a surface);
   * in contact, the contact envs of ``CONTACT_DRIVES``: after an untimed warm-up the copies
     press on their surface, driven by the course controller (AdmittanceContact-v2:
     ``impedance``; PegInHole-v2: ``hybrid_force_position``; as ``cir_gym.scoring.policies``
     resolves them, predicted in the loop on all copies at once, outside the timed
     ``step``) or, for the agent-ready variants (which have no course controller), by a
     constant action moving the setpoint down. Episodes end and restart as they come, the
     same on every side (each batched env equals its single env copy for copy). The table
     gives how many copies touch (MuJoCo contacts) when the timing starts.

   RedundantIK-v4 / RedundantIK7-v5 have no ``mj_step``: their batch runs kinematics
   (``Batch.forward`` to the position stage and ``Batch.jac`` at the site per step), and that
   is their "raw" column. The loops are timed alternately, best of ``--repeat`` trials of
   ``--steps`` vector steps (``--steps`` / 8 for SyncVectorEnv), ``env.step`` alone: in
   process CPU time with one MuJoCo thread (other jobs' time slices on this shared machine
   are not counted), and in wall-clock time the batched env with 2 threads against the
   SyncVectorEnv (both inflated by the machine's load).
2. ``evaluator``: ``cir_gym.evaluation.evaluate`` on every leaderboard (variant, policy) pair
   of the batched envs, as ``scripts/leaderboard.py`` runs them (seed 1000 on): batched on
   ``--episodes`` seeds where it batches, sequential on ``--seq-episodes`` seeds, scaled
   linearly to ``--episodes`` (each episode is one independent rollout of the same length:
   the scaling is the measurement's only assumption). The batched run's first
   ``--seq-episodes`` EpisodeResults are checked equal to the sequential ones.
3. ``leaderboard``: every other environment's pairs, ``--other-episodes`` episodes each
   (sequential: they have no batched env), scaled to ``--episodes``; with part 2 this gives
   the CPU time of a full leaderboard at ``--episodes`` seeds per variant, and that time over
   2 workers (the leaderboard's process pool on 2 cores, perfectly balanced: a lower bound on
   its wall time). Not counted: the leaderboard's figures and its page's videos.
4. ``rl``: SB3 PPO and SAC training throughput (env-steps per CPU second of ``learn``:
   rollouts and updates; one torch thread, one MuJoCo thread) on ``RL_ENVS``, the agent-ready
   contact variants: the batched env with 16 copies through ``vec_env: batched``'s adapter
   (``agents.batched.make_batched_vec_env``) against a DummyVecEnv of 16 single envs and
   against one env (a DummyVecEnv of 1), each single env wrapped as ``agents.train``
   wraps it (TaskObservation, Monitor). MlpPolicy on the flat observation of
   ``cir_gym.agents.observation.TaskObservation``. PPO: agents/hyperparams/contact/ppo.yml
   (2048-step rollouts: n_steps 128 × 16 envs, 2048 × 1 env; batch 256, 10 epochs, [64, 64]
   tanh, VecNormalize of observations and rewards). SAC: SB3's defaults (train_freq 1,
   gradient_steps 1: one gradient step of batch 256 per vector step, i.e. per 16 transitions
   with 16 envs and per transition with 1; learning_starts 100; buffer 10⁶) with the same
   [64, 64] nets (ReLU, SB3's SAC default) and VecNormalize of observations, as
   agents/hyperparams/sac.yml. Each run: an untimed ``learn`` of ``--rl-warmup`` env steps
   (PPO: rounded up to one rollout and its update; SAC: past learning_starts), then a timed
   ``learn`` of ``--rl-steps`` more (PPO: whole rollouts).
5. ``residual``: the same timing of residual PPO (:data:`RESIDUAL_RL`: over impedance_spiral
   on PegInHoleImpedance-v0; contact/ppo.yml's entry with its ``residual`` overrides: scale
   0.5, zeroed last actor layer, learning rate 1e-4, log_std_init -2) with 16 envs: the batched
   env under ``agents.batched.BatchedResidualAction`` (the controller predicted once per vector
   step on all copies) against a DummyVecEnv of 16 single envs under
   ``agents.residual.ResidualAction``; the machine's load average is printed with it. Its
   copies reach the block soon (the controller drives them there), so contacts cost more
   physics than a from-scratch agent's early episodes in free space.
6. ``residual_vs``: the same timing of residual PPO over IBVS on VisualServo-v1
   (:data:`RESIDUAL_VS`: the lever agents/hyperparams/levers/vs_residual_logerr_batched.yml,
   its env arguments and IBVS gain, the log-error bonus on both sides; 4096-step rollouts:
   n_steps 256 × 16 envs): the batched env under ``BatchedResidualAction`` (the row-vectorised
   IBVS once per vector step on all copies) against a DummyVecEnv of 16 single envs under
   ``ResidualAction`` (IBVS per env).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import mujoco
import mujoco.batch
import numpy as np
from _sections import write_section  # sibling module: the scripts run as files

import cir_gym
from cir_gym.envs.base import constructor_arguments
from cir_gym.envs.vector import VECTOR_ENVS, native_vector_env
from cir_gym.evaluation import evaluate

SECTION = "## Vector env"
OUT = Path(__file__).parents[1] / "results" / "benchmarks.md"
SEED = 1000  # scripts/leaderboard.py's
PARTS = ("throughput", "evaluator", "leaderboard", "rl", "residual", "residual_vs")

#: ids without dynamics: a step integrates q̇ and runs the kinematics of every copy
KINEMATIC_ENVS = ("cir_gym/RedundantIK-v4", "cir_gym/RedundantIK7-v5")
_POSITION_STAGE = int(mujoco.mjtStage.mjSTAGE_POS)


class ContactDrive(NamedTuple):
    """How the copies of a contact env are brought onto their surface and kept there.

    Attributes:
        controller: the course controller (``cir_gym.scoring.policies`` name) predicted on all
            copies at every step, or None: a constant action, the setpoint moved down by
            ``press`` × its largest increment per policy step (the agent-ready variants).
        press: that fraction, in [0, 1] (without a controller).
        warmup: untimed env steps before the timing starts (the time to contact: each id's
            comment, in seconds of simulated time).
    """

    controller: str | None
    press: float
    warmup: int


#: contact env id → how its copies are driven in contact (the in-contact table)
CONTACT_DRIVES: dict[str, ContactDrive] = {
    # 500 Hz; 1.2 s: the tool rests on the plate from ~0.8 s
    "cir_gym/AdmittanceContact-v2": ContactDrive("impedance", 0.0, 600),
    # 500 Hz; 2 s: the peg rests on the block from ~1.6 s
    "cir_gym/PegInHole-v2": ContactDrive("hybrid_force_position", 0.0, 1000),
    # 20 Hz; 1 s: every tool on the plate from 1 s (half the increment: ~50 N once clamped)
    "cir_gym/AdmittanceContactImpedance-v1": ContactDrive(None, 0.5, 20),
    # 20 Hz; 3 s: 0.2 of the increment (half of it terminates 3 of 5 episodes at 0.7 s);
    # most pegs on the block from 2-4 s
    "cir_gym/PegInHoleImpedance-v0": ContactDrive(None, 0.2, 60),
}


def _cpu() -> float:
    return time.process_time()


# ---------------------------------------------------------------------- 1. throughput
def _env_kwargs(env_id: str) -> dict[str, Any]:
    """``max_following_error=None`` where the env has it (no ends from following errors)."""
    cls = VECTOR_ENVS[env_id]
    if "max_following_error" in constructor_arguments(cls.env_class):
        return {"max_following_error": None}
    return {}


def _sync_vector_env(env_id: str, num_envs: int, kwargs: dict[str, Any]) -> gym.vector.VectorEnv:
    """Gymnasium's SyncVectorEnv of ``num_envs`` single envs, SAME_STEP autoreset (as the
    batched envs and ``cir_gym.make_vec``'s fallback)."""
    return gym.make_vec(
        env_id,
        num_envs=num_envs,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": gym.vector.AutoresetMode.SAME_STEP},
        **kwargs,
    )


def _action_source(
    env_id: str, envs: gym.vector.VectorEnv, drive: ContactDrive | None
) -> Callable[[dict, np.ndarray], np.ndarray]:
    """``(obs, episode_start) ↦ actions (N, dim)`` for ``envs``: zeros without a drive, else
    the drive's controller (its own recurrent state) or its constant pressing action."""
    actions = np.zeros(envs.action_space.shape, dtype=np.float32)
    if drive is None:
        return lambda obs, start: actions
    if drive.controller is None:
        actions[:, 2] = -drive.press  # the z increment of the setpoint (m, scaled to [-1, 1])
        return lambda obs, start: actions
    from cir_gym.scoring.policies import make_policy

    policy = make_policy(env_id, drive.controller, {}, {})
    state: list[Any] = [None]

    def act(obs: dict, start: np.ndarray) -> np.ndarray:
        action, state[0] = policy.predict(obs, state=state[0], episode_start=start)
        return action

    return act


class DrivenEnvs:
    """A vector env stepped from its current observation by an action source; only
    ``envs.step`` is timed.

    Args:
        envs: a Gymnasium vector env (batched or SyncVectorEnv), reset here with seed 0.
        act: ``(obs, episode_start) ↦ actions`` (:func:`_action_source`), not timed.
    """

    def __init__(self, envs: gym.vector.VectorEnv, act: Callable[[dict, np.ndarray], np.ndarray]):
        self.envs = envs
        self.act = act
        self.obs, _ = envs.reset(seed=0)
        self.start = np.ones(envs.num_envs, dtype=bool)

    def advance(self, steps: int, clock: Callable[[], float] = _cpu) -> float:
        """Seconds of ``envs.step`` over ``steps`` vector steps (the actions not counted)."""
        spent = 0.0
        for _ in range(steps):
            action = self.act(self.obs, self.start)
            t0 = clock()
            self.obs, _, terminated, truncated, _ = self.envs.step(action)
            spent += clock() - t0
            self.start = terminated | truncated
        return spent

    def run(self, steps: int, clock: Callable[[], float] = _cpu) -> float:
        """Seconds of ``envs.step`` per env-step (per copy) over ``steps`` ≥ 1 vector steps."""
        return self.advance(steps, clock) / (steps * self.envs.num_envs)


def _raw_trial(env_id: str, vec: Any, steps: int) -> Callable[[], float]:
    """A trial of the batched env's bare ``mujoco.batch.Batch`` (1 thread) from ``vec``'s
    current state (its last controls held): seconds per env-step (CPU) of ``steps`` calls of
    ``Batch.step(nstep=frame_skip)``, or for ``KINEMATIC_ENVS`` of ``Batch.forward`` to the
    position stage and ``Batch.jac`` at the end-effector site."""
    t = vec.template
    raw = mujoco.batch.Batch(t.model, nsim=vec.num_envs, nthread=1)
    if env_id in KINEMATIC_ENVS:
        site = t.kin.site_id
        body = int(t.model.site_bodyid[site])
        site_xpos = raw.bind("site_xpos")

        def call() -> None:
            raw.forward(stage=_POSITION_STAGE)
            raw.jac(body, site_xpos[:, site])
    else:

        def call() -> None:
            raw.step(nstep=t.frame_skip)

    def trial() -> float:
        raw.state[:] = vec.batch.state
        t0 = _cpu()
        for _ in range(steps):
            call()
        return (_cpu() - t0) / (steps * vec.num_envs)

    return trial


def _copies_touching(vec: Any) -> int:
    """Copies of a batched env with at least one MuJoCo contact at their current state."""
    touching = 0
    for i in range(vec.num_envs):
        data = vec.batch.get_data(i)
        mujoco.mj_forward(vec.batch.get_model(i), data)
        touching += data.ncon > 0
    return touching


def _best_rates(trials: dict[str, Callable[[], float]], repeat: int) -> dict[str, float]:
    """Env-steps/s per trial name: the trials run alternately ``repeat`` times, best kept."""
    best = dict.fromkeys(trials, math.inf)
    for _ in range(repeat):
        for key, run in trials.items():
            best[key] = min(best[key], run())
    return {key: 1.0 / sec for key, sec in best.items()}


def _measure(
    env_id: str, num_envs: int, steps: int, repeat: int, drive: ContactDrive | None
) -> tuple[dict[str, float], int]:
    """(env-steps/s of the five loops, copies touching at the start of the timing) of
    ``num_envs`` copies of ``env_id`` driven by ``drive`` (None: zero actions)."""
    kw = _env_kwargs(env_id)
    cls = VECTOR_ENVS[env_id]
    made = {
        "vec": cls(num_envs, nthread=1, **kw),
        "vec2": cls(num_envs, nthread=2, **kw),
        "sync": _sync_vector_env(env_id, num_envs, kw),
    }
    driven = {k: DrivenEnvs(e, _action_source(env_id, e, drive)) for k, e in made.items()}
    for d in driven.values():
        d.advance(drive.warmup if drive else 0)
    touching = _copies_touching(made["vec"])
    n_sync = max(1, steps // 8)
    wall = time.perf_counter
    rates = _best_rates(
        {
            "vec": lambda: driven["vec"].run(steps),
            "raw": _raw_trial(env_id, made["vec"], steps),
            "sync": lambda: driven["sync"].run(n_sync),
            "wall2": lambda: driven["vec2"].run(steps, wall),
            "sync_wall": lambda: driven["sync"].run(n_sync, wall),
        },
        repeat,
    )
    for e in made.values():
        e.close()
    print(
        f"  {env_id} x{num_envs}{' in contact' if drive else ''}: "
        + ", ".join(f"{k} {v:,.0f}/s" for k, v in rates.items()),
        flush=True,
    )
    return rates, touching


def _rate_cells(rate: dict[str, float]) -> str:
    """The table's rate and ratio cells (Sync, batched, ratio, raw, ratio, wall ×3)."""
    return (
        f"{rate['sync']:,.0f} | {rate['vec']:,.0f} | {rate['vec'] / rate['sync']:.1f} | "
        f"{rate['raw']:,.0f} | {rate['vec'] / rate['raw']:.2f} | {rate['sync_wall']:,.0f} | "
        f"{rate['wall2']:,.0f} | {rate['wall2'] / rate['sync_wall']:.1f}"
    )


_RATE_HEADER = (
    "SyncVectorEnv (CPU) | batched, 1 thread (CPU) | batched / Sync | raw batch (CPU) "
    "| batched / raw | SyncVectorEnv (wall) | batched, 2 threads (wall) "
    "| batched 2 threads / Sync (wall) |"
)
_RATE_RULE = "---:|---:|---:|---:|---:|---:|---:|---:|"


def bench_throughput(
    counts: list[int], steps: int, repeat: int, env_ids: list[str] | None = None
) -> list[str]:
    """Rows of env-steps/s per (env, copies) with zero actions: the batched env (1 thread
    CPU, 2 threads wall) vs its raw batch and vs SyncVectorEnv (CPU and wall)."""
    rows = [
        "Zero actions, `max_following_error=None` where the env has it. Raw batch: "
        "`Batch.step(nstep=frame_skip)`; RedundantIK-v4 / RedundantIK7-v5 have no `mj_step` "
        "(their batch runs kinematics: `Batch.forward` to the position stage and `Batch.jac` "
        "at the site per step, their raw column). The raw batch starts each trial from the "
        "batched env's state and never ends an episode: where the env ends them in the trials "
        "(PegInHole-v2 at zero torque: the peg drops onto the block and every copy "
        "terminates about every 20 steps) it steps contact states the env does not, and is "
        "no floor.",
        "",
        f"| env | copies | {_RATE_HEADER}",
        f"|---|---:|{_RATE_RULE}",
    ]
    for env_id in env_ids or list(VECTOR_ENVS):
        for num_envs in counts:
            rate, _ = _measure(env_id, num_envs, steps, repeat, None)
            rows.append(f"| {env_id} | {num_envs} | {_rate_cells(rate)} |")
    return rows


def _drive_label(drive: ContactDrive) -> str:
    """How the copies are driven, for the table."""
    how = (
        f"`{drive.controller}`"
        if drive.controller
        else f"setpoint down {drive.press:g} × max increment"
    )
    return f"{how}, {drive.warmup} steps warm-up"


def bench_in_contact(
    counts: list[int], steps: int, repeat: int, env_ids: list[str] | None = None
) -> list[str]:
    """Rows of env-steps/s per (contact env, copies) in contact (``CONTACT_DRIVES``), the
    same loops as :func:`bench_throughput`'s."""
    rows = [
        "In contact: the copies driven onto their surface (course controller predicted in the "
        "loop, not timed; the agent-ready variants, which have no course controller, by a "
        "constant pressing action) after an untimed warm-up; touching: copies with a MuJoCo "
        "contact when the timing starts. Raw batch: from the batched env's state, its last "
        "torques held over the whole step (the agent-ready variants' impedance loop updates "
        "them every 2 ms of their 50-ms step: held, they press harder, so raw is no floor "
        "there).",
        "",
        f"| env | copies | driven by | touching | {_RATE_HEADER}",
        f"|---|---:|---|---:|{_RATE_RULE}",
    ]
    for env_id in env_ids or list(VECTOR_ENVS):
        drive = CONTACT_DRIVES.get(env_id)
        if drive is None:
            continue
        for num_envs in counts:
            rate, touching = _measure(env_id, num_envs, steps, repeat, drive)
            rows.append(
                f"| {env_id} | {num_envs} | {_drive_label(drive)} | {touching}/{num_envs} | "
                f"{_rate_cells(rate)} |"
            )
    return rows


# ---------------------------------------------------------------------- 2./3. evaluation
def _episode_fields(result: Any) -> list[tuple]:
    return [
        (e.seed, e.length, e.success, e.diverged, e.terminated, e.metrics, e.episode_return)
        for e in result.episodes
    ]


def _timed_evaluate(
    env_id: str, kwargs: dict, policy_name: str, episodes: int, batched: bool
) -> tuple[Any, float]:
    """(result, CPU seconds) of one leaderboard job: the policy built, then evaluated."""
    from cir_gym.scoring.policies import make_policy

    t0 = _cpu()
    policy = make_policy(env_id, policy_name, kwargs, {})
    result = evaluate(
        policy,
        env_id,
        episodes,
        SEED,
        policy_name=policy_name,
        batched=None if batched else False,
        **kwargs,
    )
    return result, _cpu() - t0


def bench_evaluator(episodes: int, seq_episodes: int) -> tuple[list[str], float, float]:
    """Per (variant, policy) of the batched envs: batched vs sequential CPU time at
    ``episodes`` seeds. Returns (rows, CPU s of these jobs now, CPU s sequentially)."""
    from cir_gym.evaluation import batches_exactly
    from cir_gym.scoring.leaderboard import jobs_for
    from cir_gym.scoring.policies import make_policy

    scale = episodes / seq_episodes
    rows = [
        f"`evaluate` per leaderboard job at {episodes} seeds ({SEED}…), process CPU time. "
        f"Sequential: {seq_episodes} seeds timed, ×{scale:g}. Batched: all {episodes} seeds "
        "timed, one group (one `mujoco.batch.Batch`, 1 thread); its first "
        f"{seq_episodes} EpisodeResults checked equal to the sequential ones.",
        "",
        "| env | variant | policy | sequential (s, scaled) | batched (s) | speed-up | identical |",
        "|---|---|---|---:|---:|---:|---|",
    ]
    total_now = total_seq = 0.0
    by_kind: dict[str, list[float]] = {}  # kind of job → [sequential s, now s, jobs]
    for env_id in VECTOR_ENVS:
        for _, variant, kwargs, name in jobs_for(env_id):
            seq, t_seq = _timed_evaluate(env_id, kwargs, name, seq_episodes, batched=False)
            t_seq *= scale
            policy = make_policy(env_id, name, kwargs, {})
            can = native_vector_env(env_id, kwargs) is not None and batches_exactly(policy)
            if can:
                fast, t_fast = _timed_evaluate(env_id, kwargs, name, episodes, batched=True)
                fast.episodes = fast.episodes[:seq_episodes]
                same = "yes" if _episode_fields(fast) == _episode_fields(seq) else "**NO**"
                cells = f"{t_fast:.1f} | {t_seq / t_fast:.1f} | {same}"
            else:
                t_fast = t_seq
                why = "not batchable" if native_vector_env(env_id, kwargs) is None else "agent"
                cells = f"– (sequential: {why}) | 1.0 | –"
            total_now += t_fast
            total_seq += t_seq
            kind = (
                "batched controllers"
                if can
                else "agents (sequential)"
                if name.startswith("agent:")
                else "controllers without a batched env (sequential)"
            )
            acc = by_kind.setdefault(kind, [0.0, 0.0, 0])
            acc[0], acc[1], acc[2] = acc[0] + t_seq, acc[1] + t_fast, acc[2] + 1
            print(f"  {env_id} {variant} {name}: seq {t_seq:.1f} s, now {t_fast:.1f} s", flush=True)
            rows.append(f"| {env_id.split('/')[-1]} | {variant} | {name} | {t_seq:.1f} | {cells} |")
    rows += [
        "",
        f"These {len(rows) - 4} jobs: {total_seq:.0f} CPU s sequential → "
        f"{total_now:.0f} CPU s with the batched evaluator ({total_seq / total_now:.1f}×): "
        + "; ".join(
            f"{kind} ({int(n)} jobs) {seq:.0f} → {now:.0f} s"
            for kind, (seq, now, n) in by_kind.items()
        )
        + ".",
    ]
    return rows, total_now, total_seq


def bench_other_envs(episodes: int, other_episodes: int) -> tuple[list[str], float]:
    """CPU seconds of every other env's leaderboard jobs, scaled to ``episodes``."""
    from cir_gym.scoring.leaderboard import jobs_for

    scale = episodes / other_episodes
    per_env: dict[str, float] = {}
    for env_id in cir_gym.ENVIRONMENTS:
        if env_id in VECTOR_ENVS:
            continue
        for _, variant, kwargs, name in jobs_for(env_id):
            _, t = _timed_evaluate(env_id, kwargs, name, other_episodes, batched=False)
            per_env[env_id] = per_env.get(env_id, 0.0) + t * scale
            print(f"  {env_id} {variant} {name}: {t:.1f} s for {other_episodes}", flush=True)
    rows = [
        f"| {env_id.split('/')[-1]} | {len(jobs_for(env_id))} | {sec:.0f} |"
        for env_id, sec in per_env.items()
    ]
    return rows, sum(per_env.values())


# ---------------------------------------------------------------------- 4. RL training
#: the agent-ready contact variants trained with vec_env: batched (agents/hyperparams/contact)
RL_ENVS = ("cir_gym/PegInHoleImpedance-v0", "cir_gym/AdmittanceContactImpedance-v1")
CONTACT_PPO = Path(__file__).parents[1] / "agents" / "hyperparams" / "contact" / "ppo.yml"
ROLLOUT = 2048  # PPO env steps per rollout: ppo.yml's n_steps 128 × n_envs 16
RL_COPIES = 16
LEVERS = Path(__file__).parents[1] / "agents" / "hyperparams" / "levers"


class ResidualCase(NamedTuple):
    """A residual agent whose training throughput part 5 or 6 times.

    Attributes:
        env_id: the environment.
        controller: the course controller under the residual.
        hyperparams: the PPO entry's file (its ``residual`` overrides applied).
        env_kwargs: the environment's arguments.
        controller_kwargs: the controller's gains.
    """

    env_id: str
    controller: str
    hyperparams: Path
    env_kwargs: dict[str, Any]
    controller_kwargs: dict[str, Any]


#: part 5: residual PPO over impedance_spiral on PegInHoleImpedance-v0 (contact/ppo.yml)
RESIDUAL_RL = ResidualCase("cir_gym/PegInHoleImpedance-v0", "impedance_spiral", CONTACT_PPO,
                           {}, {})
#: part 6: the VisualServo-v1 lever "log-error bonus on the rotation family" (IBVS at the gain
#: tuned on the default family), as its header's train command runs it
RESIDUAL_VS = ResidualCase("cir_gym/VisualServo-v1", "ibvs",
                           LEVERS / "vs_residual_logerr_batched.yml",
                           {"start_rotation": (0.3, math.pi)}, {"gain": 0.6058598995030436})


def _observation_layout(env_id: str, hp: dict[str, Any],
                        env_kwargs: dict[str, Any] | None = None) -> Any:
    """The flat observation (TaskObservation's layout) of ``env_id`` under ``hp``."""
    from cir_gym.agents.hyperparameters import observation_options
    from cir_gym.agents.observation import ObservationLayout

    probe = gym.make(env_id, **(env_kwargs or {}))
    layout = ObservationLayout.from_space(probe.observation_space, **observation_options(hp))
    layout.bind(probe)
    probe.close()
    return layout


def _rl_vec_envs(
    env_id: str,
    layout: Any,
    residual: str | None = None,
    scale: Any = None,
    env_kwargs: dict[str, Any] | None = None,
    controller_kwargs: dict[str, Any] | None = None,
    log_error: dict[str, float] | None = None,
) -> list[tuple[str, int, Callable[[], Any]]]:
    """(label, n_envs, ``() ↦ SB3 VecEnv``) of the three sides, seeded 0, on ``env_kwargs``;
    with ``residual`` (a course controller's name, its ``controller_kwargs``) the agent's
    action is the residual of ``scale`` on it; ``log_error``: the training-only log-error
    bonus on both sides."""
    from cir_gym.agents.batched import make_batched_vec_env
    from cir_gym.agents.train import EnvFactory
    from stable_baselines3.common.vec_env import DummyVecEnv

    kw = env_kwargs or {}
    factory = EnvFactory(env_id, kw, layout, residual, scale, controller_kwargs,
                         log_error=log_error)

    def dummy(n: int) -> Any:
        venv = DummyVecEnv([factory] * n)
        venv.seed(0)
        return venv

    return [
        (
            f"batched, {RL_COPIES} copies",
            RL_COPIES,
            lambda: make_batched_vec_env(
                env_id, kw, layout, RL_COPIES, 0, log_error=log_error, residual=residual,
                scale=scale, controller_kwargs=controller_kwargs,
            ),
        ),
        (f"DummyVecEnv of {RL_COPIES}", RL_COPIES, lambda: dummy(RL_COPIES)),
        ("1 env", 1, lambda: dummy(1)),
    ]


def _rl_model(algo: str, venv: Any, n_envs: int, hp: dict[str, Any], rollout: int = ROLLOUT
              ) -> Any:
    """The SB3 model of ``algo`` ("ppo": ``hp``, e.g. contact/ppo.yml's entry, with n_steps
    keeping ``rollout`` env steps per rollout; "sac": SB3's defaults and [64, 64] nets) on
    ``venv`` wrapped in VecNormalize."""
    import torch
    from cir_gym.agents.hyperparameters import TRAINING_KEYS, resolve_policy_kwargs
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import VecNormalize

    if algo == "ppo":
        kwargs = {k: v for k, v in hp.items() if k not in TRAINING_KEYS}
        kwargs["n_steps"] = rollout // n_envs
        policy_kwargs = resolve_policy_kwargs(hp["policy_kwargs"])
        venv = VecNormalize(venv, gamma=kwargs["gamma"], **hp["normalize"])
        cls = PPO
    elif algo == "sac":
        kwargs = {}
        policy_kwargs = {"net_arch": [64, 64], "activation_fn": torch.nn.ReLU}
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
        cls = SAC
    else:
        raise ValueError(f"algo must be 'ppo' or 'sac', got {algo!r}")
    return cls(
        "MlpPolicy", venv, seed=0, device="cpu", verbose=0, policy_kwargs=policy_kwargs, **kwargs
    )


def _gradient_steps(model: Any) -> int:
    """Gradient steps taken so far (PPO: epochs × minibatches per rollout)."""
    from stable_baselines3 import PPO

    if isinstance(model, PPO):
        rollout = model.n_steps * model.n_envs
        return model._n_updates * math.ceil(rollout / model.batch_size)
    return model._n_updates


class LearnTiming(NamedTuple):
    """One timed ``learn``: ``env_steps`` transitions and ``gradient_steps`` in ``cpu_s``
    seconds of process CPU time and ``wall_s`` of wall-clock time."""

    env_steps: int
    gradient_steps: int
    cpu_s: float
    wall_s: float


def _timed_learn(model: Any, warmup: int, steps: int) -> LearnTiming:
    """An untimed ``learn(warmup)``, then ``learn(steps)`` timed (continuing it)."""
    model.learn(total_timesteps=warmup)
    n0, g0 = model.num_timesteps, _gradient_steps(model)
    c0, w0 = _cpu(), time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    return LearnTiming(
        model.num_timesteps - n0, _gradient_steps(model) - g0, _cpu() - c0, time.perf_counter() - w0
    )


def _timed_sides(
    what: str,
    sides: list[tuple[str, int, Callable[[], Any]]],
    model_of: Callable[[Any, int], Any],
    warmup: int,
    steps: int,
) -> dict[str, LearnTiming]:
    """Side label → :func:`_timed_learn` of ``model_of(venv, n_envs)`` on each side, one after
    the other (printed as ``what``)."""
    timings = {}
    for label, n, make in sides:
        model = model_of(make(), n)
        timings[label] = t = _timed_learn(model, warmup, steps)
        model.get_env().close()
        print(
            f"  {what} {label}: {t.env_steps / t.cpu_s:,.1f} per CPU s, "
            f"{t.env_steps / t.wall_s:,.1f}/s wall",
            flush=True,
        )
    return timings


def bench_rl(steps: int, warmup: int) -> list[str]:
    """PPO and SAC env-steps per CPU second on each of ``RL_ENVS``: the batched env (16
    copies, ``vec_env: batched``'s adapter) vs DummyVecEnv of 16 single envs vs 1 env."""
    import torch
    from cir_gym.agents.hyperparameters import load_hyperparams

    torch.set_num_threads(1)
    rows = [
        f"`learn` after an untimed warm-up of {warmup} env steps (PPO: rounded up to one "
        f"{ROLLOUT}-step rollout and its update; SAC: past learning_starts 100), timed over "
        f"{steps} more (PPO: whole {ROLLOUT}-step rollouts with their 10 epochs of "
        "minibatches of 256); one torch thread, one MuJoCo thread; the sides one after the "
        "other. PPO: agents/hyperparams/contact/ppo.yml ([64, 64] tanh, n_steps 128 × 16 "
        f"envs, {ROLLOUT} × 1 env). SAC: SB3's defaults, train_freq 1 and gradient_steps 1 "
        "(one gradient step of batch 256 per *vector* step: per 16 transitions with 16 "
        "envs, per transition with 1 env), [64, 64] ReLU, VecNormalize of observations. "
        "Batched: `agents.batched.make_batched_vec_env` (what `vec_env: batched` trains on); "
        "DummyVecEnv and 1 env: `agents.train.EnvFactory` (TaskObservation, Monitor).",
        "",
        "| env | algorithm | vec env | env steps timed | gradient steps | env-steps per "
        "CPU s | vs 1 env | vs DummyVecEnv | env-steps/s (wall) |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for env_id in RL_ENVS:
        hp = load_hyperparams("ppo", env_id, path=CONTACT_PPO)
        sides = _rl_vec_envs(env_id, _observation_layout(env_id, hp))
        for algo in ("ppo", "sac"):
            timings = _timed_sides(
                f"{env_id} {algo}",
                sides,
                lambda venv, n, algo=algo, hp=hp: _rl_model(algo, venv, n, hp),
                warmup,
                steps,
            )
            rate = {k: t.env_steps / t.cpu_s for k, t in timings.items()}
            one, dummy = rate["1 env"], rate[f"DummyVecEnv of {RL_COPIES}"]
            rows += [
                f"| {env_id.split('/')[-1]} | {algo.upper()} | {label} | {t.env_steps:,} | "
                f"{t.gradient_steps:,} | {rate[label]:,.0f} | {rate[label] / one:.1f} | "
                f"{rate[label] / dummy:.1f} | {t.env_steps / t.wall_s:,.0f} |"
                for label, t in timings.items()
            ]
    return rows


def bench_rl_residual(steps: int, warmup: int, case: ResidualCase = RESIDUAL_RL) -> list[str]:
    """Residual PPO's env-steps per CPU second over ``case``'s controller: the batched env
    under ``BatchedResidualAction`` (16 copies) vs a DummyVecEnv of 16 single envs under
    ``ResidualAction`` (the case's PPO entry with its ``residual`` overrides, its rollout
    length, its log-error bonus on both sides)."""
    import torch
    from cir_gym.agents.hyperparameters import load_hyperparams
    from cir_gym.agents.shaping import check_log_error_bonus
    from cir_gym.agents.train import zero_action_layer

    torch.set_num_threads(1)
    env_id, controller = case.env_id, case.controller
    hp = load_hyperparams("ppo", env_id, residual=True, path=case.hyperparams)
    scale = hp.pop("residual_scale")
    bonus = hp.get("log_error_bonus")
    log_error = check_log_error_bonus(bonus) if bonus is not None else None
    rollout = int(hp["n_steps"]) * RL_COPIES

    def model_of(venv: Any, n: int) -> Any:
        model = _rl_model("ppo", venv, n, hp, rollout)
        if hp.get("zero_init_action", False):
            zero_action_layer(model)
        return model

    layout = _observation_layout(env_id, hp, case.env_kwargs)
    sides = [
        side
        for side in _rl_vec_envs(env_id, layout, controller, scale, case.env_kwargs,
                                 case.controller_kwargs, log_error)
        if side[1] == RL_COPIES
    ]
    load_before = os.getloadavg()[0]
    timings = _timed_sides(f"{env_id} residual ppo", sides, model_of, warmup, steps)
    load_after = os.getloadavg()[0]
    rate = {k: t.env_steps / t.cpu_s for k, t in timings.items()}
    dummy = rate[f"DummyVecEnv of {RL_COPIES}"]
    source = case.hyperparams.relative_to(Path(__file__).parents[1])
    setting = "".join(
        f"; {what} {kw}" for what, kw in (("env arguments", case.env_kwargs),
                                           (f"{controller} gains", case.controller_kwargs),
                                           ("log-error bonus (training only)", log_error))
        if kw
    )
    return [
        f"Residual PPO over `{controller}` on {env_id.split('/')[-1]} ({source} with its "
        f"`residual` overrides: scale {scale}, zeroed last actor layer, learning rate "
        f"{hp['learning_rate']}{setting}), {RL_COPIES} envs: `learn` after an untimed warm-up "
        f"of {warmup} env steps (rounded up to one {rollout}-step rollout and its update), "
        f"timed over {steps} more (whole rollouts); one torch thread, one MuJoCo thread; the "
        "sides one after the other. Batched: `make_batched_vec_env(..., residual=...)` "
        "(`BatchedResidualAction`: the controller predicted once per vector step on all "
        "copies); DummyVecEnv: `EnvFactory` with `ResidualAction` per env. Load average "
        f"(1 min) {load_before:.1f} at the start, {load_after:.1f} at the end on 2 cores.",
        "",
        "| env | agent | vec env | env steps timed | gradient steps | env-steps per CPU s | "
        "vs DummyVecEnv | env-steps/s (wall) |",
        "|---|---|---|---:|---:|---:|---:|---:|",
        *(
            f"| {env_id.split('/')[-1]} | residual PPO ({controller}) | {label} | "
            f"{t.env_steps:,} | {t.gradient_steps:,} | {rate[label]:,.0f} | "
            f"{rate[label] / dummy:.1f} | {t.env_steps / t.wall_s:,.0f} |"
            for label, t in timings.items()
        ),
    ]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument(
        "--num-envs", type=int, nargs="+", default=[16, 64], help="copies (throughput part)"
    )
    p.add_argument(
        "--envs", nargs="*", default=None, help="ids of the throughput part (default: all)"
    )
    p.add_argument("--steps", type=int, default=200, help="vector steps per timed trial")
    p.add_argument("--repeat", type=int, default=5, help="trials; the best is kept")
    p.add_argument("--episodes", type=int, default=100, help="seeds per leaderboard variant")
    p.add_argument("--seq-episodes", type=int, default=10, help="seeds timed sequentially")
    p.add_argument(
        "--other-episodes",
        type=int,
        default=1,
        help="seeds timed per job of the envs without a batched env",
    )
    p.add_argument("--rl-steps", type=int, default=ROLLOUT, help="env steps timed per RL run")
    p.add_argument("--rl-warmup", type=int, default=256, help="untimed env steps before them")
    parts = p.add_mutually_exclusive_group()
    parts.add_argument("--skip", nargs="*", default=[], choices=PARTS, help="parts to leave out")
    parts.add_argument(
        "--only", nargs="+", choices=PARTS, help="the parts to run (the others are skipped)"
    )
    p.add_argument("--out", type=Path, default=OUT, help="markdown file ('-' for none)")
    args = p.parse_args(argv)
    if args.only:
        args.skip = [part for part in PARTS if part not in args.only]
    unknown = sorted(set(args.envs or ()) - set(VECTOR_ENVS))
    if unknown:
        p.error(f"--envs: no batched env for {unknown}; allowed: {sorted(VECTOR_ENVS)}")
    warnings.filterwarnings("ignore")
    body = [
        f"`python benchmarks/bench_vector.py{''.join(' ' + a for a in argv or sys.argv[1:])}` "
        f"(mujoco {mujoco.__version__}, gymnasium "
        f"{gym.__version__}; 2 cores shared with other jobs: only ratios measured side by "
        "side mean something; CPU time counts this process only).",
        "",
    ]
    t_batched_envs = t_seq_envs = t_other = None
    if "throughput" not in args.skip:
        print("throughput:", flush=True)
        body += [
            "### Batched env throughput",
            "",
            "Env-steps/s (per copy; the agent-ready variants: policy steps). Best of the "
            "trials, the loops timed alternately, `env.step` alone. CPU: process time, 1 "
            "MuJoCo thread. Wall: the batched env with 2 threads against the SyncVectorEnv "
            "(SAME_STEP autoreset), in the same run (the machine's load inflates both).",
            "",
            *bench_throughput(args.num_envs, args.steps, args.repeat, args.envs),
            "",
            *bench_in_contact(args.num_envs, args.steps, args.repeat, args.envs),
            "",
        ]
    if "evaluator" not in args.skip:
        print("evaluator:", flush=True)
        rows, t_batched_envs, t_seq_envs = bench_evaluator(args.episodes, args.seq_episodes)
        body += ["### Batched evaluator", "", *rows, ""]
    if "leaderboard" not in args.skip:
        print("leaderboard (other envs):", flush=True)
        rows, t_other = bench_other_envs(args.episodes, args.other_episodes)
        body += [
            f"### Full leaderboard at {args.episodes} seeds per variant (estimate)",
            "",
            f"The envs without a batched env, sequential: {args.other_episodes} episode(s) per "
            f"job timed (policy and env construction included, so scaled ×"
            f"{args.episodes / args.other_episodes:g} with the episodes: an overestimate by "
            "the construction time, ≲ 1 s per job).",
            "",
            f"| env | jobs | CPU s at {args.episodes} seeds |",
            "|---|---:|---:|",
            *rows,
            "",
        ]
        if t_batched_envs is not None:
            now = t_batched_envs + t_other
            before = t_seq_envs + t_other
            body += [
                f"All {len(cir_gym.ENVIRONMENTS)} envs at {args.episodes} seeds per variant: "
                f"{now / 60:.0f} CPU min with the batched evaluator (the envs of "
                f"VECTOR_ENVS {t_batched_envs / 60:.0f}, the others "
                f"{t_other / 60:.0f}), {before / 60:.0f} CPU min all sequential; on the "
                f"leaderboard's 2 workers at best {now / 120:.0f} min of wall time "
                f"(perfect balance, an unloaded machine; figures and videos not counted). "
                f"Target: 10 min.",
                "",
            ]
    for part, title, bench in (
        ("rl", "RL training throughput on the batched contact envs", bench_rl),
        (
            "residual",
            "Residual RL training throughput on the batched contact env",
            bench_rl_residual,
        ),
        (
            "residual_vs",
            "Residual RL training throughput on the batched VisualServo env",
            lambda steps, warmup: bench_rl_residual(steps, warmup, RESIDUAL_VS),
        ),
    ):
        if part not in args.skip:
            print(f"{part}:", flush=True)
            body += [f"### {title}", "", *bench(args.rl_steps, args.rl_warmup), ""]
    text = "\n".join(body)
    print()
    print(text)
    if str(args.out) != "-":
        write_section(args.out, SECTION, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
