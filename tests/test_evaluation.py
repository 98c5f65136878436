"""The scorer, the policy protocol seen from SB3, the leaderboard and the command line."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from cir_gym import baselines
from cir_gym.cli import main
from cir_gym.evaluation import EpisodeResult, EvaluationResult, evaluate, rank
from cir_gym.metrics import MetricSpec, aggregate, cvar, mean_interval, wilson_interval
from cir_gym.scoring.leaderboard import run_leaderboard

ENV = "cir_gym/JointTracking-v2"
SHORT = {"episode_duration": 0.2}


def test_evaluate_and_sb3_evaluate_policy_give_the_same_returns():
    """Three episodes on seeds 7, 8, 9 on both sides.

    SB3 passes a seed only at the first reset, so one environment would run its later episodes
    unseeded; instead each episode gets its own environment: ``venv.seed(7)`` seeds env i with
    7 + i, the seed ``evaluate`` gives episode i, and ``evaluate_policy`` runs one episode per
    environment (``n_eval_episodes == n_envs``) through the controller's batched ``predict``.
    The episodes all end on the time limit, at the same step, so SB3 lists them in env order.
    """
    n = 3
    policy = baselines.make("computed_torque", ENV)
    ours = evaluate(policy, ENV, n_episodes=n, seed=7, **SHORT)
    assert [e.seed for e in ours.episodes] == [7, 8, 9]
    venv = DummyVecEnv([lambda: Monitor(gym.make(ENV, **SHORT)) for _ in range(n)])
    assert venv.seed(7) == [7, 8, 9]
    returns, lengths = evaluate_policy(policy, venv, n_eval_episodes=n, return_episode_rewards=True)
    assert lengths == [e.length for e in ours.episodes]
    # Monitor reports the return rounded to 6 decimals
    assert returns == pytest.approx([e.episode_return for e in ours.episodes], abs=1e-6)
    assert len(set(returns)) == n  # the seeds differ, so do the episodes


@pytest.mark.parametrize(
    "name, env_id, gain",
    [("computed_torque", ENV, "omega_n"), ("clik", "cir_gym/RedundantIK-v4", "K")],
)
@pytest.mark.parametrize("value", [0, "abc", [1, 2], True, float("nan")])
def test_a_gain_of_the_wrong_type_or_range_raises_invalid_gain_naming_it(name, env_id, gain, value):
    with pytest.raises(baselines.InvalidGain) as info:
        baselines.make(name, env_id, **{gain: value})
    message = str(info.value)
    assert isinstance(info.value, ValueError)
    assert gain in message and repr(value) in message
    if value != 0:  # 0 has the right type: its Gains rejects the range
        assert "finite real number (int or float)" in message


@pytest.mark.parametrize("value", [30, 30.0, np.float32(30.0)])
def test_an_int_or_numpy_gain_is_stored_as_a_float(value):
    gains = baselines.make("computed_torque", ENV, omega_n=value).gains
    assert type(gains.omega_n) is float and gains.omega_n == 30.0


def test_optional_and_string_gains_keep_their_types():
    assert baselines.make("p_pi_cascade", ENV, omega_cv=None).gains.omega_cv is None
    assert baselines.make("adaptive", ENV, adapt="last_link").gains.adapt == "last_link"
    with pytest.raises(baselines.InvalidGain, match=r"'adapt'.*must be a str.*got 1"):
        baselines.make("adaptive", ENV, adapt=1)


def test_stateful_controller_state_is_reset_at_episode_start():
    policy = baselines.make("pid", ENV)
    env = gym.make(ENV)
    obs, _ = env.reset(seed=0)
    _, state = policy.predict(obs, None, np.array([True]))
    state[:] = 123.0  # a stale integrator
    a_fresh, _ = policy.predict(obs, None, np.array([True]))
    a_reset, new_state = policy.predict(obs, state, np.array([True]))
    np.testing.assert_array_equal(a_fresh, a_reset)
    assert not np.any(new_state == 123.0)


def test_same_seed_same_metrics_and_seeds_are_shared_across_policies():
    a = evaluate(baselines.make("pid", ENV), ENV, 2, 3, **SHORT)
    b = evaluate(baselines.make("pid", ENV), ENV, 2, 3, **SHORT)
    assert [e.metrics for e in a.episodes] == [e.metrics for e in b.episodes]
    assert [e.seed for e in a.episodes] == [3, 4]


def test_aggregates_cvar_and_worst():
    spec = MetricSpec("err", "rad", "lower", "")
    values = np.arange(1.0, 11.0)
    agg = aggregate(spec, values)
    assert agg["worst"] == 10.0 and agg["mean"] == 5.5
    assert agg["cvar"] == pytest.approx(9.5)  # mean of the worst 20 %: 10 and 9
    assert cvar(values, "higher") == pytest.approx(1.5)


def test_the_summary_keeps_std_and_adds_the_interval_of_the_mean():
    """ci_low ≤ mean ≤ ci_high next to the std; none from one episode or none at all."""
    spec = MetricSpec("err", "rad", "lower", "")
    agg = aggregate(spec, np.array([1.0, 2.0, np.nan, 4.0, 8.0]))  # the NaN episode ignored
    assert agg["std"] == pytest.approx(np.std([1.0, 2.0, 4.0, 8.0]))
    assert agg["ci_low"] < agg["mean"] == 3.75 < agg["ci_high"]
    assert 1.0 <= agg["ci_low"] and agg["ci_high"] <= 8.0
    one = aggregate(spec, np.array([3.0]))
    assert one["mean"] == 3.0 and np.isnan(one["ci_low"]) and np.isnan(one["ci_high"])
    assert all(np.isnan(v) for v in aggregate(spec, np.array([np.nan])).values())


def test_the_bootstrap_interval_of_the_mean_is_reproducible_and_shrinks_with_n():
    """Seeded: the same values give the same interval. It holds the mean and narrows like
    1/√n (30 → 300 episodes of one distribution: ≈ √10 = 3.2 times); on 30 normal values it
    is within 10 % of Student's t interval (2.045 s/√30 each side)."""
    rng = np.random.default_rng(1)
    x30, x300 = rng.normal(7.0, 1.5, 30), rng.normal(7.0, 1.5, 300)
    lo30, hi30 = mean_interval(x30)
    assert (lo30, hi30) == mean_interval(x30)
    assert mean_interval(x30, seed=1) != (lo30, hi30)
    assert lo30 < x30.mean() < hi30
    lo300, hi300 = mean_interval(x300)
    assert lo300 < x300.mean() < hi300
    assert 2.5 < (hi30 - lo30) / (hi300 - lo300) < 4.0
    t_width = 2 * 2.045 * np.std(x30, ddof=1) / np.sqrt(30)
    assert (hi30 - lo30) == pytest.approx(t_width, rel=0.1)
    assert mean_interval(np.full(30, 12.0)) == (12.0, 12.0)  # every episode at the limit
    assert all(np.isnan(mean_interval(np.array([5.0]))))
    with pytest.raises(ValueError, match="confidence"):
        mean_interval(x30, confidence=95)
    with pytest.raises(ValueError, match="finite"):
        mean_interval(np.array([1.0, np.nan]))
    assert mean_interval(x30, resamples=np.int64(10_000), seed=np.int32(0)) == (lo30, hi30)
    for bad in (1e4, True, 0, "10000"):
        with pytest.raises(ValueError, match="resamples must be an integer >= 1"):
            mean_interval(x30, resamples=bad)
    for bad in (1.5, False, -1, None):
        with pytest.raises(ValueError, match="seed must be an integer >= 0"):
            mean_interval(x30, seed=bad)


def test_the_wilson_interval_of_a_success_rate():
    """26/30 → 0.703–0.947 (the closed form); 0/30 and 30/30 are not zero-width, as
    p ± z √(p(1 − p)/n) would be, and end exactly at 0 and 1; the interval narrows with n and
    stays in [0, 1]."""
    assert wilson_interval(26, 30) == pytest.approx((0.7032, 0.9469), abs=1e-4)
    low, high = wilson_interval(0, 30)
    assert low == 0.0 and high == pytest.approx(0.1135, abs=1e-4)
    low, high = wilson_interval(30, 30)
    assert high == 1.0 and low == pytest.approx(0.8865, abs=1e-4)  # exactly 1, not 1 − 1e-16
    assert all(wilson_interval(0, n)[0] == 0.0 and wilson_interval(n, n)[1] == 1.0
               for n in range(1, 301))
    w30, w300 = (np.subtract(*wilson_interval(k, n)[::-1]) for k, n in ((15, 30), (150, 300)))
    assert w300 < w30 / 2.5
    for bad in ((31, 30), (-1, 30), (0, 0)):
        with pytest.raises(ValueError, match=r"successes|n must"):
            wilson_interval(*bad)


def test_leaderboard_is_deterministic(tmp_path):
    md1 = run_leaderboard(
        tmp_path / "a", episodes=1, seed=5, envs=[ENV], workers=2, env_overrides=SHORT
    ).read_text()
    md2 = run_leaderboard(
        tmp_path / "b", episodes=1, seed=5, envs=[ENV], workers=2, env_overrides=SHORT
    ).read_text()
    assert md1 == md2
    assert "computed_torque" in md1
    assert any((tmp_path / "a").glob("*.png"))


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["evaluate", "--env", "cir_gym/Nope-v0", "--policy", "pid"], "JointTracking-v2"),
        (["evaluate", "--env", ENV, "--policy", "lqr"], "computed_torque"),
        (["evaluate", "--env", ENV, "--policy", "pid", "--set", "foo=1"], "payload_mass"),
        (["evaluate", "--env", ENV, "--policy", "pid", "--set", "omega=-1"], "omega"),
    ],
)
def test_cli_bad_input_exits_non_zero_listing_what_is_valid(argv, needle, capsys):
    assert main(argv) != 0
    assert needle in capsys.readouterr().err


def test_cli_evaluate_prints_a_table(capsys):
    assert (
        main(
            [
                "evaluate",
                "--env",
                ENV,
                "--policy",
                "computed_torque",
                "--episodes",
                "1",
                "--set",
                "episode_duration=0.2",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "computed_torque" in out and "rms_error" in out


def test_a_policy_with_the_wrong_action_shape_is_reported_with_the_expected_shape():
    class Broken:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros(3), state

    with pytest.raises(ValueError, match=r"expects shape \(7,\)"):
        evaluate(Broken(), ENV, 1, 0, **SHORT)


def test_a_policy_is_evaluated_on_its_recorded_action_interface():
    """An agent trained on the position interface (6 pose increments) is scored there; a
    ready env on the torque interface (7 torques, 500 Hz) is refused naming both, and a task
    that asks for another interface is an error, not silently replaced."""

    class PositionAgent:
        def __init__(self) -> None:
            self.interface_kwargs = {"control": "position", "control_freq": 100.0}

        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros(6), state

    short = {"episode_duration": 0.05}
    result = evaluate(PositionAgent(), "cir_gym/AdmittanceContact-v2", 1, 0, **short)
    assert result.episodes[0].length == 5  # 0.05 s at 100 Hz, not 25 steps at 500 Hz
    with pytest.raises(
        ValueError,
        match=r"control: the env has control='torque', the policy needs control='position'; "
        r"control_freq: the env has control_freq=500",
    ):
        evaluate(
            PositionAgent(),
            "cir_gym/AdmittanceContact-v2",
            1,
            0,
            env=gym.make("cir_gym/AdmittanceContact-v2", **short),
        )
    with pytest.raises(ValueError, match=r"control='torque'.*control='position'"):
        evaluate(PositionAgent(), "cir_gym/AdmittanceContact-v2", 1, 0, control="torque", **short)
    ready = gym.make(
        "cir_gym/AdmittanceContact-v2", control="position", control_freq=100.0, **short
    )
    result = evaluate(PositionAgent(), "cir_gym/AdmittanceContact-v2", 1, 0, env=ready)
    assert result.episodes[0].length == 5


def test_a_given_env_off_the_policys_action_interface_is_an_error_even_when_shapes_agree():
    """A JointTracking agent recorded at 100 Hz on a ready 500 Hz env: the actions have the
    env's shape (7 torques), so it used to run at five times its rate without a word."""

    class Agent:
        def __init__(self, **interface_kwargs) -> None:
            self.interface_kwargs = interface_kwargs

        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros(7), state

    with pytest.raises(
        ValueError,
        match=r"JointTracking-v2 env is not on the policy's action interface \(control_freq: "
        r"the env has control_freq=500.0, the policy needs control_freq=100.0\)",
    ):
        evaluate(Agent(control_freq=100.0), ENV, 1, 0, env=gym.make(ENV, **SHORT))
    with pytest.raises(ValueError, match=r"control: the env has no such argument"):
        agent = Agent(control="position", control_freq=100.0)
        evaluate(agent, ENV, 1, 0, env=gym.make(ENV, control_freq=100.0, **SHORT))
    agent = Agent(control_freq=100)  # an int rate is the same rate
    result = evaluate(agent, ENV, 1, 0, env=gym.make(ENV, control_freq=100.0, **SHORT))
    assert result.episodes[0].length == 20  # 0.2 s at 100 Hz
    controller = baselines.make("computed_torque", ENV)  # no interface_kwargs: any env
    assert evaluate(controller, ENV, 1, 0, env=gym.make(ENV, **SHORT)).episodes[0].length == 100


# ---------------------------------------------------------------------- ranking
def _result(
    name: str, successes: list[bool], errors: list[float], manipulability: list[float]
) -> EvaluationResult:
    specs = (
        MetricSpec("rms_task_error", "m", "lower", ""),
        MetricSpec("min_manipulability", "", "higher", ""),
    )
    episodes = [
        EpisodeResult(i, 0.0, 1, s, False, {"rms_task_error": e, "min_manipulability": w})
        for i, (s, e, w) in enumerate(zip(successes, errors, manipulability, strict=True))
    ]
    return EvaluationResult("cir_gym/RedundantIK-v4", name, episodes, specs, "rms_task_error")


def test_rank_puts_success_first_then_the_primary_metric_in_its_direction():
    stopped = _result("stopped", [False, False], [1e-6, 1e-6], [0.9, 0.9])  # tiny error, failed
    good = _result("good", [True, True], [1e-4, 1e-4], [0.2, 0.2])
    better = _result("better", [True, True], [1e-5, 1e-5], [0.1, 0.1])
    nan = _result("nan", [True, True], [np.nan, np.nan], [np.nan, np.nan])
    assert [r.policy_name for r in rank([stopped, nan, good, better])] == [
        "better",
        "good",
        "nan",
        "stopped",
    ]
    by_w = [r.ranked_on("min_manipulability") for r in (stopped, good, better)]
    assert [r.policy_name for r in rank(by_w)] == ["good", "better", "stopped"]  # higher wins
    with pytest.raises(ValueError, match="not a metric"):
        good.ranked_on("nope")


def test_leaderboard_tables_rank_success_first_on_the_variant_metric():
    """The old table ranked on the primary metric alone: a controller stopped by a collision
    (0 % success, small error) came first."""
    from cir_gym.envs.redundant_ik import RedundantIKEnv
    from cir_gym.evaluation import variant_primary_metric
    from cir_gym.scoring.tables import best, ranked_table, rl_summary

    metric = variant_primary_metric(RedundantIKEnv, "manipulability")
    rows = [
        r.ranked_on(metric)
        for r in (
            _result("stopped", [False], [1e-6], [0.9]),
            _result("clik", [True], [1e-5], [0.1]),
            _result("clik_nullspace", [True], [2e-5], [0.3]),
        )
    ]
    table = ranked_table(rows).splitlines()
    assert "min_manipulability" in table[0]
    assert [line.split("|")[1:3] for line in table[2:]] == [
        [" 1 ", " clik_nullspace "],
        [" 2 ", " clik "],
        [" 3 ", " stopped "],
    ]
    assert best(rows).policy_name == "clik_nullspace"
    assert "| manipulability | `min_manipulability` | clik_nullspace" in rl_summary(
        {"manipulability": rows}
    )
    assert variant_primary_metric(RedundantIKEnv, "no such variant") == "rms_task_error"


def test_the_factor_to_the_best_controller_is_left_out_when_a_value_is_not_positive():
    from cir_gym.scoring.tables import _summary_cell

    best = _result("clik_nullspace", [True], [1e-5], [0.3]).ranked_on("min_manipulability")
    zero = _result("agent:ppo", [False], [1e-2], [0.0]).ranked_on("min_manipulability")
    half = _result("agent:ppo", [False], [1e-2], [0.15]).ranked_on("min_manipulability")
    assert "×" not in _summary_cell(zero, best)
    assert "**2×** the best controller's" in _summary_cell(half, best)


def _pegs(name: str, successes: list[bool], times: list[float]) -> EvaluationResult:
    from cir_gym.envs.peg_in_hole import PegInHoleEnv

    episodes = [
        EpisodeResult(i, 0.0, 1, s, False, {"insertion_time": t})
        for i, (s, t) in enumerate(zip(successes, times, strict=True))
    ]
    return EvaluationResult(
        "cir_gym/PegInHole-v2", name, episodes, PegInHoleEnv.metric_specs, "insertion_time"
    )


def test_no_factor_to_the_best_controller_of_censored_insertion_times():
    """A failed PegInHole episode scores the 12 s time limit: a 0 %-success agent's mean is
    the limit, and 12 s / 7.85 s "1.53× the best controller's" compared the limit with real
    insertion times. Such a factor is "–†" with a footnote; a factor of two fully successful
    rows stays, and so does one of a metric measured in every episode."""
    from cir_gym.envs.peg_in_hole import PegInHoleEnv
    from cir_gym.scoring.tables import NO_FACTOR, _summary_cell, censored_ratio, rl_summary

    spec = next(s for s in PegInHoleEnv.metric_specs if s.name == PegInHoleEnv.primary_metric)
    assert spec.failure_scores_limit
    assert not MetricSpec("rms_error", "rad", "lower", "").failure_scores_limit  # the default
    ctrl = _pegs("hybrid_spiral", [True, True], [7.8, 7.9])
    never = _pegs("agent:ppo_position", [False, False], [12.0, 12.0])
    partly = _pegs("agent:residual_ppo_a", [True, False], [9.0, 12.0])
    always = _pegs("agent:residual_ppo_b", [True, True], [9.0, 9.0])
    assert censored_ratio(never, ctrl) and censored_ratio(partly, ctrl)
    assert not censored_ratio(always, ctrl)
    assert censored_ratio(always, _pegs("ctrl", [True, False], [7.8, 12.0]))  # either side
    assert _summary_cell(never, ctrl).endswith(f"0 % (0–66) success), {NO_FACTOR}")
    assert "×" not in _summary_cell(partly, ctrl)
    assert "**1.15×** the best controller's" in _summary_cell(always, ctrl)

    summary = rl_summary({"sharp edge": [ctrl, never, partly]})
    assert summary.count(NO_FACTOR) == 2 and "×" not in summary
    footnote = summary.splitlines()[-1]
    assert footnote.startswith("† No factor to the best controller")
    assert "`insertion_time`" in footnote
    assert "†" not in rl_summary({"sharp edge": [ctrl, always]})  # no footnote without a "–†"
    # a 0 %-success row of a metric measured in every episode keeps its factor
    rms, clik = _result("agent:ppo", [False], [2e-2], [0.1]), _result("clik", [True], [1e-2], [0.3])
    assert "**2×** the best controller's" in _summary_cell(rms, clik)


def test_an_episode_longer_than_the_registered_spec_is_played_in_full():
    """The registered max_episode_steps (the default episode) must not cut a longer episode
    that env_kwargs ask for: evaluate plays it to its own truncation, with its metrics."""
    import warnings

    import gymnasium as gym

    from cir_gym import baselines

    env_id = "cir_gym/JointTracking-v2"
    registered = gym.spec(env_id).max_episode_steps
    policy = baselines.make("pd_gravity", env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "TimeLimit ends the episode" warning either
        result = evaluate(policy, env_id, 1, 0, episode_duration=4.2)
    episode = result.episodes[0]
    assert registered is not None and episode.length == 2100 > registered
    assert not episode.terminated and episode.metrics


def _episode_fields(result: EvaluationResult) -> list[tuple]:
    return [
        (e.seed, e.length, e.success, e.diverged, e.terminated, e.metrics, e.episode_return)
        for e in result.episodes
    ]


@pytest.mark.parametrize(
    ("env_id", "env_kwargs"),
    [
        (ENV, {"episode_duration": 0.1}),
        (ENV, {"episode_duration": 0.1, "payload_mass": 3.0}),
        ("cir_gym/ElasticJointTracking-v3", {"episode_duration": 0.1}),
    ],
)
def test_batched_evaluation_gives_the_sequential_episodes(env_id, env_kwargs, monkeypatch):
    """Every controller of the env, 4 episodes: the batched path (taken by default for a
    controller, spied on) and the sequential one give identical EpisodeResults (returns
    included, bit for bit)."""
    import cir_gym.evaluation as evaluation

    calls = []
    batched_path = evaluation._evaluate_batched
    monkeypatch.setattr(
        evaluation, "_evaluate_batched", lambda *a, **k: calls.append(1) or batched_path(*a, **k)
    )
    monkeypatch.setattr(evaluation, "MAX_BATCH", 3)  # 4 episodes: groups of 3 and 1
    for name in baselines.available(env_id):
        policy = baselines.make(name, env_id, env_kwargs=env_kwargs)
        assert evaluation.batches_exactly(policy)
        fast = evaluate(policy, env_id, n_episodes=4, seed=40, **env_kwargs)
        slow = evaluate(policy, env_id, n_episodes=4, seed=40, batched=False, **env_kwargs)
        assert _episode_fields(fast) == _episode_fields(slow), name
        assert (fast.dt, fast.specs, fast.primary_metric) == (
            slow.dt,
            slow.specs,
            slow.primary_metric,
        )
    assert len(calls) == len(baselines.available(env_id))


def test_batched_evaluation_of_episodes_that_end_at_different_steps():
    """Weak gains under an unknown payload: the following-error monitor stops some episodes
    early, at different steps, while the others run on; each is the sequential episode."""
    kwargs = {**SHORT, "payload_mass": 3.0, "episode_duration": 0.6}
    policy = baselines.make("pd_gravity", ENV, env_kwargs=kwargs, omega=2.0)
    fast = evaluate(policy, ENV, n_episodes=6, seed=3, **kwargs)
    slow = evaluate(policy, ENV, n_episodes=6, seed=3, batched=False, **kwargs)
    assert _episode_fields(fast) == _episode_fields(slow)
    lengths = {e.length for e in fast.episodes}
    assert len(lengths) > 1 and any(e.terminated for e in fast.episodes)


def test_what_cannot_be_batched_runs_sequentially_or_is_refused_when_asked():
    policy = baselines.make("computed_torque", ENV)
    for kwargs in ({**SHORT, "randomize": True}, {**SHORT, "max_episode_steps": 50}):
        assert len(evaluate(policy, ENV, 2, **kwargs).episodes) == 2  # the sequential path
    with pytest.raises(ValueError, match="randomize=True"):
        evaluate(policy, ENV, 2, batched=True, randomize=True, **SHORT)
    with pytest.raises(ValueError, match="record=True"):
        evaluate(policy, ENV, 2, batched=True, record=True, **SHORT)
    ibvs = baselines.make("ibvs_eye_to_hand", "cir_gym/VisualServoEyeToHand-v1")
    with pytest.raises(ValueError, match="cannot batch features='detected'"):
        evaluate(ibvs, "cir_gym/VisualServoEyeToHand-v1", 2, batched=True, features="detected")

    class Opaque:  # a policy without the flag and not a Controller: sequential by default
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros(np.shape(obs["q"]), dtype=np.float32), None

    from cir_gym.evaluation import batches_exactly

    assert not batches_exactly(Opaque())
    Opaque.batches_exactly = True
    assert batches_exactly(Opaque())
    ours = evaluate(Opaque(), ENV, 2, **SHORT)
    theirs = evaluate(Opaque(), ENV, 2, batched=False, **SHORT)
    assert _episode_fields(ours) == _episode_fields(theirs)


# ---------------------------------------------------------------------- diverged episodes
class _DivergesAt:
    """``policy``'s actions, with a NaN planted in the simulator's q̇ before step ``at``: the
    physics diverges there (the env restores its last finite state and terminates)."""

    def __init__(self, policy, env: gym.Env, at: int) -> None:
        self.policy, self.env, self.at, self.k = policy, env, at, 0
        self.name = f"{policy.name}+divergence"

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        if episode_start is not None and np.any(episode_start):
            self.k = 0
        if self.k == self.at:
            self.env.unwrapped.data.qvel[0] = np.nan
        self.k += 1
        return self.policy.predict(obs, state, episode_start, deterministic)


#: (env, controller, primary metric, the unplayed steps' least charge: the failure value per
#: step in the metric's own mean square, from the env at reset)
DIVERGING = [
    ("cir_gym/JointTracking-v2", "pd_gravity", "rms_error",
     lambda u: u._following_error_limit**2 / u.n),  # ‖q̃‖ = L over n joints
    ("cir_gym/ElasticJointTracking-v3", "pd_gravity", "rms_error",
     lambda u: u._following_error_limit**2 / u.n),  # the link error, as JointTracking's
    ("cir_gym/CartesianTracking-v1", "os_pd_gravity", "position_rms",
     lambda u: u._limits[0] ** 2),
]


@pytest.mark.parametrize(("env_id", "controller", "metric", "charge"), DIVERGING,
                         ids=[d[0] for d in DIVERGING])
@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_a_diverged_episode_is_scored_over_the_whole_horizon(env_id, controller, metric, charge):
    """A divergence at step 20 of a 2000-step episode is scored over the whole horizon, as a
    stopped one is: every unplayed step is charged at least the following-error limit, so the
    diverged episode scores worse than the finished one (it scored 0.00047 rad against 0.008
    rad, CartesianTracking 3e-6 m against 0.0075 m: the diverging policy ranked first among
    failing ones)."""
    env = gym.make(env_id)
    finished = evaluate(baselines.make(controller, env_id, env=env), env_id, env=env)
    policy = _DivergesAt(baselines.make(controller, env_id, env=env), env, at=20)
    diverged = evaluate(policy, env_id, env=env)
    u = env.unwrapped
    played, horizon = diverged.episodes[0].length, u.max_steps
    env.close()
    assert diverged.episodes[0].diverged and played == 21 and not diverged.episodes[0].success
    least = np.sqrt((horizon - played) / horizon * charge(u))
    value = diverged.episodes[0].metrics[metric]
    assert value >= least, (value, least)
    assert value > finished.episodes[0].metrics[metric]
    assert rank([diverged, finished])[0] is finished
