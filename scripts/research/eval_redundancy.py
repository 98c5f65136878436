"""Measure what redundancy buys (chapter 1): the kinematic controllers on RedundantIK-v4 and
RedundantIK7-v5.

    python scripts/research/eval_redundancy.py --episodes 100 --out results/redundancy/ --jobs 2

On the same seeds for every controller it reports
* the null-space laws against ``clik`` on "manipulability": minimum manipulability (% increase)
  at their task errors, for the textbook law ``clik_projected_gradient`` (q̇₀ = k₀ ∇w, nothing
  else), for ``clik_nullspace`` (∇ ln w, joint-limit barrier, null-space scaling to the
  velocity limits, saturation at the joint limits, self-motion search) and for
  ``clik_nullspace`` without its search (``search_arc=0``, the row "clik_nullspace, no
  search": everything else of it stays on);
* obstacle: collisions (episodes ending with clearance < 0) and the median minimum clearance;
* joint limits: episodes that hit a joint limit, per controller, with ``objective="joint_limits"``;
* joint drift ‖q(T) − q(0)‖ of the closed path, per controller, over the completed laps;
* ``clik_augmented``: control steps at an algorithmic singularity (σ_min(J_aug) < region);
* a straight path of the planar arm to 1 mm beyond full reach (stretched, near-singular):
  the commanded joint speeds of ``clik`` (J† grows like 1/σ_min) and ``clik_dls`` (bounded),
  saved as ``singular_path.png``.
It prints a markdown table and writes it to ``<out>/redundancy.md``.

Every episode runs through :func:`cir_gym.evaluation.evaluate`. Each seed's task is drawn
once (the "obstacle" placement and the "manipulability" start search take up to seconds) and
every controller plays it from ``reset(options={"replay": True})``, which restores that task
exactly (``--check`` compares the replayed episodes with freshly drawn ones on a few seeds).
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

ENVS = {"RedundantIK": "cir_gym/RedundantIK-v4", "RedundantIK7": "cir_gym/RedundantIK7-v5"}
ALL = ("jacobian_transpose", "pseudo_inverse", "clik", "clik_dls", "clik_weighted",
       "clik_projected_gradient", "clik_nullspace", "clik_augmented")
TEXTBOOK = "clik_projected_gradient"  # the textbook law: q̇ = J†(x̄̇ + K e) + (I − J†J) k₀ ∇w
NO_SEARCH = "clik_nullspace, no search"  # search_arc = 0; log-gradient, barrier, scaling on
VARIANTS = {NO_SEARCH: ("clik_nullspace", {"search_arc": 0.0})}
ORACLE = "clearing motion (oracle)"  # the env's certificate: needs the whole reference
METRICS = ("rms_task_error", "min_manipulability", "min_joint_limit_margin", "min_clearance",
           "joint_drift")
OBSTACLE_POLICIES = ("clik", "clik_dls", TEXTBOOK, "clik_nullspace", ORACLE)
CHUNK = 5  # seeds per worker job


def _register() -> None:
    import cir_gym  # noqa: F401
    from cir_gym.envs.base import EntryPoint
    from cir_gym.envs.redundant_ik import REDUNDANT_IK_ENVIRONMENTS

    for env_id, (cls, _) in REDUNDANT_IK_ENVIRONMENTS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=EntryPoint(cls))


class ClearingMotion:
    """Plays back the env's ``clearing_motion()`` (SB3's ``predict``): not a controller, it
    was planned with the whole reference in advance; what any causal controller is held to.
    ``state`` counts the control steps."""

    name = ORACLE

    def __init__(self, env: gym.Env) -> None:
        from cir_gym.self_motion import LAP_STRIDE

        self.env = env.unwrapped
        self.stride = LAP_STRIDE  # control steps between the path's points
        self.path = np.zeros((0, 0))

    def predict(self, obs: dict, state: np.ndarray | None = None,
                episode_start: np.ndarray | None = None, deterministic: bool = True
                ) -> tuple[np.ndarray, np.ndarray]:
        k = 0 if state is None else int(state[0])
        if k == 0:
            self.path = self.env.clearing_motion()
        i = k // self.stride
        qd = (self.path[i + 1] - self.path[i]) / (self.stride * self.env.dt)
        return np.clip(qd / self.env.velocity_limit, -1.0, 1.0), np.array([k + 1.0])


def make_policy(name: str, env: Any) -> Any:
    """The controller (or variant, or the oracle) ``name`` for ``env``."""
    from cir_gym.baselines.kinematic import KINEMATIC_CONTROLLERS

    if name == ORACLE:
        return ClearingMotion(env)
    controller, gains = VARIANTS.get(name, (name, {}))
    cls = next(c for c in KINEMATIC_CONTROLLERS if c.name == controller)
    return cls(env.unwrapped.controller_context(), **gains)


class ReplayTask(gym.Wrapper):
    """The env with its last drawn task: ``reset(seed=seed)`` replays the task drawn with
    ``seed`` (``reset(options={"replay": True})``, exact and without drawing again), so every
    controller plays the same episode through :func:`cir_gym.evaluation.evaluate`."""

    def __init__(self, env: gym.Env, seed: int) -> None:
        super().__init__(env)
        self.seed = seed

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        if seed != self.seed or options:
            raise ValueError(f"ReplayTask holds the task of seed {self.seed}, not {seed}")
        return self.env.reset(options={"replay": True})


def episode(policy: Any, env: gym.Env, env_id: str, seed: int) -> dict[str, float]:
    """One :func:`cir_gym.evaluation.evaluate` episode of ``policy`` on the task ``env`` drew
    with ``seed``: the metrics, success and whether it completed the lap."""
    from cir_gym.evaluation import evaluate

    result = evaluate(policy, env_id, 1, seed, env=ReplayTask(env, seed),
                      policy_name=getattr(policy, "name", None))
    ep = result.episodes[0]
    out = {m: float(ep.metrics[m]) for m in METRICS}
    out["success"] = float(ep.success)
    out["completed"] = float(not ep.terminated)
    out["singular_steps"] = float(getattr(policy, "singular_steps", 0))
    return out


def run(job: tuple[str, str, tuple[str, ...], int, int]
        ) -> dict[tuple[str, str, str], list[dict[str, float] | None]]:
    """(env, objective, policies, first seed, seeds) → per policy, per seed: the episode's
    numbers (None where the policy raised, e.g. SingularJacobian). Each seed is drawn once."""
    _register()
    env_name, objective, names, first, count = job
    env = gym.make(ENVS[env_name], objective=objective)
    out: dict[tuple[str, str, str], list[dict[str, float] | None]] = {
        (env_name, objective, name): [] for name in names}
    for seed in range(first, first + count):
        env.reset(seed=seed)
        for name in names:
            policy = make_policy(name, env)
            try:
                out[(env_name, objective, name)].append(
                    episode(policy, env, ENVS[env_name], seed))
            except FloatingPointError as exc:  # a singular Jacobian: reported, not hidden
                print(f"{env_name} {objective} {name} seed {seed}: {exc}")
                out[(env_name, objective, name)].append(None)
    env.close()
    print(f"done: {env_name} {objective} seeds {first}..{first + count - 1}", file=sys.stderr,
          flush=True)
    return out


def check(episodes: int = 2) -> None:
    """The replayed episodes equal freshly drawn ones (every metric)."""
    from cir_gym.evaluation import evaluate

    _register()
    for env_name in ENVS:
        for objective, name in (("obstacle", "clik_nullspace"), ("manipulability", TEXTBOOK),
                                ("joint_limits", "clik")):
            ours = run((env_name, objective, (name,), 0, episodes))[(env_name, objective, name)]
            env = gym.make(ENVS[env_name], objective=objective)
            theirs = evaluate(make_policy(name, env), ENVS[env_name], episodes, seed=0, env=env)
            for a, b in zip(ours, theirs.episodes, strict=True):
                assert a is not None and all(a[m] == b.metrics[m] for m in METRICS), (a, b)
                assert a["success"] == b.success and a["completed"] == (not b.terminated)
            print(f"check: {env_name} {objective} {name}: {episodes} episodes identical")


def _collect(results: dict[tuple[str, str, str], list[dict[str, float] | None]]
             ) -> dict[tuple[str, str, str], dict[str, np.ndarray]]:
    """Per (env, objective, policy): metric arrays over the seeds; {} if it ever raised."""
    out = {}
    for key, rows in results.items():
        if any(r is None for r in rows):
            out[key] = {}
            continue
        out[key] = {m: np.array([r[m] for r in rows]) for m in rows[0]}
        out[key]["singular_steps"] = np.array([np.sum(out[key]["singular_steps"])])
    return out


def singular_path(out: Path) -> dict[str, float]:
    """Planar arm along a radial line to 1 mm beyond full reach and back: peak q̇ (rad/s).

    The CLIK feedback K e then points along the singular (radial) direction while σ_min → 0.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from cir_gym.baselines.kinematic import CLIK, DampedLeastSquaresCLIK

    from cir_gym.envs.redundant_ik import RedundantIKEnv

    env = RedundantIKEnv()
    context = env.controller_context()
    dt, T = context.dt, 4.0
    t = np.arange(int(T / dt) + 1) * dt
    r0, r1 = 1.0, 1.2 + 1e-3  # m: reach is 1.2 m, the far end 1 mm beyond it
    s = 0.5 * (1 - np.cos(2 * np.pi * t / T))  # out and back, at rest at both ends
    sd = 0.5 * (2 * np.pi / T) * np.sin(2 * np.pi * t / T)
    heading = np.array([np.cos(0.3), np.sin(0.3)])
    x_ref = (r0 + (r1 - r0) * s)[:, None] * heading
    xd_ref = ((r1 - r0) * sd)[:, None] * heading
    q0 = env.kin.solve_ik(env.home.copy(), x_ref[0], np.eye(3))
    speeds, peaks = {}, {}
    for cls in (CLIK, DampedLeastSquaresCLIK):
        policy = cls(context)
        q, rows = q0.copy(), []
        for k in range(len(t)):
            x = env.robot.site_pose("ee", q)[0][:2]
            obs = {"q": q, "x": x, "x_ref": x_ref[k], "xd_ref": xd_ref[k]}
            try:
                qd = policy.control(obs, np.zeros(0))
            except FloatingPointError:
                qd = np.full(3, np.nan)
            rows.append(qd)
            if np.all(np.isfinite(qd)):  # the env clips to the velocity limits
                q = q + dt * np.clip(qd, -env.velocity_limit, env.velocity_limit)
        speeds[cls.name] = np.array(rows)
        peaks[cls.name] = float(np.nanmax(np.abs(rows)))
    fig, ax = plt.subplots(figsize=(7, 4))
    for name, qd in speeds.items():
        ax.semilogy(t, np.max(np.abs(qd), axis=1), label=f"{name}: max |q̇_i| commanded")
    ax.axhline(2.0, color="k", ls="--", label="velocity limit 2 rad/s")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("rad/s")
    ax.set_title("planar3r: reference to 1 mm beyond full reach and back")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "singular_path.png", dpi=120)
    plt.close(fig)
    return peaks


def _increase(r: dict[str, np.ndarray], plain: dict[str, np.ndarray]) -> str:
    """'+x % (median per seed, higher on k/n seeds, lower on j)' of min manipulability."""
    ratio = r["min_manipulability"] / plain["min_manipulability"]
    inc = 100 * (np.mean(r["min_manipulability"]) / np.mean(plain["min_manipulability"]) - 1)
    return (f"**{inc:+.1f} %** (median per seed {100 * (np.median(ratio) - 1):+.1f} %, higher "
            f"on {int(np.sum(ratio > 1.001))}/{ratio.size} seeds, lower on "
            f"{int(np.sum(ratio < 0.999))}); RMS task error {np.mean(r['rms_task_error']):.2e} m")


def summary(e: str, results: dict[tuple[str, str, str], dict[str, np.ndarray]]) -> list[str]:
    """The bullet points of one environment."""
    lines = []
    plain = results[(e, "manipulability", "clik")]
    if plain:
        lines.append(
            f"- manipulability (the start is, by construction, the posture whose "
            f"minimum-norm lap is least manipulable: plain CLIK is poor there by design): "
            f"clik's RMS task error {np.mean(plain['rms_task_error']):.2e} m; the mean minimum "
            f"manipulability against clik's:")
        for label, what in ((TEXTBOOK, "the textbook law, q̇₀ = k₀ ∇w"),
                            (NO_SEARCH, "∇ ln w, barrier, scaling, saturation"),
                            ("clik_nullspace", "the same plus the self-motion search")):
            r = results[(e, "manipulability", label)]
            lines.append(f"  - {label} ({what}): " + (_increase(r, plain) if r else
                                                       "raised SingularJacobian"))
    plain = results[(e, "obstacle", "clik")]
    if plain:
        hit = plain["min_clearance"] < 0
        lines.append(
            f"- obstacle (placed, by construction, on the sweep of the minimum-norm motion, so "
            f"clik collides in {int(hit.sum())}/{hit.size} episodes by design; every obstacle "
            f"comes with a clearing motion, \"{ORACLE}\" plays it back): kept a positive "
            f"clearance over the whole lap in the episodes where clik collides:")
        for label in (TEXTBOOK, "clik_nullspace"):
            r = results[(e, "obstacle", label)]
            if r:
                kept = int(np.sum(hit & (r["min_clearance"] > 0)))
                lines.append(f"  - {label}: **{kept}**/{int(hit.sum())} (median min clearance "
                             f"{np.median(r['min_clearance']):.4f} m, success "
                             f"{100 * np.mean(r['success']):.0f} %)")
    return lines


def table(e: str, results: dict[tuple[str, str, str], dict[str, np.ndarray]]) -> list[str]:
    """The per-controller table of one environment."""
    lines = ["| objective | controller | success | RMS task error (m): mean / worst | "
             "min manipulability | limit hits | collisions | median min clearance (m) | "
             "joint drift (rad), completed laps | algorithmic-singular steps |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for (env_name, objective, name), r in results.items():
        if env_name != e:
            continue
        if not r:
            lines.append(f"| {objective} | {name} | raised SingularJacobian | | | | | | | |")
            continue
        hits = int(np.sum(r["min_joint_limit_margin"] <= 0))
        collisions = int(np.sum(r["min_clearance"] < 0))
        clearance = f"{np.median(r['min_clearance']):.4f}" if objective == "obstacle" else "–"
        done = r["completed"] > 0
        drift = (f"{np.mean(r['joint_drift'][done]):.3f} ({int(done.sum())})" if done.any()
                 else "– (0)")
        singular = f"{int(r['singular_steps'][0])}" if name == "clik_augmented" else "–"
        lines.append(
            f"| {objective} | {name} | {100 * np.mean(r['success']):.0f} % | "
            f"{np.mean(r['rms_task_error']):.2e} / {np.max(r['rms_task_error']):.2e} | "
            f"{np.mean(r['min_manipulability']):.4f} | {hits} | {collisions} | {clearance} | "
            f"{drift} | {singular} |")
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("results/redundancy"))
    parser.add_argument("--envs", default="RedundantIK,RedundantIK7",
                        help="comma-separated: RedundantIK, RedundantIK7")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    parser.add_argument("--check", action="store_true",
                        help="only compare the replayed episodes with freshly drawn ones")
    args = parser.parse_args(argv)
    if args.check:
        check()
        return
    args.out.mkdir(parents=True, exist_ok=True)
    envs = [e for e in args.envs.split(",") if e]
    groups = [(e, "manipulability", (*ALL, NO_SEARCH)) for e in envs]
    groups += [(e, "joint_limits", ALL) for e in envs]
    groups += [(e, "obstacle", OBSTACLE_POLICIES) for e in envs]
    jobs = [(e, objective, names, first, min(CHUNK, args.episodes - first))
            for e, objective, names in groups for first in range(0, args.episodes, CHUNK)]
    raw: dict[tuple[str, str, str], list[dict[str, float] | None]] = {}
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for part in pool.map(run, jobs):  # in job order: seeds ascending per key
            for key, rows in part.items():
                raw.setdefault(key, []).extend(rows)
    results = _collect(raw)

    lines = [f"# Redundancy measurements ({args.episodes} seeds, 0..{args.episodes - 1})", "",
             "Generated by `python scripts/research/eval_redundancy.py`. RMS task error: mean "
             "and worst episode; a terminated episode is scored over the whole lap against the "
             "reference the stopped arm no longer follows. Limit hits / collisions: episodes "
             "ending at a joint limit / on the obstacle. Joint drift: ‖q(T) − q(0)‖ over the "
             "completed laps only.", ""]
    for e in envs:
        lines += [f"## {ENVS[e]}", "", *summary(e, results), "", *table(e, results), ""]
    if "RedundantIK" in envs:
        peaks = singular_path(args.out)
        lines += ["## Near-singular path (planar3r: reference to 1 mm beyond full reach and back)",
                  "",
                  "| controller | peak commanded joint speed (rad/s) |", "|---|---|"]
        lines += [f"| {k} | {v:.3g} |" for k, v in peaks.items()]
        lines += ["", "Joint speeds: `singular_path.png`.", ""]
    text = "\n".join(lines)
    print(text)
    (args.out / "redundancy.md").write_text(text)


if __name__ == "__main__":
    main()
