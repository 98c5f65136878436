"""``np.linalg.solve`` without its Python layers, for the per-step hot paths.

``np.linalg.solve(a, b)`` checks and converts its arguments in Python (~6 µs on these 3- to
7-element systems, more than the LAPACK call) before it runs numpy's own gufunc under a
floating-point error state that turns a singular matrix into ``LinAlgError``. :func:`solve`
runs that very gufunc (``solve1`` for a vector right-hand side, ``solve`` for a matrix one)
under that very error state, set with a context-variable token made once at import: the same
bits and the same errors for float64 operands. Where numpy's private layout differs (another
numpy), it is ``np.linalg.solve`` itself.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["solve"]


def _numpy_solve_internals() -> tuple[Any, Any, Any, Any]:
    """(numpy's floating-point error-state context variable, np.linalg.solve's error state,
    the one-vector gufunc, the matrix gufunc); all None where numpy's layout differs."""
    try:
        from numpy._core._ufunc_config import _extobj_contextvar
        from numpy._core.umath import _make_extobj
        from numpy.linalg import _umath_linalg
        from numpy.linalg._linalg import _raise_linalgerror_singular

        state = _make_extobj(  # np.linalg.solve's own errstate
            call=_raise_linalgerror_singular,
            invalid="call",
            over="ignore",
            divide="ignore",
            under="ignore",
        )
        return _extobj_contextvar, state, _umath_linalg.solve1, _umath_linalg.solve
    except (ImportError, AttributeError, TypeError):  # another numpy: np.linalg.solve
        return None, None, None, None


_FP_STATE, _SOLVE_STATE, _SOLVE1, _SOLVE = _numpy_solve_internals()


def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(a, b)``, bit for bit and with its errors (``LinAlgError`` on a
    singular matrix), for a float64 (n, n) ``a`` and a float64 (n,) or (n, k) ``b``."""
    if _FP_STATE is None:
        return np.linalg.solve(a, b)
    gufunc = _SOLVE1 if b.ndim == 1 else _SOLVE
    token = _FP_STATE.set(_SOLVE_STATE)
    try:
        return gufunc(a, b, signature="dd->d")
    finally:
        _FP_STATE.reset(token)
