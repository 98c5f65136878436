"""The normalized score (cir_gym.scoring.normalized) on hand-made EvaluationResults, and the
hold-still policy of each interface."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import cir_gym  # noqa: F401  (registers the ids)
from cir_gym.evaluation import EpisodeResult, EvaluationResult
from cir_gym.metrics import MetricSpec
from cir_gym.scoring.normalized import (
    HOLD_STILL,
    LOG_FLOOR,
    best_controller,
    episode_scores,
    hold_still_policy,
    normalized_score,
    normalized_scores,
    uses_log_scale,
    variant_anchors,
)

LOWER = (MetricSpec("rms_error", "rad", "lower", "tracking error"),)
HIGHER = (MetricSpec("final_depth", "m", "higher", "depth"),)


def _result(name: str, values: list[float], specs=LOWER, env_id: str = "cir_gym/X-v0",
            successes: list[bool] | None = None):
    metric = specs[0].name
    successes = successes or [False] * len(values)
    episodes = [
        EpisodeResult(seed=i, episode_return=0.0, length=1, success=ok, diverged=False,
                      metrics={metric: v})
        for i, (v, ok) in enumerate(zip(values, successes, strict=True))
    ]
    return EvaluationResult(env_id, name, episodes, specs, metric)


def test_linear_anchors_and_direction() -> None:
    assert normalized_score(10.0, hold=10.0, best=6.0) == 0.0
    assert normalized_score(6.0, hold=10.0, best=6.0) == 1.0
    assert normalized_score(8.0, hold=10.0, best=6.0) == 0.5
    assert normalized_score(12.0, hold=10.0, best=6.0) == -0.5  # worse than holding still
    assert normalized_score(4.0, hold=10.0, best=6.0) == 1.5  # better than the best
    # higher is better: the same formula
    assert normalized_score(0.02, hold=0.0, best=0.0225) == pytest.approx(0.02 / 0.0225)


def test_log_scale_where_the_metric_spans_decades() -> None:
    assert uses_log_scale(0.1, 1e-4) and uses_log_scale(1e-4, 0.1)
    assert not uses_log_scale(12.0, 3.0)
    assert not uses_log_scale(0.0, 1e-3)  # an anchor at 0: linear
    # 1e-1 → 1e-4 rad: each decade counts a third
    assert normalized_score(1e-2, hold=1e-1, best=1e-4) == pytest.approx(1 / 3)
    assert normalized_score(1e-3, hold=1e-1, best=1e-4) == pytest.approx(2 / 3)
    # linear would give one decade of three 0.90
    linear = normalized_score(1e-2, hold=1e-1, best=1e-4, log=False)
    assert linear == pytest.approx(0.9009, abs=1e-4)
    # a perfect episode is floored at m_best × LOG_FLOOR: finite, 1 + 3/3 decades = 2
    assert normalized_score(0.0, hold=1e-1, best=1e-4) == pytest.approx(
        math.log(1e-1 / (1e-4 * LOG_FLOOR)) / math.log(1e3))
    assert normalized_score(0.0, hold=1e-1, best=1e-4) == pytest.approx(2.0)


def test_bad_anchors_raise_and_nan_stays_nan() -> None:
    with pytest.raises(ValueError, match="differ"):
        normalized_score(1.0, hold=2.0, best=2.0)
    with pytest.raises(ValueError, match="finite"):
        normalized_score(1.0, hold=float("nan"), best=2.0)
    with pytest.raises(ValueError, match="log scale"):
        normalized_score(1.0, hold=0.0, best=2.0, log=True)
    assert math.isnan(normalized_score(float("nan"), hold=2.0, best=1.0))


def test_scores_of_a_variant_with_the_best_controller_as_anchor() -> None:
    hold = _result("hold_still", [20.0, 20.0, 20.0])
    rows = [
        _result("tuned:admittance", [3.0, 4.0, 5.0]),
        _result("impedance", [6.0, 6.0, 6.0]),
        _result("agent:ppo", [2.0, 2.0, 2.0]),  # an agent never anchors, even if better
    ]
    assert best_controller(rows).policy_name == "tuned:admittance"
    scores = normalized_scores(rows, hold)
    assert scores["tuned:admittance"].score == 1.0
    assert scores["impedance"].score == pytest.approx(14 / 16)
    assert scores["agent:ppo"].score == pytest.approx(18 / 16)
    s = scores["agent:ppo"]
    assert (s.hold, s.best, s.best_policy, s.log_scale) == (20.0, 4.0, "tuned:admittance", False)
    per_episode = episode_scores(rows[0], hold, rows[0])
    assert per_episode == pytest.approx([17 / 16, 1.0, 15 / 16])


def test_the_anchor_is_the_tables_best_controller_success_first() -> None:
    # PegInHole's chamfer: a faster mean insertion time bought with failed episodes (scored at
    # the time limit) must not anchor 1 over the controller that always inserts
    hold = _result("hold_still", [12.0, 12.0, 12.0])
    always = _result("impedance_insertion", [7.0, 7.0, 7.0], successes=[True] * 3)
    mostly = _result("tuned:hybrid", [2.0, 2.0, 12.0], successes=[True, True, False])
    assert best_controller([mostly, always]).policy_name == "impedance_insertion"
    scores = normalized_scores([mostly, always], hold)
    assert scores["impedance_insertion"].score == 1.0
    assert scores["tuned:hybrid"].score == pytest.approx((12 - 16 / 3) / 5)
    # at equal success the better mean anchors
    twin = _result("position_spiral", [6.0, 6.0, 6.0], successes=[True] * 3)
    assert best_controller([always, twin]).policy_name == "position_spiral"


def test_scores_on_a_higher_is_better_metric_and_on_a_log_scale() -> None:
    hold = _result("hold_still", [1e-5], HIGHER)
    rows = [_result("a", [1e-2], HIGHER), _result("b", [1e-3], HIGHER)]
    assert best_controller(rows).policy_name == "a"
    scores = normalized_scores(rows, hold)
    assert scores["a"].log_scale and scores["a"].score == 1.0
    assert scores["b"].score == pytest.approx(2 / 3)


def test_no_scale_where_holding_still_beats_the_first_ranked_controller() -> None:
    # RedundantIK's obstacle variants: holding still keeps 0.087 m of clearance, the
    # first-ranked controller 0.039 m; on that scale a failing row with less clearance than the
    # anchor would score above 1, so the variant gets no score
    hold = _result("hold_still", [0.087], HIGHER)
    rows = [_result("clik_nullspace", [0.039], HIGHER, successes=[True]),
            _result("pseudo_inverse", [0.0], HIGHER)]
    with pytest.raises(ValueError, match=r"holding still .* better .*clik_nullspace"):
        variant_anchors(rows, hold)
    lower = _result("hold_still", [1.0])
    with pytest.raises(ValueError, match="holding still"):
        variant_anchors([_result("a", [2.0])], lower)
    assert variant_anchors([_result("a", [0.5])], lower).best == 0.5


def test_results_of_another_env_or_metric_are_refused() -> None:
    hold = _result("hold_still", [20.0])
    with pytest.raises(ValueError, match="is on"):
        normalized_scores([_result("a", [1.0], env_id="cir_gym/Y-v0")], hold,
                          best=_result("b", [2.0]))
    with pytest.raises(ValueError, match="no metric"):
        normalized_scores([_result("a", [1.0])], hold, metric="peak_force")
    with pytest.raises(ValueError, match="no controller"):
        best_controller([_result("agent:ppo", [1.0])])


@pytest.mark.parametrize(
    ("env_id", "kwargs", "kind"),
    [("cir_gym/PegInHoleImpedance-v0", {}, "impedance_setpoint_increment"),
     ("cir_gym/PegInHole-v2", {"control": "position"}, "cartesian_increment"),
     ("cir_gym/PegInHole-v2", {}, "joint_torque")],
)
def test_hold_still_keeps_the_arm_where_it_starts(env_id: str, kwargs: dict, kind: str) -> None:
    """Each interface's hold-still policy: 100 steps of the arm within 0.1 mm of its start,
    no contact; zeros where the action is an increment, PD + gravity on torques."""
    env = gym.make(env_id, **kwargs)
    policy = hold_still_policy(env)
    assert policy.kind == kind and kind in HOLD_STILL
    obs, _ = env.reset(seed=11)
    q0 = obs["q"].copy()
    state, start = None, np.ones(1, bool)
    for _ in range(100):
        action, state = policy.predict(obs, state, start)
        start = np.zeros(1, bool)
        if kind != "joint_torque":
            assert not np.any(action)
        obs, _, terminated, _, info = env.step(action)
        assert not terminated and info["contact_force"] == 0.0
    assert np.max(np.abs(obs["q"] - q0)) < 1e-3
    assert np.linalg.norm(obs["peg_twist"][:3]) < 1e-3


def test_hold_still_batches_row_by_row() -> None:
    env = gym.make("cir_gym/PegInHole-v2")
    policy = hold_still_policy(env)
    obs, _ = env.reset(seed=0)
    one, q0 = policy.predict(obs, None, np.ones(1, bool))
    stacked = {k: np.stack([v, v]) for k, v in obs.items()}
    two, state = policy.predict(stacked, None, np.ones(2, bool))
    assert two.shape == (2, 7) and np.array_equal(two[0], one) and np.array_equal(two[1], one)
    assert state.shape == (2, 7) and np.array_equal(state[0], q0)


@pytest.mark.parametrize(
    ("env_id", "kind"),
    [("cir_gym/ElasticJointTracking-v3", "motor_torque"),
     ("cir_gym/CartesianTracking-v1", "joint_torque"),
     ("cir_gym/VisualServo-v1", "twist")],
)
def test_hold_still_on_the_other_interfaces(env_id: str, kind: str) -> None:
    """The motor-torque hold (PD on the motor positions + ĝ of the links) and the others keep
    every joint within 1e-5 rad of its start for 300 steps."""
    env = gym.make(env_id)
    policy = hold_still_policy(env)
    assert policy.kind == kind
    obs, _ = env.reset(seed=0)
    q0, state, start = obs["q"].copy(), None, np.ones(1, bool)
    for _ in range(300):
        action, state = policy.predict(obs, state, start)
        start = np.zeros(1, bool)
        obs, _, terminated, truncated, _ = env.step(action)
        assert not terminated
        if truncated:
            break
    assert np.max(np.abs(obs["q"] - q0)) < 1e-5
