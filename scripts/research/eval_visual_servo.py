"""Measure chapter 7: IBVS against PBVS on the classic cases, 100-seed success, detected vs
projected features, calibration errors, rotations of 90°–180° about the optical axis with
feature noise, and the cost of detected-feature episodes.

    python scripts/research/eval_visual_servo.py --out results/visual_servo/ [--episodes 100]
        [--detected-episodes 20] [--sweep-episodes 20] [--agent-episodes 50]
        [--rotation-episodes 30] [--parts cases,seeds,detected,sweep,agent,rotation]

Writes ``<out>/sections.json`` (the tables; README.md quotes them), ``<out>/rotation.md`` (the
rotation family, written whole by the ``rotation`` part) and figures:
``classic_cases.png`` (image-plane feature paths and camera paths, IBVS beside PBVS, for a
large rotation about the optical axis, the 180° case and a large translation with rotation)
and ``calibration_sweep.png``. Every number comes from an episode of the registered
environments run by :func:`cir_gym.evaluation.evaluate` or the loop below, on fixed seeds.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import cir_gym
from cir_gym import baselines
from cir_gym.evaluation import evaluate
from cir_gym.metrics import wilson_interval

EYE_IN_HAND = "cir_gym/VisualServo-v1"
EYE_TO_HAND = "cir_gym/VisualServoEyeToHand-v1"
SEED = 0  # first seed of every multi-episode measurement
AGENT_SEED = 2000  # the agent's episodes: seeds no training or leaderboard run used
#: the classic cases: (title, start_offset: tx, ty, tz (m), rotation vector (rad))
CASES = {
    "75° about the optical axis": (0.0, 0.0, 0.0, 0.0, 0.0, np.deg2rad(75.0)),
    "115° about the optical axis (Corke)": (0.0, 0.0, 0.0, 0.0, 0.0, np.deg2rad(115.0)),
    "180° about the optical axis (Chaumette)": (0.0, 0.0, 0.0, 0.0, 0.0, np.pi),
    # found by a grid search of start offsets in free space (same laws, no robot): the target
    # starts near the image border, tilted, rotated 145° about the optical axis
    "translation + 145° rotation": (0.2, -0.15, 0.05, 0.0, 0.41, 2.53),
}
#: the laws of the classic cases: (label, controller, gains)
LAWS = (("ibvs", "ibvs", {}), ("ibvs, mean L", "ibvs", {"depth": "mean"}), ("pbvs", "pbvs", {}))
#: controllers on the default seeds: (label, controller, gains)
CONTROLLERS = (
    ("ibvs (L at current depth)", "ibvs", {}),
    ("ibvs (L at desired)", "ibvs", {"depth": "desired"}),
    ("ibvs (mean L)", "ibvs", {"depth": "mean"}),
    ("ibvs, ViSP adaptive gain", "ibvs", {"adaptive": (4.0, 0.4, 30.0)}),
    ("pbvs", "pbvs", {}),
)
#: rotations about the optical axis of the rotation family (deg), its laws and first seed
ROTATION_ANGLES = (90.0, 120.0, 150.0, 170.0, 175.0, 178.0, 180.0)
ROTATION_LAWS = (
    ("ibvs (L at current depth)", "ibvs", {}),
    ("ibvs (mean L)", "ibvs", {"depth": "mean"}),
    ("ibvs (mean L, pseudo-inverse: damping 0)", "ibvs", {"depth": "mean", "damping": 0.0}),
    ("pbvs", "pbvs", {}),
)
ROTATION_SEED = 3000  # seeds no other measurement, tuning or training run uses
SWEEP = (0.0, 1.0, 2.0, 4.0)  # multiples of the unit calibration error below
UNIT_ERROR = (0.05, 10.0, 0.01, 0.02)  # focal 5 %, principal 10 px, hand-eye 1 cm / 0.02 rad


def episode(env_id: str, policy: str, gains: dict[str, Any] | None = None, seed: int = SEED,
            **kwargs: Any) -> dict[str, Any]:
    """One episode with the true features and moving-frame positions recorded."""
    env = gym.make(env_id, **kwargs)
    ctrl = baselines.make(policy, env_id, env=env, **(gains or {}))
    base = env.unwrapped
    obs, _ = env.reset(seed=seed)
    feats, state, start = [base._s_true.copy()], None, True
    while True:
        action, state = ctrl.predict(obs, state, np.array([start]))
        start = False
        obs, _, terminated, truncated, info = env.step(action)
        feats.append(base._s_true.copy())
        if terminated or truncated:
            break
    k = base._k
    out = {"features": np.array(feats), "features_ref": base._s_ref.copy(),
           "path": base._pos[: k + 1].copy(), "metrics": info["episode_metrics"],
           "success": info["is_success"], "feature_lost": info["feature_lost"],
           "joint_limit": info["joint_limit"], "camera": base.true_camera}
    env.close()
    return out


def outcome(ep: dict[str, Any]) -> str:
    if ep["success"]:
        return "converged"
    if ep["feature_lost"]:
        return "feature lost"
    if ep["joint_limit"]:
        return "joint limit"
    return "not converged"


def classic_cases(out: Path) -> list[str]:
    rows = ["| case | law | outcome | final error (px) | retreat (m) | camera path (m) |",
            "|---|---|---|---:|---:|---:|"]
    n = len(LAWS)
    fig, axes = plt.subplots(len(CASES), 2 * n, figsize=(6.0 * n * 2 * 0.62, 3.3 * len(CASES)))
    for r, (title, offset) in enumerate(CASES.items()):
        for c, (label, law, gains) in enumerate(LAWS):
            ep = episode(EYE_IN_HAND, law, gains, start_offset=offset, pixel_noise=0.0)
            m = ep["metrics"]
            rows.append(f"| {title} | {label} | {outcome(ep)} | {m['final_feature_error']:.2f} "
                        f"| {m['retreat']:.3f} | {m['path_length']:.3f} |")
            print(rows[-1], flush=True)
            ax = axes[r, 2 * c]
            cam = ep["camera"]
            for i, colour in enumerate(("r", "g", "b", "y")):
                ax.plot(ep["features"][:, i, 0], ep["features"][:, i, 1], colour, lw=1.2)
                ax.plot(*ep["features_ref"][i], marker="o", mfc="none", mec=colour, ms=9)
                ax.plot(*ep["features"][0, i], marker=".", color=colour)
            ax.add_patch(plt.Rectangle((-0.5, -0.5), cam.width, cam.height, fill=False, lw=1))
            ax.set_xlim(-60, cam.width + 60)
            ax.set_ylim(cam.height + 60, -60)
            ax.set_aspect("equal")
            ax.set_title(f"{label}: {title}\n{outcome(ep)}", fontsize=8)
            ax.set_xlabel("u (px)", fontsize=8)
            ax.set_ylabel("v (px)", fontsize=8)
            axp = axes[r, 2 * c + 1]
            p = ep["path"]
            axp.plot(p[:, 0], p[:, 2], "k")
            axp.plot(p[0, 0], p[0, 2], "ko", mfc="none")
            axp.plot(0, 0, "k*", ms=10)
            axp.set_xlabel("x, goal camera frame (m)", fontsize=8)
            axp.set_ylabel("z, along the goal optical axis (m)", fontsize=8)
            axp.set_title(f"{label}: camera path\n(retreat {m['retreat']:.2f} m)", fontsize=8)
            lo, hi = np.minimum(p.min(0), 0.0) - 0.05, np.maximum(p.max(0), 0.0) + 0.05
            axp.set_xlim(lo[0], hi[0])  # at least ±5 cm around the path and the goal
            axp.set_ylim(lo[2], hi[2])
            axp.set_aspect("equal", adjustable="datalim")
            axp.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "classic_cases.png", dpi=70)
    plt.close(fig)
    return rows


def free_space_retreat(angle: float, gain: float = 0.5, dt: float = 0.04,
                       duration: float = 15.0) -> tuple[float, float]:
    """IBVS (current L, exact depths) without a robot: a camera rotated by ``angle`` about its
    optical axis from the goal (target 0.75 m ahead, the envs' camera and twist limits).
    Returns (retreat (m), final feature error (px))."""
    from cir_gym import trajectories as traj
    from cir_gym.envs.visual_servo_base import TWIST_LIMIT
    from cir_gym.vision import Camera, interaction_matrix, project

    cam = Camera.from_fovy(60.0, 640, 480)
    h = 0.1
    points = np.array([[-h, -h, 0.75], [h, -h, 0.75], [h, h, 0.75], [-h, h, 0.75]])
    s_ref = project(points, cam)
    R = traj.matrix_from_axis_angle(np.array([0.0, 0.0, 1.0]), angle)
    c, z_min = np.zeros(3), 0.0
    for _ in range(int(duration / dt)):
        P = (points - c) @ R  # the points in the camera frame
        s = project(P, cam)
        V = -gain * np.linalg.pinv(interaction_matrix(s, P[:, 2], cam)) @ (s - s_ref).ravel()
        V /= max(1.0, float(np.max(np.abs(V) / np.array(TWIST_LIMIT))))
        c = c + dt * R @ V[:3]
        w = float(np.linalg.norm(V[3:]))
        if w > 0:
            R = R @ traj.matrix_from_axis_angle(V[3:] / w, w * dt)
        z_min = min(z_min, c[2])
    e = float(np.sqrt(np.mean(np.sum((s - s_ref) ** 2, axis=1))))
    return -z_min, e


def free_space() -> list[str]:
    rows = ["| rotation about the optical axis | IBVS retreat without the robot (m) | "
            "final error after 15 s (px) |", "|---:|---:|---:|"]
    for deg in (75.0, 90.0, 115.0, 150.0, 170.0):
        retreat, e = free_space_retreat(np.deg2rad(deg))
        rows.append(f"| {deg:.0f}° | {retreat:.2f} | {e:.2f} |")
    return rows


def seeds(n: int, n_other: int) -> list[str]:
    """``n`` seeds for the first controller (ibvs, the default), ``n_other`` for the rest."""
    rows = ["| environment | controller | success | final error (px), mean / worst | "
            "convergence time (s), median | camera path (m), mean | retreat (m), max | "
            "s / episode |",
            "|---|---|---:|---:|---:|---:|---:|---:|"]
    runs = [(EYE_IN_HAND, label, name, gains, {}) for label, name, gains in CONTROLLERS]
    runs += [(EYE_TO_HAND, "ibvs_eye_to_hand (twist)", "ibvs_eye_to_hand", {}, {}),
             (EYE_TO_HAND, "ibvs_eye_to_hand (through J(q))", "ibvs_eye_to_hand", {},
              {"action": "joint_velocity"})]
    for i, (env_id, label, name, gains, kwargs) in enumerate(runs):
        n_run = n if i == 0 else n_other
        t0 = time.perf_counter()
        policy = baselines.make(name, env_id, env_kwargs=kwargs, **gains)
        res = evaluate(policy, env_id, n_episodes=n_run, seed=SEED, policy_name=label,
                       **kwargs)
        wall = (time.perf_counter() - t0) / n_run
        s = res.summary
        rows.append(
            f"| {env_id.split('/')[1]} | {label} | {100 * res.success_rate:.0f} % of {n_run} | "
            f"{s['final_feature_error']['mean']:.3f} / {s['final_feature_error']['worst']:.2f} | "
            f"{s['convergence_time']['median']:.2f} | {s['path_length']['mean']:.3f} | "
            f"{s['retreat']['worst']:.3f} | {wall:.2f} |")
        print(rows[-1], flush=True)
    return rows


def detected(n: int) -> list[str]:
    rows = ["| features | success | final error (px), mean | max over seeds of abs(detected − "
            "projected final error) (px) | detection failures | s / episode |",
            "|---|---:|---:|---:|---:|---:|"]
    finals = {}
    for features in ("projected", "detected"):
        t0 = time.perf_counter()
        policy = baselines.make("ibvs", EYE_IN_HAND)
        res = evaluate(policy, EYE_IN_HAND, n_episodes=n, seed=SEED, features=features)
        wall = (time.perf_counter() - t0) / n
        finals[features] = np.array([ep.metrics["final_feature_error"] for ep in res.episodes])
        fails = sum(ep.metrics["detection_failures"] for ep in res.episodes)
        diff = (np.max(np.abs(finals[features] - finals["projected"]))
                if features == "detected" else 0.0)
        rows.append(f"| {features} | {100 * res.success_rate:.0f} % | "
                    f"{np.mean(finals[features]):.3f} | {diff:.3f} | {fails:.0f} | {wall:.2f} |")
        print(rows[-1], flush=True)
    return rows


def sweep(n: int, out: Path) -> list[str]:
    rows = ["| error level (× unit) | focal error | principal offset (px) | hand-eye (m, rad) | "
            "ibvs success | ibvs final error (px) | pbvs success | pbvs final error (px) |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    curves: dict[str, list[float]] = {"ibvs": [], "pbvs": []}
    for level in SWEEP:
        err = tuple(level * u for u in UNIT_ERROR)
        cells = []
        for law in ("ibvs", "pbvs"):
            policy = baselines.make(law, EYE_IN_HAND)
            res = evaluate(policy, EYE_IN_HAND, n_episodes=n, seed=SEED, camera_error=err)
            mean = res.summary["final_feature_error"]["mean"]
            curves[law].append(res.success_rate)
            cells += [f"{100 * res.success_rate:.0f} %", f"{mean:.3f}"]
        rows.append(f"| {level:g} | {err[0]:.3f} | {err[1]:.0f} | {err[2]:.3f}, {err[3]:.3f} | "
                    + " | ".join(cells) + " |")
        print(rows[-1], flush=True)
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for law, ys in curves.items():
        ax.plot(SWEEP, 100 * np.array(ys), "o-", label=law)
    ax.set_xlabel("calibration error (multiples of focal 5 %, 10 px, 1 cm, 0.02 rad)")
    ax.set_ylabel(f"success over {n} seeds (%)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "calibration_sweep.png", dpi=90)
    plt.close(fig)
    return rows


def agent(n: int) -> list[str]:
    """Every shipped agent of the eye-in-hand task, every training seed, against IBVS and PBVS
    on the same episodes of each leaderboard variant (exact camera, calibration error): seeds
    ``AGENT_SEED`` … (unseen by training, its evaluations, tuning and the leaderboard)."""
    from cir_gym import agents

    rows = ["| variant | policy | success | final error (px), mean / worst | convergence time "
            "(s), median | feature lost or joint limit |", "|---|---|---:|---:|---:|---:|"]
    env_cls = cir_gym.ENVIRONMENTS[EYE_IN_HAND][0]
    policies = [(f"agent:{name} seed {k}", agents.load(EYE_IN_HAND, name, seed=k))
                for name in agents.available(EYE_IN_HAND)
                for k in agents.seeds(EYE_IN_HAND, name)]
    for variant, kwargs in env_cls.leaderboard_variants.items():
        controllers = [(c, baselines.make(c, EYE_IN_HAND, env_kwargs=kwargs))
                       for c in ("ibvs", "pbvs")]
        for label, policy in [*policies, *controllers]:
            res = evaluate(policy, EYE_IN_HAND, n_episodes=n, seed=AGENT_SEED,
                           policy_name=label, **kwargs)
            s = res.summary
            ended = sum(ep.terminated for ep in res.episodes)
            rows.append(f"| {variant} | {label} | {100 * res.success_rate:.0f} % | "
                        f"{s['final_feature_error']['mean']:.2f} / "
                        f"{s['final_feature_error']['worst']:.2f} | "
                        f"{s['convergence_time']['median']:.2f} | {ended} of {n} |")
            print(rows[-1], flush=True)
    return rows


def rotation(n: int, out: Path) -> list[str]:
    """Each law from a pure rotation about the optical axis (start_offset (0, 0, 0, 0, 0, θ),
    the default 0.1 px feature noise) on seeds ROTATION_SEED …: success with its Wilson 95 %
    interval, how the failures ended, and the median convergence time of the successes."""
    rows = ["| rotation | law | success (95 % interval) | stopped: joint limit or feature lost | "
            "not converged in 15 s | convergence time of successes (s), median | "
            "retreat (m), median |", "|---:|---|---:|---:|---:|---:|---:|"]
    for deg in ROTATION_ANGLES:
        kwargs = {"start_offset": (0.0, 0.0, 0.0, 0.0, 0.0, float(np.deg2rad(deg)))}
        for label, law, gains in ROTATION_LAWS:
            policy = baselines.make(law, EYE_IN_HAND, env_kwargs=kwargs, **gains)
            res = evaluate(policy, EYE_IN_HAND, n_episodes=n, seed=ROTATION_SEED,
                           policy_name=label, **kwargs)
            wins = sum(ep.success for ep in res.episodes)
            stopped = sum(ep.terminated for ep in res.episodes)
            low, high = wilson_interval(wins, n)
            times = [ep.metrics["convergence_time"] for ep in res.episodes if ep.success]
            retreat = np.median([ep.metrics["retreat"] for ep in res.episodes])
            t_conv = f"{np.median(times):.2f}" if times else "–"
            rows.append(f"| {deg:.0f}° | {label} | {wins}/{n} = {100 * wins / n:.0f} % "
                        f"({100 * low:.0f}–{100 * high:.0f} %) | {stopped} | "
                        f"{n - wins - stopped} | {t_conv} | {retreat:.3f} |")
            print(rows[-1], flush=True)
    text = (
        "# Rotations about the optical axis with feature noise\n\n"
        "Written by `python scripts/research/eval_visual_servo.py --parts rotation "
        f"--rotation-episodes {n}`: `cir_gym/VisualServo-v1` from start_offset "
        "(0, 0, 0, 0, 0, θ) (the camera turned by θ about its optical axis from the goal, the "
        "target square to it), the default 0.1 px feature noise, seeds "
        f"{ROTATION_SEED}–{ROTATION_SEED + n - 1} (the seed draws only the noise), run by "
        "`cir_gym.evaluation.evaluate`. Success: the final feature error < 1 px after 15 s "
        "without a feature lost, a joint limit or a divergence; the interval is Wilson's "
        "95 % score interval. The IBVS laws invert L̂ by damped least squares (μ = 1 px, "
        "`baselines/visual_servo.py`); the row \"damping 0\" is the pseudo-inverse.\n\n"
        + "\n".join(rows) + "\n"
    )
    (out / "rotation.md").write_text(text)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/visual_servo"))
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--detected-episodes", type=int, default=20)
    parser.add_argument("--sweep-episodes", type=int, default=20)
    parser.add_argument("--agent-episodes", type=int, default=50)
    parser.add_argument("--rotation-episodes", type=int, default=30)
    parser.add_argument("--parts", default="cases,seeds,detected,sweep")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    parts = args.parts.split(",")
    sections: dict[str, Any] = {}
    store = args.out / "sections.json"
    if store.exists():
        sections = json.loads(store.read_text())
    if "cases" in parts:
        sections["cases"] = classic_cases(args.out)
        sections["free_space"] = free_space()
    if "seeds" in parts:
        sections["seeds"] = seeds(args.episodes, args.sweep_episodes)
        sections["seeds_n"] = args.episodes
    if "detected" in parts:
        sections["detected"] = detected(args.detected_episodes)
        sections["detected_n"] = args.detected_episodes
    if "sweep" in parts:
        sections["sweep"] = sweep(args.sweep_episodes, args.out)
        sections["sweep_n"] = args.sweep_episodes
    if "rotation" in parts:
        sections["rotation"] = rotation(args.rotation_episodes, args.out)
        sections["rotation_n"] = args.rotation_episodes
    if "agent" in parts:
        sections["agent"] = agent(args.agent_episodes)
        sections["agent_n"] = args.agent_episodes
    store.write_text(json.dumps(sections, indent=1))
    print(f"wrote {store}; README.md is written by hand from these tables")


if __name__ == "__main__":
    main()
