"""CPU cost of off-policy training on JointTracking-v2: SB3 SAC/TQC vs SBX (JAX) SAC, beside PPO.

    python scripts/research/bench_offpolicy.py [--steps 2000] \
        [--out results/agents/offpolicy_bench.md]

Issue 20 asks whether SBX (Stable-Baselines3's API on JAX) makes off-policy training fast
enough on these CPUs. Each algorithm trains on the same single JointTracking-v2 env (gravity
feature, flat observation, ``agents.train.EnvFactory``) with one gradient step of batch 256 per
environment step (replay ratio 1, the field's default for SAC), 256×256 networks, after a
warm-up of 1000 steps (``learning_starts``) plus 200 timed-out steps for JIT compilation; the
next ``--steps`` steps are timed in **CPU seconds of this process** (``time.process_time``,
all its threads), so the figure is a per-core cost even on a loaded machine. PPO
(``agents/hyperparams/ppo.yml``'s JointTracking-v2 settings, 16 envs) is timed the same way.
Torch and XLA are limited to one thread. Missing packages (sb3-contrib, sbx-rl) are reported
as such, not guessed.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false "
                      "intra_op_parallelism_threads=1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

ENV = "cir_gym/JointTracking-v2"


def _env(n: int = 1):
    import gymnasium as gym
    from cir_gym.agents.observation import ObservationLayout
    from cir_gym.agents.train import EnvFactory
    from stable_baselines3.common.vec_env import DummyVecEnv

    probe = gym.make(ENV)
    layout = ObservationLayout.from_space(probe.observation_space, features=["gravity"])
    return DummyVecEnv([EnvFactory(ENV, {}, layout)] * n)


def _off_policy(cls, steps: int, **extra) -> float:
    """Environment steps per CPU-second of ``cls`` at one gradient step per env step."""
    model = cls("MlpPolicy", _env(), learning_starts=1000, batch_size=256, train_freq=1,
                gradient_steps=1, buffer_size=100_000, seed=0, verbose=0,
                policy_kwargs={"net_arch": [256, 256]}, **extra)
    model.learn(1200)  # warm-up + JIT compilation (SBX) outside the timing
    t0 = time.process_time()
    model.learn(steps, reset_num_timesteps=False)
    return steps / (time.process_time() - t0)


def _ppo(steps: int) -> float:
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", _env(16), n_steps=128, batch_size=1024, n_epochs=10, gamma=0.98,
                gae_lambda=1.0, seed=0, verbose=0, device="cpu",
                policy_kwargs={"net_arch": [128, 128], "log_std_init": -2.0})
    model.learn(2048)
    t0 = time.process_time()
    model.learn(steps, reset_num_timesteps=False)
    return steps / (time.process_time() - t0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=2000, help="timed environment steps")
    p.add_argument("--out", default="results/agents/offpolicy_bench.md")
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    rows: list[tuple[str, str]] = []

    def run(label: str, fn) -> None:
        try:
            rate = fn()
            rows.append((label, f"{rate:.0f}"))
        except ImportError as exc:
            rows.append((label, f"not installed ({exc.name})"))
        print(f"{label}: {rows[-1][1]}", file=sys.stderr)

    from stable_baselines3 import SAC

    run("PPO, SB3 (torch), 16 envs, n_epochs 10", lambda: _ppo(8 * 2048))
    run("SAC, SB3 (torch)", lambda: _off_policy(SAC, args.steps, device="cpu"))

    def tqc() -> float:
        from sb3_contrib import TQC

        return _off_policy(TQC, args.steps, device="cpu")

    def sbx_sac() -> float:
        import sbx

        return _off_policy(sbx.SAC, args.steps)

    run("TQC, sb3-contrib (torch)", tqc)
    run("SAC, SBX (JAX, one XLA thread)", sbx_sac)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = [
        "# Off-policy training cost on JointTracking-v2 (`scripts/research/bench_offpolicy.py`)",
        "",
        f"Environment steps per CPU-second of the training process (`time.process_time`), "
        f"{args.steps} timed steps after warm-up; off-policy: one gradient step of batch 256 "
        f"per environment step, 256×256 networks; one torch / XLA thread. Written by the "
        f"script; a loaded machine slows every row alike only to first order.",
        "",
        "| algorithm | env steps per CPU-second |",
        "|---|---|",
        *[f"| {a} | {b} |" for a, b in rows],
        "",
    ]
    out.write_text("\n".join(lines))
    print(out, file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
