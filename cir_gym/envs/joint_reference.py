"""The joint-space references of JointTracking and ElasticJointTracking: what a reset draws.

Each reference is q̄(t), q̄̇(t), q̄̈(t) sampled at the control instants t_k = k Δt,
k = 0 … K, built with :mod:`cir_gym.trajectories` inside the robot's joint limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cir_gym import trajectories as traj

REFERENCES = ("random", "regulation", "quintic", "sine")


@dataclass(frozen=True)
class JointReferenceRanges:
    """How far from home the references go (per joint, uniform draws).

    Attributes:
        start_spread: half-width (rad) of the start posture around home (random, quintic).
        via_points: points of the random multi-point spline.
        speed_fraction: the random spline's and the sine's peak speed / the velocity limit.
        limit_margin: fraction of each joint's range kept free at both ends (quintic goal,
            regulation start and setpoint).
        sine_amplitude: (low, high) amplitude of the sine (rad), before the speed cap.
        sine_frequency: (low, high) frequency of the sine (Hz).
    """

    start_spread: float = 0.2
    via_points: int = 5
    speed_fraction: float = 0.5
    limit_margin: float = 0.1
    sine_amplitude: tuple[float, float] = (0.1, 0.4)
    sine_frequency: tuple[float, float] = (0.2, 0.6)


#: The ranges of the iiwa 14's episodes.
IIWA14_RANGES = JointReferenceRanges()


def draw_joint_reference(
    kind: str,
    rng: np.random.Generator,
    home: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    velocity_limit: np.ndarray,
    times: np.ndarray,
    ranges: JointReferenceRanges = IIWA14_RANGES,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One episode's reference and start state.

    Args:
        kind: one of ``REFERENCES``: "random" (multi-point spline from near home, speed ≤
            ``speed_fraction`` × the velocity limit), "quintic" (rest to rest from near home
            to a random goal), "sine" (one sine per joint about home), "regulation" (a
            constant random setpoint; the start another random posture).
        rng: the episode's generator (every draw comes from it).
        home: the home posture (n,) rad.
        lower, upper: joint limits (n,) rad.
        velocity_limit: joint speed limits (n,) rad/s.
        times: the control instants t_0 … t_K (K + 1,) s; the episode lasts t_K.

    Returns:
        (ref, q0, qd0): ref (3, K + 1, n) = q̄, q̄̇, q̄̈ at each instant; the start state q(0),
        q̇(0) (n,): on the reference, except for "regulation".
    """
    n = home.size
    margin = ranges.limit_margin * (upper - lower)
    duration = float(times[-1])
    ref = np.zeros((3, times.size, n))
    if kind == "regulation":
        ref[0] = rng.uniform(lower + margin, upper - margin)
        return ref, rng.uniform(lower + margin, upper - margin), np.zeros(n)
    if kind == "random":
        trajectory = traj.random_joint_trajectory(
            rng,
            lower,
            upper,
            duration=duration,
            n_points=ranges.via_points,
            v_max=ranges.speed_fraction * velocity_limit,
            start=home + rng.uniform(-ranges.start_spread, ranges.start_spread, n),
        )
    elif kind == "quintic":
        goal = rng.uniform(lower + margin, upper - margin)
        start = home + rng.uniform(-ranges.start_spread, ranges.start_spread, n)
        trajectory = traj.QuinticPolynomial(start, goal, duration)
    elif kind == "sine":
        amplitude = rng.uniform(*ranges.sine_amplitude, n)
        frequency = rng.uniform(*ranges.sine_frequency, n)
        # peak speed A 2π f ≤ speed_fraction × the limit
        amplitude = np.minimum(
            amplitude, ranges.speed_fraction * velocity_limit / (2 * np.pi * frequency)
        )
        trajectory = traj.SineTrajectory(home, amplitude, frequency, rng.uniform(0, 2 * np.pi, n))
    else:
        raise ValueError(f"reference must be one of {REFERENCES}, got {kind!r}")
    ref[0], ref[1], ref[2] = trajectory.evaluate(times)
    return ref, ref[0, 0].copy(), ref[1, 0].copy()
