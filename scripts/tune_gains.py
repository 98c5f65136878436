"""The controllers get a tuning budget too: an Optuna gain search per leaderboard variant.

    python scripts/tune_gains.py [--env cir_gym/JointTracking-v2] [--controller pd_gravity ...]
                                 [--trials 24] [--train-episodes N] [--out results/tuning]

An RL agent is tuned (hyperparameters, millions of steps); a controller at the course's default
gains is not. For every leaderboard variant of the environment (``leaderboard_variants``) and
every controller asked for, Optuna's TPE sampler (seeded) searches the controller's gains
within the bounds below for the best success rate, then primary metric, on *training*
episodes (seeds ``TRAIN_SEED …``, disjoint from the leaderboard's 1000–1009 and the learning
curves' 100000–; see "What a trial scores"). The shipped gains and the defaults are then scored
on the leaderboard's episodes (10, seeds 1000–1009): the report goes to ``<out>/<Env-vN>.md`` (the
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

What a trial scores (protocol 2): what the leaderboard ranks on, on the training episodes —
the success rate first, then the mean of the variant's own primary metric
(``variant_primary_metric``, e.g. ``min_manipulability`` on RedundantIK's manipulability
variant) over all the episodes, failed ones included (PegInHole's insertion time charges a
failure the 12-s horizon), in the metric's direction. Optuna minimises one number, so a trial
scores ``failures + s(m)``: the count of failed training episodes plus the signed metric ``m``
mapped into (0, 1) by ``s(m) = 1/2 + atan(m)/π`` (monotone: TPE reads only the order of the
trials, and one more success outranks any metric). A trial whose every training episode fails
is ranked among the others like it by a measure of progress instead (:data:`PROGRESS`: the
peg's ``final_depth`` on PegInHole, else the episode return): a censored metric (the 12-s cap)
is then the same for every trial, and an uncensored one can have the wrong slope
(RedundantIK's manipulability is bought by not tracking the path at all). A trial whose
episodes diverge, or whose gains the controller rejects (``InvalidGain``), scores +inf.

The training episodes (seeds ``TRAIN_SEED …``): 3 (:data:`TRAIN_EPISODES`) where the default
gains succeed in all of the first three; 10 (:data:`RARE_SUCCESS_TRAIN_EPISODES`, the
leaderboard's count) where they do not: the ranking then hinges on the success rate, and three
episodes cannot see a 10–30 % rate (a law inserting 10 % of the time fails all three 73 % of
the time, and the search would run blind). ``--train-episodes`` fixes the number instead.

What is shipped: the best trial's gains only when they beat the default gains (trial 0) on the
training episodes by the leaderboard's order, a higher success rate or the same one and a
strictly better mean primary metric; otherwise the default gains themselves (``kept_default``
in the row; the report says so). Progress alone (deeper, higher return) does not make gains
"tuned". The leaderboard's seeds never choose: tuned gains that lose there are reported as
they score. The training scores of both are in the row (``train_default``, ``train_tuned``).

This is protocol 2 (CHANGELOG.md says how protocol 1 differed). A study records its protocol
(study user attributes: ``protocol``, ``train_episodes``, ``tie_breaker``); a run refuses to
resume a study of another protocol (use a fresh ``--out``).

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
#: the search protocol (module docstring), recorded on every study and row: 2 ranks trials by
#: training success, then the primary metric (1 searched the metric behind a success floor, or
#: the return)
PROTOCOL = 2
#: training episodes where the default gains succeed in every one of them
TRAIN_EPISODES = 3
#: training episodes where they do not: the leaderboard's count, so a 10 % rate can show
RARE_SUCCESS_TRAIN_EPISODES = LEADERBOARD_EPISODES
#: env (id without its version) → (metric, direction) that ranks trials whose every training
#: episode fails; any other env: the episode return (higher)
PROGRESS: dict[str, tuple[str, str]] = {"PegInHole": ("final_depth", "higher")}

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
    "position_spiral": ("omega_n", "zeta", "d_f", "speed"),
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


def progress_measure(env_id: str) -> tuple[str, str]:
    """(name, "higher"/"lower") of what ranks trials that fail every training episode on
    ``env_id`` (:data:`PROGRESS`, else the return)."""
    name = env_id.split("/")[-1].rsplit("-v", 1)[0]
    return PROGRESS.get(name, ("return", "higher"))


def score(controller: str, env_id: str, variant: str, env_kwargs: dict[str, Any],
          gains: dict[str, float], episodes: int, seed: int) -> dict[str, Any]:
    """The variant's primary metric (mean over the episodes, with its name and direction),
    success, divergence and saturation rates, the return and the env's progress measure
    (:func:`progress_measure`, its mean) of the controller with ``gains``."""
    metric = variant_primary_metric(cir_gym.ENVIRONMENTS[env_id][0], variant)
    policy = baselines.make(controller, env_id, env_kwargs=env_kwargs, **gains)
    result = evaluate(policy, env_id, episodes, seed, **env_kwargs)
    out = {"metric": metric, "better": result.spec(metric).better,
           "value": result.summary[metric]["mean"], "return": result.summary["return"]["mean"],
           "success": result.success_rate,
           "divergence": result.divergence_rate, "episodes": episodes}
    progress = progress_measure(env_id)[0]
    if progress in result.summary:
        out[progress] = result.summary[progress]["mean"]
    if "saturation" in result.summary:
        out["saturation"] = result.summary["saturation"]["mean"]
    return out


def _signed(value: float, better: str) -> float:
    """``value`` signed so that lower is better."""
    return value if better == "lower" else -value


def rank_key(train: dict[str, Any]) -> tuple[float, float]:
    """The leaderboard's order of a :func:`score`: the highest success rate first, then the
    best mean primary metric (lower key is better; NaN last)."""
    value = _signed(train["value"], train["better"])
    return -train["success"], value if np.isfinite(value) else math.inf


def trial_value(train: dict[str, Any], progress: tuple[str, str]) -> float:
    """What a trial scores (minimised): failed training episodes + s(signed primary metric),
    s(m) = 1/2 + atan(m)/π in (0, 1); when every episode failed, s(signed ``progress``)
    instead (``progress``: (name in ``train``, direction)). +inf if an episode diverged or the
    ranked number is not finite. Orders trials as :func:`rank_key` does wherever one succeeds."""
    episodes = train["episodes"]
    failures = round((1.0 - train["success"]) * episodes)
    if train["divergence"] > 0:
        return math.inf
    if failures < episodes:
        m = _signed(train["value"], train["better"])
    else:
        m = _signed(train.get(progress[0], math.nan), progress[1])
    if not np.isfinite(m):
        return math.inf
    return failures + 0.5 + math.atan(m) / math.pi


def study_protocol(train_episodes: int, progress: tuple[str, str]) -> dict[str, Any]:
    """The study user attributes a resumed study must share with this run."""
    return {"protocol": PROTOCOL, "train_episodes": train_episodes, "train_seed": TRAIN_SEED,
            "tie_breaker": progress[0]}


def tune(controller: str, env_id: str, variant: str, env_kwargs: dict[str, Any], *,
         trials: int, train_episodes: int | None, out: Path,
         sampler_seed: int = 0) -> dict[str, Any]:
    """One Optuna study on the training seeds (module docstring: what a trial scores, how many
    training episodes when ``train_episodes`` is None, what is shipped); returns the row."""
    import optuna

    dt, objective_name = variant_setting(env_id, env_kwargs)
    defaults = tunable_gains(controller, env_id, objective_name, env_kwargs)
    if not defaults:
        raise ValueError(f"{controller} has no searchable gain on {env_id} (scripts/tune_gains.py"
                         f" searches {sorted(RATE_BOUNDS) + sorted(FIXED_BOUNDS)} and SEARCHED)")
    space = {g: bounds(g, v, dt) for g, v in defaults.items()}
    progress = progress_measure(env_id)
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
    recorded = {k: study.user_attrs.get(k) for k in study_protocol(0, progress)}
    if study.trials and recorded["protocol"] != PROTOCOL:
        raise ValueError(_mismatch(name, out, recorded, PROTOCOL))
    episodes = study_episodes(study, train_episodes, lambda n: score(
        controller, env_id, variant, env_kwargs, start, n, TRAIN_SEED))
    protocol = study_protocol(episodes, progress)
    if study.trials and recorded != protocol:
        raise ValueError(_mismatch(name, out, recorded, protocol))
    for k, v in protocol.items():
        study.set_user_attr(k, v)
    if default_trial(study, start) is None:
        study.enqueue_trial(start)

    def objective(trial: Any) -> float:
        gains: dict[str, float] = {}
        for g in defaults:  # a gain of BELOW after the one it must stay below
            low, high = space[g]
            if BELOW.get(g) in gains:
                high = min(high, gains[BELOW[g]] * (1.0 - 1e-9))
            gains[g] = trial.suggest_float(g, low, high, log=True)
        try:
            s = score(controller, env_id, variant, env_kwargs, gains, episodes, TRAIN_SEED)
        except baselines.InvalidGain:
            return math.inf
        trial.set_user_attr("train", s)
        return trial_value(s, progress)

    study.optimize(objective, n_trials=max(trials - len(completed(study)), 0))
    done = completed(study)
    first = default_trial(study, start)
    chosen = shipped_trial(done, first)
    return {"study": name, "protocol": PROTOCOL, "trials": len(done),
            "train_episodes": episodes, "train_seed": TRAIN_SEED,
            "best_train": chosen.value,
            "default_train": first.value if first is not None else math.nan,
            "train_default": first.user_attrs["train"] if first is not None else None,
            "train_tuned": chosen.user_attrs.get("train"),
            "kept_default": chosen is first,
            "tuned": {g: chosen.params[g] for g in defaults}, "default": defaults,
            "bounds": space,
            "searched_on": variant_primary_metric(cir_gym.ENVIRONMENTS[env_id][0], variant),
            "tie_breaker": progress[0],
            "seconds": round(sum(t.duration.total_seconds() for t in done), 1)}


def _mismatch(name: str, out: Path, recorded: dict[str, Any], asked: Any) -> str:
    """The error of a study that cannot be resumed under this run's protocol."""
    return (f"study {name!r} in {out / 'studies.db'} was run under {recorded}, this run's "
            f"protocol is {asked}: resume it with the script and --train-episodes it was run "
            "with, or give a fresh --out")


def study_episodes(study: Any, asked: int | None, probe: Any) -> int:
    """The training episodes of ``study``: ``asked`` if given, else those it recorded (a
    resumed study), else :data:`TRAIN_EPISODES` if the default gains succeed in every one of
    that many (``probe(n)``: their :func:`score` on n training episodes), else
    :data:`RARE_SUCCESS_TRAIN_EPISODES`."""
    if asked is not None:
        return asked
    if study.trials and study.user_attrs.get("train_episodes") is not None:
        return int(study.user_attrs["train_episodes"])
    return (TRAIN_EPISODES if probe(TRAIN_EPISODES)["success"] == 1.0
            else RARE_SUCCESS_TRAIN_EPISODES)


def shipped_trial(done: list[Any], first: Any) -> Any:
    """The trial whose gains are shipped: the best (lowest value, earliest of equals) if it
    beats the default gains' trial ``first`` on the training episodes by :func:`rank_key`,
    else ``first`` (the defaults); the best if there is no default trial to compare with."""
    best = min(done, key=lambda t: (t.value, t.number))
    if first is None:
        return best
    if (best is first or not np.isfinite(best.value) or "train" not in best.user_attrs
            or rank_key(best.user_attrs["train"]) >= rank_key(first.user_attrs["train"])):
        return first
    return best


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
    p.add_argument("--train-episodes", type=int, default=None,
                   help=f"training episodes of every study (default: {TRAIN_EPISODES} where the "
                        f"default gains succeed in all {TRAIN_EPISODES}, else "
                        f"{RARE_SUCCESS_TRAIN_EPISODES})")
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
    for flag, n in (("--trials", args.trials), ("--train-episodes", args.train_episodes),
                    ("--episodes", args.episodes)):
        if n is not None and n < 1:
            p.error(f"{flag} must be >= 1, got {n}")
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
            if (all(known.get(k) == r[k] for k in ("tuned", "default", "protocol",
                                                     "train_episodes"))
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


def _training(r: dict[str, Any]) -> str:
    """A row's training scores, default → shipped: 'successes/episodes, mean metric'."""
    d, t = r.get("train_default"), r.get("train_tuned")
    if not d or not t:
        return "—"

    def one(s: dict[str, Any]) -> str:
        return f"{round(s['success'] * s['episodes'])}/{s['episodes']}, {s['value']:.3g}"

    return f"{one(d)} → {one(t)}" + (" (defaults kept)" if r.get("kept_default") else "")


def report(env_id: str, results: list[dict[str, Any]], args: argparse.Namespace,
           extra: dict[str, float]) -> str:
    """The side-by-side table (markdown) of default and tuned gains on the leaderboard seeds."""
    episodes = (f"--train-episodes {args.train_episodes}" if args.train_episodes else "")
    lines = [
        f"# Controller gains tuned with Optuna: {env_id}",
        "",
        f"Generated by `python scripts/tune_gains.py --env {env_id}"
        + "".join(f" --set {k}={v:g}" for k, v in extra.items())
        + "".join(f" --controller {c}" for c in args.controller or [])
        + "".join(f" --variant '{v}'" for v in args.variant or [])
        + f" --trials {args.trials} {episodes}".rstrip() + f" --out {args.out}`"
        f" (protocol {PROTOCOL}, scripts/tune_gains.py: TPE, seeded, {args.trials} trials; the "
        "default gains are trial 0. Training episodes from seed "
        f"{TRAIN_SEED}: "
        + (f"{args.train_episodes}" if args.train_episodes else
           f"{TRAIN_EPISODES} where the default gains succeed in all {TRAIN_EPISODES}, else "
           f"{RARE_SUCCESS_TRAIN_EPISODES}")
        + ". A trial ranks by its training success rate, then the mean of the variant's "
        "primary metric over all its episodes (the leaderboard's order); a trial that fails "
        "every training episode ranks by progress instead (PegInHole: final_depth; else the "
        "return); divergence or rejected gains: last. The tuned gains are the best trial's "
        "only if it beats the defaults on the training episodes in that order (success, then "
        "metric), else the defaults themselves ('defaults kept'); the leaderboard's seeds "
        "never choose.) Scored on the leaderboard's "
        f"{args.episodes} episodes (seeds {LEADERBOARD_SEED}–"
        f"{LEADERBOARD_SEED + args.episodes - 1}), on each variant's primary metric. Bounds "
        "(log-uniform; scripts/tune_gains.py says why): rate gains in [1, 0.3/Δt] (the servo "
        "gain λ: [0.05, 0.3/Δt], CLIK's K: [1, 1/Δt]; a cascade's ω_cp below its trial's "
        "ω_cv), ζ in [0.3, 3], any other gain a decade either side of its default; each row "
        "lists its own. A row of protocol 1 (no training column) searched the return where "
        "the default gains failed every training episode (the metric column says so).",
        "",
        "| variant | controller | metric | default gains | value | success | tuned gains "
        "| value | success | saturation (default → tuned) | factor | training: successes, "
        "metric (default → tuned) | bounds |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
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
            + f" | {_ratio(d, t)} | {_training(r)} | "
            + fmt(f"{k} [{lo:.3g}, {hi:.3g}]" for k, (lo, hi) in r["bounds"].items()) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
