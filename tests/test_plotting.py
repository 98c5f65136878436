"""cir_gym.scoring.plotting: the episode plot of every env, the leaderboard bars, the sweep lines.

The episode plots run each env's first course controller for a short episode
(``evaluate(record=True)``) and check the figure is written with the task's own panels (their
titles); the bar chart and sweep tests check what is drawn (order, colours, styles, units) on
hand-made results.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import cir_gym
from cir_gym.evaluation import EpisodeResult, EvaluationResult, evaluate
from cir_gym.scoring.plotting import (
    FAMILY_COLOURS,
    argument_unit,
    comparison_bars,
    episode_panels,
    line_styles,
    plot_comparison,
    plot_episode,
    plot_sweep_axis,
)

#: env name → (short-episode kwargs, titles its plot must have besides the actions)
EXPECTED: dict[str, tuple[dict, set[str]]] = {
    "JointTracking": (
        {"episode_duration": 0.1},
        {"q: actual (thin) vs reference (wide, light)", "joint error ‖q̄ − q‖"},
    ),
    "ElasticJointTracking": (
        {"episode_duration": 0.1},
        {"q: actual (thin) vs reference (wide, light)", "joint error ‖q̄ − q‖"},
    ),
    "RedundantIK": ({"episode_duration": 1.0}, {"position (path) error ‖x̄ − x‖",
                                                "path in the plane"}),
    "RedundantIK7": (
        {"episode_duration": 1.0},
        {"position (path) error ‖x̄ − x‖", "orientation error angle",
         "path seen from above (x–y)"},
    ),
    "CartesianTracking": (
        {"episode_duration": 0.1},
        {"position (path) error ‖x̄ − x‖", "orientation error angle"},
    ),
    "VisualServo": (
        {"episode_duration": 0.4},
        {"feature error (RMS point distance, observed features)",
         "feature trajectories in the image plane"},
    ),
    "VisualServoEyeToHand": (
        {"episode_duration": 0.4},
        {"feature error (RMS point distance, observed features)",
         "feature trajectories in the image plane"},
    ),
    "AdmittanceContact": (
        {"episode_duration": 0.1, "force_ref": 10.0},
        {"normal force vs its reference", "tool tip height (world z) vs reference",
         "path error in the surface plane ‖(p̄ − p)_xy‖"},
    ),
    "PegInHole": (
        {"episode_duration": 0.1},
        {"insertion depth below the nominal hole's top",
         "lateral path of the tip (spiral search), nominal hole frame"},
    ),
}
EXPECTED["PegInHoleImpedance"] = EXPECTED["PegInHole"]  # the same observations
EXPECTED["AdmittanceContactImpedance"] = EXPECTED["AdmittanceContact"]


class HoldStill:
    """The zero action (an env without a course controller: the agent-ready variants)."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.shape = shape

    def predict(
        self, obs: dict, state: object = None, episode_start: object = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        return np.zeros(self.shape), None


def _name(env_id: str) -> str:
    return env_id.split("/")[-1].rsplit("-v", 1)[0]


@pytest.mark.parametrize("env_id", sorted(cir_gym.ENVIRONMENTS))
def test_episode_plot_shows_the_task_quantities(env_id: str, tmp_path: Path) -> None:
    from cir_gym import baselines
    from cir_gym.scoring.policies import make_policy

    kwargs, titles = EXPECTED.get(_name(env_id), ({"episode_duration": 0.2}, set()))
    controllers = baselines.available(env_id)
    if controllers:
        policy = make_policy(env_id, controllers[0], kwargs, {})
    else:
        import gymnasium as gym

        env = gym.make(env_id)
        policy = HoldStill(env.action_space.shape)
        env.close()
    result = evaluate(policy, env_id, 1, 0, record=True, policy_name="policy", **kwargs)
    panels = episode_panels(result.episodes[0].trace)
    got = [p.title for p in panels]
    assert titles <= set(got), got
    assert got[-1] == "actions (normalised commands)"
    assert len(got) == len(set(got))  # nothing drawn twice
    if _name(env_id) == "PegInHole":
        assert any(t.startswith("contact force") for t in got)
        assert not any(t.startswith("peg_pos") for t in got)
    path = plot_episode(result, tmp_path / "episode.png")
    from PIL import Image

    with Image.open(path) as image:
        assert image.size[0] > 800 and image.size[1] > 300


def test_peg_in_hole_panels_read_depth_and_tared_force_from_the_observations() -> None:
    """Depth is −z of the tip in the nominal hole frame (mm); the force is the F/T reading
    minus its first (free-space) sample."""
    from cir_gym.scoring import plotting

    steps = 5
    peg = np.zeros((steps, 3))
    peg[:, 2] = np.linspace(0.01, -0.02, steps)  # 10 mm above to 20 mm deep
    wrench = np.zeros((steps, 6))
    wrench[:, 2] = [7.0, 7.0, 7.0, 12.0, 27.0]  # a 7 N weight, then pressing
    trace = {"obs/peg_pos": peg, "obs/wrench": wrench, "action": np.zeros((steps, 7))}
    panels, claimed = plotting.peg_in_hole_panels(trace)
    assert {"obs/peg_pos", "obs/wrench"} <= claimed
    plt = plotting._plt()
    fig, axes = plt.subplots(2)
    t = np.arange(steps) * 0.002
    panels[1].draw(axes[0], t)
    np.testing.assert_allclose(axes[0].lines[0].get_ydata(), -1e3 * peg[:, 2])
    panels[0].draw(axes[1], t)
    np.testing.assert_allclose(axes[1].lines[2].get_ydata(), [0, 0, 0, 5, 20])  # raw F_z
    plt.close(fig)


def _result(name: str, success: float, mean: float, worst: float) -> EvaluationResult:
    from cir_gym.metrics import MetricSpec

    spec = MetricSpec("rms_error", "rad", "lower", "")
    n = 4
    ok = round(success * n)
    values = [mean] * (n - 1) + [worst]
    values[0] = 4 * mean - sum(values[1:])  # the mean is `mean`, the worst `worst`
    episodes = [EpisodeResult(i, 0.0, 1, i < ok, False, {"rms_error": v})
                for i, v in enumerate(values)]
    return EvaluationResult("cir_gym/JointTracking-v2", name, episodes, (spec,), "rms_error")


def test_bars_follow_the_leaderboard_rank_and_colour_the_families(tmp_path: Path) -> None:
    rows = [
        _result("agent:ppo", 1.0, 1e-4, 2e-4),
        _result("pd_gravity", 0.5, 1e-5, 2e-5),  # smallest error, half the successes
        _result("tuned:pid", 1.0, 1e-2, 1.5e-2),
        _result("computed_torque", 1.0, 1e-3, 1.2e-3),
    ]
    names, means, worst, colours = comparison_bars(rows)
    assert names == ["agent:ppo", "computed_torque", "tuned:pid", "pd_gravity"]
    np.testing.assert_allclose(means, [1e-4, 1e-3, 1e-2, 1e-5])
    assert worst[0] == pytest.approx(2e-4)
    assert colours == [FAMILY_COLOURS["RL agent"], FAMILY_COLOURS["controller, course gains"],
                       FAMILY_COLOURS["controller, tuned gains"],
                       FAMILY_COLOURS["controller, course gains"]]
    assert plot_comparison(rows, tmp_path / "bars.png").is_file()


def test_thirteen_sweep_lines_are_told_apart(tmp_path: Path) -> None:
    """13 policies (a 10-colour cycle): each line has its own (colour, marker) pair, tuned
    and agent lines their own styles; the x axis carries the argument's unit."""
    labels = [f"law_{i}" for i in range(10)] + ["tuned:law_0", "tuned:law_1", "agent:ppo"]
    styles = line_styles(labels)
    assert len({(c, m) for c, m, _ in styles.values()}) == 13
    assert styles["tuned:law_0"][2] != styles["law_0"][2] != styles["agent:ppo"][2]
    rows = [
        {"policy": p, "env.payload_mass": m, "metric.rms_error": 1e-3 * (1 + i) * (1 + m)}
        for i, p in enumerate(labels)
        for m in (0.0, 1.5, 3.0)
    ]
    path = plot_sweep_axis(rows, "cir_gym/JointTracking-v2", "env.payload_mass",
                           tmp_path / "sweep.png")
    assert path.is_file()


def test_argument_units_come_from_the_env_docstrings() -> None:
    env = {_name(e): cls for e, (cls, _) in cir_gym.ENVIRONMENTS.items()}
    assert argument_unit(env["JointTracking"], "payload_mass") == "kg"
    assert argument_unit(env["JointTracking"], "viscous_friction") == "N m s/rad"
    assert argument_unit(env["JointTracking"], "episode_duration") == "s"
    assert argument_unit(env["AdmittanceContact"], "stiffness") == "N/m"
    assert argument_unit(env["PegInHole"], "clearance") == "m"
    assert argument_unit(env["PegInHole"], "tilt_uncertainty") == "°"
    assert argument_unit(env["JointTracking"], "mass_scale") == ""  # a ratio
    assert argument_unit(env["JointTracking"], "no_such_argument") == ""
