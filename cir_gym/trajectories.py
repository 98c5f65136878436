"""Reference trajectories that give position, velocity and acceleration (chapter 3).

Siciliano et al., *Robotics: Modelling, Planning and Control*, ch. 4: point-to-point joint
motion (cubic and quintic polynomials, trapezoidal velocity profile, §4.2.1), motion through a
sequence of points (cubic splines, §4.2.2) and operational-space paths with a timing law
(segment, circle and other planar curves, orientation by axis-angle, §4.3).

The protocol (:class:`Trajectory`): every trajectory has ``duration: float`` (s) and
``evaluate(t) -> (p, v, a)``:

* ``t`` a float → ``p, v, a`` of shape (d,); ``t`` an array (k,) → arrays (k, d);
* before ``t = 0`` it holds the start and after ``t = duration`` the end, both with zero
  velocity and acceleration (a profile that ends moving, e.g. a cubic with ``v1 != 0``, stops
  abruptly at ``duration``). Periodic trajectories have ``duration = inf`` (or the finite
  duration they were given) and never reach the end.

Joint-space classes take ``q0, q1`` of shape (d,) (a scalar gives d = 1); Cartesian paths
return (2,) or (3,) positions; :class:`OrientationInterpolation` returns
``(R (3, 3), ω (3,), ω̇ (3,))`` in the world frame; :class:`TimingLaw` returns scalars
``(s, ṡ, s̈)`` (floats, or arrays (k,)). Quaternions are ``(w, x, y, z)``.

All objects are immutable (their arrays are read-only) and pickle. Invalid arguments raise
:class:`ValueError` saying what is wrong and what is allowed; arguments of the wrong type
(a timing law that is not a :class:`TimingLaw`) raise :class:`TypeError`.
"""

from __future__ import annotations

import math
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "Circle",
    "CubicPolynomial",
    "Ellipse",
    "FigureEight",
    "JointSpline",
    "OrientationInterpolation",
    "QuinticPolynomial",
    "Segment",
    "SineTrajectory",
    "TimingLaw",
    "Trajectory",
    "Trapezoidal",
    "axis_angle_from_matrix",
    "matrix_from_axis_angle",
    "matrix_from_quat",
    "quat_conj",
    "quat_from_matrix",
    "quat_mul",
    "random_joint_trajectory",
    "skew",
    "slerp",
]

_ROTATION_TOL = 1e-6  # tolerance on RᵀR = I and det R = 1 for rotation matrices given by users
_AXES_TOL = 1e-6  # tolerance on |u| = |v| = 1 and u·v = 0 for user-given plane axes
_FEASIBILITY_RTOL = 1e-12  # relative slack on the trapezoidal minimum duration (round-off)


# --------------------------------------------------------------------------------------------
# Protocol and validation helpers
# --------------------------------------------------------------------------------------------


@runtime_checkable
class Trajectory(Protocol):
    """Anything with a ``duration`` (s) and ``evaluate(t) -> (p, v, a)``."""

    @property
    def duration(self) -> float:
        """Time (s) at which the trajectory reaches its end (``inf`` if periodic)."""
        ...

    def evaluate(self, t: ArrayLike) -> tuple[Any, Any, Any]:
        """Position, velocity and acceleration at time(s) ``t`` (s)."""
        ...


def _vector(x: ArrayLike, name: str, d: int | None = None) -> np.ndarray:
    """A finite, read-only float copy of ``x`` with shape (d,); a scalar becomes (1,) or (d,)."""
    try:
        arr = np.array(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number or a 1-D array of numbers, got {x!r}") from exc
    if arr.ndim == 0:
        arr = np.full(1 if d is None else d, float(arr))
    elif arr.ndim != 1:
        raise ValueError(f"{name} must be a scalar or a 1-D array (d,), got shape {arr.shape}")
    if d is not None and arr.shape != (d,):
        raise ValueError(f"{name} must be a scalar or have shape ({d},), got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name} must have at least one element, got an empty array")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN or inf), got {arr}")
    arr.setflags(write=False)
    return arr


def _pair(q0: ArrayLike, q1: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points of the same shape (d,)."""
    a = _vector(q0, "q0")
    b = _vector(q1, "q1")
    if a.shape != b.shape:
        raise ValueError(
            f"q0 has shape {a.shape} but q1 has shape {b.shape}; they must have the same shape (d,)"
        )
    return a, b


def _positive(x: float, name: str, *, allow_inf: bool = False) -> float:
    """A float > 0 (finite unless ``allow_inf``)."""
    try:
        value = float(x)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number > 0, got {x!r}") from exc
    if math.isnan(value) or value <= 0 or (math.isinf(value) and not allow_inf):
        allowed = "a number > 0 (inf allowed)" if allow_inf else "a finite number > 0"
        raise ValueError(f"{name} must be {allowed}, got {x!r}")
    return value


def _positive_vector(x: ArrayLike, name: str, d: int) -> np.ndarray:
    """A finite vector (d,) with every element > 0 (a scalar is broadcast)."""
    arr = _vector(x, name, d)
    if np.any(arr <= 0):
        raise ValueError(f"{name} must be > 0 in every dimension, got {arr}")
    return arr


def _as_times(t: ArrayLike) -> tuple[np.ndarray, bool]:
    """Times (k,) in s and whether ``t`` was a scalar."""
    try:
        arr = np.array(t, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"t must be a float or a 1-D array of times (k,), got {t!r}") from exc
    if arr.ndim > 1:
        raise ValueError(f"t must be a float or a 1-D array of times (k,), got shape {arr.shape}")
    if np.any(np.isnan(arr)):
        raise ValueError("t must not contain NaN")
    return arr.reshape(-1), arr.ndim == 0


def _readonly(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


class _Frozen:
    """Immutable after ``__init__``: attributes are set once with :meth:`_set`."""

    def _set(self, **attributes: Any) -> None:
        for name, value in attributes.items():
            object.__setattr__(self, name, value)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable; build a new one instead")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")


class _Base(_Frozen):
    """Shared ``evaluate``: subclasses implement ``_profile(τ)`` for τ (k,) in [0, duration]."""

    duration: float

    def _profile(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise NotImplementedError

    def evaluate(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration at time(s) ``t`` (s).

        Args:
            t: a float, or times (k,) in s.

        Returns:
            ``(p, v, a)``, each of the trajectory's value shape for a float ``t`` and with a
            leading axis k for an array. Outside [0, duration] the start (before) or the end
            (after) is held with zero velocity and acceleration.
        """
        tt, scalar = _as_times(t)
        tau = np.clip(tt, 0.0, self.duration)
        p, v, a = self._profile(tau)
        outside = ((tt < 0.0) | (tt > self.duration)).reshape((-1,) + (1,) * (v.ndim - 1))
        v = np.where(outside, 0.0, v)
        a = np.where(outside, 0.0, a)
        if scalar:
            return p[0], v[0], a[0]
        return p, v, a

    def __repr__(self) -> str:
        fields = ", ".join(f"{name}={getattr(self, name)!r}" for name in self._repr_fields)
        return f"{type(self).__name__}({fields})"

    _repr_fields: tuple[str, ...] = ("duration",)


# --------------------------------------------------------------------------------------------
# Joint space: point-to-point polynomials (Siciliano §4.2.1)
# --------------------------------------------------------------------------------------------


class _Polynomial(_Base):
    """q(t) = Σ_j c_j t^j per dimension, coefficients ``coefficients`` (n + 1, d)."""

    coefficients: np.ndarray

    @property
    def dim(self) -> int:
        """Number of dimensions d."""
        return self.coefficients.shape[1]

    def _profile(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = self.coefficients
        n = c.shape[0] - 1
        t = tau[:, None]
        p = np.broadcast_to(c[n], (tau.size, c.shape[1])).copy()
        v = np.broadcast_to(n * c[n], p.shape).copy()
        a = np.broadcast_to(n * (n - 1) * c[n], p.shape).copy()
        for j in range(n - 1, -1, -1):  # Horner's scheme for q, q̇, q̈
            p = p * t + c[j]
            if j >= 1:
                v = v * t + j * c[j]
            if j >= 2:
                a = a * t + j * (j - 1) * c[j]
        return p, v, a


class CubicPolynomial(_Polynomial):
    """Cubic q(t) = a₃t³ + a₂t² + a₁t + a₀ from (q0, v0) at t = 0 to (q1, v1) at t = T.

    Args:
        q0, q1: start and end positions (d,) (rad or m; a scalar gives d = 1).
        duration: T in s, > 0.
        v0, v1: start and end velocities, scalars or (d,), default 0 (rest to rest).

    The acceleration jumps at both ends (a cubic has only four coefficients); use
    :class:`QuinticPolynomial` to also impose accelerations.
    """

    _repr_fields = ("q0", "q1", "duration", "v0", "v1")

    def __init__(
        self,
        q0: ArrayLike,
        q1: ArrayLike,
        duration: float,
        v0: ArrayLike = 0.0,
        v1: ArrayLike = 0.0,
    ) -> None:
        q0_, q1_ = _pair(q0, q1)
        d = q0_.size
        T = _positive(duration, "duration")
        v0_, v1_ = _vector(v0, "v0", d), _vector(v1, "v1", d)
        h = q1_ - q0_
        coefficients = np.stack(
            [
                q0_,
                v0_,
                (3.0 * h - (2.0 * v0_ + v1_) * T) / T**2,
                (-2.0 * h + (v0_ + v1_) * T) / T**3,
            ]
        )
        self._set(q0=q0_, q1=q1_, duration=T, v0=v0_, v1=v1_, coefficients=_readonly(coefficients))


class QuinticPolynomial(_Polynomial):
    """Quintic q(t) = Σ_{j≤5} a_j t^j with position, velocity and acceleration at both ends.

    Args:
        q0, q1: start and end positions (d,) (a scalar gives d = 1).
        duration: T in s, > 0.
        v0, v1: start and end velocities, scalars or (d,), default 0.
        a0, a1: start and end accelerations, scalars or (d,), default 0.
    """

    _repr_fields = ("q0", "q1", "duration", "v0", "v1", "a0", "a1")

    def __init__(
        self,
        q0: ArrayLike,
        q1: ArrayLike,
        duration: float,
        v0: ArrayLike = 0.0,
        v1: ArrayLike = 0.0,
        a0: ArrayLike = 0.0,
        a1: ArrayLike = 0.0,
    ) -> None:
        q0_, q1_ = _pair(q0, q1)
        d = q0_.size
        T = _positive(duration, "duration")
        v0_, v1_ = _vector(v0, "v0", d), _vector(v1, "v1", d)
        a0_, a1_ = _vector(a0, "a0", d), _vector(a1, "a1", d)
        h = q1_ - q0_
        coefficients = np.stack(
            [
                q0_,
                v0_,
                a0_ / 2.0,
                (20.0 * h - (8.0 * v1_ + 12.0 * v0_) * T - (3.0 * a0_ - a1_) * T**2) / (2.0 * T**3),
                (-30.0 * h + (14.0 * v1_ + 16.0 * v0_) * T + (3.0 * a0_ - 2.0 * a1_) * T**2)
                / (2.0 * T**4),
                (12.0 * h - 6.0 * (v1_ + v0_) * T + (a1_ - a0_) * T**2) / (2.0 * T**5),
            ]
        )
        self._set(
            q0=q0_,
            q1=q1_,
            duration=T,
            v0=v0_,
            v1=v1_,
            a0=a0_,
            a1=a1_,
            coefficients=_readonly(coefficients),
        )


# --------------------------------------------------------------------------------------------
# Joint space: trapezoidal velocity profile (Siciliano §4.2.1)
# --------------------------------------------------------------------------------------------


class Trapezoidal(_Base):
    """Trapezoidal velocity profile per dimension, all dimensions sharing one duration t_f.

    Each dimension accelerates with ``q̈_c = ±a_max`` for ``t_c``, cruises at
    ``q̇_c = q̈_c t_c`` and decelerates for the last ``t_c``. Without ``duration`` the slowest
    dimension moves in minimum time (cruising at ``v_max``, or a *triangular* profile when
    ``|q1 - q0| <= v_max² / a_max`` so the cruise phase vanishes) and t_f is its duration.
    With a ``duration`` t_f, every dimension keeps ``|q̈_c| = a_max`` and takes the textbook
    acceleration time

        t_c = t_f / 2 - ½ √((t_f² q̈_c - 4 (q1 - q0)) / q̈_c),

    i.e. the cruise velocity ``q̇_c = q̈_c t_c`` that covers the distance in t_f; this is never
    above ``v_max`` when t_f is at least the minimum duration.

    Args:
        q0, q1: start and end positions (d,) (a scalar gives d = 1).
        v_max: velocity limits > 0, scalar or (d,) (rad/s or m/s).
        a_max: acceleration limits > 0, scalar or (d,) (rad/s² or m/s²).
        duration: t_f in s, or None for the minimum duration.

    Raises:
        ValueError: non-positive limits, or ``duration`` shorter than the minimum (the message
            states it; see :meth:`minimum_duration`).

    Attributes:
        accel_time: t_c (d,) in s (0 for dimensions that do not move; t_f / 2 if triangular).
        cruise_velocity: signed q̇_c (d,).
        acceleration: signed q̈_c (d,) of the first phase.
        triangular: (d,) bool, True where the cruise phase vanishes.
    """

    _repr_fields = ("q0", "q1", "v_max", "a_max", "duration")

    def __init__(
        self,
        q0: ArrayLike,
        q1: ArrayLike,
        *,
        v_max: ArrayLike,
        a_max: ArrayLike,
        duration: float | None = None,
    ) -> None:
        q0_, q1_ = _pair(q0, q1)
        d = q0_.size
        v_max_ = _positive_vector(v_max, "v_max", d)
        a_max_ = _positive_vector(a_max, "a_max", d)
        t_min_each = _trapezoidal_min_times(np.abs(q1_ - q0_), v_max_, a_max_)
        t_min = float(np.max(t_min_each))
        if duration is None:
            T = t_min
        else:
            T = _positive(duration, "duration")
            if T < t_min * (1.0 - _FEASIBILITY_RTOL):
                i = int(np.argmax(t_min_each))
                raise ValueError(
                    f"Trapezoidal duration {T:.6g} s is infeasible: the minimum feasible duration "
                    f"is {t_min:.6g} s for v_max={v_max_.tolist()}, a_max={a_max_.tolist()} "
                    f"(set by dimension {i}); give duration >= {t_min:.6g} s or duration=None"
                )
        h = q1_ - q0_
        dist = np.abs(h)
        sign = np.sign(h)
        # t_c = T/2 - ½√(T² - 4|h|/a), written as the stable small root 2|h| / (a (T + √Δ)).
        disc = np.maximum(T**2 - 4.0 * dist / a_max_, 0.0)
        denom = a_max_ * (T + np.sqrt(disc))
        t_c = np.divide(2.0 * dist, denom, out=np.zeros(d), where=denom > 0)
        t_c = np.minimum(t_c, T / 2.0)
        moving = dist > 0
        acceleration = np.where(moving, sign * a_max_, 0.0)
        self._set(
            q0=q0_,
            q1=q1_,
            v_max=v_max_,
            a_max=a_max_,
            duration=T,
            accel_time=_readonly(t_c),
            acceleration=_readonly(acceleration),
            cruise_velocity=_readonly(acceleration * t_c),
            triangular=_readonly(moving & (T - 2.0 * t_c <= 1e-9 * max(T, 1e-300))),
        )

    @property
    def dim(self) -> int:
        """Number of dimensions d."""
        return self.q0.size

    @staticmethod
    def minimum_duration(
        q0: ArrayLike, q1: ArrayLike, *, v_max: ArrayLike, a_max: ArrayLike
    ) -> float:
        """Shortest t_f (s) such that every dimension respects ``v_max`` and ``a_max``.

        Per dimension: ``2 √(|Δq| / a_max)`` (triangular) if ``|Δq| <= v_max² / a_max``, else
        ``|Δq| / v_max + v_max / a_max``; the maximum over dimensions.
        """
        q0_, q1_ = _pair(q0, q1)
        d = q0_.size
        v = _positive_vector(v_max, "v_max", d)
        a = _positive_vector(a_max, "a_max", d)
        return float(np.max(_trapezoidal_min_times(np.abs(q1_ - q0_), v, a)))

    def _profile(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        T = self.duration
        t = tau[:, None]
        t_c, acc = self.accel_time, self.acceleration
        accel = t <= t_c
        decel = t >= T - t_c
        p = np.where(
            accel,
            self.q0 + 0.5 * acc * t**2,
            np.where(
                decel, self.q1 - 0.5 * acc * (T - t) ** 2, self.q0 + acc * t_c * (t - t_c / 2)
            ),
        )
        v = np.where(accel, acc * t, np.where(decel, acc * (T - t), acc * t_c))
        a = np.where(accel, acc, np.where(decel, -acc, 0.0))
        # A triangular profile switches from +q̈_c to -q̈_c at t_f / 2, where both masks hold.
        return p, v, np.broadcast_to(a, p.shape).copy()


def _trapezoidal_min_times(dist: np.ndarray, v_max: np.ndarray, a_max: np.ndarray) -> np.ndarray:
    """Minimum duration (s) per dimension to travel ``dist`` (d,) within the limits."""
    triangular = dist <= v_max**2 / a_max
    return np.where(triangular, 2.0 * np.sqrt(dist / a_max), dist / v_max + v_max / a_max)


# --------------------------------------------------------------------------------------------
# Timing laws s(t)
# --------------------------------------------------------------------------------------------


class TimingLaw(_Base):
    """Scalar timing law s(t) from 0 to ``length`` with ṡ(t) and s̈(t).

    Build one with :meth:`quintic`, :meth:`cubic`, :meth:`trapezoidal` or :meth:`linear`.
    ``evaluate(t)`` returns ``(s, ṡ, s̈)`` as floats for a float t and arrays (k,) for an
    array. A periodic law (``TimingLaw.linear(period, periodic=True)``) has
    ``duration = inf``, ``period`` = the time of one unit of ``length``, and s grows without
    bound (s = length · t / period for t >= 0), so a closed path is traced again and again.

    Paths use the fraction σ = s / length of the path, so ``length`` only scales s
    (e.g. pass the arc length to get s in metres).
    """

    _repr_fields = ("kind", "duration", "length")

    def __init__(
        self,
        kind: str,
        length: float,
        profile: _Base | None = None,
        *,
        period: float | None = None,
    ) -> None:
        """Internal: use the class methods. ``profile`` is a 1-D trajectory from 0 to length,
        or None for the periodic constant-speed law with the given ``period``."""
        length_ = _positive(length, "length")
        if profile is None:
            period_ = _positive(period, "period")  # type: ignore[arg-type]
            duration = math.inf
        else:
            period_ = None
            duration = profile.duration
        self._set(kind=kind, length=length_, duration=duration, period=period_, _law=profile)

    @property
    def periodic(self) -> bool:
        """True for the unbounded constant-speed law (``duration = inf``)."""
        return self._law is None

    @classmethod
    def quintic(cls, duration: float, length: float = 1.0) -> TimingLaw:
        """Quintic s(t) with zero ṡ and s̈ at both ends (smooth start and stop)."""
        return cls("quintic", length, QuinticPolynomial(0.0, length, duration))

    @classmethod
    def cubic(cls, duration: float, length: float = 1.0) -> TimingLaw:
        """Cubic s(t) with zero ṡ at both ends (s̈ jumps at the ends)."""
        return cls("cubic", length, CubicPolynomial(0.0, length, duration))

    @classmethod
    def trapezoidal(
        cls, duration: float, length: float = 1.0, *, accel_fraction: float = 1.0 / 3.0
    ) -> TimingLaw:
        """Trapezoidal speed profile: accelerate for ``t_c = accel_fraction · duration``,
        cruise, decelerate for t_c.

        Args:
            duration: t_f in s, > 0.
            length: final value of s, > 0.
            accel_fraction: t_c / t_f in (0, 0.5]; 0.5 is the triangular profile. The cruise
                speed is ``length / (t_f - t_c)`` and the acceleration ``ṡ_c / t_c``.
        """
        T = _positive(duration, "duration")
        length_ = _positive(length, "length")
        try:
            frac = float(accel_fraction)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"accel_fraction must be a number in (0, 0.5], got {accel_fraction!r}"
            ) from exc
        if not 0.0 < frac <= 0.5:
            raise ValueError(f"accel_fraction must be in (0, 0.5] (0.5 = triangular), got {frac!r}")
        t_c = frac * T
        v_c = length_ / (T - t_c)
        profile = Trapezoidal(0.0, length_, v_max=v_c, a_max=v_c / t_c, duration=T)
        return cls("trapezoidal", length_, profile)

    @classmethod
    def linear(cls, duration: float, length: float = 1.0, *, periodic: bool = False) -> TimingLaw:
        """Constant speed ṡ = length / duration (ṡ jumps at the start and at the end).

        Args:
            duration: time in s to cover ``length``; with ``periodic=True`` the period.
            length: s at ``duration``.
            periodic: if True, s keeps growing after ``duration`` (law ``duration = inf``), so
                a closed path repeats with this period.
        """
        T = _positive(duration, "duration")
        if periodic:
            return cls("linear-periodic", length, None, period=T)
        rate = _positive(length, "length") / T
        return cls("linear", length, CubicPolynomial(0.0, length, T, v0=rate, v1=rate))

    def _profile(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._law is None:
            rate = self.length / self.period
            return rate * tau, np.full_like(tau, rate), np.zeros_like(tau)
        p, v, a = self._law.evaluate(tau)
        return p[:, 0], v[:, 0], a[:, 0]

    def evaluate(self, t: ArrayLike) -> tuple[Any, Any, Any]:
        """``(s, ṡ, s̈)`` at time(s) ``t`` (s): floats for a float t, arrays (k,) for (k,)."""
        s, sd, sdd = super().evaluate(t)
        if np.ndim(s) == 0:
            return float(s), float(sd), float(sdd)
        return s, sd, sdd

    def _fraction(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Path fraction σ = s / length and its derivatives, each (k,)."""
        s, sd, sdd = self._profile(tau)
        return s / self.length, sd / self.length, sdd / self.length


def _check_timing(timing: Any, owner: str, *, allow_periodic: bool) -> TimingLaw:
    if not isinstance(timing, TimingLaw):
        raise TypeError(
            f"{owner} timing must be a TimingLaw (e.g. TimingLaw.quintic(2.0)), "
            f"got {type(timing).__name__}"
        )
    if timing.periodic and not allow_periodic:
        raise ValueError(
            f"{owner} is not a closed path, so it needs a timing law with a finite duration; "
            f"got a periodic one ({timing.kind})"
        )
    return timing


# --------------------------------------------------------------------------------------------
# Joint space: cubic splines through a sequence of points (Siciliano §4.2.2)
# --------------------------------------------------------------------------------------------


class JointSpline(_Base):
    """C² cubic spline through points q_k at times t_k, with given end velocities.

    The interior knot velocities v_k solve the tridiagonal system of acceleration continuity

        T_k v_{k-1} + 2 (T_{k-1} + T_k) v_k + T_{k-1} v_{k+1}
            = 3 (T_k Δq_{k-1} / T_{k-1} + T_{k-1} Δq_k / T_k),   T_k = t_{k+1} - t_k,

    by the Thomas algorithm (the matrix is strictly diagonally dominant); each interval is
    then the cubic with the knot positions and velocities at its ends.

    Args:
        times: knot times (n,) in s, n >= 2, starting at 0 and strictly increasing.
        points: knot positions (n, d) (or (n,) for d = 1).
        v0, v1: velocities at the first and last knot, scalars or (d,), default 0.

    Attributes:
        times (n,), points (n, d), velocities (n, d) at the knots; coefficients (n - 1, 4, d)
        of each interval's cubic in the local time t - t_k.
    """

    _repr_fields = ("times", "points", "v0", "v1")

    def __init__(
        self,
        times: ArrayLike,
        points: ArrayLike,
        *,
        v0: ArrayLike = 0.0,
        v1: ArrayLike = 0.0,
    ) -> None:
        t = _vector(times, "times")
        if t.size < 2:
            raise ValueError(f"times needs at least 2 knots, got {t.size}")
        if t[0] != 0.0:
            raise ValueError(f"times must start at 0 (got {t[0]!r}); subtract times[0]")
        dt = np.diff(t)
        if np.any(dt <= 0):
            k = int(np.argmax(dt <= 0))
            raise ValueError(
                f"times must be strictly increasing, but times[{k + 1}] = {t[k + 1]!r} <= "
                f"times[{k}] = {t[k]!r}"
            )
        try:
            q = np.array(points, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"points must be an array (n, d) of numbers, got {points!r}") from exc
        if q.ndim == 1:
            q = q[:, None]
        if q.ndim != 2 or q.shape[0] != t.size or q.shape[1] == 0:
            raise ValueError(
                f"points must have shape (n, d) = ({t.size}, d) to match times, got {q.shape}"
            )
        if not np.all(np.isfinite(q)):
            raise ValueError("points must be finite (no NaN or inf)")
        d = q.shape[1]
        v0_, v1_ = _vector(v0, "v0", d), _vector(v1, "v1", d)
        velocities = _spline_velocities(dt, q, v0_, v1_)
        h = dt[:, None]
        dq = np.diff(q, axis=0)
        vk, vk1 = velocities[:-1], velocities[1:]
        coefficients = np.stack(
            [
                q[:-1],
                vk,
                (3.0 * dq - (2.0 * vk + vk1) * h) / h**2,
                (-2.0 * dq + (vk + vk1) * h) / h**3,
            ],
            axis=1,
        )
        self._set(
            times=t,
            points=_readonly(q),
            v0=v0_,
            v1=v1_,
            duration=float(t[-1]),
            velocities=_readonly(velocities),
            coefficients=_readonly(coefficients),
        )

    @property
    def dim(self) -> int:
        """Number of dimensions d."""
        return self.points.shape[1]

    def _segments(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Interval index (k,) and local time (k,) of each τ."""
        idx = np.clip(np.searchsorted(self.times, tau, side="right") - 1, 0, self.times.size - 2)
        return idx, tau - self.times[idx]

    def _profile(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        idx, s = self._segments(tau)
        c = self.coefficients[idx]  # (k, 4, d)
        s = s[:, None]
        p = c[:, 0] + s * (c[:, 1] + s * (c[:, 2] + s * c[:, 3]))
        v = c[:, 1] + s * (2.0 * c[:, 2] + 3.0 * s * c[:, 3])
        a = 2.0 * c[:, 2] + 6.0 * s * c[:, 3]
        return p, v, a

    def peak_velocity(self) -> np.ndarray:
        """Exact max over [0, duration] of |q̇| per dimension (d,).

        q̇ is quadratic on each interval, so its extremum is at an end or where q̈ = 0.
        """
        c = self.coefficients
        h = np.diff(self.times)[:, None]
        c2, c3 = c[:, 2], c[:, 3]
        safe = np.where(c3 != 0.0, 3.0 * c3, 1.0)
        t_star = np.clip(np.where(c3 != 0.0, -c2 / safe, 0.0), 0.0, h)
        peak = np.zeros(self.dim)
        for s in (np.zeros_like(c2), np.broadcast_to(h, c2.shape), t_star):
            v = c[:, 1] + s * (2.0 * c2 + 3.0 * s * c3)
            peak = np.maximum(peak, np.max(np.abs(v), axis=0))
        return peak

    def position_range(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact (min (d,), max (d,)) of q over [0, duration] (ends and roots of q̇ = 0)."""
        c = self.coefficients
        h = np.broadcast_to(np.diff(self.times)[:, None], c[:, 0].shape)
        A, B, C = 3.0 * c[:, 3], 2.0 * c[:, 2], c[:, 1]  # q̇ = A s² + B s + C
        disc = B**2 - 4.0 * A * C
        real = disc >= 0.0
        # Stable roots: Q = -(B + sign(B) √Δ) / 2, s₁ = Q / A, s₂ = C / Q.
        Q = -0.5 * (B + np.where(B >= 0.0, 1.0, -1.0) * np.sqrt(np.where(real, disc, 0.0)))
        s1 = np.where(real & (A != 0.0), Q / np.where(A != 0.0, A, 1.0), 0.0)
        s2 = np.where(real & (Q != 0.0), C / np.where(Q != 0.0, Q, 1.0), 0.0)
        lo = np.full(self.dim, np.inf)
        hi = np.full(self.dim, -np.inf)
        for s in (np.zeros_like(h), h, np.clip(s1, 0.0, h), np.clip(s2, 0.0, h)):
            q = c[:, 0] + s * (c[:, 1] + s * (c[:, 2] + s * c[:, 3]))
            lo = np.minimum(lo, q.min(axis=0))
            hi = np.maximum(hi, q.max(axis=0))
        return lo, hi


def _spline_velocities(dt: np.ndarray, q: np.ndarray, v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """Knot velocities (n, d) of the C² clamped cubic spline (Thomas algorithm)."""
    n = q.shape[0]
    velocities = np.empty_like(q)
    velocities[0], velocities[-1] = v0, v1
    m = n - 2
    if m == 0:
        return velocities
    T_prev, T_next = dt[:-1], dt[1:]  # T_{k-1}, T_k for interior knots k = 1..n-2
    dq = np.diff(q, axis=0)
    Tp, Tn = T_prev[:, None], T_next[:, None]
    rhs = 3.0 * (Tn * dq[:-1] / Tp + Tp * dq[1:] / Tn)
    lower = T_next.copy()  # coefficient of v_{k-1}
    diag = 2.0 * (T_prev + T_next)
    upper = T_prev.copy()  # coefficient of v_{k+1}
    rhs[0] -= lower[0] * v0
    rhs[-1] -= upper[-1] * v1
    # Forward sweep.
    c_prime = np.empty(m)
    d_prime = np.empty_like(rhs)
    c_prime[0] = upper[0] / diag[0]
    d_prime[0] = rhs[0] / diag[0]
    for i in range(1, m):
        denom = diag[i] - lower[i] * c_prime[i - 1]
        c_prime[i] = upper[i] / denom
        d_prime[i] = (rhs[i] - lower[i] * d_prime[i - 1]) / denom
    # Back substitution.
    x = np.empty_like(rhs)
    x[-1] = d_prime[-1]
    for i in range(m - 2, -1, -1):
        x[i] = d_prime[i] - c_prime[i] * x[i + 1]
    velocities[1:-1] = x
    return velocities


def random_joint_trajectory(
    rng: np.random.Generator | int,
    lower: ArrayLike,
    upper: ArrayLike,
    *,
    duration: float,
    n_points: int,
    v_max: ArrayLike,
    margin: float = 0.1,
    start: ArrayLike | None = None,
) -> JointSpline:
    """Random smooth rest-to-rest joint trajectory inside the limits and below ``v_max``.

    Knots: ``n_points`` equally spaced in [0, duration]; the first is ``start`` (or uniform in
    the box), the others uniform in the box [lower + margin·range, upper - margin·range] with
    range = upper - lower. The spline (:class:`JointSpline`, zero end velocities) may
    overshoot its knots, so up to 100 draws are made until its exact position range
    (:meth:`JointSpline.position_range`) lies in the box. Then, since the spline is linear in
    its knots and a constant is interpolated exactly, shrinking the knots toward ``start``
    by λ ∈ (0, 1] scales q(t) - start and q̇(t) by λ: λ is chosen so the exact peak speed
    (:meth:`JointSpline.peak_velocity`) is at most ``v_max`` in every joint, which keeps the
    positions in the (convex) box. If no draw stays in the box, the last draw is shrunk for
    both conditions.

    Args:
        rng: a ``numpy.random.Generator`` (e.g. an env's ``np_random``) or an int seed.
        lower, upper: joint limits (d,), lower < upper.
        duration: total time in s, > 0.
        n_points: number of knots including start and end, >= 2.
        v_max: speed bound > 0 (rad/s or m/s), scalar or (d,).
        margin: fraction of the range kept free at each limit, in [0, 0.5).
        start: start position (d,) inside the box; None for a random one.

    Returns:
        A :class:`JointSpline` starting and ending at rest.
    """
    if isinstance(rng, (int, np.integer)):
        rng = np.random.default_rng(int(rng))
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator or an int seed, got {type(rng)}")
    lo_lim = _vector(lower, "lower")
    d = lo_lim.size
    hi_lim = _vector(upper, "upper", d)
    if np.any(hi_lim <= lo_lim):
        raise ValueError(f"need lower < upper in every joint, got lower={lo_lim}, upper={hi_lim}")
    T = _positive(duration, "duration")
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)) or n_points < 2:
        raise ValueError(f"n_points must be an int >= 2 (start and end included), got {n_points!r}")
    v_lim = _positive_vector(v_max, "v_max", d)
    margin_ = float(margin)
    if not 0.0 <= margin_ < 0.5:
        raise ValueError(f"margin must be a fraction in [0, 0.5), got {margin!r}")
    span = hi_lim - lo_lim
    box_lo, box_hi = lo_lim + margin_ * span, hi_lim - margin_ * span
    if start is None:
        q_start = rng.uniform(box_lo, box_hi)
    else:
        q_start = np.array(_vector(start, "start", d))
        if np.any(q_start < box_lo) or np.any(q_start > box_hi):
            raise ValueError(
                f"start {q_start} must lie in the box [lower + margin·range, upper - margin·range]"
                f" = [{box_lo}, {box_hi}] (margin={margin_})"
            )
    times = np.linspace(0.0, T, n_points)
    for _ in range(100):
        points = rng.uniform(box_lo, box_hi, size=(n_points, d))
        points[0] = q_start
        spline = JointSpline(times, points)
        q_min, q_max = spline.position_range()
        if np.all(q_min >= box_lo) and np.all(q_max <= box_hi):
            break
    # λ for the box (1 after a successful draw): start + λ (q - start) in [box_lo, box_hi].
    with np.errstate(divide="ignore", invalid="ignore"):
        up = np.where(q_max > box_hi, (box_hi - q_start) / (q_max - q_start), np.inf)
        down = np.where(q_min < box_lo, (q_start - box_lo) / (q_start - q_min), np.inf)
        peak = spline.peak_velocity()
        speed = np.where(peak > v_lim, v_lim / np.where(peak > 0, peak, 1.0), np.inf)
    lam = float(min(1.0, up.min(), down.min(), speed.min()))
    if lam < 1.0:
        lam *= 1.0 - 1e-9  # stay strictly below the bounds despite round-off
        spline = JointSpline(times, q_start + lam * (points - q_start))
    return spline


# --------------------------------------------------------------------------------------------
# Joint space: periodic sine
# --------------------------------------------------------------------------------------------


class SineTrajectory(_Base):
    """q(t) = center + amplitude · sin(2π f t + φ) per dimension (periodic).

    Args:
        center: offset (d,) (a scalar is broadcast to the other arguments' d).
        amplitude: amplitude (d,) (rad or m).
        frequency: f > 0 in Hz, scalar or (d,).
        phase: φ in rad, scalar or (d,).
        duration: ``inf`` (default, never ends) or a time in s after which q(duration) is held
            with zero velocity.

    Before t = 0 q(0) is held with zero velocity and acceleration (the protocol), so the
    reference jumps in velocity at t = 0 unless ``cos φ = 0``.
    """

    _repr_fields = ("center", "amplitude", "frequency", "phase", "duration")

    def __init__(
        self,
        center: ArrayLike,
        amplitude: ArrayLike,
        frequency: ArrayLike,
        phase: ArrayLike = 0.0,
        *,
        duration: float = math.inf,
    ) -> None:
        args = {"center": center, "amplitude": amplitude, "frequency": frequency, "phase": phase}
        sizes = {name: np.size(value) for name, value in args.items()}
        d = max(sizes.values())
        if any(size not in (1, d) for size in sizes.values()):
            raise ValueError(
                "center, amplitude, frequency and phase must each be a scalar or have the same "
                f"shape (d,); got sizes {sizes}"
            )
        c = _vector(center, "center", d)
        amp = _vector(amplitude, "amplitude", d)
        f = _positive_vector(frequency, "frequency", d)
        phi = _vector(phase, "phase", d)
        self._set(
            center=c,
            amplitude=amp,
            frequency=f,
            phase=phi,
            duration=_positive(duration, "duration", allow_inf=True),
        )

    @property
    def dim(self) -> int:
        """Number of dimensions d."""
        return self.center.size

    def _profile(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        omega = 2.0 * np.pi * self.frequency  # rad/s
        arg = omega * tau[:, None] + self.phase
        s, c = np.sin(arg), np.cos(arg)
        return (
            self.center + self.amplitude * s,
            self.amplitude * omega * c,
            -self.amplitude * omega**2 * s,
        )


# --------------------------------------------------------------------------------------------
# Operational space: paths with a timing law (Siciliano §4.3)
# --------------------------------------------------------------------------------------------


def _point(x: ArrayLike, name: str) -> np.ndarray:
    p = _vector(x, name)
    if p.size not in (2, 3):
        raise ValueError(f"{name} must have 2 (planar) or 3 elements, got shape {p.shape}")
    return p


class Segment(_Base):
    """Straight line p(s) = p0 + σ (p1 - p0), σ = s / length of the timing law (R² or R³).

    Args:
        p0, p1: end points (2,) or (3,) in m.
        timing: a non-periodic :class:`TimingLaw`; the segment's duration is its duration.
    """

    _repr_fields = ("p0", "p1", "timing")

    def __init__(self, p0: ArrayLike, p1: ArrayLike, timing: TimingLaw) -> None:
        a = _point(p0, "p0")
        b = _point(p1, "p1")
        if a.shape != b.shape:
            raise ValueError(f"p0 has shape {a.shape} but p1 has {b.shape}; they must match")
        timing = _check_timing(timing, "Segment", allow_periodic=False)
        self._set(p0=a, p1=b, timing=timing, duration=timing.duration)

    @property
    def dim(self) -> int:
        """Ambient dimension, 2 or 3."""
        return self.p0.size

    @property
    def length(self) -> float:
        """Length of the segment in m."""
        return float(np.linalg.norm(self.p1 - self.p0))

    def _profile(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        sigma, sigma_d, sigma_dd = self.timing._fraction(tau)
        delta = self.p1 - self.p0
        return (
            self.p0 + sigma[:, None] * delta,
            sigma_d[:, None] * delta,
            sigma_dd[:, None] * delta,
        )


def _plane_axes(
    dim: int, normal: ArrayLike | None, axes: tuple[ArrayLike, ArrayLike] | None
) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal axes u, v (dim,) of the plane of a planar curve."""
    if normal is not None and axes is not None:
        raise ValueError("give either normal or axes=(u, v), not both")
    if axes is not None:
        try:
            u_raw, v_raw = axes
        except (TypeError, ValueError) as exc:
            raise ValueError("axes must be a pair (u, v) of orthonormal vectors") from exc
        u = _vector(u_raw, "axes[0] (u)", dim)
        v = _vector(v_raw, "axes[1] (v)", dim)
        if (
            abs(np.linalg.norm(u) - 1.0) > _AXES_TOL
            or abs(np.linalg.norm(v) - 1.0) > _AXES_TOL
            or abs(u @ v) > _AXES_TOL
        ):
            raise ValueError(
                f"axes u={u}, v={v} must be orthonormal (|u| = |v| = 1, u·v = 0 within {_AXES_TOL})"
            )
        u = u / np.linalg.norm(u)  # re-orthonormalise (Gram-Schmidt) to machine precision
        v = v - (v @ u) * u
        return _readonly(u), _readonly(v / np.linalg.norm(v))
    if dim == 2:
        if normal is not None:
            raise ValueError(
                "normal is only meaningful for a 3-D center; planar curves in 2-D "
                "use axes=(u, v) or the default x, y axes"
            )
        return _readonly(np.array([1.0, 0.0])), _readonly(np.array([0.0, 1.0]))
    n = _vector((0.0, 0.0, 1.0) if normal is None else normal, "normal", 3)
    norm = np.linalg.norm(n)
    if norm < 1e-12:
        raise ValueError(f"normal must be a non-zero 3-vector, got {n}")
    n = n / norm
    # u: world x projected on the plane (world y if x is nearly normal), v = n × u.
    e = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = e - (e @ n) * n
    u /= np.linalg.norm(u)
    return _readonly(u), _readonly(np.cross(n, u))


class _PlanarCurve(_Base):
    """p = c + x(θ) u + y(θ) v with θ = θ₀ + 2π · turns · σ(t).

    Subclasses give ``_shape(θ) -> (f, f', f'')``, each (k, 2) holding (x, y) and its first
    and second derivatives with respect to θ; the chain rule gives
    ṗ = U f' θ̇ and p̈ = U (f'' θ̇² + f' θ̈) with U = [u v].
    """

    _repr_fields = ("center", "timing", "start_angle", "turns")

    def _init_plane(
        self,
        center: ArrayLike,
        timing: TimingLaw,
        normal: ArrayLike | None,
        axes: tuple[ArrayLike, ArrayLike] | None,
        start_angle: float,
        turns: float,
    ) -> None:
        name = type(self).__name__
        c = _point(center, "center")
        u, v = _plane_axes(c.size, normal, axes)
        timing = _check_timing(timing, name, allow_periodic=True)
        theta0 = float(start_angle)
        if not math.isfinite(theta0):
            raise ValueError(f"start_angle must be a finite angle in rad, got {start_angle!r}")
        n_turns = float(turns)
        if not math.isfinite(n_turns) or n_turns == 0.0:
            raise ValueError(
                f"turns must be a finite non-zero number (negative = clockwise), got {turns!r}"
            )
        self._set(
            center=c,
            u=u,
            v=v,
            timing=timing,
            start_angle=theta0,
            turns=n_turns,
            duration=timing.duration,
        )

    @property
    def dim(self) -> int:
        """Ambient dimension, 2 or 3."""
        return self.center.size

    @property
    def normal(self) -> np.ndarray | None:
        """Unit normal u × v of the plane (3,) for a 3-D curve, None in 2-D."""
        return np.cross(self.u, self.v) if self.dim == 3 else None

    @property
    def closed(self) -> bool:
        """True when the curve returns to its start at σ = 1 (an integer number of turns)."""
        return float(self.turns).is_integer()

    def _shape(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _profile(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        sigma, sigma_d, sigma_dd = self.timing._fraction(tau)
        k = 2.0 * np.pi * self.turns
        theta = self.start_angle + k * sigma
        theta_d, theta_dd = (k * sigma_d)[:, None], (k * sigma_dd)[:, None]
        f, f1, f2 = self._shape(theta)
        U = np.stack([self.u, self.v])  # (2, dim)
        p = self.center + f @ U
        v = (f1 * theta_d) @ U
        a = (f2 * theta_d**2 + f1 * theta_dd) @ U
        return p, v, a


class Ellipse(_PlanarCurve):
    """Ellipse p = c + a cos θ u + b sin θ v, θ = θ₀ + 2π · turns · σ (θ is the eccentric
    anomaly, not the polar angle).

    Args:
        center: (2,) or (3,) in m; a 3-D ellipse lies in the plane of u, v.
        a, b: semi-axes > 0 in m along u and v.
        timing: :class:`TimingLaw`; σ = s / length is the fraction of the path.
        normal: 3-D only, plane normal (default (0, 0, 1)); u is the world x axis projected
            on the plane (world y if x is nearly normal) and v = normal × u.
        axes: (u, v) orthonormal in-plane axes instead of ``normal`` (2-D or 3-D).
        start_angle: θ₀ in rad (the start point is c + a cos θ₀ u + b sin θ₀ v).
        turns: number of revolutions over σ ∈ [0, 1] (negative = clockwise); an integer
            gives a closed path that ends where it starts.
    """

    _repr_fields = ("center", "a", "b", "timing", "start_angle", "turns")

    def __init__(
        self,
        center: ArrayLike,
        a: float,
        b: float,
        timing: TimingLaw,
        *,
        normal: ArrayLike | None = None,
        axes: tuple[ArrayLike, ArrayLike] | None = None,
        start_angle: float = 0.0,
        turns: float = 1.0,
    ) -> None:
        self._init_plane(center, timing, normal, axes, start_angle, turns)
        self._set(a=_positive(a, "a"), b=_positive(b, "b"))

    def _shape(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c, s = np.cos(theta), np.sin(theta)
        f = np.stack([self.a * c, self.b * s], axis=1)
        f1 = np.stack([-self.a * s, self.b * c], axis=1)
        return f, f1, -f


class Circle(Ellipse):
    """Circle of ``radius`` around ``center``: p = c + r (cos θ u + sin θ v),
    θ = θ₀ + 2π · turns · σ, with σ the arc fraction. Other arguments as :class:`Ellipse`.
    """

    _repr_fields = ("center", "radius", "timing", "start_angle", "turns")

    def __init__(
        self,
        center: ArrayLike,
        radius: float,
        timing: TimingLaw,
        *,
        normal: ArrayLike | None = None,
        axes: tuple[ArrayLike, ArrayLike] | None = None,
        start_angle: float = 0.0,
        turns: float = 1.0,
    ) -> None:
        r = _positive(radius, "radius")
        super().__init__(
            center, r, r, timing, normal=normal, axes=axes, start_angle=start_angle, turns=turns
        )
        self._set(radius=r)


class FigureEight(_PlanarCurve):
    """Figure eight (Lissajous 1:2): p = c + a sin θ u + b sin 2θ v, θ = θ₀ + 2π · turns · σ.

    It spans ±a along u and ±b along v, crosses itself at the center (where it starts for
    θ₀ = 0) and is closed for an integer number of turns. Arguments as :class:`Ellipse`.
    """

    _repr_fields = ("center", "a", "b", "timing", "start_angle", "turns")

    def __init__(
        self,
        center: ArrayLike,
        a: float,
        b: float,
        timing: TimingLaw,
        *,
        normal: ArrayLike | None = None,
        axes: tuple[ArrayLike, ArrayLike] | None = None,
        start_angle: float = 0.0,
        turns: float = 1.0,
    ) -> None:
        self._init_plane(center, timing, normal, axes, start_angle, turns)
        self._set(a=_positive(a, "a"), b=_positive(b, "b"))

    def _shape(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s1, c1 = np.sin(theta), np.cos(theta)
        s2, c2 = np.sin(2.0 * theta), np.cos(2.0 * theta)
        f = np.stack([self.a * s1, self.b * s2], axis=1)
        f1 = np.stack([self.a * c1, 2.0 * self.b * c2], axis=1)
        f2 = np.stack([-self.a * s1, -4.0 * self.b * s2], axis=1)
        return f, f1, f2


# --------------------------------------------------------------------------------------------
# Orientation: quaternions (w, x, y, z) and axis-angle interpolation (Siciliano §4.3.3)
# --------------------------------------------------------------------------------------------


def _quat(q: ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(q, dtype=float)
    if arr.shape[-1:] != (4,):
        raise ValueError(f"{name} must have shape (..., 4) as (w, x, y, z), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return arr


def _unit_quat(q: ArrayLike, name: str) -> np.ndarray:
    arr = _quat(q, name)
    norm = np.linalg.norm(arr, axis=-1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError(f"{name} must be a non-zero quaternion, got norm {norm.min():.3g}")
    return arr / norm


def quat_mul(q: ArrayLike, r: ArrayLike) -> np.ndarray:
    """Hamilton product q ⊗ r of quaternions (..., 4) in (w, x, y, z) (broadcasts)."""
    q_, r_ = _quat(q, "q"), _quat(r, "r")
    w1, x1, y1, z1 = np.moveaxis(q_, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(r_, -1, 0)
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def quat_conj(q: ArrayLike) -> np.ndarray:
    """Conjugate (w, -x, -y, -z) of quaternions (..., 4); the inverse of a unit quaternion."""
    return _quat(q, "q") * np.array([1.0, -1.0, -1.0, -1.0])


def quat_from_matrix(R: ArrayLike) -> np.ndarray:
    """Unit quaternion (..., 4), w >= 0, of rotation matrices (..., 3, 3) (Shepperd's method:
    the largest of 4w², 4x², 4y², 4z² is used as the pivot, so it is accurate at any angle)."""
    M = np.asarray(R, dtype=float)
    if M.shape[-2:] != (3, 3):
        raise ValueError(f"R must have shape (..., 3, 3), got {M.shape}")
    if M.ndim == 2 and math.isfinite(M.sum()):  # one matrix (the envs' hot path)
        q1 = _quat_from_matrix_floats(M.ravel().tolist())
        if q1 is not None:
            return np.array(q1)
    if not np.all(np.isfinite(M)):
        raise ValueError("R must be finite (no NaN or inf)")
    m00, m11, m22 = M[..., 0, 0], M[..., 1, 1], M[..., 2, 2]
    trace = m00 + m11 + m22
    # Candidates from each pivot (each equal to 4·pivot·q).
    cands = np.stack(
        [
            np.stack(
                [
                    1 + trace,
                    M[..., 2, 1] - M[..., 1, 2],
                    M[..., 0, 2] - M[..., 2, 0],
                    M[..., 1, 0] - M[..., 0, 1],
                ],
                axis=-1,
            ),
            np.stack(
                [
                    M[..., 2, 1] - M[..., 1, 2],
                    1 + m00 - m11 - m22,
                    M[..., 0, 1] + M[..., 1, 0],
                    M[..., 0, 2] + M[..., 2, 0],
                ],
                axis=-1,
            ),
            np.stack(
                [
                    M[..., 0, 2] - M[..., 2, 0],
                    M[..., 0, 1] + M[..., 1, 0],
                    1 - m00 + m11 - m22,
                    M[..., 1, 2] + M[..., 2, 1],
                ],
                axis=-1,
            ),
            np.stack(
                [
                    M[..., 1, 0] - M[..., 0, 1],
                    M[..., 0, 2] + M[..., 2, 0],
                    M[..., 1, 2] + M[..., 2, 1],
                    1 - m00 - m11 + m22,
                ],
                axis=-1,
            ),
        ],
        axis=-2,
    )  # (..., 4, 4)
    pivots = np.stack(
        [1 + trace, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], axis=-1
    )
    best = np.argmax(pivots, axis=-1)
    q = np.take_along_axis(cands, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def _quat_from_matrix_floats(m: list[float]) -> list[float] | None:
    """:func:`quat_from_matrix` of one matrix given row-major as 9 floats: the same operations
    in the same order on Python floats (bit-identical, without ~30 array temporaries); None
    for a zero pivot row (not a rotation: the array path gives its NaN)."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m
    trace = m00 + m11 + m22
    pivots = (1 + trace, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22)
    best = max(range(4), key=pivots.__getitem__)  # the first of equal maxima, as np.argmax
    if best == 0:
        q = (1 + trace, m21 - m12, m02 - m20, m10 - m01)
    elif best == 1:
        q = (m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20)
    elif best == 2:
        q = (m02 - m20, m01 + m10, 1 - m00 + m11 - m22, m12 + m21)
    else:
        q = (m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22)
    norm = math.sqrt(0.0 + q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if norm == 0.0:
        return None
    out = [v / norm for v in q]
    return [-v for v in out] if out[0] < 0 else out


def matrix_from_quat(q: ArrayLike) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) (normalised first)."""
    w, x, y, z = np.moveaxis(_unit_quat(q, "q"), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def slerp(q0: ArrayLike, q1: ArrayLike, s: ArrayLike) -> np.ndarray:
    """Spherical linear interpolation from unit quaternion q0 (s = 0) to q1 (s = 1).

    Takes the shortest path (q1 is negated when q0·q1 < 0, since q and -q are the same
    rotation) at constant angular speed; nearly equal quaternions fall back to normalised
    linear interpolation. Inputs are normalised.

    Args:
        q0, q1: quaternions (4,) in (w, x, y, z).
        s: a float or fractions (k,) (not restricted to [0, 1]).

    Returns:
        (4,) for a float s, (k, 4) for an array.
    """
    a = _unit_quat(q0, "q0")
    b = _unit_quat(q1, "q1")
    if a.shape != (4,) or b.shape != (4,):
        raise ValueError(f"q0 and q1 must have shape (4,), got {a.shape} and {b.shape}")
    ss, scalar = _as_times(s)
    dot = float(a @ b)
    if dot < 0.0:
        b, dot = -b, -dot
    # Half-angle Ω between q0 and q1 from atan2 (accurate also for small Ω).
    sin_omega = float(np.linalg.norm(b - dot * a))
    omega = math.atan2(sin_omega, dot)
    col = ss[:, None]
    if sin_omega < 1e-9:
        q = (1.0 - col) * a + col * b
    else:
        q = (np.sin((1.0 - col) * omega) * a + np.sin(col * omega) * b) / math.sin(omega)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return q[0] if scalar else q


def skew(v: ArrayLike) -> np.ndarray:
    """The cross-product matrix S(v), S(v) x = v × x, for v (3,) or rows (..., 3).

    S(v) = [[0, −v_z, v_y], [v_z, 0, −v_x], [−v_y, v_x, 0]] (3, 3), or (..., 3, 3) for rows,
    in the unit of v. The single vector is built from its three floats, rows by one matrix
    product vec S(v) = v [vec S(e_x); vec S(e_y); vec S(e_z)] (exact: one nonzero product per
    entry). Another shape raises ``ValueError``.
    """
    if type(v) is not np.ndarray:  # an ndarray of any real dtype goes through as it is
        v = np.asarray(v, dtype=float)
    try:
        if v.ndim == 1:  # the common single vector: three floats, no matrix product
            x, y, z = v.tolist()
            return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
        return (v @ _SKEW_BASIS).reshape(*v.shape[:-1], 3, 3)
    except ValueError:  # three values to unpack, or the product's inner dimension
        raise ValueError(f"v must have shape (3,) or (..., 3), got {v.shape}") from None


#: (3, 9): row k is vec S(e_k); for each cyclic (i, j, k), S[i, j] = −v_k and S[j, i] = +v_k
_SKEW_BASIS = np.zeros((3, 9))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _SKEW_BASIS[_k, 3 * _j + _i] = 1.0
    _SKEW_BASIS[_k, 3 * _i + _j] = -1.0
del _i, _j, _k


def matrix_from_axis_angle(r: ArrayLike, theta: ArrayLike) -> np.ndarray:
    """Rot(r, θ) = I + sin θ S(r) + (1 - cos θ) S(r)² (Rodrigues).

    Args:
        r: unit axis (3,) (normalised here).
        theta: angle in rad, a float or (k,).

    Returns:
        (3, 3) for a float θ, (k, 3, 3) for an array.
    """
    axis = _vector(r, "r", 3)
    norm = np.linalg.norm(axis)
    if norm < 1e-12:
        raise ValueError(f"r must be a non-zero axis, got {axis}")
    S = skew(axis / norm)
    th, scalar = _as_times(theta)
    th = th[:, None, None]
    R = np.eye(3) + np.sin(th) * S + (1.0 - np.cos(th)) * (S @ S)
    return R[0] if scalar else R


def axis_angle_from_matrix(R: ArrayLike) -> tuple[np.ndarray, float]:
    """Axis r (3,) and angle θ ∈ [0, π] (rad) with R = Rot(r, θ); r = (0, 0, 1) when θ = 0.

    Computed through the quaternion, so it is accurate also near θ = π.
    """
    q = quat_from_matrix(_rotation(R, "R"))
    xyz = q[1:]
    sin_half = float(np.linalg.norm(xyz))
    theta = 2.0 * math.atan2(sin_half, float(q[0]))
    if sin_half < 1e-15:
        return np.array([0.0, 0.0, 1.0]), 0.0
    return xyz / sin_half, theta


def _rotation(R: ArrayLike, name: str) -> np.ndarray:
    M = np.array(R, dtype=float)
    if M.shape != (3, 3):
        raise ValueError(f"{name} must be a rotation matrix of shape (3, 3), got {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    if (
        np.max(np.abs(M.T @ M - np.eye(3))) > _ROTATION_TOL
        or abs(np.linalg.det(M) - 1.0) > _ROTATION_TOL
    ):
        raise ValueError(
            f"{name} must be a rotation matrix (RᵀR = I and det R = +1 within {_ROTATION_TOL})"
        )
    return M


class OrientationInterpolation(_Base):
    """Orientation from R0 to R1 by axis-angle: R(t) = R0 Rot(r, θ s(t)) (s the path fraction).

    With R0ᵀ R1 = Rot(r, θ), θ ∈ [0, π] (the shorter rotation), the angular velocity and
    acceleration in the world frame are ω = R0 r θ ṡ and ω̇ = R0 r θ s̈.

    Args:
        R0, R1: rotation matrices (3, 3) (frame → world).
        timing: a non-periodic :class:`TimingLaw`; σ = s / length is used as s.

    ``evaluate(t)`` returns ``(R (3, 3), ω (3,), ω̇ (3,))`` (rad/s, rad/s²), with a leading
    axis k for an array t.

    Attributes:
        axis: r (3,) in the frame of R0; angle: θ in rad.
    """

    _repr_fields = ("axis", "angle", "timing")

    def __init__(self, R0: ArrayLike, R1: ArrayLike, timing: TimingLaw) -> None:
        R0_ = _readonly(_rotation(R0, "R0"))
        R1_ = _readonly(_rotation(R1, "R1"))
        timing = _check_timing(timing, "OrientationInterpolation", allow_periodic=False)
        r, theta = axis_angle_from_matrix(R0_.T @ R1_)
        self._set(
            R0=R0_,
            R1=R1_,
            timing=timing,
            duration=timing.duration,
            axis=_readonly(r),
            angle=theta,
            _omega_dir=_readonly(R0_ @ r * theta),  # R0 r θ
        )

    def _profile(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        sigma, sigma_d, sigma_dd = self.timing._fraction(tau)
        R = self.R0 @ matrix_from_axis_angle(self.axis, self.angle * sigma)
        return R, sigma_d[:, None] * self._omega_dir, sigma_dd[:, None] * self._omega_dir
