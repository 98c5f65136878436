"""The main job (``bash scripts/run.sh`` → ``cir-gym leaderboard``) leaves the checkout as it
found it: by default it writes into ``runs/leaderboard/`` (untracked, gitignored), never into
the committed ``results/`` (regenerated on purpose with ``--out results/``).

Run through :func:`cir_gym.cli.main` in the repository, at a tiny budget: one environment
(VisualServoEyeToHand-v1: 2 policies × 2 variants), 1 episode, its videos and figures.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from cir_gym.cli import LEADERBOARD_OUT, main

ROOT = Path(__file__).resolve().parents[1]
#: the paths the job could write into if it went wrong: the committed results, the shipped
#: gains and agents (a clean checkout's ``git status`` is then equal before and after)
WATCHED = ("results", "cir_gym", "agents", "baselines", "runs", "sweeps", "docs")


def git_status() -> str:
    return subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=all", "--", *WATCHED],
        cwd=ROOT, capture_output=True, text=True, check=True,
    ).stdout


@pytest.fixture
def in_repository(monkeypatch, tmp_path):
    """cwd = the repository; an existing ``runs/leaderboard`` is moved aside and restored."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs the git checkout")
    out = ROOT / LEADERBOARD_OUT
    saved = tmp_path / "saved"
    if out.exists():
        shutil.move(out, saved)
    monkeypatch.chdir(ROOT)
    yield out
    shutil.rmtree(out, ignore_errors=True)
    if saved.exists():
        shutil.move(saved, out)


def test_the_main_job_leaves_the_checkout_clean_and_writes_its_folder(in_repository, capsys):
    out = in_repository
    before = git_status()
    assert main(["leaderboard", "--env", "VisualServoEyeToHand-v1", "--episodes", "1"]) == 0
    after = git_status()
    if not before:  # a clean checkout (CI): exactly as clean after
        assert after == ""
    # a shared working tree, where others edit sources meanwhile: nothing under results/,
    # runs/ or the shipped data changed or added
    changed = set(after.splitlines()) - set(before.splitlines())
    data = ("results/", "runs/", "cir_gym/scoring/tuned_gains/", "agents/trained/")
    assert not [c for c in changed if c[3:].startswith(data)], changed
    assert (out / "index.html").is_file() and (out / "leaderboard.md").is_file()
    assert len(list((out / "videos").glob("*.gif"))) == 2 and len(list(out.glob("*.png"))) == 2
    ignored = subprocess.run(["git", "check-ignore", "-q", str(out / "index.html")], cwd=ROOT)
    assert ignored.returncode == 0, "runs/leaderboard must be gitignored"
    captured = capsys.readouterr()
    assert captured.out == ""  # nothing dumped on stdout: progress and summary on stderr
    err = captured.err
    for phase in ("estimate with", "episodes:", "figures:", "videos:"):
        assert phase in err, phase
    assert "best per environment" in err and "ibvs_eye_to_hand" in err
    assert f"page: {(out / 'index.html').resolve()}" in err
    assert os.path.getsize(out / "timings.json") > 0
    # each variant's hold-still run anchors the normalized score: its anchors file, the score
    # in the summary and the tables
    assert len(json.loads((out / "normalized.json").read_text())["variants"]) == 2
    assert "score 1.00" in err and "| score |" in (out / "leaderboard.md").read_text()
