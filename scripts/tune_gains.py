"""The controllers get a tuning budget too: an Optuna gain search per leaderboard variant.

    python scripts/tune_gains.py [--env cir_gym/JointTracking-v2] [--controller pd_gravity ...]
                                 [--trials 24] [--train-episodes 3] [--out results/tuning]

An RL agent is tuned (hyperparameters, millions of steps); a controller at the course's default
gains is not. For every leaderboard variant of the environment (``leaderboard_variants``) and
every controller asked for, Optuna's TPE sampler (seeded) searches the controller's gains
within :data:`BOUNDS` to minimise the mean primary metric over *training* episodes (seeds
``TRAIN_SEED …``, disjoint from the leaderboard's 1000–1009 and the learning curves'
100000–); a trial whose gains are rejected by the controller (``InvalidGain``) or whose
episodes diverge scores +inf. The best gains and the defaults are then scored on the
leaderboard's episodes (10, seeds 1000–1009): the report goes to ``<out>/<Env-vN>.md`` (the
Optuna study beside it as SQLite), the gains to ``<gains-out>/<Env-vN>.json`` (default ``<out>``;
``--gains-out cir_gym/scoring/tuned_gains`` updates the package's, which
``tuned:<controller>`` reads).

A run resumes: a study already in ``<out>/studies.db`` continues with the trials it still
lacks (completed trials count, one left running by a stopped process does not), a study that
has them all is not searched again, and a row whose tuned gains are already scored in the gains
file is not scored again. Each study's row is merged into ``<gains-out>/<Env-vN>.json`` (and
the report rewritten) as soon as it ends, replacing the row of the same (variant, controller)
and keeping the others: a run of some variants or controllers updates just those.

Which gains are searched: a controller's rate gains and damping ratio (below) by default;
:data:`SEARCHED` names the gains of the controllers whose law has more (the interaction and
peg-in-hole laws: stiffnesses, force-loop ratios, the insertion speed; the adaptive law's Λ,
K_D and adaptation gain). A null-space gain
``k0_<objective>`` is searched only on the RedundantIK variant of that objective (elsewhere it
does nothing). A gain whose default is None (the law's own rule) is searched only where that
rule gives one number for every joint, which is then its default: the decentralized cascades'
ω_cv and ω_cp on rigid joints (80 and 16 rad/s), not their per-joint design on elastic ones.

What a trial scores: the variant's own primary metric (``variant_primary_metric``, e.g.
``min_manipulability`` on RedundantIK's manipulability variant), signed by the metric's
direction; a trial whose success rate on the training episodes is below the default gains'
scores +inf, like one that diverges or whose gains the controller rejects: the leaderboard
ranks on success first, so the search may not buy precision with failed episodes. When the
default gains fail every training episode, that metric gives the search no slope, or a wrong
one (PegInHole's insertion time is then the 12-s cap on every trial; RedundantIK's
manipulability is bought by not tracking the path at all), so such a study maximises the
episode return instead, the env's own measure of progress on the task (``searched_on`` in the
results).

Bounds (documented, physical), all searched log-uniformly; Δt is the env's control period
(``1/control_freq`` of the variant's arguments):

* rate gains of a second-order loop, ``omega``, ``omega_n`` (rad/s), and the force loop's
  ``crossover`` and the motion loop's ``motion_omega`` (rad/s): [1, 0.3/Δt]. The closed loop
  must stay well inside the sampling (ω·Δt ≤ 0.3: 150 rad/s at 500 Hz), so the discrete loop
  behaves like the continuous design the course's gain rules assume.
* visual servoing's λ, ``gain`` (1/s): [0.05, 0.3/Δt] (7.5 at the 25-Hz camera), the same
  margin; the camera-velocity limits are the env's (the command is clipped).
* CLIK's ``K`` (1/s): [1, 1/Δt]. The env integrates the commanded q̇ exactly over Δt, so the
  task error obeys e⁺ = (1 − KΔt) e: KΔt = 1 is dead-beat, beyond it the error overshoots
  every step (and diverges at KΔt = 2).
* the adaptive law's Λ = λ I, ``lam`` (1/s, the pole of its sliding variable σ = q̃̇ + Λ q̃):
  [1, 0.3/Δt] too; its ``kd`` and adaptation gain ``gamma`` a decade either side.
* the cascades' speed-loop bandwidth ``omega_cv`` and position-loop crossover ``omega_cp``
  (rad/s): [1, 0.3/Δt] like any rate gain, and ω_cp below the ω_cv of its trial (the law
  rejects ω_cp ≥ ω_cv: the position loop must be the slower one).
* ``zeta`` in [0.3, 3]: from lightly to heavily damped.
* every other searched gain (stiffnesses, dampings, ratios, speeds, null-space gains), which
  has no physical bound of its own: a decade either side of the course's value.
* Actuator limits are the environment's own (torques clipped at τ_max, counted in
  ``saturation``), and so is whatever sensing/actuation model the variant's arguments set
  (the tuned gains are searched and scored on the same env arguments as the leaderboard).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

import cir_gym
from cir_gym import baselines
from cir_gym.evaluation import evaluate, variant_primary_metric
from cir_gym.scoring.policies import TUNED_GAINS_DIR

TRAIN_SEED = 0
LEADERBOARD_SEED, LEADERBOARD_EPISODES = 1000, 10

#: rate gain → (low, margin): searched in [low, margin/Δt]; see the module docstring
RATE_BOUNDS: dict[str, tuple[float, float]] = {
    "omega": (1.0, 0.3),
    "omega_n": (1.0, 0.3),
    "crossover": (1.0, 0.3),
    "motion_omega": (1.0, 0.3),
    "gain": (0.05, 0.3),
    "K": (1.0, 1.0),
    "omega_cv": (1.0, 0.3),
    "omega_cp": (1.0, 0.3),
    "lam": (1.0, 0.3),
}
#: gain → the gain it must stay below (sampled after it, its upper bound capped there)
BELOW: dict[str, str] = {"omega_cp": "omega_cv"}
#: gain → (low, high), whatever the control period
FIXED_BOUNDS: dict[str, tuple[float, float]] = {"zeta": (0.3, 3.0)}
#: any other searched gain: [default / DECADE, default · DECADE]
DECADE = 10.0
#: controller → the gains its search covers, where more than its rate gains and ζ
SEARCHED: dict[str, tuple[str, ...]] = {
    "clik_nullspace": ("K", "k0_manipulability", "k0_joint_limits", "k0_obstacle"),
    "clik_projected_gradient": ("K", "k0_manipulability", "k0_joint_limits", "k0_obstacle"),
    "impedance": ("normal_stiffness", "zeta"),
    "admittance": ("crossover", "motion_omega"),
    "explicit_force": ("crossover_ratio", "zeta"),
    "implicit_force": ("crossover", "integral_ratio"),
    "parallel_force_position": ("crossover", "proportional"),
    "hybrid_force_position": ("omega_n", "zeta", "crossover_ratio", "d_f", "speed"),
    "hybrid_spiral": ("omega_n", "zeta", "crossover_ratio", "d_f", "speed"),
    "position_only": ("k_p", "k_d", "speed"),
    "adaptive": ("lam", "kd", "gamma"),
}


def tunable_gains(controller: str, env_id: str, objective: str | None = None,
                  env_kwargs: dict[str, Any] | None = None) -> dict[str, float]:
    """{gain: default} searched for ``controller`` on ``env_id``: the gains of :data:`SEARCHED`
    (else its rate gains and ζ) whose default is a number; a ``k0_<objective>`` only for that
    RedundantIK ``objective``. A rate gain whose default is None (the law's own rule, e.g. the
    cascades' ω_cv and ω_cp) is searched when ``env_kwargs`` is given and the law, built for
    the env with those arguments, sets it to one number for every joint (that number is then
    its default); a per-joint design (ω_cv = 0.7 ω_z on elastic joints) is left as designed."""
    import dataclasses

    fields = {f.name: f.default
              for f in dataclasses.fields(baselines.controller_class(controller, env_id).Gains)}
    names = SEARCHED.get(controller, tuple(n for n in fields
                                          if n in RATE_BOUNDS or n in FIXED_BOUNDS))
    names = [n for n in names if n in fields
             and (not n.startswith("k0_") or n == f"k0_{objective}")]
    ruled = [n for n in names if fields[n] is None and n in RATE_BOUNDS]
    if ruled and env_kwargs is not None:
        built = baselines.make(controller, env_id, env_kwargs=env_kwargs)
        for n in ruled:
            value = np.unique(np.asarray(getattr(built, n, np.nan), dtype=float))
            if value.size == 1 and np.isfinite(value[0]):
                fields[n] = float(value[0])
    return {
        n: float(fields[n]) for n in names
        if isinstance(fields[n], (int, float)) and not isinstance(fields[n], bool)
    }


def bounds(gain: str, default: float, dt: float) -> tuple[float, float]:
    """(low, high) of ``gain`` (course value ``default``) at control period ``dt`` (s)."""
    if gain in RATE_BOUNDS:
        low, margin = RATE_BOUNDS[gain]
        return low, margin / dt
    if gain in FIXED_BOUNDS:
        return FIXED_BOUNDS[gain]
    return default / DECADE, default * DECADE


def variant_setting(env_id: str, env_kwargs: dict[str, Any]) -> tuple[float, str | None]:
    """(control period Δt in s, RedundantIK's objective or None) of the env with a variant's
    arguments (made, not reset)."""
    import gymnasium as gym

    env = gym.make(env_id, **env_kwargs)
    try:
        return float(env.unwrapped.dt), getattr(env.unwrapped, "objective", None)
    finally:
        env.close()


def score(controller: str, env_id: str, variant: str, env_kwargs: dict[str, Any],
          gains: dict[str, float], episodes: int, seed: int) -> dict[str, Any]:
    """The variant's primary metric (mean over the episodes, with its name and direction),
    success, divergence and saturation rates of the controller with ``gains``."""
    metric = variant_primary_metric(cir_gym.ENVIRONMENTS[env_id][0], variant)
    policy = baselines.make(controller, env_id, env_kwargs=env_kwargs, **gains)
    result = evaluate(policy, env_id, episodes, seed, **env_kwargs)
    out = {"metric": metric, "better": result.spec(metric).better,
           "value": result.summary[metric]["mean"], "return": result.summary["return"]["mean"],
           "success": result.success_rate,
           "divergence": result.divergence_rate}
    if "saturation" in result.summary:
        out["saturation"] = result.summary["saturation"]["mean"]
    return out


def tune(controller: str, env_id: str, variant: str, env_kwargs: dict[str, Any], *,
         trials: int, train_episodes: int, out: Path, sampler_seed: int = 0) -> dict[str, Any]:
    """One Optuna study: best gains on the training seeds; returns the study summary."""
    import optuna

    dt, objective_name = variant_setting(env_id, env_kwargs)
    defaults = tunable_gains(controller, env_id, objective_name, env_kwargs)
    if not defaults:
        raise ValueError(f"{controller} has no searchable gain on {env_id} (scripts/tune_gains.py"
                         f" searches {sorted(RATE_BOUNDS) + sorted(FIXED_BOUNDS)} and SEARCHED)")
    space = {g: bounds(g, v, dt) for g, v in defaults.items()}
    name = f"{env_id.split('/')[-1]}-{variant.replace(' ', '_')}-{controller}"
    storage = f"sqlite:///{out / 'studies.db'}"
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    # a study of this name in the storage is continued: the trials it completed count, so a
    # run stopped half-way (or a whole environment's run) resumes where it stood
    study = optuna.create_study(study_name=name, storage=storage, direction="minimize",
                                sampler=optuna.samplers.TPESampler(seed=sampler_seed),
                                load_if_exists=True)
    # the course's gains are trial 0 (clamped into the bounds if they lie outside)
    start = {g: min(max(v, space[g][0]), space[g][1]) for g, v in defaults.items()}
    if default_trial(study, start) is None:
        study.enqueue_trial(start)
    # set by the default gains' trial: the success rate no trial may fall below, and the
    # metric searched on (the variant's, or the return when the defaults never succeed)
    floor: dict[str, Any] = {}
    first = default_trial(study, start)
    if first is not None:
        set_floor(floor, first.user_attrs["train"])

    def objective(trial: Any) -> float:
        gains: dict[str, float] = {}
        for g in defaults:  # a gain of BELOW after the one it must stay below
            low, high = space[g]
            if BELOW.get(g) in gains:
                high = min(high, gains[BELOW[g]] * (1.0 - 1e-9))
            gains[g] = trial.suggest_float(g, low, high, log=True)
        try:
            s = score(controller, env_id, variant, env_kwargs, gains, train_episodes,
                      TRAIN_SEED)
        except baselines.InvalidGain:
            return math.inf
        if not floor:
            set_floor(floor, s)
        trial.set_user_attr("train", s)
        value, better = ((s["value"], s["better"]) if floor["on"] == s["metric"]
                         else (s["return"], "higher"))
        if s["divergence"] > 0 or not np.isfinite(value) or s["success"] < floor["success"]:
            return math.inf
        return value if better == "lower" else -value

    study.optimize(objective, n_trials=max(trials - len(completed(study)), 0))
    done = completed(study)
    first = default_trial(study, start)
    return {"study": name, "trials": len(done), "train_episodes": train_episodes,
            "train_seed": TRAIN_SEED, "best_train": study.best_value,
            "default_train": first.value if first is not None else math.nan,
            "tuned": study.best_params, "default": defaults, "bounds": space,
            "searched_on": floor.get("on"),
            "seconds": round(sum(t.duration.total_seconds() for t in done), 1)}


def completed(study: Any) -> list[Any]:
    """The study's completed trials (a trial left running by a stopped process is not)."""
    import optuna

    return study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))


def default_trial(study: Any, start: dict[str, float]) -> Any:
    """The completed trial of the default gains ``start`` (the study's first), or None."""
    for t in completed(study):
        if t.params == start and "train" in t.user_attrs:
            return t
    return None


def set_floor(floor: dict[str, Any], train: dict[str, Any]) -> None:
    """What the default gains' training score sets for every trial (see :func:`tune`)."""
    floor.update(success=train["success"],
                 on=train["metric"] if train["success"] > 0 else "return")


def merge_rows(path: Path, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The tuned-gain rows of ``path`` (if it exists) with ``rows`` in place of those of the
    same (variant, controller); new ones appended. Written back to ``path`` and returned, so
    a run of some variants or controllers keeps the file's other rows."""
    new = {(r["variant"], r["controller"]): r for r in rows}
    old = json.loads(path.read_text()) if path.exists() else []
    merged = [new.pop((r["variant"], r["controller"]), r) for r in old] + list(new.values())
    path.write_text(json.dumps(merged, indent=2) + "\n")
    return merged


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env", default="cir_gym/JointTracking-v2")
    p.add_argument("--controller", action="append",
                   help="repeatable (default: every controller of the env with a searchable "
                        "gain)")
    p.add_argument("--trials", type=int, default=24)
    p.add_argument("--train-episodes", type=int, default=3)
    p.add_argument("--episodes", type=int, default=LEADERBOARD_EPISODES,
                   help="leaderboard episodes for the side-by-side scores")
    p.add_argument("--variant", action="append", help="restrict to these variants")
    p.add_argument("--out", default="results/tuning", help="the report and the Optuna study")
    p.add_argument("--gains-out", default=None,
                   help=f"the tuned gains, <Env-vN>.json (default: --out; {TUNED_GAINS_DIR} "
                        "is the package's, which tuned:<controller> reads)")
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
    variants = getattr(cls, "leaderboard_variants", {"default": {}})
    if args.variant:
        unknown = sorted(set(args.variant) - set(variants))
        if unknown:
            p.error(f"unknown variant(s) {unknown}; valid: {sorted(variants)}")
        variants = {v: variants[v] for v in args.variant}
    variants = {v: {**kw, **extra} for v, kw in variants.items()}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = out / env_id.split("/")[-1]
    gains_out = Path(args.gains_out or args.out)
    gains_out.mkdir(parents=True, exist_ok=True)
    gains_file = gains_out / f"{stem.name}.json"
    earlier = {(r["variant"], r["controller"]): r
               for r in (json.loads(gains_file.read_text()) if gains_file.exists() else [])}
    rows: list[dict[str, Any]] = []
    for variant, kwargs in variants.items():
        objective = variant_setting(env_id, kwargs)[1]
        for c in args.controller or [c for c in baselines.available(env_id)
                                     if tunable_gains(c, env_id, objective, kwargs)]:
            r = tune(c, env_id, variant, kwargs, trials=args.trials,
                     train_episodes=args.train_episodes, out=out)
            r.update(variant=variant, env_kwargs=kwargs, controller=c)
            known = earlier.get((variant, c), {})
            if (known.get("tuned") == r["tuned"] and known.get("default") == r["default"]
                    and "leaderboard_tuned" in known):  # a resumed run: scored already
                r["leaderboard_default"] = known["leaderboard_default"]
                r["leaderboard_tuned"] = known["leaderboard_tuned"]
            else:
                r["leaderboard_default"] = score(c, env_id, variant, kwargs, r["default"],
                                                 args.episodes, LEADERBOARD_SEED)
                r["leaderboard_tuned"] = score(c, env_id, variant, kwargs, r["tuned"],
                                               args.episodes, LEADERBOARD_SEED)
            rows.append(r)
            # written after every study, so that a stopped run keeps what it finished
            merged = merge_rows(gains_file, [r])
            stem.with_suffix(".md").write_text(report(env_id, merged, args, extra))
            d, t = r["leaderboard_default"], r["leaderboard_tuned"]
            print(f"{variant:24s} {c:24s} {d['metric']} default {d['value']:.3g} "
                  f"({d['success']:.0%}) tuned {t['value']:.3g} ({t['success']:.0%}) "
                  f"{r['tuned']} [{r['seconds']:.0f} s]", file=sys.stderr, flush=True)
    print(stem.with_suffix(".md").read_text())
    return 0


def _ratio(default: dict[str, Any], tuned: dict[str, Any]) -> str:
    """How many times better the tuned value is (a direction-aware ratio), or '—'."""
    a, b = abs(default["value"]), abs(tuned["value"])
    if default["better"] == "higher":
        a, b = b, a
    if not (np.isfinite(a) and np.isfinite(b)) or b == 0.0:
        return "—"
    return f"{a / b:.1f}×"


def report(env_id: str, results: list[dict[str, Any]], args: argparse.Namespace,
           extra: dict[str, float]) -> str:
    """The side-by-side table (markdown) of default and tuned gains on the leaderboard seeds."""
    lines = [
        f"# Controller gains tuned with Optuna: {env_id}",
        "",
        f"Generated by `python scripts/tune_gains.py --env {env_id}"
        + "".join(f" --set {k}={v:g}" for k, v in extra.items())
        + "".join(f" --controller {c}" for c in args.controller or [])
        + f" --trials {args.trials} --train-episodes {args.train_episodes} --out {args.out}`"
        " (TPE, seeded; "
        f"{args.trials} trials of {args.train_episodes} training episodes, seeds "
        f"{TRAIN_SEED}–{TRAIN_SEED + args.train_episodes - 1}; the default gains are trial 0; a "
        "trial below their success rate scores +inf). Scored on the leaderboard's "
        f"{args.episodes} episodes (seeds {LEADERBOARD_SEED}–"
        f"{LEADERBOARD_SEED + args.episodes - 1}), on each variant's primary metric. Bounds "
        "(log-uniform; scripts/tune_gains.py says why): rate gains in [1, 0.3/Δt] (the servo "
        "gain λ: [0.05, 0.3/Δt], CLIK's K: [1, 1/Δt]; a cascade's ω_cp below its trial's "
        "ω_cv), ζ in [0.3, 3], any other gain a decade either side of its default; each row "
        "lists its own. Where the default gains fail every training "
        "episode the search maximised the return (the metric column says so).",
        "",
        "| variant | controller | metric | default gains | value | success | tuned gains "
        "| value | success | saturation (default → tuned) | factor | bounds |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        d, t = r["leaderboard_default"], r["leaderboard_tuned"]
        fmt = ", ".join
        lines.append(
            f"| {r['variant']} | {r['controller']} | {d['metric']}"
            + (f" (searched on {r['searched_on']})" if r["searched_on"] != d["metric"] else "")
            + " | "
            f"{fmt(f'{k} {v:g}' for k, v in r['default'].items())} | {d['value']:.3g} | "
            f"{d['success']:.0%} | {fmt(f'{k} {v:.3g}' for k, v in r['tuned'].items())} | "
            f"{t['value']:.3g} | {t['success']:.0%} | "
            + (f"{d['saturation']:.2g} → {t['saturation']:.2g}" if "saturation" in d else "—")
            + f" | {_ratio(d, t)} | "
            + fmt(f"{k} [{lo:.3g}, {hi:.3g}]" for k, (lo, hi) in r["bounds"].items()) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
