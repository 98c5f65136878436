"""cir_gym.envs.vector's batched envs against the single envs, copy by copy; make_vec and the
registered vector entry points."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import cir_gym
from cir_gym.envs import BATCHED_ENVIRONMENTS
from cir_gym.envs.admittance_vector import AdmittanceContactVectorEnv
from cir_gym.envs.cartesian_vector import CartesianTrackingVectorEnv
from cir_gym.envs.joint_tracking import JointTrackingEnv
from cir_gym.envs.peg_in_hole_vector import PegInHoleVectorEnv
from cir_gym.envs.vector import (
    VECTOR_ENVS,
    ElasticJointTrackingVectorEnv,
    JointTrackingVectorEnv,
    make_vec,
)
from cir_gym.validation import InvalidArgument

N = 3
KW = {"episode_duration": 0.1}  # 50 steps: the run below crosses an autoreset
# Observations are compared exactly: mujoco.batch steps each copy with mj_step's own
# computation, and the observation is copies and one clip of those numbers. Rewards and
# metrics to 1e-12 relative: the single env and the batch call the same reward function
# (TrackingReward) on a (n,) row and on a (N, n) array, whose reductions numpy may run in
# another order (SIMD lanes), a difference in the last bits.
REWARD_TOL = 1e-12


def _run_singles(seed: int, actions: np.ndarray, env_cls=JointTrackingEnv, **kw) -> list[list]:
    """Per copy: (obs, reward, terminated, truncated, final_obs) per step, resets inline."""
    out = []
    for i in range(actions.shape[1]):
        env = env_cls(**kw)
        obs, _ = env.reset(seed=seed + i)
        rows = [(obs, None, None, None, None)]
        for a in actions[:, i]:
            obs, rew, term, trunc, info = env.step(a)
            final = None
            if term or trunc:
                final = (obs, info)
                obs, _ = env.reset()
            rows.append((obs, rew, term, trunc, final))
        out.append(rows)
    return out


@pytest.mark.parametrize(
    ("vec_cls", "kw"),
    [
        (JointTrackingVectorEnv, KW),
        (JointTrackingVectorEnv, {**KW, "reference": "sine", "payload_mass": 2.0}),
        # the elastic env: frame_skip 4, motor keys, charge_unplayed_steps on; a 0.4 stiffness
        # scale and 3 kg make the clipped random torques trip the following-error monitor
        (ElasticJointTrackingVectorEnv, {**KW, "payload_mass": 3.0, "stiffness_scale": 0.4}),
    ],
)
def test_each_copy_is_the_single_env_with_seed_plus_i(vec_cls, kw):
    rng = np.random.default_rng(1)
    steps = 60
    actions = rng.uniform(-1.3, 1.3, (steps, N, 7)).astype(np.float32)  # some get clipped
    want = _run_singles(10, actions, vec_cls.env_class, **kw)
    envs = vec_cls(num_envs=N, nthread=1, **kw)
    obs, _ = envs.reset(seed=10)
    assert set(obs) == set(want[0][0][0]) == set(envs.single_observation_space.spaces)
    for i in range(N):
        for key in obs:
            np.testing.assert_array_equal(obs[key][i], want[i][0][0][key])
    ended = 0
    for k in range(steps):
        obs, rew, term, trunc, infos = envs.step(actions[k])
        for i in range(N):
            w_obs, w_rew, w_term, w_trunc, w_final = want[i][k + 1]
            for key in obs:
                np.testing.assert_array_equal(obs[key][i], w_obs[key], err_msg=f"{k} {i} {key}")
            assert rew[i] == pytest.approx(w_rew, rel=REWARD_TOL, abs=REWARD_TOL)
            assert (bool(term[i]), bool(trunc[i])) == (w_term, w_trunc)
            if w_final is not None:
                ended += 1
                f_obs, f_info = w_final
                assert infos["_final_obs"][i]
                for key in f_obs:
                    np.testing.assert_array_equal(infos["final_obs"][i][key], f_obs[key])
                got = infos["final_info"]
                assert bool(got["is_success"][i]) == f_info["is_success"]
                for name, value in f_info["episode_metrics"].items():
                    assert got["episode_metrics"][name][i] == pytest.approx(value, rel=REWARD_TOL)
    assert ended == N  # every copy crossed one episode end


def test_unsupported_and_bad_arguments_are_named():
    with pytest.raises(InvalidArgument, match="randomize"):
        JointTrackingVectorEnv(num_envs=2, randomize=True)
    with pytest.raises(InvalidArgument, match="num_envs"):
        JointTrackingVectorEnv(num_envs=0)
    with pytest.raises(InvalidArgument, match="control_freq"):
        JointTrackingVectorEnv(num_envs=2, control_freq=-1.0)


def test_bad_actions_raise_value_errors():
    envs = JointTrackingVectorEnv(num_envs=2, nthread=1, **KW)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        envs.step(np.zeros(7))
    bad = np.zeros((2, 7))
    bad[1, 3] = np.nan
    with pytest.raises(ValueError, match=r"envs \[1\]"):
        envs.step(bad)


def test_sb3_adapter_follows_sb3_conventions_and_trains():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecEnv

    from cir_gym.envs.vector import sb3_vec_env

    envs = JointTrackingVectorEnv(num_envs=2, nthread=1, **KW)
    vec = sb3_vec_env(envs)
    assert isinstance(vec, VecEnv)
    vec.seed(5)
    obs = vec.reset()
    single = JointTrackingEnv(**KW)
    want, _ = single.reset(seed=6)  # copy 1 of seed 5
    np.testing.assert_array_equal(obs["q"][1], want["q"])
    zeros = np.zeros((2, 7), dtype=np.float32)
    for _ in range(50):  # the 50-step episode ends at the 50th step at the latest
        obs, rew, dones, infos = vec.step(zeros)
        if dones.any():
            break
    assert dones.all() and rew.dtype == np.float32
    for info in infos:
        assert "terminal_observation" in info and isinstance(info["is_success"], bool)
        assert set(info["episode_metrics"]) >= {"rms_error", "max_error"}
    PPO("MultiInputPolicy", vec, n_steps=8, batch_size=16, n_epochs=1, device="cpu").learn(16)


@pytest.mark.parametrize(
    "vec_cls",
    [JointTrackingVectorEnv, CartesianTrackingVectorEnv, AdmittanceContactVectorEnv,
     PegInHoleVectorEnv],
)
def test_a_nan_in_one_copy_diverges_that_copy_as_the_single_env(vec_cls):
    """NaN injected into copy 1's velocities: that copy (only) ends diverged, back at its last
    finite state (RobotEnv._simulate's rule), with the single env's final observation, reward
    and metrics; the others go on. (The contact envs' torque interface: their position
    interface's torque law rejects a NaN state, in the single env as in the batch.)"""
    actions = np.random.default_rng(2).uniform(-0.3, 0.3, (4, 2, 7))
    single = vec_cls.env_class(**KW)
    single.reset(seed=8)  # copy 1 of seed 7
    envs = vec_cls(num_envs=2, nthread=1, **KW)
    envs.reset(seed=7)
    for a in actions[:3]:
        single.step(a[1])
        envs.step(a)
    single.data.qvel[0] = np.nan
    envs.batch.bind("qvel")[1, 0] = np.nan
    w_obs, w_rew, w_term, _, w_info = single.step(actions[3, 1])
    obs, rew, term, _, infos = envs.step(actions[3])
    assert w_term and w_info["diverged"]
    assert list(term) == [False, True] and list(infos["diverged"]) == [False, True]
    assert rew[1] == pytest.approx(w_rew, rel=REWARD_TOL)
    for key in w_obs:
        np.testing.assert_allclose(infos["final_obs"][1][key], w_obs[key], rtol=REWARD_TOL,
                                   atol=REWARD_TOL)
        assert np.all(np.isfinite(obs[key]))
    metrics = infos["final_info"]["episode_metrics"]
    for name, value in w_info["episode_metrics"].items():
        assert metrics[name][1] == pytest.approx(value, rel=REWARD_TOL)


def _compare_with_gym_make(envs: gym.vector.VectorEnv, env_id: str, seed: int, **kw) -> int:
    """Step ``envs`` and one ``gymnasium.make(env_id)`` per copy (seed + i) with the same
    random actions past an episode end; assert equal observations, rewards, ends and final
    metrics; return how many episodes ended."""
    n = envs.num_envs
    singles = [gym.make(env_id, **kw) for _ in range(n)]
    obs, _ = envs.reset(seed=seed)
    for i, single in enumerate(singles):
        w_obs, _ = single.reset(seed=seed + i)
        for key in w_obs:
            np.testing.assert_array_equal(obs[key][i], w_obs[key])
    shape = (55, *envs.action_space.shape)
    actions = np.random.default_rng(3).uniform(-0.2, 0.2, shape).astype(np.float32)
    ended = 0
    for a in actions:
        obs, rew, term, trunc, infos = envs.step(a)
        for i, single in enumerate(singles):
            w_obs, w_rew, w_term, w_trunc, w_info = single.step(a[i])
            assert rew[i] == pytest.approx(w_rew, rel=REWARD_TOL, abs=REWARD_TOL)
            assert (bool(term[i]), bool(trunc[i])) == (w_term, w_trunc)
            if w_term or w_trunc:
                ended += 1
                metrics = infos["final_info"]["episode_metrics"]
                for name, value in w_info["episode_metrics"].items():
                    assert metrics[name][i] == pytest.approx(value, rel=REWARD_TOL)
                for key in w_obs:
                    np.testing.assert_array_equal(infos["final_obs"][i][key], w_obs[key])
                w_obs, _ = single.reset()
            for key in w_obs:
                np.testing.assert_array_equal(obs[key][i], w_obs[key])
    return ended


@pytest.mark.parametrize("env_id", BATCHED_ENVIRONMENTS)
def test_gymnasium_make_vec_builds_the_batched_env_equal_to_the_single_envs(env_id):
    assert set(BATCHED_ENVIRONMENTS) == set(VECTOR_ENVS)  # the registration's list is complete
    for mode in ("vector_entry_point", None):  # None: the registered vector entry point
        envs = gym.make_vec(env_id, num_envs=2, vectorization_mode=mode, nthread=1, **KW)
        assert type(envs) is VECTOR_ENVS[env_id] and envs.spec.id == env_id
        envs.close()
    sync = gym.make_vec(env_id, num_envs=2, vectorization_mode="sync", **KW)
    assert isinstance(sync, gym.vector.SyncVectorEnv)  # the other modes are Gymnasium's
    sync.close()
    envs = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", **KW)
    # both copies crossed an episode end (the agent-ready variants' 0.1-s episodes are 2 policy
    # steps: they cross several)
    assert _compare_with_gym_make(envs, env_id, 20, **KW) >= 2


def test_make_vec_falls_back_to_sync_with_the_same_seeding_and_autoreset():
    # a per-episode model is not batched: a SyncVectorEnv of the single env
    randomized = {**KW, "randomize": True}
    envs = cir_gym.make_vec("cir_gym/JointTracking-v2", 2, **randomized)
    assert isinstance(envs, gym.vector.SyncVectorEnv)
    assert envs.metadata["autoreset_mode"] == gym.vector.AutoresetMode.SAME_STEP
    assert _compare_with_gym_make(envs, "cir_gym/JointTracking-v2", 5, **randomized) == 2
    native = cir_gym.make_vec("cir_gym/JointTracking-v2", 2, **KW)
    assert type(native) is JointTrackingVectorEnv
    # rendered features are not batched: sync
    other = cir_gym.make_vec("cir_gym/VisualServoEyeToHand-v1", 2, features="detected")
    assert isinstance(other, gym.vector.SyncVectorEnv)
    for venv in (envs, native, other):
        venv.close()


def test_make_vec_names_what_it_cannot_batch():
    with pytest.raises(InvalidArgument, match=r"randomize=True.*sync"):
        gym.make_vec(
            "cir_gym/JointTracking-v2",
            2,
            vectorization_mode="vector_entry_point",
            randomize=True,
        )
    with pytest.raises(InvalidArgument, match=r"max_episode_steps=10 would cut this 50-step"):
        make_vec("cir_gym/JointTracking-v2", 2, max_episode_steps=10, **KW)
    longer = make_vec("cir_gym/JointTracking-v2", 2, max_episode_steps=-1, episode_duration=8.0)
    assert longer.template.max_steps == 4000
    longer.close()
