"""The normalized score wired into the leaderboard: the hold-still run of every variant, the
anchors file, the score columns of the markdown tables, the summary, the page and the agents'
seed tables (cir_gym.scoring.normalized, cir_gym.score_scale)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from cir_gym.agents.report import SeedReport, read_anchors, seed_markdown

import cir_gym
from cir_gym.evaluation import EpisodeResult, EvaluationResult, evaluate
from cir_gym.metrics import MetricSpec
from cir_gym.score_scale import Anchors
from cir_gym.scoring.leaderboard import (
    ANCHORS_FILE,
    HOLD_STILL,
    run_leaderboard,
    score_anchors,
    summary,
)
from cir_gym.scoring.normalized import hold_still_policy, variant_anchors
from cir_gym.scoring.page import ranked_html
from cir_gym.scoring.tables import ranked_table, rl_summary

LOWER = (MetricSpec("rms_error", "rad", "lower", "tracking error"),)
ENV = "cir_gym/X-v0"


def _result(name: str, values: list[float], success: bool = True) -> EvaluationResult:
    episodes = [
        EpisodeResult(seed=i, episode_return=0.0, length=1, success=success, diverged=False,
                      metrics={"rms_error": v})
        for i, v in enumerate(values)
    ]
    return EvaluationResult(ENV, name, episodes, LOWER, "rms_error")


HOLD = _result(HOLD_STILL, [20.0, 20.0])
ROWS = [_result("tuned:admittance", [4.0, 4.0]), _result("impedance", [12.0, 12.0]),
        _result("agent:ppo", [24.0, 24.0], success=False)]


def _score_column(table: str) -> dict[str, str]:
    """policy → the cell under the "score" header of a markdown table."""
    lines = [line.split("|")[1:-1] for line in table.splitlines() if line.startswith("|")]
    head = [c.strip() for c in lines[0]]
    col, pol = head.index("score"), head.index("policy")
    return {cells[pol].strip(): cells[col].strip() for cells in lines[2:]}


def test_the_ranked_table_and_the_summary_carry_the_score() -> None:
    anchors = variant_anchors(ROWS, HOLD)
    assert (anchors.best_policy, anchors.hold, anchors.best, anchors.log) == (
        "tuned:admittance", 20.0, 4.0, False)
    assert _score_column(ranked_table(ROWS, anchors)) == {
        "tuned:admittance": "1.00", "impedance": "0.50", "agent:ppo": "-0.25"}
    assert "score" not in ranked_table(ROWS).splitlines()[0]  # no anchors, no column
    text = rl_summary({"v": ROWS}, {"v": anchors})
    assert "score 1.00" in text and "score -0.25" in text and "0 = hold still" in text
    assert "score" not in rl_summary({"v": ROWS})
    html = ranked_html(ROWS, anchors)
    assert ">score</abbr>" in html and "<td>-0.25</td>" in html
    assert "score" not in ranked_html(ROWS)


def test_variants_without_a_scale_say_why() -> None:
    results = {(ENV, "default", r.policy_name): r for r in ROWS}
    flat = _result(HOLD_STILL, [4.0, 4.0])  # holding still as good as the best: no scale
    cls = type("X", (), {"leaderboard_variants": {"default": {}}})
    cir_gym.ENVIRONMENTS[ENV] = (cls, "test")
    try:
        anchors, why = score_anchors(results, {(ENV, "default"): flat}, [ENV])
        assert anchors == {} and "differ" in why[(ENV, "default")]
        anchors, why = score_anchors(results, {}, [ENV])
        assert anchors == {} and "hold-still run failed" in why[(ENV, "default")]
        anchors, why = score_anchors(results, {(ENV, "default"): HOLD}, [ENV])
        assert why == {} and anchors[(ENV, "default")].best == 4.0
        assert "score 1.00" in summary(results, [ENV], anchors)
    finally:
        del cir_gym.ENVIRONMENTS[ENV]


def test_the_seed_table_scores_every_seed_episode() -> None:
    """IQM of the per-(seed, episode) scores: with anchors 20 → 4 (linear), errors 8 and 12 on
    every episode of two seeds score 0.75 and 0.5; IQM over the four values 0.625."""
    scores = np.array([[8.0, 8.0], [12.0, 12.0]])
    report = SeedReport("ppo", [0, 1], scores, np.ones((2, 2)), "rms_error", 10.0, 8.0, 12.0)
    anchors = Anchors.of("rms_error", 20.0, 4.0, "tuned:admittance", "rad")
    table = seed_markdown([report], anchors)
    head, _, row = table.splitlines()[-3:]
    assert head.endswith("| IQM score | score CI |")
    assert row.split("|")[-3].strip() == "0.625"
    assert "IQM score" not in seed_markdown([report])
    with pytest.raises(ValueError, match="anchors are on"):
        seed_markdown([report], Anchors.of("max_error", 20.0, 4.0, "x"))


def test_anchors_round_trip_through_the_file(tmp_path: Path) -> None:
    a = Anchors.of("rms_error", 0.0185, 1.7e-5, "tuned:computed_torque", "rad")
    assert a.log  # three decades apart
    path = tmp_path / ANCHORS_FILE
    path.write_text(json.dumps({"episodes": 3, "seed": 1000,
                                "variants": {f"{ENV} default": a.to_dict()}}))
    assert read_anchors(path, ENV, "default", 3, 1000) == a
    assert read_anchors(path, ENV, "default", 5, 1000) is None  # other episodes: no score
    assert read_anchors(path, ENV, "other", 3, 1000) is None
    assert read_anchors(tmp_path / "missing.json", ENV, "default", 3, 1000) is None


def test_a_leaderboard_run_measures_its_own_anchors(tmp_path: Path) -> None:
    """A real run (VisualServoEyeToHand-v1, 1 episode of 1 s per policy): each variant's
    hold-still mean in normalized.json is that policy's own evaluation on the same seed, the
    best controller scores 1.00 in its table and the hold-still run is not ranked."""
    env_id = "cir_gym/VisualServoEyeToHand-v1"
    short = {"episode_duration": 1.0}
    md = run_leaderboard(tmp_path, episodes=1, seed=1000, envs=[env_id], workers=2,
                         env_overrides=short, figures=False, videos=False).read_text()
    data = json.loads((tmp_path / ANCHORS_FILE).read_text())
    cls = cir_gym.ENVIRONMENTS[env_id][0]
    assert (data["episodes"], data["seed"]) == (1, 1000)
    assert set(data["variants"]) == {f"{env_id} {v}" for v in cls.leaderboard_variants}
    for variant, kwargs in cls.leaderboard_variants.items():
        a = Anchors.from_dict(data["variants"][f"{env_id} {variant}"])
        env = gym.make(env_id, **kwargs, **short)
        hold = evaluate(hold_still_policy(env), env_id, 1, 1000, **kwargs, **short)
        env.close()
        assert a.hold == pytest.approx(hold.summary[a.metric]["mean"], rel=1e-12)
        section = md.split(f"### {variant} (")[1].split("\n### ")[0]
        scores = _score_column(section)
        assert scores[a.best_policy] == "1.00"
        assert HOLD_STILL not in scores
        assert f"Normalized score on `{a.metric}`: 0 = hold still" in section
    page = (tmp_path / "index.html").read_text()
    assert ">score</abbr>" in page and "Normalized score on" in page
    assert re.search(r"score \d\.\d\d\)", md)  # the summary's cells
