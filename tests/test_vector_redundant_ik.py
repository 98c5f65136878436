"""RedundantIK's batched envs (planar 3R and iiwa14) against their single env, copy by copy:
random actions into the joint limits, course controllers over whole episodes of every
leaderboard variant, autoreset after a termination, and the batched evaluator."""

from __future__ import annotations

import numpy as np
import pytest
from lockstep import lockstep

from cir_gym import baselines
from cir_gym.envs import BATCHED_ENVIRONMENTS
from cir_gym.envs.redundant_ik import RedundantIK7Env, RedundantIKEnv
from cir_gym.envs.redundant_ik_vector import RedundantIK7VectorEnv, RedundantIKVectorEnv
from cir_gym.evaluation import evaluate
from cir_gym.validation import InvalidArgument

ARMS = {
    "cir_gym/RedundantIK-v4": (RedundantIKVectorEnv, RedundantIKEnv),
    "cir_gym/RedundantIK7-v5": (RedundantIK7VectorEnv, RedundantIK7Env),
}
JOINTS = {"cir_gym/RedundantIK-v4": 3, "cir_gym/RedundantIK7-v5": 7}
# Rewards, infos and metrics to 1e-12: the batch's kinematics are MuJoCo's own (the position
# stage of mj_forward as mj_kinematics, mj_jac at the site as mj_jacSite), the rest the single
# env's arithmetic on (N, ...) rows, whose norms and sums numpy may order differently (the
# last bits). Observations as well (x, q are bit-equal; the iiwa's measured quaternion comes
# from trajectories.quat_from_matrix's batched path, the single env's from its one-matrix path).
TOL = 1e-12


def _lockstep(env_id: str, kw: dict, n: int, seed: int, steps: int, actions) -> list[dict]:
    """Each of n copies equal to its single env over ``steps`` steps; the ended episodes'
    last infos (the single envs')."""
    vec_cls, single_cls = ARMS[env_id]
    envs = vec_cls(num_envs=n, nthread=1, **kw)
    singles = [single_cls(**kw) for _ in range(n)]
    return lockstep(envs, singles, actions, seed=seed, steps=steps, tol=TOL).ends


@pytest.mark.parametrize("env_id", list(ARMS))
@pytest.mark.parametrize("objective", ["manipulability", "joint_limits"])
def test_each_copy_is_the_single_env_with_random_actions(env_id, objective):
    """Random actions beyond [-1, 1] with a drift per copy, 0.5-s laps: truncations,
    joint-limit terminations (the stopped arm's scoring) and autoresets in every copy."""
    kw = {"objective": objective, "episode_duration": 0.5}
    n, m = 3, JOINTS[env_id]
    rng = np.random.default_rng(3)
    drift = rng.choice((-0.9, 0.0, 0.9), (n, m))
    actions = (drift + rng.uniform(-0.6, 0.6, (120, n, m))).astype(np.float32) * 1.3
    ends = _lockstep(env_id, kw, n, 20, len(actions), lambda k, obs, start: actions[k])
    assert len(ends) >= n
    assert any(e["joint_limit_violation"] for e in ends)


def _controller_actions(name: str, env_id: str, kw: dict):
    policy = baselines.make(name, env_id, env_kwargs=kw)
    state = {"s": None}

    def control(k: int, obs: dict, start: np.ndarray) -> np.ndarray:
        action, state["s"] = policy.predict(obs, state=state["s"], episode_start=start)
        return action

    return control


SLOW = pytest.mark.slow  # whole default laps with obstacle draws (~0.4 s each): 10-20 s each


@pytest.mark.parametrize(
    ("env_id", "controller", "objective", "duration"),
    [
        ("cir_gym/RedundantIK-v4", "clik_nullspace", "manipulability", 1.0),
        ("cir_gym/RedundantIK7-v5", "clik_nullspace", "manipulability", 1.0),
        ("cir_gym/RedundantIK-v4", "clik_nullspace", "joint_limits", 1.0),
        ("cir_gym/RedundantIK7-v5", "clik_nullspace", "joint_limits", 1.0),
        # plain CLIK collides in every "obstacle" episode, by construction
        ("cir_gym/RedundantIK-v4", "clik", "obstacle", None),
        ("cir_gym/RedundantIK7-v5", "clik_nullspace", "obstacle", None),
        pytest.param("cir_gym/RedundantIK-v4", "clik_nullspace", "obstacle", None, marks=SLOW),
        pytest.param("cir_gym/RedundantIK7-v5", "clik", "obstacle", None, marks=SLOW),
        pytest.param("cir_gym/RedundantIK-v4", "clik_nullspace", "manipulability", None,
                     marks=SLOW),
    ],
)
def test_each_copy_is_the_single_env_over_whole_episodes_with_a_course_controller(
    env_id, controller, objective, duration
):
    """Every leaderboard variant, whole episodes (two copies, one for a default lap): the
    batched episodes are the single env's to the end, metrics and success included (plain
    CLIK's collisions: the termination, the stopped arm's scores and the autoreset's new
    obstacle)."""
    kw = {"objective": objective} | ({"episode_duration": duration} if duration else {})
    steps = ARMS[env_id][1](**kw).max_steps
    n = 2 if duration else 1  # one copy of a whole default lap (its draws cost the most)
    ends = _lockstep(env_id, kw, n, 1000, steps, _controller_actions(controller, env_id, kw))
    assert len(ends) >= n
    if controller == "clik":
        assert all(e["collision"] for e in ends[:n])


def test_only_render_mode_is_unsupported():
    for env_id, (vec_cls, _) in ARMS.items():
        with pytest.raises(InvalidArgument, match="render_mode"):
            vec_cls(num_envs=2, render_mode="rgb_array")
        with pytest.raises(InvalidArgument, match="objective"):
            vec_cls(num_envs=2, objective="speed")
        envs = vec_cls(num_envs=2, objective="joint_limits", initial_error=0.01,
                       secondary_weight=0.3, charge_unplayed_steps=False)
        assert envs.env_id == env_id and envs.template.initial_error == 0.01
        envs.close()


@pytest.mark.parametrize("env_id", list(ARMS))
def test_batched_evaluation_gives_the_sequential_episodes(env_id):
    """evaluate(batched=True) and the one-by-one evaluation: the same EpisodeResults (the
    kinematic laws are row-vectorised, so a row's action is the same alone or in a batch)."""
    vec_cls = ARMS[env_id][0]  # the registered batched env is the one tested above
    assert BATCHED_ENVIRONMENTS[env_id] == f"{vec_cls.__module__}:{vec_cls.__name__}"
    kw = {"objective": "joint_limits", "episode_duration": 0.5}
    for name in baselines.available(env_id):
        policy = baselines.make(name, env_id, env_kwargs=kw)
        fast = evaluate(policy, env_id, n_episodes=2, seed=40, batched=True, **kw)
        slow = evaluate(policy, env_id, n_episodes=2, seed=40, batched=False, **kw)
        for f, s in zip(fast.episodes, slow.episodes, strict=True):
            assert (f.seed, f.length, f.success, f.terminated) == (
                s.seed, s.length, s.success, s.terminated), name
            assert f.episode_return == pytest.approx(s.episode_return, rel=TOL), name
            assert f.metrics == pytest.approx(s.metrics, rel=TOL, abs=TOL), name
