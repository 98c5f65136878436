"""One table per task: the leaderboard runs the policies of an agent-ready variant
(PegInHoleImpedance-v0, AdmittanceContactImpedance-v1) on its task's variants and ranks their
rows, labelled with the interface, in the task's tables; an agent-ready controller may anchor
the normalized score."""

from __future__ import annotations

import pytest

import cir_gym
from cir_gym.evaluation import EpisodeResult, EvaluationResult
from cir_gym.scoring.leaderboard import jobs_for, row_key, run_job, run_leaderboard
from cir_gym.scoring.normalized import best_controller, normalized_scores
from cir_gym.scoring.policies import (
    interface_ids,
    policy_names,
    policy_of_row,
    row_label,
    task_id,
)

PEG = "cir_gym/PegInHoleImpedance-v0"
CONTACT = "cir_gym/AdmittanceContactImpedance-v1"


def test_agent_ready_ids_play_their_task() -> None:
    assert task_id(PEG) == "cir_gym/PegInHole-v2"
    assert task_id(CONTACT) == "cir_gym/AdmittanceContact-v2"
    assert task_id("cir_gym/PegInHole-v2") == "cir_gym/PegInHole-v2"
    assert interface_ids("cir_gym/PegInHole-v2") == ["cir_gym/PegInHole-v2", PEG]
    assert interface_ids("cir_gym/JointTracking-v2") == ["cir_gym/JointTracking-v2"]
    assert row_label(PEG, "impedance_spiral") == "impedance_spiral [PegInHoleImpedance-v0]"
    assert row_label("cir_gym/PegInHole-v2", "hybrid_spiral") == "hybrid_spiral"
    assert policy_of_row(row_label(PEG, "agent:ppo")) == "agent:ppo"  # for the page's videos


def test_jobs_of_an_agent_ready_id_are_rows_of_its_task_s_tables() -> None:
    """Every policy of the agent-ready id on each of its task's variants, with the task's
    kwargs (and the overrides); each job's row is in the task's table, labelled."""
    task = "cir_gym/PegInHole-v2"
    variants = cir_gym.ENVIRONMENTS[task][0].leaderboard_variants
    jobs = jobs_for(PEG, {"episode_duration": 1.0})
    assert {(v, p) for _, v, _, p in jobs} == {
        (v, p) for v in variants for p in policy_names(PEG)}
    for env_id, variant, kw, policy in jobs:
        assert env_id == PEG and kw == {**variants[variant], "episode_duration": 1.0}
        assert row_key((env_id, variant, kw, policy)) == (task, variant, f"{policy} "
                                                          "[PegInHoleImpedance-v0]")
    key, result, _ = run_job(jobs[0], 1, 1000)
    assert key == row_key(jobs[0]) and result.policy_name == key[2]
    assert result.env_id == PEG and result.primary_metric == "insertion_time"


def test_the_leaderboard_writes_agent_ready_rows_into_the_task_s_table(tmp_path,
                                                                        monkeypatch) -> None:
    """``--env`` an agent-ready id: one table, its task's, with the interface's rows beside
    the task's controllers, scored on the task's hold-still and best controller."""
    from cir_gym.scoring import leaderboard

    real = leaderboard.jobs_for
    only = ("impedance_setpoint", "impedance")
    monkeypatch.setattr(leaderboard, "jobs_for", lambda e, o=None: [
        j for j in real(e, o) if j[3] in only and j[1] == "stiffness 1e4 N/m"])
    md = run_leaderboard(tmp_path, episodes=1, envs=[CONTACT], workers=1,
                         env_overrides={"episode_duration": 1.0}, figures=False, videos=False)
    text = md.read_text()
    assert "## cir_gym/AdmittanceContact-v2" in text and "## " + CONTACT not in text
    table = text.split("### stiffness 1e4 N/m", 1)[1].split("###", 1)[0]
    assert "| impedance_setpoint [AdmittanceContactImpedance-v1] |" in table
    assert "| impedance |" in table
    anchors = (tmp_path / "normalized.json").read_text()
    assert "cir_gym/AdmittanceContact-v2 stiffness 1e4 N/m" in anchors


def _result(env_id: str, name: str, values: list[float]) -> EvaluationResult:
    """A hand-made result on ``env_id`` with PegInHole's metrics."""
    cls = cir_gym.ENVIRONMENTS["cir_gym/PegInHole-v2"][0]
    episodes = [EpisodeResult(seed=i, episode_return=0.0, length=1, success=False,
                              diverged=False, metrics={"insertion_time": v})
                for i, v in enumerate(values)]
    return EvaluationResult(env_id, name, episodes, tuple(cls.metric_specs), "insertion_time")


def test_an_agent_ready_controller_may_anchor_the_score() -> None:
    """The best controller at any interface of the task scores 1; an agent's row on the
    agent-ready id is scored on the task's anchors; a row of another task is refused."""
    hold = _result("cir_gym/PegInHole-v2", "hold_still", [12.0, 12.0])
    rows = [
        _result("cir_gym/PegInHole-v2", "hybrid_spiral", [10.0, 11.0]),
        _result(PEG, row_label(PEG, "impedance_spiral"), [8.0, 9.0]),
        _result(PEG, row_label(PEG, "agent:ppo"), [6.0, 6.0]),
    ]
    assert best_controller(rows).policy_name == "impedance_spiral [PegInHoleImpedance-v0]"
    scores = normalized_scores(rows, hold)
    assert scores["impedance_spiral [PegInHoleImpedance-v0]"].score == pytest.approx(1.0)
    assert scores["agent:ppo [PegInHoleImpedance-v0]"].score == pytest.approx(6.0 / 3.5)
    other = _result("cir_gym/CartesianTracking-v1", "pd", [1.0, 1.0])
    with pytest.raises(ValueError, match="another task"):
        normalized_scores([*rows, other], hold)
