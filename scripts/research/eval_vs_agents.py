"""Score the visual-servoing agents of ``scripts/research/train_vs.sh`` against tuned IBVS.

    python scripts/research/eval_vs_agents.py evaluate [--env cir_gym/VisualServo-v1]
        [--episodes 100] [--runs /work/main/runs/rl] [--out results/visual_servo/agents]
    python scripts/research/eval_vs_agents.py rotation [--episodes 30] [...]
    python scripts/research/eval_vs_agents.py bench [--steps 1000]

``evaluate``: every run ``<runs>/<Env>/<algo>/seed_<k>`` (its final model when it finished,
else its last checkpoint, labelled with its step count) and the env's controllers — tuned
IBVS (``tuned:ibvs``, cir_gym/scoring/tuned_gains/), the course gains — on the held-out
episodes ``TEST_SEED …`` (seeds no training, evaluation during training, study, tuning or
leaderboard run uses), by :func:`cir_gym.evaluation.evaluate`. Per policy: success with its
Wilson 95 % interval, the final feature error's IQM with a 95 % bootstrap interval
(:func:`cir_gym.agents.report.interval`, rliable's stratified bootstrap: over the training
seeds × episodes matrix when an algorithm has ≥ 2 seeds, over the episodes for one run or a
controller), and its ratio to tuned IBVS's IQM. Writes ``<out>/<Env>.md`` and
``<out>/<Env>.json`` (every episode's final error and outcome; a policy already there with the
same label, seeds and episode count is not run again, so re-running after more training
evaluates only the new checkpoints).

``rotation``: the rotation family of ``eval_visual_servo.py`` (start_offset (0, 0, 0, 0, 0, θ),
the default 0.1 px feature noise, seeds ``ROTATION_SEED …``) for the eye-in-hand agents beside
IBVS (tuned and course gains, and the mean-L law) and PBVS; the convergence region of a policy
is the largest θ up to which every angle of the list succeeds in ≥ 90 % of the episodes.
Writes ``<out>/rotation.md``.

``bench``: CPU cost of the off-policy learners on VisualServo-v1 — SB3's SAC, sb3-contrib's
TQC and CrossQ, beside PPO — with ``bench_offpolicy.py``'s settings (one gradient step of batch
256 per env step, 256×256 networks, one torch thread, ``time.process_time``), on this env.
Writes ``<out>/offpolicy_bench.md``.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_visual_servo import ROTATION_SEED, wilson

EYE_IN_HAND = "cir_gym/VisualServo-v1"
EYE_TO_HAND = "cir_gym/VisualServoEyeToHand-v1"
TEST_SEED = 7000  # held-out: no training (0…, 100_000…), study (60_000…) or other measurement
RUNS = Path("/work/main/runs/rl")
OUT = Path("results/visual_servo/agents")
#: the controllers scored beside the agents: (label, controller name, tuned)
CONTROLLERS = {
    EYE_IN_HAND: (("tuned:ibvs", "ibvs", True), ("ibvs", "ibvs", False),
                  ("pbvs", "pbvs", False)),
    EYE_TO_HAND: (("tuned:ibvs_eye_to_hand", "ibvs_eye_to_hand", True),
                  ("ibvs_eye_to_hand", "ibvs_eye_to_hand", False)),
}
ROTATION_ANGLES = (60.0, 75.0, 90.0, 120.0, 150.0, 170.0, 180.0)  # deg
REGION_SUCCESS = 0.9  # a rotation inside a policy's convergence region: ≥ 90 % success


def controller(env_id: str, name: str, tuned: bool, env_kwargs: dict[str, Any] | None = None,
               **gains: Any) -> Any:
    """A course controller at its course gains, or at the gains tuned for the projected-
    features variant (``tuned``)."""
    from cir_gym import baselines
    from cir_gym.scoring.policies import tuned_gains

    if tuned:
        gains = {**tuned_gains(env_id, name, {}), **gains}
    return baselines.make(name, env_id, env_kwargs=env_kwargs or {}, **gains)


def runs_of(root: Path, env_id: str) -> list[Path]:
    """The run directories ``<root>/<Env>/<algo>/seed_<k>`` that hold a config."""
    base = root / env_id.split("/")[1]
    return sorted(p.parent for p in base.glob("*/seed_*/config.yml"))


def snapshot(run: Path, root: Path) -> tuple[Path, int, bool]:
    """(agent directory, steps, finished) of a run: the run itself when it finished, else its
    last checkpoint as an agent directory under ``<root>/snapshots/`` (config, model.zip and
    the checkpoint's VecNormalize statistics as normalization.npz)."""
    meta = run / "meta.json"
    if meta.exists() and json.loads(meta.read_text()).get("finished"):
        return run, int(json.loads(meta.read_text())["timesteps"]), True
    steps = sorted(int(m.group(1)) for f in (run / "checkpoints").glob("model_*_steps.zip")
                   if (m := re.fullmatch(r"model_(\d+)_steps\.zip", f.name)))
    if not steps:
        raise FileNotFoundError(f"{run}: no checkpoint yet")
    k = steps[-1]
    dest = root / "snapshots" / run.relative_to(root) / f"step_{k}"
    if not (dest / "normalization.npz").exists():
        import pickle

        dest.mkdir(parents=True, exist_ok=True)
        shutil.copy2(run / "config.yml", dest / "config.yml")
        shutil.copy2(run / "checkpoints" / f"model_{k}_steps.zip", dest / "model.zip")
        with (run / "checkpoints" / f"model_vecnormalize_{k}_steps.pkl").open("rb") as f:
            vn = pickle.load(f)  # our own training's checkpoint: a trusted pickle
        np.savez(dest / "normalization.npz", norm_obs=bool(vn.norm_obs),
                 obs_mean=vn.obs_rms.mean, obs_var=vn.obs_rms.var,
                 clip_obs=float(vn.clip_obs), epsilon=float(vn.epsilon))
    return dest, k, False


def outcomes(res: Any) -> dict[str, list]:
    eps = res.episodes
    return {"final_feature_error": [float(e.metrics["final_feature_error"]) for e in eps],
            "success": [bool(e.success) for e in eps],
            "terminated": [bool(e.terminated) for e in eps],
            "convergence_time": [float(e.metrics["convergence_time"]) for e in eps]}


def row(label: str, finals: np.ndarray, success: np.ndarray, ended: int, t_conv: float,
        reference: float | None) -> str:
    """One table row; ``finals`` and ``success`` (runs × episodes)."""
    from cir_gym.agents.report import interval

    x = finals if finals.shape[0] > 1 else finals.T  # one run: bootstrap the episodes
    point, lo, hi = interval(x)
    wins, n = int(success.sum()), success.size
    low, high = wilson(wins, n)
    ratio = f"{point / reference:.2f}" if reference else "–"
    return (f"| {label} | {wins}/{n} = {100 * wins / n:.1f} % ({100 * low:.1f}–{100 * high:.1f}) "
            f"| {point:.3f} ({lo:.3f}–{hi:.3f}) | {ratio} | {np.median(finals):.3f} | {ended} "
            f"| {t_conv:.2f} |")


def evaluate_env(env_id: str, episodes: int, root: Path, out: Path) -> Path:
    from cir_gym.agents.policy import load_agent

    from cir_gym.evaluation import evaluate

    stem = out / env_id.split("/")[1]
    earlier: dict[str, dict[str, Any]] = {}  # the last call's episodes, reused when unchanged
    if stem.with_suffix(".json").exists():
        old = json.loads(stem.with_suffix(".json").read_text())
        if (old["seed"], old["episodes"]) == (TEST_SEED, episodes):
            earlier = old["results"]
    results: dict[str, dict[str, Any]] = {}
    for label, name, tuned in CONTROLLERS[env_id]:
        if label not in earlier:
            res = evaluate(controller(env_id, name, tuned), env_id, episodes, TEST_SEED,
                           policy_name=label)
            earlier[label] = {"kind": "controller", **outcomes(res)}
        results[label] = earlier[label]
        print(label, np.mean(results[label]["success"]), flush=True)
    for run in runs_of(root, env_id):
        try:
            agent_dir, steps, finished = snapshot(run, root)
        except FileNotFoundError as exc:
            print(exc, flush=True)
            continue
        algo, seed = run.parent.name, run.name
        label = f"{algo} {seed.replace('_', ' ')} @ {steps / 1e6:.2f} M steps" + \
            ("" if finished else " (in training)")
        if label not in earlier:
            res = evaluate(load_agent(agent_dir, env_id), env_id, episodes, TEST_SEED,
                           policy_name=label)
            earlier[label] = {"kind": "agent", "algo": algo, "run": str(run), "steps": steps,
                              "finished": finished, **outcomes(res)}
        results[label] = earlier[label]
        print(label, np.mean(results[label]["success"]), flush=True)
    reference_label = CONTROLLERS[env_id][0][0]
    ref = results[reference_label]
    from cir_gym.agents.report import iqm

    reference = iqm(np.array(ref["final_feature_error"]))
    lines = [f"# Agents on {env_id.split('/')[1]} against tuned IBVS", "",
             f"Written by `python scripts/research/eval_vs_agents.py evaluate --env {env_id} "
             f"--episodes {episodes}`: seeds {TEST_SEED}–{TEST_SEED + episodes - 1} (held out "
             "from training, its evaluations and the study), deterministic actions, "
             "`cir_gym.evaluation.evaluate`. Success: final feature error < 1 px, no feature "
             "lost, no joint limit. Final error: IQM over the episodes (over seeds × episodes "
             "for an algorithm's seeds together) with rliable's 95 % stratified-bootstrap "
             "interval; success with Wilson's 95 % interval. Ratio: IQM / tuned IBVS's IQM "
             "(the target: ≤ 3). Runs still in training are scored at their last checkpoint.",
             "", "| policy | success (95 %) | final error IQM, px (95 %) | ratio to "
             f"{reference_label} | median final error (px) | ended early | convergence time "
             "(s), median |", "|---|---:|---:|---:|---:|---:|---:|"]
    by_algo: dict[str, list[dict[str, Any]]] = {}
    for label, r in results.items():
        f = np.array(r["final_feature_error"])[None, :]
        s = np.array(r["success"], dtype=float)[None, :]
        lines.append(row(label, f, s, int(sum(r["terminated"])),
                         float(np.median(r["convergence_time"])), reference))
        if r["kind"] == "agent":
            by_algo.setdefault(r["algo"], []).append(r)
    for algo, rs in by_algo.items():
        if len(rs) > 1:
            f = np.array([r["final_feature_error"] for r in rs])
            s = np.array([r["success"] for r in rs], dtype=float)
            ended = int(sum(sum(r["terminated"]) for r in rs))
            t = float(np.median([r["convergence_time"] for r in rs]))
            lines.append(row(f"**{algo}, {len(rs)} seeds**", f, s, ended, t, reference))
    out.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    stem.with_suffix(".json").write_text(json.dumps(
        {"env_id": env_id, "seed": TEST_SEED, "episodes": episodes, "results": results},
        indent=1))
    print("\n".join(lines))
    return stem.with_suffix(".md")


def rotation(episodes: int, root: Path, out: Path) -> Path:
    from cir_gym.agents.policy import load_agent

    from cir_gym.evaluation import evaluate

    env_id = EYE_IN_HAND
    policies: list[tuple[str, Any]] = []
    for run in runs_of(root, env_id):
        try:
            agent_dir, steps, finished = snapshot(run, root)
        except FileNotFoundError:
            continue
        label = f"{run.parent.name} {run.name.replace('_', ' ')} @ {steps / 1e6:.2f} M steps"
        policies.append((label + ("" if finished else " (in training)"),
                         load_agent(agent_dir, env_id)))
    laws = (("tuned:ibvs", "ibvs", True, {}), ("ibvs", "ibvs", False, {}),
            ("ibvs (mean L)", "ibvs", False, {"depth": "mean"}), ("pbvs", "pbvs", False, {}))
    makers = [(label, lambda kw, a=agent: a) for label, agent in policies]
    makers += [(label, lambda kw, n=name, t=tuned, g=gains: controller(env_id, n, t, kw, **g))
               for label, name, tuned, gains in laws]
    rows = ["| policy | " + " | ".join(f"{a:.0f}°" for a in ROTATION_ANGLES)
            + " | convergence region |", "|---|" + "---:|" * (len(ROTATION_ANGLES) + 1)]
    for label, make in makers:
        rates = []
        for deg in ROTATION_ANGLES:
            kwargs = {"start_offset": (0.0, 0.0, 0.0, 0.0, 0.0, float(np.deg2rad(deg)))}
            res = evaluate(make(kwargs), env_id, episodes, ROTATION_SEED, policy_name=label,
                           **kwargs)
            rates.append(res.success_rate)
        region = None  # the largest angle up to which every angle is inside
        for a, r in zip(ROTATION_ANGLES, rates, strict=True):
            if r < REGION_SUCCESS:
                break
            region = a
        cell = f"< {ROTATION_ANGLES[0]:.0f}°" if region is None else f"{region:.0f}°"
        rows.append(f"| {label} | " + " | ".join(f"{100 * r:.0f} %" for r in rates)
                    + f" | {cell} |")
        print(rows[-1], flush=True)
    text = ("# Rotation family: agents against IBVS\n\n"
            "Written by `python scripts/research/eval_vs_agents.py rotation --episodes "
            f"{episodes}`: `{env_id}` from start_offset (0, 0, 0, 0, 0, θ) with the default "
            f"0.1 px feature noise, seeds {ROTATION_SEED}–{ROTATION_SEED + episodes - 1}; "
            "success rate per angle; convergence region: the largest θ up to which every "
            f"angle succeeds in ≥ {100 * REGION_SUCCESS:.0f} % of the episodes.\n\n"
            + "\n".join(rows) + "\n")
    out.mkdir(parents=True, exist_ok=True)
    (out / "rotation.md").write_text(text)
    return out / "rotation.md"


def bench(steps: int, out: Path) -> Path:
    """bench_offpolicy.py's measurement with its env swapped for VisualServo-v1's."""
    import bench_offpolicy as bo
    import gymnasium as gym
    import torch
    from cir_gym.agents.observation import ObservationLayout
    from cir_gym.agents.train import EnvFactory
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv

    torch.set_num_threads(1)

    def env(n: int = 1) -> Any:
        probe = gym.make(EYE_IN_HAND)
        layout = ObservationLayout.from_space(probe.observation_space)
        return DummyVecEnv([EnvFactory(EYE_IN_HAND, {}, layout)] * n)

    bo._env = env  # the benchmark's env factory, on this task
    from sb3_contrib import TQC, CrossQ

    rows = [("PPO, SB3, 16 envs, n_epochs 10", bo._ppo(8 * 2048)),
            ("SAC, SB3", bo._off_policy(SAC, steps, device="cpu")),
            ("TQC, sb3-contrib", bo._off_policy(TQC, steps, device="cpu")),
            ("CrossQ, sb3-contrib", bo._off_policy(CrossQ, steps, device="cpu"))]
    lines = ["# Off-policy training cost on VisualServo-v1", "",
             "Written by `python scripts/research/eval_vs_agents.py bench --steps "
             f"{steps}` (`bench_offpolicy.py`'s measurement on this env): environment steps "
             "per CPU-second of the training process (`time.process_time`) after a 1200-step "
             "warm-up; off-policy: one gradient step of batch 256 per environment step, "
             "256×256 networks (CrossQ: its batch-normalised critic, no target network); one "
             "torch thread. The env step alone costs ~0.8 ms.", "",
             "| algorithm | env steps per CPU-second |", "|---|---:|",
             *[f"| {a} | {r:.0f} |" for a, r in rows], ""]
    out.mkdir(parents=True, exist_ok=True)
    (out / "offpolicy_bench.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return out / "offpolicy_bench.md"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("evaluate", help="agents and controllers on the held-out seeds")
    e.add_argument("--env", default=EYE_IN_HAND, choices=sorted(CONTROLLERS))
    e.add_argument("--episodes", type=int, default=100)
    r = sub.add_parser("rotation", help="the rotation family")
    r.add_argument("--episodes", type=int, default=30)
    b = sub.add_parser("bench", help="off-policy CPU cost")
    b.add_argument("--steps", type=int, default=1000)
    for p in (e, r, b):
        p.add_argument("--runs", type=Path, default=RUNS)
        p.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    if args.cmd == "evaluate":
        evaluate_env(args.env, args.episodes, args.runs, args.out)
    elif args.cmd == "rotation":
        rotation(args.episodes, args.runs, args.out)
    else:
        bench(args.steps, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
