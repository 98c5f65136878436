"""The convergence region of the visual-servoing laws (and of an agent) on the rotation family.

    python scripts/research/eval_vs_rotation.py [--policy ibvs --policy pbvs ...] [--agent RUN
        [--steps N]] [--env cir_gym/VisualServo-v1] [--episodes 400] [--seed 7000]
        [--set start_rotation=(0.3,3.14159)] [--runs /work/main/runs/rl]
        [--out results/visual_servo/rotation_family]

The rotation family: ``VisualServo-v1`` with ``start_rotation=(0.3, π)``, the random start whose
rotation vector r = (r_x, r_y, r_z) (rad, in the goal camera's optical frame, z the optical axis)
draws r_x, r_y uniformly in ±0.3 and r_z uniformly in ±π, with the default 0.1 px feature noise.
Each policy (``--policy``, names of :func:`cir_gym.scoring.policies.make_policy`; default
``ibvs``, ``pbvs``, ``tuned:ibvs``) and the checkpoint of a training run (``--agent RUN``, a run
folder ``<Env>/<agent>/seed_<k>`` under ``--runs``, loaded as ``eval_checkpoint.py`` does) runs
the episodes ``--seed … --seed + episodes − 1`` through :func:`cir_gym.evaluation.evaluate`, on an
env wrapped to keep each episode's ``info["start_offset"]`` (reset) and its last step's info.

The spin of an episode is |r_z| of its start offset, in degrees. The start rotation is
``rotation(r)``, one rotation by ‖r‖ about r/‖r‖, so the tilt mixes in: the rotation's own angle
about the optical axis (its twist, from the swing-twist split R = R_swing R_z(ψ):
ψ = 2 atan2(n_z sin(θ/2), cos(θ/2)), θ = ‖r‖, n = r/θ) is not exactly r_z; with |r_x|, |r_y| ≤ 0.3
it differs by under 2° (the JSON keeps ψ per episode and the largest ||ψ| − |r_z||). The bins
use |r_z|, the variable the env draws uniformly.

Per policy, per 45° bin of spin: the episodes, the successes k/n with Wilson's 95 % interval
(:func:`cir_gym.metrics.wilson_interval`), the median final feature error (px, every episode of
the bin), and the failures by their cause on the last step (:func:`failure_cause`: diverged,
feature lost, joint limit, else not converged: the 15 s ran out at a final error ≥ 1 px).
Convergence region (:func:`convergence_region`): the spin up to which the policy succeeds in
≥ 95 % of the episodes, bin by bin: the upper edge of the last 15° bin before the first one that
has no episode or a success rate under 95 % (0° if the 0–15° bin already fails, 180° if none
does). ``tuned:<law>`` takes the gains tuned for the env's arguments without ``start_rotation``
(no study was tuned on the rotation family: these are the default start's gains).

Writes ``<out>/<Env>.md`` (the table), ``<out>/<Env>.json`` (every episode and the summaries) and
``<out>/<Env>.png`` (success rate against spin, 15° bins, Wilson band, one line per policy).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from cir_gym.envs.base import make_env
from cir_gym.evaluation import evaluate, interface_env_kwargs
from cir_gym.metrics import wilson_interval
from cir_gym.scoring.policies import PolicyError, make_policy, parse_value, tuned_gains

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_vs_agents import RUNS, checkpoint_policy

ENV = "cir_gym/VisualServo-v1"
POLICIES = ("ibvs", "pbvs", "tuned:ibvs")
ROTATION_FAMILY = {"start_rotation": (0.3, math.pi)}  # rad: (tilt, spin) bounds
OUT = Path("results/visual_servo/rotation_family")
TABLE_BIN = 45.0  # deg: the table's bins of spin
REGION_BIN = 15.0  # deg: the convergence region's (and the figure's) bins
REGION_SUCCESS = 0.95  # a bin inside the convergence region succeeds in ≥ 95 % of its episodes
CAUSES = ("diverged", "feature lost", "joint limit", "not converged")


@dataclass
class Episode:
    """One episode on the rotation family: seed, spin |r_z| and twist |ψ| (deg), outcome,
    final feature error (px), cause of failure (None for a success), steps played."""

    seed: int
    spin: float
    twist: float
    success: bool
    final_error: float
    cause: str | None
    length: int


class StartAndEnd(gym.Wrapper):
    """Keeps each episode's ``info["start_offset"]`` (6,) from reset and its last step's info."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.starts: list[np.ndarray] = []
        self.ends: list[dict[str, Any]] = []

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        if "start_offset" not in info:
            raise KeyError(f"{self.env.spec.id if self.env.spec else self.env} puts no "
                           "start_offset in its reset info")
        self.starts.append(np.asarray(info["start_offset"], dtype=float))
        self.ends.append({})
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.ends[-1] = info
        return obs, reward, terminated, truncated, info


def twist_angle(r: np.ndarray) -> float:
    """|ψ| (rad) of the rotation vector ``r`` (3,): the angle about z of R = rotation(r) in the
    swing-twist split R = R_swing R_z(ψ), ψ = 2 atan2(n_z sin(θ/2), cos(θ/2)) wrapped to ±π."""
    theta = float(np.linalg.norm(r))
    if theta < 1e-15:
        return 0.0
    psi = 2.0 * math.atan2(r[2] / theta * math.sin(theta / 2), math.cos(theta / 2))
    return abs((psi + math.pi) % (2 * math.pi) - math.pi)


def failure_cause(info: dict[str, Any]) -> str | None:
    """Why an episode failed, from its last step's info: ``"diverged"``, ``"feature lost"``,
    ``"joint limit"`` (the first flag set, in this order: a step that loses a feature at a joint
    limit counts as feature lost), ``"not converged"`` (ran out of time at ≥ 1 px); None for a
    success."""
    if info.get("is_success", False):
        return None
    for cause, key in (("diverged", "diverged"), ("feature lost", "feature_lost"),
                       ("joint limit", "joint_limit")):
        if info.get(key, False):
            return cause
    return "not converged"


def policy_of(env_id: str, name: str, env_kwargs: dict[str, Any]) -> Any:
    """The policy ``name`` (:func:`make_policy`) on ``env_id`` with ``env_kwargs``; a
    ``tuned:<law>`` without a study for these arguments takes the gains tuned without
    ``start_rotation`` (the default start's)."""
    try:
        return make_policy(env_id, name, env_kwargs, {})
    except PolicyError:
        if not name.startswith("tuned:") or "start_rotation" not in env_kwargs:
            raise
    law = name.removeprefix("tuned:")
    rest = {k: v for k, v in env_kwargs.items() if k != "start_rotation"}
    return make_policy(env_id, law, env_kwargs, tuned_gains(env_id, law, rest))


def run_episodes(policy: Any, env_id: str, episodes: int, seed: int, name: str,
                 env_kwargs: dict[str, Any]) -> list[Episode]:
    """``policy`` on seeds ``seed …`` by :func:`evaluate` on a :class:`StartAndEnd` env."""
    env = StartAndEnd(make_env(env_id, **interface_env_kwargs(policy, env_kwargs)))
    try:
        result = evaluate(policy, env_id, episodes, seed, policy_name=name, env=env)
    finally:
        env.close()
    return [Episode(seed=ep.seed, spin=math.degrees(abs(start[5])),
                    twist=math.degrees(twist_angle(start[3:])), success=bool(ep.success),
                    final_error=float(ep.metrics["final_feature_error"]),
                    cause=failure_cause(end), length=ep.length)
            for ep, start, end in zip(result.episodes, env.starts, env.ends, strict=True)]


def bins(spin: np.ndarray, width: float) -> list[tuple[float, float, np.ndarray]]:
    """(low, high, mask) of the bins [0, w), [w, 2w), …, [180 − w, 180] (deg) over ``spin``."""
    edges = np.arange(0.0, 180.0 + width / 2, width)
    if not np.isclose(edges[-1], 180.0):
        raise ValueError(f"bin width {width}° does not divide 180°")
    last = len(edges) - 2
    return [(float(lo), float(hi), (spin >= lo) & ((spin < hi) | (i == last)))
            for i, (lo, hi) in enumerate(itertools.pairwise(edges))]


def bin_rows(eps: list[Episode], width: float) -> list[dict[str, Any]]:
    """Per bin of spin: low, high (deg), n, successes, rate, Wilson 95 % (low, high), median
    final feature error (px; None for an empty bin) and the failures by cause."""
    spin = np.array([e.spin for e in eps])
    rows = []
    for lo, hi, mask in bins(spin, width):
        inside = [e for e, m in zip(eps, mask, strict=True) if m]
        n, k = len(inside), sum(e.success for e in inside)
        rows.append({
            "low": lo, "high": hi, "n": n, "successes": k, "rate": k / n if n else None,
            "wilson": list(wilson_interval(k, n)) if n else None,
            "median_final_error": float(np.median([e.final_error for e in inside])) if n else None,
            "causes": {c: sum(e.cause == c for e in inside) for c in CAUSES},
        })
    return rows


def convergence_region(eps: list[Episode], width: float = REGION_BIN,
                       threshold: float = REGION_SUCCESS) -> float:
    """The spin (deg) up to which every ``width``° bin succeeds in ≥ ``threshold`` of its
    episodes: the upper edge of the last bin before the first one that is empty or under the
    threshold (0 if the first bin is, 180 if none is)."""
    region = 0.0
    for row in bin_rows(eps, width):
        if row["n"] == 0 or row["rate"] < threshold:
            break
        region = row["high"]
    return region


def table(results: dict[str, list[Episode]]) -> list[str]:
    """The markdown rows: policy × 45° bin, success (Wilson), median final error, causes."""
    lines = ["| policy | spin | episodes | success (Wilson 95 %) | median final error (px) | "
             + " | ".join(CAUSES) + " | convergence region |",
             "|---|---|---:|---:|---:|" + "---:|" * len(CAUSES) + "---:|"]
    for name, eps in results.items():
        region = f"{convergence_region(eps):.0f}°"
        for row in bin_rows(eps, TABLE_BIN):
            n, k = row["n"], row["successes"]
            success = (f"{k}/{n} = {100 * k / n:.0f} % ({100 * row['wilson'][0]:.0f}–"
                       f"{100 * row['wilson'][1]:.0f} %)" if n else "–")
            median = f"{row['median_final_error']:.3g}" if n else "–"
            lines.append(f"| {name} | {row['low']:.0f}–{row['high']:.0f}° | {n} | {success} | "
                         f"{median} | " + " | ".join(str(row["causes"][c]) for c in CAUSES)
                         + f" | {region} |")
            region = ""
    return lines


def plot(results: dict[str, list[Episode]], title: str, path: Path) -> Path:
    """Success rate against spin per 15° bin, one line per policy, its Wilson 95 % band."""
    from cir_gym.scoring.plotting import _plt, _save, line_styles

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    styles = line_styles(list(results))
    for name, eps in results.items():
        rows = [r for r in bin_rows(eps, REGION_BIN) if r["n"]]
        x = np.array([(r["low"] + r["high"]) / 2 for r in rows])
        colour, marker, ls = styles[name]
        ax.fill_between(x, [100 * r["wilson"][0] for r in rows],
                        [100 * r["wilson"][1] for r in rows], color=colour, alpha=0.15, lw=0)
        ax.plot(x, [100 * r["rate"] for r in rows], color=colour, marker=marker, ls=ls, lw=1.4,
                ms=5, label=f"{name} (region {convergence_region(eps):.0f}°)")
    ax.axhline(100 * REGION_SUCCESS, color="0.5", lw=0.8, ls=":")
    ax.set_xlim(0, 180)
    ax.set_xticks(np.arange(0, 181, 45))
    ax.set_ylim(-2, 102)
    ax.set_xlabel("spin |r_z| about the optical axis (°), 15° bins")
    ax.set_ylabel("success (%), Wilson 95 % band")
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.tight_layout()
    return _save(fig, path, plt)


def agent_policy(run: str, root: Path, steps: int | None, env_id: str) -> tuple[str, Any]:
    """(label, agent) of the checkpoint ``steps`` (default: the last) of the run ``root/run``."""
    steps, agent = checkpoint_policy(root / run, root, steps, env_id)
    return f"train:{run} @ {steps}", agent


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", action="append", default=None,
                        help=f"a policy name (repeat; default: {', '.join(POLICIES)})")
    parser.add_argument("--agent", default=None, help="<Env>/<agent>/seed_<k> under --runs")
    parser.add_argument("--steps", type=int, default=None, help="default: the last checkpoint")
    parser.add_argument("--env", default=ENV)
    parser.add_argument("--episodes", type=int, default=400)
    parser.add_argument("--seed", type=int, default=7000)
    parser.add_argument("--runs", type=Path, default=RUNS)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    kwargs = {**ROTATION_FAMILY,
              **{k: parse_value(v) for k, v in (s.split("=", 1) for s in args.set)}}
    try:
        policies = [(name, policy_of(args.env, name, kwargs)) for name in args.policy or POLICIES]
    except PolicyError as exc:
        parser.error(f"--policy: {exc}")
    if args.agent is not None:
        try:
            policies.append(agent_policy(args.agent, args.runs, args.steps, args.env))
        except ValueError as exc:
            parser.error(str(exc))
    results: dict[str, list[Episode]] = {}
    cpu: dict[str, float] = {}
    for name, policy in policies:
        start = time.process_time()
        results[name] = run_episodes(policy, args.env, args.episodes, args.seed, name, kwargs)
        cpu[name] = time.process_time() - start
        print(f"{name}: {sum(e.success for e in results[name])}/{args.episodes} successes, "
              f"region {convergence_region(results[name]):.0f}°, {cpu[name]:.0f} CPU-s", flush=True)
    # an agent's table beside the controllers' (not over it): <Env>_<agent>_seed_<k>
    stem = args.out / (args.agent.replace("/", "_") if args.agent else args.env.split("/")[-1])
    command = shlex.join(["python", "scripts/research/eval_vs_rotation.py",
                          *(sys.argv[1:] if argv is None else argv)])
    seeds = f"seeds {args.seed}–{args.seed + args.episodes - 1}"
    every = [e for eps in results.values() for e in eps]
    text = "\n".join([
        f"# {args.env}: the rotation family's convergence region", "",
        f"Written by `{command}`: {args.env} with {kwargs} "
        f"(default 0.1 px feature noise unless set), {seeds}, by `cir_gym.evaluation.evaluate`. "
        "Spin: |r_z| of the start's rotation vector (its twist about the optical axis differs "
        f"by ≤ {max(abs(e.twist - e.spin) for e in every):.1f}° here). Convergence region: the "
        "upper edge of the last 15° bin of spin before the first one under "
        f"{100 * REGION_SUCCESS:.0f} % success. Failures by the cause on their last step. "
        "tuned:<law>: the gains tuned on the default start.", "",
        *table(results), "",
        "CPU seconds: " + ", ".join(f"{n} {c:.0f}" for n, c in cpu.items()), ""])
    record = {
        "env_id": args.env, "env_kwargs": kwargs, "seed": args.seed, "episodes": args.episodes,
        "region_bin_deg": REGION_BIN, "region_success": REGION_SUCCESS,
        "max_twist_minus_spin_deg": max(abs(e.twist - e.spin) for e in every),
        "policies": {name: {
            "convergence_region_deg": convergence_region(eps), "cpu_s": round(cpu[name], 1),
            "bins_45": bin_rows(eps, TABLE_BIN), "bins_15": bin_rows(eps, REGION_BIN),
            "episodes": [vars(e) for e in eps]} for name, eps in results.items()},
    }
    args.out.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".md").write_text(text)
    stem.with_suffix(".json").write_text(json.dumps(record, indent=1) + "\n")
    tilt, spin = kwargs["start_rotation"]
    plot(results, f"{args.env}, start_rotation ({tilt:.3g}, {spin:.3g}) rad: success against "
         f"spin ({seeds})", stem.with_suffix(".png"))
    print(text)
    return record


if __name__ == "__main__":
    main()
