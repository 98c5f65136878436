"""Measured claims of chapters 4 and 5 on JointTracking-v2 (figures and a markdown summary).

    python scripts/research/eval_joint_tracking.py [--episodes 10] [--jobs 1] \
        [--out results/joint_tracking]

1. Robust control against computed torque AT EQUAL LINEAR GAINS: the designed ω_n = 20,
   ζ = 1; robust (same design, boundary layer from :class:`baselines.centralized.RobustGains`);
   computed torque at robust's in-layer gains; computed torque at the gains the old, thin layer
   gave (ω_n = 73.5, ζ = 1.97); adaptive control. On the exact model, the 3 kg payload, the
   corners of robust's declared uncertainty set (5 kg, masses ×0.8 or ×1.2, friction 1 N m s/rad
   and 1 N m), JointTracking's ``randomize`` draws, and a 0.3-rad initial error (outside the
   layer). The adaptive law's π̂ and ‖Y π̃‖ over a payload episode.
2. Where gains cost: computed torque's error against ω_n with ideal sensing and with the
   ``drive="industrial"`` model of :mod:`cir_gym.drives` (20-bit encoders, velocity by
   differences, one period of delay, 2 % ripple), exact model and 3 kg payload.
3. Anti-windup of the decentralized integrators (back-calculation, clamping, none) where
   the torque saturates: large regulation moves, and tracking at small gear ratios.
4. Chapter 4's claim: decentralized vs centralized control as the gear ratio goes from direct
   drive (1:1) to 160:1, with the rotor inertias of the robot file (armature = N² J_m), on the
   exact model and under the unknown 3 kg payload; RMS error, max error, saturation, and a
   conclusion computed from those numbers.

Every line of the README is written here: regenerate it, do not edit it by hand.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from cir_gym import baselines, dynamics
from cir_gym.evaluation import EvaluationResult, evaluate
from cir_gym.robot import ModelError, Robot
from cir_gym.scoring.plotting import _plt

ENV = "cir_gym/JointTracking-v2"
GEAR_RATIOS = (1.0, 5.0, 20.0, 50.0, 100.0, 160.0)
DECENTRALIZED = ("pid", "p_pi_cascade", "p_pi_feedforward", "decentralized_feedforward")
SWEEP = (*DECENTRALIZED, "computed_torque")
SWEEP_VARIANTS = {"exact model": {}, "unknown 3 kg payload": {"payload_mass": 3.0}}
#: "competitive with computed torque": RMS error at most this factor above computed torque's
COMPETITIVE = 2.0


def _cell(name: str, kwargs: dict[str, Any], episodes: int, seed: int, record: bool = False,
          gains: dict[str, Any] | None = None):
    """One controller (with gain overrides) on one environment variant (a process-pool task)."""
    policy = baselines.make(name, ENV, env_kwargs=kwargs, **(gains or {}))
    return evaluate(policy, ENV, episodes, seed, record=record, **kwargs)


def _run(tasks: list[tuple], jobs: int) -> list[EvaluationResult]:
    if jobs <= 1:
        return [_cell(*t) for t in tasks]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        return list(pool.map(_cell, *zip(*tasks, strict=True)))


def _stopped(r: EvaluationResult) -> int:
    return sum(ep.terminated for ep in r.episodes)


#: the variants of the robust comparison: inside robust's declared uncertainty set
ROBUST_VARIANTS = {
    "exact model": {},
    "3 kg payload": {"payload_mass": 3.0},
    "set corner: 5 kg, masses ×0.8, friction": {
        "payload_mass": 5.0, "mass_scale": 0.8, "viscous_friction": 1.0, "coulomb_friction": 1.0},
    "set corner: 5 kg, masses ×1.2, friction": {
        "payload_mass": 5.0, "mass_scale": 1.2, "viscous_friction": 1.0, "coulomb_friction": 1.0},
    "randomize (draws inside the set)": {"randomize": True},
    "0.3-rad initial error, 3 kg": {"initial_error": 0.3, "payload_mass": 3.0},
}
#: the gains the old boundary layer (ε = ρ Q₂₂ dt / 0.5) gave robust control inside its layer
OLD_LAYER_GAINS = {"omega_n": 73.5, "zeta": 1.97}


def robust_comparison(episodes: int, out: Path, jobs: int) -> list[str]:
    robust = baselines.make("robust", ENV)
    omega = float(np.sqrt(robust.kp_layer))
    layer = {"omega_n": omega, "zeta": float(robust.kd_layer / (2 * omega))}
    rows_spec = {
        "computed_torque (ω_n = 20, ζ = 1: the design)": ("computed_torque", {}),
        "robust (same design, ε from the designed gains)": ("robust", {}),
        f"computed_torque at robust's in-layer gains (ω_n = {omega:.1f}, ζ = "
        f"{layer['zeta']:.2f})": ("computed_torque", layer),
        "computed_torque at the old thin layer's gains (ω_n = 73.5, ζ = 1.97)": (
            "computed_torque", OLD_LAYER_GAINS),
        "adaptive": ("adaptive", {}),
    }
    tasks, keys = [], []
    for variant, kwargs in ROBUST_VARIANTS.items():
        for label, (name, gains) in rows_spec.items():
            record = name == "adaptive" and variant == "3 kg payload"
            tasks.append((name, kwargs, episodes, 1000, record, gains))
            keys.append((variant, label))
    results = dict(zip(keys, _run(tasks, jobs), strict=True))
    plot_adaptive(results["3 kg payload", "adaptive"], out / "adaptive_parameters.png")
    head = "| controller | " + " | ".join(ROBUST_VARIANTS) + " |"
    rule = "|---|" + "---|" * len(ROBUST_VARIANTS)

    def table(metric: str, stat: str) -> list[str]:
        return [f"| {label} | " + " | ".join(
            f"{results[v, label].summary[metric][stat]:.3g}"
            + (f" ({_stopped(results[v, label])} stopped)" if _stopped(results[v, label]) else "")
            for v in ROBUST_VARIANTS) + " |" for label in rows_spec]

    labels = list(rows_spec)
    design, rob, same, old = labels[:4]
    in_set = [v for v in ROBUST_VARIANTS if not v.startswith("0.3")]
    worst = {lab: max(results[v, lab].summary["max_error"]["worst"] for v in in_set)
             for lab in labels}
    ratio = [results[v, rob].summary["rms_error"]["mean"]
             / results[v, same].summary["rms_error"]["mean"] for v in ROBUST_VARIANTS]
    return [
        "## Robust control against computed torque at equal linear gains",
        "",
        f"{episodes} episodes per cell, seeds 1000…. Robust's declared uncertainty set: "
        f"payload 0…{robust.gains.payload_bound:g} kg, link masses ×(1 ± "
        f"{robust.gains.mass_scale_bound:g}), viscous friction ≤ "
        f"{robust.gains.viscous_friction_bound:g} N m s/rad, Coulomb ≤ "
        f"{robust.gains.coulomb_friction_bound:g} N m (JointTracking's `randomize` ranges); "
        f"sampled bound α = {robust.alpha:.3f}, B_M Φ = {robust.b_phi:.3g} rad/s², ρ = "
        f"{robust.rho:.0f} rad/s²; boundary layer ε = {robust.epsilon:.3g}, inside which the "
        f"law is computed torque with K_P = {robust.kp_layer:.0f}, K_D = "
        f"{robust.kd_layer:.0f} (designed: 400, 40).",
        "",
        "### RMS joint error (rad, mean over episodes)",
        "",
        head, rule, *table("rms_error", "mean"),
        "",
        "### max joint error (rad, worst episode)",
        "",
        head, rule, *table("max_error", "worst"),
        "",
        "### saturated steps (mean fraction)",
        "",
        head, rule, *table("saturation", "mean"),
        "",
        "What the numbers say (computed by the script):",
        "",
        f"- robust / computed torque at robust's in-layer gains, RMS error: "
        f"{min(ratio):.3g}–{max(ratio):.3g}× over the variants: inside its layer robust control "
        "IS that computed torque, and the errors here stay inside the layer.",
        f"- the old 11.9× of robust over computed torque was the gain: computed torque at the "
        f"old layer's gains reaches {results['3 kg payload', old].summary['rms_error']['mean']:.3g}"
        f" rad under the 3 kg payload, against "
        f"{results['3 kg payload', design].summary['rms_error']['mean']:.3g} at the design "
        "gains.",
        f"- what robustness buys is a bound, not a smaller error: the worst max error over "
        f"the episodes inside the declared set is {worst[rob]:.3g} rad for robust, "
        f"{worst[same]:.3g} for computed torque at the same gains, {worst[design]:.3g} at the "
        "design gains; ρ is computed so that the course's V̇ < 0 holds outside the layer for "
        "every model of the set (a sampled bound), which no fixed-gain computed torque "
        "states.",
        "",
        "![adaptive π̂ and ‖Yπ̃‖](adaptive_parameters.png)",
        "",
    ]


OMEGAS = (10.0, 20.0, 40.0, 80.0, 160.0, 200.0, 240.0, 320.0)
DRIVES = {"ideal sensing": {}, "industrial drive": {"drive": "industrial"}}
GAIN_VARIANTS = {"exact model": {}, "3 kg payload": {"payload_mass": 3.0}}


def gain_sweep(episodes: int, out: Path, jobs: int) -> list[str]:
    """Computed torque's RMS error against ω_n (ζ = 1), ideal sensing vs the industrial drive."""
    tasks, keys = [], []
    for variant, kwargs in GAIN_VARIANTS.items():
        for drive, dk in DRIVES.items():
            for w in OMEGAS:
                tasks.append(("computed_torque", {**kwargs, **dk}, episodes, 3000, False,
                              {"omega_n": w}))
                keys.append((variant, drive, w))
    results = dict(zip(keys, _run(tasks, jobs), strict=True))
    rms = {k: r.summary["rms_error"]["mean"] for k, r in results.items()}
    head = "| variant, sensing | " + " | ".join(f"ω_n = {w:g}" for w in OMEGAS) + " |"
    rows, notes = [], []
    for variant in GAIN_VARIANTS:
        for drive in DRIVES:
            cells = []
            for w in OMEGAS:
                r = results[variant, drive, w]
                stop = _stopped(r)
                sat = r.summary["saturation"]["mean"]
                cells.append(f"{rms[variant, drive, w]:.2g}"
                             + (f" ({stop} stopped)" if stop else "")
                             + (f" [{100 * sat:.0f}% sat]" if sat > 0.01 else ""))
            rows.append(f"| {variant}, {drive} | " + " | ".join(cells) + " |")
        ideal = np.array([rms[variant, "ideal sensing", w] for w in OMEGAS])
        real = np.array([rms[variant, "industrial drive", w] for w in OMEGAS])
        best = OMEGAS[int(np.argmin(real))]
        cost = [w for w, a, b in zip(OMEGAS, ideal, real, strict=True) if b > 2 * a]
        notes.append(
            f"- **{variant}**: with ideal sensing the error falls {ideal[0] / ideal[-1]:.3g}× from "
            f"ω_n = {OMEGAS[0]:g} to {OMEGAS[-1]:g}; with the industrial drive it is lowest at "
            f"ω_n = {best:g} ({real.min():.3g} rad)"
            + (f" and at least twice the ideal from ω_n = {cost[0]:g} on" if cost else
               ", never twice the ideal in this range")
            + "."
        )
    plot_gain_sweep(rms, out / "gain_sweep.png")
    return [
        "## Where gains cost: computed torque vs ω_n, ideal sensing vs an industrial drive",
        "",
        f"{episodes} episodes per cell, seeds 3000…, ζ = 1. Industrial drive "
        "(`drive=\"industrial\"`, cir_gym/drives.py): 20-bit encoders (6.0e-6 rad), q̇ as the "
        "difference of two readings, one control period (2 ms) of actuation delay, 2 % torque "
        "ripple. RMS joint error (rad); [sat]: mean fraction of saturated steps when > 1 %.",
        "",
        head, "|---|" + "---|" * len(OMEGAS), *rows,
        "",
        *notes,
        "",
        "![gain sweep](gain_sweep.png)",
        "",
    ]


WINDUP_CASES = {
    "regulation, N = 160": {"reference": "regulation"},
    "regulation, N = 20": {"reference": "regulation", "gear_ratio": 20.0},
    "tracking, N = 1": {"gear_ratio": 1.0},
    "tracking, N = 50": {"gear_ratio": 50.0},
}
WINDUP_MODES = ("back_calculation", "clamping", "none")


def windup_comparison(episodes: int, jobs: int) -> list[str]:
    """RMS and final error of pid and p_pi_cascade with each anti-windup mode."""
    tasks, keys = [], []
    for case, kwargs in WINDUP_CASES.items():
        for name in ("pid", "p_pi_cascade"):
            for mode in WINDUP_MODES:
                tasks.append((name, kwargs, episodes, 2000, False, {"anti_windup": mode}))
                keys.append((case, name, mode))
    results = dict(zip(keys, _run(tasks, jobs), strict=True))
    rows = []
    for name in ("pid", "p_pi_cascade"):
        for mode in WINDUP_MODES:
            cells = []
            for case in WINDUP_CASES:
                s = results[case, name, mode].summary
                cells.append(f"{s['rms_error']['mean']:.2g} / {s['final_error']['worst']:.2g} / "
                             f"{100 * s['saturation']['mean']:.0f}%")
            rows.append(f"| {name}, {mode} | " + " | ".join(cells) + " |")
    return [
        "## Anti-windup of the decentralized integrators",
        "",
        f"{episodes} episodes per cell, seeds 2000…. Cells: RMS joint error (rad) / final "
        "error (rad, worst episode) / saturated steps. Default: back-calculation "
        "(baselines/decentralized.py).",
        "",
        "| controller, anti-windup | " + " | ".join(WINDUP_CASES) + " |",
        "|---|" + "---|" * len(WINDUP_CASES),
        *rows,
        "",
    ]


def plot_gain_sweep(rms: dict[tuple[str, str, float], float], path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for variant in GAIN_VARIANTS:
        for drive, style in zip(DRIVES, ("o-", "s--"), strict=True):
            ax.loglog(OMEGAS, [rms[variant, drive, w] for w in OMEGAS], style,
                      label=f"{variant}, {drive}")
    ax.set_xlabel("ω_n (rad/s), ζ = 1")
    ax.set_ylabel("RMS joint error (rad)")
    ax.set_title("Computed torque: the gain at which sensing starts to cost (JointTracking-v2)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_adaptive(result, path: Path) -> None:
    """π̂ of the last link (mass and first moments) and ‖Y π̃‖ along the first episode."""
    plt = _plt()
    trace = result.episodes[0].trace
    true = Robot.from_name("iiwa14").with_error(ModelError(payload_mass=3.0))
    pi_true = dynamics.inertial_parameters(true.model)
    pi_hat = trace["state"]  # (T, p): the policy state is π̂
    q, qd = trace["obs/q"], trace["obs/qd"]
    lam = baselines.CONTROLLERS["adaptive"].Gains().lam
    e, ed = trace["obs/q_ref"] - q, trace["obs/qd_ref"] - qd
    qd_r, qdd_r = trace["obs/qd_ref"] + lam * e, trace["obs/qdd_ref"] + lam * ed
    err = np.array(
        [
            np.linalg.norm(
                dynamics.regressor(true.model, q[k], qd[k], qdd_r[k], qd_r=qd_r[k])
                @ (pi_true - pi_hat[k])
            )
            for k in range(0, len(q), 10)
        ]
    )
    t = np.arange(len(q)) * result.dt
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    i0 = 10 * 6  # link 7: [m, m c_x, m c_y, m c_z, ...]
    for j, label in enumerate(["m₇ (kg)", "m₇c₇ₓ", "m₇c₇ᵧ", "m₇c₇_z (kg m)"]):
        (line,) = a1.plot(t, pi_hat[:, i0 + j], label=f"π̂: {label}")
        a1.axhline(pi_true[i0 + j], color=line.get_color(), ls="--", lw=0.8)
    a1.set_ylabel("parameter")
    a1.set_title("Slotine-Li estimates of the last link (dashed: true with the payload)")
    a1.legend(fontsize=8)
    a2.semilogy(t[::10], err)
    a2.set_ylabel("‖Y π̃‖ (N m)")
    a2.set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _factor(x: float) -> str:
    return f"{x:.2g}×" if x < 100 else f"{x:.0f}×"


def _at(ratios: list[float]) -> str:
    if len(ratios) == len(GEAR_RATIOS):
        return "every N"
    return "N = " + ", ".join(f"{n:g}" for n in ratios)


def conclusion(variant: str, rms: dict[str, list[float]], sat: dict[str, list[float]]) -> str:
    """Sentences from the numbers: which decentralized controllers come within
    ``COMPETITIVE``× of computed torque's RMS error, at which N, within what factor (factor =
    the controller's RMS error / computed torque's at the same N), how much N helps, and where
    the loops saturate."""
    ct = np.array(rms["computed_torque"])
    parts, never = [], []
    for name in DECENTRALIZED:
        f = np.array(rms[name]) / ct
        ok = f <= COMPETITIVE
        if ok.any():
            lo, hi = _factor(f[ok].min()), _factor(f[ok].max())
            span = lo if lo == hi else f"{lo[:-1]}–{hi}"
            parts.append(f"{name} at {_at([GEAR_RATIOS[i] for i in np.flatnonzero(ok)])} "
                         f"({span})")
        else:
            i = int(np.argmin(f))
            never.append(f"{name} (best {_factor(f[i])} at N = {GEAR_RATIOS[i]:g})")
    sentences = []
    if parts:
        sentences.append(
            f"within {COMPETITIVE:g}× of computed torque's RMS error: " + "; ".join(parts)
        )
    else:
        sentences.append(f"no decentralized controller comes within {COMPETITIVE:g}× of "
                         "computed torque's RMS error at any N")
    if never:
        sentences.append("never within: " + ", ".join(never))
    better = [n for n in DECENTRALIZED if np.any(np.array(rms[n]) < ct)]
    if better:
        sentences.append("below computed torque's error at some N: " + ", ".join(better))
    gain = [rms[n][0] / rms[n][-1] for n in DECENTRALIZED]
    sentences.append(
        f"from N = {GEAR_RATIOS[0]:g} to {GEAR_RATIOS[-1]:g} the decentralized errors fall "
        f"{_factor(min(gain))[:-1]}–{_factor(max(gain))}, computed torque's "
        f"{_factor(rms['computed_torque'][0] / rms['computed_torque'][-1])}"
    )
    saturating = [r for i, r in enumerate(GEAR_RATIOS)
                  if max(sat[n][i] for n in DECENTRALIZED) > 0.01]
    if saturating:
        worst = max(max(sat[n]) for n in DECENTRALIZED)
        sentences.append(
            f"decentralized loops saturate on more than 1 % of the steps at "
            f"{_at(saturating)} (up to {100 * worst:.0f} %)"
        )
    return f"**{variant}**: " + "; ".join(sentences) + "."


def gear_ratio_sweep(episodes: int, out: Path, jobs: int) -> list[str]:
    tasks, keys = [], []
    for variant, extra in SWEEP_VARIANTS.items():
        for ratio in GEAR_RATIOS:
            for name in SWEEP:
                tasks.append((name, {"gear_ratio": ratio, **extra}, episodes, 2000))
                keys.append((variant, ratio, name))
    results = dict(zip(keys, _run(tasks, jobs), strict=True))
    head = "| controller | " + " | ".join(f"N = {r:g}" for r in GEAR_RATIOS) + " |"
    rule = "|---|" + "---|" * len(GEAR_RATIOS)
    lines = [
        "## Gear ratio: decentralized vs centralized",
        "",
        f"{episodes} episodes per cell, seeds 2000…, rotor inertias of the robot file; computed "
        "torque uses the nominal model (so under the payload it has the model error too).",
        "",
    ]
    rms_by_variant, sat_by_variant = {}, {}
    for variant in SWEEP_VARIANTS:
        rms = {n: [results[variant, r, n].summary["rms_error"]["mean"] for r in GEAR_RATIOS]
               for n in SWEEP}
        rms_by_variant[variant] = rms
        sat_by_variant[variant] = {
            n: [results[variant, r, n].summary["saturation"]["mean"] for r in GEAR_RATIOS]
            for n in SWEEP
        }
        detail = []
        for n in SWEEP:
            cells = []
            for r in GEAR_RATIOS:
                res = results[variant, r, n]
                s = res.summary
                stop = _stopped(res)
                mark = f", {stop} stopped" if stop else ""
                cells.append(
                    f"{s['max_error']['worst']:.2g} / {100 * s['saturation']['mean']:.0f}%{mark}"
                )
            detail.append(f"| {n} | " + " | ".join(cells) + " |")
        lines += [
            f"### {variant}: RMS joint error (rad)",
            "",
            head,
            rule,
            *[f"| {n} | " + " | ".join(f"{v:.2g}" for v in rms[n]) + " |" for n in SWEEP],
            "",
            f"### {variant}: max joint error (rad, worst episode) / saturated steps (mean)",
            "",
            "\"stopped\": episodes ended by the following-error monitor (scored over the whole "
            "horizon with the last error held).",
            "",
            head,
            rule,
            *detail,
            "",
        ]
    plot_sweep(rms_by_variant, out / "gear_ratio_sweep.png")
    lines += [
        "![gear ratio sweep](gear_ratio_sweep.png)",
        "",
        "## Conclusion (computed by the script from the tables above)",
        "",
        *[f"- {conclusion(v, rms, sat_by_variant[v])}" for v, rms in rms_by_variant.items()],
        "",
    ]
    return lines


def plot_sweep(rms_by_variant: dict[str, dict[str, list[float]]], path: Path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, len(rms_by_variant), figsize=(12, 4.5), sharey=True)
    for ax, (variant, table) in zip(np.atleast_1d(axes), rms_by_variant.items(), strict=True):
        for name, values in table.items():
            ax.loglog(GEAR_RATIOS, values, "o-", label=name)
        ax.set_xlabel("gear ratio N (armature = N² J_m)")
        ax.set_title(variant)
        ax.grid(True, which="both", alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("RMS joint error (rad)")
    np.atleast_1d(axes)[0].legend(fontsize=8)
    fig.suptitle("Decentralized vs centralized control vs gear ratio (JointTracking-v2)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--episodes", type=int, default=10, help="robust comparison; sweeps: half")
    p.add_argument("--jobs", type=int, default=1, help="worker processes")
    p.add_argument("--out", default="results/joint_tracking")
    args = p.parse_args(argv)
    if args.episodes < 1 or args.jobs < 1:
        p.error("--episodes and --jobs must be >= 1")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lines = [
        "# JointTracking-v2: measured claims",
        "",
        f"Generated by `python scripts/research/eval_joint_tracking.py --episodes {args.episodes}` "
        f"on `{ENV}`; do not edit by hand.",
        "",
    ]
    lines += robust_comparison(args.episodes, out, args.jobs)
    lines += gain_sweep(max(1, args.episodes // 2), out, args.jobs)
    lines += windup_comparison(max(1, args.episodes // 2), args.jobs)
    lines += gear_ratio_sweep(max(1, args.episodes // 2), out, args.jobs)
    text = "\n".join(lines)
    (out / "README.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
