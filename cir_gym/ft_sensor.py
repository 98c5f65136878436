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
    """A :class:`SensorSpec` running at the physics rate (see the module docstring).

    Call :meth:`reset` at the start of an episode and :meth:`update` after every physics step
    with the true wrench; :attr:`reading` is the last held sample (6,).

    Args:
        spec: the sensor's parameters.
        timestep: physics step (s).
    """

    def __init__(self, spec: SensorSpec, timestep: float) -> None:
        self.spec = spec
        self.timestep = check_number("timestep", timestep, 0.0, 1.0, low_open=True)
        if spec.sample_rate > 1.0 / timestep * (1.0 + 1e-9) and math.isfinite(spec.sample_rate):
            raise InvalidArgument(
                f"sample_rate must be at most the physics rate {1.0 / timestep:g} Hz (or inf), "
                f"got {spec.sample_rate!r}"
            )
        rate = spec.sample_rate
        self.sample_steps = 1 if not math.isfinite(rate) else max(1, round(1 / (rate * timestep)))
        self.delay_steps = round(spec.delay / timestep)
        # exact discretisation of ẏ = ω_c (u − y) with u held over one physics step
        wc = 2 * math.pi * spec.cutoff
        self.alpha = 1.0 if not math.isfinite(wc) else 1.0 - math.exp(-wc * timestep)
        self.bias = np.array(spec.bias)
        self._std = np.repeat(spec.noise_std, 3)
        self._res = np.repeat(spec.resolution, 3)
        # the filter state and the delay line as Python floats: the recursion runs one physics
        # step at a time over six numbers, where a numpy call costs more than the arithmetic
        self._f = [0.0] * 6  # the filtered wrench
        self._nline = self.delay_steps + 1
        self._line: list[tuple[float, ...]] = [(0.0,) * 6] * self._nline  # ring of filtered values
        self._filter = self.alpha < 1.0
        self._noisy = bool(np.any(self._std > 0))
        self._quantised = self._res > 0
        self._any_quantised = bool(np.any(self._quantised))
        self._head = 0
        self._count = 0
        self.reading = np.zeros(6)
        self._rng = np.random.default_rng(0)

    @property
    def sample_period(self) -> float:
        """Time between two samples (s)."""
        return self.sample_steps * self.timestep

    @property
    def _filtered(self) -> np.ndarray:
        """The low-pass filter's output now (6,) (a copy)."""
        return np.array(self._f)

    def reset(
        self,
        rng: np.random.Generator,
        wrench: np.ndarray,
        bias: np.ndarray | None = None,
    ) -> np.ndarray:
        """Start an episode in a steady state at ``wrench`` (the sensor has been on); return
        the first reading. ``bias`` replaces the spec's bias for this episode."""
        self._rng = rng
        if bias is not None:
            self.bias = np.asarray(bias, dtype=float).reshape(6).copy()
        w = np.broadcast_to(np.asarray(wrench, dtype=float), (6,))
        self._f = w.tolist()
        self._line = [tuple(self._f)] * self._nline
        self._head = 0
        self._count = 0
        self._sample()
        return self.reading.copy()

    def update(self, wrench: np.ndarray) -> np.ndarray:
        """Advance one physics step with the true wrench (6,); return the (held) reading."""
        self._run((np.broadcast_to(np.asarray(wrench, dtype=float), (6,)).tolist(),))
        return self.reading.copy()

    def advance(self, wrench: np.ndarray) -> None:
        """:meth:`update` without the copy of the reading it returns (an env's physics loop
        reads :attr:`reading` when it needs it). ``wrench``: a float64 (6,) array, read
        before this returns (a view of MuJoCo's sensordata will do)."""
        self._run((wrench.tolist(),))

    def update_many(self, wrenches: np.ndarray) -> np.ndarray:
        """Advance ``len(wrenches)`` physics steps, one true wrench (6,) each, in time order
        ((N, 6), oldest first): the same as N calls of :meth:`update`; return the
        reading after the last."""
        self._run(np.asarray(wrenches, dtype=float).reshape(-1, 6).tolist())
        return self.reading.copy()

    def advance_many(self, wrenches: Any) -> None:
        """:meth:`update_many` of the rows of ``wrenches`` (a sequence of six floats each,
        e.g. ``array.tolist()``), without the copy of the reading."""
        self._run(wrenches)

    def _run(self, rows: Any) -> None:
        """Advance one physics step per row (six floats), oldest first: filter, delay line,
        sampling (see the module docstring).

        Only the last sample of the rows is computed: the earlier ones would be replaced
        before anyone reads :attr:`reading`. Their noise is still drawn, all at once (the
        generator's stream is the same as sample by sample: nothing else draws in between).
        """
        f0, f1, f2, f3, f4, f5 = self._f
        alpha, line, nline = self.alpha, self._line, self._nline
        head, count, steps = self._head, self._count, self.sample_steps
        filtering = self._filter
        samples, held = 0, None
        for w0, w1, w2, w3, w4, w5 in rows:
            if filtering:  # filtered += (w − filtered) α, entry by entry
                f0 += (w0 - f0) * alpha
                f1 += (w1 - f1) * alpha
                f2 += (w2 - f2) * alpha
                f3 += (w3 - f3) * alpha
                f4 += (w4 - f4) * alpha
                f5 += (w5 - f5) * alpha
            else:  # no filter: exactly the input
                f0, f1, f2, f3, f4, f5 = w0, w1, w2, w3, w4, w5
            head += 1
            if head == nline:
                head = 0
            line[head] = (f0, f1, f2, f3, f4, f5)
            count += 1
            if count >= steps:
                count = 0
                samples += 1
                oldest = head + 1  # the value delay_steps ago
                held = line[0 if oldest == nline else oldest]
        self._f = [f0, f1, f2, f3, f4, f5]
        self._head, self._count = head, count
        if held is not None:
            self._sample(held, samples)

    def _sample(self, held: tuple[float, ...] | None = None, draws: int = 1) -> None:
        """Set :attr:`reading` from the delayed filtered value ``held`` (default: the one
        ``delay_steps`` ago now), the last of ``draws`` samples (the noise of the others is
        drawn and discarded, as their readings were overwritten)."""
        if held is None:
            oldest = self._head + 1
            held = self._line[0 if oldest == self._nline else oldest]
        value = np.array(held) + self.bias
        if self._noisy:
            value += self._std * self._rng.standard_normal(6 * draws)[-6:]
        if self._any_quantised:  # rounded to the resolution where it is set
            q, res = self._quantised, self._res
            value[q] = np.round(value[q] / res[q]) * res[q]
        self.reading = value


def tool_gravity_wrench(
    mass: float, com: np.ndarray, R_ws: np.ndarray, gravity: np.ndarray = GRAVITY
) -> np.ndarray:
    """The reading (6,) a static tool gives: the supporting force and torque, sensor frame.

    ``f = −m R_wsᵀ g`` and ``μ = c × f`` with ``c`` (3,) the tool's centre of mass in the sensor
    frame (m) and ``R_ws`` (3, 3) the sensor-to-world rotation.
    """
    f = -mass * (R_ws.T @ np.asarray(gravity, dtype=float))
    return np.concatenate((f, np.cross(np.asarray(com, dtype=float), f)))


def contact_wrench(
    reading: np.ndarray,
    R_ws: np.ndarray,
    *,
    tool_mass: float,
    tool_com: np.ndarray,
    bias: np.ndarray | None = None,
    gravity: np.ndarray = GRAVITY,
) -> np.ndarray:
    """The wrench the tool exerts on the environment, ``h = [f; μ]`` (6,) in the WORLD frame.

    ``reading − bias − tool_gravity_wrench`` in the sensor frame, rotated to the world (the
    torque stays about the sensor origin). Quasi-static: the tool's inertial forces are
    neglected. ``bias`` is the controller's estimate (from re-biasing in free space), zero if
    None.
    """
    h = np.asarray(reading, dtype=float) - tool_gravity_wrench(tool_mass, tool_com, R_ws, gravity)
    if bias is not None:
        h = h - bias
    return np.concatenate((R_ws @ h[:3], R_ws @ h[3:]))
