"""scripts/tune_gains.py resumes: studies continue, rows merge, scored rows are not re-scored."""

from __future__ import annotations

import json

import optuna
import pytest

from scripts import tune_gains

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
