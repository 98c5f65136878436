"""Small numeric helpers of the hot paths: clipping and episode reductions."""

from __future__ import annotations

import math

import numpy as np

#: numpy's clip ufunc without np.clip's Python wrapper (~4x cheaper on small arrays; the same
#: values); np.clip itself where numpy has no such private module.
CLIP = getattr(getattr(getattr(np, "_core", None), "umath", None), "clip", np.clip)
_MAX = np.maximum.reduce
_SUM = np.add.reduce


def mean_of(x: np.ndarray) -> float:
    """``float(np.mean(x))`` of a float or bool array of any shape, bit for bit: numpy's own
    reduction (np.mean sums with ``np.add.reduce`` and divides by the count) without
    np.mean's Python layers; the episode metrics' hot path."""
    if x.size == 0 or x.dtype.kind != "f":
        return float(np.mean(x))
    return float(_SUM(x, None)) / x.size


def rms_of(x: np.ndarray) -> float:
    """``float(np.sqrt(np.mean(x**2)))``, bit for bit (IEEE sqrt: math's is numpy's)."""
    return math.sqrt(mean_of(x**2))


def max_of(x: np.ndarray) -> float:
    """``float(np.max(x))`` (over every axis), bit for bit."""
    return float(_MAX(x, None))


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
