"""Plots of recorded episodes and of leaderboards (matplotlib, imported lazily; Agg backend).

Generic over environments: every observation pair ``<key>`` / ``<key>_ref`` is drawn as
reference vs actual, the per-step ``joint_error`` / ``task_error`` as an error plot, and the
actions as commands, so a new environment gets its plots by naming its observations well.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cir_gym.evaluation import EvaluationResult

__all__ = ["plot_comparison", "plot_episode", "save_video"]


def _plt() -> Any:
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ImportError("plots need matplotlib: pip install 'cir-gym[plots]'") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_episode(
    result: EvaluationResult, path: str | Path, episode: int = 0, max_dims: int = 7
) -> Path:
    """Reference vs actual, errors and commands of one recorded episode, saved to ``path``."""
    plt = _plt()
    trace = result.episodes[episode].trace
    if trace is None:
        raise ValueError("the evaluation was run without record=True")
    pairs = [
        k[len("obs/") : -len("_ref")]
        for k in trace
        if k.startswith("obs/") and k.endswith("_ref") and f"{k[:-4]}" in trace
    ]
    errors = [k for k in ("joint_error", "task_error") if k in trace]
    rows = len(pairs) + len(errors) + 1
    fig, axes = plt.subplots(rows, 1, figsize=(9, 2.6 * rows), sharex=True, squeeze=False)
    t = np.arange(len(trace["action"])) * result.dt
    r = 0
    for key in pairs:
        ax = axes[r, 0]
        act, ref = trace[f"obs/{key}"], trace[f"obs/{key}_ref"]
        for j in range(min(act.shape[1], max_dims)):
            (line,) = ax.plot(t, act[:, j], lw=1.2, label=f"{key}[{j}]")
            ax.plot(t, ref[:, j], "--", color=line.get_color(), lw=0.9)
        ax.set_ylabel(key)
        ax.set_title(f"{key}: actual (solid) vs reference (dashed)", fontsize=9)
        r += 1
    for key in errors:
        ax = axes[r, 0]
        ax.semilogy(t, np.maximum(trace[key], 1e-12))
        ax.set_ylabel(f"‖{key}‖")
        ax.grid(True, which="both", alpha=0.3)
        r += 1
    ax = axes[r, 0]
    ax.plot(t, trace["action"], lw=0.8)
    ax.set_ylabel("action (−1…1)")
    ax.set_xlabel("time (s)")
    fig.suptitle(f"{result.policy_name} on {result.env_id} (seed {result.episodes[episode].seed})")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_comparison(results: list[EvaluationResult], path: str | Path, title: str = "") -> Path:
    """Bar chart (log scale) of the primary metric, mean with the worst episode, per policy."""
    plt = _plt()
    primary = results[0].primary_metric
    spec = results[0].spec(primary)
    names = [r.policy_name for r in results]
    means = np.array([r.summary[primary]["mean"] for r in results])
    worst = np.array([r.summary[primary]["worst"] for r in results])
    fig, ax = plt.subplots(figsize=(max(6, 0.9 * len(names) + 2), 4))
    x = np.arange(len(names))
    ax.bar(x, means, color="tab:blue", label="mean")
    ax.scatter(x, worst, color="tab:red", zorder=3, label="worst episode")
    ax.set_xticks(x, names, rotation=30, ha="right")
    if np.all(means[np.isfinite(means)] > 0):
        ax.set_yscale("log")
    ax.set_ylabel(f"{primary} ({spec.unit})" if spec.unit else primary)
    ax.set_title(title or results[0].env_id)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


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
