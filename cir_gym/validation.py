"""Argument validation: every argument checked once, the error naming the argument, the value
and what is allowed."""

from __future__ import annotations

from typing import Any

import numpy as np


class InvalidArgument(ValueError, TypeError):
    """An unknown or out-of-range constructor argument (a ValueError and a TypeError)."""


def check_number(
    name: str, value: Any, low: float = -np.inf, high: float = np.inf, *, low_open: bool = False
) -> float:
    """Return ``value`` as a float in [low, high] (or (low, high]); else InvalidArgument."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InvalidArgument(f"{name} must be a number, got {type(value).__name__} {value!r}")
    v = float(value)
    bad = not np.isfinite(v) and not (np.isinf(v) and np.isinf(high) and v > 0)
    if bad or v < low or v > high or (low_open and v <= low):
        lo = "(" if low_open else "["
        raise InvalidArgument(f"{name} must be in {lo}{low}, {high}], got {value!r}")
    return v


def check_encoder_resolution(value: Any) -> float:
    """An encoder quantum (rad): 0 (exact) or in [1e-12, 0.1]; else InvalidArgument."""
    res = check_number("encoder_resolution", value, 0.0, 0.1)
    if 0.0 < res < 1e-12:
        raise InvalidArgument(
            f"encoder_resolution must be 0 (exact) or in [1e-12, 0.1] rad, got {value!r}"
        )
    return res


def check_flag(name: str, value: Any) -> bool:
    """``value`` as a bool (a Python or numpy bool only); else InvalidArgument."""
    if not isinstance(value, (bool, np.bool_)):
        raise InvalidArgument(f"{name} must be True or False, got {value!r}")
    return bool(value)


def as_float_array(name: str, value: Any) -> np.ndarray:
    """``value`` as a float array, or :class:`InvalidArgument` naming ``name``."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidArgument(
            f"{name} must be a number or a sequence of numbers, got {value!r}"
        ) from exc
    if not np.all(np.isfinite(arr)):
        raise InvalidArgument(f"{name} must be finite, got {value!r}")
    return arr
