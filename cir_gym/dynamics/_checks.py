"""Validation of the array arguments of the dynamics functions (real, shape, finiteness)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def as_real_array(name: str, value: ArrayLike, shape: str) -> np.ndarray:
    """Return ``value`` as a float array (any shape); complex or non-numeric input is an error.

    ``np.asarray(value, dtype=float)`` alone would drop the imaginary part of a complex input
    with only a ``ComplexWarning``.

    Args:
        name: argument name used in error messages.
        value: the argument.
        shape: the expected shape, for the error messages (e.g. "(7,) or (N, 7)").
    """
    try:
        array = np.asarray(value)
    except ValueError as error:  # e.g. ragged nested lists
        raise ValueError(f"{name} must be a real array of shape {shape}") from error
    if np.iscomplexobj(array):
        raise ValueError(
            f"{name} is complex ({array.dtype}); expected a real array of shape {shape}"
        )
    try:
        return array.astype(float, copy=False)
    except (TypeError, ValueError) as error:  # objects that are not real numbers
        raise ValueError(f"{name} must be a real array of shape {shape}") from error


def as_batch(
    name: str, value: ArrayLike, n: int, *, per_joint: bool = True
) -> tuple[np.ndarray, bool]:
    """Return ``value`` as a float array of shape (N, n) and whether it was a single vector.

    Args:
        name: argument name used in error messages.
        value: array of shape (n,) or (N, n).
        n: number of entries (joints, or 6 for a wrench).
        per_joint: say "one entry per joint" in error messages.

    Raises:
        ValueError: not real (e.g. complex), wrong shape, or NaN/inf entries.
    """
    array = as_real_array(name, value, f"({n},) or (N, {n})")
    if array.ndim == 1 and array.shape[0] == n:
        single = True
        array = array[None, :]
    elif array.ndim == 2 and array.shape[1] == n:
        single = False
    else:
        where = f" (one entry per joint of this {n}-joint chain)" if per_joint else ""
        raise ValueError(f"{name} has shape {array.shape}, expected ({n},) or (N, {n}){where}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} contains NaN or inf; expected finite values")
    return array, single


def matching_batch(
    name: str, value: ArrayLike, n: int, like: np.ndarray, single: bool, *, per_joint: bool = True
) -> np.ndarray:
    """Return ``value`` as (N, n) with the same batch layout as ``q`` (already checked)."""
    array, value_single = as_batch(name, value, n, per_joint=per_joint)
    if value_single != single or (not single and array.shape[0] != like.shape[0]):
        expected = f"({n},)" if single else f"({like.shape[0]}, {n})"
        shape = array.shape[1:] if value_single else array.shape
        raise ValueError(f"{name} has shape {shape}, expected {expected} like q")
    return array


def as_vector(name: str, value: ArrayLike, size: int) -> np.ndarray:
    """Return ``value`` as a finite float vector of shape (size,)."""
    array = as_real_array(name, value, f"({size},)")
    if array.shape != (size,):
        raise ValueError(f"{name} has shape {array.shape}, expected ({size},)")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or inf; expected finite values")
    return array
