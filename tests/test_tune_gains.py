"""scripts/tune_gains.py: what a trial scores (success first, then the variant's metric; progress
when every episode fails), what is shipped (never worse than the defaults on the training
seeds), how many training episodes, the search space, and resuming (studies continue, rows
merge, scored rows are not re-scored, a study of another protocol is refused)."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import optuna
import pytest

from scripts import tune_gains

JT = "cir_gym/JointTracking-v2"

ENV_ARGS = ["--variant", "exact model", "--set", "episode_duration=0.1", "--train-episodes", "1",
            "--episodes", "1"]


@pytest.fixture
def counted_scores(monkeypatch):
    """Counts the calls of tune_gains.score (each plays episodes)."""
    calls: list[int] = []
    real = tune_gains.score

    def score(*args, **kwargs):
        calls.append(args[5])  # the number of episodes
        return real(*args, **kwargs)

    monkeypatch.setattr(tune_gains, "score", score)
    return calls


def test_a_stopped_run_resumes_and_keeps_the_other_rows(tmp_path, counted_scores):
    out = ["--out", str(tmp_path)]
    assert tune_gains.main(["--controller", "pd_gravity", "--trials", "2", *ENV_ARGS, *out]) == 0
    assert tune_gains.main(["--controller", "pid", "--trials", "2", *ENV_ARGS, *out]) == 0
    rows = json.loads((tmp_path / "JointTracking-v2.json").read_text())
    assert [r["controller"] for r in rows] == ["pd_gravity", "pid"]  # merged, not replaced

    # more trials: the study continues (the default gains are not enqueued again)
    assert tune_gains.main(["--controller", "pd_gravity", "--trials", "3", *ENV_ARGS, *out]) == 0
    study = optuna.load_study(study_name="JointTracking-v2-exact_model-pd_gravity",
                              storage=f"sqlite:///{tmp_path}/studies.db")
    assert len(study.trials) == 3
    assert study.trials[0].params == {"omega": 10.0, "zeta": 1.0}
    assert sum(t.params == study.trials[0].params for t in study.trials) == 1
    rows = json.loads((tmp_path / "JointTracking-v2.json").read_text())
    assert [(r["controller"], r["trials"]) for r in rows] == [("pd_gravity", 3), ("pid", 2)]

    # nothing left to do: no trial, no scoring
    before = len(counted_scores)
    assert tune_gains.main(["--controller", "pd_gravity", "--trials", "3", *ENV_ARGS, *out]) == 0
    assert len(counted_scores) == before
    assert len(study.trials) == len(optuna.load_study(
        study_name=study.study_name, storage=f"sqlite:///{tmp_path}/studies.db").trials)
    assert "| exact model | pid |" in (tmp_path / "JointTracking-v2.md").read_text()


def test_the_hybrid_laws_search_their_force_loop():
    """The force loop's crossover ratio is part of the hybrid laws' design, searched a decade
    either side of the course's 0.1 (0.01-1: below the contact's natural frequency)."""
    peg = "cir_gym/PegInHole-v2"
    for law in ("hybrid_force_position", "hybrid_spiral"):
        assert "crossover_ratio" in tune_gains.tunable_gains(law, peg)
    assert tune_gains.bounds("crossover_ratio", 0.1, 0.002) == pytest.approx((0.01, 1.0))


def _train(success: float, value: float, episodes: int = 10, better: str = "lower",
           **more: float) -> dict:
    """A training score as tune_gains.score returns it."""
    return {"metric": "insertion_time", "better": better, "value": value, "return": -1.0,
            "success": success, "divergence": 0.0, "episodes": episodes, **more}


DEPTH = ("final_depth", "higher")


def test_a_trial_ranks_by_success_then_metric_then_progress_when_all_fail():
    """One more inserted training episode outranks any insertion time; at equal success the
    lower mean time ranks first; where every episode fails (the time is the 12-s cap for all)
    the deeper peg ranks first, below every trial with a success; divergence ranks last."""
    v = tune_gains.trial_value
    one_slow = v(_train(0.1, 11.9), DEPTH)
    two_slow = v(_train(0.2, 11.8), DEPTH)
    one_fast = v(_train(0.1, 10.9), DEPTH)
    assert two_slow < one_fast < one_slow
    shallow = v(_train(0.0, 12.0, final_depth=0.001), DEPTH)
    deep = v(_train(0.0, 12.0, final_depth=0.004), DEPTH)
    assert one_slow < deep < shallow
    assert 10.0 < deep < shallow < 11.0  # 10 failures + s(−depth), s in (0, 1)
    assert v({**_train(0.5, 5.0), "divergence": 0.1}, DEPTH) == math.inf
    assert v(_train(0.0, 12.0), DEPTH) == math.inf  # no progress measured: not ranked
    # a higher-is-better metric is signed: a larger manipulability ranks first
    assert v(_train(1.0, 0.3, better="higher"), DEPTH) < v(_train(1.0, 0.2, better="higher"),
                                                           DEPTH)
    # the order of rank_key (the leaderboard's) wherever a trial succeeds
    trains = [_train(0.1, 11.9), _train(0.2, 11.8), _train(0.1, 10.9), _train(1.0, 3.0)]
    by_value = sorted(trains, key=lambda t: v(t, DEPTH))
    assert by_value == sorted(trains, key=tune_gains.rank_key)


def _trial(number: int, value: float, train: dict) -> SimpleNamespace:
    return SimpleNamespace(number=number, value=value, user_attrs={"train": train})


def test_the_defaults_are_kept_unless_a_trial_beats_them_on_the_training_seeds():
    """Shipped: the best trial only if it has a higher training success rate, or the same and a
    strictly better mean metric; a trial that only went deeper (all failing, like the defaults)
    does not replace them, nor does an equal one."""
    first = _trial(0, 10.6, _train(0.0, 12.0, final_depth=0.0))
    deeper = _trial(1, 10.4, _train(0.0, 12.0, final_depth=0.003))
    assert tune_gains.shipped_trial([first, deeper], first) is first
    inserts = _trial(2, 9.7, _train(0.1, 11.5, final_depth=0.02))
    assert tune_gains.shipped_trial([first, deeper, inserts], first) is inserts
    same = _trial(1, 10.6, _train(0.0, 12.0, final_depth=0.0))
    assert tune_gains.shipped_trial([first, same], first) is first
    # no default trial (its gains rejected): the best is all there is
    assert tune_gains.shipped_trial([deeper], None) is deeper


def test_training_episodes_follow_the_default_gains_success():
    """3 training episodes where the defaults succeed in all 3, 10 where they do not (a 10 %
    rate shows in 10, rarely in 3); an asked number, else a resumed study's own, wins."""
    fresh = SimpleNamespace(trials=[], user_attrs={})
    probe_ok = lambda n: {"success": 1.0}  # noqa: E731
    probe_rare = lambda n: {"success": 2 / 3}  # noqa: E731
    assert tune_gains.study_episodes(fresh, None, probe_ok) == tune_gains.TRAIN_EPISODES == 3
    assert tune_gains.study_episodes(fresh, None, probe_rare) == 10
    resumed = SimpleNamespace(trials=[object()], user_attrs={"train_episodes": 7})
    assert tune_gains.study_episodes(resumed, None, probe_ok) == 7
    assert tune_gains.study_episodes(resumed, 4, probe_ok) == 4


def test_a_failing_peg_search_keeps_the_defaults_and_ranks_by_depth(tmp_path):
    """PegInHole cut to 0.05 s (no trial can insert): every trial is ranked by its mean
    final_depth (the failures' count + s(−depth)), none beats the defaults on what the leaderboard
    ranks, so the defaults are shipped as the tuned gains."""
    peg = "cir_gym/PegInHole-v2"
    row = tune_gains.tune("hybrid_force_position", peg, "sharp edge",
                          {"episode_duration": 0.05}, trials=3, train_episodes=1,
                          out=tmp_path)
    assert row["tie_breaker"] == "final_depth" and row["kept_default"]
    assert row["tuned"] == row["default"]
    assert row["train_tuned"] == row["train_default"]
    study = optuna.load_study(study_name=row["study"], storage=f"sqlite:///{tmp_path}/studies.db")
    assert study.user_attrs["protocol"] == tune_gains.PROTOCOL
    for t in study.trials:
        train = t.user_attrs["train"]
        assert train["success"] == 0.0 and train["value"] == pytest.approx(0.05)
        assert t.value == pytest.approx(1.5 - math.atan(train["final_depth"]) / math.pi)


def test_a_study_of_another_protocol_is_not_resumed(tmp_path):
    """A study searched with other training episodes, or by the earlier protocol (no protocol
    recorded), is refused with a message naming it, rather than mixed with new trials."""
    args = ["--controller", "pd_gravity", "--trials", "1", *ENV_ARGS, "--out", str(tmp_path)]
    assert tune_gains.main(args) == 0
    with pytest.raises(ValueError, match=r"JointTracking-v2-exact_model-pd_gravity.*fresh --out"):
        tune_gains.main([*args, "--train-episodes", "2"])
    old = optuna.create_study(study_name="JointTracking-v2-exact_model-pid",
                              storage=f"sqlite:///{tmp_path}/studies.db")
    old.enqueue_trial({"omega": 10.0, "zeta": 1.0})
    old.optimize(lambda t: t.suggest_float("omega", 1, 100) + t.suggest_float("zeta", 0.3, 3),
                 n_trials=1)
    with pytest.raises(ValueError, match="protocol"):
        tune_gains.main(["--controller", "pid", "--trials", "2", *ENV_ARGS, "--out",
                         str(tmp_path)])


# moved from tests/test_agents.py (tune_gains' search space, smoke run and ranking)

def test_tune_gains_smoke(tmp_path):
    assert tune_gains.main(["--controller", "pd_gravity", "--trials", "2", *ENV_ARGS,
                            "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "JointTracking-v2.json").read_text())
    assert data[0]["default"] == {"omega": 10.0, "zeta": 1.0}
    assert 1.0 <= data[0]["tuned"]["omega"] <= 150.0
    assert data[0]["best_train"] <= data[0]["default_train"]  # trial 0 is the default
    assert (tmp_path / "studies.db").is_file()


def test_tune_gains_searches_the_servo_gain_within_the_camera_rate_bound():
    """Visual servoing's λ is tunable, bounded by λ Δt ≤ 0.3 at the 25-Hz camera rate; the
    joint-space laws' ω within ω Δt ≤ 0.3 at 500 Hz (150 rad/s)."""
    from scripts.tune_gains import bounds, tunable_gains

    vs = "cir_gym/VisualServo-v1"
    assert tunable_gains("ibvs", vs) == {"gain": 0.5} == tunable_gains("pbvs", vs)
    assert bounds("gain", 0.5, 0.04)[1] * 0.04 == pytest.approx(0.3)
    assert tunable_gains("computed_torque", JT) == {"omega_n": 20.0, "zeta": 1.0}
    assert bounds("omega_n", 20.0, 0.002) == pytest.approx((1.0, 150.0))


def test_tune_gains_search_space_follows_the_law_and_the_variant():
    """CLIK's K is bounded by dead-beat, KΔt ≤ 1 (200 1/s on the planar arm's 200 Hz, 100 on
    the iiwa's 100 Hz); a null-space gain is searched only on its own objective's variant; the
    interaction laws search their force-loop gains, a gain without a physical bound a decade
    either side of the course's value; a gain whose default is the law's rule (None) is
    searched from the value the rule gives when it is one number for every joint (the
    cascades' ω_cv = 80, ω_cp = ω_cv / 5 on rigid joints), not where the rule designs each
    joint (ω_cv = 0.7 ω_z on elastic joints)."""
    from scripts.tune_gains import bounds, tunable_gains, variant_setting

    rik, rik7 = "cir_gym/RedundantIK-v4", "cir_gym/RedundantIK7-v5"
    assert variant_setting(rik, {"objective": "obstacle"}) == (pytest.approx(0.005), "obstacle")
    assert bounds("K", 50.0, variant_setting(rik7, {})[0]) == pytest.approx((1.0, 100.0))
    assert bounds("K", 50.0, 0.005) == pytest.approx((1.0, 200.0))
    assert tunable_gains("clik_nullspace", rik, "obstacle") == {"K": 50.0, "k0_obstacle": 5.0}
    assert tunable_gains("clik_nullspace", rik, "joint_limits") == {"K": 50.0,
                                                                    "k0_joint_limits": 10.0}
    assert tunable_gains("clik", rik, "obstacle") == {"K": 50.0}
    assert tunable_gains("pseudo_inverse", rik, "obstacle") == {}
    ac = "cir_gym/AdmittanceContact-v2"
    assert tunable_gains("admittance", ac) == {"crossover": 20.0, "motion_omega": 40.0}
    assert tunable_gains("explicit_force", ac) == {"crossover_ratio": 0.5, "zeta": 1.0}
    assert bounds("crossover_ratio", 0.5, 0.002) == pytest.approx((0.05, 5.0))
    assert tunable_gains("p_pi_cascade", JT) == {}  # the rule's value needs the env's arguments
    assert tunable_gains("p_pi_cascade", JT, None, {}) == {"omega_cv": 80.0, "omega_cp": 16.0}
    assert tunable_gains("p_pi_cascade", "cir_gym/ElasticJointTracking-v3", None, {}) == {}
    assert bounds("omega_cv", 80.0, 0.002) == pytest.approx((1.0, 150.0))
    assert set(tunable_gains("adaptive", JT)) == {"lam", "kd", "gamma"}
    assert bounds("gamma", 100.0, 0.002) == pytest.approx((10.0, 1000.0))
    assert bounds("lam", 10.0, 0.002) == pytest.approx((1.0, 150.0))
    assert set(tunable_gains("hybrid_force_position", "cir_gym/PegInHole-v2")) == {
        "omega_n", "zeta", "crossover_ratio", "d_f", "speed"}


def test_tune_gains_keeps_the_cascades_position_loop_below_its_speed_loop(tmp_path):
    """The cascades' ω_cp is sampled below the ω_cv of its own trial (the law rejects
    ω_cp ≥ ω_cv), trial 0 is the course's rule (80, 16 rad/s), and the rule's value is what
    the law builds without the gains: trial 0 scores what the default controller scores."""
    from scripts.tune_gains import TRAIN_SEED, score, tune

    row = tune("p_pi_cascade", JT, "exact model", {"episode_duration": 0.5}, trials=4,
               train_episodes=1, out=tmp_path)
    assert row["default"] == {"omega_cv": 80.0, "omega_cp": 16.0}
    study = optuna.load_study(study_name=row["study"], storage=f"sqlite:///{tmp_path}/studies.db")
    assert study.trials[0].params == row["default"]
    for t in study.trials:
        assert t.params["omega_cp"] < t.params["omega_cv"] <= 150.0
    rule = score("p_pi_cascade", JT, "exact model", {"episode_duration": 0.5}, {}, 1, TRAIN_SEED)
    assert study.trials[0].user_attrs["train"]["value"] == rule["value"]


def test_tune_gains_ranks_on_the_variants_metric_and_never_ships_worse_gains(tmp_path):
    """On RedundantIK's manipulability variant a trial that succeeds scores by
    −min_manipulability (higher is better there); the Jacobian transpose, which misses the
    1-mm bar on every training episode, ranks its trials by the return (manipulability is
    bought by not tracking). Every trial's value is trial_value of its training score, and
    the shipped gains are never below the defaults' training rank."""
    assert tune_gains.main(["--env", "cir_gym/RedundantIK-v4", "--controller", "clik_nullspace",
                            "--controller", "jacobian_transpose", "--trials", "4",
                            "--train-episodes", "1", "--episodes", "1", "--variant",
                            "manipulability", "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "RedundantIK-v4.json").read_text())
    assert rows[0]["default"] == {"K": 50.0, "k0_manipulability": 20.0}
    assert rows[0]["bounds"]["K"] == pytest.approx([1.0, 200.0])
    assert rows[0]["leaderboard_tuned"]["metric"] == "min_manipulability"
    assert [r["searched_on"] for r in rows] == ["min_manipulability"] * 2
    assert [r["tie_breaker"] for r in rows] == ["return"] * 2
    assert [r["train_default"]["success"] for r in rows] == [1.0, 0.0]
    for row in rows:
        assert row["best_train"] <= row["default_train"]
        assert (tune_gains.rank_key(row["train_tuned"])
                <= tune_gains.rank_key(row["train_default"]))
        assert row["kept_default"] == (row["tuned"] == row["default"])
        study = optuna.load_study(study_name=row["study"],
                                  storage=f"sqlite:///{tmp_path}/studies.db")
        for t in study.trials:
            assert t.value == tune_gains.trial_value(t.user_attrs["train"], ("return", "higher"))
    md = (tmp_path / "RedundantIK-v4.md").read_text()
    assert "| manipulability | clik_nullspace | min_manipulability |" in md
    assert "| manipulability | jacobian_transpose | min_manipulability |" in md
