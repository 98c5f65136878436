"""Small numeric helpers: clipping, episode reductions, index views."""

from __future__ import annotations

import numpy as np

#: ``np.clip(x, low, high, out)`` as numpy's clip ufunc itself: the same values without
#: np.clip's Python wrapper, which costs several times the work on a step's small arrays
#: (np.clip where numpy has no such module)
CLIP = getattr(getattr(getattr(np, "_core", None), "umath", None), "clip", np.clip)
#: ``np.add.reduce`` (``np.sum``); kept for the modules that import it
_SUM = np.add.reduce


def mean_of(x: np.ndarray) -> float:
    """Mean of every entry of ``x`` (float or bool, any shape), as a Python float."""
    return float(np.mean(x))


def rms_of(x: np.ndarray) -> float:
    """Root mean square of every entry of ``x``: sqrt(mean(x²))."""
    return float(np.sqrt(np.mean(np.square(x))))


def max_of(x: np.ndarray) -> float:
    """Largest entry of ``x`` (over every axis), as a Python float."""
    return float(np.max(x))


def index_view(index: np.ndarray) -> slice | np.ndarray:
    """A slice that selects what the integer array ``index`` selects, when its entries are
    evenly spaced (``qpos[s]`` is then a view: no copy, no fancy-indexing cost), else
    ``index`` itself. Used on the hot path for the robot's joints in ``qpos``/``qvel``."""
    idx = np.asarray(index, dtype=np.int64).ravel()
    if idx.size == 0 or np.any(idx < 0):
        return np.asarray(index)
    step = int(idx[1] - idx[0]) if idx.size > 1 else 1
    if step == 0:
        return np.asarray(index)
    stop = int(idx[-1]) + step
    view = slice(int(idx[0]), None if stop < 0 else stop, step)
    if not np.array_equal(np.arange(int(idx.max()) + 1)[view], idx):
        return np.asarray(index)
    return view
