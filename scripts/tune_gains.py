"""The controllers get a tuning budget too: an Optuna gain search per leaderboard variant.

    python scripts/tune_gains.py [--env cir_gym/JointTracking-v1] [--controller pd_gravity ...]
                                 [--trials 24] [--train-episodes 3] [--out results/tuning]

An RL agent is tuned (hyperparameters, millions of steps); a controller at the course's default
gains is not. For every leaderboard variant of the environment (``leaderboard_variants``) and
every controller asked for, Optuna's TPE sampler (seeded) searches the controller's gains
within :data:`BOUNDS` to minimise the mean primary metric over *training* episodes (seeds
``TRAIN_SEED …``, disjoint from the leaderboard's 1000–1009 and the learning curves'
100000–); a trial whose gains are rejected by the controller (``InvalidGain``) or whose
episodes diverge scores +inf. The best gains and the defaults are then scored on the
leaderboard's episodes (10, seeds 1000–1009) and written side by side to
``<out>/<Env-vN>.md`` and ``.json`` (the Optuna study is saved beside them as SQLite).

Bounds (documented, physical):

* ``omega``, ``omega_n`` (rad/s) in [1, 150]: the closed loop must stay well inside the
  500-Hz sampling (ω·dt ≤ 0.3 at dt = 2 ms, so the discrete loop behaves like the continuous
  design the course's gain rules assume); log-uniform.
* ``zeta`` in [0.3, 3]: from lightly to heavily damped; log-uniform.
* ``gain`` (visual servoing's λ, 1/s) in [0.05, 7.5]: λ·Δt ≤ 0.3 at the 25-Hz (40 ms) camera
  rate, the same discrete-loop margin as ω above; log-uniform. The camera-velocity limits are
  the env's (the command is clipped).
* Actuator limits are the environment's own (torques clipped at τ_max, counted in
  ``saturation``), and so is whatever sensing/actuation model the variant's arguments set
  (the tuned gains are searched and scored on the same env arguments as the leaderboard).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import baselines
import cir_gym
from cir_gym.evaluation import evaluate

TRAIN_SEED = 0
LEADERBOARD_SEED, LEADERBOARD_EPISODES = 1000, 10

#: gain → (low, high), searched log-uniformly; see the module docstring
BOUNDS: dict[str, tuple[float, float]] = {
    "omega": (1.0, 150.0),
    "omega_n": (1.0, 150.0),
    "zeta": (0.3, 3.0),
    "gain": (0.05, 7.5),
}
DEFAULT_CONTROLLERS = ("pd_gravity", "computed_torque")


def tunable_gains(controller: str) -> dict[str, float]:
    """{gain: default} of the controller's Gains fields that have bounds in :data:`BOUNDS`."""
    import dataclasses

    gains_cls = baselines.CONTROLLERS[controller].Gains
    return {f.name: f.default for f in dataclasses.fields(gains_cls) if f.name in BOUNDS}


def score(controller: str, env_id: str, env_kwargs: dict[str, Any], gains: dict[str, float],
          episodes: int, seed: int) -> dict[str, float]:
    """Mean primary metric (and success, saturation, divergence) of the controller with gains."""
    primary = cir_gym.ENVIRONMENTS[env_id][0].primary_metric
    policy = baselines.make(controller, env_id, env_kwargs=env_kwargs, **gains)
    result = evaluate(policy, env_id, episodes, seed, **env_kwargs)
    out = {primary: result.summary[primary]["mean"], "success": result.success_rate,
           "divergence": result.divergence_rate}
    if "saturation" in result.summary:
        out["saturation"] = result.summary["saturation"]["mean"]
    return out


def tune(controller: str, env_id: str, variant: str, env_kwargs: dict[str, Any], *,
         trials: int, train_episodes: int, out: Path, sampler_seed: int = 0) -> dict[str, Any]:
    """One Optuna study: best gains on the training seeds; returns the study summary."""
    import optuna

    primary = cir_gym.ENVIRONMENTS[env_id][0].primary_metric
    defaults = tunable_gains(controller)
    if not defaults:
        raise ValueError(f"{controller} has no gain with documented bounds ({sorted(BOUNDS)})")
    name = f"{env_id.split('/')[-1]}-{variant.replace(' ', '_')}-{controller}"
    storage = f"sqlite:///{out / 'studies.db'}"
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(study_name=name, storage=storage, direction="minimize",
                                sampler=optuna.samplers.TPESampler(seed=sampler_seed),
                                load_if_exists=False)
    study.enqueue_trial(defaults)  # the course's gains are trial 0

    def objective(trial: Any) -> float:
        gains = {g: trial.suggest_float(g, *BOUNDS[g], log=True) for g in defaults}
        try:
            s = score(controller, env_id, env_kwargs, gains, train_episodes, TRAIN_SEED)
        except baselines.InvalidGain:
            return math.inf
        if s["divergence"] > 0 or not np.isfinite(s[primary]):
            return math.inf
        trial.set_user_attr("train", s)
        return s[primary]

    t0 = time.perf_counter()
    study.optimize(objective, n_trials=trials)
    return {"study": name, "trials": trials, "train_episodes": train_episodes,
            "train_seed": TRAIN_SEED, "best_train": study.best_value,
            "default_train": study.trials[0].value, "tuned": study.best_params,
            "default": defaults, "seconds": round(time.perf_counter() - t0, 1)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env", default="cir_gym/JointTracking-v1")
    p.add_argument("--controller", action="append", help="repeatable (default: pd_gravity, "
                                                         "computed_torque)")
    p.add_argument("--trials", type=int, default=24)
    p.add_argument("--train-episodes", type=int, default=3)
    p.add_argument("--episodes", type=int, default=LEADERBOARD_EPISODES,
                   help="leaderboard episodes for the side-by-side scores")
    p.add_argument("--variant", action="append", help="restrict to these variants")
    p.add_argument("--out", default="results/tuning")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="environment argument added to every variant (e.g. a short "
                        "episode_duration for a smoke run; results then differ)")
    args = p.parse_args(argv)
    extra = {}
    for item in args.set:
        key, _, value = item.partition("=")
        extra[key] = float(value)
    env_id = args.env.split(":")[-1]
    if env_id not in cir_gym.ENVIRONMENTS:
        p.error(f"unknown environment {env_id!r}; valid: {sorted(cir_gym.ENVIRONMENTS)}")
    cls = cir_gym.ENVIRONMENTS[env_id][0]
    primary = cls.primary_metric
    variants = getattr(cls, "leaderboard_variants", {"default": {}})
    if args.variant:
        unknown = sorted(set(args.variant) - set(variants))
        if unknown:
            p.error(f"unknown variant(s) {unknown}; valid: {sorted(variants)}")
        variants = {v: variants[v] for v in args.variant}
    variants = {v: {**kw, **extra} for v, kw in variants.items()}
    controllers = args.controller or [c for c in DEFAULT_CONTROLLERS
                                      if c in baselines.available(env_id)]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = out / env_id.split("/")[-1]
    results: list[dict[str, Any]] = []
    for variant, kwargs in variants.items():
        for c in controllers:
            r = tune(c, env_id, variant, kwargs, trials=args.trials,
                     train_episodes=args.train_episodes, out=out)
            r["leaderboard_default"] = score(c, env_id, kwargs, r["default"], args.episodes,
                                             LEADERBOARD_SEED)
            r["leaderboard_tuned"] = score(c, env_id, kwargs, r["tuned"], args.episodes,
                                           LEADERBOARD_SEED)
            r.update(variant=variant, env_kwargs=kwargs, controller=c)
            results.append(r)
            print(f"{variant:24s} {c:18s} default {r['leaderboard_default'][primary]:.3g} "
                  f"tuned {r['leaderboard_tuned'][primary]:.3g} {r['tuned']}", file=sys.stderr)
    stem.with_suffix(".json").write_text(json.dumps(results, indent=2) + "\n")
    lines = [
        f"# Controller gains tuned with Optuna: {env_id}",
        "",
        f"Generated by `python scripts/tune_gains.py --env {env_id}"
        + "".join(f" --set {k}={v:g}" for k, v in extra.items())
        + f" --out {args.out}` (TPE, seeded; "
        f"{args.trials} trials of {args.train_episodes} training episodes, seeds "
        f"{TRAIN_SEED}–{TRAIN_SEED + args.train_episodes - 1}; the default gains are trial 0). "
        f"Scored on the leaderboard's {args.episodes} episodes (seeds {LEADERBOARD_SEED}–"
        f"{LEADERBOARD_SEED + args.episodes - 1}). Bounds: "
        + ", ".join(f"{g} ∈ [{lo:g}, {hi:g}]" for g, (lo, hi) in BOUNDS.items())
        + " (log-uniform; scripts/tune_gains.py says why).",
        "",
        f"| variant | controller | default gains | {primary} | success | tuned gains | "
        f"{primary} | success | saturation (default → tuned) | factor |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        d, t = r["leaderboard_default"], r["leaderboard_tuned"]
        fmt = ", ".join
        lines.append(
            f"| {r['variant']} | {r['controller']} | "
            f"{fmt(f'{k} {v:g}' for k, v in r['default'].items())} | {d[primary]:.3g} | "
            f"{d['success']:.0%} | {fmt(f'{k} {v:.3g}' for k, v in r['tuned'].items())} | "
            f"{t[primary]:.3g} | {t['success']:.0%} | "
            f"{d.get('saturation', float('nan')):.2g} → {t.get('saturation', float('nan')):.2g}"
            f" | {d[primary] / t[primary]:.1f}× |")
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(stem.with_suffix(".md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
