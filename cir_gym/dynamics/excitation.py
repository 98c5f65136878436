"""Excitation trajectories for identification: finite Fourier series per joint.

Swevers, Ganseman, Tükel, De Schutter, Van Brussel, "Optimal robot excitation and
identification", IEEE Trans. Robotics and Automation 13(5), 1997:

    q_i(t)  = q_i0 + Σ_{l=1..L} [a_il / (l ω_f) sin(l ω_f t) − b_il / (l ω_f) cos(l ω_f t)]
    q̇_i(t)  = Σ_l [a_il cos(l ω_f t) + b_il sin(l ω_f t)]
    q̈_i(t)  = Σ_l l ω_f [−a_il sin(l ω_f t) + b_il cos(l ω_f t)]

with ω_f = 2π f_base. The trajectory is periodic with period 1/f_base, so a measurement can be
averaged over periods. Here the coefficients are random (not optimised for the condition
number), scaled per joint so that q stays in the joint range shrunk by ``margin`` on each side
and |q̇| stays below the velocity limit, and the offset q_i0 centres the motion in the range.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from cir_gym.dynamics._checks import as_vector
from cir_gym.dynamics.chain import chain_model

_GRID_PER_HARMONIC = 512  # samples per period of the highest harmonic when scaling
_GRID_SAFETY = 1e-3  # relative shrink covering the peak between grid samples


@dataclass(frozen=True, eq=False)
class ExcitationTrajectory:
    """A finite Fourier series per joint; call it (or ``evaluate``) with a time.

    Attributes:
        offset: q_i0 (rad or m).  # (n,)
        a: sine coefficients of q̇ (rad/s or m/s).  # (n, L)
        b: cosine coefficients of q̇.  # (n, L)
        base_frequency: f_base (Hz); the period is 1 / f_base.
        duration: intended length (s); ``sample`` covers [0, duration].
    """

    offset: np.ndarray
    a: np.ndarray
    b: np.ndarray
    base_frequency: float
    duration: float

    def evaluate(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities and accelerations at time(s) t (s).

        Args:
            t: a time or times.  # () or (T,)

        Returns:
            q, q̇, q̈.  # each (n,) for a scalar t, (T, n) for a vector
        """
        times = np.asarray(t, dtype=float)
        if times.ndim > 1 or not np.isfinite(times).all():
            raise ValueError(f"t must be a finite scalar or 1-d array, got shape {times.shape}")
        harmonics = np.arange(1, self.a.shape[1] + 1)
        frequencies = 2.0 * np.pi * self.base_frequency * harmonics  # l ω_f, (L,)
        phase = np.multiply.outer(times, frequencies)  # (..., L)
        sin, cos = np.sin(phase), np.cos(phase)
        q = self.offset + (sin / frequencies) @ self.a.T - (cos / frequencies) @ self.b.T
        qd = cos @ self.a.T + sin @ self.b.T
        qdd = (-sin * frequencies) @ self.a.T + (cos * frequencies) @ self.b.T
        return q, qd, qdd

    __call__ = evaluate

    def sample(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Samples every ``dt`` seconds over [0, duration]: t (T,), q, q̇, q̈ (T, n)."""
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive time step, got {dt}")
        times = np.arange(0.0, self.duration + 0.5 * dt, dt)
        return (times, *self.evaluate(times))


def _joint_limits(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    chain = chain_model(model)
    joints = chain.topology.joints
    limited = model.jnt_limited[joints].astype(bool)
    unlimited_slides = np.flatnonzero(~limited & ~chain.revolute)
    if unlimited_slides.size:
        names = [
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, int(joints[i])) or str(i)
            for i in unlimited_slides
        ]
        raise ValueError(f'slide joint(s) {names} have no range; give them range="lo hi"')
    lower = np.where(limited, model.jnt_range[joints, 0], -np.pi)
    upper = np.where(limited, model.jnt_range[joints, 1], np.pi)
    return lower, upper


def _model_velocity_limit(model: mujoco.MjModel, n: int) -> np.ndarray | None:
    """The custom numeric ``velocity_limit`` (one value, or one per joint), if present."""
    try:
        data = np.asarray(model.numeric("velocity_limit").data, dtype=float)
    except KeyError:
        return None
    if data.size not in (1, n) or not np.all(data > 0):
        raise ValueError(
            f"custom numeric 'velocity_limit' has {data.size} entries {data}; expected 1 or "
            f"{n} positive values"
        )
    return np.broadcast_to(data, (n,)).copy()


def excitation_trajectory(
    model: mujoco.MjModel,
    *,
    duration: float,
    n_harmonics: int = 5,
    base_frequency: float = 0.1,
    seed: int | np.random.Generator | None = None,
    margin: float = 0.1,
    velocity_limit: ArrayLike | None = None,
    rest_at_ends: bool = True,
) -> ExcitationTrajectory:
    """A random Fourier-series excitation trajectory inside the joint and velocity limits.

    Args:
        model: a serial chain (joint ranges from ``jnt_range``; an unlimited hinge uses ±π).
        duration: intended length (s); the motion is at rest at t = duration when
            ``rest_at_ends`` and duration · base_frequency is an integer.
        n_harmonics: L, harmonics per joint.
        base_frequency: f_base (Hz).
        seed: seed or generator of the random coefficients.
        margin: fraction of each joint's range kept free at both ends: q stays within
            [lower + margin · range, upper − margin · range].
        velocity_limit: |q̇| bound per joint (rad/s or m/s); None reads the model's custom
            numeric ``velocity_limit`` and skips the bound when it does not exist.  # (n,)
        rest_at_ends: make q̇(0) = q̈(0) = 0 (needs n_harmonics ≥ 2); by periodicity also at
            every multiple of the period.

    Returns:
        The trajectory; ``trajectory(t)`` gives (q, q̇, q̈).
    """
    n = chain_model(model).n
    if not (np.isfinite(duration) and duration > 0):
        raise ValueError(f"duration must be a positive time in seconds, got {duration}")
    if not (np.isfinite(base_frequency) and base_frequency > 0):
        raise ValueError(f"base_frequency must be a positive frequency in Hz, got {base_frequency}")
    if int(n_harmonics) != n_harmonics or n_harmonics < 1:
        raise ValueError(f"n_harmonics must be a positive integer, got {n_harmonics}")
    n_harmonics = int(n_harmonics)
    if rest_at_ends and n_harmonics < 2:
        raise ValueError("rest_at_ends needs n_harmonics >= 2")
    if not 0.0 <= margin < 0.5:
        raise ValueError(f"margin must be in [0, 0.5), got {margin}")
    if velocity_limit is None:
        v_max = _model_velocity_limit(model, n)
    else:
        v_max = as_vector("velocity_limit", velocity_limit, n)
        if np.any(v_max <= 0):
            raise ValueError(f"velocity_limit must be positive, got {v_max}")
    lower, upper = _joint_limits(model)

    rng = np.random.default_rng(seed)
    harmonics = np.arange(1, n_harmonics + 1)
    a = rng.normal(size=(n, n_harmonics)) / harmonics
    b = rng.normal(size=(n, n_harmonics)) / harmonics
    if rest_at_ends:
        a[:, 0] -= a.sum(axis=1)  # q̇(0) = Σ_l a_l = 0
        b[:, 0] -= b @ harmonics  # q̈(0) ∝ Σ_l l b_l = 0
    unit = ExcitationTrajectory(np.zeros(n), a, b, float(base_frequency), float(duration))
    grid = np.linspace(0.0, 1.0 / base_frequency, _GRID_PER_HARMONIC * n_harmonics, False)
    q, qd, _ = unit.evaluate(grid)
    q_max, q_min = q.max(axis=0), q.min(axis=0)
    width = (upper - lower) * (1.0 - 2.0 * margin)
    scale = width / (q_max - q_min)
    if v_max is not None:
        scale = np.minimum(scale, v_max / np.abs(qd).max(axis=0))
    scale *= 1.0 - _GRID_SAFETY
    offset = 0.5 * (lower + upper) - scale * 0.5 * (q_max + q_min)
    return ExcitationTrajectory(
        offset, a * scale[:, None], b * scale[:, None], float(base_frequency), float(duration)
    )
