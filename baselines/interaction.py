"""Chapter 6, interaction control: impedance, admittance, explicit, implicit, parallel force.

The task (``AdmittanceContact``): approach a compliant surface, press with the reference normal
force f̄ and follow a wiping path on it. A controller knows the *nominal* surface (a point s₀ and
the normal n̂), the tool (mass, centre of mass), the nominal arm, the sensor's timing and — when
the env says so — the surface's stiffness k̂ (``context.extras``); the true surface is off by a
few mm and degrees, and with ``randomize=True`` its stiffness is unknown (each law then designs
for its worst case in [1e3, 1e5] N/m, see below).

**Measurement** (all laws): the wrench the tool exerts on the environment,
ĥ = R_s (w − b̂ − w_tool(R_s)) (:func:`cir_gym.ft_sensor.contact_wrench`): the sensor reading w
minus the tool's weight and the bias b̂, which the controller *re-biases* as on a real arm — it
holds still for the first ``bias_time`` s in free space and averages w − w_tool. The normal force
is f̂ = −n̂ · ĥ_f (positive when pressing).

**Guarded approach** (admittance, explicit, implicit, parallel): force laws cannot find the
surface, so until f̂ first exceeds ``contact_force`` the tool moves along −n̂ at ``approach_speed``;
at that instant each law takes over with its state initialised for continuity (the state of every
filter, the contact flag and the bias live in the policy state, reset at each episode start).

**Force reference** (the four force-feedback laws alike): the course's form takes f̄ as a step at
the first contact (``ramp_time=0``, the default). With ``ramp_time`` T > 0 every law tracks f_r
instead, a quintic from f̂ at the first contact to f̄ in T s (the same shaping for each law);
explicit force control can add, with ``feedforward=True``, the nominal plant's inverse on that
ramp (a model-based feed-forward the other laws do not have).

**Motion** (tangential directions and orientation): the compliant/commanded frame follows the
path reference projected on the nominal surface plane, with the task's constant tool
orientation. On the position interface (``control="position"``) a law outputs the increment from
the env's current setpoint to its x_c. On the torque interface a position-based law (admittance,
implicit, parallel) runs the high-gain inner motion controller itself: operational-space inverse
dynamics τ = Jᵀ Λ (K_P (x_c − x) + K_D (ẋ_c − ẋ) − J̇q̇) + n̂(q, q̇) + N_dynᵀ τ₀ with
K_P = ω_i², K_D = 2ω_i, ω_i = ``inner_omega`` (the same stiffness as the env's position interface,
Λ ω_i² ≈ 2·10⁵ N/m along n̂ at the start pose), τ₀ a posture PD in the dynamically consistent null
space.

The laws along n̂ and their design rules (control-laws.md §6, cir-notes.txt §6.2–6.5):

* ``impedance`` (torque interface): M_d x̃̈ + D_d x̃̇ + K_d x̃ = h_e with force measurement,
  F = Λ (ẍ_d + M_d⁻¹(D_d x̃̇ + K_d x̃ − ĥ) − J̇q̇) + ĥ. No force loop: the force is set by the
  equilibrium of the impedance against the environment's stiffness k̂. At rest the impedance's
  spring and the surface carry the same force, K_d,n (x − x_d)·n̂ = f = k̂ (s₀ − x)·n̂, so
  f = f̄ on the nominal surface needs x_d = path − n̂ f̄ (1/K_d,n + 1/k̂): the setpoint sunk by
  the impedance's deflection f̄/K_d,n *and* the surface's f̄/k̂ (``surface_compliance=False``
  leaves out f̄/k̂: on a soft surface the force is then f̄ k/(K_d,n + k), half of f̄ when
  k = K_d,n). A surface height error e gives a force error K_d,n k/(K_d,n + k) e. Unknown
  stiffness: design at 1e5 N/m (the smallest sink: a soft surface is pressed too little,
  never a stiff one too hard).
* ``admittance``: x_c = x̄ + Δ with M_d Δ̈ + D_d Δ̇ + K_d Δ = ĥ_ext − h̄ (the admittance filter
  H(s) = 1/(M_d s² + D_d s + K_d) on the force error, K_d,n = 0: integral force control through the
  stiff inner loop). With x ≈ x_c the force loop is L(s) = k_e/(M_d s² + D_d s), k_e the
  surface in series with the arm's servo stiffness: crossover ω_c ≈ k̂_e/D_d. Rule: D_d = k̂_e/ω_c,
  M_d = D_d/(4ω_c) (the filter's pole a factor 4 above crossover), ω_c = min(``crossover``,
  ω_s) with ω_s = 1/(3 τ_s) the sensor's limit (τ_s: delay + half a sample period + the filter's
  time constant + a control period + one physics step) so the sensor costs ≤ 20° of phase.
  Unknown stiffness: design at 1e5 N/m (the loop gain is largest on the stiffest surface).
* ``explicit_force`` (torque interface): the notes' force loop with integral regulator
  R_f(s) = K_if/s on the plant G_f(s) = ω_n²/(s² + 2ζω_n s + ω_n²), ω_n = √(k̂/m̂), m̂ = Λ_nn:
  the commanded normal force u = f̄ + K_if ∫(f̄ − f̂) dt, applied as F_n = −u − d ẋ_n with an
  active damping d = 2ζ√(k̂ m̂) (the notes' plant is undamped: with a pure integrator s³ +
  ω_n² s + K_if ω_n² fails Routh for any K_if > 0; with d it needs K_if < d/m̂ = 2ζω_n).
  Crossover rule: K_if = ω_cf = ``crossover_ratio`` · ω_n < ω_n (and ≤ ω_s). Unknown
  stiffness: design at 1e3 N/m (ω_n grows with k, so the rule holds on every surface).
  ``crossover_ratio`` ≥ 2ζ breaks Routh: it oscillates and loses contact (tests).
  With the course's step to f̄, K_if = 0.5 ω_n leaves a closed-loop pair at ≈ 0.57 ω_n with
  damping ratio ≈ 0.38: on 1e3 N/m (ω_n ≈ 11 rad/s) the contact transient lasts ≈ 1.7 s, past
  the task's 0.5 s before scoring. ``feedforward=True`` (with ``ramp_time`` > 0 and k̂ known)
  adds the plant's inverse on the ramp, u = f_r + (d ḟ_r + m̂ f̈_r)/k̂ + K_if ∫(f_r − f̂) dt
  (f = k x ⇒ u = f + (d ḟ + m̂ f̈)/k): two degrees of freedom, the feedback unchanged.
* ``implicit_force``: the force loop around the position loop. The inner loop turns a setpoint
  depth into a force through R(s) ≈ k̂_e (1 + s/ω_i) (its stiffness in series with the surface);
  the notes' compensator C(s) = 1/(s R(s)) = 1/(k̂_e s (1 + s/ω_i)) leaves L_f = R_f(s)/s with
  R_f = k_Pf + k_If/s, crossover ω_cf ≈ k_Pf: k_Pf = ω_c (as admittance), k_If = k_Pf²/4
  (the PI's zero a factor 4 below crossover).
* ``parallel_force_position`` (Siciliano et al. §9.6.2, beyond the notes): x_c = x̄ + x_F,
  x_F = −n̂ (K_F e_f + K_I ∫e_f), e_f = f̄ − f̂: the position error along n̂ is left to the
  integral of the force error, so the force wins (force priority) wherever x̄ and the surface
  disagree, and motion control keeps the rest. Rule: K_I = ω_c/k̂_e (crossover ω_c),
  K_F = 0.25/k̂_e.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from cir_gym.baselines.base import (
    Controller,
    InvalidGain,
    Observation,
    RowLaw,
    SiteTerms,
    is_real,
    matvec,
    rows_method,
)

from cir_gym import operational_space as osp
from cir_gym.context import TaskContext
from cir_gym.ft_sensor import contact_wrench, tool_gravity_wrench
from cir_gym.robot import ModelError, Robot, apply_model_error

__all__ = [
    "INTERACTION_CONTROLLERS",
    "Admittance",
    "CommonGains",
    "ExplicitForce",
    "Impedance",
    "ImplicitForce",
    "ParallelForcePosition",
    "PositionBased",
    "sensor_crossover_limit",
]

TASKS = ("AdmittanceContact",)
# state layout shared by every law (then each law's own filter states)
_BIAS = slice(0, 6)  # b̂, the re-biased sensor offset (N, N m)
_BIAS_N, _CONTACT, _TIME, _Z = 6, 7, 8, 9  # bias samples, contact latch, t (s), approach depth
_Q0 = slice(10, 17)  # the start posture (null-space target)
_T_CONTACT, _F_CONTACT = 17, 18  # time since the first contact (s), f̂ at that contact (N)
_COMMON = 19
APPROACH_RAMP = 0.2  # s


def sensor_crossover_limit(context: TaskContext) -> float:
    """ω_s = 1/(3 τ_s) (rad/s): the highest force-loop crossover the sensor allows with ≤ 20° of
    phase lost, τ_s = delay + sample period / 2 + 1/(2π f_c) + control period + physics step."""
    ex = context.extras
    cutoff = float(ex.get("sensor_cutoff", math.inf))
    tau = (
        float(ex.get("sensor_delay", 0.0))
        + 0.5 * float(ex.get("sensor_period", 0.0))
        + (1.0 / (2 * math.pi * cutoff) if math.isfinite(cutoff) else 0.0)
        + context.dt
        + float(ex.get("physics_timestep", 0.0))
    )
    return 1.0 / (3.0 * tau)


def _positive(gains: Any, *names: str, allow_zero: tuple[str, ...] = ()) -> None:
    for name in names:
        value = getattr(gains, name)
        if value is None:
            continue
        ok = (is_real(value) and np.isfinite(value)
              and (value >= 0 if name in allow_zero else value > 0))
        if not ok:
            bound = ">= 0" if name in allow_zero else "> 0"
            raise InvalidGain(f"{name} must be a finite number {bound}, got {value!r}")


@dataclass(frozen=True)
class CommonGains:
    """Gains every interaction law shares (SI units).

    stiffness: the surface stiffness k̂ the law is designed for (N/m); None = the env's nominal
        value, or the law's worst case in the env's range when the env draws it.
    approach_speed: guarded-approach speed along −n̂ until first contact (m/s).
    slow_height: height above the nominal surface below which the approach slows down (m),
        more than the surface's height uncertainty.
    slow_speed: the approach speed below ``slow_height`` (m/s): the impact on the stiffest
        surface is ≈ v √(k_e m̂), about 10 N at 1 cm/s.
    contact_force: measured normal force that declares the first contact (N).
    ramp_time: the force reference f_r rises from f̂ at the first contact to f̄ along a
        quintic in this time (s); 0 = the course's step to f̄ (module docstring).
    bias_time: time held still at the start to re-bias the sensor (s).
    motion_omega: natural frequency of the tangential/orientation motion control (rad/s).
    inner_omega: natural frequency of the inner motion loop on the torque interface (rad/s).
    posture_omega: null-space posture PD frequency (rad/s).
    """

    stiffness: float | None = None
    approach_speed: float = 0.025
    slow_height: float = 0.008
    slow_speed: float = 0.01
    contact_force: float = 2.0
    ramp_time: float = 0.0
    bias_time: float = 0.1
    motion_omega: float = 40.0
    inner_omega: float = 150.0
    posture_omega: float = 10.0

    def __post_init__(self) -> None:
        _positive(
            self,
            "stiffness",
            "approach_speed",
            "slow_height",
            "slow_speed",
            "contact_force",
            "motion_omega",
            "inner_omega",
            "posture_omega",
        )
        _positive(self, "bias_time", "ramp_time", allow_zero=("bias_time", "ramp_time"))


class _Interaction(RowLaw):
    """Shared: the nominal arm with its tool, re-biasing, f̂, the guarded approach, the motion
    laws and both output interfaces (see the module docstring).

    Every law is written once on rows of observations (values (N, ...), state (N, size)):
    the branches of one row (holding, approaching, in contact) are masks over the rows, the
    model calls run row by row (:meth:`Controller.model_rows`), one observation is a row of
    one. The gains of :meth:`design` come from the start posture, which the task fixes
    (every row's ``initial_state`` designs the same gains).
    """

    tasks: ClassVar[tuple[str, ...]] = TASKS
    #: the stiffness in the env's range each law designs for when it is unknown: 0 low, 1 high
    worst_case: ClassVar[int] = 1
    needs_torque: ClassVar[bool] = False

    def __init__(
        self,
        context: TaskContext,
        gains: Any = None,
        *,
        robot: Robot | None = None,
        **overrides: Any,
    ) -> None:
        super().__init__(context, gains, **overrides)
        ex = context.extras
        if "surface_normal" not in ex:
            raise InvalidGain(f"{self.name} needs an AdmittanceContact context (surface_normal)")
        self.torque = context.action_kind == "joint_torque"
        if self.needs_torque and not self.torque:
            raise InvalidGain(
                f"{self.name} commands joint torques: it needs control='torque', not the "
                f"position interface ({context.action_kind!r})"
            )
        self.tool_mass = float(ex["tool_mass"])
        self.tool_com = np.asarray(ex["tool_com"], dtype=float)
        self.robot = robot if robot is not None else context.nominal_robot()
        if robot is None:
            apply_model_error(self.robot.model, ModelError(payload_mass=self.tool_mass))
            self.robot.invalidate()
        self.site = self.robot.site_id(context.site or "tcp")
        self.ft_site = self.robot.site_id("ft_site")
        self.normal = np.asarray(ex["surface_normal"], dtype=float)
        self.surface_point = np.asarray(ex["surface_point"], dtype=float)
        self.quat_ref = np.asarray(ex["tool_quat"], dtype=float)
        lo, hi = ex.get("stiffness_range", (1e3, 1e5))
        g = self.gains
        self.k_hat = float(
            g.stiffness
            if g.stiffness is not None
            else ex.get("stiffness") or (lo if self.worst_case == 0 else hi)
        )
        self.omega_s = sensor_crossover_limit(context)

    # ------------------------------------------------------------------ model quantities
    def lambda_normal(self, q: np.ndarray) -> float:
        """m̂ = n̂ᵀ Λ_p n̂ (kg): the arm's inertia along the normal (translational Λ at q)."""
        J = self.robot.jacobian(self.site, q)[:3]
        Lp = osp.task_inertia(J, self.robot.inertia(q))
        return float(self.normal @ Lp @ self.normal)

    def servo_stiffness(self, q: np.ndarray) -> float:
        """Λ_nn ω_i²: the inner motion loop's stiffness along n̂ (N/m)."""
        return self.lambda_normal(q) * self.gains.inner_omega**2

    def effective_stiffness(self, q: np.ndarray) -> float:
        """k̂_e: the surface in series with the inner loop's servo stiffness (N/m)."""
        k_arm = self.servo_stiffness(q)
        return 1.0 / (1.0 / self.k_hat + 1.0 / k_arm)

    # ------------------------------------------------------------------ state
    @property
    def state_size(self) -> int:
        return _COMMON + self.law_size

    law_size: ClassVar[int] = 0

    def initial_state(self, obs: Observation) -> np.ndarray:
        s = np.zeros(self.state_size)
        s[_Z] = float(self.normal @ (obs["tool_pos"] - self.surface_point))
        s[_Q0] = obs["q"]
        self._design_at(s[_Q0])
        return s

    def design(self, q: np.ndarray) -> None:
        """Compute the law's gains from its rules at the start posture ``q``."""

    def _design_at(self, q0: np.ndarray) -> None:
        """:meth:`design` at the start posture ``q0`` unless the gains are already its."""
        if not np.array_equal(getattr(self, "_designed_at", None), q0):
            self.design(q0)
            self._designed_at = np.array(q0, dtype=float)

    @rows_method
    def control_batch(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        """:meth:`control_rows` with the gains designed at the rows' start posture (the state's
        q0): all rows at once when they started at one posture (every AdmittanceContact
        episode starts at the same one), else row by row, each with its own design."""
        q0 = state[:, _Q0]
        if np.all(q0 == q0[0]):
            self._design_at(q0[0])
            return self.control_rows(obs, state)
        out = []
        for i in range(len(q0)):
            self._design_at(q0[i])
            row = {key: value[i : i + 1] for key, value in obs.items()}
            out.append(self.control_rows(row, state[i : i + 1]))
        return np.concatenate(out)

    # ------------------------------------------------------------------ measurement
    def measure(
        self, obs: Observation, state: np.ndarray, R_s: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """ĥ (N, 6) world wrenches on the environment and f̂ (N,) (N) of rows, with the
        sensor rotations R_s (N, 3, 3); re-biases the rows within ``bias_time``."""
        wrench = obs["wrench"]
        for i in np.flatnonzero(state[:, _TIME] < self.gains.bias_time):
            # free space, held still: average w − w_tool
            sample = wrench[i] - tool_gravity_wrench(self.tool_mass, self.tool_com, R_s[i])
            n = state[i, _BIAS_N]
            state[i, _BIAS] = (n * state[i, _BIAS] + sample) / (n + 1)
            state[i, _BIAS_N] = n + 1
        h = np.stack([
            contact_wrench(wrench[i], R_s[i], tool_mass=self.tool_mass, tool_com=self.tool_com,
                           bias=state[i, _BIAS])
            for i in range(len(wrench))
        ])
        return h, -self.along_normal(h[:, :3])

    # ------------------------------------------------------------------ motion
    def along_normal(self, v: np.ndarray) -> np.ndarray:
        """n̂ · v (...) of vectors v (..., 3), one product per vector."""
        return (v[..., None, :] @ self.normal)[..., 0]

    def path_in_plane(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """The path reference and its velocity (N, 3) projected on the nominal surface plane."""
        n, ref, vel = self.normal, obs["tool_pos_ref"], obs["tool_vel_ref"]
        p = ref - self.along_normal(ref - self.surface_point)[:, None] * n
        v = vel - self.along_normal(vel)[:, None] * n
        return p, v

    def osc_torque(
        self,
        obs: Observation,
        state: np.ndarray,
        terms: SiteTerms,
        a_p: np.ndarray,
        force: np.ndarray | None = None,
        normal_free: bool = False,
        omega_o: float | None = None,
    ) -> np.ndarray:
        """τ = Jᵀ F + n̂(q, q̇) + N_dynᵀ τ₀ (N, n), F = Λ ([a_p; a_o] − J̇q̇) (+ ``force``
        (N, 3)), for rows with their site terms (J, B̂, n̂, J̇q̇ at the tool site).

        a_o = K_o φ − D_o ω toward the task's orientation (ω_o = ``motion_omega``);
        ``normal_free`` removes the normal component of the motion force (the explicit force
        law owns that direction).
        """
        q, qd = obs["q"], obs["qd"]
        J, B = terms.J, terms.inertia
        J_T = np.swapaxes(J, -1, -2)
        Lam = osp.task_inertia(J, B)
        w = self.gains.motion_omega if omega_o is None else omega_o
        phi = osp.rotvec_error(self.quat_ref, obs["tool_quat"])
        a_o = w * w * phi - 2.0 * w * obs["tool_angvel"]
        F = matvec(Lam, np.concatenate((a_p, a_o), axis=-1) - terms.jdqd)
        if normal_free:
            F[:, :3] -= self.along_normal(F[:, :3])[:, None] * self.normal
        if force is not None:
            F[:, :3] += force
        J_bar = osp.dynamically_consistent_inverse(J, B, Lam)
        N = osp.null_space_projector(J, J_bar)
        wp = self.gains.posture_omega
        tau0 = matvec(B, wp * wp * (state[:, _Q0] - q) - 2.0 * wp * qd)
        return matvec(J_T, F) + terms.bias + matvec(np.swapaxes(N, -1, -2), tau0)

    def track(
        self, obs: Observation, state: np.ndarray, terms: SiteTerms, x_c: np.ndarray,
        v_c: np.ndarray,
    ) -> np.ndarray:
        """The commands (N, m) that move the tool to the frames x_c (velocities v_c) (N, 3),
        task orientation."""
        if not self.torque:  # the env's motion controller: an increment from its setpoint
            d_p = x_c - obs["setpoint_pos"]
            d_o = osp.rotvec_error(self.quat_ref, obs["setpoint_quat"])
            return np.concatenate((d_p, d_o), axis=-1)
        w = self.gains.inner_omega
        a_p = w * w * (x_c - obs["tool_pos"]) + 2.0 * w * (v_c - obs["tool_vel"])
        return self.osc_torque(obs, state, terms, a_p, omega_o=w)

    # ------------------------------------------------------------------ the loop
    def control_rows(self, obs: Observation, state: np.ndarray) -> np.ndarray:
        g = self.gains
        terms = self.model_rows().site_terms(
            self.site, obs["q"], obs["qd"], inertia=self.torque, bias=self.torque,
            rotations=(self.ft_site,),
        )
        h, f = self.measure(obs, state, terms.rotations[:, 0])
        holding = state[:, _TIME] < g.bias_time
        touch = ~holding & (state[:, _CONTACT] == 0.0) & (f > g.contact_force)
        if touch.any():  # the first contact of these rows
            state[touch, _CONTACT] = 1.0
            state[touch, _T_CONTACT], state[touch, _F_CONTACT] = 0.0, f[touch]
            self.on_contact(obs, state, f, touch)
        command = self.law(obs, state, terms, h, f, holding)
        state[:, _TIME] += self.dt
        state[:, _T_CONTACT] += np.where(state[:, _CONTACT] != 0.0, self.dt, 0.0)
        return command

    def force_reference(
        self, obs: Observation, state: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """f_r, ḟ_r, f̈_r (N, N/s, N/s²), one observation's or rows' (N,): f̄ (the course's
        step, ``ramp_time=0``), or a quintic from f̂ at the first contact to f̄ over
        ``ramp_time`` s (f̄ before the contact)."""
        f_bar = obs["f_ref"][..., 0]
        T = self.gains.ramp_time
        zero = np.zeros_like(f_bar)
        if T <= 0.0:
            return f_bar, zero, zero
        tau = np.minimum(state[..., _T_CONTACT] / T, 1.0)
        df = f_bar - state[..., _F_CONTACT]
        s = tau**3 * (10 - 15 * tau + 6 * tau**2)
        ds = 30 * tau**2 * (1 - tau) ** 2 / T
        dds = 60 * tau * (1 - tau) * (1 - 2 * tau) / T**2
        contact = state[..., _CONTACT] != 0.0
        return (
            np.where(contact, state[..., _F_CONTACT] + df * s, f_bar),
            np.where(contact, df * ds, zero),
            np.where(contact, df * dds, zero),
        )

    def approach(
        self, state: np.ndarray, holding: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The guarded approach's depth coordinate z (along n̂ from s₀) and its rate (N,);
        moves z of the ``rows`` (a mask) that are not holding still."""
        # the speed ramps up over APPROACH_RAMP s: a step would shake the tool's weight
        # through the sensor (m a) and fake a contact
        g = self.gains
        z = state[:, _Z]
        ramp = np.minimum(1.0, (state[:, _TIME] - g.bias_time) / APPROACH_RAMP)
        speed = ramp * np.where(z > g.slow_height, g.approach_speed, g.slow_speed)
        moving = rows & ~holding
        state[:, _Z] = np.where(moving, z - speed * self.dt, z)
        return state[:, _Z], np.where(holding, 0.0, -speed)

    def on_contact(
        self, obs: Observation, state: np.ndarray, f: np.ndarray, rows: np.ndarray
    ) -> None:
        """Initialise the law's filter states of the ``rows`` (a mask) at their first
        contact."""

    def law(
        self, obs: Observation, state: np.ndarray, terms: SiteTerms, h: np.ndarray,
        f: np.ndarray, holding: np.ndarray,
    ) -> np.ndarray:
        raise NotImplementedError


class PositionBased(_Interaction):
    """A law that outputs a depth z_c along n̂: x_c = path (in the plane) + n̂ z_c."""

    def depth(
        self, obs: Observation, state: np.ndarray, f: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """z_c and ż_c (N,) of the force law; advances the filter states of the ``rows`` (a
        mask: those in contact)."""
        raise NotImplementedError

    def law(
        self, obs: Observation, state: np.ndarray, terms: SiteTerms, h: np.ndarray,
        f: np.ndarray, holding: np.ndarray,
    ) -> np.ndarray:
        p, v = self.path_in_plane(obs)
        contact = state[:, _CONTACT] != 0.0
        # holding still (re-bias), then the guarded approach; then the force law
        z_a, z_dot_a = self.approach(state, holding, ~contact)
        z_f, z_dot_f = self.depth(obs, state, f, contact)
        z, z_dot = np.where(contact, z_f, z_a), np.where(contact, z_dot_f, z_dot_a)
        n = self.normal
        return self.track(obs, state, terms, p + z[:, None] * n, v + z_dot[:, None] * n)


# ---------------------------------------------------------------------- impedance
@dataclass(frozen=True)
class ImpedanceGains(CommonGains):
    """Impedance M_d x̃̈ + D_d x̃̇ + K_d x̃ = h_e (translation), with force measurement.

    mass: apparent mass M_d (kg, every direction).
    normal_stiffness: K_d along n̂ (N/m); tangential_stiffness: K_d in the plane (N/m).
    zeta: damping ratio: D_d = 2ζ√(M_d K_d) per direction.
    use_force_ref: sink the setpoint below the nominal surface so that the equilibrium force is
        f̄ (else x_d is the path).
    surface_compliance: the sink includes the surface's deflection f̄/k̂ (the equilibrium of the
        impedance against the environment's stiffness); False = f̄/K_d,n alone.
    """

    mass: float = 10.0
    normal_stiffness: float = 1000.0
    tangential_stiffness: float = 5000.0
    zeta: float = 1.0
    use_force_ref: bool = True
    surface_compliance: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "mass", "normal_stiffness", "tangential_stiffness", "zeta")
        if self.ramp_time != 0.0:
            raise InvalidGain(
                f"ramp_time must be 0 for impedance, got {self.ramp_time!r}: it has no force "
                "reference to shape (its setpoint sink is static); the force laws take ramp_time"
            )


class Impedance(_Interaction):
    """Impedance control with force measurement (torque interface), see the module docstring."""

    name = "impedance"
    Gains = ImpedanceGains
    needs_torque = True

    def __init__(self, context: TaskContext, gains: Any = None, **kw: Any) -> None:
        super().__init__(context, gains, **kw)
        g = self.gains
        n = self.normal
        P = np.outer(n, n)
        self.K = g.normal_stiffness * P + g.tangential_stiffness * (np.eye(3) - P)
        self.D = (
            2
            * g.zeta
            * np.sqrt(g.mass)
            * (
                math.sqrt(g.normal_stiffness) * P
                + math.sqrt(g.tangential_stiffness) * (np.eye(3) - P)
            )
        )

    def sink(self, f_bar: np.ndarray) -> np.ndarray:
        """The setpoint's depth below the nominal surface (m) whose equilibrium force is f̄
        (N, or rows (N,)): f̄ (1/K_d,n + 1/k̂), or f̄/K_d,n without ``surface_compliance``."""
        g = self.gains
        compliance = 1.0 / g.normal_stiffness
        if g.surface_compliance:
            compliance += 1.0 / self.k_hat
        return f_bar * compliance if g.use_force_ref else np.zeros_like(f_bar)

    def setpoint(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """x_d and ẋ_d (3,) of one observation or (N, 3) of rows: the path reference, sunk by
        :meth:`sink`."""
        sink = self.sink(np.asarray(obs["f_ref"], dtype=float)[..., 0])
        x_d = obs["tool_pos_ref"] - self.normal * sink[..., None]
        return x_d, obs["tool_vel_ref"]

    def law(
        self, obs: Observation, state: np.ndarray, terms: SiteTerms, h: np.ndarray,
        f: np.ndarray, holding: np.ndarray,
    ) -> np.ndarray:
        x_d, v_d = self.setpoint(obs)
        still = holding[:, None]  # re-biasing: hold the path's start, no force
        x_d = np.where(still, obs["tool_pos_ref"], x_d)
        v_d = np.where(still, 0.0, v_d)
        h_f = np.where(still, 0.0, h[:, :3])
        # M_d x̃̈ + D_d x̃̇ + K_d x̃ = h_e  ⇒  ẍ = ẍ_d + M_d⁻¹ (D_d x̃̇ + K_d x̃ − h_e)
        a_p = matvec(self.D, v_d - obs["tool_vel"]) + matvec(self.K, x_d - obs["tool_pos"]) - h_f
        a_p = a_p / self.gains.mass
        return self.osc_torque(obs, state, terms, a_p, force=h_f)


# ---------------------------------------------------------------------- admittance
@dataclass(frozen=True)
class AdmittanceGains(CommonGains):
    """Admittance filter along n̂: M_d Δ̈ + D_d Δ̇ + K_d Δ = f̂ − f̄ on the depth.

    crossover: the force loop's crossover ω_c (rad/s), capped by the sensor's ω_s; D_d and M_d
        follow from it (module docstring) unless given.
    damping, mass: D_d (N s/m) and M_d (kg) overrides; None = the rule.
    stiffness_normal: K_d along n̂ (N/m), 0 = integral force control (default).
    """

    crossover: float = 20.0
    damping: float | None = None
    mass: float | None = None
    stiffness_normal: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "crossover", "damping", "mass")
        _positive(self, "stiffness_normal", allow_zero=("stiffness_normal",))


class Admittance(PositionBased):
    """Admittance control: compliant frame from the force error, stiff inner motion loop."""

    name = "admittance"
    Gains = AdmittanceGains
    worst_case = 1
    law_size = 2  # z_c, ż_c

    def design(self, q: np.ndarray) -> None:
        g = self.gains
        self.omega_c = min(g.crossover, self.omega_s)
        self.k_e = self.effective_stiffness(q)
        self.D_d = g.damping if g.damping is not None else self.k_e / self.omega_c
        self.M_d = g.mass if g.mass is not None else self.D_d / (4.0 * self.omega_c)

    def on_contact(
        self, obs: Observation, state: np.ndarray, f: np.ndarray, rows: np.ndarray
    ) -> None:
        state[rows, _COMMON] = state[rows, _Z]
        state[rows, _COMMON + 1] = -self.gains.approach_speed

    def depth(
        self, obs: Observation, state: np.ndarray, f: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        z, z_dot = state[:, _COMMON], state[:, _COMMON + 1]
        # M_d z̈ + D_d ż + K_d z = f̂ − f_r (z up along n̂: pressing too hard moves up)
        f_r = self.force_reference(obs, state)[0]
        z_ddot = f - f_r - self.D_d * z_dot - self.gains.stiffness_normal * z
        z_ddot /= self.M_d
        # semi-implicit Euler, exact for the damping term
        z_dot = (z_dot + self.dt * (z_ddot + self.D_d / self.M_d * z_dot)) / (
            1.0 + self.dt * self.D_d / self.M_d
        )
        z = z + self.dt * z_dot
        state[rows, _COMMON], state[rows, _COMMON + 1] = z[rows], z_dot[rows]
        return z, z_dot


# ---------------------------------------------------------------------- explicit force
@dataclass(frozen=True)
class ExplicitForceGains(CommonGains):
    """Explicit force control along n̂ with an integral regulator (the notes' §6.4).

    crossover_ratio: K_if = ω_cf = ratio · ω_n, ω_n = √(k̂/m̂) (the rule: ratio < 1).
    zeta: ζ of the active damping d = 2ζ√(k̂ m̂) along n̂.
    cap_at_sensor: also cap K_if at the sensor's ω_s.
    feedforward: add the nominal plant's inverse on the reference ramp, (d ḟ_r + m̂ f̈_r)/k̂
        (acts only with ``ramp_time`` > 0 and the stiffness known: with a worst-case k̂ it
        over-drives a stiffer surface).
    """

    crossover_ratio: float = 0.5
    zeta: float = 1.0
    cap_at_sensor: bool = True
    feedforward: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "crossover_ratio", "zeta")


class ExplicitForce(_Interaction):
    """Explicit force control (torque interface), see the module docstring."""

    name = "explicit_force"
    Gains = ExplicitForceGains
    worst_case = 0
    needs_torque = True
    law_size = 1  # ∫(f_r − f̂) dt

    def design(self, q: np.ndarray) -> None:
        g = self.gains
        self.m_hat = self.lambda_normal(q)
        self.omega_n = math.sqrt(self.k_hat / self.m_hat)
        self.k_if = g.crossover_ratio * self.omega_n
        if g.cap_at_sensor:
            self.k_if = min(self.k_if, self.omega_s)
        self.d = 2.0 * g.zeta * math.sqrt(self.k_hat * self.m_hat)
        known = g.stiffness is not None or self.context.extras.get("stiffness") is not None
        self.ff = g.feedforward and known and g.ramp_time > 0.0

    def on_contact(
        self, obs: Observation, state: np.ndarray, f: np.ndarray, rows: np.ndarray
    ) -> None:
        # bumpless transfer: u = f_r + K_if ∫e starts at the measured force f̂
        f_r = self.force_reference(obs, state)[0]
        state[rows, _COMMON] = ((f - f_r) / self.k_if)[rows]

    def law(
        self, obs: Observation, state: np.ndarray, terms: SiteTerms, h: np.ndarray,
        f: np.ndarray, holding: np.ndarray,
    ) -> np.ndarray:
        p, v = self.path_in_plane(obs)
        w = self.gains.motion_omega
        a_p = w * w * (p - obs["tool_pos"]) + 2 * w * (v - obs["tool_vel"])
        x_dot_n = self.along_normal(obs["tool_vel"])
        contact = state[:, _CONTACT] != 0.0
        # holding still, then the guarded approach: PD on z along n̂
        z, z_dot = self.approach(state, holding, ~contact)
        x_n = self.along_normal(obs["tool_pos"] - self.surface_point)
        f_approach = self.m_hat * (w * w * (z - x_n) + 2 * w * (z_dot - x_dot_n))
        # in contact: the force loop
        f_r, df_r, ddf_r = self.force_reference(obs, state)
        e = f_r - f
        state[:, _COMMON] = np.where(contact, state[:, _COMMON] + e * self.dt, state[:, _COMMON])
        # u = f_r + K_if ∫e, with the plant's inverse on the ramp: f = k x ⇒
        # u = f + (d ḟ + m̂ f̈)/k̂ (zero once the ramp is over)
        u = f_r + self.k_if * state[:, _COMMON]
        if self.ff:
            u += (self.d * df_r + self.m_hat * ddf_r) / self.k_hat
        f_n = np.where(contact, -u - self.d * x_dot_n, f_approach)
        return self.osc_torque(
            obs, state, terms, a_p, force=f_n[:, None] * self.normal, normal_free=True
        )


# ---------------------------------------------------------------------- implicit force
@dataclass(frozen=True)
class ImplicitForceGains(CommonGains):
    """Implicit force control: R_f = k_Pf + k_If/s and the compensator C(s) (the notes' §6.5).

    crossover: ω_cf = k_Pf (rad/s), capped at the sensor's ω_s.
    integral_ratio: k_If = integral_ratio · k_Pf².
    """

    crossover: float = 20.0
    integral_ratio: float = 0.25

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "crossover")
        _positive(self, "integral_ratio", allow_zero=("integral_ratio",))


class ImplicitForce(PositionBased):
    """Implicit force control: a force loop around the position loop."""

    name = "implicit_force"
    Gains = ImplicitForceGains
    worst_case = 1
    law_size = 4  # Δ (depth below the contact point), Δ̇, ∫e, z at contact

    def design(self, q: np.ndarray) -> None:
        g = self.gains
        self.k_pf = min(g.crossover, self.omega_s)
        self.k_if = g.integral_ratio * self.k_pf**2
        self.k_e = self.effective_stiffness(q)
        self.omega_i = g.inner_omega

    def on_contact(
        self, obs: Observation, state: np.ndarray, f: np.ndarray, rows: np.ndarray
    ) -> None:
        state[rows, _COMMON : _COMMON + 3] = (0.0, self.gains.approach_speed, 0.0)
        state[rows, _COMMON + 3] = state[rows, _Z]

    def depth(
        self, obs: Observation, state: np.ndarray, f: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        s = state[:, _COMMON : _COMMON + 4].copy()  # Δ, Δ̇, ∫e, z at contact
        e = self.force_reference(obs, state)[0] - f
        s[:, 2] += e * self.dt
        r = self.k_pf * e + self.k_if * s[:, 2]  # R_f(s) e
        # C(s) = 1/(k̂_e s (1 + s/ω_i)):  (k̂_e/ω_i) Δ̈ + k̂_e Δ̇ = r
        tau = 1.0 / self.omega_i
        s[:, 1] = (s[:, 1] + self.dt * r / (self.k_e * tau)) / (1.0 + self.dt / tau)
        s[:, 0] += self.dt * s[:, 1]
        state[rows, _COMMON : _COMMON + 4] = s[rows]
        return s[:, 3] - s[:, 0], -s[:, 1]


# ---------------------------------------------------------------------- parallel
@dataclass(frozen=True)
class ParallelGains(CommonGains):
    """Parallel force/position control: x_F = −n̂ (K_F e + K_I ∫e).

    crossover: ω_c (rad/s) of the integral force loop, capped at ω_s: K_I = ω_c/k̂_e.
    proportional: K_F k̂_e (dimensionless loop gain of the proportional part).
    """

    crossover: float = 20.0
    proportional: float = 0.25

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "crossover")
        _positive(self, "proportional", allow_zero=("proportional",))


class ParallelForcePosition(PositionBased):
    """Parallel force/position control with force priority (Siciliano et al. §9.6.2)."""

    name = "parallel_force_position"
    Gains = ParallelGains
    worst_case = 1
    law_size = 1  # ∫e

    def design(self, q: np.ndarray) -> None:
        g = self.gains
        self.k_e = self.effective_stiffness(q)
        self.k_i = min(g.crossover, self.omega_s) / self.k_e
        self.k_f = g.proportional / self.k_e

    def on_contact(
        self, obs: Observation, state: np.ndarray, f: np.ndarray, rows: np.ndarray
    ) -> None:
        # continuity: z̄ − K_I ∫e = z at contact (z̄ = the path's depth, 0 on the surface)
        z_bar = self.along_normal(obs["tool_pos_ref"] - self.surface_point)
        state[rows, _COMMON] = ((z_bar - state[:, _Z]) / self.k_i)[rows]

    def depth(
        self, obs: Observation, state: np.ndarray, f: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        e = self.force_reference(obs, state)[0] - f
        integral = state[:, _COMMON] + e * self.dt
        state[rows, _COMMON] = integral[rows]
        z_bar = self.along_normal(obs["tool_pos_ref"] - self.surface_point)
        zd_bar = self.along_normal(obs["tool_vel_ref"])
        z = z_bar - self.k_f * e - self.k_i * integral
        return z, zd_bar - self.k_i * e


INTERACTION_CONTROLLERS: tuple[type[Controller], ...] = (
    Impedance,
    Admittance,
    ExplicitForce,
    ImplicitForce,
    ParallelForcePosition,
)
