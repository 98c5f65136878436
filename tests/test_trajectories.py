"""Tests of cir_gym.trajectories: boundary conditions, derivatives against finite differences,
limits, closed paths, quaternions and orientation interpolation, input validation."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from cir_gym.trajectories import (
    Circle,
    CubicPolynomial,
    Ellipse,
    FigureEight,
    JointSpline,
    OrientationInterpolation,
    QuinticPolynomial,
    Segment,
    SineTrajectory,
    TimingLaw,
    Trajectory,
    Trapezoidal,
    axis_angle_from_matrix,
    matrix_from_axis_angle,
    matrix_from_quat,
    quat_conj,
    quat_from_matrix,
    quat_mul,
    random_joint_trajectory,
    slerp,
)

FAST = settings(max_examples=40, deadline=None)

coord = st.floats(-3.0, 3.0, allow_nan=False)
vec3 = hnp.arrays(np.float64, 3, elements=coord)
durations = st.floats(0.2, 10.0)


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------


def vee(S: np.ndarray) -> np.ndarray:
    """ω from a skew-symmetric matrix S(ω) (..., 3, 3)."""
    return np.stack([S[..., 2, 1], S[..., 0, 2], S[..., 1, 0]], axis=-1)


def sample_times(duration: float, breakpoints=(), k: int = 40, seed: int = 0) -> np.ndarray:
    """Random times inside (0, duration) at least 1e-3 s away from every breakpoint."""
    T = duration if math.isfinite(duration) else 10.0
    t = np.random.default_rng(seed).uniform(0.01 * T, 0.99 * T, size=4 * k)
    for b in breakpoints:
        t = t[np.abs(t - b) > 1e-3]
    return t[:k]


def assert_derivatives(traj, times: np.ndarray, h: float = 1e-5) -> None:
    """v and a against central differences of p and of v."""
    p, v, a = traj.evaluate(times)
    p_plus, v_plus, _ = traj.evaluate(times + h)
    p_minus, v_minus, _ = traj.evaluate(times - h)
    scale = 1.0 + max(np.max(np.abs(p)), np.max(np.abs(v)), np.max(np.abs(a)))
    np.testing.assert_allclose((p_plus - p_minus) / (2 * h), v, rtol=0, atol=1e-6 * scale)
    np.testing.assert_allclose((v_plus - v_minus) / (2 * h), a, rtol=0, atol=1e-6 * scale)


def quat_angle(q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Rotation angle (rad) between unit quaternions (accurate for small angles)."""
    d = quat_mul(quat_conj(q0), q1)
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    return matrix_from_quat(rng.normal(size=4))


# --------------------------------------------------------------------------------------------
# every trajectory: protocol, derivatives, holding outside [0, duration]
# --------------------------------------------------------------------------------------------


def _trapezoidal_breaks(tr: Trapezoidal) -> list[float]:
    return [*tr.accel_time, *(tr.duration - tr.accel_time)]


def _cases():
    q0, q1 = np.array([0.1, -0.5, 1.0]), np.array([1.2, 0.3, -0.7])
    tr_min = Trapezoidal(q0, q1, v_max=[0.8, 1.0, 0.5], a_max=[2.0, 1.0, 3.0])
    tr_dur = Trapezoidal(q0, q1, v_max=1.0, a_max=2.0, duration=5.0)
    tri = Trapezoidal(0.0, 0.1, v_max=1.0, a_max=2.0)
    spline = JointSpline([0.0, 0.7, 1.5, 3.0, 3.4], np.random.default_rng(1).normal(size=(5, 2)))
    tl_trap = TimingLaw.trapezoidal(2.0, 0.5, accel_fraction=0.25)
    quintic = TimingLaw.quintic(2.5)
    return [
        ("cubic", CubicPolynomial(q0, q1, 2.0, v0=[0.5, 0, -1], v1=[0, 1, 0.2]), []),
        ("quintic", QuinticPolynomial(q0, q1, 1.5, v0=1, v1=-1, a0=2, a1=[0, 1, 2]), []),
        ("trapezoidal-min", tr_min, _trapezoidal_breaks(tr_min)),
        ("trapezoidal-duration", tr_dur, _trapezoidal_breaks(tr_dur)),
        ("triangular", tri, _trapezoidal_breaks(tri)),
        ("spline", spline, list(spline.times)),
        ("sine", SineTrajectory([0, 1], [0.5, 0.2], [0.3, 1.1], [0, 1]), []),
        ("timing-quintic", quintic, []),
        ("timing-cubic", TimingLaw.cubic(1.0, 3.0), []),
        ("timing-trapezoidal", tl_trap, [0.5, 1.5]),
        ("timing-linear", TimingLaw.linear(2.0), []),
        ("timing-periodic", TimingLaw.linear(2.0, periodic=True), []),
        ("segment-3d", Segment([0.4, 0, 0.3], [0.5, 0.2, 0.6], quintic), []),
        ("segment-2d", Segment([0, 0], [1, -1], tl_trap), [0.5, 1.5]),
        ("circle-2d", Circle([0.5, 0.1], 0.2, quintic, start_angle=0.3), []),
        ("circle-3d", Circle([0.5, 0, 0.4], 0.1, quintic, normal=[1, 1, 1], turns=2), []),
        ("circle-periodic", Circle([0, 0, 0], 0.1, TimingLaw.linear(1.5, periodic=True)), []),
        ("ellipse", Ellipse([0, 0, 1], 0.3, 0.1, quintic, axes=([0, 1, 0], [0, 0, 1])), []),
        ("figure-eight", FigureEight([0.5, 0, 0.5], 0.2, 0.1, quintic, normal=[0, 1, 0]), []),
        ("figure-eight-2d", FigureEight([0, 0], 0.2, 0.1, tl_trap, turns=-1), [0.5, 1.5]),
    ]


CASES = _cases()
CASE_IDS = [name for name, _, _ in CASES]


@pytest.mark.parametrize(("name", "traj", "breaks"), CASES, ids=CASE_IDS)
def test_derivatives_match_finite_differences(name, traj, breaks):
    assert isinstance(traj, Trajectory)
    assert_derivatives(traj, sample_times(traj.duration, breaks))


@pytest.mark.parametrize(("name", "traj", "breaks"), CASES, ids=CASE_IDS)
def test_shapes_and_holding_outside(name, traj, breaks):
    p, v, a = traj.evaluate(0.3)
    P, V, A = traj.evaluate(np.array([0.3, 0.4]))
    assert P.shape == (2, *np.shape(p)) and V.shape == P.shape and A.shape == P.shape
    np.testing.assert_array_equal(P[0], p)
    start = traj.evaluate(0.0)[0]
    p, v, a = traj.evaluate(-1.0)
    np.testing.assert_array_equal(p, start)
    assert np.all(v == 0) and np.all(a == 0)
    if math.isfinite(traj.duration):
        end = traj.evaluate(traj.duration)[0]
        p, v, a = traj.evaluate(traj.duration + 1.0)
        np.testing.assert_array_equal(p, end)
        assert np.all(v == 0) and np.all(a == 0)


@pytest.mark.parametrize(("name", "traj", "breaks"), CASES, ids=CASE_IDS)
def test_immutable_and_picklable(name, traj, breaks):
    with pytest.raises(AttributeError):
        traj.duration = 1.0
    copy = pickle.loads(pickle.dumps(traj))
    t = sample_times(traj.duration, k=5)
    for x, y in zip(traj.evaluate(t), copy.evaluate(t), strict=True):
        np.testing.assert_array_equal(x, y)
    assert type(traj).__name__ in repr(traj)


def test_scalar_points_give_one_dimension():
    p, v, a = CubicPolynomial(0.0, 1.0, 2.0).evaluate(1.0)
    assert p.shape == v.shape == a.shape == (1,)
    assert p[0] == pytest.approx(0.5)
    P, _, _ = QuinticPolynomial(0.0, 1.0, 2.0).evaluate(np.linspace(0, 2, 7))
    assert P.shape == (7, 1)


def test_timing_law_returns_scalars():
    s, sd, sdd = TimingLaw.quintic(2.0).evaluate(1.0)
    assert all(isinstance(x, float) for x in (s, sd, sdd))
    assert s == pytest.approx(0.5)
    s, _, _ = TimingLaw.quintic(2.0, length=3.0).evaluate(np.array([0.0, 2.0, 5.0]))
    np.testing.assert_allclose(s, [0.0, 3.0, 3.0])


# --------------------------------------------------------------------------------------------
# point-to-point polynomials
# --------------------------------------------------------------------------------------------


@FAST
@given(q0=vec3, q1=vec3, v0=vec3, v1=vec3, T=durations)
def test_cubic_boundary_conditions(q0, q1, v0, v1, T):
    traj = CubicPolynomial(q0, q1, T, v0=v0, v1=v1)
    (p0, vel0, _), (p1, vel1, _) = traj.evaluate(0.0), traj.evaluate(T)
    scale = 1 + np.max(np.abs([q0, q1, v0, v1])) * max(1.0, T)
    np.testing.assert_allclose(p0, q0, atol=1e-12 * scale)
    np.testing.assert_allclose(vel0, v0, atol=1e-12 * scale)
    np.testing.assert_allclose(p1, q1, atol=1e-11 * scale)
    np.testing.assert_allclose(vel1, v1, atol=1e-11 * scale)


@FAST
@given(q0=vec3, q1=vec3, v0=vec3, v1=vec3, a0=vec3, a1=vec3, T=durations)
def test_quintic_boundary_conditions(q0, q1, v0, v1, a0, a1, T):
    traj = QuinticPolynomial(q0, q1, T, v0=v0, v1=v1, a0=a0, a1=a1)
    start, end = traj.evaluate(0.0), traj.evaluate(T)
    scale = (1 + np.max(np.abs([q0, q1, v0, v1, a0, a1]))) * max(1.0, T) ** 2
    for got, want in zip((*start, *end), (q0, v0, a0, q1, v1, a1), strict=True):
        np.testing.assert_allclose(got, want, atol=1e-10 * scale)


def test_rest_to_rest_quintic_is_symmetric():
    traj = QuinticPolynomial(0.0, 1.0, 2.0)
    p, v, a = traj.evaluate(1.0)
    assert p[0] == pytest.approx(0.5)
    assert v[0] == pytest.approx(15 / 8 / 2)  # peak speed 15 Δq / (8 T)
    assert a[0] == pytest.approx(0.0, abs=1e-12)


# --------------------------------------------------------------------------------------------
# trapezoidal velocity profile
# --------------------------------------------------------------------------------------------


@FAST
@given(
    q0=vec3,
    q1=vec3,
    v_max=hnp.arrays(np.float64, 3, elements=st.floats(0.1, 5.0)),
    a_max=hnp.arrays(np.float64, 3, elements=st.floats(0.1, 10.0)),
    stretch=st.one_of(st.none(), st.floats(1.0, 3.0)),
)
def test_trapezoidal_respects_limits_and_reaches_goal(q0, q1, v_max, a_max, stretch):
    t_min = Trapezoidal.minimum_duration(q0, q1, v_max=v_max, a_max=a_max)
    duration = None if stretch is None or t_min == 0 else stretch * t_min
    traj = Trapezoidal(q0, q1, v_max=v_max, a_max=a_max, duration=duration)
    assert traj.duration == pytest.approx(t_min if duration is None else duration)
    t = np.linspace(0.0, traj.duration, 2001)
    p, v, a = traj.evaluate(t)
    assert np.all(np.abs(v) <= v_max + 1e-9)
    assert np.all(np.abs(a) <= a_max + 1e-9)
    np.testing.assert_allclose(p[0], q0, atol=1e-12)
    np.testing.assert_allclose(p[-1], q1, atol=1e-9)
    np.testing.assert_allclose(v[[0, -1]], 0.0, atol=1e-9)
    # Continuous position: steps between samples bounded by the speed limit.
    dt = t[1] - t[0]
    assert np.all(np.abs(np.diff(p, axis=0)) <= v_max * dt + 1e-9)
    # Continuous velocity: steps bounded by the acceleration limit, on the grid and on a fine
    # grid straddling each dimension's switch times t_c and t_f − t_c.
    assert np.all(np.abs(np.diff(v, axis=0)) <= a_max * dt + 1e-9)
    fine = 1e-6 * traj.duration
    for i, t_c in enumerate(traj.accel_time):
        for t_switch in (t_c, traj.duration - t_c):
            t_fine = t_switch + fine * np.arange(-5, 6)
            v_fine = traj.evaluate(t_fine)[1][:, i]
            assert np.all(np.abs(np.diff(v_fine)) <= a_max[i] * fine + 1e-9)


def test_trapezoidal_synchronises_on_the_slowest_dimension():
    traj = Trapezoidal([0, 0, 0], [2.0, -0.5, 0.0], v_max=1.0, a_max=1.0)
    assert traj.duration == pytest.approx(2.0 / 1.0 + 1.0 / 1.0)  # |Δq|/v + v/a
    np.testing.assert_allclose(traj.cruise_velocity[0], 1.0)
    assert abs(traj.cruise_velocity[1]) < 1.0
    np.testing.assert_allclose(traj.evaluate(traj.duration)[0], [2.0, -0.5, 0.0])
    np.testing.assert_array_equal(traj.evaluate(1.3)[0][2], 0.0)  # a dimension at rest


def test_trapezoidal_with_duration_uses_textbook_acceleration_time():
    q0, q1, a_max, T = 0.3, 1.5, 2.0, 3.0
    traj = Trapezoidal(q0, q1, v_max=10.0, a_max=a_max, duration=T)
    t_c = T / 2 - 0.5 * math.sqrt((T**2 * a_max - 4 * (q1 - q0)) / a_max)
    assert traj.accel_time[0] == pytest.approx(t_c)
    assert traj.cruise_velocity[0] == pytest.approx(a_max * t_c)
    _, v, a = traj.evaluate(np.array([t_c / 2, T / 2, T - t_c / 2]))
    np.testing.assert_allclose(a[:, 0], [a_max, 0.0, -a_max])
    assert v[1, 0] == pytest.approx(a_max * t_c)


def test_trapezoidal_triangular_profile():
    h, v_max, a_max = 0.1, 1.0, 2.0  # h < v_max² / a_max: no cruise phase
    traj = Trapezoidal(0.0, h, v_max=v_max, a_max=a_max)
    assert traj.triangular[0]
    assert traj.duration == pytest.approx(2 * math.sqrt(h / a_max))
    assert traj.accel_time[0] == pytest.approx(traj.duration / 2)
    _, v, _ = traj.evaluate(np.linspace(0, traj.duration, 1001))
    assert np.max(v) == pytest.approx(math.sqrt(a_max * h), rel=1e-3)
    assert np.max(v) < v_max
    assert not Trapezoidal(0.0, 2.0, v_max=v_max, a_max=a_max).triangular[0]


def test_trapezoidal_infeasible_duration_states_the_minimum():
    t_min = Trapezoidal.minimum_duration([0, 0], [1.0, 3.0], v_max=1.0, a_max=2.0)
    assert t_min == pytest.approx(3.5)
    with pytest.raises(ValueError, match=r"minimum feasible duration is 3\.5 s"):
        Trapezoidal([0, 0], [1.0, 3.0], v_max=1.0, a_max=2.0, duration=3.0)
    Trapezoidal([0, 0], [1.0, 3.0], v_max=1.0, a_max=2.0, duration=3.5)  # exactly feasible


def test_trapezoidal_timing_law():
    law = TimingLaw.trapezoidal(4.0, 2.0, accel_fraction=0.25)
    s, sd, _ = law.evaluate(np.linspace(0, 4, 401))
    assert s[-1] == pytest.approx(2.0)
    assert np.max(sd) == pytest.approx(2.0 / 3.0)  # length / (t_f - t_c)
    triangular = TimingLaw.trapezoidal(1.0, accel_fraction=0.5)
    assert triangular.evaluate(1.0)[0] == pytest.approx(1.0)


# --------------------------------------------------------------------------------------------
# splines and random joint trajectories
# --------------------------------------------------------------------------------------------


@st.composite
def spline_data(draw):
    n = draw(st.integers(2, 7))
    d = draw(st.integers(1, 3))
    steps = draw(hnp.arrays(np.float64, n - 1, elements=st.floats(0.1, 2.0)))
    times = np.concatenate([[0.0], np.cumsum(steps)])
    points = draw(hnp.arrays(np.float64, (n, d), elements=coord))
    v0 = draw(hnp.arrays(np.float64, d, elements=coord))
    v1 = draw(hnp.arrays(np.float64, d, elements=coord))
    return times, points, v0, v1


@FAST
@given(data=spline_data())
def test_spline_interpolates_and_is_c2_at_knots(data):
    times, points, v0, v1 = data
    spline = JointSpline(times, points, v0=v0, v1=v1)
    assert spline.duration == times[-1]
    p, v, _ = spline.evaluate(times)
    np.testing.assert_allclose(p, points, atol=1e-9)
    np.testing.assert_allclose(v[0], v0, atol=1e-9)
    np.testing.assert_allclose(v[-1], v1, atol=1e-9)
    eps = 1e-9
    inner = times[1:-1]
    if inner.size:
        left = spline.evaluate(inner - eps)
        right = spline.evaluate(inner + eps)
        # Across 2 eps a continuous quantity changes by at most 2 eps · |its derivative|.
        jerk = 6.0 * np.max(np.abs(spline.coefficients[:, 3]))
        rates = (np.max(np.abs(left[1])), np.max(np.abs(left[2])), jerk)
        for x, y, rate in zip(left, right, rates, strict=True):
            tol = 2.5 * eps * rate + 1e-9 * (1.0 + np.max(np.abs(x)))
            np.testing.assert_allclose(x, y, rtol=0, atol=tol)
    assert_derivatives(spline, sample_times(spline.duration, times, k=20))


@FAST
@given(data=spline_data())
def test_spline_exact_bounds_match_dense_grid(data):
    times, points, v0, v1 = data
    spline = JointSpline(times, points, v0=v0, v1=v1)
    t, dt = np.linspace(0, spline.duration, 4001, retstep=True)
    p, v, a = spline.evaluate(t)
    peak = spline.peak_velocity()
    lo, hi = spline.position_range()
    # The exact extrema bound the grid's; the grid misses at most |a| dt (speed) and
    # ½ |a| dt² (position, where q̇ = 0 at the extremum).
    tol_v = np.max(np.abs(a)) * dt + 1e-9
    tol_p = 0.5 * np.max(np.abs(a)) * dt**2 + 1e-9
    assert np.all(np.max(np.abs(v), axis=0) <= peak + 1e-9)
    np.testing.assert_allclose(np.max(np.abs(v), axis=0), peak, rtol=0, atol=tol_v)
    assert np.all(p.min(axis=0) >= lo - 1e-9) and np.all(p.max(axis=0) <= hi + 1e-9)
    np.testing.assert_allclose(p.min(axis=0), lo, rtol=0, atol=tol_p)
    np.testing.assert_allclose(p.max(axis=0), hi, rtol=0, atol=tol_p)


def test_spline_with_two_points_is_the_cubic():
    spline = JointSpline([0.0, 2.0], [[0.0, 1.0], [1.0, -1.0]], v0=[0.5, 0.0], v1=[0.0, 1.0])
    cubic = CubicPolynomial([0.0, 1.0], [1.0, -1.0], 2.0, v0=[0.5, 0.0], v1=[0.0, 1.0])
    t = np.linspace(0, 2, 11)
    for x, y in zip(spline.evaluate(t), cubic.evaluate(t), strict=True):
        np.testing.assert_allclose(x, y, atol=1e-12)


LOWER = np.array([-2.9, -2.0, -2.9, -2.0, -2.9, -2.0, -3.0])
UPPER = -LOWER
V_LIMIT = 0.5 * np.array([1.5, 1.5, 1.7, 2.2, 2.4, 3.1, 3.1])  # half a robot's limits


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_points=st.integers(2, 8), margin=st.floats(0.0, 0.3))
def test_random_joint_trajectory_limits(seed, n_points, margin):
    traj = random_joint_trajectory(
        np.random.default_rng(seed),
        LOWER,
        UPPER,
        duration=8.0,
        n_points=n_points,
        v_max=V_LIMIT,
        margin=margin,
    )
    p, v, _ = traj.evaluate(np.linspace(0.0, 8.0, 8001))
    span = UPPER - LOWER
    assert np.all(p >= LOWER + margin * span - 1e-12)
    assert np.all(p <= UPPER - margin * span + 1e-12)
    assert np.all(np.abs(v) <= V_LIMIT)
    np.testing.assert_allclose(v[[0, -1]], 0.0, atol=1e-12)
    assert np.all(np.abs(traj.peak_velocity()) <= V_LIMIT)


def test_random_joint_trajectory_is_deterministic_and_starts_at_start():
    kwargs = {"duration": 5.0, "n_points": 4, "v_max": V_LIMIT}
    a = random_joint_trajectory(np.random.default_rng(3), LOWER, UPPER, **kwargs)
    b = random_joint_trajectory(np.random.default_rng(3), LOWER, UPPER, **kwargs)
    c = random_joint_trajectory(np.random.default_rng(4), LOWER, UPPER, **kwargs)
    np.testing.assert_array_equal(a.points, b.points)
    assert not np.allclose(a.points, c.points)
    np.testing.assert_array_equal(
        random_joint_trajectory(3, LOWER, UPPER, **kwargs).points, a.points
    )
    start = np.linspace(-1.0, 1.0, 7)
    traj = random_joint_trajectory(np.random.default_rng(0), LOWER, UPPER, start=start, **kwargs)
    p, v, _ = traj.evaluate(0.0)
    np.testing.assert_array_equal(p, start)
    np.testing.assert_array_equal(v, 0.0)
    assert traj.duration == 5.0


# --------------------------------------------------------------------------------------------
# Cartesian paths
# --------------------------------------------------------------------------------------------

CLOSED = [
    Circle([0.5, 0.1], 0.2, TimingLaw.quintic(2.0), start_angle=1.0),
    Circle([0.5, 0.0, 0.4], 0.1, TimingLaw.trapezoidal(3.0), normal=[0.2, -1, 0.5], turns=3),
    Ellipse([0, 0], 0.3, 0.1, TimingLaw.cubic(1.0), turns=-1),
    Ellipse([0, 0, 1], 0.3, 0.1, TimingLaw.quintic(1.0), axes=([0, 0.6, 0.8], [1, 0, 0])),
    FigureEight([0.0, 0.0], 0.2, 0.1, TimingLaw.quintic(4.0)),
    FigureEight([0.5, 0, 0.5], 0.2, 0.1, TimingLaw.linear(4.0), normal=[1, 0, 0]),
]


@pytest.mark.parametrize("path", CLOSED, ids=lambda p: f"{type(p).__name__}-{p.dim}d")
def test_closed_paths_return_to_start(path):
    assert path.closed
    np.testing.assert_allclose(path.evaluate(path.duration)[0], path.evaluate(0.0)[0], atol=1e-12)
    p, v, a = path.evaluate(np.linspace(0.0, path.duration, 501))
    assert p.shape[1] == path.dim
    if path.dim == 3:
        n = path.normal
        for x in (p - path.center, v, a):
            np.testing.assert_allclose(x @ n, 0.0, atol=1e-12)


def test_circle_radius_and_plane():
    normal = np.array([1.0, 2.0, 2.0]) / 3.0
    circle = Circle([0.4, -0.1, 0.6], 0.15, TimingLaw.quintic(2.0), normal=normal)
    np.testing.assert_allclose(circle.normal, normal, atol=1e-15)
    p, v, _ = circle.evaluate(np.linspace(0.0, 2.0, 301))
    r = p - circle.center
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), 0.15, atol=1e-12)
    np.testing.assert_allclose(r @ normal, 0.0, atol=1e-12)
    np.testing.assert_allclose(np.sum(r * v, axis=1), 0.0, atol=1e-12)  # velocity ⟂ radius
    np.testing.assert_allclose(v[[0, -1]], 0.0, atol=1e-12)  # quintic: rest to rest
    default = Circle([0, 0, 0], 1.0, TimingLaw.quintic(1.0))
    np.testing.assert_allclose(default.evaluate(0.0)[0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(default.normal, [0.0, 0.0, 1.0])


def test_periodic_circle_repeats_at_constant_speed():
    circle = Circle([0, 0], 0.5, TimingLaw.linear(2.0, periodic=True))
    assert circle.duration == math.inf
    t = np.linspace(0.0, 2.0, 50)
    p0, v, _ = circle.evaluate(t)
    p1, _, _ = circle.evaluate(t + 2.0 * 7)
    np.testing.assert_allclose(p1, p0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 2 * np.pi * 0.5 / 2.0)


def test_segment_and_figure_eight_geometry():
    seg = Segment([0, 0, 0], [0.3, 0.4, 0.0], TimingLaw.quintic(1.0))
    assert seg.length == pytest.approx(0.5)
    p, _, _ = seg.evaluate(np.linspace(0, 1, 11))
    np.testing.assert_allclose(np.cross(p, [0.3, 0.4, 0.0]), 0.0, atol=1e-15)  # on the line
    np.testing.assert_allclose(p[-1], [0.3, 0.4, 0.0])
    eight = FigureEight([1.0, 2.0], 0.2, 0.1, TimingLaw.linear(1.0))
    p, _, _ = eight.evaluate(np.linspace(0, 1, 2001))
    np.testing.assert_allclose(eight.evaluate(0.5)[0], [1.0, 2.0], atol=1e-12)  # crosses center
    np.testing.assert_allclose(np.max(np.abs(p - [1.0, 2.0]), axis=0), [0.2, 0.1], rtol=1e-5)


def test_non_integer_turns_is_open():
    arc = Circle([0, 0], 1.0, TimingLaw.quintic(1.0), turns=0.25)
    assert not arc.closed
    np.testing.assert_allclose(arc.evaluate(1.0)[0], [0.0, 1.0], atol=1e-12)


# --------------------------------------------------------------------------------------------
# quaternions and orientation
# --------------------------------------------------------------------------------------------

quats = hnp.arrays(np.float64, 4, elements=st.floats(-1, 1)).filter(
    lambda q: np.linalg.norm(q) > 0.1
)


@FAST
@given(q=quats, r=quats)
def test_quaternion_matrix_round_trip_and_product(q, r):
    q, r = q / np.linalg.norm(q), r / np.linalg.norm(r)
    R, S = matrix_from_quat(q), matrix_from_quat(r)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    back = quat_from_matrix(R)
    assert back[0] >= 0.0
    np.testing.assert_allclose(abs(back @ q), 1.0, atol=1e-9)  # q and -q: same rotation
    np.testing.assert_allclose(matrix_from_quat(quat_mul(q, r)), R @ S, atol=1e-12)
    np.testing.assert_allclose(quat_mul(q, quat_conj(q)), [1, 0, 0, 0], atol=1e-12)
    batch = quat_from_matrix(np.stack([R, S]))
    np.testing.assert_allclose(matrix_from_quat(batch), np.stack([R, S]), atol=1e-12)


@FAST
@given(q0=quats, q1=quats)
def test_slerp_unit_endpoints_constant_speed(q0, q1):
    q0, q1 = q0 / np.linalg.norm(q0), q1 / np.linalg.norm(q1)
    s = np.linspace(0.0, 1.0, 21)
    q = slerp(q0, q1, s)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(q[0], q0, atol=1e-9)
    np.testing.assert_allclose(abs(q[-1] @ q1), 1.0, atol=1e-9)  # q1 or -q1: same rotation
    steps = quat_angle(q[:-1], q[1:])
    total = quat_angle(q0, q1)
    assert total <= np.pi + 1e-9  # shortest path
    np.testing.assert_allclose(steps, total / 20, atol=1e-7)
    if abs(q0 @ q1) > 1e-6:  # at exactly 180° both directions are shortest
        np.testing.assert_allclose(slerp(q0, -q1, s), q, atol=1e-9)


def test_slerp_nearly_equal_and_scalar():
    q0 = np.array([1.0, 0.0, 0.0, 0.0])
    q1 = np.array([1.0, 1e-13, 0.0, 0.0])
    q = slerp(q0, q1, 0.5)
    assert q.shape == (4,)
    assert np.all(np.isfinite(q))
    np.testing.assert_allclose(np.linalg.norm(q), 1.0)
    half = slerp(q0, [0.0, 0.0, 0.0, 1.0], 0.5)  # 180° about z: halfway is 90°
    np.testing.assert_allclose(half, [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-12)


def test_axis_angle_round_trip_near_pi():
    for theta in (0.0, 1e-8, 1.0, np.pi - 1e-9, np.pi):
        axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
        R = matrix_from_axis_angle(axis, theta)
        r, th = axis_angle_from_matrix(R)
        np.testing.assert_allclose(matrix_from_axis_angle(r, th), R, atol=1e-9)
        assert th == pytest.approx(theta, abs=1e-7)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("law", ["quintic", "trapezoidal"])
def test_orientation_interpolation(seed, law):
    rng = np.random.default_rng(seed)
    R0, R1 = random_rotation(rng), random_rotation(rng)
    timing = getattr(TimingLaw, law)(2.0)
    traj = OrientationInterpolation(R0, R1, timing)
    assert isinstance(traj, Trajectory)
    np.testing.assert_allclose(traj.evaluate(0.0)[0], R0, atol=1e-12)
    np.testing.assert_allclose(traj.evaluate(2.0)[0], R1, atol=1e-9)
    breaks = [2.0 / 3.0, 4.0 / 3.0] if law == "trapezoidal" else []
    t = sample_times(2.0, breaks, k=20, seed=seed)
    h = 1e-5
    R, w, wd = traj.evaluate(t)
    assert R.shape == (t.size, 3, 3) and w.shape == wd.shape == (t.size, 3)
    np.testing.assert_allclose(
        R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )
    Rp, wp, _ = traj.evaluate(t + h)
    Rm, wm, _ = traj.evaluate(t - h)
    R_dot = (Rp - Rm) / (2 * h)
    np.testing.assert_allclose(vee(R_dot @ np.swapaxes(R, 1, 2)), w, atol=1e-6)
    np.testing.assert_allclose((wp - wm) / (2 * h), wd, atol=1e-6)
    # ω is along the fixed world axis R0 r.
    np.testing.assert_allclose(np.cross(w, R0 @ traj.axis), 0.0, atol=1e-12)


def test_orientation_interpolation_identical_rotations_is_still():
    R = matrix_from_axis_angle([0, 0, 1], 0.4)
    R_t, w, w_dot = OrientationInterpolation(R, R, TimingLaw.quintic(1.0)).evaluate(0.5)
    np.testing.assert_allclose(R_t, R, atol=1e-12)
    np.testing.assert_allclose(w, 0.0, atol=1e-12)
    np.testing.assert_allclose(w_dot, 0.0, atol=1e-12)


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------

TL = TimingLaw.quintic(1.0)
BAD = [
    (lambda: CubicPolynomial([0, 0], [1, 1, 1], 1.0), r"same shape"),
    (lambda: CubicPolynomial(0, 1, 0.0), r"duration must be a finite number > 0"),
    (lambda: QuinticPolynomial(0, 1, -2.0), r"duration must be a finite number > 0"),
    (lambda: CubicPolynomial(np.nan, 1, 1.0), r"q0 must be finite"),
    (lambda: CubicPolynomial([[0, 1]], [[1, 1]], 1.0), r"1-D array"),
    (lambda: QuinticPolynomial([0, 0], [1, 1], 1.0, a0=[1, 2, 3]), r"a0 .* shape \(2,\)"),
    (lambda: Trapezoidal(0, 1, v_max=0.0, a_max=1.0), r"v_max must be > 0"),
    (lambda: Trapezoidal(0, 1, v_max=1.0, a_max=[1.0, 2.0]), r"a_max .* shape \(1,\)"),
    (lambda: Trapezoidal(0, 1, v_max=1.0, a_max=1.0, duration=1.0), r"minimum feasible .* 2 s"),
    (lambda: TimingLaw.trapezoidal(1.0, accel_fraction=0.7), r"accel_fraction must be in"),
    (lambda: TimingLaw.quintic(1.0, length=0.0), r"length must be"),
    (lambda: JointSpline([0, 1, 1], [0, 1, 2]), r"strictly increasing.*times\[2\]"),
    (lambda: JointSpline([0, 1], [0, 1, 2]), r"points must have shape \(n, d\) = \(2, d\)"),
    (lambda: JointSpline([1, 2], [0, 1]), r"start at 0"),
    (lambda: JointSpline([0.0], [0.0]), r"at least 2"),
    (lambda: JointSpline([0, 1], [0, np.nan]), r"points must be finite"),
    (lambda: random_joint_trajectory(0, [1, 1], [0, 2], duration=1, n_points=3, v_max=1), r"lower"),
    (
        lambda: random_joint_trajectory(0, [0], [1], duration=1, n_points=3, v_max=1, start=0.05),
        r"start .* must lie in the box",
    ),
    (
        lambda: random_joint_trajectory(0, [0], [1], duration=1, n_points=3, v_max=1, margin=0.5),
        r"margin",
    ),
    (lambda: random_joint_trajectory(0, [0], [1], duration=1, n_points=1, v_max=1), r"n_points"),
    (
        lambda: SineTrajectory([0, 0], [1, 1, 1], 1.0),
        r"same shape \(d,\); got sizes .*'amplitude': 3",
    ),
    (lambda: SineTrajectory(0, 1, 0.0), r"frequency must be > 0"),
    (lambda: SineTrajectory(0, 1, 1.0, duration=-1), r"duration must be"),
    (lambda: Segment([0, 0], [1, 1, 1], TL), r"p0 has shape"),
    (lambda: Segment([0, 0], [1, 1], TimingLaw.linear(1.0, periodic=True)), r"finite duration"),
    (lambda: Circle([0, 0, 0], -1.0, TL), r"radius must be"),
    (lambda: Circle([0, 0, 0, 0], 1.0, TL), r"2 \(planar\) or 3"),
    (lambda: Circle([0, 0], 1.0, TL, normal=[0, 0, 1]), r"only meaningful for a 3-D"),
    (lambda: Circle([0, 0, 0], 1.0, TL, axes=([1, 0, 0], [1, 0, 0])), r"orthonormal"),
    (lambda: Circle([0, 0, 0], 1.0, TL, normal=[0, 0, 0]), r"non-zero"),
    (lambda: Circle([0, 0, 0], 1.0, TL, turns=0), r"turns must be"),
    (lambda: Ellipse([0, 0], 1.0, 0.0, TL), r"b must be"),
    (lambda: OrientationInterpolation(np.ones((3, 3)), np.eye(3), TL), r"R0 must be a rotation"),
    (lambda: OrientationInterpolation(-np.eye(3), np.eye(3), TL), r"det R = \+1"),
    (lambda: slerp([0, 0, 0, 0], [1, 0, 0, 0], 0.5), r"non-zero"),
    (lambda: slerp([1, 0, 0], [1, 0, 0, 0], 0.5), r"shape \(\.\.\., 4\)"),
    (lambda: quat_from_matrix(np.eye(4)), r"\(\.\.\., 3, 3\)"),
    (lambda: TL.evaluate(np.zeros((2, 2))), r"1-D array of times"),
    (lambda: TL.evaluate(np.nan), r"NaN"),
]


@pytest.mark.parametrize(("build", "message"), BAD, ids=[m for _, m in BAD])
def test_bad_input_raises_helpful_value_error(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def test_wrong_timing_type_raises_type_error():
    with pytest.raises(TypeError, match="TimingLaw"):
        Segment([0, 0], [1, 1], "quintic")
    with pytest.raises(TypeError, match="Generator"):
        random_joint_trajectory("seed", [0], [1], duration=1, n_points=3, v_max=1)


def test_quat_from_matrix_of_one_matrix_is_bit_identical_to_the_batched_path() -> None:
    """The single-matrix path (Python floats) and the array path agree bit for bit, with each
    of the four Shepperd pivots, at 180° turns and on ties; non-finite input still raises."""
    rng = np.random.default_rng(5)
    axes = rng.standard_normal((300, 3))
    mats = [
        matrix_from_axis_angle(a / np.linalg.norm(a), t)
        for a, t in zip(axes, rng.uniform(0.0, np.pi, 300), strict=True)
    ]
    mats += [
        np.eye(3),
        np.diag([1.0, -1.0, -1.0]),
        np.diag([-1.0, 1.0, -1.0]),
        np.diag([-1.0, -1.0, 1.0]),
        matrix_from_axis_angle(np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0), np.pi),
    ]
    batched = quat_from_matrix(np.array(mats))
    pivots = set()
    for R, q in zip(mats, batched, strict=True):
        assert quat_from_matrix(R).tobytes() == q.tobytes()
        pivots.add(int(np.argmax([1 + np.trace(R), *(1 + 2 * np.diag(R) - np.trace(R))])))
    assert pivots == {0, 1, 2, 3}
    with pytest.raises(ValueError, match="finite"):
        quat_from_matrix(np.full((3, 3), np.nan))
