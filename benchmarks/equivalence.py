"""Episode-level equivalence of two code revisions on the leaderboard's jobs.

    python benchmarks/equivalence.py record OUT.json [--episodes 1] [--env ID ...]
    python benchmarks/equivalence.py compare BEFORE.json AFTER.json [--rtol 1e-6]

``record`` plays every leaderboard job (every variant × controller, tuned controller and
shipped agent; :func:`cir_gym.scoring.leaderboard.jobs_for`) on the leaderboard's first seeds
and stores each episode's metrics, return, length, success and divergence. ``compare`` checks
two such files job by job: the same jobs, equal lengths, success and divergence flags, and every
number within ``rtol`` relative (``atol`` absolute near zero). A refactor or a speed-up runs
``record`` on the revision before and after and states the tolerance it met; bit-identity is
not asked for (floating-point sums may be reordered), equal episodes are.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

LEADERBOARD_SEED = 1000


def _library() -> tuple[Any, Any, Any]:
    """(jobs_for, make_policy, evaluate) of the checked-out revision."""
    from cir_gym.evaluation import evaluate
    from cir_gym.scoring.leaderboard import jobs_for
    from cir_gym.scoring.policies import make_policy

    return jobs_for, make_policy, evaluate


def record(out: Path, episodes: int, envs: list[str] | None) -> int:
    import cir_gym

    jobs_for, make_policy, evaluate = _library()
    rows: dict[str, Any] = {}
    t0 = time.perf_counter()
    for env_id in envs or list(cir_gym.ENVIRONMENTS):
        for _, variant, kwargs, name in jobs_for(env_id):
            policy = make_policy(env_id, name, kwargs, {})
            result = evaluate(policy, env_id, episodes, LEADERBOARD_SEED, policy_name=name,
                              **kwargs)
            rows[f"{env_id} | {variant} | {name}"] = [
                {"seed": e.seed, "length": e.length, "return": e.episode_return,
                 "success": bool(e.success), "diverged": bool(e.diverged),
                 "metrics": {k: float(v) for k, v in e.metrics.items()}}
                for e in result.episodes
            ]
        print(f"{env_id}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    out.write_text(json.dumps(rows, indent=1, sort_keys=True) + "\n")
    print(f"{len(rows)} jobs -> {out}")
    return 0


def _close(a: float, b: float, rtol: float, atol: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return math.isclose(a, b, rel_tol=rtol, abs_tol=atol)


def compare(before: Path, after: Path, rtol: float, atol: float) -> int:
    a, b = json.loads(before.read_text()), json.loads(after.read_text())
    problems = [f"only before: {k}" for k in sorted(set(a) - set(b))]
    problems += [f"only after: {k}" for k in sorted(set(b) - set(a))]
    worst = 0.0
    for job in sorted(set(a) & set(b)):
        for ea, eb in zip(a[job], b[job], strict=True):
            for key in ("seed", "length", "success", "diverged"):
                if ea[key] != eb[key]:
                    problems.append(f"{job}: {key} {ea[key]} -> {eb[key]}")
            pairs = [("return", ea["return"], eb["return"])]
            pairs += [(m, v, eb["metrics"].get(m, math.nan)) for m, v in ea["metrics"].items()]
            for name, x, y in pairs:
                if not _close(x, y, rtol, atol):
                    problems.append(f"{job}: {name} {x!r} -> {y!r}")
                elif math.isfinite(x) and math.isfinite(y) and abs(x) > atol:
                    worst = max(worst, abs(x - y) / abs(x))
    print(f"{len(set(a) & set(b))} jobs compared; largest relative difference {worst:.3g}")
    for p in problems:
        print(p)
    return 1 if problems else 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("record", help="play the leaderboard's jobs, store their episodes")
    r.add_argument("out", type=Path)
    r.add_argument("--episodes", type=int, default=1)
    r.add_argument("--env", action="append", help="only these environment ids")
    c = sub.add_parser("compare", help="compare two recordings")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    c.add_argument("--rtol", type=float, default=1e-6, help="relative tolerance (default 1e-6)")
    c.add_argument("--atol", type=float, default=1e-12, help="absolute tolerance near zero")
    args = p.parse_args(argv)
    if args.command == "record":
        return record(args.out, args.episodes, args.env)
    return compare(args.before, args.after, args.rtol, args.atol)


if __name__ == "__main__":
    sys.exit(main())
