"""What a real joint drive does to a controller's measurements and commands.

The joint-space environments simulate ideal sensing by default: exact q and q̇, the commanded
torque applied at once and exactly. Then raising a feedback gain costs nothing, and every
ranking is partly a ranking of gains. A real drive pays for gain through four effects, each
modelled here for every joint i (``DriveModel``; :data:`INDUSTRIAL` holds the defaults):

* **Encoder quantisation.** An absolute encoder of b bits per revolution reads
  q_meas = Δ · round(q / Δ), Δ = 2π / 2^b. Default b = 20: the 2^-20-rev class of the
  single-turn absolute encoders used at robot joint outputs (e.g. the RLS AksIM-2 family,
  17–20 bit per its data sheet); Δ = 6.0e-6 rad.
* **Velocity from encoder differences.** No drive measures q̇; the usual estimate is the
  backward difference of two encoder readings one control period apart,
  q̇_meas,k = (q_meas,k − q_meas,k−1) / Δt. Its error is up to Δ / Δt (3.0e-3 rad/s at
  500 Hz), a noise that a velocity gain K_D multiplies.
* **One control period of actuation delay.** The command computed from the measurement at
  t_k is applied from t_k + Δt (sampling, computation and the bus to the drive take a period:
  the computational delay of digital control, Franklin, Powell & Workman, *Digital Control of
  Dynamic Systems*, 3rd ed., §5.x); ``delay_steps`` periods in general. The first period of
  an episode applies its own command (nothing was computed before it).
* **Torque ripple.** A permanent-magnet servo motor's torque varies with the rotor angle
  (cogging and the harmonics of the stator current's field with the rotor flux; the latter
  grow with the load: Dedecan, Ayçiçek & Aydeniz, "Investigation of Torque Ripple in Servo
  Motors with Different Magnet Geometries", Electronics 14(5), 1049, 2025). Modelled as a
  load-proportional harmonic of the motor angle θ_m = N q:
  τ_applied = τ (1 + r sin(h θ_m)), r = ``torque_ripple`` (default 0.02, an ASSUMPTION of the
  order that servo data sheets quote, a few per cent), h = ``ripple_harmonic`` periods per
  motor revolution (default 6, the sixth harmonic of a three-phase machine, per pole pair:
  an ASSUMPTION).

Joint elasticity, the fifth cost the issue names, is ElasticJointTracking's own model.
Defaults are per joint-independent scalars; every effect can be switched off (bits = 0,
``delay_steps`` = 0, r = 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["DRIVES", "INDUSTRIAL", "DriveModel", "DriveState"]


@dataclass(frozen=True)
class DriveModel:
    """Sensing and actuation of one drive per joint (see the module docstring).

    Attributes:
        encoder_bits: bits per revolution of the joint encoder (0 = exact positions);
            the quantum is 2π / 2^bits rad.
        velocity_from_differences: q̇ is the backward difference of the encoder readings
            (else the exact q̇; only sensible with ``encoder_bits`` = 0).
        delay_steps: control periods between a measurement and the torque computed from it.
        torque_ripple: relative amplitude r of the ripple (0 = none).
        ripple_harmonic: ripple periods per motor revolution h.
    """

    encoder_bits: int = 20
    velocity_from_differences: bool = True
    delay_steps: int = 1
    torque_ripple: float = 0.02
    ripple_harmonic: int = 6

    def __post_init__(self) -> None:
        for name, low, high in (
            ("encoder_bits", 0, 40),
            ("delay_steps", 0, 100),
            ("ripple_harmonic", 1, 1000),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not low <= v <= high:
                raise ValueError(f"{name} must be an integer in [{low}, {high}], got {v!r}")
        r = self.torque_ripple
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not 0.0 <= r <= 0.5:
            raise ValueError(f"torque_ripple must be a number in [0, 0.5], got {r!r}")
        if not isinstance(self.velocity_from_differences, bool):
            raise ValueError("velocity_from_differences must be True or False")

    @property
    def resolution(self) -> float:
        """Encoder quantum Δ (rad); 0 for exact positions."""
        return 2.0 * np.pi / 2.0**self.encoder_bits if self.encoder_bits > 0 else 0.0

    def quantize(self, q: np.ndarray) -> np.ndarray:
        """q_meas = Δ round(q / Δ) (a copy of q when exact)."""
        res = self.resolution
        return np.round(q / res) * res if res > 0 else np.array(q, dtype=float, copy=True)

    def ripple(self, tau: np.ndarray, q: np.ndarray, gear_ratio: np.ndarray) -> np.ndarray:
        """τ (1 + r sin(h N q)): the torque a drive applies for the command τ at joint angle q."""
        if self.torque_ripple == 0:
            return tau
        return tau * (1.0 + self.torque_ripple * np.sin(self.ripple_harmonic * gear_ratio * q))


#: Real-drive defaults (module docstring): 20-bit encoders, velocity by differences, one
#: period of delay, 2 % ripple at the 6th harmonic of the motor angle.
INDUSTRIAL = DriveModel()

#: The ``drive`` argument of the joint-space environments: name → model (None = ideal).
DRIVES: dict[str, DriveModel | None] = {"ideal": None, "industrial": INDUSTRIAL}


class DriveState:
    """The drive's memory over episodes of one or ``rows`` arms: the previous encoder reading
    and the commands in flight.

    One code for a single env (``rows=None``: arrays (n,)) and a batch of copies (``rows=N``:
    arrays (N, n), each row its own episode, reset on its own): :meth:`measure` and
    :meth:`actuate` are elementwise per row, so a row of the batch is the single drive given
    that row's numbers.

    Args:
        model: the drive.
        n: joints.
        rows: copies (None: one arm, arrays without the row axis).
    """

    def __init__(self, model: DriveModel, n: int, rows: int | None = None) -> None:
        self.model = model
        self.n = n
        shape = (n,) if rows is None else (rows, n)
        self.q_prev = np.zeros(shape)  # the previous encoder reading (rad)
        # the commands of the last delay_steps + 1 periods, oldest first (N m)
        self._sent = np.zeros((model.delay_steps + 1, *shape))
        # () or (rows,): no command sent yet in the row's episode
        self._fresh = np.ones(shape[:-1], dtype=bool)

    def reset(
        self, q: np.ndarray, qd: np.ndarray, dt: float, rows: Any = None
    ) -> None:
        """Start an episode at (q, q̇) (of ``rows``, an index of the row axis; None: every
        row): the previous reading is the encoder's at q − q̇ Δt, as if the drive had been
        measuring the motion before (the first q̇_meas ≈ q̇, not a jump)."""
        at = ... if rows is None else rows
        self.q_prev[at] = self.model.quantize(np.asarray(q) - np.asarray(qd) * dt)
        self._fresh[at] = True

    def load_row(self, row: int, single: DriveState) -> None:
        """Row ``row`` takes the episode of a single arm's drive ``single`` (rows=None)."""
        self.q_prev[row] = single.q_prev
        self._sent[:, row] = single._sent
        self._fresh[row] = single._fresh

    def measure(self, q: np.ndarray, qd: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(q_meas, q̇_meas) at a control instant, from q, q̇ (n,) or (rows, n); advances the
        difference's memory."""
        q_meas = self.model.quantize(q)
        if self.model.velocity_from_differences:
            qd_meas = (q_meas - self.q_prev) / dt
        else:
            qd_meas = np.array(qd, dtype=float, copy=True)
        self.q_prev = q_meas
        return q_meas, qd_meas

    def actuate(self, tau: np.ndarray) -> np.ndarray:
        """The command applied this period, for the command τ (n,) or (rows, n) computed now:
        the one from ``delay_steps`` periods ago (the oldest of the episode in its first
        ``delay_steps`` periods, i.e. the first command)."""
        sent = self._sent
        sent[:-1] = sent[1:]  # one period older
        sent[-1] = tau
        if self._fresh.any():  # a row's first command stands for the ones never sent
            sent[...] = np.where(self._fresh[..., None], sent[-1], sent)
            self._fresh[...] = False
        return sent[0].copy()
