"""scripts/leaderboard_page.py: the static results page, its GIFs, and the page in Chromium.

The browser tests load ``index.html`` from disk in Debian's headless Chromium and check: no
console message, every image loaded (the page's own check writes ``data-broken``), and a
screenshot in which the tables are drawn. The fast one (default run) writes the page from two
controllers' short episodes; the slow one (``-m slow``) runs ``run_leaderboard`` on one
environment, every policy. ``bash scripts/test.sh`` installs ``chromium`` when it is missing
(CI does so); run directly without it, pytest skips them with that message, except under CI
(``CI=true``), where a missing browser fails.
"""

from __future__ import annotations

import html
import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from cir_gym.scoring.page import (
    glossary_html,
    label_lines,
    labelled,
    markdown_to_html,
    ranked_html,
    save_gif,
    side_by_side,
    with_units,
)

CHROMIUM = "/usr/bin/chromium"
#: flags from the machine notes: no sandbox as root, no GPU, no background network traffic
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",  # containers often give /dev/shm only 64 MB
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def test_markdown_tables_and_inline_marks_become_html() -> None:
    md = (
        "Intro with `code` and **bold** & <tag>.\n\n| rank | policy |\n|---|---|\n"
        "| 1 | *pid* |\n| 2 | pd |\n"
    )
    out = markdown_to_html(md, "summary")
    assert "<code>code</code>" in out and "<strong>bold</strong>" in out
    assert "&amp; &lt;tag&gt;" in out
    assert '<table class="summary">' in out
    assert out.count("<tr>") == 3 and "<th>rank</th>" in out and "<td><em>pid</em></td>" in out


def test_the_summary_footnote_of_a_left_out_factor_is_a_paragraph_under_its_table() -> None:
    """rl_summary's "–†" cells and their footnote (a censored insertion time) on the page."""
    from cir_gym.envs.peg_in_hole import PegInHoleEnv
    from cir_gym.evaluation import EpisodeResult, EvaluationResult
    from cir_gym.scoring.tables import rl_summary

    def result(name: str, success: bool, seconds: float) -> EvaluationResult:
        episodes = [EpisodeResult(0, 0.0, 1, success, False, {"insertion_time": seconds})]
        specs = PegInHoleEnv.metric_specs
        return EvaluationResult("cir_gym/PegInHole-v2", name, episodes, specs, "insertion_time")

    rows = [result("hybrid_spiral", True, 7.8), result("agent:ppo_position", False, 12.0)]
    out = markdown_to_html(rl_summary({"sharp edge": rows}), "summary")
    table, after = out.split("</table>", 1)
    assert "0 % (0–79) success), –†</td>" in table  # the Wilson interval of 0 of 1
    assert re.search(r"<p>† No factor to the best controller: .*<code>insertion_time</code>", after)


def test_gif_round_trip_keeps_the_frames_and_stays_small(tmp_path: Path) -> None:
    from PIL import Image, ImageSequence

    rng = np.random.default_rng(0)
    colours = rng.integers(0, 255, (20, 3), dtype=np.uint8)
    y, x = np.mgrid[0:160, 0:160]  # a smooth shading: more colours than a GIF palette holds
    background = np.stack((x * 1.5, y * 1.5, (x + y) * 0.6), axis=2).astype(np.uint8)
    frames = []
    for k in range(20):  # a red square moving over a fixed background, a changing "caption"
        f = background.copy()
        f[40:56, 4 * k : 4 * k + 16] = (230, 20, 20)
        f[0:4, 0:8] = colours[k]
        frames.append(f)
    path = save_gif(frames, tmp_path / "clip.gif", fps=10)
    decoded = [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(Image.open(path))]
    assert len(decoded) == len(frames)
    for k, (a, b) in enumerate(zip(decoded, frames, strict=True)):
        assert np.abs(a.astype(int) - b).mean() < 6.0
        assert a[44, 4 * k + 8, 0] > 180 and a[44, 4 * k + 8, 1] < 60  # the square is red
    # one palette, unchanged pixels transparent: smaller than plotting.save_video's GIF
    from cir_gym.scoring.plotting import save_video

    plain = save_video(frames, tmp_path / "plain.gif", fps=10)
    assert path.stat().st_size < 0.5 * plain.stat().st_size


def test_labelled_side_by_side_frames() -> None:
    a = [np.zeros((50, 40, 3), np.uint8)] * 3
    b = [np.full((50, 40, 3), 100, np.uint8)] * 5
    left, right = labelled(a, "pid"), labelled(b, "agent:ppo")
    assert right[0].shape[0] > left[0].shape[0] > 50  # "agent:ppo" wraps after its ":"
    pair = side_by_side(left, right)
    assert len(pair) == 5 and pair[0].shape == (right[0].shape[0], 84, 3)
    assert np.any(pair[0][50:, :40] > 200)  # the label's ink in the strip
    np.testing.assert_array_equal(pair[4][:50, :40], a[-1])  # the shorter clip holds


def test_a_label_keeps_the_whole_policy_name() -> None:
    """A long agent name wraps at ``:`` and ``_`` over lines of the strip, never cut off."""
    from cir_gym import rendering

    name = "agent:residual_ppo_hybrid_force_position"
    lines = label_lines(name, 180, 1)
    assert "".join(lines) == name and len(lines) == 2
    assert all(len(line) * 6 <= 180 for line in lines)
    assert label_lines("pid", 180, 2) == ["pid"]
    frame = labelled([np.zeros((180, 180, 3), np.uint8)], name)[0]
    strip = frame[180:] > 200
    ink = sum(rendering.text_mask(line, 1).sum() for line in lines)
    assert strip.all(axis=2).sum() == ink  # every glyph of both lines is drawn


def test_the_ranked_table_has_units_on_every_metric_and_family_rows() -> None:
    from cir_gym.envs.peg_in_hole import PegInHoleEnv
    from cir_gym.evaluation import EpisodeResult, EvaluationResult

    specs = PegInHoleEnv.metric_specs

    def result(name: str, success: bool, seconds: float) -> EvaluationResult:
        metrics = {s.name: 1.0 for s in specs} | {"insertion_time": seconds}
        episodes = [EpisodeResult(0, -1.0, 1, success, False, metrics)]
        return EvaluationResult("cir_gym/PegInHole-v2", name, episodes, specs, "insertion_time")

    rows = [result("agent:ppo", False, 3.0), result("tuned:hybrid_spiral", True, 5.0),
            result("hybrid_spiral", True, 4.0)]
    out = ranked_html(rows)
    cells = re.findall(r'<td class="policy \w+">(.*?)</td>', out)
    order = [c.replace("<wbr>", "") for c in cells]
    assert order == ["hybrid_spiral", "tuned:hybrid_spiral", "agent:ppo"]  # success first
    assert '"policy course"' in out and '"policy tuned"' in out and '"policy agent"' in out
    head = re.sub(r"<wbr>|</?strong>", "", out.split("</thead>")[0])
    for s in specs:
        if s.unit:
            assert f"{s.name} ({s.unit.replace(' ', '&nbsp;')})" in head, s.name
    assert "worst (s)" in head and "CVaR&nbsp;20&nbsp;% (s)" in head


def test_the_ranked_tables_quote_the_mean_and_the_success_rate_with_95_intervals() -> None:
    """26 of 30 episodes inserted (6.5–7.75 s), 4 at the 12 s limit: the markdown and the HTML
    table show the mean with its bootstrap interval and 87 % (70–95), the Wilson interval of
    26/30, under headers that name the intervals; the old "mean ± std" is gone."""
    from cir_gym.envs.peg_in_hole import PegInHoleEnv
    from cir_gym.evaluation import EpisodeResult, EvaluationResult
    from cir_gym.metrics import mean_interval
    from cir_gym.scoring.tables import interval_cell, ranked_table

    times = [6.5 + 0.05 * i if i < 26 else 12.0 for i in range(30)]
    episodes = [EpisodeResult(i, 0.0, 1, i < 26, False, {"insertion_time": t})
                for i, t in enumerate(times)]
    r = EvaluationResult("cir_gym/PegInHole-v2", "position_spiral", episodes,
                         PegInHoleEnv.metric_specs, "insertion_time")
    low, high = mean_interval(np.array(times))
    mean = interval_cell(float(np.mean(times)), low, high)
    assert re.fullmatch(r"7\.7\d \[7\.\d\d, 8\.\d\d\]", mean), mean

    head, _, row = ranked_table([r]).splitlines()
    assert "| insertion_time (s) mean [95 % CI] |" in head and "| success (95 % Wilson) |" in head
    assert f"| {mean} |" in row and "| 87 % (70–95) |" in row and "±" not in head + row
    page = ranked_html([r])
    assert "percentile bootstrap of the mean over the episodes&#x27; seeds" in page
    assert "95 % Wilson interval, in %" in page
    assert f"<td>{mean}</td>" in page and "<td>87 % (70–95)</td>" in page and "±" not in page


def test_the_interval_of_the_mean_is_shown_from_ten_episodes() -> None:
    """3 episodes (a bootstrap covering ~74 %): the mean alone; 30 episodes: mean [low, high]
    as interval_cell writes it from the summary; the header's meaning and the page's glossary
    say where the interval starts."""
    from cir_gym.envs.peg_in_hole import PegInHoleEnv
    from cir_gym.evaluation import EpisodeResult, EvaluationResult
    from cir_gym.scoring.page import GLOSSARY
    from cir_gym.scoring.tables import (
        MEAN_MEANING,
        MIN_INTERVAL_EPISODES,
        interval_cell,
        mean_cell,
        ranked_table,
    )

    def result(n: int) -> EvaluationResult:
        episodes = [EpisodeResult(i, 0.0, 1, True, False, {"insertion_time": 6.5 + 0.1 * i})
                    for i in range(n)]
        return EvaluationResult("cir_gym/PegInHole-v2", "position_spiral", episodes,
                                PegInHoleEnv.metric_specs, "insertion_time")

    few, many = result(3), result(30)
    assert np.isfinite(few.summary["insertion_time"]["ci_low"])  # computed, not shown
    assert mean_cell(few, "insertion_time") == "6.6"
    assert "| 6.6 |" in ranked_table([few]).splitlines()[2]
    s = many.summary["insertion_time"]
    shown = interval_cell(s["mean"], s["ci_low"], s["ci_high"])
    assert re.fullmatch(r"7\.95 \[7\.\d\d, 8\.\d\d\]", shown), shown
    assert mean_cell(many, "insertion_time") == shown
    assert mean_cell(result(MIN_INTERVAL_EPISODES), "insertion_time").endswith("]")
    assert mean_cell(result(MIN_INTERVAL_EPISODES - 1), "insertion_time").count("[") == 0
    assert f"below {MIN_INTERVAL_EPISODES} episodes the mean alone" in MEAN_MEANING
    glossary = dict(GLOSSARY)["mean [95 % CI]"]
    assert f"Below {MIN_INTERVAL_EPISODES} episodes the table shows the mean alone" in glossary


def test_a_mean_and_its_interval_share_one_precision() -> None:
    from cir_gym.scoring.tables import interval_cell

    assert interval_cell(6.98, 6.41, 7.6) == "6.98 [6.41, 7.60]"
    assert interval_cell(9.9, 9.5, 10.3) == "9.9 [9.5, 10.3]"  # 3 digits of the largest
    assert interval_cell(0.0123, 0.0101, 0.0148) == "0.0123 [0.0101, 0.0148]"
    assert interval_cell(2.5e-6, 1e-6, 4e-6) == "2.5e-06 [1e-06, 4e-06]"
    assert interval_cell(7.123, float("nan"), float("nan")) == "7.12"  # one episode: no CI


def test_markdown_tables_get_the_metric_units() -> None:
    from cir_gym.envs.peg_in_hole import PegInHoleEnv

    md = "| variant | ranked on | IQM insertion_time |\n|---|---|---|\n| a | `insertion_time` | 3 |"
    out = with_units(md, PegInHoleEnv.metric_specs)
    assert "| IQM insertion_time (s) |" in out and "| `insertion_time` (s) |" in out


def test_the_glossary_explains_the_rl_terms() -> None:
    text = glossary_html()
    for term in ("return", "success", "CVaR 20 %", "IQM", "bootstrap CI", "tuned:",
                 "mean [95 % CI]", "success (95 % Wilson)"):
        assert f"<th>{html.escape(term)}" in text, term


def _chromium(*args: str, user_dir: Path) -> subprocess.CompletedProcess:
    """Run headless Chromium once with a fresh profile in ``user_dir``."""
    return subprocess.run(
        [CHROMIUM, *FLAGS, f"--user-data-dir={user_dir}", *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def _need_chromium() -> None:
    if Path(CHROMIUM).exists():
        return
    message = (
        f"Debian's chromium is not installed ({CHROMIUM}): `apt-get install chromium`, or run "
        "`bash scripts/test.sh`, which installs it"
    )
    if os.environ.get("CI", "").lower() == "true":  # CI installs it: missing is a failure
        pytest.fail(message)
    pytest.skip(message)


def _check_in_chromium(index: Path, tmp_path: Path, min_images: int) -> None:
    """``index`` loads without console messages, its >= ``min_images`` images all load, and
    a screenshot shows its tables."""
    dom = _chromium(
        "--enable-logging=stderr",
        "--v=0",
        "--virtual-time-budget=10000",
        "--dump-dom",
        index.as_uri(),
        user_dir=tmp_path / "profile_dom",
    )
    assert dom.returncode == 0, dom.stderr[-2000:]
    console = [line for line in dom.stderr.splitlines() if ":CONSOLE" in line]
    assert not console, console
    html_tag = re.search(r"<html[^>]*>", dom.stdout).group(0)
    images = int(re.search(r'data-images="(\d+)"', html_tag).group(1))
    assert images >= min_images, html_tag
    assert 'data-broken="0"' in html_tag, html_tag

    shot = tmp_path / "shot.png"
    done = _chromium(
        "--window-size=1280,2400",
        f"--screenshot={shot}",
        index.as_uri(),
        user_dir=tmp_path / "profile_shot",
    )
    assert done.returncode == 0 and shot.is_file(), done.stderr[-2000:]
    from PIL import Image

    pixels = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    border = np.all(pixels == (200, 204, 212), axis=2)  # the tables' cell borders (#c8ccd4)
    header = np.all(pixels == (236, 238, 242), axis=2)  # their header cells (#eceef2)
    assert border.sum() > 2000 and header.sum() > 2000
    assert border.any(axis=1).sum() > 20  # many horizontal rules: table rows on screen


def test_page_of_two_controllers_loads_in_chromium(tmp_path: Path) -> None:
    """The page written from short episodes of two controllers (every variant, GIFs and
    figures as run_leaderboard writes them) in the real browser: a few seconds."""
    _need_chromium()
    import cir_gym
    from cir_gym.scoring.leaderboard import jobs_for, run_job
    from cir_gym.scoring.page import write_page
    from cir_gym.scoring.plotting import plot_comparison
    from cir_gym.scoring.tables import slug

    env_id = "cir_gym/JointTracking-v2"
    overrides = {"episode_duration": 0.2}
    jobs = [j for j in jobs_for(env_id, overrides) if j[3] in ("pd_gravity", "computed_torque")]
    results = {key: result for key, result, _ in (run_job(j, 1, 1000) for j in jobs)}
    out = tmp_path / "results"
    out.mkdir()
    variants = cir_gym.ENVIRONMENTS[env_id][0].leaderboard_variants
    for variant in variants:
        rows = [r for (_, v, _), r in sorted(results.items()) if v == variant]
        plot_comparison(rows, out / f"JointTracking-v2_{slug(variant)}.png", title=variant)
    index = write_page(out, results, [env_id], 1, 1000, overrides, workers=1)
    gifs = sorted((out / "videos").glob("*.gif"))
    assert len(gifs) == len(variants)
    assert "http://" not in index.read_text() and "https://" not in index.read_text()
    _check_in_chromium(index, tmp_path, min_images=2 * len(variants))


@pytest.mark.slow
def test_page_loads_in_chromium_with_every_image_and_the_tables(tmp_path: Path) -> None:
    _need_chromium()
    import cir_gym
    from cir_gym.scoring.leaderboard import run_leaderboard

    env_id = "cir_gym/JointTracking-v2"
    variants = len(cir_gym.ENVIRONMENTS[env_id][0].leaderboard_variants)
    out = tmp_path / "results"
    run_leaderboard(
        out, episodes=1, envs=[env_id], workers=2, env_overrides={"episode_duration": 0.6}
    )
    index = out / "index.html"
    text = index.read_text()
    gifs = sorted((out / "videos").glob("*.gif"))
    assert len(gifs) == variants and all(g.stat().st_size < 1_000_000 for g in gifs)
    assert "http://" not in text and "https://" not in text  # nothing fetched at view time
    # a video and a figure per variant, a learning curve
    _check_in_chromium(index, tmp_path, min_images=2 * variants + 1)


def test_markdown_images_and_headings_become_html() -> None:
    out = markdown_to_html("# Title\n\ntext\n![a plot](x_y.png)\n## Env\n![not an image")
    assert "<h1>Title</h1>" in out and "<h2>Env</h2>" in out and "<p>text</p>" in out
    assert '<img class="figure" src="x_y.png" alt="a plot">' in out
    assert "<p>![not an image</p>" in out


def test_leaderboard_from_a_sweep_ranks_its_episodes_as_the_evaluator_scores_them(
    tmp_path: Path,
) -> None:
    """Tasks run in this process (no pool) into a sweep table, one failed task beside them;
    ``leaderboard_from`` ranks the episodes into the evaluator's own summaries (nothing is
    re-run), draws a figure per variant and one against the swept payload, lists the failure."""
    import cir_gym
    from cir_gym.evaluation import evaluate
    from cir_gym.scoring.leaderboard import leaderboard_from, sweep_results
    from cir_gym.scoring.policies import make_policy
    from cir_gym.scoring.sweep import expand, read_table, run_task, write_table

    env_id = "cir_gym/JointTracking-v2"
    short = {"episode_duration": 0.1}
    grid = {
        "evaluate": {
            "envs": [env_id],
            "policies": ["computed_torque", "pd_gravity"],
            "episodes": 2,
            "episodes_per_task": 2,
            "seed": 7,
            "env_kwargs": {"payload_mass": [0.0, 3.0]},
            "env_overrides": short,
        }
    }
    tasks = expand(grid)
    rows = [{**r, "status": "ok"} for t in tasks for r in run_task(t, str(tmp_path))["rows"]]
    rows.append(
        {
            **{k: tasks[0][k] for k in ("env_id", "variant", "policy", "kind")},
            "task_id": "f" * 16,
            "status": "failed",
            "error": "RuntimeError: boom",
        }
    )
    write_table(rows, tmp_path, "csv")

    results = sweep_results(read_table(tmp_path))
    assert set(results) == {(env_id, "payload_mass=0.0"), (env_id, "payload_mass=3.0")}
    direct = evaluate(
        make_policy(env_id, "pd_gravity", {**short, "payload_mass": 3.0}, {}),
        env_id,
        2,
        7,
        payload_mass=3.0,
        **short,
    )
    mine = results[(env_id, "payload_mass=3.0")]["pd_gravity"]
    assert [e.seed for e in mine.episodes] == [7, 8]
    assert mine.summary["rms_error"] == pytest.approx(direct.summary["rms_error"], rel=1e-12)
    assert mine.summary["return"] == pytest.approx(direct.summary["return"], rel=1e-12)

    md = leaderboard_from(tmp_path, tmp_path / "page").read_text()
    assert f"## {env_id}" in md and "### payload_mass=3.0 (episode_duration=0.1, " in md
    for variant in ("payload_mass=0.0", "payload_mass=3.0"):
        best = min(
            results[(env_id, variant)].values(), key=lambda r: r.summary["rms_error"]["mean"]
        )
        section = md.split(f"### {variant}")[1]
        assert section.split("| 1 | ", 1)[1].startswith(best.policy_name)
    assert "## Failed tasks" in md and "RuntimeError: boom" in md
    figures = sorted(p.name for p in (tmp_path / "page").glob("*.png"))
    assert figures == [
        "JointTracking-v2_payload_mass_0_0.png",
        "JointTracking-v2_payload_mass_3_0.png",
        "JointTracking-v2_vs_payload_mass.png",
    ]
    page = (tmp_path / "page" / "index.html").read_text()
    assert all(f'src="{f}"' in page for f in figures) and page.count("<table") == 3
    assert cir_gym.ENVIRONMENTS[env_id][0].primary_metric == "rms_error"


def test_a_video_plays_each_row_on_its_own_interface(monkeypatch, tmp_path: Path):
    """A variant's video shows its best rows side by side; a row of another interface
    (``impedance_insertion [PegInHoleImpedance-v0]``) is played on that interface's id by its
    policy name, and captioned with the row's label."""
    import cir_gym.scoring.page as page

    played, captions = [], []
    monkeypatch.setattr(page, "episode_frames",
                        lambda env_id, policy, kwargs, seed: played.append((env_id, policy)) or [])
    monkeypatch.setattr(page, "labelled", lambda frames, label: captions.append(label) or frames)
    monkeypatch.setattr(page, "side_by_side", lambda *clips: [])
    monkeypatch.setattr(page, "save_gif", lambda frames, path, fps: None)
    label = "impedance_insertion [PegInHoleImpedance-v0]"
    shown = [("cir_gym/PegInHole-v2", "hybrid_spiral", "hybrid_spiral"),
             ("cir_gym/PegInHoleImpedance-v0", "impedance_insertion", label)]
    assert page.make_video((shown, {"chamfer": 0.003}, 1000, str(tmp_path / "v.gif"))) == ""
    assert played == [("cir_gym/PegInHole-v2", "hybrid_spiral"),
                      ("cir_gym/PegInHoleImpedance-v0", "impedance_insertion")]
    assert captions == ["hybrid_spiral", label]
