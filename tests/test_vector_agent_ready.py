"""The batched agent-ready variants (cir_gym.envs.agent_ready_vector) against the single
variants, copy by copy, and the impedance law on N arms against each arm alone.

Tolerance: a copy runs the single variant's computations — the task's batched env (itself
equal to the single task to 1e-12, tests/test_vector_admittance.py), MuJoCo's forward
kinematics and dynamics of the nominal arm row by row, and the single variant's own methods
(setpoint move, impedance law, reward terms, observation) on (N, ...) arrays instead of one
row. What may differ is round-off: numpy may reduce an (N, n) array and a (1, n) row in
different orders (SIMD lanes). So observations, rewards, step infos and metrics agree to 1e-12
(relative, or absolute near 0); lengths, ends and success exactly.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from lockstep import assert_close, assert_same_episodes, lockstep

import cir_gym
from cir_gym.envs.agent_ready import AdmittanceContactImpedanceEnv, PegInHoleImpedanceEnv
from cir_gym.envs.agent_ready_vector import (
    AdmittanceContactImpedanceVectorEnv,
    PegInHoleImpedanceVectorEnv,
)
from cir_gym.impedance import CartesianImpedance, ImpedanceGains, exp_rotvec
from cir_gym.validation import InvalidArgument

CONTACT = "cir_gym/AdmittanceContactImpedance-v1"
CONTACT_CLASS = "cir_gym.envs.agent_ready_vector:AdmittanceContactImpedanceVectorEnv"
TOL = 1e-12
STEPS_PEG = 22  # copy 0 inserts at its 20th policy step




def _lockstep(envs: Any, singles: list, seed: int, actions: np.ndarray) -> list[dict]:
    """Each copy equal to its single variant (tests/lockstep.py, to TOL) under ``actions``
    (steps, N, dim); returns the single variants' last infos of the ended episodes."""
    return lockstep(envs, singles, lambda k, obs, start: actions[k], seed=seed,
                    steps=len(actions), tol=TOL).ends


def test_each_copy_is_the_single_variant_with_ends_inside_a_policy_step() -> None:
    """Random setpoint increments pushing down with random high stiffness (variable
    impedance) on plates of unknown stiffness: copies exceed a 40-N force limit at different
    task steps inside a policy step (their task-term sums, final infos and metrics as of that
    task step), the others run on; every end is autoreset in the same step. Sensor noise on:
    an ended copy's unused task steps must draw nothing from its generator."""
    kw = {"episode_duration": 1.0, "variable_stiffness": True, "randomize": True,
          "force_limit": 40.0}
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1.0, 1.0, (26, 2, 12))
    actions[:, :, 2] = -1.0  # down onto the plate
    actions[:, :, 6:9] = rng.uniform(0.0, 1.0, (26, 2, 3))  # stiff
    envs = AdmittanceContactImpedanceVectorEnv(num_envs=2, nthread=1, **kw)
    singles = [AdmittanceContactImpedanceEnv(**kw) for _ in range(2)]
    ends = _lockstep(envs, singles, 5, actions)
    envs.close()
    assert len(ends) >= 2  # then their next episodes, from the autoreset
    assert all(e["force_limit_exceeded"] for e in ends)
    assert any(e["task_steps"] < singles[0].substeps for e in ends)  # inside a policy step


def test_each_copy_is_the_single_variant_over_whole_episodes() -> None:
    """The default variant (constant stiffness): wiping increments pressing the tip into the
    plate, two truncated episodes per copy (6 policy steps each)."""
    kw = {"episode_duration": 0.3}
    rng = np.random.default_rng(1)
    actions = rng.uniform(-0.5, 0.5, (12, 2, 6))
    actions[:, :, 2] = -1.0
    envs = AdmittanceContactImpedanceVectorEnv(num_envs=2, nthread=1, **kw)
    ends = _lockstep(envs, [AdmittanceContactImpedanceEnv(**kw) for _ in range(2)], 11, actions)
    envs.close()
    assert len(ends) == 4 and not any(e["force_limit_exceeded"] for e in ends)


def test_each_peg_copy_is_the_single_variant_with_insertions_and_stops() -> None:
    """PegInHoleImpedance with the hole where it is believed to be (no pose error; 1 mm
    clearance, 2 mm chamfer): copy 0 pushes straight down at the geometric-mean stiffness and
    inserts (success ends inside a policy step), copy 1 wanders sideways at the highest
    stiffness and is stopped by the force limit on the block's face; both are autoreset and
    go on (the single PegInHole task's batched env underneath)."""
    kw = {"episode_duration": 1.5, "variable_stiffness": True, "position_uncertainty": 0.0,
          "tilt_uncertainty": 0.0, "clearance": 0.001, "chamfer": 0.002}
    rng = np.random.default_rng(2)
    actions = np.zeros((STEPS_PEG, 2, 12))
    actions[:, :, 2] = -1.0
    actions[:, 1, :2] = rng.uniform(-1.0, 1.0, (STEPS_PEG, 2))
    actions[:, 1, 6:] = 1.0
    envs = PegInHoleImpedanceVectorEnv(num_envs=2, nthread=1, **kw)
    singles = [PegInHoleImpedanceEnv(**kw) for _ in range(2)]
    ends = _lockstep(envs, singles, 0, actions)
    envs.close()
    assert any(e["is_success"] for e in ends)
    assert any(e["force_limit_exceeded"] for e in ends)
    assert any(e["task_steps"] < singles[0].substeps for e in ends)


def test_the_impedance_law_on_n_arms_is_each_arm_alone() -> None:
    """CartesianImpedance of N arms (q (N, n)) against one arm per row ((n,)): poses, Λ and
    torques to 1e-12 (the same MuJoCo computations and formulas; round-off only)."""
    env = AdmittanceContactImpedanceEnv(episode_duration=0.5)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(2)
    N, n = 4, env.nominal.n
    q = obs["q"] + 0.1 * rng.standard_normal((N, n))
    qd = 0.5 * rng.standard_normal((N, n))
    q_rest = obs["q"] + 0.05 * rng.standard_normal((N, n))
    gains = ImpedanceGains(np.r_[np.full(3, 800.0), np.full(3, 40.0)], np.full(6, 30.0))
    arms = CartesianImpedance(env.nominal, "tcp", gains, q_rest)
    p, R = arms.pose(q)
    p_d = p + 0.01 * rng.standard_normal((N, 3))
    R_d = exp_rotvec(0.1 * rng.standard_normal((N, 3))) @ R
    K_p = rng.uniform(100.0, 5000.0, (N, 6))
    K_d = rng.uniform(1.0, 100.0, (N, 6))
    tau = arms.torque(q, qd, p_d, R_d, K_p, K_d)
    Lam = arms.task_inertia(q)
    for i in range(N):
        one = CartesianImpedance(env.nominal, "tcp", gains, q_rest[i])
        p_i, R_i = one.pose(q[i])
        assert_close(p[i], p_i, TOL, "p")
        assert_close(R[i], R_i, TOL, "R")
        assert_close(Lam[i], one.task_inertia(q[i]), TOL, "Λ")
        assert_close(tau[i], one.torque(q[i], qd[i], p_d[i], R_d[i], K_p[i], K_d[i]), TOL, "τ")
    with pytest.raises(ValueError, match="shape"):
        arms.torque(q[0], qd[0], p_d[0], R_d[0])


def test_make_vec_gives_the_batched_variant_and_falls_back(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(cir_gym.envs.BATCHED_ENVIRONMENTS, CONTACT, CONTACT_CLASS)
    native = cir_gym.make_vec(CONTACT, 2, nthread=1, episode_duration=0.5, randomize=True)
    assert type(native) is AdmittanceContactImpedanceVectorEnv and native.num_envs == 2
    assert native.single_observation_space == AdmittanceContactImpedanceEnv(
        episode_duration=0.5).observation_space
    native.close()
    with pytest.raises(InvalidArgument, match="render_mode"):
        AdmittanceContactImpedanceVectorEnv(num_envs=2, render_mode="rgb_array")
    with pytest.raises(InvalidArgument, match="control_freq"):
        AdmittanceContactImpedanceVectorEnv(num_envs=2, control_freq=30.0)  # the single's check
    sync = cir_gym.make_vec(CONTACT, 2, render_mode="rgb_array", episode_duration=0.5)
    assert isinstance(sync, gym.vector.SyncVectorEnv)
    sync.close()


def test_batched_training_env_is_the_registry_s(monkeypatch: pytest.MonkeyPatch) -> None:
    """vec_env 'batched' (agents/batched.py) takes the id's class from the registry: the
    batched variant once it is in BATCHED_ENVIRONMENTS (copy i the flat single observation
    with seed 7 + i; through the SB3 adapter, every copy done at the 5th step with its
    terminal observation, truncation flag, metrics and Monitor statistics), a clear error
    for an id with none or an argument it does not batch."""
    from cir_gym.agents.batched import make_batched_vec_env
    from cir_gym.agents.observation import ObservationLayout

    monkeypatch.setitem(cir_gym.envs.BATCHED_ENVIRONMENTS, CONTACT, CONTACT_CLASS)
    kw = {"episode_duration": 0.25}
    single = AdmittanceContactImpedanceEnv(**kw)
    layout = ObservationLayout.from_space(single.observation_space)
    venv = make_batched_vec_env(CONTACT, kw, layout, 2, seed=7)
    obs = venv.reset()
    assert type(venv.venv.venv) is AdmittanceContactImpedanceVectorEnv
    for i in range(2):
        assert_close(obs[i], layout.flatten(single.reset(seed=7 + i)[0]), TOL, f"reset {i}")
    for _ in range(5):
        obs, rew, dones, infos = venv.step(np.zeros((2, 6), dtype=np.float32))
    assert dones.all() and rew.dtype == np.float32 and obs.shape == (2, layout.size)
    for info in infos:
        assert info["TimeLimit.truncated"] and info["episode"]["l"] == 5
        assert info["terminal_observation"].shape == (layout.size,)
        assert "force_rms_error" in info["episode_metrics"]
    venv.close()
    with pytest.raises(ValueError, match="render_mode"):
        make_batched_vec_env(CONTACT, {"render_mode": "rgb_array"}, layout, 2, seed=7)
    with pytest.raises(ValueError, match="features='detected'"):
        make_batched_vec_env("cir_gym/VisualServoEyeToHand-v1", {"features": "detected"},
                             layout, 2, seed=7)


def test_batched_evaluation_gives_the_sequential_episodes(monkeypatch: pytest.MonkeyPatch) -> None:
    """evaluate() with the id in BATCHED_ENVIRONMENTS runs the normalized score's hold-still
    policy (zeros: the setpoint held) on the batched variant: the sequential EpisodeResults,
    returns and metrics to TOL; the unknown-stiffness variant."""
    import cir_gym.evaluation as evaluation
    from cir_gym.scoring.normalized import hold_still_policy

    monkeypatch.setitem(cir_gym.envs.BATCHED_ENVIRONMENTS, CONTACT, CONTACT_CLASS)
    monkeypatch.setattr(evaluation, "MAX_BATCH", 2)  # 3 episodes: groups of 2 and 1
    kw = {"episode_duration": 0.5, "randomize": True}
    policy = hold_still_policy(AdmittanceContactImpedanceEnv(**kw))
    assert evaluation._batched_env_class(CONTACT, None, False, kw, None) is (
        AdmittanceContactImpedanceVectorEnv)
    fast = evaluation.evaluate(policy, CONTACT, n_episodes=3, seed=40, **kw)
    slow = evaluation.evaluate(policy, CONTACT, n_episodes=3, seed=40, batched=False, **kw)
    assert_same_episodes(fast, slow, TOL)
