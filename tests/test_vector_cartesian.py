"""CartesianTracking's batched env against the single env, copy by copy (random actions and a
course controller over full episodes), its autoreset, make_vec and the batched evaluator (its
divergence and gymnasium.make_vec equivalence are tested with the others in test_vector.py)."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pytest
from lockstep import assert_obs, lockstep, row

import cir_gym
from cir_gym import baselines
from cir_gym.envs.cartesian_tracking import CartesianTrackingEnv
from cir_gym.envs.cartesian_vector import CartesianTrackingVectorEnv
from cir_gym.envs.vector import VECTOR_ENVS
from cir_gym.evaluation import evaluate
from cir_gym.validation import InvalidArgument

ENV = "cir_gym/CartesianTracking-v1"
KW = {"episode_duration": 0.1}  # 50 steps
# Observations are compared exactly: the batch runs MuJoCo's own computations of the single
# env (mj_step; the position stage of mj_forward for the flange pose, as mj_kinematics; mj_jac
# at the flange site, as mj_jacSite) and the single env's functions (cartesian_tracking's
# flange_pose_errors, observe) on (N, ...) arrays whose rows are laid out as the single env's.
# Rewards and metrics to 1e-12 relative: the reward and the metrics reduce over (N, 7) arrays
# and (7,) rows, whose sums numpy may order differently (SIMD lanes): the last bits.
TOL = 1e-12


def _assert_obs(got: dict, want: dict, what: str) -> None:
    """One copy's observation ``got`` (key → row) equal to the single env's ``want``."""
    assert_obs(got, want, 0.0, what)


def _lockstep(
    envs: CartesianTrackingVectorEnv,
    kw: dict,
    seed: int,
    steps: int,
    actions_for: Callable[[int, dict, np.ndarray], np.ndarray],
) -> int:
    """Each copy equal to its single env to TOL (tests/lockstep.py) under ``actions_for``;
    returns how many episodes ended."""
    singles = [CartesianTrackingEnv(**kw) for _ in range(envs.num_envs)]
    return len(lockstep(envs, singles, actions_for, seed=seed, steps=steps, tol=TOL).ends)


@pytest.mark.parametrize(
    "kw",
    [
        KW,
        # an unknown payload and the near-singular path; the clipped random torques trip the
        # following-error monitor at different steps
        {**KW, "payload_mass": 3.0, "path": "near_singular", "max_following_error": 0.02},
    ],
)
def test_each_copy_is_the_single_env_with_random_actions(kw):
    actions = np.random.default_rng(1).uniform(-1.3, 1.3, (70, 3, 7)).astype(np.float32)
    envs = CartesianTrackingVectorEnv(num_envs=3, nthread=1, **kw)
    ended = _lockstep(envs, kw, 10, len(actions), lambda k, obs, start: actions[k])
    assert ended >= 3  # every copy crossed at least one episode end


@pytest.mark.parametrize(
    ("controller", "kw"),
    [
        ("os_inverse_dynamics", {"episode_duration": 1.0}),
        pytest.param("os_inverse_dynamics", {}, marks=pytest.mark.slow),  # 4 s: 2000 steps
        pytest.param("os_khatib", {"path": "near_singular"}, marks=pytest.mark.slow),
    ],
)
def test_each_copy_is_the_single_env_over_full_episodes_with_a_course_controller(controller, kw):
    """A course controller on whole episodes, two copies: the batched episodes are the
    single env's to the end, metrics and success included."""
    policy = baselines.make(controller, ENV, env_kwargs=kw)
    state = {"s": None}

    def control(k: int, obs: dict, start: np.ndarray) -> np.ndarray:
        action, state["s"] = policy.predict(obs, state=state["s"], episode_start=start)
        return action

    envs = CartesianTrackingVectorEnv(num_envs=2, nthread=1, **kw)
    steps = envs.template.max_steps
    assert _lockstep(envs, kw, 1000, steps, control) == 2


def test_autoreset_is_same_step_with_final_obs_and_masks():
    """Copy 1 alone is stopped (a large torque on joint 2): its final observation and info
    are under the masks, its row of obs is already the next episode's start, the reset
    info (model_error) is added for it only, and the other copies go on."""
    envs = CartesianTrackingVectorEnv(num_envs=3, nthread=1, **KW)
    assert envs.metadata["autoreset_mode"] == gym.vector.AutoresetMode.SAME_STEP
    obs, infos = envs.reset(seed=[4, 9, 5])
    single = CartesianTrackingEnv(**KW)
    _assert_obs(row(obs, 1), single.reset(seed=9)[0], "reset with a list of seeds")
    assert infos["_model_error"].all()
    a = np.zeros((3, 7), dtype=np.float32)
    a[1, 1] = 1.0
    played, term = 0, np.zeros(3, dtype=bool)
    while not term.any():
        obs, _, term, trunc, infos = envs.step(a)
        w_obs, _, w_term, _, w_info = single.step(a[1])
        played += 1
    assert w_term and w_info["following_error_exceeded"] and played < 50
    assert list(term) == [False, True, False] and not trunc.any()
    assert list(infos["_final_obs"]) == list(infos["_final_info"]) == [False, True, False]
    assert infos["final_obs"][0] is None and infos["final_obs"][2] is None
    _assert_obs(infos["final_obs"][1], w_obs, "final")
    assert infos["final_info"]["following_error_exceeded"][1]
    assert not infos["final_info"]["is_success"][1]
    assert list(infos["_model_error"]) == [False, True, False]
    _assert_obs(row(obs, 1), single.reset()[0], "the next episode")  # the same generator
    assert envs._k.tolist() == [played, 0, played]


def test_make_vec_builds_it_and_falls_back_on_what_it_cannot_batch():
    assert VECTOR_ENVS[ENV] is CartesianTrackingVectorEnv
    native = cir_gym.make_vec(ENV, 2, nthread=1, **KW)
    assert type(native) is CartesianTrackingVectorEnv
    entry = gym.make_vec(ENV, num_envs=2, nthread=1, **KW)  # the registered vector entry point
    assert type(entry) is CartesianTrackingVectorEnv and entry.spec.id == ENV
    for kwargs in ({"randomize": True}, {"torque_noise": 0.5}, {"encoder_resolution": 1e-4}):
        name = next(iter(kwargs))
        with pytest.raises(InvalidArgument, match=name):
            CartesianTrackingVectorEnv(num_envs=2, **KW, **kwargs)
        sync = cir_gym.make_vec(ENV, 2, **KW, **kwargs)
        assert isinstance(sync, gym.vector.SyncVectorEnv), name
        sync.close()
    with pytest.raises(InvalidArgument, match="path"):
        CartesianTrackingVectorEnv(num_envs=2, path="spiral")
    for venv in (native, entry):
        venv.close()


def test_batched_evaluation_gives_the_sequential_episodes(monkeypatch):
    """Every CartesianTracking controller, 4 short episodes: evaluate's batched path (taken by
    default for a controller) and the sequential one give the same EpisodeResults: lengths,
    ends and success equal, returns and metrics to TOL (see above)."""
    import cir_gym.evaluation as evaluation

    monkeypatch.setattr(evaluation, "MAX_BATCH", 3)  # 4 episodes: groups of 3 and 1
    kw = {"episode_duration": 0.3}
    for name in baselines.available(ENV):
        policy = baselines.make(name, ENV, env_kwargs=kw)
        assert evaluation._batched_env_class(ENV, None, False, kw, None) is not None
        fast = evaluate(policy, ENV, n_episodes=4, seed=40, **kw)
        slow = evaluate(policy, ENV, n_episodes=4, seed=40, batched=False, **kw)
        for f, s in zip(fast.episodes, slow.episodes, strict=True):
            assert (f.seed, f.length, f.success, f.diverged, f.terminated) == (
                s.seed,
                s.length,
                s.success,
                s.diverged,
                s.terminated,
            ), name
            assert f.episode_return == pytest.approx(s.episode_return, rel=TOL), name
            assert f.metrics == pytest.approx(s.metrics, rel=TOL, abs=TOL), name
        assert (fast.dt, fast.specs, fast.primary_metric) == (
            slow.dt,
            slow.specs,
            slow.primary_metric,
        )
