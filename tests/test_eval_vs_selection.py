"""scripts/research/eval_vs_agents.py: checkpoint selection on validation seeds, apart from the
test seeds, and the models ``evaluate`` then scores per run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from scripts.research import eval_vs_agents as ev

ENV = "cir_gym/VisualServoEyeToHand-v1"


def _run(root: Path, seed: int, checkpoints: tuple[int, ...], finished: int | None,
         algo: str = "ppo") -> Path:
    """A run directory as the trainer leaves it (empty model files: the scorer is faked)."""
    run = root / "VisualServoEyeToHand-v1" / algo / f"seed_{seed}"
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.yml").write_text("env_id: cir_gym/VisualServoEyeToHand-v1\n")
    for k in checkpoints:
        (run / "checkpoints" / f"model_{k}_steps.zip").touch()
        (run / "checkpoints" / f"model_vecnormalize_{k}_steps.pkl").touch()
    if finished is not None:
        (run / "model.zip").touch()
        (run / "meta.json").write_text(json.dumps({"timesteps": finished, "finished": True}))
    return run


class FakeScorer:
    """Validation outcomes from a table (run name, source, steps) → (successes, final error),
    counting the calls."""

    def __init__(self, table: dict[tuple[str, str, int], tuple[int, float]], episodes: int):
        self.table, self.episodes, self.calls = table, episodes, []

    def __call__(self, run: Path, source: str, steps: int) -> dict[str, list]:
        self.calls.append((run.name, source, steps))
        wins, error = self.table[run.name, source, steps]
        n = self.episodes
        return {"final_feature_error": [error if i < wins else 5.0 for i in range(n)],
                "success": [i < wins for i in range(n)], "terminated": [False] * n,
                "convergence_time": [1.0] * n}


def _row(steps: int, rate: float, iqm: float) -> dict:
    return {"source": "checkpoint", "steps": steps, "success_rate": rate, "iqm": iqm}


def test_best_ranks_success_then_final_error_iqm_then_fewer_steps():
    rows = [_row(100, 0.9, 0.10), _row(200, 1.0, 0.30), _row(300, 1.0, 0.20)]
    assert ev.best(rows)["steps"] == 300  # success ties at 100 %: the lower IQM
    assert ev.best([*rows[:1], _row(400, 0.9, 0.05)])["steps"] == 400
    assert ev.best([_row(500, 1.0, 0.2), _row(200, 1.0, 0.2)])["steps"] == 200
    with pytest.raises(ValueError, match="no candidate"):
        ev.best([])


def _ranges() -> dict[str, range]:
    from cir_gym.agents.train import EVAL_SEED

    from scripts.research import eval_visual_servo as evs
    from scripts.research.eval_peg_in_hole import LAW_SEED

    return {"test": range(ev.TEST_SEED, ev.TEST_SEED + 100),
            "training (seeds 0-4, 16 envs each)": range(0, 4 + 16),
            "evaluation during training": range(EVAL_SEED, EVAL_SEED + 100),
            "study": range(60_000, 60_000 + 20), "leaderboard": range(1000, 1100),
            "agent episodes": range(evs.AGENT_SEED, evs.AGENT_SEED + 100),
            "rotation": range(evs.ROTATION_SEED, evs.ROTATION_SEED + 100),
            "peg-in-hole laws": range(LAW_SEED, LAW_SEED + 100),
            "contact": range(5000, 5100)}


def test_validation_seeds_are_disjoint_from_every_other_seed_range():
    validation = set(range(ev.VALIDATION_SEED, ev.VALIDATION_SEED + ev.VALIDATION_EPISODES))
    for name, seeds in _ranges().items():
        assert not validation & set(seeds), name


def test_select_scores_every_checkpoint_and_final_model_and_chooses_per_run(tmp_path):
    root, out = tmp_path / "runs", tmp_path / "out"
    _run(root, 0, (100_000, 200_000, 300_000), finished=310_000)
    _run(root, 1, (100_000,), finished=None)
    table = {("seed_0", "checkpoint", 100_000): (8, 0.3),
             ("seed_0", "checkpoint", 200_000): (10, 0.25),  # all succeed, not the lowest
             ("seed_0", "checkpoint", 300_000): (10, 0.20),  # all succeed, lowest error
             ("seed_0", "final", 310_000): (9, 0.10),  # lower error, one failure more
             ("seed_1", "checkpoint", 100_000): (3, 0.4)}
    scorer = FakeScorer(table, episodes=10)
    record = ev.select_env(ENV, root, out, episodes=10, score=scorer)
    assert record["runs"]["ppo/seed_0"]["chosen"] == {"source": "checkpoint", "steps": 300_000}
    assert record["runs"]["ppo/seed_1"]["chosen"] == {"source": "checkpoint", "steps": 100_000}
    assert not record["runs"]["ppo/seed_1"]["finished"]
    assert sorted(scorer.calls) == sorted((r, s, k) for r, s, k in table)
    rows = {(r["source"], r["steps"]): r for r in record["runs"]["ppo/seed_0"]["rows"]}
    assert rows["final", 310_000]["success_rate"] == pytest.approx(0.9)
    assert rows["checkpoint", 300_000]["iqm"] == pytest.approx(0.20)
    saved = json.loads((out / "VisualServoEyeToHand-v1_selection.json").read_text())
    assert (saved["seed"], saved["episodes"]) == (ev.VALIDATION_SEED, 10)
    assert saved["runs"] == json.loads(json.dumps(record["runs"]))
    md = (out / "VisualServoEyeToHand-v1_selection.md").read_text()
    assert "| **checkpoint** | 300000 | 10/10 | 0.200 |" in md


def test_select_with_algo_scores_only_those_runs_and_keeps_the_others(tmp_path):
    root, out = tmp_path / "runs", tmp_path / "out"
    _run(root, 0, (100_000,), finished=None)
    _run(root, 0, (100_000,), finished=None, algo="residual_ppo")
    scorer = FakeScorer({("seed_0", "checkpoint", 100_000): (10, 0.2)}, episodes=10)
    ev.select_env(ENV, root, out, episodes=10, score=scorer, algos=["ppo"])
    record = ev.select_env(ENV, root, out, episodes=10, score=scorer, algos=["residual_ppo"])
    assert len(scorer.calls) == 2  # one candidate per call: the ppo run is not scored again
    assert sorted(record["runs"]) == ["ppo/seed_0", "residual_ppo/seed_0"]
    md = (out / "VisualServoEyeToHand-v1_selection.md").read_text()
    assert f"select --env {ENV} --algo residual_ppo`" in md
    with pytest.raises(ValueError, match=r"--algo sac: no run .* agents there: ppo, residual_ppo"):
        ev.select_env(ENV, root, out, episodes=10, score=scorer, algos=["sac"])


def test_select_does_not_score_a_candidate_twice_but_scores_new_ones(tmp_path):
    root, out = tmp_path / "runs", tmp_path / "out"
    run = _run(root, 2, (100_000, 200_000), finished=None)
    table = {("seed_2", "checkpoint", 100_000): (10, 0.3),
             ("seed_2", "checkpoint", 200_000): (10, 0.4),
             ("seed_2", "checkpoint", 300_000): (10, 0.2)}
    ev.select_env(ENV, root, out, episodes=10, score=FakeScorer(table, 10))
    again = FakeScorer(table, 10)
    assert ev.select_env(ENV, root, out, episodes=10, score=again)["runs"]["ppo/seed_2"][
        "chosen"]["steps"] == 100_000
    assert again.calls == []
    (run / "checkpoints" / "model_300000_steps.zip").touch()  # training went on
    assert ev.candidates(run) == [("checkpoint", 100_000), ("checkpoint", 200_000)]  # no pkl yet
    (run / "checkpoints" / "model_vecnormalize_300000_steps.pkl").touch()
    newer = FakeScorer(table, 10)
    chosen = ev.select_env(ENV, root, out, episodes=10, score=newer)["runs"]["ppo/seed_2"]
    assert newer.calls == [("seed_2", "checkpoint", 300_000)]
    assert chosen["chosen"]["steps"] == 300_000
    other = FakeScorer(table, 12)  # another episode count: every candidate again
    ev.select_env(ENV, root, out, episodes=12, score=other)
    assert len(other.calls) == 3


def test_evaluate_scores_the_final_model_and_the_validation_choice_labelled(tmp_path):
    root = tmp_path / "runs"
    done = _run(root, 0, (100_000, 400_000), finished=1_002_064)
    chosen = {"source": "checkpoint", "steps": 400_000}
    assert ev.policies_of(done, chosen) == [
        ("ppo seed 0 @ 1.00 M steps", "final", "final", 1_002_064),
        ("ppo seed 0 @ 0.40 M steps (validation choice: checkpoint)", "validation",
         "checkpoint", 400_000)]
    training = _run(root, 2, (100_000, 300_000), finished=None)
    assert ev.policies_of(training, {"source": "checkpoint", "steps": 100_000}) == [
        ("ppo seed 2 @ 0.30 M steps (in training)", "final", "checkpoint", 300_000),
        ("ppo seed 2 @ 0.10 M steps (validation choice: checkpoint) (in training)",
         "validation", "checkpoint", 100_000)]
    assert ev.policies_of(_run(root, 3, (), finished=None), None) == []


def test_a_test_record_written_before_the_selection_names_its_model():
    final = {"run": "r", "steps": 1_002_064, "finished": True}
    last = {"run": "r", "steps": 300_000, "finished": False}
    assert ev.model_of(final) == ("r", "final", 1_002_064)
    assert ev.model_of(last) == ("r", "checkpoint", 300_000)
    assert ev.model_of({**last, "source": "final"}) == ("r", "final", 300_000)


def test_agent_of_rejects_an_unknown_source(tmp_path):
    with pytest.raises(ValueError, match="source must be"):
        ev.agent_of(tmp_path, tmp_path, "best", 1)
