"""The batched agent-ready variants against Gymnasium's SyncVectorEnv of the single variant,
and PPO on them against SB3's DummyVecEnv of the single variant.

    python benchmarks/bench_vector_agent_ready.py [--env cir_gym/AdmittanceContactImpedance-v0]
        [--num-envs 16 64] [--steps 6] [--repeat 2] [--ppo-steps 2048] [--skip ppo]

1. ``throughput``: env-steps/s (policy steps per copy) of ``--num-envs`` copies in the native
   batched env (:mod:`cir_gym.envs.agent_ready_vector`) and in ``gymnasium.vector.
   SyncVectorEnv`` of ``gymnasium.make`` (SAME_STEP autoreset, ``cir_gym.make_vec``'s
   fallback), timed alternately in the same run, best of ``--repeat`` trials of ``--steps``
   policy steps: in process CPU time with one MuJoCo thread (other jobs' time slices on this
   shared machine are not counted), and in wall-clock time with 2 MuJoCo threads. The copies
   are driven in contact: a constant action moves every setpoint down by half the largest
   increment per policy step, so after the untimed warm-up of ``WARMUP`` policy steps the
   tool presses on the plate (AdmittanceContactImpedance: ~50 N once the setpoint offset is
   clamped) or the peg on the block (PegInHoleImpedance); episodes end and are reset as they
   come (both sides play the very same episodes: the batched env equals the single variant
   copy by copy).
2. ``ppo``: SB3 PPO ``learn`` for ``--ppo-steps`` env-steps (``MultiInputPolicy`` on the raw
   Dict observation, n_steps 128 per env, batch 256, 4 epochs; one torch thread, one MuJoCo
   thread) on a DummyVecEnv of 16 single variants and on ``sb3_vec_env`` of the batched env
   with 16 copies, one after the other: env-steps per second of wall and of CPU time.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import gymnasium as gym
import numpy as np
from bench_vector import _per_env_step  # sibling module: the scripts run as files

import cir_gym  # noqa: F401  (registers the environments)
from cir_gym.envs.agent_ready_vector import (
    AdmittanceContactImpedanceVectorEnv,
    PegInHoleImpedanceVectorEnv,
)
from cir_gym.envs.base import make_env
from cir_gym.envs.vector import sb3_vec_env

#: id → its batched class
CLASSES: dict[str, type] = {
    "cir_gym/AdmittanceContactImpedance-v0": AdmittanceContactImpedanceVectorEnv,
    "cir_gym/PegInHoleImpedance-v0": PegInHoleImpedanceVectorEnv,
}
WARMUP = 20  # policy steps before timing (1 s at 20 Hz: the tool is in contact)
PARTS = ("throughput", "ppo")


def pressing(envs: gym.vector.VectorEnv) -> np.ndarray:
    """The constant actions (N, dim): the setpoint down by half the largest increment."""
    a = np.zeros(envs.action_space.shape, dtype=np.float32)
    a[:, 2] = -0.5
    return a


def bench_throughput(env_id: str, counts: list[int], steps: int, repeat: int) -> None:
    """Print env-steps/s of the batched env and SyncVectorEnv, CPU (1 thread) and wall (2)."""
    cls = CLASSES[env_id]
    print(f"{env_id}: env-steps/s (policy steps per copy), batched / SyncVectorEnv, same run")
    print("| copies | clock | batched | SyncVectorEnv | ratio |")
    print("|---:|---|---:|---:|---:|", flush=True)
    for n in counts:
        sync = gym.vector.SyncVectorEnv(
            [lambda: gym.make(env_id) for _ in range(n)],
            autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
        )
        for label, nthread, clock in (("CPU, 1 thread", 1, time.process_time),
                                      ("wall, 2 threads", 2, time.perf_counter)):
            batched = cls(num_envs=n, nthread=nthread)
            loops = []
            for envs in (batched, sync):
                a = pressing(envs)
                envs.reset(seed=0)
                for _ in range(WARMUP):
                    envs.step(a)
                loops.append(_per_env_step(lambda e=envs, a=a: e.step(a), steps, n, clock))
            best = [float("inf")] * 2
            for _ in range(repeat):
                best = [min(b, run()) for b, run in zip(best, loops, strict=True)]
            t_b, t_s = best
            print(f"| {n} | {label} | {1 / t_b:,.0f} | {1 / t_s:,.0f} | {t_s / t_b:.2f} |",
                  flush=True)
            batched.close()
        sync.close()


def bench_ppo(env_id: str, steps: int) -> None:
    """Print PPO env-steps/s (wall and CPU) on DummyVecEnv(16) and the batched env (16)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    torch.set_num_threads(1)
    n = 16

    def dummy() -> Any:
        return DummyVecEnv([lambda: make_env(env_id) for _ in range(n)])

    def batched() -> Any:
        return sb3_vec_env(CLASSES[env_id](num_envs=n, nthread=1))

    print(f"PPO learn, {steps} env-steps, {n} envs x 128 n_steps, one thread each")
    print("| vec env | env-steps/s (wall) | env-steps per CPU s |")
    print("|---|---:|---:|", flush=True)
    rates = []
    for label, make in (("DummyVecEnv of 16 single variants", dummy),
                        ("sb3_vec_env(batched, 16 copies)", batched)):
        venv = make()
        venv.seed(0)
        model = PPO("MultiInputPolicy", venv, n_steps=128, batch_size=256, n_epochs=4, seed=0,
                    device="cpu", verbose=0)
        t0, c0 = time.perf_counter(), time.process_time()
        model.learn(total_timesteps=steps)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        done = model.num_timesteps
        rates.append(done / cpu)
        print(f"| {label} | {done / wall:,.0f} | {done / cpu:,.0f} |", flush=True)
        venv.close()
    print(f"batched / Dummy (CPU): {rates[1] / rates[0]:.2f}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env", default="cir_gym/AdmittanceContactImpedance-v0", choices=CLASSES)
    p.add_argument("--num-envs", type=int, nargs="+", default=[16, 64])
    p.add_argument("--steps", type=int, default=6)
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--ppo-steps", type=int, default=2048)
    p.add_argument("--skip", nargs="*", default=[], choices=PARTS)
    args = p.parse_args()
    if "throughput" not in args.skip:
        bench_throughput(args.env, args.num_envs, args.steps, args.repeat)
    if "ppo" not in args.skip:
        bench_ppo(args.env, args.ppo_steps)


if __name__ == "__main__":
    main()
