"""Learning curves of the shipped agents, one PNG per environment, against the best controller.

    python scripts/plot_learning_curves.py [--out results/learning_curves] [--env ID ...]

For each environment with shipped agents (``agents/trained/<EnvName-vN>/``) the primary metric
of every agent's ``learning_curve.csv`` is drawn against training steps; an agent trained over
several seeds (``seed_<k>/``) is drawn as the IQM over seeds with its 95 % stratified-bootstrap
band and each seed's curve thin (:func:`agents.report.curve_band`). For every distinct training
setting of those agents (e.g. the exact model and an unknown 3 kg payload) each applicable
controller is run through :func:`cir_gym.evaluation.evaluate` on the *same* seeds and number of
episodes as the curves' evaluations (``agents.train.EVAL_SEED``): the best one is drawn as a
dashed horizontal line, the best of those tuned for that setting (``scripts/tune_gains.py``, at
their tuned gains) as a dash-dotted one, and a residual agent's base controller as a dotted one
in the agent's colour. An agent's interface arguments (``control``, ``control_freq``: a
PegInHole agent may act through the position interface) are not a training setting: the
controllers run on the task's other arguments with their own interface. Environments in
``SUCCESS_PANEL`` get two more panels, the evaluation success rate and mean return (a failed
episode's primary metric is only the time limit; the return still shows progress).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from cir_gym.agents.policy import INTERFACE_KEYS
from cir_gym.agents.report import curve_band, read_curve
from cir_gym.agents.train import EVAL_SEED

import cir_gym
from cir_gym import agents, baselines
from cir_gym.evaluation import evaluate
from cir_gym.scoring.policies import PolicyError, tuned_gains

#: the bar for a from-scratch agent: this controller at its default gains
TARGETS = {"cir_gym/JointTracking-v2": "pd_gravity"}
#: environments whose failures all score the time limit: success rate drawn beside the metric
SUCCESS_PANEL = {"cir_gym/PegInHole-v2"}


def controller_scores(env_id: str, env_kwargs: dict[str, Any], episodes: int, seed: int,
                      extras: dict[str, dict[str, float]] | None = None, *,
                      tuned: bool = False) -> dict[str, float]:
    """Mean primary metric of every applicable controller on these seeds (and, into
    ``extras`` when given, each one's success rate and mean return). ``tuned``: only the
    controllers ``scripts/tune_gains.py`` tuned for ``env_kwargs`` (the env's reward arguments
    aside, :func:`cir_gym.cli.tuned_gains`), at their tuned gains (keys ``tuned:<controller>``)."""
    primary = cir_gym.ENVIRONMENTS[env_id][0].primary_metric
    scores = {}
    for name in baselines.available(env_id):
        key = f"tuned:{name}" if tuned else name
        gains = {}
        if tuned:
            try:
                gains = tuned_gains(env_id, name, env_kwargs)
            except PolicyError:  # not tuned for this setting
                continue
        policy = baselines.make(name, env_id, env_kwargs=env_kwargs, **gains)
        result = evaluate(policy, env_id, episodes, seed, **env_kwargs)
        scores[key] = result.summary[primary]["mean"]
        if extras is not None:
            extras[key] = {"success_rate": result.success_rate,
                           "return": result.summary["return"]["mean"]}
        print(f"  {key:28s} {env_kwargs or 'defaults'}: {primary} = {scores[key]:.4g}, "
              f"success {result.success_rate:.0%}", file=sys.stderr)
    return scores


def best_of(env_id: str, scores: dict[str, float]) -> tuple[str, float] | None:
    """(name, score) of the best controller by the primary metric's direction."""
    if not scores:
        return None
    cls = cir_gym.ENVIRONMENTS[env_id][0]
    spec = next(s for s in cls.metric_specs if s.name == cls.primary_metric)
    pick = min if spec.better == "lower" else max
    name = pick(scores, key=scores.get)
    return name, scores[name]


def plot_env(env_id: str, out: Path) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = agents.available(env_id)
    if not names:
        return None
    cls = cir_gym.ENVIRONMENTS[env_id][0]
    primary = cls.primary_metric
    unit = next(s.unit for s in cls.metric_specs if s.name == primary)
    panel = env_id in SUCCESS_PANEL
    fig, axes = plt.subplots(1, 3 if panel else 1, figsize=(18 if panel else 12, 4.2))
    ax, ax_s, ax_r = (axes[0], axes[1], axes[2]) if panel else (axes, None, None)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    scores: dict[str, dict[str, float]] = {}  # setting label -> controller -> score
    tuned: dict[str, dict[str, float]] = {}  # setting label -> tuned:<controller> -> score
    extras: dict[str, dict[str, dict[str, float]]] = {}  # label -> controller -> rate, return
    bases: list[tuple[str, float, str]] = []  # (base's label, its score, colour) of residuals
    for i, name in enumerate(names):
        seed_dirs = [agents.agent_dir(env_id, name, k) for k in agents.seeds(env_id, name)]
        d = seed_dirs[0]
        config = yaml.safe_load((d / "config.yml").read_text())
        recorded = config.get("env_kwargs") or {}
        kwargs = {k: v for k, v in recorded.items() if k not in INTERFACE_KEYS}
        label = ", ".join(f"{k}={v}" for k, v in kwargs.items()) or "defaults"
        interface = "".join(f", {k}={recorded[k]}" for k in INTERFACE_KEYS if k in recorded)
        if label not in scores:
            episodes = int(config["hyperparams"].get("n_eval_episodes", 5))
            extras[label] = {}
            scores[label] = controller_scores(env_id, kwargs, episodes, EVAL_SEED,
                                              extras[label])
            tuned[label] = controller_scores(env_id, kwargs, episodes, EVAL_SEED,
                                             tuned=True)
        color = colors[i % len(colors)]
        if len(seed_dirs) == 1:
            steps, values = read_curve(d, primary)
            ax.plot(steps, values, "o-", ms=3, color=color,
                    label=f"{name} ({label}{interface}, 1 seed)")
            if ax_s is not None and ax_r is not None:
                ax_s.plot(steps, 100 * _success_curve(d), "o-", ms=3, color=color, label=name)
                ax_r.plot(*read_curve(d, "return"), "o-", ms=3, color=color, label=name)
        else:  # IQM over seeds, 95 % stratified-bootstrap band, each seed thin
            band = curve_band([read_curve(sd, primary) for sd in seed_dirs])
            how = ", interpolated to common steps" if band["interpolated"] else ""
            ax.plot(band["steps"], band["iqm"], "o-", ms=3, color=color,
                    label=f"{name} ({label}, IQM of {len(seed_dirs)} seeds, 95 % CI{how})")
            ax.fill_between(band["steps"], band["low"], band["high"], color=color, alpha=0.2)
            for row in band["seeds"]:
                ax.plot(band["steps"], row, "-", lw=0.6, alpha=0.5, color=color)
        res = config.get("residual")
        if res:  # its base at the gains it was trained on (controller_kwargs: e.g. tuned ones)
            gains = res.get("controller_kwargs") or {}
            value = scores[label][res["controller"]]
            tuned_key = f"tuned:{res['controller']}"
            if (gains and tuned_key in tuned[label]
                    and gains == tuned_gains(env_id, res["controller"], kwargs)):
                value = tuned[label][tuned_key]  # the tuned line's own evaluation, not again
            elif gains:
                base = baselines.make(res["controller"], env_id, env_kwargs=kwargs, **gains)
                episodes = int(config["hyperparams"].get("n_eval_episodes", 5))
                value = evaluate(base, env_id, episodes, EVAL_SEED,
                                 **kwargs).summary[primary]["mean"]
            at = ", ".join(f"{k} {v:.3g}" for k, v in gains.items())
            bases.append((f"{res['controller']}{f' at {at}' if at else ''} ({label})", value,
                          color))
    for j, (label, by_name) in enumerate(scores.items()):
        best = best_of(env_id, by_name)
        if best is not None:
            ax.axhline(best[1], ls="--", color=colors[(len(names) + j) % len(colors)],
                       label=f"best controller: {best[0]} ({label})")
        best = best_of(env_id, tuned.get(label, {}))
        if best is not None:
            ax.axhline(best[1], ls="-.", color=colors[(len(names) + j) % len(colors)],
                       label=f"best tuned controller: {best[0]} ({label})")
    for base_label, value, color in bases:
        ax.axhline(value, ls=":", color=color, label=f"residual's base: {base_label}")
    if ax_s is not None and ax_r is not None:
        for label, by_name in extras.items():
            for k, (controller, e) in enumerate(sorted(by_name.items())):
                style = {"ls": ("--", ":", "-.")[k % 3],
                         "color": colors[(len(names) + k) % len(colors)],
                         "label": f"{controller} ({label})"}
                ax_s.axhline(100 * e["success_rate"], **style)
                ax_r.axhline(e["return"], **style)
        ax_s.set_ylabel("success rate (%), evaluation")
        ax_s.set_ylim(-5, 105)
        ax_r.set_ylabel("mean return (env reward), evaluation")
        for a in (ax_s, ax_r):
            a.set_xlabel("training steps")
            a.grid(True, alpha=0.3)
            a.legend(fontsize=7)
    target = TARGETS.get(env_id)
    for label, by_name in scores.items():  # the bar for a from-scratch agent
        if target in by_name and (best_of(env_id, by_name) or ("",))[0] != target:
            ax.axhline(by_name[target], ls="-.", color="k", lw=0.8,
                       label=f"target: {target}, default gains ({label})")
    if not panel:  # a time to the goal capped by the time limit reads better linear
        ax.set_yscale("log")
    ax.set_xlabel("training steps")
    ax.set_ylabel(f"{primary} ({unit})" if unit else primary)
    ax.set_title(f"{env_id}: evaluation during training (seeds {EVAL_SEED}…)")
    ax.grid(True, which="both", alpha=0.3)
    if panel:
        ax.legend(fontsize=8)
    else:  # beside the axes: the lines it names run across the whole plot
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{agents.env_dir_name(env_id)}.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _success_curve(path: Path) -> np.ndarray:
    """The ``success_rate`` column of an agent directory's ``learning_curve.csv``."""
    with (Path(path) / "learning_curve.csv").open() as f:
        return np.array([float(r["success_rate"]) for r in csv.DictReader(f)])


def export_training_curve(run_dir: Path, dest: Path) -> Path:
    """Write a run's training episode length and return (TensorBoard ``rollout/ep_len_mean``,
    ``rollout/ep_rew_mean``: the training envs' reward, shaping included) to ``dest`` (CSV)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    rows: dict[int, dict[str, float]] = {}
    for events in sorted((run_dir / "tb").glob("*")):
        acc = EventAccumulator(str(events))
        acc.Reload()
        for tag, col in (("rollout/ep_len_mean", "ep_len_mean"),
                         ("rollout/ep_rew_mean", "ep_rew_mean")):
            if tag in acc.Tags()["scalars"]:
                for e in acc.Scalars(tag):
                    rows.setdefault(int(e.step), {})[col] = float(e.value)
    dest.parent.mkdir(parents=True, exist_ok=True)
    with dest.open("w") as f:
        f.write("timesteps,ep_len_mean,ep_rew_mean\n")
        for step in sorted(rows):
            r = rows[step]
            f.write(f"{step},{r.get('ep_len_mean', float('nan')):.2f},"
                    f"{r.get('ep_rew_mean', float('nan')):.3f}\n")
    return dest


def plot_levers(curves: Path, out: Path, primary: str = "rms_error") -> Path:
    """The lever runs (``<curves>/*.csv``, copies of their ``learning_curve.csv``) against the
    baseline JointTracking-v1 ``ppo`` curve (``<curves>/baseline/``; that agent is no longer
    shipped), on the same evaluation episodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env_id = "cir_gym/JointTracking-v2"
    training = sorted((curves / "train").glob("*.csv"))
    fig, axes = plt.subplots(1, 3 if training else 2, figsize=(16 if training else 11, 4.2))
    runs = [("ppo, 500 Hz, 5 M (baseline)", curves / "baseline" / "ppo_500hz_5m.csv")]
    runs += [(f.stem, f) for f in sorted(curves.glob("*.csv"))]
    for label, src in runs:
        steps, values = read_curve(src, primary)
        keep = steps <= 3_100_000
        axes[0].plot(steps[keep], values[keep], "o-", ms=3, label=label)
        steps, returns = read_curve(src, "return")
        axes[1].plot(steps[steps <= 3_100_000], returns[steps <= 3_100_000], "o-", ms=3,
                     label=label)
    for f in training:  # batched-env levers: training episode length (the survival they learn)
        data = np.genfromtxt(f, delimiter=",", names=True)
        axes[2].plot(data["timesteps"], data["ep_len_mean"], "-", label=f.stem)
    if training:
        axes[2].set_ylabel("training episode length (steps of 2000)")
        axes[2].legend(fontsize=8)
    axes[0].set_ylabel(f"{primary} (rad), evaluation")
    axes[1].set_ylabel("mean return (env reward), evaluation")
    for ax in axes:
        ax.set_xlabel("training steps")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{env_id} from scratch: issue-20 levers (seeds {EVAL_SEED}…, one training "
                 f"seed each, loaded machine)", fontsize=10)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / "JointTracking-v2_levers.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default="results/learning_curves")
    p.add_argument("--env", action="append", help="environment id (repeatable; default: all)")
    p.add_argument("--levers", metavar="DIR", help="also plot the lever curves in DIR/*.csv "
                   "(results/learning_curves/levers) against the baseline JointTracking ppo")
    p.add_argument("--export-training", nargs=2, metavar=("RUN_DIR", "CSV"),
                   help="write RUN_DIR's training episode length/return (TensorBoard) to CSV")
    args = p.parse_args(argv)
    if args.export_training:
        run, dest = args.export_training
        print(f"  {export_training_curve(Path(run), Path(dest))}", file=sys.stderr)
        return 0
    if args.levers:
        print(f"  {plot_levers(Path(args.levers), Path(args.out))}", file=sys.stderr)
        return 0
    for env_id in args.env or list(cir_gym.ENVIRONMENTS):
        key = env_id.split(":")[-1]
        if key not in cir_gym.ENVIRONMENTS:
            p.error(f"unknown environment {env_id!r}; valid: {sorted(cir_gym.ENVIRONMENTS)}")
        print(f"{key}:", file=sys.stderr)
        path = plot_env(key, Path(args.out))
        print(f"  {path or 'no shipped agents'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
