"""``cir-gym identify``: least-squares identification on the true simulator, then control.

1. An excitation trajectory (finite Fourier series inside the joint and speed limits) is
   tracked on the TRUE simulator of JointTracking-v1 (with the unknown payload) by computed
   torque on the nominal model, at 1 kHz.
2. Measurements: q, q̇ (encoders), q̈ from the forward difference of q̇ (exact for MuJoCo's
   semi-implicit step), and the applied torque plus Gaussian noise (``noise`` N m std).
3. ``cir_gym.dynamics.identify`` estimates the base parameters (condition number reported);
   the full parameter vector closest to the nominal one is handed to computed torque.
4. Computed torque on the identified model is scored against the nominal and the exact model
   on the same seeds.

The torque noise (0.2 N m std by default) is an assumption. Measured with a 60-s excitation
and a 3 kg payload: identified/exact RMS error 1.65× at 0.2 N m, 3.2× at 0.5 N m; noise-free
data gives 1.00× (the base parameters are exact).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

import baselines
from cir_gym import dynamics
from cir_gym.evaluation import evaluate
from cir_gym.robot import Robot

ENV = "cir_gym/JointTracking-v1"


def excitation_data(
    payload_mass: float, duration: float, noise: float, seed: int
) -> tuple[np.ndarray, ...]:
    """(q, q̇, q̈, τ_measured) sampled at 1 kHz on the true simulator."""
    env = gym.make(ENV, payload_mass=payload_mass)
    true_model = env.unwrapped.model
    nominal = env.unwrapped.controller_context().nominal_robot()
    env.close()
    traj = dynamics.excitation_trajectory(
        nominal.model, duration=duration, seed=seed, margin=0.15,
        velocity_limit=0.6 * nominal.velocity_limit,
    )
    data = mujoco.MjData(true_model)
    dt = true_model.opt.timestep
    t = np.arange(round(duration / dt)) * dt
    q_ref, qd_ref, qdd_ref = traj.evaluate(t)
    data.qpos[:], data.qvel[:] = q_ref[0], qd_ref[0]
    kp, kd = 400.0, 40.0
    limit = nominal.torque_limit
    q, qd, tau = (np.zeros_like(q_ref) for _ in range(3))
    for k in range(t.size):
        q[k], qd[k] = data.qpos, data.qvel
        y = qdd_ref[k] + kd * (qd_ref[k] - qd[k]) + kp * (q_ref[k] - q[k])
        tau[k] = np.clip(nominal.inverse_dynamics(q[k], qd[k], y), -limit, limit)
        data.ctrl[:] = tau[k]
        mujoco.mj_step(true_model, data)
    qd_next = np.vstack((qd[1:], data.qvel))
    qdd = (qd_next - qd) / dt
    rng = np.random.default_rng(seed)
    tau_measured = tau + noise * rng.standard_normal(tau.shape)
    return q, qd, qdd, tau_measured


def run_identify(
    payload_mass: float = 3.0,
    duration: float = 60.0,
    noise: float = 0.2,
    seed: int = 0,
    episodes: int = 5,
    out: str | Path = "results/identification",
) -> dict[str, float]:
    """Identify, evaluate, print and write a markdown report; return the RMS errors."""
    q, qd, qdd, tau = excitation_data(payload_mass, duration, noise, seed)
    every = 1  # every 1 kHz sample: the noise averages out as 1/sqrt(N)
    env = gym.make(ENV, payload_mass=payload_mass)
    nominal = env.unwrapped.controller_context().nominal_robot()
    result = dynamics.identify(nominal.model, q[::every], qd[::every], qdd[::every],
                               tau[::every])
    prior = dynamics.inertial_parameters(nominal.model)
    identified = result.to_full_parameters(prior=prior)
    exact = Robot(env.unwrapped.model).copy()  # the simulator's truth, for the reference only
    policies = {
        "computed_torque (nominal model)": baselines.make("computed_torque", ENV, env=env),
        "computed_torque (identified model)": baselines.make(
            "computed_torque", ENV, env=env, parameters=identified
        ),
        "computed_torque (exact model)": baselines.make("computed_torque", ENV, env=env,
                                                        robot=exact),
    }
    env.close()
    rms = {}
    for name, policy in policies.items():
        r = evaluate(policy, ENV, episodes, 1000, policy_name=name, payload_mass=payload_mass)
        rms[name] = r.summary["rms_error"]["mean"]
    ratio = rms["computed_torque (identified model)"] / rms["computed_torque (exact model)"]
    link7_mass = identified[10 * 6]
    lines = [
        "# Identification (`cir-gym identify`)", "",
        f"Unknown payload {payload_mass} kg, excitation {duration} s at 1 kHz "
        f"(every {every}th sample used: {q[::every].shape[0]} samples), torque noise "
        f"{noise} N m, seed {seed}.", "",
        f"- base parameters: {result.base_parameters.size} of {prior.size}; condition number "
        f"of the stacked base regressor {result.condition_number:.3g}; residual RMS "
        f"{result.residual_rms:.3g} N m",
        f"- identified link-7 mass (with the payload merged): {link7_mass:.3f} kg "
        f"(nominal {prior[60]:.3f} kg; true {prior[60] + payload_mass:.3f} kg — the mass "
        "itself is identifiable only in combination, see `base_parameter_names`)", "",
        f"| controller ({episodes} episodes, seeds 1000…) | RMS joint error (rad) |", "|---|---|",
        *[f"| {k} | {v:.3g} |" for k, v in rms.items()], "",
        f"Identified / exact: {ratio:.2f}× (target ≤ 2×).", "",
    ]
    text = "\n".join(lines)
    print(text)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "README.md").write_text(text)
    return rms
