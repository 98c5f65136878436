"""``<out>/index.html``: the leaderboard as one static page, with a video per variant.

Written by :func:`cir_gym.scoring.leaderboard.run_leaderboard` (``cir-gym leaderboard``) after
``leaderboard.md`` and its figures, from the same results. The page needs no server and no
network: plain HTML and CSS in one file, images by relative path (the per-variant figures
beside it, the learning curves in ``results/learning_curves``, the videos in
``<out>/videos``). It holds, per environment and variant, the controllers-vs-RL summary, the
ranked table, the comparison figure and a GIF of one episode (the leaderboard's first seed)
of the best controller and the best agent side by side (best =
:func:`cir_gym.scoring.tables.best`: the highest success rate, then the best primary metric),
each frame showing the task (:meth:`cir_gym.envs.base.RobotEnv.draw_task`) and its caption,
through the camera of :data:`VIDEO_CAMERAS` where one is set. The ranked tables are HTML
written here from the results (:func:`ranked_html`: every metric column with its unit, long
names wrapped to fit a 1366-px laptop screen), each environment lists its metrics (unit,
direction, meaning), and a glossary (:data:`GLOSSARY`) explains the RL terms the tables use.
A small inline script marks the page (``<html data-broken="N">``) with the number of images
that failed to load, which the browser test reads; it changes nothing else.
"""

from __future__ import annotations

import html
import multiprocessing
import os
import re
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

import cir_gym
from cir_gym.envs.base import make_env
from cir_gym.evaluation import interface_env_kwargs
from cir_gym.metrics import BOOTSTRAP_RESAMPLES
from cir_gym.scoring.policies import policy_of_row
from cir_gym.scoring.tables import MIN_INTERVAL_EPISODES

#: GIF frame size (px, each side), frame rate (frames/s) and the longest episode shown (s)
VIDEO_SIZE = 320
VIDEO_FPS = 15
VIDEO_SECONDS = 6.0
#: where the learning curves live (scripts/plot_learning_curves.py)
LEARNING_CURVES = Path(__file__).resolve().parents[2] / "results" / "learning_curves"

CSS = """
body { font-family: system-ui, sans-serif; margin: 0 auto; max-width: 1240px; padding: 0 1em;
       color: #1d1f24; background: #fafafa; line-height: 1.4; }
h1 { margin-top: 0.6em; } h2 { border-bottom: 2px solid #c8ccd4; padding-top: 0.6em; }
nav a { margin-right: 1em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.82em; background: #fff; }
th, td { border: 1px solid #c8ccd4; padding: 0.2em 0.4em; text-align: right; }
th { background: #eceef2; vertical-align: bottom; }
td:nth-child(2), th:nth-child(2) { text-align: left; }
.summary td, .summary th, .glossary td, .glossary th, .metrics td, .metrics th {
  text-align: left; }
table.ranked { width: 100%; } table.ranked td { white-space: nowrap; }
table.ranked td.policy { white-space: normal; overflow-wrap: anywhere; min-width: 9em;
  border-left-width: 5px; }
td.course { border-left-color: #1f77b4; } td.tuned { border-left-color: #ff7f0e; }
td.agent { border-left-color: #2ca02c; }
.key span { display: inline-block; width: 0.8em; height: 0.8em; margin: 0 0.3em 0 0.8em; }
.row { display: flex; flex-wrap: wrap; gap: 1em; align-items: flex-start; }
.row figure.figure { flex: 1 1 420px; }
figure { margin: 0; } figcaption { font-size: 0.85em; color: #444; max-width: 660px; }
img.figure { max-width: 640px; width: 100%; } img.curve { max-width: 100%; }
img.video { display: block; max-width: 100%; height: auto; }
code { background: #eceef2; padding: 0 0.2em; }
.scroll { overflow-x: auto; }
details.glossary-box { background: #fff; border: 1px solid #c8ccd4; padding: 0.4em 0.8em; }
details.glossary-box summary { font-weight: bold; cursor: pointer; }
.glossary th { vertical-align: top; white-space: nowrap; }
"""

#: the RL and statistics vocabulary of the page, for control students: (term, meaning)
GLOSSARY: tuple[tuple[str, str], ...] = (
    (
        "success",
        "the environment's own pass/fail test of one episode (its docstring's Episode "
        "End: e.g. the peg at the goal depth without exceeding the force limit, a tracking error "
        "below a threshold); the success rate is the share of episodes that passed. Rankings put "
        "it first: an episode that stops early can show a small error it stopped accumulating.",
    ),
    (
        "primary metric",
        "the physical quantity a variant is ranked on after success (its unit "
        "in the column header), e.g. the RMS joint error in rad or the insertion time in s.",
    ),
    (
        "score",
        "the normalized score on the primary metric: 0 = a policy that holds the arm still "
        "(run on the same seeds), 1 = the best controller of the variant; < 0 is worse than "
        "holding still, > 1 better than the best controller. Where the two anchors are a "
        "decade or more apart the scale is logarithmic (each decade counts alike). The anchors "
        "are under each ranked table.",
    ),
    (
        "worst",
        "the worst episode's value of the primary metric (the largest error, the "
        "longest time; the smallest where higher is better).",
    ),
    (
        "CVaR 20 %",
        "conditional value at risk: the mean of the worst 20 % of the episodes (at "
        "least one). Between the mean and the worst: how bad the bad cases are.",
    ),
    (
        "return",
        "the sum of the per-step rewards over an episode, the number an RL agent is "
        "trained to maximise. Each reward term is in the env docstring's Rewards section "
        "(tracking kernels, torque and force penalties); it is unitless and not a control "
        "metric: compare controllers on the metrics, read the return as the agents' objective.",
    ),
    (
        "diverged",
        "the share of episodes in which the simulation blew up (non-finite state): "
        "the episode ends with a flag.",
    ),
    (
        "tuned:<controller>",
        "the same control law at gains found for this variant by "
        "scripts/tune_gains.py (Optuna on training seeds, disjoint from the leaderboard's "
        "1000–1009); without the prefix, the course's gains.",
    ),
    (
        "agent:<name>",
        "a trained RL policy (Stable-Baselines3). A residual agent adds a learned "
        "correction to a course controller's action; from-scratch agents act alone.",
    ),
    (
        "IQM",
        "interquartile mean: the mean of the middle 50 % of the values (the best and worst "
        "quarters left out), robust to a few outlying training runs (Agarwal et al. 2021).",
    ),
    (
        "bootstrap CI",
        "a 95 % confidence interval from resampling: the statistic is recomputed "
        "on thousands of samples drawn with replacement from the runs (stratified: per training "
        "seed) and the interval holds the middle 95 % of those values.",
    ),
    (
        "mean [95 % CI]",
        "the primary metric's mean over the episodes and its 95 % confidence interval: a "
        "percentile bootstrap of the mean over the episodes' seeds "
        f"({BOOTSTRAP_RESAMPLES:,} resamples with a fixed generator seed, so a regenerated "
        "table shows the same interval). It says how "
        "well the mean is known, not how the episodes spread (see worst and CVaR). Below "
        f"{MIN_INTERVAL_EPISODES} episodes the table shows the mean alone: there the bootstrap "
        "covers far less than 95 % (~74 % at 3 episodes, ~90 % at 10 on normal data); with "
        "fewer than 30 episodes, read the ranking as indicative.",
    ),
    (
        "success (95 % Wilson)",
        "the success rate and, in parentheses, its 95 % Wilson score interval in %: e.g. "
        "87 % (70–95) for 26 of 30 episodes. Unlike ± a standard error it stays inside "
        "0–100 % and is not zero-width at 0 or 30 of 30 (0 of 30 → 0–11 %).",
    ),
)

#: counts the images that did not load (naturalWidth 0) into <html data-broken>
CHECK_SCRIPT = """
window.addEventListener("load", function () {
  var broken = 0, imgs = document.getElementsByTagName("img");
  for (var i = 0; i < imgs.length; i++) {
    if (!imgs[i].complete || imgs[i].naturalWidth === 0) { broken++; }
  }
  document.documentElement.setAttribute("data-broken", String(broken));
  document.documentElement.setAttribute("data-images", String(imgs.length));
});
"""


# ---------------------------------------------------------------------- markdown → HTML
def _inline(text: str) -> str:
    """Escape ``text`` and render ``**bold**``, ``*em*`` and ```code``` spans."""
    out = html.escape(text, quote=False)
    out = re.sub(r"`([^`]+)`", r"<code>\1</code>", out)
    out = re.sub(r"\*\*([^*]+)\*\*", r"<strong>\1</strong>", out)
    return re.sub(r"(?<![*\w])\*([^*]+)\*(?![*\w])", r"<em>\1</em>", out)


IMAGE = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")


def markdown_to_html(md: str, table_class: str = "") -> str:
    """The markdown the leaderboards write (headings, paragraphs, pipe tables and image lines
    ``![alt](src)``) as HTML."""
    blocks: list[str] = []
    lines = md.strip("\n").split("\n")
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("|"):
            rows = []
            while i < len(lines) and lines[i].startswith("|"):
                rows.append(lines[i])
                i += 1
            cells = [[c.strip() for c in r.strip().strip("|").split("|")] for r in rows]
            body = [c for c in cells[1:] if not all(set(x) <= set("-: ") for x in c)]
            cls = f' class="{table_class}"' if table_class else ""
            head = "".join(f"<th>{_inline(c)}</th>" for c in cells[0])
            trs = "".join(
                "<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in body
            )
            blocks.append(
                f'<div class="scroll"><table{cls}><thead><tr>{head}</tr></thead>'
                f"<tbody>{trs}</tbody></table></div>"
            )
            continue
        image = IMAGE.fullmatch(line.strip())
        if image:
            blocks.append(
                f'<figure><img class="figure" src="{html.escape(image[2])}" '
                f'alt="{html.escape(image[1])}"></figure>'
            )
            i += 1
            continue
        heading = re.fullmatch(r"(#{1,4}) (.+)", line.strip())
        if heading:
            n = len(heading[1])
            blocks.append(f"<h{n}>{_inline(heading[2])}</h{n}>")
            i += 1
            continue
        if line.strip():
            para = [line]  # the first line always (a stray "![" or "#" is text)
            i += 1
            while (
                i < len(lines)
                and lines[i].strip()
                and not lines[i].startswith(("|", "# ", "## ", "### ", "#### ", "!["))
            ):
                para.append(lines[i])
                i += 1
            blocks.append(f"<p>{_inline(' '.join(para))}</p>")
            continue
        i += 1
    return "\n".join(blocks)


def html_page(title: str, body: str) -> str:
    """A complete HTML document around ``body`` with the page's CSS and image check."""
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{html.escape(title)}</title>\n"
        '<link rel="icon" href="data:,">\n'
        f"<style>{CSS}</style>\n<script>{CHECK_SCRIPT}</script>\n</head>\n<body>\n"
        + body
        + "\n</body>\n</html>\n"
    )


# ---------------------------------------------------------------------- videos
def peg_in_hole_camera(env: Any) -> mujoco.MjvCamera:
    """A low side view of PegInHole's hole: 12 cm from a point 16 mm down the nominal bore,
    12° from horizontal, from the side of the env's ``hole_cam``. The bore (its near wall drawn
    translucent by ``draw_task``), the peg and the block stay in view to the end of the
    insertion, where ``hole_cam``, 14 cm away and 24° above, has the wrist above the frame's
    top."""
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    block = env.model.body("block").pos  # the nominal hole's top centre (world), m
    camera.lookat[:] = np.asarray(block, dtype=float) + np.array([0.0, 0.0, -0.016])
    camera.distance = 0.12
    camera.azimuth = 116.6  # looking along (−0.06, 0.12): hole_cam's direction
    camera.elevation = -12.0
    return camera


#: env name (without version) → the camera of its videos (a function of the unwrapped env);
#: others use the env's own camera. Visual only: the model is unchanged.
VIDEO_CAMERAS: dict[str, Callable[[Any], mujoco.MjvCamera]] = {
    "PegInHole": peg_in_hole_camera,
    "PegInHoleImpedance": peg_in_hole_camera,
}


def episode_frames(
    env_id: str,
    policy_name: str,
    env_kwargs: dict[str, Any],
    seed: int,
    size: int = VIDEO_SIZE,
    fps: int = VIDEO_FPS,
    seconds: float = VIDEO_SECONDS,
) -> list[np.ndarray]:
    """Frames (size × size RGB) of one episode of ``policy_name`` at ≈ ``fps`` frames/s, the
    first ``seconds`` of it (the episode goes on to its end: the last frame is its end),
    through the camera of :data:`VIDEO_CAMERAS` where one is set."""

    from cir_gym.scoring.policies import make_policy

    policy = make_policy(env_id, policy_name, env_kwargs, {})
    env_kwargs = interface_env_kwargs(policy, env_kwargs)
    env = make_env(env_id, render_mode="rgb_array", width=size, height=size, **env_kwargs)
    camera = VIDEO_CAMERAS.get(env_id.split("/")[-1].rsplit("-v", 1)[0])
    if camera is not None:
        env.unwrapped.camera = camera(env.unwrapped)
    dt = env.unwrapped.dt
    every = max(1, round(1.0 / (fps * dt)))
    limit = max(1, round(seconds * fps))
    frames: list[np.ndarray] = []
    obs, _ = env.reset(seed=seed)
    state, start, done, k = None, True, False, 0
    while not done:
        if k % every == 0 and len(frames) < limit:
            frames.append(env.render())
        action, state = policy.predict(obs, state=state, episode_start=[start], deterministic=True)
        start = False
        obs, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated
        k += 1
    if len(frames) < limit:
        frames.append(env.render())  # the final state
    env.close()
    return frames


def label_lines(label: str, width: int, scale: int) -> list[str]:
    """A policy name broken into lines of at most ``width`` px at font ``scale``, after a
    ``:`` or ``_`` (``agent:residual_ppo_…``) or a space, never inside a word part."""
    from cir_gym import rendering

    chars = max(1, width // ((rendering.GLYPH_W + 1) * scale))
    lines, current = [], ""
    for part in re.split(r"(?<=[:_ ])", label):
        if current and len(current) + len(part.rstrip()) > chars:
            lines.append(current.rstrip())
            current = ""
        current += part
    return [*lines, current.rstrip()] if current else lines


def labelled(frames: list[np.ndarray], label: str) -> list[np.ndarray]:
    """``frames`` with a dark strip below carrying ``label`` whole: the font scale of the
    frame's caption (:func:`cir_gym.rendering.caption_scale`) when the name fits two lines,
    else a smaller one, down to 1 over as many lines as it needs (:func:`label_lines`)."""
    from cir_gym import rendering

    h, w = frames[0].shape[:2]
    scale = rendering.caption_scale(h)
    while scale > 1 and len(label_lines(label, w - 4, scale)) > 2:
        scale -= 1
    lines = label_lines(label, w - 4, scale)
    step = (rendering.GLYPH_H + 3) * scale
    strip = np.full((len(lines) * step + 2 * scale + 1, w, 3), 30, dtype=np.uint8)
    for i, line in enumerate(lines):
        mask = rendering.text_mask(line, scale)[:, : w - 4]
        y = 2 * scale + i * step
        strip[y : y + mask.shape[0], 2 : 2 + mask.shape[1]][mask] = 235
    return [np.vstack((f, strip)) for f in frames]


def side_by_side(left: list[np.ndarray], right: list[np.ndarray]) -> list[np.ndarray]:
    """Pairs of frames with a 4 px gap; the shorter clip holds its last frame, the lower one
    is padded at the bottom with its label strip's colour."""
    n = max(len(left), len(right))
    height = max(left[0].shape[0], right[0].shape[0])

    def pad(frame: np.ndarray) -> np.ndarray:
        extra = np.full((height - frame.shape[0], *frame.shape[1:]), 30, dtype=np.uint8)
        return np.vstack((frame, extra)) if len(extra) else frame

    gap = np.full((height, 4, 3), 250, dtype=np.uint8)
    return [
        np.hstack((pad(left[min(i, len(left) - 1)]), gap, pad(right[min(i, len(right) - 1)])))
        for i in range(n)
    ]


def save_gif(frames: list[np.ndarray], path: str | Path, fps: float, colours: int = 255) -> Path:
    """Write RGB ``frames`` as a small looping GIF: one palette for all frames and, from the
    second frame on, the pixels that did not change left transparent (so a fixed camera costs
    only what moves: ~100 KB for 50 frames of 360 × 190 px, ~6× less than per-frame palettes).
    """
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sample = np.vstack(frames[:: max(1, len(frames) // 8)])
    palette_image = Image.fromarray(sample).quantize(
        colors=colours, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE
    )
    palette = palette_image.getpalette()[: 3 * colours]
    palette += [0] * (3 * colours - len(palette)) + [0, 0, 0]  # index `colours`: transparent
    images, previous = [], None
    for frame in frames:
        index = np.asarray(
            Image.fromarray(np.ascontiguousarray(frame)).quantize(
                palette=palette_image, dither=Image.Dither.NONE
            )
        )
        shown = index.copy()
        if previous is not None:
            shown[index == previous] = colours
        previous = index
        image = Image.frombytes(
            "P", (index.shape[1], index.shape[0]), shown.astype(np.uint8).tobytes()
        )
        image.putpalette(palette)
        images.append(image)
    images[0].save(
        path,
        save_all=True,
        append_images=images[1:],
        duration=round(1000 / fps),
        loop=0,
        optimize=False,
        disposal=1,
        transparency=colours,
    )
    return path


def make_video(job: tuple[list[tuple[str, str, str]], dict[str, Any], int, str]) -> str:
    """Write one variant's GIF; return "" or the error (a failed video never stops the page).

    ``job``: ([(env id, policy, row label), ...] side by side, env kwargs, seed, path); a row
    of another interface (``impedance_insertion [PegInHoleImpedance-v0]``) plays on its own id.
    """
    shown, env_kwargs, seed, path = job
    try:
        clips = [labelled(episode_frames(env_id, policy, env_kwargs, seed), label)
                 for env_id, policy, label in shown]
        frames = clips[0] if len(clips) == 1 else side_by_side(*clips)
        save_gif(frames, path, fps=VIDEO_FPS)
        return ""
    except Exception as exc:  # reported on the page instead
        return f"{type(exc).__name__}: {exc}"


# ---------------------------------------------------------------------- the page
def _breakable(text: str) -> str:
    """``text`` escaped, with a line-break opportunity (``<wbr>``) after each ``_`` and ``:``
    (long policy and metric names wrap there instead of widening their column)."""
    return re.sub(r"([_:])", r"\1<wbr>", html.escape(text))


def _unit(unit: str) -> str:
    """`` (unit)`` for a header, never broken inside the parentheses; "" without a unit."""
    return f" ({html.escape(unit).replace(' ', '&nbsp;')})" if unit else ""


def _family_class(policy_name: str) -> str:
    if policy_name.startswith("agent:"):
        return "agent"
    return "tuned" if policy_name.startswith("tuned:") else "course"


FAMILY_KEY = (
    '<p class="key">Policy families (left border of each row, bar colours in the figures):'
    '<span style="background:#1f77b4"></span>controller at the course\'s gains'
    '<span style="background:#ff7f0e"></span>controller at tuned gains (<code>tuned:</code>)'
    '<span style="background:#2ca02c"></span>RL agent (<code>agent:</code>)</p>'
)


def ranked_html(rows: list[Any], anchors: Any = None) -> str:
    """The ranked table of one variant as HTML: rows in :func:`cir_gym.evaluation.rank` order
    (success rate, then the primary metric's mean), the success rate with its 95 % Wilson
    interval, the normalized score given the variant's ``anchors``
    (:class:`cir_gym.score_scale.Anchors`), the primary metric's mean with its 95 % bootstrap
    interval (:func:`cir_gym.scoring.tables.mean_cell`), worst episode and CVaR 20 %, every
    other metric's mean, the return and the share of diverged episodes; every metric header
    carries its unit, each row its family's colour (:data:`FAMILY_KEY`)."""
    from cir_gym.evaluation import rank
    from cir_gym.scoring.tables import (
        MEAN_HEADER,
        MEAN_MEANING,
        SCORE_HEADER,
        SCORE_MEANING,
        SUCCESS_HEADER,
        SUCCESS_MEANING,
        mean_cell,
        score_cell,
        score_of,
        success_cell,
    )

    if not rows:
        return "<p>(no results)</p>"
    ranked = rank(rows)
    primary = ranked[0].primary_metric
    spec = ranked[0].spec(primary)
    others = [m for m in ranked[0].specs if m.name != primary]
    head = [
        "#",
        "policy",
        f'success <abbr title="{html.escape(SUCCESS_MEANING)}">{SUCCESS_HEADER}</abbr>',
        *([f'<abbr title="{SCORE_MEANING}">{SCORE_HEADER}</abbr>'] if anchors else []),
        f"<strong>{_breakable(primary)}</strong>{_unit(spec.unit)} "
        f'<abbr title="{html.escape(MEAN_MEANING)}">{MEAN_HEADER}</abbr>',
        f"worst{_unit(spec.unit)}",
        f"CVaR&nbsp;20&nbsp;%{_unit(spec.unit)}",
        *(f"{_breakable(m.name)}{_unit(m.unit)}" for m in others),
        "return",
        "diverged",
    ]
    body = []
    for i, r in enumerate(ranked, 1):
        p = r.summary[primary]
        cells = [
            str(i),
            success_cell(r),
            *([score_cell(score_of(r, anchors))] if anchors else []),
            mean_cell(r, primary),
            f"{p['worst']:.3g}",
            f"{p['cvar']:.3g}",
            *(f"{r.summary[m.name]['mean']:.3g}" for m in others),
            f"{r.summary['return']['mean']:.1f}",
            f"{100 * r.divergence_rate:.0f} %",
        ]
        family = _family_class(r.policy_name)
        policy = f'<td class="policy {family}">{_breakable(r.policy_name)}</td>'
        body.append(
            f"<tr><td>{cells[0]}</td>{policy}"
            + "".join(f"<td>{c}</td>" for c in cells[1:])
            + "</tr>"
        )
    return (
        '<div class="scroll"><table class="ranked"><thead><tr>'
        + "".join(f"<th>{h}</th>" for h in head)
        + "</tr></thead><tbody>"
        + "".join(body)
        + "</tbody></table></div>"
    )


def metrics_html(specs: Any) -> str:
    """An environment's metrics (:class:`cir_gym.metrics.MetricSpec`): name, unit, which way is
    better, meaning."""
    rows = "".join(
        f"<tr><td><code>{html.escape(m.name)}</code></td><td>{html.escape(m.unit) or '–'}</td>"
        f"<td>{m.better}</td><td>{html.escape(m.description)}"
        + (" (a failed episode scores the limit)" if m.failure_scores_limit else "")
        + "</td></tr>"
        for m in specs
    )
    return (
        "<details><summary>Metrics of this environment (units, which way is better)</summary>"
        '<table class="metrics"><thead><tr><th>metric</th><th>unit</th><th>better</th>'
        f"<th>meaning</th></tr></thead><tbody>{rows}</tbody></table></details>"
    )


def with_units(md: str, specs: Any) -> str:
    """``md`` (the leaderboards' markdown) with each metric's unit after its name where a table
    names it without one: a header cell ending in a metric name (``IQM insertion_time``) and a
    cell that is only a metric name in backticks (the summary's "ranked on")."""
    units = {m.name: m.unit for m in specs if m.unit}
    if not units:
        return md
    names = "|".join(sorted(map(re.escape, units), key=len, reverse=True))

    def cell(match: re.Match[str]) -> str:
        return f"{match[0]} ({units[match[1] or match[2]]})"

    out = []
    for line in md.split("\n"):
        if line.startswith("|"):
            line = re.sub(rf"(?<=[| ])`({names})`(?= \|)|(?<= )({names})(?= \|)", cell, line)
        out.append(line)
    return "\n".join(out)


def glossary_html() -> str:
    """:data:`GLOSSARY` as a collapsible table."""
    rows = "".join(
        f"<tr><th>{html.escape(term)}</th><td>{html.escape(text)}</td></tr>"
        for term, text in GLOSSARY
    )
    return (
        '<details class="glossary-box" open><summary>How to read the tables (glossary for '
        "control students)</summary>"
        f'<table class="glossary"><tbody>{rows}</tbody></table></details>'
    )


def _learning_curve(env_id: str) -> Path | None:
    """results/learning_curves/<Name>-vN.png, else the newest version's curve of <Name>."""
    name = env_id.split("/")[-1]
    exact = LEARNING_CURVES / f"{name}.png"
    if exact.is_file():
        return exact
    base = name.rsplit("-v", 1)[0]
    found = sorted(
        LEARNING_CURVES.glob(f"{base}-v*.png"),
        key=lambda p: int(re.sub(r"\D", "", p.stem.rsplit("-v", 1)[1]) or 0),
    )
    return found[-1] if found else None


def _rel(path: Path, out: Path) -> str:
    return Path(os.path.relpath(path.resolve(), out.resolve())).as_posix()


def write_page(
    out: Path,
    results: dict[tuple[str, str, str], Any],
    env_ids: list[str],
    episodes: int,
    seed: int,
    env_overrides: dict[str, Any] | None = None,
    workers: int | None = None,
    videos: bool = True,
    extra: dict[tuple[str, str], str] | None = None,
    anchors: dict[tuple[str, str], Any] | None = None,
) -> Path:
    """Write ``out/index.html`` (and ``out/videos/*.gif``) from the leaderboard's results.

    Args:
        out: the leaderboard's output directory (its figures are already there).
        results: (env_id, variant, policy) → EvaluationResult, as run_leaderboard holds them.
        env_ids, episodes, seed, env_overrides: as given to run_leaderboard.
        workers: processes for the videos (default: one per core).
        videos: False writes the page without GIFs.
        extra: (env_id, variant) → markdown shown under that variant's ranked table (the
            multi-seed agents' table).
        anchors: (env_id, variant) → the variant's normalized-score anchors
            (:class:`cir_gym.score_scale.Anchors`; the leaderboard's hold-still run and best
            controller): a score column in its tables and the anchors under its ranked table.
    """
    from cir_gym.scoring.tables import best, rl_summary, slug

    out.mkdir(parents=True, exist_ok=True)
    sections: list[tuple[str, str, list[tuple[str, str, str, list[Any], str, list[str]]]]] = []
    jobs = []
    for env_id in env_ids:
        cls, description = cir_gym.ENVIRONMENTS[env_id]
        variants = getattr(cls, "leaderboard_variants", {"default": {}})
        rows_of = {
            v: [r for (e, vv, _), r in sorted(results.items()) if e == env_id and vv == v]
            for v in variants
        }
        entries = []
        for variant, kwargs in variants.items():
            rows = rows_of[variant]
            ctrl = best([r for r in rows if not r.policy_name.startswith("agent:")])
            agent = best([r for r in rows if r.policy_name.startswith("agent:")])
            shown = [(r.env_id, policy_of_row(r.policy_name), r.policy_name)
                     for r in (ctrl, agent) if r is not None]
            name = env_id.split("/")[-1]
            gif = out / "videos" / f"{name}_{slug(variant)}.gif"
            if videos and shown:
                jobs.append((shown, {**kwargs, **(env_overrides or {})}, seed, str(gif)))
            setting = ", ".join(f"{k}={v}" for k, v in kwargs.items()) or "default arguments"
            fig = out / f"{name}_{slug(variant)}.png"
            entries.append(
                (variant, setting, str(gif) if videos and shown else "", rows, str(fig), shown)
            )
        env_anchors = {v: (anchors or {}).get((env_id, v)) for v in variants}
        sections.append(
            (env_id, description + "\n\n" + rl_summary(rows_of, env_anchors), entries)
        )

    errors: dict[str, str] = {}
    if jobs:
        n = min(len(jobs), workers or os.cpu_count() or 1)
        if n > 1:
            # spawn, not fork: a process forked after its parent made a GL (EGL/OSMesa)
            # context hangs creating its own (seen: the leaderboard test after render tests)
            spawn = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(max_workers=n, mp_context=spawn) as pool:
                messages = list(pool.map(make_video, jobs))
        else:
            messages = [make_video(j) for j in jobs]
        errors = {j[3]: m for j, m in zip(jobs, messages, strict=True) if m}

    body = [
        "<h1>cir_gym leaderboard</h1>",
        f"<p>{episodes} episode{'s' if episodes != 1 else ''} per policy, seeds {seed}…"
        f"{seed + episodes - 1} (the same for every policy), ranked by success rate, then by "
        "each variant's primary metric (mean over episodes, with its 95 % interval: see the "
        "glossary). Each video is one episode (seed "
        f"{seed}, the first {VIDEO_SECONDS:g} s at {VIDEO_FPS} frames/s) of the best "
        "controller (left) and the best agent (right) with the task drawn: the reference "
        "(cyan), the target (yellow), obstacles and forces (red arrows). Generated by "
        "<code>cir-gym leaderboard</code>; the same tables are in "
        '<a href="leaderboard.md">leaderboard.md</a>.</p>',
        glossary_html(),
        FAMILY_KEY,
        "<nav>"
        + "".join(
            f'<a href="#{slug(e)}">{html.escape(e.split("/")[-1])}</a>' for e, _, _ in sections
        )
        + "</nav>",
    ]
    for env_id, description, entries in sections:
        specs = cir_gym.ENVIRONMENTS[env_id][0].metric_specs
        body.append(f'<h2 id="{slug(env_id)}">{html.escape(env_id)}</h2>')
        body.append(markdown_to_html(with_units(description, specs), "summary"))
        body.append(metrics_html(specs))
        curve = _learning_curve(env_id)
        if curve is not None:
            body.append(
                f'<figure><img class="curve" src="{_rel(curve, out)}" alt="learning '
                f'curves {html.escape(env_id)}"><figcaption>Learning curves '
                f"({html.escape(curve.stem)}).</figcaption></figure>"
            )
        for variant, setting, gif, rows, fig, shown in entries:
            body.append(f"<h3>{html.escape(variant)} <small>({html.escape(setting)})</small></h3>")
            row = []
            if gif and gif not in errors:
                sides = ("left", "right") if len(shown) == 2 else ("",)
                who = "; ".join(
                    f"{side + ': ' if side else ''}<code>{html.escape(label)}</code>"
                    for side, (_, _, label) in zip(sides, shown, strict=False)
                )
                row.append(
                    f'<figure><img class="video" src="{_rel(Path(gif), out)}" alt="video '
                    f'{html.escape(env_id)} {html.escape(variant)}"><figcaption>{who}'
                    "</figcaption></figure>"
                )
            elif gif:
                row.append(f"<p>video failed: {html.escape(errors[gif])}</p>")
            if Path(fig).is_file():
                row.append(
                    f'<figure class="figure"><img class="figure" src="{_rel(Path(fig), out)}" '
                    f'alt="{html.escape(env_id)} {html.escape(variant)}"></figure>'
                )
            body.append('<div class="row">' + "".join(row) + "</div>")
            a = (anchors or {}).get((env_id, variant))
            body.append(ranked_html(rows, a))
            if a is not None:
                body.append(f"<p class=\"anchors\">Normalized {_inline(a.describe())}.</p>")
            if (extra or {}).get((env_id, variant)):
                body.append(markdown_to_html(with_units(extra[(env_id, variant)], specs)))
    index = out / "index.html"
    index.write_text(html_page("cir_gym leaderboard", "\n".join(body)), encoding="utf-8")
    print(
        f"wrote {index} ({len(jobs) - len(errors)} videos"
        + (f", {len(errors)} failed" if errors else "")
        + ")",
        file=sys.stderr,
    )
    return index
