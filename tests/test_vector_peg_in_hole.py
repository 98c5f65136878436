"""The batched PegInHole (cir_gym/envs/peg_in_hole_vector.py): each copy is the single env.

Tolerance: 1e-9 (absolute, SI units; relative 1e-9 for rewards and metrics). A copy runs the
same MuJoCo calls on the same state as the single env (one ``Batch.step(nstep=1)`` per
physics step, the contact sensors in C) and the task's arithmetic on (N, ...) arrays; numpy
may reduce an array in another order than a vector, so the last bits are allowed to differ
(they do not on these runs), never more than rounding.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from lockstep import assert_close, lockstep, row

import cir_gym  # noqa: F401
from cir_gym import baselines
from cir_gym.envs.peg_in_hole import PegInHoleEnv
from cir_gym.envs.peg_in_hole_vector import PegInHoleVectorEnv
from cir_gym.validation import InvalidArgument

ENV_ID = "cir_gym/PegInHole-v2"
TOL = 1e-9




def _compare(
    vec: PegInHoleVectorEnv, singles: list[PegInHoleEnv], actions: Any, seed: int, steps: int
) -> dict[str, int]:
    """Each copy equal to its single env (tests/lockstep.py, to TOL) under ``actions(k, the
    copies' observations)`` → (N, m). Returns counts of episode ends, force-limit stops and
    steps in contact."""
    seen = lockstep(vec, singles, lambda k, obs, start: actions(k, [row(obs, i) for i in
                                                                    range(vec.num_envs)]),
                    seed=seed, steps=steps, tol=TOL)
    return {"ends": len(seen.ends),
            "stops": sum(bool(e["force_limit_exceeded"]) for e in seen.ends),
            "contact": sum(info["contact_force"] > 0 for step in seen.infos for info in step)}


@pytest.mark.parametrize("control", ["torque", "position"])
def test_each_copy_is_the_single_env_under_random_actions_with_autoreset(control: str) -> None:
    """Random actions pushing into the block (down the bore's axis in the position interface,
    toward the block in torque) from 2 mm above it, 0.3-s episodes and a 60-N force limit:
    copies end by the force limit (their period stopped at a physics step) and by time, and
    are reset in the same step; each copy is the single env reset with seed + i, then
    reset()."""
    kwargs = {"control": control, "episode_duration": 0.3, "force_limit": 60.0,
              "start_height": 0.002}
    N = 3
    vec = PegInHoleVectorEnv(N, nthread=1, **kwargs)
    singles = [PegInHoleEnv(**kwargs) for _ in range(N)]
    rng = np.random.default_rng(0)
    push = np.zeros(vec.single_action_space.shape)
    push[2 if control == "position" else 1] = -0.6 if control == "position" else 0.3

    def actions(k: int, obs: list) -> np.ndarray:
        return (push + rng.uniform(-0.3, 0.3, vec.action_space.shape)).astype(np.float32)

    counts = _compare(vec, singles, actions, seed=10, steps=300)
    assert counts["ends"] >= N and counts["stops"] >= 1 and counts["contact"] > 0, counts
    vec.close()


def _drive(name: str, kwargs: dict[str, Any], steps: int) -> dict[str, int]:
    """Two copies driven by the controller ``name`` (one policy state per copy, its actions
    from each single env's observation), compared with their single envs."""
    N = 2
    vec = PegInHoleVectorEnv(N, nthread=1, **kwargs)
    singles = [PegInHoleEnv(**kwargs) for _ in range(N)]
    policies = [baselines.make(name, ENV_ID) for _ in range(N)]
    states: list[Any] = [None] * N

    def actions(k: int, obs: list) -> np.ndarray:
        rows = []
        for i, policy in enumerate(policies):
            a, states[i] = policy.predict(obs[i], states[i], np.array([k == 0]))
            rows.append(np.asarray(a, dtype=np.float32).reshape(-1))
        return np.stack(rows)

    counts = _compare(vec, singles, actions, seed=1000, steps=steps)
    vec.close()
    return counts


def test_a_controller_drives_each_copy_as_the_single_env() -> None:
    """hybrid_force_position from 4 mm above the hole: the approach, the touch down on the
    face (about 0.8 s in) and the search in contact, each copy equal to its single env."""
    counts = _drive("hybrid_force_position", {"episode_duration": 1.0, "start_height": 0.004}, 500)
    assert counts["contact"] > 50, counts


@pytest.mark.slow
@pytest.mark.parametrize("name", ["hybrid_spiral", "hybrid_force_position"])
def test_full_controller_episodes_are_the_single_envs(name: str) -> None:
    """Whole default episodes (up to 12 s) of the leaderboard's controllers, through their
    end (insertion, force limit or time) and the autoreset into the next one."""
    steps = PegInHoleEnv().max_steps + 200
    counts = _drive(name, {}, steps)
    assert counts["ends"] >= 2 and counts["contact"] > 500, counts


def test_batched_evaluation_is_the_sequential_one(monkeypatch: pytest.MonkeyPatch) -> None:
    """cir_gym.evaluation.evaluate on the batched env (the policy's batched predict on the
    stacked observations) gives the sequential episodes: lengths, success, return and
    metrics to 1e-9 relative (the controller's rows and the env's copies are each computed
    as alone, up to numpy's summation order)."""
    from cir_gym import envs
    from cir_gym.evaluation import evaluate

    monkeypatch.setitem(
        envs.BATCHED_ENVIRONMENTS, ENV_ID, "cir_gym.envs.peg_in_hole_vector:PegInHoleVectorEnv"
    )
    policy = baselines.make("position_only", ENV_ID)
    kw = {"episode_duration": 0.6, "start_height": 0.002}
    batched = evaluate(policy, ENV_ID, 3, seed=7, batched=True, **kw).episodes
    alone = evaluate(policy, ENV_ID, 3, seed=7, batched=False, **kw).episodes
    for b, s in zip(batched, alone, strict=True):
        same = (b.seed, b.length, b.success, b.diverged)
        assert same == (s.seed, s.length, s.success, s.diverged)
        assert_close(b.episode_return, s.episode_return, TOL, "return")
        for name, value in s.metrics.items():
            assert_close(b.metrics[name], value, TOL, name)
    assert any(e.metrics["peak_force"] > 0 for e in alone)  # the episodes reach the block


def test_unsupported_and_bad_arguments_are_named() -> None:
    with pytest.raises(InvalidArgument, match="render_mode"):
        PegInHoleVectorEnv(2, render_mode="rgb_array")
    with pytest.raises(InvalidArgument, match="clearance"):
        PegInHoleVectorEnv(2, clearance=1.0)
    with pytest.raises(InvalidArgument, match="num_envs"):
        PegInHoleVectorEnv(0)
    vec = PegInHoleVectorEnv(2, nthread=1)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        vec.step(np.full((2, 7), np.nan))
    vec.close()


def test_the_flags_of_each_copy_are_the_single_envs_in_constructed_contacts() -> None:
    """The constructed two-point contacts of tests/test_peg_in_hole.py (jammed 10 mm deep,
    wedged 3 mm deep, one contact lifted) put into the copies of a batch: each copy's flags
    are the single env's."""
    import mujoco
    from test_peg_in_hole import _exact_env, _two_point_pose

    cases = [(0.010, 0.0), (0.003, 0.0), (0.010, 2e-5)]
    vec = PegInHoleVectorEnv(len(cases), nthread=1, position_uncertainty=0.0,
                             tilt_uncertainty=0.0, sensor="ideal")
    vec.reset(seed=0)
    spec = int(mujoco.mjtState.mjSTATE_INTEGRATION)
    want, depth, speed = [], [], []
    for i, (d, shift) in enumerate(cases):
        env = _exact_env()
        _two_point_pose(env, d, shift)
        row = np.zeros(mujoco.mj_stateSize(env.model, spec))
        mujoco.mj_getState(env.model, env.data, row, spec)
        vec.batch.state[i] = row
        depth.append(env._depth())
        speed.append(float(env.true_hole_R[:, 2] @ env._tip_twist()[:3]))
        flags = env._contact_flags(depth[-1], speed[-1])
        want.append((flags.two_point, flags.wedged, flags.jammed))
    vec.batch.forward()
    got = vec._contact_flags(np.array(depth), np.array(speed))
    assert list(zip(got.two_point, got.wedged, got.jammed, strict=True)) == want
    assert want == [(True, False, True), (True, True, False), (False, False, False)]
    vec.close()
