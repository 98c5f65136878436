"""Rows of the redundancy measures, of the self-motion walk and of the F/T sensor's gravity
compensation: each row gives the numbers it gives alone (what the row-vectorised laws of
baselines/kinematic.py and baselines/hybrid.py rely on), and the measures are what they say."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cir_gym import redundancy
from cir_gym.ft_sensor import contact_wrench, tool_gravity_wrench

LINKS = np.array([1.0, 0.8, 0.6])  # m, a planar 3R arm (dim ker J = 1 for its 2 x 3 J)
LOWER, UPPER = np.full(3, -2.5), np.full(3, 2.5)  # rad


def _position(q: np.ndarray) -> np.ndarray:
    """Tip position (2,) of the planar arm at one q (3,)."""
    angles = np.cumsum(q)
    return np.array([LINKS @ np.cos(angles), LINKS @ np.sin(angles)])


def _jacobian(q: np.ndarray) -> np.ndarray:
    """Position Jacobian (2, 3) of the planar arm at one q (3,)."""
    angles = np.cumsum(q)
    tail = lambda f: np.cumsum((LINKS * f(angles))[::-1])[::-1]  # noqa: E731
    return np.stack((-tail(np.sin), tail(np.cos)))


def _newton(x: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Three Newton steps of one configuration x (3,) to the tip position ``target``."""
    for _ in range(3):
        x = x + np.linalg.lstsq(_jacobian(x), target - _position(x), rcond=None)[0]
    return x


def _each(f, q: np.ndarray) -> np.ndarray:
    """f of each row of q (N, 3), stacked (the kinematics row by row, so a row's numbers do
    not depend on the batch: the walk's bookkeeping is what the tests below compare)."""
    return np.stack([f(x) for x in q])


def _rows(seed: int = 0, n: int = 5) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-2.0, 2.0, (n, 3))


def test_stacked_measures_equal_each_row_alone():
    q = _rows()
    J = _each(_jacobian, q)
    w = redundancy.manipulability(J)
    v = redundancy.null_vector(J)
    margin = redundancy.joint_limit_margin(q, LOWER, UPPER)
    grad = redundancy.joint_limit_objective_gradient(q, LOWER, UPPER)
    assert w.shape == margin.shape == (5,) and v.shape == grad.shape == (5, 3)
    for i in range(len(q)):
        assert w[i] == redundancy.manipulability(J[i])
        assert margin[i] == redundancy.joint_limit_margin(q[i], LOWER, UPPER)
        np.testing.assert_array_equal(v[i], redundancy.null_vector(J[i]))
        np.testing.assert_array_equal(grad[i], redundancy.joint_limit_objective_gradient(
            q[i], LOWER, UPPER))
        # and they are the textbook's quantities
        assert w[i] == pytest.approx(math.sqrt(np.linalg.det(J[i] @ J[i].T)), rel=1e-12)
        assert margin[i] == min(np.min(q[i] - LOWER), np.min(UPPER - q[i]))
        h = 1e-6
        fd = [(redundancy.joint_limit_objective(q[i] + h * e, LOWER, UPPER)
               - redundancy.joint_limit_objective(q[i] - h * e, LOWER, UPPER)) / (2 * h)
              for e in np.eye(3)]
        np.testing.assert_allclose(grad[i], fd, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose((J @ v[..., None])[..., 0], 0.0, atol=1e-12)
    assert type(redundancy.manipulability(J[0])) is float  # one J or q: a number
    assert type(redundancy.joint_limit_margin(q[0], LOWER, UPPER)) is float


def test_walk_of_rows_is_each_rows_walk_alone_and_holds_the_task():
    """walk_self_motions of rows (each holding its start's tip position by Newton steps, a
    side stopping within 0.3 rad of a limit): each row's points are its walk_self_motion
    points alone, bit for bit, though the rows stop at different steps."""
    q = _rows(0, 4)
    home = _each(_position, q)
    steps = list(redundancy.walk_self_motions(
        q,
        lambda x: _each(_jacobian, x),
        lambda x, rows: np.stack([_newton(xi, home[r]) for xi, r in zip(x, rows, strict=True)]),
        lambda rows, x, x_next: redundancy.joint_limit_margin(x_next, LOWER, UPPER) < 0.3,
        np.pi, 0.1))
    assert len({len(rows) for _, rows, _, _ in steps}) > 1  # some rows stopped before others
    for _, _, x, J in steps:  # the yielded Jacobians are those at the yielded points
        np.testing.assert_array_equal(J, _each(_jacobian, x))
    for i in range(len(q)):
        mine = [(s, x[list(rows).index(i)]) for s, rows, x, _ in steps if i in rows]
        alone = redundancy.walk_self_motion(
            q[i], _jacobian, lambda x, i=i: _newton(x, home[i]),
            lambda _, x: redundancy.joint_limit_margin(x, LOWER, UPPER) < 0.3, np.pi, 0.1)
        assert len(mine) > 3 and [s for s, _ in mine] == [s for s, _ in alone]
        assert any(s < 0 for s, _ in mine)
        for (_, a), (_, b) in zip(mine, alone, strict=True):
            np.testing.assert_array_equal(a, b)
            np.testing.assert_allclose(_position(a), home[i], atol=1e-8)
            assert redundancy.joint_limit_margin(a, LOWER, UPPER) >= 0.3


def _rotation(seed: int) -> np.ndarray:
    Q, R = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    return Q * np.sign(np.diag(R)) * np.linalg.det(Q * np.sign(np.diag(R)))


def test_gravity_compensation_of_rows_equals_each_row_alone():
    R = np.stack([_rotation(s) for s in range(4)])
    rng = np.random.default_rng(7)
    reading, bias = rng.normal(0, 5, (4, 6)), rng.normal(0, 0.5, (4, 6))
    mass, com = 0.3, np.array([0.01, -0.02, 0.05])
    static = tool_gravity_wrench(mass, com, R)
    h = contact_wrench(reading, R, tool_mass=mass, tool_com=com, bias=bias)
    assert static.shape == h.shape == (4, 6)
    for i in range(4):
        np.testing.assert_array_equal(static[i], tool_gravity_wrench(mass, com, R[i]))
        np.testing.assert_array_equal(h[i], contact_wrench(
            reading[i], R[i], tool_mass=mass, tool_com=com, bias=bias[i]))
    # the static tool's own reading (plus the bias) is no contact at all, in any row
    np.testing.assert_allclose(
        contact_wrench(static + bias, R, tool_mass=mass, tool_com=com, bias=bias), 0.0,
        atol=1e-12)
