"""Cost of a rendered frame with the task drawn (issue 23) against the bare robot, per env.

    python benchmarks/bench_render.py [--size 320] [--frames 30] [--repeat 5] [--target 2]
                                      [--env cir_gym/JointTracking-v2 ...]

For each registered environment (or ``--env``), in ``rgb_array`` mode at ``--size`` px, two
instances in the same state (a few zero-action steps into an episode):

- before: render() as it was before issue 23: the robot alone (the floor geom moved to a
  hidden geom group, ``draw_markers = False``: no ``draw_task``, no caption) with MuJoCo's
  default primitive meshes (``vis.quality`` numslices 28, numstacks 16);
- now:    render() as shipped: the robot file's coarser meshes (16, 8), the checker floor
  (sampled nearest-texel where the env's drawing calls ``rendering.sharp_floor``),
  ``draw_task``'s markers, the 2-D overlays and the caption.

Time is the process's CPU time (software GL renders on the CPU, in threads this counts), so
other jobs on the machine do not inflate one side; wall time is printed too. Each side renders
``--frames`` frames per trial, the sides alternate, the best of ``--repeat`` trials is kept.
Prints a markdown table, writes it to ``--out`` under ``## Rendering`` (only that
section is replaced) and exits 1 if a ratio now / before exceeds ``--target``. The GL
backend is the one cir_gym chose (MUJOCO_GL); a GPU gives other absolute numbers.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
from _sections import write_section  # sibling module: the scripts run as files

import cir_gym

SECTION = "## Rendering"
OUT = Path(__file__).parents[1] / "results" / "benchmarks.md"
HIDDEN_GROUP = 5  # MjvOption shows geom groups 0-2 by default
DEFAULT_QUALITY = (28, 16)  # MuJoCo's default numslices, numstacks (the robot files before)


def _time(env: gym.Env, frames: int) -> tuple[float, float]:
    """(CPU, wall) seconds per frame."""
    c0, w0 = time.process_time(), time.perf_counter()
    for _ in range(frames):
        env.render()
    return (time.process_time() - c0) / frames, (time.perf_counter() - w0) / frames


def _env(env_id: str, size: int, before: bool) -> gym.Env:
    env = gym.make(env_id, render_mode="rgb_array", width=size, height=size)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.zeros(env.action_space.shape))
    u = env.unwrapped
    if before:
        floor = mujoco.mj_name2id(u.model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
        if floor >= 0:
            u.model.geom_group[floor] = HIDDEN_GROUP
        u.model.vis.quality.numslices, u.model.vis.quality.numstacks = DEFAULT_QUALITY
        u.draw_markers = False
    env.render()  # create the GL context outside the timing
    return env


def measure(env_id: str, size: int, frames: int, repeat: int) -> dict[str, float]:
    """CPU and wall seconds per frame before and now, and the geoms in the scene now."""
    old, new = _env(env_id, size, before=True), _env(env_id, size, before=False)
    out = {"cpu_before": np.inf, "cpu_now": np.inf, "wall_before": np.inf, "wall_now": np.inf}
    for _ in range(repeat):
        for side, env in (("before", old), ("now", new)):
            cpu, wall = _time(env, frames)
            out[f"cpu_{side}"] = min(out[f"cpu_{side}"], cpu)
            out[f"wall_{side}"] = min(out[f"wall_{side}"], wall)
    out["ngeom"] = new.unwrapped._renderer.scene.ngeom
    old.close()
    new.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=320, help="frame width and height (px)")
    parser.add_argument("--frames", type=int, default=30, help="frames per timed trial")
    parser.add_argument("--repeat", type=int, default=5, help="trials per side (best kept)")
    parser.add_argument("--target", type=float, default=2.0, help="largest full/bare ratio")
    parser.add_argument("--env", action="append", help="env id (default: every registered)")
    parser.add_argument("--out", type=Path, default=OUT, help="markdown file ('-' for none)")
    args = parser.parse_args(argv)
    ids = args.env or sorted(cir_gym.ENVIRONMENTS)
    lines = [
        f"`python benchmarks/bench_render.py --size {args.size} --frames {args.frames} "
        f"--repeat {args.repeat}` (MUJOCO_GL={os.environ.get('MUJOCO_GL', '')}, mujoco "
        f"{mujoco.__version__}; process CPU time per frame, best of the trials, the two sides "
        "alternating in one run). *before*: the bare robot as rendered before issue 23; "
        "*now*: the shipped frame (checker floor, the task's markers, 2-D overlays, caption).",
        "",
        "| env | before CPU (ms/frame) | now CPU (ms/frame) | now / before | before wall "
        "| now wall | scene geoms now |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    print(lines[0] + "\n")
    print("\n".join(lines[2:]))
    worst = 0.0
    for env_id in ids:
        m = measure(env_id, args.size, args.frames, args.repeat)
        ratio = m["cpu_now"] / m["cpu_before"]
        worst = max(worst, ratio)
        lines.append(
            f"| {env_id} | {1e3 * m['cpu_before']:.2f} | {1e3 * m['cpu_now']:.2f} | "
            f"{ratio:.2f} | {1e3 * m['wall_before']:.2f} | {1e3 * m['wall_now']:.2f} | "
            f"{m['ngeom']:.0f} |"
        )
        print(lines[-1], flush=True)
    ok = worst <= args.target
    lines += [
        "",
        f"Worst ratio {worst:.2f}: {'within' if ok else 'ABOVE'} the target "
        f"{args.target:g} (issue 23).",
    ]
    print("\n" + lines[-1])
    if str(args.out) != "-":
        write_section(args.out, SECTION, "\n".join(lines))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
