"""AdmittanceContact's batched env against Gymnasium's SyncVectorEnv of the single env.

    python benchmarks/bench_vector_admittance.py [--num-envs 16 64] [--steps 40] [--repeat 3]
                                                 [--randomize]

Env-steps/s of ``--num-envs`` copies of ``cir_gym/AdmittanceContact-v1`` in
:class:`cir_gym.envs.admittance_vector.AdmittanceContactVectorEnv` and in
``gymnasium.vector.SyncVectorEnv`` of ``gymnasium.make`` (SAME_STEP autoreset, as
``cir_gym.make_vec``'s fallback), timed alternately in the same run, best of ``--repeat``
trials of ``--steps`` steps: in process CPU time with one MuJoCo thread (other jobs' time
slices on this shared machine are not counted), and in wall-clock time with 2 MuJoCo threads.

The copies are driven in contact by the course's ``impedance`` controller (as
``cir_gym.scoring.policies`` resolves it; one batched ``predict`` per step, not timed): the
timed steps start after an untimed warm-up of 600 steps (1.2 s; the tool touches the plate at
about 1 s). Both sides play the very same episodes (the batched env equals the single env step
for step).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np

import cir_gym  # noqa: F401  (registers the environments)
from cir_gym.envs.admittance_vector import AdmittanceContactVectorEnv
from cir_gym.scoring.policies import make_policy

ENV_ID = "cir_gym/AdmittanceContact-v1"
WARMUP = 600


def timed_loop(envs: gym.vector.VectorEnv, kwargs: dict, steps: int,
               clock: Callable[[], float]) -> Callable[[], float]:
    """Seconds per env-step (per copy) of ``steps`` steps driven by the impedance controller,
    continuing from the last call (only ``envs.step`` is timed)."""
    policy = make_policy(ENV_ID, "impedance", kwargs, {})
    obs, _ = envs.reset(seed=0)
    state: list = [None]
    start = [np.ones(envs.num_envs, dtype=bool)]

    def step() -> float:
        action, state[0] = policy.predict(obs_now[0], state=state[0], episode_start=start[0])
        t0 = clock()
        obs_now[0], _, term, trunc, _ = envs.step(action)
        elapsed = clock() - t0
        start[0] = term | trunc
        return elapsed

    obs_now = [obs]
    for _ in range(WARMUP):
        step()

    def loop() -> float:
        return sum(step() for _ in range(steps)) / (steps * envs.num_envs)

    return loop


def best_pair(a: Callable[[], float], b: Callable[[], float], repeat: int) -> tuple[float, float]:
    """Best of ``repeat`` alternating trials of two loops."""
    ta, tb = [], []
    for _ in range(repeat):
        ta.append(a())
        tb.append(b())
    return min(ta), min(tb)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--num-envs", type=int, nargs="+", default=[16, 64])
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--randomize", action="store_true", help="unknown stiffness per episode")
    args = p.parse_args()
    kwargs = {"randomize": True} if args.randomize else {}
    print(f"{ENV_ID} {kwargs or ''}: env-steps/s, batched / SyncVectorEnv, same run")
    print("| copies | clock | batched | SyncVectorEnv | ratio |")
    print("|---:|---|---:|---:|---:|")
    for n in args.num_envs:
        sync = gym.vector.SyncVectorEnv(
            [lambda: gym.make(ENV_ID, **kwargs) for _ in range(n)],
            autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
        )
        for label, nthread, clock in (("CPU, 1 thread", 1, time.process_time),
                                      ("wall, 2 threads", 2, time.perf_counter)):
            batched = AdmittanceContactVectorEnv(num_envs=n, nthread=nthread, **kwargs)
            t_b, t_s = best_pair(timed_loop(batched, kwargs, args.steps, clock),
                                 timed_loop(sync, kwargs, args.steps, clock), args.repeat)
            print(f"| {n} | {label} | {1 / t_b:,.0f} | {1 / t_s:,.0f} | {t_s / t_b:.2f} |",
                  flush=True)
            batched.close()
        sync.close()


if __name__ == "__main__":
    main()
