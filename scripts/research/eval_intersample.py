"""A policy's joint tracking error between its samples: at every physics step (JointTracking).

    python scripts/research/eval_intersample.py [--env ID] --agent ppo_100hz [--seed-agent 0]
    python scripts/research/eval_intersample.py --controller pd_gravity [--gain omega=53.4 ...]
        [--control-freq 100] [--episodes 10] [--seed 1000] [--set payload_mass=3.0]

JointTracking's metrics read the error at the control instants only. A policy that acts at
100 Hz holds each torque for 10 physics steps of 1 ms; if its error between those instants
were much larger than at them (a policy that is exact at the samples and swings between them),
its RMS error would flatter it against controllers that act at 500 Hz. This script runs the
policy in its own environment (:func:`cir_gym.evaluation.evaluate` plays the episode), records
the joint positions at the start of every ``mj_step``
(MuJoCo's control callback, ``mujoco.set_mjcb_control``: the state at t = 0, 1, 2 ... ms) and
compares them with the same episode's reference evaluated on the physics grid (the reference
of an env with ``control_freq`` = 1 / timestep — 1 kHz on JointTracking, 2 kHz on
ElasticJointTracking — reset with the same seed: for ``reference="random"`` the path is drawn
from the seed independently of the grid). It prints, per episode, the RMS error at
the control instants (the env's own ``rms_error``) and at every physics step.
"""

from __future__ import annotations

import argparse
import warnings
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

import cir_gym  # noqa: F401  (registers the environments)
from cir_gym.envs.base import make_env
from cir_gym.evaluation import evaluate, interface_env_kwargs

ENV_ID = "cir_gym/JointTracking-v2"
ENVS = ("cir_gym/JointTracking-v2", "cir_gym/ElasticJointTracking-v3")


def _value(text: str) -> Any:
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


class PhysicsSteps(gym.Wrapper):
    """The joint positions (qpos) at the start of every physics step since the last reset:
    MuJoCo's control callback (``mujoco.set_mjcb_control``) records them while installed
    (:meth:`recording`)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.qpos: list[np.ndarray] = []

    def reset(self, **kwargs: Any) -> tuple[Any, dict]:
        result = self.env.reset(**kwargs)
        self.qpos = []  # the reset's own forward passes are not steps
        return result

    def _record(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        if data is self.env.unwrapped.data:
            self.qpos.append(data.qpos.copy())

    def recording(self) -> Any:
        """A context in which the callback records (it is process-wide: removed on exit)."""
        import contextlib

        @contextlib.contextmanager
        def installed() -> Any:
            mujoco.set_mjcb_control(self._record)
            try:
                yield self
            finally:
                mujoco.set_mjcb_control(None)

        return installed()


def physics_rate_errors(policy: Any, env_kwargs: dict[str, Any], seed: int,
                        env_id: str = ENV_ID) -> tuple[float, float, int]:
    """(env rms_error at the control instants, RMS error at every physics step, physics steps).

    The episode is one deterministic rollout of ``policy`` by :func:`cir_gym.evaluation.evaluate`
    in ``make_env(env_id, **env_kwargs)`` reset with ``seed``; the reference on the physics grid
    comes from the same seed's reset of an env with ``control_freq`` = 1 / timestep (same other
    arguments)."""
    env = PhysicsSteps(make_env(env_id, **env_kwargs))
    base = env.unwrapped
    rate = 1.0 / base.model.opt.timestep
    with warnings.catch_warnings():  # its episode has more steps than the registered limit
        warnings.simplefilter("ignore")
        fine = make_env(env_id, **{**env_kwargs, "control_freq": rate})
    fine.reset(seed=seed)
    ref_fine = fine.unwrapped._ref[0].copy()
    fine.close()
    if hasattr(policy, "reset"):
        policy.reset()
    with env.recording():
        episode = evaluate(policy, env_id, 1, seed, env=env).episodes[0]
    if not np.array_equal(ref_fine[0], base._ref[0, 0]):
        raise RuntimeError("the physics-rate reference does not start where the env's does: the "
                           "reference is not grid-independent for these arguments")
    q = np.array(env.qpos)[:, base.robot.qpos_adr]
    n = min(len(q), len(ref_fine))
    err = ref_fine[:n] - q[:n]  # (steps, joints): the env's rms_error is over both
    env.close()
    return float(episode.metrics["rms_error"]), float(np.sqrt(np.mean(err**2))), n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", default=ENV_ID, choices=ENVS)
    who = ap.add_mutually_exclusive_group(required=True)
    who.add_argument("--agent", help="a shipped agent's name (agents.available)")
    who.add_argument("--controller", help="a controller's name (baselines.available)")
    ap.add_argument("--seed-agent", type=int, default=None, help="the agent's training seed")
    ap.add_argument("--control-freq", type=float, default=None,
                    help="the controller's control rate (Hz); an agent uses its recorded one")
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="environment argument (e.g. payload_mass=3.0)")
    ap.add_argument("--gain", action="append", default=[], metavar="KEY=VALUE",
                    help="a controller gain (e.g. omega=53.4; tuned gains: results/tuning/)")
    args = ap.parse_args(argv)
    env_kwargs = {k: _value(v) for k, v in (s.split("=", 1) for s in args.set)}
    if args.agent:
        from cir_gym import agents

        policy = agents.load(args.env, args.agent, seed=args.seed_agent)
        env_kwargs = interface_env_kwargs(policy, env_kwargs)
        label = f"agent {args.agent}"
    else:
        from cir_gym import baselines

        if args.control_freq is not None:
            env_kwargs["control_freq"] = args.control_freq
        gains = {k: float(v) for k, v in (g.split("=", 1) for g in args.gain)}
        policy = baselines.make(args.controller, args.env, env_kwargs=env_kwargs, **gains)
        label = f"controller {args.controller} {gains or '(default gains)'}"
    print(f"{label}, env arguments {env_kwargs}")
    print("| seed | rms_error at control instants (rad) | RMS error at every physics step (rad) "
          "| ratio | physics steps |")
    print("|---|---:|---:|---:|---:|")
    ratios = []
    for s in range(args.seed, args.seed + args.episodes):
        at_samples, every_step, n = physics_rate_errors(policy, env_kwargs, s, args.env)
        ratios.append(every_step / at_samples)
        print(f"| {s} | {at_samples:.3e} | {every_step:.3e} | {ratios[-1]:.3f} | {n} |")
    print(f"\nratio (every step / control instants): median {np.median(ratios):.3f}, "
          f"max {np.max(ratios):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
