"""A wrist force/torque sensor as a real one measures: filtered, delayed, sampled, biased, noisy.

MuJoCo's ``force``/``torque`` sensors give the exact wrench between the sensor site's body and
its parent at every physics step (their ``noise`` attribute is metadata that the simulator never
applies). A real six-axis sensor differs in ways that matter to force control (chapter 6): its
electronics low-pass filter the strain-gauge signals, the reading arrives after a transport
delay, the stream is sampled (a 100 Hz sensor holds each value for 10 ms), and every sample
carries an offset (bias, drifting with temperature), noise and a quantisation step.
:class:`WrenchSensor` applies those effects in that order, in our code, once per physics step:

    w_true ─► first-order low-pass (cut-off f_c) ─► delay (s) ─► sample at f_s, hold (ZOH)
           ─► + bias + N(0, σ²) ─► round to the resolution ─► reading

Wrench layout (6,): ``[f; μ]`` (N, N m) in the **sensor frame**, as MuJoCo reports it at the
site: the force and torque (about the site) that the robot's flange exerts on everything
distal to the sensor (the tool). So the reading includes the tool's weight: a static tool of
mass m reads the supporting force −m g (+m|g| upwards, see :func:`tool_gravity_wrench`), and a
tool pressing on a surface reads, on top of that, the force the tool exerts on the surface
(quasi-statically). A controller therefore compensates the tool's weight and re-biases in free
space (:func:`contact_wrench`), as on a real arm.

Presets (:data:`PRESETS`), from the sensors' documents as summarised in
``reference/anchors-ch5-7.md`` (facts; values marked *assumption* are ours):

* ``"robotiq_ft300"``: Robotiq FT 300-S: 100 Hz data stream, 0.01 N / 0.001 N m encoding
  steps, about 0.1 N effective resolution over its 300 N range (Robotiq FT 300 manual; a
  third-party comparison table). Noise std 0.1 N / 0.005 N m (the effective resolution taken
  as the noise level; the torque figure is an assumption), cut-off 20 Hz (an anti-aliasing
  filter well below the 50 Hz Nyquist frequency, assumption: with 50 Hz, at a 1-ms physics
  step, the contact bounces of a sliding tool aliased into a 5 N bias of the 100 Hz samples),
  delay 5 ms (transport over
  the serial/USB link, assumption).
* ``"ati_gamma"``: ATI Gamma SI-32-2.5 class: about 6 mN resolution, sampled up to 7 kHz
  (ATI data sheet). Here sampled at 1 kHz (at most the physics rate can be represented: 1 kHz
  for the robot files' 1-ms step, 4 kHz in AdmittanceContact), noise std 0.01 N / 0.0005 N m,
  resolution 1/160 N / 1/2000 N m (torque: assumption), cut-off 200 Hz, delay 1 ms
  (assumptions).
* ``"ideal"``: the exact MuJoCo wrench every physics step (tests, upper bounds).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from cir_gym.validation import InvalidArgument, as_float_array, check_number

__all__ = [
    "PRESETS",
    "SensorSpec",
    "WrenchSensor",
    "contact_wrench",
    "preset",
    "sensor_spec",
    "tool_gravity_wrench",
]

GRAVITY = np.array([0.0, 0.0, -9.81])  # m/s², the robots' <option gravity>


@dataclass(frozen=True)
class SensorSpec:
    """The parameters of a six-axis force/torque sensor.

    Attributes:
        bias: (6,) constant offset added to every sample (N, N m); the env may draw it per
            episode (``randomize``).
        noise_std: (force, torque) standard deviation of white Gaussian noise per sample
            (N, N m).
        resolution: (force, torque) quantisation step (N, N m); 0 = none.
        sample_rate: samples per second (Hz); ``inf`` = every physics step. The sample period
            is rounded to a whole number of physics steps.
        cutoff: −3 dB frequency of the first-order low-pass filter (Hz); ``inf`` = none.
        delay: transport delay (s), rounded to whole physics steps.
    """

    bias: tuple[float, ...] = (0.0,) * 6
    noise_std: tuple[float, float] = (0.0, 0.0)
    resolution: tuple[float, float] = (0.0, 0.0)
    sample_rate: float = math.inf
    cutoff: float = math.inf
    delay: float = 0.0

    def __post_init__(self) -> None:
        bias = as_float_array("bias", self.bias)
        if bias.shape != (6,) or np.any(np.abs(bias) > 1000.0):
            raise InvalidArgument(
                f"bias must be 6 numbers (N, N m) in [-1000, 1000], got {self.bias!r}"
            )
        object.__setattr__(self, "bias", tuple(float(b) for b in bias))
        for name, high in (("noise_std", 100.0), ("resolution", 10.0)):
            value = getattr(self, name)
            arr = as_float_array(name, value) if not isinstance(value, bool) else None
            if arr is not None and arr.shape == ():
                arr = np.array([arr, arr])  # one number for both
            if arr is None or arr.shape != (2,) or np.any(arr < 0) or np.any(arr > high):
                raise InvalidArgument(
                    f"{name} must be a number or (force, torque), each in [0, {high}], "
                    f"got {value!r}"
                )
            object.__setattr__(self, name, (float(arr[0]), float(arr[1])))
        for name in ("sample_rate", "cutoff"):  # ≥ 0.01 Hz: one sample per 100 s at most
            object.__setattr__(self, name, check_number(name, getattr(self, name), 0.01, math.inf))
        object.__setattr__(self, "delay", check_number("delay", self.delay, 0.0, 1.0))


PRESETS: dict[str, SensorSpec] = {
    "ideal": SensorSpec(),
    "robotiq_ft300": SensorSpec(
        noise_std=(0.1, 0.005),
        resolution=(0.01, 0.001),
        sample_rate=100.0,
        cutoff=20.0,
        delay=0.005,
    ),
    "ati_gamma": SensorSpec(
        noise_std=(0.01, 0.0005),
        resolution=(1.0 / 160.0, 1.0 / 2000.0),
        sample_rate=1000.0,
        cutoff=200.0,
        delay=0.001,
    ),
}


def preset(sensor: Any, name: str = "sensor") -> SensorSpec:
    """The preset named ``sensor`` (a key of :data:`PRESETS`).

    Raises:
        InvalidArgument: naming the argument ``name``, the value and the presets, for any
            other value (another string, a list, None, …).
    """
    if isinstance(sensor, str) and sensor in PRESETS:
        return PRESETS[sensor]
    raise InvalidArgument(
        f"{name} must be one of the presets {sorted(PRESETS)}, got {sensor!r}"
    )


def sensor_spec(sensor: str | SensorSpec, **changes: Any) -> SensorSpec:
    """A preset by name (see :data:`PRESETS`) or a :class:`SensorSpec`, with fields replaced.

    Raises:
        InvalidArgument: ``sensor`` is neither (its message names ``sensor``, the value and
            the presets).
    """
    if isinstance(sensor, SensorSpec):
        spec = sensor
    elif isinstance(sensor, str) and sensor in PRESETS:
        spec = PRESETS[sensor]
    else:
        raise InvalidArgument(
            f"sensor must be one of the presets {sorted(PRESETS)} or a SensorSpec, "
            f"got {sensor!r}"
        )
    return replace(spec, **changes) if changes else spec


class WrenchSensor:
    """A :class:`SensorSpec` running at the physics rate (see the module docstring), for one
    sensor or for ``num_envs`` independent copies (a vector env's rows).

    Call :meth:`reset` at the start of an episode and :meth:`advance` (or :meth:`update`)
    after every physics step with the true wrench, or :meth:`advance_many` once with a
    control period's wrenches; :attr:`reading` is the last held sample.

    Shapes: one sensor (``num_envs=None``) reads and takes (6,) wrenches, a period's as
    (K, 6); a batch takes (num_envs, 6) and (num_envs, K, 6) (time along axis −2, oldest
    first) and :attr:`reading` is (num_envs, 6). Each copy has its own filter, delay line,
    sample clock, bias and random generator, so copy i of a batch reads what a single sensor
    reset with copy i's generator reads (to round-off: the filter is evaluated as a matrix
    product over the period, :meth:`_run`).

    Args:
        spec: the sensor's parameters.
        timestep: physics step (s).
        num_envs: copies (≥ 1), or None for one sensor.
    """

    def __init__(self, spec: SensorSpec, timestep: float, num_envs: int | None = None) -> None:
        self.spec = spec
        self.timestep = check_number("timestep", timestep, 0.0, 1.0, low_open=True)
        if spec.sample_rate > 1.0 / timestep * (1.0 + 1e-9) and math.isfinite(spec.sample_rate):
            raise InvalidArgument(
                f"sample_rate must be at most the physics rate {1.0 / timestep:g} Hz (or inf), "
                f"got {spec.sample_rate!r}"
            )
        self.num_envs = (
            None if num_envs is None else int(check_number("num_envs", num_envs, 1, 1e7))
        )
        rows = 1 if self.num_envs is None else self.num_envs
        rate = spec.sample_rate
        self.sample_steps = 1 if not math.isfinite(rate) else max(1, round(1 / (rate * timestep)))
        self.delay_steps = round(spec.delay / timestep)
        # exact discretisation of ẏ = ω_c (u − y) with u held over one physics step
        wc = 2 * math.pi * spec.cutoff
        self.alpha = 1.0 if not math.isfinite(wc) else 1.0 - math.exp(-wc * timestep)
        self._std = np.repeat(spec.noise_std, 3)
        self._res = np.repeat(spec.resolution, 3)
        self._quantised = self._res > 0
        self._all_quantised = bool(self._quantised.all())
        self._noisy = bool(np.any(self._std > 0))
        self._filtering = self.alpha < 1.0
        # the state of every copy, rows first (one row for a single sensor)
        self._bias = np.tile(np.array(spec.bias), (rows, 1))  # (rows, 6)
        self._f = np.zeros((rows, 6))  # the low-pass filter's output now
        # the delay line (its last delay_steps values, oldest first), then a period's new ones
        self._buffer = np.zeros((rows, self.delay_steps, 6))
        self._count = np.zeros(rows, dtype=np.int64)  # physics steps since the last sample
        self._reading = np.zeros((rows, 6))
        self._rngs = [np.random.default_rng(0)] * rows
        self._filters: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def reading(self) -> np.ndarray:
        """The last held sample [f; μ] (N, N m), sensor frame: (6,), or (num_envs, 6)."""
        return self._reading[0] if self.num_envs is None else self._reading

    @property
    def bias(self) -> np.ndarray:
        """This episode's bias (N, N m): (6,), or (num_envs, 6)."""
        return self._bias[0] if self.num_envs is None else self._bias

    @property
    def sample_period(self) -> float:
        """Time between two samples (s)."""
        return self.sample_steps * self.timestep

    @property
    def _filtered(self) -> np.ndarray:
        """The low-pass filter's output now, (6,) or (num_envs, 6) (a copy)."""
        return (self._f[0] if self.num_envs is None else self._f).copy()

    def reset(
        self,
        rng: np.random.Generator | Sequence[np.random.Generator],
        wrench: np.ndarray,
        bias: np.ndarray | None = None,
        rows: Any = None,
    ) -> np.ndarray:
        """Start an episode in a steady state at ``wrench`` (the sensor has been on); return
        the first reading (a copy).

        Args:
            rng: the noise's generator; for a batch one per reset row.
            wrench: (6,), or for a batch (len(rows), 6) (a (6,) is every row's).
            bias: this episode's bias (6,) / (len(rows), 6) replacing the spec's; None: the
                spec's.
            rows: a batch's copies to reset (indices; None: all). Not for a single sensor.
        """
        if self.num_envs is None:
            if rows is not None:
                raise InvalidArgument("rows is for a batched sensor (num_envs given), got rows")
            idx, rngs = np.array([0]), [rng]
        else:
            idx = np.arange(self.num_envs) if rows is None else np.atleast_1d(np.asarray(rows))
            rngs = list(rng)  # type: ignore[arg-type]
            if len(rngs) != len(idx):
                raise InvalidArgument(
                    f"rng must be one generator per reset row ({len(idx)}), got {len(rngs)}"
                )
        for i, g in zip(idx.tolist(), rngs, strict=True):
            self._rngs[i] = g
        w = np.broadcast_to(np.asarray(wrench, dtype=float), (len(idx), 6))
        self._bias[idx] = np.array(self.spec.bias) if bias is None else np.broadcast_to(
            np.asarray(bias, dtype=float), (len(idx), 6)
        )
        self._f[idx] = w
        self._buffer[idx, : self.delay_steps] = w[:, None, :]
        self._count[idx] = 0
        self._sample(idx, w, np.ones(len(idx), dtype=np.int64))
        return self.reading.copy()

    def load_row(self, row: int, sensor: WrenchSensor) -> None:
        """Continue the episode of a single ``sensor`` (same spec and timestep) in row ``row``
        of this batch: its filter, delay line, sample clock, bias, reading and generator (the
        same generator object: the row draws on from where the single sensor stopped).
        A vector env resets a copy with a single env and moves the sensor here."""
        if self.num_envs is None or sensor.num_envs is not None:
            raise InvalidArgument("load_row moves a single sensor into a row of a batched one")
        if sensor.spec != self.spec or sensor.timestep != self.timestep:
            raise InvalidArgument("sensor must have this batch's spec and timestep")
        D = self.delay_steps
        self._bias[row] = sensor._bias[0]
        self._f[row] = sensor._f[0]
        self._buffer[row, :D] = sensor._buffer[0, :D]
        self._count[row] = sensor._count[0]
        self._reading[row] = sensor._reading[0]
        self._rngs[row] = sensor._rngs[0]

    def update(self, wrench: np.ndarray) -> np.ndarray:
        """Advance one physics step with the true wrench (6,) / (num_envs, 6); return the
        (held) reading (a copy)."""
        self.advance(wrench)
        return self.reading.copy()

    def advance(self, wrench: np.ndarray) -> None:
        """:meth:`update` without the copy of the reading (an env's physics loop reads
        :attr:`reading` when it needs it). ``wrench`` is read before this returns (a view of
        MuJoCo's sensordata will do)."""
        w = np.asarray(wrench, dtype=float)
        self._run(w.reshape(1, 1, 6) if self.num_envs is None else w.reshape(-1, 1, 6))

    def update_many(self, wrenches: np.ndarray) -> np.ndarray:
        """Advance K physics steps, one true wrench each, oldest first ((K, 6), or
        (num_envs, K, 6)): the same as K calls of :meth:`update`; return the reading after
        the last (a copy)."""
        self.advance_many(wrenches)
        return self.reading.copy()

    def advance_many(self, wrenches: Any, rows: Any = None) -> None:
        """:meth:`update_many` without the copy of the reading. ``wrenches``: (K, 6) (any
        sequence of six-number rows, none for K = 0), or (num_envs, K, 6) for a batch; with
        ``rows`` (a batch's copies: indices or a boolean mask) only those advance, and
        ``wrenches`` is (len(rows), K, 6)."""
        w = np.asarray(wrenches, dtype=float)
        if w.size == 0:
            return
        if rows is None:
            self._run(w.reshape(len(self._f), -1, 6))
            return
        if self.num_envs is None:
            raise InvalidArgument("rows is for a batched sensor (num_envs given), got rows")
        index = np.asarray(rows)
        index = np.flatnonzero(index) if index.dtype == bool else index.reshape(-1)
        if index.size:
            self._run(w.reshape(len(index), -1, 6), index)

    def _filter_matrices(self, steps: int) -> tuple[np.ndarray, np.ndarray]:
        """(L (K, K), b (K, 1)) with which the filter's outputs over K steps are
        F = L W + b f₀: f_k = β f_{k−1} + α w_k, β = 1 − α, so f_k = β^(k+1) f₀ +
        Σ_{j≤k} α β^(k−j) w_j (0-based k, j)."""
        if steps not in self._filters:
            beta = 1.0 - self.alpha
            k = np.arange(steps)
            lag = k[:, None] - k[None, :]
            L = np.where(lag >= 0, self.alpha * beta ** np.maximum(lag, 0), 0.0)
            self._filters[steps] = (L, (beta ** (k + 1.0))[:, None])
        return self._filters[steps]

    def _run(self, w: np.ndarray, rows: np.ndarray | None = None) -> None:
        """Advance copies K physics steps with their wrenches ``w`` ((rows, K, 6): every copy,
        or those of the index array ``rows``): filter, delay line, sampling (see the module
        docstring).

        The filtered values go into a buffer after the delay line's last ``delay_steps``
        values (oldest first). Only the last sample of each copy in the K steps is computed:
        the earlier ones would be replaced before anyone reads :attr:`reading`. Their noise
        is still drawn, all at once (the generator's stream is the same as sample by
        sample)."""
        K, D = w.shape[1], self.delay_steps
        if self._buffer.shape[1] < D + K:
            grown = np.zeros((len(self._f), D + K, 6))
            grown[:, :D] = self._buffer[:, :D]
            self._buffer = grown
        these = slice(None) if rows is None else rows
        history = self._buffer[these, : D + K]  # (rows, D + K, 6): the delay line, then the new
        new = history[:, D:]
        if self._filtering:
            L, b = self._filter_matrices(K)
            np.matmul(L, w, out=new)
            new += b * self._f[these, None, :]
        else:  # no filter: exactly the input
            new[...] = w
        self._f[these] = new[:, -1]
        total = self._count[these] + K
        samples = total // self.sample_steps  # samples in these K steps
        count = total - samples * self.sample_steps
        self._count[these] = count
        # the last sample at step j = K − count (1-based) holds the value D steps earlier:
        # history index (D + j − 1) − D = j − 1
        sampled = samples.nonzero()[0]
        if sampled.size:
            copies = sampled if rows is None else rows[sampled]
            self._sample(copies, history[sampled, K - 1 - count[sampled]], samples[sampled])
        history[:, :D] = history[:, K:]  # the delay line for the next call
        if rows is not None:  # history was a copy of those rows
            self._buffer[rows, : D + K] = history

    def _sample(self, rows: np.ndarray, held: np.ndarray, draws: np.ndarray) -> None:
        """Set the readings of ``rows`` from their delayed filtered values ``held``
        (len(rows), 6), the last of ``draws`` samples each (the noise of the others is drawn
        and discarded, as their readings were overwritten)."""
        value = held + self._bias[rows]
        if self._noisy:
            for r, (i, n) in enumerate(zip(rows.tolist(), draws.tolist(), strict=True)):
                value[r] += self._std * self._rngs[i].standard_normal(6 * n)[-6:]
        if self._all_quantised:  # rounded to the resolution
            value = np.round(value / self._res) * self._res
        elif self._quantised.any():  # where it is set
            q, res = self._quantised, self._res
            value[:, q] = np.round(value[:, q] / res[q]) * res[q]
        self._reading[rows] = value


def tool_gravity_wrench(
    mass: float, com: np.ndarray, R_ws: np.ndarray, gravity: np.ndarray = GRAVITY
) -> np.ndarray:
    """The reading a static tool gives: the supporting force and torque, sensor frame.

    ``f = −m R_wsᵀ g`` and ``μ = c × f`` with ``c`` (3,) the tool's centre of mass in the sensor
    frame (m) and ``R_ws`` the sensor-to-world rotation: (3, 3) gives one wrench (6,), rows of
    rotations (..., 3, 3) a wrench each (..., 6).
    """
    f = -mass * (np.swapaxes(R_ws, -1, -2) @ np.asarray(gravity, dtype=float))
    return np.concatenate((f, np.cross(np.asarray(com, dtype=float), f)), axis=-1)


def contact_wrench(
    reading: np.ndarray,
    R_ws: np.ndarray,
    *,
    tool_mass: float,
    tool_com: np.ndarray,
    bias: np.ndarray | None = None,
    gravity: np.ndarray = GRAVITY,
) -> np.ndarray:
    """The wrench the tool exerts on the environment, ``h = [f; μ]`` in the WORLD frame.

    ``reading − bias − tool_gravity_wrench`` in the sensor frame, rotated to the world (the
    torque stays about the sensor origin). Quasi-static: the tool's inertial forces are
    neglected. ``bias`` is the controller's estimate (from re-biasing in free space), zero if
    None. Shapes: one reading (6,) with its rotation (3, 3) gives (6,); rows of readings
    (..., 6) with rotations (..., 3, 3) (and biases (..., 6) or (6,)) give (..., 6), each row
    the same numbers as alone.
    """
    R_ws = np.asarray(R_ws, dtype=float)
    h = np.asarray(reading, dtype=float) - tool_gravity_wrench(tool_mass, tool_com, R_ws, gravity)
    if bias is not None:
        h = h - bias
    return np.concatenate(((R_ws @ h[..., :3, None])[..., 0], (R_ws @ h[..., 3:, None])[..., 0]),
                          axis=-1)
