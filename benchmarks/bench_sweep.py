"""Sweep throughput: tasks/s with 1 and 2 workers, on the local pool and on a local Ray.

    python benchmarks/bench_sweep.py [--tasks 40] [--duration 2.0] [--repeat 2]
                                     [--out results/benchmarks.md]

One grid (``--tasks`` evaluation tasks of one JointTracking-v2 episode of ``--duration`` s,
computed torque and PD + gravity alternately) runs in four configurations into fresh
directories: local pool with 1 and 2 workers, a Ray instance started for the run
(``ray="local"``) with 1 and 2 CPUs; ``--repeat`` rounds, every other one in reverse order,
the best steady rate of each configuration kept. Two rates per run:

* end to end: tasks / wall time of :func:`cir_gym.scoring.sweep.run_sweep`, including starting the
  worker processes (about 4 s here, each imports MuJoCo, cir_gym and the controllers) or Ray
  (about 20 s here);
* steady: (tasks − 1) / (time between the first and the last finished task), from the task
  files' modification times: the rate once the workers are up.

The four tables must hold the same episodes (checked: the run fails otherwise). The machine is
shared (2 cores, other jobs running): the load average before and after is printed with the
figures, and only the ratios inside one run mean much. Writes the markdown section
``## Sweeps`` of ``--out`` (the other sections of the file are kept).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from _sections import write_section  # sibling module: the scripts run as files

SECTION = "## Sweeps"
OUT = Path(__file__).parents[1] / "results" / "benchmarks.md"
VOLATILE = {"seconds", "worker", "attempts", "task_id"}


def grid(tasks: int, duration: float) -> dict:
    """``tasks`` one-episode tasks: two controllers × tasks/2 seeds."""
    return {
        "evaluate": {
            "envs": ["cir_gym/JointTracking-v2"],
            "policies": ["computed_torque", "pd_gravity"],
            "seed": 0,
            "episodes": tasks // 2,
            "env_kwargs": {"episode_duration": duration},
        }
    }


def episodes(directory: Path) -> list[tuple]:
    """The table's episodes without the columns that differ between runs, sorted."""
    from cir_gym.scoring.sweep import read_table

    rows = [{k: v for k, v in r.items() if k not in VOLATILE} for r in read_table(directory)]
    return sorted(tuple(sorted(r.items(), key=lambda kv: kv[0])) for r in rows)


def one_run(g: dict, out: Path, workers: int, ray: str | None) -> dict:
    from cir_gym.scoring.sweep import run_sweep

    t0 = time.perf_counter()
    summary = run_sweep(g, out, workers=workers, ray=ray, progress=False)
    wall = time.perf_counter() - t0
    if summary.failed:
        raise RuntimeError(f"{summary.failed} tasks failed in {out}")
    files = sorted((out / "tasks").glob("*.json"))
    stamps = sorted(p.stat().st_mtime for p in files)
    steady = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if stamps[-1] > stamps[0] else 0.0
    task_s = sum(json.loads(p.read_text())["seconds"] for p in files) / len(files)
    return {
        "tasks": summary.ran,
        "wall": wall,
        "rate": summary.ran / wall,
        "steady": steady,
        "task_s": task_s,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--tasks", type=int, default=40)
    p.add_argument("--duration", type=float, default=2.0, help="episode length (s)")
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--repeat", type=int, default=2, help="rounds; the best of each is kept")
    args = p.parse_args(argv)
    g = grid(args.tasks, args.duration)
    load_before = os.getloadavg()[0]
    configs = [
        ("local pool", 1, None),
        ("local pool", 2, None),
        ("Ray (local instance)", 1, "local"),
        ("Ray (local instance)", 2, "local"),
    ]
    runs: dict[tuple[str, int], dict] = {}
    reference = None
    with tempfile.TemporaryDirectory() as tmp:
        for round_ in range(args.repeat):
            # every other round in reverse order: a load that drifts during the run hits
            # every configuration alike
            for name, workers, ray in configs if round_ % 2 == 0 else configs[::-1]:
                out = Path(tmp) / f"{ray or 'pool'}_{workers}_{round_}"
                r = one_run(g, out, workers, ray)
                print(f"round {round_}: {name}, {workers} workers: {r}", file=sys.stderr)
                best = runs.get((name, workers))
                if best is None or r["steady"] > best["steady"]:
                    runs[(name, workers)] = r
                got = episodes(out)
                if reference is None:
                    reference = got
                elif got != reference:
                    raise RuntimeError(f"{name} with {workers} workers gave other episodes")
    runs = {(n, w): runs[(n, w)] for n, w, _ in configs}
    load_after = os.getloadavg()[0]
    lines = [
        f"`python benchmarks/bench_sweep.py --tasks {args.tasks} --duration {args.duration} "
        f"--repeat {args.repeat}`: "
        f"{args.tasks} tasks, each one JointTracking-v2 episode of {args.duration:g} s "
        f"({round(args.duration * 500)} steps; computed torque and PD + gravity), on this "
        f"2-core machine shared with other jobs (load average {load_before:.1f} before, "
        f"{load_after:.1f} after). *End to end* includes starting the workers (each imports "
        "MuJoCo, cir_gym and the controllers) or the Ray instance; *steady* is (tasks − 1) / "
        "(last − first task finished); a task's time in its worker grows when the workers "
        "share the cores with other jobs (workers / task time bounds the steady rate). Each "
        f"configuration ran {args.repeat} times (rounds in alternating order); the run with "
        "the best steady rate is shown. Every run gave the same episodes (checked).",
        "",
        "| executor | workers | wall (s) | tasks/s end to end | tasks/s steady | "
        "steady speed-up vs 1 worker | mean task time in its worker (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for (name, workers), r in runs.items():
        base = runs[(name, 1)]["steady"]
        speedup = r["steady"] / base if base > 0 else float("nan")
        lines.append(
            f"| {name} | {workers} | {r['wall']:.1f} | {r['rate']:.2f} | {r['steady']:.2f} | "
            f"{speedup:.2f}× | {r['task_s']:.2f} |"
        )
    body = "\n".join(lines)
    print(body)
    if args.out:
        text = body + "\n\n" + reading()
        write_section(args.out, SECTION, text)
        print(f"wrote the {SECTION!r} section of {args.out}", file=sys.stderr)
    return 0


def reading() -> str:
    """What the figures say about this machine (its scheduler is read, not assumed)."""
    try:
        autogroup = Path("/proc/sys/kernel/sched_autogroup_enabled").read_text().strip() == "1"
    except OSError:
        autogroup = False
    text = (
        "Reading: a task's time in its worker is its share of the CPU. "
        if not autogroup
        else "Reading: Linux autogroup scheduling is on here "
        "(`/proc/sys/kernel/sched_autogroup_enabled` = 1): the sweep's driver and every worker "
        "it starts, pool process or Ray worker alike (seen in `/proc/PID/autogroup` during a run), "
        "share one session's slice of the 2 cores next to every other session on the machine. "
        "With the load above 2, a second worker splits that slice (its task time roughly "
        "doubles) instead of adding a core, so these runs measure the sharing, not the "
        "executors: on free cores the steady rate is about workers / task time. "
    )
    return text + (
        "Ray's per-task cost (scheduling, the object store) is small next to an episode; its "
        "start-up is not (end to end against steady). On a multi-node cluster (`--ray auto` on "
        "a node of it) the same grid spreads over every node's CPUs: docs/sweeps.md."
    )


if __name__ == "__main__":
    sys.exit(main())
