"""Plots of recorded episodes, of leaderboards and of sweeps (matplotlib, imported lazily; Agg).

- :func:`plot_episode` (``cir-gym evaluate --plot``): one recorded episode. Every observation
  pair ``<key>`` / ``<key>_ref`` is drawn as actual (solid) vs reference (dashed), the
  per-step ``joint_error`` / ``task_error`` as an error plot, the actions as commands, and
  each task's own quantities where its observations name them (:data:`TASK_PANELS`): the
  contact force, insertion depth and lateral (spiral) path of ``peg_pos`` + ``wrench``; the
  normal force against ``f_ref``; the position and orientation errors of ``x``/``quat`` against
  their references; the feature error and the image-plane trajectories of ``features``.
- :func:`plot_comparison`: a leaderboard's bar chart, policies in :func:`cir_gym.evaluation.rank`
  order, coloured by family (:func:`family`).
- :func:`plot_sweep_axis`: a sweep's primary metric against the one swept environment
  argument, one line per policy, the argument's unit read from the env docstring.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import cir_gym
from cir_gym.evaluation import EvaluationResult, rank

__all__ = [
    "FAMILY_COLOURS",
    "argument_unit",
    "comparison_bars",
    "episode_panels",
    "family",
    "line_styles",
    "plot_comparison",
    "plot_episode",
    "plot_sweep_axis",
    "save_video",
]

#: bar / line colour of each policy family (:func:`family`)
FAMILY_COLOURS = {
    "controller, course gains": "#1f77b4",
    "controller, tuned gains": "#ff7f0e",
    "RL agent": "#2ca02c",
}
#: line style of each policy family in sweep plots
FAMILY_STYLES = {
    "controller, course gains": "-",
    "controller, tuned gains": "--",
    "RL agent": ":",
}
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*")
DPI = 110


def _plt() -> Any:
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ImportError("plots need matplotlib: pip install 'cir-gym[plots]'") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: str | Path, plt: Any) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return path


def family(policy_name: str) -> str:
    """The family of a policy name: ``agent:…`` and ``train:…`` (a sweep's training runs) are
    RL agents, ``tuned:…`` a controller at tuned gains, anything else a controller at the
    course's gains (a key of :data:`FAMILY_COLOURS`)."""
    if policy_name.startswith(("agent:", "train:")):
        return "RL agent"
    if policy_name.startswith("tuned:"):
        return "controller, tuned gains"
    return "controller, course gains"


def _spans_decades(values: np.ndarray) -> bool:
    """Whether ``values`` (finite ones) are all positive and span at least a factor 10."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return bool(len(v) and np.all(v > 0) and v.max() >= 10 * v.min())


def _metric_label(name: str, unit: str, what: str = "") -> str:
    text = f"{name}, {what}" if what else name
    return f"{text} ({unit})" if unit else text


# ---------------------------------------------------------------------- leaderboard bars
def comparison_bars(
    results: list[EvaluationResult],
) -> tuple[list[str], np.ndarray, np.ndarray, list[str]]:
    """What :func:`plot_comparison` draws: the policy names in :func:`rank` order, their
    primary metric's means and worst episodes, and each bar's colour (:func:`family`)."""
    ranked = rank(results)
    primary = ranked[0].primary_metric
    names = [r.policy_name for r in ranked]
    means = np.array([r.summary[primary]["mean"] for r in ranked])
    worst = np.array([r.summary[primary]["worst"] for r in ranked])
    return names, means, worst, [FAMILY_COLOURS[family(n)] for n in names]


def plot_comparison(results: list[EvaluationResult], path: str | Path, title: str = "") -> Path:
    """Horizontal bar chart of the primary metric's mean per policy with its worst episode (a
    tick), best first from the top in :func:`cir_gym.evaluation.rank` order (success rate,
    then the mean), bars coloured by :func:`family`, each policy's success rate in a column
    on the right; a log axis when the values span a decade or more."""
    plt = _plt()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.transforms import blended_transform_factory

    ranked = rank(results)
    primary = ranked[0].primary_metric
    spec = ranked[0].spec(primary)
    names, means, worst, colours = comparison_bars(results)
    n = len(names)
    fig, ax = plt.subplots(figsize=(7.2, 0.27 * n + 1.9))  # a row of 0.27 in per policy
    y = np.arange(n)
    log = _spans_decades(np.concatenate((means, worst)))
    ax.barh(y, np.where(np.isfinite(means), means, np.nan), color=colours, height=0.72)
    ax.scatter(worst, y, color="black", marker="|", s=110, linewidths=1.8, zorder=3)
    if log:
        ax.set_xscale("log")
    ax.set_yticks(y, [f"{i}. {name}" for i, name in enumerate(names, 1)], fontsize=8)
    ax.set_ylim(n - 0.4, -0.6)  # rank 1 at the top
    right = blended_transform_factory(ax.transAxes, ax.transData)
    ax.text(1.01, -1.0, "success", transform=right, fontsize=7.5, va="center", weight="bold")
    for i, r in enumerate(ranked):
        text = f"{100 * r.success_rate:.0f} %" if np.isfinite(means[i]) else "n/a"
        ax.text(1.01, i, text, transform=right, fontsize=7.5, va="center")
    direction = "lower is better" if spec.better == "lower" else "higher is better"
    ax.set_xlabel(f"{_metric_label(primary, spec.unit)}: mean over episodes, {direction}")
    ax.set_title(title or ranked[0].env_id, fontsize=10)
    ax.grid(True, axis="x", which="both", alpha=0.3)
    fams = [f for f in FAMILY_COLOURS if any(family(name) == f for name in names)]
    handles = [Patch(color=FAMILY_COLOURS[f], label=f) for f in fams]
    handles.append(
        Line2D([], [], color="black", marker="|", ls="", ms=10, mew=1.8, label="worst episode")
    )
    height = 0.27 * n + 1.9  # in
    fig.legend(handles=handles, fontsize=7, loc="lower center", ncol=len(handles), frameon=False)
    fig.tight_layout(rect=(0.0, 0.3 / height, 1.0, 1.0))  # the legend's row at the bottom
    return _save(fig, path, plt)


# ---------------------------------------------------------------------- sweeps
#: unit words an env docstring's argument table uses (inside the parentheses of a meaning)
_UNIT_WORDS = {"m", "s", "kg", "N", "rad", "Hz", "px", "degrees", "°", "mm", "cm", "W"}


def argument_unit(env_cls: type, name: str) -> str:
    """The unit of constructor argument ``name`` of ``env_cls``, from the Arguments table of its
    docstring: the meaning ``s`` or ``s: …``, else the first parenthesised group made of unit
    words (``(kg)``, ``(N m s/rad)``, ``(m, in [1e-4, 2e-3])`` → ``m``); "" if none."""
    for line in (env_cls.__doc__ or "").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not line.strip().startswith("|") or len(cells) < 3 or cells[0] != name:
            continue
        meaning = cells[2]
        if meaning == "s" or meaning.startswith("s:") or meaning.startswith("s ("):
            return "s"
        for group in re.findall(r"\(([^()]*)\)", meaning):
            head = group.split(",")[0].strip()
            words = re.split(r"[\s/]+", head)
            if head and all(w.rstrip("²³") in _UNIT_WORDS for w in words):
                return "°" if head == "degrees" else head
        return ""
    return ""


def _sweep_label(row: dict[str, Any]) -> str:
    """A policy's name in a sweep: the policy, its gains, its training seed (as the sweep's
    leaderboard names it)."""
    gains = ", ".join(
        f"{k[5:]}={row[k]}" for k in sorted(row) if k.startswith("gain.") and row[k] is not None
    )
    label = f"{row['policy']} ({gains})" if gains else str(row["policy"])
    if row.get("train_seed") is not None:
        label += f" seed {row['train_seed']}"
    return label


def line_styles(labels: list[str]) -> dict[str, tuple[str, str, str]]:
    """(colour, marker, line style) of each of ``labels``: the i-th label takes colour i of
    matplotlib's 10-colour cycle and marker i of :data:`MARKERS` (8), so up to 40 labels get
    distinct pairs, and its family's line style (:data:`FAMILY_STYLES`)."""
    colours = [f"C{i}" for i in range(10)]
    return {
        label: (colours[i % len(colours)], MARKERS[i % len(MARKERS)], FAMILY_STYLES[family(label)])
        for i, label in enumerate(labels)
    }


def plot_sweep_axis(rows: list[dict[str, Any]], env_id: str, axis: str, path: Path) -> Path:
    """The primary metric (mean over each policy's episodes) against a swept numeric
    environment argument, one line per policy: where each controller stops coping.

    ``rows`` are a sweep's episode rows (``policy``, ``gain.*``, ``train_seed``, ``axis`` =
    ``env.<name>``, ``metric.<primary>``). Each line has its own colour and marker (10 colours
    × 8 markers), its family's line style (course gains solid, tuned dashed, agents dotted);
    the legend sits outside the axes; the x axis carries the argument's unit
    (:func:`argument_unit`), the y axis the metric's (log when it spans a decade).
    """
    plt = _plt()
    cls = cir_gym.ENVIRONMENTS[env_id][0]
    primary = cls.primary_metric
    spec = next(s for s in cls.metric_specs if s.name == primary)
    lines: dict[str, dict[float, list[float]]] = {}
    for r in rows:
        value = r.get(f"metric.{primary}")
        lines.setdefault(_sweep_label(r), {}).setdefault(float(r[axis]), []).append(
            float(value) if value is not None else np.nan
        )
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    order = sorted(lines, key=lambda label: (list(FAMILY_STYLES).index(family(label)), label))
    styles = line_styles(order)  # course gains, then tuned, then agents (as in the legend)
    every: list[np.ndarray] = []
    for label in order:
        points = lines[label]
        x = np.array(sorted(points))
        with np.errstate(all="ignore"):
            mean = np.array(
                [np.nanmean(points[v]) if np.any(np.isfinite(points[v])) else np.nan for v in x]
            )
        every.append(mean)
        colour, marker, ls = styles[label]
        ax.plot(x, mean, color=colour, marker=marker, ls=ls, lw=1.4, ms=5, label=label)
    if every and _spans_decades(np.concatenate(every)):
        ax.set_yscale("log")
    name = axis[4:] if axis.startswith("env.") else axis
    unit = argument_unit(cls, name)
    ax.set_xlabel(f"{name} ({unit})" if unit else name)
    ax.set_ylabel(_metric_label(primary, spec.unit, "mean"))
    ax.set_title(f"{env_id}: {primary} against {name}", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(
        fontsize=7,
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        frameon=False,
        title="policy (— course, -- tuned, ·· agent)",
        title_fontsize=7,
    )
    fig.tight_layout()
    return _save(fig, path, plt)


# ---------------------------------------------------------------------- one episode
#: unit of an observation key drawn against its reference (``<key>`` / ``<key>_ref``)
OBS_UNITS = {"q": "rad", "qd": "rad/s", "q_motor": "rad", "qd_motor": "rad/s", "x": "m"}
#: the per-step errors :func:`cir_gym.evaluation.evaluate` records from ``info``
ERRORS = {"joint_error": ("joint error ‖q̄ − q‖", "rad"), "task_error": ("task error", "m")}
#: the colours of VisualServo's four markers, in the order of ``features``
FEATURE_COLOURS = ("tab:red", "tab:green", "tab:blue", "goldenrod")


class Panel:
    """One axes of :func:`plot_episode`: a title, a y label and how to draw it.

    ``draw(ax, t)`` draws into ``ax`` (``t`` (T,) s); ``plane``: the panel is a path in a
    plane (its own x axis), not a quantity against time; ``log``: a log y axis.
    """

    def __init__(
        self,
        title: str,
        ylabel: str,
        draw: Callable[[Any, np.ndarray], None],
        plane: bool = False,
        log: bool = False,
    ) -> None:
        self.title, self.ylabel, self.draw, self.plane, self.log = title, ylabel, draw, plane, log


#: a task's panels from a recorded trace, and the trace keys they stand for (not drawn again
#: as generic reference pairs or errors); None when the trace is not of that task
TaskPanels = Callable[[dict[str, np.ndarray]], tuple[list[Panel], set[str]] | None]


def _tared(wrench: np.ndarray) -> np.ndarray:
    """Force (T, 3) N of an F/T reading (T, 6) minus its first sample: the episode starts at
    rest in free space, so the first sample is the tool's weight and the bias."""
    return wrench[:, :3] - wrench[0, :3]


def _running_mean(t: np.ndarray, values: np.ndarray, window: float) -> np.ndarray:
    """The mean of ``values`` (T,) over the last ``window`` s at each time of ``t`` (T,) s."""
    n = max(1, round(window / (t[1] - t[0]))) if len(t) > 1 else 1
    total = np.cumsum(np.concatenate(([0.0], values)))
    k = np.arange(1, len(values) + 1)
    return (total[k] - total[np.maximum(k - n, 0)]) / np.minimum(k, n)


def _semilogy(ax: Any, t: np.ndarray, values: np.ndarray, decades: float = 5.0) -> None:
    """``values`` (T,) against ``t`` on a log axis showing at most ``decades`` below their
    largest value (exact zeros, e.g. at the start on the reference, are left out)."""
    v = np.asarray(values, dtype=float)
    ax.semilogy(t, np.where(v > 0, v, np.nan), lw=1.0)
    positive = v[np.isfinite(v) & (v > 0)]
    if len(positive):
        ax.set_ylim(bottom=max(positive.min(), positive.max() * 10.0**-decades) / 2)


def _plane_path(ax: Any, xy: np.ndarray, ref: np.ndarray | None, unit: str) -> None:
    """A path in a plane (start ○, end ×), its reference dashed, equal axes."""
    if ref is not None:
        ax.plot(ref[:, 0], ref[:, 1], color="0.75", lw=4.0, label="reference")
    ax.plot(xy[:, 0], xy[:, 1], color="tab:blue", lw=1.0, label="actual")
    ax.plot(*xy[0], "o", color="tab:green", ms=6, label="start")
    ax.plot(*xy[-1], "x", color="tab:red", ms=7, mew=2, label="end")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"x ({unit})")
    ax.legend(fontsize=7)


def peg_in_hole_panels(trace: dict[str, np.ndarray]) -> tuple[list[Panel], set[str]] | None:
    """PegInHole (``peg_pos`` in the nominal hole frame, ``wrench``): contact force, insertion
    depth, and the tip's lateral path (the spiral search) seen along the bore."""
    if "obs/peg_pos" not in trace or "obs/wrench" not in trace:
        return None
    p = 1e3 * trace["obs/peg_pos"]  # mm, nominal hole frame (z out of the hole)
    force = _tared(trace["obs/wrench"])

    def draw_force(ax: Any, t: np.ndarray) -> None:
        for values, label in (
            (np.linalg.norm(force, axis=1), "|F|"),
            (force[:, 2], "F_z (along the peg)"),
        ):
            (line,) = ax.plot(t, values, lw=0.6, alpha=0.35)
            ax.plot(
                t,
                _running_mean(t, values, 0.02),
                color=line.get_color(),
                lw=1.3,
                label=f"{label}, 20 ms mean",
            )
        ax.legend(fontsize=7, loc="upper left")

    def draw_depth(ax: Any, t: np.ndarray) -> None:
        ax.plot(t, -p[:, 2], lw=1.2, label="tip depth")
        ax.axhline(0.0, color="0.4", lw=0.8, ls="--", label="hole's top")
        ax.legend(fontsize=7, loc="upper left")

    def draw_lateral(ax: Any, t: np.ndarray) -> None:
        ax.plot(0.0, 0.0, "+", color="0.3", ms=12, mew=1.5, label="nominal axis")
        _plane_path(ax, p[:, :2], None, "mm")
        ax.set_ylabel("y (mm)")

    return [
        Panel(
            "contact force: F/T reading tared at t = 0, sensor frame (light: every step)",
            "force (N)",
            draw_force,
        ),
        Panel("insertion depth below the nominal hole's top", "depth (mm)", draw_depth),
        Panel(
            "lateral path of the tip (spiral search), nominal hole frame",
            "y (mm)",
            draw_lateral,
            plane=True,
        ),
    ], {"obs/peg_pos", "obs/peg_quat", "obs/peg_twist", "obs/wrench"}


def contact_force_panels(trace: dict[str, np.ndarray]) -> tuple[list[Panel], set[str]] | None:
    """AdmittanceContact (``wrench``, ``f_ref``, ``tool_pos``/``tool_pos_ref``): the normal
    force against f̄, the tool's height against its reference, the path error in the plane."""
    if "obs/wrench" not in trace or "obs/f_ref" not in trace:
        return None
    force = _tared(trace["obs/wrench"])[:, 2]  # along the tool (pointing into the surface)
    f_ref = trace["obs/f_ref"][:, 0]
    pos, ref = 1e3 * trace["obs/tool_pos"], 1e3 * trace["obs/tool_pos_ref"]

    def draw_force(ax: Any, t: np.ndarray) -> None:
        ax.plot(t, force, lw=1.0, label="f (F/T along the tool, tared at t = 0)")
        ax.plot(t, f_ref, "--", color="0.3", lw=1.0, label="f̄ (reference)")
        ax.legend(fontsize=7, loc="upper left")

    def draw_height(ax: Any, t: np.ndarray) -> None:
        ax.plot(t, pos[:, 2], lw=1.0, label="tip z")
        ax.plot(t, ref[:, 2], "--", color="0.3", lw=1.0, label="reference z")
        ax.legend(fontsize=7, loc="upper right")

    def draw_path(ax: Any, t: np.ndarray) -> None:
        ax.plot(t, np.linalg.norm(pos[:, :2] - ref[:, :2], axis=1), lw=1.0)

    return [
        Panel("normal force vs its reference", "force (N)", draw_force),
        Panel("tool tip height (world z) vs reference", "z (mm)", draw_height),
        Panel("path error in the surface plane ‖(p̄ − p)_xy‖", "error (mm)", draw_path),
    ], {
        "obs/wrench",
        "obs/f_ref",
        "obs/tool_pos",
        "obs/tool_pos_ref",
        "obs/tool_vel",
        "obs/tool_vel_ref",
    }


def _quat_angle(q: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """Rotation angle (T,) rad between unit quaternions (T, 4) and (T, 4)."""
    dot = np.abs(np.sum(q * q_ref, axis=1)) / (
        np.linalg.norm(q, axis=1) * np.linalg.norm(q_ref, axis=1)
    )
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def pose_error_panels(trace: dict[str, np.ndarray]) -> tuple[list[Panel], set[str]] | None:
    """Cartesian tasks (``x``/``x_ref``, optionally ``quat``/``quat_ref``): the position
    (path) error, the orientation error angle, and the path seen from above (x–y)."""
    if "obs/x" not in trace or "obs/x_ref" not in trace:
        return None
    x, ref = 1e3 * trace["obs/x"], 1e3 * trace["obs/x_ref"]
    error = np.linalg.norm(ref - x, axis=1)

    def draw_error(ax: Any, t: np.ndarray) -> None:
        _semilogy(ax, t, error)

    panels = [Panel("position (path) error ‖x̄ − x‖", "error (mm)", draw_error, log=True)]
    claimed = {
        "task_error",
        "obs/twist",
        "obs/twist_ref",
        "obs/acc_ref",
        "obs/xd_ref",
        "obs/obstacle",
    }
    if "obs/quat" in trace and "obs/quat_ref" in trace:
        angle = np.degrees(_quat_angle(trace["obs/quat"], trace["obs/quat_ref"]))

        def draw_angle(ax: Any, t: np.ndarray) -> None:
            _semilogy(ax, t, angle)

        panels.append(Panel("orientation error angle", "angle (°)", draw_angle, log=True))
        claimed |= {"obs/quat", "obs/quat_ref", "obs/omega_ref"}

    obstacle = trace.get("obs/obstacle")

    def draw_path(ax: Any, t: np.ndarray) -> None:
        if obstacle is not None and obstacle[0, -1] > 0:  # centre (x, y[, z]) and radius, m
            import matplotlib.patches

            centre, radius = 1e3 * obstacle[0, :2], 1e3 * obstacle[0, -1]
            ax.add_patch(
                matplotlib.patches.Circle(
                    centre, radius, color="tab:red", alpha=0.3, label="obstacle"
                )
            )
        _plane_path(ax, x[:, :2], ref[:, :2], "mm")
        ax.set_ylabel("y (mm)")

    view = "in the plane" if x.shape[1] == 2 else "seen from above (x–y)"
    panels.append(Panel(f"path {view}", "y (mm)", draw_path, plane=True))
    return panels, claimed


def feature_panels(trace: dict[str, np.ndarray]) -> tuple[list[Panel], set[str]] | None:
    """Visual servoing (``features``/``features_ref``, (u, v) of each point in px): the
    feature error (RMS point distance) and the points' trajectories in the image plane."""
    if "obs/features" not in trace or "obs/features_ref" not in trace:
        return None
    s, s_ref = trace["obs/features"], trace["obs/features_ref"]
    points = s.shape[1] // 2
    error = np.linalg.norm(s - s_ref, axis=1) / np.sqrt(points)  # RMS point distance

    def draw_error(ax: Any, t: np.ndarray) -> None:
        _semilogy(ax, t, error)

    def draw_image(ax: Any, t: np.ndarray) -> None:
        for i in range(points):
            colour = FEATURE_COLOURS[i % len(FEATURE_COLOURS)]
            u, v = s[:, 2 * i], s[:, 2 * i + 1]
            ax.plot(u, v, color=colour, lw=1.0)
            ax.plot(u[0], v[0], "o", color=colour, ms=5)
            ax.plot(s_ref[-1, 2 * i], s_ref[-1, 2 * i + 1], "x", color=colour, ms=8, mew=2)
        ax.set_aspect("equal", adjustable="datalim")
        ax.invert_yaxis()  # image rows grow downwards
        ax.set_xlabel("u (px)")
        ax.plot([], [], "ko", ms=5, label="start")
        ax.plot([], [], "kx", ms=8, mew=2, label="desired s*")
        ax.legend(fontsize=7)

    return [
        Panel(
            "feature error (RMS point distance, observed features)",
            "error (px)",
            draw_error,
            log=True,
        ),
        Panel("feature trajectories in the image plane", "v (px)", draw_image, plane=True),
    ], {"obs/features", "obs/features_ref"}


#: the task panel builders :func:`plot_episode` tries, in order (the first that matches wins
#: for a key it claims)
TASK_PANELS: tuple[TaskPanels, ...] = (
    peg_in_hole_panels,
    contact_force_panels,
    pose_error_panels,
    feature_panels,
)


def episode_panels(trace: dict[str, np.ndarray], max_dims: int = 7) -> list[Panel]:
    """The panels of :func:`plot_episode` for a recorded ``trace``: reference pairs, the
    task's own panels (:data:`TASK_PANELS`), the recorded errors, the actions."""
    task: list[Panel] = []
    claimed: set[str] = set()
    for build in TASK_PANELS:
        found = build(trace)
        if found is not None:
            task += found[0]
            claimed |= found[1]
    panels: list[Panel] = []
    for k in trace:
        if not (k.startswith("obs/") and k.endswith("_ref")) or k[:-4] not in trace:
            continue
        if k in claimed or k[:-4] in claimed:
            continue
        key = k[len("obs/") : -len("_ref")]
        act, ref = trace[f"obs/{key}"], trace[k]

        def draw_pair(ax: Any, t: np.ndarray, key: str = key, act: Any = act, ref: Any = ref):
            for j in range(min(act.shape[1], max_dims)):
                (line,) = ax.plot(t, act[:, j], lw=1.0, label=f"{key}[{j}]", zorder=3)
                ax.plot(t, ref[:, j], color=line.get_color(), lw=3.5, alpha=0.3)
            ax.legend(fontsize=6, ncol=min(act.shape[1], max_dims), loc="upper left")

        unit = OBS_UNITS.get(key, "")
        panels.append(
            Panel(
                f"{key}: actual (thin) vs reference (wide, light)",
                f"{key} ({unit})" if unit else key,
                draw_pair,
            )
        )
    panels += task
    for key, (what, unit) in ERRORS.items():
        if key in trace and key not in claimed:
            values = np.asarray(trace[key], dtype=float)

            def draw_error(ax: Any, t: np.ndarray, values: np.ndarray = values) -> None:
                _semilogy(ax, t, values)

            panels.append(Panel(what, f"error ({unit})", draw_error, log=True))
    actions = trace["action"]

    def draw_actions(ax: Any, t: np.ndarray) -> None:
        ax.plot(t, actions, lw=0.8)

    panels.append(Panel("actions (normalised commands)", "action (−1…1)", draw_actions))
    return panels


def plot_episode(
    result: EvaluationResult, path: str | Path, episode: int = 0, max_dims: int = 7
) -> Path:
    """One recorded episode of ``result`` (:func:`cir_gym.evaluation.evaluate` with
    ``record=True``) as a figure saved to ``path``: the quantities against time in the left
    column (a shared time axis, s), the paths in a plane (a spiral, image-plane features, a
    top view) in the right column (:func:`episode_panels`). Returns ``path``."""
    plt = _plt()
    trace = result.episodes[episode].trace
    if trace is None:
        raise ValueError("the evaluation was run without record=True")
    panels = episode_panels(trace, max_dims)
    timed = [p for p in panels if not p.plane]
    planes = [p for p in panels if p.plane]
    rows = len(timed)
    fig = plt.figure(figsize=(13.0 if planes else 9.0, 2.3 * rows + 0.6))
    grid = fig.add_gridspec(rows, 2 if planes else 1, width_ratios=[2.2, 1.0] if planes else None)
    t = np.arange(len(trace["action"])) * result.dt
    first = None
    for i, panel in enumerate(timed):
        ax = fig.add_subplot(grid[i, 0], sharex=first)
        first = first or ax
        panel.draw(ax, t)
        ax.set_title(panel.title, fontsize=9)
        ax.set_ylabel(panel.ylabel)
        ax.grid(True, which="both", alpha=0.3)
        if i < rows - 1:
            ax.tick_params(labelbottom=False)
    fig.axes[-1].set_xlabel("time (s)")  # the bottom axes of the time column
    for j, panel in enumerate(planes):
        lo, hi = rows * j // len(planes), rows * (j + 1) // len(planes)
        ax = fig.add_subplot(grid[lo : max(hi, lo + 1), 1])
        panel.draw(ax, t)
        ax.set_title(panel.title, fontsize=9)
        ax.set_ylabel(panel.ylabel)
        ax.grid(True, alpha=0.3)
    ep = result.episodes[episode]
    outcome = (
        "success"
        if ep.success
        else "diverged"
        if ep.diverged
        else "ended early, no success"
        if ep.terminated
        else "time limit, no success"
    )
    fig.suptitle(
        f"{result.policy_name} on {result.env_id} (seed {ep.seed}, {ep.length} steps, {outcome})"
    )
    fig.tight_layout()
    return _save(fig, path, plt)


# ---------------------------------------------------------------------- videos
def save_video(frames: list[np.ndarray], path: str | Path, fps: int) -> Path:
    """Write RGB frames to a GIF or MP4 (imageio; MP4 needs the imageio-ffmpeg plugin)."""
    try:
        import imageio.v3 as iio
    except ImportError as exc:  # pragma: no cover
        raise ImportError("videos need imageio: pip install 'cir-gym[plots]'") from exc
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        iio.imwrite(path, np.stack(frames), duration=1000 / fps, loop=0)
    elif path.suffix.lower() == ".mp4":
        try:
            iio.imwrite(path, np.stack(frames), fps=fps, codec="libx264")
        except Exception as exc:
            raise RuntimeError(
                f"cannot write MP4 ({exc}); install imageio-ffmpeg or use a .gif path"
            ) from exc
    else:
        raise ValueError(f"video path must end in .gif or .mp4, got {path}")
    return path
