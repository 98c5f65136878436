"""The setpoint-level force laws on AdmittanceContactImpedance: held-out table, crossover
selection and the loop's model margins (docs/controllers/setpoint.md, baselines/setpoint.py).

    python scripts/research/eval_setpoint_force_laws.py [--episodes 30] [--seed 5000]
    python scripts/research/eval_setpoint_force_laws.py --selection [--episodes 10 --seed 6000]
    python scripts/research/eval_setpoint_force_laws.py --margins

Default mode: impedance_setpoint, admittance_setpoint and implicit_force_setpoint at default
gains on held-out seeds ``--seed`` … ``--seed + episodes − 1`` (the leaderboard uses 1000+),
on plates of unknown stiffness (``randomize=True``: stiffness, damping, sensor bias and f̄
drawn) and of known 1e3, 1e4, 1e5 N/m (f̄ = 20 N), every episode through
``cir_gym.evaluation.evaluate``. Per row: the force RMS error's mean with its 95 % bootstrap
interval (``cir_gym.metrics.mean_interval``), successes with their 95 % Wilson interval
(``wilson_interval``), the largest single contact force (``max_force``: ‖f_i‖ of the largest
contact on the plate at any physics step) mean and worst, and the worst episode's contact
loss. Written to ``<out>/held_out.md``.

``--selection``: admittance_setpoint's crossover rule against the alternatives it was chosen
over (a fixed ω_c = √(K_p,n/Λ_nn)/3 on every plate, ω_c = ω_s on every plate through the
filter's ``damping``/``mass`` overrides, the default with a 0.5-s force ramp), force RMS error
mean per plate. Written to ``<out>/crossover_selection.md``.

``--margins``: the phase and gain margins of the 1-D loop model of
:class:`cir_gym.baselines.setpoint.SetpointInteraction` (numpy frequency sweep, no
simulation beyond one episode that gives the tip's inertia range):

    plant   f/z_c = k_e (1 + s/ω_L) G(s),  k_e = K_p,n k/(K_p,n + k),
            G(s) = (1 + c s/k)(K_p,n + k)/(Λ_nn s² + (K_d,n + c) s + K_p,n + k)
    sensor  e^{−s(τ_d + T_s/2 + h)}/(1 + s/(2π f_c)),  policy hold e^{−s T/2}
    admittance  C(s) = 1/(M_d s² + D_d s);  implicit  C(s) = (k_Pf + k_If/s)/(k̂_e s (1 + s/ω_L))

with each law's gains as it designs them in the env (K_p,n, K_d,n = K_p,n/ω_L, τ_d, T_s, f_c,
h and T from the controller context), over Λ_nn in the range the nominal arm's task inertia
along n̂ takes in an episode (q₀ and every posture in contact), c ∈ {5, 20, 50} N s/m, and k
the designed k̂ (known plates) or 21 log-spaced values in [1e3, 1e5] N/m (unknown stiffness,
designed at 1e5 N/m). The sweep runs to the policy's Nyquist frequency π/T, above which the
continuous model says nothing of the 20-Hz loop. Written to ``<out>/margins.md``.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import cir_gym
from cir_gym import baselines
from cir_gym.evaluation import EvaluationResult, evaluate
from cir_gym.metrics import mean_interval, wilson_interval

ENV_ID = next(e for e in cir_gym.ENVIRONMENTS
              if e.startswith("cir_gym/AdmittanceContactImpedance-"))
LAWS = ("impedance_setpoint", "admittance_setpoint", "implicit_force_setpoint")
FORCE_LAWS = LAWS[1:]
SETTINGS: dict[str, dict[str, Any]] = {
    "unknown (randomize)": {"randomize": True},
    "1e3 N/m": {"stiffness": 1.0e3, "force_ref": 20.0},
    "1e4 N/m": {"stiffness": 1.0e4, "force_ref": 20.0},
    "1e5 N/m": {"stiffness": 1.0e5, "force_ref": 20.0},
}
SELECTION_SETTINGS = ("unknown (randomize)", "1e3 N/m", "1e5 N/m")
DAMPING = (5.0, 20.0, 50.0)  # N s/m: the plate's damping, the randomized range and default
UNKNOWN_GRID = np.logspace(3.0, 5.0, 21)  # N/m


# ---------------------------------------------------------------------- held-out table
def row(result: EvaluationResult) -> list[str]:
    """The table's cells of one law on one plate."""
    rms = np.array([ep.metrics["force_rms_error"] for ep in result.episodes])
    peak = np.array([ep.metrics["max_force"] for ep in result.episodes])
    loss = np.array([ep.metrics["contact_loss"] for ep in result.episodes])
    n, k = len(result.episodes), sum(ep.success for ep in result.episodes)
    lo, hi = mean_interval(rms)
    w_lo, w_hi = wilson_interval(k, n)
    return [f"{rms.mean():.2f} [{lo:.2f}, {hi:.2f}]",
            f"{k}/{n} ({100 * w_lo:.0f}–{100 * w_hi:.0f} %)",
            f"{peak.mean():.1f}, {peak.max():.1f}", f"{loss.max():.4f}"]


def held_out(episodes: int, seed: int) -> list[str]:
    """The held-out table (markdown lines)."""
    lines = [
        "| plate | law | force RMS error (N), mean [95 % CI] | success (Wilson 95 %) | "
        "largest contact (N), mean, worst | contact loss, worst |",
        "|---|---|---|---|---|---|",
    ]
    for setting, kw in SETTINGS.items():
        for law in LAWS:
            policy = baselines.make(law, ENV_ID, env_kwargs=kw)
            result = evaluate(policy, ENV_ID, episodes, seed, policy_name=law, **kw)
            cells = row(result)
            lines.append(f"| {setting} | {law} | " + " | ".join(cells) + " |")
            print(lines[-1], flush=True)
    return lines


# ---------------------------------------------------------------------- crossover selection
def designed(law: str, kw: dict[str, Any], **gains: Any) -> tuple[Any, np.ndarray]:
    """``law`` on an env made with ``kw``, designed at the start posture q₀ (seed 1000), and
    q₀ (7,) (rad)."""
    env = gym.make(ENV_ID, **kw)
    policy = baselines.make(law, ENV_ID, env=env, **gains)
    obs, _ = env.reset(seed=1000)
    policy.predict(obs, None, episode_start=[True])
    env.close()
    return policy, obs["q"]


def selection_variants(kw: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """admittance_setpoint's gain overrides of each alternative rule on plate ``kw``."""
    law, q0 = designed("admittance_setpoint", kw)
    lam = law.lambda_normal(q0)  # Λ_nn (kg) at the start posture
    damping_s = law.k_e / law.omega_s  # ω_c = ω_s whatever the loop's lag
    return {
        "the rule: min(ω_s, 1/(3 τ_G))": {},
        "ω_c = √(K_p,n/Λ_nn)/3 on every plate": {
            "crossover": math.sqrt(law.loop_normal_stiffness / lam) / 3},
        "ω_c = ω_s on every plate": {"damping": damping_s, "mass": damping_s / law.lead_zero},
        "the rule + 0.5-s force ramp": {"ramp_time": 0.5},
    }


def selection(episodes: int, seed: int) -> list[str]:
    """admittance_setpoint's force RMS error (mean) per rule and plate (markdown lines)."""
    results: dict[str, dict[str, str]] = {}
    for setting in SELECTION_SETTINGS:
        kw = SETTINGS[setting]
        for label, gains in selection_variants(kw).items():
            policy = baselines.make("admittance_setpoint", ENV_ID, env_kwargs=kw, **gains)
            result = evaluate(policy, ENV_ID, episodes, seed, **kw)
            rms = np.array([ep.metrics["force_rms_error"] for ep in result.episodes])
            results.setdefault(label, {})[setting] = f"{rms.mean():.2f}"
            print(f"{label} @ {setting}: {rms.mean():.3f} N", flush=True)
    lines = ["| admittance_setpoint, crossover | " + " | ".join(SELECTION_SETTINGS) + " |",
             "|---" * (len(SELECTION_SETTINGS) + 1) + "|"]
    lines += [f"| {label} | " + " | ".join(cells[s] for s in SELECTION_SETTINGS) + " |"
              for label, cells in results.items()]
    return lines


# ---------------------------------------------------------------------- margins
def inertia_range(seed: int = 5000) -> tuple[float, float]:
    """min, max of the nominal arm's Λ_nn (kg) at the start posture and every posture in
    contact of one admittance_setpoint episode on an unknown plate (the wipe included)."""
    env = gym.make(ENV_ID, randomize=True)
    law = baselines.make("admittance_setpoint", ENV_ID, env=env)
    obs, _ = env.reset(seed=seed)
    values = [law.lambda_normal(obs["q"])]
    state, start, done = None, [True], False
    while not done:
        action, state = law.predict(obs, state, episode_start=start)
        start = [False]
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
        if info["contact_force"] > 0.5:
            values.append(law.lambda_normal(obs["q"]))
    env.close()
    return min(values), max(values)


def plant(s: np.ndarray, k: float, c: float, lam: float, K: float, K_d: float) -> np.ndarray:
    """f/z_c (N/m) of the loop along n̂ on a plate k (N/m), c (N s/m), tip inertia lam (kg)."""
    k_e = K * k / (K + k)
    G = (1 + c * s / k) * (K + k) / (lam * s**2 + (K_d + c) * s + K + k)
    return k_e * (1 + s * K_d / K) * G


def lags(s: np.ndarray, extras: dict[str, Any], T: float) -> np.ndarray:
    """The sensor's filter and delays and the policy's hold, e^{−s τ}/(1 + s/(2π f_c))."""
    tau = (extras["sensor_delay"] + extras["sensor_period"] / 2 + extras["physics_timestep"]
           + T / 2)
    return np.exp(-s * tau) / (1 + s / (2 * math.pi * extras["sensor_cutoff"]))


def compensator(law: Any, s: np.ndarray) -> np.ndarray:
    """The force law's C(s) from the force error to the depth z_c (m/N), as designed."""
    if law.name == "admittance_setpoint":
        return 1.0 / (law.M_d * s**2 + law.D_d * s + law.gains.stiffness_normal)
    return (law.k_pf + law.k_if / s) / (law.k_e * s * (1 + s / law.omega_i))


def margins_of(L: np.ndarray, w: np.ndarray) -> tuple[float, float, float, float]:
    """(phase margin (deg), its frequency, gain margin, its frequency) of L(jω): the least over
    every gain crossover |L| = 1 and every phase crossover ∠L = −180° (mod 360°) with |L| < 1."""
    mag, phase = np.abs(L), np.unwrap(np.angle(L))
    pm, w_pm, gm, w_gm = math.inf, math.nan, math.inf, math.nan
    for i in np.nonzero(np.diff(np.sign(mag - 1.0)))[0]:
        margin = (math.degrees(phase[i]) + 180.0) % 360.0
        if margin > 180.0:
            margin -= 360.0
        if margin < pm:
            pm, w_pm = margin, w[i]
    wrapped = (phase + math.pi) / (2 * math.pi)  # integer at −180° + m 360°
    for i in np.nonzero(np.diff(np.floor(wrapped)))[0]:
        if mag[i] < 1.0 and 1.0 / mag[i] < gm:
            gm, w_gm = 1.0 / mag[i], w[i]
    return pm, w_pm, gm, w_gm


def margins() -> list[str]:
    """The least margins per law and plate over the model's cases (markdown lines)."""
    lam_lo, lam_hi = inertia_range()
    lines = [f"Λ_nn of the nominal arm along n̂: {lam_lo:.2f}–{lam_hi:.2f} kg (start posture "
             "and every posture in contact, one admittance_setpoint episode, seed 5000); "
             f"plate damping c ∈ {list(DAMPING)} N s/m.", "",
             "| law | plate (design k̂) | ω_c designed (rad/s) | phase margin, least (deg) | "
             "where (k N/m, c, Λ_nn, ω rad/s) | gain margin, least | where |",
             "|---|---|---|---|---|---|---|"]
    for law_name, setting in itertools.product(FORCE_LAWS, SETTINGS):
        kw = SETTINGS[setting]
        env = gym.make(ENV_ID, **kw)
        extras, T = env.unwrapped.controller_context().extras, env.unwrapped.dt
        env.close()
        law, _ = designed(law_name, kw)
        w = np.logspace(-2, math.log10(math.pi / T), 40001)
        s = 1j * w
        C, H = compensator(law, s), lags(s, extras, T)
        plates = UNKNOWN_GRID if kw.get("randomize") else [law.k_hat]
        least = [math.inf, "", math.inf, ""]
        for k, c, lam in itertools.product(plates, DAMPING, (lam_lo, lam_hi)):
            L = C * plant(s, k, c, lam, law.loop_normal_stiffness, law.normal_damping) * H
            pm, w_pm, gm, w_gm = margins_of(L, w)
            where = f"{k:.3g}, {c:g}, {lam:.2f}, "
            if pm < least[0]:
                least[:2] = pm, where + f"{w_pm:.2f}"
            if gm < least[2]:
                least[2:] = gm, where + f"{w_gm:.1f}"
        omega_c = law.crossover()
        gm_text = f"{least[2]:.2f}" if math.isfinite(least[2]) else f"none below {w[-1]:.0f}"
        lines.append(f"| {law_name} | {setting} ({law.k_hat:.0e}) | {omega_c:.2f} | "
                     f"{least[0]:.1f} | {least[1]} | {gm_text} | {least[3] or '—'} |")
        print(lines[-1], flush=True)
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--selection", action="store_true", help="the crossover rule's choice")
    mode.add_argument("--margins", action="store_true", help="the 1-D model's loop margins")
    parser.add_argument("--episodes", type=int, default=None, help="30; --selection: 10")
    parser.add_argument("--seed", type=int, default=None, help="5000; --selection: 6000")
    parser.add_argument("--out", type=Path, default=Path("results/setpoint_force_laws"))
    args = parser.parse_args(argv)
    episodes = args.episodes or (10 if args.selection else 30)
    seed = args.seed if args.seed is not None else (6000 if args.selection else 5000)
    command = "python scripts/research/eval_setpoint_force_laws.py " + " ".join(
        sys.argv[1:] if argv is None else argv)
    if args.margins:
        name, title, body = "margins.md", "Loop margins of the 1-D model", margins()
    elif args.selection:
        name, title = "crossover_selection.md", "admittance_setpoint: the crossover rule"
        body = [f"{episodes} episodes per cell, seeds {seed}–{seed + episodes - 1}; force RMS "
                "error mean (N).", "", *selection(episodes, seed)]
    else:
        name, title = "held_out.md", "Setpoint-level force laws, held-out seeds"
        body = [f"{episodes} episodes per cell, seeds {seed}–{seed + episodes - 1}, default "
                "gains, `cir_gym.evaluation.evaluate`.", "", *held_out(episodes, seed)]
    args.out.mkdir(parents=True, exist_ok=True)
    text = [f"# {title}", "", f"Written by `{command.strip()}` on {ENV_ID} (do not edit).", "",
            *body]
    (args.out / name).write_text("\n".join(text) + "\n")


if __name__ == "__main__":
    main()
