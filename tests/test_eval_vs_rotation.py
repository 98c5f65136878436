"""scripts/research/eval_vs_rotation.py: the bins of spin, the convergence region, the failure
causes, the twist angle, and one tiny run end to end."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cir_gym.envs.visual_servo_base import rotation
from scripts.research import eval_vs_rotation as ev


def _episodes(spins_and_outcomes: list[tuple[float, bool]]) -> list[ev.Episode]:
    return [ev.Episode(seed=i, spin=spin, twist=spin, success=ok, final_error=0.1 if ok else 50.0,
                       cause=None if ok else "joint limit", length=10)
            for i, (spin, ok) in enumerate(spins_and_outcomes)]


def _bin_of(n_ok: int, n_fail: int, spin: float) -> list[tuple[float, bool]]:
    return [(spin, True)] * n_ok + [(spin, False)] * n_fail


def test_bins_cover_0_to_180_once() -> None:
    spin = np.array([0.0, 14.999, 15.0, 44.9, 45.0, 179.9, 180.0])
    found = ev.bins(spin, 15.0)
    assert len(found) == 12
    counts = np.sum([mask for _, _, mask in found], axis=0)
    assert np.all(counts == 1)  # every spin in exactly one bin, 180° in the last
    assert found[0][2].tolist() == [True, True, False, False, False, False, False]
    assert found[-1][2].tolist() == [False] * 5 + [True, True]
    with pytest.raises(ValueError, match="does not divide"):
        ev.bins(spin, 50.0)


def test_convergence_region_ends_before_the_first_bin_under_95_percent() -> None:
    # 0–15°: 20/20, 15–30°: 19/20 (95 %: inside), 30–45°: 18/20 (90 %: outside),
    # 45–60°: 20/20 again — the region stops at the first failing bin: 30°
    data = (_bin_of(20, 0, 5.0) + _bin_of(19, 1, 20.0) + _bin_of(18, 2, 40.0)
            + _bin_of(20, 0, 50.0))
    data += [(s, True) for s in np.arange(60.0, 180.0, 5.0)]
    assert ev.convergence_region(_episodes(data)) == 30.0


def test_convergence_region_edges() -> None:
    everywhere = [(s, True) for s in np.arange(1.0, 180.0, 2.0)]
    assert ev.convergence_region(_episodes(everywhere)) == 180.0
    first_fails = [(s, s > 10.0) for s in np.arange(1.0, 180.0, 2.0)]
    assert ev.convergence_region(_episodes(first_fails)) == 0.0
    gap = [(s, True) for s in np.arange(1.0, 180.0, 2.0) if not 90.0 <= s < 105.0]
    assert ev.convergence_region(_episodes(gap)) == 90.0  # an empty bin ends the region


def test_bin_rows_counts_wilson_median_and_causes() -> None:
    eps = _episodes(_bin_of(3, 1, 10.0) + _bin_of(0, 2, 100.0))
    eps[-1].cause = "feature lost"
    rows = ev.bin_rows(eps, 45.0)
    assert [r["n"] for r in rows] == [4, 0, 2, 0]
    assert rows[0]["successes"] == 3 and rows[0]["rate"] == 0.75
    assert rows[0]["wilson"][0] < 0.75 < rows[0]["wilson"][1]
    assert rows[0]["median_final_error"] == pytest.approx(0.1)
    assert rows[2]["causes"] == {"diverged": 0, "feature lost": 1, "joint limit": 1,
                                 "not converged": 0}
    assert rows[1]["rate"] is None and rows[1]["median_final_error"] is None


def test_failure_cause_order() -> None:
    assert ev.failure_cause({"is_success": True}) is None
    assert ev.failure_cause({"feature_lost": True, "joint_limit": True}) == "feature lost"
    assert ev.failure_cause({"joint_limit": True}) == "joint limit"
    assert ev.failure_cause({"diverged": True, "feature_lost": True}) == "diverged"
    assert ev.failure_cause({"is_success": False}) == "not converged"


@pytest.mark.parametrize("r", [(0.0, 0.0, 2.0), (0.3, -0.2, 3.1), (-0.3, 0.3, -1.0),
                               (0.1, 0.2, 0.5), (0.3, 0.3, 3.14)])
def test_twist_angle_is_the_angle_about_z_of_the_swing_twist_split(r: tuple) -> None:
    R = rotation(np.array(r))
    psi = ev.twist_angle(np.array(r))
    # R = R_swing R_z(ψ) with R_swing leaving no rotation about z: R_z(−ψ) applied on the right
    # leaves a swing whose rotation axis is perpendicular to z; try both signs of ψ
    swings = [R @ rotation(np.array([0.0, 0.0, -s * psi])) for s in (1.0, -1.0)]
    axis_z = [abs(sw[0, 1] - sw[1, 0]) for sw in swings]  # 2 sin(angle) n_z of the swing
    assert min(axis_z) < 1e-12
    if r[:2] == (0.0, 0.0):
        assert psi == pytest.approx(abs(r[2]))


def test_tiny_run_end_to_end(tmp_path) -> None:
    record = ev.main(["--episodes", "2", "--policy", "pbvs", "--policy", "ibvs",
                      "--out", str(tmp_path)])
    saved = json.loads((tmp_path / "VisualServo-v1.json").read_text())
    assert saved["env_kwargs"]["start_rotation"] == [0.3, pytest.approx(math.pi)]
    for name in ("pbvs", "ibvs"):
        eps = record["policies"][name]["episodes"]
        assert [e["seed"] for e in eps] == [7000, 7001]
        assert all(0.0 <= e["spin"] <= 180.0 for e in eps)
        assert all((e["cause"] is None) == e["success"] for e in eps)
    # both policies met the same starts
    assert ([e["spin"] for e in record["policies"]["pbvs"]["episodes"]]
            == [e["spin"] for e in record["policies"]["ibvs"]["episodes"]])
    assert (tmp_path / "VisualServo-v1.md").read_text().count("| pbvs |") == 4
    assert (tmp_path / "VisualServo-v1.png").stat().st_size > 0
