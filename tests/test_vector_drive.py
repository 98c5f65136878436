"""The batched joint-space envs with a real drive (``drive``: encoders, velocity by differences,
delay, ripple), ``torque_noise`` and ``encoder_resolution`` against the single envs, copy by copy.

Tolerance: observations, rewards, infos and metrics to 1e-12 relative. The drive's arithmetic
is one code (:class:`cir_gym.drives.DriveState`) on a (n,) row and on (N, n) rows, elementwise
(rounding to the encoder quantum, the backward difference, the ripple's sin), the physics is
mj_step's own per copy, and the noise is drawn from the copy's generator in the single env's
order, so a copy's numbers are in fact its single env's, bit for bit; the rewards' reductions
may run in another order on (N, n) arrays (tests/test_vector.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from lockstep import lockstep

from cir_gym import baselines
from cir_gym.drives import DriveModel, DriveState
from cir_gym.envs.vector import (
    ElasticJointTrackingVectorEnv,
    JointTrackingVectorEnv,
    make_vec,
    native_vector_env,
)
from cir_gym.evaluation import batchable, evaluate

ENV = "cir_gym/JointTracking-v2"
N = 3
TOL = 1e-12
SHORT = {"episode_duration": 0.1}  # 50 steps: 120 steps cross two autoresets per copy
INDUSTRIAL_DRIVE = {"drive": "industrial"}


def _singles(vec_cls: type, kw: dict, n: int) -> list:
    return [vec_cls.env_class(**kw) for _ in range(n)]


@pytest.mark.parametrize(
    ("vec_cls", "kw"),
    [
        (JointTrackingVectorEnv, INDUSTRIAL_DRIVE),
        # 3 periods of delay (the queue's first periods), a stronger ripple
        (JointTrackingVectorEnv, {"drive": DriveModel(delay_steps=3, torque_ripple=0.2)}),
        (JointTrackingVectorEnv, {"torque_noise": 2.0}),
        (JointTrackingVectorEnv, {"encoder_resolution": 1e-3}),
        (JointTrackingVectorEnv, {**INDUSTRIAL_DRIVE, "torque_noise": 1.0, "payload_mass": 2.0}),
        # motor encoders too; a soft spring and 3 kg stop some episodes early
        (ElasticJointTrackingVectorEnv,
         {**INDUSTRIAL_DRIVE, "payload_mass": 3.0, "stiffness_scale": 0.4}),
    ],
)
def test_random_actions_each_copy_is_the_single_env(vec_cls, kw):
    kw = {**SHORT, **kw}
    rng = np.random.default_rng(1)
    envs = vec_cls(num_envs=N, nthread=1, **kw)
    seen = lockstep(
        envs, _singles(vec_cls, kw, N), lambda k, obs, start: rng.uniform(-1.3, 1.3, (N, 7)),
        seed=10, steps=120, tol=TOL,
    )
    assert len(seen.ends) >= 2 * N  # every copy crossed two episode ends
    envs.close()


def test_noise_is_drawn_from_each_copys_generator():
    """A copy's torque noise is its own seed's: copy 1 of seed 10 and copy 0 of seed 11 (the
    same single env) see the same observations; and the noise does act (copies differ from the
    noise-free run)."""
    kw = {**SHORT, "torque_noise": 5.0}
    a = np.full((2, 7), 0.1)
    envs, other = (JointTrackingVectorEnv(num_envs=2, nthread=1, **kw) for _ in range(2))
    quiet = JointTrackingVectorEnv(num_envs=2, nthread=1, **SHORT)
    envs.reset(seed=10)
    other.reset(seed=11)
    quiet.reset(seed=10)
    for _ in range(5):
        obs, *_ = envs.step(a)
        obs_other, *_ = other.step(a)
        obs_quiet, *_ = quiet.step(a)
    np.testing.assert_array_equal(obs["qd"][1], obs_other["qd"][0])
    assert np.all(np.abs(obs["qd"] - obs_quiet["qd"]) > 0)


@pytest.mark.parametrize(
    "law", ["pd_gravity", "computed_torque", "decentralized_feedforward", "pid"]
)
def test_course_laws_over_whole_episodes_with_the_industrial_drive(law):
    """A course law closes the loop on the drive's measurements (the batch's rows, its batched
    predict): two copies, 1-s episodes, 700 steps (a whole episode, an autoreset and part of
    the next one), each copy its single env."""
    kw = {"episode_duration": 1.0, **INDUSTRIAL_DRIVE}
    policy = baselines.make(law, ENV, env_kwargs=kw)
    state: list = [None]

    def act(k: int, obs: dict, start: np.ndarray) -> np.ndarray:
        action, state[0] = policy.predict(obs, state=state[0], episode_start=start,
                                          deterministic=True)
        return np.asarray(action)

    envs = JointTrackingVectorEnv(num_envs=2, nthread=1, **kw)
    seen = lockstep(envs, _singles(JointTrackingVectorEnv, kw, 2), act, seed=1000, steps=700,
                    tol=TOL)
    assert len(seen.ends) == 2 and not any(e["diverged"] for e in seen.ends)
    envs.close()


def test_evaluate_batches_the_industrial_drive_with_the_sequential_episodes():
    """``evaluate`` takes the batched path for the industrial drive (a course law: by itself)
    and its episodes are the sequential ones, returns included (bit for bit, as for the ideal
    drive in tests/test_evaluation.py)."""
    kw = {"episode_duration": 0.5, **INDUSTRIAL_DRIVE}
    assert native_vector_env(ENV, kw) is JointTrackingVectorEnv
    policy = baselines.make("pd_gravity", ENV, env_kwargs=kw)
    assert batchable(policy, ENV, **kw)
    fast = evaluate(policy, ENV, 3, 1000, batched=True, **kw)
    slow = evaluate(policy, ENV, 3, 1000, batched=False, **kw)
    for f, s in zip(fast.episodes, slow.episodes, strict=True):
        assert (f.seed, f.length, f.success, f.terminated, f.episode_return, f.metrics) == (
            s.seed, s.length, s.success, s.terminated, s.episode_return, s.metrics)


def test_make_vec_batches_drives_and_noise_but_not_randomize():
    for kw in (INDUSTRIAL_DRIVE, {"torque_noise": 0.1}, {"encoder_resolution": 1e-4}):
        envs = make_vec(ENV, 2, nthread=1, **SHORT, **kw)
        assert type(envs) is JointTrackingVectorEnv
        envs.close()
    assert JointTrackingVectorEnv.unsupported({"randomize": True}) is not None


def test_drive_rows_are_the_single_drive_of_each_row():
    """DriveState with rows: each row, reset on its own, is a single DriveState given that
    row's numbers (delay of 2 periods: the first command stands for the ones never sent)."""
    model = DriveModel(delay_steps=2)
    rng = np.random.default_rng(3)
    dt = 0.002
    rows = DriveState(model, 7, rows=3)
    singles = [DriveState(model, 7) for _ in range(3)]
    q, qd = rng.normal(size=(3, 7)), rng.normal(size=(3, 7))
    rows.reset(q, qd, dt)
    for i, s in enumerate(singles):
        s.reset(q[i], qd[i], dt)
    taus = []
    for k in range(6):
        if k == 3:  # row 1 starts a new episode
            rows.reset(q[1], qd[1], dt, rows=1)
            singles[1].reset(q[1], qd[1], dt)
        q = q + 0.01 * rng.normal(size=(3, 7))
        tau = rng.normal(size=(3, 7))
        taus.append(tau)
        got_q, got_qd = rows.measure(q, qd, dt)
        got_tau = rows.actuate(tau)
        for i, s in enumerate(singles):
            want_q, want_qd = s.measure(q[i], qd[i], dt)
            np.testing.assert_array_equal(got_q[i], want_q)
            np.testing.assert_array_equal(got_qd[i], want_qd)
            np.testing.assert_array_equal(got_tau[i], s.actuate(tau[i]))
    # row 0 now applies the command of 2 periods ago; row 1 (restarted at k = 3) k = 3's
    np.testing.assert_array_equal(got_tau[0], taus[3][0])
    np.testing.assert_array_equal(got_tau[1], taus[3][1])
    single = DriveState(model, 7)
    single.reset(q[2], qd[2], dt)
    rows.load_row(2, single)
    np.testing.assert_array_equal(rows.actuate(tau)[2], tau[2])  # a fresh episode's first
