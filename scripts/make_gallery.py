"""The README's gallery: one small GIF per registered environment in ``docs/gallery/``.

    python scripts/make_gallery.py [--out docs/gallery] [--size 200] [--seed 0] [--env ID ...]

Each GIF is one episode (seed ``--seed``, at most its first ``--seconds`` s at ``--fps``
frames/s) of a reference controller, with the task drawn by the environment's ``draw_task``
and its caption (wrapped onto more lines when wider than the frame), through the camera
the leaderboard's videos use (:data:`cir_gym.scoring.page.VIDEO_CAMERAS`: PegInHole's low
side view). The controller and the setting per environment are in :data:`SHOWN` (chosen
to show the task: the obstacle variant of the redundancy envs, the controller that solves it);
an environment not listed there shows its first controller in default settings. Frames are
written by :func:`cir_gym.scoring.page.save_gif` (one palette, unchanged pixels
transparent) and each file must stay under 1 MB. Also prints the README's gallery table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import cir_gym
from cir_gym.scoring.page import episode_frames, save_gif

ROOT = Path(__file__).resolve().parents[1]
MAX_BYTES = 1_000_000

#: env name without its version → (controller, env kwargs, what the picture shows)
SHOWN: dict[str, tuple[str, dict[str, Any], str]] = {
    "JointTracking": ("computed_torque", {"payload_mass": 3.0},
                      "computed torque with an unknown 3 kg payload; ghost arm = q̄(t)"),
    "ElasticJointTracking": ("decentralized_feedforward", {},
                             "elastic joints; ghost arm = q̄(t)"),
    "RedundantIK": ("clik_nullspace", {"objective": "obstacle"},
                    "planar 3R: path, target, obstacle kept clear in the null space"),
    "RedundantIK7": ("clik_nullspace", {"objective": "obstacle"},
                     "iiwa: path, target frame, obstacle kept clear in the null space"),
    "CartesianTracking": ("os_inverse_dynamics", {},
                          "operational-space inverse dynamics: path and target frame"),
    "AdmittanceContact": ("admittance", {"stiffness": 10000.0, "force_ref": 20.0},
                          "admittance control on a 1e4 N/m surface: force arrows"),
    "PegInHole": ("hybrid_spiral", {"chamfer": 0.003}, "hybrid force/position with a spiral"),
    "VisualServo": ("ibvs", {}, "eye-in-hand IBVS: camera image inset with the features"),
    "VisualServoEyeToHand": ("ibvs_eye_to_hand", {}, "eye-to-hand IBVS"),
}


def shown(env_id: str) -> tuple[str, dict[str, Any], str] | None:
    """(controller, env kwargs, description) for ``env_id`` (see :data:`SHOWN`); None for an
    environment without a reference controller (the agent-ready variants)."""
    from cir_gym import baselines

    name = env_id.split("/")[-1].rsplit("-v", 1)[0]
    if name in SHOWN:
        return SHOWN[name]
    controllers = baselines.available(env_id)
    if not controllers:
        return None
    return controllers[0], {}, cir_gym.ENVIRONMENTS[env_id][1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "gallery"))
    parser.add_argument("--size", type=int, default=200, help="frame width and height (px)")
    parser.add_argument("--fps", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--env", action="append", help="env id (default: every registered)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    cells, status = [], 0
    for env_id in args.env or sorted(cir_gym.ENVIRONMENTS):
        if (chosen := shown(env_id)) is None:
            print(f"{env_id}: no reference controller to film, skipped", file=sys.stderr)
            continue
        controller, kwargs, what = chosen
        frames = episode_frames(env_id, controller, kwargs, args.seed, size=args.size,
                                fps=args.fps, seconds=args.seconds)
        name = env_id.split("/")[-1]
        path = save_gif(frames, out / f"{name}.gif", fps=args.fps)
        size = path.stat().st_size
        print(f"{path}: {len(frames)} frames, {size / 1e3:.0f} kB ({controller}, {kwargs})",
              file=sys.stderr)
        if size > MAX_BYTES:
            print(f"  larger than {MAX_BYTES / 1e6:g} MB", file=sys.stderr)
            status = 1
        rel = path.resolve().relative_to(ROOT).as_posix() if path.resolve().is_relative_to(
            ROOT) else path.as_posix()
        cells.append(f'<a href="{rel}"><img src="{rel}" width="{args.size}" '
                     f'alt="{name}: {what}" title="{name}: {what}"></a>')
    for i in range(0, len(cells), 3):
        print("".join(cells[i: i + 3]))
    return status


if __name__ == "__main__":
    sys.exit(main())
