"""The chapter-6 law reports of scripts/research: eval_contact.py's largest single contact
force (table column and figure) and eval_peg_in_hole.py's laws table with and without the
force loop, built from stored per-episode numbers (no episode is run)."""

from __future__ import annotations

import json

import pytest


def _contact_cell(max_force: list[float], stops: list[bool]) -> dict:
    n = len(max_force)
    return {
        "seeds": list(range(5000, 5000 + n)),
        "force_rms_error": [0.5 + 0.1 * i for i in range(n)],
        "contact_loss": [0.0] * n,
        "max_force": max_force,
        "peak_overshoot": [0.0] * n,
        "success": [not s for s in stops],
        "force_limit_stop": stops,
        "diverged": [False] * n,
        "seconds": 1.0,
    }


def test_contact_tables_and_figure_show_the_largest_single_contact_force(tmp_path):
    """--render-only: every table row carries the mean (max) of the episodes' max_force and
    the force-limit stops, and contact_forces.png is written from results.json alone."""
    from scripts.research.eval_contact import COLUMNS, main

    results = {
        "admittance @ k = 1e3 N/m": _contact_cell([10.0, 30.0, 20.0], [False] * 3),
        "impedance @ randomize": _contact_cell([40.0, 130.0, 70.0], [False, True, False]),
    }
    (tmp_path / "results.json").write_text(json.dumps(results))
    main(["--render-only", "--out", str(tmp_path), "--episodes", "3"])
    readme = (tmp_path / "README.md").read_text()
    assert "| " + " | ".join(COLUMNS) + " |" in readme
    rows = {line.split(" | ")[0] + " | " + line.split(" | ")[1]: line.split(" | ")
            for line in readme.splitlines() if line.startswith("| ") and " @ " not in line}
    admittance = rows["| admittance | k = 1e3 N/m"]
    assert admittance[-1] == "20.0 (30.0) |"
    assert admittance[COLUMNS.index("force-limit stops")] == "0/3"
    impedance = rows["| impedance | randomize"]
    assert impedance[-1] == "80.0 (130.0) |"
    assert impedance[COLUMNS.index("force-limit stops")] == "1/3"
    assert "not run yet" in rows["| explicit_force | k = 1e3 N/m"][2]
    figure = tmp_path / "contact_forces.png"
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _peg_row(label: str, controller: str, gains: dict, env_id: str, first: int,
             success: list[bool], peak: list[float], jammed: list[float]) -> dict:
    n = len(success)
    return {
        "label": label,
        "controller": controller,
        "gains": gains,
        "env_id": env_id,
        "seeds": list(range(first, first + n)),
        "wall_time_s": 10.0,
        "cpu_time_s": 8.0,
        "insertion_time": [5.0 if ok else 12.0 for ok in success],
        "peak_force": peak,
        "peak_net_force": [p / 2 for p in peak],
        "jammed_time": jammed,
        "success": success,
        "force_limit": [p > 100.0 for p in peak],
    }


def test_peg_laws_table_compares_each_hybrid_law_with_its_force_loop_off():
    """laws.md joins a law's seed chunks of the current env only (a row measured on an
    earlier version is left out, and the title names the version that ran), and its force-loop
    table counts, on the same seeds, the insertions with and without the loop, the seeds only
    one of them inserted, the paired difference of the largest single contact, the stops and
    the jammed episodes."""
    from scripts.research.eval_peg_in_hole import ENV_ID, join_runs, laws_markdown

    old = "cir_gym/PegInHole-v1"
    loop, none = {}, {"crossover_ratio": 0.0}
    runs = [
        _peg_row("hybrid_spiral", "hybrid_spiral", loop, old, 3000, [True] * 2, [1.0] * 2,
                 [0.0] * 2),
        _peg_row("hybrid_spiral", "hybrid_spiral", loop, ENV_ID, 3002, [False, True],
                 [120.0, 60.0], [0.0, 0.0]),
        _peg_row("hybrid_spiral", "hybrid_spiral", loop, ENV_ID, 3000, [True, False],
                 [40.0, 110.0], [0.2, 0.0]),
        _peg_row("hybrid_spiral, no force loop", "hybrid_spiral", none, ENV_ID, 3000,
                 [True, True, True, False], [30.0, 50.0, 80.0, 40.0], [0.0] * 4),
    ]
    rows = join_runs(runs)
    assert [r["label"] for r in rows] == ["hybrid_spiral", "hybrid_spiral, no force loop"]
    assert rows[0]["seeds"] == [3000, 3001, 3002, 3003]
    assert rows[0]["success"] == [True, False, False, True]
    assert rows[0]["cpu_time_s"] == pytest.approx(16.0)
    text = laws_markdown(rows)
    assert text.startswith("# PegInHole-v2:")
    assert "PegInHole-v1" not in text
    loop_row = next(line for line in text.splitlines() if line.startswith("| hybrid_spiral |")
                    and "/4 /" in line)
    cells = [c.strip() for c in loop_row.strip("|").split("|")]
    # with: seeds 3000, 3003 inserted; without: 3000-3002; peaks (40, 110, 120, 60) against
    # (30, 50, 80, 40): differences 10, 60, 40, 20, mean 32.5
    assert cells[1:3] == ["2/4 / 3/4", "1 / 2"]
    assert cells[3].startswith("32.5 [")
    assert cells[4:] == ["2 / 0", "1 / 0"]
