"""AdmittanceContact's batched env against the single env, copy by copy: random actions and the
course's controllers (as cir_gym.scoring.policies resolves them), the stiffness known and drawn
per episode (randomize), both interfaces, autoreset, and the batched evaluator."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pytest
from lockstep import lockstep

import cir_gym
from cir_gym.envs import admittance_scene as scene
from cir_gym.envs.admittance_contact import AdmittanceContactEnv
from cir_gym.envs.admittance_vector import AdmittanceContactVectorEnv
from cir_gym.evaluation import evaluate
from cir_gym.scoring.policies import make_policy
from cir_gym.validation import InvalidArgument

ENV = "cir_gym/AdmittanceContact-v2"
CLASS_PATH = "cir_gym.envs.admittance_vector:AdmittanceContactVectorEnv"
# Each copy runs the single env's MuJoCo computations (mj_step per physics step with the
# copy's own plate stiffness, damping and pose; the position and velocity stages for the
# reached state) and the single env's functions (period_forces, AdmittanceReward,
# episode_metrics, the wrist-sensor model) on (N, ...) arrays. What may differ is round-off:
# numpy reduces an (N, n) array and an (n,) row in different orders (SIMD lanes), the sensor
# filter runs once per period on the batch as on one row, and the tool quaternion is computed
# for N matrices at once. So observations, rewards and metrics agree to 1e-12 (relative, or
# absolute near 0); lengths, ends and success exactly.
TOL = 1e-12
def _lockstep(
    envs: AdmittanceContactVectorEnv,
    kw: dict,
    seed: int,
    steps: int,
    actions_for: Callable[[int, dict, np.ndarray], np.ndarray],
) -> list[dict]:
    """Each copy equal to its single env (tests/lockstep.py, to TOL) under ``actions_for``;
    returns the single env's last infos of the episodes that ended."""
    singles = [AdmittanceContactEnv(**kw) for _ in range(envs.num_envs)]
    return lockstep(envs, singles, actions_for, seed=seed, steps=steps, tol=TOL).ends


@pytest.mark.parametrize("randomize", [False, True])
def test_each_copy_is_the_single_env_with_random_actions(randomize: bool) -> None:
    """Random torques pulling the arm down: copies slam the plate and stop at the force limit
    at different steps, others run to the end; every end is autoreset in the same step."""
    kw = {"episode_duration": 0.2, "randomize": randomize}
    rng = np.random.default_rng(3)
    actions = rng.uniform(-0.6, 0.6, (160, 3, 7))
    actions[:, :, 1] += 0.4  # shoulder forward: down onto the plate
    envs = AdmittanceContactVectorEnv(num_envs=3, nthread=1, **kw)
    ends = _lockstep(envs, kw, 10, len(actions), lambda k, obs, start: actions[k])
    assert len(ends) >= 3
    assert any(e["force_limit_exceeded"] for e in ends)  # a stop, scored over the horizon


def _controller(name: str, kw: dict) -> Callable[[int, dict, np.ndarray], np.ndarray]:
    """A course controller as the leaderboard resolves it, predicting on the batch."""
    policy = make_policy(ENV, name, kw, {})
    state = {"s": None}

    def control(k: int, obs: dict, start: np.ndarray) -> np.ndarray:
        action, state["s"] = policy.predict(obs, state=state["s"], episode_start=start)
        return action

    return control


@pytest.mark.parametrize(
    ("name", "kw"),
    [
        # contact from t ≈ 1 s: 0.4 s pressing
        ("impedance", {"episode_duration": 1.4, "randomize": True}),
        pytest.param("impedance", {"stiffness": 1e5, "force_ref": 20.0}, marks=pytest.mark.slow),
        pytest.param("explicit_force", {"randomize": True}, marks=pytest.mark.slow),
        pytest.param("admittance", {"stiffness": 1e3, "force_ref": 20.0}, marks=pytest.mark.slow),
        pytest.param("admittance", {"randomize": True}, marks=pytest.mark.slow),
    ],
)
def test_each_copy_is_the_single_env_with_a_course_controller(name: str, kw: dict) -> None:
    envs = AdmittanceContactVectorEnv(num_envs=2, nthread=1, **kw)
    ends = _lockstep(envs, kw, 1000, envs.template.max_steps, _controller(name, kw))
    assert len(ends) == 2
    assert all(e["episode_metrics"]["contact_loss"] < 1.0 for e in ends)  # they pressed


def test_the_position_interface_batches_its_torque_law() -> None:
    """control="position": the motion interface's torque law at every physics step on (N, 7)
    arrays, its setpoint in the observation; increments pushing down into the plate."""
    kw = {"control": "position", "episode_duration": 0.2, "stiffness": 1e5}
    rng = np.random.default_rng(4)
    actions = rng.uniform(-1.0, 1.0, (120, 2, 6))
    actions[:, :, 2] = -1.0
    envs = AdmittanceContactVectorEnv(num_envs=2, nthread=1, **kw)
    assert len(_lockstep(envs, kw, 5, len(actions), lambda k, obs, start: actions[k])) >= 2


def test_the_tool_quaternion_is_its_bodys() -> None:
    """The observation's tool_quat is the tcp's body's xquat (w ≥ 0): the tcp site is aligned
    with that body (site_quat the identity), so it is the site's orientation."""
    env = AdmittanceContactEnv(episode_duration=0.1)
    env.reset(seed=0)
    np.testing.assert_array_equal(env.model.site_quat[env._site], [1.0, 0.0, 0.0, 0.0])
    obs, *_ = env.step(np.full(7, 0.2))
    R = env.data.site_xmat[env._site].reshape(3, 3)
    np.testing.assert_allclose(obs["tool_quat"], scene.quat_of(R), atol=1e-15)


def test_make_vec_and_unsupported_arguments(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(cir_gym.envs.BATCHED_ENVIRONMENTS, ENV, CLASS_PATH)
    native = cir_gym.make_vec(ENV, 2, nthread=1, episode_duration=0.1, randomize=True)
    assert type(native) is AdmittanceContactVectorEnv and native.num_envs == 2
    native.close()
    with pytest.raises(InvalidArgument, match="render_mode"):
        AdmittanceContactVectorEnv(num_envs=2, render_mode="rgb_array")
    with pytest.raises(InvalidArgument, match="stiffness"):
        AdmittanceContactVectorEnv(num_envs=2, stiffness=1.0)  # the single env's check
    sync = cir_gym.make_vec(ENV, 2, render_mode="rgb_array", episode_duration=0.1)
    assert isinstance(sync, gym.vector.SyncVectorEnv)
    sync.close()


def test_batched_evaluation_gives_the_sequential_episodes(monkeypatch: pytest.MonkeyPatch) -> None:
    """evaluate's batched path (taken by default for a course controller once the id is in
    BATCHED_ENVIRONMENTS) and the sequential one give the same EpisodeResults: lengths, ends
    and success equal, returns and metrics to TOL; the unknown-stiffness variant."""
    import cir_gym.evaluation as evaluation

    monkeypatch.setitem(cir_gym.envs.BATCHED_ENVIRONMENTS, ENV, CLASS_PATH)
    monkeypatch.setattr(evaluation, "MAX_BATCH", 2)  # 3 episodes: groups of 2 and 1
    kw = {"episode_duration": 1.2, "randomize": True}  # in contact from t ≈ 1 s
    policy = make_policy(ENV, "impedance", kw, {})
    assert evaluation._batched_env_class(ENV, None, False, kw, None) is AdmittanceContactVectorEnv
    fast = evaluate(policy, ENV, n_episodes=3, seed=40, **kw)
    slow = evaluate(policy, ENV, n_episodes=3, seed=40, batched=False, **kw)
    for f, s in zip(fast.episodes, slow.episodes, strict=True):
        assert (f.seed, f.length, f.success, f.diverged, f.terminated) == (
            s.seed, s.length, s.success, s.diverged, s.terminated,
        )
        assert f.episode_return == pytest.approx(s.episode_return, rel=TOL)
        assert f.metrics == pytest.approx(s.metrics, rel=TOL, abs=TOL)
    assert any(e.metrics["contact_loss"] < 1.0 for e in slow.episodes)  # in contact
