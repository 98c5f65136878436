"""Measured claims of chapters 4 and 5 on JointTracking-v1 (figures and a markdown summary).

    python scripts/eval_joint_tracking.py [--episodes 10] [--out results/joint_tracking]

1. Unknown 3 kg payload: RMS error of computed torque on the nominal model vs robust and
   adaptive control (the factors), and the adaptive law's π̂ and ‖Y π̃‖ over an episode.
2. Chapter 4's claim: decentralized vs centralized control as the gear ratio goes from direct
   drive (1:1) to 160:1, with the rotor inertias of the robot file (armature = N² J_m).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import baselines
from cir_gym import dynamics
from cir_gym.evaluation import evaluate
from cir_gym.plotting import _plt
from cir_gym.robot import ModelError, Robot

ENV = "cir_gym/JointTracking-v1"
GEAR_RATIOS = (1.0, 5.0, 20.0, 50.0, 100.0, 160.0)


def payload_comparison(episodes: int, out: Path) -> list[str]:
    kwargs = {"payload_mass": 3.0}
    rows, results = [], {}
    for name in ("computed_torque", "robust", "adaptive"):
        policy = baselines.make(name, ENV, env_kwargs=kwargs)
        results[name] = evaluate(policy, ENV, episodes, 1000, record=name == "adaptive", **kwargs)
    base = results["computed_torque"].summary["rms_error"]["mean"]
    for name, r in results.items():
        s = r.summary["rms_error"]
        rows.append(
            f"| {name} | {s['mean']:.3g} | {s['worst']:.3g} | {base / s['mean']:.1f}× |"
            f" {100 * r.success_rate:.0f}% |"
        )
    plot_adaptive(results["adaptive"], out / "adaptive_parameters.png")
    return [
        "## Unknown 3 kg payload (computed torque on the nominal model as the base)",
        "",
        f"{episodes} episodes, seeds 1000…",
        "",
        "| controller | RMS error (rad) | worst episode | factor vs computed torque | success |",
        "|---|---|---|---|---|",
        *rows,
        "",
        "![adaptive π̂ and ‖Yπ̃‖](adaptive_parameters.png)",
        "",
    ]


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


def gear_ratio_sweep(episodes: int, out: Path) -> list[str]:
    names = ("pid", "p_pi_feedforward", "decentralized_feedforward", "computed_torque")
    table = {n: [] for n in names}
    for ratio in GEAR_RATIOS:
        kwargs = {"gear_ratio": ratio}
        for name in names:
            policy = baselines.make(name, ENV, env_kwargs=kwargs)
            r = evaluate(policy, ENV, episodes, 2000, **kwargs)
            table[name].append(r.summary["rms_error"]["mean"])
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, values in table.items():
        ax.loglog(GEAR_RATIOS, values, "o-", label=name)
    ax.set_xlabel("gear ratio N (armature = N² J_m)")
    ax.set_ylabel("RMS joint error (rad)")
    ax.set_title("Decentralized vs centralized control vs gear ratio (JointTracking-v1)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "gear_ratio_sweep.png", dpi=110)
    plt.close(fig)
    head = "| controller | " + " | ".join(f"N = {r:g}" for r in GEAR_RATIOS) + " |"
    rows = [f"| {n} | " + " | ".join(f"{v:.2g}" for v in vals) + " |" for n, vals in table.items()]
    return [
        "## Gear ratio: decentralized vs centralized (RMS joint error, rad)",
        "",
        f"{episodes} episodes per cell, seeds 2000…, rotor inertias of the robot file.",
        "",
        head,
        "|---|" + "---|" * len(GEAR_RATIOS),
        *rows,
        "",
        "![gear ratio sweep](gear_ratio_sweep.png)",
        "",
    ]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--out", default="results/joint_tracking")
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lines = [
        "# JointTracking-v1: measured claims",
        "",
        "Generated by `python scripts/eval_joint_tracking.py`.",
        "",
    ]
    lines += payload_comparison(args.episodes, out)
    lines += gear_ratio_sweep(max(1, args.episodes // 2), out)
    (out / "README.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
