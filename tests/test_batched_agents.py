"""The leaderboard's shipped agents evaluated batched equal their sequential episodes.

The leaderboard runs a shipped agent's episodes at once on the ids of
``cir_gym.scoring.leaderboard.AGENT_BATCH_IDS`` (its ranked table and its seed table). A torch
network rounds a batch of rows differently from one row (~1e-7 in the float32 actions), and the
closed loop carries that into the metrics: measured on 4 full episodes of every shipped agent of
JointTracking-v2, ElasticJointTracking-v3 and CartesianTracking-v1, ≤ 3e-6 relative in the return
and primary metric for the agents tested here (ppo_100hz on JointTracking: 3.0e-6 in the return,
1.4e-6 in rms_error; ppo_100hz on CartesianTracking, seeds 1000-1003: 2.0e-6 in the return,
1.9e-6 in position_rms, and at most 4.2e-5 in any metric: joint_drift 4.1e-7 rad of 9.8e-3),
up to 4e-3 in an episode's primary metric and return of a tuned residual agent (not tested here:
its rounding is amplified by its closed loop, a property of that agent, not of the batching).
``RTOL`` = 1e-4 is 30 times the largest difference measured in a return or primary metric, 2.4
times the largest in any metric, and 10 times below the 3 significant digits the tables print;
an episode's length, success and divergence must be equal. """

from __future__ import annotations

import pytest

pytest.importorskip("torch")

from cir_gym.agents.report import seed_report

import cir_gym.evaluation as evaluation
from cir_gym.evaluation import EvaluationResult, batchable, evaluate
from cir_gym.scoring.leaderboard import AGENT_BATCH_IDS, run_job
from cir_gym.scoring.policies import make_policy

#: relative tolerance of a batched agent's metrics and return (module docstring: the reason)
RTOL = 1e-4
EPISODES = 4
SEED = 1000


def assert_equivalent(batched: EvaluationResult, sequential: EvaluationResult) -> None:
    """Every episode: the same seed, length, success and divergence; return and every metric
    to ``RTOL``."""
    assert len(batched.episodes) == len(sequential.episodes)
    for b, s in zip(batched.episodes, sequential.episodes, strict=True):
        assert (b.seed, b.length, b.success, b.diverged, b.terminated) == (
            s.seed, s.length, s.success, s.diverged, s.terminated)
        assert b.episode_return == pytest.approx(s.episode_return, rel=RTOL)
        assert b.metrics.keys() == s.metrics.keys()
        for name, value in s.metrics.items():
            assert b.metrics[name] == pytest.approx(value, rel=RTOL, abs=1e-12), name


class CountBatches:
    """Counts the calls of evaluation's batched path (the one ``evaluate`` takes to batch)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.calls = 0
        inner = evaluation._evaluate_batched

        def counted(*args, **kwargs):
            self.calls += 1
            return inner(*args, **kwargs)

        monkeypatch.setattr(evaluation, "_evaluate_batched", counted)


@pytest.mark.parametrize(
    ("env_id", "agent"),
    [
        ("cir_gym/JointTracking-v2", "agent:ppo_100hz@JointTracking-v1"),
        ("cir_gym/CartesianTracking-v1", "agent:ppo_100hz@CartesianTracking-v0"),
    ],
)
def test_leaderboard_job_batches_agent_to_tolerance(env_id, agent, monkeypatch):
    assert env_id in AGENT_BATCH_IDS
    batches = CountBatches(monkeypatch)
    # the leaderboard's own job, the agent resolved by its "@" name as the leaderboard does
    _, batched, _ = run_job((env_id, "exact model", {}, agent), EPISODES, SEED)
    assert batches.calls == 1  # all the episodes in one batch
    policy = make_policy(env_id, agent, {}, {})
    sequential = evaluate(policy, env_id, EPISODES, SEED, batched=False)
    assert batches.calls == 1
    assert_equivalent(batched, sequential)


def test_seed_report_batched_to_tolerance(monkeypatch):
    env_id, name = "cir_gym/ElasticJointTracking-v3", "ppo_100hz@ElasticJointTracking-v2"
    short = {"episode_duration": 0.5}
    batches = CountBatches(monkeypatch)
    at_once = seed_report(env_id, name, short, episodes=2, seed=SEED, batched=True)
    assert batches.calls == len(at_once.seeds) >= 2  # one batch per training seed
    one_by_one = seed_report(env_id, name, short, episodes=2, seed=SEED)
    assert batches.calls == len(at_once.seeds)
    assert (at_once.success == one_by_one.success).all()
    assert at_once.scores == pytest.approx(one_by_one.scores, rel=RTOL)


def test_agent_without_a_batched_env_runs_sequentially(monkeypatch):
    """A randomized model has no native batched env (each copy would need its own MjModel): the
    leaderboard's agent job runs it one episode after the other, and evaluate(batched=True)
    would refuse it."""
    env_id, agent = "cir_gym/JointTracking-v2", "agent:ppo_100hz@JointTracking-v1"
    policy = make_policy(env_id, agent, {}, {})
    assert batchable(policy, env_id)
    assert not batchable(policy, env_id, randomize=True)
    with pytest.raises(ValueError, match="randomize"):
        evaluate(policy, env_id, 1, SEED, batched=True, randomize=True, episode_duration=0.1)
    batches = CountBatches(monkeypatch)
    run_job((env_id, "randomized model", {"randomize": True, "episode_duration": 0.1}, agent), 1,
            SEED)
    assert batches.calls == 0
