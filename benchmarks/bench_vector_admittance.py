"""AdmittanceContact's batched env against Gymnasium's SyncVectorEnv of the single env.

    python benchmarks/bench_vector_admittance.py [--num-envs 16 64] [--steps 40] [--repeat 3]
                                                 [--randomize]

Env-steps/s of ``--num-envs`` copies of ``cir_gym/AdmittanceContact-v1`` in
:class:`cir_gym.envs.admittance_vector.AdmittanceContactVectorEnv` and in
``gymnasium.vector.SyncVectorEnv`` of ``gymnasium.make`` (SAME_STEP autoreset, as
``cir_gym.make_vec``'s fallback), timed alternately in the same run, best of ``--repeat``
trials of ``--steps`` steps: in process CPU time with one MuJoCo thread (other jobs' time
slices on this shared machine are not counted), and in wall-clock time with 2 MuJoCo threads.

The copies are driven in contact: each holds the torque that compensates gravity at the start
pose and pushes the tip down with 15 N (a constant action per copy), so after ~0.3 s every copy
presses on its plate; the timed steps start after an untimed warm-up of 250 steps (0.5 s).
Both sides play the very same episodes (the batched env equals the single env step for step).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np

import cir_gym  # noqa: F401  (registers the environments)
from cir_gym.envs.admittance_scene import SITE, START_Q, tool_robot
from cir_gym.envs.admittance_vector import AdmittanceContactVectorEnv

ENV_ID = "cir_gym/AdmittanceContact-v1"
WARMUP = 250


def pressing_action(torque_limit: np.ndarray) -> np.ndarray:
    """The normalised torque (7,) that holds the start pose against gravity and pushes the tip
    down with 15 N: (g(q₀) + Jᵀ f) / τ_max, f = (0, 0, −15, 0, 0, 0)."""
    robot = tool_robot()
    J = robot.jacobian(robot.site_id(SITE), START_Q)
    wrench = np.array([0.0, 0.0, -15.0, 0.0, 0.0, 0.0])
    return np.clip((robot.gravity(START_Q) + J.T @ wrench) / torque_limit, -1.0, 1.0)


def timed_loop(envs: gym.vector.VectorEnv, actions: np.ndarray, steps: int,
               clock: Callable[[], float]) -> Callable[[], float]:
    """Seconds per env-step (per copy) of ``steps`` steps, continuing from the last call."""
    envs.reset(seed=0)
    for _ in range(WARMUP):
        envs.step(actions)

    def loop() -> float:
        t0 = clock()
        for _ in range(steps):
            envs.step(actions)
        return (clock() - t0) / (steps * envs.num_envs)

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
        a = np.tile(pressing_action(sync.envs[0].unwrapped.torque_limit), (n, 1))
        for label, nthread, clock in (("CPU, 1 thread", 1, time.process_time),
                                      ("wall, 2 threads", 2, time.perf_counter)):
            batched = AdmittanceContactVectorEnv(num_envs=n, nthread=nthread, **kwargs)
            t_b, t_s = best_pair(timed_loop(batched, a, args.steps, clock),
                                 timed_loop(sync, a, args.steps, clock), args.repeat)
            print(f"| {n} | {label} | {1 / t_b:,.0f} | {1 / t_s:,.0f} | {t_s / t_b:.2f} |",
                  flush=True)
            batched.close()
        sync.close()


if __name__ == "__main__":
    main()
