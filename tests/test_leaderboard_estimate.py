"""The leaderboard's time estimate: a seed table's per-agent load is a fixed cost, so the
timings a run saves at one ``--episodes`` estimate a run at another."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cir_gym.scoring import leaderboard as lb

ENV, VARIANT = "cir_gym/CartesianTracking-v1", "exact model"


def test_seed_table_timing_separates_the_agents_load_from_the_episodes(tmp_path: Path) -> None:
    loads = lb._seed_count(ENV, {})
    if loads == 0:
        pytest.skip("no multi-seed agents shipped for CartesianTracking (no train extra)")
    per_episode, episodes = 0.4, 3
    spent = lb.SEED_LOAD_SECONDS * loads + per_episode * episodes
    lb._save_timings(tmp_path, {}, [], {}, {(ENV, VARIANT): spent}, {(ENV, VARIANT): loads},
                     episodes)
    timings = json.loads((tmp_path / lb.TIMINGS).read_text())
    assert timings["seed_table"][f"CartesianTracking-v1 {VARIANT}"] == pytest.approx(per_episode)
    # the same table at 30 episodes: the load once, the episodes ten times
    estimate = lb.seed_table_cost(ENV, VARIANT, {}, 30, timings)
    assert estimate == pytest.approx(lb.SEED_LOAD_SECONDS * loads + 30 * per_episode)
