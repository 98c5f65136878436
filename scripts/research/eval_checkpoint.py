"""Score a training run's saved model beside a controller on held-out seeds.

    python scripts/research/eval_checkpoint.py RUN --env ID --metric NAME --controller POLICY
        [--steps N] [--episodes 100] [--seed 7000] [--runs /work/main/runs/rl] [--set K=V ...]

``RUN`` is a run folder under ``--runs`` (``<Env>/<agent>/seed_<k>``, e.g.
``VisualServo-v1/residual_ppo_tuned_ibvs/seed_0``); its checkpoint ``--steps`` (default: the
last one) is loaded as an agent (``eval_vs_agents.checkpoint_policy``: the checkpoint's model and
VecNormalize statistics) and scored with :func:`cir_gym.evaluation.evaluate` on the episodes
``--seed … --seed + episodes − 1`` (7000+: seeds no training, evaluation during training,
validation, tuning or leaderboard run uses), then ``--controller`` (a policy name:
``admittance_setpoint``, ``tuned:ibvs``, …) on the same seeds and environment arguments. Per
policy: the metric's mean with its 95 % bootstrap interval
(:func:`cir_gym.metrics.mean_interval`), the success rate with its Wilson interval, the mean
largest single contact force where the task has one, and the CPU seconds. A check of a run in
training, not a selection: nothing is chosen on these seeds.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from cir_gym.evaluation import EvaluationResult, evaluate
from cir_gym.metrics import wilson_interval
from cir_gym.scoring.policies import make_policy, parse_value

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_vs_agents import RUNS, checkpoint_policy

FORCE_METRICS = ("max_force", "peak_force")  # the largest single contact, where a task has one


def line(result: EvaluationResult, metric: str, cpu_s: float) -> str:
    """One policy's row: metric mean [95 % CI], successes (Wilson), largest contact, CPU-s."""
    s = result.summary[metric]
    n = len(result.episodes)
    k = sum(ep.success for ep in result.episodes)
    low, high = wilson_interval(k, n)
    force = next((f"largest contact {result.summary[m]['mean']:.3g} N (mean), "
                  for m in FORCE_METRICS if m in result.summary), "")
    return (f"| {result.policy_name} | {s['mean']:.3g} [{s['ci_low']:.3g}, {s['ci_high']:.3g}] "
            f"| {k}/{n} ({100 * low:.0f}–{100 * high:.0f} %) | {force}{cpu_s:.0f} CPU-s |")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", help="<Env>/<agent>/seed_<k> under --runs")
    parser.add_argument("--env", required=True)
    parser.add_argument("--metric", required=True)
    parser.add_argument("--controller", required=True)
    parser.add_argument("--steps", type=int, default=None, help="default: the last checkpoint")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=7000)
    parser.add_argument("--runs", type=Path, default=RUNS)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args(argv)
    try:
        steps, agent = checkpoint_policy(args.runs / args.run, args.runs, args.steps, args.env)
    except ValueError as exc:
        parser.error(str(exc))
    kwargs = {k: parse_value(v) for k, v in (s.split("=", 1) for s in args.set)}
    print(f"{args.env} {kwargs or ''}, seeds {args.seed}–{args.seed + args.episodes - 1}, "
          f"`{args.metric}`:\n\n| policy | mean [95 % CI] | success (Wilson 95 %) | |\n"
          "|---|---|---|---|")
    for name, policy in ((f"{args.run} @ {steps}", agent),
                         (args.controller, make_policy(args.env, args.controller, kwargs, {}))):
        start = time.process_time()
        result = evaluate(policy, args.env, args.episodes, args.seed, policy_name=name, **kwargs)
        print(line(result, args.metric, time.process_time() - start), flush=True)


if __name__ == "__main__":
    main()
